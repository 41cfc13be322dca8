#!/usr/bin/env python3
"""Where the inclination error comes from: the ESKF against VQF with one error source at a time.

The rough ``handheld`` motion (imulink.sim.motion_with_rests: moves of 5-20 s up to about
200 deg/s between rests of 2-10 s, a hand's translation; 300 s at 100 Hz) is read by the
default simulated sensors, then again with the sources taken apart:

- ``all``: the default sensors and 1 m/s^2 per axis of linear acceleration (``handheld``);
- ``no translation``: the same without linear acceleration;
- ``ideal gyroscope``: translation, and a gyroscope without noise or bias;
- ``only <term>``: no translation, and of the gyroscope's errors only that one
  (imulink.sim.GyroModel: ``arw`` white noise, ``bias_instability`` its Gauss-Markov bias,
  ``rrw`` its random-walk bias, ``bias`` the turn-on bias).

Each row: the inclination RMSE (deg, from 10 s on, the BROAD metric) of the fixed-point
ESKF (default settings, or --settings) and of VQF (default parameters, fed the same
register counts), mean and worst of the seeds.

A measurement, not a gate (exit 0; 2: usage error).

    .venv/bin/python tools/eval_tilt_sources.py --markdown
    .venv/bin/python tools/eval_tilt_sources.py --settings '{"gyro_rrw": 4e-5}'
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from imulink import core, sim
from imulink.analysis import rough
from imulink.analysis.attitude import attitude_errors

GYRO_TERMS = ("arw", "bias_instability", "rrw", "bias")
CONDITIONS = ("all", "no translation", "ideal gyroscope", *(f"only {term}" for term in GYRO_TERMS))


def case(condition: str, seed: int) -> sim.SimResult:
    """The simulated readings of one condition and seed."""
    translation = condition in ("all", "ideal gyroscope")
    traj = sim.motion_with_rests(rough.DURATION_S, rough.RATE_HZ, seed=seed, translation="bounded",
                                 accel_std=1.0 if translation else 0.0)
    suite = sim.SensorSuite.default()
    keep = set(GYRO_TERMS) if condition in ("all", "no translation") else set()
    if condition.startswith("only "):
        keep = {condition.removeprefix("only ")}
    for term in set(GYRO_TERMS) - keep:
        setattr(suite.gyro, term, np.zeros(3))
    return sim.simulate(traj, suite, seed=seed)


def inclination(q, data: sim.SimResult) -> float:
    scored = data.t >= rough.SETTLE_S
    return float(np.sqrt(np.mean(attitude_errors(q, data.quat_true)["inclination"][scored] ** 2)))


def evaluate(seeds, settings: dict) -> dict[str, dict[str, list[float]]]:
    """{condition: {"eskf": [deg per seed], "vqf": [...]}}."""
    out: dict[str, dict[str, list[float]]] = {}
    for condition in CONDITIONS:
        rows: dict[str, list[float]] = {"eskf": [], "vqf": []}
        for seed in seeds:
            data = case(condition, seed)
            eskf = core.run("eskf", data.gyr, data.acc, data.mag, data.rate_hz, "fixed", settings=settings,
                            profile=data.profile).quat
            rows["eskf"].append(inclination(eskf, data))
            rows["vqf"].append(inclination(rough.run_estimator("vqf", data), data))
        out[condition] = rows
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", default="0,1,2,3,4", help="comma-separated seeds (default 0-4)")
    p.add_argument("--settings", default="{}", help="JSON settings of the ESKF, e.g. '{\"gyro_rrw\": 4e-5}'")
    p.add_argument("--markdown", action="store_true", help="print a markdown table")
    args = p.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
        settings = json.loads(args.settings)
        if not isinstance(settings, dict) or not seeds:
            raise ValueError("--settings must be a JSON object and --seeds must name a seed")
        core.resolve_settings("eskf", rough.RATE_HZ, settings)
    except (ValueError, KeyError) as exc:
        print(f"eval_tilt_sources: {exc}", file=sys.stderr)
        return 2
    results = evaluate(seeds, settings)
    if args.markdown:
        print("| condition | ESKF mean | ESKF worst | VQF mean | VQF worst |")
        print("|---|---|---|---|---|")
    for condition, rows in results.items():
        e, v = np.array(rows["eskf"]), np.array(rows["vqf"])
        if args.markdown:
            print(f"| {condition} | {e.mean():.3f} | {e.max():.3f} | {v.mean():.3f} | {v.max():.3f} |")
        else:
            print(f"{condition:24s} eskf mean {e.mean():.3f} worst {e.max():.3f}   vqf mean {v.mean():.3f} "
                  f"worst {v.max():.3f}")
    print(f"\nInclination RMSE (deg) from {rough.SETTLE_S:g} s, handheld motion {rough.DURATION_S:g} s at "
          f"{rough.RATE_HZ:g} Hz, seeds {','.join(map(str, seeds))}; ESKF fixed point, "
          f"settings {settings or 'default'}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
