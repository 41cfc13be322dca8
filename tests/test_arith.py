"""The integer divisions and saturating sums of the arithmetic layer (firmware/core/imu_arith.h).

IMU_DIV_SAT divides 64 by 32 bits with imu_udiv64_32 (long division in base 2^16 on
32-bit hardware divisions) instead of a 64-bit division: its results and saturation
counts must be those of the exact quotients, truncated, for every input. IMU_ADD_SAT and
IMU_SUB_SAT add in 32 bits and test the overflow: theirs must be those of the exact sums,
saturated.
tests/c/arith_driver.c, built with UBSan and ASan, computes them; Python's integers are
the reference.
"""
from __future__ import annotations

import os
import random
import shutil
import subprocess
from pathlib import Path

import pytest

GCC = shutil.which("gcc")
pytestmark = pytest.mark.skipif(GCC is None, reason="gcc not found")

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "firmware" / "core"
DRIVER = ROOT / "tests" / "c" / "arith_driver.c"
INT32_MIN, INT32_MAX = -2**31, 2**31 - 1


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    out = tmp_path_factory.mktemp("arith") / "arith_driver"
    proc = subprocess.run([GCC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-DIMU_FIXED",
                           "-fsanitize=undefined,address", "-fno-sanitize-recover=all", "-g", f"-I{CORE}",
                           str(DRIVER), "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return out


def run(driver: Path, lines: list[str]) -> list[tuple[int, int]]:
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=0", UBSAN_OPTIONS="print_stacktrace=1")
    proc = subprocess.run([str(driver)], input="\n".join(lines) + "\n", capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0 and "runtime error" not in proc.stderr, proc.stderr
    return [tuple(map(int, line.split())) for line in proc.stdout.splitlines()]


def sat32(v: int) -> tuple[int, int]:
    return (INT32_MAX, 1) if v > INT32_MAX else (INT32_MIN, 1) if v < INT32_MIN else (v, 0)


def trunc_div(num: int, den: int) -> int:
    q = abs(num) // abs(den)
    return -q if (num < 0) != (den < 0) else q


def some_int32(rng: random.Random) -> int:
    """Any int32, with small magnitudes, powers of two and the ends as likely as the rest."""
    kind = rng.randrange(4)
    if kind == 0:
        return rng.randint(INT32_MIN, INT32_MAX)
    if kind == 1:
        return rng.randint(INT32_MIN, INT32_MAX) >> rng.randrange(32)
    if kind == 2:
        return rng.choice([1, -1]) * (2**rng.randrange(31) + rng.randint(-2, 2))
    return rng.choice([INT32_MIN, INT32_MIN + 1, -1, 0, 1, INT32_MAX - 1, INT32_MAX])


def test_div_sat_is_the_truncated_quotient(driver):
    rng = random.Random(1)
    cases = []
    while len(cases) < 60000:
        a, b, s = some_int32(rng), some_int32(rng), rng.randrange(32)
        if b != 0:
            cases.append((a, b, s))
    got = run(driver, [f"d {a} {b} {s}" for a, b, s in cases])
    expected = [sat32(trunc_div(a * 2**s, b)) for a, b, s in cases]
    wrong = [(c, g, e) for c, g, e in zip(cases, got, expected) if g != e]
    assert not wrong, f"{len(wrong)} wrong, first (a, b, s), got, expected: {wrong[0]}"
    assert 0 < sum(e[1] for e in expected) < len(cases), "the cases must include saturating and exact quotients"


def test_udiv64_32_is_exact(driver):
    rng = random.Random(3)
    cases = []
    for _ in range(60000):
        v = rng.choice([rng.randint(1, 2**32 - 1), rng.randint(1, 2**32 - 1) >> rng.randrange(32) or 1,
                        2**rng.randrange(32), 2**32 - 1, 2**31, 2**31 + 1])
        hi = rng.choice([rng.randrange(v), v - 1, 0, rng.randrange(v) >> rng.randrange(32)])
        lo = rng.choice([rng.randrange(2**32), 0, 2**32 - 1])
        cases.append((hi, lo, v))
    got = run(driver, [f"u {hi} {lo} {v}" for hi, lo, v in cases])
    expected = [((hi * 2**32 + lo) // v, 0) for hi, lo, v in cases]
    wrong = [(c, g, e) for c, g, e in zip(cases, got, expected) if g != e]
    assert not wrong, f"{len(wrong)} wrong, first (hi, lo, v), got, expected: {wrong[0]}"


def test_add_and_sub_sat_are_the_exact_results_saturated(driver):
    rng = random.Random(4)
    cases = [(rng.choice("+-"), some_int32(rng), some_int32(rng)) for _ in range(60000)]
    ends = (INT32_MIN, -1, 0, 1, INT32_MAX)
    cases += [(op, a, b) for op in "+-" for a in ends for b in ends]
    got = run(driver, [f"{op} {a} {b}" for op, a, b in cases])
    expected = [sat32(a + b if op == "+" else a - b) for op, a, b in cases]
    wrong = [(c, g, e) for c, g, e in zip(cases, got, expected) if g != e]
    assert not wrong, f"{len(wrong)} wrong, first (op, a, b), got, expected: {wrong[0]}"
    clamped = [e for e in expected if e[1]]
    assert {v for v, _ in clamped} == {INT32_MIN, INT32_MAX}, "the cases must saturate both ways"
