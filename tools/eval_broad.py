#!/usr/bin/env python3
"""Evaluate the imulink attitude filters on the BROAD subset with the dataset's own metric.

For every trial (``*.mat`` in ``--data``) and every filter x arithmetic, the filter
runs on the recorded IMU data through :func:`imulink.core.run` (with
:data:`imulink.core.counts.BROAD_PROFILE`, so nothing saturates), and the error against
the optical reference is computed as the dataset README defines it:

* ``e = q_est ⊗ q_ref⁻¹`` (both w-first, sensor-to-earth, ENU), in the earth frame;
* total error ``2·acos|e_w|``, heading error ``2·atan|e_z/e_w|``,
  inclination error ``2·acos sqrt(e_w² + e_z²)``;
* RMSE over the samples where ``movement`` is true and the reference is not NaN,
  per trial, then the plain mean over the trials.

No alignment of any kind is fitted. Results go to stdout, progress to stderr.

With ``--vqf`` the same metric is computed for VQF (the ``vqf`` package, a maintained
reference implementation by the authors of BROAD, used for comparison only:
``VQF(1 / rate).updateBatch(gyr, acc, mag)["quat9D"]`` with its default parameters, on
the recordings' SI values as stored, not on register counts), and the report says
whether each selected filter's mean total RMSE beats VQF's. ``vqf`` is not a runtime
dependency of imulink: ``pip install 'imulink[bench]'`` installs it. ``--madgwick`` adds
Madgwick's MARG filter likewise (the ``ahrs`` package's ``Madgwick``, its default gain
0.041, earth frame north-west-up turned into ENU). The filter ``eskf9`` is the ESKF with
its accelerometer-bias states (``estimate_acc_bias`` 1). ``--means`` prints one markdown
table of the mean total, heading and inclination RMSE of every column.

Examples::

    .venv/bin/python tools/eval_broad.py
    .venv/bin/python tools/eval_broad.py --filters eecf --arithmetic float \\
        --settings '{"eecf": {"kp": 0.5}}'
    .venv/bin/python tools/eval_broad.py --markdown
    .venv/bin/python tools/eval_broad.py --markdown --vqf
    .venv/bin/python tools/eval_broad.py --json --vqf
    .venv/bin/python tools/eval_broad.py --means --vqf --madgwick --arithmetic fixed \
        --filters eecf,eskf,eskf9
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np

from imulink.analysis.attitude import attitude_errors, rmse
from imulink.core.counts import BROAD_PROFILE, si_to_counts
from imulink.io.broad import BroadError, BroadTrial, load_broad
from imulink.io.broad import data_dir as broad_data_dir

DEFAULT_DATA = broad_data_dir()

#: Exit code for a missing data directory, missing trial files or a file that is not a trial.
EXIT_NO_DATA = 2
#: Exit code for --vqf or --madgwick without its reference package.
EXIT_NO_REFERENCE = 3

#: The one-line message of --vqf without the vqf package.
VQF_MISSING = "error: --vqf needs the vqf package (a reference for comparison only): pip install 'imulink[bench]'"

#: Key of the VQF reference in the results of :func:`evaluate`.
VQF_KEY = ("vqf", "reference")
#: The one-line message of --madgwick without the ahrs package.
AHRS_MISSING = ("error: --madgwick needs the ahrs package (a reference for comparison only): "
                "pip install 'imulink[bench]'")
#: Key of the Madgwick reference in the results of :func:`evaluate`.
MADGWICK_KEY = ("madgwick", "reference")
#: Filters that are a core filter with settings of their own: name -> (core filter, settings).
VARIANTS = {"eskf9": ("eskf", {"estimate_acc_bias": 1})}

ERROR_KINDS = ("total", "heading", "inclination")


def load_trial(path) -> BroadTrial:
    """Load one BROAD trial (:func:`imulink.io.broad.load_broad`); BroadError when it lacks
    the optical reference or the movement mask the metric needs."""
    trial = load_broad(path)
    if trial.quat_ref is None or trial.movement is None:
        raise BroadError(f"{path} has no opt_quat or movement: the metric needs both")
    return trial


def trial_paths(data_dir) -> list[Path]:
    """Sorted .mat files of a BROAD directory; FileNotFoundError when there are none."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise FileNotFoundError(f"BROAD data directory not found: {data_dir}")
    paths = sorted(data_dir.glob("*.mat"))
    if not paths:
        raise FileNotFoundError(f"no BROAD trial files (*.mat) in {data_dir}")
    return paths


def load_trials(data_dir) -> list[BroadTrial]:
    """All trials of a BROAD directory, sorted by file name."""
    return [load_trial(p) for p in trial_paths(data_dir)]


def broad_errors(q_est, q_ref, movement) -> dict[str, float]:
    """RMSE (degrees) of the total, heading and inclination errors of one trial.

    Args:
        q_est: (N,4) estimate, w-first, sensor-to-earth ENU.
        q_ref: (N,4) reference in the same convention (NaN rows are skipped).
        movement: (N,) mask of the samples to evaluate.

    Returns:
        {"total": deg, "heading": deg, "inclination": deg, "n": samples used}.
    """
    q_ref = np.asarray(q_ref, dtype=np.float64)
    mask = np.asarray(movement).ravel().astype(bool) & np.all(np.isfinite(q_ref), axis=-1)
    out = rmse(attitude_errors(np.asarray(q_est)[mask], q_ref[mask]))
    out["n"] = int(mask.sum())
    return out


def fixed_float_difference(q_fixed, q_float) -> float:
    """Largest rotation angle (deg) between two (N,4) quaternion series (sign-invariant)."""
    from imulink.sim.quat import angle_between

    return float(np.rad2deg(np.max(angle_between(q_fixed, q_float))))


def _reference_class(module: str, name: str, missing: str):
    """`name` from the reference package `module`; ImportError with the install hint
    `missing` when the package is not installed."""
    try:
        return getattr(importlib.import_module(module), name)
    except ImportError as exc:
        raise ImportError(missing) from exc


def import_vqf():
    """The ``vqf.VQF`` class (ImportError with the install hint without vqf)."""
    return _reference_class("vqf", "VQF", VQF_MISSING)


def run_vqf(trial: BroadTrial):
    """VQF's 9D quaternion (w-first, sensor-to-earth ENU) on one trial, default parameters."""
    VQF = import_vqf()
    out = VQF(1.0 / trial.rate_hz).updateBatch(np.ascontiguousarray(trial.gyr, dtype=np.float64),
                                             np.ascontiguousarray(trial.acc, dtype=np.float64),
                                             np.ascontiguousarray(trial.mag, dtype=np.float64))
    return out["quat9D"]


def import_madgwick():
    """The ``ahrs.filters.Madgwick`` class (ImportError with the install hint without ahrs)."""
    return _reference_class("ahrs.filters", "Madgwick", AHRS_MISSING)


def run_madgwick(trial: BroadTrial):
    """Madgwick's MARG filter (the ahrs package, default gain) on one trial, w-first,
    sensor-to-earth ENU: its earth frame is north-west-up, a quarter turn about up from ENU."""
    from imulink.sim import quat

    Madgwick = import_madgwick()
    q_nwu = Madgwick(gyr=trial.gyr, acc=trial.acc, mag=trial.mag, frequency=trial.rate_hz).Q
    return quat.multiply(quat.from_axis_angle([0.0, 0.0, 1.0], np.pi / 2), q_nwu)


def _mean_errors(per) -> dict[str, float]:
    per = list(per)
    return {k: float(np.mean([e[k] for e in per])) for k in ERROR_KINDS}


def evaluate_reference(trials, run, label: str, log=None) -> dict:
    """The errors of a reference (`run(trial)`: its quaternions) on every trial:
    {"trials": {name: errors}, "mean": {...}}; `label` heads its progress lines."""
    out: dict = {"trials": {}}
    for trial in trials:
        t0 = time.perf_counter()
        err = broad_errors(run(trial), trial.quat_ref, trial.movement)
        out["trials"][trial.name] = err
        if log:
            log(f"{label} {trial.name:40s} total {err['total']:7.3f} deg ({time.perf_counter() - t0:.2f} s)")
    out["mean"] = _mean_errors(out["trials"].values())
    return out


def compare_with_vqf(results, filters, arithmetics) -> list[dict]:
    """Mean total RMSE of each filter x arithmetic against VQF's (needs results[VQF_KEY]).

    Returns one dict per column: filter, arithmetic, mean (deg), vqf (deg),
    difference (filter - VQF, deg), beats (filter's mean strictly below VQF's) and
    trials_better (trials where the filter's total RMSE is below VQF's).
    """
    ref = results[VQF_KEY]
    rows = []
    for f in filters:
        for a in arithmetics:
            r = results[(f, a)]
            mean, vqf_mean = r["mean"]["total"], ref["mean"]["total"]
            rows.append({
                "filter": f, "arithmetic": a, "mean": mean, "vqf": vqf_mean, "difference": mean - vqf_mean,
                "beats": bool(mean < vqf_mean),
                "trials_better": int(sum(r["trials"][n]["total"] < ref["trials"][n]["total"] for n in ref["trials"])),
                "trials": len(ref["trials"]),
            })
    return rows


def comparison_lines(results, filters, arithmetics) -> list[str]:
    """One sentence per filter x arithmetic: does its mean total RMSE beat VQF's? (ESKF fixed first.)"""
    rows = compare_with_vqf(results, filters, arithmetics)
    rows.sort(key=lambda r: (not (r["filter"] == "eskf" and r["arithmetic"] == "fixed"),))
    lines = []
    for r in rows:
        verdict = "beats" if r["beats"] else "does NOT beat"
        lines.append(f"{r['filter'].upper()} {r['arithmetic']} {verdict} VQF's mean: total RMSE {r['mean']:.2f} deg vs "
                     f"VQF {r['vqf']:.2f} deg ({r['difference']:+.2f} deg); better than VQF on "
                     f"{r['trials_better']} of {r['trials']} trials.")
    return lines


def run_filter(trial: BroadTrial, filter_name: str, arithmetic: str, settings: dict | None = None):
    """Run one filter on one trial with the BROAD register profile; returns a RunResult."""
    from imulink import core
    from imulink.core.counts import BROAD_PROFILE

    if filter_name in VARIANTS:
        filter_name, own = VARIANTS[filter_name]
        settings = {**own, **(settings or {})}
    return core.run(filter_name, trial.gyr, trial.acc, trial.mag, rate_hz=trial.rate_hz,
                    arithmetic=arithmetic, profile=BROAD_PROFILE, settings=settings)


def evaluate(trials, filters, arithmetics, settings=None, log=None, vqf: bool = False,
             madgwick: bool = False) -> dict:
    """Errors of every filter x arithmetic on every trial.

    Returns {(filter, arithmetic): {"trials": {name: errors}, "mean": {...}}} and, when
    both arithmetics ran, {(filter, "diff"): {name: max fixed-vs-float deg}}; with
    `vqf`, also {VQF_KEY: {"trials": ..., "mean": ...}} (ImportError without vqf), with
    `madgwick` {MADGWICK_KEY: ...} likewise.
    """
    if vqf:
        import_vqf()  # fail before the long part
    if madgwick:
        import_madgwick()
    settings = settings or {}
    results: dict = {}
    for f in filters:
        for arith in arithmetics:
            results[(f, arith)] = {"trials": {}, "saturations": {}}
        if len(arithmetics) == 2:
            results[(f, "diff")] = {}
        for trial in trials:
            quats = {}
            for arith in arithmetics:
                t0 = time.perf_counter()
                res = run_filter(trial, f, arith, settings.get(f))
                err = broad_errors(res.quat, trial.quat_ref, trial.movement)
                results[(f, arith)]["trials"][trial.name] = err
                results[(f, arith)]["saturations"][trial.name] = res.saturations
                quats[arith] = res.quat
                if log:
                    log(f"{f:5s} {arith:5s} {trial.name:40s} total {err['total']:7.3f} deg "
                        f"({time.perf_counter() - t0:.2f} s)")
            if len(arithmetics) == 2:
                results[(f, "diff")][trial.name] = fixed_float_difference(quats["fixed"], quats["float"])
        for arith in arithmetics:
            results[(f, arith)]["mean"] = _mean_errors(results[(f, arith)]["trials"].values())
    if vqf:
        results[VQF_KEY] = evaluate_reference(trials, run_vqf, "vqf   9D   ", log)
    if madgwick:
        results[MADGWICK_KEY] = evaluate_reference(trials, run_madgwick, "madgwick   ", log)
    return results


def format_means(results, filters, arithmetics) -> str:
    """One markdown row per filter x arithmetic and reference: mean total, heading and
    inclination RMSE over the trials (deg)."""
    names = {VQF_KEY: "VQF 2.1.2 (reference)", MADGWICK_KEY: "Madgwick, ahrs 0.4.0 (reference)"}
    keys = [(f, a) for f in filters for a in arithmetics] + [k for k in names if k in results]
    lines = ["| estimator | total | heading | inclination |", "|---|---|---|---|"]
    for key in keys:
        m = results[key]["mean"]
        label = names.get(key, f"{key[0].upper()} {key[1]}")
        lines.append(f"| {label} | {m['total']:.3f} | {m['heading']:.3f} | {m['inclination']:.3f} |")
    lines.append("")
    lines.append(f"Mean over {len(results[keys[0]]['trials'])} trials of the RMSE (deg) over the movement phase.")
    return "\n".join(lines)


def mean_total_rmse(trials, filter_name, arithmetic="float", settings=None) -> float:
    """Mean over trials of the total-error RMSE (deg): the tuning objective."""
    return float(np.mean([
        broad_errors(run_filter(t, filter_name, arithmetic, settings).quat, t.quat_ref, t.movement)["total"]
        for t in trials
    ]))



def format_text(results, trials, filters, arithmetics) -> str:
    lines = []
    names = [t.name for t in trials]
    width = max(len(n) for n in names + ["mean"])
    for f in filters:
        for arith in arithmetics:
            r = results[(f, arith)]
            lines.append(f"{f} ({arith}) RMSE, deg")
            hdr = f"  {'trial':{width}s}  {'total':>8s} {'heading':>8s} {'inclin.':>8s} {'samples':>8s} {'sat':>5s}"
            if len(arithmetics) == 2:
                hdr += f" {'fix-flt max':>12s}"
            lines.append(hdr)
            for n in names:
                e = r["trials"][n]
                row = (f"  {n:{width}s}  {e['total']:8.3f} {e['heading']:8.3f} {e['inclination']:8.3f}"
                       f" {e['n']:8d} {r['saturations'][n]:5d}")
                if len(arithmetics) == 2:
                    row += f" {results[(f, 'diff')][n]:12.4f}"
                lines.append(row)
            m = r["mean"]
            lines.append(f"  {'mean':{width}s}  {m['total']:8.3f} {m['heading']:8.3f} {m['inclination']:8.3f}")
            lines.append("")
    if VQF_KEY in results:
        r = results[VQF_KEY]
        lines.append("VQF (reference, vqf package, default parameters, quat9D) RMSE, deg")
        lines.append(f"  {'trial':{width}s}  {'total':>8s} {'heading':>8s} {'inclin.':>8s} {'samples':>8s}")
        for n in names:
            e = r["trials"][n]
            lines.append(f"  {n:{width}s}  {e['total']:8.3f} {e['heading']:8.3f} {e['inclination']:8.3f} {e['n']:8d}")
        m = r["mean"]
        lines.append(f"  {'mean':{width}s}  {m['total']:8.3f} {m['heading']:8.3f} {m['inclination']:8.3f}")
        lines.append("")
        lines.extend(comparison_lines(results, filters, arithmetics))
    return "\n".join(lines)


def format_markdown(results, trials, filters, arithmetics) -> str:
    cols = [(f, a) for f in filters for a in arithmetics]
    has_vqf = VQF_KEY in results
    head = "| trial | " + " | ".join(f"{f.upper()} {a} total / heading / incl." for f, a in cols)
    if has_vqf:
        cols = cols + [VQF_KEY]
        head += " | VQF (reference) total / heading / incl."
    sep = "|---|" + "---|" * len(cols)
    diff_cols = [f for f in filters if (f, "diff") in results]
    if diff_cols:
        head += " | " + " | ".join(f"{f.upper()} fixed-vs-float max" for f in diff_cols)
        sep += "---|" * len(diff_cols)
    lines = [head + " |", sep]

    def cell(e):
        return f"{e['total']:.2f} / {e['heading']:.2f} / {e['inclination']:.2f}"

    for t in trials:
        row = f"| {t.name} | " + " | ".join(cell(results[c]["trials"][t.name]) for c in cols)
        if diff_cols:
            row += " | " + " | ".join(f"{results[(f, 'diff')][t.name]:.4f}" for f in diff_cols)
        lines.append(row + " |")
    row = "| **mean** | " + " | ".join(f"**{cell(results[c]['mean'])}**" for c in cols)
    if diff_cols:
        row += " | " + " | ".join(f"{max(results[(f, 'diff')].values()):.4f} (max)" for f in diff_cols)
    lines.append(row + " |")
    lines.append("")
    note = ("RMSE in degrees over the movement phase (NaN reference samples skipped); "
            "fixed-vs-float: largest angle between the two builds' quaternions over the whole trial, deg.")
    if has_vqf:
        note += (" VQF: the vqf package's VQF(1/rate).updateBatch(gyr, acc, mag)['quat9D'], default parameters, "
                 "on the recordings' SI values.")
    lines.append(note)
    if has_vqf:
        lines.append("")
        lines.extend(comparison_lines(results, filters, [a for a in arithmetics]))
    return "\n".join(lines)


def csv_choice(value: str, allowed, what: str) -> list[str]:
    """argparse type: a comma-separated list whose items are all in `allowed`."""
    items = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        raise argparse.ArgumentTypeError(f"unknown {what} {bad or value!r}; choose from {', '.join(allowed)}")
    return items


def main(argv=None) -> int:
    from imulink import core

    p = argparse.ArgumentParser(
        description="RMSE of the imulink filters on the BROAD subset (the dataset's own metric).")
    p.add_argument("--data", type=Path, default=DEFAULT_DATA,
                   help="directory with the BROAD .mat files (default: $IMULINK_BROAD_DIR, else "
                        "shared/data/broad beside the repository)")
    p.add_argument("--filters", default=",".join(core.FILTERS),
                   type=lambda v: csv_choice(v, [*core.FILTERS, *VARIANTS], "filter"),
                   help=f"comma-separated filters (default: {','.join(core.FILTERS)}; eskf9: the ESKF with "
                        "its accelerometer-bias states)")
    p.add_argument("--arithmetic", default="fixed,float",
                   type=lambda v: csv_choice(v, list(core.ARITHMETICS), "arithmetic"),
                   help="comma-separated arithmetics: fixed, float (default: fixed,float)")
    p.add_argument("--settings", default=None,
                   help='JSON settings overrides per filter, e.g. \'{"eecf": {"kp": 0.5}}\'')
    p.add_argument("--markdown", action="store_true", help="print a markdown table instead of text")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--vqf", action="store_true",
                   help="add VQF (the vqf package, default parameters) as a reference column; "
                        "needs pip install 'imulink[bench]'")
    p.add_argument("--madgwick", action="store_true",
                   help="add Madgwick's MARG filter (the ahrs package, default gain) as a reference column; "
                        "needs pip install 'imulink[bench]'")
    p.add_argument("--means", action="store_true",
                   help="print one markdown table of the mean total, heading and inclination RMSE")
    args = p.parse_args(argv)

    for wanted, import_reference in ((args.vqf, import_vqf), (args.madgwick, import_madgwick)):
        try:
            if wanted:
                import_reference()
        except ImportError as exc:
            print(exc, file=sys.stderr)
            return EXIT_NO_REFERENCE

    settings = {}
    if args.settings:
        try:
            settings = json.loads(args.settings)
        except json.JSONDecodeError as exc:
            p.error(f"--settings is not valid JSON: {exc}")
        if not isinstance(settings, dict) or not all(isinstance(v, dict) for v in settings.values()):
            p.error('--settings must be an object of objects, e.g. {"eecf": {"kp": 0.5}}')
        unknown = sorted(set(settings) - {*core.FILTERS, *VARIANTS})
        if unknown:
            p.error(f"--settings names unknown filters {unknown}")

    try:
        paths = trial_paths(args.data)
    except FileNotFoundError as exc:
        print(f"error: {exc}\n(pass the BROAD subset directory with --data DIR)", file=sys.stderr)
        return EXIT_NO_DATA

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    log(f"loading {len(paths)} trials from {args.data.resolve()}")
    try:
        trials = [load_trial(x) for x in paths]
    except BroadError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_NO_DATA
    for trial in trials:
        clipped = si_to_counts(trial.gyr, trial.acc, trial.mag, BROAD_PROFILE, return_saturation=True)[3]
        log(f"{trial.name}: sensor values clipped by {BROAD_PROFILE.name}: {clipped}")
    try:
        results = evaluate(trials, args.filters, args.arithmetic, settings, log, vqf=args.vqf,
                           madgwick=args.madgwick)
    except core.SettingsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2  # a usage error, like argparse's
    if args.json:
        out = {f"{k[0]}/{k[1]}": v for k, v in results.items()}
        if args.vqf:
            out["comparison_with_vqf"] = compare_with_vqf(results, args.filters, args.arithmetic)
        print(json.dumps(out, indent=1))
    elif args.means:
        print(format_means(results, args.filters, args.arithmetic))
    elif args.markdown:
        print(format_markdown(results, trials, args.filters, args.arithmetic))
    else:
        print(format_text(results, trials, args.filters, args.arithmetic))
    return 0


if __name__ == "__main__":
    sys.exit(main())
