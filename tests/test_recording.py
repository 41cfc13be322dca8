"""Recording files (imulink.io.recording): the record format, crash-safe reading, decoding.

The writer's records read back exactly; a tail cut anywhere (or zero-filled, as a crash
may leave it) is ignored and everything before it kept; damage anywhere else (a flipped
bit in any byte, a zero-filled span) costs only the damaged record, reported by offset,
and every record after it is kept; a file that is not a recording says so. The writer
never truncates a file, completes short writes and survives write errors with a
readable file. A header of another protocol schema, or malformed JSON behind a valid
CRC, is refused in one clear error. Frames decode into sample and estimate tables split
into filter runs (segments) at restarts.
"""
from __future__ import annotations

import errno
import json
import os
import re
import struct
import zlib

import numpy as np
import pytest

from imulink import core, protocol
from imulink.core.counts import BROAD_PROFILE, DEFAULT_PROFILE, fixed_scales
from imulink.hil.replica import FirmwareFilter
from imulink.io import recording as recording_module
from imulink.io.recording import (
    KIND_EVENT,
    KIND_HEADER,
    KIND_RECEIVED,
    MAGIC,
    RecordingError,
    RecordingWriter,
    load_recording,
    read_records,
)

SETTINGS = FirmwareFilter.default_raw_settings("eecf", 100.0)


def hello_scales(profile) -> dict:
    """The HELLO fields in which a board states its sensor profile."""
    return dict(zip(("gyro_scale", "acc_scale", "mag_scale"), fixed_scales(profile)))


def _setting_frames(seq: int = 0) -> bytes:
    """SETTING frames for every eecf setting, as a board answers GET_SETTING."""
    fields = core.settings_fields("eecf")
    return b"".join(protocol.encode("SETTING", seq + i, filter_id=1, index=i, setting_count=len(fields),
                                    value=SETTINGS[f.name], frac_bits=f.frac_bits, name=f.name, unit=f.unit,
                                    min=core.to_fixed(f.minimum, f.frac_bits),
                                    max=core.to_fixed(f.maximum, f.frac_bits))
                    for i, f in enumerate(fields))


def _stream_frames(indices, seq: int = 100) -> bytes:
    """SAMPLE + ESTIMATE pairs with the given sample indices (values do not matter here)."""
    out = b""
    for k, index in enumerate(indices):
        out += protocol.encode("SAMPLE", seq + 2 * k, timestamp_us=k * 10_000, index=index, gyr=(k, 0, 0),
                               acc=(0, 0, 4096), mag=(100, 0, -200), temperature=0)
        out += protocol.encode("ESTIMATE", seq + 2 * k + 1, index=index, filter_id=1, quat=(1 << 30, 0, 0, 0),
                               gyro_bias=(0, 0, 0), euler=(0, 0, 0), cov_mantissa=(0,) * 9, cov_exponent=(0,) * 9,
                               saturations=0, weights=(0, 0))
    return out


def _write(path, chunks, profile=DEFAULT_PROFILE):
    with RecordingWriter(path, "test://", profile) as writer:
        for chunk in chunks:
            writer.received(chunk, 1000.0)
        writer.event("stopped", reason="test")
    return path


def _record_spans(path) -> list[tuple[int, int]]:
    """(offset, size) of every record of an intact file."""
    return [(r.offset, 13 + len(r.body) + 4) for r in read_records(path).records]


def test_records_round_trip(tmp_path):
    path = tmp_path / "a.imulog"
    with RecordingWriter(path, "socket://127.0.0.1:1", BROAD_PROFILE) as writer:
        writer.received(b"\x01\x02\x00", 12.5)
        writer.event("snapshot", filter="eecf")
    found = read_records(path)
    assert found.truncated_bytes == 0 and found.damaged == []
    records = found.records
    assert [r.kind for r in records] == [KIND_HEADER, KIND_RECEIVED, KIND_EVENT]
    header = json.loads(records[0].body)
    assert header["port"] == "socket://127.0.0.1:1" and header["schema_hash"] == protocol.SCHEMA_HASH
    assert header["profile"]["name"] == "gy86-broad"
    assert records[1].body == b"\x01\x02\x00" and records[1].time == 12.5
    assert json.loads(records[2].body) == {"event": "snapshot", "filter": "eecf"}


def test_truncated_tail_is_ignored_wherever_the_cut_falls(tmp_path):
    chunks = [_setting_frames(), _stream_frames(range(5)), _stream_frames(range(5, 10), seq=200)]
    full = _write(tmp_path / "full.imulog", chunks).read_bytes()
    complete = read_records(tmp_path / "full.imulog").records
    cut_path = tmp_path / "cut.imulog"
    for cut in range(len(MAGIC), len(full)):
        cut_path.write_bytes(full[:cut])
        found = read_records(cut_path)
        kept = len(MAGIC) + sum(13 + len(r.body) + 4 for r in found.records)
        assert kept + found.truncated_bytes == cut  # every byte is either a whole record or the ignored tail
        assert found.damaged == []
        assert [r.body for r in found.records] == [r.body for r in complete[:len(found.records)]]


def test_zero_filled_tail_is_ignored(tmp_path):
    path = _write(tmp_path / "z.imulog", [_stream_frames(range(3))])
    good = path.read_bytes()
    path.write_bytes(good + bytes(4096))
    found = read_records(path)
    assert found.truncated_bytes == 4096 and found.damaged == []
    assert len(found.records) == 3


def test_a_flipped_bit_anywhere_costs_only_its_record(tmp_path):
    """Every bit of every record flipped in turn: the reader skips exactly the damaged
    record, reports it by offset (or as the tail when it is the last) and keeps every
    other record byte for byte."""
    path = _write(tmp_path / "f.imulog", [_setting_frames()[:120], _stream_frames(range(2)), b"\x00" * 7])
    original = path.read_bytes()
    records = read_records(path).records
    spans = _record_spans(path)
    damaged_path = tmp_path / "flipped.imulog"
    damaged_path.write_bytes(original)
    with open(damaged_path, "r+b", buffering=0) as damaged:  # one byte rewritten in place: quicker than a new file
        for position in range(len(MAGIC), len(original)):
            k = next(i for i, (start, size) in enumerate(spans) if start <= position < start + size)
            for bit in range(8):
                damaged.seek(position)
                damaged.write(bytes([original[position] ^ (1 << bit)]))
                found = read_records(damaged_path)
                assert [r.body for r in found.records] == [r.body for i, r in enumerate(records) if i != k]
                if k == len(spans) - 1:
                    assert found.damaged == [] and found.truncated_bytes == spans[k][1]
                else:
                    assert found.damaged == [spans[k]] and found.truncated_bytes == 0
            damaged.seek(position)
            damaged.write(original[position:position + 1])


def test_flipped_length_bit_mid_file_keeps_the_rest(tmp_path):
    """One flipped bit in a length field must not turn the rest of the file into a
    'truncated tail'."""
    chunks = [_setting_frames()] + [_stream_frames([k], seq=100 + 2 * k) for k in range(30)]
    path = _write(tmp_path / "l.imulog", chunks)
    spans = _record_spans(path)
    middle = spans[len(spans) // 2][0]
    for bit in (0, 13, 23, 30):  # small and large lengths alike
        data = bytearray(path.read_bytes())
        data[middle:middle + 4] = (int.from_bytes(data[middle:middle + 4], "little") ^ (1 << bit)).to_bytes(4, "little")
        damaged = tmp_path / f"bit{bit}.imulog"
        damaged.write_bytes(bytes(data))
        recording = load_recording(damaged)
        assert recording.damaged == [spans[len(spans) // 2]] and recording.truncated_bytes == 0
        assert len(recording.samples) == 29  # one of 30 lost, not two thirds


def test_zero_filled_span_mid_file_is_skipped_and_reported(tmp_path):
    path = _write(tmp_path / "zm.imulog", [_stream_frames([k], seq=100 + 2 * k) for k in range(20)])
    spans = _record_spans(path)
    data = bytearray(path.read_bytes())
    start, end = spans[5][0] + 3, spans[8][0] + 10  # from inside record 5 into record 8
    data[start:end] = bytes(end - start)
    path.write_bytes(bytes(data))
    recording = load_recording(path)
    assert recording.damaged == [(spans[5][0], spans[9][0] - spans[5][0])]
    assert len(recording.samples) == 20 - 4  # records 5..8 held one sample each


@pytest.mark.parametrize("content", [b"", b"hello world\n", b"IMULOG2\n" + bytes(40)])
def test_not_a_recording(tmp_path, content):
    path = tmp_path / "x.imulog"
    path.write_bytes(content)
    with pytest.raises(RecordingError, match="not an imulink recording"):
        read_records(path)


def test_missing_file(tmp_path):
    with pytest.raises(RecordingError, match="cannot read"):
        load_recording(tmp_path / "missing.imulog")


def test_unknown_record_kinds_are_skipped(tmp_path):
    path = _write(tmp_path / "u.imulog", [_setting_frames(), _stream_frames(range(4))])
    head = struct.pack("<IBd", 3, 99, 0.0)  # a record of a kind a later version may add
    with open(path, "ab") as f:
        f.write(head + b"new" + struct.pack("<I", zlib.crc32(b"new", zlib.crc32(head))))
    recording = load_recording(path)
    assert len(recording.samples) == 4 and recording.truncated_bytes == 0 and recording.damaged == []


def test_load_recording_tables_and_snapshot(tmp_path):
    hello = protocol.encode("HELLO", 5, firmware_major=1, firmware_minor=2, firmware_patch=3,
                            protocol_version=protocol.PROTOCOL_VERSION, schema_hash=protocol.SCHEMA_HASH,
                            board="test", filters=2, **hello_scales(BROAD_PROFILE))
    path = _write(tmp_path / "t.imulog", [hello, _setting_frames(6), _stream_frames(range(8))], BROAD_PROFILE)
    recording = load_recording(path)
    assert recording.hello["board"] == "test"
    assert recording.profile == BROAD_PROFILE
    assert len(recording.samples) == 8 and len(recording.estimates) == 8
    assert recording.samples.gyr.dtype == np.int16 and recording.samples.gyr.shape == (8, 3)
    np.testing.assert_array_equal(recording.samples.gyr[:, 0], np.arange(8))
    np.testing.assert_array_equal(recording.estimates.quat[:, 0], 1 << 30)
    assert recording.filter_settings(1) == ("eecf", SETTINGS)
    assert recording.segments == 1
    assert recording.events[-1]["event"] == "stopped"


def test_the_profile_is_the_one_the_board_states(tmp_path):
    """The counts' profile is the HELLO's; the header's (what a user declared) only stands in
    for a missing HELLO, and without either the recording is refused."""
    hello = protocol.encode("HELLO", 0, firmware_major=1, firmware_minor=2, firmware_patch=3,
                            protocol_version=protocol.PROTOCOL_VERSION, schema_hash=protocol.SCHEMA_HASH,
                            board="test", filters=2, **hello_scales(BROAD_PROFILE))
    assert load_recording(_write(tmp_path / "a.imulog", [hello], None)).profile == BROAD_PROFILE
    assert load_recording(_write(tmp_path / "b.imulog", [hello], DEFAULT_PROFILE)).profile == BROAD_PROFILE
    assert load_recording(_write(tmp_path / "c.imulog", [_stream_frames(range(2))], BROAD_PROFILE)).profile == (
        BROAD_PROFILE)
    with pytest.raises(RecordingError, match="no HELLO and no profile in the header"):
        load_recording(_write(tmp_path / "d.imulog", [_stream_frames(range(2))], None))
    odd = protocol.encode("HELLO", 0, firmware_major=1, firmware_minor=2, firmware_patch=3,
                          protocol_version=protocol.PROTOCOL_VERSION, schema_hash=protocol.SCHEMA_HASH,
                          board="test", filters=2, gyro_scale=1 << 30, acc_scale=1 << 22, mag_scale=1 << 20)
    other = load_recording(_write(tmp_path / "e.imulog", [odd], None)).profile
    assert other.name == "board" and fixed_scales(other) == (1 << 30, 1 << 22, 1 << 20)
    zero = protocol.encode("HELLO", 0, firmware_major=1, firmware_minor=2, firmware_patch=3,
                           protocol_version=protocol.PROTOCOL_VERSION, schema_hash=protocol.SCHEMA_HASH,
                           board="test", filters=2, gyro_scale=0, acc_scale=1, mag_scale=1)
    with pytest.raises(RecordingError, match="states no usable sensor sensitivities"):
        load_recording(_write(tmp_path / "f.imulog", [zero], None))


def test_segments_start_at_restarts_and_index_drops(tmp_path):
    restart_ack = protocol.encode("ACK", 50, command_seq=7, command=protocol.COMMAND_IDS["SELECT_FILTER"], reason=0)
    other_ack = protocol.encode("ACK", 51, command_seq=8, command=protocol.COMMAND_IDS["GET_STATUS"], reason=0)
    reset_hello = protocol.encode("HELLO", 0, firmware_major=0, firmware_minor=1, firmware_patch=0,
                                  protocol_version=1, schema_hash=protocol.SCHEMA_HASH, board="x", filters=2,
                                  **hello_scales(DEFAULT_PROFILE))
    chunks = [_stream_frames(range(4)), restart_ack, _stream_frames(range(3), 300), other_ack,
              _stream_frames(range(3, 5), 400), _stream_frames(range(2), 500), reset_hello, _stream_frames([0], 600)]
    recording = load_recording(_write(tmp_path / "s.imulog", chunks))
    np.testing.assert_array_equal(recording.samples.segment, [0] * 4 + [1] * 5 + [2] * 2 + [3])
    np.testing.assert_array_equal(recording.samples.index, [0, 1, 2, 3, 0, 1, 2, 3, 4, 0, 1, 0])
    np.testing.assert_array_equal(recording.estimates.segment, recording.samples.segment)
    assert recording.segments == 4


def test_missing_settings_is_a_clear_error(tmp_path):
    recording = load_recording(_write(tmp_path / "n.imulog", [_stream_frames(range(2))]))
    with pytest.raises(RecordingError, match="settings of eecf were not recorded"):
        recording.filter_settings(1)


def test_writer_refuses_an_unwritable_path(tmp_path):
    with pytest.raises(RecordingError, match="cannot create"):
        RecordingWriter(tmp_path / "no" / "such" / "dir.imulog", "x", DEFAULT_PROFILE)


def test_writer_never_truncates_an_existing_file(tmp_path):
    path = tmp_path / "yesterday.imulog"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError, match="cannot create"):
        RecordingWriter(path, "x", DEFAULT_PROFILE)
    assert path.read_bytes() == b"precious"


def test_writer_completes_short_writes(tmp_path, monkeypatch):
    real_write = os.write
    monkeypatch.setattr(recording_module.os, "write", lambda fd, data: real_write(fd, bytes(data[:5])))
    path = _write(tmp_path / "short.imulog", [_stream_frames(range(3))])
    monkeypatch.undo()
    recording = load_recording(path)
    assert len(recording.samples) == 3 and recording.damaged == [] and recording.truncated_bytes == 0


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EFBIG])
def test_a_write_error_stops_writing_and_leaves_a_readable_file(tmp_path, monkeypatch, code):
    """A full disk or the file-size limit in the middle of a record: the tap (run by the
    link's reader thread) does not raise, check() does, and the file reads up to there."""
    path = tmp_path / "full.imulog"
    writer = RecordingWriter(path, "x", DEFAULT_PROFILE)
    writer.received(_setting_frames(), 1.0)
    writer.received(_stream_frames(range(2)), 2.0)
    real_write, budget = os.write, [60]

    def write_until_full(fd, data):
        if budget[0] <= 0:
            raise OSError(code, os.strerror(code))
        written = real_write(fd, bytes(data[:budget[0]]))
        budget[0] -= written
        return written

    monkeypatch.setattr(recording_module.os, "write", write_until_full)
    writer.received(_stream_frames(range(2, 4)), 3.0)  # 60 bytes of it reach the file
    writer.received(_stream_frames(range(4, 6)), 4.0)
    writer.event("stopped", reason="test")
    monkeypatch.undo()
    assert writer.failure == f"cannot write {path}: {os.strerror(code)}"
    with pytest.raises(RecordingError, match="cannot write"):
        writer.check()
    writer.close()
    recording = load_recording(path)
    assert len(recording.samples) == 2 and recording.truncated_bytes == 60 and recording.damaged == []


def _with_header(path, header: bytes) -> None:
    """Rewrite a recording's header record body (with a valid CRC)."""
    found = read_records(path)
    head = struct.pack("<IBd", len(header), KIND_HEADER, 0.0)
    rest = path.read_bytes()[found.records[1].offset:]
    path.write_bytes(MAGIC + head + header + struct.pack("<I", zlib.crc32(header, zlib.crc32(head))) + rest)


def _header_json(**changes) -> bytes:
    header = {"format": "imulink-recording", "format_version": 1, "imulink": "0.1.0",
              "protocol_version": protocol.PROTOCOL_VERSION, "schema_hash": protocol.SCHEMA_HASH,
              "port": "x", "profile": {"name": "gy86-default", "gyro_lsb_per_dps": 16.4, "acc_lsb_per_g": 4096.0,
                                       "mag_lsb_per_gauss": 1090.0}}
    header.update(changes)
    return json.dumps(header).encode()


@pytest.mark.parametrize("header, message", [
    (_header_json(schema_hash=0x0BADF00D), "schema hash 0x0BADF00D; this imulink decodes"),
    (_header_json(protocol_version=7), "recorded with protocol v7"),
    (_header_json(schema_hash="x"), "schema hash 'x'"),
    (b"{not json", "header record at byte 8 is not a JSON object"),
    (b"[1, 2]", "header record at byte 8 is not a JSON object"),
    (b"\xff\xfe\x00", "header record at byte 8 is not a JSON object"),
    (b"[" * 100_000, "header record at byte 8 is not a JSON object"),
    (_header_json(format_version=2), "recording format 2 is not supported"),
    (_header_json(profile={"name": "p", "gyro_lsb_per_dps": 0, "acc_lsb_per_g": 1, "mag_lsb_per_gauss": 1}),
     "gyro_lsb_per_dps is 0, not a positive number"),
    (_header_json(profile={"name": "p", "gyro_lsb_per_dps": 1}), "header without a valid sensor profile"),
    (_header_json(profile=[]), "header without a valid sensor profile"),
], ids=["other-schema", "other-version", "schema-not-a-number", "not-json", "json-list", "not-utf8", "too-deep",
        "other-format", "zero-sensitivity", "profile-incomplete", "profile-not-an-object"])
def test_a_header_this_host_cannot_decode_is_refused(tmp_path, header, message):
    path = _write(tmp_path / "h.imulog", [_setting_frames(), _stream_frames(range(3))])
    _with_header(path, header)
    with pytest.raises(RecordingError, match=re.escape(message)):
        load_recording(path)


def test_a_malformed_event_behind_a_valid_crc_is_refused(tmp_path):
    path = _write(tmp_path / "e.imulog", [_stream_frames(range(3))])
    head = struct.pack("<IBd", 5, KIND_EVENT, 0.0)
    with open(path, "ab") as f:
        f.write(head + b"[1,2]" + struct.pack("<I", zlib.crc32(b"[1,2]", zlib.crc32(head))))
    with pytest.raises(RecordingError, match=r"event record at byte \d+ is not a JSON object"):
        load_recording(path)


def test_a_damaged_header_is_named(tmp_path):
    path = _write(tmp_path / "dh.imulog", [_stream_frames(range(3))])
    data = bytearray(path.read_bytes())
    data[len(MAGIC) + 20] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="no header record .* missing or damaged"):
        load_recording(path)


def test_only_regular_files_of_bounded_size_are_read(tmp_path, monkeypatch):
    fifo = tmp_path / "fifo.imulog"
    os.mkfifo(fifo)  # opening it would block until a writer comes
    with pytest.raises(RecordingError, match="not a regular file"):
        load_recording(fifo)
    with pytest.raises(RecordingError, match="not a regular file"):
        load_recording(tmp_path)
    path = _write(tmp_path / "big.imulog", [_stream_frames(range(3))])
    monkeypatch.setattr(recording_module, "MAX_FILE_BYTES", 100)
    with pytest.raises(RecordingError, match=r"bytes, more than the 100 this command reads"):
        load_recording(path)


def test_frames_before_the_snapshot_are_marked_leftover(tmp_path):
    """A stream the board was still sending when the recording began (a recorder killed
    and restarted) is told apart from frames after the snapshot."""
    path = tmp_path / "left.imulog"
    restart_ack = protocol.encode("ACK", 60, command_seq=9, command=protocol.COMMAND_IDS["SELECT_FILTER"], reason=0)
    with RecordingWriter(path, "test://", DEFAULT_PROFILE) as writer:
        writer.received(_stream_frames(range(500, 504), seq=10), 1.0)
        writer.event("snapshot", status={}, filter="eecf", settings={})
        writer.received(_setting_frames(30) + restart_ack + _stream_frames(range(3), seq=100), 2.0)
    recording = load_recording(path)
    np.testing.assert_array_equal(recording.estimates.leftover, [True] * 4 + [False] * 3)
    np.testing.assert_array_equal(recording.estimates.segment, [0] * 4 + [1] * 3)
