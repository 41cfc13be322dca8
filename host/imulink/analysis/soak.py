"""Long-run stress of a filter on simulated data, hour by hour.

Each simulated hour is motion with rests plus the hard cases: taps that saturate
the accelerometer, free fall (specific force near zero), spins beyond the gyro's
range, and a magnetic disturbance. The attitude carries over from hour to hour;
the sensor errors are drawn anew each hour (a fresh bias: a step for the filter).
After every hour the full covariance is read back and checked (symmetric,
positive definite), and the run's saturation counter and attitude errors are kept.
Used by tools/soak_eskf.py (24 h) and by the test suite (minutes).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imulink import core, sim
from imulink.analysis.attitude import angle_difference

RATE_HZ = 100.0


@dataclass
class SegmentReport:
    index: int
    samples: int
    saturations: int           # the filter's saturation counter at the end of the segment
    sensor_clipped: int        # sensor values clipped by the simulated registers
    min_eigenvalue: float      # smallest eigenvalue of P in the normalised state units
    max_asymmetry: float       # max |P_ij - P_ji|
    diag_min: np.ndarray       # smallest P_ii seen at the periodic dumps, state units
    diag_max: np.ndarray
    max_error_deg: float       # largest attitude error outside the disturbed windows
    rms_error_deg: float


def hour_scenario(index: int, duration_s: float, initial, rate_hz: float = RATE_HZ):
    """One segment: motion with rests, taps, free fall, a fast spin and a magnet."""
    rng = np.random.default_rng(1000 + index)
    traj = sim.motion_with_rests(duration_s, rate_hz, seed=index, initial=initial)
    span = duration_s
    # A spin beyond the +-2000 deg/s range for 0.3 s (the gyro saturates).
    k0 = int(rng.uniform(0.3, 0.4) * span * rate_hz)
    k1 = k0 + int(0.3 * rate_hz)
    traj.gyr[k0:k1] += np.array([0.0, 0.0, np.deg2rad(2500.0)])
    traj.quat[:] = sim.integrate_gyro(traj.quat[0], traj.gyr, 1.0 / rate_hz)
    traj.rest[k0:k1] = False
    free_fall = [(rng.uniform(0.5, 0.6) * span, rng.uniform(0.5, 0.6) * span + 0.5)]
    taps = [(rng.uniform(0.1, 0.9) * span, 120.0) for _ in range(max(1, int(span / 60)))]
    magnet_start = rng.uniform(0.7, 0.8) * span
    magnet = (magnet_start, magnet_start + min(30.0, 0.1 * span), np.array([20.0, -15.0, 10.0]))
    suite = sim.SensorSuite.default()
    suite.mag.disturbances = [magnet]
    data = sim.simulate(traj, suite, seed=index, free_fall=free_fall, acc_spikes=taps)
    disturbed = np.zeros(len(data.t), bool)
    for start, end in [(magnet[0], magnet[1] + 20.0), (free_fall[0][0], free_fall[0][1] + 5.0),
                       (k0 / rate_hz, k1 / rate_hz + 20.0)]:
        disturbed |= (data.t >= start) & (data.t < end)
    return data, disturbed


def run(filter_name: str = "eskf", hours: float = 24.0, segment_s: float = 3600.0, arithmetic: str = "fixed",
        dumps_per_segment: int = 12, progress=None) -> list[SegmentReport]:
    """Run `hours` of simulated data through one filter instance, segment by segment."""
    filt = core.Filter(filter_name, RATE_HZ, arithmetic)
    reports = []
    initial = None
    segments = int(np.ceil(hours * 3600.0 / segment_s))
    for index in range(segments):
        duration = min(segment_s, hours * 3600.0 - index * segment_s)
        data, disturbed = hour_scenario(index, duration, initial)
        initial = data.quat_true[-1]
        chunk = max(1, len(data.t) // dumps_per_segment)
        quats, eigs, asym, diags = [], [], [], []
        for start in range(0, len(data.t), chunk):
            sl = slice(start, start + chunk)
            out = filt.run_counts(data.gyr_counts[sl], data.acc_counts[sl], data.mag_counts[sl])
            quats.append(out.quat)
            if filter_name == "eskf":
                cov = filt.covariance()
                scale = np.sqrt(np.diag(cov))
                eigs.append(np.linalg.eigvalsh(cov / np.outer(scale, scale)).min())
                asym.append(np.abs(cov - cov.T).max())
                diags.append(np.diag(cov))
        err = angle_difference(np.concatenate(quats), data.quat_true)
        calm = err[~disturbed]
        diag_rows = np.array(diags) if diags else np.zeros((1, 1))
        reports.append(SegmentReport(
            index=index, samples=len(data.t), saturations=out.saturations,
            sensor_clipped=int(sum(data.saturated.values())),
            min_eigenvalue=float(min(eigs)) if eigs else float("nan"),
            max_asymmetry=float(max(asym)) if asym else float("nan"),
            diag_min=diag_rows.min(axis=0), diag_max=diag_rows.max(axis=0),
            max_error_deg=float(calm.max()), rms_error_deg=float(np.sqrt(np.mean(calm**2)))))
        if progress:
            progress(reports[-1])
    return reports
