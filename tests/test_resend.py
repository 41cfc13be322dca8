"""Frames lost on the way and sent again (RESEND / RESENT): the board's memory of its input
frames, the host's bookkeeping of what is missing, and recordings that stay verifiable."""
from __future__ import annotations

import time

import numpy as np
import pytest

from imulink import hil, protocol
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Link
from imulink.board.proxy import FaultConfig
from imulink.io.recording import load_recording
from imulink.protocol.follower import StreamFollower
from imulink.protocol.recovery import RESEND_STATUS, CheckpointParts, LostFrames, in_sent_order, resent_message


def _sample(seq: int, index: int) -> protocol.Message:
    return protocol.decode(protocol.encode("SAMPLE", seq, timestamp_us=10 * index, index=index, gyr=(index, 0, 0),
                                           acc=(0, 0, 4096), mag=(1, 2, 3), temperature=0))


def _resent(seq: int, original: protocol.Message) -> protocol.Message:
    payload = protocol.cobs.decode(protocol.encode(original.name, original.seq, **original.fields)[:-1])[3:-4]
    return protocol.Message("RESENT", seq, {"original_seq": original.seq, "status": RESEND_STATUS["HELD"],
                                            "msg_id": protocol.MESSAGE_IDS[original.name], "payload": payload})


def _gone(seq: int, original_seq: int) -> protocol.Message:
    return protocol.Message("RESENT", seq, {"original_seq": original_seq, "status": RESEND_STATUS["GONE"],
                                            "msg_id": 0, "payload": b""})


# ---------------------------------------------------------------------------- host bookkeeping


def test_resent_message_is_the_original_frame():
    original = _sample(7, 3)
    assert resent_message(_resent(40, original)) == original
    assert resent_message(_gone(41, 7)) is None


def test_lost_frames_asks_for_each_gap_and_again_until_answered():
    lost = LostFrames(retry_s=1.0, attempts=2)
    for seq in (0, 1, 4, 5, 9):  # 2, 3 and 6, 7, 8 missing
        lost.follow(_sample(seq, seq))
    assert lost.lost == 5 and lost.requests(0.0) == [(2, 2), (6, 3)]
    assert lost.requests(0.5) == []  # asked within retry_s
    recovered = lost.follow(_resent(10, _sample(3, 3)))
    assert recovered == _sample(3, 3) and lost.recovered_messages == {"SAMPLE": 1}
    lost.follow(_gone(11, 7))
    assert lost.requests(1.0) == [(2, 1), (6, 1), (8, 1)]
    assert lost.requests(2.0) == [] and lost.unanswered == 3 and lost.outstanding == 0
    assert lost.counters()["gone"] == 1


def test_lost_frames_runs_wrap_and_are_at_most_64_long():
    lost = LostFrames()
    lost.follow(_sample(0xFFF0, 0))
    lost.follow(_sample(0x0050, 1))  # 0xFFF1 .. 0x004F missing, across the wrap
    runs = lost.requests(0.0)
    assert runs[0] == (0xFFF1, 64) and sum(count for _, count in runs) == 0x50 - 0xFFF1 + 0x10000
    assert all(count <= 64 for _, count in runs)


def test_a_reset_forgets_what_was_missing():
    lost = LostFrames()
    lost.follow(_sample(5, 0))
    lost.follow(_sample(9, 1))
    assert lost.outstanding == 3
    lost.follow(protocol.Message("HELLO", 0, {}))
    assert lost.outstanding == 0 and lost.gone == 3


def test_in_sent_order_puts_recovered_frames_back_once():
    live = [_sample(0, 0), _sample(2, 2), _sample(3, 3)]  # seq 1 (sample 1) lost
    again = [(_resent(4, _sample(1, 1)), "again"), (_resent(5, _sample(1, 1)), "twice")]
    received = [(m, "live") for m in live] + again
    ordered = list(in_sent_order(received))
    assert [m.fields["index"] for m, _, _ in ordered] == [0, 1, 2, 3]
    assert [recovered for _, _, recovered in ordered] == [False, True, False, False]
    assert ordered[1][1] == "again"


def test_in_sent_order_keeps_runs_of_a_board_that_started_again():
    received = [(_sample(0, 0), 0), (_sample(2, 2), 0), (protocol.Message("HELLO", 0, {}), 0), (_sample(1, 0), 0),
                (_resent(2, _sample(1, 1)), 0)]  # after the reset seq 1 is the new run's: nothing to recover
    names = [(m.name, m.seq) for m, _, _ in in_sent_order(received)]
    assert names == [("SAMPLE", 0), ("SAMPLE", 2), ("HELLO", 0), ("SAMPLE", 1)]


def test_follower_counts_a_run_complete_once_its_lost_samples_come_back():
    follower = StreamFollower()
    for index in (0, 1, 3, 4):
        follower.follow(_sample(index, index))
    assert not follower.complete and follower.missing_samples == {2}
    follower.recover(_sample(2, 2))
    assert follower.complete
    # recovered before a later SAMPLE shows it missing (a fast round trip)
    follower.recover(_sample(6, 6))
    follower.follow(_sample(5, 5))
    follower.follow(_sample(7, 7))
    assert follower.complete
    follower.follow(_sample(9, 9))
    assert not follower.complete and follower.missing_samples == {8}


# ---------------------------------------------------------------------------- the board


@pytest.fixture(scope="module")
def streaming_link():
    with EmulatedBoard(duration_s=30.0, filter_name="eskf") as board:
        link = Link(board.address)
        try:
            link.connect()
            link.command("START_STREAM")
            yield link
        finally:
            link.close()


def _resend(link: Link, first_seq: int, count: int) -> list[dict]:
    link.command("RESEND", first_seq=first_seq, count=count)
    return [item.message.fields for item in link.receive(timeout=0.2) if item.message.name == "RESENT"]


def test_board_resends_its_input_frames_byte_for_byte(streaming_link):
    link = streaming_link
    received = []
    while len([m for m in received if m.name == "SAMPLE"]) < 20:
        received += [item.message for item in link.receive(timeout=0.2)]
    # the newest SAMPLE with its ESTIMATE: older ones may have waited in the link's buffer (a
    # loaded machine) until the board's ring no longer holds them
    estimated = {m.fields["index"]: m for m in received if m.name == "ESTIMATE"}
    sample = [m for m in received if m.name == "SAMPLE" and m.fields["index"] in estimated][-1]
    estimate = estimated[sample.fields["index"]]
    answers = {fields["original_seq"]: fields for fields in _resend(link, sample.seq, estimate.seq - sample.seq + 1)}
    again = resent_message(protocol.Message("RESENT", 0, answers[sample.seq]))
    assert again == sample  # seq, fields: the same frame
    assert answers[estimate.seq]["status"] == RESEND_STATUS["NOT_KEPT"] and answers[estimate.seq]["payload"] == b""


def test_board_says_what_it_no_longer_holds_and_refuses_bad_counts(streaming_link):
    link = streaming_link
    # 5 000 frames (2 000 samples, 80 kB of SAMPLE frames) have pushed the first ones out of the
    # board's 36 KiB ring: a seq 30 000 back is older than what it holds. The emulator streams as
    # fast as it is read: a few seconds, longer on a busy machine.
    deadline = time.monotonic() + 60.0
    while link.counters()["frames"] <= 5000:
        assert time.monotonic() < deadline, "the emulated board did not stream 5 000 frames in 60 s"
        link.receive(timeout=0.2)
    latest = max(item.message.seq for item in link.receive(timeout=0.2))
    old = _resend(link, (latest - 30000) & 0xFFFF, 1)
    assert [fields["status"] for fields in old] == [RESEND_STATUS["GONE"]]
    for count in (0, 65):
        with pytest.raises(protocol.CommandError, match="BAD_ARGUMENT"):
            link.command("RESEND", first_seq=0, count=count)


# ---------------------------------------------------------------------------- recordings


@pytest.mark.parametrize("target", ["native", "qemu"])
def test_one_dropped_sample_mid_run_leaves_the_rest_of_the_run_verified(tmp_path, target):
    path = tmp_path / "one.imulog"
    with EmulatedBoard(target, duration_s=3.0, filter_name="eskf", faults=FaultConfig(drop_samples=(150,))) as board:
        result = hil.record(board.address, path)
        assert board.proxy.faults.counts["dropped_samples"] == 1
    assert result.filter_restarts == 0 and result.recovery["recovered_messages"] == {"SAMPLE": 1}
    recording = load_recording(path)
    assert recording.segments == 1 and recording.recovered == {"SAMPLE": 1}
    assert recording.samples.index.tolist() == list(range(300))  # in place, nothing missing
    assert recording.samples.recovered.tolist() == [i == 150 for i in range(300)]
    comparison = hil.compare(recording)
    assert comparison.bit_exact and comparison.verified_count == len(recording.estimates) == 300


def test_without_resend_a_lost_sample_ends_verification(tmp_path):
    path = tmp_path / "old.imulog"
    with EmulatedBoard(duration_s=3.0, filter_name="eskf", faults=FaultConfig(drop_samples=(150,))) as board:
        result = hil.record(board.address, path, resend=False, resync=False, checkpoint_s=0.0)
    recording = load_recording(path)
    assert result.recovery["lost"] > 0 and result.recovery["recovered"] == 0
    assert 150 not in recording.samples.index.tolist() and not recording.samples.recovered.any()
    assert hil.compare(recording).verified_count == 150  # the estimates before the loss


def test_a_sample_lost_at_the_very_end_is_recovered(tmp_path):
    path = tmp_path / "end.imulog"
    with EmulatedBoard(duration_s=2.0, faults=FaultConfig(drop_samples=(199,))) as board:
        hil.record(board.address, path)
    recording = load_recording(path)
    assert recording.samples.index.tolist() == list(range(200)) and recording.samples.recovered[-1]


@pytest.mark.xdist_group("takes-a-core")  # never beside the virtual board (tests/test_virtual_board.py)
@pytest.mark.parametrize("faults", [
    FaultConfig(drop_byte=2e-4, seed=1),
    FaultConfig(flip_bit=1e-3, seed=2),
    FaultConfig(garbage=0.01, seed=3),
    FaultConfig(drop_byte=1e-2, seed=4),
], ids=["dropped-2e-4", "flipped-1e-3", "garbage", "dropped-1e-2"])
def test_lossy_links_lose_no_sample_and_every_arrived_estimate_verifies(tmp_path, faults):
    path = tmp_path / "lossy.imulog"
    with EmulatedBoard(duration_s=5.0, rate_hz=1000.0, realtime=True, filter_name="eskf", faults=faults) as board:
        result = hil.record(board.address, path, duration_s=3.0)
    assert result.counters["lost_frames"] > 0 and result.filter_restarts == 0
    recording = load_recording(path)
    assert recording.segments == 1
    np.testing.assert_array_equal(recording.samples.index, np.arange(len(recording.samples)))
    assert recording.samples.recovered.any()
    comparison = hil.compare(recording)
    assert comparison.bit_exact and comparison.verified_count == len(recording.estimates)


@pytest.mark.xdist_group("takes-a-core")
def test_a_two_second_stall_loses_nothing(tmp_path):
    """The link holds everything for 2 s (as long as the default silence timeout): the recorder
    asks the board, which says it streams, and the recording goes on complete."""
    path = tmp_path / "stall.imulog"
    with EmulatedBoard(front="tcp", duration_s=12.0, realtime=True, filter_name="eskf",
                       faults=FaultConfig(stall=1e-3, stall_s=2.0, seed=5)) as board:
        result = hil.record(board.address, path, duration_s=6.0)
        stalls = board.proxy.faults.counts["stalls"]
    assert stalls >= 1 and result.counters["lost_frames"] == 0
    recording = load_recording(path)
    np.testing.assert_array_equal(recording.samples.index, np.arange(len(recording.samples)))
    assert hil.compare(recording).verdict.passed


def test_checkpoint_parts_give_the_state_once_whole():
    parts = CheckpointParts()
    state = bytes(range(200)) + bytes(range(100))

    def part(k: int, index: int = 9) -> dict:
        return {"index": index, "filter_id": 3, "part": k, "parts": 2, "state_size": 300,
                "data": state[192 * k:192 * (k + 1)]}

    assert parts.add(part(1)) is None and parts.add(part(1)) is None  # out of order, and twice
    assert parts.add(part(0)) == state
    assert parts.add(part(0, index=10), key=(0,)) is None
    assert parts.add(part(1, index=10), key=(1,)) is None  # another run's: not the same checkpoint
    for index in range(11, 11 + CheckpointParts.KEEP + 1):  # checkpoints that never become whole
        parts.add(part(0, index))
    assert parts.add(part(1, index=10), key=(0,)) is None  # its first part was forgotten
