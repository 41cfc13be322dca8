"""The C frame codec (firmware/core/imu_proto.c, through cffi) against the Python codec.

The same bytes both ways for every message and command: Python-encoded frames decode
in C to the same fields, C-encoded frames are byte-identical to Python's; CRC-32 and
COBS agree with zlib and the `cobs` package; the C stream decoder accepts and counts
exactly what the Python FrameDecoder does on damaged streams. Both builds (fixed and
float) compile the same integer-only codec: the fixed build is tested in full, the
float build is checked to carry the same schema and CRC.
"""
from __future__ import annotations

import os
import random
import shutil
import subprocess
import zlib
from pathlib import Path

import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from imulink import core, protocol
from imulink.core import _fixed as _core_fixed
from imulink.core import _float as _core_float
from imulink.protocol import _schema as schema
from test_protocol import (
    ARGS,
    DAMAGE,
    FIELDS,
    HYPOTHESIS,
    MESSAGE_NAMES,
    damage_stream,
    number_frames,
    random_damaged_stream,
    random_fields,
)

ffi, lib = _core_fixed.ffi, _core_fixed.lib


def raw(pointer, n: int) -> bytes:
    """n bytes at a cffi pointer or array."""
    return ffi.buffer(pointer, n)[:]


# --------------------------------------------------------------------------- C structs <-> field dicts


def to_struct(ctype: str, fields: tuple, values: dict):
    """A new C struct `ctype` filled from a field dict."""
    s = ffi.new(f"{ctype} *")
    for name, base, length in fields:
        value = values[name]
        if base in ("char", "text", "bytes"):
            data = value.encode("utf-8") if isinstance(value, str) else value
            ffi.memmove(getattr(s, name), data, len(data))  # ffi.new zero-fills: char fields are NUL padded
            if base != "char":
                setattr(s, f"{name}_len", len(data))
        elif length is None:
            setattr(s, name, value)
        else:
            getattr(s, name)[0:length] = list(value)
    return s


def from_struct(s, fields: tuple) -> dict:
    """The field dict of a C struct (as the Python codec would decode it)."""
    out = {}
    for name, base, length in fields:
        if base == "char":
            out[name] = raw(getattr(s, name), length).partition(b"\0")[0].decode("utf-8", "replace")
        elif base in ("text", "bytes"):
            data = raw(getattr(s, name), getattr(s, f"{name}_len"))
            out[name] = data.decode("utf-8", "replace") if base == "text" else data
        elif length is None:
            out[name] = getattr(s, name)
        else:
            out[name] = tuple(getattr(s, name))
    return out


class CDecoder:
    """imu_proto_decoder_t fed byte by byte; collects (msg_id, seq, payload) of the frames."""

    def __init__(self, cap: int = lib.IMU_PROTO_MAX_FRAME):
        self.buf = ffi.new("uint8_t[]", cap)
        self.state = ffi.new("imu_proto_decoder_t *")
        self.frame = ffi.new("imu_proto_frame_t *")
        lib.imu_proto_decoder_init(self.state, self.buf, cap)

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        frames = []
        for byte in data:
            if lib.imu_proto_decoder_push(self.state, byte, self.frame):
                f = self.frame
                frames.append((f.msg_id, f.seq, raw(f.payload, f.payload_len)))
        return frames

    def counters(self) -> dict:
        s = self.state
        return {"bytes": s.bytes, "frames": s.frames, "crc_errors": s.crc_errors, "resyncs": s.resyncs,
                "oversize": s.oversize}


def c_decode_payload(wire: bytes) -> tuple[int, int, bytes]:
    decoder = CDecoder()
    frames = decoder.feed(wire)
    assert len(frames) == 1, decoder.counters()
    return frames[0]


def frame_parts(wire: bytes) -> tuple[int, int, bytes]:
    """(msg_id, seq, payload) of a wire frame, by the Python side."""
    frame = cobs.decode(wire[:-1])
    return frame[0], int.from_bytes(frame[1:3], "little"), frame[3:-4]


# --------------------------------------------------------------------------- constants


def test_both_builds_carry_the_schema_of_the_python_codec():
    for module in (_core_fixed, _core_float):
        assert module.lib.IMU_PROTO_SCHEMA_HASH == protocol.SCHEMA_HASH == schema.SCHEMA_HASH
        assert module.lib.IMU_PROTO_VERSION == protocol.PROTOCOL_VERSION
        assert module.lib.IMU_PROTO_MAX_FRAME == protocol.MAX_FRAME
        assert module.lib.IMU_PROTO_MAX_WIRE == protocol.MAX_ENCODED + 1
    assert lib.IMU_PROTO_MIN_FRAME == protocol.MIN_FRAME


def test_ids_codes_and_sizes_agree():
    for name, spec in schema.MESSAGES.items():
        assert getattr(lib, f"IMU_PROTO_MSG_{name}") == spec["id"] == protocol.MESSAGE_IDS[name]
        assert getattr(lib, f"IMU_PROTO_{name}_SIZE") == protocol._CODECS[name].max_frame - protocol.MIN_FRAME
    for name, spec in schema.COMMANDS.items():
        assert getattr(lib, f"IMU_PROTO_CMD_{name}") == spec["id"]
        assert lib.imu_proto_command_args_size(spec["id"]) == protocol._COMMAND_LAYOUTS[name].payload_size
    unknown = set(range(256)) - {spec["id"] for spec in schema.COMMANDS.values()}
    assert {lib.imu_proto_command_args_size(i) for i in unknown} == {-1}
    for table, codes in schema.ENUMS.items():
        for code, value in codes.items():
            assert getattr(lib, f"IMU_PROTO_{table.upper()}_{code}") == value


def test_protocol_filter_ids_are_the_core_filter_ids():
    """The filter code table, the core's imu_filter_id_t (imu_filter.h, through the cffi
    declaration generated from the table) and the host's filter table agree."""
    assert {name.lower(): value for name, value in protocol.FILTER_IDS.items()} == \
        {name: filter_id for name, (filter_id, _) in core.BOARD_FILTERS.items()}
    for module in (_core_fixed, _core_float):
        for name, value in protocol.FILTER_IDS.items():
            assert getattr(module.lib, f"IMU_FILTER_{name}") == value == getattr(module.lib, f"IMU_PROTO_FILTER_{name}")


def test_q_formats_and_command_flags_agree():
    for name, formats in schema.FIELD_FORMATS.items():
        for field, (frac_bits, scale, _unit) in formats.items():
            if frac_bits:
                assert getattr(lib, f"IMU_PROTO_{name}_{field.upper()}_FRAC_BITS") == frac_bits
                assert scale == 2.0**-frac_bits
    assert lib.IMU_PROTO_CMD_SET_CALIBRATION_OFFSET_FRAC_BITS == protocol.arg_format("SET_CALIBRATION", "offset")[0]
    assert lib.IMU_PROTO_CMD_SET_CALIBRATION_ROW_FRAC_BITS == protocol.arg_format("SET_CALIBRATION", "row")[0]
    for name, spec in schema.COMMANDS.items():
        flags = lib.imu_proto_command_flags(spec["id"])
        assert flags == getattr(lib, f"IMU_PROTO_CMD_{name}_FLAGS")
        assert bool(flags & lib.IMU_PROTO_FLAG_RESTARTS_FILTER) == spec["restarts_filter"] == \
            (name in protocol.RESTARTING_COMMANDS)
        assert bool(flags & lib.IMU_PROTO_FLAG_IDEMPOTENT) == spec["idempotent"] == \
            (name not in protocol.NOT_IDEMPOTENT_COMMANDS)
    unknown = set(range(256)) - {spec["id"] for spec in schema.COMMANDS.values()}
    assert {lib.imu_proto_command_flags(i) for i in unknown} == {0}


# --------------------------------------------------------------------------- messages both ways


@pytest.mark.parametrize("name", MESSAGE_NAMES)
@settings(max_examples=100, **HYPOTHESIS)
@given(data=st.data())
def test_every_message_is_the_same_bytes_in_c_and_python(name, data):
    fields = data.draw(FIELDS[name])
    seq = data.draw(st.integers(0, 0xFFFF))
    lower, spec = name.lower(), schema.MESSAGES[name]
    py_wire = protocol.encode(name, seq, **fields)

    # Python -> C: the C decoder finds the frame, the C unpack gives the same fields
    msg_id, c_seq, payload = c_decode_payload(py_wire)
    assert (msg_id, c_seq) == (spec["id"], seq)
    decoded = ffi.new(f"imu_proto_{lower}_t *")
    assert getattr(lib, f"imu_proto_{lower}_unpack")(decoded, payload, len(payload)) == lib.IMU_PROTO_OK
    assert from_struct(decoded, spec["fields"]) == fields

    # C -> Python: the C encoder writes exactly the same bytes
    wire = ffi.new("uint8_t[]", lib.IMU_PROTO_MAX_WIRE)
    n = getattr(lib, f"imu_proto_{lower}_encode")(to_struct(f"imu_proto_{lower}_t", spec["fields"], fields), seq,
                                                  wire, lib.IMU_PROTO_MAX_WIRE)
    c_wire = raw(wire, n)
    assert c_wire == py_wire
    assert protocol.decode(c_wire) == protocol.Message(name, seq, fields)

    # A buffer of exactly the frame's size suffices; one byte less gets 0 and nothing
    # written past the buffer (the fixed-size messages are packed into it in place).
    struct = to_struct(f"imu_proto_{lower}_t", spec["fields"], fields)
    for cap in (n, n - 1):
        guarded = ffi.new("uint8_t[]", lib.IMU_PROTO_MAX_WIRE)
        ffi.memmove(guarded, b"\xa5" * lib.IMU_PROTO_MAX_WIRE, lib.IMU_PROTO_MAX_WIRE)
        got = getattr(lib, f"imu_proto_{lower}_encode")(struct, seq, guarded, cap)
        assert got == (n if cap == n else 0)
        assert raw(guarded, lib.IMU_PROTO_MAX_WIRE)[cap:] == b"\xa5" * (lib.IMU_PROTO_MAX_WIRE - cap)


@pytest.mark.parametrize("name", MESSAGE_NAMES)
def test_unpack_rejects_every_wrong_length(name):
    lower, codec = name.lower(), protocol._CODECS[name]
    sizes = range(codec.min_frame - protocol.MIN_FRAME, codec.max_frame - protocol.MIN_FRAME + 1)
    payload = bytes(range(256))
    for length in range(len(payload)):
        status = getattr(lib, f"imu_proto_{lower}_unpack")(ffi.new(f"imu_proto_{lower}_t *"), payload, length)
        assert status == (lib.IMU_PROTO_OK if length in sizes else lib.IMU_PROTO_ERR_LENGTH), length


def test_variable_length_pack_refuses_a_length_past_the_maximum():
    log = ffi.new("imu_proto_log_t *")
    log.text_len = 201
    wire = ffi.new("uint8_t[]", lib.IMU_PROTO_MAX_WIRE)
    assert lib.imu_proto_log_pack(log, wire) == 0
    assert lib.imu_proto_log_encode(log, 0, wire, lib.IMU_PROTO_MAX_WIRE) == 0
    log.text_len = 200
    assert lib.imu_proto_log_encode(log, 0, wire, lib.IMU_PROTO_MAX_WIRE) == 200 + 1 + protocol.MIN_FRAME + 2


@pytest.mark.parametrize("command", [name for name, spec in schema.COMMANDS.items() if spec["args"]])
@settings(max_examples=40, **HYPOTHESIS)
@given(data=st.data())
def test_command_arguments_are_the_same_bytes_in_c_and_python(command, data):
    args = data.draw(ARGS[command])
    lower, fields = command.lower(), schema.COMMANDS[command]["args"]
    py_args = protocol.decode(protocol.encode_command(0, command, 1, **args)).fields["args"]
    ctype = "imu_proto_sample_t" if command == "INJECT_SAMPLE" else f"imu_proto_cmd_{lower}_t"
    out = ffi.new("uint8_t[]", 64)
    n = getattr(lib, f"imu_proto_cmd_{lower}_pack")(to_struct(ctype, fields, args), out)
    assert raw(out, n) == py_args
    decoded = ffi.new(f"{ctype} *")
    assert getattr(lib, f"imu_proto_cmd_{lower}_unpack")(decoded, py_args, len(py_args)) == lib.IMU_PROTO_OK
    assert from_struct(decoded, fields) == args
    assert getattr(lib, f"imu_proto_cmd_{lower}_unpack")(decoded, py_args, len(py_args) + 1) == \
        lib.IMU_PROTO_ERR_LENGTH


# --------------------------------------------------------------------------- CRC and COBS


def test_crc32_check_value():
    assert lib.imu_proto_crc32(0, b"123456789", 9) == 0xCBF43926 == zlib.crc32(b"123456789")


@settings(max_examples=300, **HYPOTHESIS)
@given(data=st.binary(max_size=600), split=st.integers(0, 600))
def test_crc32_is_zlib_crc32_and_chains(data, split):
    head, tail = data[:split], data[split:]
    assert lib.imu_proto_crc32(0, data, len(data)) == zlib.crc32(data)
    assert lib.imu_proto_crc32(lib.imu_proto_crc32(0, head, len(head)), tail, len(tail)) == zlib.crc32(data)
    assert _core_float.lib.imu_proto_crc32(0, data, len(data)) == zlib.crc32(data)


#: Bytes with many zeros and long non-zero runs (COBS's 254-byte block boundary).
COBS_INPUTS = st.one_of(
    st.binary(max_size=700),
    st.lists(st.sampled_from([b"\0", b"\x01" * 253, b"\x02" * 254, b"\x03" * 255, b"\x04"]), max_size=6)
    .map(b"".join),
)


@settings(max_examples=300, **HYPOTHESIS)
@given(data=COBS_INPUTS)
def test_cobs_matches_the_cobs_package_and_round_trips(data):
    cap = len(data) + len(data) // 254 + 1
    out = ffi.new("uint8_t[]", cap)
    n = lib.imu_proto_cobs_encode(data, len(data), out, cap)
    encoded = raw(out, n)
    assert encoded == cobs.encode(data) and b"\0" not in encoded
    decoded = ffi.new("uint8_t[]", max(1, len(data)))
    length = ffi.new("size_t *")
    assert lib.imu_proto_cobs_decode(encoded, n, decoded, len(data), length) == lib.IMU_PROTO_OK
    assert raw(decoded, length[0]) == data
    if n > 1:
        assert lib.imu_proto_cobs_encode(data, len(data), out, n - 1) == 0, "must not overrun a short buffer"
    if data:
        assert lib.imu_proto_cobs_decode(encoded, n, decoded, len(data) - 1, length) == lib.IMU_PROTO_ERR_SPACE


@settings(max_examples=300, **HYPOTHESIS)
@given(data=st.binary(min_size=1, max_size=300))
def test_cobs_decode_rejects_what_the_cobs_package_rejects(data):
    out = ffi.new("uint8_t[]", 400)
    length = ffi.new("size_t *")
    status = lib.imu_proto_cobs_decode(data, len(data), out, 400, length)
    try:
        expected = cobs.decode(data)
    except cobs.DecodeError:
        assert status == lib.IMU_PROTO_ERR_COBS
    else:
        assert status == lib.IMU_PROTO_OK and raw(out, length[0]) == expected
    assert lib.imu_proto_cobs_decode(data, 0, out, 400, length) == lib.IMU_PROTO_ERR_COBS


@settings(max_examples=300, **HYPOTHESIS)
@given(payload=st.one_of(st.binary(max_size=300), COBS_INPUTS.filter(lambda d: len(d) <= 300)),
       seq=st.integers(0, 0xFFFF))
def test_frame_encode_matches_python_in_place_and_streaming(payload, seq):
    """Frames up to 253 bytes are COBS-encoded in place, longer ones by the streaming
    writer (a full block of 254 data bytes needs an extra code byte): the same bytes."""
    body = bytes([lib.IMU_PROTO_MSG_LOG]) + seq.to_bytes(2, "little") + payload
    expected = cobs.encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\0"
    wire = ffi.new("uint8_t[]", len(expected) + 8)
    n = lib.imu_proto_frame_encode(lib.IMU_PROTO_MSG_LOG, seq, payload, len(payload), wire, len(expected))
    assert raw(wire, n) == expected
    assert lib.imu_proto_frame_encode(lib.IMU_PROTO_MSG_LOG, seq, payload, len(payload), wire,
                                      len(expected) - 1) == 0


def test_frame_encode_refuses_a_short_buffer():
    payload = b"\x01\x02\x03\x04"
    wire = ffi.new("uint8_t[]", 64)
    full = lib.imu_proto_frame_encode(lib.IMU_PROTO_MSG_ACK, 7, payload, 4, wire, 64)
    assert raw(wire, full) == protocol.encode("ACK", 7, command_seq=0x0201, command=3, reason=4)
    for cap in range(full):
        assert lib.imu_proto_frame_encode(lib.IMU_PROTO_MSG_ACK, 7, payload, 4, wire, cap) == 0


# --------------------------------------------------------------------------- stream decoder


def _python_frames(messages) -> list[tuple[int, int, bytes]]:
    return [frame_parts(protocol.encode(m.name, m.seq, **m.fields)) for m in messages]


@settings(max_examples=200, **HYPOTHESIS)
@given(garbage=st.binary(max_size=2000))
def test_c_decoder_counts_garbage_like_python(garbage):
    data = garbage + b"\0"
    c, py = CDecoder(), protocol.FrameDecoder()
    assert c.feed(data) == _python_frames(py.feed(data)) == []
    counters = c.counters()
    assert (counters["frames"], counters["crc_errors"], counters["resyncs"], counters["bytes"]) == \
        (py.frames, py.crc_errors, py.resyncs, py.bytes)


@pytest.mark.parametrize("seed", range(3))
def test_c_decoder_accepts_and_counts_damaged_streams_like_python(seed):
    rnd = random.Random(seed)
    for _ in range(50):
        _, data, _ = random_damaged_stream(rnd, frames=(10, 60), max_damages=20)
        c, py = CDecoder(), protocol.FrameDecoder()
        assert c.feed(data) == _python_frames(py.feed(data))
        counters = c.counters()
        assert (counters["frames"], counters["crc_errors"], counters["resyncs"]) == \
            (py.frames, py.crc_errors, py.resyncs)


def test_c_decoder_drops_frames_longer_than_its_buffer():
    log = protocol.encode("LOG", 1, level=20, text="x" * 50)
    ack = protocol.encode("ACK", 2, command_seq=1, command=2, reason=0)
    c = CDecoder(cap=40)
    assert c.feed(log + ack + b"\x01" * 500 + b"\0" + ack) == [frame_parts(ack)] * 2
    assert c.counters() == {"bytes": 2 * len(ack) + len(log) + 501, "frames": 2, "crc_errors": 0, "resyncs": 2,
                            "oversize": 2}


# --------------------------------------------------------------------------- sanitizers

#: Reads a byte stream from a file, decodes it with a buffer of argv[2] bytes, unpacks and
#: re-encodes every frame, prints the re-encoded wire bytes in hex, then the counters.
_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "imu_proto.h"

static void print_hex(const uint8_t *p, size_t n)
{
    size_t i;
    for (i = 0; i < n; ++i) {
        printf("%02x", p[i]);
    }
    printf("\n");
}

#define REENCODE(lower, UPPER)                                                        \
    case IMU_PROTO_MSG_##UPPER: {                                                     \
        imu_proto_##lower##_t m;                                                      \
        if (imu_proto_##lower##_unpack(&m, frame.payload, frame.payload_len) == IMU_PROTO_OK) { \
            print_hex(wire, imu_proto_##lower##_encode(&m, frame.seq, wire, sizeof wire)); \
        } else {                                                                      \
            printf("bad length\n");                                                   \
        }                                                                             \
        break;                                                                        \
    }

int main(int argc, char **argv)
{
    static uint8_t buf[IMU_PROTO_MAX_FRAME];
    uint8_t wire[IMU_PROTO_MAX_WIRE];
    imu_proto_decoder_t d;
    imu_proto_frame_t frame;
    FILE *in = fopen(argv[1], "rb");
    int c;
    (void)argc;
    imu_proto_decoder_init(&d, buf, (size_t)atoi(argv[2]));
    while ((c = fgetc(in)) != EOF) {
        if (!imu_proto_decoder_push(&d, (uint8_t)c, &frame)) {
            continue;
        }
        switch (frame.msg_id) {
        MESSAGES
        default:
            printf("unknown id\n");
        }
    }
    fclose(in);
    printf("%lu %lu %lu %lu %lu\n", (unsigned long)d.bytes, (unsigned long)d.frames,
           (unsigned long)d.crc_errors, (unsigned long)d.resyncs, (unsigned long)d.oversize);
    return 0;
}
"""

GCC = shutil.which("gcc")


@pytest.fixture(scope="module")
def sanitized_driver(tmp_path_factory):
    if GCC is None:
        pytest.skip("gcc not found")
    out = tmp_path_factory.mktemp("proto")
    source = out / "proto_driver.c"
    cases = " ".join(f"REENCODE({name.lower()}, {name})" for name in schema.MESSAGES)
    source.write_text(_DRIVER.replace("MESSAGES", cases))
    core = Path(__file__).resolve().parents[1] / "firmware" / "core"
    proc = subprocess.run([GCC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-DIMU_FIXED", "-g",
                           "-fsanitize=undefined,address", "-fno-sanitize-recover=all", f"-I{core}",
                           str(source), str(core / "imu_proto.c"), str(core / "imu_proto_gen.c"), "-o",
                           str(out / "driver")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return out / "driver"


@pytest.mark.parametrize("cap", [lib.IMU_PROTO_MAX_FRAME, 24])
def test_c_decoder_under_sanitizers(sanitized_driver, tmp_path, cap):
    """Damaged streams through the C decoder and every unpack/encode, with ASan and UBSan:
    no memory error, and the same frames and counters as the Python decoder (which has no
    buffer limit: with a small C buffer, the longer frames become oversize resyncs)."""
    rnd = random.Random(cap)
    named = [(name, random_fields(schema.MESSAGES[name]["fields"], rnd))
             for name in rnd.choices(MESSAGE_NAMES, k=3000)]
    sent = number_frames(named, {d: rnd.randint(0, 0xFFFF) for d in protocol.DIRECTIONS})
    damages = [(rnd.choice(DAMAGE), rnd.random(), rnd.randint(0, 255)) for _ in range(400)]
    data, _ = damage_stream(sent, damages)
    stream = tmp_path / "stream.bin"
    stream.write_bytes(data + bytes(range(256)) * 4 + b"\0")  # ends with garbage spans
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=0", UBSAN_OPTIONS="print_stacktrace=1")
    proc = subprocess.run([str(sanitized_driver), str(stream), str(cap)], capture_output=True, text=True,
                          env=env, timeout=120)
    assert proc.returncode == 0 and "runtime error" not in proc.stderr, proc.stderr
    *frames, counters = proc.stdout.splitlines()

    py = protocol.FrameDecoder()
    expected = [protocol.encode(m.name, m.seq, **m.fields) for m in py.feed(stream.read_bytes())]
    fitting = [wire for wire in expected if len(cobs.decode(wire[:-1])) <= cap]
    assert [bytes.fromhex(line) for line in frames] == fitting
    c_bytes, c_frames, c_crc, c_resyncs, c_oversize = map(int, counters.split())
    assert c_bytes == py.bytes and c_frames == len(fitting)
    assert c_frames + c_crc + c_resyncs == py.frames + py.crc_errors + py.resyncs, "every span counted once"
    if cap == lib.IMU_PROTO_MAX_FRAME:
        assert (c_crc, c_resyncs) == (py.crc_errors, py.resyncs)
    else:
        assert c_oversize >= len(expected) - len(fitting) > 0
