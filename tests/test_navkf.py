"""The `nav` filter (firmware/core/imu_navkf.c) against the navigation simulator, in both
builds through imulink.analysis.nav (cffi): a car drive with the MPU6050 data sheet's noise and
turn-on biases and a 1 Hz receiver (issue 16's numbers), GNSS outages, a multipath jump,
a receiver's latency, a foot-mounted walk with zero-velocity updates and no GNSS, a
handheld walk with a marker each minute; the fixed build against the float twin; and the
C core under the sanitizers with every narrowing checked (tests/c/navkf_driver.c)."""
from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imulink.analysis import nav
from imulink.io.nav_input import simulated_input
from imulink.io.sensor_input import InputError
from imulink.sim import navigation as nv
from imulink.sim import simulate

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "firmware" / "core"
RATE = 100.0


def sensors():
    return nv.datasheet_sensors(RATE)


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def both(inp):
    return {a: nav.run(inp, a) for a in ("fixed", "float")}


def assert_builds_agree(results, position_m=0.1, attitude_deg=0.05):
    fixed, flt = results["fixed"], results["float"]
    d = nv.local_offsets(fixed.lat_deg, fixed.lon_deg, fixed.height_m, flt.lat_deg, flt.lon_deg, flt.height_m)
    assert np.abs(d).max() <= position_m
    dot = np.abs(np.sum(fixed.quat * flt.quat, axis=1)) / np.linalg.norm(fixed.quat, axis=1)
    assert np.degrees(2.0 * np.arccos(np.minimum(dot, 1.0))).max() <= attitude_deg
    assert fixed.saturations == 0


@pytest.fixture(scope="module")
def drive():
    traj = nv.car_drive(1200.0, RATE, seed=0)
    return traj, simulate(traj, sensors(), seed=0)


def test_car_drive_meets_the_issues_numbers(drive):
    """20 min, GNSS at 1 Hz with white errors of 2.5 m horizontal, 5 m vertical, 0.1 m/s:
    horizontal RMSE <= 1.2 m, velocity <= 0.08 m/s, heading <= 1 deg (after the first
    minute), in both builds, which agree to 0.1 m and 0.05 deg."""
    traj, imu = drive
    results = both(simulated_input(imu, nv.gnss_fixes(traj, nv.GnssModel(), seed=0)))
    for result in results.values():
        e = nav.errors(result, traj)
        settled = (result.timestamp_us - result.timestamp_us[0]) >= 60e6
        assert rms(e["horizontal"][settled]) <= 1.2
        assert rms(e["velocity"][settled]) <= 0.08
        assert rms(e["heading"][settled]) <= 1.0
        assert rms(e["vertical"][settled]) <= 1.5  # GNSS alone: its 5 m vertical, filtered
        assert result.rejected <= 2  # white errors: the gate lets nearly all in
        # the reported uncertainty matches the error: the horizontal sigma within a factor 2 of the RMSE
        sigma = rms(np.hypot(result.sigma[settled, 0], result.sigma[settled, 1]))
        assert 0.5 <= sigma / rms(e["horizontal"][settled]) <= 2.0
    assert_builds_agree(results)


def test_the_barometer_holds_the_height(drive):
    """With the MS5611 (50 Hz: noise, a temperature drift, the weather), the vertical RMSE
    falls from GNSS's to within 0.5 m (the issue asks 1 m), in both builds."""
    traj, imu = drive
    fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=0)
    without = nav.run(simulated_input(imu, fixes), "fixed")
    results = both(simulated_input(imu, fixes, baro=nv.baro_samples(traj, seed=0)))
    settled = slice(6000, None)
    for result in results.values():
        vertical = rms(nav.errors(result, traj)["vertical"][settled])
        assert vertical <= 0.5 and vertical < 0.8 * rms(nav.errors(without, traj)["vertical"][settled])
        assert result.sigma[-1, 15] < 1.0  # the barometer's bias is learnt from the fixes
    assert_builds_agree(results)


def test_the_antennas_lever_arm_is_taken_into_account(drive):
    """An antenna 0.5 m right, 1.5 m forward and 1.2 m above the sensor: with its lever arm
    the filter is as accurate as with the antenna at the sensor; without, it is not."""
    traj, imu = drive
    arm = np.array([0.5, 1.5, 1.2])
    inp = simulated_input(imu, nv.antenna_fixes(traj, nv.gnss_fixes(traj, nv.GnssModel(), seed=0), arm))
    settled = slice(6000, None)
    results = {a: nav.run(inp, a, lever_arm_m=arm) for a in ("fixed", "float")}
    for result in results.values():
        e = nav.errors(result, traj)
        assert rms(e["horizontal"][settled]) <= 1.2 and rms(e["velocity"][settled]) <= 0.08
        assert rms(e["heading"][settled]) <= 1.0
    assert_builds_agree(results)
    ignored = nav.errors(nav.run(inp, "fixed"), traj)
    assert rms(ignored["horizontal"][settled]) > 1.2 * rms(nav.errors(results["fixed"], traj)["horizontal"][settled])
    with pytest.raises(InputError, match="lever arm"):
        nav.run(inp, "fixed", lever_arm_m=(0.0, 11.0, 0.0))


def test_receiver_latency_is_taken_back(drive):
    """Fixes reaching the board 0.2 s after the time they are valid for, in the rows of
    their arrival with their age: as accurate as on time; used as if current they are not."""
    traj, imu = drive
    late = nv.gnss_fixes(traj, nv.GnssModel(latency_s=0.2), seed=0)
    inp = simulated_input(imu, late, at_arrival=True)
    settled = slice(6000, None)
    with_age = rms(nav.errors(nav.run(inp, "fixed"), traj)["horizontal"][settled])
    inp.fix_age_s = None
    without = rms(nav.errors(nav.run(inp, "fixed"), traj)["horizontal"][settled])
    assert with_age <= 1.2
    assert without > 1.5 * with_age


def test_outages_drift_little_and_the_return_is_smooth(drive):
    """Two 30 s outages: mean horizontal drift at their ends <= 10 m; 10 s after each the
    error is back within the fixes' 2.5 m, and no fix was rejected on the return."""
    traj, imu = drive
    spans = ((300.0, 330.0), (700.0, 730.0))
    results = both(simulated_input(imu, nv.gnss_fixes(traj, nv.GnssModel(outages=spans), seed=0)))
    for result in results.values():
        h = nav.errors(result, traj)["horizontal"]
        t = (result.timestamp_us - result.timestamp_us[0]) / 1e6
        drift = [h[np.searchsorted(t, end) - 1] for _, end in spans]
        assert np.mean(drift) <= 10.0
        assert min(drift) > 0.5  # the outage is real: dead reckoning drifts
        for _, end in spans:
            assert h[np.searchsorted(t, end + 10.0)] <= 2.5
        assert result.rejected == 0
        # the covariance grew through the outage
        k = np.searchsorted(t, spans[0][1]) - 1
        assert result.sigma[k, 0] > 3.0 * result.sigma[np.searchsorted(t, spans[0][0]) - 1, 0]
    assert_builds_agree(results)


def test_a_multipath_jump_is_rejected_and_counted(drive):
    """A 19 m jump for 10 s (the receiver does not report it): its fixes are rejected and
    counted, the estimate does not follow it."""
    traj, imu = drive
    model = nv.GnssModel(multipath=((420.0, 430.0, 15.0, -10.0, 5.0),))
    fixes = nv.gnss_fixes(traj, model, seed=0)
    for arithmetic in ("fixed", "float"):
        result = nav.run(simulated_input(imu, fixes), arithmetic)
        t = (result.timestamp_us - result.timestamp_us[0]) / 1e6
        jumped = (fixes.t_valid[1:] >= 420.0) & (fixes.t_valid[1:] < 430.0)
        assert not result.fix_accepted[jumped].any()
        assert result.rejected == int(jumped.sum()) == 10
        assert result.gated()[-1] == 10
        during = (t >= 420.0) & (t < 440.0)
        assert nav.errors(result, traj)["horizontal"][during].max() < 3.0


def test_a_receivers_fix_without_velocity_is_gated_a_markers_is_not(drive):
    """An NMEA receiver's fixes (GGA: no velocity) with the multipath jump: gated as the
    receiver's they are; taken as markers' (a CSV's row without velocity) they are not."""
    traj, imu = drive
    inp = simulated_input(imu, nv.gnss_fixes(traj, nv.GnssModel(multipath=((420.0, 430.0, 15.0, -10.0, 5.0),)),
                                             seed=0))
    inp.fix_vel_enu = np.full_like(inp.fix_vel_enu, np.nan)
    inp.fix_s_acc_m_s = np.full_like(inp.fix_s_acc_m_s, np.nan)
    inp.fix_is_marker = np.zeros(len(inp.fix_index), bool)
    receiver = nav.run(inp, "fixed")
    assert receiver.rejected >= 9
    assert nav.errors(receiver, traj)["horizontal"][42000:44000].max() < 5.0
    inp.fix_is_marker = None
    assert nav.run(inp, "fixed").rejected == 0


def test_foot_walk_with_zero_velocity_returns_within_two_percent():
    """5 min of laps with a foot-mounted sensor, no GNSS, a start at a known place: zero
    velocity in every stance keeps the return-to-start error within 2 % of the distance."""
    traj = nv.foot_walk(300.0, RATE, seed=0)
    imu = simulate(traj, sensors(), seed=0)
    start = nv.MarkerFixes(index=np.array([0]), lat_deg=traj.lat_deg[:1], lon_deg=traj.lon_deg[:1],
                           height_m=traj.height_m[:1], accuracy_m=0.01, truth_pos_enu=traj.pos_enu[:1])
    results = both(simulated_input(imu, start))
    walked = float(np.sum(np.linalg.norm(traj.vel_enu[:, :2], axis=1)) / RATE)
    for result in results.values():
        assert result.zero_velocity > 2000  # every stance, each 50 ms
        end = nav.errors(result, traj)["horizontal"][-1]
        assert end <= 0.02 * walked
    assert_builds_agree(results, position_m=0.1)


def test_handheld_walk_is_pulled_back_by_each_marker():
    """10 min indoors, a marker each minute (0.1 m): the error just after each marker is
    below 0.5 m whatever it was before; no marker is rejected."""
    traj = nv.handheld_walk(600.0, RATE, seed=0)
    imu = simulate(traj, sensors(), seed=0)
    markers = nv.marker_fixes(traj, 60.0, 0.1, seed=0)
    every = nv.MarkerFixes(index=np.r_[0, markers.index], lat_deg=np.r_[traj.lat_deg[0], markers.lat_deg],
                           lon_deg=np.r_[traj.lon_deg[0], markers.lon_deg],
                           height_m=np.r_[traj.height_m[0], markers.height_m], accuracy_m=0.1,
                           truth_pos_enu=np.vstack([traj.pos_enu[:1], markers.truth_pos_enu]))
    for arithmetic in ("fixed", "float"):
        result = nav.run(simulated_input(imu, every), arithmetic)
        h = nav.errors(result, traj)["horizontal"]
        assert result.fix_accepted.all()
        assert h[markers.index].max() < 0.5
        assert h[markers.index - 1].max() > 2.0  # between markers it drifts: the markers do the work


@pytest.mark.parametrize("scenario", ["car", "handheld"])
def test_without_gnss_the_attitude_is_at_least_the_eskfs(scenario):
    """No GNSS and no fixes after a start at a known place: the accelerometer's tilt and the
    magnetometer's heading keep the attitude at least as well as the attitude ESKF (default
    settings) on the same samples."""
    from imulink import core

    make = {"car": lambda: nv.car_drive(300.0, RATE, seed=3), "handheld": lambda: nv.handheld_walk(300.0, RATE, seed=3)}
    traj = make[scenario]()
    imu = simulate(traj, sensors(), seed=3)
    start = nv.MarkerFixes(index=np.array([0]), lat_deg=traj.lat_deg[:1], lon_deg=traj.lon_deg[:1],
                           height_m=traj.height_m[:1], accuracy_m=1.0, truth_pos_enu=traj.pos_enu[:1])
    estimate = nav.run(simulated_input(imu, start), "fixed").quat
    eskf = core.run("eskf", imu.gyr, imu.acc, imu.mag, rate_hz=RATE, arithmetic="fixed").quat

    def attitude_rmse(q):
        dot = np.minimum(np.abs(np.sum(q * traj.quat, axis=1)) / np.linalg.norm(q, axis=1), 1.0)
        return rms(np.degrees(2.0 * np.arccos(dot))[6000:])

    assert attitude_rmse(estimate) <= attitude_rmse(eskf)


def test_a_run_needs_a_fix_and_a_rate_the_filter_takes(drive):
    traj, imu = drive
    inp = simulated_input(imu, None)
    with pytest.raises(InputError, match="no GNSS or position fix"):
        nav.run(inp)
    fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=0)
    fast = simulated_input(imu, fixes)
    fast.timestamp_us = fast.timestamp_us // 20  # 2 kHz
    with pytest.raises(InputError, match="2000 Hz"):
        nav.run(fast)
    late = simulated_input(imu, fixes)
    late.fix_age_s = np.full(len(fixes), 1.5)
    with pytest.raises(InputError, match="1.5 s old"):
        nav.run(late)


# ---------------------------------------------------------------- the C core, sanitized

GCC = shutil.which("gcc")


@pytest.fixture(scope="module")
def drivers(tmp_path_factory):
    if GCC is None:
        pytest.skip("gcc not found")
    out = {}
    for build in ("FIXED", "FLOAT"):
        exe = tmp_path_factory.mktemp("navkf") / f"navkf_{build.lower()}"
        checked = ["-DIMU_CHECK_NARROWING"] if build == "FIXED" else []
        proc = subprocess.run([GCC, "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", f"-DIMU_{build}", *checked,
                               f"-I{CORE}", "-fsanitize=undefined,address", "-fno-sanitize-recover=all", "-o", str(exe),
                               str(ROOT / "tests" / "c" / "navkf_driver.c"),
                               *(str(CORE / name) for name in ("imu_navkf.c", "imu_nav.c", "imu_navcov.c",
                                                                "imu_math.c")),
                               "-lm"], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        out[build.lower()] = exe
    return out


def driver_text(inp) -> str:
    """The driver's input for a NavInput: start at its first fix ("b" GNSS, "k" a marker),
    its samples, each barometer sample and later fix after the sample of its row."""
    def fix_words(j):
        has_vel = not math.isnan(inp.fix_s_acc_m_s[j])
        vel = inp.fix_vel_enu[j] if has_vel else (0.0, 0.0, 0.0)
        values = (inp.fix_lat_deg[j], inp.fix_lon_deg[j], inp.fix_height_m[j], *vel, inp.fix_h_acc_m[j],
                  inp.fix_v_acc_m[j], inp.fix_s_acc_m_s[j] if has_vel else 1.0)
        return ("f " if has_vel else "m ") + " ".join(f"{x:.12f}" for x in values) + f" {int(has_vel)}"

    first = fix_words(0)
    lines = [repr(RATE), ("b" if first[0] == "f" else "k") + first[1:] + " "
             + " ".join(repr(float(x)) for x in (*inp.acc[0], *inp.mag[0]))]
    after = {int(k): j for j, k in enumerate(inp.fix_index) if j > 0}
    baro = {int(k): float(p) for k, p in zip(inp.baro_index, inp.baro_pa)}
    for k in range(1, len(inp)):
        lines.append("s " + " ".join(repr(float(x)) for x in (*inp.gyr[k], *inp.acc[k], *inp.mag[k])))
        if k in baro:
            lines.append(f"p {baro[k]!r}")
        if k in after:
            lines.append(fix_words(after[k]) + " 0")
    return "\n".join(lines) + "\n"


def run_driver(exe, text: str) -> tuple[np.ndarray, str]:
    proc = subprocess.run([str(exe)], input=text, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rows = proc.stdout.strip().split("\n")
    assert rows[-1].startswith("rejected "), rows[-1]
    return np.array([r.split() for r in rows[:-1]], dtype=float), rows[-1]


@pytest.mark.parametrize("scenario", ["car", "foot"])
def test_the_core_is_clean_under_the_sanitizers(drivers, scenario):
    """A minute of the car drive with a multipath jump and a barometer, and of the foot walk, through the C
    core built with -fsanitize=undefined,address, the fixed build with every int64 -> int32
    narrowing checked: no report, no saturation, and the same estimate as the cffi build."""
    if scenario == "car":
        traj = nv.car_drive(60.0, RATE, seed=1)
        imu = simulate(traj, sensors(), seed=1)
        fixes = nv.gnss_fixes(traj, nv.GnssModel(multipath=((40.0, 45.0, 20.0, 0.0, 0.0),)), seed=1)
        inp = simulated_input(imu, fixes, baro=nv.baro_samples(traj, seed=1))
    else:
        traj = nv.foot_walk(60.0, RATE, seed=1)
        imu = simulate(traj, sensors(), seed=1)
        start = nv.MarkerFixes(index=np.array([0]), lat_deg=traj.lat_deg[:1], lon_deg=traj.lon_deg[:1],
                               height_m=traj.height_m[:1], accuracy_m=0.05 / math.sqrt(2.0),
                               truth_pos_enu=traj.pos_enu[:1])
        inp = simulated_input(imu, start)
    assert inp.fix_index[0] == 0
    for build in ("fixed", "float"):
        rows, tail = run_driver(drivers[build], driver_text(inp))
        assert tail.endswith("saturations 0"), tail
        reference = nav.run(inp, build)
        assert len(rows) == len(reference) - 1
        # the driver prints a sample's state before the fix or barometer sample that follows
        # it, imulink.analysis.nav after
        same = ~np.isin(np.arange(1, len(reference)), np.r_[inp.fix_index, inp.baro_index])
        np.testing.assert_allclose(rows[same, 3:6], reference.vel_enu[1:][same], atol=1e-6)
        d = nv.local_offsets(rows[same, 0], rows[same, 1], rows[same, 2], reference.lat_deg[1:][same],
                             reference.lon_deg[1:][same], reference.height_m[1:][same])
        assert np.abs(d).max() < 2e-3  # the driver prints 1e-12 deg and 1 um


# ---------------------------------------------------------------- imulink nav

def nav_cli(capsys, *argv):
    from imulink.cli import main

    code = main(["nav", *(str(a) for a in argv)])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def drive_csv(tmp_path_factory):
    """Two minutes of the car drive as a navigation CSV, with the truth (ignored by readers)."""
    from imulink.io.nav_input import write_nav_csv

    traj = nv.car_drive(120.0, RATE, seed=2)
    imu = simulate(traj, sensors(), seed=2)
    path = tmp_path_factory.mktemp("navcsv") / "drive.csv"
    write_nav_csv(path, imu, nv.gnss_fixes(traj, nv.GnssModel(), seed=2), truth=traj)
    return traj, path


def test_imulink_nav_writes_the_estimate_of_every_sample(drive_csv, tmp_path, capsys):
    import json

    traj, path = drive_csv
    out = tmp_path / "nav.csv"
    code, stdout, _ = nav_cli(capsys, path, "--csv", out, "--json")
    assert code == 0
    report = json.loads(stdout)
    assert report["samples"] == report["rows_written"] == len(traj.t) and report["fixes"] == 120
    assert report["fixes_used"] + report["fixes_gated"] == 120 and report["saturations"] == 0
    estimate = np.genfromtxt(out, delimiter=",", names=True)
    assert estimate.dtype.names == ("timestamp_us",) + nav.OUTPUT_COLUMNS
    e = nv.local_offsets(estimate["lat_deg"], estimate["lon_deg"], estimate["height_m"], traj.lat_deg, traj.lon_deg,
                         traj.height_m)
    assert rms(np.hypot(e[10000:, 0], e[10000:, 1])) < 1.5
    np.testing.assert_allclose(estimate["vel_e_m_s"][10000:], traj.vel_enu[10000:, 0], atol=0.5)
    assert (estimate["fix_age_s"] <= 1.01).all() and estimate["sd_east_m"].min() > 0
    float_out = tmp_path / "nav_float.csv"
    assert nav_cli(capsys, path, "--csv", float_out, "--arith", "float")[0] == 0
    other = np.genfromtxt(float_out, delimiter=",", names=True)
    d = nv.local_offsets(estimate["lat_deg"], estimate["lon_deg"], estimate["height_m"], other["lat_deg"],
                         other["lon_deg"], other["height_m"])
    assert 0 < np.abs(d).max() < 0.1  # two builds, one filter


def test_imulink_nav_refuses_bad_input_in_one_line(drive_csv, tmp_path, capsys):
    traj, path = drive_csv
    out = tmp_path / "nav.csv"
    lines = path.read_text().splitlines()
    keep = [k for k, column in enumerate(lines[0].split(",")) if not column.startswith("gnss_")]
    cases = {
        "missing.csv": (None, "no such file"),
        "no_fix.csv": ("\n".join(",".join(line.split(",")[k] for k in keep) for line in lines),
                       "no GNSS or position fix"),
        "backwards.csv": ("\n".join(lines[:5] + [lines[3]] + lines[5:]), "line 6: timestamp_us"),
        "nan.csv": ("\n".join(lines[:7] + [lines[7].replace(lines[7].split(",")[1], "nan", 1)] + lines[8:]),
                    "line 8: gyr_x_rad_s is 'nan'"),
    }
    for name, (text, message) in cases.items():
        source = tmp_path / name
        if text is not None:
            source.write_text(text + "\n")
        code, _, err = nav_cli(capsys, source, "--csv", out)
        assert code == 2 and err.startswith("imulink: error: ") and err.count("\n") == 1, (name, err)
        assert message in err, (name, err)
        assert not out.exists()
    code, _, err = nav_cli(capsys, path, "--csv", out, "--gnss-latency", "0.1")
    assert code == 2 and "--gnss-latency is for a recording" in err
    code, _, err = nav_cli(capsys, path, "--csv", path)
    assert code == 2 and "is an input of this command" in err


def test_extreme_input_saturates_without_undefined_behaviour(drivers):
    """Inputs no sensor gives but the interfaces take: rates of 100 rad/s and specific forces
    of 20 000 m/s^2 in every direction, fixes across the world and at 85 deg, speeds of
    1 000 m/s, accuracies of 1 mm and of 1 000 km, a second's age, pressures at and beyond
    the barometer's limits, markers far off. The core, under the sanitizers and with every
    narrowing checked, saturates (and counts it) and never overflows; the start refuses what
    is out of its range."""
    rng = np.random.default_rng(7)

    def fix_line(kind, lat, lon, h, vel, h_acc, v_acc, s_acc, has_vel, age):
        return f"{kind} " + " ".join(repr(float(x)) for x in (lat, lon, h, *vel, h_acc, v_acc, s_acc)) \
            + f" {has_vel} {float(age)!r}"

    lines = [repr(RATE), "b 85.0 180.0 9999.0 0 0 0 1000000 1000000 1000 1 0.0 0.0 9.81 0.0 0.0 0.0"]
    for k in range(3000):
        scale = rng.choice([1e-3, 1.0, 100.0])
        gyr = rng.uniform(-1.0, 1.0, 3) * scale
        acc = rng.uniform(-1.0, 1.0, 3) * scale * 200.0
        mag = rng.uniform(-1.0, 1.0, 3) * rng.choice([0.0, 50.0, 30000.0])
        lines.append("s " + " ".join(repr(float(x)) for x in (*gyr, *acc, *mag)))
        if k % 7 == 0:
            lines.append(f"p {float(rng.choice([-5.0, 0.0, 9999.0, 10000.0, 101325.0, 120000.0, 1e7]))!r}")
        if k % 50 == 0:
            lat, lon = rng.uniform(-85.0, 85.0), rng.uniform(-180.0, 180.0)
            vel = rng.uniform(-1000.0, 1000.0, 3)
            acc_m = rng.choice([0.001, 1.0, 1e6])
            lines.append(fix_line("f", lat, lon, rng.uniform(-9000.0, 9000.0), vel, acc_m, acc_m, acc_m, 1,
                                  rng.choice([0.0, 1.0])))
        if k % 300 == 0:
            lines.append(fix_line("m", rng.uniform(-85.0, 85.0), rng.uniform(-180.0, 180.0), 0.0, (0, 0, 0), 0.001,
                                  0.001, 1.0, 0, 0.0))
    for build in ("fixed", "float"):
        rows, tail = run_driver(drivers[build], "\n".join(lines) + "\n")
        assert len(rows) == 3000
        if build == "fixed":
            assert not tail.endswith("saturations 0"), tail  # it did saturate, and said so
    # out of the start's range: a latitude beyond 85 deg, an accuracy of 0, a rate of 5 Hz
    for start in ("b 86.0 0 0 0 0 0 1 1 1 1 0 0 9.81 1 0 0", "b 45.0 0 0 0 0 0 0 1 1 1 0 0 9.81 1 0 0"):
        proc = subprocess.run([str(drivers["fixed"])], input=f"{RATE!r}\n{start}\n", capture_output=True, text=True)
        assert proc.returncode == 3, proc.stderr
    proc = subprocess.run([str(drivers["fixed"])], input="5.0\nb 45.0 0 0 0 0 0 1 1 1 1 0 0 9.81 1 0 0\n",
                          capture_output=True, text=True)
    assert proc.returncode == 3, proc.stderr
