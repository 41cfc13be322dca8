"""Record a board: snapshot, restart its filter, stream, write every received byte, ask the
board again for the frames lost on the way (RESEND), and have it send checkpoints of its
filter state (CHECKPOINT) from which verification resumes after a sample lost for good."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

from imulink import core, protocol
from imulink.board.link import (
    COMMAND_ATTEMPTS,
    DEFAULT_BAUD,
    CommandTimeout,
    Disconnected,
    Link,
    LinkError,
    ReceiveTimeout,
)
from imulink.core.counts import SensorProfile
from imulink.hil.board_setup import apply_settings, check_profile, leave_injection_mode, read_calibration, read_settings
from imulink.hil.common import HilError
from imulink.hil.report import board_json, board_log, link_json, link_summary
from imulink.io.files import check_writable_target, create_beside, publish
from imulink.io.recording import RecordingError, RecordingWriter
from imulink.progress import StatusLine
from imulink.protocol.follower import StreamFollower
from imulink.protocol.recovery import CheckpointParts, LostFrames

#: Attempts of each command of the recorder: over a link that loses 1 % of its bytes a
#: SETTING and its ACK both arrive about one time in two, and the snapshot is some twenty
#: commands, each of which must get through.
RECORD_COMMAND_ATTEMPTS = 12
#: A stream that sends no frame for this long (or for SILENCE_PERIODS sample periods at the
#: board's rate, whichever is longer) has gone silent: the board hangs or stopped unannounced.
SILENCE_MIN_S = 2.0
SILENCE_PERIODS = 20
#: Attempts of the GET_STATUS that asks a silent board whether it stopped streaming (about 4 s
#: for a board that does not answer; over a link losing 1 % of its bytes 19 in 20 get an answer).
SILENCE_QUESTION_ATTEMPTS = 4
INTERRUPTED = "interrupted"
#: Seconds `record` waits by default for a board that went away (a reset, a USB re-enumeration).
RECONNECT_S = 30.0
#: Seconds between attempts to open a port that went away.
REOPEN_INTERVAL_S = 0.5
#: Seconds the recorder waits after the stream for the frames it still asked for (their
#: RESEND retried at LostFrames' pace).
RECOVERY_WAIT_S = 3.0
#: Seconds of samples between the board's checkpoints of its filter state (CHECKPOINT) by
#: default: after a sample lost for good, verification resumes at the next one.
CHECKPOINT_S = 1.0


@dataclass
class RecordResult:
    path: Path
    hello: dict
    filter_name: str
    samples: int
    estimates: int
    filter_restarts: int
    stop_reason: str
    duration_s: float
    counters: dict
    reconnects: int = 0  # the board went away (or started again) and came back; each began a new segment
    recovery: dict = field(default_factory=dict)  # LostFrames.counters(): frames lost and asked for again
    checkpoints: int = 0  # checkpoints of the board's filter state received whole

    @property
    def interrupted(self) -> bool:
        """Whether Ctrl-C (or SIGTERM) ended the recording."""
        return self.stop_reason == INTERRUPTED

    def to_json(self) -> dict:
        """The summary of `imulink record --json`."""
        return {"recording": str(self.path), "board": board_json(self.hello), "filter": self.filter_name,
                "samples": self.samples, "estimates": self.estimates, "duration_s": self.duration_s,
                "stop_reason": self.stop_reason, "interrupted": self.interrupted,
                "filter_restarts": self.filter_restarts, "reconnects": self.reconnects,
                "link": link_json(self.counters), "recovery": self.recovery, "checkpoints": self.checkpoints}


def default_silence_timeout(status: dict) -> float:
    """Seconds without a frame after which a stream at the STATUS's sample rate is silent."""
    rate_hz = status["sample_rate_mhz"] / 1000.0
    return max(SILENCE_MIN_S, SILENCE_PERIODS / rate_hz) if rate_hz > 0 else SILENCE_MIN_S


def record(url: str, path, *, duration_s: float | None = None, baud: int = DEFAULT_BAUD,
           profile: SensorProfile | None = None, resync: bool = True, silence_timeout_s: float | None = None,
           force: bool = False, progress: StatusLine | None = None, settings=None,
           reconnect_s: float = RECONNECT_S, listen: bool = False, resend: bool = True,
           checkpoint_s: float = CHECKPOINT_S) -> RecordResult:
    """Record a board's stream to `path` until `duration_s` s have passed, the board stops
    streaming (STATUS.streaming = 0), or Ctrl-C (then `interrupted`).

    An existing `path` is refused before the port is opened unless `force`. The file is
    written under a temporary name beside `path` until the board has answered the
    handshake and the snapshot; only then does it take the name `path` (replacing the
    old file with `force`): a wrong port, a peer that is not a board, a failure before
    streaming leave no file behind and the old one untouched.

    A board that goes away (its port fails: a USB re-enumeration, a TCP board that stops)
    or starts again (a HELLO with sequence number 0: a reset) is waited for up to
    `reconnect_s` seconds (0: not at all); when it answers again, the snapshot is taken
    again (with `settings` given again) and the recording goes on in a new segment of the
    same file.

    resend: ask the board again (RESEND) for every frame found missing, while streaming and
    after it (up to RECOVERY_WAIT_S): the board keeps its input frames (SAMPLE, BARO, GNSS,
    MARKER) of about the last second at 1 kHz, and what it sends again goes into the file,
    where load_recording puts it back in place.

    checkpoint_s: the board sends its filter's whole state (CHECKPOINT) after every
    checkpoint_s seconds of samples (0: never), from which the host resumes verification
    after a SAMPLE lost for good (older than the board's memory); the recorder then asks for
    one at once (GET_CHECKPOINT). A board without checkpoints has its filter restarted
    instead, when `resync`.

    listen: record a board another client commands (a fan-out TCP front, see
    imulink.board.proxy.TcpFront) without sending anything: the file starts with the board's last
    HELLO, STATUS, SETTING and CALIBRATION frames the front passes on, then the stream from
    wherever it is (estimates verify from the next filter run that starts at sample 0);
    a silent stream ends the recording normally. `settings` cannot be given then.

    The file keeps everything received up to a failure, and is closed cleanly: a board
    gone for longer raises Disconnected; a stream silent for `silence_timeout_s` (default
    :func:`default_silence_timeout`) raises ReceiveTimeout; a write error (a full disk)
    raises RecordingError at once.

    settings: an imulink.io.settings_file.FilterSettings given to the board (its filter
    made active) before the snapshot, so the recording runs with them. profile: the sensor
    profile the caller expects (None: whatever the board states); HilError, and no file,
    when the board states another.
    """
    path = Path(path)
    if listen and settings is not None:
        raise HilError("a listener cannot give the board settings: the client that commands it can")
    check_writable_target(path, replace=force)
    fd, temporary = create_beside(path)
    writer = RecordingWriter(path, url, profile, fd=fd)
    try:
        # the file holds every byte from the moment the port opens
        link = Link(url, baud, tap=writer.received, attempts=RECORD_COMMAND_ATTEMPTS)
        try:
            if listen:
                hello, filter_id, filter_name, status = _listen(link, writer, profile), 0, "unknown", None
            else:
                hello, filter_id, filter_name, status = snapshot(link, writer, settings, profile)
            writer.check()
            publish(temporary, path, replace=force)
        except BaseException:
            link.close()
            raise
    except BaseException:
        writer.close()
        temporary.unlink(missing_ok=True)
        raise
    silence = silence_timeout_s or (default_silence_timeout(status) if status else SILENCE_MIN_S)
    recorder = _StreamRecorder(link, writer, filter_id, resync and not listen, resend and not listen, progress,
                               listen=listen, checkpoint_s=0.0 if listen else checkpoint_s,
                               reopen=lambda: Link(url, baud, tap=writer.received, attempts=RECORD_COMMAND_ATTEMPTS),
                               settings=settings, profile=profile, reconnect_s=reconnect_s)
    with writer:
        try:
            return recorder.run(hello, filter_name, status, duration_s, silence)
        finally:
            recorder.link.close()  # the last one (closing twice is harmless)


def snapshot(link: Link, writer: RecordingWriter | None, settings=None,
             profile: SensorProfile | None = None) -> tuple[dict, int, str, dict]:
    """Handshake (HilError when the board states another sensor profile than `profile`,
    None: any), quiet the board (and give it `settings`), read its state, settings and
    calibration (into the recording, when there is one), and restart its filter so that
    the stream starts at sample index 0. Returns the HELLO fields, the active filter's id
    and name, and the STATUS fields."""
    hello = link.connect()
    check_profile(profile, hello)
    if writer is not None:
        writer.event("connected", hello=hello)
    link.command("STOP_STREAM")
    leave_injection_mode(link)
    if settings is not None:
        apply_settings(link, settings)
    status = link.query("GET_STATUS")
    filter_id, settings = read_settings(link)
    filter_name = core.filter_name_of(filter_id)
    if writer is not None:
        calibration = read_calibration(link)
        writer.event("snapshot", status=status, filter=filter_name,
                     settings={s["name"]: s["value"] for s in settings.values()},
                     calibration={name: {"offset_counts": c.offset.tolist(), "matrix": c.matrix.tolist()}
                                  for name, c in calibration.sensors.items()})
    link.command("SELECT_FILTER", filter_id=filter_id)
    return hello, filter_id, filter_name, status


def _listen(link: Link, writer: RecordingWriter, profile: SensorProfile | None) -> dict:
    """The start of a listener's recording: the board's HELLO as the front passes it on."""
    hello = link.listen()
    check_profile(profile, hello)
    writer.event("connected", hello=hello, listening=True)
    return hello


class _BoardRestarted(Exception):
    """A HELLO with sequence number 0 in the stream: the board started again."""


def _sum_counters(first: dict, second: dict) -> dict:
    """Counters of two links one after the other: the counts add up, the rates are the second's."""
    out = dict(second)
    for key in ("frames", "bytes", "crc_errors", "resyncs", "lost_frames", "sequence_restarts"):
        out[key] = first.get(key, 0) + second.get(key, 0)
    return out


class _StreamRecorder:
    """The streaming part of :func:`record`: follows the stream, asks the board again for
    lost frames (when `resend`), after a SAMPLE lost for good asks for a checkpoint of the
    board's filter state or, from a board without them, restarts its filter (when `resync`),
    waits for a board that went away or started
    again (`reopen`, `settings`, `profile`, `reconnect_s`: see record), shows progress,
    stops the stream."""

    RESTART_TIMEOUT_S = 1.0

    def __init__(self, link: Link, writer: RecordingWriter, filter_id: int, resync: bool, resend: bool,
                 progress: StatusLine | None, *, listen: bool, checkpoint_s: float, reopen, settings,
                 profile: SensorProfile | None, reconnect_s: float):
        self.link, self.writer, self.filter_id = link, writer, filter_id
        self.resync, self.resend, self.progress = resync, resend, progress
        self._lost = LostFrames()
        self._missing_since: dict[int, float] = {}  # a missing SAMPLE's index -> when it was found missing
        self._missing_segment = 0  # the follower's segment those indices belong to
        self.checkpoint_s = checkpoint_s
        self._checkpointing = False  # the board sends checkpoints (it took SET_CHECKPOINT_PERIOD)
        self._checkpoint_asked = float("-inf")  # when the last GET_CHECKPOINT went
        self._asked_silent = False  # a silent board answered that it streams, and no SAMPLE came since
        self._checkpoint_parts = CheckpointParts()
        self.checkpoints = 0
        self.samples = self.estimates = self.restarts = self.reconnects = 0
        self.listen = listen  # record without commanding (see record)
        self.reopen = reopen  # () -> a new Link on the same port
        self.settings, self.profile, self.reconnect_s = settings, profile, reconnect_s
        self._earlier_counters: dict = {}  # the counters of the links closed before
        self._link_open = True  # self.link's counters are not among the earlier ones yet
        self._follower = StreamFollower()
        self._restart: tuple | None = None  # (PendingCommand, time sent) of a filter restart in flight
        # the START_STREAM ACK: messages before it belong to the snapshot
        self._start_ack: protocol.Message | None = None
        self._streaming = False
        self._last_heard = 0.0
        self.stop_reason: str | None = None

    def counters(self) -> dict:
        return _sum_counters(self._earlier_counters, self.link.counters()) if self._link_open else (
            dict(self._earlier_counters))

    def _close_link(self) -> None:
        if self._link_open:
            self._earlier_counters, self._link_open = self.counters(), False
        self.link.close()

    def _use_link(self, link: Link) -> None:
        self._close_link()
        self.link, self._link_open = link, True

    def _take(self, message: protocol.Message) -> None:
        """One received frame: note what it shows lost or brings back, and follow the stream."""
        recovered = self._lost.follow(message)
        if recovered is not None and self._streaming:
            self._follower.recover(recovered)
        if self._streaming:
            self._follow(message)
        self._streaming = self._streaming or message is self._start_ack

    def _ask_again(self) -> None:
        """RESEND what is missing and due (LostFrames paces the asks)."""
        if self.resend:
            for first_seq, count in self._lost.requests(time.monotonic()):
                self.link.post("RESEND", first_seq=first_seq, count=count)

    def _follow(self, message: protocol.Message) -> None:
        name, fields = message.name, message.fields
        self._follower.follow(message)  # a lost SAMPLE: its run is unverifiable unless it comes again
        if name == "CHECKPOINT":
            self._take_checkpoint(fields)
        elif name == "SAMPLE":
            self.samples += 1
            self._asked_silent = False
        elif name == "ESTIMATE":
            self.estimates += 1
            self.filter_name = core.filter_name_of(fields["filter_id"])
        elif name in ("ACK", "NACK") and self._restart and fields["command_seq"] == self._restart[0].command_seq:
            self._restart = None  # an ACK began a new run (the follower saw it); a NACK: ask again
        elif name == "STATUS" and not fields["streaming"] and not (self.listen and self.samples == 0):
            # (a listener's first STATUS may be the front's copy from before the stream started)
            self.stop_reason = "the board stopped streaming"
        elif name == "LOG":
            board_log(self.progress, fields)
        elif name == "HELLO" and message.seq == 0 and not (self.listen and self.samples == 0):
            raise _BoardRestarted  # (a listener's first HELLO is the front's copy)

    def _take_checkpoint(self, fields: dict) -> None:
        """A CHECKPOINT part: once every part of one arrived, the samples lost before it no
        longer keep its run from being verified (the host resumes there)."""
        if self._checkpoint_parts.add(fields, key=(self._follower.segment,)) is not None:
            self.checkpoints += 1
            self._follower.resume_at(fields["index"])

    def _lost_for_good(self) -> bool:
        """Whether a SAMPLE of the current run is missing for good: not recovered within the
        time LostFrames asks for it (at once without `resend`)."""
        missing = self._follower.missing_samples
        if not self.resend or not missing:
            return not self._follower.complete
        now = time.monotonic()
        since = self._missing_since
        if self._missing_segment != self._follower.segment:  # a new run: its indices are new ones
            since.clear()
            self._missing_segment = self._follower.segment
        for index in [i for i in since if i not in missing]:
            del since[index]
        for index in missing:
            since.setdefault(index, now)
        return now - min(since.values()) > self._lost.give_up_s

    def _restart_if_needed(self) -> None:
        if not self.resync or self._follower.complete or not self._lost_for_good():
            return
        now = time.monotonic()
        if self._checkpointing:  # verification resumes from the board's state: its filter runs on undisturbed
            if now - self._checkpoint_asked > self.RESTART_TIMEOUT_S:  # (its parts may be lost: ask now and then)
                self.link.post("GET_CHECKPOINT")
                self._checkpoint_asked = now
        elif self._restart is None or now - self._restart[1] > self.RESTART_TIMEOUT_S:
            self._restart = (self.link.send_command("SELECT_FILTER", filter_id=self.filter_id), now)
            self.restarts += 1

    def _start_stream(self, filter_name: str, status: dict | None) -> None:
        self.filter_name = filter_name
        if self.listen:  # the stream is whatever the board sends
            self._start_ack, self._streaming, self._last_heard = None, True, time.monotonic()
            self.writer.event("listening")
            return
        self._checkpointing = self._ask_for_checkpoints(status)
        self._start_ack = self.link.command("START_STREAM").ack
        self._streaming, self._last_heard = False, time.monotonic()
        self._follower, self._restart = StreamFollower(), None  # the snapshot restarted the filter
        self._missing_since.clear()
        self._missing_segment = 0
        self.writer.event("stream_started", filter=filter_name)

    def _ask_for_checkpoints(self, status: dict | None) -> bool:
        """SET_CHECKPOINT_PERIOD for checkpoint_s at the board's rate; whether the board took it
        (a board built before checkpoints refuses the command)."""
        rate_hz = status["sample_rate_mhz"] / 1000.0 if status else 0.0
        if self.checkpoint_s <= 0 or rate_hz <= 0:
            return False
        try:
            self.link.command("SET_CHECKPOINT_PERIOD", period=max(1, round(self.checkpoint_s * rate_hz)))
        except protocol.CommandError:
            return False
        return True

    def run(self, hello: dict, filter_name: str, status: dict | None, duration_s: float | None,
            silence_s: float) -> RecordResult:
        self._start_stream(filter_name, status)
        # the duration counts from the board's ACK: on a lossy link START_STREAM's retries may take seconds
        started = time.monotonic()
        try:
            while self.stop_reason is None:
                try:
                    try:
                        self._follow_stream(started, duration_s, silence_s)
                    except _BoardRestarted:
                        if self.reconnect_s > 0:  # else (no --reconnect) its silence ends the recording
                            self._resume("the board started again (a HELLO with sequence number 0)")
                except (Disconnected, CommandTimeout) as exc:  # also while the snapshot is taken again
                    self._await_board(str(exc))
        except KeyboardInterrupt:
            self.stop_reason = INTERRUPTED
        self._stop_stream()
        if self.stop_reason != INTERRUPTED:
            self._recover_the_rest()
        counters = self.counters()
        self.writer.event("stopped", reason=self.stop_reason, counters=counters, recovery=self._lost.counters())
        elapsed = time.monotonic() - started
        if self.progress is not None:
            self.progress.update(self._status_line(elapsed, counters), force=True)
            self.progress.done()
        return RecordResult(self.writer.path, hello, self.filter_name, self.samples, self.estimates, self.restarts,
                            self.stop_reason, elapsed, counters, self.reconnects, self._lost.counters(),
                            self.checkpoints)

    def _recover_the_rest(self) -> None:
        """After the stream: wait up to RECOVERY_WAIT_S for the frames still asked for (the
        STOP_STREAM ACK shows the frames lost at the very end), asking again as they are due."""
        if not self.resend:
            return
        deadline = time.monotonic() + RECOVERY_WAIT_S
        try:
            while self._lost.outstanding and time.monotonic() < deadline:
                for item in self.link.receive(timeout=0.05):
                    self._take(item.message)
                self._ask_again()
        except LinkError:
            pass  # the board went away: what came is in the file

    def _follow_stream(self, started: float, duration_s: float | None, silence_s: float) -> None:
        """Follow the stream until a stop reason (or an exception: the board went away or
        started again)."""
        link, writer = self.link, self.writer
        while self.stop_reason is None:
            received = link.receive(timeout=0.1)
            now = time.monotonic()
            if received:
                self._last_heard = now
            for item in received:
                self._take(item.message)
            self._ask_again()
            if writer.failure is not None:
                self._stop_stream()
                self._abort(RecordingError, f"{writer.failure}; the recording ends there", "is readable up to there")
            if now - self._last_heard > silence_s and self.listen:
                self.stop_reason = f"nothing received for {silence_s:g} s: the stream stopped"
            elif now - self._last_heard > silence_s:
                self._silence(silence_s)
            self._restart_if_needed()
            elapsed = now - started
            if duration_s is not None and elapsed >= duration_s:
                self.stop_reason = f"{duration_s:g} s recorded"
            if self.progress is not None and self.progress.due():
                self.progress.update(self._status_line(elapsed, self.counters()))

    def _silence(self, silence_s: float) -> None:
        """Nothing came for silence_s: ask the board. One that says it stopped streaming ends the
        recording normally (the STATUS that announced it was lost on the way); one that says it
        streams was held up (a stalled link) and is given another silence_s, once until a SAMPLE
        comes again; one that does not answer hangs or went away: ReceiveTimeout."""
        try:
            status = None if self._asked_silent else self.link.query("GET_STATUS",
                                                                     attempts=SILENCE_QUESTION_ATTEMPTS)
        except (LinkError, protocol.ProtocolError):
            status = None
        if status is not None and not status["streaming"]:
            self.stop_reason = "the board stopped streaming"
        elif status is not None:
            self._asked_silent, self._last_heard = True, time.monotonic()
        else:
            self._abort(ReceiveTimeout, f"{self.link.url} sent nothing for {silence_s:g} s: the board stopped "
                                        "streaming unannounced or hangs (--silence-timeout sets the wait)")

    def _say(self, text: str) -> None:
        if self.progress is not None:
            self.progress.message(text)

    def _await_board(self, reason: str) -> None:
        """The link failed: wait up to reconnect_s for the port to open and the board to
        answer, then go on in a new segment; Disconnected (the file closed cleanly) if it
        does not come back."""
        if self.reconnect_s <= 0:
            self._abort(Disconnected, reason)
        self.writer.event("disconnected", reason=reason)
        self._close_link()
        self._say(f"{self.link.url}: {reason}; waiting up to {self.reconnect_s:g} s for the board to come back")
        lost_at = time.monotonic()
        while True:
            try:
                link = self.reopen()
            except LinkError as exc:
                failure = str(exc)
            else:
                self.writer.received(b"\0", time.time())  # ends a frame the old link left half received
                self._use_link(link)
                try:
                    self._resume(f"the board is back after {time.monotonic() - lost_at:.1f} s")
                    return
                except (LinkError, protocol.ProtocolError) as exc:  # it went away again, or is not answering yet
                    failure = str(exc)
                    self._close_link()
            if time.monotonic() - lost_at > self.reconnect_s:
                self._abort(Disconnected, f"{reason}; the board did not come back within {self.reconnect_s:g} s "
                                          f"(--reconnect sets the wait; last attempt: {failure})")
            time.sleep(REOPEN_INTERVAL_S)

    def _resume(self, why: str) -> None:
        """Take the snapshot again (the board's settings and calibration go into the file
        for the new segment) and start the stream again."""
        self.writer.event("reconnected", reason=why)
        status = None
        if self.listen:
            _listen(self.link, self.writer, self.profile)
            filter_name = self.filter_name
        else:
            _, self.filter_id, filter_name, status = snapshot(self.link, self.writer, self.settings, self.profile)
        self.reconnects += 1
        self._start_stream(filter_name, status)
        self._say(f"{self.link.url}: {why}: the recording goes on in a new segment")

    def _stop_stream(self) -> None:
        if self.listen:
            return  # not this client's to stop
        try:  # the recording is complete either way, and the board may be gone: no long retries
            self.link.command("STOP_STREAM", attempts=COMMAND_ATTEMPTS)
        except (LinkError, protocol.ProtocolError):
            pass

    def _abort(self, error: type[Exception], reason: str, kept: str | None = None) -> NoReturn:
        """End the recording on a failure: a last event, and `error` saying what the file keeps."""
        counters = self.counters()
        self.writer.event("stopped", reason=reason, counters=counters)
        if self.progress is not None:
            self.progress.done()
        kept = kept or f"keeps the {counters['frames']} frames received before (complete and readable)"
        raise error(f"{reason}; {self.writer.path} {kept}")

    def _status_line(self, elapsed: float, counters: dict) -> str:
        recovered = self._lost.recovered_messages.get("SAMPLE", 0)
        return (f"recording {elapsed:6.1f} s: {self.samples} samples, {link_summary(counters)}"
                + (f", {recovered} lost samples recovered" if recovered else "")
                + (f", filter restarts {self.restarts}" if self.restarts else "")
                + (f", reconnects {self.reconnects}" if self.reconnects else ""))
