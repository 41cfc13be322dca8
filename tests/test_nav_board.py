"""The nav filter on the emulated boards: the board application runs it on its sensor feed
(IMU samples, the barometer, a GNSS receiver), streams ESTIMATE + NAV_STATE, and the host
replays the recording through the host build of the same C, bit for bit, on the native
board and on the ARM image in QEMU; position fixes (POSITION_FIX, MARKER) in injection
mode; `imulink demo --filter nav`.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imulink import core, hil, protocol
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Link
from imulink.cli import main
from imulink.hil import comparison as hil_comparison
from imulink.io.recording import load_recording
from imulink.sim import navigation as nv
from imulink.sim import simulate

ROOT = Path(__file__).resolve().parents[1]
RATE = 100.0
NAV_ID = core.BOARD_FILTERS["nav"][0]


def car_feed(duration_s: float) -> tuple[nv.NavTrajectory, dict]:
    """A simulated car drive and what the emulated board's sensors deliver along it."""
    traj = nv.car_drive(duration_s, RATE, seed=3)
    return traj, dict(simulation=simulate(traj, nv.datasheet_sensors(RATE), seed=3),
                      gnss=nv.gnss_fixes(traj, nv.GnssModel(), seed=3), baro=nv.baro_samples(traj, seed=3))


def record_nav_drive(target: str, duration_s: float, tmp_path):
    traj, feed = car_feed(duration_s)
    with EmulatedBoard(target, front="tcp", filter_name="nav", duration_s=duration_s, **feed) as board:
        hil.record(board.address, tmp_path / "nav.imulog")
        recording = load_recording(tmp_path / "nav.imulog")
        fed = board.positions(recording.samples.gyr, recording.samples.acc, recording.samples.mag)
    return traj, recording, fed


@pytest.mark.parametrize("target,duration_s", [("native", 90.0), ("qemu", 25.0)])
def test_the_board_navigates_bit_exact_with_the_host(target, duration_s, tmp_path):
    traj, recording, fed = record_nav_drive(target, duration_s, tmp_path)
    n = int(duration_s * RATE)
    states = recording.nav_states.fields
    assert len(recording.samples) == len(recording.estimates) == len(recording.nav_states) == n
    assert (recording.estimates.filter_id == NAV_ID).all() and (np.diff(fed) == 1).all()
    assert len(recording.gnss) == int(duration_s) and len(recording.baro) > 0
    comparison = hil.compare(recording)
    assert comparison.verdict.passed and comparison.verified_count == n, str(comparison.first_difference)
    assert comparison.fixed_vs_float["position_max_m"] < 0.1 and comparison.fixed_vs_float["angle_max_deg"] < 0.05
    # attitude from the first sample on, the position from the sample the first fix came with
    first_fix = int(recording.gnss.index[0])
    assert (states["mode"][:first_fix] == 1).all() and (states["mode"][first_fix:] == 2).all()
    later = np.arange(n) >= 20 * RATE
    e = nv.local_offsets(np.degrees(states["lat"] / 2.0**29), np.degrees(states["lon"] / 2.0**29),
                         states["height_mm"] / 1000.0, traj.lat_deg[fed], traj.lon_deg[fed], traj.height_m[fed])
    assert np.sqrt(np.mean(np.sum(e[later, :2] ** 2, axis=1))) < 2.0
    assert states["rejected"][-1] == 0 and recording.estimates.saturations[-1] == 0


def test_a_changed_nav_state_is_found(tmp_path):
    """The comparison covers NAV_STATE: one changed bit of a latitude fails it and is named."""
    _, recording, _ = record_nav_drive("native", 5.0, tmp_path)
    recording.nav_states.fields["lat"][300] ^= 1
    comparison = hil.compare(recording)
    assert not comparison.bit_exact
    assert comparison.first_difference.field == "nav_state.lat" and comparison.first_difference.index == 300


def test_a_lost_nav_state_leaves_its_estimate_verified_and_the_others_compared(tmp_path):
    """A NAV_STATE is an output (the board does not send it again): where one was lost its
    ESTIMATE is still verified, and the other NAV_STATEs are still compared."""
    _, recording, _ = record_nav_drive("native", 5.0, tmp_path)
    kept = np.arange(len(recording.nav_states)) != 200
    recording.nav_states.segment = recording.nav_states.segment[kept]
    recording.nav_states.host_time = recording.nav_states.host_time[kept]
    recording.nav_states.fields = {k: v[kept] for k, v in recording.nav_states.fields.items()}
    comparison = hil.compare(recording)
    assert comparison.verified_count == len(recording.estimates) and comparison.bit_exact
    recording.nav_states.fields["height_mm"][300] += 1
    comparison = hil.compare(recording)
    assert not comparison.bit_exact and comparison.first_difference.field == "nav_state.height_mm"


def test_replay_of_a_nav_recording_has_its_positions(tmp_path, capsys):
    _, recording, _ = record_nav_drive("native", 10.0, tmp_path)
    out = tmp_path / "replay.csv"
    assert main(["replay", str(recording.path), "--csv", str(out)]) == 0
    capsys.readouterr()
    rows = np.genfromtxt(out, delimiter=",", names=True)
    states = recording.nav_states.fields
    assert np.array_equal(rows["board_lat_deg"], rows["fixed_lat_deg"])
    np.testing.assert_array_equal(rows["board_height_m"], states["height_mm"] / 1000.0)
    assert np.abs(rows["float_lat_deg"] - rows["fixed_lat_deg"]).max() * 111_000 < 0.1  # m
    assert np.isfinite(rows["board_vel_e_m_s"]).all()


@pytest.fixture(scope="module")
def board():
    with EmulatedBoard("native", duration_s=60.0) as emulated:
        yield emulated


@pytest.fixture
def link(board):
    with Link(board.address) as connected:
        connected.connect()
        connected.command("RESET")
        connected.receive_until(lambda m: m.name == "HELLO" and m.seq == 0)
        connected.receive(0)
        yield connected


def inject(link: Link, k: int, counts) -> list[protocol.Message]:
    """Inject sample k; the messages that came with it (MARKER, ESTIMATE, NAV_STATE)."""
    gyr, acc, mag = (c[k].tolist() for c in counts)
    reply = link.command("INJECT_SAMPLE", timestamp_us=k * 10_000, index=k, gyr=gyr, acc=acc, mag=mag, temperature=0)
    return [reply.data] + [r.message for r in link.receive(0.05) if r.message.name in ("MARKER", "NAV_STATE")]


MARKER = dict(lat_1e7deg=483_712_345, lon_1e7deg=-1_234_567, height_mm=251_000, h_acc_mm=50, v_acc_mm=80)


def test_a_position_fix_anchors_the_board_as_the_host_computes(link):
    """POSITION_FIX in injection mode: applied after the next sample (a MARKER frame comes
    with it), the NAV_STATE then at the marker, every frame the host build's."""
    link.command("SELECT_FILTER", filter_id=NAV_ID)
    link.command("SET_INJECTION_MODE", enabled=1)
    traj = nv.handheld_walk(3.0, RATE, seed=1)
    imu = simulate(traj, nv.datasheet_sensors(RATE), seed=1)
    counts = (imu.gyr_counts, imu.acc_counts, imu.mag_counts)
    got = {}
    for k in range(len(imu.t)):
        if k == 100:
            link.command("POSITION_FIX", **MARKER)
            with pytest.raises(protocol.CommandError) as busy:
                link.command("POSITION_FIX", **MARKER)
            assert busy.value.reason == "BUSY"  # one waits at a time
        messages = inject(link, k, counts)
        got[k] = {m.name: m.fields for m in messages}
    assert set(got[100]) == {"MARKER", "ESTIMATE", "NAV_STATE"} and set(got[99]) == {"ESTIMATE", "NAV_STATE"}
    assert got[100]["MARKER"]["used"] == 1 and got[100]["MARKER"]["index"] == 100
    assert got[99]["NAV_STATE"]["mode"] == 1 and got[100]["NAV_STATE"]["mode"] == 2
    state = got[100]["NAV_STATE"]
    assert abs(np.degrees(state["lat"] / 2.0**29) - 48.3712345) < 1e-7 and state["height_mm"] == 251_000
    host = core.Filter("nav", RATE).run_nav_counts(*counts, marker_after=[100], markers=[MARKER])
    for k in range(len(imu.t)):
        for name, values in host.nav_states.items():
            if name != "index":
                assert np.array_equal(np.asarray(got[k]["NAV_STATE"][name]), values[k]), (k, name)
        assert list(got[k]["ESTIMATE"]["quat"]) == host.raw["quat"][k].tolist()


def test_injection_into_nav_compares_its_nav_state_too(board):
    """imulink inject into the nav filter: every ESTIMATE and its NAV_STATE against the host
    build, bit for bit; a NAV_STATE that differs is named."""
    source = hil.load_injection_input("sim:rests:4:100:1")
    result = hil.inject(board.address, source, filter_name="nav")
    assert result.answered == result.samples == 400 and result.bit_exact, result.first_difference
    state = {"index": 3, "mode": 1, "lat": 0, "lon": 0, "height_mm": 0, "vel": [0, 0, 0], "acc_bias": [0, 0, 0],
             "baro_bias_mm": 0, "var_mantissa": [1] * 16, "var_exponent": [0] * 16, "since_fix": 0, "rejected": 0,
             "zero_velocity": 0, "resets": 0, "fades": 0}
    changed = {**state, "zero_velocity": 1}
    assert hil_comparison._first_different_nav_field(state, dict(state)) is None
    assert hil_comparison._first_different_nav_field(changed, state) == "nav_state.zero_velocity"
    assert hil_comparison._first_different_nav_field({**state, "fades": 2}, state) == "nav_state.fades"


def test_position_fix_refusals(link):
    with pytest.raises(protocol.CommandError) as error:
        link.command("POSITION_FIX", **MARKER)
    assert error.value.reason == "NOT_NAV"  # the default filter is an attitude filter
    link.command("SELECT_FILTER", filter_id=NAV_ID)
    for change in (dict(lat_1e7deg=860_000_000), dict(lon_1e7deg=-1_800_000_001), dict(height_mm=10_000_001),
                   dict(h_acc_mm=0), dict(v_acc_mm=2**30 + 1)):
        with pytest.raises(protocol.CommandError) as error:
            link.command("POSITION_FIX", **{**MARKER, **change})
        assert error.value.reason == "OUT_OF_RANGE", change


def test_nav_settings_are_the_cores(link):
    link.command("SELECT_FILTER", filter_id=NAV_ID)
    fields = core.settings_fields("nav")
    assert [f.name for f in fields] == ["sample_rate", "lever_arm_x", "lever_arm_y", "lever_arm_z", "gnss_latency",
                                        "gyro_noise", "acc_noise", "gyro_bias_walk", "acc_bias_walk", "gate",
                                        "reset_time", "rest_rate", "rest_force", "acc_range"]
    for name, bad, good in (("gnss_latency", 1.5, 0.25), ("gate", 7.0, 30.0), ("reset_time", 0.5, 5.0),
                            ("gyro_bias_walk", 0.02, 1e-4)):
        index = [f.name for f in fields].index(name)
        q = fields[index].frac_bits
        with pytest.raises(protocol.CommandError) as error:
            link.command("SET_SETTING", index=index, value=core.to_fixed(bad, q))
        assert error.value.reason == "OUT_OF_RANGE", name
        link.command("SET_SETTING", index=index, value=core.to_fixed(good, q))
        assert link.command("GET_SETTING", index=index).data.fields["value"] == core.to_fixed(good, q), name


def test_a_tuned_board_is_bit_exact_with_the_host(tmp_path):
    """The tuning settings reach the board's filter and the host's replica alike: a cold
    receiver on a board whose reset time is 5 s resets sooner, with fewer fixes rejected,
    than with the default 15 s, bit for bit with the host."""
    from imulink.io.settings_file import FilterSettings

    duration_s = 30.0
    traj = nv.car_drive(duration_s, RATE, seed=5)
    cold = nv.GnssModel(cold_start_fixes=1, cold_start_offset_m=(800.0, -755.0, 0.0))
    feed = dict(simulation=simulate(traj, nv.datasheet_sensors(RATE), seed=5),
                gnss=nv.gnss_fixes(traj, cold, seed=5))
    rejected = {}
    for reset_time in (15.0, 5.0):
        with EmulatedBoard("native", front="tcp", filter_name="nav", duration_s=duration_s, **feed) as board:
            hil.record(board.address, tmp_path / f"tuned{reset_time:g}.imulog",
                       settings=FilterSettings("nav", {"reset_time": reset_time, "gyro_bias_walk": 1e-4}))
        recording = load_recording(tmp_path / f"tuned{reset_time:g}.imulog")
        comparison = hil.compare(recording)
        assert comparison.verdict.passed and comparison.verified_count == len(recording.estimates)
        states = recording.nav_states.fields
        assert states["resets"][-1] == 1
        rejected[reset_time] = int(states["rejected"][-1])
    assert rejected[5.0] < rejected[15.0]


def test_imulink_demo_filter_nav(capsys):
    assert main(["demo", "--filter", "nav", "--duration", "40", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["verdict"]["passed"] and report["compare"]["fixed_vs_float"]["position_max_m"] < 0.1
    accuracy = report["navigation_accuracy"]
    assert accuracy["horizontal_m"] < 2.0 and accuracy["velocity_m_s"] < 0.2 and accuracy["rejected"] == 0


@pytest.mark.parametrize("build", ["FIXED", "FLOAT"])
def test_extreme_protocol_input_has_no_undefined_behaviour(build, tmp_path):
    """The board's nav filter fed GNSS frames, markers and pressures with every field at its
    type's limits (tests/c/navfilter_driver.c), under the sanitizers, the fixed build with
    every narrowing checked: no undefined behaviour, and the usable fixes among them used."""
    gcc = shutil.which("gcc")
    assert gcc, "gcc not found"
    core_dir = ROOT / "firmware" / "core"
    exe = tmp_path / "navfilter"
    checked = ["-DIMU_CHECK_NARROWING"] if build == "FIXED" else []
    sources = [core_dir / name for name in ("imu_filter.c", "imu_navfilter.c", "imu_navkf.c", "imu_nav.c",
                                            "imu_navcov.c", "imu_eecf.c", "imu_kf1d.c", "imu_eskf.c", "imu_cov.c",
                                            "imu_rest.c", "imu_sensor.c", "imu_settings.c", "imu_math.c",
                                            "imu_wire.c")]
    proc = subprocess.run([gcc, "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", f"-DIMU_{build}", *checked,
                           f"-I{core_dir}", "-fsanitize=undefined,address", "-fno-sanitize-recover=all", "-o", str(exe),
                           str(ROOT / "tests" / "c" / "navfilter_driver.c"), *map(str, sources), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    run = subprocess.run([str(exe), "3000"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    counts = dict(zip(*[iter(run.stdout.split())] * 2))
    assert counts["samples"] == "3000" and int(counts["gnss_used"]) > 0 and int(counts["markers_used"]) > 0
    assert counts["mode"] == "2"


def test_nav_state_reports_a_reset_to_the_fixes_bit_exact(tmp_path):
    """A cold receiver whose first fix is 1.1 km off: the board's filter starts there, rejects
    the good fixes after it, and after the reset time puts its position and velocity on them;
    NAV_STATE counts the reset (and any covariance fading) and the host's replica agrees bit
    for bit."""
    duration_s = 40.0
    traj = nv.car_drive(duration_s, RATE, seed=5)
    cold = nv.GnssModel(cold_start_fixes=1, cold_start_offset_m=(800.0, -755.0, 0.0))  # 1.1 km
    feed = dict(simulation=simulate(traj, nv.datasheet_sensors(RATE), seed=5),
                gnss=nv.gnss_fixes(traj, cold, seed=5))
    with EmulatedBoard("native", front="tcp", filter_name="nav", duration_s=duration_s, **feed) as board:
        hil.record(board.address, tmp_path / "cold.imulog")
    recording = load_recording(tmp_path / "cold.imulog")
    states = recording.nav_states.fields
    assert states["resets"][0] == 0 and states["resets"][-1] == 1
    assert states["rejected"][-1] >= 10
    comparison = hil.compare(recording)
    assert comparison.verdict.passed and comparison.verified_count == len(recording.estimates)
