#!/usr/bin/env python3
"""What the ESKF settings that `imulink allan --settings eskf` derives are worth.

The path a user takes: a still board's noise terms (Allan deviation) -> filter settings
-> the filter on a moving board. For each source of terms the ESKF (fixed point) runs
with its defaults, with the derived settings (the sensor's terms plus the allowance for a
moving board, the default) and with `--sensor-only` (the sensor's terms alone), and the
mean total attitude RMSE is printed:

- simulated: a still run of the simulator's default sensors ([seed 000]'s gyroscopes,
  0.02 m/s^2 per sample on the accelerometer) analysed for terms, then the scenarios
  rests, random, static and turntable (--seconds each, seeds 0-2, 10 s settling left out);
- BROAD: the longest rest of 02_undisturbed_slow_rotation_B analysed for terms, then the
  twelve trials with the dataset's own metric (tools/eval_broad.py); skipped, with a line
  saying so, when the data is not beside the repository.

    .venv/bin/python tools/eval_allan_settings.py [--hours 1] [--seconds 120] [--broad DIR]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from imulink import core, sim
from imulink.analysis import allan
from imulink.analysis.scenarios import euler_errors_deg
from imulink.io.broad import data_dir as broad_data_dir

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_broad  # noqa: E402 - the BROAD metric of tools/eval_broad.py

BROAD = broad_data_dir()
RATE_HZ = 100.0
SETTLE_S = 10.0
SCENARIOS = ("rests", "random", "static", "turntable")
BROAD_REST_TRIAL = "02_undisturbed_slow_rotation_B"


def variants(terms: dict) -> dict[str, dict]:
    return {"defaults": {}, "derived": allan.settings_from_terms(terms, "eskf"),
            "sensor only": allan.settings_from_terms(terms, "eskf", sensor_only=True)}


def simulated_terms(hours: float) -> dict:
    still = sim.make_scenario("static", hours * 3600.0, RATE_HZ, seed=7)
    record = allan.StaticRecord("simulated still board", RATE_HZ, still.gyr, still.acc)
    return allan.to_json(allan.analyse(record))


def simulated_rmse(settings: dict, scenario: str, seconds: float) -> float:
    errors = []
    for seed in range(3):
        run = sim.make_scenario(scenario, seconds, RATE_HZ, seed=seed)
        out = core.run("eskf", run.gyr, run.acc, run.mag, RATE_HZ, "fixed", settings=settings)
        e = euler_errors_deg(out.quat, run.quat_true)[int(SETTLE_S * RATE_HZ):]
        errors.append(float(np.sqrt(np.mean(np.sum(e**2, axis=1)))))
    return float(np.mean(errors))


def show(name: str, settings: dict) -> str:
    return f"{name} ({', '.join(f'{k}={v:.4g}' for k, v in settings.items()) or 'as they are'})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=1.0, help="length of the simulated still run (default: 1)")
    parser.add_argument("--seconds", type=float, default=120.0, help="length of each scenario run (default: 120)")
    parser.add_argument("--broad", type=Path, default=BROAD, help="directory of the BROAD trials")
    args = parser.parse_args()

    print(f"simulated sensors: terms from {args.hours:g} h still; ESKF total RMSE (deg), mean of seeds 0-2, "
          f"{args.seconds:g} s each\n")
    print("| settings | " + " | ".join(SCENARIOS) + " |\n|---|" + "---:|" * len(SCENARIOS))
    for name, settings in variants(simulated_terms(args.hours)).items():
        cells = [f"{simulated_rmse(settings, scenario, args.seconds):.2f}" for scenario in SCENARIOS]
        print(f"| {show(name, settings)} | " + " | ".join(cells) + " |", flush=True)

    try:
        paths = eval_broad.trial_paths(args.broad)
    except FileNotFoundError as exc:
        print(f"\nBROAD: {exc}: skipped", file=sys.stderr)
        return 0
    trials = [eval_broad.load_trial(path) for path in paths]
    rest = allan.load_static(args.broad / f"{BROAD_REST_TRIAL}.mat")
    print(f"\nBROAD: terms from the longest rest of {BROAD_REST_TRIAL}; ESKF mean total RMSE over the "
          f"{len(trials)} trials (deg)\n")
    print("| settings | BROAD |\n|---|---:|")
    for name, settings in variants(allan.to_json(allan.analyse(rest))).items():
        rmse = eval_broad.mean_total_rmse(trials, "eskf", "fixed", settings)
        print(f"| {show(name, settings)} | {rmse:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
