"""imulink.board.emulator around the firmware: the feed, finding and checking images, the truth
of recorded samples, and the errors a user meets (a missing or wrong image, a bad option)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imulink import protocol, sim
from imulink.board.chips import ms5611
from imulink.board.emulator import (
    BARO_HEIGHT_M,
    BARO_TEMPERATURE_CDEG,
    EmulatedBoard,
    EmulatorError,
    baro_due,
    feed_frames,
    find_image,
)
from imulink.cli import main
from imulink.core.counts import BROAD_PROFILE, SensorProfile
from imulink.sim import navigation, simulate


def test_feed_is_a_sample_per_request_with_the_barometer_every_20_ms_and_a_closing_log():
    run = sim.make_scenario("turntable", 0.5, 100.0, seed=1)
    requests = [list(protocol.FrameDecoder().feed(f)) for f in feed_frames(run)]
    assert [[m.name for m in r] for r in requests] == \
        [["BARO", "SAMPLE"] if k % 2 == 0 else ["SAMPLE"] for k in range(50)] + [["LOG"]]
    samples = [r[-1] for r in requests[:-1]]
    np.testing.assert_array_equal([m.fields["gyr"] for m in samples], run.gyr_counts)
    assert requests[-1][0].fields["text"] == "end of the simulated run (50 samples)"
    for k, r in enumerate(requests[:-1:2]):
        baro = r[0].fields
        pressure, temperature = ms5611.compensate(ms5611.EXAMPLE_C, baro["d1"], baro["d2"])
        assert baro["index"] == 2 * k and abs(pressure - navigation.pressure_at(BARO_HEIGHT_M)) <= 1.0
        assert temperature == BARO_TEMPERATURE_CDEG
    broad = [list(protocol.FrameDecoder().feed(f))[-1] for f in feed_frames(run, BROAD_PROFILE)]
    np.testing.assert_allclose(np.array([m.fields["acc"] for m in broad[:-1]]) * 2, run.acc_counts, atol=1)


def test_feed_carries_each_gnss_fix_before_the_sample_it_arrives_with():
    traj = navigation.car_drive(3.0, 100.0, seed=2)
    fixes = navigation.gnss_fixes(traj, navigation.GnssModel(rate_hz=5.0, latency_s=0.05), seed=2)
    requests = [list(protocol.FrameDecoder().feed(f)) for f in feed_frames(simulate(traj, seed=2), gnss=fixes)]
    with_fix = {k: r[-2].fields for k, r in enumerate(requests[:-1]) if r[-2:-1] and r[-2].name == "GNSS"}
    arrived = fixes.index + 5 < len(traj.t)
    assert sorted(with_fix) == (fixes.index[arrived] + 5).tolist()
    for k, fields in with_fix.items():
        i = int(np.flatnonzero(fixes.index == k - 5)[0])
        assert fields["time_ms"] == round(fixes.t_valid[i] * 1000) and fields["fix_type"] == 3
        assert fields["lat_1e7deg"] == round(fixes.lat_deg[i] * 1e7)
        assert fields["vel_ned_mm_s"] == tuple(round(v * 1000) for v in (fixes.vel_enu[i, 1], fixes.vel_enu[i, 0],
                                                                           -fixes.vel_enu[i, 2]))
        assert fields["h_acc_mm"] == round(fixes.h_acc_m[i] * 1000)


def test_feed_carries_a_barometer_along_a_trajectory():
    """Given the simulator's barometer samples (50 Hz, the air along a hill of the drive, with
    noise and drift), the feed's BARO frames are at their samples and compensate back to
    their pressure and temperature to the data sheet's resolution (1 Pa, 0.01 degC)."""
    traj = navigation.car_drive(3.0, 100.0, seed=3)
    baro = navigation.baro_samples(traj, seed=3)
    requests = [list(protocol.FrameDecoder().feed(f)) for f in feed_frames(simulate(traj, seed=3), baro=baro)]
    found = {k: r[0].fields for k, r in enumerate(requests[:-1]) if r[0].name == "BARO"}
    assert sorted(found) == baro.index.tolist()
    for k, pa, c in zip(baro.index, baro.pressure_pa, baro.temperature_c):
        pressure, temperature = ms5611.compensate(ms5611.EXAMPLE_C, found[k]["d1"], found[k]["d2"])
        assert abs(pressure - pa) <= 1.0 and abs(temperature - c * 100.0) <= 1.0


def test_barometer_is_due_every_20_ms_at_any_rate():
    assert baro_due(6, 100.0).tolist() == [True, False, True, False, True, False]
    assert baro_due(3, 30.0).all()  # 33 ms apart: every sample
    assert np.flatnonzero(baro_due(100, 1000.0)).tolist() == [0, 20, 40, 60, 80]
    # the first sample at or after each 20 ms: sample k is at k / 285.714 s
    assert np.flatnonzero(baro_due(40, 285.714)).tolist() == [math.ceil(m * 0.02 * 285.714) for m in range(7)]


def test_images_are_found_and_checked(tmp_path):
    native, qemu = find_image("native"), find_image("qemu")
    assert native.name == "imulink-native" and qemu.name.endswith(".elf") and "netduinoplus2" in qemu.name
    with pytest.raises(EmulatorError, match="not the qemu board's firmware"):
        find_image("qemu", native)
    with pytest.raises(EmulatorError, match="not the native board's firmware"):
        find_image("native", qemu)
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(EmulatorError, match="not a firmware image"):
        find_image("native", text)
    with pytest.raises(EmulatorError, match="cannot read .*missing.elf: No such file or directory"):
        find_image("qemu", tmp_path / "missing.elf")
    with pytest.raises(EmulatorError, match="unknown target"):
        find_image("fpga")


def test_a_missing_build_says_how_to_make_it(tmp_path, monkeypatch):
    monkeypatch.setattr("imulink.board.emulator.firmware_build_dirs", lambda: [tmp_path])
    with pytest.raises(EmulatorError, match=r"not built: run `make -C firmware qemu`"):
        find_image("qemu")


def test_cli_errors_are_one_line(capsys, tmp_path):
    assert main(["emulate", "--target", "qemu", "--image", str(find_image("native"))]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("imulink: error: ") and "not the qemu board's firmware" in err


def test_unknown_profile_is_refused():
    with pytest.raises(EmulatorError, match="sensor profiles gy86-default, gy86-broad"):
        EmulatedBoard(profile=SensorProfile(name="mine", acc_lsb_per_g=8192.0))


def test_truth_follows_the_feed_across_lost_samples():
    board = EmulatedBoard(scenario="random", duration_s=5.0)  # not started: truth needs only the simulation
    run = board.simulation
    rows = np.r_[3:40, 45:50, 200:210]  # what a recording with two gaps holds
    positions = board.positions(run.gyr_counts[rows], run.acc_counts[rows], run.mag_counts[rows])
    np.testing.assert_array_equal(positions, rows)
    stranger = np.full((1, 3), 1234, np.int16)
    truth = board.truth(np.r_[run.gyr_counts[rows[:2]], stranger], np.r_[run.acc_counts[rows[:2]], stranger],
                        np.r_[run.mag_counts[rows[:2]], stranger])
    np.testing.assert_array_equal(truth[:2], run.quat_true[rows[:2]])
    assert np.isnan(truth[2]).all()
