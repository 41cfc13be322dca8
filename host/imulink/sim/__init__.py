"""Simulated GY-86 data: truth trajectories and sensor error models.

Conventions: quaternions w-first, sensor(body)-to-earth, earth frame ENU; gyro rad/s,
accelerometer specific force m/s^2, magnetometer uT, all in the body frame.

Typical use::

    from imulink import sim
    res = sim.make_scenario("rests", duration_s=600, rate_hz=100, seed=1)
    res.gyr_counts, res.acc_counts, res.mag_counts   # int16 inputs of the firmware core
    res.quat_true                                     # truth attitude
"""
from __future__ import annotations

import numbers

from imulink.sim import quat
from imulink.sim.sensors import AccModel, GyroModel, MagModel, SensorSuite, SimResult, simulate
from imulink.sim.trajectories import (
    DEFAULT_INITIAL,
    MAX_SAMPLES,
    TRANSLATIONS,
    ScenarioError,
    Trajectory,
    integrate_gyro,
    motion_with_rests,
    random_motion,
    static,
    turntable,
)

__all__ = [
    "quat",
    "Trajectory",
    "DEFAULT_INITIAL",
    "MAX_SAMPLES",
    "ScenarioError",
    "integrate_gyro",
    "static",
    "turntable",
    "random_motion",
    "motion_with_rests",
    "TRANSLATIONS",
    "GyroModel",
    "AccModel",
    "MagModel",
    "SensorSuite",
    "SimResult",
    "simulate",
    "SCENARIOS",
    "make_scenario",
]

#: Names accepted by :func:`make_scenario`.
SCENARIOS = ("static", "turntable", "random", "rests")


def make_scenario(name: str, duration_s: float, rate_hz: float, seed: int = 0) -> SimResult:
    """Simulate a standard scenario with the default sensors (:meth:`SensorSuite.default`).

    Args:
        name: "static" (no motion), "turntable" (10 s rest, then 10 deg/s about the
            vertical), "random" (:func:`random_motion`) or "rests"
            (:func:`motion_with_rests`).
        duration_s: length in s.
        rate_hz: sample rate in Hz.
        seed: seed of the trajectory (where random) and of the sensor noise, an integer
            from 0.

    Raises ScenarioError for an unknown name, a negative seed, and a duration and rate
    that are not finite or make fewer than 2 or more than MAX_SAMPLES samples.
    """
    if not isinstance(seed, numbers.Integral) or seed < 0:
        raise ScenarioError(f"the seed must be an integer from 0, not {seed!r}")
    if name == "static":
        traj = static(duration_s, rate_hz)
    elif name == "turntable":
        traj = turntable(duration_s, rate_hz)
    elif name == "random":
        traj = random_motion(duration_s, rate_hz, seed=seed)
    elif name == "rests":
        traj = motion_with_rests(duration_s, rate_hz, seed=seed)
    else:
        raise ScenarioError(f"unknown scenario {name!r}; expected one of {SCENARIOS}")
    return simulate(traj, SensorSuite.default(), seed=seed)
