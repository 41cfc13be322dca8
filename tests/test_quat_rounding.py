"""Open-loop quaternion integration in the fixed build has no drift of its own.

imu_quat_integrate (firmware/core/imu_math.c) once formed the half-angle step
sin(x)/x * theta / 2 in Q30 with ties rounded toward +inf: every step whose rotation
vector had an odd component (always so for the small steps of a board at rest or
turning slowly, where sin(x)/x is exactly 1) turned the attitude by +2^-31 rad of half
angle on that axis, whichever way the board turned: 9.3e-10 rad per step and axis
(0.11 deg/h open loop at 1 kHz). A rotation followed by its opposite did not come back.

Here the C function is called directly through the cffi modules (as in test_math.py),
with Q30 inputs: quaternions and rotation vectors in rad.
"""
from __future__ import annotations

import numpy as np
import pytest

from imulink.core import _fixed as _core_fixed
from imulink.core import _float as _core_float

Q30 = 2.0**30
#: The old drift per step and axis, rad (one Q31 LSB of half angle, doubled).
OLD_DRIFT = 2.0**-30
#: What the tests allow per step: a twentieth of the old drift. Rounding of the Q30
#: state then adds up as a random walk (about 1e-12 rad per step over these runs).
LIMIT = OLD_DRIFT / 20

#: A general attitude: no component a power of two, so its products carry random low
#: bits (near the identity a Q30 state cannot hold half-LSB turns at all).
GENERAL = np.array([0.8, 0.2, -0.4, 0.4]) / np.linalg.norm([0.8, 0.2, -0.4, 0.4])


def integrate_fixed(q0, steps_lsb) -> np.ndarray:
    """q0 (4,) real; steps (N,3) integer Q30 rotation vectors; returns the final q (real)."""
    ffi, lib = _core_fixed.ffi, _core_fixed.lib
    q = ffi.new("int32_t[4]", [int(round(x * Q30)) for x in q0])
    theta = ffi.new("int32_t[3]")
    for step in np.asarray(steps_lsb, dtype=np.int64):
        theta[0], theta[1], theta[2] = int(step[0]), int(step[1]), int(step[2])
        lib.imu_quat_integrate(q, theta)
    return np.array([q[k] for k in range(4)]) / Q30


def integrate_float(q0, steps_lsb) -> np.ndarray:
    ffi, lib = _core_float.ffi, _core_float.lib
    q = ffi.new("double[4]", [float(round(x * Q30)) / Q30 for x in q0])
    theta = ffi.new("double[3]")
    for step in np.asarray(steps_lsb, dtype=np.float64) / Q30:
        theta[0], theta[1], theta[2] = step
        lib.imu_quat_integrate(q, theta)
    return np.array([q[k] for k in range(4)])


def body_rotation(q_from, q_to) -> np.ndarray:
    """Rotation vector (rad, body frame) from q_from to q_to (small angles)."""
    w1, v1 = q_from[0], -np.asarray(q_from[1:])
    w2, v2 = q_to[0], np.asarray(q_to[1:])
    w = w1 * w2 - v1 @ v2
    v = w1 * v2 + w2 * v1 + np.cross(v1, v2)
    return 2.0 * v * np.sign(w)


def start(q0) -> np.ndarray:
    return np.rint(np.asarray(q0) * Q30) / Q30


@pytest.mark.parametrize("q0", [np.array([1.0, 0.0, 0.0, 0.0]), GENERAL], ids=["identity", "general"])
def test_alternating_odd_steps_do_not_drift(q0):
    """+1 LSB and -1 LSB on every axis in turn: the old rounding turned both the same way."""
    n = 20000
    steps = np.tile([[1, 1, 1], [-1, -1, -1]], (n // 2, 1))
    drift = body_rotation(start(q0), integrate_fixed(q0, steps)) / n
    assert np.abs(drift).max() < LIMIT, f"drift per step {drift} rad"


@pytest.mark.parametrize("scale", [1000, 40000, 2_000_000])
def test_a_rotation_and_its_opposite_come_back(scale):
    """Random steps (up to `scale` LSB per axis: 1e-6 to 2e-3 rad), then the same steps
    negated in reverse order: the exact result is the starting attitude."""
    rng = np.random.default_rng(scale)
    there = rng.integers(-scale, scale + 1, size=(10000, 3))
    steps = np.concatenate([there, -there[::-1]])
    drift = body_rotation(start(GENERAL), integrate_fixed(GENERAL, steps)) / len(steps)
    assert np.abs(drift).max() < LIMIT, f"drift per step {drift} rad"


def test_zero_mean_random_steps_follow_the_float_twin():
    """Zero-mean random steps of a board at rest (gyro noise of 0.5 deg/s at 100 Hz, about
    9e-5 rad, plus a slow turn): the fixed build stays with the exact float integration."""
    rng = np.random.default_rng(8)
    n = 20000
    steps = np.rint(rng.normal(0.0, 9e-5 * Q30, size=(n, 3)) + 3e-6 * Q30).astype(np.int64)
    fixed = integrate_fixed(GENERAL, steps)
    exact = integrate_float(GENERAL, steps)
    drift = body_rotation(exact, fixed) / n
    assert np.abs(drift).max() < LIMIT, f"drift per step {drift} rad"
