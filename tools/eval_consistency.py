#!/usr/bin/env python3
"""Covariance consistency of the ESKF: normalised estimation error squared (NEES).

For each scenario, N Monte-Carlo runs (seeds) of the simulator feed the ESKF
(:class:`imulink.core.Filter`, fixed build by default); every ``--every`` seconds, at
the end of a filter step (the ESKF fuses groups of three samples, so the check
happens right after a step, where the output attitude is the filtered one), the
tool reads the estimate and the error-state covariance
(:meth:`imulink.core.Filter.covariance`: rad, rad/s, g) and forms the true error in
the filter's own error convention (``firmware/core/imu_eskf.h``):

* attitude: ``dtheta`` with ``true = estimate (x) exp(dtheta)``, sensor frame, rad;
* gyro bias: ``b_true - b_estimate``, rad/s;
* accelerometer bias (with ``--acc-bias``): ``(b_true - b_estimate) / g``, in g.

The NEES of a group with d states is ``e^T P_gg^-1 e`` (the marginal covariance of
the group); the attitude is also split into tilt (2 dof: the part perpendicular to
the estimated vertical) and heading (1 dof: the component along it). For a
consistent filter each run's NEES is chi-square with d degrees of freedom, so the
average over N runs, times N, is chi-square with N d: the two-sided 95 % bounds of
the average are ``chi2.ppf(0.025, N d) / N`` and ``chi2.ppf(0.975, N d) / N``. The
table gives, per scenario and group, the mean over time of the run-averaged NEES
(consistent: about d), the fraction of the time it lies inside the bounds (about 95 %
for a consistent filter) and the fractions below the lower bound (covariance too
large: conservative) and above the upper one (covariance too small: overconfident).
Statistics are over t >= ``--skip`` seconds (default 10 s: the start-up alignment,
whose errors are far smaller than the filter's prior, and the magnetometer's
dip-learning phase).

Scenarios (default sensors of the simulator, magnetometer free of disturbances,
filter settings :data:`imulink.analysis.scenarios.SIM_SETTINGS` as ``tools/eval_sim.py`` uses):

* ``static``: at rest;
* ``slow``: slow random rotation (:func:`imulink.sim.random_motion` with
  ``max_rate_dps=30``, ``bandwidth_hz=0.2``, no linear acceleration: the
  accelerometer measures gravity plus noise, as the filter's model assumes);
* ``static-nomag`` and ``slow-nomag``: the same without a magnetometer (the core is
  fed zero field: no heading updates, initial heading 0, i.e. north).

To make the Monte-Carlo runs samples of the filter's prior, every run draws the
truth's turn-on gyro bias from N(0, init_gyro_bias_std^2) per axis (and, with
``--acc-bias``, the accelerometer bias from N(0, init_acc_bias_std^2)); without a
magnetometer, where the core starts at heading 0, the truth's initial heading is
drawn from N(0, init_attitude_std^2).

``--matched`` removes the remaining differences between the simulated sensors and
the filter's model: an isotropic gyroscope (the settings' mean ARW and RRW on every
axis) without the Gauss-Markov bias instability the filter does not model, and
``acc_noise`` / ``mag_noise`` set to the noise of the three-sample average the
filter actually fuses (per-sample noise / sqrt(3)), and ``gyro_scale_std`` 0: the
simulated gyroscope has no scale error.

Examples::

    .venv/bin/python tools/eval_consistency.py --markdown
    .venv/bin/python tools/eval_consistency.py --markdown --matched
    .venv/bin/python tools/eval_consistency.py --runs 50 --arithmetic fixed,float --png nees.png
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_broad import csv_choice  # noqa: E402  (a sibling script: its argparse list type)

#: Scenario names, in table order.
SCENARIOS = ("static", "slow", "static-nomag", "slow-nomag")

#: Slow random rotation: soft limit on the rate (deg/s) and corner frequency (Hz).
SLOW_MAX_RATE_DPS = 30.0
SLOW_BANDWIDTH_HZ = 0.2

#: Two-sided confidence level of the chi-square bounds.
LEVEL = 0.95


def chi2_bounds(dof: int, runs: int, level: float = LEVEL) -> tuple[float, float]:
    """Two-sided `level` bounds of the average of `runs` independent chi-square(dof) values.

    ``runs * average`` is chi-square with ``runs * dof`` degrees of freedom, so the
    bounds are ``chi2.ppf((1 -+ level) / 2, runs * dof) / runs``.
    """
    from scipy.stats import chi2

    alpha = 1.0 - level
    n = runs * dof
    return float(chi2.ppf(alpha / 2.0, n) / runs), float(chi2.ppf(1.0 - alpha / 2.0, n) / runs)


def error_rotvec(q_est, q_true) -> np.ndarray:
    """(..., 3) rotation vector dtheta with ``q_true = q_est (x) exp(dtheta)`` (sensor frame, rad)."""
    from imulink.sim import quat as Q

    d = Q.multiply(Q.conjugate(q_est), q_true)
    d = d * np.where(d[..., :1] < 0, -1.0, 1.0)  # shortest rotation
    v = d[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, d[..., :1])
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(s > 1e-15, angle / np.where(s > 0, s, 1.0), 2.0)
    return v * scale


def nees(err, cov) -> np.ndarray:
    """e^T P^-1 e for (T, d) errors and (T, d, d) covariances."""
    err = np.asarray(err, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    sol = np.linalg.solve(cov, err[..., None])[..., 0]
    return np.einsum("...i,...i->...", err, sol)


def _perpendicular_basis(up) -> np.ndarray:
    """(T, 3, 2) orthonormal bases of the planes perpendicular to (T, 3) unit vectors."""
    up = np.asarray(up, dtype=np.float64)
    helper = np.where(np.abs(up[:, :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(up, e1)
    return np.stack([e1, e2], axis=-1)


def group_nees(att_err, bias_err, cov, up, acc_err=None) -> dict[str, np.ndarray]:
    """NEES time series of every state group of one run.

    Args:
        att_err: (T, 3) attitude errors dtheta (rad, sensor frame).
        bias_err: (T, 3) gyro bias errors (rad/s).
        cov: (T, n, n) error-state covariances (n = 6 or 9).
        up: (T, 3) estimated vertical in the sensor frame (unit).
        acc_err: (T, 3) accelerometer bias errors (g), when n = 9.

    Returns:
        {"attitude", "tilt", "heading", "gyro_bias"[, "acc_bias"]: (T,) arrays}.
    """
    cov = np.asarray(cov, dtype=np.float64)
    p_att = cov[:, 0:3, 0:3]
    out = {"attitude": nees(att_err, p_att)}
    b = _perpendicular_basis(up)
    tilt = np.einsum("tik,ti->tk", b, att_err)
    p_tilt = np.einsum("tik,tij,tjl->tkl", b, p_att, b)
    out["tilt"] = nees(tilt, p_tilt)
    h = np.einsum("ti,ti->t", up, att_err)
    var_h = np.einsum("ti,tij,tj->t", up, p_att, up)
    out["heading"] = h**2 / var_h
    out["gyro_bias"] = nees(bias_err, cov[:, 3:6, 3:6])
    if acc_err is not None:
        out["acc_bias"] = nees(acc_err, cov[:, 6:9, 6:9])
    return out


#: Degrees of freedom of each group, in table order.
GROUP_DOF = {"attitude": 3, "tilt": 2, "heading": 1, "gyro_bias": 3, "acc_bias": 3}


@dataclass
class Config:
    """One consistency experiment (shared by all its scenarios and runs)."""

    duration_s: float = 300.0
    rate_hz: float = 100.0
    runs: int = 20
    every_s: float = 0.3
    skip_s: float = 10.0
    first_seed: int = 1
    arithmetic: str = "fixed"
    acc_bias: bool = False
    matched: bool = False
    settings: dict | None = None  # overrides on top of the scenario settings

    def filter_settings(self) -> dict:
        """ESKF settings: SIM_SETTINGS, the --matched noise, --acc-bias, then the overrides."""
        from imulink.analysis import scenarios

        s = dict(scenarios.SIM_SETTINGS["eskf"])
        if self.matched:
            s["acc_noise"] = s["acc_noise"] / np.sqrt(3.0)
            s["mag_noise"] = s["mag_noise"] / np.sqrt(3.0)
            s["gyro_scale_std"] = 0.0
        if self.acc_bias:
            s["estimate_acc_bias"] = 1.0
        s.update(self.settings or {})
        return s


def simulate_run(scenario: str, seed: int, cfg: Config, settings: dict):
    """Simulated readings of one run (:class:`imulink.sim.SimResult`) and the true accelerometer bias (m/s^2)."""
    from imulink import core, sim
    from imulink.analysis.attitude import quat_to_euler
    from imulink.sim import quat as Q

    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; choose from {', '.join(SCENARIOS)}")
    values = core.resolve_settings("eskf", cfg.rate_hz, settings)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))
    gyro_bias = rng.standard_normal(3) * values["init_gyro_bias_std"]
    acc_bias = rng.standard_normal(3) * values["init_acc_bias_std"] if cfg.acc_bias else np.zeros(3)
    heading = rng.standard_normal() * values["init_attitude_std"]
    nomag = scenario.endswith("-nomag")
    initial = sim.DEFAULT_INITIAL
    if nomag:
        # Without a field the core starts at heading 0: the truth starts at `heading`
        # (a draw from the prior), the same tilt as the default attitude.
        h0 = quat_to_euler(initial)[2]
        initial = Q.multiply(Q.from_axis_angle([0.0, 0.0, 1.0], h0 - heading), initial)
    if scenario.startswith("static"):
        traj = sim.static(cfg.duration_s, cfg.rate_hz, initial=initial)
    else:
        traj = sim.random_motion(cfg.duration_s, cfg.rate_hz, seed=seed, max_rate_dps=SLOW_MAX_RATE_DPS,
                                 bandwidth_hz=SLOW_BANDWIDTH_HZ, accel_std=0.0, initial=initial)
    suite = sim.SensorSuite.default()
    gyro = sim.GyroModel.seed000(bias_dps=np.degrees(gyro_bias))
    if cfg.matched:
        gyro = sim.GyroModel(arw=float(np.mean(gyro.arw)), bias_instability=0.0, rrw=float(np.mean(gyro.rrw)),
                             bias=gyro.bias)
    suite.gyro = gyro
    suite.acc = sim.AccModel(noise_std=suite.acc.noise_std, bias=acc_bias)
    data = sim.simulate(traj, suite, seed=seed)
    if nomag:
        data.mag_counts = np.zeros_like(data.mag_counts)
        data.mag = np.zeros_like(data.mag)
    return data, acc_bias


def run_once(scenario: str, seed: int, cfg: Config) -> dict:
    """One Monte-Carlo run: times (s) and the NEES series of every group."""
    from imulink import core
    from imulink.sim import quat as Q

    settings = cfg.filter_settings()
    data, acc_bias_true = simulate_run(scenario, seed, cfg, settings)
    filt = core.Filter("eskf", cfg.rate_hz, cfg.arithmetic, settings, data.profile)
    gravity = filt.settings["gravity"]
    n = len(data)
    step = 3 * max(1, int(round(cfg.every_s * cfg.rate_hz / 3.0)))
    # Sample 0 initialises; samples 3k end the filter steps.
    idx = np.arange(step, n, step)
    q_est = np.empty((len(idx), 4))
    b_est = np.empty((len(idx), 3))
    a_est = np.empty((len(idx), 3))
    covs = []
    start = 0
    counts = (data.gyr_counts, data.acc_counts, data.mag_counts)
    for j, k in enumerate(idx):
        res = filt.run_counts(*(c[start:k + 1] for c in counts))
        start = k + 1
        q_est[j] = res.quat[-1]
        b_est[j] = res.gyro_bias[-1]
        covs.append(filt.covariance())
        if cfg.acc_bias:
            a_est[j] = filt.acc_bias()
    cov = np.array(covs)
    q_est = Q.normalize(q_est)
    att = error_rotvec(q_est, data.quat_true[idx])
    bias = data.gyro_bias_true[idx] - b_est
    up = Q.rotate_inverse(q_est, np.array([0.0, 0.0, 1.0]))
    acc = (acc_bias_true[None, :] - a_est) / gravity if cfg.acc_bias else None
    out = group_nees(att, bias, cov, up, acc)
    return {"t": data.t[idx], "nees": out, "saturations": res.saturations}


def evaluate(scenarios, cfg: Config, log=None) -> dict:
    """Run-averaged NEES of every scenario and its statistics (see the module doc)."""
    results = {}
    for scenario in scenarios:
        t0 = time.perf_counter()
        runs = []
        for i in range(cfg.runs):
            runs.append(run_once(scenario, cfg.first_seed + i, cfg))
        t = runs[0]["t"]
        keep = t >= cfg.skip_s
        groups = {}
        for g in runs[0]["nees"]:
            series = np.array([r["nees"][g] for r in runs])  # (runs, T)
            avg = series.mean(axis=0)
            lo, hi = chi2_bounds(GROUP_DOF[g], cfg.runs)
            a = avg[keep]
            groups[g] = {
                "dof": GROUP_DOF[g],
                "mean": float(np.mean(a)),
                "median": float(np.median(a)),
                "lower": lo,
                "upper": hi,
                "inside": float(np.mean((a >= lo) & (a <= hi))),
                "below": float(np.mean(a < lo)),
                "above": float(np.mean(a > hi)),
                "average": avg,
            }
        sat = max(r["saturations"] for r in runs)
        results[scenario] = {"t": t, "groups": groups, "saturations": int(sat),
                             "seconds": time.perf_counter() - t0}
        if log:
            summary = ", ".join(f"{g} {v['mean']:.2f}/{v['dof']}" for g, v in groups.items())
            log(f"{scenario:13s} {cfg.runs} runs, {time.perf_counter() - t0:.1f} s: mean NEES {summary}")
    return results


def verdict(stats: dict) -> str:
    """'consistent' when at least 90 % of the time is inside the 95 % bounds, otherwise
    the direction of the larger excursion."""
    if stats["inside"] >= 0.9:
        return "consistent"
    if stats["above"] > stats["below"]:
        return "overconfident (P too small)"
    return "conservative (P too large)"


def format_markdown(results, cfg: Config) -> str:
    lines = [
        "| scenario | group (dof) | mean NEES | mean NEES / dof | 95 % bounds of the mean of "
        f"{cfg.runs} | time inside | below (P too large) | above (P too small) | verdict |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for scenario, r in results.items():
        for g, s in r["groups"].items():
            lines.append(f"| {scenario} | {g.replace('_', ' ')} ({s['dof']}) | {s['mean']:.2f} | "
                         f"{s['mean'] / s['dof']:.2f} | {s['lower']:.2f} .. {s['upper']:.2f} | "
                         f"{100 * s['inside']:.0f} % | {100 * s['below']:.0f} % | {100 * s['above']:.0f} % | "
                         f"{verdict(s)} |")
    lines.append("")
    lines.append(_caption(cfg))
    return "\n".join(lines)


def _caption(cfg: Config) -> str:
    return (f"ESKF {cfg.arithmetic} build, {cfg.runs} Monte-Carlo runs (seeds {cfg.first_seed}.."
            f"{cfg.first_seed + cfg.runs - 1}) of {cfg.duration_s:g} s at {cfg.rate_hz:g} Hz, NEES every "
            f"{cfg.every_s:g} s after t = {cfg.skip_s:g} s; settings SIM_SETTINGS"
            f"{' with --matched noise' if cfg.matched else ''}{', acc bias estimated' if cfg.acc_bias else ''}"
            f"{' + ' + json.dumps(cfg.settings) if cfg.settings else ''}. Mean NEES: time average of the "
            f"run-averaged NEES (consistent: = dof); time inside: fraction of the evaluation times where "
            f"the run-averaged NEES lies within the two-sided 95 % chi-square bounds (consistent: about 95 %).")


def format_text(results, cfg: Config) -> str:
    lines = [_caption(cfg), ""]
    lines.append(f"{'scenario':13s} {'group':10s} {'dof':>3s} {'mean':>8s} {'mean/dof':>8s} {'bounds':>14s} "
                 f"{'inside':>7s} {'below':>6s} {'above':>6s}  verdict")
    for scenario, r in results.items():
        for g, s in r["groups"].items():
            lines.append(f"{scenario:13s} {g:10s} {s['dof']:3d} {s['mean']:8.2f} {s['mean'] / s['dof']:8.2f} "
                         f"{s['lower']:6.2f}..{s['upper']:6.2f} {100 * s['inside']:6.0f}% {100 * s['below']:5.0f}% "
                         f"{100 * s['above']:5.0f}%  {verdict(s)}")
    return "\n".join(lines)


def to_json(results, cfg: Config) -> dict:
    return {
        "config": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
        "scenarios": {
            scenario: {
                "saturations": r["saturations"],
                "groups": {g: {k: v for k, v in s.items() if k != "average"} | {"verdict": verdict(s)}
                           for g, s in r["groups"].items()},
            }
            for scenario, r in results.items()
        },
    }


def plot(results, cfg: Config, path) -> bool:
    """A PNG of the run-averaged NEES over time with its bounds; False without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    names = list(results)
    groups = list(results[names[0]]["groups"])
    fig, axes = plt.subplots(len(groups), len(names), figsize=(4 * len(names), 2.2 * len(groups)),
                             squeeze=False, sharex=True)
    for j, scenario in enumerate(names):
        r = results[scenario]
        for i, g in enumerate(groups):
            ax = axes[i][j]
            s = r["groups"][g]
            ax.semilogy(r["t"], s["average"], lw=0.8)
            ax.axhline(s["lower"], color="k", ls="--", lw=0.6)
            ax.axhline(s["upper"], color="k", ls="--", lw=0.6)
            ax.axhline(s["dof"], color="g", lw=0.6)
            ax.axvline(cfg.skip_s, color="grey", lw=0.5)
            if i == 0:
                ax.set_title(scenario)
            if j == 0:
                ax.set_ylabel(f"{g} NEES")
            if i == len(groups) - 1:
                ax.set_xlabel("t (s)")
    fig.suptitle(f"ESKF {cfg.arithmetic}: mean NEES of {cfg.runs} runs, 95 % bounds")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def main(argv=None) -> int:
    from imulink import core

    p = argparse.ArgumentParser(description="ESKF covariance consistency (NEES against chi-square bounds) on "
                                            "simulations whose noise matches the filter settings.")
    p.add_argument("--scenarios", default=",".join(SCENARIOS), type=lambda v: csv_choice(v, SCENARIOS, "scenario"),
                   help=f"comma-separated scenarios (default: {','.join(SCENARIOS)})")
    p.add_argument("--runs", type=int, default=Config.runs, help=f"Monte-Carlo runs (default {Config.runs})")
    p.add_argument("--duration", type=float, default=Config.duration_s,
                   help=f"seconds per run (default {Config.duration_s:g})")
    p.add_argument("--rate", type=float, default=Config.rate_hz, help=f"sample rate, Hz (default {Config.rate_hz:g})")
    p.add_argument("--every", type=float, default=Config.every_s,
                   help=f"seconds between NEES evaluations (rounded to filter steps; default {Config.every_s:g})")
    p.add_argument("--skip", type=float, default=Config.skip_s,
                   help=f"statistics over t >= SKIP seconds (default {Config.skip_s:g})")
    p.add_argument("--first-seed", type=int, default=Config.first_seed, help="seed of the first run (default 1)")
    p.add_argument("--arithmetic", default="fixed", type=lambda v: csv_choice(v, list(core.ARITHMETICS), "arithmetic"),
                   help="comma-separated builds: fixed, float (default fixed)")
    p.add_argument("--acc-bias", action="store_true",
                   help="estimate the accelerometer bias (9 states) and simulate one drawn from the prior")
    p.add_argument("--matched", action="store_true",
                   help="match the simulated sensors to the filter model exactly (see the module doc)")
    p.add_argument("--settings", default=None, help='JSON ESKF settings overrides, e.g. \'{"gyro_rrw": 1e-5}\'')
    p.add_argument("--markdown", action="store_true", help="print a markdown table")
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.add_argument("--png", default=None, metavar="PATH",
                   help="also plot the run-averaged NEES over time (needs matplotlib; skipped without it)")
    args = p.parse_args(argv)
    if args.runs < 1:
        p.error("--runs must be at least 1")
    if args.rate < 30:
        p.error("--rate must be at least 30 Hz (the ESKF's lowest sample_rate)")
    if args.duration <= args.skip + args.every:
        p.error("--duration must exceed --skip + --every")
    overrides = None
    if args.settings:
        try:
            overrides = json.loads(args.settings)
        except json.JSONDecodeError as exc:
            p.error(f"--settings is not valid JSON: {exc}")
        if not isinstance(overrides, dict):
            p.error('--settings must be a JSON object, e.g. {"gyro_rrw": 1e-5}')

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    outputs = []
    t_start = time.perf_counter()
    for arith in args.arithmetic:
        cfg = Config(duration_s=args.duration, rate_hz=args.rate, runs=args.runs, every_s=args.every,
                     skip_s=args.skip, first_seed=args.first_seed, arithmetic=arith, acc_bias=args.acc_bias,
                     matched=args.matched, settings=overrides)
        try:
            results = evaluate(args.scenarios, cfg, log)
        except core.SettingsError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        outputs.append((cfg, results))
        if args.png:
            path = args.png if len(args.arithmetic) == 1 else args.png.replace(".png", f"_{arith}.png")
            if plot(results, cfg, path):
                log(f"wrote {path}")
            else:
                log("matplotlib is not installed: no PNG")
    log(f"total {time.perf_counter() - t_start:.1f} s")
    if args.json:
        print(json.dumps([to_json(r, c) for c, r in outputs], indent=1))
    else:
        print("\n\n".join(format_markdown(r, c) if args.markdown else format_text(r, c) for c, r in outputs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
