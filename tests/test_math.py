"""The math helpers of firmware/core (imu_math.h) against independent numpy references.

Called through the cffi modules: imulink.core._fixed (Q formats of imu_arith.h:
angles Q29 rad, unit values Q30, rates Q24) and imulink.core._float (doubles).
"""
from __future__ import annotations

import numpy as np
import pytest

from imulink.core import _fixed as _core_fixed
from imulink.core import _float as _core_float

Q29 = 2.0**29
Q30 = 2.0**30
PI_Q29 = int(round(np.pi * Q29))  # IMU_PI_ANGLE
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


def wrapped(d):
    """Angle differences wrapped to [-pi, pi)."""
    return (np.asarray(d) + np.pi) % (2.0 * np.pi) - np.pi


# --------------------------------------------------------------------------- numpy references


def qmul(a, b):
    """Hamilton product of (..., 4) w-first quaternions."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def qexp(theta):
    """exp(theta/2): unit quaternion of the rotation vector theta (..., 3), exact."""
    theta = np.asarray(theta, dtype=np.float64)
    angle = np.linalg.norm(theta, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where(angle > 0, theta / angle, 0.0)
    return np.concatenate([np.cos(angle / 2), np.sin(angle / 2) * axis], axis=-1)


def axis_quat(axis, angle):
    q = np.zeros(np.shape(angle) + (4,))
    q[..., 0] = np.cos(np.asarray(angle) / 2)
    q[..., 1 + axis] = np.sin(np.asarray(angle) / 2)
    return q


def euler_to_quat_np(e):
    """imu_math.h convention: R = Rz(-heading) Rx(pitch) Ry(roll), e = [roll, pitch, heading]."""
    e = np.asarray(e)
    return qmul(qmul(axis_quat(2, -e[..., 2]), axis_quat(0, e[..., 1])), axis_quat(1, e[..., 0]))


def rotmat_np(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


# --------------------------------------------------------------------------- C wrappers


class Math:
    """Scalar wrappers of the C helpers for one build; values in SI (conversion at the boundary)."""

    def __init__(self, mod, fixed: bool):
        self.ffi, self.lib, self.fixed = mod.ffi, mod.lib, fixed
        t = "int32_t" if fixed else "double"
        self.q = self.ffi.new(f"{t}[4]")
        self.v = self.ffi.new(f"{t}[3]")
        self.s = self.ffi.new(f"{t} *")
        self.c = self.ffi.new(f"{t} *")

    def _to(self, x, scale):
        return int(round(x * scale)) if self.fixed else float(x)

    def _from(self, x, scale):
        return x / scale if self.fixed else x

    def euler_to_quat(self, e):
        for k in range(3):
            self.v[k] = self._to(e[k], Q29)
        self.lib.imu_euler_to_quat(self.v, self.q)
        return np.array([self._from(self.q[k], Q30) for k in range(4)])

    def quat_to_euler(self, q):
        for k in range(4):
            self.q[k] = self._to(q[k], Q30)
        self.lib.imu_quat_to_euler(self.q, self.v)
        return np.array([self._from(self.v[k], Q29) for k in range(3)])

    def quat_integrate(self, q, theta, function="imu_quat_integrate"):
        for k in range(4):
            self.q[k] = self._to(q[k], Q30)
        for k in range(3):
            self.v[k] = self._to(theta[k], Q30)
        getattr(self.lib, function)(self.q, self.v)
        return np.array([self._from(self.q[k], Q30) for k in range(4)])

    def quat_turn(self, q, theta):
        return self.quat_integrate(q, theta, "imu_quat_turn")

    def heading_from_mag_tilt(self, mag, roll, pitch):
        """mag in the caller's integers (fixed) or any scale (float); angles in rad."""
        for k in range(3):
            self.v[k] = int(mag[k]) if self.fixed else float(mag[k])
        sc = [self._to(f(a), Q30) for a in (roll, pitch) for f in (np.sin, np.cos)]
        return self._from(self.lib.imu_heading_from_mag_tilt(self.v, *sc), Q29)

    def deviation_weight(self, deviation, tolerance):
        """Both in Q24 units (m/s^2 for the filters)."""
        sat = self.ffi.new("uint32_t *")
        w = self.lib.imu_deviation_weight(self._to(deviation, 2.0**24), self._to(tolerance, 2.0**24), sat)
        return self._from(w, Q30), sat[0]


FIXED = Math(_core_fixed, True)
FLOAT = Math(_core_float, False)
BUILDS = {"fixed": FIXED, "float": FLOAT}


def fixed_atan2(pairs):
    f = _core_fixed.lib.imu_atan2
    return np.array([f(int(y), int(x)) for y, x in pairs], dtype=np.int64)


def fixed_sincos(angles):
    lib, ffi = _core_fixed.lib, _core_fixed.ffi
    s, c = ffi.new("int32_t *"), ffi.new("int32_t *")
    out = np.empty((len(angles), 2), dtype=np.int64)
    for i, a in enumerate(angles):
        lib.imu_sincos(int(a), s, c)
        out[i] = s[0], c[0]
    return out


# --------------------------------------------------------------------------- square root


def test_hypot_fixed_is_the_floor_of_the_exact_root():
    """imu_hypot is floor(sqrt(a^2 + b^2)) exactly (its integer square root, isqrt64, is
    normalised and Newton-stepped: its last checks must make it exact), over the whole
    int32 range, near perfect squares and at small values."""
    import math
    import random
    rng = random.Random(11)
    pairs = [(rng.randint(INT32_MIN, INT32_MAX) >> rng.randrange(32), rng.randint(INT32_MIN, INT32_MAX)
              >> rng.randrange(32)) for _ in range(40000)]
    for _ in range(5000):  # Pythagorean triples scaled and moved by one: the root's floor changes there
        m, n = rng.randint(2, 30000), rng.randint(1, 30000)
        a, b = abs(m * m - n * n), 2 * m * n
        if max(a, b) <= INT32_MAX:
            pairs += [(a, b), (a - 1, b), (a, b - 1), (a + 1, b)]
    pairs += [(a, b) for a in (INT32_MIN, INT32_MAX, -1, 0, 1) for b in (INT32_MIN, INT32_MAX, -1, 0, 1, 2, 3)]
    pairs += [(a, b) for a in range(-20, 21) for b in range(0, 21)]
    f = _core_fixed.lib.imu_hypot
    wrong = [(a, b) for a, b in pairs if f(a, b) != min(math.isqrt(a * a + b * b), INT32_MAX)]
    assert not wrong, f"{len(wrong)} wrong, first {wrong[0]}"


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_vec3_normalize_unit_vector_and_length_alone(build):
    """imu_vec3_normalize gives v / |v| (Q30, within a few LSB) and |v| in v's format (within
    one unit in the fixed build, which rounds it from the scaled vector's root and saturates it
    to int32); without a unit vector (NULL) the same length and return value; the zero vector
    returns 0."""
    import random
    m = BUILDS[build]
    ffi, lib = m.ffi, m.lib
    t = "int32_t" if m.fixed else "double"
    v, unit, norm, alone = ffi.new(f"{t}[3]"), ffi.new(f"{t}[3]"), ffi.new(f"{t} *"), ffi.new(f"{t} *")
    rng = random.Random(13)
    cases = [[rng.randint(INT32_MIN, INT32_MAX) >> rng.randrange(32) for _ in range(3)] for _ in range(20000)]
    cases += [[INT32_MIN] * 3, [INT32_MAX, 0, 0], [0, 0, 1], [1, 1, 0], [-3, 4, 12], [0, 0, 0]]
    for x in cases:
        for k in range(3):
            v[k] = x[k]
        got = lib.imu_vec3_normalize(v, unit, norm)
        assert lib.imu_vec3_normalize(v, ffi.NULL, alone) == got
        if not any(x):
            assert got == 0
            continue
        assert got == 1 and alone[0] == norm[0], x
        length = float(np.linalg.norm(np.array(x, dtype=np.float64)))
        if m.fixed:
            assert abs(norm[0] - min(length, INT32_MAX)) <= 1.0, x  # saturated to int32
        else:
            assert norm[0] == pytest.approx(length, rel=1e-15), x
        direction = np.array(x, dtype=np.float64) / length
        got_unit = np.array([unit[k] for k in range(3)]) / (Q30 if m.fixed else 1.0)
        assert np.abs(got_unit - direction).max() < (5e-9 if m.fixed else 1e-15), x


# --------------------------------------------------------------------------- atan2


def atan2_inputs():
    rng = np.random.default_rng(20240601)
    pairs = []
    # Random magnitudes from 1 to 2^31 in both arguments (independent shifts).
    raw = rng.integers(INT32_MIN, INT32_MAX, size=(30000, 2), endpoint=True)
    shifts = rng.integers(0, 32, size=(30000, 2))
    pairs += [(int(y) >> int(sy), int(x) >> int(sx)) for (y, x), (sy, sx) in zip(raw, shifts)]
    mags = [1, 2, 3, 7, 1000, 2**20, 2**29, 2**30, 2**30 + 1, INT32_MAX - 1, INT32_MAX]
    for m in mags:
        for sy, sx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
            pairs.append((sy * m, sx * m))
        # Just beside the axes and the diagonals; both sides of the branch cut at -x.
        pairs += [(1, m), (-1, m), (1, -m), (-1, -m), (m, 1), (m, -1), (-m, 1), (-m, -1)]
        pairs += [(m, m - 1), (m - 1, m), (-m, m - 1), (m - 1, -m), (-(m - 1), -m)]
    for y in (INT32_MIN, INT32_MIN + 1, -1, 0, 1, INT32_MAX):
        for x in (INT32_MIN, INT32_MIN + 1, -1, 0, 1, INT32_MAX):
            pairs.append((y, x))
    pairs += [(y, x) for y in range(-4, 5) for x in range(-4, 5)]  # tiny magnitudes
    return np.array(pairs, dtype=np.int64)


ATAN2_INPUTS = atan2_inputs()
ATAN2_OUT = fixed_atan2(ATAN2_INPUTS)


def test_vec3_norm_fixed_is_the_rounded_exact_root():
    """imu_vec3_norm is sqrt(x^2 + y^2 + z^2) rounded to nearest, exactly, over the int32 range
    (saturated to INT32_MAX beyond it); a floor would bias every magnitude low."""
    import math
    import random
    lib, ffi = _core_fixed.lib, _core_fixed.ffi
    v = ffi.new("int32_t[3]")
    rng = random.Random(12)
    cases = [[rng.randint(INT32_MIN, INT32_MAX) >> rng.randrange(32) for _ in range(3)] for _ in range(30000)]
    cases += [[INT32_MIN] * 3, [INT32_MAX, 0, 0], [0, 0, 0], [1, 1, 0], [0, 2, 1], [3, 4, 0], [-3, 4, 12]]
    for x in cases:
        for k in range(3):
            v[k] = x[k]
        total = sum(c * c for c in x)
        root = math.isqrt(total)
        want = root + (1 if total - root * root > root else 0)  # exact: sqrt(total) >= root + 1/2
        assert lib.imu_vec3_norm(v) == min(want, INT32_MAX), x
    assert _core_float.lib.imu_vec3_norm(_core_float.ffi.new("double[3]", [3.0, -4.0, 12.0])) == 13.0


def test_atan2_fixed_accuracy():
    y, x = ATAN2_INPUTS[:, 0].astype(np.float64), ATAN2_INPUTS[:, 1].astype(np.float64)
    err = np.abs(wrapped(ATAN2_OUT / Q29 - np.arctan2(y, x)))
    worst = int(np.argmax(err))
    assert err[worst] < 1e-8, f"atan2({ATAN2_INPUTS[worst, 0]}, {ATAN2_INPUTS[worst, 1]}): error {err[worst]:.3g}"


def test_atan2_fixed_range_and_origin():
    assert np.all(ATAN2_OUT > -PI_Q29) and np.all(ATAN2_OUT <= PI_Q29), "result outside (-pi, pi]"
    assert _core_fixed.lib.imu_atan2(0, 0) == 0
    assert _core_float.lib.imu_atan2(0.0, 0.0) == 0.0
    # Exact axes: +-pi/2 and 0 to the LSB of Q29.
    assert _core_fixed.lib.imu_atan2(5, 0) == int(round(np.pi / 2 * Q29))
    assert _core_fixed.lib.imu_atan2(-5, 0) == -int(round(np.pi / 2 * Q29))
    assert _core_fixed.lib.imu_atan2(0, 5) == 0


def test_atan2_negative_x_axis_is_plus_pi():
    for x in (-1, -1000, INT32_MIN):
        assert _core_fixed.lib.imu_atan2(0, x) > 0
    assert _core_float.lib.imu_atan2(0.0, -1.0) == pytest.approx(np.pi, abs=0)


def test_atan2_float_twin_matches_numpy():
    rng = np.random.default_rng(5)
    pts = rng.standard_normal((2000, 2)) * 10.0 ** rng.uniform(-6, 6, size=(2000, 1))
    got = np.array([_core_float.lib.imu_atan2(y, x) for y, x in pts])
    np.testing.assert_allclose(got, np.arctan2(pts[:, 0], pts[:, 1]), rtol=0, atol=1e-15)


# --------------------------------------------------------------------------- sincos


def sincos_inputs():
    rng = np.random.default_rng(77)
    special = [0, 1, -1, INT32_MIN, INT32_MAX, PI_Q29, -PI_Q29, PI_Q29 + 1, -PI_Q29 - 1, PI_Q29 - 1]
    for frac in (0.25, 0.5, 0.75, 1.0, 1.25):
        a = int(round(frac * np.pi * Q29))
        special += [a - 1, a, a + 1, -a - 1, -a, -a + 1]
    return np.concatenate([rng.integers(INT32_MIN, INT32_MAX, size=60000, endpoint=True),
                           np.array(special, dtype=np.int64)])


SINCOS_IN = sincos_inputs()
SINCOS_OUT = fixed_sincos(SINCOS_IN)
SINCOS_ERR = np.maximum(np.abs(SINCOS_OUT[:, 0] / Q30 - np.sin(SINCOS_IN / Q29)),
                        np.abs(SINCOS_OUT[:, 1] / Q30 - np.cos(SINCOS_IN / Q29)))


def _worst_sincos() -> str:
    i = int(np.argmax(SINCOS_ERR))
    return f"angle {SINCOS_IN[i]} (Q29, {SINCOS_IN[i] / Q29:.6f} rad): error {SINCOS_ERR[i]:.3g}"


def test_math_tables_are_generated():
    """imu_math_tables.h is what tools/gen_math_tables.py writes (its formulas are the reference)."""
    import subprocess
    import sys
    from pathlib import Path
    tool = Path(__file__).resolve().parents[1] / "tools" / "gen_math_tables.py"
    proc = subprocess.run([sys.executable, str(tool), "--check"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_sincos_fixed_accuracy():
    """Table and Taylor series with a Q62 sum: within 1 LSB of Q30."""
    assert SINCOS_ERR.max() < 2e-9, _worst_sincos()
    assert np.median(SINCOS_ERR) < 1e-9


def test_sincos_fixed_exact_points():
    """sin/cos of 0 and +-pi/2 to one LSB, and any angle of the type is accepted (wrapped)."""
    s, c = fixed_sincos([0])[0]
    assert abs(s) <= 1 and abs(c - 2**30) <= 1
    s, c = fixed_sincos([int(round(np.pi / 2 * Q29))])[0]
    assert abs(s - 2**30) <= 1 and abs(c) <= 2
    s, c = fixed_sincos([-int(round(np.pi / 2 * Q29))])[0]
    assert abs(s + 2**30) <= 1 and abs(c) <= 2
    # Angles beyond +-pi (up to the +-4 rad of the type) equal their wrapped values.
    big = np.array([INT32_MAX, INT32_MIN, int(3.5 * Q29), -int(3.5 * Q29)])
    wrapped_q29 = np.rint(wrapped(big / Q29) * Q29).astype(np.int64)
    assert np.all(np.abs(fixed_sincos(big) - fixed_sincos(wrapped_q29)) <= 2)


# --------------------------------------------------------------------------- Euler <-> quaternion


def random_euler(n, seed, max_pitch=1.5):
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-np.pi, np.pi, n), rng.uniform(-max_pitch, max_pitch, n),
                     rng.uniform(-np.pi, np.pi, n)], axis=1)


TOL = {"fixed": {"quat": 1e-8, "euler": 2e-8}, "float": {"quat": 1e-14, "euler": 1e-12}}


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_euler_to_quat_matches_convention(build):
    m = BUILDS[build]
    for e in random_euler(3000, 1):
        if build == "fixed":
            e = np.rint(e * Q29) / Q29  # exactly representable input
        q = m.euler_to_quat(e)
        ref = euler_to_quat_np(e)
        err = min(np.abs(q - ref).max(), np.abs(q + ref).max())
        assert err < TOL[build]["quat"], f"euler {e}: quaternion error {err:.3g}"


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_quat_to_euler_inverts_convention(build):
    """Quaternions built in numpy give back their Euler angles; the error grows as 1/cos(pitch)
    for roll and heading near the gimbal lock, hence the scaling."""
    m = BUILDS[build]
    for e in random_euler(3000, 2):
        got = m.quat_to_euler(euler_to_quat_np(e))
        err = np.abs(wrapped(got - e))
        assert err[1] < TOL[build]["euler"], f"euler {e}: pitch error {err[1]:.3g}"
        assert max(err[0], err[2]) * np.cos(e[1]) < TOL[build]["euler"], f"euler {e}: error {err}"


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_quat_to_euler_axes_give_the_angles_sines_and_cosines(build):
    """imu_quat_to_euler_axes: imu_quat_to_euler's angles, and axes from which the sines and
    cosines of roll r and pitch p are read: up = (-sin r cos p, sin p, cos r cos p), y[2] = sin p,
    cos_pitch = cos p, each within a few Q30 LSB of the sine and cosine of the angles themselves."""
    m = BUILDS[build]
    ffi, lib = m.ffi, m.lib
    t = "int32_t" if m.fixed else "double"
    q, euler, axes = ffi.new(f"{t}[4]"), ffi.new(f"{t}[3]"), ffi.new("imu_euler_axes_t *")
    scale_q = Q30 if m.fixed else 1.0
    for e in random_euler(3000, 4):
        quat = euler_to_quat_np(e)
        for k in range(4):
            q[k] = int(round(quat[k] * Q30)) if m.fixed else float(quat[k])
        lib.imu_quat_to_euler_axes(q, euler, axes)
        angles = np.array([euler[k] / (Q29 if m.fixed else 1.0) for k in range(3)])
        np.testing.assert_array_equal(angles, m.quat_to_euler(np.array([q[k] / scale_q for k in range(4)])))
        r, p = angles[0], angles[1]
        up = np.array([axes.up[k] for k in range(3)]) / scale_q
        want = [-np.sin(r) * np.cos(p), np.sin(p), np.cos(r) * np.cos(p), np.sin(p), np.cos(p)]
        got = [*up, axes.y[2] / scale_q, axes.cos_pitch / scale_q]
        assert np.abs(np.array(got) - want).max() < (1e-8 if m.fixed else 1e-14), f"euler {e}"


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_euler_quat_round_trip(build):
    m = BUILDS[build]
    for e in random_euler(3000, 3, max_pitch=1.2):
        if build == "fixed":
            e = np.rint(e * Q29) / Q29
        back = m.quat_to_euler(m.euler_to_quat(e))
        err = np.abs(wrapped(back - e))
        assert err.max() < 2 * TOL[build]["euler"], f"euler {e}: round-trip error {err}"


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_euler_meaning(build):
    """The documented meaning, checked on the rotation matrix of the C quaternion:
    heading = compass heading of the y axis, pitch lifts y, positive roll lowers the right side (x)."""
    m = BUILDS[build]
    d = np.deg2rad
    r = rotmat_np(m.euler_to_quat([0.0, 0.0, d(90.0)]))
    np.testing.assert_allclose(r[:, 1], [1.0, 0.0, 0.0], atol=1e-8)  # y axis points east
    r = rotmat_np(m.euler_to_quat([0.0, d(30.0), 0.0]))
    np.testing.assert_allclose(r[:, 1], [0.0, np.cos(d(30.0)), np.sin(d(30.0))], atol=1e-8)
    r = rotmat_np(m.euler_to_quat([d(30.0), 0.0, 0.0]))
    np.testing.assert_allclose(r[:, 0], [np.cos(d(30.0)), 0.0, -np.sin(d(30.0))], atol=1e-8)
    np.testing.assert_allclose(r[:, 1], [0.0, 1.0, 0.0], atol=1e-8)


# --------------------------------------------------------------------------- quaternion integration


def random_steps(n, seed, lo, hi):
    rng = np.random.default_rng(seed)
    q = rng.standard_normal((n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    direction = rng.standard_normal((n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    size = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
    return q, direction * size[:, None]


def exact_integrate(q, theta):
    out = qmul(q, qexp(theta))
    return out / np.linalg.norm(out)


def test_quat_integrate_fixed_filter_steps():
    """Steps of a filter (|theta| <= 0.1 rad: 570 deg/s at 100 Hz) match the exact exponential
    to a few Q30 LSB."""
    q, theta = random_steps(4000, 10, 1e-8, 0.1)
    worst = 0.0
    for qi, ti in zip(q, theta):
        qi = np.rint(qi * Q30) / Q30
        ti = np.rint(ti * Q30) / Q30
        got = FIXED.quat_integrate(qi, ti)
        err = np.abs(got - exact_integrate(qi, ti)).max()
        worst = max(worst, err)
        assert abs(np.linalg.norm(got) - 1.0) < 3e-9
    assert worst < 3e-9, f"worst error {worst:.3g}"


def test_quat_integrate_fixed_zero_step_keeps_attitude():
    q, _ = random_steps(200, 11, 1e-3, 1e-2)
    for qi in q:
        qi = np.rint(qi * Q30) / Q30
        assert np.abs(FIXED.quat_integrate(qi, np.zeros(3)) - qi / np.linalg.norm(qi)).max() < 2e-9


def test_quat_integrate_fixed_large_steps_within_series_truncation():
    """Up to |theta| = 1 rad the error stays within the x^4 Taylor series' truncation (x = |theta|/2):
    below x^6/720 (the cos term) plus rounding."""
    q, theta = random_steps(3000, 12, 0.1, 1.0)
    for qi, ti in zip(q, theta):
        qi = np.rint(qi * Q30) / Q30
        ti = np.rint(ti * Q30) / Q30
        x = np.linalg.norm(ti) / 2
        err = np.abs(FIXED.quat_integrate(qi, ti) - exact_integrate(qi, ti)).max()
        assert err < 3e-9 + x**6 / 720, f"|theta| {2 * x:.3f}: error {err:.3g}"


def test_quat_integrate_float_is_exact():
    q, theta = random_steps(2000, 13, 1e-12, 1.0)
    for qi, ti in zip(q, theta):
        np.testing.assert_allclose(FLOAT.quat_integrate(qi, ti), exact_integrate(qi, ti), rtol=0, atol=1e-14)


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_quat_integrate_limits_steps_beyond_one_radian(build):
    """A step longer than 1 rad (sample rate far too low for the motion) turns by 1 rad about
    the same axis, in both builds; no overflow for any Q30 input."""
    impl = FIXED if build == "fixed" else FLOAT
    q, theta = random_steps(500, 14, 1.0001, 1.99)
    tol = 3e-9 + 0.5**6 / 720 if build == "fixed" else 1e-14
    for qi, ti in zip(q, theta):
        qi = np.rint(qi * Q30) / Q30
        ti = np.rint(ti * Q30) / Q30
        unit_step = ti / np.linalg.norm(ti)
        err = np.abs(impl.quat_integrate(qi, ti) - exact_integrate(qi, unit_step)).max()
        assert err < tol
    extreme = np.array([INT32_MIN, INT32_MIN, INT32_MIN]) / Q30
    out = impl.quat_integrate(np.array([1.0, 0, 0, 0]), extreme)
    assert abs(np.linalg.norm(out) - 1.0) < 3e-9


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_quat_from_rotation_is_the_integration_of_the_identity(build):
    """imu_quat_from_rotation (exp(theta / 2) without the product by the identity) gives the
    integers imu_quat_integrate gives from (1, 0, 0, 0): steps of a filter, steps up to and
    beyond the 1 rad limit, the zero step and the most negative one."""
    impl = BUILDS[build]
    identity = np.array([1.0, 0.0, 0.0, 0.0])
    _, small = random_steps(1500, 17, 1e-9, 0.1)
    _, large = random_steps(1500, 18, 0.1, 1.99)
    steps = np.vstack([small, large, np.zeros((1, 3)), np.array([[INT32_MIN, INT32_MIN, INT32_MIN]]) / Q30])
    for ti in steps:
        ti = np.rint(ti * Q30) / Q30
        np.testing.assert_array_equal(impl.quat_integrate(identity, ti, "imu_quat_from_rotation"),
                                      impl.quat_integrate(identity, ti))


# --------------------------------------------------------------------------- small turns


def test_quat_turn_below_the_bound_is_the_second_order_exponential():
    """imu_quat_turn below |theta| = 1/64 rad: the rotation of q (x) (1 - |theta|^2/8, theta/2),
    long by at most |theta|^3/24 against the exact exponential, and a norm within the Q30
    rounding of 1 (|theta|^4/128 < 2^-31 at the bound); both builds, a few LSB apart."""
    q, theta = random_steps(3000, 15, 1e-9, 1 / 64 * 0.999)
    for qi, ti in zip(q, theta):
        qi = np.rint(qi * Q30) / Q30
        ti = np.rint(ti * Q30) / Q30
        qi /= np.linalg.norm(qi)
        exact = exact_integrate(qi, ti)
        size = np.linalg.norm(ti)
        for impl, rounding in ((FIXED, 3e-9), (FLOAT, 1e-15)):
            got = impl.quat_turn(qi, ti)
            assert abs(np.linalg.norm(got) - 1.0) < rounding + size**4 / 128
            # the angle between the two attitudes: 2 |vector part of exact^-1 (x) got|
            gap = 2 * np.linalg.norm(qmul(exact * [1, -1, -1, -1], got)[1:])
            assert gap < rounding * 2 + size**3 / 24 * 1.01, f"|theta| {size:.3g}: gap {gap:.3g}"
        assert np.abs(FIXED.quat_turn(qi, ti) - FLOAT.quat_turn(qi, ti)).max() < 3e-9


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_quat_turn_above_the_bound_is_the_integration(build):
    """From |theta| = 1/64 rad on, imu_quat_turn is imu_quat_integrate: the same numbers."""
    impl = BUILDS[build]
    q, theta = random_steps(500, 16, 1 / 64 * 1.001, 1.5)
    for qi, ti in zip(q, theta):
        qi = np.rint(qi * Q30) / Q30
        ti = np.rint(ti * Q30) / Q30
        np.testing.assert_array_equal(impl.quat_turn(qi, ti), impl.quat_integrate(qi, ti))


# --------------------------------------------------------------------------- matrix, heading, weight


def test_quat_y_axis_is_column_one_of_the_rows():
    """imu_quat_y_axis gives the same integers as element 1 of imu_quat_matrix_row's rows."""
    lib, ffi = _core_fixed.lib, _core_fixed.ffi
    q, _ = random_steps(1000, 17, 1e-3, 1e-2)
    qq, out, row = ffi.new("int32_t[4]"), ffi.new("int32_t[3]"), ffi.new("int32_t[3]")
    for qi in q:
        for k in range(4):
            qq[k] = int(np.rint(qi[k] * Q30))
        lib.imu_quat_y_axis(qq, out)
        for r in range(3):
            lib.imu_quat_matrix_row(qq, r, row)
            assert out[r] == row[1]


def test_rotation_applies_the_quaternion_rows_with_one_rounding_each():
    """imu_quat_rotation holds imu_quat_matrix_row's rows; imu_rotation_apply gives R v, each
    product rounded once (within 1.5 LSB of the exact product of those rows), in either Q
    format the ESKF uses (Q30 unit vectors, Q16 specific forces)."""
    lib, ffi = _core_fixed.lib, _core_fixed.ffi
    rng = np.random.default_rng(5)
    q, _ = random_steps(300, 23, 1e-3, 1e-2)
    qq, row, rot = ffi.new("int32_t[4]"), ffi.new("int32_t[3]"), ffi.new("imu_rotation_t *")
    v, out = ffi.new("int32_t[3]"), ffi.new("int32_t[3]")
    for qi in q:
        for k in range(4):
            qq[k] = int(np.rint(qi[k] * Q30))
        lib.imu_quat_rotation(qq, rot)
        rows = np.array([[rot.row[r][k] for k in range(3)] for r in range(3)], dtype=np.int64)
        for r in range(3):
            lib.imu_quat_matrix_row(qq, r, row)
            assert list(rows[r]) == [row[0], row[1], row[2]]
        for scale in (Q30, 2.0**16 * 100.0):
            vec = rng.normal(size=3)
            vec *= scale / np.linalg.norm(vec)
            for k in range(3):
                v[k] = int(np.rint(vec[k]))
            lib.imu_rotation_apply(rot, v, out)
            exact = rows.astype(object) @ np.array([v[0], v[1], v[2]], dtype=object)
            for r in range(3):
                assert abs(out[r] - exact[r] / 2**30) <= 1.5


def reference_heading(mag, roll, pitch):
    """atan2(-h_x, h_y) of h = Rx(pitch) Ry(roll) m (imu_math.h's convention)."""
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    m = np.asarray(mag, dtype=np.float64)
    hx = cr * m[0] + sr * m[2]
    w = cr * m[2] - sr * m[0]
    hy = cp * m[1] - sp * w
    return np.arctan2(-hx, hy)


def test_heading_from_mag_tilt_at_any_field_scale():
    """The heading does not depend on the field's scale: from a few LSB to the int32 limits
    (INT32_MIN included), the fixed build is within its roundings of the exact heading of its
    integers: atan2's 2e-9 rad plus a few LSB of the field scaled to 30 bits (largest
    component at least 2^29: 4e-9 of |m|) over the horizontal part; the float build within
    1e-12 of the exact heading."""
    rng = np.random.default_rng(18)
    worst = 0.0  # error over its bound
    for _ in range(3000):
        bits = rng.integers(4, 32)
        mag = np.clip(np.rint(rng.standard_normal(3) * 2.0**bits / 2), INT32_MIN, INT32_MAX).astype(np.int64)
        if not mag.any():
            continue
        roll, pitch = rng.uniform(-np.pi, np.pi), rng.uniform(-1.5, 1.5)
        sc = [np.rint(f(a) * Q30) / Q30 for a in (roll, pitch) for f in (np.sin, np.cos)]
        exact = np.arctan2(-(sc[1] * mag[0] + sc[0] * mag[2]),
                           sc[3] * mag[1] - sc[2] * (sc[1] * mag[2] - sc[0] * mag[0]))
        horizontal = np.hypot(sc[1] * mag[0] + sc[0] * mag[2],
                              sc[3] * mag[1] - sc[2] * (sc[1] * mag[2] - sc[0] * mag[0]))
        if horizontal < np.linalg.norm(mag) / 16:  # nearly vertical field: the heading is ill-conditioned
            continue
        err = abs(wrapped(FIXED.heading_from_mag_tilt(mag, roll, pitch) - exact))
        worst = max(worst, err / (2e-9 + 4e-9 * np.linalg.norm(mag) / horizontal))
        assert abs(wrapped(FLOAT.heading_from_mag_tilt(mag, roll, pitch) - reference_heading(mag, roll, pitch))) < 1e-12
    assert worst < 1.0, worst
    for extreme in ([INT32_MIN, INT32_MIN, INT32_MIN], [INT32_MAX, INT32_MIN, 0], [0, 1, 0], [0, 0, 0]):
        got = FIXED.heading_from_mag_tilt(extreme, 0.3, -0.2)
        want = reference_heading(extreme, 0.3, -0.2) if any(extreme) else 0.0
        assert abs(wrapped(got - want)) < 1e-8, (extreme, got, want)


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_deviation_weight_is_the_formula(build):
    """imu_deviation_weight = 1 / (1 + (d/t)^2)^2 below 16 tolerances (within 2^-28 in the fixed
    build), 0 from there on; symmetric in d; no saturation counted for any legal tolerance."""
    impl = BUILDS[build]
    rng = np.random.default_rng(19)
    for _ in range(3000):
        tol = float(np.exp(rng.uniform(np.log(2.0**-20), np.log(1.9))))
        dev = float(rng.uniform(-20, 20) * tol)
        if build == "fixed":
            tol, dev = max(round(tol * 2**24), 1) / 2**24, round(dev * 2**24) / 2**24
        got, sat = impl.deviation_weight(dev, tol)
        want = 0.0 if abs(dev) >= 16 * tol else 1.0 / (1.0 + (dev / tol) ** 2) ** 2
        assert abs(got - want) < (2.0**-28 if build == "fixed" else 1e-15), (dev, tol, got, want)
        assert sat == 0
        assert impl.deviation_weight(-dev, tol)[0] == got


@pytest.mark.parametrize("build", ["fixed", "float"])
def test_a_new_field_must_outlast_the_trust_of_the_old(build):
    """imu_field_trust_t, the ESKF's and the nav filter's one rule: a candidate replaces the
    reference once it has held for at least the minimum and for longer than the reference
    was trusted; trust stops at the limit; a candidate given up starts again from zero."""
    lib, ffi = BUILDS[build].lib, BUILDS[build].ffi
    t = ffi.new("imu_field_trust_t *")
    lib.imu_field_trust_reset(t)

    def hold(steps):
        return [lib.imu_field_trust_hold(t, 1, 20) for _ in range(steps)]

    assert hold(20)[-1] == 1 and t.trusted == 20 and t.held == 0  # no trust yet: the minimum
    for _ in range(50):
        lib.imu_field_trust_confirm(t, 1, 60)
    assert t.trusted == 60  # 20 + 50 stops at the limit
    lib.imu_field_trust_confirm(t, 0, 60)  # a step that does not count (the ESKF: not turning)
    assert t.trusted == 60
    assert not any(hold(60)) and t.held == 60  # as long as the trust: not yet
    assert lib.imu_field_trust_hold(t, 0, 20) == 0  # a step that does not count
    assert lib.imu_field_trust_hold(t, 1, 20) == 1 and t.trusted == 61  # longer: taken, its trust its hold
    hold(30)
    lib.imu_field_trust_drop(t)  # the candidate went: its count restarts
    assert t.held == 0 and t.trusted == 61
    hold(5)
    lib.imu_field_trust_confirm(t, 1, 60)  # the reference held again: the candidate is given up
    assert t.held == 0 and t.trusted == 61  # above the limit already: no more counted
