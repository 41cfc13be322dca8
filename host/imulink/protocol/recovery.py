"""Frames lost on the way and sent again: RESEND and RESENT (shared/protocol.toml).

The board keeps the filter's input frames it sent lately (SAMPLE, BARO, GNSS, MARKER) and
sends any of them again inside a RESENT frame when the host asks by seq (firmware/app/frame_ring.h).

- :class:`LostFrames` follows a board's frames as they arrive, knows which seqs are missing,
  says which to ask for (and when to ask again), and counts how each ended: recovered, not
  kept (an output frame: ESTIMATE, NAV_STATE, STATUS ...), gone (older than the board's ring)
  or unanswered.
- :func:`resent_message`: the original message inside a RESENT frame.
- :func:`in_sent_order`: a received stream with its recovered frames put back where they were
  first sent, each marked as recovered or not.
- :class:`CheckpointParts`: a board's CHECKPOINT frames put together into its filter's state.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from imulink import protocol

RESEND_STATUS: dict[str, int] = dict(protocol._schema.ENUMS["resend_status"])
_HELD = RESEND_STATUS["HELD"]
_NOT_KEPT = RESEND_STATUS["NOT_KEPT"]
#: Frames one RESEND may ask for (its count argument; the board refuses more).
MAX_RESEND = 64
_HALF = 0x8000


def resent_message(message: protocol.Message) -> protocol.Message | None:
    """The frame inside a RESENT message, with the seq it was first sent with; None when the
    board no longer held it (status NOT_KEPT or GONE) or its bytes are no message of this schema."""
    fields = message.fields
    if fields["status"] != _HELD:
        return None
    try:
        return protocol.message_of_payload(fields["msg_id"], fields["original_seq"], fields["payload"])
    except protocol.FrameError:
        return None


def _missed(message: protocol.Message, expected: int | None) -> int | None:
    """Frames missing before this one, given the seq `expected` next (None: none yet, 0
    missing); None when the board's seq count starts again with it (a HELLO with seq 0 after
    a reset, or a seq that went backwards). protocol.FrameDecoder counts lost frames by the
    same rule, inline."""
    if expected is None:
        return 0
    gap = (message.seq - expected) & 0xFFFF
    return None if (message.name == "HELLO" and message.seq == 0) or gap >= _HALF else gap


class LostFrames:
    """Which of a board's frames are missing, for RESEND. Feed it every frame from the board
    in arrival order (:meth:`follow`); :meth:`requests` says what to ask for now.

    A missing seq is asked for again every `retry_s` seconds (its RESENT or the RESEND may be
    lost too) up to `attempts` times, then counted as unanswered. Counters (:meth:`counters`):
    lost (seqs found missing), recovered, not_kept, gone, unanswered; `outstanding` are the
    seqs still waited for.
    """

    def __init__(self, retry_s: float = 0.1, attempts: int = 20):
        self.retry_s, self.attempts = retry_s, attempts
        self._expected: int | None = None  # the seq the next live frame should have
        self._asked: dict[int, tuple[float, int]] = {}  # missing seq -> (time last asked, asks), in seq order
        self.lost = self.recovered = self.not_kept = self.gone = self.unanswered = 0
        self.recovered_messages: dict[str, int] = {}

    @property
    def give_up_s(self) -> float:
        """Seconds after which a missing seq has been asked for `attempts` times and given up."""
        return self.retry_s * self.attempts

    @property
    def outstanding(self) -> int:
        """Missing seqs not answered yet."""
        return len(self._asked)

    def follow(self, message: protocol.Message) -> protocol.Message | None:
        """Take the next frame received; for a RESENT that answers a missing seq, the recovered
        message (see :func:`resent_message`), else None."""
        missed = _missed(message, self._expected)
        if missed is None:
            self.gone += len(self._asked)  # the board started again: its ring went with it
            self._asked.clear()
        elif missed:
            for seq in range(message.seq - missed, message.seq):
                self._asked[seq & 0xFFFF] = (float("-inf"), 0)
            self.lost += missed
        self._expected = (message.seq + 1) & 0xFFFF
        if message.name != "RESENT" or message.fields["original_seq"] not in self._asked:
            return None
        del self._asked[message.fields["original_seq"]]
        recovered = resent_message(message)
        if recovered is not None:
            self.recovered += 1
            self.recovered_messages[recovered.name] = self.recovered_messages.get(recovered.name, 0) + 1
        elif message.fields["status"] == _NOT_KEPT:
            self.not_kept += 1
        else:
            self.gone += 1
        return recovered

    def requests(self, now: float) -> list[tuple[int, int]]:
        """(first_seq, count) of each RESEND to send now: the missing seqs not asked for within
        retry_s, in runs of consecutive seqs (at most MAX_RESEND each). Seqs asked for `attempts`
        times are given up (unanswered)."""
        due = []
        for seq, (asked_at, asks) in list(self._asked.items()):
            if now - asked_at < self.retry_s:
                continue
            if asks >= self.attempts:
                del self._asked[seq]
                self.unanswered += 1
                continue
            self._asked[seq] = (now, asks + 1)
            due.append(seq)
        runs: list[tuple[int, int]] = []
        for seq in due:
            if runs and (runs[-1][0] + runs[-1][1]) & 0xFFFF == seq and runs[-1][1] < MAX_RESEND:
                runs[-1] = (runs[-1][0], runs[-1][1] + 1)
            else:
                runs.append((seq, 1))
        return runs

    def counters(self) -> dict:
        """How the missing frames ended so far (a summary for reports and recordings)."""
        return {"lost": self.lost, "recovered": self.recovered, "recovered_messages": dict(self.recovered_messages),
                "not_kept": self.not_kept, "gone": self.gone, "unanswered": self.unanswered,
                "outstanding": self.outstanding}


def in_sent_order(received: Sequence[tuple[protocol.Message, Any]]) -> Iterator[tuple[protocol.Message, Any, bool]]:
    """A board's frames (only the board's: its seq count orders them), with anything the caller
    attaches to each (e.g. the time it arrived), in the order the board first sent them: each
    recovered frame (inside a RESENT) is put back at its original place, where the live one
    was lost; a frame that arrived both live and recovered, or recovered twice, is given once.
    Yields (message, attached, recovered); the RESENT frames themselves are left out.

    Frames are ordered by seq within each run of the board's seq count (a reset starts a new
    one); a recovered frame is placed by its original seq, counted back from the RESENT's own.
    A stream without RESENT frames is given as it is."""
    if not any(message.name == "RESENT" for message, _ in received):
        yield from ((message, attached, False) for message, attached in received)
        return
    placed: list[tuple[int, int, protocol.Message, object, bool]] = []
    position = run_start = 0
    expected: int | None = None
    for arrival, (message, attached) in enumerate(received):
        missed = _missed(message, expected)
        if missed is None:
            run_start = position = position + 0x10000  # after everything of the last run
        elif expected is not None:
            position += 1 + missed
        expected = (message.seq + 1) & 0xFFFF
        if message.name != "RESENT":
            placed.append((position, arrival, message, attached, False))
            continue
        original = resent_message(message)
        if original is None:
            continue
        at = position - ((message.seq - original.seq) & 0xFFFF)
        if at >= run_start:  # (a RESENT cannot reach back across a reset: the board's ring is new)
            placed.append((at, arrival, original, attached, True))
    placed.sort(key=lambda item: (item[0], item[1]))
    last = None
    for at, _, message, attached, recovered in placed:
        if at != last:
            yield message, attached, recovered
        last = at


class CheckpointParts:
    """Puts a board's CHECKPOINT frames together: :meth:`add` each one; the filter's whole
    state comes back when the last of its parts arrives. Parts of checkpoints that never
    become whole (one was lost) are forgotten once KEEP others wait."""

    KEEP = 16

    def __init__(self) -> None:
        self._parts: dict[tuple, dict[int, bytes]] = {}

    def add(self, fields: dict, key: tuple = ()) -> bytes | None:
        """A CHECKPOINT's fields (`key` tells apart checkpoints of the same index, e.g. the
        filter run); the state once every part of its checkpoint has arrived, else None."""
        count = fields["parts"]
        name = (*key, fields["index"], fields["filter_id"], count, fields["state_size"])
        got = self._parts.setdefault(name, {})
        got.setdefault(fields["part"], fields["data"])
        if set(got) != set(range(count)):
            while len(self._parts) > self.KEEP:
                del self._parts[next(iter(self._parts))]  # the oldest: a dict keeps the order they came in
            return None
        del self._parts[name]
        state = b"".join(got[k] for k in range(count))
        return state if len(state) == fields["state_size"] else None
