"""Checkpoints of the board's filter state (CHECKPOINT, SET_CHECKPOINT_PERIOD, GET_CHECKPOINT):
the host resumes verification from them after a sample lost for good, and checks them where
it reaches them without a gap."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from imulink import core, hil, protocol, sim
from imulink.board.emulator import NAV_SCENARIO, EmulatedBoard
from imulink.board.link import Link
from imulink.board.proxy import FaultConfig
from imulink.hil.comparison import unverifiable_spans
from imulink.io.recording import load_recording


def test_a_restored_state_goes_on_as_the_original():
    run = sim.make_scenario("random", 4.0, 100.0, seed=3)
    counts = run.gyr_counts, run.acc_counts, run.mag_counts
    for name in core.BOARD_FILTERS:
        original = core.Filter(name, 100.0)
        original.run_estimates(*(c[:200] for c in counts))
        copy = core.Filter(name, 100.0)
        copy.restore(original.state())
        assert copy.state() == original.state()
        after = [f.run_estimates(*(c[200:] for c in counts)) for f in (original, copy)]
        for field in after[0]:
            np.testing.assert_array_equal(after[0][field], after[1][field])
    with pytest.raises(ValueError, match="is not a state of 'eskf'"):
        core.Filter("eskf", 100.0).restore(core.Filter("eecf", 100.0).state())


def _record(tmp_path, target: str, filter_name: str, drop: tuple[int, ...], duration_s: float = 8.0,
            realtime: bool = False, **options):
    path = tmp_path / f"{target}-{filter_name}.imulog"
    scenario = NAV_SCENARIO if filter_name == "nav" else "random"
    with EmulatedBoard(target, duration_s=duration_s, filter_name=filter_name, scenario=scenario, realtime=realtime,
                       faults=FaultConfig(drop_samples=drop)) as board:
        result = hil.record(board.address, path, resend=False, **options)
    return result, load_recording(path)


@pytest.mark.parametrize("target, filter_name", [("native", "eskf"), ("native", "nav"), ("native", "eecf"),
                                                 ("native", "kf1d"), ("qemu", "eskf"), ("qemu", "nav")])
def test_verification_resumes_at_the_next_checkpoint_after_a_sample_lost_for_good(tmp_path, target, filter_name):
    """Two samples lost for good (no RESEND here): the board's filter runs on, undisturbed (no
    restart); the host resumes from the checkpoints after each loss and checks every other one
    against its own state. The ARM image's states restore in the x86 host build."""
    result, recording = _record(tmp_path, target, filter_name, (150, 420))
    assert result.filter_restarts == 0 and recording.segments == 1
    assert result.checkpoints >= 8 and len(recording.checkpoints) >= 8
    comparison = hil.compare(recording)
    states = comparison.states
    assert states.resumed == 2 and not states.different and not states.unusable
    assert states.verified == states.received - states.resumed >= 6
    assert comparison.bit_exact and comparison.identical_count == comparison.verified_count
    # after each loss, the estimates up to the next checkpoint that arrived are unverifiable, no more
    spans = unverifiable_spans(recording, comparison)
    checkpoints = {c.index for c in recording.checkpoints}
    assert [span["first_index"] for span in spans] == [150, 420]
    assert all(span["last_index"] in checkpoints for span in spans)
    assert comparison.verified[-1]


def test_without_checkpoints_the_filter_is_restarted(tmp_path):
    # in real time: the restart takes effect while the board still streams
    result, recording = _record(tmp_path, "native", "eskf", (50,), duration_s=2.0, realtime=True, checkpoint_s=0.0)
    assert result.checkpoints == 0 and not recording.checkpoints
    assert result.filter_restarts >= 1 and recording.segments >= 2


def test_a_checkpoint_that_differs_from_the_host_is_a_difference(tmp_path):
    _, recording = _record(tmp_path, "native", "eskf", ())
    assert hil.compare(recording).verdict.passed
    first = recording.checkpoints[0]
    state = bytearray(first.state)
    state[-40] ^= 1
    recording.checkpoints[0] = dataclasses.replace(first, state=bytes(state))
    comparison = hil.compare(recording)
    assert comparison.states.different == [(0, first.index)] and not comparison.bit_exact
    assert str(comparison.verdict).startswith("bit-exact: NO (1 checkpoint(s) of the board's filter state differ")
    report = hil.format_comparison(recording, comparison)
    assert f"checkpoints that differ: segment 0 sample index {first.index}" in report


def test_board_checkpoint_commands():
    with EmulatedBoard(duration_s=5.0, filter_name="eskf") as board, Link(board.address) as link:
        link.connect()
        with pytest.raises(protocol.CommandError, match="BUSY"):  # no sample of this run yet
            link.command("GET_CHECKPOINT")
        link.command("START_STREAM")
        link.receive_until(lambda m: m.name == "SAMPLE" and m.fields["index"] >= 20)
        link.command("STOP_STREAM")
        assert not [r for r in link.receive(0.2) if r.message.name == "CHECKPOINT"]  # none periodic by default
        link.command("GET_CHECKPOINT")
        parts = [r.message.fields for r in link.receive(0.2) if r.message.name == "CHECKPOINT"]
        size = parts[0]["state_size"]
        assert [p["part"] for p in parts] == list(range(parts[0]["parts"])) and parts[0]["parts"] == -(-size // 192)
        assert len(b"".join(p["data"] for p in parts)) == size == len(core.Filter("eskf", 100.0).state())
