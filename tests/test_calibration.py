"""Sensor calibration (imulink.calibration, `imulink calibrate`): gyroscope bias at rest,
accelerometer six-position (and misalignment), magnetometer ellipsoid fit with coverage;
the calibration file; the command line."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imulink import calibration as cal, sim
from imulink.counts import DEFAULT_PROFILE, STANDARD_GRAVITY, si_to_counts
from imulink.sensor_input import SensorRecord
from imulink.sim.sensors import AccModel, GyroModel, MagModel, SensorSuite

CLI = [sys.executable, "-m", "imulink.cli"]
RATE = 100.0
P = DEFAULT_PROFILE

#: A distorted magnetometer: hard iron (uT) and a symmetric soft-iron matrix.
HARD_IRON = np.array([12.0, -7.0, 20.0])
SOFT_IRON = np.array([[1.10, 0.05, -0.03], [0.05, 0.92, 0.04], [-0.03, 0.04, 1.02]])
MAG_NOISE_UT = 0.2


def record_of(gyr, acc, mag, rate=RATE) -> SensorRecord:
    """SI data as a record read from a file holds it (counts of the default profile)."""
    g, a, m = si_to_counts(gyr, acc, mag, P)
    return SensorRecord("test data", np.arange(len(g)) / rate, g * P.gyro_scale, a * P.acc_scale, m * P.mag_scale,
                        P, None, rate)


def rotating_mag(seconds=120.0, seed=3):
    """The simulator's board turned at random (up to 200 deg/s) for `seconds`, with the
    distorted magnetometer."""
    traj = sim.random_motion(seconds, RATE, seed=seed)
    suite = SensorSuite(GyroModel.seed000(), AccModel(),
                        MagModel(noise_std=MAG_NOISE_UT, hard_iron=HARD_IRON, soft_iron=SOFT_IRON))
    return sim.simulate(traj, suite, seed=seed)


# ---------------------------------------------------------------------------- magnetometer


def test_ellipsoid_fit_recovers_hard_and_soft_iron():
    res = rotating_mag()
    result = cal.mag_ellipsoid(record_of(res.gyr, res.acc, res.mag), P)
    np.testing.assert_allclose(result.offset * P.mag_scale, HARD_IRON, atol=0.05)  # uT
    # the correction undoes the soft iron up to the scale that keeps the mean norm
    product = result.matrix @ SOFT_IRON
    scale = np.trace(product) / 3.0
    np.testing.assert_allclose(product / scale, np.eye(3), atol=1e-3)
    np.testing.assert_allclose(result.matrix, result.matrix.T, atol=1e-12)
    report = result.report
    field_norms = np.linalg.norm(res.mag, axis=1)
    assert report["norm_spread_before_uT"] == pytest.approx(np.std(field_norms))
    assert report["norm_spread_before_uT"] > 5.0
    # after: the sensor's own noise (0.2 uT an axis, the norm's share of it) and the counts' rounding
    assert report["norm_spread_after_uT"] < 1.2 * np.hypot(MAG_NOISE_UT, P.mag_scale / np.sqrt(12))
    assert report["field_norm_uT"] == pytest.approx(np.mean(np.linalg.norm(res.mag - HARD_IRON, axis=1)), rel=2e-3)
    assert report["coverage"]["missing"] == []


def test_coverage_names_the_missing_direction():
    res = rotating_mag(seconds=240.0)
    true_field = res.mag - HARD_IRON  # the field in sensor axes, before the soft iron: its direction is what counts
    body = true_field @ np.linalg.inv(SOFT_IRON).T
    unit = body / np.linalg.norm(body, axis=1, keepdims=True)
    keep = unit[:, 2] > -0.6  # never within 53 deg of -z
    result = cal.mag_ellipsoid(record_of(res.gyr[keep], res.acc[keep], res.mag[keep]), P)
    missing = result.report["coverage"]["missing"]
    assert "-z" in missing and all("-z" in name for name in missing), missing
    assert "+z" not in missing
    found = cal.coverage(body[keep])
    assert found.missing_axes == ["-z"] and found.covered == 26 - len(found.missing)


def test_coverage_of_a_full_sphere_and_of_one_plane():
    rng = np.random.default_rng(0)
    assert cal.coverage(rng.standard_normal((5000, 3))).missing == []
    flat = rng.standard_normal((5000, 3)) * [1.0, 1.0, 0.0]  # the board only turned about z
    found = cal.coverage(flat)
    assert set(found.missing_axes) == {"+z", "-z"}


def test_mag_turned_in_one_plane_is_no_ellipsoid():
    res = sim.simulate(sim.turntable(60.0, RATE, rate_dps=30.0),
                       SensorSuite(GyroModel.ideal(), AccModel(), MagModel(hard_iron=HARD_IRON)), seed=1)
    with pytest.raises(cal.CalibrationError, match="more directions"):
        cal.mag_ellipsoid(record_of(res.gyr, res.acc, res.mag), P)


# ---------------------------------------------------------------------------- gyroscope


def test_gyro_bias_at_rest():
    res = sim.make_scenario("static", 60.0, RATE, seed=4)  # turn-on bias (0.2, -0.3, 0.1) deg/s and its drift
    result = cal.gyro_bias(record_of(res.gyr, res.acc, res.mag), P)
    truth = res.gyro_bias_true.mean(axis=0)
    white = np.std(res.gyr - res.gyro_bias_true, axis=0) / np.sqrt(len(res.gyr))
    assert np.all(np.abs(result.offset * P.gyro_scale - truth) < 4.0 * white + 1e-6), (result.offset, truth)
    assert np.degrees(truth) == pytest.approx([0.2, -0.3, 0.1], abs=0.05)
    np.testing.assert_array_equal(result.matrix, np.eye(3))
    assert result.report["rests"] == 1 and result.report["still_s"] > 55.0


def test_gyro_bias_needs_a_rest():
    res = sim.make_scenario("random", 30.0, RATE, seed=1)
    with pytest.raises(cal.CalibrationError, match="lies still for 0.0 s"):
        cal.gyro_bias(record_of(res.gyr, res.acc, res.mag), P)


# ---------------------------------------------------------------------------- accelerometer

SIX = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
TILTED = [(1, 1, 0), (0, 1, 1), (1, 0, 1), (-1, 1, 1), (1, -1, -1)]


def positions_record(up_directions, distortion, offset_m_s2, rest_s=4.0, move_s=1.5, seed=0):
    """The board still with each direction up in turn for rest_s, turned between them for
    move_s (rates of 1 rad/s, the specific force moving from one position to the next).
    The accelerometer reads distortion @ f + offset + noise."""
    rng = np.random.default_rng(seed)
    n_rest, n_move = int(rest_s * RATE), int(move_s * RATE)
    gyr, acc = [], []
    ups = [np.asarray(d, float) / np.linalg.norm(d) for d in up_directions]
    for k, up in enumerate(ups):
        nxt = ups[(k + 1) % len(ups)]
        acc.append(np.tile(STANDARD_GRAVITY * up, (n_rest, 1)))
        gyr.append(np.zeros((n_rest, 3)))
        blend = np.linspace(0, 1, n_move)[:, None]
        acc.append(STANDARD_GRAVITY * ((1 - blend) * up + blend * nxt) + rng.standard_normal((n_move, 3)))
        gyr.append(np.ones((n_move, 3)))
    acc = np.concatenate(acc) @ np.asarray(distortion).T + offset_m_s2
    acc += 0.02 * rng.standard_normal(acc.shape)
    gyr = np.concatenate(gyr) + 0.005 * rng.standard_normal(acc.shape)
    return record_of(gyr, acc, np.tile([20.0, 0.0, -40.0], (len(acc), 1)))


ACC_OFFSET = np.array([0.25, -0.4, 0.6])  # m/s^2
ACC_SCALE = np.array([1.03, 0.97, 1.015])  # what the axes read per unit of true specific force


def test_six_position_recovers_offsets_and_scales():
    record = positions_record(SIX, np.diag(ACC_SCALE), ACC_OFFSET)
    result = cal.accel_six_position(record, P)
    np.testing.assert_allclose(result.offset * P.acc_scale, ACC_OFFSET, atol=0.005)
    np.testing.assert_allclose(np.diag(result.matrix), 1.0 / ACC_SCALE, rtol=5e-4)
    assert np.count_nonzero(result.matrix - np.diag(np.diag(result.matrix))) == 0
    r = result.report
    assert r["positions"] == 6 and r["faces"] == {face: 1 for face in cal.FACES}
    assert r["norm_error_before_m_s2"]["rms"] > 0.2 and r["norm_error_after_m_s2"]["rms"] < 0.005


def test_misalignment_from_tilted_positions():
    distortion = np.diag(ACC_SCALE) + np.array([[0, 0.02, -0.01], [0.02, 0, 0.015], [-0.01, 0.015, 0]])
    record = positions_record(SIX + TILTED, distortion, ACC_OFFSET)
    result = cal.accel_six_position(record, P, misalignment=True)
    np.testing.assert_allclose(result.offset * P.acc_scale, ACC_OFFSET, atol=0.01)
    np.testing.assert_allclose(result.matrix @ distortion, np.eye(3), atol=2e-3)
    scale_only = cal.accel_six_position(record, P)
    assert (result.report["norm_error_after_m_s2"]["rms"]
            < 0.3 * scale_only.report["norm_error_after_m_s2"]["rms"])
    with pytest.raises(cal.CalibrationError, match="6 distinct position"):
        cal.accel_six_position(positions_record(SIX, distortion, ACC_OFFSET), P, misalignment=True)


def test_six_position_names_the_missing_position():
    record = positions_record([d for d in SIX if d != (0, -1, 0)], np.eye(3), ACC_OFFSET)
    with pytest.raises(cal.CalibrationError, match=r"no rest with -y up"):
        cal.accel_six_position(record, P)


# ---------------------------------------------------------------------------- the file


def test_fixed_point_and_file_round_trip(tmp_path):
    c = cal.SensorCalibration("mag", np.array([100.25, -3.5, 0.0]), SOFT_IRON)
    offset, matrix = cal.to_fixed(c)
    assert offset == [25664, -896, 0] and matrix[0] == round(1.10 * 2**24)
    back = cal.from_fixed("mag", offset, matrix)
    np.testing.assert_allclose(back.matrix, SOFT_IRON, atol=2**-25)
    calibration = cal.Calibration(P, {"mag": c})
    cal.save(calibration, tmp_path / "c.json")
    loaded = cal.load(tmp_path / "c.json")
    assert loaded.profile == P and loaded.sensor("gyr").offset.tolist() == [0, 0, 0]
    np.testing.assert_array_equal(loaded.sensors["mag"].matrix, SOFT_IRON)
    with pytest.raises(cal.CalibrationError, match="beyond"):
        cal.to_fixed(cal.SensorCalibration("acc", np.array([7e4, 0, 0]), np.eye(3)))
    (tmp_path / "bad.json").write_text('{"format": "imulink-calibration", "format_version": 1, "profile": {}}')
    with pytest.raises(cal.CalibrationError, match="not a valid calibration file"):
        cal.load(tmp_path / "bad.json")


# ---------------------------------------------------------------------------- the command line


def run_cli(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True, timeout=120, cwd=cwd,
                          stdin=subprocess.DEVNULL)


def assert_error(result, fragment: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr)
    errors = [line for line in result.stderr.splitlines() if line.startswith("imulink: error: ")]
    assert len(errors) == 1 and result.stderr.rstrip().endswith(errors[0]), result.stderr
    assert "Traceback" not in result.stderr and fragment in errors[0], result.stderr


def write_csv(path: Path, record: SensorRecord) -> Path:
    """A CSV with the columns of `imulink replay --csv`."""
    columns = ["time_s", "gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s", "acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2",
               "mag_x_uT", "mag_y_uT", "mag_z_uT"]
    table = np.column_stack([record.time_s, record.gyr, record.acc, record.mag])
    np.savetxt(path, table, delimiter=",", header=",".join(columns), comments="", fmt="%.9g")
    return path


def test_cli_calibrates_each_sensor_into_one_file(tmp_path):
    res = rotating_mag(seconds=90.0)
    write_csv(tmp_path / "turned.csv", record_of(res.gyr, res.acc, res.mag))
    write_csv(tmp_path / "six.csv", positions_record(SIX, np.diag(ACC_SCALE), ACC_OFFSET))
    out = tmp_path / "board.json"
    result = run_cli("calibrate", "mag", tmp_path / "turned.csv", "-o", out)
    assert result.returncode == 0, result.stderr
    assert "coverage: 26 of 26 directions (all)" in result.stdout and "field norm spread" in result.stdout
    result = run_cli("calibrate", "accel", tmp_path / "six.csv", "-o", out, "--json")
    assert result.returncode == 0, result.stderr
    printed = json.loads(result.stdout)
    np.testing.assert_allclose(np.diag(printed["matrix"]), 1.0 / ACC_SCALE, rtol=5e-4)
    assert "(accelerometer written; magnetometer kept)" in result.stderr
    saved = json.loads(out.read_text())
    assert set(saved["sensors"]) == {"mag", "acc"} and saved["profile"]["name"] == "gy86-default"
    np.testing.assert_allclose(np.array(saved["sensors"]["mag"]["offset_counts"]) * P.mag_scale, HARD_IRON,
                               atol=0.1)
    loaded = cal.load(out)
    assert loaded.sensors["acc"].report["input"] == "CSV six.csv"


def test_cli_refuses_missing_directions_and_positions(tmp_path):
    res = sim.simulate(sim.turntable(60.0, RATE, rate_dps=30.0),
                       SensorSuite(GyroModel.ideal(), AccModel(), MagModel(hard_iron=HARD_IRON)), seed=1)
    write_csv(tmp_path / "flat.csv", record_of(res.gyr, res.acc, res.mag))
    assert_error(run_cli("calibrate", "mag", tmp_path / "flat.csv", "-o", tmp_path / "c.json"), "more directions")
    assert_error(run_cli("calibrate", "accel", tmp_path / "flat.csv", "-o", tmp_path / "c.json"),
                 "the six-position method needs each axis up and down")
    assert not (tmp_path / "c.json").exists()
    # a hemisphere missing: fitted, but refused unless --allow-gaps
    turned = rotating_mag(seconds=240.0)
    body = (turned.mag - HARD_IRON) @ np.linalg.inv(SOFT_IRON).T
    keep = body[:, 0] / np.linalg.norm(body, axis=1) < 0.5
    write_csv(tmp_path / "gap.csv", record_of(turned.gyr[keep], turned.acc[keep], turned.mag[keep]))
    assert_error(run_cli("calibrate", "mag", tmp_path / "gap.csv", "-o", tmp_path / "c.json"),
                 "the field never lay along +x of the board")
    assert not (tmp_path / "c.json").exists()
    result = run_cli("calibrate", "mag", tmp_path / "gap.csv", "-o", tmp_path / "c.json", "--allow-gaps")
    assert result.returncode == 0 and "missing: +x" in result.stdout, result.stderr
    assert_error(run_cli("calibrate", "gyro", tmp_path / "nothing.csv"), "nothing.csv")
    assert_error(run_cli("calibrate", "gyro", tmp_path / "flat.csv", "-o", tmp_path / "flat.csv"),
                 "is an input of this command")
