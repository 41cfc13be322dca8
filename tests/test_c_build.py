"""Build checks of the C core with gcc, outside cffi.

(a) the fixed build contains no floating point (-mgeneral-regs-only, x86-64);
(b) both builds are clean under -std=c99 -Wall -Wextra -Werror -pedantic;
(c) firmware/core includes no platform header, and the fixed build compiles
    freestanding with only the compiler's own headers;
(d) tests/c/vector_driver.c, built with UBSan and ASan, replays every golden vector;
(e) compiling with both or neither of IMU_FIXED / IMU_FLOAT stops at the #error;
(f) the filters' state structs have no implicit padding (a checkpoint copies them byte for byte).
Skipped only when gcc is absent.
"""
from __future__ import annotations

import os
import platform
import re
import shutil
import subprocess
from pathlib import Path

import pytest

GCC = shutil.which("gcc")
pytestmark = pytest.mark.skipif(GCC is None, reason="gcc not found")

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "firmware" / "core"
SOURCES = sorted(CORE.glob("*.c"))
HEADERS = sorted(CORE.glob("*.h"))
DRIVER = ROOT / "tests" / "c" / "vector_driver.c"
VECTORS = sorted((ROOT / "shared" / "vectors").glob("*.vec"))
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
IS_X86_64 = platform.machine().lower() in ("x86_64", "amd64")


def gcc(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([GCC, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=120)


def assert_ok(proc: subprocess.CompletedProcess, what: str):
    assert proc.returncode == 0, f"{what} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"


def test_core_sources_exist():
    names = {p.name for p in SOURCES}
    assert {"imu_math.c", "imu_filter.c", "imu_eecf.c", "imu_kf1d.c", "imu_sensor.c"} <= names


# --------------------------------------------------------------------------- (a) no floating point


@pytest.mark.skipif(not IS_X86_64, reason="-mgeneral-regs-only check runs on x86-64 only")
@pytest.mark.parametrize("opt", ["-O0", "-O2"])
def test_fixed_build_uses_no_floating_point(opt, tmp_path):
    for src in SOURCES:
        proc = gcc("-std=c99", "-DIMU_FIXED", "-mgeneral-regs-only", opt, f"-I{CORE}", "-c", src,
                   "-o", tmp_path / (src.stem + ".o"))
        assert_ok(proc, f"{src.name} {opt} -mgeneral-regs-only (floating point in the fixed build?)")


@pytest.mark.skipif(not IS_X86_64, reason="-mgeneral-regs-only check runs on x86-64 only")
def test_general_regs_only_rejects_floating_point(tmp_path):
    """Control: the flag does catch floating point, in a snippet and in the float twin."""
    snippet = tmp_path / "fp.c"
    snippet.write_text("int f(int a) { double x = a; x *= 1.5; return (int)x; }\n")
    assert gcc("-std=c99", "-O2", "-mgeneral-regs-only", "-c", snippet, "-o", tmp_path / "fp.o").returncode != 0
    proc = gcc("-std=c99", "-DIMU_FLOAT", "-mgeneral-regs-only", f"-I{CORE}", "-c", CORE / "imu_math.c",
               "-o", tmp_path / "m.o")
    assert proc.returncode != 0


# --------------------------------------------------------------------------- (b) strict warnings


@pytest.mark.parametrize("opt", ["-O0", "-O2"])
@pytest.mark.parametrize("arith", ["IMU_FIXED", "IMU_FLOAT"])
def test_strict_warnings(arith, opt, tmp_path):
    proc = gcc(*STRICT, opt, f"-D{arith}", f"-I{CORE}", "-c", *SOURCES, cwd=tmp_path)
    assert_ok(proc, f"{arith} {opt} {' '.join(STRICT)}")
    assert len(list(tmp_path.glob("*.o"))) == len(SOURCES)


@pytest.mark.parametrize("arith", ["IMU_FIXED", "IMU_FLOAT"])
def test_headers_are_self_contained(arith, tmp_path):
    for header in HEADERS:
        unit = tmp_path / f"only_{header.stem}.c"
        unit.write_text(f'#include "{header.name}"\ntypedef int translation_unit_not_empty;\n')
        assert_ok(gcc(*STRICT, f"-D{arith}", f"-I{CORE}", "-fsyntax-only", unit), f"{header.name} alone")


# --------------------------------------------------------------------------- (c) headers

ALLOWED_SYSTEM = {"stdint.h", "stddef.h"}
FLOAT_ONLY_SYSTEM = {"math.h"}
_INCLUDE = re.compile(r'^\s*#\s*include\s*([<"])([^>"]+)[>"]')
_COND = re.compile(r"^\s*#\s*(ifdef|ifndef|if|elif|else|endif)\b(.*)$")


def _norm(expr: str) -> str:
    expr = re.sub(r"/\*.*?\*/|//.*$", "", expr)
    expr = re.sub(r"defined\s*\(\s*(\w+)\s*\)|defined\s+(\w+)", lambda m: f"defined({m.group(1) or m.group(2)})",
                  expr)
    return re.sub(r"\s+", "", expr)


#: Conditions under which only the float twin is compiled (exactly one of the two is defined).
FLOAT_CONDITIONS = {"defined(IMU_FLOAT)", "!defined(IMU_FIXED)", "!(defined(IMU_FIXED))"}


def include_violations(text: str, name: str, local_headers: set[str]) -> list[str]:
    """Platform or unknown includes of one source file (see module docstring, check (c))."""
    stack: list[str] = []
    problems = []
    for no, line in enumerate(text.splitlines(), 1):
        m = _COND.match(line)
        if m:
            kind, rest = m.group(1), m.group(2).strip()
            if kind == "ifdef":
                stack.append(f"defined({rest.split()[0]})")
            elif kind == "ifndef":
                stack.append(f"!defined({rest.split()[0]})")
            elif kind == "if":
                stack.append(_norm(rest))
            elif kind == "elif" and stack:
                stack[-1] = _norm(rest)
            elif kind == "else" and stack:
                stack[-1] = f"!({stack[-1]})"
            elif kind == "endif" and stack:
                stack.pop()
            continue
        m = _INCLUDE.match(line)
        if not m:
            continue
        delim, header = m.groups()
        where = f"{name}:{no}: #include {delim}{header}{'>' if delim == '<' else chr(34)}"
        if delim == '"':
            if header not in local_headers:
                problems.append(f"{where}: not a firmware/core header")
        elif header in ALLOWED_SYSTEM:
            pass
        elif header in FLOAT_ONLY_SYSTEM:
            if not any(cond in FLOAT_CONDITIONS for cond in stack):
                problems.append(f"{where}: allowed only inside #ifdef IMU_FLOAT")
        else:
            problems.append(f"{where}: platform header (only <stdint.h>, <stddef.h>, <math.h> for IMU_FLOAT)")
    return problems


def test_include_checker_catches_violations():
    local = {"imu_arith.h"}
    ok = ('#include "imu_arith.h"\n#include <stdint.h>\n#include <stddef.h>\n'
          "#ifdef IMU_FLOAT\n#include <math.h>\n#endif\n"
          "#ifdef IMU_FIXED\nint x;\n#else\n#include <math.h>\n#endif\n"
          "#if defined(IMU_FLOAT)\n#  include <math.h>\n#endif\n")
    assert include_violations(ok, "ok.c", local) == []
    assert len(include_violations("#include <stdio.h>\n", "a.c", local)) == 1
    assert len(include_violations('#include "board.h"\n', "a.c", local)) == 1
    assert len(include_violations("#include <math.h>\n", "a.c", local)) == 1
    assert len(include_violations("#ifdef IMU_FIXED\n#include <math.h>\n#endif\n", "a.c", local)) == 1
    assert len(include_violations("#ifdef IMU_FLOAT\n#endif\n#include <math.h>\n", "a.c", local)) == 1


def test_core_includes_no_platform_header():
    local = {p.name for p in HEADERS + SOURCES}  # imu_navcov.c compiles imu_cov.c again
    problems = []
    n_includes = 0
    for path in SOURCES + HEADERS:
        text = path.read_text()
        n_includes += len([ln for ln in text.splitlines() if _INCLUDE.match(ln)])
        problems += include_violations(text, path.name, local)
    assert n_includes >= len(SOURCES), "the include scan found nothing: checker broken?"
    assert not problems, "\n".join(problems)


def test_fixed_build_is_freestanding(tmp_path):
    """The fixed build needs nothing but the compiler's freestanding headers (no libc at all)."""
    gcc_include = gcc("-print-file-name=include").stdout.strip()
    assert Path(gcc_include, "stdint.h").is_file()
    for src in SOURCES:
        proc = gcc("-std=c99", "-DIMU_FIXED", "-ffreestanding", "-nostdinc", "-isystem", gcc_include,
                   f"-I{CORE}", "-c", src, "-o", tmp_path / (src.stem + ".o"))
        assert_ok(proc, f"freestanding {src.name}")


# --------------------------------------------------------------------------- (d) vector driver


def _build_driver(out: Path, *flags) -> Path:
    proc = gcc(*STRICT, "-DIMU_FIXED", *flags, f"-I{CORE}", DRIVER, *SOURCES, "-o", out)
    assert_ok(proc, f"vector driver build {' '.join(flags)}")
    return out


@pytest.fixture(scope="module")
def sanitized_driver(tmp_path_factory):
    if GCC is None:
        pytest.skip("gcc not found")
    out = tmp_path_factory.mktemp("driver") / "vector_driver_san"
    return _build_driver(out, "-fsanitize=undefined,address", "-fno-sanitize-recover=all", "-g")


def run_driver(driver: Path, *files) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    # No heap use in the driver; leak detection is off because LeakSanitizer cannot run under ptrace.
    env["ASAN_OPTIONS"] = "detect_leaks=0:abort_on_error=0"
    env["UBSAN_OPTIONS"] = "print_stacktrace=1"
    return subprocess.run([str(driver), *map(str, files)], capture_output=True, text=True, env=env, timeout=120)


def test_vectors_exist():
    assert len(VECTORS) >= 4, "no golden vectors in shared/vectors; run tools/gen_vectors.py"


@pytest.mark.parametrize("vector", VECTORS, ids=[p.stem for p in VECTORS])
def test_vector_driver_sanitized(sanitized_driver, vector):
    proc = run_driver(sanitized_driver, vector)
    assert proc.returncode == 0, f"{vector.name}:\n{proc.stdout}\n{proc.stderr}"
    assert "OK" in proc.stdout and "runtime error" not in proc.stderr


def test_vector_driver_optimised(tmp_path):
    """-O2 without sanitizers gives the same integers (no optimisation-dependent result)."""
    driver = _build_driver(tmp_path / "vector_driver_o2", "-O2")
    proc = run_driver(driver, *VECTORS)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.count(": OK,") == len(VECTORS)


def _damaged_copy(tmp_path: Path, edit) -> Path:
    lines = VECTORS[0].read_text().split("\n")
    edit(lines)
    out = tmp_path / "damaged.vec"
    out.write_text("\n".join(lines))
    return out


def test_vector_driver_reports_first_mismatch(sanitized_driver, tmp_path):
    def bump_pitch_of_sample_37(lines):
        i = lines.index("data") + 1 + 37
        values = lines[i].split(" ")
        values[9 + 5] = str(int(values[9 + 5]) + 1)  # outputs start at column 9; pitch is output 5
        lines[i] = " ".join(values)
        j = lines.index("data") + 1 + 50
        values = lines[j].split(" ")
        values[9] = str(int(values[9]) - 1)
        lines[j] = " ".join(values)

    proc = run_driver(sanitized_driver, _damaged_copy(tmp_path, bump_pitch_of_sample_37))
    assert proc.returncode == 1
    assert "sample 37" in proc.stderr and "field pitch" in proc.stderr and "sample 50" not in proc.stderr


def test_vector_driver_rejects_incomplete_or_unknown_settings(sanitized_driver, tmp_path):
    def drop_first_setting(lines):
        lines.pop(next(i for i, ln in enumerate(lines) if ln.startswith("setting ")))

    def add_unknown_setting(lines):
        lines.insert(next(i for i, ln in enumerate(lines) if ln.startswith("setting ")), "setting warp 16 1 0.0 s")

    def change_q_format(lines):
        i = next(i for i, ln in enumerate(lines) if ln.startswith("setting "))
        parts = lines[i].split(" ")
        parts[2] = str(int(parts[2]) + 1)
        lines[i] = " ".join(parts)

    for edit, needle in ((drop_first_setting, "missing"), (add_unknown_setting, "warp"),
                         (change_q_format, "in the C core")):
        proc = run_driver(sanitized_driver, _damaged_copy(tmp_path, edit))
        assert proc.returncode == 1 and needle in proc.stderr, (edit.__name__, proc.stderr)


# --------------------------------------------------------------------------- (e) arithmetic selection


@pytest.mark.parametrize("defines,message", [
    (["-DIMU_FIXED", "-DIMU_FLOAT"], "define exactly one of IMU_FIXED and IMU_FLOAT"),
    ([], "define IMU_FIXED"),
])
def test_arithmetic_must_be_chosen_once(defines, message):
    """Every source built on the arithmetic layer refuses an ambiguous or missing
    choice (the frame codec is integer code independent of it)."""
    layered = [src for src in SOURCES
               if "imu_arith.h" in gcc("-std=c99", "-DIMU_FIXED", f"-I{CORE}", "-MM", src).stdout]
    assert len(layered) >= 6
    for src in layered:
        proc = gcc("-std=c99", *defines, f"-I{CORE}", "-fsyntax-only", src)
        assert proc.returncode != 0, f"{src.name} compiled with {defines or 'no arithmetic'}"
        assert "#error" in proc.stderr and message in proc.stderr, proc.stderr


# --------------------------------------------------------------------------- (f) no padding in a state

#: Structs that may hold implicit padding: they hold pointers or are constants, never a filter's state.
NOT_STATE = {"imu_setting_desc_t", "imu_filter_kind_t", "imu_filter_t", "imu_cov_map_t", "imu_navcov_map_t"}


def _padded_structs(compiler: str, *flags) -> set[str]:
    """The structs -Wpadded reports padding in, compiling imu_filter.c (which includes every state)."""
    proc = subprocess.run([compiler, "-std=c99", "-DIMU_FIXED", "-Wpadded", "-fsyntax-only", *flags, f"-I{CORE}",
                           str(CORE / "imu_filter.c")], capture_output=True, text=True, timeout=120)
    assert_ok(proc, f"{compiler} -Wpadded")
    found = set()
    for path, line in re.findall(r"^(\S+?\.h):(\d+):\d+: warning: padding", proc.stderr, re.M):
        text = Path(path if Path(path).is_absolute() else CORE / Path(path).name).read_text().splitlines()
        closing = next(t for t in text[int(line) - 1:] if t.startswith("}"))  # the struct's "} name_t;"
        found.add(closing.strip("} ;"))
    return found


@pytest.mark.parametrize("target", ["host", "cortex-m4"])
def test_filter_states_have_no_implicit_padding(target):
    """A checkpoint (imu_filter_state) is a state struct's bytes: with no implicit padding every
    byte is defined, and the layout is the same on the board and the host."""
    if target == "host":
        padded = _padded_structs(GCC)
    else:
        arm = shutil.which("arm-none-eabi-gcc")
        if arm is None:
            pytest.skip("arm-none-eabi-gcc not found")
        padded = _padded_structs(arm, "-mcpu=cortex-m4", "-mthumb")
    assert padded and padded <= NOT_STATE, f"implicit padding in {sorted(padded - NOT_STATE)}"
