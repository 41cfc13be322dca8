#!/usr/bin/env python3
"""Accuracy and Cortex-M4 cost of the `nav` filter (issue 16; firmware/core/imu_navkf.c).

Accuracy: the filter through imulink.analysis.nav (the C core via cffi), fixed point and float twin,
on the navigation simulator's scenarios with the MPU6050 data sheet's noise and turn-on
biases (`imulink.sim.navigation.datasheet_sensors`), seed 0, 100 Hz:

- car drive, 20 min, GNSS at 1 Hz with white errors of 2.5 m horizontal, 5 m vertical,
  0.1 m/s; the same with the barometer (the MS5611 at 50 Hz: noise, temperature drift,
  weather); with two 30 s outages; with the antenna 1.5 m forward and 1.2 m up (its lever
  arm set); with positions only (NMEA's GGA); with time-correlated errors (2 m horizontal,
  3 m vertical, 100 s) and a multipath jump of 19 m for 10 s; with 0.2 s latency;
- drone flight, 10 min (climbs, hovers, legs at up to 12 m/s), GNSS and the barometer;
- foot-mounted walk, 5 min of laps, no GNSS, zero velocity in the stances: the error at
  the end as a share of the distance walked;
- handheld walk indoors, 10 min, a marker's position fix (0.1 m) each minute: the error
  just before each.

Errors after the first minute (the car's start). Fixed vs float: the largest position
difference and attitude difference over each run. Without GNSS or fixes: the attitude of
the nav filter and of the attitude ESKF on the car drive, the drone flight and both walks.

Cost: the fixed-point core built for the Cortex-M4 as tools/bench_arm.py builds it (same
flags, same harness ELF), run in the unicorn emulator over the first `--seconds` of the car
drive with its barometer: instructions per IMU step (imu_navkf_step; every fifth sample
also propagates the covariance), per GNSS fix (imu_navkf_fix) and per barometer sample
(imu_navkf_baro: an update once a second), the deepest stack, sizeof(imu_navkf_t).
After every sample the position, velocity and attitude are read back and compared with
the x86 fixed build (imulink.analysis.nav): the benchmark fails at the first difference.

Rough conditions (`--rough`, instead of the accuracy scenarios above): every scenario of
imulink.analysis.nav_scenarios (engine vibration, GNSS outliers and multipath, a gyro bias
step, a magnetic disturbance, an indoor outage, a cold start, a velocity blunder, heel
strikes that clip and stairs) over seeds 0..N-1 (`--seeds`, default 3), both builds; one
table per scenario: each metric's worst seed (not the best) in each build, beside the
clean twin's worst (the same runs without the conditions), the GNSS fixes alone (their own
errors: the simplest alternative) and the target; and the largest fixed-vs-float
difference over the seeds. The cases run in parallel (two processes).

    .venv/bin/python tools/bench_nav.py [--seconds 60] [--no-accuracy] [--no-arm] [--json]
    .venv/bin/python tools/bench_nav.py --rough [--seeds 3] [--no-arm] [--json]
"""
from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import multiprocessing.connection
import os
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT / "host"))

import bench_arm  # noqa: E402
from imulink import protocol  # noqa: E402
from imulink.analysis import nav  # noqa: E402
from imulink.analysis import nav_scenarios as ns  # noqa: E402
from imulink.io.nav_input import simulated_input  # noqa: E402
from imulink.sim import navigation as nv  # noqa: E402
from imulink.sim import simulate  # noqa: E402

RATE_HZ = 100.0
SEED = 0
OUTAGES = ((300.0, 330.0), (700.0, 730.0))
MULTIPATH = ((420.0, 430.0, 15.0, -10.0, 5.0),)
ANTENNA = (0.5, 1.5, 1.2)  # m: right, forward, up of the sensor


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def builds_differ(results) -> tuple[float, float]:
    """Largest position (m) and attitude (deg) difference of the fixed build from the float."""
    fixed, flt = results["fixed"], results["float"]
    d = nv.local_offsets(fixed.lat_deg, fixed.lon_deg, fixed.height_m, flt.lat_deg, flt.lon_deg, flt.height_m)
    dot = np.minimum(np.abs(np.sum(fixed.quat * flt.quat, axis=1)) / np.linalg.norm(fixed.quat, axis=1), 1.0)
    return float(np.linalg.norm(d, axis=1).max()), float(np.degrees(2.0 * np.arccos(dot)).max())


def car_drive(minutes: float):
    traj = nv.car_drive(minutes * 60.0, RATE_HZ, seed=SEED)
    return traj, simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=SEED)


def start_marker(traj, accuracy_m: float, extra=None) -> nv.MarkerFixes:
    """A marker's fix at the start (where a walk without GNSS starts), and `extra` markers."""
    index, lat, lon, h = [0], [traj.lat_deg[0]], [traj.lon_deg[0]], [traj.height_m[0]]
    if extra is not None:
        index += list(extra.index)
        lat, lon, h = lat + list(extra.lat_deg), lon + list(extra.lon_deg), h + list(extra.height_m)
    return nv.MarkerFixes(index=np.array(index), lat_deg=np.array(lat), lon_deg=np.array(lon),
                          height_m=np.array(h), accuracy_m=accuracy_m, truth_pos_enu=traj.pos_enu[index])


def accuracy(progress=lambda _m: None) -> list[dict]:
    rows = []
    traj, imu = car_drive(20.0)
    car = {
        "car drive, 20 min, white GNSS errors": (nv.GnssModel(), None),
        "the same with the barometer": (nv.GnssModel(), "baro"),
        "the same, two 30 s outages (300 s, 700 s)": (nv.GnssModel(outages=OUTAGES), None),
        "the same, correlated errors and a 19 m multipath jump": (
            nv.GnssModel(correlated_h_m=2.0, correlated_v_m=3.0, multipath=MULTIPATH), None),
        "the same, white errors, fixes 0.2 s late": (nv.GnssModel(latency_s=0.2), "late"),
        f"the same, the antenna at {ANTENNA} m from the sensor, its lever arm set": (nv.GnssModel(), "antenna"),
        "the same, position only (an NMEA receiver's GGA)": (nv.GnssModel(), "position"),
    }
    for name, (model, option) in car.items():
        fixes = nv.gnss_fixes(traj, model, seed=SEED)
        if option == "antenna":
            fixes = nv.antenna_fixes(traj, fixes, ANTENNA)
        baro = nv.baro_samples(traj, seed=SEED) if option == "baro" else None
        inp = simulated_input(imu, fixes, at_arrival=option == "late", baro=baro)
        if option == "position":
            inp.fix_vel_enu = np.full_like(inp.fix_vel_enu, np.nan)
            inp.fix_s_acc_m_s = np.full_like(inp.fix_s_acc_m_s, np.nan)
            inp.fix_is_marker = np.zeros(len(inp.fix_index), bool)
        arm = ANTENNA if option == "antenna" else None
        results = {a: nav.run(inp, a, lever_arm_m=arm) for a in ("fixed", "float")}
        row = {"scenario": name, "fixed_vs_float_m_deg": builds_differ(results)}
        for arithmetic, result in results.items():
            e = nav.errors(result, traj)
            t = (result.timestamp_us - result.timestamp_us[0]) / 1e6
            settled = t >= 60.0
            row[arithmetic] = {"horizontal_rmse_m": rms(e["horizontal"][settled]),
                               "vertical_rmse_m": rms(e["vertical"][settled]),
                               "velocity_rmse_m_s": rms(e["velocity"][settled]),
                               "heading_rmse_deg": rms(e["heading"][settled]),
                               "horizontal_max_m": float(e["horizontal"][settled].max()),
                               "rejected": result.rejected}
            if model.outages:
                row[arithmetic]["drift_at_outage_ends_m"] = [float(e["horizontal"][np.searchsorted(t, end) - 1])
                                                             for _, end in model.outages]
        rows.append(row)
        progress(f"{name}: done")

    drone = nv.drone_flight(600.0, RATE_HZ, seed=SEED)
    imu = simulate(drone, nv.datasheet_sensors(RATE_HZ), seed=SEED)
    inp = simulated_input(imu, nv.gnss_fixes(drone, nv.GnssModel(), seed=SEED), baro=nv.baro_samples(drone, seed=SEED))
    results = {a: nav.run(inp, a) for a in ("fixed", "float")}
    row = {"scenario": "drone flight, 10 min, GNSS and the barometer", "fixed_vs_float_m_deg": builds_differ(results)}
    for arithmetic, result in results.items():
        e = nav.errors(result, drone)
        settled = (result.timestamp_us - result.timestamp_us[0]) >= 60e6
        row[arithmetic] = {"horizontal_rmse_m": rms(e["horizontal"][settled]),
                           "vertical_rmse_m": rms(e["vertical"][settled]),
                           "velocity_rmse_m_s": rms(e["velocity"][settled]),
                           "heading_rmse_deg": rms(e["heading"][settled]), "rejected": result.rejected}
    rows.append(row)
    progress("drone flight: done")

    walk = nv.foot_walk(300.0, RATE_HZ, seed=SEED)
    imu = simulate(walk, nv.datasheet_sensors(RATE_HZ), seed=SEED)
    results = {a: nav.run(simulated_input(imu, start_marker(walk, 0.01)), a) for a in ("fixed", "float")}
    walked = float(np.sum(np.linalg.norm(walk.vel_enu[:, :2], axis=1)) / RATE_HZ)
    row = {"scenario": f"foot-mounted walk, 5 min ({walked:.0f} m), no GNSS, zero velocity",
           "fixed_vs_float_m_deg": builds_differ(results)}
    for arithmetic, result in results.items():
        end = float(nav.errors(result, walk)["horizontal"][-1])
        row[arithmetic] = {"end_error_m": end, "end_error_percent": 100.0 * end / walked}
    rows.append(row)
    progress("foot walk: done")

    hand = nv.handheld_walk(600.0, RATE_HZ, seed=SEED)
    imu = simulate(hand, nv.datasheet_sensors(RATE_HZ), seed=SEED)
    markers = nv.marker_fixes(hand, 60.0, 0.1, seed=SEED)
    results = {a: nav.run(simulated_input(imu, start_marker(hand, 0.1, markers)), a) for a in ("fixed", "float")}
    row = {"scenario": "handheld walk indoors, 10 min, a marker (0.1 m) each minute",
           "fixed_vs_float_m_deg": builds_differ(results)}
    for arithmetic, result in results.items():
        before = nav.errors(result, hand)["horizontal"][markers.index - 1]
        row[arithmetic] = {"error_before_each_marker_m": [round(float(x), 1) for x in before]}
    rows.append(row)
    progress("handheld walk: done")
    rows.append(without_gnss(progress))
    return rows


def without_gnss(progress=lambda _m: None) -> dict:
    """The attitude without GNSS or fixes (a start at a known place), the nav filter's against
    the attitude ESKF's (default settings) on the same samples: RMSE (deg) after the first
    minute."""
    from imulink import core

    row = {"scenario": "no GNSS, no fixes: attitude RMSE, nav filter (fixed) vs attitude ESKF (fixed)",
           "fixed_vs_float_m_deg": None}
    for name, traj in (("car drive 20 min", nv.car_drive(1200.0, RATE_HZ, seed=SEED)),
                       ("drone flight 10 min", nv.drone_flight(600.0, RATE_HZ, seed=SEED)),
                       ("handheld walk 10 min", nv.handheld_walk(600.0, RATE_HZ, seed=SEED)),
                       ("foot walk 5 min", nv.foot_walk(300.0, RATE_HZ, seed=SEED))):
        imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=SEED)
        estimate = nav.run(simulated_input(imu, start_marker(traj, 1.0)), "fixed").quat
        eskf = core.run("eskf", imu.gyr, imu.acc, imu.mag, rate_hz=RATE_HZ, arithmetic="fixed").quat
        errors_deg = []
        for q in (estimate, eskf):
            dot = np.minimum(np.abs(np.sum(q * traj.quat, axis=1)) / np.linalg.norm(q, axis=1), 1.0)
            errors_deg.append(rms(np.degrees(2.0 * np.arccos(dot))[int(60 * RATE_HZ):]))
        row[name] = {"nav_deg": errors_deg[0], "eskf_deg": errors_deg[1]}
        progress(f"without GNSS, {name}: done")
    return row


def _plain(value):
    """`value` with numpy's scalars and arrays and tuples made JSON's types."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def rough_case(case: tuple[str, int]) -> dict:
    """One rough scenario and seed: its metrics in both builds, its clean twin's (fixed build),
    the GNSS fixes alone, and the builds' largest difference."""
    name, seed = case
    scenario = ns.build(name, seed)
    results = {a: nav.run(scenario.inp, a) for a in ("fixed", "float")}
    row = {"name": name, "seed": seed, "description": scenario.description, "targets": dict(scenario.targets),
           "events": _plain(scenario.events), "fixed_vs_float_m_deg": builds_differ(results),
           "clean": ns.evaluate(scenario, nav.run(scenario.clean, "fixed"), clean=True),
           "gnss": ns.gnss_alone(scenario)}
    for arithmetic, result in results.items():
        row[arithmetic] = ns.evaluate(scenario, result)
    return row


def _case_process(case: tuple[str, int], pipe) -> None:
    try:
        pipe.send(rough_case(case))
    except Exception as exc:  # reported in the parent, with the case it belongs to
        pipe.send(exc)
    pipe.close()


def run_cases(cases: list[tuple[str, int]], processes: int, timeout_s: float, progress=lambda _m: None):
    """rough_case over `cases`, `processes` at a time, each in a process of its own, so that a
    case that takes longer than `timeout_s` (s; a filter that never returns) is ended, and one
    whose process dies (a crash in the C core) or raises is reported, instead of either
    holding the benchmark up or ending it. Yields (case, row), row a str saying why it failed."""
    context = multiprocessing.get_context("fork")
    waiting, running = list(cases), []
    while waiting or running:
        while waiting and len(running) < processes:
            case = waiting.pop(0)
            receive, send = context.Pipe(duplex=False)
            process = context.Process(target=_case_process, args=(case, send), daemon=True)
            process.start()
            send.close()
            running.append((case, process, receive, time.monotonic()))
        multiprocessing.connection.wait([r for _, _, r, _ in running], timeout=1.0)
        for entry in list(running):
            case, process, receive, started = entry
            if receive.poll():
                try:
                    row = receive.recv()
                except EOFError:  # the process died without a word
                    row = None
            elif time.monotonic() - started > timeout_s:
                process.kill()
                row = f"timed out after {timeout_s:g} s"
            elif not process.is_alive():
                row = None
            else:
                continue
            process.join()
            receive.close()
            running.remove(entry)
            if row is None:
                row = f"the process died (exit code {process.exitcode})"
            elif isinstance(row, Exception):
                row = f"raised {row!r}"
            yield case, row


def _failed_case(case: tuple[str, int], why: str) -> dict:
    """A case that failed (`why`), as a row: every metric NaN (the worst), the clean twin's
    too; the GNSS fixes' as they are."""
    name, seed = case
    scenario = ns.build(name, seed)
    nan = {metric: math.nan for metric in scenario.metrics}
    return {"name": name, "seed": seed, "description": scenario.description, "targets": dict(scenario.targets),
            "events": _plain(scenario.events), "fixed_vs_float_m_deg": (math.nan, math.nan), "clean": nan,
            "gnss": ns.gnss_alone(scenario), "fixed": nan, "float": dict(nan), "failed": why}


def _worst(rows: list[dict], column: str, metric: str) -> tuple[float | None, int | None]:
    """The largest (worst: every metric is an error) value of a metric over the seeds, and its
    seed; a NaN (nothing measured, or a run that failed) is the worst of all."""
    values = [(row[column][metric], row["seed"]) for row in rows if row[column][metric] is not None]
    if not values:
        return None, None
    return max(values, key=lambda v: (math.isnan(v[0]), v[0]))


def rough(seeds: int, progress=lambda _m: None, timeout_s: float = 300.0) -> list[dict]:
    """Every rough scenario over seeds 0..seeds-1, in parallel: per scenario, each metric's
    worst seed in each build, the clean twin's and the GNSS fixes' worst, and the target. A
    case that takes longer than `timeout_s` (s), or crashes, counts as failed: NaN, the worst."""
    cases = [(name, seed) for name in ns.SCENARIOS for seed in range(seeds)]
    rows: dict[str, list[dict]] = {name: [] for name in ns.SCENARIOS}
    processes = max(1, min(2, os.cpu_count() or 1, len(cases)))
    for case, row in run_cases(cases, processes, timeout_s, progress):
        if isinstance(row, str):
            progress(f"{case[0]} seed {case[1]}: FAILED, {row}")
            row = _failed_case(case, row)
        else:
            progress(f"{case[0]} seed {case[1]}: done")
        rows[case[0]].append(row)
    table = []
    for name, runs in rows.items():
        runs.sort(key=lambda r: r["seed"])
        metrics = {}
        for metric in runs[0]["fixed"]:
            entry = {column: _worst(runs, column, metric) for column in ("fixed", "float", "clean", "gnss")}
            limit = runs[0]["targets"].get(metric)
            entry["target"] = limit
            if limit is not None:
                worst = [entry[a][0] for a in ("fixed", "float")]
                entry["met"] = all(v is not None and v <= limit for v in worst)
            metrics[metric] = entry
        differ = max(runs, key=lambda r: (math.isnan(r["fixed_vs_float_m_deg"][0]), r["fixed_vs_float_m_deg"][0]))
        table.append({"scenario": name, "description": runs[0]["description"], "seeds": [r["seed"] for r in runs],
                      "metrics": metrics, "fixed_vs_float_m_deg": list(differ["fixed_vs_float_m_deg"]),
                      "fixed_vs_float_worst_seed": differ["seed"], "events": {r["seed"]: r["events"] for r in runs},
                      "failed": {r["seed"]: r["failed"] for r in runs if "failed" in r}})
    return table


def _cell(value_seed, seed: bool = True) -> str:
    value, at = value_seed
    if value is None:
        return "-"
    text = f"{value:.3g}" if isinstance(value, float) else f"{value}"
    return f"{text} (seed {at})" if seed else text


def print_rough(table: list[dict]) -> None:
    for row in table:
        seeds = row["seeds"]
        print(f"\n{row['scenario']}: {row['description']}")
        print(f"seeds {seeds[0]}-{seeds[-1]}; each metric at its worst seed; the clean twin: the same runs without "
              "the conditions (fixed build); GNSS alone: the fixes' own errors")
        print("| metric | fixed | float | clean twin | GNSS alone | target | met |")
        print("|---|---:|---:|---:|---:|---:|---|")
        for metric, entry in row["metrics"].items():
            target = "-" if entry["target"] is None else f"<= {entry['target']:g}"
            met = "" if entry["target"] is None else ("yes" if entry["met"] else "NO")
            print(f"| {metric} | {_cell(entry['fixed'])} | {_cell(entry['float'])} | {_cell(entry['clean'], False)} "
                  f"| {_cell(entry['gnss'], False)} | {target} | {met} |")
        m, deg = row["fixed_vs_float_m_deg"]
        seed = row["fixed_vs_float_worst_seed"]
        print(f"fixed vs float (max over the seeds): {m:.3f} m, {deg:.4f} deg (seed {seed})")
        for seed, why in row["failed"].items():
            print(f"FAILED: seed {seed}: {why} (its metrics nan)")


#: Q formats of the fixed build's latitude and longitude, velocity and quaternion (those of
#: NAV_STATE's lat and vel and ESTIMATE's quat in shared/protocol.toml).
ANGLE_Q = protocol.frac_bits("NAV_STATE", "lat")
VEL_Q = protocol.frac_bits("NAV_STATE", "vel")
QUAT_Q = protocol.frac_bits("ESTIMATE", "quat")


def to_words(values, q: int) -> list[int]:
    return [int(v) for v in np.rint(np.asarray(values, dtype=np.float64) * 2.0 ** q)]


def arm_cost(seconds: float, build_dir: Path, progress=lambda _m: None) -> dict:
    """The Cortex-M4 build over the first `seconds` of the car drive, every sample compared
    with the x86 fixed build."""
    build = bench_arm.build_arm(build_dir)
    bench_arm.check_no_float(build)
    traj, imu = car_drive(seconds / 60.0)
    fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=SEED)
    inp = simulated_input(imu, fixes, baro=nv.baro_samples(traj, seed=SEED))
    host = nav.run(inp, "fixed")
    progress(f"built {build.elf}; the x86 fixed build run on {len(inp)} samples")
    emu = bench_arm.Emulator(build)

    def fix_bytes(j: int) -> bytes:
        lat, lon = math.radians(float(inp.fix_lat_deg[j])), math.radians(float(inp.fix_lon_deg[j]))
        words = [0, *to_words([lat, lon], ANGLE_Q), *to_words([inp.fix_height_m[j] * 1000.0], 0),
                 *to_words(inp.fix_vel_enu[j], VEL_Q), 1,
                 *to_words([inp.fix_h_acc_m[j] * 1000.0, inp.fix_v_acc_m[j] * 1000.0,
                            inp.fix_s_acc_m_s[j] * 1000.0], 0), 0]
        return struct.pack("<12i", *words)

    g_addr, a_addr, m_addr = (emu.address(n) for n in ("bench_navkf_gyr", "bench_navkf_acc", "bench_navkf_mag"))
    state, fix_addr = emu.address("bench_navkf"), emu.address("bench_navkf_fix")
    emu.write(fix_addr, fix_bytes(0))
    emu.write(a_addr, struct.pack("<3i", *to_words(inp.acc[0], 16)))
    emu.write(m_addr, struct.pack("<3i", *to_words(inp.mag[0], 16)))
    status = emu.call("bench_navkf_start", to_words([RATE_HZ], 16)[0]).value
    if status != 0:
        raise bench_arm.BenchError(f"bench_navkf_start returned {status}")
    fix_at = {int(k): j for j, k in enumerate(inp.fix_index) if j > 0}
    baro_at = {int(k): int(np.rint(p)) for k, p in zip(inp.baro_index, inp.baro_pa)}
    expected = np.c_[to_words(np.radians(host.lat_deg), ANGLE_Q), to_words(np.radians(host.lon_deg), ANGLE_Q),
                     np.rint(host.height_m * 1000.0), np.rint(host.vel_enu * 2.0 ** VEL_Q),
                     np.rint(host.quat * 2.0 ** QUAT_Q)].astype(np.int64)
    steps, ended, fix_counts, baro_counts, stack = [], [], [], [], 0
    for k in range(1, len(inp)):
        emu.write(g_addr, struct.pack("<3i", *to_words(inp.gyr[k], 24)))
        emu.write(a_addr, struct.pack("<3i", *to_words(inp.acc[k], 16)))
        emu.write(m_addr, struct.pack("<3i", *to_words(inp.mag[k], 16)))
        r = emu.call("imu_navkf_step", state, g_addr, a_addr, m_addr)
        steps.append(r.instructions)
        stack = max(stack, r.stack)
        emu.call("bench_navkf_read")
        ended.append(struct.unpack("<14i", emu.read("bench_navkf_out", 56))[13] == 0)
        if k in baro_at:
            r = emu.call("imu_navkf_baro", state, baro_at[k] & 0xFFFFFFFF)
            baro_counts.append(r.instructions)
            stack = max(stack, r.stack)
        if k in fix_at:
            emu.write(fix_addr, fix_bytes(fix_at[k]))
            r = emu.call("imu_navkf_fix", state, fix_addr)
            fix_counts.append(r.instructions)
            stack = max(stack, r.stack)
        emu.call("bench_navkf_read")
        out = struct.unpack("<14i", emu.read("bench_navkf_out", 56))
        if out[10] != 0:
            raise bench_arm.BenchError(f"sample {k}: {out[10]} saturations")
        if not np.array_equal(np.array(out[:10]), expected[k]):
            raise bench_arm.BenchError(f"sample {k}: the Cortex-M4 build differs from the x86 fixed build: "
                                       f"{list(out[:10])} vs {expected[k].tolist()}")
    steps, ended = np.array(steps), np.array(ended)
    return {
        "compiler": build.compiler,
        "samples": len(steps),
        "fixes": len(fix_counts),
        "step_mean": float(steps.mean()),
        "step_max": int(steps.max()),
        "step_covariance_mean": float(steps[ended].mean()),
        "step_other_mean": float(steps[~ended].mean()),
        "fix_mean": float(np.mean(fix_counts)),
        "fix_max": int(np.max(fix_counts)),
        "baro_mean": float(np.mean(baro_counts)),
        "baro_max": int(np.max(baro_counts)),
        "per_step_with_fixes_mean": float((steps.sum() + np.sum(fix_counts) + np.sum(baro_counts)) / len(steps)),
        "stack_bytes": int(stack),
        "state_bytes": build.symbols["bench_navkf"].size,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--seconds", type=float, default=60.0,
                        help="seconds of the car drive the Cortex-M4 build runs (default 60)")
    parser.add_argument("--no-accuracy", action="store_true", help="skip the accuracy scenarios")
    parser.add_argument("--no-arm", action="store_true", help="skip the Cortex-M4 cost")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--rough", action="store_true",
                        help="the rough scenarios (imulink.analysis.nav_scenarios) instead of the accuracy ones")
    parser.add_argument("--seeds", type=int, default=3, help="with --rough: seeds 0..N-1 of each scenario (default 3)")
    parser.add_argument("--case-timeout", type=float, default=300.0,
                        help="with --rough: seconds a scenario and seed may take before it counts as failed "
                        "(default 300)")
    args = parser.parse_args()
    if args.seconds < 2.0:
        parser.error("--seconds must be at least 2 (a fix each second)")
    if args.seeds < 1:
        parser.error("--seeds must be at least 1")
    started = time.perf_counter()
    log = (lambda m: None) if args.json else (lambda m: print(m, file=sys.stderr))
    out = {}
    try:
        if args.rough:
            out["rough"] = rough(args.seeds, log, args.case_timeout)
        elif not args.no_accuracy:
            out["accuracy"] = accuracy(log)
        if not args.no_arm:
            with tempfile.TemporaryDirectory(prefix="bench_nav.") as tmp:
                out["arm"] = arm_cost(args.seconds, Path(tmp), log)
    except bench_arm.BenchError as exc:
        print(f"bench_nav: {exc}", file=sys.stderr)
        return 1
    out["run_s"] = time.perf_counter() - started
    if args.json:
        print(json.dumps(_plain(out) if args.rough else out, indent=2))
        return 0
    if "rough" in out:
        print_rough(out["rough"])
    for row in out.get("accuracy", []):
        print(f"{row['scenario']}:")
        for key in (k for k in row if k not in ("scenario", "fixed_vs_float_m_deg")):
            values = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row[key].items())
            print(f"  {key}: {values}")
        if row["fixed_vs_float_m_deg"] is not None:
            print(f"  fixed vs float: {row['fixed_vs_float_m_deg'][0]:.3f} m, {row['fixed_vs_float_m_deg'][1]:.4f} deg")
    if "arm" in out:
        r = out["arm"]
        print(f"\nCortex-M4 ({r['compiler']}), the car drive's {r['samples']} samples, {r['fixes']} fixes and its "
              "barometer, every sample identical to the x86 fixed build:")
        print("| measured | instructions |")
        print("|---|---:|")
        print(f"| imu_navkf_step, mean / max | {r['step_mean']:.0f} / {r['step_max']} |")
        print(f"| ... samples that end a covariance interval (50 ms), mean | {r['step_covariance_mean']:.0f} |")
        print(f"| ... the other samples, mean | {r['step_other_mean']:.0f} |")
        print(f"| imu_navkf_fix (GNSS position and velocity), mean / max | {r['fix_mean']:.0f} / {r['fix_max']} |")
        print(f"| imu_navkf_baro (50 Hz, an update once a second), mean / max | {r['baro_mean']:.0f} / "
              f"{r['baro_max']} |")
        print(f"| per IMU sample with the fixes and the barometer, mean | {r['per_step_with_fixes_mean']:.0f} |")
        print(f"\nstack {r['stack_bytes']} B (painted), imu_navkf_t {r['state_bytes']} B")
    print(f"\nruntime: {out['run_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
