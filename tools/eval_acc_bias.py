#!/usr/bin/env python3
"""How well the 9-state ESKF finds an accelerometer bias: its estimate against the simulated truth.

For every scenario of imulink.analysis.rough that has an accelerometer bias (``acc-bias``:
0.2-0.4 m/s^2 per axis, random signs, MPU6050 size; ``acc-bias-drift``: the same plus 0.2 m/s^2
of temperature drift in 8 steps) and every seed, the fixed-point ESKF with
``estimate_acc_bias`` 1 (and ``--settings``) runs on the 300 s at 100 Hz, and the error
|b_est - b_true| (m/s^2) is read every second. Reported per scenario, the WORST seed of:
the initial bias |b_true(0)|, the error at 60 s, at 150 s and at the end, the largest error
from 150 s on, and the filter's own one-sigma bound sqrt(trace P_ba) at the end.

A measurement, not a gate (exit 0; 2: usage error).

    .venv/bin/python tools/eval_acc_bias.py --markdown
    .venv/bin/python tools/eval_acc_bias.py --settings '{"init_acc_bias_std": 0.3}' --markdown
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from imulink import core
from imulink.analysis import rough

SCENARIOS = ("acc-bias", "acc-bias-drift")
#: Seconds between two readings of the estimate.
READ_EVERY_S = 1.0
#: The times of the table's columns, s.
EARLY_S, MIDDLE_S = 60.0, 150.0
GRAVITY = 9.80665


def bias_errors(scenario: str, seed: int, settings: dict) -> dict:
    """One run: {"initial", "at_60", "at_150", "end", "max_late", "sigma_end"} in m/s^2."""
    data, _ = rough.SCENARIOS[scenario](seed)
    f = core.Filter("eskf", data.rate_hz, "fixed", {**settings, "estimate_acc_bias": 1})
    step = round(READ_EVERY_S * data.rate_hz)
    times, errors = [], []
    for start in range(0, len(data.t), step):
        stop = min(start + step, len(data.t))
        f.run_counts(data.gyr_counts[start:stop], data.acc_counts[start:stop], data.mag_counts[start:stop])
        times.append(data.t[stop - 1])
        errors.append(float(np.linalg.norm(f.acc_bias() - data.acc_bias_true[stop - 1])))
    times, errors = np.array(times), np.array(errors)
    sigma = float(np.sqrt(np.trace(f.covariance()[6:, 6:]))) * GRAVITY  # P_ba is in g^2
    return {"initial": float(np.linalg.norm(data.acc_bias_true[0])),
            "at_60": float(np.interp(EARLY_S, times, errors)), "at_150": float(np.interp(MIDDLE_S, times, errors)),
            "end": float(errors[-1]), "max_late": float(errors[times >= MIDDLE_S].max()), "sigma_end": sigma}


def evaluate(seeds, settings: dict) -> dict:
    """{scenario: {"seeds": {seed: bias_errors}, "worst": {column: (value, seed)}}}."""
    out = {}
    for scenario in SCENARIOS:
        runs = {seed: bias_errors(scenario, seed, settings) for seed in seeds}
        print(f"{scenario}: {len(runs)} seeds", file=sys.stderr)
        worst = {key: max(((run[key], seed) for seed, run in runs.items()), key=lambda item: item[0])
                 for key in next(iter(runs.values()))}
        out[scenario] = {"seeds": runs, "worst": worst}
    return out


def markdown(results: dict, settings: dict) -> str:
    columns = (("initial", "bias at start"), ("at_60", "error at 60 s"), ("at_150", "error at 150 s"),
               ("end", "error at 300 s"), ("max_late", "largest error after 150 s"),
               ("sigma_end", "filter's sigma at 300 s"))
    lines = ["| scenario | " + " | ".join(title for _, title in columns) + " |",
             "|---|" + "---|" * len(columns)]
    for scenario, result in results.items():
        cells = [f"{result['worst'][key][0]:.3f} (s{result['worst'][key][1]})" for key, _ in columns]
        lines.append(f"| {scenario} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(f"m/s^2, worst of seeds {', '.join(str(s) for s in next(iter(results.values()))['seeds'])}; "
                 f"ESKF fixed, estimate_acc_bias 1, settings {json.dumps(settings) if settings else 'the defaults'}.")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--seeds", default="0,1,2,3,4,5,6,7,8,9", help="comma-separated seeds (default 0..9)")
    parser.add_argument("--settings", default="{}", help="JSON ESKF settings, e.g. '{\"init_acc_bias_std\": 0.3}'")
    parser.add_argument("--markdown", action="store_true", help="print a markdown table")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
        settings = json.loads(args.settings)
        if not isinstance(settings, dict):
            raise ValueError("--settings must be a JSON object")
        core.Filter("eskf", rough.RATE_HZ, "fixed", {**settings, "estimate_acc_bias": 1})  # checks the settings
    except (ValueError, core.SettingsError) as exc:
        parser.error(str(exc))
    results = evaluate(seeds, settings)
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print(markdown(results, settings))
    return 0


if __name__ == "__main__":
    sys.exit(main())
