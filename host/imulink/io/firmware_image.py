"""Firmware images to flash: ELF, Intel HEX or raw binary, as memory segments, and the
identification block the firmware build places in every flashable image.

- ELF: the loadable program headers (PT_LOAD with file bytes), at their physical (load)
  addresses: code, constants and the initial values of .data, which the start-up code
  copies to RAM.
- Intel HEX: data records with extended linear / segment addresses; every checksum checked.
- raw binary: one segment at the address the user gives.

The identification block (firmware/app/identification.h) is found by its magic in any
format: the board and chip the image was built for, the firmware version, the protocol
version and schema hash its HELLO will report, the chip's device id and flash size.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from imulink.errors import ImulinkError
from imulink.io.files import FileError, read_regular_file

ID_MAGIC = b"IMULNKID"
_ID_LAYOUT = struct.Struct("<8sHH16s16s3BBIHH")
_ELF_HEADER = struct.Struct("<16sHHIIIIIHHHHHH")
_ELF_PROGRAM_HEADER = struct.Struct("<IIIIIIII")
_PT_LOAD = 1
_EM_ARM = 40
#: Largest image accepted: bigger than any flash this tool writes (a wrong file, not firmware).
MAX_IMAGE_BYTES = 16 << 20


class ImageError(ImulinkError):
    """A file that is not a usable firmware image (one line, fit to print)."""


@dataclass(frozen=True)
class Segment:
    address: int
    data: bytes

    @property
    def end(self) -> int:
        return self.address + len(self.data)


@dataclass(frozen=True)
class Identification:
    """What an image says it is (firmware/app/identification.h)."""

    board: str
    chip: str
    firmware_version: tuple[int, int, int]
    protocol_version: int
    schema_hash: int
    device_id: int
    flash_kib: int

    @property
    def version_text(self) -> str:
        return ".".join(map(str, self.firmware_version))


@dataclass(frozen=True)
class FirmwareImage:
    path: Path
    format: str  # "elf", "hex" or "bin"
    segments: tuple[Segment, ...]  # sorted, non-overlapping, adjacent ones merged
    identification: Identification | None

    @property
    def start(self) -> int:
        return self.segments[0].address

    @property
    def end(self) -> int:
        return self.segments[-1].end

    @property
    def size(self) -> int:
        """Bytes to write (the gaps between segments excluded)."""
        return sum(len(s.data) for s in self.segments)

    def bytes_at(self, address: int, length: int) -> bytes:
        """The image's bytes over [address, address + length); 0xFF (erased flash) in gaps."""
        out = bytearray(b"\xff" * length)
        for s in self.segments:
            lo, hi = max(address, s.address), min(address + length, s.end)
            if lo < hi:
                out[lo - address:hi - address] = s.data[lo - s.address:hi - s.address]
        return bytes(out)


def load_image(path, address: int | None = None) -> FirmwareImage:
    """Read an ELF, Intel HEX (.hex, .ihex) or raw binary (.bin, with `address`) image."""
    path = Path(path)
    try:
        data = read_regular_file(path, MAX_IMAGE_BYTES)
    except FileError as exc:
        raise ImageError(str(exc)) from None
    if data[:4] == b"\x7fELF":
        fmt, segments = "elf", _elf_segments(path, data)
    elif path.suffix.lower() in (".hex", ".ihex") or data[:1] == b":":
        fmt, segments = "hex", _hex_segments(path, data)
    elif path.suffix.lower() == ".bin":
        if address is None:
            raise ImageError(f"{path} is a raw binary: say where it goes with --address (e.g. 0x08000000)")
        fmt, segments = "bin", [Segment(address, data)]
    else:
        raise ImageError(f"{path} is not a firmware image: expected an ELF file, Intel HEX (.hex) or a raw .bin")
    if address is not None and fmt != "bin":
        raise ImageError(f"--address applies to raw .bin images only; {path} carries its own addresses")
    segments = _merge([s for s in segments if s.data])
    if not segments:
        raise ImageError(f"{path} holds no bytes to flash")
    return FirmwareImage(path, fmt, tuple(segments), _identification(segments))


def _elf_segments(path: Path, data: bytes) -> list[Segment]:
    if len(data) < _ELF_HEADER.size or data[4] != 1 or data[5] != 1:
        raise ImageError(f"{path} is not a 32-bit little-endian ELF file (an MCU image)")
    (_, _, machine, _, _, phoff, _, _, _, phentsize, phnum, _, _, _) = _ELF_HEADER.unpack_from(data)
    if machine != _EM_ARM:
        raise ImageError(f"{path} is an ELF file for another processor (machine {machine}), not an Arm image")
    segments = []
    for i in range(phnum):
        offset = phoff + i * phentsize
        if offset + _ELF_PROGRAM_HEADER.size > len(data):
            raise ImageError(f"{path} is a truncated ELF file (program header {i})")
        kind, file_offset, _, paddr, filesz, _, _, _ = _ELF_PROGRAM_HEADER.unpack_from(data, offset)
        if kind != _PT_LOAD or filesz == 0:
            continue
        if file_offset + filesz > len(data):
            raise ImageError(f"{path} is a truncated ELF file (segment {i})")
        segments.append(Segment(paddr, data[file_offset:file_offset + filesz]))
    return segments


def _hex_segments(path: Path, data: bytes) -> list[Segment]:
    segments: list[Segment] = []
    base = 0
    ended = False
    for number, raw in enumerate(data.splitlines(), 1):
        line = raw.strip()
        if not line:
            continue
        if ended:
            raise ImageError(f"{path}:{number}: data after the end-of-file record")
        try:
            if line[:1] != b":":
                raise ValueError("no ':' at the start")
            record = bytes.fromhex(line[1:].decode("ascii"))
            if len(record) < 5 or len(record) != record[0] + 5:
                raise ValueError("wrong length")
        except (ValueError, UnicodeDecodeError) as exc:
            raise ImageError(f"{path}:{number}: not an Intel HEX record ({exc})") from None
        if sum(record) & 0xFF:
            raise ImageError(f"{path}:{number}: checksum mismatch")
        count, offset, kind, payload = record[0], int.from_bytes(record[1:3], "big"), record[3], record[4:-1]
        if kind == 0x00:
            segments.append(Segment(base + offset, payload))
        elif kind == 0x01:
            ended = True
        elif kind == 0x02 and count == 2:
            base = int.from_bytes(payload, "big") << 4
        elif kind == 0x04 and count == 2:
            base = int.from_bytes(payload, "big") << 16
        elif kind in (0x03, 0x05):
            pass  # start address: the MCU starts from its vector table anyway
        else:
            raise ImageError(f"{path}:{number}: unknown record type {kind:#04x}")
    if not ended:
        raise ImageError(f"{path} has no end-of-file record (truncated?)")
    return segments


def _merge(segments: list[Segment]) -> list[Segment]:
    out: list[Segment] = []
    for s in sorted(segments, key=lambda s: s.address):
        if out and s.address < out[-1].end:
            raise ImageError(f"two parts of the image overlap at {s.address:#010x}")
        if out and s.address == out[-1].end:
            out[-1] = Segment(out[-1].address, out[-1].data + s.data)
        else:
            out.append(s)
    return out


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", errors="replace")


def identification_in(data: bytes) -> Identification | None:
    """The identification block in `data` (an image's bytes, or flash read back), or None."""
    at = data.find(ID_MAGIC)
    if at < 0 or at + _ID_LAYOUT.size > len(data):
        return None
    (_, layout, size, board, chip, major, minor, patch, protocol_version, schema_hash, device_id,
     flash_kib) = _ID_LAYOUT.unpack_from(data, at)
    if layout != 1 or size != _ID_LAYOUT.size:
        return None  # another layout: a later firmware; treated as no block
    return Identification(_text(board), _text(chip), (major, minor, patch), protocol_version, schema_hash,
                          device_id, flash_kib)


def _identification(segments: list[Segment]) -> Identification | None:
    for s in segments:
        found = identification_in(s.data)
        if found is not None:
            return found
    return None
