"""Adversarial campaign of the fixed-point core (issue 8, "Checks that keep these fixed").

tests/c/campaign_driver.c runs every filter with every setting at its true minimum and
maximum (found by bisection on set_settings' range check), one at a time and all at once,
times hostile input streams (INT16 extremes, zeros, alternating saturation, random counts,
spins near gyro full scale, free fall, a drop) at 30 Hz and 5 kHz, and the sensor scales at
their extremes. It is built twice:

- gcc: -DIMU_FIXED -DIMU_CHECK_NARROWING -fsanitize=undefined,address: every int64 -> int32
  narrowing of the arithmetic layer that does not saturate is checked (imu_arith.h);
- clang: -fsanitize=undefined,integer on the filter sources (the firmware's own macro
  expansions, unchecked: signed overflow of IMU_ADD, shifts, implicit truncations,
  unsigned wrap). Skipped only when clang is absent (tools/install-system-packages.sh
  installs it, so CI has it).

A case that aborts is recorded with the first error and the campaign restarts after it, so
one run lists every failing case. Each failure is reported with its case name (filter /
settings / sensor scales / input / rate), the sample, the file:line of the error, the first
filter-level caller, and a one-line reproduction:

    .venv/bin/python tests/test_campaign.py --build gcc --case 'eskf/acc_noise=max/sensor=default/still/30Hz'
    .venv/bin/python tests/test_campaign.py --build gcc [--filter eskf]    # whole campaign, summary
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "firmware" / "core"
DRIVER = ROOT / "tests" / "c" / "campaign_driver.c"
#: The filter core: every source of firmware/core but the frame codec (its CRCs wrap on
#: purpose, and no filter uses it).
NOT_FILTER = {"imu_proto.c", "imu_proto_gen.c"}
FILTER_SOURCES = [p for p in sorted(CORE.glob("imu_*.c")) if p.name not in NOT_FILTER]
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
FILTERS = ("eecf", "kf1d", "eskf", "nav")
#: The header that documents a filter's settings, where it is not imu_<filter>.h.
SETTINGS_HEADERS = {"nav": ("imu_navfilter.h", "imu_navkf.h")}  # nav's tuning is imu_navkf_tuning_t
#: The fast rate of the campaign: 5 kHz, or the filter's largest below it.
FAST_RATES = {"nav": "1kHz"}
GCC = shutil.which("gcc")
CLANG = shutil.which("clang")
#: Cases run in parallel shards (the CI machines have 2 cores).
SHARDS = max(1, min(2, os.cpu_count() or 1))
DRIVER_TIMEOUT = 600


# --------------------------------------------------------------------------- builds


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=300, **kw)


def _check(proc: subprocess.CompletedProcess, what: str):
    if proc.returncode != 0:
        raise RuntimeError(f"{what} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")


def build_gcc(out_dir: Path) -> Path:
    """gcc, checked narrowing, UBSan + ASan, every sanitizer error fatal."""
    out = out_dir / "campaign_gcc"
    _check(_run([GCC, *STRICT, "-O1", "-g", "-DIMU_FIXED", "-DIMU_CHECK_NARROWING",
                 "-fsanitize=undefined,address", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer",
                 f"-I{CORE}", DRIVER, *FILTER_SOURCES, "-lm", "-o", out]), "gcc campaign build")
    return out


def build_clang(out_dir: Path) -> Path:
    """clang, -fsanitize=undefined,integer on the filter sources (the driver: undefined only,
    its random generator wraps on purpose), unchecked narrowing: the firmware's expansions."""
    out = out_dir / "campaign_clang"
    objs = []
    for src in FILTER_SOURCES:
        obj = out_dir / (src.stem + ".clang.o")
        _check(_run([CLANG, *STRICT, "-O1", "-g", "-DIMU_FIXED", "-fsanitize=undefined,integer",
                     "-fno-sanitize-recover=all", f"-I{CORE}", "-c", src, "-o", obj]), f"clang {src.name}")
        objs.append(obj)
    drv = out_dir / "campaign_driver.clang.o"
    _check(_run([CLANG, *STRICT, "-O1", "-g", "-DIMU_FIXED", "-fsanitize=undefined", "-fno-sanitize-recover=all",
                 f"-I{CORE}", "-c", DRIVER, "-o", drv]), "clang campaign driver")
    _check(_run([CLANG, "-fsanitize=undefined,integer", drv, *objs, "-lm", "-o", out]), "clang campaign link")
    return out


BUILDERS = {"gcc": build_gcc, "clang": build_clang}


def driver_env(stack: bool = False) -> dict:
    """Sanitizer options. Stack traces of sanitizer errors cost a symbolizer process per
    driver run: the campaign runs without them and re-runs one case per distinct error with
    them (narrowing reports print their own stack, in-process)."""
    env = dict(os.environ)
    # LeakSanitizer cannot run under ptrace; abort() is the narrowing check's own exit.
    env["ASAN_OPTIONS"] = "detect_leaks=0:abort_on_error=0:handle_abort=0"
    env["UBSAN_OPTIONS"] = f"print_stacktrace={int(stack)}:halt_on_error=1"
    symbolizer = shutil.which("llvm-symbolizer")
    if symbolizer:
        env.setdefault("ASAN_SYMBOLIZER_PATH", symbolizer)
        env.setdefault("UBSAN_SYMBOLIZER_PATH", symbolizer)
    return env


# --------------------------------------------------------------------------- running and parsing


@dataclass
class Failure:
    kind: str       # NARROWING, UBSAN, ASAN, OUTPUT, CRASH
    case: str       # case name (filter/settings/sensor/input/rate)
    site: str       # file:line of the error ("" for output checks)
    via: str        # first caller in a filter source (imu_eskf.c, ...), when the site is a helper
    message: str    # the error line
    sample: str = ""


@dataclass
class Campaign:
    cases: int = 0
    samples: int = 0
    restarts: int = 0
    failures: list = field(default_factory=list)
    seconds: float = 0.0


_LOCATION = re.compile(r"(?:firmware/core/|/)(imu_\w+\.[ch]):(\d+)")
_FRAME = re.compile(r"^\s*#\d+ 0x[0-9a-f]+ in (\S+) (\S+?):(\d+)")
_HELPERS = ("imu_math.c", "imu_arith.h", "imu_cov.c")


def _short(path: str) -> str:
    return path.split("/")[-1]


def _frames(stderr: str) -> list[tuple[str, str]]:
    out = []
    for line in stderr.splitlines():
        m = _FRAME.match(line)
        if m:
            out.append((m.group(1), f"{_short(m.group(2))}:{m.group(3)}"))
    return out


def _via(frames: list[tuple[str, str]], site: str) -> str:
    """The first caller outside the helpers (imu_math.c, imu_cov.c, the layer), as func@file:line."""
    if not site or not site.startswith(_HELPERS):
        return ""
    for func, loc in frames:
        if loc.startswith("imu_") and not loc.startswith(_HELPERS):
            return f"{func}@{loc}"
    return ""


def parse_narrowings(stderr: str) -> list[Failure]:
    """Every NARROWING report (the driver ran with --keep-going), each with its own stack."""
    out = []
    lines = stderr.splitlines()
    for i, line in enumerate(lines):
        if not line.startswith("NARROWING "):
            continue
        frames_text = []
        for nxt in lines[i + 1:]:
            if nxt.startswith("NARROWING ") or not (nxt.strip().startswith("#") or not nxt.strip()):
                break
            frames_text.append(nxt)
        frames = _frames("\n".join(frames_text))
        m = re.match(r"NARROWING (\S+):(\d+): (.*?) \| case (\S+) \| sample (-?\d+)", line)
        if not m:
            out.append(Failure("NARROWING", "?", "?", "", line))
            continue
        site = f"{_short(m.group(1))}:{m.group(2)}"
        out.append(Failure("NARROWING", m.group(4), site, _via(frames, site), m.group(3), m.group(5)))
    return out


def parse_abort(stdout: str, stderr: str, returncode: int) -> tuple[int | None, Failure]:
    """The case that aborted the driver (the last one it started) and its error."""
    case_index, case_name = None, "?"
    for line in stdout.splitlines():
        if line.startswith("CASE "):
            _, idx, name = line.split(" ", 2)
            case_index, case_name = int(idx), name
    frames = _frames(stderr)
    for line in stderr.splitlines():
        m = re.search(r"(\S+):(\d+):(\d+): runtime error: (.*)", line)
        if m:
            site = f"{_short(m.group(1))}:{m.group(2)}"
            return case_index, Failure("UBSAN", case_name, site, _via(frames, site), m.group(4))
    for line in stderr.splitlines():
        if "ERROR: AddressSanitizer" in line:
            site = next((loc for func, loc in frames if loc.startswith("imu_")), "?")
            return case_index, Failure("ASAN", case_name, site, _via(frames, site), line.strip())
    tail = (stderr.strip().splitlines() or [f"exit status {returncode}"])[-1]
    return case_index, Failure("CRASH", case_name, "", "", f"exit status {returncode}: {tail}")


def parse_outputs(stdout: str) -> list[Failure]:
    out = []
    for line in stdout.splitlines():
        if line.startswith("OUTPUT "):
            m = re.search(r"\| case (\S+)", line)
            s = re.search(r"\| sample (\d+)", line)
            out.append(Failure("OUTPUT", m.group(1) if m else "?", "", "", line.split(" | ")[0][7:],
                               s.group(1) if s else ""))
    return out


def run_range(driver: Path, start: int, stop: int, result: Campaign, lock: threading.Lock):
    """Cases start..stop-1: a narrowing failure abandons its case and the driver goes on
    (--keep-going); after a sanitizer abort the driver restarts after the failing case."""
    env = driver_env()
    while start < stop:
        proc = subprocess.run([str(driver), "--keep-going", "--from", str(start), "--to", str(stop)],
                              capture_output=True, text=True, env=env, timeout=DRIVER_TIMEOUT)
        found = parse_outputs(proc.stdout) + parse_narrowings(proc.stderr)
        done = re.search(r"^DONE cases=(\d+) samples=(\d+)", proc.stdout, re.M)
        with lock:
            result.failures.extend(found)
        if done:
            with lock:
                result.cases += int(done.group(1))
                result.samples += int(done.group(2))
            if proc.returncode not in (0, 1):
                raise RuntimeError(f"campaign driver exit {proc.returncode}:\n{proc.stderr[-4000:]}")
            return
        index, failure = parse_abort(proc.stdout, proc.stderr, proc.returncode)
        if index is None:  # died before its first case: nothing to skip over
            raise RuntimeError(f"campaign driver died before any case ({proc.returncode}):\n{proc.stderr[-4000:]}")
        with lock:
            result.failures.append(failure)
            result.restarts += 1
            result.cases += index - start + 1
        start = index + 1


def case_indices(driver: Path, filter_name: str | None = None) -> list[tuple[int, str, int]]:
    cmd = [str(driver), "--list"] + (["--filter", filter_name] if filter_name else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, env=driver_env(), timeout=120)
    _check(proc, "campaign --list")
    rows = []
    for line in proc.stdout.splitlines():
        idx, name, length = line.split(" ")
        rows.append((int(idx), name, int(length)))
    return rows


def run_campaign(driver: Path, filter_name: str | None = None, shards: int = SHARDS) -> Campaign:
    """Every case of `filter_name` (all filters for None), in `shards` parallel processes
    balanced by sample count."""
    rows = case_indices(driver, filter_name)
    result = Campaign()
    if not rows:
        return result
    # Contiguous index ranges of about equal sample counts (cases of one filter are contiguous).
    total = sum(n for _, _, n in rows)
    bounds, acc, start = [], 0, rows[0][0]
    for i, (idx, _, n) in enumerate(rows):
        acc += n
        if len(bounds) < shards - 1 and acc >= total * (len(bounds) + 1) / shards and i + 1 < len(rows):
            bounds.append((start, idx + 1))
            start = rows[i + 1][0]
    bounds.append((start, rows[-1][0] + 1))
    lock = threading.Lock()
    errors = []

    def worker(lo, hi):
        try:
            run_range(driver, lo, hi, result, lock)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    t0 = time.monotonic()
    threads = [threading.Thread(target=worker, args=b) for b in bounds]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    order = {name: idx for idx, name, _ in rows}
    result.failures.sort(key=lambda f: order.get(f.case, -1))  # shards finish in any order
    find_callers(driver, result.failures)
    result.seconds = time.monotonic() - t0
    return result


def find_callers(driver: Path, failures: list[Failure]):
    """For sanitizer errors in a helper (imu_math.c, ...): re-run the first case of each
    distinct error with stack traces to name the filter-level caller."""
    seen = {}
    for f in failures:
        if f.kind not in ("UBSAN", "ASAN") or not f.site.startswith(_HELPERS):
            continue
        key = (f.kind, f.site, _message_key(f.message))
        if key not in seen:
            proc = subprocess.run([str(driver), "--case", f.case], capture_output=True, text=True,
                                  env=driver_env(stack=True), timeout=DRIVER_TIMEOUT)
            _, again = parse_abort(proc.stdout, proc.stderr, proc.returncode)
            seen[key] = again.via if again.site == f.site else ""
        f.via = seen[key]


def repro(build: str, case: str) -> str:
    return f".venv/bin/python tests/test_campaign.py --build {build} --case '{case}'"


def _message_key(message: str) -> str:
    return re.sub(r"-?\d+", "N", message)[:80]


def format_failures(build: str, failures: list[Failure]) -> str:
    """Failures grouped by (kind, site, message kind) and, for narrowings (whose every report
    carries its stack), the filter-level caller: each group with its cases."""
    groups: "OrderedDict[tuple, list[Failure]]" = OrderedDict()
    for f in failures:
        groups.setdefault((f.kind, f.site, f.via if f.kind == "NARROWING" else "", _message_key(f.message)),
                          []).append(f)
    lines = [f"{len(failures)} failing case(s) in {len(groups)} distinct failure(s) ({build} build):"]
    for (kind, site, _, _), items in groups.items():
        first = items[0]
        via = first.via if kind == "NARROWING" else next((f.via for f in items if f.via), "")
        where = site + (f" (via {via})" if via else "")
        lines.append(f"- {kind} {where}: {first.message}")
        at = {"": "", "-1": " in set_settings"}.get(first.sample, f" at sample {first.sample}")
        lines.append(f"    {len(items)} case(s), e.g. {first.case}{at}")
        for other in items[1:6]:
            lines.append(f"      also {other.case}")
        if len(items) > 6:
            lines.append(f"      ... and {len(items) - 6} more")
        lines.append(f"    reproduce: {repro(build, first.case)}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def drivers(tmp_path_factory):
    return {}


def _driver(drivers: dict, build: str, tmp_path_factory) -> Path:
    if build not in drivers:
        compiler = GCC if build == "gcc" else CLANG
        if compiler is None:
            pytest.skip(f"{build} not found")
        drivers[build] = BUILDERS[build](tmp_path_factory.mktemp(f"campaign_{build}"))
    return drivers[build]


# --------------------------------------------------------------------------- tests


@pytest.mark.skipif(GCC is None, reason="gcc not found")
def test_checked_narrowing_reports_file_and_line_and_aborts(tmp_path):
    """Control: each checked operation of the layer reports its call site and aborts
    on a value outside int32, and lets every value inside through unchanged."""
    ops = {
        "IMU_ADD": "IMU_ADD(INT32_MAX, v)",
        "IMU_SUB": "IMU_SUB(INT32_MIN, v)",
        "IMU_MUL": "IMU_MUL(INT32_MAX, INT32_MAX, 30 + v - 1)",
        "imu_mul": "imu_mul(INT32_MIN, INT32_MIN, 31 + v - 1)",
        "IMU_SHR": "IMU_SHR((int64_t)INT32_MAX * 4, v)",
        "IMU_HALF": "IMU_HALF((int64_t)INT32_MAX * 2 + 2 * v)",
        "IMU_TO_INT": "IMU_TO_INT((int64_t)INT32_MAX << 8, 7 + v - 1)",
        "IMU_MUL_TO_INT": "IMU_MUL_TO_INT(INT32_MAX, INT32_MAX, 30 + v - 1)",
        "IMU_NARROW": "IMU_NARROW((int64_t)INT32_MAX + v)",
    }
    for name, expr in ops.items():
        src = tmp_path / f"{name}.c"
        src.write_text(
            '#include <stdio.h>\n#include <stdlib.h>\n#include "imu_arith.h"\n'
            "void imu_narrowing_failed(const char *file, int line, const char *what, int64_t value)\n"
            '{ printf("REPORT %s:%d %s %lld\\n", file, line, what, (long long)value); fflush(stdout); abort(); }\n'
            "int main(int argc, char **argv)\n{\n    volatile int32_t v = argc;\n    int32_t r;\n    (void)argv;\n"
            f"    r = {expr};\n"
            '    printf("VALUE %ld\\n", (long)r);\n    return 0;\n}\n')
        exe = tmp_path / name
        _check(_run([GCC, *STRICT, "-DIMU_FIXED", "-DIMU_CHECK_NARROWING", f"-I{CORE}", src, "-o", exe]), name)
        proc = _run([exe])  # argc = 1: the value is out of range
        assert proc.returncode != 0, f"{name}: no abort\n{proc.stdout}"
        what = "IMU_MUL" if name == "imu_mul" else name
        assert re.search(rf"REPORT \S*{name}\.c:11 {what} -?\d+", proc.stdout), (name, proc.stdout)
    # In range: unchanged values, no report.
    src = tmp_path / "inside.c"
    src.write_text(
        '#include <stdio.h>\n#include "imu_arith.h"\n'
        "void imu_narrowing_failed(const char *file, int line, const char *what, int64_t value)\n"
        "{ (void)file; (void)line; (void)what; (void)value; puts(\"REPORT\"); }\n"
        "int main(void)\n{\n"
        "    volatile int32_t a = INT32_MAX - 1, b = -3;\n"
        '    printf("%ld %ld %ld %ld %ld %ld\\n", (long)IMU_ADD(a, 1), (long)IMU_SUB(b, 5), (long)IMU_MUL(a, b, 2),\n'
        "           (long)IMU_SHR((int64_t)a * 4, 2), (long)IMU_HALF(b), (long)IMU_MUL_TO_INT(a, 2, 1));\n"
        "    return 0;\n}\n")
    outs = []
    for checked in ([], ["-DIMU_CHECK_NARROWING"]):
        exe = tmp_path / f"inside{len(checked)}"
        _check(_run([GCC, *STRICT, "-DIMU_FIXED", *checked, f"-I{CORE}", src, "-o", exe]), "inside")
        proc = _run([exe])
        assert proc.returncode == 0 and "REPORT" not in proc.stdout, proc.stdout
        outs.append(proc.stdout)
    assert outs[0] == outs[1]


@pytest.mark.skipif(GCC is None, reason="gcc not found")
def test_checked_build_computes_the_same_integers(tmp_path):
    """The check only observes: the golden-vector driver built with and without
    IMU_CHECK_NARROWING gives the same answer on every vector (both compare every output
    integer; the firmware build itself is checked against the vectors by test_c_build.py)."""
    vectors = sorted((ROOT / "shared" / "vectors").glob("*.vec"))
    assert vectors
    stub = tmp_path / "stub.c"
    stub.write_text('#include <stdio.h>\n#include <stdlib.h>\n#include <stdint.h>\n'
                    "void imu_narrowing_failed(const char *file, int line, const char *what, int64_t value);\n"
                    "void imu_narrowing_failed(const char *file, int line, const char *what, int64_t value)\n"
                    '{ fprintf(stderr, "NARROWING %s:%d %s %lld\\n", file, line, what, (long long)value); abort(); }\n')
    answers = []
    for checked in ([], ["-DIMU_CHECK_NARROWING"]):
        exe = tmp_path / f"vector_driver{len(checked)}"
        _check(_run([GCC, *STRICT, "-O1", "-DIMU_FIXED", *checked, f"-I{CORE}",
                     ROOT / "tests" / "c" / "vector_driver.c",
                     *([stub] if checked else []), *FILTER_SOURCES, "-o", exe]), f"vector driver {checked}")
        runs = [(v.name, _run([exe, v])) for v in vectors]
        answers.append([(name, proc.returncode, proc.stdout + proc.stderr) for name, proc in runs])
    assert "NARROWING" not in str(answers[1]), "a golden vector overflows int32 in the checked build"
    assert answers[0] == answers[1]
    assert sum(1 for _, rc, _ in answers[0] if rc == 0) >= 1


@pytest.mark.skipif(GCC is None, reason="gcc not found")
def test_checked_mode_is_ignored_by_the_float_build(tmp_path):
    for src in FILTER_SOURCES:
        _check(_run([GCC, *STRICT, "-DIMU_FLOAT", "-DIMU_CHECK_NARROWING", f"-I{CORE}", "-c", src,
                     "-o", tmp_path / (src.stem + ".o")]), src.name)


@pytest.mark.skipif(CLANG is None, reason="clang not found")
def test_clang_sanitizers_are_effective(tmp_path):
    """Control: the clang flags of the campaign do stop at a signed overflow and at an
    implicit truncation (so a clean clang campaign means something)."""
    src = tmp_path / "ub.c"
    src.write_text("#include <stdint.h>\n#include <stdio.h>\n"
                   "int main(int argc, char **argv)\n{\n    int32_t a = INT32_MAX - 2 + argc;\n"
                   "    int64_t w = (int64_t)a * 4;\n    int32_t t = argv[1][0] == 't' ? w : 0;\n"
                   "    int32_t s = argv[1][0] == 's' ? a + argc : 0;\n"
                   '    printf("%d %d\\n", t, s);\n    return 0;\n}\n')
    exe = tmp_path / "ub"
    _check(_run([CLANG, "-std=c99", "-fsanitize=undefined,integer", "-fno-sanitize-recover=all", src, "-o", exe]),
           "clang control")
    for arg, needle in (("t", "implicit conversion"), ("s", "signed integer overflow")):
        proc = _run([exe, arg], env=driver_env())
        assert proc.returncode != 0 and needle in proc.stderr, (arg, proc.stderr)


@pytest.fixture(scope="module")
def ranges(drivers, tmp_path_factory):
    if GCC is None:
        pytest.skip("gcc not found")
    driver = _driver(drivers, "gcc", tmp_path_factory)
    proc = subprocess.run([str(driver), "--ranges"], capture_output=True, text=True, env=driver_env(), timeout=120)
    rows = {}
    for line in proc.stdout.splitlines():
        if line.startswith("RANGE "):
            _, filt, name, q, lo, hi, unit = line.split(" ", 6)
            rows[(filt, name)] = (int(q), int(lo), int(hi), unit)
    return rows, proc


@pytest.mark.long
def test_settings_ranges_found_for_every_setting(ranges):
    """Every descriptor of every filter has a bisected [min, max] that contains its default,
    is an interval, and whose own set_settings computations never overflowed."""
    rows, proc = ranges
    problems = [ln for ln in proc.stdout.splitlines() if ln.startswith("OUTPUT ")]
    assert proc.returncode in (0, 1), proc.stderr
    assert {f for f, _ in rows} == set(FILTERS)
    for (filt, name), (_, lo, hi, _) in rows.items():
        assert lo <= hi, (filt, name)
    assert not problems, "\n".join(problems)


_DOC_RANGE = re.compile(
    r"imu_real_t\s+(\w+);\s*/\*\*<.*?,\s*Q(\d+),\s*([\[(])\s*([-+0-9.e]+),\s*([-+0-9.e]+)\s*([\])])")


def documented_ranges(header: Path) -> dict[str, tuple[int, float, float, bool, bool]]:
    """{field: (q, lo, hi, lo_closed, hi_closed)} from the settings struct's field comments."""
    out = {}
    for m in _DOC_RANGE.finditer(header.read_text()):
        out[m.group(1)] = (int(m.group(2)), float(m.group(4)), float(m.group(5)), m.group(3) == "[", m.group(6) == "]")
    return out


def range_mismatches(rows: dict) -> list[str]:
    """Documented ranges (header comments) against the ranges set_settings enforces and the
    values the Q format can hold: a documented value the check rejects, or an accepted value
    outside the documentation, is a mismatch (tolerance: one unit in the last place of Q)."""
    problems = []
    for filt in FILTERS:
        headers = SETTINGS_HEADERS.get(filt, (f"imu_{filt}.h",))
        header = " or ".join(headers)
        docs = {}
        for name in headers:
            docs.update(documented_ranges(CORE / name))
        for (f, name), (q, lo_raw, hi_raw, unit) in sorted(rows.items()):
            if f != filt:
                continue
            lo, hi = lo_raw / 2.0 ** q, hi_raw / 2.0 ** q
            ulp = 2.0 ** -q
            qmax = (2 ** 31 - 1) / 2.0 ** q
            if name not in docs:
                if name != "estimate_acc_bias":
                    problems.append(f"{filt}.{name}: no documented range in {header}")
                continue
            dq, dlo, dhi, lo_closed, hi_closed = docs[name]
            if dq != q:
                problems.append(f"{filt}.{name}: documented Q{dq}, descriptor Q{q}")
            if dhi > qmax + ulp:
                problems.append(f"{filt}.{name}: documented maximum {dhi:g} {unit} exceeds what Q{q} can hold "
                                f"({qmax:.9g})")
            documented = f"{'[' if lo_closed else '('}{dlo:g}, {dhi:g}{']' if hi_closed else ')'}"
            lo_ok = abs(lo - dlo) <= max(ulp, abs(dlo) * 1e-6) if lo_closed else dlo < lo <= dlo + 2 * ulp
            if hi_closed:
                hi_ok = abs(hi - dhi) <= max(ulp, abs(dhi) * 1e-6)
            else:  # just below the bound (or the largest value of the format)
                limit = min(dhi, qmax + ulp)
                hi_ok = limit - 2 * ulp <= hi < limit
            if not (lo_ok and hi_ok):
                problems.append(f"{filt}.{name}: documented {documented} {unit}, set_settings accepts "
                                f"[{lo:.9g}, {hi:.9g}]")
    return problems


@pytest.mark.long
def test_documented_ranges_match_the_checks(ranges):
    rows, _ = ranges
    problems = range_mismatches(rows)
    assert not problems, "settings ranges: documentation vs set_settings:\n" + "\n".join(problems)


@pytest.mark.long
def test_campaign_covers_every_setting_at_both_ends(drivers, tmp_path_factory):
    if GCC is None:
        pytest.skip("gcc not found")
    driver = _driver(drivers, "gcc", tmp_path_factory)
    names = [name for _, name, _ in case_indices(driver)]
    text = "\n".join(names)
    proc = subprocess.run([str(driver), "--ranges"], capture_output=True, text=True, env=driver_env(), timeout=120)
    settings = [line.split(" ")[1:3] for line in proc.stdout.splitlines() if line.startswith("RANGE ")]
    assert len(settings) >= 25
    for filt, name in settings:
        for end in ("min", "max"):
            assert f"{filt}/{name}={end}/" in text, f"{filt}.{name} at its {end} is not in the campaign"
    for filt in FILTERS:
        for variant in ("all=min", "all=max", "default"):
            for rate in ("30Hz", FAST_RATES.get(filt, "5kHz")):
                assert re.search(rf"^{filt}/{variant}/sensor=default/\w+/{rate}$", text, re.M), (filt, variant, rate)
        for scale in ("gyro_scale", "acc_scale", "mag_scale"):
            for end in ("min", "max"):
                assert f"{filt}/default/{scale}={end}/" in text
    for stream in ("still", "zeros", "int16_max", "int16_min", "int16_mixed", "alt_saturation", "alt_sat_still",
                   "random", "random_unclipped", "spin_z", "spin_x", "spin_xyz", "spin_noisy", "freefall",
                   "freefall_spin", "drop"):
        assert f"/{stream}/" in text


@pytest.mark.long
@pytest.mark.parametrize("filter_name", FILTERS)
@pytest.mark.parametrize("build", ["gcc", "clang"])
def test_campaign(build, filter_name, drivers, tmp_path_factory):
    driver = _driver(drivers, build, tmp_path_factory)
    result = run_campaign(driver, filter_name)
    assert result.cases == len(case_indices(driver, filter_name)), "not every case ran"
    print(f"\n{build} {filter_name}: {result.cases} cases, {result.samples} samples (clean cases), "
          f"{len(result.failures)} failures, {result.seconds:.1f} s")
    if result.failures:
        pytest.fail(format_failures(build, result.failures), pytrace=False)


# --------------------------------------------------------------------------- command line


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Build and run the adversarial campaign of the C core.")
    parser.add_argument("--build", choices=sorted(BUILDERS), default="gcc")
    parser.add_argument("--case", help="run this one case (a name from --list) and show its report")
    parser.add_argument("--filter", choices=FILTERS, help="only this filter's cases")
    parser.add_argument("--list", action="store_true", help="list the cases")
    parser.add_argument("--ranges", action="store_true", help="print the settings' ranges found by bisection")
    parser.add_argument("--shards", type=int, default=SHARDS)
    args = parser.parse_args(argv)
    if (GCC if args.build == "gcc" else CLANG) is None:
        print(f"{args.build} not found", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="imulink-campaign-") as tmp:
        driver = BUILDERS[args.build](Path(tmp))
        if args.ranges or args.list or args.case:
            cmd = [str(driver)]
            cmd += ["--ranges"] if args.ranges else ["--list"] if args.list else ["--case", args.case]
            if args.filter and not args.ranges:
                cmd += ["--filter", args.filter]
            proc = subprocess.run(cmd, env=driver_env())
            if args.ranges:
                rows = {}
                out = subprocess.run(cmd, capture_output=True, text=True, env=driver_env()).stdout
                for line in out.splitlines():
                    if line.startswith("RANGE "):
                        _, filt, name, q, lo, hi, unit = line.split(" ", 6)
                        rows[(filt, name)] = (int(q), int(lo), int(hi), unit)
                for problem in range_mismatches(rows):
                    print("MISMATCH", problem)
            return proc.returncode
        result = run_campaign(driver, args.filter, args.shards)
        print(f"{args.build}: {result.cases} cases, {result.samples} samples in clean cases, "
              f"{len(result.failures)} failing, {result.restarts} restarts, {result.seconds:.1f} s")
        if result.failures:
            print(format_failures(args.build, result.failures))
        return 1 if result.failures else 0


if __name__ == "__main__":
    sys.exit(main())
