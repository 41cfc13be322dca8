"""Rough real-world conditions for the `nav` filter (imulink.analysis.nav): named scenarios, each the
same run twice (rough, and its clean twin without the conditions: the same trajectory,
sensors and seed), the windows its errors are measured over, its metrics and targets.

The conditions are the simulator's (sensors.Vibration, sensors.Shock, the gyro's bias
steps, the magnetometer's disturbances, GnssModel's outliers, multipath episodes,
velocity blunders, cold start, outages; foot_walk's stairs), set to what a car, a phone
or a foot meets, not to what any filter copes with. Where a scenario places an event
(a bias step's axis, a multipath episode, a disturbance, an outage), the place is drawn
from the scenario's seed, so that several seeds measure several placements.

Every metric is an error, a count of errors or a share of the distance: lower is better,
and a target is an upper bound. Beside the filter, `gnss_alone` gives the simplest
alternative's value of each position and velocity metric: the fixes' own errors at
their samples (the last fix held where a window has none: an outage).

    from imulink.sim import nav_scenarios as ns
    outcome = ns.run_scenario("car_rough", seed=0, arithmetic="fixed")
    outcome["metrics"], outcome["clean"], outcome["gnss"], outcome["targets"]
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imulink.analysis import nav
from imulink.io.nav_input import NavInput, simulated_input
from imulink.sim import navigation as nv
from imulink.sim.sensors import Shock, SimResult, Vibration, extra_field, simulate

__all__ = ["RATE_HZ", "SETTLE_S", "Scenario", "SCENARIOS", "build", "car_rough", "handheld_rough", "car_cold_start",
           "car_velocity_outlier", "foot_rough", "start_marker", "heel_strikes", "evaluate", "gnss_alone",
           "targets_met", "run_scenario"]

#: The IMU rate of every scenario, Hz (the benchmarks').
RATE_HZ = 100.0
#: Errors are measured from this time on (s): the filter's start (attitude, biases) is not a rough condition.
SETTLE_S = 60.0
STANDARD_G = 9.80665


@dataclass
class Scenario:
    """One rough run and its clean twin.

    Attributes:
        name, seed, description: what it is.
        traj: the truth (a NavTrajectory at RATE_HZ).
        imu, clean_imu: the sensors' readings, with the conditions and without.
        fixes, clean_fixes: the GNSS fixes (GnssFixes), or the markers' (MarkerFixes: no
            GNSS), with the conditions and without.
        inp, clean: the NavInputs for imulink.analysis.nav.run, with the conditions and without.
        windows: name -> ``((start_s, end_s), ...)``: the union of these intervals of the
            truth's time (s) is the window (a sample at t is in [start, end)).
        metrics: name -> ``(quantity, statistic, where)``, what :func:`evaluate` measures:
            quantity "horizontal", "vertical" (m), "velocity" (m/s), "heading" (deg), with
            statistic "rmse", "max" or "mean" over the window named by `where`, or "at" the
            time `where` (s), or "end" (the last sample; "end_percent": as a share of the
            horizontal distance walked, %); quantity "good_rejected" (the fixes touched by
            no condition that the gate rejected) or "bad_accepted" (the outliers, velocity
            blunders and cold-start fixes it let in), statistic "count", over a window.
        targets: metric name -> upper bound (the metrics without one are reported only).
        events: what the conditions are and where they were placed (for reports).
    """

    name: str
    seed: int
    description: str
    traj: nv.NavTrajectory
    imu: SimResult
    clean_imu: SimResult
    fixes: nv.GnssFixes | nv.MarkerFixes
    clean_fixes: nv.GnssFixes | nv.MarkerFixes
    inp: NavInput
    clean: NavInput
    windows: dict
    metrics: dict
    targets: dict
    events: dict = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(self.traj.t[-1] + 1.0 / RATE_HZ)


def _events_rng(seed: int, name: str) -> np.random.Generator:
    """The generator that places a scenario's events: from the seed and the scenario's name,
    apart from every stream the trajectory, the sensors and the receiver draw from."""
    return np.random.default_rng([seed, *name.encode()])


def _describe(function) -> str:
    """A scenario's docstring on one line."""
    return " ".join(function.__doc__.split())


def _horizontal(rng: np.random.Generator, size: float) -> np.ndarray:
    """(3,) a horizontal vector of `size` in a random direction."""
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    return np.array([size * math.sin(azimuth), size * math.cos(azimuth), 0.0])


def start_marker(traj: nv.NavTrajectory, accuracy_m: float) -> nv.MarkerFixes:
    """A marker's fix where the walk starts (the truth, given with `accuracy_m`, m): a walk
    without GNSS starts from a known place."""
    return nv.MarkerFixes(index=np.array([0]), lat_deg=traj.lat_deg[:1].copy(), lon_deg=traj.lon_deg[:1].copy(),
                          height_m=traj.height_m[:1].copy(), accuracy_m=accuracy_m, truth_pos_enu=traj.pos_enu[:1])


def heel_strikes(traj: nv.NavTrajectory) -> np.ndarray:
    """Sample indices where a foot lands: the first still sample after each swing."""
    rest = traj.rest.astype(np.int8)
    return np.flatnonzero(np.diff(rest) == 1) + 1


#: A running engine shaking the board (car_rough; tools/bench_nav_field.py): 0.7 m/s^2 and 2 deg/s
#: RMS at 20-45 Hz and its 2nd order, each axis its own phase.
CAR_VIBRATION = Vibration(acc_rms_m_s2=0.7, gyro_rms_rad_s=math.radians(2.0), freq_min_hz=20.0, freq_max_hz=45.0)


def car_rough(seed: int) -> Scenario:
    """A 12 min car drive with the MPU6050 of the data sheet, its engine shaking the board
    (0.7 m/s^2 and 2 deg/s RMS at 20-45 Hz and its 2nd order, each axis its own phase), a
    gyro bias step of 0.5 deg/s on an axis at 6 min (a knock, a mount that shifts), GNSS at
    1 Hz with the usual white errors, 2 % of the fixes off by 20-50 m and one 20 s multipath
    episode of up to 5 m, neither in the reported accuracies."""
    name, duration = "car_rough", 720.0
    rng = _events_rng(seed, name)
    traj = nv.car_drive(duration, RATE_HZ, seed=seed)
    step = np.zeros(3)
    axis = int(rng.integers(3))
    step[axis] = math.radians(0.5) * rng.choice([-1.0, 1.0])
    step_s = duration / 2.0
    multipath_s = float(rng.uniform(SETTLE_S + 30.0, duration - 60.0))
    sensors = nv.datasheet_sensors(RATE_HZ)
    sensors.gyro.bias_steps = [(step_s, step)]
    imu = simulate(traj, sensors, seed=seed, vibration=CAR_VIBRATION)
    clean_imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=seed)
    model = nv.GnssModel(outlier_fraction=0.02, outlier_m=(20.0, 50.0),
                         multipath_episodes=((multipath_s, multipath_s + 20.0, 5.0),))
    fixes = nv.gnss_fixes(traj, model, seed=seed)
    clean_fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=seed)
    settled = ((SETTLE_S, duration),)
    return Scenario(
        name=name, seed=seed, description=_describe(car_rough), traj=traj,
        imu=imu, clean_imu=clean_imu, fixes=fixes, clean_fixes=clean_fixes, inp=simulated_input(imu, fixes),
        clean=simulated_input(clean_imu, clean_fixes),
        windows={"settled": settled, "multipath": ((multipath_s, multipath_s + 30.0),),
                 "after_step": ((step_s, step_s + 120.0),), "all": ((0.0, duration),)},
        metrics={"horizontal_rmse_m": ("horizontal", "rmse", "settled"),
                 "horizontal_max_m": ("horizontal", "max", "settled"),
                 "heading_rmse_deg": ("heading", "rmse", "settled"),
                 "vertical_rmse_m": ("vertical", "rmse", "settled"),
                 "velocity_rmse_m_s": ("velocity", "rmse", "settled"),
                 "multipath_horizontal_max_m": ("horizontal", "max", "multipath"),
                 "after_step_heading_max_deg": ("heading", "max", "after_step"),
                 "good_fixes_rejected": ("good_rejected", "count", "all"),
                 "outliers_accepted": ("bad_accepted", "count", "all")},
        targets={"horizontal_rmse_m": 1.5, "horizontal_max_m": 3.0, "heading_rmse_deg": 1.5},
        events={"gyro_bias_step": (step_s, "xyz"[axis], math.degrees(step[axis])),
                "multipath_s": (multipath_s, multipath_s + 20.0), "outliers": int(fixes.flags["outlier"].sum()),
                "acc_clipped": int(imu.saturated["acc"])})


def handheld_rough(seed: int) -> Scenario:
    """A 10 min walk with a phone held in front, GNSS at 1 Hz with the usual white errors, an
    extra field of 30 uT (in a random direction) for 30 s during the walk (a steel door, a
    parked car), then a 60 s outage (indoors)."""
    name, duration = "handheld_rough", 600.0
    rng = _events_rng(seed, name)
    traj = nv.handheld_walk(duration, RATE_HZ, seed=seed)
    disturbed_s = float(rng.uniform(150.0, 300.0))
    outage_s = disturbed_s + 30.0 + float(rng.uniform(60.0, 120.0))
    direction = rng.standard_normal(3)
    sensors = nv.datasheet_sensors(RATE_HZ)
    sensors.mag.disturbances = [extra_field(disturbed_s, disturbed_s + 30.0, 30.0, direction)]
    imu = simulate(traj, sensors, seed=seed)
    clean_imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=seed)
    fixes = nv.gnss_fixes(traj, nv.GnssModel(outages=((outage_s, outage_s + 60.0),)), seed=seed)
    clean_fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=seed)
    field_norm = float(np.linalg.norm(sensors.mag.earth_field() + sensors.mag.disturbances[0][2]))
    return Scenario(
        name=name, seed=seed, description=_describe(handheld_rough), traj=traj, imu=imu,
        clean_imu=clean_imu, fixes=fixes, clean_fixes=clean_fixes, inp=simulated_input(imu, fixes),
        clean=simulated_input(clean_imu, clean_fixes),
        windows={"outside": ((SETTLE_S, outage_s), (outage_s + 60.0, duration)),
                 "outage": ((outage_s, outage_s + 60.0),), "settled": ((SETTLE_S, duration),),
                 "disturbed": ((disturbed_s, disturbed_s + 60.0),)},
        metrics={"horizontal_rmse_m": ("horizontal", "rmse", "outside"),
                 "outage_horizontal_mean_m": ("horizontal", "mean", "outage"),
                 "outage_horizontal_max_m": ("horizontal", "max", "outage"),
                 "heading_rmse_deg": ("heading", "rmse", "settled"),
                 "disturbed_heading_max_deg": ("heading", "max", "disturbed"),
                 "velocity_rmse_m_s": ("velocity", "rmse", "outside")},
        targets={"horizontal_rmse_m": 2.0, "outage_horizontal_mean_m": 35.0},
        events={"disturbance_s": (disturbed_s, disturbed_s + 30.0), "disturbed_norm_uT": field_norm,
                "outage_s": (outage_s, outage_s + 60.0)})


def car_cold_start(seed: int) -> Scenario:
    """A 5 min car drive whose receiver's first fix is 1.1 km off (a random direction),
    reported with the usual accuracy (a cold receiver can), every later fix good (1 Hz,
    the usual white errors): measured at 150 s and 290 s."""
    name, duration = "car_cold_start", 300.0
    rng = _events_rng(seed, name)
    traj = nv.car_drive(duration, RATE_HZ, seed=seed)
    offset = _horizontal(rng, 1100.0)
    imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=seed)
    fixes = nv.gnss_fixes(traj, nv.GnssModel(cold_start_offset_m=tuple(offset), cold_start_fixes=1), seed=seed)
    clean_fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=seed)
    return Scenario(
        name=name, seed=seed, description=_describe(car_cold_start), traj=traj, imu=imu,
        clean_imu=imu, fixes=fixes, clean_fixes=clean_fixes, inp=simulated_input(imu, fixes),
        clean=simulated_input(imu, clean_fixes),
        windows={"after_150s": ((150.0, duration),), "all": ((0.0, duration),)},
        metrics={"horizontal_at_150s_m": ("horizontal", "at", 150.0),
                 "horizontal_at_290s_m": ("horizontal", "at", 290.0),
                 "horizontal_rmse_after_150s_m": ("horizontal", "rmse", "after_150s"),
                 "heading_at_150s_deg": ("heading", "at", 150.0),
                 "good_fixes_rejected": ("good_rejected", "count", "all")},
        # within a few metres: twice the fixes' 2-D RMS (2.5 m), never worse than they are
        targets={"horizontal_at_150s_m": 5.0, "horizontal_at_290s_m": 5.0},
        events={"first_fix_offset_m": tuple(float(v) for v in offset)})


def car_velocity_outlier(seed: int) -> Scenario:
    """A 10 min car drive, GNSS at 1 Hz with the usual white errors, one fix (at a random
    time in 200-400 s) whose velocity is 30 m/s off horizontally: how many of the good fixes
    after it the gate turns away."""
    name, duration = "car_velocity_outlier", 600.0
    rng = _events_rng(seed, name)
    traj = nv.car_drive(duration, RATE_HZ, seed=seed)
    outlier_s = float(np.round(rng.uniform(200.0, 400.0)))
    error = _horizontal(rng, 30.0)
    imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=seed)
    fixes = nv.gnss_fixes(traj, nv.GnssModel(velocity_outliers=((outlier_s, tuple(error)),)), seed=seed)
    clean_fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=seed)
    return Scenario(
        name=name, seed=seed, description=_describe(car_velocity_outlier), traj=traj, imu=imu,
        clean_imu=imu, fixes=fixes, clean_fixes=clean_fixes, inp=simulated_input(imu, fixes),
        clean=simulated_input(imu, clean_fixes),
        windows={"after": ((outlier_s, duration),), "minute_after": ((outlier_s, outlier_s + 60.0),),
                 "settled": ((SETTLE_S, duration),), "all": ((0.0, duration),)},
        metrics={"good_fixes_rejected_after": ("good_rejected", "count", "after"),
                 "outlier_accepted": ("bad_accepted", "count", "all"),
                 "minute_after_horizontal_max_m": ("horizontal", "max", "minute_after"),
                 "minute_after_velocity_max_m_s": ("velocity", "max", "minute_after"),
                 "horizontal_rmse_m": ("horizontal", "rmse", "settled")},
        targets={"good_fixes_rejected_after": 2},
        events={"outlier_s": outlier_s, "velocity_error_m_s": tuple(float(v) for v in error)})


def foot_rough(seed: int) -> Scenario:
    """A 5 min walk with the sensor on the foot, no GNSS, from a marker at the start (1 cm):
    a flight of stairs up (8 strides, 16 steps of 0.17 m) and later one down, every heel
    strike a shock of 6-12 g (10-20 ms, up and back along the foot, a few degrees off),
    clipped at the accelerometer's +-8 g with gravity on top."""
    name, duration = "foot_rough", 300.0
    rng = _events_rng(seed, name)
    up_s = float(rng.uniform(60.0, 110.0))
    down_s = up_s + float(rng.uniform(60.0, 100.0))
    stairs = ((up_s, 8, 0.17), (down_s, 8, -0.17))
    traj = nv.foot_walk(duration, RATE_HZ, seed=seed, stairs=stairs)
    strikes = heel_strikes(traj)
    shocks = []
    for k in strikes:
        direction = np.array([0.0, -0.4, 1.0]) + rng.normal(0.0, 0.1, 3)  # the sole stops the foot
        shocks.append(Shock(time_s=float(traj.t[k] + rng.uniform(-0.01, 0.01)),
                            peak_m_s2=float(rng.uniform(6.0, 12.0) * STANDARD_G), direction=direction,
                            duration_s=float(rng.uniform(0.010, 0.020))))
    imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=seed, shocks=shocks)
    clean_imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=seed)
    marker = start_marker(traj, 0.01)
    walked = float(np.sum(np.linalg.norm(traj.vel_enu[:, :2], axis=1)) / RATE_HZ)
    return Scenario(
        name=name, seed=seed, description=_describe(foot_rough), traj=traj, imu=imu,
        clean_imu=clean_imu, fixes=marker, clean_fixes=marker, inp=simulated_input(imu, marker),
        clean=simulated_input(clean_imu, marker), windows={"all": ((0.0, duration),)},
        metrics={"end_horizontal_percent": ("horizontal", "end_percent", "all"),
                 "vertical_max_m": ("vertical", "max", "all"),
                 "end_vertical_m": ("vertical", "end", "all"),
                 "horizontal_max_m": ("horizontal", "max", "all")},
        # the 2 % of the distance; a third of a storey, so that the floor is never mistaken
        targets={"end_horizontal_percent": 2.0, "vertical_max_m": 1.0},
        events={"walked_m": walked, "stairs": stairs, "heel_strikes": len(shocks),
                "acc_clipped": int(imu.saturated["acc"])})


#: The scenarios by name: each a function of the seed returning a Scenario.
SCENARIOS = {f.__name__: f for f in (car_rough, handheld_rough, car_cold_start, car_velocity_outlier, foot_rough)}


def build(name: str, seed: int) -> Scenario:
    """The scenario `name` (SCENARIOS) for `seed`; KeyError for an unknown name."""
    if name not in SCENARIOS:
        raise KeyError(f"unknown scenario {name!r}; expected one of {', '.join(SCENARIOS)}")
    return SCENARIOS[name](seed)


def _in_window(t: np.ndarray, intervals) -> np.ndarray:
    mask = np.zeros(len(t), bool)
    for start, end in intervals:
        mask |= (t >= start) & (t < end)
    return mask


def _statistic(x: np.ndarray, statistic: str) -> float:
    if len(x) == 0:
        return math.nan
    if statistic == "rmse":
        return float(np.sqrt(np.mean(np.square(x))))
    if statistic == "max":
        return float(np.max(x))
    if statistic == "mean":
        return float(np.mean(x))
    raise ValueError(f"unknown statistic {statistic!r}")


def _fix_flags(fixes) -> tuple[np.ndarray, np.ndarray]:
    """(good, bad) per fix: touched by no condition; an outlier, a velocity blunder or a cold start."""
    flags = getattr(fixes, "flags", None) or {}
    zero = np.zeros(len(fixes), bool)
    bad = flags.get("outlier", zero) | flags.get("velocity_outlier", zero) | flags.get("cold_start", zero)
    return ~(bad | flags.get("multipath", zero)), bad


def evaluate(scenario: Scenario, result, clean: bool = False) -> dict[str, float]:
    """The scenario's metrics (Scenario.metrics) of a filter's run (imulink.analysis.nav.NavResult) over
    ``scenario.inp`` (or, with `clean`, over ``scenario.clean``), against the truth."""
    traj = scenario.traj
    e = nav.errors(result, traj)
    t = traj.t[result.start:]
    fixes = scenario.clean_fixes if clean else scenario.fixes
    good, bad = _fix_flags(fixes)
    later = slice(1, None)  # the run's fixes after its start (NavResult.fix_index)
    walked = float(np.sum(np.linalg.norm(traj.vel_enu[:, :2], axis=1)) / RATE_HZ)
    out: dict[str, float] = {}
    for name, (quantity, statistic, where) in scenario.metrics.items():
        if quantity in ("good_rejected", "bad_accepted"):
            fix_t = traj.t[result.fix_index]
            inside = _in_window(fix_t, scenario.windows[where])
            if quantity == "good_rejected":
                out[name] = int(np.sum(inside & good[later] & ~result.fix_accepted))
            else:
                out[name] = int(np.sum(inside & bad[later] & result.fix_accepted))
        elif statistic == "at":
            out[name] = float(e[quantity][int(round(where * RATE_HZ)) - result.start])
        elif statistic == "end":
            out[name] = float(e[quantity][-1])
        elif statistic == "end_percent":
            out[name] = 100.0 * float(e[quantity][-1]) / walked
        else:
            out[name] = _statistic(e[quantity][_in_window(t, scenario.windows[where])], statistic)
    return out


def gnss_alone(scenario: Scenario, clean: bool = False) -> dict[str, float | None]:
    """The simplest alternative's value of each metric: the GNSS fixes' own errors at their
    samples (horizontal, vertical, velocity) over the metric's window; where the window holds
    no fix (an outage), the last fix held against the truth at each sample; "at" a time: the
    last fix by then. None where the fixes say nothing (heading, the gate's counts; no GNSS)."""
    fixes = scenario.clean_fixes if clean else scenario.fixes
    if not isinstance(fixes, nv.GnssFixes):  # a MarkerFixes: no velocity
        return {name: None for name in scenario.metrics}
    traj = scenario.traj
    error = fixes.pos_enu - fixes.truth_pos_enu
    per_fix = {"horizontal": np.hypot(error[:, 0], error[:, 1]), "vertical": np.abs(error[:, 2]),
               "velocity": np.linalg.norm(fixes.vel_enu - fixes.truth_vel_enu, axis=1)}
    t_fix = traj.t[fixes.index]
    out: dict[str, float | None] = {}
    for name, (quantity, statistic, where) in scenario.metrics.items():
        if quantity not in per_fix or statistic in ("end", "end_percent"):
            out[name] = None
        elif statistic == "at":
            last = np.searchsorted(t_fix, where + 1e-9) - 1
            out[name] = float(per_fix[quantity][last]) if last >= 0 else None
        else:
            inside = _in_window(t_fix, scenario.windows[where])
            if inside.any():
                out[name] = _statistic(per_fix[quantity][inside], statistic)
            elif quantity == "velocity":
                out[name] = None
            else:  # no fix in the window: the last one held
                samples = np.flatnonzero(_in_window(traj.t, scenario.windows[where]))
                last = np.searchsorted(fixes.index, samples, side="right") - 1
                ok = last >= 0
                held = fixes.pos_enu[last[ok]] - traj.pos_enu[samples[ok]]
                values = np.hypot(held[:, 0], held[:, 1]) if quantity == "horizontal" else np.abs(held[:, 2])
                out[name] = _statistic(values, statistic)
    return out


def targets_met(scenario: Scenario, metrics: dict) -> dict[str, bool]:
    """Per target: whether the metric is within it (a NaN is not)."""
    return {name: bool(metrics[name] <= limit) for name, limit in scenario.targets.items()}


def run_scenario(name: str, seed: int, arithmetic: str = "fixed", scenario: Scenario | None = None) -> dict:
    """Build the scenario (or take `scenario`, built already) and run the nav filter in the
    given arithmetic ("fixed" or "float") on it and on its clean twin.

    Returns:
        {"scenario": the Scenario, "result", "clean_result": the NavResults,
        "metrics", "clean": evaluate() of each, "gnss", "gnss_clean": gnss_alone() of each,
        "targets": Scenario.targets, "met": targets_met() of the rough run}.
    """
    scenario = build(name, seed) if scenario is None else scenario
    result = nav.run(scenario.inp, arithmetic)
    clean_result = nav.run(scenario.clean, arithmetic)
    metrics = evaluate(scenario, result)
    return {"scenario": scenario, "result": result, "clean_result": clean_result, "metrics": metrics,
            "clean": evaluate(scenario, clean_result, clean=True), "gnss": gnss_alone(scenario),
            "gnss_clean": gnss_alone(scenario, clean=True), "targets": dict(scenario.targets),
            "met": targets_met(scenario, metrics)}
