"""The frame protocol on the host: encode and decode frames, decode byte streams.

A frame on the wire is ``COBS(msg_id u8 | seq u16 | payload | crc u32) 0x00``, all
little-endian; crc is CRC-32/ISO-HDLC (zlib.crc32) over msg_id, seq and payload.
Messages, their fields, the commands and the code tables come from
shared/protocol.toml through the generated module ``imulink.protocol._schema``; see
docs/protocol.md for the format and the message tables.

- :func:`encode` / :func:`decode`: one message to wire bytes and back.
- :class:`FrameDecoder`: feed it received bytes in chunks of any size; it returns the
  complete messages and keeps the link counters (frames, bytes, CRC errors, resyncs,
  lost frames per direction).
- :func:`encode_command` / :func:`decode_command`: COMMAND frames with their typed
  arguments; :class:`CommandError` carries the NACK reason for bad input.
- :func:`check_hello`: refuse a board built from another protocol definition.

Decoded fields are plain Python values: ints, tuples of ints for arrays, str for
char/text fields, bytes for bytes fields. COBS goes through the ``cobs`` package
(a C extension; about 20x faster than a Python loop on these frames).
"""
from __future__ import annotations

import struct
import zlib
from typing import NamedTuple

from cobs import cobs

from imulink.errors import ImulinkError
from imulink.protocol import _schema as _schema

PROTOCOL_VERSION: int = _schema.PROTOCOL_VERSION
SCHEMA_HASH: int = _schema.SCHEMA_HASH
#: Schema hashes whose recordings this host decodes: its own and the earlier definitions it only
#: adds to (messages, commands, codes; shared/protocol.toml [protocol] earlier_hashes).
READABLE_SCHEMA_HASHES: frozenset[int] = frozenset((SCHEMA_HASH, *_schema.EARLIER_SCHEMA_HASHES))
DIRECTIONS = ("to_host", "to_board")
HEADER_SIZE: int = _schema.HEADER_SIZE
CRC_SIZE: int = _schema.CRC_SIZE
MIN_FRAME = HEADER_SIZE + CRC_SIZE
#: Largest frame of the schema before COBS, and its largest COBS encoding (without the delimiter).
MAX_FRAME = HEADER_SIZE + _schema.MAX_PAYLOAD + CRC_SIZE
MAX_ENCODED = MAX_FRAME + max(1, -(-MAX_FRAME // 254))

MESSAGE_IDS: dict[str, int] = {name: spec["id"] for name, spec in _schema.MESSAGES.items()}
COMMAND_IDS: dict[str, int] = {name: spec["id"] for name, spec in _schema.COMMANDS.items()}
FILTER_IDS: dict[str, int] = dict(_schema.ENUMS["filter"])
REASONS: dict[str, int] = dict(_schema.ENUMS["reason"])
LOG_LEVELS: dict[str, int] = dict(_schema.ENUMS["log_level"])
SENSORS: dict[str, int] = dict(_schema.ENUMS["sensor"])
#: Commands after which a board's active filter starts again from sample index 0 (their
#: restarts_filter flag in shared/protocol.toml; firmware/app/app.c does it).
RESTARTING_COMMANDS = frozenset(name for name, spec in _schema.COMMANDS.items() if spec["restarts_filter"])
#: Commands that must not be sent twice for one request (no idempotent flag in the schema):
#: a host does not resend them when their ACK is late.
NOT_IDEMPOTENT_COMMANDS = frozenset(name for name, spec in _schema.COMMANDS.items() if not spec["idempotent"])
#: command name -> the data message the board sends before its ACK, for the commands that ask for one.
REPLY_MESSAGES: dict[str, str] = {name: spec["reply"] for name, spec in _schema.COMMANDS.items() if spec["reply"]}

#: zlib.crc32 of any bytes followed by their own CRC-32 (little-endian): checking a whole
#: frame against this constant is the same as comparing its CRC field with the CRC of the rest.
_CRC_RESIDUE = 0x2144DF1C

_INT_FORMATS = {"u8": "B", "i8": "b", "u16": "H", "i16": "h", "u32": "I", "i32": "i"}
_INT_RANGES = {"u8": (0, 0xFF), "i8": (-0x80, 0x7F), "u16": (0, 0xFFFF), "i16": (-0x8000, 0x7FFF),
               "u32": (0, 0xFFFFFFFF), "i32": (-0x80000000, 0x7FFFFFFF)}
_VARIABLE_TYPES = ("text", "bytes")


class ProtocolError(ImulinkError, ValueError):
    """Something on the link does not follow the protocol."""


class FrameError(ProtocolError):
    """Bytes that are not a valid frame of this schema (bad COBS, length or id)."""


class CrcError(FrameError):
    """A well-formed frame whose CRC does not match its contents."""


class ProtocolMismatch(ProtocolError):
    """The board was built from another protocol definition than this host."""


class CommandError(ProtocolError):
    """A COMMAND the board must refuse; `reason` is the NACK reason name (see REASONS)."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


class FieldFormat(NamedTuple):
    """How a field's raw integer becomes a real value: raw * scale, in unit. frac_bits is
    its Q format (scale = 2^-frac_bits; 0 for an integer in its unit, None for a decimal
    scale such as 1e-7 deg)."""

    frac_bits: int | None
    scale: float
    unit: str | None


class Message(NamedTuple):
    """A decoded frame: message name, sequence number, and field name -> value."""

    name: str
    seq: int
    fields: dict


class Command(NamedTuple):
    """The arguments of a received COMMAND."""

    name: str
    command_seq: int
    args: dict


def _decode_utf8(raw: bytes) -> str:
    return raw.decode("utf-8", "replace")


def _decode_padded(raw: bytes) -> str:
    """A char[N] field: UTF-8 up to the first NUL."""
    return raw.partition(b"\0")[0].decode("utf-8", "replace")


class _Layout:
    """A field list compiled for speed: one struct.Struct for the fixed-size fields
    (after `prefix`, e.g. the frame header), a generated function that turns the
    unpacked tuple into the field dict, and the packer for the other direction."""

    def __init__(self, fields: tuple, prefix: str = "", message_name: str | None = None):
        self.variable = fields[-1] if fields and fields[-1][1] in _VARIABLE_TYPES else None
        self.fixed_fields = fields[:-1] if self.variable else fields
        fmt = "".join(self._format(base, length) for _, base, length in self.fixed_fields)
        self.struct = struct.Struct("<" + prefix + fmt)
        self.payload_size = self.struct.size - struct.calcsize("<" + prefix)  # the fixed-size fields
        self.names = {name for name, _, _ in fields}
        self.build = self._compile_builder(len(prefix), message_name)

    @staticmethod
    def _format(base: str, length: int | None) -> str:
        if base == "char":
            return f"{length}s"
        return _INT_FORMATS[base] if length is None else f"{length}{_INT_FORMATS[base]}"

    def _compile_builder(self, skip: int, message_name: str | None):
        """build(values, tail) -> the field dict, or with `message_name` the Message
        (its seq is values[1]): `values` from self.struct.unpack, `tail` the variable
        field's bytes. Generated source, so that decoding is one dict display."""
        items, i = [], skip
        for name, base, length in self.fixed_fields:
            if base == "char":
                items.append(f"{name!r}: _decode_padded(v[{i}])")
                i += 1
            elif length is None:
                items.append(f"{name!r}: v[{i}]")
                i += 1
            else:
                items.append(f"{name!r}: v[{i}:{i + length}]")
                i += length
        if self.variable:
            name, base, _ = self.variable
            items.append(f"{name!r}: _decode_utf8(tail)" if base == "text" else f"{name!r}: tail")
        result = f"{{{', '.join(items)}}}"
        if message_name is not None:
            result = f"_new(Message, ({message_name!r}, v[1], {result}))"
        namespace = {"_decode_padded": _decode_padded, "_decode_utf8": _decode_utf8, "_new": tuple.__new__,
                     "Message": Message}
        exec(f"def build(v, tail):\n    return {result}\n", namespace)
        return namespace["build"]

    def pack(self, what: str, values: dict, *prefix) -> bytes:
        """`prefix` values then the fields in `values`, packed; ValueError names a bad field."""
        if values.keys() != self.names:
            problems = []
            if self.names - values.keys():
                problems.append(f"missing fields {sorted(self.names - values.keys())}")
            if values.keys() - self.names:
                problems.append(f"unknown fields {sorted(values.keys() - self.names)}")
            raise ValueError(f"{what}: {'; '.join(problems)}")
        flat = list(prefix)
        for name, base, length in self.fixed_fields:
            value = values[name]
            if base == "char":
                flat.append(self._char_bytes(what, name, value, length))
            elif length is None:
                flat.append(value)
            else:
                if len(value) != length:
                    raise ValueError(f"{what}.{name}: needs {length} values, got {len(value)}")
                flat.extend(value)
        try:
            packed = self.struct.pack(*flat)
        except struct.error:
            self._raise_range_error(what, values)
            raise
        if self.variable:
            packed += self._variable_bytes(what, values[self.variable[0]])
        return packed

    @staticmethod
    def _char_bytes(what: str, name: str, value, length: int) -> bytes:
        raw = value.encode("utf-8") if isinstance(value, str) else bytes(value)
        if len(raw) > length or b"\0" in raw:
            raise ValueError(f"{what}.{name}: at most {length} UTF-8 bytes without NUL, got {raw!r}")
        return raw

    def _variable_bytes(self, what: str, value) -> bytes:
        assert self.variable is not None  # pack calls this only for a layout with a variable field
        name, base, length = self.variable
        raw = value.encode("utf-8") if base == "text" else bytes(value)
        if len(raw) > length:
            raise ValueError(f"{what}.{name}: at most {length} bytes, got {len(raw)}")
        return raw

    def _raise_range_error(self, what: str, values: dict) -> None:
        for name, base, length in self.fixed_fields:
            if base == "char":
                continue
            low, high = _INT_RANGES[base]
            for item in (values[name],) if length is None else values[name]:
                if isinstance(item, bool) or not hasattr(item, "__index__") or not low <= item <= high:
                    raise ValueError(f"{what}.{name}: {item!r} is not a {base} integer ({low}..{high})")

    def unpack(self, data: bytes) -> dict:
        """Fields of a buffer that holds exactly this layout (no prefix); caller checks the length."""
        return self.build(self.struct.unpack_from(data), data[self.payload_size:])


class _MessageCodec:
    """Everything needed to encode and decode one message type."""

    def __init__(self, name: str, spec: dict):
        self.name = name
        self.id = spec["id"]
        self.direction = spec["direction"]
        self.layout = _Layout(spec["fields"], prefix="BH", message_name=name)
        self.struct = self.layout.struct
        self.build = self.layout.build
        self.has_tail = self.layout.variable is not None
        self.min_frame = self.struct.size + CRC_SIZE
        self.max_frame = self.min_frame + (self.layout.variable[2] if self.layout.variable is not None else 0)

    def frame(self, seq: int, fields: dict) -> bytes:
        """msg_id, seq, payload and CRC (before COBS)."""
        if not 0 <= seq <= 0xFFFF:
            raise ValueError(f"{self.name}: seq {seq!r} is not a u16")
        body = self.layout.pack(self.name, fields, self.id, seq)
        return body + zlib.crc32(body).to_bytes(CRC_SIZE, "little")

    def message(self, frame: bytes) -> Message:
        """The message of a frame whose CRC and length were checked."""
        tail = frame[self.struct.size:-CRC_SIZE] if self.has_tail else None
        return self.build(self.struct.unpack_from(frame), tail)


_CODECS = {name: _MessageCodec(name, spec) for name, spec in _schema.MESSAGES.items()}
_CODEC_BY_ID = {codec.id: codec for codec in _CODECS.values()}
_COMMAND_LAYOUTS = {name: _Layout(spec["args"]) for name, spec in _schema.COMMANDS.items()}
_COMMAND_BY_ID = {spec["id"]: name for name, spec in _schema.COMMANDS.items()}
_DIRECTIONS = {name: codec.direction for name, codec in _CODECS.items()}


def _codec(name: str) -> _MessageCodec:
    try:
        return _CODECS[name]
    except KeyError:
        raise ValueError(f"unknown message {name!r}; messages: {', '.join(_CODECS)}") from None


def message_fields(name: str) -> tuple[tuple[str, str, int | None], ...]:
    """A message's fields as the schema declares them: (name, type, array length or None)."""
    _codec(name)  # ProtocolError for an unknown message
    return _schema.MESSAGES[name]["fields"]


def _format(formats: dict, owner: str, kind: str, field: str) -> FieldFormat:
    try:
        return FieldFormat(*formats[owner][field])
    except KeyError:
        raise ValueError(f"{kind} {owner}'s field {field!r} has no format in the schema "
                         "(no q, scale or unit in shared/protocol.toml)") from None


def field_format(message: str, field: str) -> FieldFormat:
    """The Q format or scale and the unit of a message field (shared/protocol.toml)."""
    return _format(_schema.FIELD_FORMATS, message, "message", field)


def arg_format(command: str, field: str) -> FieldFormat:
    """The Q format or scale and the unit of a command argument (shared/protocol.toml)."""
    return _format(_schema.ARG_FORMATS, command, "command", field)


def _q(owner: str, field: str, found: FieldFormat) -> int:
    if found.frac_bits is None:
        raise ValueError(f"{owner}.{field} has a decimal scale, not a Q format")
    return found.frac_bits


def frac_bits(message: str, field: str) -> int:
    """The Q format of a message field: its real value is raw * 2^-frac_bits."""
    return _q(message, field, field_format(message, field))


def arg_frac_bits(command: str, field: str) -> int:
    """The Q format of a command argument: its real value is raw * 2^-frac_bits."""
    return _q(command, field, arg_format(command, field))


def encode(name: str, seq: int, /, **fields) -> bytes:
    """Wire bytes of one frame (COBS-encoded, delimiter included).

    `seq` is the sender's frame counter for this direction (u16, wrapping). Every field
    of the message must be given: ints, sequences of ints for arrays, str (or bytes)
    for char and text fields, bytes for bytes fields. ValueError names a missing,
    unknown or out-of-range field.
    """
    return cobs.encode(_codec(name).frame(seq, fields)) + b"\0"


def _parse(span: bytes) -> Message:
    """Decode the bytes between two delimiters; FrameError / CrcError when they are no frame."""
    if len(span) > MAX_ENCODED:
        raise FrameError(f"{len(span)} bytes without a delimiter: longer than any frame")
    try:
        frame = cobs.decode(span)
    except cobs.DecodeError as exc:
        raise FrameError(f"not valid COBS: {exc}") from None
    if len(frame) < MIN_FRAME:
        raise FrameError(f"{len(frame)} bytes: shorter than the smallest frame")
    if zlib.crc32(frame) != _CRC_RESIDUE:
        raise CrcError("CRC mismatch")
    codec = _CODEC_BY_ID.get(frame[0])
    if codec is None:
        raise FrameError(f"unknown message id 0x{frame[0]:02X} (a peer with another schema?)")
    if not codec.min_frame <= len(frame) <= codec.max_frame:
        raise FrameError(f"{codec.name} frame of {len(frame)} bytes, expected "
                         f"{codec.min_frame}..{codec.max_frame}")
    return codec.message(frame)


def message_of_payload(msg_id: int, seq: int, payload: bytes) -> Message:
    """The message of a payload known to be whole (e.g. carried inside a RESENT frame, whose
    CRC covered it); FrameError for an unknown id or a length the message cannot have."""
    codec = _CODEC_BY_ID.get(msg_id)
    if codec is None:
        raise FrameError(f"unknown message id 0x{msg_id:02X}")
    frame = bytes((msg_id,)) + seq.to_bytes(2, "little") + bytes(payload) + bytes(CRC_SIZE)
    if not codec.min_frame <= len(frame) <= codec.max_frame:
        raise FrameError(f"{codec.name} payload of {len(payload)} bytes")
    return codec.message(frame)


def decode(wire: bytes) -> Message:
    """Decode one frame as :func:`encode` wrote it (the trailing delimiter may be left off).

    Raises FrameError (CrcError for a CRC mismatch) when the bytes are not exactly one valid frame.
    """
    span = bytes(wire)
    if span.endswith(b"\0"):
        span = span[:-1]
    if b"\0" in span:
        raise FrameError("a delimiter inside the frame: more than one frame, or a truncated one")
    return _parse(span)


class FrameDecoder:
    """Streaming decoder with the link counters.

    :meth:`feed` takes received bytes in chunks of any size and returns the messages
    completed by them. Any span between delimiters that is not a valid frame is
    dropped and counted; decoding resumes at the next delimiter. Counters:

    - ``bytes``: bytes fed; ``frames``: messages returned
    - ``crc_errors``: well-formed frames whose CRC did not match
    - ``resyncs``: other spans dropped (bad COBS, too short or long, unknown id, wrong
      length for the message): every dropped span counts once, here or in crc_errors
    - ``lost``: per direction ("to_host", "to_board"), frames missing from the sequence
      numbers between two received frames, whatever the cause (never sent on, or
      dropped here). Frames lost after the last received one are not yet known.
    - ``sequence_restarts``: the sequence went backwards (a duplicated or reordered
      frame, or a sender restart), or a HELLO with seq 0 announced a fresh start;
      no loss is counted for these.
    """

    def __init__(self):
        self.bytes = 0
        self.frames = 0
        self.crc_errors = 0
        self.resyncs = 0
        self.sequence_restarts = 0
        self.lost = {direction: 0 for direction in DIRECTIONS}
        self._next_seq: dict[str, int] = {}
        self._partial = b""
        self._discarding = False  # the current span outgrew any frame: drop it up to its delimiter

    @property
    def lost_frames(self) -> int:
        """Lost frames in both directions."""
        return sum(self.lost.values())

    def counters(self) -> dict:
        """A snapshot of the counters."""
        return {"bytes": self.bytes, "frames": self.frames, "crc_errors": self.crc_errors,
                "resyncs": self.resyncs, "lost_frames": self.lost_frames, "lost": dict(self.lost),
                "sequence_restarts": self.sequence_restarts}

    def feed(self, data: bytes) -> list[Message]:
        """Decode the frames that `data` completes (the rest is kept for the next call)."""
        self.bytes += len(data)
        spans = (self._partial + bytes(data)).split(b"\0")
        self._partial = spans.pop()
        if self._discarding and spans:
            spans[0] = b""  # the end of the overlong span
            self.resyncs += 1
            self._discarding = False
        if len(self._partial) > MAX_ENCODED:
            self._partial = b""
            self._discarding = True
        messages = []
        next_seq, lost = self._next_seq, self.lost
        for span in spans:
            if not span:
                continue  # two delimiters in a row
            try:
                message = _parse(span)
            except CrcError:
                self.crc_errors += 1
                continue
            except FrameError:
                self.resyncs += 1
                continue
            messages.append(message)
            # sequence accounting, inline: it runs for every frame (recovery._missed is the same rule)
            name, seq = message.name, message.seq
            direction = _DIRECTIONS[name]
            expected = next_seq.get(direction)
            if expected is not None:
                gap = (seq - expected) & 0xFFFF
                if gap >= 0x8000 or (seq == 0 and name == "HELLO"):
                    self.sequence_restarts += 1
                else:
                    lost[direction] += gap
            next_seq[direction] = (seq + 1) & 0xFFFF
        self.frames += len(messages)
        return messages


def encode_command(seq: int, command: str, command_seq: int, /, **args) -> bytes:
    """Wire bytes of a COMMAND frame: `command` by name, its arguments as keywords."""
    try:
        layout = _COMMAND_LAYOUTS[command]
    except KeyError:
        raise ValueError(f"unknown command {command!r}; commands: {', '.join(_COMMAND_LAYOUTS)}") from None
    return encode("COMMAND", seq, command=COMMAND_IDS[command], command_seq=command_seq,
                  args=layout.pack(command, args))


def decode_command(message: Message) -> Command:
    """The command and typed arguments of a decoded COMMAND message.

    Raises CommandError with reason UNKNOWN_COMMAND or BAD_LENGTH, as the board NACKs them.
    """
    if message.name != "COMMAND":
        raise ValueError(f"not a COMMAND message: {message.name}")
    fields = message.fields
    name = _COMMAND_BY_ID.get(fields["command"])
    if name is None:
        raise CommandError("UNKNOWN_COMMAND", f"command id {fields['command']} is not in this schema")
    layout, args = _COMMAND_LAYOUTS[name], fields["args"]
    if len(args) != layout.payload_size:
        raise CommandError("BAD_LENGTH", f"{name} takes {layout.payload_size} argument bytes, got {len(args)}")
    return Command(name, fields["command_seq"], layout.unpack(args))


def check_hello(fields: dict) -> None:
    """Raise ProtocolMismatch unless a HELLO's protocol version and schema hash are this host's."""
    theirs, version = fields["schema_hash"], fields["protocol_version"]
    if theirs == SCHEMA_HASH and version == PROTOCOL_VERSION:
        return
    firmware = f"{fields['firmware_major']}.{fields['firmware_minor']}.{fields['firmware_patch']}"
    raise ProtocolMismatch(
        f"protocol mismatch: board {fields['board']!r} (firmware {firmware}) speaks protocol v{version} with "
        f"schema hash 0x{theirs:08X}; this host speaks v{PROTOCOL_VERSION} with schema hash 0x{SCHEMA_HASH:08X}. "
        "Build the firmware and the host from the same shared/protocol.toml.")
