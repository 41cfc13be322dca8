"""The ARM image in QEMU against the host build of the same C, bit for bit, frame by frame.

For every filter and both sensor profiles: a simulated run in live mode (the board reads
its sensor feed, streams SAMPLE + ESTIMATE, the host records and replays it) and a
simulated run in injection mode; for every filter a BROAD trial in injection mode
(skipped without ../shared/data/broad). Then the command line against a QEMU board:
`imulink demo --target qemu`, and record / compare / replay / inject against
`imulink emulate --target qemu` in its own process.

These tests need qemu-system-arm and the ARM image (`make -C firmware qemu`); without
them they fail, saying what is missing (CI installs both: `make setup`).
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from imulink import core, hil, sim
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Link
from imulink.cli import main
from imulink.core.counts import BROAD_PROFILE, DEFAULT_PROFILE, si_to_counts
from imulink.io.recording import load_recording

#: A QEMU board takes a core, and an injected sample's ACK must come within the link's longest
#: wait (2 s): these tests never run beside the virtual board or the real-time lossy-link tests
#: (`make test` runs with --dist loadgroup). Beside them, a loaded CI run once stalled an ACK
#: past 2 s, and the filter restart that follows failed the 800-of-800 injection check.
pytestmark = pytest.mark.xdist_group("takes-a-core")

BROAD_TRIAL = "25_disturbed_tapping_B.mat"  # taps up to 155 m/s^2: the +-16 g profile's reason to exist
PROFILES = {"gy86-default": DEFAULT_PROFILE, "gy86-broad": BROAD_PROFILE}


@pytest.fixture(scope="module", params=list(PROFILES))
def qemu_board(request):
    """The QEMU image with its sensors in one profile; 10 simulated minutes of 'random' motion."""
    with EmulatedBoard("qemu", scenario="random", duration_s=600.0, seed=4,
                       profile=PROFILES[request.param]) as board:
        yield board


@pytest.mark.parametrize("filter_name", list(core.FILTERS))
def test_live_run_is_bit_exact(qemu_board, filter_name, tmp_path):
    with Link(qemu_board.address) as link:
        link.connect()
        link.command("SELECT_FILTER", filter_id=core.FILTERS[filter_name][0])
    path = tmp_path / "live.imulog"
    result = hil.record(qemu_board.address, path, duration_s=5.0, profile=qemu_board.profile)
    recording = load_recording(path)
    comparison = hil.compare(recording)
    assert result.filter_name == filter_name and recording.hello["board"] == "qemu-stm32f405"
    assert recording.counters["lost_frames"] == 0 and recording.counters["crc_errors"] == 0
    assert comparison.verified_count == len(recording.estimates) > 500
    assert comparison.bit_exact, str(comparison.first_difference)
    # the samples are the simulated ones, in order, in the board's profile
    positions = qemu_board.positions(recording.samples.gyr, recording.samples.acc, recording.samples.mag)
    assert (positions >= 0).all() and (np.diff(positions) == 1).all()


@pytest.mark.parametrize("filter_name", list(core.FILTERS))
def test_injected_simulated_run_is_bit_exact(qemu_board, filter_name):
    run = sim.make_scenario("rests", 8.0, 100.0, seed=7)
    counts = si_to_counts(run.gyr, run.acc, run.mag, qemu_board.profile)
    source = hil.InjectionInput("simulated rests", *counts, 100.0, qemu_board.profile, truth=run.quat_true)
    result = hil.inject(qemu_board.address, source, filter_name=filter_name)
    assert result.answered == result.samples == 800 and result.answers_lost == 0
    assert result.bit_exact, result.first_difference


@pytest.mark.parametrize("filter_name", list(core.FILTERS))
def test_injected_broad_trial_is_bit_exact(broad_dir, filter_name):
    trial = hil.load_injection_input(str(broad_dir / BROAD_TRIAL))
    n = 3000  # 10.5 s of the trial: injection into QEMU runs at a few hundred samples/s
    source = hil.InjectionInput(trial.description, trial.gyr[:n], trial.acc[:n], trial.mag[:n], trial.rate_hz,
                                trial.profile)
    with EmulatedBoard("qemu", duration_s=1.0, profile=BROAD_PROFILE) as board:
        result = hil.inject(board.address, source, filter_name=filter_name)
    assert result.answered == n and result.bit_exact, (f"{result.answers_lost} answers lost, "
                                                       f"{result.filter_restarts} restarts after a timeout, "
                                                       f"first difference {result.first_difference}")


def test_the_image_states_its_sensor_profile_and_another_is_refused(qemu_board):
    """The ARM image states the profile it was started with in HELLO; counts of another
    profile (every estimate would differ) are refused before anything is injected."""
    with Link(qemu_board.address) as link:
        assert hil.board_profile(link.connect()) == qemu_board.profile
    other = BROAD_PROFILE if qemu_board.profile == DEFAULT_PROFILE else DEFAULT_PROFILE
    run = sim.make_scenario("random", 2.0, 100.0, seed=1)
    source = hil.InjectionInput("simulated random", *si_to_counts(run.gyr, run.acc, run.mag, other), 100.0, other)
    with pytest.raises(hil.HilError, match=f"states sensor profile {qemu_board.profile.name} .* says {other.name}"):
        hil.inject(qemu_board.address, source, filter_name="eecf")


# ---------------------------------------------------------------------------- the command line on QEMU


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_demo_on_the_arm_image(tmp_path, capsys):
    code, out, err = run_cli(capsys, "demo", "--target", "qemu", "--duration", "20", "--output", tmp_path / "d.imulog")
    assert code == 0, out + err
    assert "qemu-stm32f405, qemu target" in out and "recorded: 2000 samples, 2000 estimates" in out
    assert "bit-exact: yes (2000 of 2000" in out and "accuracy vs simulated truth" in out


def test_demo_on_the_arm_image_leaves_nothing_in_the_temporary_directory(tmp_path):
    result = subprocess.run([sys.executable, "-m", "imulink.cli", "demo", "--target", "qemu", "--duration", "10"],
                            env={**os.environ, "TMPDIR": str(tmp_path)}, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "recording: not kept" in result.stdout and list(tmp_path.iterdir()) == []


def test_every_host_verb_against_imulink_emulate_target_qemu(tmp_path):
    emulator = subprocess.Popen([sys.executable, "-m", "imulink.cli", "emulate", "--target", "qemu", "--tcp",
                                 "--fast", "--duration", "30", "--filter", "kf1d"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = emulator.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:"), emulator.stderr.read()

        def cli(*argv) -> subprocess.CompletedProcess:
            return subprocess.run([sys.executable, "-m", "imulink.cli", *map(str, argv)], capture_output=True,
                                  text=True, timeout=300)

        path = tmp_path / "q.imulog"
        record = cli("record", url, "-o", path, "--duration", "2")
        assert record.returncode == 0 and "estimates of kf1d" in record.stdout, record.stderr
        compare = cli("compare", path)
        assert compare.returncode == 0 and "bit-exact: yes" in compare.stdout
        replay = cli("replay", path, "--csv", tmp_path / "q.csv")
        assert replay.returncode == 0 and (tmp_path / "q.csv").stat().st_size > 0
        inject = cli("inject", url, "--input", "sim:turntable:4:100:2", "--filter", "eskf")
        assert inject.returncode == 0 and "bit-exact: yes (400 of 400" in inject.stdout, inject.stdout
        with Link(url) as link:  # inject left the board as it found it
            link.connect()
            status = link.command("GET_STATUS").data.fields
        assert status["active_filter"] == core.FILTERS["kf1d"][0] and status["injection_mode"] == 0
    finally:
        emulator.terminate()
        emulator.wait(10)
    assert emulator.returncode == 0  # SIGTERM is a clean stop
