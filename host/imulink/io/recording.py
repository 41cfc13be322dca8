"""Recording files: the raw received byte stream with host receive times, append-only.

File layout (all little-endian)::

    magic    8 bytes  b"IMULOG1\\n"
    record*  u32 body_length | u8 kind | f64 host_time (s, Unix) | body | u32 crc32(all before it)

Kinds: HEADER (the first record; JSON: format version, host version, schema hash, port,
the sensor profile the user declared or null), RECEIVED (a chunk of bytes exactly as read from the port, frames
and damage alike), EVENT (JSON: connected, snapshot, stream started, stopped with the
reason and the link counters, ...). Records of unknown kinds are skipped.

Every record is written whole (short writes are completed) to a file opened for
appending, and the file is fsync'ed about once a second: a crash, a pulled cable or a
full disk leaves at worst a partial last record. :func:`read_records` checks every
record's CRC; where a record is damaged it looks for the next valid one and reports
the damaged span by offset. Bytes after which no valid record follows are a truncated
tail (a partial last record, zero fill): ignored, everything before kept.

:func:`load_recording` refuses a recording whose header names another protocol
version or schema hash than this host's (or an earlier one this host's only adds to): its
frames would be misread. The counts' sensor
profile is the one the board states in its HELLO (the header's only without a HELLO).

:func:`load_recording` decodes the frames of a file into numpy tables of samples and
estimates, split into *segments*: runs of the filter from sample index 0, as
:class:`imulink.protocol.follower.StreamFollower` finds them (a restarting command's ACK,
a start-up HELLO, or a sample index that goes backwards begins a new segment).
Frames lost on the way and sent again by the board (RESENT, asked for by the recorder) are
put back where they were first sent (:func:`imulink.protocol.recovery.in_sent_order`) and
marked as recovered; a recording without them reads as before.
"""
from __future__ import annotations

import errno
import json
import os
import re
import struct
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imulink import __version__, core, protocol
from imulink.core.calibration import SENSORS, Calibration, CalibrationError, calibration_from_frames
from imulink.core.counts import SensorProfile, profile_from_json, profile_from_scales, profile_to_json
from imulink.errors import ImulinkError
from imulink.io.files import FileError, read_regular_file
from imulink.progress import CountProgress
from imulink.protocol.follower import RUN_FRAMES, StreamFollower
from imulink.protocol.recovery import CheckpointParts, in_sent_order

MAGIC = b"IMULOG1\n"
FORMAT_VERSION = 1
KIND_HEADER, KIND_RECEIVED, KIND_EVENT = 1, 2, 3
_RECORD_HEAD = struct.Struct("<IBd")
_CRC = struct.Struct("<I")
#: Longest record body accepted on reading (the writer's are at most one read chunk or
#: an event): below 2**24, so the top byte of a valid length field is always 0.
MAX_BODY = (1 << 24) - 1
#: Largest recording read: its frames are decoded in memory, about 13 GB at this size
#: (some 2 h of ESKF at 1 kHz).
MAX_FILE_BYTES = 1 << 30
_KNOWN_KINDS = (KIND_HEADER, KIND_RECEIVED, KIND_EVENT)
#: Where a record of a known kind may start: its length's top byte (0), then its kind.
#: Looking for these (in C) instead of trying every offset keeps resynchronisation fast.
_RECORD_START = re.compile(b"\\x00[" + bytes(_KNOWN_KINDS) + b"]")
_FSYNC_INTERVAL_S = 1.0


class RecordingError(ImulinkError):
    """A file that is not a readable imulink recording (or lacks what is asked of it)."""


# ---------------------------------------------------------------------------- writing


class RecordingWriter:
    """Appends records to a new recording file; thread-safe (the link's reader thread
    writes RECEIVED records while the main thread writes events).

    `path` is created and must not exist: an existing file is never truncated. `fd`
    instead: the file already created at `path` (:func:`imulink.io.files.create_beside`).

    A write that fails (a full disk, the file-size limit) ends all writing: `failure`
    says why and :meth:`check` raises it. The file keeps every record written before
    it, and at worst part of one, which readers ignore as a truncated tail. Writing
    never raises, so that a failure cannot kill the reader thread that writes.
    """

    def __init__(self, path, port: str, profile: SensorProfile | None, fd: int | None = None):
        self.path = Path(path)
        self.profile = profile
        self._lock = threading.Lock()
        if fd is None:
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o666)
            except OSError as exc:
                raise RecordingError(f"cannot create {self.path}: {exc.strerror}") from None
        self._fd = fd
        self._last_sync = time.monotonic()
        self.bytes_received = 0
        self.failure: str | None = None
        self._write_bytes(MAGIC)
        header = {"format": "imulink-recording", "format_version": FORMAT_VERSION, "imulink": __version__,
                  "protocol_version": protocol.PROTOCOL_VERSION, "schema_hash": protocol.SCHEMA_HASH,
                  "port": port, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                  "profile": profile_to_json(profile)}
        self._write(KIND_HEADER, time.time(), json.dumps(header).encode())

    def _write_bytes(self, data: bytes) -> None:
        """Write all of `data` (a write may be short, near a size limit) or note the failure."""
        if self._fd < 0 or self.failure is not None:
            return  # closed (late bytes from a reader thread shutting down), or failed before
        view = memoryview(data)
        try:
            while view:
                written = os.write(self._fd, view)
                if not written:  # never seen on a regular file; looping on it would hang
                    raise OSError(errno.EIO, "the file takes no more bytes")
                view = view[written:]
            if time.monotonic() - self._last_sync > _FSYNC_INTERVAL_S:
                os.fsync(self._fd)
                self._last_sync = time.monotonic()
        except OSError as exc:
            self.failure = f"cannot write {self.path}: {exc.strerror}"

    def _write(self, kind: int, host_time: float, body: bytes) -> None:
        head = _RECORD_HEAD.pack(len(body), kind, host_time)
        with self._lock:
            self._write_bytes(head + body + _CRC.pack(zlib.crc32(body, zlib.crc32(head))))

    def check(self) -> None:
        """Raise RecordingError if a write failed."""
        if self.failure is not None:
            raise RecordingError(self.failure)

    def received(self, chunk: bytes, host_time: float) -> None:
        """Append a chunk of received bytes (the Link's `tap`)."""
        self.bytes_received += len(chunk)
        self._write(KIND_RECEIVED, host_time, bytes(chunk))

    def event(self, name: str, **details) -> None:
        """Append an event (JSON-serialisable details)."""
        self._write(KIND_EVENT, time.time(), json.dumps({"event": name, **details}).encode())

    def close(self) -> None:
        with self._lock:
            if self._fd >= 0:
                try:
                    os.fsync(self._fd)
                except OSError as exc:
                    self.failure = self.failure or f"cannot write {self.path}: {exc.strerror}"
                os.close(self._fd)
                self._fd = -1

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


# ---------------------------------------------------------------------------- reading records


@dataclass
class LogRecord:
    offset: int  # of its first byte in the file
    kind: int
    time: float
    body: bytes


@dataclass
class RecordFile:
    """What :func:`read_records` found: the valid records, the damaged spans skipped
    between them (byte offset, length), and the length of a truncated tail."""

    records: list[LogRecord]
    damaged: list[tuple[int, int]]
    truncated_bytes: int


def read_records(path) -> RecordFile:
    """The records of a file, the damaged spans between them and the truncated tail.

    A record that is not whole and CRC-valid where one should start is damage: the
    reader looks for the next valid record of a known kind after it and goes on from
    there. Only when none follows are the remaining bytes a truncated tail (what a
    crash leaves: a partial last record, zero fill). Raises RecordingError when the
    file cannot be read or is not a recording.
    """
    path = Path(path)
    try:
        data = read_regular_file(path, MAX_FILE_BYTES)
    except FileError as exc:
        raise RecordingError(str(exc)) from None
    if not data.startswith(MAGIC):
        raise RecordingError(f"{path} is not an imulink recording (it does not start with {MAGIC!r})")
    records: list[LogRecord] = []
    damaged: list[tuple[int, int]] = []
    offset, end = len(MAGIC), len(data)
    while offset < end:
        record = _record_at(data, offset)
        if record is None:
            following = _next_record(data, offset + 1)
            if following is None:
                return RecordFile(records, damaged, end - offset)
            damaged.append((offset, following - offset))
            offset = following
            continue
        records.append(record)
        offset += _RECORD_HEAD.size + len(record.body) + _CRC.size
    return RecordFile(records, damaged, 0)


def _record_at(data: bytes, offset: int) -> LogRecord | None:
    """The record starting at `offset` if it is whole and its CRC matches, else None."""
    if len(data) - offset < _RECORD_HEAD.size + _CRC.size:
        return None
    length, kind, host_time = _RECORD_HEAD.unpack_from(data, offset)
    stop = offset + _RECORD_HEAD.size + length
    if length > MAX_BODY or stop + _CRC.size > len(data):
        return None
    if zlib.crc32(memoryview(data)[offset:stop]) != _CRC.unpack_from(data, stop)[0]:
        return None
    return LogRecord(offset, kind, host_time, data[offset + _RECORD_HEAD.size:stop])


def _next_record(data: bytes, start: int) -> int | None:
    """The offset of the first valid record of a known kind at or after `start`."""
    position = start + 3  # the length's top byte, where _RECORD_START matches
    while (match := _RECORD_START.search(data, position)) is not None:
        if _record_at(data, match.start() - 3) is not None:
            return match.start() - 3
        position = match.start() + 1
    return None


# ---------------------------------------------------------------------------- decoded recordings


@dataclass
class Samples:
    """SAMPLE frames in arrival order: (N,) arrays and (N,3) int16 counts."""

    host_time: np.ndarray
    segment: np.ndarray
    index: np.ndarray
    timestamp_us: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    temperature: np.ndarray
    recovered: np.ndarray  # bool: lost on the way and sent again by the board (RESENT)

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class Estimates:
    """ESTIMATE frames in arrival order: the board's raw integers (Q30 quat, Q24 gyro
    bias, Q29 euler, covariance mantissa/exponent pairs, saturation counts).
    leftover: received before the recording's snapshot, from a stream that was already
    running when the recording began (e.g. left by a recorder that was killed)."""

    host_time: np.ndarray
    segment: np.ndarray
    leftover: np.ndarray
    index: np.ndarray
    filter_id: np.ndarray
    quat: np.ndarray
    gyro_bias: np.ndarray
    euler: np.ndarray
    cov_mantissa: np.ndarray
    cov_exponent: np.ndarray
    saturations: np.ndarray
    weights: np.ndarray  # ESKF gravity and heading measurement weights, Q30 (n, 2)

    #: the fields compared bit for bit, in the order a difference is reported
    COMPARED = ("filter_id", "quat", "gyro_bias", "euler", "cov_mantissa", "cov_exponent", "saturations", "weights")

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class Baro:
    """BARO frames in arrival order: the barometer's raw conversions (24-bit D1, D2) and
    the board's compensation of them (Pa, 0.01 degC), each with the index of the SAMPLE
    read with it."""

    host_time: np.ndarray
    segment: np.ndarray
    index: np.ndarray
    timestamp_us: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    pressure_pa: np.ndarray
    temperature_cdeg: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class Gnss:
    """GNSS frames in arrival order: the receiver's fixes in its own units (1e-7 deg, mm,
    mm/s, NED velocity), each with the index of the SAMPLE it arrived with and the time
    it is valid for (time_ms)."""

    host_time: np.ndarray
    segment: np.ndarray
    index: np.ndarray
    timestamp_us: np.ndarray
    time_ms: np.ndarray
    fix_type: np.ndarray
    fix_ok: np.ndarray
    num_sv: np.ndarray
    has_velocity: np.ndarray
    lat_1e7deg: np.ndarray
    lon_1e7deg: np.ndarray
    height_mm: np.ndarray
    h_acc_mm: np.ndarray
    v_acc_mm: np.ndarray
    vel_ned_mm_s: np.ndarray  # (n, 3)
    s_acc_mm_s: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class MessageTable:
    """Frames of one message in arrival order: the board's raw integers, one row per frame;
    `fields` maps each of the message's field names to its array ((n,) or (n, length))."""

    host_time: np.ndarray
    segment: np.ndarray
    fields: dict

    @property
    def index(self) -> np.ndarray:
        return self.fields["index"]

    def rows(self) -> list[dict]:
        """One dict of fields per frame (integers)."""
        return [{name: values[k].tolist() for name, values in self.fields.items()} for k in range(len(self))]

    def __len__(self) -> int:
        return len(self.host_time)


@dataclass(frozen=True)
class Checkpoint:
    """A board's filter state after sample `index` of `segment` (its CHECKPOINT frames put
    together; host_time: when the last of them arrived): the bytes core.Filter.restore takes."""

    segment: int
    index: int
    filter_id: int
    state: bytes
    host_time: float


def _checkpoints(rows) -> list[Checkpoint]:
    """The checkpoints whose every part arrived, in order (one per segment and index)."""
    parts = CheckpointParts()
    found: dict[tuple[int, int], Checkpoint] = {}
    for host_time, segment, fields, _ in rows:
        state, index = parts.add(fields, key=(segment,)), fields["index"]
        if state is not None and (segment, index) not in found:
            found[segment, index] = Checkpoint(segment, index, fields["filter_id"], state, host_time)
    return [found[key] for key in sorted(found)]


class NavStates(MessageTable):
    """NAV_STATE frames: the nav filter's state after each sample."""


class Markers(MessageTable):
    """MARKER frames: the position fixes (POSITION_FIX) the board gave its nav filter, each
    after the sample `index` (1e-7 deg, mm; used: whether it took it)."""


@dataclass
class Recording:
    """A decoded recording.

    hello / status: the first HELLO and STATUS (the snapshot taken before streaming).
    settings: filter_id -> setting index -> SETTING fields (the last value received).
    counters: the frame decoder's counters over the whole recorded byte stream.
    damaged: (byte offset, length) of each damaged span of the file that was skipped.
    truncated_bytes: bytes of a damaged tail that were ignored.
    segments: number of filter runs (see the module docstring).
    recovered: message name -> frames of it that were lost on the way and recovered (RESENT).
    checkpoints: the board's filter states (CHECKPOINT) whose every part arrived.
    """

    path: Path
    header: dict
    profile: SensorProfile
    events: list[dict]
    hello: dict | None
    status: dict | None
    settings: dict[int, dict[int, dict]]
    samples: Samples
    estimates: Estimates
    logs: list[tuple[float, int, str]]
    counters: dict
    damaged: list[tuple[int, int]]
    truncated_bytes: int
    segments: int
    #: the last CALIBRATION frame of each (sensor code, axis) the board reported
    calibration_reports: dict[tuple[int, int], dict] = field(default_factory=dict)
    #: per segment, what the board had reported when its first frame arrived: the SETTING
    #: fields (filter id -> index -> fields) and the CALIBRATION frames ((sensor, axis) -> fields)
    segment_settings: dict[int, dict[int, dict[int, dict]]] = field(default_factory=dict)
    segment_calibration: dict[int, dict[tuple[int, int], dict]] = field(default_factory=dict)
    baro: Baro = field(default_factory=lambda: _baro_table([]))
    gnss: Gnss = field(default_factory=lambda: _gnss_table([]))
    nav_states: NavStates = field(default_factory=lambda: _message_table(NavStates, "NAV_STATE", []))
    markers: Markers = field(default_factory=lambda: _message_table(Markers, "MARKER", []))
    recovered: dict[str, int] = field(default_factory=dict)
    checkpoints: list[Checkpoint] = field(default_factory=list)

    def calibration(self, segment: int | None = None):
        """The board's calibration (imulink.analysis.calibration.Calibration, in this recording's
        profile) as its CALIBRATION frames report it (the recorder reads it before
        streaming, and again after the board came back); None when the recording holds none
        (the board's identity calibration then, as after start-up). RecordingError when
        only part of it was recorded.

        segment: the one in effect for that segment (the last frames before it began; an
        axis not reported before it, the last one after); None: the last reported."""
        if not self.calibration_reports:
            return None
        # those reported before the segment began win; an axis not reported by then: its last report
        before = self.segment_calibration.get(segment, {}) if segment is not None else {}
        frames = {**self.calibration_reports, **before}
        try:
            sensors = calibration_from_frames(list(frames.values()))
        except CalibrationError as exc:
            raise RecordingError(f"{self.path}: {exc}") from None
        if set(sensors) != set(SENSORS):
            why = (f"the file is damaged, and its {len(self.damaged)} skipped span(s) may have held them"
                   if self.damaged else "some CALIBRATION frames are missing")
            raise RecordingError(f"{self.path}: the board's calibration was recorded for "
                                 f"{', '.join(sorted(sensors)) or 'no sensor'} only; {why}")
        return Calibration(self.profile, sensors)

    def filter_settings(self, filter_id: int, segment: int | None = None) -> tuple[str, dict[str, int]]:
        """(filter name, raw settings by name) of a filter, as the board reported them: for
        `segment`, as they stood when it began (a setting not reported by then: its last
        value); None: the last values reported."""
        if filter_id not in core.FILTER_NAMES:
            raise RecordingError(f"{self.path}: unknown filter id {filter_id}")
        name = core.FILTER_NAMES[filter_id]
        at_segment = self.segment_settings.get(segment, {}) if segment is not None else {}
        reported = {**self.settings.get(filter_id, {}), **at_segment.get(filter_id, {})}
        fields = core.settings_fields(name)
        missing = [f.name for i, f in enumerate(fields) if i not in reported]
        if missing:
            why = (f"the file is damaged, and its {len(self.damaged)} skipped span(s) may have held them"
                   if self.damaged else "record with `imulink record`, which reads them first")
            raise RecordingError(f"{self.path}: the settings of {name} were not recorded (missing: "
                                 f"{', '.join(missing)}); {why}")
        for i, f in enumerate(fields):
            if reported[i]["name"] != f.name or reported[i]["frac_bits"] != f.frac_bits:
                raise RecordingError(f"{self.path}: the board's setting {i} of {name} is {reported[i]['name']} "
                                     f"Q{reported[i]['frac_bits']}, this host's is {f.name} Q{f.frac_bits}")
        return name, {f.name: reported[i]["value"] for i, f in enumerate(fields)}

    @property
    def active_filter(self) -> int | None:
        """Filter id the board ran (from the estimates, else from the snapshot STATUS)."""
        if len(self.estimates):
            return int(self.estimates.filter_id[0])
        return self.status["active_filter"] if self.status else None


def sample_times(recording: Recording) -> np.ndarray:
    """Each sample's time (s from the first) at the board's sample rate (its STATUS; 100 Hz
    when the recording has none), by sample index: a recording taken as fast as the link
    goes keeps the pace the board sampled at, and a lost sample leaves its gap. Where a
    filter run restarts (index 0 again), one period passes."""
    samples, status = recording.samples, recording.status
    rate_hz = status["sample_rate_mhz"] / 1000.0 if status and status["sample_rate_mhz"] else 100.0
    steps = np.diff(samples.index)
    same_run = (np.diff(samples.segment) == 0) & (steps > 0)
    return np.concatenate(([0.0], np.cumsum(np.where(same_run, steps, 1)) / rate_hz))


def load_recording(path, progress: CountProgress | None = None) -> Recording:
    """Read and decode a recording file (see the module docstring).

    progress: called with (bytes decoded, bytes in all) before each record: frames are
    decoded in Python, some 30 000 samples a second, so a long recording takes minutes.
    """
    path = Path(path)
    found = read_records(path)
    records = found.records
    total = records[-1].offset + len(records[-1].body) if records else 0
    header, declared_profile = _header(path, records)
    events = [(record.offset, {"time": record.time, **_json_object(path, record, "event")})
              for record in records if record.kind == KIND_EVENT]
    snapshot_at = next((offset for offset, event in events if event.get("event") == "snapshot"), -1)
    decoder, follower = protocol.FrameDecoder(), StreamFollower()
    logs, segment_settings, segment_calibration = [], {}, {}
    tables: dict[str, list] = {name: [] for name in RUN_FRAMES}
    received: list[tuple[protocol.Message, LogRecord]] = []  # in arrival order
    for record in records[1:]:
        if progress is not None:
            progress(record.offset, total)
        if record.kind == KIND_RECEIVED:
            received.extend((message, record) for message in decoder.feed(record.body))
    recovered: dict[str, int] = {}
    for message, record, was_recovered in in_sent_order(received):
        name, fields = message.name, message.fields
        if was_recovered:
            recovered[name] = recovered.get(name, 0) + 1
        segment = follower.follow(message)
        if segment is not None:
            if segment not in segment_settings:  # its first frame: what the board had reported by then
                segment_settings[segment] = {fid: dict(by_index) for fid, by_index in follower.settings.items()}
                segment_calibration[segment] = dict(follower.calibration)
            if name == "ESTIMATE":
                tables[name].append((record.time, segment, record.offset < snapshot_at, fields))
            else:
                tables[name].append((record.time, segment, fields, was_recovered))
        elif name == "LOG":
            logs.append((record.time, fields["level"], fields["text"]))
    if progress is not None:
        progress(total, total)
    profile = _profile(path, follower.hello, declared_profile)
    sample_table, estimate_table = _sample_table(tables["SAMPLE"]), _estimate_table(tables["ESTIMATE"])
    segments = len(set(sample_table.segment.tolist()) | set(estimate_table.segment.tolist()))
    return Recording(path, header, profile, [event for _, event in events], follower.hello, follower.status,
                     follower.settings, sample_table, estimate_table, logs, decoder.counters(), found.damaged,
                     found.truncated_bytes, segments, follower.calibration, segment_settings, segment_calibration,
                     _baro_table(tables["BARO"]), _gnss_table(tables["GNSS"]),
                     _message_table(NavStates, "NAV_STATE", tables["NAV_STATE"]),
                     _message_table(Markers, "MARKER", tables["MARKER"]), recovered,
                     _checkpoints(tables["CHECKPOINT"]))


def _json_object(path: Path, record: LogRecord, what: str) -> dict:
    """The JSON object in a header or event record (whose CRC may be right and its text not)."""
    try:
        value = json.loads(record.body)
    except (ValueError, RecursionError):  # not UTF-8, not JSON, or nested too deep
        value = None
    if not isinstance(value, dict):
        raise RecordingError(f"{path}: the {what} record at byte {record.offset} is not a JSON object")
    return value


def _profile(path: Path, hello: dict | None, declared: SensorProfile | None) -> SensorProfile:
    """The sensor profile of the counts: the one the board states in its HELLO, else (a
    recording without one) the one the header declares."""
    if hello is not None:
        try:
            return profile_from_scales(hello["gyro_scale"], hello["acc_scale"], hello["mag_scale"])
        except ValueError as exc:
            raise RecordingError(f"{path}: the board's HELLO states no usable sensor sensitivities: {exc}") from None
    if declared is None:
        raise RecordingError(f"{path}: no HELLO and no profile in the header: the counts' sensor profile is unknown")
    return declared


def _header(path: Path, records: list[LogRecord]) -> tuple[dict, SensorProfile | None]:
    """The header and the sensor profile it declares (None: none, the board's HELLO says);
    RecordingError unless this imulink can decode the file: its frames are decoded with this
    host's protocol schema, so the file's must be the same."""
    if not records or records[0].kind != KIND_HEADER or records[0].offset != len(MAGIC):
        raise RecordingError(f"{path} has no header record (the record at byte {len(MAGIC)} is missing or damaged)")
    header = _json_object(path, records[0], "header")
    if header.get("format_version") != FORMAT_VERSION:
        raise RecordingError(f"{path}: recording format {header.get('format_version')!r} is not supported "
                             f"(this imulink reads format {FORMAT_VERSION})")
    version, schema = header.get("protocol_version"), header.get("schema_hash")
    if version != protocol.PROTOCOL_VERSION or schema not in protocol.READABLE_SCHEMA_HASHES:
        schema_text = f"0x{schema:08X}" if isinstance(schema, int) else repr(schema)
        raise RecordingError(f"{path} was recorded with protocol v{version!r}, schema hash {schema_text}; this "
                             f"imulink decodes v{protocol.PROTOCOL_VERSION}, 0x{protocol.SCHEMA_HASH:08X}: read it "
                             f"with the imulink that recorded it (version {header.get('imulink', 'unknown')})")
    if header.get("profile", 0) is None:
        return header, None
    try:
        profile = profile_from_json(header["profile"])
    except (KeyError, TypeError, ValueError) as exc:
        raise RecordingError(f"{path}: header without a valid sensor profile ({exc})") from None
    return header, profile


def _sample_table(rows) -> Samples:
    f = [r[2] for r in rows]
    return Samples(
        host_time=np.array([r[0] for r in rows], np.float64),
        segment=np.array([r[1] for r in rows], np.int32),
        index=np.array([x["index"] for x in f], np.int64),
        timestamp_us=np.array([x["timestamp_us"] for x in f], np.int64),
        gyr=np.array([x["gyr"] for x in f], np.int16).reshape(-1, 3),
        acc=np.array([x["acc"] for x in f], np.int16).reshape(-1, 3),
        mag=np.array([x["mag"] for x in f], np.int16).reshape(-1, 3),
        temperature=np.array([x["temperature"] for x in f], np.int16),
        recovered=np.array([r[3] for r in rows], bool),
    )


def _baro_table(rows) -> Baro:
    f = [r[2] for r in rows]
    return Baro(
        host_time=np.array([r[0] for r in rows], np.float64),
        segment=np.array([r[1] for r in rows], np.int32),
        **{name: np.array([x[name] for x in f], np.int64)
           for name in ("index", "timestamp_us", "d1", "d2", "pressure_pa", "temperature_cdeg")},
    )


def _gnss_table(rows) -> Gnss:
    f = [r[2] for r in rows]
    return Gnss(
        host_time=np.array([r[0] for r in rows], np.float64),
        segment=np.array([r[1] for r in rows], np.int32),
        vel_ned_mm_s=np.array([x["vel_ned_mm_s"] for x in f], np.int64).reshape(-1, 3),
        **{name: np.array([x[name] for x in f], np.int64)
           for name in ("index", "timestamp_us", "time_ms", "fix_type", "fix_ok", "num_sv", "has_velocity",
                        "lat_1e7deg", "lon_1e7deg", "height_mm", "h_acc_mm", "v_acc_mm", "s_acc_mm_s")},
    )


def _message_table(kind, message: str, rows):
    """A NavStates or Markers table of (host time, segment, fields) rows of `message`."""
    f = [r[2] for r in rows]
    columns = {}
    for name, _, length in protocol.message_fields(message):
        values = np.array([x[name] for x in f], np.int64)
        columns[name] = values.reshape(-1, length) if length else values
    return kind(np.array([r[0] for r in rows], np.float64), np.array([r[1] for r in rows], np.int32), columns)


def _estimate_table(rows) -> Estimates:
    f = [r[3] for r in rows]
    return Estimates(
        host_time=np.array([r[0] for r in rows], np.float64),
        segment=np.array([r[1] for r in rows], np.int32),
        leftover=np.array([r[2] for r in rows], bool),
        index=np.array([x["index"] for x in f], np.int64),
        filter_id=np.array([x["filter_id"] for x in f], np.int64),
        quat=np.array([x["quat"] for x in f], np.int64).reshape(-1, 4),
        gyro_bias=np.array([x["gyro_bias"] for x in f], np.int64).reshape(-1, 3),
        euler=np.array([x["euler"] for x in f], np.int64).reshape(-1, 3),
        cov_mantissa=np.array([x["cov_mantissa"] for x in f], np.int64).reshape(-1, 9),
        cov_exponent=np.array([x["cov_exponent"] for x in f], np.int64).reshape(-1, 9),
        saturations=np.array([x["saturations"] for x in f], np.int64),
        weights=np.array([x["weights"] for x in f], np.int64).reshape(-1, 2),
    )


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
