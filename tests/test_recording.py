"""Recording files (imulink.recording): the record format, crash-safe reading, decoding.

The writer's records read back exactly; a tail cut anywhere (or zero-filled, as a crash
may leave it) is ignored and everything before it kept; damage before the tail is a
RecordingCorrupt naming the byte offset; a file that is not a recording says so. Frames
decode into sample and estimate tables split into filter runs (segments) at restarts.
"""
from __future__ import annotations

import json
import struct
import zlib

import numpy as np
import pytest

from imulink import protocol
from imulink.reference import FirmwareFilter
from imulink.counts import BROAD_PROFILE, DEFAULT_PROFILE
from imulink.recording import (
    KIND_EVENT,
    KIND_HEADER,
    KIND_RECEIVED,
    MAGIC,
    RecordingCorrupt,
    RecordingError,
    RecordingWriter,
    load_recording,
    read_records,
)

SETTINGS = FirmwareFilter.default_raw_settings("eecf", 100.0)


def _setting_frames(seq: int = 0) -> bytes:
    """SETTING frames for every eecf setting, as a board answers GET_SETTING."""
    from imulink import core

    fields = core.settings_fields("eecf")
    return b"".join(protocol.encode("SETTING", seq + i, filter_id=1, index=i, setting_count=len(fields),
                                    value=SETTINGS[f.name], frac_bits=f.frac_bits, name=f.name, unit=f.unit)
                    for i, f in enumerate(fields))


def _stream_frames(indices, seq: int = 100) -> bytes:
    """SAMPLE + ESTIMATE pairs with the given sample indices (values do not matter here)."""
    out = b""
    for k, index in enumerate(indices):
        out += protocol.encode("SAMPLE", seq + 2 * k, timestamp_us=k * 10_000, index=index, gyr=(k, 0, 0),
                               acc=(0, 0, 4096), mag=(100, 0, -200), temperature=0)
        out += protocol.encode("ESTIMATE", seq + 2 * k + 1, index=index, filter_id=1, quat=(1 << 30, 0, 0, 0),
                               gyro_bias=(0, 0, 0), euler=(0, 0, 0), cov_mantissa=(0,) * 9, cov_exponent=(0,) * 9,
                               saturations=0)
    return out


def _write(path, chunks, profile=DEFAULT_PROFILE):
    with RecordingWriter(path, "test://", profile) as writer:
        for chunk in chunks:
            writer.received(chunk, 1000.0)
        writer.event("stopped", reason="test")
    return path


def test_records_round_trip(tmp_path):
    path = tmp_path / "a.imulog"
    with RecordingWriter(path, "socket://127.0.0.1:1", BROAD_PROFILE) as writer:
        writer.received(b"\x01\x02\x00", 12.5)
        writer.event("snapshot", filter="eecf")
    records, truncated = read_records(path)
    assert truncated == 0
    assert [r.kind for r in records] == [KIND_HEADER, KIND_RECEIVED, KIND_EVENT]
    header = json.loads(records[0].body)
    assert header["port"] == "socket://127.0.0.1:1" and header["schema_hash"] == protocol.SCHEMA_HASH
    assert header["profile"]["name"] == "gy86-broad"
    assert records[1].body == b"\x01\x02\x00" and records[1].time == 12.5
    assert json.loads(records[2].body) == {"event": "snapshot", "filter": "eecf"}


def test_truncated_tail_is_ignored_wherever_the_cut_falls(tmp_path):
    chunks = [_setting_frames(), _stream_frames(range(5)), _stream_frames(range(5, 10), seq=200)]
    full = _write(tmp_path / "full.imulog", chunks).read_bytes()
    complete, _ = read_records(tmp_path / "full.imulog")
    cut_path = tmp_path / "cut.imulog"
    for cut in range(len(MAGIC), len(full)):
        cut_path.write_bytes(full[:cut])
        records, truncated = read_records(cut_path)
        kept = len(MAGIC) + sum(13 + len(r.body) + 4 for r in records)
        assert kept + truncated == cut  # every byte is either a whole record or the ignored tail
        assert [r.body for r in records] == [r.body for r in complete[:len(records)]]


def test_zero_filled_tail_is_ignored(tmp_path):
    path = _write(tmp_path / "z.imulog", [_stream_frames(range(3))])
    good = path.read_bytes()
    path.write_bytes(good + bytes(4096))
    records, truncated = read_records(path)
    assert truncated == 4096
    assert len(records) == 3


def test_damage_before_the_tail_is_corruption(tmp_path):
    path = _write(tmp_path / "c.imulog", [_stream_frames(range(3)), _stream_frames(range(3, 6))])
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingCorrupt, match=r"corrupt at byte \d+ \(record \d+\): CRC mismatch"):
        read_records(path)


def test_impossible_record_length_is_corruption(tmp_path):
    path = _write(tmp_path / "l.imulog", [b"x" * 10, b"y" * 10])
    data = bytearray(path.read_bytes())
    first_record = len(MAGIC)
    data[first_record:first_record + 4] = (1 << 30).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingCorrupt, match="impossible record length"):
        read_records(path)


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
    assert len(recording.samples) == 4 and recording.truncated_bytes == 0


def test_load_recording_tables_and_snapshot(tmp_path):
    hello = protocol.encode("HELLO", 5, firmware_major=1, firmware_minor=2, firmware_patch=3,
                            protocol_version=protocol.PROTOCOL_VERSION, schema_hash=protocol.SCHEMA_HASH,
                            board="test", filters=2)
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


def test_segments_start_at_restarts_and_index_drops(tmp_path):
    restart_ack = protocol.encode("ACK", 50, command_seq=7, command=protocol.COMMAND_IDS["SELECT_FILTER"], reason=0)
    other_ack = protocol.encode("ACK", 51, command_seq=8, command=protocol.COMMAND_IDS["GET_STATUS"], reason=0)
    reset_hello = protocol.encode("HELLO", 0, firmware_major=0, firmware_minor=1, firmware_patch=0,
                                  protocol_version=1, schema_hash=protocol.SCHEMA_HASH, board="x", filters=2)
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
