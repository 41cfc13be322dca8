"""Rough simulated cases for the attitude filters, and their evaluation against VQF
(tools/eval_rough.py).

Every scenario is a function ``(seed, duration_s=DURATION_S) -> (SimResult, mask)``: the
simulator's readings at :data:`RATE_HZ` (:meth:`SensorSuite.default` sensors plus the
scenario's condition) and the samples scored: everything from :data:`SETTLE_S` on (the
filters' start is not what is measured; where a disturbance is the point, the time during
and after it is scored like the rest). Where a scenario places an event (an axis, a
direction, a time), the place is drawn from the seed and the scenario's name, apart from
the streams of the trajectory and the sensors, so that several seeds measure several
placements. Times and lengths of events are given for the default 300 s and scale with
``duration_s`` (a short run for the tests keeps the same shape).

Linear acceleration is that of a position within reach (``translation="bounded"`` of
:func:`imulink.sim.random_motion`: it averages out within seconds, as in BROAD's
recordings) everywhere but in ``sustained``.

1. ``handheld``: :func:`motion_with_rests` (moves of 5-20 s up to about 200 deg/s, rests of
   2-10 s) with a linear acceleration of 1 m/s^2 per axis (std).
2. ``fast``: :func:`random_motion` without rests, rate soft-limited to 400 deg/s, linear
   acceleration 3 m/s^2 per axis.
3. ``sustained``: ``handheld`` with a sustained linear acceleration (flat down to 0 Hz:
   a vehicle's, which no low-pass averages out).
4. ``vibration``: slow :func:`random_motion` (100 deg/s, 0.5 m/s^2) on a shaking mount:
   a :class:`Vibration` of 3 m/s^2 and 0.1 rad/s (5.7 deg/s) RMS at 20-45 Hz and its 2nd
   order (the class's default is a car's engine, 0.7 m/s^2 and 2 deg/s: this is some four
   and three times that, a drone's frame or a power tool), read at 100 Hz without an
   anti-alias filter, so its 2nd order aliases.
5. ``acc-bias``: ``handheld`` with a constant accelerometer bias of MPU6050 size: each axis
   0.2-0.4 m/s^2 with a random sign (the data sheet's +-50 mg zero-g offset on x and y).
6. ``acc-bias-drift``: ``acc-bias`` plus a temperature drift: 8 equal steps from 10 % to
   90 % of the run that add up to 0.2 m/s^2 along a random direction (AccModel.bias_steps).
7. ``gyro-bias-step``: ``handheld`` with a gyro bias step of 0.5 deg/s (random sign) on a
   random axis halfway through (GyroModel.bias_steps): a knock, a mount that shifts.
8. ``gyro-scale``: continuous rotation up to 300 deg/s with 1 m/s^2 of linear acceleration,
   read by an uncalibrated gyroscope (GyroModel.scale_error): scale-factor errors of 1-2 %
   and cross-axis sensitivities up to 1 %, random signs (the MPU6050 allows 3 % and 2 %).
9. ``magnet-room``: ``handheld`` with an extra field of 25 uT fixed in the room, in a random
   direction, for 30 s (a tenth of the run) starting at 30-60 % of the run
   (MagModel.disturbances, with 0.5 s ramps).
10. ``attached-magnet``: ``handheld`` with a magnet on the board: a hard-iron offset of 15 uT
   in a random body direction for the WHOLE run (MagModel has only a constant hard_iron,
   so it cannot be switched on for a while; no filter is told about it).
11. ``shocks``: ``handheld`` with knocks: a :class:`Shock` every 2-5 s (a Ricker pulse of
   200 m/s^2, 15 ms main lobe, random body direction), clipped at the accelerometer's
   +-8 g (78 m/s^2).
12. ``outage``: ``handheld`` with the magnetometer reading zeros (counts 0: no field, which
    the filters and VQF take as "no magnetometer sample") for 60 s (a fifth of the run)
    starting at 30-60 % of the run.
13. ``slow-turn``: ``handheld`` with three steady rotations of 40 s (starting at 15, 45 and
    75 % of the run), each at 0.5-1.8 deg/s about a random body axis, with no linear
    acceleration: a turntable, a boat's slow swing. Slower than a rest detector's rate
    threshold (2 deg/s in VQF and the ESKF), so a filter that takes it for rest learns it
    as a gyro bias.

Estimators (:func:`evaluate_case`): the fixed-point builds of ``eecf``, ``eskf`` (6 states)
and ``eskf9`` (the eskf with ``estimate_acc_bias``), with their DEFAULT settings; the
references ``vqf`` (the vqf package, ``VQF(1 / rate).updateBatch(gyr, acc, mag)["quat9D"]``,
default parameters, fed exactly what the filters see: the readings through the register
counts and back, clipping included) and ``gyro`` (no filter: the gyroscope integrated
from the TRUE initial attitude). Errors: the BROAD metric
(:func:`imulink.analysis.attitude.attitude_errors`), RMSE over the mask, degrees.
"""
from __future__ import annotations

import math
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import Callable, Sequence

import numpy as np

from imulink import sim
from imulink.analysis.attitude import attitude_errors, rmse
from imulink.core.counts import counts_to_si, si_to_counts
from imulink.sim.sensors import Shock, SimResult, Vibration, extra_field

__all__ = ["RATE_HZ", "DURATION_S", "SETTLE_S", "MARGIN_DEG", "KINDS", "FILTERS", "REFERENCES", "SCENARIOS",
           "filter_inputs", "run_estimator", "score", "evaluate_case", "evaluate", "worse_than_vqf",
           "paired_losses"]

#: Sample rate of every scenario, Hz.
RATE_HZ = 100.0
#: Default length of a scenario, s.
DURATION_S = 300.0
#: Errors are scored from this time on, s.
SETTLE_S = 10.0
#: A filter is "worse than VQF" where its worst-seed RMSE exceeds VQF's by more than this, deg.
MARGIN_DEG = 0.05
#: The error kinds of the BROAD metric.
KINDS = ("total", "heading", "inclination")

#: The filters: name -> (core filter, settings; None = the defaults users get).
FILTERS: dict[str, tuple[str, dict | None]] = {
    "eecf": ("eecf", None),
    "eskf": ("eskf", None),
    "eskf9": ("eskf", {"estimate_acc_bias": 1}),
}
#: The reference columns: VQF and the gyroscope alone.
REFERENCES = ("vqf", "gyro")

Case = tuple[SimResult, np.ndarray]


def _events_rng(seed: int, name: str) -> np.random.Generator:
    """The generator that places a scenario's events (from the seed and the name, apart from
    the trajectory's and the sensors' streams)."""
    return np.random.default_rng([seed, *name.encode()])


def _mask(data: SimResult) -> np.ndarray:
    return data.t >= SETTLE_S


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def _handheld_traj(seed: int, duration_s: float, translation: str = "bounded") -> sim.Trajectory:
    return sim.motion_with_rests(duration_s, RATE_HZ, seed=seed, accel_std=1.0, translation=translation)


def _acc_bias(rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(0.2, 0.4, 3) * rng.choice([-1.0, 1.0], 3)


def handheld(seed: int, duration_s: float = DURATION_S) -> Case:
    """Moves and rests, up to about 200 deg/s, linear acceleration 1 m/s^2 per axis."""
    data = sim.simulate(_handheld_traj(seed, duration_s), sim.SensorSuite.default(), seed=seed)
    return data, _mask(data)


def fast(seed: int, duration_s: float = DURATION_S) -> Case:
    """Continuous motion up to 400 deg/s, linear acceleration 3 m/s^2 per axis, no rests."""
    traj = sim.random_motion(duration_s, RATE_HZ, seed=seed, max_rate_dps=400.0, accel_std=3.0,
                             translation="bounded")
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=seed)
    return data, _mask(data)


def sustained(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` whose linear acceleration (1 m/s^2 per axis) is sustained: flat down to
    0 Hz, as in a vehicle, not a hand's, which averages out within seconds."""
    traj = _handheld_traj(seed, duration_s, translation="sustained")
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=seed)
    return data, _mask(data)


#: The ``vibration`` scenario's shaking: 3 m/s^2 and 0.1 rad/s RMS at 20-45 Hz and its 2nd order.
VIBRATION = Vibration(acc_rms_m_s2=3.0, gyro_rms_rad_s=0.1)


def vibration(seed: int, duration_s: float = DURATION_S) -> Case:
    """Slow motion (100 deg/s, 0.5 m/s^2) with 3 m/s^2 and 0.1 rad/s RMS of vibration."""
    traj = sim.random_motion(duration_s, RATE_HZ, seed=seed, max_rate_dps=100.0, accel_std=0.5,
                             translation="bounded")
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=seed, vibration=VIBRATION)
    return data, _mask(data)


def acc_bias(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` with a constant accelerometer bias of 0.2-0.4 m/s^2 per axis."""
    rng = _events_rng(seed, "acc-bias")
    suite = sim.SensorSuite.default()
    suite.acc.bias = _acc_bias(rng)
    data = sim.simulate(_handheld_traj(seed, duration_s), suite, seed=seed)
    return data, _mask(data)


def acc_bias_drift(seed: int, duration_s: float = DURATION_S) -> Case:
    """``acc-bias`` plus 8 steps from 10 % to 90 % of the run adding up to 0.2 m/s^2."""
    rng = _events_rng(seed, "acc-bias-drift")
    suite = sim.SensorSuite.default()
    suite.acc.bias = _acc_bias(rng)
    direction = _unit(rng)
    steps = 8
    suite.acc.bias_steps = [(float(t), 0.2 / steps * direction)
                            for t in np.linspace(0.1 * duration_s, 0.9 * duration_s, steps)]
    data = sim.simulate(_handheld_traj(seed, duration_s), suite, seed=seed)
    return data, _mask(data)


def gyro_bias_step(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` with a 0.5 deg/s gyro bias step on a random axis halfway."""
    rng = _events_rng(seed, "gyro-bias-step")
    step = np.zeros(3)
    step[int(rng.integers(3))] = math.radians(0.5) * float(rng.choice([-1.0, 1.0]))
    suite = sim.SensorSuite.default()
    suite.gyro.bias_steps = [(0.5 * duration_s, step)]
    data = sim.simulate(_handheld_traj(seed, duration_s), suite, seed=seed)
    return data, _mask(data)


def gyro_scale(seed: int, duration_s: float = DURATION_S) -> Case:
    """Continuous rotation up to 300 deg/s (1 m/s^2 of linear acceleration) read by an
    uncalibrated gyroscope: scale-factor errors of 1-2 % and cross-axis sensitivities up
    to 1 % (random signs; the MPU6050's data sheet allows 3 % and 2 %)."""
    rng = _events_rng(seed, "gyro-scale")
    error = rng.uniform(-0.01, 0.01, (3, 3))
    np.fill_diagonal(error, rng.uniform(0.01, 0.02, 3) * rng.choice([-1.0, 1.0], 3))
    suite = sim.SensorSuite.default()
    suite.gyro.scale_error = error
    traj = sim.random_motion(duration_s, RATE_HZ, seed=seed, max_rate_dps=300.0, accel_std=1.0,
                             translation="bounded")
    data = sim.simulate(traj, suite, seed=seed)
    return data, _mask(data)


def magnet_room(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` with 25 uT fixed in the room for a tenth of the run."""
    rng = _events_rng(seed, "magnet-room")
    start = float(rng.uniform(0.3, 0.6)) * duration_s
    suite = sim.SensorSuite.default()
    suite.mag.disturbances = [extra_field(start, start + 0.1 * duration_s, 25.0, _unit(rng))]
    data = sim.simulate(_handheld_traj(seed, duration_s), suite, seed=seed)
    return data, _mask(data)


def attached_magnet(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` with a 15 uT hard-iron offset (random body direction) all the run."""
    rng = _events_rng(seed, "attached-magnet")
    suite = sim.SensorSuite.default()
    suite.mag.hard_iron = 15.0 * _unit(rng)
    data = sim.simulate(_handheld_traj(seed, duration_s), suite, seed=seed)
    return data, _mask(data)


def shocks(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` with a 200 m/s^2 knock (random direction) every 2-5 s, clipped at 8 g."""
    rng = _events_rng(seed, "shocks")
    pulses = []
    t = float(rng.uniform(2.0, 5.0))
    while t < duration_s - 0.1:
        pulses.append(Shock(time_s=t, peak_m_s2=200.0, direction=_unit(rng)))
        t += float(rng.uniform(2.0, 5.0))
    data = sim.simulate(_handheld_traj(seed, duration_s), sim.SensorSuite.default(), seed=seed, shocks=pulses)
    return data, _mask(data)


def outage(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` with the magnetometer reading zeros for a fifth of the run."""
    rng = _events_rng(seed, "outage")
    start = float(rng.uniform(0.3, 0.6)) * duration_s
    data = sim.simulate(_handheld_traj(seed, duration_s), sim.SensorSuite.default(), seed=seed)
    off = (data.t >= start) & (data.t < start + 0.2 * duration_s)
    mag_counts = data.mag_counts.copy()
    mag_counts[off] = 0
    mag = data.mag.copy()
    mag[off] = 0.0
    return replace(data, mag=mag, mag_counts=mag_counts), _mask(data)


def slow_turn(seed: int, duration_s: float = DURATION_S) -> Case:
    """``handheld`` with three 40 s steady rotations at 0.5-1.8 deg/s about random axes."""
    rng = _events_rng(seed, "slow-turn")
    traj = _handheld_traj(seed, duration_s)
    gyr = traj.gyr.copy()
    acc_lin = traj.acc_lin.copy()
    rest = traj.rest.copy()
    length = int(round(40.0 / DURATION_S * duration_s * RATE_HZ))
    for start in (0.15, 0.45, 0.75):
        first = int(round(start * duration_s * RATE_HZ))
        window = slice(first, first + length)
        gyr[window] = math.radians(float(rng.uniform(0.5, 1.8))) * _unit(rng)
        acc_lin[window] = 0.0
        rest[window] = False
    turned = replace(traj, gyr=gyr, acc_lin=acc_lin, rest=rest,
                     quat=sim.integrate_gyro(traj.quat[0], gyr, 1.0 / RATE_HZ))
    data = sim.simulate(turned, sim.SensorSuite.default(), seed=seed)
    return data, _mask(data)


#: The scenarios by name, in the report's order.
SCENARIOS: dict[str, Callable[..., Case]] = {
    "handheld": handheld,
    "fast": fast,
    "sustained": sustained,
    "vibration": vibration,
    "acc-bias": acc_bias,
    "acc-bias-drift": acc_bias_drift,
    "gyro-bias-step": gyro_bias_step,
    "gyro-scale": gyro_scale,
    "magnet-room": magnet_room,
    "attached-magnet": attached_magnet,
    "shocks": shocks,
    "outage": outage,
    "slow-turn": slow_turn,
}


def filter_inputs(data: SimResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The SI readings as the filters see them: through the register counts of the data's
    profile (rounded and clipped, what :func:`imulink.core.run` does) and back."""
    gyr, acc, mag = si_to_counts(data.gyr, data.acc, data.mag, data.profile)
    return counts_to_si(gyr, acc, mag, data.profile)


def run_estimator(name: str, data: SimResult) -> np.ndarray:
    """(N,4) attitude (w-first, sensor-to-earth ENU) of a filter of :data:`FILTERS` (fixed
    build, its settings there) or of a reference of :data:`REFERENCES`; KeyError otherwise."""
    if name in FILTERS:
        from imulink import core

        core_name, settings = FILTERS[name]
        return core.run(core_name, data.gyr, data.acc, data.mag, data.rate_hz, "fixed", settings=settings,
                        profile=data.profile).quat
    gyr, acc, mag = filter_inputs(data)
    if name == "vqf":
        from vqf import VQF

        out = VQF(1.0 / data.rate_hz).updateBatch(np.ascontiguousarray(gyr), np.ascontiguousarray(acc),
                                                  np.ascontiguousarray(mag))
        return np.asarray(out["quat9D"])
    if name == "gyro":
        return sim.integrate_gyro(data.quat_true[0], gyr, data.dt)
    raise KeyError(f"unknown estimator {name!r}; expected one of {[*FILTERS, *REFERENCES]}")


def score(q_est, data: SimResult, mask) -> dict[str, float]:
    """RMSE (deg) of the total, heading and inclination errors of an estimate over the mask."""
    return rmse(attitude_errors(q_est, data.quat_true), mask)


def evaluate_case(scenario: str, seed: int, estimators: Sequence[str] = (*FILTERS, *REFERENCES),
                  duration_s: float = DURATION_S) -> dict:
    """One scenario and seed: {"scenario", "seed", "errors": {estimator: {kind: deg}},
    "saturated": {"gyr", "acc", "mag": clipped values}, "samples": scored samples, "seconds"}."""
    t0 = time.perf_counter()
    data, mask = SCENARIOS[scenario](seed, duration_s)
    errors = {name: score(run_estimator(name, data), data, mask) for name in estimators}
    return {"scenario": scenario, "seed": seed, "errors": errors, "saturated": dict(data.saturated),
            "samples": int(np.count_nonzero(mask)), "seconds": time.perf_counter() - t0}


def _worst_key(value: float) -> float:
    """Sort key of an RMSE: NaN (no estimate) counts as the worst."""
    return math.inf if math.isnan(value) else value


def _evaluate_job(job: tuple) -> dict:
    return evaluate_case(*job)


def evaluate(scenarios: Sequence[str], seeds: Sequence[int], estimators: Sequence[str],
             duration_s: float = DURATION_S, workers: int = 1, log: Callable[[str], None] | None = None) -> dict:
    """Every scenario x seed (``workers`` processes when more than 1).

    Returns {scenario: {"seeds": {seed: evaluate_case's dict}, "worst": {estimator: {kind:
    {"rmse": deg, "seed": seed}}}}}: the worst (largest) RMSE over the seeds, kind by kind.
    """
    jobs = [(s, seed, tuple(estimators), duration_s) for s in scenarios for seed in seeds]
    results: dict = {s: {"seeds": {}} for s in scenarios}

    def take(case: dict) -> None:
        results[case["scenario"]]["seeds"][case["seed"]] = case
        if log:
            e = case["errors"]
            log(f"{case['scenario']:16s} seed {case['seed']:3d}  " + "  ".join(
                f"{n} {e[n]['total']:.2f}" for n in estimators) + f"  (total deg, {case['seconds']:.1f} s)")

    if workers > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for case in pool.map(_evaluate_job, jobs):
                take(case)
    else:
        for job in jobs:
            take(_evaluate_job(job))
    for s in scenarios:
        per_seed = results[s]["seeds"]
        results[s]["worst"] = {
            name: {kind: max(({"rmse": per_seed[seed]["errors"][name][kind], "seed": seed} for seed in seeds),
                             key=lambda w: _worst_key(w["rmse"])) for kind in KINDS}
            for name in estimators}
    return results


def worse_than_vqf(results: dict, filter_name: str, margin_deg: float = MARGIN_DEG) -> dict[str, list[dict]]:
    """Per kind, the scenarios where the filter's worst-seed RMSE exceeds VQF's worst-seed RMSE
    by more than ``margin_deg`` (a NaN of the filter's counts as worse):
    [{"scenario", "filter", "vqf", "excess"}] (deg)."""
    out: dict[str, list[dict]] = {kind: [] for kind in KINDS}
    for scenario, r in results.items():
        for kind in KINDS:
            mine, ref = r["worst"][filter_name][kind]["rmse"], r["worst"]["vqf"][kind]["rmse"]
            if _worst_key(mine) - ref > margin_deg:
                out[kind].append({"scenario": scenario, "filter": mine, "vqf": ref, "excess": mine - ref})
    return out


def paired_losses(results: dict, filter_name: str, margin_deg: float = MARGIN_DEG) -> dict[str, list[dict]]:
    """Per kind, the scenarios where the filter's RMSE exceeds VQF's ON THE SAME SEED (the same
    data) by more than ``margin_deg`` on at least one seed: [{"scenario", "seed" (the largest
    excess's), "excess" (deg), "seeds_worse" (how many seeds), "seeds"}]. Stricter than
    :func:`worse_than_vqf`, whose worst seeds may be different runs."""
    out: dict[str, list[dict]] = {kind: [] for kind in KINDS}
    for scenario, r in results.items():
        for kind in KINDS:
            excess = {seed: case["errors"][filter_name][kind] - case["errors"]["vqf"][kind]
                      for seed, case in r["seeds"].items()}
            worse = [seed for seed, e in excess.items() if _worst_key(e) > margin_deg]
            if worse:
                seed = max(worse, key=lambda k: _worst_key(excess[k]))
                out[kind].append({"scenario": scenario, "seed": seed, "excess": excess[seed],
                                  "seeds_worse": len(worse), "seeds": len(excess)})
    return out
