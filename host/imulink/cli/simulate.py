"""`imulink simulate`."""
from __future__ import annotations

import sys
import time
from typing import Any

from imulink import core, sim
from imulink.analysis.attitude import angle_difference, attitude_errors, rmse
from imulink.cli.common import (
    UsageError,
    json_argument,
    non_negative_float,
    one_line_errors,
    parse_filters,
    positive_float,
    print_json,
    seed_number,
)


@one_line_errors
def run(args) -> int:
    filters = parse_filters(args.filters)
    if args.settle >= args.duration:
        raise UsageError(f"--settle {args.settle:g} s leaves nothing of the {args.duration:g} s run to evaluate")
    print(f"simulating {args.scenario!r}: {args.duration:g} s at {args.rate:g} Hz, seed {args.seed}", file=sys.stderr)
    result = sim.make_scenario(args.scenario, args.duration, args.rate, seed=args.seed)
    settle = int(args.settle * args.rate)
    report = {"scenario": args.scenario, "duration_s": args.duration, "rate_hz": args.rate, "seed": args.seed,
              "settle_s": args.settle, "samples": len(result.t), "filters": []}
    if not args.json:
        print(f"samples: {len(result.t)}; errors are RMS after the first {args.settle:g} s, in degrees")
        header = f"{'filter':<6} {'arith':<6} {'total':>8} {'heading':>8} {'incl.':>8} {'sat':>5} {'samples/s':>11}"
        print(header)
        print("-" * len(header))
    for name in filters:
        runs = {}
        entry: dict[str, Any] = {"filter": name}
        for arithmetic in core.ARITHMETICS:
            start = time.perf_counter()
            runs[arithmetic] = core.run(name, result.gyr, result.acc, result.mag, args.rate, arithmetic,
                                        profile=result.profile)
            speed = len(result.t) / (time.perf_counter() - start)
            err = rmse(attitude_errors(runs[arithmetic].quat[settle:], result.quat_true[settle:]))
            entry[arithmetic] = {"rms_total_deg": err["total"], "rms_heading_deg": err["heading"],
                                 "rms_inclination_deg": err["inclination"],
                                 "saturations": runs[arithmetic].saturations, "samples_per_s": speed}
            if not args.json:
                print(f"{name:<6} {arithmetic:<6} {err['total']:8.3f} {err['heading']:8.3f} "
                      f"{err['inclination']:8.3f} {runs[arithmetic].saturations:5d} {speed:11.0f}")
        diff = angle_difference(runs["fixed"].quat, runs["float"].quat)
        entry.update(fixed_vs_float_max_deg=float(diff.max()), fixed_vs_float_mean_deg=float(diff.mean()))
        report["filters"].append(entry)
        if not args.json:
            print(f"{name:<6} fixed vs float: max {diff.max():.5f} deg, mean {diff.mean():.5f} deg")
    if args.json:
        print_json(report)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="run a simulated trajectory through every filter, fixed and float",
                       description="Simulate a trajectory with MEMS sensor errors, run each filter in the "
                                   "fixed-point build and its float twin, and print the accuracy against the "
                                   "simulated truth and the fixed-vs-float agreement.")
    p.add_argument("--scenario", default="random", choices=["static", "turntable", "random", "rests"],
                   help="trajectory (default: random)")
    p.add_argument("--duration", type=positive_float, default=300.0, help="seconds to simulate (default: 300)")
    p.add_argument("--rate", type=positive_float, default=100.0, help="sample rate in Hz (default: 100)")
    p.add_argument("--seed", type=seed_number, default=0, help="random seed (default: 0)")
    p.add_argument("--settle", type=non_negative_float, default=10.0,
                   help="seconds excluded from the error statistics (alignment and convergence, default: 10); "
                        "shorter than --duration")
    p.add_argument("--filters", default="all", help="comma-separated filter names (default: all)")
    json_argument(p, "the errors and the fixed-vs-float agreement")
    p.set_defaults(func=run)

