#!/bin/sh
# Install the system packages imulink needs, on Debian or Ubuntu (what `make setup` runs).
#
#   gcc, make, python3-venv                    the host package and the native board
#   gcc-arm-none-eabi, libnewlib-arm-none-eabi the ARM images (QEMU board, STM32F407 board)
#   qemu-system-arm                            the ARM image's tests and `--target qemu`
#   clang, libclang-rt-N-dev                   the core's campaign under -fsanitize=undefined,integer
#                                              (tests/test_campaign.py; the sanitizer runtime is only
#                                              a recommendation of Debian's clang package)
#   xvfb, libxcb-cursor0, libxcb-icccm4,       `imulink monitor` in a real window without a display (Xvfb):
#   libxcb-keysyms1                            the X libraries Qt's xcb platform (PyQt6-Qt6) loads that a
#                                              minimal Debian lacks (Qt 6.5+ needs libxcb-cursor0)
#   libgl1, libglx-mesa0, libegl1,             OpenGL in software (Mesa's llvmpipe) for the monitor's 3D
#   libgl1-mesa-dri                            board view, in Xvfb too
#   ser2net                                    a labgrid exporter shares a board's serial port through it
#                                              (RFC 2217): `make test-farm` exports an emulated board's pty
#
# Installs only what is missing: as root directly, otherwise through sudo. Exits 1 with the
# apt-get command to run when it cannot install them itself.
set -eu

have() { command -v "$1" >/dev/null 2>&1; }

# Install the packages named in $1 (space-separated, leading space), or explain how to.
install_packages() {
    echo "imulink: installing system packages:$1"
    if [ "$(id -u)" = 0 ]; then
        sudo=""
    elif have sudo && sudo -n true 2>/dev/null; then
        sudo="sudo"
    else
        echo "imulink: cannot install them without root; run: sudo apt-get install$1" >&2
        exit 1
    fi
    if ! have apt-get; then
        echo "imulink: no apt-get on this machine; install the equivalents of:$1" >&2
        exit 1
    fi
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends $1
}

# 0 when clang links a program with the undefined and integer sanitizers.
clang_sanitizers_link() {
    dir=$(mktemp -d)
    echo 'int main(void) { return 0; }' >"$dir/t.c"
    if clang -fsanitize=undefined,integer "$dir/t.c" -o "$dir/t" >/dev/null 2>&1; then
        rm -rf "$dir"
        return 0
    fi
    rm -rf "$dir"
    return 1
}

missing=""
have gcc || missing="$missing gcc"
have make || missing="$missing make"
python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || missing="$missing python3-venv"
have arm-none-eabi-gcc || missing="$missing gcc-arm-none-eabi"
# newlib: without it arm-none-eabi-gcc prints the bare file name instead of a path
if ! have arm-none-eabi-gcc || [ "$(arm-none-eabi-gcc -print-file-name=libc_nano.a)" = "libc_nano.a" ]; then
    missing="$missing libnewlib-arm-none-eabi"
fi
have qemu-system-arm || missing="$missing qemu-system-arm"
have clang || missing="$missing clang"
have Xvfb || missing="$missing xvfb"
for lib in xcb-cursor.so.0:libxcb-cursor0 xcb-icccm.so.4:libxcb-icccm4 xcb-keysyms.so.1:libxcb-keysyms1 \
           GL.so.1:libgl1 GLX_mesa.so.0:libglx-mesa0 EGL.so.1:libegl1; do
    ldconfig -p 2>/dev/null | grep -q "lib${lib%%:*}" || missing="$missing ${lib#*:}"
done
ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1 || missing="$missing libgl1-mesa-dri"
have ser2net || [ -x /usr/sbin/ser2net ] || missing="$missing ser2net"

[ -z "$missing" ] || install_packages "$missing"

# The sanitizer runtime of the clang just found or installed (its version is known only now).
if ! clang_sanitizers_link; then
    install_packages " libclang-rt-$(clang -dumpversion | cut -d. -f1)-dev"
    if ! clang_sanitizers_link; then
        echo "imulink: clang cannot link -fsanitize=undefined,integer (install its compiler-rt runtime)" >&2
        exit 1
    fi
fi
exit 0
