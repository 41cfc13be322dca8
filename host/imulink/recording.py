"""Recording files: the raw received byte stream with host receive times, append-only.

File layout (all little-endian)::

    magic    8 bytes  b"IMULOG1\\n"
    record*  u32 body_length | u8 kind | f64 host_time (s, Unix) | body | u32 crc32(all before it)

Kinds: HEADER (the first record; JSON: format version, host version, schema hash, port,
sensor profile), RECEIVED (a chunk of bytes exactly as read from the port, frames
and damage alike), EVENT (JSON: connected, snapshot, stream started, stopped with the
reason and the link counters, ...). Records of unknown kinds are skipped.

Every record is one write() to a file opened for appending, and the file is fsync'ed
about once a second: a crash or a pulled cable leaves at worst a partial last record.
:func:`read_records` detects such a truncated tail (a record running past the end of
the file, a bad CRC on the very last record, zero fill) and ignores it, keeping
everything before; damage anywhere else is :class:`RecordingCorrupt`.

:func:`load_recording` decodes the frames of a file into numpy tables of samples and
estimates, split into *segments*: runs of the filter from sample index 0 (a filter
restart -- SELECT_FILTER, SET_SETTING, SET_INJECTION_MODE, RESET, a start-up HELLO --
begins a new segment).
"""
from __future__ import annotations

import json
import os
import struct
import threading
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import __version__, core, protocol
from .counts import SensorProfile

MAGIC = b"IMULOG1\n"
FORMAT_VERSION = 1
KIND_HEADER, KIND_RECEIVED, KIND_EVENT = 1, 2, 3
_RECORD_HEAD = struct.Struct("<IBd")
_CRC = struct.Struct("<I")
#: Longest record body accepted on reading (the writer's are at most one read chunk).
MAX_BODY = 1 << 24
_FSYNC_INTERVAL_S = 1.0
_RESTARTING_IDS = {protocol.COMMAND_IDS[name] for name in protocol.RESTARTING_COMMANDS}


class RecordingError(Exception):
    """A file that is not a readable imulink recording (or lacks what is asked of it)."""


class RecordingCorrupt(RecordingError):
    """A recording damaged somewhere other than its tail."""


# ---------------------------------------------------------------------------- writing


def profile_to_json(profile: SensorProfile) -> dict:
    return {"name": profile.name, "gyro_lsb_per_dps": profile.gyro_lsb_per_dps,
            "acc_lsb_per_g": profile.acc_lsb_per_g, "mag_lsb_per_gauss": profile.mag_lsb_per_gauss}


def profile_from_json(data: dict) -> SensorProfile:
    return SensorProfile(name=data["name"], gyro_lsb_per_dps=data["gyro_lsb_per_dps"],
                         acc_lsb_per_g=data["acc_lsb_per_g"], mag_lsb_per_gauss=data["mag_lsb_per_gauss"])


class RecordingWriter:
    """Appends records to a new recording file; thread-safe (the link's reader thread
    writes RECEIVED records while the main thread writes events)."""

    def __init__(self, path, port: str, profile: SensorProfile):
        self.path = Path(path)
        self._lock = threading.Lock()
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
        except OSError as exc:
            raise RecordingError(f"cannot create {self.path}: {exc.strerror}") from None
        self._last_sync = time.monotonic()
        self.bytes_received = 0
        os.write(self._fd, MAGIC)
        header = {"format": "imulink-recording", "format_version": FORMAT_VERSION, "imulink": __version__,
                  "protocol_version": protocol.PROTOCOL_VERSION, "schema_hash": protocol.SCHEMA_HASH,
                  "port": port, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                  "profile": profile_to_json(profile)}
        self._write(KIND_HEADER, time.time(), json.dumps(header).encode())

    def _write(self, kind: int, host_time: float, body: bytes) -> None:
        head = _RECORD_HEAD.pack(len(body), kind, host_time)
        record = head + body + _CRC.pack(zlib.crc32(body, zlib.crc32(head)))
        with self._lock:
            if self._fd < 0:
                return  # closed: late bytes from a reader thread that is shutting down
            os.write(self._fd, record)
            if time.monotonic() - self._last_sync > _FSYNC_INTERVAL_S:
                os.fsync(self._fd)
                self._last_sync = time.monotonic()

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
                os.fsync(self._fd)
                os.close(self._fd)
                self._fd = -1

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


# ---------------------------------------------------------------------------- reading records


@dataclass
class LogRecord:
    kind: int
    time: float
    body: bytes


def read_records(path) -> tuple[list[LogRecord], int]:
    """The records of a file and the number of bytes of a truncated tail that was ignored.

    Raises RecordingError when the file is missing or not a recording, RecordingCorrupt
    when a record before the tail is damaged.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror}") from None
    if not data.startswith(MAGIC):
        raise RecordingError(f"{path} is not an imulink recording (it does not start with {MAGIC!r})")
    records, offset, end = [], len(MAGIC), len(data)
    while offset < end:
        remaining = end - offset
        if remaining < _RECORD_HEAD.size + _CRC.size:
            return records, remaining  # a partial record header
        length, kind, host_time = _RECORD_HEAD.unpack_from(data, offset)
        stop = offset + _RECORD_HEAD.size + length
        if length <= MAX_BODY and stop + _CRC.size > end:
            return records, remaining  # the last record was cut short
        if length > MAX_BODY or zlib.crc32(memoryview(data)[offset:stop]) != _CRC.unpack_from(data, stop)[0]:
            if stop + _CRC.size == end or data.count(0, offset) == remaining:
                return records, remaining  # a last record written in part, or the zero fill a crash may leave
            problem = f"impossible record length {length}" if length > MAX_BODY else "CRC mismatch"
            raise RecordingCorrupt(f"{path} is corrupt at byte {offset} (record {len(records)}): {problem}, "
                                   f"{remaining} bytes from there")
        records.append(LogRecord(kind, host_time, data[offset + _RECORD_HEAD.size:stop]))
        offset = stop + _CRC.size
    return records, 0


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

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class Estimates:
    """ESTIMATE frames in arrival order: the board's raw integers (Q30 quat, Q24 gyro
    bias, Q29 euler, covariance mantissa/exponent pairs, saturation counts)."""

    host_time: np.ndarray
    segment: np.ndarray
    index: np.ndarray
    filter_id: np.ndarray
    quat: np.ndarray
    gyro_bias: np.ndarray
    euler: np.ndarray
    cov_mantissa: np.ndarray
    cov_exponent: np.ndarray
    saturations: np.ndarray

    #: the fields compared bit for bit, in the order a difference is reported
    COMPARED = ("filter_id", "quat", "gyro_bias", "euler", "cov_mantissa", "cov_exponent", "saturations")

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class Recording:
    """A decoded recording.

    hello / status: the first HELLO and STATUS (the snapshot taken before streaming).
    settings: filter_id -> setting index -> SETTING fields (the last value received).
    counters: the frame decoder's counters over the whole recorded byte stream.
    truncated_bytes: bytes of a damaged tail that were ignored.
    segments: number of filter runs (see the module docstring).
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
    truncated_bytes: int
    segments: int

    def filter_settings(self, filter_id: int) -> tuple[str, dict[str, int]]:
        """(filter name, raw settings by name) of a filter, as the board reported them."""
        names = {fid: name for name, (fid, _) in core.FILTERS.items()}
        if filter_id not in names:
            raise RecordingError(f"{self.path}: unknown filter id {filter_id}")
        name = names[filter_id]
        reported = self.settings.get(filter_id, {})
        fields = core.settings_fields(name)
        missing = [f.name for i, f in enumerate(fields) if i not in reported]
        if missing:
            raise RecordingError(f"{self.path}: the settings of {name} were not recorded (missing: "
                                 f"{', '.join(missing)}); record with `imulink record`, which reads them first")
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


class _Segmenter:
    """Assigns stream frames to filter runs: a new segment after a restart, or when the
    sample index goes backwards."""

    def __init__(self):
        self.segment = 0
        self._last_index = None

    def restart(self) -> None:
        if self._last_index is not None:
            self.segment += 1
            self._last_index = None

    def place(self, index: int) -> int:
        if self._last_index is not None and index < self._last_index:
            self.segment += 1
        self._last_index = index
        return self.segment


def load_recording(path) -> Recording:
    """Read and decode a recording file (see the module docstring)."""
    path = Path(path)
    records, truncated = read_records(path)
    if not records or records[0].kind != KIND_HEADER:
        raise RecordingError(f"{path} has no header record")
    header = json.loads(records[0].body)
    if header.get("format_version") != FORMAT_VERSION:
        raise RecordingError(f"{path}: recording format {header.get('format_version')!r} is not supported "
                             f"(this imulink reads format {FORMAT_VERSION})")
    decoder, segmenter = protocol.FrameDecoder(), _Segmenter()
    events, logs, settings = [], [], {}
    hello = status = None
    samples, estimates = [], []
    for record in records[1:]:
        if record.kind == KIND_EVENT:
            events.append({"time": record.time, **json.loads(record.body)})
            continue
        if record.kind != KIND_RECEIVED:
            continue
        for message in decoder.feed(record.body):
            name, fields = message.name, message.fields
            if name == "SAMPLE":
                samples.append((record.time, segmenter.place(fields["index"]), fields))
            elif name == "ESTIMATE":
                estimates.append((record.time, segmenter.place(fields["index"]), fields))
            elif name == "ACK" and fields["command"] in _RESTARTING_IDS:
                segmenter.restart()
            elif name == "HELLO":
                hello = hello or fields
                if message.seq == 0:  # the board started up or reset
                    segmenter.restart()
            elif name == "STATUS":
                status = status or fields
            elif name == "SETTING":
                settings.setdefault(fields["filter_id"], {})[fields["index"]] = fields
            elif name == "LOG":
                logs.append((record.time, fields["level"], fields["text"]))
    try:
        profile = profile_from_json(header["profile"])
    except (KeyError, TypeError) as exc:
        raise RecordingError(f"{path}: header without a valid sensor profile ({exc})") from None
    sample_table, estimate_table = _sample_table(samples), _estimate_table(estimates)
    segments = len(set(sample_table.segment.tolist()) | set(estimate_table.segment.tolist()))
    return Recording(path, header, profile, events, hello, status, settings, sample_table, estimate_table, logs,
                     decoder.counters(), truncated, segments)


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
    )


def _estimate_table(rows) -> Estimates:
    f = [r[2] for r in rows]
    return Estimates(
        host_time=np.array([r[0] for r in rows], np.float64),
        segment=np.array([r[1] for r in rows], np.int32),
        index=np.array([x["index"] for x in f], np.int64),
        filter_id=np.array([x["filter_id"] for x in f], np.int64),
        quat=np.array([x["quat"] for x in f], np.int64).reshape(-1, 4),
        gyro_bias=np.array([x["gyro_bias"] for x in f], np.int64).reshape(-1, 3),
        euler=np.array([x["euler"] for x in f], np.int64).reshape(-1, 3),
        cov_mantissa=np.array([x["cov_mantissa"] for x in f], np.int64).reshape(-1, 9),
        cov_exponent=np.array([x["cov_exponent"] for x in f], np.int64).reshape(-1, 9),
        saturations=np.array([x["saturations"] for x in f], np.int64),
    )
