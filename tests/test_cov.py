"""The block-floating covariance (firmware/core/imu_cov.c) against numpy: the scalar
update, optimal and with a gain map (Schmidt / "consider" update in Joseph's form), and the
time update with a transition that moves a few rows, in both builds (tests/c/cov_driver.c);
and its 16-state instance for the navigation filter (imu_navcov.c)."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

GCC = shutil.which("gcc")
pytestmark = pytest.mark.skipif(GCC is None, reason="gcc not found")

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "firmware" / "core"
DRIVER = ROOT / "tests" / "c" / "cov_driver.c"


@pytest.fixture(scope="module")
def drivers(tmp_path_factory):
    """The drivers of imu_cov.c ("fixed", "float") and of imu_navcov.c ("nav fixed", "nav float")."""
    out = {}
    for build in ("FIXED", "FLOAT"):
        for name, source, flags in (("", "imu_cov.c", []), ("nav ", "imu_navcov.c", ["-DNAVCOV"])):
            exe = tmp_path_factory.mktemp("cov") / f"cov_{name.strip()}{build.lower()}"
            proc = subprocess.run([GCC, "-std=c99", "-Wall", "-Wextra", "-Werror", f"-DIMU_{build}", *flags,
                                   f"-I{CORE}", "-fsanitize=undefined,address", "-fno-sanitize-recover=all", "-o",
                                   str(exe), str(DRIVER), str(CORE / source), "-lm"], capture_output=True, text=True)
            assert proc.returncode == 0, proc.stderr
            out[name + build.lower()] = exe
    return out


NONE, ALL, ALONG = 0, 1, 2  # imu_cov_block_t


def gain_matrix(n, gain_map):
    """The n x n matrix G of a gain map (blocks, unit vector) as imu_cov_map_t describes it."""
    blocks, v = gain_map
    g = np.zeros((n, n))
    for b, kind in enumerate(blocks):
        part = {NONE: np.zeros((3, 3)), ALL: np.eye(3), ALONG: np.outer(v, v)}[kind]
        size = min(3, n - 3 * b)
        g[3 * b:3 * b + size, 3 * b:3 * b + size] = part[:size, :size]
    return g


class Predict(NamedTuple):
    """A time update: Phi is the identity but for rows[t] at row moving[t]; process noise
    diag(qvar) plus a 3 x 3 block of states 0-2 (zero: none)."""
    moving: list
    rows: np.ndarray
    qvar: list
    block: np.ndarray = np.zeros((3, 3))


def process_noise(step: Predict) -> np.ndarray:
    """The n x n Q of a time update."""
    q = np.diag(np.asarray(step.qvar, dtype=float))
    q[:3, :3] += step.block
    return q


def run_driver(exe, variances, updates):
    """updates: (h, r, z, w, gain map (blocks, unit vector) or None) or Predict; returns
    [(dx, P)] after each."""
    n = len(variances)
    words = [str(n), *(repr(float(v)) for v in variances)]
    for step in updates:
        if isinstance(step, Predict):
            words += ["p", str(len(step.moving)), *(str(i) for i in step.moving)]
            words += [repr(float(v)) for v in (*np.ravel(step.rows), *step.qvar, *step.block[np.triu_indices(3)])]
            continue
        h, r, z, w, g = step
        words += ["u"] + [repr(float(v)) for v in (*h, r, z, w)] + ["0" if g is None else "1"]
        if g is not None:
            words += [str(kind) for kind in g[0]] + [repr(float(v)) for v in g[1]]
    proc = subprocess.run([str(exe)], input=" ".join(words), capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.split("\n")
    results = []
    for dx_line, p_line in zip(lines[0::2], lines[1::2]):
        if not dx_line.startswith("dx"):
            break
        dx = np.array(dx_line.split()[1:], dtype=float)
        p = np.array(p_line.split()[1:], dtype=float).reshape(n, n)
        results.append((dx, p))
    assert lines[-2].startswith("saturations 0"), "no saturation in a well-scaled case"
    return results


def assert_covariance_close(p, p_ref, atol, build):
    """P against the reference in units of the reference's standard deviations (variances
    over eight decades compare on one scale)."""
    scale = np.sqrt(np.outer(np.diag(p_ref), np.diag(p_ref)))
    np.testing.assert_allclose(p / scale, p_ref / scale, rtol=0, atol=atol, err_msg=build)


def reference(p0, updates):
    """numpy: K = P h / (h P h + r / w); the correction G K z and P in Joseph's form for G K."""
    p = np.diag(p0).astype(float)
    out = []
    for step in updates:
        if isinstance(step, Predict):
            phi = np.eye(len(p0))
            phi[step.moving] = step.rows
            p = phi @ p @ phi.T + process_noise(step)
            out.append((np.zeros(len(p0)), p))
            continue
        h, r, z, w, g = step
        h = np.asarray(h, dtype=float)
        s = h @ p @ h + r / w
        k = p @ h / s
        gk = k if g is None else gain_matrix(len(p0), g) @ k
        a = np.eye(len(p0)) - np.outer(gk, h)
        p = a @ p @ a.T + np.outer(gk, gk) * (r / w)
        out.append((gk * z, p))
    return out


def _case(seed):
    """Six states with variances over eight decades (attitude-like and bias-like), two
    optimal updates that correlate them, then one whose gain map keeps only the part of
    the first and second blocks along a unit vector (as the ESKF's heading update)."""
    rng = np.random.default_rng(seed)
    p0 = [1e-2, 2e-2, 5e-3, 1e-6, 3e-7, 2e-6]
    up = rng.standard_normal(3)
    up /= np.linalg.norm(up)
    g = ((ALONG, ALONG), up)
    updates = [
        (rng.uniform(-1, 1, 6) * [1, 1, 1, 0, 0, 0] + [0, 0, 0, 1, 0, 0], 1e-4, 0.01, 1.0, None),
        (rng.uniform(-1, 1, 6), 4e-4, -0.02, 0.75, None),
        (np.r_[rng.uniform(-1, 1, 3) * 0.6, 0, 0, 0], 1e-4, 0.015, 1.0, g),
        (rng.uniform(-1, 1, 6) * 0.5, 1e-4, 0.005, 0.5, g),
    ]
    return p0, updates


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_gain_mapped_update_is_josephs_form(drivers, seed):
    p0, updates = _case(seed)
    expected = reference(p0, updates)
    for build, rtol in (("float", 1e-12), ("fixed", 2e-6)):
        got = run_driver(drivers[build], p0, updates)
        assert len(got) == len(updates)
        for (dx, p), (dx_ref, p_ref) in zip(got, expected):
            assert_covariance_close(p, p_ref, rtol * 10, build)
            np.testing.assert_allclose(dx, dx_ref, rtol=rtol * 10, atol=1e-9 if build == "fixed" else 1e-15,
                                       err_msg=build)


def test_gain_map_keeps_the_uncertainty_of_what_it_does_not_correct(drivers):
    """A map that corrects only state 0 leaves every other variance and covariance as it
    was (Schmidt), while the optimal update would have shrunk them."""
    p0 = [1e-2, 1e-2, 1e-4]
    g = ((ALONG,), (1.0, 0.0, 0.0))  # G = diag(1, 0, 0)
    h = [1.0, 1.0, 0.5]
    (dx_opt, p_opt), = run_driver(drivers["fixed"], p0, [(h, 1e-3, 0.01, 1.0, None)])
    (dx_map, p_map), = run_driver(drivers["fixed"], p0, [(h, 1e-3, 0.01, 1.0, g)])
    assert p_opt[1, 1] < 0.6 * p0[1] and p_opt[2, 2] < p0[2]
    np.testing.assert_allclose(np.diag(p_map)[1:], p0[1:], rtol=1e-7)
    assert abs(p_map[1, 2]) < 1e-12
    assert dx_map[1] == 0 and dx_map[2] == 0 and dx_map[0] == pytest.approx(dx_opt[0], rel=1e-6)
    assert p_map[0, 0] < p0[0]


def test_every_kind_of_block_in_one_map_is_josephs_form(drivers):
    """Nine states: a map that corrects the first block in full, the second not at all and
    the third along a unit vector (the ESKF's at-rest and heading maps together)."""
    rng = np.random.default_rng(11)
    p0 = [1e-2, 2e-2, 5e-3, 1e-6, 3e-7, 2e-6, 1e-3, 4e-4, 2e-3]
    v = rng.standard_normal(3)
    v /= np.linalg.norm(v)
    updates = [(rng.uniform(-1, 1, 9), 2e-4, 0.01, 1.0, None),
               (rng.uniform(-1, 1, 9) * 0.7, 1e-4, -0.02, 0.8, ((ALL, NONE, ALONG), v)),
               (rng.uniform(-1, 1, 9) * 0.5, 3e-4, 0.005, 1.0, ((NONE, ALL, ALONG), v))]
    expected = reference(p0, updates)
    for build, rtol in (("float", 1e-12), ("fixed", 2e-6)):
        for (dx, p), (dx_ref, p_ref) in zip(run_driver(drivers[build], p0, updates), expected):
            assert_covariance_close(p, p_ref, rtol * 10, build)
            np.testing.assert_allclose(dx, dx_ref, rtol=rtol * 10, atol=1e-9 if build == "fixed" else 1e-15,
                                       err_msg=build)


def _rotation(rng, angle):
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def assert_time_updates_match(drivers, p0, steps, expected):
    """Both builds' P after every step against the reference (in the reference's standard
    deviations: 2e-5 fixed, 1e-11 float), and exactly symmetric."""
    for build, tol in (("float", 1e-12), ("fixed", 2e-6)):
        got = run_driver(drivers[build], p0, steps)
        assert len(got) == len(steps)
        for (dx, p), (dx_ref, p_ref) in zip(got, expected):
            assert_covariance_close(p, p_ref, tol * 10, build)
            np.testing.assert_array_equal(p, p.T)


@pytest.mark.parametrize("seed", [4, 5])
def test_time_update_moves_only_the_given_rows(drivers, seed):
    """Nine states over eight decades. The ESKF's transition (attitude rows: a rotation and
    -T I on the gyro bias), an update that correlates everything, then a transition with a
    dense row and a row given that is the identity's after all (the prediction takes it as
    one), with process noise on every state."""
    rng = np.random.default_rng(seed)
    p0 = [1e-2, 2e-2, 5e-3, 1e-6, 3e-7, 2e-6, 1e-3, 4e-4, 2e-3]
    attitude = np.zeros((3, 9))
    attitude[:, 0:3] = _rotation(rng, 0.3).T
    attitude[:, 3:6] = -0.03 * np.eye(3)
    dense = np.zeros((2, 9))
    dense[0] = rng.uniform(-0.5, 0.5, 9)
    dense[0, 1] = 1.0
    dense[1, 4] = 1.0
    steps = [Predict([0, 1, 2], attitude, [1e-6] * 3 + [1e-10] * 3 + [1e-8] * 3),
             (rng.uniform(-1, 1, 9), 2e-4, 0.01, 1.0, None),
             Predict([1, 4], dense, list(rng.uniform(1e-9, 1e-6, 9)))]
    expected = reference(p0, steps)
    assert_time_updates_match(drivers, p0, steps, expected)


@pytest.mark.parametrize("seed", [8, 9])
def test_time_update_with_a_full_attitude_block_of_process_noise(drivers, seed):
    """The ESKF's tilt-only scale noise: a block of states 0-2 of the form
    (I - v v^T) D (I - v v^T), rank two, with covariances of its own, added to a rotation of
    correlated attitude errors; the same steps without it differ."""
    rng = np.random.default_rng(seed)
    p0 = [1e-2, 2e-2, 5e-3, 1e-6, 3e-7, 2e-6]
    attitude = np.zeros((3, 6))
    attitude[:, 0:3] = _rotation(rng, 0.3).T
    attitude[:, 3:6] = -0.03 * np.eye(3)
    up = rng.standard_normal(3)
    up /= np.linalg.norm(up)
    tilt = (np.eye(3) - np.outer(up, up)) * rng.uniform(1e-4, 3e-3, 3)
    qvar = [1e-8] * 3 + [1e-10] * 3
    steps = [(rng.uniform(-1, 1, 6), 2e-4, 0.01, 1.0, None),
             Predict([0, 1, 2], attitude, qvar, tilt @ tilt.T),
             (rng.uniform(-1, 1, 6) * [1, 1, 1, 0, 0, 0], 1e-6, 0.002, 1.0, None),
             Predict([0, 1, 2], attitude, qvar, tilt @ tilt.T)]
    expected = reference(p0, steps)
    without = reference(p0, [s._replace(block=np.zeros((3, 3))) if isinstance(s, Predict) else s for s in steps])
    assert np.max(np.abs(expected[-1][1] - without[-1][1])) > 1e-7  # the block matters here
    assert_time_updates_match(drivers, p0, steps, expected)


@pytest.mark.parametrize("seed", [6, 7])
def test_navigation_instance_with_sixteen_states(drivers, seed):
    """The 16-state instance (imu_navcov.c) over eleven decades, as the navigation filter uses
    it: its transition applied as three factors of three moving rows each (position from
    velocity, attitude and accelerometer bias; velocity from attitude and that bias; attitude
    from itself and the gyro bias), then position and velocity updates, a barometer's (the
    height and the barometer's bias) and one that correlates everything; the result is
    Phi P Phi^T + Q and the Kalman update."""
    rng = np.random.default_rng(seed)
    p0 = [4e-5, 4e-5, 1e-4, 2e-4, 2e-4, 3e-4, 1e-3, 1e-3, 3e-2, 1e-6, 1e-6, 2e-6, 1e-2, 1e-2, 2e-2, 4e-4]
    position = np.zeros((3, 16))
    position[:, 0:3] = np.eye(3)
    position[:, 3:6] = 0.05 * np.eye(3)
    position[:, 6:9] = rng.uniform(-1e-3, 1e-3, (3, 3))
    position[:, 12:15] = rng.uniform(-1e-4, 1e-4, (3, 3))
    velocity = np.zeros((3, 16))
    velocity[:, 3:6] = np.eye(3)
    velocity[:, 6:9] = rng.uniform(-0.01, 0.01, (3, 3))
    velocity[:, 12:15] = 0.003 * _rotation(rng, 1.0)
    attitude = np.zeros((3, 16))
    attitude[:, 6:9] = _rotation(rng, 0.05).T
    attitude[:, 9:12] = -0.05 * np.eye(3)
    qvar = [0.0] * 3 + [1e-9] * 3 + [1e-9] * 3 + [1e-12] * 3 + [1e-10] * 3 + [1e-9]
    unit = np.eye(16)
    steps = [Predict([0, 1, 2], position, [0.0] * 16), Predict([3, 4, 5], velocity, [0.0] * 16),
             Predict([6, 7, 8], attitude, qvar),
             *[(unit[k], 2e-6, 1e-3 * (k + 1), 1.0, None) for k in range(6)],
             (unit[2] + unit[15], 1e-6, 2e-3, 1.0, None),
             (rng.uniform(-1, 1, 16), 2e-4, 0.01, 1.0, None),
             Predict([0, 1, 2], position, [0.0] * 16), Predict([3, 4, 5], velocity, [0.0] * 16),
             Predict([6, 7, 8], attitude, qvar)]
    expected = reference(p0, steps)
    for build, tol in (("nav float", 1e-12), ("nav fixed", 2e-6)):
        got = run_driver(drivers[build], p0, steps)
        assert len(got) == len(steps)
        for (dx, p), (dx_ref, p_ref) in zip(got, expected):
            assert_covariance_close(p, p_ref, tol * 10, build)
            np.testing.assert_allclose(dx, dx_ref, rtol=1e-4 if build == "nav fixed" else 1e-9, atol=tol)
            np.testing.assert_array_equal(p, p.T)


def test_32_bit_shifts_give_the_64_bit_shifts_integers(tmp_path):
    """The covariance's 32-bit shortcuts (real_ldexp for an int32 times 2^n, shifted_int32
    for a wide value narrowed by a right shift) against the 64-bit rounding shift they stand
    for, over random values, each range's extremes and rounding ties (tests/c/cov_shift_driver.c):
    the same integers and the same saturation counts. The golden vectors check them only
    where the filters' data take them."""
    exe = tmp_path / "cov_shift"
    subprocess.run([GCC, "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", "-DIMU_FIXED", f"-I{CORE}",
                    str(ROOT / "tests" / "c" / "cov_shift_driver.c"), "-o", str(exe)], check=True)
    proc = subprocess.run([str(exe)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout
    cases, differences = (int(word) for word in proc.stdout.split()[::2][:2])
    assert cases > 7_000_000 and differences == 0, proc.stdout
