"""The Python frame codec (imulink.protocol) and its generator (tools/gen_protocol.py).

Property tests throw random and damaged byte streams at FrameDecoder: random garbage,
flipped bits, dropped, duplicated and inserted bytes, truncated frames, overwritten
COBS code bytes and delimiters. Whatever the damage: no exception; every span between
delimiters is counted exactly once (frame, CRC error or resync); every undamaged frame
is decoded; every decoded frame is byte-identical to a frame that was sent, in order;
the lost-frame count equals the frames missing between the first and the last frame
received. The totals of streams and bytes thrown at the decoder are printed at the end
of this module (`pytest -s`) and recorded in docs/protocol.md.

The strategies for message fields and wire streams are imported by test_protocol_c.py.
"""
from __future__ import annotations

import importlib.util
import random
import shutil
import subprocess
import sys
import zlib
from collections import Counter
from pathlib import Path

import pytest
from cobs import cobs
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imulink import protocol
from imulink.protocol import _schema as schema

ROOT = Path(__file__).resolve().parents[1]
GENERATOR = ROOT / "tools" / "gen_protocol.py"

#: Shared hypothesis settings: no deadline (example timings vary on CI machines).
HYPOTHESIS = {"deadline": None}

#: Streams and bytes fed to FrameDecoder by the property tests of this module.
THROWN = Counter()

_INT_RANGES = {"u8": (0, 0xFF), "i8": (-0x80, 0x7F), "u16": (0, 0xFFFF), "i16": (-0x8000, 0x7FFF),
               "u32": (0, 0xFFFFFFFF), "i32": (-0x80000000, 0x7FFFFFFF)}
_TEXT_CHARS = st.characters(blacklist_categories=("Cs",), blacklist_characters="\0")


def _utf8_prefix(text: str, limit: int) -> str:
    """The longest prefix of `text` whose UTF-8 encoding has at most `limit` bytes."""
    raw = text.encode("utf-8")[:limit]
    return raw.decode("utf-8", "ignore")


def field_strategy(base: str, length: int | None):
    """Values of one schema field, as protocol.encode takes them and decode returns them."""
    if base in ("char", "text"):
        return st.text(_TEXT_CHARS, max_size=length).map(lambda s: _utf8_prefix(s, length))
    if base == "bytes":
        return st.binary(max_size=length)
    low, high = _INT_RANGES[base]
    ints = st.one_of(st.integers(low, high), st.sampled_from([low, high, 0, -1 if low else 1]))
    return ints if length is None else st.lists(ints, min_size=length, max_size=length).map(tuple)


def fields_strategy(fields: tuple):
    return st.fixed_dictionaries({name: field_strategy(base, length) for name, base, length in fields})


MESSAGE_NAMES = list(schema.MESSAGES)
FIELDS = {name: fields_strategy(spec["fields"]) for name, spec in schema.MESSAGES.items()}
ARGS = {name: fields_strategy(spec["args"]) for name, spec in schema.COMMANDS.items()}


@st.composite
def messages(draw, names=MESSAGE_NAMES):
    """(name, fields) of a random message."""
    name = draw(st.sampled_from(names))
    return name, draw(FIELDS[name])


def number_frames(named_fields, first_seqs: dict) -> list:
    """Frames as a sender writes them: a list of (name, seq, fields, wire bytes) with
    consecutive sequence numbers per direction from `first_seqs`. A HELLO that would get
    seq 0 is left out: it would announce a sender restart."""
    next_seq = dict(first_seqs)
    out = []
    for name, fields in named_fields:
        direction = schema.MESSAGES[name]["direction"]
        seq = next_seq[direction]
        if name == "HELLO" and seq == 0:
            continue
        next_seq[direction] = (seq + 1) & 0xFFFF
        out.append((name, seq, fields, protocol.encode(name, seq, **fields)))
    return out


@st.composite
def sent_streams(draw, max_frames=30):
    """number_frames() of random messages; some sequences start near 65535 and wrap."""
    seq_ranges = st.one_of(st.integers(0, 0xFFFF), st.integers(0xFFFF - 10, 0xFFFF))
    first_seqs = {direction: draw(seq_ranges) for direction in protocol.DIRECTIONS}
    return number_frames(draw(st.lists(messages(), min_size=1, max_size=max_frames)), first_seqs)


def random_fields(fields: tuple, rnd: random.Random) -> dict:
    """Random values of a field list (the soak test's faster stand-in for FIELDS)."""
    out = {}
    for name, base, length in fields:
        if base in ("char", "text"):
            out[name] = "".join(rnd.choice("abcxyz_-019 éü") for _ in range(rnd.randint(0, length // 2)))
        elif base == "bytes":
            out[name] = rnd.randbytes(rnd.randint(0, length))
        else:
            low, high = _INT_RANGES[base]
            small = rnd.random() < 0.3  # small values: zero bytes, many COBS code bytes
            values = [rnd.randint(max(low, -3), 3) if small else rnd.randint(low, high)
                      for _ in range(length or 1)]
            out[name] = tuple(values) if length else values[0]
    return out


def chunked(data: bytes, rnd: random.Random, largest: int = 64):
    """`data` cut into random chunks (some empty)."""
    i = 0
    while i < len(data):
        n = rnd.randint(0, largest)
        yield data[i:i + n]
        i += n


def feed_all(decoder: protocol.FrameDecoder, data: bytes, rnd: random.Random | None = None) -> list:
    """Feed `data` to a new decoder (in random chunks when `rnd` is given); count it in THROWN."""
    if rnd is None:
        received = decoder.feed(data)
    else:
        received = [m for chunk in chunked(data, rnd) for m in decoder.feed(chunk)]
    THROWN["streams"] += 1
    THROWN["bytes"] += len(data)
    THROWN["frames"] += decoder.frames
    THROWN["rejected"] += decoder.crc_errors + decoder.resyncs
    return received


def nonempty_spans(data: bytes) -> int:
    """Spans between delimiters that the decoder must account for (the tail after the last
    delimiter is still incomplete)."""
    return sum(1 for span in data.split(b"\0")[:-1] if span)


def wire_of(message: protocol.Message) -> bytes:
    return protocol.encode(message.name, message.seq, **message.fields)


@pytest.fixture(scope="module", autouse=True)
def report_thrown():
    yield
    print(f"\ntest_protocol.py: FrameDecoder fed {THROWN['streams']} random streams, {THROWN['bytes']} bytes; "
          f"decoded {THROWN['frames']} frames, rejected {THROWN['rejected']} spans")


# --------------------------------------------------------------------------- encode / decode


@pytest.mark.parametrize("name", MESSAGE_NAMES)
@settings(max_examples=60, **HYPOTHESIS)
@given(data=st.data())
def test_every_message_round_trips(name, data):
    fields = data.draw(FIELDS[name])
    seq = data.draw(st.integers(0, 0xFFFF))
    wire = protocol.encode(name, seq, **fields)
    assert wire.index(b"\0") == len(wire) - 1, "exactly one delimiter, at the end"
    assert protocol.decode(wire) == protocol.Message(name, seq, fields)
    frame = cobs.decode(wire[:-1])
    assert frame[0] == schema.MESSAGES[name]["id"]
    assert int.from_bytes(frame[1:3], "little") == seq
    assert int.from_bytes(frame[-4:], "little") == zlib.crc32(frame[:-4])


def test_fixed_layout_of_sample_is_little_endian_and_packed():
    fields = dict(timestamp_us=0x04030201, index=0x08070605, gyr=(0x0A09, -2, 3), acc=(4, 5, 6),
                  mag=(7, 8, 9), temperature=-0x1234)
    frame = cobs.decode(protocol.encode("SAMPLE", 0xBEEF, **fields)[:-1])
    payload = frame[3:-4]
    assert frame[:3] == bytes([0x10, 0xEF, 0xBE])
    assert len(payload) == 28
    assert payload[:10] == bytes([1, 2, 3, 4, 5, 6, 7, 8, 0x09, 0x0A])
    assert payload[10:12] == (-2).to_bytes(2, "little", signed=True)
    assert payload[26:] == (-0x1234).to_bytes(2, "little", signed=True)


@pytest.mark.parametrize("name,fields,needle", [
    ("SAMPLE", {"index": 1}, "missing fields"),
    ("ACK", {"command_seq": 1, "command": 2, "reason": 0, "extra": 1}, "unknown fields ['extra']"),
    ("ACK", {"command_seq": 70000, "command": 2, "reason": 0}, "ACK.command_seq: 70000 is not a u16"),
    ("ACK", {"command_seq": 1, "command": -1, "reason": 0}, "ACK.command: -1 is not a u8"),
    ("ACK", {"command_seq": 1.5, "command": 1, "reason": 0}, "ACK.command_seq: 1.5"),
    ("LOG", {"level": 20, "text": "x" * 201}, "LOG.text: at most 200 bytes"),
    ("HELLO", {"firmware_major": 0, "firmware_minor": 1, "firmware_patch": 0, "protocol_version": 1,
               "schema_hash": 0, "board": "a\0b", "filters": 0, "gyro_scale": 1, "acc_scale": 1, "mag_scale": 1},
     "HELLO.board"),
    ("HELLO", {"firmware_major": 0, "firmware_minor": 1, "firmware_patch": 0, "protocol_version": 1,
               "schema_hash": 0, "board": "x" * 17, "filters": 0, "gyro_scale": 1, "acc_scale": 1, "mag_scale": 1},
     "at most 16 UTF-8 bytes"),
    ("NOPE", {}, "unknown message 'NOPE'"),
])
def test_encode_names_the_bad_field(name, fields, needle):
    with pytest.raises(ValueError) as info:
        protocol.encode(name, 0, **fields)
    assert needle in str(info.value)


def test_encode_rejects_wrong_array_length_and_seq():
    sample = dict(timestamp_us=0, index=0, gyr=(1, 2), acc=(0, 0, 0), mag=(0, 0, 0), temperature=0)
    with pytest.raises(ValueError, match="SAMPLE.gyr: needs 3 values, got 2"):
        protocol.encode("SAMPLE", 0, **sample)
    with pytest.raises(ValueError, match="seq 65536 is not a u16"):
        protocol.encode("ACK", 65536, command_seq=0, command=1, reason=0)


def _raw_frame(msg_id: int, seq: int, payload: bytes) -> bytes:
    """A frame with a valid CRC around any bytes (to reach the checks after the CRC)."""
    body = bytes([msg_id]) + seq.to_bytes(2, "little") + payload
    return cobs.encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\0"


def test_decode_errors_say_what_is_wrong():
    good = protocol.encode("ACK", 1, command_seq=2, command=3, reason=0)
    flipped = bytearray(good)
    flipped[1] ^= 0x10  # the msg_id byte (byte 0 is a COBS code byte)
    with pytest.raises(protocol.CrcError):
        protocol.decode(bytes(flipped))
    with pytest.raises(protocol.FrameError, match="not valid COBS"):
        protocol.decode(good[:-3] + b"\0")
    with pytest.raises(protocol.FrameError, match="unknown message id 0x7F"):
        protocol.decode(_raw_frame(0x7F, 0, b"abcd"))
    with pytest.raises(protocol.FrameError, match="SAMPLE frame of 10 bytes, expected 35..35"):
        protocol.decode(_raw_frame(0x10, 0, b"abc"))
    with pytest.raises(protocol.FrameError, match="delimiter inside"):
        protocol.decode(good + good)
    with pytest.raises(protocol.FrameError, match="shorter than the smallest frame"):
        protocol.decode(cobs.encode(b"\x04\x01") + b"\0")
    assert issubclass(protocol.CrcError, protocol.FrameError) and issubclass(protocol.FrameError, ValueError)


def test_variable_length_messages_accept_every_length_up_to_the_maximum():
    for n in (0, 1, 199, 200):
        text = "é" * (n // 2) + "x" * (n % 2)
        assert protocol.decode(protocol.encode("LOG", 7, level=30, text=text)).fields["text"] == text


# --------------------------------------------------------------------------- commands


@pytest.mark.parametrize("command", list(schema.COMMANDS))
@settings(max_examples=25, **HYPOTHESIS)
@given(data=st.data())
def test_every_command_round_trips(command, data):
    args = data.draw(ARGS[command])
    command_seq = data.draw(st.integers(0, 0xFFFF))
    message = protocol.decode(protocol.encode_command(9, command, command_seq, **args))
    assert message.name == "COMMAND" and message.fields["command"] == protocol.COMMAND_IDS[command]
    assert protocol.decode_command(message) == protocol.Command(command, command_seq, args)


def test_inject_sample_arguments_are_a_sample_payload():
    sample = dict(timestamp_us=5, index=6, gyr=(1, 2, 3), acc=(4, 5, 6), mag=(7, 8, 9), temperature=10)
    inject = protocol.decode(protocol.encode_command(0, "INJECT_SAMPLE", 1, **sample))
    assert inject.fields["args"] == cobs.decode(protocol.encode("SAMPLE", 0, **sample)[:-1])[3:-4]


def test_bad_commands_carry_the_nack_reason():
    unknown = protocol.decode(protocol.encode("COMMAND", 0, command=200, command_seq=1, args=b""))
    with pytest.raises(protocol.CommandError, match="UNKNOWN_COMMAND") as info:
        protocol.decode_command(unknown)
    assert info.value.reason == "UNKNOWN_COMMAND" and info.value.reason in protocol.REASONS
    short = protocol.decode(protocol.encode("COMMAND", 0, command=protocol.COMMAND_IDS["SET_SETTING"],
                                            command_seq=1, args=b"\x01\x02"))
    with pytest.raises(protocol.CommandError, match="SET_SETTING takes 5 argument bytes, got 2") as info:
        protocol.decode_command(short)
    assert info.value.reason == "BAD_LENGTH"
    with pytest.raises(ValueError, match="unknown command 'FLY'"):
        protocol.encode_command(0, "FLY", 1)
    with pytest.raises(ValueError, match="SELECT_FILTER: missing fields"):
        protocol.encode_command(0, "SELECT_FILTER", 1)


# --------------------------------------------------------------------------- HELLO / schema hash


def _hello(**overrides) -> dict:
    fields = dict(firmware_major=1, firmware_minor=2, firmware_patch=3, protocol_version=protocol.PROTOCOL_VERSION,
                  schema_hash=protocol.SCHEMA_HASH, board="qemu-netduino", filters=0b1110, gyro_scale=1, acc_scale=2,
                  mag_scale=3)
    fields.update(overrides)
    return protocol.decode(protocol.encode("HELLO", 0, **fields)).fields


def test_check_hello_accepts_the_same_schema():
    assert protocol.check_hello(_hello()) is None


def test_check_hello_names_both_hashes():
    other = protocol.SCHEMA_HASH ^ 0x00010000
    with pytest.raises(protocol.ProtocolMismatch) as info:
        protocol.check_hello(_hello(schema_hash=other))
    text = str(info.value)
    assert f"0x{other:08X}" in text and f"0x{protocol.SCHEMA_HASH:08X}" in text
    assert "qemu-netduino" in text and "1.2.3" in text and "shared/protocol.toml" in text


def test_check_hello_refuses_another_protocol_version():
    with pytest.raises(protocol.ProtocolMismatch, match=f"speaks protocol v{protocol.PROTOCOL_VERSION + 1}"):
        protocol.check_hello(_hello(protocol_version=protocol.PROTOCOL_VERSION + 1))


# --------------------------------------------------------------------------- stream decoding


@settings(max_examples=300, **HYPOTHESIS)
@given(garbage=st.binary(max_size=3000), seed=st.integers(0, 2**32 - 1))
def test_random_garbage_is_counted_and_never_accepted(garbage, seed):
    data = garbage + b"\0"
    decoder = protocol.FrameDecoder()
    assert feed_all(decoder, data, random.Random(seed)) == []
    assert decoder.frames == 0
    assert decoder.crc_errors + decoder.resyncs == nonempty_spans(data)
    assert decoder.bytes == len(data)


# Damage applied to a byte stream. Each function changes `data` (a bytearray) in place
# at `pos`, using `value` (0..255) as its parameter, keeps `owners` in step (owners[i]:
# index of the sent frame byte i belongs to, None for inserted bytes) and returns the
# frames it may have damaged: a superset, never fewer.


def _touch(owners, pos):
    """Frames damaged by changing byte `pos`: its frame, and the next one too when the
    byte is a delimiter (the two frames merge)."""
    frame = owners[pos]
    is_last_byte = pos + 1 == len(owners) or owners[pos + 1] != frame
    return {frame, frame + 1} if is_last_byte else {frame}


def _flip_bits(data, owners, pos, value):
    data[pos] ^= value or 1
    return _touch(owners, pos)


def _drop_byte(data, owners, pos, value):
    touched = _touch(owners, pos)
    del data[pos], owners[pos]
    return touched


def _duplicate_byte(data, owners, pos, value):
    data.insert(pos, data[pos])
    owners.insert(pos, owners[pos])
    return {owners[pos]}


def _insert_garbage(data, owners, pos, value):
    """Random bytes (zeros included) before byte `pos`."""
    touched = {owners[pos]}
    run = random.Random(value).randbytes(1 + value % 40)
    data[pos:pos] = run
    owners[pos:pos] = [None] * len(run)
    return touched


def _truncate_frame(data, owners, pos, value):
    """Cut a frame's end off, keeping its delimiter."""
    frame = owners[pos]
    end = max(i for i, o in enumerate(owners) if o == frame)  # its delimiter
    if data[end] != 0 or end - pos < 1:
        return set()
    del data[pos:end], owners[pos:end]
    return {frame}


def _overwrite_code_byte(data, owners, pos, value):
    """Replace the first COBS code byte of the frame at `pos` (a corrupted length)."""
    frame = owners[pos]
    first = owners.index(frame)
    if data[first] == 0:
        return set()
    data[first] = value or 0xFF
    return _touch(owners, first)


def _zero_byte(data, owners, pos, value):
    """A spurious delimiter inside a frame."""
    data[pos] = 0
    return {owners[pos]}


DAMAGE = [_flip_bits, _drop_byte, _duplicate_byte, _insert_garbage, _truncate_frame, _overwrite_code_byte,
          _zero_byte]


def random_damaged_stream(rnd: random.Random, frames: tuple[int, int], max_damages: int) -> tuple[list, bytes, set]:
    """A random run of numbered frames (between frames[0] and frames[1] of them) and the
    same stream with up to max_damages random damages: (sent, damaged bytes, touched)."""
    named = [(name, random_fields(schema.MESSAGES[name]["fields"], rnd))
             for name in rnd.choices(MESSAGE_NAMES, k=rnd.randint(*frames))]
    sent = number_frames(named, {d: rnd.randint(0, 0xFFFF) for d in protocol.DIRECTIONS})
    damages = [(rnd.choice(DAMAGE), rnd.random(), rnd.randint(0, 255)) for _ in range(rnd.randint(0, max_damages))]
    data, touched = damage_stream(sent, damages)
    return sent, data, touched


def damage_stream(sent: list, damages) -> tuple[bytes, set]:
    """The sent frames' bytes after `damages`, a list of (DAMAGE function, relative
    position in [0, 1), value 0..255); and the indices of the frames they may have damaged."""
    data = bytearray(b"".join(wire for *_, wire in sent))
    owners = [k for k, (*_, wire) in enumerate(sent) for _ in wire]
    touched = set()
    for damage, where, value in damages:
        if not data:
            break
        pos = int(where * len(data))
        if owners[pos] is None:
            continue  # inside earlier damage: keep the bookkeeping simple
        touched |= damage(data, owners, pos, value)
    return bytes(data), touched


@st.composite
def damaged_streams(draw):
    """(sent frames, damaged stream bytes, indices of the frames that may be damaged)."""
    sent = draw(sent_streams())
    damages = draw(st.lists(st.tuples(st.sampled_from(DAMAGE), st.floats(0, 1, exclude_max=True),
                                      st.integers(0, 255)), max_size=6))
    return (sent, *damage_stream(sent, damages))


def check_damaged_stream(sent: list, data: bytes, touched: set, rnd: random.Random) -> list:
    """Decode `data` whole and in random chunks and check every promise of the decoder
    (module docstring); returns the decoded messages."""
    wires = [wire for *_, wire in sent]
    whole = protocol.FrameDecoder()
    received = feed_all(whole, data)
    chunked_decoder = protocol.FrameDecoder()
    assert feed_all(chunked_decoder, data, rnd) == received, "chunking changed the result"
    assert chunked_decoder.counters() == whole.counters()

    # every decoded frame is byte-identical to a sent frame, in sending order, never twice
    indices = [wires.index(wire_of(m)) for m in received]
    assert indices == sorted(set(indices))
    # every undamaged frame is decoded (resync at the next delimiter)
    assert set(range(len(sent))) - touched <= set(indices)
    # every span was counted exactly once
    assert whole.frames + whole.crc_errors + whole.resyncs == nonempty_spans(data)
    # lost frames: exactly those missing between the first and the last received frame
    assert whole.lost == _lost_by_direction(sent, indices)
    return received


@settings(max_examples=1500, **HYPOTHESIS, suppress_health_check=[HealthCheck.too_slow])
@given(stream=damaged_streams(), seed=st.integers(0, 2**32 - 1))
def test_damaged_streams_resync_and_never_accept_a_corrupted_frame(stream, seed):
    check_damaged_stream(*stream, random.Random(seed))


@pytest.mark.parametrize("seed", range(8))
def test_long_damaged_streams(seed):
    """Soak: long streams (about 100 frames each) with up to 30 damages, from a seeded
    generator (hypothesis keeps its streams short)."""
    rnd = random.Random(seed)
    for _ in range(150):
        check_damaged_stream(*random_damaged_stream(rnd, frames=(50, 150), max_damages=30), rnd)


def _lost_by_direction(sent, indices) -> dict:
    """Per direction, the sent frames missing between the first and the last received one."""
    lost = {}
    for direction in protocol.DIRECTIONS:
        mine = [i for i in range(len(sent)) if schema.MESSAGES[sent[i][0]]["direction"] == direction]
        got = [i for i in indices if i in mine]
        lost[direction] = sum(1 for i in mine if got and got[0] <= i <= got[-1]) - len(got)
    return lost


@pytest.mark.parametrize("damage", DAMAGE, ids=lambda f: f.__name__)
def test_each_damage_breaks_only_the_frame_it_claims(damage):
    """The bookkeeping the property test relies on: the damaged frame is rejected, its
    neighbours are decoded."""
    sent = [protocol.encode("ACK", k, command_seq=k, command=1, reason=0) for k in range(3)]
    data = bytearray(b"".join(sent))
    owners = [k for k, wire in enumerate(sent) for _ in wire]
    assert damage(data, owners, len(sent[0]) + 2, 0x41) == {1}  # a byte inside frame 1
    assert [wire_of(m) for m in protocol.FrameDecoder().feed(bytes(data))] == [sent[0], sent[2]]


@settings(max_examples=300, **HYPOTHESIS)
@given(frames=st.lists(st.tuples(messages([n for n in MESSAGE_NAMES if n != "HELLO"]), st.booleans()),
                       min_size=1, max_size=60),
       starts=st.tuples(st.integers(0, 0xFFFF), st.integers(0xFFF0, 0xFFFF)))
def test_lost_frames_are_counted_per_direction(frames, starts):
    """Frames of both directions interleaved, each direction with its own sequence (one
    wrapping at 65535), some never delivered: lost counts them exactly, per direction.
    (No HELLO: one with seq 0 announces a restart, tested below.)"""
    next_seq = dict(zip(protocol.DIRECTIONS, starts))
    delivered, expected = bytearray(), {d: [] for d in protocol.DIRECTIONS}
    for (name, fields), deliver in frames:
        direction = schema.MESSAGES[name]["direction"]
        seq = next_seq[direction]
        next_seq[direction] = (seq + 1) & 0xFFFF
        expected[direction].append(deliver)
        if deliver:
            delivered += protocol.encode(name, seq, **fields)
    decoder = protocol.FrameDecoder()
    feed_all(decoder, bytes(delivered))
    for direction, flags in expected.items():
        got = [i for i, deliver in enumerate(flags) if deliver]
        missing = got[-1] - got[0] + 1 - len(got) if got else 0
        assert decoder.lost[direction] == missing
    assert decoder.sequence_restarts == 0 and decoder.frames == sum(map(sum, expected.values()))


def test_sequence_restarts_are_not_losses():
    def ack(seq):
        return protocol.encode("ACK", seq, command_seq=0, command=7, reason=0)

    hello = _hello_wire(seq=0)
    decoder = protocol.FrameDecoder()
    decoder.feed(ack(40000) + ack(40001) + hello + ack(1) + ack(1) + ack(5))
    # 40001 -> HELLO seq 0: the board restarted; 1 -> 1: a duplicate; 1 -> 5: three lost
    assert decoder.sequence_restarts == 2
    assert decoder.lost == {"to_host": 3, "to_board": 0}
    assert decoder.frames == 6


def _hello_wire(seq: int) -> bytes:
    return protocol.encode("HELLO", seq, firmware_major=0, firmware_minor=1, firmware_patch=0,
                           protocol_version=protocol.PROTOCOL_VERSION, schema_hash=protocol.SCHEMA_HASH,
                           board="emulator", filters=14, gyro_scale=1, acc_scale=2, mag_scale=3)


def test_an_endless_span_is_dropped_once_and_memory_stays_bounded():
    decoder = protocol.FrameDecoder()
    good = protocol.encode("ACK", 3, command_seq=1, command=2, reason=0)
    for _ in range(1000):
        assert decoder.feed(b"\x01" * 1000) == []
    assert decoder.resyncs == 0, "a span is judged at its delimiter"
    assert decoder.feed(b"\x02\x03\0" + good) == [protocol.decode(good)]
    assert decoder.resyncs == 1 and decoder.crc_errors == 0 and decoder.bytes == 10**6 + 3 + len(good)
    assert len(decoder._partial) <= protocol.MAX_ENCODED, "the decoder holds at most one frame's bytes"


def test_consecutive_delimiters_are_not_errors():
    decoder = protocol.FrameDecoder()
    good = protocol.encode("ACK", 3, command_seq=1, command=2, reason=0)
    assert len(decoder.feed(b"\0\0" + good + b"\0\0\0" + good)) == 2
    assert decoder.counters()["resyncs"] == 0 and decoder.crc_errors == 0


# --------------------------------------------------------------------------- generator


def _load_generator():
    """tools/gen_protocol.py as a module (registered first: its dataclasses look themselves up)."""
    if "gen_protocol" not in sys.modules:
        spec = importlib.util.spec_from_file_location("gen_protocol", GENERATOR)
        sys.modules["gen_protocol"] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules["gen_protocol"])
    return sys.modules["gen_protocol"]


def _run_generator(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(GENERATOR), *map(str, args)], capture_output=True, text=True,
                          timeout=60)


def test_generated_files_are_up_to_date():
    proc = _run_generator("--check")
    assert proc.returncode == 0, f"stale generated protocol files:\n{proc.stderr}"


@pytest.fixture
def project_copy(tmp_path):
    """The generator's inputs and outputs, copied into a scratch project root."""
    gen = _load_generator()
    for rel in (gen.DEFINITION, gen.C_HEADER, gen.C_SOURCE, gen.PY_SCHEMA, gen.DOCS):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp_path / rel)
    return tmp_path


def test_check_names_every_stale_file(project_copy):
    toml = project_copy / "shared" / "protocol.toml"
    toml.write_text(toml.read_text().replace(
        '{ name = "injection_mode", type = "u8",',
        '{ name = "battery_mv", type = "u16", doc = "supply voltage" },\n    { name = "injection_mode", type = "u8",'))
    proc = _run_generator("--check", "--root", project_copy)
    assert proc.returncode == 1
    for name in ("imu_proto_gen.h", "imu_proto_gen.c", "_schema.py", "protocol.md"):
        assert name in proc.stderr, proc.stderr
    assert _run_generator("--root", project_copy).returncode == 0
    assert _run_generator("--check", "--root", project_copy).returncode == 0
    assert "battery_mv" in (project_copy / "host" / "imulink" / "protocol" / "_schema.py").read_text()


def test_a_hand_edit_of_a_generated_file_is_stale(project_copy):
    header = project_copy / "firmware" / "core" / "imu_proto_gen.h"
    header.write_text(header.read_text().replace("IMU_PROTO_MSG_SAMPLE = 16", "IMU_PROTO_MSG_SAMPLE = 18"))
    proc = _run_generator("--check", "--root", project_copy)
    assert proc.returncode == 1 and "imu_proto_gen.h" in proc.stderr and "imu_proto_gen.c" not in proc.stderr


def test_generated_c_is_in_files_of_its_own():
    """No generated section inside a hand-written file: the generated C is whole files,
    which the hand-written codec includes."""
    gen = _load_generator()
    firmware = [p for p in (ROOT / "firmware").rglob("*.[ch]") if "build" not in p.relative_to(ROOT).parts]
    marked = [str(p.relative_to(ROOT)) for p in firmware if "BEGIN GENERATED" in p.read_text()]
    assert marked == []
    for rel in (gen.C_HEADER, gen.C_SOURCE):
        assert gen.GENERATED_NOTE in (ROOT / rel).read_text()
    assert '#include "imu_proto_gen.h"' in (ROOT / "firmware" / "core" / "imu_proto.h").read_text()


def test_formats_and_flags_are_generated_but_not_hashed(project_copy):
    """A field's format or a command's flag is in the generated code (so a change makes it
    stale) but not in the schema hash (no byte on the wire changes)."""
    toml = project_copy / "shared" / "protocol.toml"
    original = toml.read_text()
    for old, new, wanted in (
            ('{ name = "euler", type = "i32[3]", q = 29,', '{ name = "euler", type = "i32[3]", q = 28,',
             "IMU_PROTO_ESTIMATE_EULER_FRAC_BITS 28"),
            ('nacks = ["BAD_LENGTH", "NOT_SUPPORTED"]\nrestarts_filter = false\nidempotent = true',
             'nacks = ["BAD_LENGTH", "NOT_SUPPORTED"]\nrestarts_filter = false\nidempotent = false',
             "IMU_PROTO_CMD_ENTER_BOOTLOADER_FLAGS (0u)")):
        assert old in original
        toml.write_text(original.replace(old, new))
        proc = _run_generator("--check", "--root", project_copy)
        assert proc.returncode == 1 and "imu_proto_gen.h" in proc.stderr and "_schema.py" in proc.stderr
        assert _run_generator("--root", project_copy).returncode == 0
        assert wanted in (project_copy / "firmware" / "core" / "imu_proto_gen.h").read_text()
        assert f"SCHEMA_HASH = 0x{schema.SCHEMA_HASH:08X}" in (project_copy / "host" / "imulink" / "protocol" /
                                                                "_schema.py").read_text()


def test_schema_formats_and_flags():
    """What the host derives from the schema: the Q formats it used to spell out, and the
    command sets it used to list by hand."""
    assert protocol.frac_bits("ESTIMATE", "quat") == 30 and protocol.frac_bits("ESTIMATE", "euler") == 29
    assert protocol.frac_bits("ESTIMATE", "gyro_bias") == 24 and protocol.frac_bits("ESTIMATE", "weights") == 30
    assert protocol.field_format("NAV_STATE", "lat") == (29, 2.0**-29, "rad")
    assert protocol.field_format("NAV_STATE", "vel") == (20, 2.0**-20, "m/s")
    assert protocol.field_format("GNSS", "lat_1e7deg") == (None, 1e-7, "deg")
    assert [protocol.frac_bits("HELLO", f) for f in ("gyro_scale", "acc_scale", "mag_scale")] == [40, 32, 24]
    assert protocol.arg_format("SET_CALIBRATION", "offset").frac_bits == 8
    assert protocol.arg_format("SET_CALIBRATION", "row").frac_bits == 24
    assert protocol.RESTARTING_COMMANDS == {"SELECT_FILTER", "SET_SETTING", "SET_INJECTION_MODE", "RESET",
                                            "SET_CALIBRATION"}
    assert protocol.NOT_IDEMPOTENT_COMMANDS == {"INJECT_SAMPLE", "RESET"}
    assert protocol.REPLY_MESSAGES == {"GET_VERSION": "HELLO", "GET_STATUS": "STATUS", "GET_SETTING": "SETTING",
                                       "GET_CALIBRATION": "CALIBRATION", "INJECT_SAMPLE": "ESTIMATE",
                                       "RESEND": "RESENT", "GET_CHECKPOINT": "CHECKPOINT"}
    with pytest.raises(ValueError, match="no format"):
        protocol.field_format("ESTIMATE", "index")
    with pytest.raises(ValueError, match="decimal scale"):
        protocol.frac_bits("GNSS", "lat_1e7deg")


def test_schema_hash_covers_layout_not_documentation(project_copy):
    gen = _load_generator()
    toml = project_copy / "shared" / "protocol.toml"
    original = toml.read_text()
    assert gen.schema_hash(gen.load_schema(toml)) == schema.SCHEMA_HASH == protocol.SCHEMA_HASH
    toml.write_text(original.replace("board time when the sample was read", "when the sample was taken"))
    assert gen.schema_hash(gen.load_schema(toml)) == schema.SCHEMA_HASH
    for edit in (('name = "temperature", type = "i16"', 'name = "temperature", type = "u16"'),
                 ("id = 0x11", "id = 0x1F"),
                 ('{ name = "BUSY", value = 5', '{ name = "BUSY", value = 15')):
        assert edit[0] in original
        toml.write_text(original.replace(*edit))
        assert gen.schema_hash(gen.load_schema(toml)) != schema.SCHEMA_HASH, edit


_LOG_FIELDS = """fields = [
    { name = "level", type = "u8", enum = "log_level", doc = "severity" },
    { name = "text", type = "text[200]", doc = "message, UTF-8, no terminator" },
]"""


@pytest.mark.parametrize("old,new,message", [
    ("id = 0x11", "id = 0x10", "duplicate id 16"),
    ('type = "i16[3]"', 'type = "f32[3]"', "unknown type 'f32[3]'"),
    (_LOG_FIELDS, "fields = []", "a message needs at least one field"),
    ('type = "text[200]"', 'type = "text[300]"', "at most 255 bytes"),
    ('type = "bytes[28]"', 'type = "bytes[20]"', "INJECT_SAMPLE needs 28"),
    ('nacks = ["BAD_LENGTH", "UNKNOWN_FILTER"]', 'nacks = ["TOO_LATE"]', "are not reason codes"),
    ('[[message]]\nname = "STATUS"', '[[message]]\nname = "REASON"', "clash with C type names"),
    ('args_like = "SAMPLE"', 'args_like = "SAMPLES"', "args_like 'SAMPLES' is not a message"),
    ('reply = "SETTING, then ACK"', 'reply = "SETTINGS, then ACK"', "reply starts with ACK or with the message"),
    ('type = "i32[4]", q = 30,', 'type = "i32[4]", q = 30, scale = 0.5,', "give q (a Q format) or scale"),
    ('type = "i32[4]", q = 30,', 'type = "i32[4]", q = 70,', "q is the number of fraction bits"),
    ('type = "i32[4]", q = 30,', 'type = "i32[4]", q = "30",', "q is the number of fraction bits"),
    ('type = "char[16]",', 'type = "char[16]", unit = "m",', "belong to integer fields"),
    ('scale = 1e-7,', 'scale = -1e-7,', "scale is a positive number"),
    ('nacks = ["BAD_LENGTH", "UNKNOWN_FILTER"]\nrestarts_filter = true',
     'nacks = ["BAD_LENGTH", "UNKNOWN_FILTER"]', "missing restarts_filter"),
    ('nacks = ["BAD_LENGTH", "UNKNOWN_FILTER"]\nrestarts_filter = true',
     'nacks = ["BAD_LENGTH", "UNKNOWN_FILTER"]\nrestarts_filter = 1', "restarts_filter is true or false"),
])
def test_generator_rejects_a_broken_definition(project_copy, old, new, message):
    toml = project_copy / "shared" / "protocol.toml"
    text = toml.read_text()
    assert old in text
    toml.write_text(text.replace(old, new))
    proc = _run_generator("--check", "--root", project_copy)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
