#!/bin/sh
# Install the system packages imulink needs, on Debian or Ubuntu (what `make setup` runs).
#
#   gcc, make, python3-venv                    the host package and the native board
#   gcc-arm-none-eabi, libnewlib-arm-none-eabi the ARM images (QEMU board, STM32F407 board)
#   qemu-system-arm                            the ARM image's tests and `--target qemu`
#
# Installs only what is missing: as root directly, otherwise through sudo. Exits 1 with the
# apt-get command to run when it cannot install them itself.
set -eu

missing=""
have() { command -v "$1" >/dev/null 2>&1; }
have gcc || missing="$missing gcc"
have make || missing="$missing make"
python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || missing="$missing python3-venv"
have arm-none-eabi-gcc || missing="$missing gcc-arm-none-eabi"
# newlib: without it arm-none-eabi-gcc prints the bare file name instead of a path
if ! have arm-none-eabi-gcc || [ "$(arm-none-eabi-gcc -print-file-name=libc_nano.a)" = "libc_nano.a" ]; then
    missing="$missing libnewlib-arm-none-eabi"
fi
have qemu-system-arm || missing="$missing qemu-system-arm"

[ -z "$missing" ] && exit 0

echo "imulink: installing system packages:$missing"
if [ "$(id -u)" = 0 ]; then
    sudo=""
elif have sudo && sudo -n true 2>/dev/null; then
    sudo="sudo"
else
    echo "imulink: cannot install them without root; run: sudo apt-get install$missing" >&2
    exit 1
fi
if ! have apt-get; then
    echo "imulink: no apt-get on this machine; install the equivalents of:$missing" >&2
    exit 1
fi
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends $missing
