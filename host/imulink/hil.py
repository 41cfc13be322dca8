"""Hardware in the loop: record a board, replay and compare a recording against the host
build of the same C, inject samples into a board, and the no-hardware demo.

- :func:`record`: snapshot the board (HELLO, STATUS, every setting of the active
  filter), restart its filter, stream, and write every received byte to a recording.
  A lost SAMPLE makes the rest of a filter run impossible to reproduce, so by default
  the recorder then restarts the board's filter (``resync``): a new segment begins
  that can be verified again.
- :func:`host_run`: re-run the recorded samples through the fixed-point build (what
  the board must have computed) and the float twin, with the recorded settings and
  sensor profile. :func:`compare` checks every board estimate that can be verified
  (its segment's samples complete from index 0 up to it) bit for bit;
  :func:`export_csv` / :func:`export_npz` write the replay.
- :func:`inject`: stream samples (a recording, a simulation, a BROAD .mat file) into a
  board in injection mode and compare every answer on the fly.
- :func:`demo`: an emulated board (the firmware as a native process or the ARM image
  in QEMU, fed by the simulator), a recording of its simulated run, the comparison,
  and the accuracy against the simulated truth.
"""
from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import numpy as np

from . import core, protocol, sim
from .analysis import angle_difference, attitude_errors, rmse, wrap_deg
from .broad import BroadError, load_broad
from .counts import (BROAD_PROFILE, DEFAULT_PROFILE, SensorDataError, SensorProfile, describe_profile, fixed_scales,
                     profile_from_scales, si_to_counts)
from .emulator import EmulatedBoard
from .files import check_writable_target, create_beside, publish
from .link import (COMMAND_ATTEMPTS, COMMAND_TIMEOUT_MAX_S, DEFAULT_BAUD, CommandTimeout, Disconnected, Link, LinkError,
                   ReceiveTimeout)
from .recording import Estimates, Recording, RecordingError, RecordingWriter, load_recording, sample_times
from .reference import FirmwareFilter

#: Seconds excluded from accuracy statistics (alignment and convergence).
SETTLE_S = 10.0
_FILTER_NAMES = {filter_id: name for name, (filter_id, _) in core.BOARD_FILTERS.items()}


def name_of_filter(filter_id: int) -> str:
    """The name of a filter id a board reports (the number itself for one this host does not know)."""
    return _FILTER_NAMES.get(filter_id, str(filter_id))
_Q = {"quat": core.QUAT_FRAC_BITS, "euler": core.EULER_FRAC_BITS, "gyro_bias": core.RATE_FRAC_BITS}


class HilError(Exception):
    """A HIL job that cannot go on (a board that cannot be configured, a bad input)."""


# ---------------------------------------------------------------------------- progress


class Progress:
    """One status line on stderr: rewritten in place on a terminal, a plain line every
    `interval_s` seconds otherwise."""

    def __init__(self, stream=None, interval_s: float = 5.0):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.interval_s = 0.25 if self.tty else interval_s
        self._last = 0.0
        self._shown = False

    def due(self) -> bool:
        """Whether an update would be shown now (so the caller can skip building it)."""
        return time.monotonic() - self._last >= self.interval_s

    def update(self, text: str, force: bool = False) -> None:
        if not force and not self.due():
            return
        self._last = time.monotonic()
        if self.tty:
            self.stream.write("\r\x1b[K" + text)
            self._shown = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        """A line of its own (a board LOG, a warning) that does not clobber the status line."""
        if self._shown:
            self.stream.write("\r\x1b[K")
        self.stream.write(text + "\n")
        self.stream.flush()

    def done(self) -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False


def link_summary(counters: dict) -> str:
    """Link counters in one phrase."""
    return (f"{counters['frames']} frames, {counters['bytes'] / 1e3:.0f} kB, "
            f"{counters['frame_rate']:.0f} frames/s, CRC errors {counters['crc_errors']}, "
            f"resyncs {counters['resyncs']}, lost {counters['lost_frames']}")


def link_json(counters: dict) -> dict:
    """Link counters for --json (the frame rate only where the live link measured it)."""
    out = {"frames": counters["frames"], "bytes": counters["bytes"], "crc_errors": counters["crc_errors"],
           "resyncs": counters["resyncs"], "lost_frames": counters["lost_frames"]}
    if "frame_rate" in counters:
        out["frame_rate_hz"] = counters["frame_rate"]
    return out


def accuracy_json(accuracy: dict | None) -> dict | None:
    """RMS attitude errors (deg) for --json, after SETTLE_S s; None without a truth."""
    if not accuracy:
        return None
    out = {"rms_total_deg": accuracy["total"], "rms_heading_deg": accuracy["heading"],
           "rms_inclination_deg": accuracy["inclination"], "settle_s": SETTLE_S}
    if "samples" in accuracy:
        out["samples"] = accuracy["samples"]
    return out


def _board_json(hello: dict | None) -> dict | None:
    if not hello:
        return None
    return {"name": hello["board"], "firmware_version": f"{hello['firmware_major']}.{hello['firmware_minor']}."
                                                         f"{hello['firmware_patch']}",
            "schema_hash": f"0x{hello['schema_hash']:08X}"}


def _board_log(progress: Progress | None, fields: dict) -> None:
    if progress is not None:
        level = {v: k for k, v in protocol.LOG_LEVELS.items()}.get(fields["level"], str(fields["level"]))
        progress.message(f"board: {level} {fields['text']}")


# ---------------------------------------------------------------------------- board set-up


def read_settings(link: Link) -> tuple[int, dict[int, dict]]:
    """The active filter's id and its settings (index -> SETTING fields), read with GET_SETTING."""
    first = link.command("GET_SETTING", index=0).data.fields
    settings = {0: first}
    for index in range(1, first["setting_count"]):
        settings[index] = link.command("GET_SETTING", index=index).data.fields
    return first["filter_id"], settings


def setting_range(setting: dict) -> tuple[float, float]:
    """The range [min, max] a SETTING states, in the setting's unit."""
    return setting["min"] / 2.0 ** setting["frac_bits"], setting["max"] / 2.0 ** setting["frac_bits"]


def setting_range_text(setting: dict) -> str:
    """"[0.001, 32767]": a SETTING's range, four significant digits (the ends are the Q
    format's nearest values: 0.001 in Q24 is 0.000999987)."""
    def short(value: float) -> str:
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"

    low, high = setting_range(setting)
    return f"[{short(low)}, {short(high)}]"


def apply_settings(link: Link, settings) -> None:
    """Make the settings file's filter (an imulink.settings_file.FilterSettings) active and
    give it the file's settings (SET_SETTING, raw); the others keep the board's values.
    HilError naming the setting the board refuses."""
    fields = core.settings_fields(settings.filter_name)
    link.command("SELECT_FILTER", filter_id=core.BOARD_FILTERS[settings.filter_name][0])
    raw = settings.raw()
    for index, f in enumerate(fields):
        if f.name in raw:
            try:
                link.command("SET_SETTING", index=index, value=raw[f.name])
            except protocol.CommandError as exc:
                raise HilError(f"the board refuses {f.name} = {settings.values[f.name]:g} {f.unit} "
                               f"({exc.reason})") from None


#: The protocol's sensor codes in the order of imulink.calibration.SENSORS.
_SENSOR_CODES = dict(zip(("gyr", "acc", "mag"), ("GYROSCOPE", "ACCELEROMETER", "MAGNETOMETER")))


def board_profile(hello: dict) -> SensorProfile:
    """The sensor profile a board states in its HELLO (its sensitivities; see
    counts.profile_from_scales). HilError when they are not usable."""
    try:
        return profile_from_scales(hello["gyro_scale"], hello["acc_scale"], hello["mag_scale"])
    except ValueError as exc:
        raise HilError(f"board {hello['board']!r} states no usable sensor sensitivities: {exc}") from None


def check_profile(declared: SensorProfile | None, hello: dict, what: str = "--profile") -> SensorProfile:
    """The board's profile (HELLO); HilError when `declared` (None: nothing declared) has
    other sensitivities, as every estimate would then differ."""
    board = board_profile(hello)
    if declared is not None and fixed_scales(declared) != fixed_scales(board):
        raise HilError(f"the board ({hello['board']}) states sensor profile {describe_profile(board)}; "
                       f"{what} says {describe_profile(declared)}")
    return board


def read_calibration(link: Link):
    """The board's calibration (GET_CALIBRATION of every sensor and axis), as an
    imulink.calibration.Calibration of the profile the board states (link.connect() first)."""
    from .calibration import Calibration, calibration_from_frames

    frames = [link.command("GET_CALIBRATION", sensor=protocol.SENSORS[code], axis=axis).data.fields
              for code in _SENSOR_CODES.values() for axis in range(3)]
    return Calibration(board_profile(link.hello), calibration_from_frames(frames))


def set_calibration(link: Link, calibration) -> None:
    """Give the board `calibration` (every sensor and axis: SET_CALIBRATION; a sensor the
    calibration lacks gets the identity). The board restarts its filter with each."""
    from .calibration import SENSORS, to_fixed

    for name in SENSORS:
        offset, matrix = to_fixed(calibration.sensor(name))
        for axis in range(3):
            link.command("SET_CALIBRATION", sensor=protocol.SENSORS[_SENSOR_CODES[name]], axis=axis,
                         offset=offset[axis], row=tuple(matrix[3 * axis:3 * axis + 3]))


def _leave_injection_mode(link: Link) -> None:
    if link.command("GET_STATUS").data.fields["injection_mode"]:
        link.command("SET_INJECTION_MODE", enabled=0)


# ---------------------------------------------------------------------------- record


#: Attempts of each command of the recorder: over a link that loses 1 % of its bytes a
#: SETTING and its ACK both arrive about one time in two, and the snapshot is some twenty
#: commands, each of which must get through.
RECORD_COMMAND_ATTEMPTS = 12
#: A stream that sends no frame for this long (or for SILENCE_PERIODS sample periods at the
#: board's rate, whichever is longer) has gone silent: the board hangs or stopped unannounced.
SILENCE_MIN_S = 2.0
SILENCE_PERIODS = 20
INTERRUPTED = "interrupted"
#: Seconds `record` waits by default for a board that went away (a reset, a USB re-enumeration).
RECONNECT_S = 30.0
#: Seconds between attempts to open a port that went away.
REOPEN_INTERVAL_S = 0.5


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

    @property
    def interrupted(self) -> bool:
        """Whether Ctrl-C (or SIGTERM) ended the recording."""
        return self.stop_reason == INTERRUPTED

    def to_json(self) -> dict:
        """The summary of `imulink record --json`."""
        return {"recording": str(self.path), "board": _board_json(self.hello), "filter": self.filter_name,
                "samples": self.samples, "estimates": self.estimates, "duration_s": self.duration_s,
                "stop_reason": self.stop_reason, "interrupted": self.interrupted,
                "filter_restarts": self.filter_restarts, "reconnects": self.reconnects,
                "link": link_json(self.counters)}


def default_silence_timeout(status: dict) -> float:
    """Seconds without a frame after which a stream at the STATUS's sample rate is silent."""
    rate_hz = status["sample_rate_mhz"] / 1000.0
    return max(SILENCE_MIN_S, SILENCE_PERIODS / rate_hz) if rate_hz > 0 else SILENCE_MIN_S


def record(url: str, path, *, duration_s: float | None = None, baud: int = DEFAULT_BAUD,
           profile: SensorProfile | None = None, resync: bool = True, silence_timeout_s: float | None = None,
           force: bool = False, progress: Progress | None = None, settings=None,
           reconnect_s: float = RECONNECT_S, listen: bool = False) -> RecordResult:
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

    listen: record a board another client commands (a fan-out TCP front, see
    imulink.proxy.TcpFront) without sending anything: the file starts with the board's last
    HELLO, STATUS, SETTING and CALIBRATION frames the front passes on, then the stream from
    wherever it is (estimates verify from the next filter run that starts at sample 0);
    a silent stream ends the recording normally. `settings` cannot be given then.

    The file keeps everything received up to a failure, and is closed cleanly: a board
    gone for longer raises Disconnected; a stream silent for `silence_timeout_s` (default
    :func:`default_silence_timeout`) raises ReceiveTimeout; a write error (a full disk)
    raises RecordingError at once.

    settings: an imulink.settings_file.FilterSettings given to the board (its filter
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
    recorder = _StreamRecorder(link, writer, filter_id, resync and not listen, progress, listen=listen,
                               reopen=lambda: Link(url, baud, tap=writer.received, attempts=RECORD_COMMAND_ATTEMPTS),
                               settings=settings, profile=profile, reconnect_s=reconnect_s)
    with writer:
        try:
            return recorder.run(hello, filter_name, duration_s, silence)
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
    _leave_injection_mode(link)
    if settings is not None:
        apply_settings(link, settings)
    status = link.command("GET_STATUS").data.fields
    filter_id, settings = read_settings(link)
    filter_name = name_of_filter(filter_id)
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
    """The streaming part of :func:`record`: follows the stream, restarts the board's
    filter after a lost SAMPLE (when `resync`), waits for a board that went away or started
    again (`reopen`, `settings`, `profile`, `reconnect_s`: see record), shows progress,
    stops the stream."""

    RESTART_TIMEOUT_S = 1.0

    def __init__(self, link: Link, writer: RecordingWriter, filter_id: int, resync: bool, progress: Progress | None,
                 *, listen: bool, reopen, settings, profile: SensorProfile | None, reconnect_s: float):
        self.link, self.writer, self.filter_id = link, writer, filter_id
        self.resync, self.progress = resync, progress
        self.samples = self.estimates = self.restarts = self.reconnects = 0
        self.listen = listen  # record without commanding (see record)
        self.reopen = reopen  # () -> a new Link on the same port
        self.settings, self.profile, self.reconnect_s = settings, profile, reconnect_s
        self._earlier_counters: dict = {}  # the counters of the links closed before
        self._link_open = True  # self.link's counters are not among the earlier ones yet
        self._expected_index = 0
        self._segment_complete = True
        self._restart: tuple | None = None  # (PendingCommand, time sent) of a filter restart in flight
        self._start_ack = None  # the START_STREAM ACK: messages before it belong to the snapshot
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

    def _follow(self, message: protocol.Message) -> None:
        name, fields = message.name, message.fields
        if name == "SAMPLE":
            self.samples += 1
            index = fields["index"]
            if index == 0:
                self._segment_complete = True  # a (re)started filter run
            elif index != self._expected_index:
                self._segment_complete = False  # a SAMPLE was lost: the rest of this run cannot be verified
            self._expected_index = index + 1
        elif name == "ESTIMATE":
            self.estimates += 1
            self.filter_name = name_of_filter(fields["filter_id"])
        elif name in ("ACK", "NACK") and self._restart and fields["command_seq"] == self._restart[0].command_seq:
            self._restart = None
            if name == "ACK":  # every frame of the old run came before this: the next SAMPLE must be index 0
                self._segment_complete, self._expected_index = True, 0
        elif name == "STATUS" and not fields["streaming"] and not (self.listen and self.samples == 0):
            # (a listener's first STATUS may be the front's copy from before the stream started)
            self.stop_reason = "the board stopped streaming"
        elif name == "LOG":
            _board_log(self.progress, fields)
        elif name == "HELLO" and message.seq == 0 and not (self.listen and self.samples == 0):
            raise _BoardRestarted  # (a listener's first HELLO is the front's copy)

    def _restart_if_needed(self) -> None:
        if not self.resync or self._segment_complete:
            return
        if self._restart is None or time.monotonic() - self._restart[1] > self.RESTART_TIMEOUT_S:
            self._restart = (self.link.send_command("SELECT_FILTER", filter_id=self.filter_id), time.monotonic())
            self.restarts += 1

    def _start_stream(self, filter_name: str) -> None:
        self.filter_name = filter_name
        if self.listen:  # the stream is whatever the board sends
            self._start_ack, self._streaming, self._last_heard = None, True, time.monotonic()
            self.writer.event("listening")
            return
        self._start_ack = self.link.command("START_STREAM").ack
        self._streaming, self._last_heard = False, time.monotonic()
        self._expected_index, self._segment_complete, self._restart = 0, True, None
        self.writer.event("stream_started", filter=filter_name)

    def run(self, hello: dict, filter_name: str, duration_s: float | None, silence_s: float) -> RecordResult:
        self._start_stream(filter_name)
        # the duration counts from the board's ACK: on a lossy link START_STREAM's retries may take seconds
        started = time.monotonic()
        try:
            while self.stop_reason is None:
                try:
                    try:
                        self._follow_stream(started, duration_s, silence_s)
                    except _BoardRestarted:
                        if self.reconnect_s > 0:  # else its silence ends the recording, as before
                            self._resume("the board started again (a HELLO with sequence number 0)")
                except (Disconnected, CommandTimeout) as exc:  # also while the snapshot is taken again
                    self._await_board(str(exc))
        except KeyboardInterrupt:
            self.stop_reason = INTERRUPTED
        self._stop_stream()
        counters = self.counters()
        self.writer.event("stopped", reason=self.stop_reason, counters=counters)
        elapsed = time.monotonic() - started
        if self.progress is not None:
            self.progress.update(self._status_line(elapsed, counters), force=True)
            self.progress.done()
        return RecordResult(self.writer.path, hello, self.filter_name, self.samples, self.estimates, self.restarts,
                            self.stop_reason, elapsed, counters, self.reconnects)

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
                if self._streaming:
                    self._follow(item.message)
                self._streaming = self._streaming or item.message is self._start_ack
            if writer.failure is not None:
                self._stop_stream()
                self._abort(RecordingError, f"{writer.failure}; the recording ends there", "is readable up to there")
            if now - self._last_heard > silence_s and self.listen:
                self.stop_reason = f"nothing received for {silence_s:g} s: the stream stopped"
            elif now - self._last_heard > silence_s:
                self._abort(ReceiveTimeout, f"{link.url} sent nothing for {silence_s:g} s: the board stopped "
                                            "streaming unannounced or hangs (--silence-timeout sets the wait)")
            self._restart_if_needed()
            elapsed = now - started
            if duration_s is not None and elapsed >= duration_s:
                self.stop_reason = f"{duration_s:g} s recorded"
            if self.progress is not None and self.progress.due():
                self.progress.update(self._status_line(elapsed, self.counters()))

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
        if self.listen:
            _listen(self.link, self.writer, self.profile)
            filter_name = self.filter_name
        else:
            _, self.filter_id, filter_name, _ = snapshot(self.link, self.writer, self.settings, self.profile)
        self.reconnects += 1
        self._start_stream(filter_name)
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
        return (f"recording {elapsed:6.1f} s: {self.samples} samples, {link_summary(counters)}"
                + (f", filter restarts {self.restarts}" if self.restarts else "")
                + (f", reconnects {self.reconnects}" if self.reconnects else ""))


# ---------------------------------------------------------------------------- host run and compare


#: ESTIMATE fields the host computes (Estimates.COMPARED) and the shape of one sample's value.
_ESTIMATE_SHAPES = {"filter_id": (), "quat": (4,), "gyro_bias": (3,), "euler": (3,), "cov_mantissa": (9,),
                    "cov_exponent": (9,), "saturations": (), "weights": (2,)}


@dataclass
class HostRun:
    """The host's computation for each recorded sample (arrays aligned with
    recording.samples). fixed: the fixed-point build's ESTIMATE fields (raw integers);
    float_quat / float_euler / float_gyro_bias: the float twin (SI, rad and rad/s);
    verifiable: the sample's segment is complete from index 0 up to it, so the host
    saw exactly what the board saw."""

    fixed: dict[str, np.ndarray]
    float_quat: np.ndarray
    float_euler: np.ndarray
    float_gyro_bias: np.ndarray
    verifiable: np.ndarray
    #: where the nav filter ran: the NAV_STATE fields of the fixed build (name -> array over
    #: the recorded samples; rows of other filters zero), and the float twin's position
    #: (lat, lon deg, height m; NaN elsewhere and before its first fix)
    nav: dict[str, np.ndarray] | None = None
    nav_rows: np.ndarray | None = None
    float_position: np.ndarray | None = None


def _events_after(table, segment: int, sample_index: np.ndarray) -> np.ndarray:
    """Per row of `table` (BARO, GNSS, MARKER), the position in `sample_index` (a segment's
    recorded samples) of the sample it came after; -1 for another segment or a lost sample."""
    where = np.full(len(table), -1, np.int64)
    mine = np.flatnonzero(table.segment == segment)
    at = np.searchsorted(sample_index, table.index[mine])
    found = (at < len(sample_index)) & (sample_index[np.minimum(at, len(sample_index) - 1)] == table.index[mine])
    where[mine[found]] = at[found]
    return where


def nav_inputs(recording: Recording, segment: int, sample_index: np.ndarray) -> dict:
    """What the board's nav filter took besides the samples of a segment, for
    core.Filter.run_nav_counts: its barometer readings, receiver's fixes and markers, each
    at the position of its sample among `sample_index` (the segment's recorded indices)."""
    baro, gnss, markers = recording.baro, recording.gnss, recording.markers
    b = _events_after(baro, segment, sample_index)
    g = _events_after(gnss, segment, sample_index)
    m = _events_after(markers, segment, sample_index)
    gnss_fields = [name for name, _, _ in protocol.message_fields("GNSS") if name not in ("timestamp_us", "index")]
    fixes = [{name: (getattr(gnss, name)[k].tolist()) for name in gnss_fields} for k in np.flatnonzero(g >= 0)]
    marker_rows = markers.rows()
    return {"baro_after": b[b >= 0], "baro_pa": baro.pressure_pa[b >= 0], "gnss_after": g[g >= 0], "gnss": fixes,
            "marker_after": m[m >= 0], "markers": [marker_rows[k] for k in np.flatnonzero(m >= 0)]}


def host_run(recording: Recording) -> HostRun:
    """Re-run the recorded samples through both builds of the filter the board ran (the
    nav filter with the barometer readings, fixes and markers the board gave it)."""
    samples = recording.samples
    n = len(samples)
    fixed = {name: np.zeros((n,) + shape, np.int64) for name, shape in _ESTIMATE_SHAPES.items()}
    float_quat, float_euler, float_bias = np.full((n, 4), np.nan), np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    verifiable = np.zeros(n, bool)
    nav = nav_rows = float_position = None
    for segment in np.unique(samples.segment).tolist():
        rows = np.flatnonzero(samples.segment == segment)
        name, raw_settings = recording.filter_settings(_segment_filter(recording, segment), segment)
        counts = samples.gyr[rows], samples.acc[rows], samples.mag[rows]
        calibration = recording.calibration(segment)
        reference = FirmwareFilter(name, raw_settings, recording.profile, calibration)
        twin = core.Filter(name, reference.si_settings["sample_rate"], "float", reference.si_settings,
                           recording.profile, calibration)
        if name == "nav":
            inputs = nav_inputs(recording, segment, samples.index[rows])
            board = reference.core.run_nav_counts(*counts, **inputs)
            fixed["filter_id"][rows] = reference.filter_id
            for key in ("quat", "gyro_bias", "euler"):
                fixed[key][rows] = board.raw[key]
            fixed["saturations"][rows] = board.saturations
            if nav is None:
                nav = {key: np.zeros((n,) + values.shape[1:], np.int64) for key, values in board.nav_states.items()}
                nav_rows, float_position = np.zeros(n, bool), np.full((n, 3), np.nan)
            for key, values in board.nav_states.items():
                nav[key][rows] = values
            nav["index"][rows] = samples.index[rows]
            nav_rows[rows] = True
            result = twin.run_nav_counts(*counts, **inputs)
            anchored = board.nav_states["mode"] == 2
            float_position[rows[anchored]] = np.c_[result.lat_deg, result.lon_deg, result.height_m][anchored]
        else:
            for key, values in fixed_outputs(name, raw_settings, recording.profile, *counts, calibration).items():
                fixed[key][rows] = values
            result = twin.run_counts(*counts)
        float_quat[rows], float_euler[rows], float_bias[rows] = result.quat, result.euler, result.gyro_bias
        complete = samples.index[rows] == np.arange(len(rows))
        verifiable[rows] = np.cumprod(complete).astype(bool)
    return HostRun(fixed, float_quat, float_euler, float_bias, verifiable, nav, nav_rows, float_position)


def fixed_outputs(filter_name: str, raw_settings: dict[str, int], profile: SensorProfile, gyr, acc, mag,
                  calibration=None) -> dict:
    """The ESTIMATE fields (arrays, one row per sample) the firmware computes for a filter
    run from its start over these counts (with the board's calibration: None is identity).

    One batch call to the core when that gives every field: not for the ESKF (its
    covariance is read after each sample), and not when the saturation counter moved
    (its value after each sample is needed); then one sample at a time, as the board.
    """
    n = len(gyr)
    reference = FirmwareFilter(filter_name, raw_settings, profile, calibration)
    if filter_name != "eskf":
        batch = reference.core.run_counts(gyr, acc, mag)
        if batch.saturations == 0:  # the counter never decreases: zero at the end means zero throughout
            return {"filter_id": np.full(n, reference.filter_id), "quat": batch.raw["quat"],
                    "gyro_bias": batch.raw["gyro_bias"], "euler": batch.raw["euler"],
                    "cov_mantissa": np.zeros((n, 9), np.int64), "cov_exponent": np.zeros((n, 9), np.int64),
                    "saturations": np.zeros(n, np.int64), "weights": np.zeros((n, 2), np.int64)}
        reference = FirmwareFilter(filter_name, raw_settings, profile, calibration)  # again, sample by sample
    out = {name: np.zeros((n,) + shape, np.int64) for name, shape in _ESTIMATE_SHAPES.items()}
    for k in range(n):
        for key, value in reference.step(k, gyr[k], acc[k], mag[k]).items():
            if key in out:
                out[key][k] = value
    return out


def _segment_filter(recording: Recording, segment: int) -> int:
    ids = recording.estimates.filter_id[recording.estimates.segment == segment]
    if len(ids):
        return int(ids[0])
    if recording.active_filter is None:
        raise RecordingError(f"{recording.path}: no STATUS or ESTIMATE says which filter the board ran")
    return recording.active_filter


#: Default least share of a run that must be verified for a bit-exact "yes" (--min-verified):
#: a few hundred identical estimates out of thousands prove little about the rest.
MIN_VERIFIED = 0.99


@dataclass(frozen=True)
class Verdict:
    """Bit-exact or not, and how much of the run that covers: `verified` of `total` (the
    recorded estimates, or the injected samples: `what`) were checked against the host
    fixed-point build and `identical` of those were equal. It passes only when something
    was verified, all of it identical, at least `min_verified` of the total, and the
    recording is not `damaged`."""

    total: int
    verified: int
    identical: int
    what: str = "recorded estimates"
    damaged: bool = False
    min_verified: float = MIN_VERIFIED

    @property
    def coverage(self) -> float:
        """The share of the total that was verified (0 when there is nothing)."""
        return self.verified / self.total if self.total else 0.0

    @property
    def different(self) -> int:
        return self.verified - self.identical

    @property
    def passed(self) -> bool:
        return (self.verified > 0 and not self.different and not self.damaged
                and self.coverage >= self.min_verified)

    def __str__(self) -> str:
        """The verdict line: "bit-exact: yes (542 of 550 recorded estimates verified, all identical)"."""
        covered = f"{self.verified} of {self.total} {self.what} verified"
        if self.different:
            return f"bit-exact: NO ({self.different} of the {self.verified} verified differ; {covered})"
        if not self.verified:
            return f"bit-exact: no estimate to verify ({covered})"
        if self.damaged:
            return f"bit-exact: not proven: the recording is damaged ({covered}, all identical)"
        if self.coverage < self.min_verified:
            shown = math.floor(self.coverage * 1000) / 10  # never rounded up to the minimum
            return (f"bit-exact: not proven: only {covered} ({shown:g} %, below the minimum "
                    f"{self.min_verified * 100:g} % of --min-verified), all identical")
        return f"bit-exact: yes ({covered}, all identical)"

    def to_json(self) -> dict:
        return {"passed": self.passed, "line": str(self), "counted": self.what, "total": self.total,
                "verified": self.verified, "identical": self.identical, "different": self.different,
                "verified_fraction": self.coverage, "min_verified_fraction": self.min_verified,
                "damaged": self.damaged}


@dataclass
class Difference:
    """The first estimate that differs from the host: where, which field, both values."""

    estimate: int  # position among the recorded estimates
    segment: int
    index: int
    field: str
    board: object
    host: object

    def __str__(self) -> str:
        return (f"estimate #{self.estimate} (segment {self.segment}, sample index {self.index}): {self.field}: "
                f"board {self.board}, host {self.host}")

    def to_json(self) -> dict:
        return {"estimate": self.estimate, "segment": self.segment, "sample_index": self.index,
                "field": self.field, "board": self.board, "host": self.host}


@dataclass
class Comparison:
    """Bit-exactness of a recording's estimates and the fixed-vs-float agreement.

    Per estimate (arrays aligned with recording.estimates): sample_row, the row of its
    SAMPLE in recording.samples (-1 when that SAMPLE was lost); verified, whether the
    host could reproduce it (its filter run complete up to it); identical, verified and
    equal in every field. fixed_vs_float: over the verified estimates, the rotation angle
    between the board's quaternion and the float twin's (deg: max, mean, rms), the
    largest Euler angle difference (deg) and gyro bias difference (deg/s). damaged: the
    recording's damaged spans; what they held was not compared, so a damaged recording
    is never bit-exact. leftover: per estimate, whether it came from a stream the board
    was already sending before the recording began (not part of the recorded run).
    min_verified: the least share of the recorded estimates to verify for a pass.
    """

    sample_row: np.ndarray
    verified: np.ndarray
    identical: np.ndarray
    first_difference: Difference | None
    fixed_vs_float: dict
    damaged: list[tuple[int, int]]
    leftover: np.ndarray
    min_verified: float = MIN_VERIFIED

    @property
    def estimates(self) -> int:
        return len(self.verified)

    @property
    def verified_count(self) -> int:
        return int(self.verified.sum())

    @property
    def identical_count(self) -> int:
        return int(self.identical.sum())

    @property
    def recorded_count(self) -> int:
        """The estimates of the recorded run (all but the leftovers of an earlier stream)."""
        return int((~self.leftover).sum())

    @property
    def bit_exact(self) -> bool:
        """Every verified estimate identical (at least one) and the file undamaged, however
        few were verified: :attr:`verdict` also weighs the coverage."""
        return self.verified_count > 0 and self.identical_count == self.verified_count and not self.damaged

    @property
    def verdict(self) -> Verdict:
        return Verdict(self.recorded_count, self.verified_count, self.identical_count, damaged=bool(self.damaged),
                       min_verified=self.min_verified)


def _sample_rows(recording: Recording) -> np.ndarray:
    """Per estimate, the row of the SAMPLE with the same segment and index (-1: lost)."""
    return sample_rows(recording, recording.estimates.segment, recording.estimates.index)


def _nav_state_rows(recording: Recording) -> np.ndarray:
    """Per estimate, the row of the NAV_STATE with the same segment and index (-1: none)."""
    states, estimates = recording.nav_states, recording.estimates
    return matching_rows(estimates.segment, estimates.index, states.segment, states.index)


def nav_state_position(fields: dict, rows=slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude (deg) and height (m) of NAV_STATE fields (Q29 rad, mm) at `rows`."""
    return (np.degrees(fields["lat"][rows] / 2.0**29), np.degrees(fields["lon"][rows] / 2.0**29),
            fields["height_mm"][rows] / 1000.0)


def compare(recording: Recording, run: HostRun | None = None, min_verified: float = MIN_VERIFIED) -> Comparison:
    """Compare every verifiable board estimate with the host fixed-point build, bit for bit;
    its verdict passes with at least `min_verified` of the recorded estimates verified."""
    run = run or host_run(recording)
    estimates = recording.estimates
    sample_row = _sample_rows(recording)
    verified = sample_row >= 0
    verified[verified] = run.verifiable[sample_row[verified]]
    state_row = _nav_state_rows(recording)
    if run.nav_rows is not None:
        # the nav filter's estimate is verified with its NAV_STATE: both must have arrived
        nav = verified.copy()
        nav[verified] = run.nav_rows[sample_row[verified]]
        verified &= ~nav | (state_row >= 0)
    positions, rows = np.flatnonzero(verified), sample_row[verified]

    def board_and_host(name: str):
        """A compared field's values at the verified estimates: the board's and the host's
        (NAV_STATE fields, "nav_state.<name>", only where the nav filter ran)."""
        if not name.startswith("nav_state."):
            return getattr(estimates, name)[positions], run.fixed[name][rows]
        field = name.split(".", 1)[1]
        states = np.flatnonzero(run.nav_rows[rows])
        return (recording.nav_states.fields[field][state_row[positions[states]]],
                run.nav[field][rows[states]])

    compared = list(Estimates.COMPARED)
    if run.nav is not None:
        compared += [f"nav_state.{name}" for name, _, _ in protocol.message_fields("NAV_STATE")]
    equal = np.ones(len(positions), bool)
    for name in compared:
        board, host = board_and_host(name)
        same = board == host if board.ndim == 1 else np.all(board == host, axis=1)
        if name.startswith("nav_state."):
            equal[np.flatnonzero(run.nav_rows[rows])] &= same
        else:
            equal &= same
    identical = np.zeros(len(verified), bool)
    identical[positions] = equal
    first = None
    if not equal.all():
        k = int(np.flatnonzero(~equal)[0])
        position, row = int(positions[k]), int(rows[k])
        for name in compared:
            if name.startswith("nav_state."):
                field = name.split(".", 1)[1]
                board_value = recording.nav_states.fields[field][state_row[position]]
                host_value = run.nav[field][row]
            else:
                board_value, host_value = getattr(estimates, name)[position], run.fixed[name][row]
            if np.any(board_value != host_value):
                first = Difference(position, int(estimates.segment[position]), int(estimates.index[position]), name,
                                   board_value.tolist(), host_value.tolist())
                break
    fixed_vs_float = _fixed_vs_float(estimates, positions, run.float_quat[rows], run.float_euler[rows],
                                     run.float_gyro_bias[rows])
    if run.nav is not None and len(positions):
        fixed_vs_float.update(_position_fixed_vs_float(recording, run, state_row[positions], rows))
    return Comparison(sample_row, verified, identical, first, fixed_vs_float, recording.damaged,
                      np.asarray(estimates.leftover, bool), min_verified)


def _position_fixed_vs_float(recording: Recording, run: HostRun, state_rows: np.ndarray, rows: np.ndarray) -> dict:
    """The largest distance (m) between the board's nav position (its NAV_STATE) and the
    float twin's, over the verified samples where both have a position."""
    from .sim.navigation import local_offsets

    states = recording.nav_states.fields
    usable = (state_rows >= 0) & ~np.isnan(run.float_position[rows, 0])
    usable[usable] &= states["mode"][state_rows[usable]] == 2
    if not usable.any():
        return {}
    board = state_rows[usable]
    twin = run.float_position[rows[usable]]
    d = local_offsets(*nav_state_position(states, board), twin[:, 0], twin[:, 1], twin[:, 2])
    return {"position_max_m": float(np.linalg.norm(d, axis=1).max())}


def _fixed_vs_float(estimates: Estimates, positions, float_quat, float_euler, float_bias) -> dict:
    """Attitude agreement of the board (fixed build) and the float twin over the verified estimates."""
    if not len(positions):
        return {}
    quat = estimates.quat[positions] / 2.0**_Q["quat"]
    angle = angle_difference(quat, float_quat)
    euler = np.degrees(estimates.euler[positions] / 2.0**_Q["euler"])
    bias = estimates.gyro_bias[positions] / 2.0**_Q["gyro_bias"]
    return {"angle_max_deg": float(angle.max()), "angle_mean_deg": float(angle.mean()),
            "angle_rms_deg": float(np.sqrt(np.mean(angle**2))),
            "euler_max_deg": float(np.abs(wrap_deg(euler - np.degrees(float_euler))).max()),
            "gyro_bias_max_deg_s": float(np.degrees(np.abs(bias - float_bias)).max())}


def format_comparison(recording: Recording, comparison: Comparison) -> str:
    """The human report of `imulink compare`."""
    counters = recording.counters
    lines = [f"recording: {recording.path}"]
    if recording.hello:
        h = recording.hello
        lines.append(f"board: {h['board']} firmware {h['firmware_major']}.{h['firmware_minor']}."
                     f"{h['firmware_patch']}, sensor profile {recording.profile.name}")
    lines.append(f"link: {counters['frames']} frames, {counters['bytes']} bytes, CRC errors {counters['crc_errors']}, "
                 f"resyncs {counters['resyncs']}, lost frames {counters['lost_frames']}; "
                 f"{recording.segments} filter run(s)"
                 + (f"; ignored a truncated tail of {recording.truncated_bytes} bytes"
                    if recording.truncated_bytes else ""))
    if recording.damaged:
        spans = ", ".join(f"{length} bytes at byte {offset}" for offset, length in recording.damaged[:5])
        more = f" and {len(recording.damaged) - 5} more" if len(recording.damaged) > 5 else ""
        lines.append(f"DAMAGED FILE: skipped {len(recording.damaged)} span(s) that are not valid records "
                     f"({spans}{more}); the frames they held are missing")
    c = comparison
    unverifiable = ~c.verified
    leftover = int((unverifiable & recording.estimates.leftover).sum())
    lost = int(unverifiable.sum()) - leftover
    reasons = [text for count, text in (
        (leftover, f"{leftover} left over from a stream the board was already sending when the recording began"),
        (lost, f"{lost} after a lost sample of their filter run")) if count]
    lines.append(f"estimates: {c.estimates} received, {c.verified_count} verifiable, {c.identical_count} identical, "
                 f"{c.verified_count - c.identical_count} different, {c.estimates - c.verified_count} unverifiable"
                 + (f" ({'; '.join(reasons)})" if reasons else ""))
    if c.first_difference is not None:
        lines.append(f"first difference: {c.first_difference}")
    lines.append(str(c.verdict))
    ff = comparison.fixed_vs_float
    if ff:
        lines.append(f"fixed vs float: attitude max {ff['angle_max_deg']:.5f} deg, RMS {ff['angle_rms_deg']:.5f} deg; "
                     f"Euler max {ff['euler_max_deg']:.5f} deg; gyro bias max {ff['gyro_bias_max_deg_s']:.2e} deg/s")
    return "\n".join(lines)


def comparison_json(recording: Recording, comparison: Comparison) -> dict:
    """What `imulink compare --json` prints: the facts of :func:`format_comparison`."""
    c = comparison
    unverifiable = ~c.verified
    leftover = int((unverifiable & c.leftover).sum())
    counters = recording.counters
    return {
        "recording": str(recording.path), "board": _board_json(recording.hello),
        "sensor_profile": recording.profile.name,
        "link": {**link_json(counters), "filter_runs": recording.segments,
                 "truncated_tail_bytes": recording.truncated_bytes},
        "damaged_spans": [{"offset_bytes": offset, "length_bytes": length} for offset, length in recording.damaged],
        "estimates": {"received": c.estimates, "recorded": c.recorded_count, "verifiable": c.verified_count,
                      "identical": c.identical_count, "different": c.verified_count - c.identical_count,
                      "unverifiable": c.estimates - c.verified_count, "unverifiable_left_over": leftover,
                      "unverifiable_after_lost_sample": int(unverifiable.sum()) - leftover},
        "first_difference": c.first_difference.to_json() if c.first_difference is not None else None,
        "verdict": c.verdict.to_json(),
        "fixed_vs_float": dict(c.fixed_vs_float) or None,
    }


# ---------------------------------------------------------------------------- replay export


def replay_columns(recording: Recording, run: HostRun, comparison: Comparison) -> dict[str, np.ndarray]:
    """One row per recorded sample: its time (recording.sample_times), inputs in SI, the
    board's estimate (NaN where its ESTIMATE was lost), the host fixed build and the float
    twin, and whether the board's estimate was identical (1), different (0) or not
    verifiable (NaN). Keys are CSV
    column names that carry their units."""
    s, e, p = recording.samples, recording.estimates, recording.profile
    n = len(s)
    estimate_of = np.full(n, -1)
    has_sample = comparison.sample_row >= 0
    estimate_of[comparison.sample_row[has_sample]] = np.flatnonzero(has_sample)
    have = estimate_of >= 0

    def board(values: np.ndarray, frac_bits: int) -> np.ndarray:
        out = np.full((n,) + values.shape[1:], np.nan)
        out[have] = values[estimate_of[have]] * 2.0**-frac_bits
        return out

    # time_s first: strictly increasing (the sample index at the board's rate), the axis a plotting tool wants
    columns = {"time_s": sample_times(recording), "host_time_s": s.host_time, "timestamp_us": s.timestamp_us,
               "segment": s.segment,
               "index": s.index, "verifiable": run.verifiable.astype(int)}
    axes = ("x", "y", "z")
    for name, counts, scale, unit in (("gyr", s.gyr, p.gyro_scale, "rad_s"), ("acc", s.acc, p.acc_scale, "m_s2"),
                                      ("mag", s.mag, p.mag_scale, "uT")):
        for k, axis in enumerate(axes):
            columns[f"{name}_{axis}_{unit}"] = counts[:, k] * scale
    fixed_quat = run.fixed["quat"] * 2.0**-_Q["quat"]
    sources = {"board": (board(e.quat, _Q["quat"]), board(e.euler, _Q["euler"]), board(e.gyro_bias, _Q["gyro_bias"])),
               "fixed": (fixed_quat, run.fixed["euler"] * 2.0**-_Q["euler"],
                         run.fixed["gyro_bias"] * 2.0**-_Q["gyro_bias"]),
               "float": (run.float_quat, run.float_euler, run.float_gyro_bias)}
    for source, (quat, euler, bias) in sources.items():
        for k, part in enumerate("wxyz"):
            columns[f"{source}_q{part}"] = quat[:, k]
        for k, angle in enumerate(("roll", "pitch", "heading")):
            columns[f"{source}_{angle}_deg"] = np.degrees(euler[:, k])
        for k, axis in enumerate(axes):
            columns[f"{source}_gyro_bias_{axis}_rad_s"] = bias[:, k]
    weights = board(e.weights, 30)  # zero but for the ESKF
    columns["board_gravity_weight"], columns["board_heading_weight"] = weights[:, 0], weights[:, 1]
    if run.nav is not None:
        columns.update(_nav_columns(recording, run))
    columns["baro_pa"], columns["baro_temp_c"] = _baro_columns(recording)
    columns.update(_gnss_columns(recording))
    identical = np.full(n, np.nan)
    checked = have.copy()
    checked[have] = comparison.verified[estimate_of[have]]
    identical[checked] = comparison.identical[estimate_of[checked]]
    columns["identical"] = identical
    columns["fixed_float_angle_deg"] = angle_difference(fixed_quat, run.float_quat)
    return columns


def _nav_columns(recording: Recording, run: HostRun) -> dict[str, np.ndarray]:
    """The nav filter's position and velocity per sample: the board's (its NAV_STATE), the
    host fixed build's and the float twin's (position only); NaN without a position."""
    n = len(recording.samples)
    states = recording.nav_states.fields
    rows = sample_rows(recording, recording.nav_states.segment, recording.nav_states.index)
    board = {name: np.zeros((n,) + values.shape[1:], np.int64) for name, values in states.items()}
    board_mode = np.zeros(n, np.int64)
    for name, values in states.items():
        board[name][rows[rows >= 0]] = values[rows >= 0]
    board_mode[rows[rows >= 0]] = states["mode"][rows >= 0]
    columns = {}
    for source, fields, positioned in (("board", board, board_mode == 2),
                                       ("fixed", run.nav, run.nav_rows & (run.nav["mode"] == 2))):
        def masked(values: np.ndarray) -> np.ndarray:
            return np.where(positioned, values, np.nan)

        lat, lon, height = nav_state_position(fields)
        columns[f"{source}_lat_deg"], columns[f"{source}_lon_deg"] = masked(lat), masked(lon)
        columns[f"{source}_height_m"] = masked(height)
        for k, axis in enumerate(("e", "n", "u")):
            columns[f"{source}_vel_{axis}_m_s"] = masked(fields["vel"][:, k] * 2.0**-20)
    for k, name in enumerate(("lat_deg", "lon_deg", "height_m")):
        columns[f"float_{name}"] = run.float_position[:, k]
    return columns


def matching_rows(segment: np.ndarray, index: np.ndarray, table_segment: np.ndarray,
                  table_index: np.ndarray) -> np.ndarray:
    """The row of a table (its frames' segments and indices) holding each (segment, index), -1 where none does."""
    row_of = {key: row for row, key in enumerate(zip(np.asarray(table_segment).tolist(),
                                                     np.asarray(table_index).tolist()))}
    return np.array([row_of.get(key, -1) for key in zip(np.asarray(segment).tolist(), np.asarray(index).tolist())],
                    np.int64)


def sample_rows(recording: Recording, segment: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The sample row of each (segment, index), -1 where that sample was not received."""
    return matching_rows(segment, index, recording.samples.segment, recording.samples.index)


def _gnss_columns(recording: Recording) -> dict[str, np.ndarray]:
    """The receiver's fixes in the rows of the samples they arrived with, empty elsewhere, in
    SI units under `imulink nav`'s input names (velocity east, north, up), with gnss_time_ms,
    the time each is valid for (the receiver's clock: its latency is the difference)."""
    g, n = recording.gnss, len(recording.samples)
    rows = sample_rows(recording, g.segment, g.index)
    have = rows >= 0
    values = {"gnss_time_ms": g.time_ms, "gnss_lat_deg": g.lat_1e7deg * 1e-7, "gnss_lon_deg": g.lon_1e7deg * 1e-7,
              "gnss_height_m": g.height_mm * 1e-3, "gnss_vel_e_m_s": g.vel_ned_mm_s[:, 1] * 1e-3,
              "gnss_vel_n_m_s": g.vel_ned_mm_s[:, 0] * 1e-3, "gnss_vel_u_m_s": -g.vel_ned_mm_s[:, 2] * 1e-3,
              "gnss_h_acc_m": g.h_acc_mm * 1e-3, "gnss_v_acc_m": g.v_acc_mm * 1e-3,
              "gnss_s_acc_m_s": g.s_acc_mm_s * 1e-3}
    columns = {}
    for name, value in values.items():
        column = np.full(n, np.nan)
        if name.startswith("gnss_vel") or name == "gnss_s_acc_m_s":
            ok = have & (g.has_velocity != 0)
        else:
            ok = have
        column[rows[ok]] = value[ok]
        columns[name] = column
    return columns


def _baro_columns(recording: Recording) -> tuple[np.ndarray, np.ndarray]:
    """The barometer's pressure (Pa) and temperature (degC) in the rows of the samples they
    were read with (by segment and index), empty elsewhere: the columns `imulink nav`'s input
    names so."""
    b, n = recording.baro, len(recording.samples)
    rows = sample_rows(recording, b.segment, b.index)
    have = rows >= 0
    pressure, temperature = np.full(n, np.nan), np.full(n, np.nan)
    pressure[rows[have]] = b.pressure_pa[have]
    temperature[rows[have]] = b.temperature_cdeg[have] / 100.0
    return pressure, temperature


#: Replay columns that hold integers (a float column only where some rows have no value).
_INTEGER_COLUMNS = ("timestamp_us", "segment", "index", "verifiable", "identical", "gnss_time_ms")


def export_csv(columns: dict[str, np.ndarray], path) -> None:
    """Write replay columns as CSV (empty cells where a value is missing). Every number
    reads back as the value it was: integers as integers, floats in Python's shortest
    round-trip form (a Unix host time keeps its microseconds, not nine digits)."""
    names = list(columns)

    def cells(name: str) -> list[str]:
        values = np.asarray(columns[name])
        if name in _INTEGER_COLUMNS or np.issubdtype(values.dtype, np.integer):
            return ["" if v != v else str(int(v)) for v in values.tolist()]  # v != v: NaN
        return ["" if v != v else repr(v) for v in values.astype(np.float64).tolist()]

    with open(path, "w", encoding="utf-8") as out:
        out.write(",".join(names) + "\n")
        for row in zip(*(cells(name) for name in names)):
            out.write(",".join(row) + "\n")


def export_npz(recording: Recording, run: HostRun, columns: dict[str, np.ndarray], path) -> None:
    """Write the replay as .npz: the CSV columns, the raw integers (sensor counts, the
    board's and the host's ESTIMATE fields) and the recording's metadata as JSON."""
    raw = {f"samples_{k}": getattr(recording.samples, k) for k in
           ("gyr", "acc", "mag", "temperature", "timestamp_us", "index", "segment", "host_time")}
    raw.update({f"board_{k}": getattr(recording.estimates, k) for k in
                ("index", "segment", "host_time") + Estimates.COMPARED})
    raw.update({f"host_fixed_{k}": v for k, v in run.fixed.items()})
    meta = {"header": recording.header, "hello": recording.hello, "status": recording.status,
            "counters": recording.counters, "events": recording.events}
    with open(path, "wb") as out:  # a file object: numpy would add ".npz" to a path without it
        np.savez_compressed(out, **columns, **raw, metadata=np.array(json.dumps(meta, default=str)))


# ---------------------------------------------------------------------------- inject


@dataclass
class InjectionInput:
    """Samples to inject: int16 counts (N,3), their rate and sensor profile; optionally
    the filter and raw settings to run them with (a recording's) and the truth."""

    description: str
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    rate_hz: float
    profile: SensorProfile
    filter_name: str | None = None
    raw_settings: dict[str, int] | None = None
    truth: np.ndarray | None = None


def load_injection_input(spec: str) -> InjectionInput:
    """`sim:SCENARIO[:DURATION_S[:RATE_HZ[:SEED]]]` (default 60 s at 100 Hz, seed 0),
    a BROAD .mat file (converted to counts with BROAD_PROFILE) or a recording."""
    if spec.startswith("sim:"):
        return _simulated_input(spec)
    path = Path(spec)
    if not path.exists():
        raise HilError(f"input {spec!r} not found (give a recording, a BROAD .mat file or sim:SCENARIO:SECONDS)")
    if path.suffix.lower() == ".mat":
        return _load_broad(path)
    recording = load_recording(path)
    if not len(recording.samples):
        raise HilError(f"{path} holds no samples")
    name, raw_settings = recording.filter_settings(recording.active_filter)
    s = recording.samples
    return InjectionInput(f"recording {path.name} ({len(s)} samples)", s.gyr, s.acc, s.mag,
                          raw_settings["sample_rate"] / 2.0**16, recording.profile, name, raw_settings)


def _simulated_input(spec: str) -> InjectionInput:
    usage = f"use sim:SCENARIO[:DURATION_S[:RATE_HZ[:SEED]]] with SCENARIO one of {', '.join(sim.SCENARIOS)}"
    parts = spec.split(":")[1:]
    if not 1 <= len(parts) <= 4 or parts[0] not in sim.SCENARIOS:
        raise HilError(f"bad simulated input {spec!r}: {usage}")
    try:
        duration = float(parts[1]) if len(parts) > 1 else 60.0
        rate = float(parts[2]) if len(parts) > 2 else 100.0
        seed = int(parts[3]) if len(parts) > 3 else 0
    except ValueError:
        raise HilError(f"bad simulated input {spec!r}: duration and rate must be numbers, seed an integer") from None
    try:
        run = sim.make_scenario(parts[0], duration, rate, seed)
    except sim.ScenarioError as exc:
        raise HilError(f"bad simulated input {spec!r}: {exc}") from None
    return InjectionInput(f"simulated {parts[0]} ({duration:g} s at {rate:g} Hz, seed {seed})", run.gyr_counts,
                          run.acc_counts, run.mag_counts, rate, run.profile, truth=run.quat_true)


def _load_broad(path: Path) -> InjectionInput:
    try:
        trial = load_broad(path)
    except BroadError as exc:
        raise HilError(str(exc)) from None
    try:
        g, a, m = si_to_counts(trial.gyr, trial.acc, trial.mag, BROAD_PROFILE)
    except SensorDataError as exc:
        raise HilError(f"{path}: {exc}") from None
    return InjectionInput(f"BROAD trial {path.stem} ({len(g)} samples at {trial.rate_hz:g} Hz)", g, a, m,
                          trial.rate_hz, BROAD_PROFILE, truth=trial.quat_ref)


@dataclass
class InjectResult:
    description: str
    samples: int
    answered: int
    identical: int
    answers_lost: int
    filter_restarts: int
    first_difference: dict | None  # sample_index, field, board, host (raw integers)
    filter_name: str
    duration_s: float
    accuracy: dict | None  # RMS errors in deg (total, heading, inclination) over `samples` answered samples
    min_verified: float = MIN_VERIFIED  # the least share of the samples answered and verified for a pass

    @property
    def bit_exact(self) -> bool:
        return self.answered > 0 and self.identical == self.answered

    @property
    def verdict(self) -> Verdict:
        return Verdict(self.samples, self.answered, self.identical, what="injected samples",
                       min_verified=self.min_verified)

    def to_json(self) -> dict:
        """What `imulink inject --json` prints: the facts of :func:`format_inject`."""
        return {"input": self.description, "filter": self.filter_name, "samples": self.samples,
                "answered": self.answered, "unanswered": self.samples - self.answered,
                "answers_lost": self.answers_lost, "filter_restarts": self.filter_restarts,
                "duration_s": self.duration_s, "samples_per_s": self.samples / max(self.duration_s, 1e-9),
                "verdict": self.verdict.to_json(), "first_difference": self.first_difference,
                "accuracy": accuracy_json(self.accuracy)}


def format_inject(result: InjectResult) -> str:
    """The human report of `imulink inject`."""
    unanswered = result.samples - result.answered
    lines = [f"input: {result.description}",
             f"injected {result.samples} samples into {result.filter_name} in {result.duration_s:.1f} s "
             f"({result.samples / max(result.duration_s, 1e-9):.0f} samples/s): {result.answered} answered, "
             f"{unanswered} unanswered"
             + (f" ({result.answers_lost} answers lost on the way, {result.filter_restarts} samples without any reply, "
                "after each of which the filter was restarted)" if unanswered else "")]
    lines.append(str(result.verdict))
    if result.first_difference:
        d = result.first_difference
        lines.append(f"first difference: sample {d['sample_index']}: {d['field']}: board {d['board']}, "
                     f"host {d['host']}")
    if result.accuracy:
        a = result.accuracy
        lines.append(f"accuracy vs truth (RMS after {SETTLE_S:g} s, over the {a['samples']} answered samples): "
                     f"total {a['total']:.3f} deg, heading {a['heading']:.3f} deg, "
                     f"inclination {a['inclination']:.3f} deg")
    return "\n".join(lines)


def _configure_for_injection(link: Link, source: InjectionInput, filter_name: str | None,
                             given=None) -> tuple[str, dict, dict]:
    """Select the filter and set the settings the injection runs with; returns the
    filter name, the raw settings in force, and the original values changed (to restore)."""
    _leave_injection_mode(link)
    wanted_filter = filter_name or (given.filter_name if given is not None else None) or source.filter_name
    if wanted_filter is not None and wanted_filter != _FILTER_NAMES.get(read_settings(link)[0]):
        link.command("SELECT_FILTER", filter_id=core.BOARD_FILTERS[wanted_filter][0])
    filter_id, settings = read_settings(link)
    name = _FILTER_NAMES[filter_id]
    fields = core.settings_fields(name)
    current = {fields[i].name: settings[i]["value"] for i in range(len(fields))}
    wanted = dict(source.raw_settings) if source.raw_settings and name == source.filter_name else {}
    if given is not None:  # a settings file's values, over a recording's
        wanted.update(given.raw())
    wanted["sample_rate"] = core.to_fixed(source.rate_hz, 16, "sample_rate")
    changed = {}
    for index, f in enumerate(fields):
        if f.name in wanted and wanted[f.name] != current[f.name]:
            try:
                link.command("SET_SETTING", index=index, value=wanted[f.name])
            except protocol.CommandError as exc:
                raise HilError(f"the board refuses {f.name} = {wanted[f.name] / 2.0**f.frac_bits:g} {f.unit} "
                               f"({exc.reason})") from None
            changed[index] = current[f.name]
            current[f.name] = wanted[f.name]
    return name, current, changed


def inject(url: str, source: InjectionInput, *, baud: int = DEFAULT_BAUD, filter_name: str | None = None,
           progress: Progress | None = None,
           settings=None, min_verified: float = MIN_VERIFIED) -> InjectResult:
    """Inject every sample of `source` into the board and compare each ESTIMATE with the
    host fixed-point build (with the board's calibration) on the fly.

    settings: an imulink.settings_file.FilterSettings: its filter and settings are used
    (over a recording's); changed settings are restored afterwards. min_verified: the
    least share of the samples answered and verified for the verdict to pass.

    An ESTIMATE lost on the way is counted (answers_lost). A sample whose ACK never
    comes may or may not have run on the board, so the filter is restarted on both
    sides (SET_INJECTION_MODE 1) and the comparison goes on from the next sample.
    The input's counts must be in the sensor profile the board states (HELLO), else HilError.
    """
    if settings is not None and filter_name not in (None, settings.filter_name):
        raise HilError(f"the settings file is for {settings.filter_name}, not {filter_name}")
    with Link(url, baud) as link:
        hello = link.connect()
        profile = check_profile(source.profile, hello, f"the input ({source.description})")
        link.command("STOP_STREAM")
        original_filter = link.command("GET_STATUS").data.fields["active_filter"]
        name, raw_settings, changed = _configure_for_injection(link, source, filter_name, settings)
        calibration = read_calibration(link)
        link.command("SET_INJECTION_MODE", enabled=1)
        try:
            result = _inject_samples(link, source, name, raw_settings, profile, calibration, progress)
            result.min_verified = min_verified
        finally:  # leave the board as it was found
            link.command("SET_INJECTION_MODE", enabled=0)
            for index, value in changed.items():
                link.command("SET_SETTING", index=index, value=value)
            if original_filter != core.BOARD_FILTERS[name][0]:
                link.command("SELECT_FILTER", filter_id=original_filter)
    return result


def _first_different_field(board: dict, host: dict) -> str | None:
    """The first ESTIMATE field in which the board's answer differs from the host's."""
    for name in ("index",) + Estimates.COMPARED:
        mine = list(host[name]) if isinstance(host[name], (list, tuple)) else host[name]
        theirs = list(board[name]) if isinstance(board[name], (list, tuple)) else board[name]
        if mine != theirs:
            return name
    return None


def _first_different_nav_field(board: dict, host: dict) -> str | None:
    """The first NAV_STATE field in which the board's differs from the host's, as "nav_state.<name>"."""
    for name, _, _ in protocol.message_fields("NAV_STATE"):
        theirs = list(board[name]) if isinstance(board[name], (list, tuple)) else board[name]
        if theirs != host[name]:
            return f"nav_state.{name}"
    return None


def _inject_samples(link: Link, source: InjectionInput, name: str, raw_settings: dict, profile: SensorProfile,
                    calibration, progress: Progress | None) -> InjectResult:
    reference = FirmwareFilter(name, raw_settings, profile, calibration)
    n = len(source.gyr)
    answered = identical = lost = restarts = 0
    first = None
    board_quat = np.full((n, 4), np.nan)
    started = time.monotonic()
    gyr, acc, mag = source.gyr.tolist(), source.acc.tolist(), source.mag.tolist()
    for k in range(n):
        try:
            # Not retried (a sample must run once), so its ACK gets the link's longest wait: an
            # emulated board on a busy host can stall past the usual COMMAND_TIMEOUT_S.
            reply = link.command("INJECT_SAMPLE", timeout=COMMAND_TIMEOUT_MAX_S,
                                 timestamp_us=round(k * 1e6 / source.rate_hz) & 0xFFFFFFFF,
                                 index=k, gyr=gyr[k], acc=acc[k], mag=mag[k], temperature=0)
        except CommandTimeout:  # did the sample run on the board? Unknown: restart the filter on both sides
            link.command("SET_INJECTION_MODE", enabled=1)
            reference = FirmwareFilter(name, raw_settings, profile, calibration)
            restarts += 1
            continue
        expected = reference.step(k, gyr[k], acc[k], mag[k])
        # the nav filter's NAV_STATE came after the ESTIMATE, before the ACK: already received
        state = next((r.message.fields for r in link.receive(0) if r.message.name == "NAV_STATE"
                      and r.message.fields["index"] == k), None) if reference.nav_state is not None else None
        if reply.data is None or (reference.nav_state is not None and state is None):
            lost += 1
            continue
        answered += 1
        got = reply.data.fields
        board_quat[k] = np.array(got["quat"]) / 2.0**_Q["quat"]
        different = _first_different_field(got, expected)
        board_value, host_value = (got.get(different), expected.get(different)) if different else (None, None)
        if different is None and state is not None:
            different = _first_different_nav_field(state, reference.nav_state)
            if different is not None:
                field = different.split(".", 1)[1]
                board_value, host_value = state[field], reference.nav_state[field]
        if different is None:
            identical += 1
        elif first is None:
            first = {"sample_index": k, "field": different, "board": np.asarray(board_value).tolist(),
                     "host": np.asarray(host_value).tolist()}
        if progress is not None:
            progress.update(f"injecting: {k + 1}/{n} samples, {identical}/{answered} identical, "
                            f"{(k + 1) / (time.monotonic() - started):.0f} samples/s")
    if progress is not None:
        progress.done()
    accuracy = None
    if source.truth is not None:
        usable = ~np.isnan(board_quat[:, 0]) & ~np.isnan(source.truth[:, 0])  # answered, and a truth to compare
        usable[:int(SETTLE_S * source.rate_hz)] = False
        if usable.any():
            accuracy = {**rmse(attitude_errors(board_quat[usable], source.truth[usable])), "samples": int(usable.sum())}
    return InjectResult(source.description, n, answered, identical, lost, restarts, first, name,
                        time.monotonic() - started, accuracy)


# ---------------------------------------------------------------------------- demo


@dataclass
class DemoReport:
    address: str
    target: str
    record: RecordResult
    recording: Recording
    comparison: Comparison
    accuracy: dict
    duration_s: float
    kept: bool  # whether the recording file was kept (demo(output=...))
    #: the nav filter's position against the truth (RMS m, m/s after SETTLE_S, from the
    #: board's NAV_STATE once it has a position); None for the attitude filters
    nav_accuracy: dict | None = None

    def format(self) -> str:
        r, c, rec = self.record, self.comparison, self.recording
        lost = rec.counters["lost_frames"]
        lines = [
            f"emulated board: {self.address} ({rec.hello['board']}, {self.target} target, filter {r.filter_name})",
            f"recorded: {r.samples} samples, {r.estimates} estimates, {rec.counters['frames']} frames in "
            f"{r.duration_s:.2f} s ({rec.counters['frames'] / max(r.duration_s, 1e-9):.0f} frames/s); "
            f"lost frames {lost}, CRC errors {rec.counters['crc_errors']}",
            str(c.verdict),
        ]
        if c.first_difference is not None:
            lines.append(f"first difference: {c.first_difference}")
        if c.fixed_vs_float:
            ff = c.fixed_vs_float
            lines.append(f"fixed vs float twin: attitude max {ff['angle_max_deg']:.5f} deg, "
                         f"RMS {ff['angle_rms_deg']:.5f} deg")
        if c.fixed_vs_float.get("position_max_m") is not None:
            lines.append(f"fixed vs float twin: position max {c.fixed_vs_float['position_max_m']:.4f} m")
        if self.accuracy:
            a = self.accuracy
            lines.append(f"accuracy vs simulated truth (RMS after {SETTLE_S:g} s): total {a['total']:.3f} deg, "
                         f"heading {a['heading']:.3f} deg, inclination {a['inclination']:.3f} deg")
        if self.nav_accuracy:
            n = self.nav_accuracy
            lines.append(f"navigation vs simulated truth (RMS after {SETTLE_S:g} s, {n['samples']} samples): "
                         f"horizontal {n['horizontal_m']:.2f} m, vertical {n['vertical_m']:.2f} m, "
                         f"velocity {n['velocity_m_s']:.3f} m/s; GNSS fixes rejected {n['rejected']}")
        lines.append(f"recording: {rec.path}" if self.kept else "recording: not kept (--output FILE keeps it)")
        lines.append(f"demo took {self.duration_s:.1f} s")
        return "\n".join(lines)

    def to_json(self) -> dict:
        """What `imulink demo --json` prints: the record summary and the comparison (as
        `record --json` and `compare --json` give them), the accuracy, the kept file."""
        record, comparison = self.record.to_json(), comparison_json(self.recording, self.comparison)
        if not self.kept:  # the temporary file is gone
            record["recording"] = comparison["recording"] = None
        return {"emulated_board": {"address": self.address, "target": self.target}, "record": record,
                "compare": comparison, "verdict": comparison["verdict"], "accuracy": accuracy_json(self.accuracy),
                "navigation_accuracy": self.nav_accuracy,
                "recording": str(self.recording.path) if self.kept else None, "duration_s": self.duration_s}


def demo(*, target: str = "native", transport: str = "tcp", scenario: str = "rests", duration_s: float = 60.0,
         rate_hz: float = 100.0, seed: int = 0, filter_name: str = "eskf", output=None, force: bool = False,
         progress: Progress | None = None, min_verified: float = MIN_VERIFIED) -> DemoReport:
    """Record an emulated board's simulated run (as fast as the link goes) and verify it.

    `target` is "native" (the firmware as a native process) or "qemu" (the ARM image in
    QEMU). `scenario` is one of emulator.SCENARIOS: NAV_SCENARIO feeds the board a
    receiver's fixes and the barometer too, and the nav filter's accuracy is reported.
    `output` keeps the recording (an existing file only with `force`); without it the
    recording lives in a temporary directory that is removed at the end.
    """
    started = time.monotonic()
    if output is not None:
        check_writable_target(output, replace=force)  # before the board is started
    with tempfile.TemporaryDirectory(prefix="imulink-demo-") as scratch, \
            EmulatedBoard(target, front=transport, scenario=scenario, duration_s=duration_s, rate_hz=rate_hz,
                          seed=seed, filter_name=filter_name) as board:
        path = Path(output) if output is not None else Path(scratch) / "demo.imulog"
        result = record(board.address, path, force=force, progress=progress)
        recording = load_recording(path)
        samples = recording.samples
        truth = board.truth(samples.gyr, samples.acc, samples.mag)
        fed = board.positions(samples.gyr, samples.acc, samples.mag)
    comparison = compare(recording, min_verified=min_verified)
    accuracy = {}
    verified = comparison.verified
    if verified.any():
        rows = comparison.sample_row[verified]
        quat = recording.estimates.quat[verified] / 2.0**_Q["quat"]
        settled = rows >= SETTLE_S * rate_hz  # the first samples of the run: alignment and convergence
        usable = settled & ~np.isnan(truth[rows, 0])
        accuracy = rmse(attitude_errors(quat[usable], truth[rows][usable]))
    nav_accuracy = None
    if board.trajectory is not None and filter_name == "nav":
        nav_accuracy = _nav_accuracy(recording, fed, board.trajectory, rate_hz)
    return DemoReport(board.address, target, result, recording, comparison, accuracy, time.monotonic() - started,
                      kept=output is not None, nav_accuracy=nav_accuracy)


def _nav_accuracy(recording: Recording, fed: np.ndarray, traj, rate_hz: float) -> dict | None:
    """The board's navigation (its NAV_STATE frames) against the simulated truth: RMS
    horizontal and vertical position (m) and velocity (m/s) error after SETTLE_S, where
    the board had a position; the gated fixes. `fed`: the simulated sample of each recorded
    sample (EmulatedBoard.positions)."""
    from .sim.navigation import local_offsets

    states = recording.nav_states.fields
    sample = sample_rows(recording, recording.nav_states.segment, recording.nav_states.index)
    at = np.where(sample >= 0, fed[np.maximum(sample, 0)], -1)  # the simulated sample of each NAV_STATE
    usable = (at >= SETTLE_S * rate_hz) & (states["mode"] == 2)
    if not usable.any():
        return None
    k = at[usable]
    e = local_offsets(*nav_state_position(states, usable), traj.lat_deg[k], traj.lon_deg[k], traj.height_m[k])
    velocity = states["vel"][usable] / 2.0**20 - traj.vel_enu[k]
    return {"horizontal_m": float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))),
            "vertical_m": float(np.sqrt(np.mean(e[:, 2] ** 2))),
            "velocity_m_s": float(np.sqrt(np.mean(np.sum(velocity**2, axis=1)))),
            "rejected": int(states["rejected"][usable][-1]), "samples": int(usable.sum())}
