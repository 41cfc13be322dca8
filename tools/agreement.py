#!/usr/bin/env python3
"""Fixed-vs-float agreement benchmark of the imulink attitude filters.

For each filter, a simulated random-motion recording
(``imulink.sim.make_scenario("random", duration, 100, seed)``, default one hour)
runs through the fixed-point build and through its double-precision twin
(:func:`imulink.core.run`, default sensor profile, identical integer inputs). The
table reports the total rotation angle between the two builds' quaternions
(:func:`imulink.sim.quat.angle_between`) -- maximum, 99th percentile and mean, in
degrees -- and the fixed build's saturation count.

Example::

    .venv/bin/python tools/agreement.py --duration 3600 --seed 0
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def agreement(filter_name: str, scenario, settings: dict | None = None) -> dict:
    """Run fixed and float on a simulated scenario; angle statistics (deg) and saturations."""
    from imulink import core
    from imulink.sim.quat import angle_between

    args = (scenario.gyr, scenario.acc, scenario.mag)
    fixed = core.run(filter_name, *args, rate_hz=scenario.rate_hz, arithmetic="fixed", settings=settings)
    flt = core.run(filter_name, *args, rate_hz=scenario.rate_hz, arithmetic="float", settings=settings)
    d = np.rad2deg(angle_between(fixed.quat, flt.quat))
    return {
        "max_deg": float(np.max(d)),
        "p99_deg": float(np.percentile(d, 99)),
        "mean_deg": float(np.mean(d)),
        "t_max_s": float(scenario.t[int(np.argmax(d))]),
        "saturations_fixed": int(fixed.saturations),
        "saturations_float": int(flt.saturations),
        "samples": int(d.size),
    }


def main(argv=None) -> int:
    from imulink import core, sim

    p = argparse.ArgumentParser(description="Fixed-point vs float-twin agreement on a simulated random motion.")
    p.add_argument("--duration", type=float, default=3600.0, help="simulated duration in s (default 3600)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectory and sensor noise (default 0)")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate in Hz (default 100)")
    p.add_argument("--filters", default=",".join(core.FILTERS),
                   help=f"comma-separated filters (default: {','.join(core.FILTERS)})")
    p.add_argument("--settings", default=None,
                   help='JSON settings overrides per filter, e.g. \'{"kf1d": {"q_angle": 1e-4}}\'')
    p.add_argument("--markdown", action="store_true", help="print a markdown table")
    args = p.parse_args(argv)

    filters = [f.strip() for f in args.filters.split(",") if f.strip()]
    bad = [f for f in filters if f not in core.FILTERS]
    if bad or not filters:
        p.error(f"unknown filters {bad}; choose from {', '.join(core.FILTERS)}")
    settings = json.loads(args.settings) if args.settings else {}

    t0 = time.perf_counter()
    print(f"simulating random motion: {args.duration:g} s at {args.rate:g} Hz, seed {args.seed}",
          file=sys.stderr, flush=True)
    scenario = sim.make_scenario("random", args.duration, args.rate, args.seed)
    print(f"  done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)

    rows = []
    for f in filters:
        t0 = time.perf_counter()
        r = agreement(f, scenario, settings.get(f))
        print(f"{f}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        rows.append((f, r))

    if args.markdown:
        print("| filter | max (deg) | 99th pct (deg) | mean (deg) | saturations (fixed) |")
        print("|---|---|---|---|---|")
        for f, r in rows:
            print(f"| {f.upper()} | {r['max_deg']:.4f} | {r['p99_deg']:.4f} | {r['mean_deg']:.5f} "
                  f"| {r['saturations_fixed']} |")
    else:
        print(f"fixed vs float, random motion {args.duration:g} s @ {args.rate:g} Hz, seed {args.seed}")
        print(f"{'filter':8s} {'max deg':>9s} {'p99 deg':>9s} {'mean deg':>9s} {'t(max) s':>9s} {'sat fix':>8s}")
        for f, r in rows:
            print(f"{f:8s} {r['max_deg']:9.4f} {r['p99_deg']:9.4f} {r['mean_deg']:9.5f} "
                  f"{r['t_max_s']:9.1f} {r['saturations_fixed']:8d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
