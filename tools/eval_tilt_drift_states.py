#!/usr/bin/env python3
"""A float prototype of the ESKF's tilt loop, with and without states for the low-pass's drift.

The ESKF measures gravity through the specific force low-passed in its estimated earth frame
(time constant 3 s), turned with each attitude correction. Against the present tilt, that
low-passed force errs by the gyroscope's drift over the low-pass's window: every past sample
was projected with the attitude of its time, and the drift since then moved the estimate but
not the sample. That error D is correlated with the attitude's own process noise; counted as
white measurement noise (the ESKF's ``acc_noise``) it keeps the Kalman gain small, and the
tilt loop is the low-pass followed by a slow gain (tools/eval_tilt_sources.py: the gap to VQF
is the gyroscope's noise).

This prototype models D (three more states, in the error state's sensor frame):

    theta' = Phi theta - T dbias + w
    D'     = (1 - alpha) (Phi D - T dbias + w)      (the same w)
    z      = theta - D + the low-passed translation  (the gravity rows' H: [h, 0, -h])

and turns the low-pass by the attitude correction minus D's, which leaves D's estimate at zero.
It is the tilt loop alone: gyroscope and accelerometer, no field, no rest updates, no
down-weighting, a plain dense covariance. The variant without D states is the ESKF's former
loop (its inclination matched the ESKF's within 0.03 deg on these cases); the 6-state ESKF
has since taken the states, as the low-pass's error L = theta - D (docs/filters.md). The
design study behind them, not a filter of the product.

    .venv/bin/python tools/eval_tilt_drift_states.py --markdown [--broad ../shared/data/broad]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import eval_tilt_sources  # noqa: E402  (the cases, one error source at a time)
from imulink.analysis import rough  # noqa: E402
from imulink.sim import quat as Q  # noqa: E402

GRAVITY = 9.80665
#: name -> (drift states, the gravity rows' noise in m/s^2)
VARIANTS = {
    "no drift states (the ESKF's loop), 0.3": (False, 0.3),
    "drift states, 0.07": (True, 0.07),
    "drift states, 0.1": (True, 0.1),
    "drift states, 0.15": (True, 0.15),
    "drift states, 0.2": (True, 0.2),
}
CONDITIONS = ("all", "no translation", "only arw", "only rrw")


def run(gyr, acc, rate_hz: float, drift_states: bool, noise: float, tau: float = 3.0, arw: float = 8.7e-4,
        rrw: float = 1e-5, init_attitude: float = 0.1, init_bias: float = 0.01) -> np.ndarray:
    """(N,4) attitude of the prototype on SI readings; the ESKF's default noise settings."""
    dt = 1.0 / rate_hz
    period = 3 * dt
    alpha = period / (tau + period)
    n = 9 if drift_states else 6
    cov = np.zeros((n, n))
    cov[0:3, 0:3] = np.eye(3) * init_attitude ** 2
    cov[3:6, 3:6] = np.eye(3) * init_bias ** 2
    r = (noise / GRAVITY) ** 2
    a = acc[0] / np.linalg.norm(acc[0])
    q = Q.from_zyx(np.arctan2(a[1], a[2]), np.arctan2(-a[0], np.hypot(a[1], a[2])), 0.0)
    bias = np.zeros(3)
    lowpass = None
    steps = 0
    group_turn = np.array([1.0, 0.0, 0.0, 0.0])
    earth_sum = np.zeros(3)
    out = np.zeros((len(gyr), 4))
    for i in range(len(gyr)):
        turn = Q.from_rotvec((gyr[i] - bias) * dt)
        q = Q.normalize(Q.multiply(q, turn))
        group_turn = Q.multiply(group_turn, turn)
        earth_sum += Q.to_rotmat(q) @ acc[i]  # each sample with the attitude of its time
        out[i] = q
        if (i + 1) % 3:
            continue
        phi = Q.to_rotmat(group_turn).T
        group_turn = np.array([1.0, 0.0, 0.0, 0.0])
        transition = np.eye(n)
        transition[0:3, 0:3] = phi
        transition[0:3, 3:6] = -period * np.eye(3)
        noise_in = np.zeros((n, 3))
        noise_in[0:3] = np.eye(3)
        if drift_states:
            transition[6:9, 3:6] = -(1 - alpha) * period * np.eye(3)
            transition[6:9, 6:9] = (1 - alpha) * phi
            noise_in[6:9] = (1 - alpha) * np.eye(3)
        cov = transition @ cov @ transition.T + arw ** 2 * period * noise_in @ noise_in.T
        cov[3:6, 3:6] += rrw ** 2 * period * np.eye(3)
        rot = Q.to_rotmat(q)
        steps += 1
        earth = earth_sum / 3
        earth_sum[:] = 0.0
        lowpass = earth.copy() if lowpass is None else lowpass + max(alpha, 1.0 / steps) * (earth - lowpass)
        measured = rot.T @ lowpass / GRAVITY
        up = rot[2]
        dx = np.zeros(n)
        for k in range(2):  # east and north
            h = np.zeros(n)
            h[0:3] = np.cross(rot[k], up)
            if drift_states:
                h[6:9] = -h[0:3]
            innovation = rot[k] @ measured - h @ dx
            gain = cov @ h / (h @ cov @ h + r)
            dx += gain * innovation
            keep = np.eye(n) - np.outer(gain, h)
            cov = keep @ cov @ keep.T + r * np.outer(gain, gain)
        lowpass += np.cross(rot @ (dx[0:3] - (dx[6:9] if drift_states else 0.0)), lowpass)
        q = Q.normalize(Q.multiply(q, Q.from_rotvec(dx[0:3])))
        bias += dx[3:6]
        out[i] = q
    return out


def evaluate(seeds) -> dict[str, dict[str, list[float]]]:
    """{condition: {variant or "VQF": [inclination RMSE deg per seed]}}."""
    out: dict[str, dict[str, list[float]]] = {}
    for condition in CONDITIONS:
        rows: dict[str, list[float]] = {name: [] for name in [*VARIANTS, "VQF"]}
        for seed in seeds:
            data = eval_tilt_sources.case(condition, seed)
            gyr, acc, _ = rough.filter_inputs(data)
            for name, (drift_states, noise) in VARIANTS.items():
                rows[name].append(eval_tilt_sources.inclination(run(gyr, acc, data.rate_hz, drift_states, noise), data))
            rows["VQF"].append(eval_tilt_sources.inclination(rough.run_estimator("vqf", data), data))
            print(f"  {condition}, seed {seed}", file=sys.stderr, flush=True)
        out[condition] = rows
    return out


def evaluate_broad(data_dir) -> dict[str, dict[str, list[float]]]:
    """{"BROAD": {variant: [inclination RMSE deg per trial]}}: the dataset's metric over the
    movement phase (tools/eval_broad.py), the prototype on the recordings' SI values."""
    import eval_broad

    rows: dict[str, list[float]] = {name: [] for name in VARIANTS}
    for trial in eval_broad.load_trials(data_dir):
        for name, (drift_states, noise) in VARIANTS.items():
            q = run(trial.gyr, trial.acc, trial.rate_hz, drift_states, noise)
            rows[name].append(eval_broad.broad_errors(q, trial.quat_ref, trial.movement)["inclination"])
        print(f"  {trial.name}", file=sys.stderr, flush=True)
    return {"BROAD (12 trials)": rows}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="0,1,2,3,4", help="comma-separated seeds (default 0-4)")
    p.add_argument("--broad", metavar="DIR", help="also the BROAD trials in DIR (VQF's column: tools/eval_broad.py)")
    p.add_argument("--markdown", action="store_true", help="print a markdown table")
    args = p.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
        if not seeds:
            raise ValueError("--seeds must name a seed")
        if args.broad and not Path(args.broad).is_dir():
            raise ValueError(f"--broad: no directory {args.broad}")
    except ValueError as exc:
        print(f"eval_tilt_drift_states: {exc}", file=sys.stderr)
        return 2
    results = evaluate(seeds)
    if args.broad:
        results.update(evaluate_broad(args.broad))
    names = [*VARIANTS, "VQF"]
    if args.markdown:
        print("| condition | " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(names))
    for condition, rows in results.items():
        cells = [f"{np.mean(rows[name]):.3f} / {np.max(rows[name]):.3f}" if name in rows else "" for name in names]
        if args.markdown:
            print(f"| {condition} | " + " | ".join(cells) + " |")
        else:
            print(f"{condition:18s} " + "  ".join(cells))
    print(f"\nInclination RMSE (deg) from {rough.SETTLE_S:g} s, mean / worst of seeds {','.join(map(str, seeds))}, "
          "handheld motion "
          f"{rough.DURATION_S:g} s at {rough.RATE_HZ:g} Hz (tools/eval_tilt_sources.py's cases); BROAD: mean / worst "
          "trial over the movement phase. Float prototype; the number after each variant is the gravity rows' noise "
          "in m/s^2.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
