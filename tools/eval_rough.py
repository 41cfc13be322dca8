#!/usr/bin/env python3
"""The attitude filters against VQF on rough simulated cases, reporting the WORST seed.

For every scenario and seed the simulator makes 300 s at 100 Hz (SensorSuite.default():
the [seed 000] gyros with a (0.2, -0.3, 0.1) deg/s turn-on bias, accelerometer noise
0.02 m/s^2, magnetometer 0.2 uT in a 49 uT field of 67 deg dip; MPU6050 at +-2000 deg/s
and +-8 g, HMC5883L at +-1.3 Ga), plus the scenario's condition:

  handheld         moves of 5-20 s (about 200 deg/s) between rests of 2-10 s, linear
                   acceleration 1 m/s^2 per axis (std) while moving.
  fast             continuous random motion, 400 deg/s, linear acceleration 3 m/s^2 per axis.
  sustained        handheld with a sustained linear acceleration: flat down to 0 Hz (a
                   vehicle's), where every other case has a hand's (the second derivative of
                   a position within reach, which averages out within seconds).
  vibration        slow random motion (100 deg/s, 0.5 m/s^2) on a shaking mount: 3 m/s^2 and
                   0.1 rad/s (5.7 deg/s) RMS of vibration at 20-45 Hz and its 2nd order,
                   sampled without an anti-alias filter (the Vibration class's default, a
                   car's engine, is 0.7 m/s^2 and 2 deg/s: this is a drone frame, a power tool).
  acc-bias         handheld with a constant accelerometer bias of 0.2-0.4 m/s^2 per axis,
                   random signs (MPU6050 size).
  acc-bias-drift   acc-bias plus a temperature drift: 8 steps from 30 s to 270 s adding up to
                   0.2 m/s^2 along a random direction.
  gyro-bias-step   handheld with a gyro bias step of 0.5 deg/s (random sign) on a random
                   axis at 150 s.
  gyro-scale       continuous rotation up to 300 deg/s (1 m/s^2) read by an uncalibrated
                   gyroscope: scale-factor errors of 1-2 % and cross-axis sensitivities up
                   to 1 %, random signs (the MPU6050 allows 3 % and 2 %).
  magnet-room      handheld with an extra 25 uT fixed in the room (random direction) for 30 s
                   starting at 90-180 s.
  attached-magnet  handheld with a magnet on the board: a 15 uT hard-iron offset (random body
                   direction) for the whole run. (The simulator's MagModel has a constant
                   hard_iron only, so the magnet cannot be switched on for 60 s.)
  shocks           handheld with a knock every 2-5 s: a 200 m/s^2 Ricker pulse (15 ms main
                   lobe, random direction), clipped at +-8 g (78 m/s^2).
  outage           handheld with the magnetometer reading zeros (no sample) for 60 s
                   starting at 90-180 s.
  slow-turn        handheld with three 40 s steady rotations at 0.5-1.8 deg/s about random
                   axes (at 45, 135 and 225 s), no linear acceleration: slower than a rest
                   detector's 2 deg/s rate threshold.

Event placements (directions, axes, times) are drawn from the seed; every scenario is
scored from 10 s on (disturbances included: they are the point).

Estimators: the fixed-point builds of eecf, eskf (6 states) and eskf9 (eskf with
estimate_acc_bias = 1), each with its DEFAULT settings (what users get), through
imulink.core.run; VQF (the vqf package, VQF(1 / rate).updateBatch(gyr, acc, mag)["quat9D"],
default parameters) on exactly what the filters see (the readings through the register
counts and back, clipping included); and "gyro" (no filter: the gyroscope integrated from
the TRUE initial attitude, the simplest alternative).

Errors: the BROAD metric, e = q_est (x) q_true^-1: total 2 acos|e_w|, heading
2 atan|e_z / e_w|, inclination 2 acos sqrt(e_w^2 + e_z^2); RMSE over the scored samples,
then the WORST (largest) over the seeds, kind by kind, with the seed that gave it. A
filter is listed as worse than VQF where its worst-seed RMSE exceeds VQF's worst-seed RMSE
by more than 0.05 deg (the table's `!`), and, stricter, where on any one seed (the same
data) its RMSE exceeds VQF's by more than 0.05 deg (the seed of the largest excess and how
many seeds lose are given). A measurement, not a gate: the exit status is 0 (2: usage error,
3: the vqf package is missing). Progress goes to stderr. The scenarios and the evaluation
are imulink.analysis.rough.

    .venv/bin/python tools/eval_rough.py --markdown
    .venv/bin/python tools/eval_rough.py --seeds 0,1 --scenarios fast,shocks --filters eskf9 --json
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

from imulink.analysis import rough

#: Exit code for a usage error (unknown scenario, filter, bad seeds).
EXIT_USAGE = 2
#: Exit code when the vqf package is missing.
EXIT_NO_VQF = 3

VQF_MISSING = "error: the VQF reference needs the vqf package (comparison only): pip install 'imulink[bench]'"

LABELS = {"eecf": "eecf", "eskf": "eskf", "eskf9": "eskf9", "vqf": "VQF (ref.)", "gyro": "gyro only"}


class UsageError(ValueError):
    """A one-line usage error."""


def _names(value: str, allowed, what: str) -> list[str]:
    items = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        raise UsageError(f"unknown {what} {', '.join(map(repr, bad)) or repr(value)}; "
                         f"choose from {', '.join(allowed)}")
    return list(dict.fromkeys(items))


def _seeds(value: str) -> list[int]:
    try:
        seeds = [int(v) for v in value.split(",") if v.strip()]
    except ValueError:
        raise UsageError(f"--seeds must be comma-separated integers from 0, not {value!r}") from None
    if not seeds or min(seeds) < 0:
        raise UsageError(f"--seeds must be comma-separated integers from 0, not {value!r}")
    return list(dict.fromkeys(seeds))


def _cell(worst: dict) -> str:
    return f"{worst['rmse']:.2f} (s{worst['seed']})"


def _flags(results: dict, scenario: str, name: str, margin: float) -> dict[str, bool]:
    """Per kind: is this filter's worst-seed RMSE more than `margin` above VQF's?"""
    w = results[scenario]["worst"]
    return {k: name in rough.FILTERS and not w[name][k]["rmse"] - w["vqf"][k]["rmse"] <= margin for k in rough.KINDS}


def summary_lines(results: dict, filters, margin: float = rough.MARGIN_DEG) -> list[str]:
    """Per filter: the scenarios where its worst seed is worse than VQF's worst seed, per kind,
    by how much; then those where it is worse than VQF on the same seed (any seed)."""
    lines = []
    for f in filters:
        worse = rough.worse_than_vqf(results, f, margin)
        parts = []
        for kind in ("inclination", "heading", "total"):
            items = ", ".join(f"{w['scenario']} (+{w['excess']:.2f})" for w in worse[kind]) or "none"
            parts.append(f"{kind}: {items}")
        lines.append(f"{f}: worse than VQF (worst seed vs worst seed) by > {margin:g} deg in " + "; ".join(parts))
    for f in filters:
        paired = rough.paired_losses(results, f, margin)
        parts = []
        for kind in ("inclination", "heading", "total"):
            items = ", ".join(f"{w['scenario']} (s{w['seed']} +{w['excess']:.2f}, "
                              f"{w['seeds_worse']}/{w['seeds']} seeds)" for w in paired[kind]) or "none"
            parts.append(f"{kind}: {items}")
        lines.append(f"{f}: worse than VQF on the same seed by > {margin:g} deg in " + "; ".join(parts))
    return lines


def format_markdown(results: dict, estimators, filters, seeds, duration_s: float) -> str:
    lines = ["| scenario | estimator | total RMSE (deg) | heading RMSE (deg) | inclination RMSE (deg) |",
             "|---|---|---|---|---|"]
    for scenario, r in results.items():
        for name in estimators:
            flags = _flags(results, scenario, name, rough.MARGIN_DEG)
            cells = [_cell(r["worst"][name][k]) + (" !" if flags[k] else "") for k in rough.KINDS]
            lines.append(f"| {scenario} | {LABELS[name]} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(f"Worst RMSE over seeds {','.join(map(str, seeds))} (sN: the seed that gave it), {duration_s:g} s "
                 f"at {rough.RATE_HZ:g} Hz per run, scored from {rough.SETTLE_S:g} s; filters fixed-point with "
                 f"default settings; `!`: more than {rough.MARGIN_DEG:g} deg above VQF's worst.")
    lines.append("")
    lines.extend(f"- {line}" for line in summary_lines(results, filters))
    return "\n".join(lines)


def format_text(results: dict, estimators, filters, seeds, duration_s: float) -> str:
    width = max(len(s) for s in results)
    lines = [f"{'scenario':{width}s}  {'estimator':10s}  {'total':>12s}  {'heading':>12s}  {'inclination':>12s}"]
    for scenario, r in results.items():
        for name in estimators:
            flags = _flags(results, scenario, name, rough.MARGIN_DEG)
            cells = [(_cell(r["worst"][name][k]) + ("!" if flags[k] else " ")) for k in rough.KINDS]
            lines.append(f"{scenario:{width}s}  {LABELS[name]:10s}  " + "  ".join(f"{c:>12s}" for c in cells))
    lines.append("")
    lines.append(f"worst RMSE (deg) over seeds {','.join(map(str, seeds))}, {duration_s:g} s per run, scored from "
                 f"{rough.SETTLE_S:g} s; !: more than {rough.MARGIN_DEG:g} deg above VQF's worst")
    lines.extend(summary_lines(results, filters))
    return "\n".join(lines)


def to_json(results: dict, estimators, filters, seeds, duration_s: float) -> dict:
    scenarios = {s: {"worst": r["worst"], "seeds": {str(seed): case for seed, case in r["seeds"].items()}}
                 for s, r in results.items()}
    return {"config": {"seeds": list(seeds), "duration_s": duration_s, "rate_hz": rough.RATE_HZ,
                       "settle_s": rough.SETTLE_S, "margin_deg": rough.MARGIN_DEG, "estimators": list(estimators),
                       "filters": {f: {"core": rough.FILTERS[f][0], "settings": rough.FILTERS[f][1]} for f in filters}},
            "scenarios": scenarios,
            "worse_than_vqf": {f: rough.worse_than_vqf(results, f) for f in filters},
            "paired_losses": {f: rough.paired_losses(results, f) for f in filters}}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", default="0,1,2,3,4", help="comma-separated seeds (default 0,1,2,3,4)")
    p.add_argument("--scenarios", default=",".join(rough.SCENARIOS),
                   help=f"comma-separated scenarios (default all: {','.join(rough.SCENARIOS)})")
    p.add_argument("--filters", default=",".join(rough.FILTERS),
                   help=f"comma-separated filters (default {','.join(rough.FILTERS)})")
    p.add_argument("--duration", type=float, default=rough.DURATION_S,
                   help=f"length of each run in s (default {rough.DURATION_S:g}; events scale with it)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="processes over (scenario, seed) (default: 2, or 1 on a single core)")
    p.add_argument("--markdown", action="store_true", help="print a markdown table")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    args = p.parse_args(argv)
    try:
        seeds = _seeds(args.seeds)
        scenarios = _names(args.scenarios, list(rough.SCENARIOS), "scenario")
        filters = _names(args.filters, list(rough.FILTERS), "filter")
        if not 20.0 <= args.duration <= 3600.0:
            raise UsageError(f"--duration must be from 20 to 3600 s, not {args.duration:g}")
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        import vqf  # noqa: F401
    except ImportError:
        print(VQF_MISSING, file=sys.stderr)
        return EXIT_NO_VQF
    estimators = [*filters, *rough.REFERENCES]

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    log(f"{len(scenarios)} scenario(s) x {len(seeds)} seed(s), {args.duration:g} s each, "
        f"{max(1, args.workers)} worker(s)")
    results = rough.evaluate(scenarios, seeds, estimators, args.duration, max(1, args.workers), log)
    log(f"done in {time.perf_counter() - t0:.1f} s")
    if args.json:
        print(json.dumps(to_json(results, estimators, filters, seeds, args.duration), indent=1))
    elif args.markdown:
        print(format_markdown(results, estimators, filters, seeds, args.duration))
    else:
        print(format_text(results, estimators, filters, seeds, args.duration))
    return 0


if __name__ == "__main__":
    sys.exit(main())
