#!/usr/bin/env python3
"""Fixed-vs-float agreement benchmark of the imulink attitude filters.

For each filter, a simulated random-motion recording
(``imulink.sim.make_scenario("random", duration, 100, seed)``, default one hour)
runs through the fixed-point build and through its double-precision twin
(:func:`imulink.core.run`, default sensor profile, identical integer inputs). The
table reports the total rotation angle between the two builds' quaternions
(:func:`imulink.sim.quat.angle_between`) -- maximum, 99th percentile and mean, in
degrees -- and the fixed build's saturation count.

With ``--static SEEDS`` it instead runs the static check: for each seed a
``make_scenario("static", 120, 100, seed)`` recording through the fixed build, and
the roll / pitch / heading errors against the truth after t = 10 s (Euler angles
in the core's convention, :func:`imulink.analysis.quat_to_euler`): their standard
deviation and maximum absolute value, degrees.

Examples::

    .venv/bin/python tools/agreement.py --duration 3600 --seed 0
    .venv/bin/python tools/agreement.py --seed 0,1,2,3,4,5      # several seeds
    .venv/bin/python tools/agreement.py --static 0,1,2,3
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


def static_errors(filter_name: str, seed: int, settings: dict | None = None, arithmetic: str = "fixed",
                  duration_s: float = 120.0, skip_s: float = 10.0) -> dict:
    """Roll/pitch/heading errors (deg) of a filter on a simulated static recording, after `skip_s`."""
    from imulink import core, sim
    from imulink.analysis import quat_to_euler, wrap_deg

    data = sim.make_scenario("static", duration_s, 100, seed)
    out = core.run(filter_name, data.gyr, data.acc, data.mag, rate_hz=data.rate_hz, arithmetic=arithmetic,
                   settings=settings)
    keep = data.t >= skip_s
    est = np.degrees(quat_to_euler(out.quat[keep]))
    ref = np.degrees(quat_to_euler(data.quat_true[keep]))
    err = wrap_deg(est - ref)  # columns: roll, pitch, heading
    return {"std": np.std(err, axis=0), "max": np.max(np.abs(err), axis=0), "mean": np.mean(err, axis=0)}


def _seeds(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"seeds must be comma-separated integers, not {text!r}") from None


def main_static(filters, seeds, settings, markdown) -> int:
    rows = []
    for f in filters:
        per = [static_errors(f, s, settings.get(f)) for s in seeds]
        rows.append((f, per))
    cols = ("roll", "pitch", "heading")
    if markdown:
        print("| filter | seed | std roll / pitch / heading (deg) | max abs roll / pitch / heading (deg) |")
        print("|---|---|---|---|")
    else:
        print(f"static 120 s @ 100 Hz, fixed build, errors after 10 s (deg); columns {'/'.join(cols)}")
    for f, per in rows:
        for s, r in zip(seeds, per):
            std = " / ".join(f"{v:.3f}" for v in r["std"])
            mx = " / ".join(f"{v:.3f}" for v in r["max"])
            print(f"| {f.upper()} | {s} | {std} | {mx} |" if markdown else f"{f:6s} seed {s:3d}  std {std}   max {mx}")
        std = " / ".join(f"{v:.3f}" for v in np.mean([r["std"] for r in per], axis=0))
        mx = " / ".join(f"{v:.3f}" for v in np.max([r["max"] for r in per], axis=0))
        print(f"| {f.upper()} | mean std, max of max | **{std}** | **{mx}** |" if markdown
              else f"{f:6s} all       std {std}   max {mx}  (mean std, max of max)")
    return 0


def main(argv=None) -> int:
    from imulink import core, sim

    p = argparse.ArgumentParser(description="Fixed-point vs float-twin agreement on a simulated random motion.")
    p.add_argument("--duration", type=float, default=3600.0, help="simulated duration in s (default 3600)")
    p.add_argument("--seed", type=_seeds, default=[0],
                   help="seed of the trajectory and sensor noise, or a comma-separated list (default 0)")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate in Hz (default 100)")
    p.add_argument("--filters", default=",".join(core.FILTERS),
                   help=f"comma-separated filters (default: {','.join(core.FILTERS)})")
    p.add_argument("--settings", default=None,
                   help='JSON settings overrides per filter, e.g. \'{"kf1d": {"q_angle": 1e-4}}\'')
    p.add_argument("--markdown", action="store_true", help="print a markdown table")
    p.add_argument("--static", type=_seeds, metavar="SEEDS", default=None,
                   help="instead: static-scenario roll/pitch/heading errors for these comma-separated seeds")
    args = p.parse_args(argv)

    filters = [f.strip() for f in args.filters.split(",") if f.strip()]
    bad = [f for f in filters if f not in core.FILTERS]
    if bad or not filters:
        p.error(f"unknown filters {bad}; choose from {', '.join(core.FILTERS)}")
    try:
        settings = json.loads(args.settings) if args.settings else {}
    except json.JSONDecodeError as exc:
        p.error(f"--settings is not valid JSON: {exc}")
    if not isinstance(settings, dict) or not all(isinstance(v, dict) for v in settings.values()):
        p.error('--settings must be an object of objects, e.g. {"kf1d": {"q_angle": 1e-4}}')

    if args.static is not None:
        return main_static(filters, args.static, settings, args.markdown)

    rows = []
    for seed in args.seed:
        t0 = time.perf_counter()
        print(f"simulating random motion: {args.duration:g} s at {args.rate:g} Hz, seed {seed}",
              file=sys.stderr, flush=True)
        scenario = sim.make_scenario("random", args.duration, args.rate, seed)
        print(f"  done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        for f in filters:
            t0 = time.perf_counter()
            r = agreement(f, scenario, settings.get(f))
            print(f"  {f}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
            rows.append((f, seed, r))
    rows.sort(key=lambda x: filters.index(x[0]))

    if args.markdown:
        print("| filter | seed | max (deg) | 99th pct (deg) | mean (deg) | t of max (s) | saturations (fixed) |")
        print("|---|---|---|---|---|---|---|")
        for f, seed, r in rows:
            print(f"| {f.upper()} | {seed} | {r['max_deg']:.4f} | {r['p99_deg']:.4f} | {r['mean_deg']:.5f} "
                  f"| {r['t_max_s']:.1f} | {r['saturations_fixed']} |")
    else:
        print(f"fixed vs float, random motion {args.duration:g} s @ {args.rate:g} Hz")
        print(f"{'filter':8s} {'seed':>4s} {'max deg':>9s} {'p99 deg':>9s} {'mean deg':>9s} {'t(max) s':>9s} {'sat fix':>8s}")
        for f, seed, r in rows:
            print(f"{f:8s} {seed:4d} {r['max_deg']:9.4f} {r['p99_deg']:9.4f} {r['mean_deg']:9.5f} "
                  f"{r['t_max_s']:9.1f} {r['saturations_fixed']:8d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
