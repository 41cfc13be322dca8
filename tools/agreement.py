#!/usr/bin/env python3
"""Fixed-vs-float agreement benchmark of the imulink attitude filters.

For each filter, a simulated random-motion recording
(``imulink.sim.make_scenario("random", duration, 100, seed)``, default one hour)
runs through the fixed-point build and through its double-precision twin
(:func:`imulink.core.run`, default sensor profile, identical integer inputs). The
table reports the total rotation angle between the two builds' quaternions
(:func:`imulink.sim.quat.angle_between`) -- maximum, 99th percentile and mean, in
degrees -- and the fixed build's saturation count.

With ``--rates R1,R2,...`` it checks the requirement "fixed vs float <= 0.05 deg over
an hour of random motion at 30 Hz, 100 Hz, 1 kHz and 5 kHz": for each rate (and seed)
it simulates ``make_scenario("random", duration, rate, seed)`` at that rate and runs
every filter with its ``sample_rate`` setting equal to the rate (as
:func:`imulink.core.run` does), fixed and float side by side in chunks of
``--chunk`` samples (an hour at 5 kHz is 18 million samples), with progress on
stderr. The tables give, per filter and rate, the largest angle between the two
builds' quaternions (and its 99th percentile, mean, time, the fixed build's
saturation count) and a pass/fail against ``--limit`` (default 0.05 deg).

With ``--static SEEDS`` it instead runs the static check: for each seed a
``make_scenario("static", 120, 100, seed)`` recording through the fixed build, and
the roll / pitch / heading errors against the truth after t = 10 s (Euler angles
in the core's convention, :func:`imulink.analysis.attitude.quat_to_euler`): their standard
deviation and maximum absolute value, degrees.

Examples::

    .venv/bin/python tools/agreement.py --duration 3600 --seed 0
    .venv/bin/python tools/agreement.py --seed 0,1,2,3,4,5      # several seeds
    .venv/bin/python tools/agreement.py --static 0,1,2,3
    .venv/bin/python tools/agreement.py --rates 30,100,1000,5000 --duration 3600 --markdown
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

#: The requirement: largest fixed-vs-float angle, degrees.
LIMIT_DEG = 0.05
#: The rates the requirement names, Hz.
REQUIRED_RATES = (30.0, 100.0, 1000.0, 5000.0)
#: Samples per call into the core in the chunked runs.
DEFAULT_CHUNK = 1 << 20


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


def agreement_chunked(filter_name: str, scenario, settings: dict | None = None, chunk: int = DEFAULT_CHUNK,
                      progress=None) -> dict:
    """:func:`agreement` with bounded memory: both builds fed the scenario's counts
    `chunk` samples at a time (one :class:`imulink.core.Filter` each, state carried over,
    so the result is identical to one call). `progress(done, total)` is called after
    each chunk. Same keys as :func:`agreement`."""
    from imulink import core
    from imulink.sim.quat import angle_between

    rate = scenario.rate_hz
    fixed = core.Filter(filter_name, rate, "fixed", settings, scenario.profile)
    flt = core.Filter(filter_name, rate, "float", settings, scenario.profile)
    counts = (scenario.gyr_counts, scenario.acc_counts, scenario.mag_counts)
    n = counts[0].shape[0]
    d = np.empty(n)
    sat_fixed = sat_float = 0
    for start in range(0, n, chunk):
        part = [c[start:start + chunk] for c in counts]
        a = fixed.run_counts(*part)
        b = flt.run_counts(*part)
        d[start:start + len(part[0])] = np.rad2deg(angle_between(a.quat, b.quat))
        sat_fixed, sat_float = a.saturations, b.saturations
        if progress:
            progress(min(start + chunk, n), n)
    k = int(np.argmax(d))
    return {
        "max_deg": float(d[k]),
        "p99_deg": float(np.percentile(d, 99)),
        "mean_deg": float(np.mean(d)),
        "t_max_s": float(scenario.t[k]),
        "saturations_fixed": int(sat_fixed),
        "saturations_float": int(sat_float),
        "samples": int(n),
    }


def _rates(text: str) -> list[float]:
    try:
        rates = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"rates must be comma-separated numbers (Hz), not {text!r}") from None
    if not rates or any(r <= 0 for r in rates):
        raise argparse.ArgumentTypeError(f"rates must be positive, not {text!r}")
    return rates


def rate_sweep(filters, rates, seeds, duration_s: float, settings: dict | None = None, chunk: int = DEFAULT_CHUNK,
               log=None) -> list[dict]:
    """Fixed vs float for every rate x seed x filter on simulated random motion.

    One scenario per rate and seed (``make_scenario("random", duration_s, rate, seed)``),
    dropped before the next one. Returns a list of rows {filter, rate_hz, seed, ...
    :func:`agreement_chunked`'s keys, seconds}. `log(msg)` receives progress lines.
    """
    from imulink import sim

    settings = settings or {}
    rows = []
    for rate in rates:
        for seed in seeds:
            t0 = time.perf_counter()
            if log:
                log(f"simulating random motion: {duration_s:g} s at {rate:g} Hz, seed {seed} "
                    f"({int(round(duration_s * rate))} samples)")
            scenario = sim.make_scenario("random", duration_s, rate, seed)
            if log:
                log(f"  simulated in {time.perf_counter() - t0:.1f} s")
            for f in filters:
                t0 = time.perf_counter()
                last = [t0]

                def progress(done, total, f=f, t0=t0, last=last):
                    now = time.perf_counter()
                    if log and (done == total or now - last[0] >= 10.0):
                        last[0] = now
                        eta = (now - t0) * (total - done) / max(done, 1)
                        log(f"  {f} @ {rate:g} Hz seed {seed}: {done}/{total} samples "
                            f"({100.0 * done / total:.0f} %, {now - t0:.0f} s, ETA {eta:.0f} s)")

                r = agreement_chunked(f, scenario, settings.get(f), chunk, progress)
                r.update(filter=f, rate_hz=float(rate), seed=int(seed), seconds=time.perf_counter() - t0)
                rows.append(r)
                if log:
                    log(f"  {f} @ {rate:g} Hz seed {seed}: max {r['max_deg']:.4f} deg "
                        f"({r['seconds']:.1f} s)")
            del scenario
    rows.sort(key=lambda r: (filters.index(r["filter"]), rates.index(r["rate_hz"]), seeds.index(r["seed"])))
    return rows


def format_rates(rows, filters, rates, seeds, duration_s: float, limit: float = LIMIT_DEG,
                 markdown: bool = False) -> str:
    """The detailed table (one row per filter x rate x seed) and a filter x rate summary
    (max over seeds, pass/fail against `limit`)."""
    lines = []
    ok = all(r["max_deg"] <= limit for r in rows)
    worst = max(rows, key=lambda r: r["max_deg"])
    if markdown:
        lines.append("| filter | rate (Hz) | seed | max (deg) | 99th pct (deg) | mean (deg) | t of max (s) "
                     f"| saturations (fixed) | <= {limit:g} deg |")
        lines.append("|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            lines.append(f"| {r['filter'].upper()} | {r['rate_hz']:g} | {r['seed']} | {r['max_deg']:.4f} "
                         f"| {r['p99_deg']:.4f} | {r['mean_deg']:.5f} | {r['t_max_s']:.1f} | {r['saturations_fixed']} "
                         f"| {'yes' if r['max_deg'] <= limit else '**no**'} |")
        lines.append("")
        lines.append("| filter | " + " | ".join(f"{r:g} Hz" for r in rates) + " |")
        lines.append("|---|" + "---|" * len(rates))
        for f in filters:
            cells = []
            for rate in rates:
                m = max(r["max_deg"] for r in rows if r["filter"] == f and r["rate_hz"] == rate)
                cells.append(f"{m:.4f}" if m <= limit else f"**{m:.4f}**")
            lines.append(f"| {f.upper()} | " + " | ".join(cells) + " |")
        lines.append("")
        lines.append(f"Largest angle between the fixed and float quaternions (deg), random motion "
                     f"{duration_s:g} s per rate, seeds {','.join(str(s) for s in seeds)}, max over seeds; "
                     f"bold: above {limit:g} deg.")
    else:
        lines.append(f"fixed vs float, random motion {duration_s:g} s per rate, seeds {','.join(map(str, seeds))}")
        lines.append(f"{'filter':8s} {'rate Hz':>8s} {'seed':>4s} {'max deg':>9s} {'p99 deg':>9s} {'mean deg':>9s} "
                     f"{'t(max) s':>9s} {'sat fix':>8s} {'ok':>3s}")
        for r in rows:
            lines.append(f"{r['filter']:8s} {r['rate_hz']:8g} {r['seed']:4d} {r['max_deg']:9.4f} {r['p99_deg']:9.4f} "
                         f"{r['mean_deg']:9.5f} {r['t_max_s']:9.1f} {r['saturations_fixed']:8d} "
                         f"{'yes' if r['max_deg'] <= limit else 'NO':>3s}")
    lines.append("")
    lines.append(f"{'PASS' if ok else 'FAIL'}: largest fixed-vs-float angle {worst['max_deg']:.4f} deg "
                 f"({worst['filter'].upper()} at {worst['rate_hz']:g} Hz, seed {worst['seed']}) "
                 f"{'<=' if ok else '>'} {limit:g} deg")
    return "\n".join(lines)


def static_errors(filter_name: str, seed: int, settings: dict | None = None, arithmetic: str = "fixed",
                  duration_s: float = 120.0, skip_s: float = 10.0) -> dict:
    """Roll/pitch/heading errors (deg) of a filter on a simulated static recording, after `skip_s`."""
    from imulink import core, sim
    from imulink.analysis.attitude import quat_to_euler, wrap_deg

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
    p.add_argument("--rates", type=_rates, metavar="HZ", default=None,
                   help="instead: one simulation per comma-separated rate (the requirement's: "
                        f"{','.join(f'{r:g}' for r in REQUIRED_RATES)}), every filter's sample_rate set to it; "
                        "per filter and rate the largest fixed-vs-float angle")
    p.add_argument("--limit", type=float, default=LIMIT_DEG,
                   help=f"with --rates: the requirement in degrees (default {LIMIT_DEG:g}); exit status 1 above it")
    p.add_argument("--chunk", type=int, default=DEFAULT_CHUNK,
                   help=f"with --rates: samples per call into the core (default {DEFAULT_CHUNK})")
    p.add_argument("--json", action="store_true", help="with --rates: print the rows as JSON")
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

    if args.rates is not None:
        if args.chunk < 1:
            p.error("--chunk must be at least 1")
        t_start = time.perf_counter()
        try:
            rows = rate_sweep(filters, args.rates, args.seed, args.duration, settings, args.chunk,
                              log=lambda m: print(m, file=sys.stderr, flush=True))
        except core.SettingsError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(f"total {time.perf_counter() - t_start:.0f} s", file=sys.stderr, flush=True)
        if args.json:
            print(json.dumps({"limit_deg": args.limit, "duration_s": args.duration, "rows": rows}, indent=1))
        else:
            print(format_rates(rows, filters, args.rates, args.seed, args.duration, args.limit, args.markdown))
        return 0 if all(r["max_deg"] <= args.limit for r in rows) else 1

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
        print(f"{'filter':8s} {'seed':>4s} {'max deg':>9s} {'p99 deg':>9s} {'mean deg':>9s} {'t(max) s':>9s} "
              f"{'sat fix':>8s}")
        for f, seed, r in rows:
            print(f"{f:8s} {seed:4d} {r['max_deg']:9.4f} {r['p99_deg']:9.4f} {r['mean_deg']:9.5f} "
                  f"{r['t_max_s']:9.1f} {r['saturations_fixed']:8d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
