"""The `imulink` command line."""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from . import __version__


def _cmd_simulate(args) -> int:
    from . import core, sim
    from .analysis import angle_difference, attitude_errors, rmse

    filters = _parse_filters(args.filters)
    print(f"simulating {args.scenario!r}: {args.duration:g} s at {args.rate:g} Hz, seed {args.seed}", file=sys.stderr)
    result = sim.make_scenario(args.scenario, args.duration, args.rate, seed=args.seed)
    settle = min(int(args.settle * args.rate), len(result.t) - 1)
    print(f"samples: {len(result.t)}; errors are RMS after the first {args.settle:g} s, in degrees")
    header = f"{'filter':<6} {'arith':<6} {'total':>8} {'heading':>8} {'incl.':>8} {'sat':>5} {'samples/s':>11}"
    print(header)
    print("-" * len(header))
    for name in filters:
        runs = {}
        for arithmetic in core.ARITHMETICS:
            start = time.perf_counter()
            runs[arithmetic] = core.run(name, result.gyr, result.acc, result.mag, args.rate, arithmetic,
                                        profile=result.profile)
            speed = len(result.t) / (time.perf_counter() - start)
            err = rmse(attitude_errors(runs[arithmetic].quat[settle:], result.quat_true[settle:]))
            print(f"{name:<6} {arithmetic:<6} {err['total']:8.3f} {err['heading']:8.3f} {err['inclination']:8.3f} "
                  f"{runs[arithmetic].saturations:5d} {speed:11.0f}")
        diff = angle_difference(runs["fixed"].quat, runs["float"].quat)
        print(f"{name:<6} fixed vs float: max {diff.max():.5f} deg, mean {diff.mean():.5f} deg")
    return 0


def _cmd_filters(args) -> int:
    from . import core

    for name in _parse_filters(args.filters):
        print(f"{name}:")
        defaults = core.default_settings(name)
        for field in core.settings_fields(name):
            print(f"  {field.name:<12} {defaults[field.name]:<14.6g} {field.unit:<10} (fixed: Q{field.frac_bits})")
    return 0


def _parse_filters(text: str) -> list[str]:
    from . import core

    names = [n.strip() for n in text.split(",") if n.strip()] if text != "all" else list(core.FILTERS)
    unknown = [n for n in names if n not in core.FILTERS]
    if unknown:
        raise SystemExit(f"imulink: unknown filter(s) {', '.join(unknown)}; choose from {', '.join(core.FILTERS)}")
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="imulink",
        description="Hardware-in-the-loop companion for fixed-point MEMS attitude-estimation firmware.",
    )
    parser.add_argument("--version", action="version", version=f"imulink {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("simulate", help="run a simulated trajectory through every filter, fixed and float",
                       description="Simulate a trajectory with MEMS sensor errors, run each filter in the "
                                   "fixed-point build and its float twin, and print the accuracy against the "
                                   "simulated truth and the fixed-vs-float agreement.")
    p.add_argument("--scenario", default="random", choices=["static", "turntable", "random", "rests"],
                   help="trajectory (default: random)")
    p.add_argument("--duration", type=_positive_float, default=300.0, help="seconds to simulate (default: 300)")
    p.add_argument("--rate", type=_positive_float, default=100.0, help="sample rate in Hz (default: 100)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--settle", type=float, default=10.0, help="seconds excluded from the error statistics "
                                                               "(alignment and convergence, default: 10)")
    p.add_argument("--filters", default="all", help="comma-separated filter names (default: all)")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("filters", help="list the filters and their default settings",
                       description="List each filter's settings: default value, SI unit and fixed-point format.")
    p.add_argument("--filters", default="all", help="comma-separated filter names (default: all)")
    p.set_defaults(func=_cmd_filters)
    return parser


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive: {text!r}")
    return value


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
