"""Sensor calibration (imulink.analysis.calibration, `imulink calibrate`): gyroscope bias at rest,
accelerometer six-position (and misalignment), magnetometer ellipsoid fit with coverage;
the calibration file; the command line."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imulink import sim
from imulink.analysis import calibration as cal
from imulink.core import calibration as calfmt
from imulink.core.counts import DEFAULT_PROFILE, STANDARD_GRAVITY, si_to_counts
from imulink.hil import live_calibration
from imulink.io import calibration_file
from imulink.io.sensor_input import SensorRecord
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
    with pytest.raises(calfmt.CalibrationError, match="more directions") as error:
        cal.mag_ellipsoid(record_of(res.gyr, res.acc, res.mag), P)
    # it names the directions the turn never gave (about z: the field never along +z or -z)
    assert "the field never lay along -z, +z of the board" in str(error.value)


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
    with pytest.raises(calfmt.CalibrationError, match="lies still for 0.0 s"):
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
    with pytest.raises(calfmt.CalibrationError, match="6 distinct position"):
        cal.accel_six_position(positions_record(SIX, distortion, ACC_OFFSET), P, misalignment=True)


def test_six_position_names_the_missing_position():
    record = positions_record([d for d in SIX if d != (0, -1, 0)], np.eye(3), ACC_OFFSET)
    with pytest.raises(calfmt.CalibrationError, match=r"no rest with -y up"):
        cal.accel_six_position(record, P)


# ---------------------------------------------------------------------------- the file


def test_fixed_point_and_file_round_trip(tmp_path):
    c = calfmt.SensorCalibration("mag", np.array([100.25, -3.5, 0.0]), SOFT_IRON)
    offset, matrix = calfmt.to_fixed(c)
    assert offset == [25664, -896, 0] and matrix[0] == round(1.10 * 2**24)
    back = calfmt.from_fixed("mag", offset, matrix)
    np.testing.assert_allclose(back.matrix, SOFT_IRON, atol=2**-25)
    calibration = calfmt.Calibration(P, {"mag": c})
    calibration_file.save(calibration, tmp_path / "c.json")
    loaded = calibration_file.load(tmp_path / "c.json")
    assert loaded.profile == P and loaded.sensor("gyr").offset.tolist() == [0, 0, 0]
    np.testing.assert_array_equal(loaded.sensors["mag"].matrix, SOFT_IRON)
    with pytest.raises(calfmt.CalibrationError, match="beyond"):
        calfmt.to_fixed(calfmt.SensorCalibration("acc", np.array([7e4, 0, 0]), np.eye(3)))
    (tmp_path / "bad.json").write_text('{"format": "imulink-calibration", "format_version": 1, "profile": {}}')
    with pytest.raises(calfmt.CalibrationError, match="not a valid calibration file"):
        calibration_file.load(tmp_path / "bad.json")


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
    loaded = calibration_file.load(out)
    assert loaded.sensors["acc"].report["input"] == "CSV six.csv"


def test_cli_refuses_missing_directions_and_positions(tmp_path):
    res = sim.simulate(sim.turntable(60.0, RATE, rate_dps=30.0),
                       SensorSuite(GyroModel.ideal(), AccModel(), MagModel(hard_iron=HARD_IRON)), seed=1)
    write_csv(tmp_path / "flat.csv", record_of(res.gyr, res.acc, res.mag))
    assert_error(run_cli("calibrate", "mag", tmp_path / "flat.csv", "-o", tmp_path / "c.json"),
                 "more directions; the field never lay along -z, +z of the board")
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


# ---------------------------------------------------------------------------- the board applies it


#: A calibration of every sensor with odd values: sub-count offsets, scales, cross terms.
BOARD_CALIBRATION = calfmt.Calibration(P, {
    "gyr": calfmt.SensorCalibration("gyr", np.array([3.7, -2.25, 1.5]), np.eye(3)),
    "acc": calfmt.SensorCalibration("acc", np.array([-41.3, 17.0, 60.9]),
                                 np.array([[1.012, 0.003, -0.002], [0.003, 0.987, 0.001], [-0.002, 0.001, 1.004]])),
    "mag": calfmt.SensorCalibration("mag", np.array([130.75, -76.3, 217.9]), np.linalg.inv(SOFT_IRON)),
})


def test_fixed_point_correction_is_the_documented_integer_arithmetic():
    """imu_sample_from_raw_calibrated (fixed build) against the arithmetic imu_sensor.h
    states, computed with Python integers: c = raw 2^8 - offset; corrected = the sum of
    Q24 products rounded to Q8 and saturated; then the scale, its shift 8 bits longer."""
    from imulink import core
    from imulink.core import _fixed as _core_fixed

    ffi, lib = _core_fixed.ffi, _core_fixed.lib
    rng = np.random.default_rng(5)

    def shift_round(v, s):
        return (v + (1 << (s - 1))) >> s

    def sat(v):
        return max(-2**31, min(2**31 - 1, v))

    scales = {"gyr": (core.to_fixed(P.gyro_scale, 40), 16), "acc": (core.to_fixed(P.acc_scale, 32), 16),
              "mag": (core.to_fixed(P.mag_scale, 24), 8)}
    sensor = core.sensor_struct(_core_fixed, "fixed", P)
    saturations = 0
    for trial in range(200):
        matrix_scale = 100.0 if trial % 10 == 9 else 1.5  # every tenth: saturating corrections
        c = calfmt.Calibration(P, {name: calfmt.SensorCalibration(name, rng.uniform(-3e4, 3e4, 3),
                                                            rng.uniform(-matrix_scale, matrix_scale, (3, 3)))
                                for name in calfmt.SENSORS})
        struct = core.calibration_struct(_core_fixed, "fixed", c, P)
        raw = ffi.new("imu_raw_sample_t *")
        counts = {name: rng.integers(-32768, 32768, 3) for name in calfmt.SENSORS}
        counts["mag"] = rng.integers(-2048, 2048, 3)
        for name in calfmt.SENSORS:
            setattr(raw, name, counts[name].tolist())
        out, count = ffi.new("imu_sample_t *"), ffi.new("uint32_t *")
        lib.imu_sample_from_raw_calibrated(sensor, struct, raw, out, count)
        expected_sat = 0
        for name in calfmt.SENSORS:
            offset, matrix = calfmt.to_fixed(c.sensor(name))
            d = [int(counts[name][j]) * 256 - offset[j] for j in range(3)]
            for i in range(3):
                corrected = shift_round(sum(matrix[3 * i + j] * d[j] for j in range(3)), 24)
                expected_sat += corrected != sat(corrected)
                scaled = shift_round(sat(corrected) * scales[name][0], scales[name][1] + 8)
                expected_sat += scaled != sat(scaled)
                assert getattr(out, name)[i] == sat(scaled), (trial, name, i)
        assert count[0] == expected_sat
        saturations += expected_sat
    assert saturations > 0  # the saturating cases were exercised


def test_counts_scaled_as_the_identity_calibration_scales_them():
    """imu_sample_from_raw scales the raw counts straight (imu_sensor.c): every output and
    saturation equals imu_sample_from_raw_calibrated's with the identity calibration (counts
    in Q8, the shift 8 bits longer), with scales of every size, saturating ones included."""
    from imulink import core
    from imulink.core import _fixed as _core_fixed

    ffi, lib = _core_fixed.ffi, _core_fixed.lib
    rng = np.random.default_rng(6)
    identity = ffi.new("imu_calibration_t *", lib.imu_calibration_identity)
    sensor = core.sensor_struct(_core_fixed, "fixed", P)
    saturated = 0
    for trial in range(300):
        if trial % 3:  # a scale of every size; the largest saturate the counts near full range
            for name in ("gyro_scale", "acc_scale", "mag_scale"):
                setattr(sensor, name, int(rng.integers(-2**31, 2**31)) >> int(rng.integers(0, 31)))
        raw = ffi.new("imu_raw_sample_t *")
        for name in ("gyr", "acc", "mag"):
            counts = rng.integers(-32768, 32768, 3)
            counts[rng.integers(0, 3)] = rng.choice([-32768, 32767, 0])
            setattr(raw, name, counts.tolist())
        outs, sats = [], []
        for convert in (lambda o, c: lib.imu_sample_from_raw(sensor, raw, o, c),
                        lambda o, c: lib.imu_sample_from_raw_calibrated(sensor, identity, raw, o, c)):
            out, count = ffi.new("imu_sample_t *"), ffi.new("uint32_t *")
            convert(out, count)
            outs.append([list(out.gyr), list(out.acc), list(out.mag), out.clipped])
            sats.append(count[0])
        assert outs[0] == outs[1] and sats[0] == sats[1], trial
        saturated += sats[0]
    assert saturated > 0  # the saturating scalings were exercised


def test_core_runs_a_calibration_in_both_builds():
    """The float twin follows the fixed build with a calibration too; a magnetometer
    calibration from the data themselves brings the heading back; a calibration of
    another profile or beyond the board's range is refused."""
    from imulink import core
    from imulink.analysis.attitude import attitude_errors, rmse

    res = rotating_mag(seconds=120.0, seed=8)
    board = calfmt.Calibration(P, {"mag": cal.mag_ellipsoid(record_of(res.gyr, res.acc, res.mag), P)})
    runs = {arithmetic: core.run("eskf", res.gyr, res.acc, res.mag, RATE, arithmetic, calibration=board)
            for arithmetic in core.ARITHMETICS}
    raw = core.run("eskf", res.gyr, res.acc, res.mag, RATE, "fixed")
    settle = int(10 * RATE)
    with_cal = rmse(attitude_errors(runs["fixed"].quat[settle:], res.quat_true[settle:]))["heading"]
    without = rmse(attitude_errors(raw.quat[settle:], res.quat_true[settle:]))["heading"]
    assert without > 3.0 and with_cal < without / 3.0, (without, with_cal)
    fixed_vs_float = rmse(attitude_errors(runs["fixed"].quat, runs["float"].quat))["total"]
    assert fixed_vs_float < 0.05
    from imulink.core.counts import BROAD_PROFILE
    with pytest.raises(core.SettingsError, match="profile gy86-default"):
        core.Filter("eskf", RATE, profile=BROAD_PROFILE, calibration=board)
    from imulink.core import _fixed as _core_fixed
    struct = core.calibration_struct(_core_fixed, "fixed", None, P)
    struct.acc.offset[1] = 65536 * 256 + 1
    handle = _core_fixed.ffi.new("imu_filter_t *")
    _core_fixed.lib.imu_filter_init(handle, 3)
    assert _core_fixed.lib.imu_filter_set_calibration(handle, struct) == -1
    struct.acc.offset[1] = 65536 * 256
    assert _core_fixed.lib.imu_filter_set_calibration(handle, struct) == 0


@pytest.mark.parametrize("target, seconds", [("native", 20.0), ("qemu", 5.0)])
def test_emulated_board_applies_a_calibration_bit_exact(tmp_path, target, seconds):
    """The native board and the ARM image in QEMU take a calibration over the protocol,
    report it back, the recording keeps it, and the host's run with it reproduces every
    estimate bit for bit (which the identity calibration would not)."""
    from imulink import hil, protocol
    from imulink.board.emulator import EmulatedBoard
    from imulink.board.link import Link
    from imulink.io.recording import load_recording

    path = tmp_path / "calibrated.imulog"
    with EmulatedBoard(target, duration_s=seconds, rate_hz=100.0, filter_name="eskf") as board:
        with Link(board.address) as link:
            link.connect()
            assert hil.read_calibration(link).sensors["mag"].matrix.tolist() == np.eye(3).tolist()
            hil.set_calibration(link, BOARD_CALIBRATION)
            back = hil.read_calibration(link)
            for name in calfmt.SENSORS:
                assert calfmt.to_fixed(back.sensor(name)) == calfmt.to_fixed(BOARD_CALIBRATION.sensor(name))
            for args, reason in (({"sensor": 3, "axis": 0}, "BAD_ARGUMENT"), ({"sensor": 0, "axis": 3}, "BAD_ARGUMENT"),
                                 ({"sensor": 1, "axis": 0, "offset": 65536 * 256 + 1}, "OUT_OF_RANGE")):
                with pytest.raises(protocol.CommandError) as refused:
                    link.command("SET_CALIBRATION", **{"offset": 0, "row": (1 << 24, 0, 0), **args})
                assert refused.value.reason == reason
            with pytest.raises(protocol.CommandError, match="BAD_ARGUMENT"):
                link.command("GET_CALIBRATION", sensor=7, axis=0)
        hil.record(board.address, path)
    recording = load_recording(path)
    stored = recording.calibration()
    for name in calfmt.SENSORS:
        assert calfmt.to_fixed(stored.sensor(name)) == calfmt.to_fixed(BOARD_CALIBRATION.sensor(name))
    snapshot = next(e for e in recording.events if e["event"] == "snapshot")
    # Q8: the nearest 1/256 count
    assert snapshot["calibration"]["mag"]["offset_counts"] == [130.75, -19533 / 256, 55782 / 256]
    comparison = hil.compare(recording)
    assert comparison.bit_exact and len(recording.estimates) == round(seconds * 100)
    # without the calibration the host computes something else: the test is not vacuous
    name, raw_settings = recording.filter_settings(recording.active_filter)
    s = recording.samples
    plain = hil.fixed_outputs(name, raw_settings, P, s.gyr, s.acc, s.mag)
    assert not np.array_equal(plain["quat"], recording.estimates.quat)


def test_cli_apply(tmp_path, capsys):
    from imulink.board.emulator import EmulatedBoard
    from imulink.cli import main

    calibration_file.save(BOARD_CALIBRATION, tmp_path / "board.json")
    with EmulatedBoard(duration_s=5.0) as board:
        assert main(["calibrate", "apply", str(tmp_path / "board.json"), board.address]) == 0
        out = capsys.readouterr().out
        assert "applied and read back" in out and "offset [+130.75, -76.30, +217.90] counts" in out
        assert main(["calibrate", "apply", "--identity", board.address]) == 0
        assert "offset [+0.00, +0.00, +0.00] counts, M [+1.000000, +0.000000, +0.000000]" in capsys.readouterr().out
        assert main(["calibrate", "apply", board.address]) == 2
        assert "give a calibration FILE or --identity" in capsys.readouterr().err


def test_calibrate_gyro_from_a_recording_of_the_emulated_board(tmp_path, capsys):
    """The whole path: a still emulated board recorded with `imulink record`, its bias
    computed by `imulink calibrate gyro` from the recording (the board's counts, its profile
    from the header)."""
    from imulink import hil
    from imulink.board.emulator import EmulatedBoard
    from imulink.cli import main

    with EmulatedBoard(scenario="static", duration_s=30.0, rate_hz=100.0) as board:
        hil.record(board.address, tmp_path / "still.imulog")
        truth = board.simulation.gyro_bias_true.mean(axis=0)
        noise = np.std(board.simulation.gyr - board.simulation.gyro_bias_true, axis=0)
    assert main(["calibrate", "gyro", str(tmp_path / "still.imulog"), "-o", str(tmp_path / "c.json"), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    bias = np.array(printed["offset_counts"]) * P.gyro_scale
    assert np.all(np.abs(bias - truth) < 4.0 * noise / np.sqrt(3000) + 1e-6), (bias, truth)
    assert printed["report"]["input"].startswith("recording still.imulog (profile gy86-default)")


# ---------------------------------------------------------------------------- live, on a board


def test_live_coverage_waits_for_the_board_to_turn():
    still = np.array([[100, -50, 300]]) + np.random.default_rng(0).integers(-2, 3, (500, 3))
    assert live_calibration.live_coverage(still.astype(float), P) is None  # noise about one point covers nothing
    turned = rotating_mag()
    counts = si_to_counts(turned.gyr, turned.acc, turned.mag, P)[2].astype(float)
    found = live_calibration.live_coverage(counts, P)
    assert found is not None and found.missing == []
    assert "the field has hardly changed" in live_calibration.status_line(1.0, 500, None)
    assert "25 of 26 directions; missing -z" in live_calibration.status_line(
        1.0, 500, cal.Coverage({name: 0 if name == "-z" else 9 for name in cal.GRID_NAMES}, ["-z"]))


@pytest.mark.parametrize("text, port", [("socket://127.0.0.1:5760", True), ("/dev/ttyUSB7", True), ("COM3", True),
                                        ("/dev/null", True), ("turned.imulog", False), ("README.md", False)])
def test_calibrate_mag_tells_a_port_from_a_file(text, port):
    from imulink.cli.calibrate import _is_port

    assert _is_port(text) is port


def test_calibrate_mag_live_on_an_emulated_board(tmp_path, capsys):
    """`imulink calibrate mag PORT --apply`: the emulated board, its magnetometer with hard
    and soft iron, streams while it turns; the fit recovers the distortion, the file is
    written, and the board takes the calibration (read back)."""
    from imulink import hil
    from imulink.board.emulator import EmulatedBoard
    from imulink.board.link import Link
    from imulink.cli import main

    # turned fast (up to some 1000 deg/s): every direction within about 10 s of the 60 s run, which
    # the board streams in real time, so the collection stops well before the run ends
    suite = SensorSuite(GyroModel.seed000(), AccModel(),
                        MagModel(noise_std=MAG_NOISE_UT, hard_iron=HARD_IRON, soft_iron=SOFT_IRON))
    turned = sim.simulate(sim.random_motion(60.0, RATE, seed=5, max_rate_dps=1000.0), suite, seed=5)
    output = tmp_path / "board.json"
    with EmulatedBoard(simulation=turned, rate_hz=RATE, realtime=True) as board:
        assert main(["calibrate", "mag", board.address, "-o", str(output), "--json", "--apply"]) == 0
        printed = json.loads(capsys.readouterr().out.split("\n}\n")[0] + "\n}")
        with Link(board.address) as link:
            link.connect()
            on_board = hil.read_calibration(link)
    report = printed["report"]
    assert report["input"].startswith(f"{board.address} (live, ")
    assert report["coverage"]["missing"] == [] and report["samples"] < len(turned.mag) / 2  # stopped once covered
    np.testing.assert_allclose(np.array(printed["offset_counts"]) * P.mag_scale, HARD_IRON, atol=0.3)
    assert report["norm_spread_before_uT"] > 5.0 > 20 * report["norm_spread_after_uT"]
    written = calibration_file.load(output)
    assert calfmt.to_fixed(on_board.sensor("mag")) == calfmt.to_fixed(written.sensor("mag"))
    assert calfmt.to_fixed(on_board.sensor("gyr")) == calfmt.to_fixed(calfmt.SensorCalibration.identity("gyr"))


def test_calibrate_mag_live_refuses_a_board_that_did_not_turn(tmp_path, capsys):
    from imulink.board.emulator import EmulatedBoard
    from imulink.cli import main

    output = tmp_path / "board.json"
    with EmulatedBoard(scenario="static", duration_s=60.0, rate_hz=RATE, realtime=True) as board:
        assert main(["calibrate", "mag", board.address, "-o", str(output), "--max-duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "1 s passed" in err and "imulink: error:" in err and not output.exists()
    recording = tmp_path / "turned.csv"
    recording.write_text("time_s,mag_x_uT,mag_y_uT,mag_z_uT\n")
    assert main(["calibrate", "mag", str(recording), "--apply", "-o", str(output)]) == 2
    assert "--apply is for a board" in capsys.readouterr().err


def test_mag_of_a_still_board_is_refused():
    """A still board's readings are noise about one point: they fit a sphere of a fraction of
    a uT that "covers" every direction; no calibration comes of them."""
    still = sim.make_scenario("static", 30.0, RATE, seed=2)
    with pytest.raises(calfmt.CalibrationError, match="the board hardly turned"):
        cal.mag_ellipsoid(record_of(still.gyr, still.acc, still.mag), P)
