#!/usr/bin/env python3
"""[seed 000]'s and [seed 004]'s experiments on the simulator, for every filter
(docs/filters.md, Bibliography).

- static: standard deviation and largest error of pitch / roll / heading after the
  first 10 s of 120 s at rest (seeds 1-3 pooled), the way [seed 004]'s table reports;
- turntable: heading error while turning at 10 deg/s ([seed 000]'s figure 8);
- gyro bias: seconds until the bias estimate stays within 0.05 deg/s of the truth.

Settings: imulink.analysis.scenarios.SIM_SETTINGS (the simulated sensors' noise).

    python tools/eval_sim.py [--markdown]
"""
from __future__ import annotations

import argparse

import numpy as np

from imulink import core
from imulink.analysis import scenarios


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--markdown", action="store_true", help="print markdown tables")
    parser.add_argument("--seeds", default="1,2,3", help="comma-separated seeds of the static runs")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]

    rows = []
    for name in core.FILTERS:
        err = np.concatenate([scenarios.static_errors(name, seed) for seed in seeds])
        std = err.std(axis=0)
        peak = np.abs(err).max(axis=0)
        table = scenarios.turntable_heading_errors(name, seed=seeds[0])
        converge = scenarios.bias_convergence_time(name, seed=seeds[0])
        rows.append((name, std[1], std[0], std[2], peak[1], peak[0], peak[2],
                     float(np.sqrt(np.mean(table**2))), float(np.abs(table).max()), converge))

    header = ("filter", "std pitch", "std roll", "std heading", "max pitch", "max roll", "max heading",
              "turntable rms", "turntable max", "bias within 0.05 deg/s after (s)")
    if args.markdown:
        print("| " + " | ".join(header) + " |")
        print("|" + "---|" * len(header))
        for r in rows:
            print(f"| {r[0]} | " + " | ".join(f"{v:.3f}" for v in r[1:9]) + f" | {r[9]:.1f} |")
    else:
        print("  ".join(f"{h:>14}" for h in header))
        for r in rows:
            print(f"{r[0]:>14}  " + "  ".join(f"{v:14.3f}" for v in r[1:9]) + f"  {r[9]:14.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
