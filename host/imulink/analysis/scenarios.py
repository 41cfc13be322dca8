"""Simulation experiments shared by the tests and tools/eval_sim.py.

Each function simulates one of the source documents' experiments (docs/filters.md,
Bibliography) and returns plain numbers, so that a test can assert them and a tool can
tabulate them.
The filter settings passed here describe the simulated sensors ([seed 000]'s
gyroscope noise, the HMC5883L data sheet's magnetometer noise), as a user would
set them from an Allan-variance analysis; the defaults in the C core are tuned on
real recordings instead (docs/accuracy.md).
"""
from __future__ import annotations

import numpy as np

from imulink import core, sim
from imulink.analysis.attitude import quat_to_euler, wrap_deg
from imulink.sim.sensors import GyroModel

RATE_HZ = 100.0

#: Settings matching the simulator's default sensors (SensorSuite.default()).
SIM_SETTINGS = {
    "eskf": {
        "gyro_arw": float(np.mean(GyroModel.seed000().arw)),
        "gyro_rrw": float(np.mean(GyroModel.seed000().rrw)),
        "acc_noise": 0.02,
        "mag_noise": 0.2,
        "acc_lowpass": 0.0,
    },
    "eecf": {"kp": 1.0, "kp_mag": 1.0, "ki": 0.02},
    "kf1d": {},
}


def euler_errors_deg(estimate_quat, true_quat) -> np.ndarray:
    """(N,3) [roll, pitch, heading] errors in degrees, wrapped to (-180, 180]."""
    return wrap_deg(np.degrees(quat_to_euler(estimate_quat)) - np.degrees(quat_to_euler(true_quat)))


def static_errors(filter_name: str, seed: int, duration_s: float = 120.0, settle_s: float = 10.0,
                  arithmetic: str = "fixed") -> np.ndarray:
    """Euler errors (deg) of a static run after `settle_s` ([seed 000] / [seed 004]'s static experiment)."""
    data = sim.make_scenario("static", duration_s, RATE_HZ, seed=seed)
    out = core.run(filter_name, data.gyr, data.acc, data.mag, RATE_HZ, arithmetic,
                   settings=SIM_SETTINGS[filter_name])
    return euler_errors_deg(out.quat, data.quat_true)[int(settle_s * RATE_HZ):]


def turntable_heading_errors(filter_name: str, seed: int, rate_dps: float = 10.0, duration_s: float = 120.0,
                             settle_s: float = 20.0) -> np.ndarray:
    """Heading errors (deg) while a turntable turns at `rate_dps` ([seed 000]'s 10 deg/s test)."""
    traj = sim.turntable(duration_s, RATE_HZ, rate_dps=rate_dps, settle_s=10.0)
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=seed)
    out = core.run(filter_name, data.gyr, data.acc, data.mag, RATE_HZ, "fixed", settings=SIM_SETTINGS[filter_name])
    return euler_errors_deg(out.quat, data.quat_true)[int(settle_s * RATE_HZ):, 2]


def bias_convergence_time(filter_name: str, seed: int, bias_dps=(0.5, -0.4, 0.3), tolerance_dps: float = 0.05,
                          duration_s: float = 300.0) -> float:
    """Seconds until every axis of the gyro bias estimate stays within `tolerance_dps` of the
    truth (static board with a known turn-on bias; inf if it never does)."""
    traj = sim.static(duration_s, RATE_HZ)
    suite = sim.SensorSuite.default()
    suite.gyro = GyroModel.seed000(bias_dps=bias_dps)
    data = sim.simulate(traj, suite, seed=seed)
    out = core.run(filter_name, data.gyr, data.acc, data.mag, RATE_HZ, "fixed", settings=SIM_SETTINGS[filter_name])
    err = np.degrees(np.abs(out.gyro_bias - data.gyro_bias_true)).max(axis=1)
    outside = np.nonzero(err > tolerance_dps)[0]
    if len(outside) == 0:
        return 0.0
    if outside[-1] == len(err) - 1:
        return float("inf")
    return float(data.t[outside[-1] + 1])
