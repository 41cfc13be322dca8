"""`imulink flash`: put a firmware image on an STM32 board and prove that what runs is what
was built.

Over the chip's system-memory bootloader on USART1 (:mod:`imulink.board.flash.stm32boot`, AN3155):

1. the image (ELF, Intel HEX or .bin, :mod:`imulink.io.firmware_image`) must carry the
   identification block of a board on this chip family, and fit the chip's flash;
2. the board enters its bootloader: by hand (BOOT0 high and a reset), by the imulink
   firmware's ENTER_BOOTLOADER command, through the adapter's DTR and RTS lines wired
   to NRST and BOOT0, or through a lab's BOOT0 and reset lines (or power switch) that the
   caller drives (`lines`: a labgrid place's, imulink.board.lab.PlaceLines);
3. synchronisation, Get, Get ID: the chip must be the one the image was built for; its
   flash size (the chip's own flash size register) must hold the image; a refused read
   there means readout protection is on;
4. only the sectors the image touches are erased (the F405/407's sectors are 16, 64 and
   128 KiB), then written in 256-byte blocks, then read back and compared;
5. Go at the image's own vector table (where it was flashed; with `lines`, BOOT0 low and a
   reset instead, which boots the flash as a power-on does), and the firmware's HELLO on
   the same port (the link's own rate) must report the image's board, firmware version and
   schema hash; an image flashed with --force that is not imulink's (or speaks another
   schema) is started and not asked for a HELLO.

Over SWD the same checks frame :func:`imulink.board.flash.swd.flash_swd` (pyOCD or openocd).
Progress goes to a `progress(phase, done, total)` callback (:class:`imulink.progress.Bars`).
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import Protocol

import serial

from imulink import protocol
from imulink.board.flash.stm32boot import BLOCK, Bootloader, BootloaderError, NoAnswer, Refused
from imulink.board.link import DEFAULT_BAUD, Link, LinkError, PortError
from imulink.errors import ImulinkError
from imulink.io.firmware_image import FirmwareImage, Identification, identification_in

#: Rate for the bootloader (AN3155: up to 115200 baud; the bootloader measures it).
BOOTLOADER_BAUD = 115200
#: Ways into the bootloader (see ENTRY_HELP).
ENTRIES = ("manual", "command", "dtr-rts", "lines")
ENTRY_HELP = {
    "manual": "the board is already in its bootloader: BOOT0 held high (a jumper to 3.3 V) and a reset",
    "command": "the board runs imulink firmware: ENTER_BOOTLOADER over the link",
    "dtr-rts": "the adapter's DTR drives NRST and RTS drives BOOT0 (each line low while asserted)",
    "lines": "a lab's BOOT0 and reset lines (or power switch): BOOT0 high and a reset, the flash, then BOOT0 low "
             "and a reset",
}


class BootLines(Protocol):
    """A board's BOOT0 and reset lines that the host drives (imulink.board.lab.PlaceLines)."""

    def describe(self) -> str:
        """What drives them, for the log."""
        ...

    def enter_bootloader(self) -> None:
        """BOOT0 high and a reset: the system bootloader starts."""
        ...

    def start_application(self) -> None:
        """BOOT0 low and a reset: what the flash holds starts."""
        ...

    def set_boot0(self, high: bool) -> None:
        ...

#: Board names of images for emulated boards, not for hardware (firmware/boards/qemu).
EMULATED_BOARD_PREFIX = "qemu-"
#: Bytes at the start of flash read to find the identification block of what the chip holds.
FLASHED_ID_SEARCH = 1024
#: Seconds from Go to the firmware's HELLO (the reference board needs about 0.2 s to start).
HELLO_TIMEOUT_S = 3.0


class FlashError(ImulinkError):
    """Flashing cannot go on (one line, with what to do)."""


@dataclass(frozen=True)
class Chip:
    """A chip family as its bootloader reports it (Get ID)."""

    device_id: int
    names: tuple[str, ...]  # what an image's identification block may name
    flash_base: int
    sector_sizes: tuple[int, ...]  # bytes of each sector from flash_base, for the largest part
    flash_size_register: int  # where the chip keeps its flash size in KiB (u16)


_KIB = 1024
#: RM0090 section 3.3 (flash module organisation) and section 39.2 (flash size register).
CHIPS = {
    0x413: Chip(0x413, ("STM32F405", "STM32F407", "STM32F415", "STM32F417"), 0x0800_0000,
                (16 * _KIB,) * 4 + (64 * _KIB,) + (128 * _KIB,) * 7, 0x1FFF_7A22),
}


@dataclass
class FlashResult:
    image: FirmwareImage
    method: str
    chip_name: str
    bootloader_version: str
    sectors: list[int]
    bytes_written: int
    verified: bool
    started: bool
    hello: dict | None
    duration_s: float
    dry_run: bool
    started_at: int | None = None  # where Go started it: the image's vector table
    note: str = ""  # why it was not started, or why its HELLO was not asked for


def sectors_for(image: FirmwareImage, chip: Chip) -> list[int]:
    """The sectors the image's bytes fall in."""
    needed, start = [], chip.flash_base
    for number, size in enumerate(chip.sector_sizes):
        if any(s.address < start + size and s.end > start for s in image.segments):
            needed.append(number)
        start += size
    return needed


def check_identification(image: FirmwareImage, force: bool) -> Identification | None:
    """The image's identification block; FlashError when it has none (unless `force`)."""
    ident = image.identification
    if ident is None and not force:
        raise FlashError(f"{image.path} has no imulink identification block (not built by firmware/Makefile?); "
                         "--force flashes it anyway, unchecked")
    if ident is not None and ident.board.startswith(EMULATED_BOARD_PREFIX) and not force:
        raise FlashError(f"{image.path} is the image of {ident.board}, an emulated board (QEMU), not of a real "
                         "one: flash build/stm32f407/imulink-stm32f407-gy86.elf (--force flashes it anyway)")
    if ident is not None and ident.schema_hash != protocol.SCHEMA_HASH and not force:
        raise FlashError(f"{image.path} speaks protocol schema 0x{ident.schema_hash:08X}, this host "
                         f"0x{protocol.SCHEMA_HASH:08X}: build the firmware and the host from the same checkout "
                         "(--force flashes it anyway, its HELLO unchecked)")
    return ident


def unasked_hello(ident: Identification | None) -> str:
    """Why a started image's HELLO is not asked for ("" when it is: an imulink image of this
    host's schema)."""
    if ident is None:
        return "no imulink identification: its HELLO is not asked for"
    if ident.schema_hash != protocol.SCHEMA_HASH:
        return f"protocol schema 0x{ident.schema_hash:08X}, not this host's: its HELLO is not asked for"
    return ""


#: Where a Cortex-M4's initial stack pointer may point on these chips: SRAM and CCM RAM.
_STACK_RANGES = ((0x2000_0000, 0x2002_0000), (0x1000_0000, 0x1001_0000))


def vector_table_start(image: FirmwareImage) -> int | None:
    """The image's start when a vector table is there (Go takes its stack pointer and reset
    handler from it, AN3155 3.5): an initial stack pointer in RAM and a Thumb reset handler
    inside the image; None otherwise."""
    head = image.bytes_at(image.start, 8)
    stack, reset = int.from_bytes(head[:4], "little"), int.from_bytes(head[4:], "little")
    in_ram = any(low < stack <= high for low, high in _STACK_RANGES)
    return image.start if in_ram and reset & 1 and image.start <= reset & ~1 < image.end else None


def check_chip(image: FirmwareImage, ident: Identification | None, device_id: int, flash_bytes: int) -> Chip:
    """The chip the bootloader reported, if the image is for it and fits its flash."""
    chip = CHIPS.get(device_id)
    if chip is None:
        raise FlashError(f"the chip reports device id 0x{device_id:03X}, which imulink does not know "
                         f"(known: {', '.join(f'0x{d:03X} {c.names[0]} family' for d, c in CHIPS.items())})")
    if ident is not None and (ident.device_id != device_id or ident.chip not in chip.names):
        raise FlashError(f"{image.path} is built for {ident.chip} (board {ident.board}, device id "
                         f"0x{ident.device_id:03X}), but this chip is a {'/'.join(chip.names)} "
                         f"(device id 0x{device_id:03X})")
    end = chip.flash_base + flash_bytes
    if image.start < chip.flash_base or image.end > end:
        raise FlashError(f"{image.path} spans 0x{image.start:08X}..0x{image.end:08X}, outside this chip's flash "
                         f"0x{chip.flash_base:08X}..0x{end:08X} ({flash_bytes // _KIB} KiB)")
    return chip


def _blocks(image: FirmwareImage):
    """(address, bytes) of 256-byte blocks aligned to 256, padded with 0xFF (erased flash) to whole words."""
    for s in image.segments:
        address = s.address - s.address % 4
        while address < s.end:
            length = min(BLOCK - address % BLOCK, s.end - address)
            length += -length % 4
            yield address, image.bytes_at(address, length)
            address += length


def _report(progress, phase: str, done: int, total: int) -> None:
    if progress is not None:
        progress(phase, done, total)


# ---------------------------------------------------------------------------- the UART bootloader


def _open(url: str, baud: int, parity: str, rts: bool | None = None, dtr: bool | None = None):
    """The port with every line setting given before it opens (set once: see stm32boot.Bootloader)."""
    try:
        port = serial.serial_for_url(url, baudrate=baud, parity=parity, timeout=0.1, do_not_open=True)
        if rts is not None:
            port.rts = rts  # set before opening, so the lines do not glitch as the port opens
        if dtr is not None:
            port.dtr = dtr
        port.open()
        return port
    except (serial.SerialException, ValueError, OSError) as exc:
        raise PortError(f"cannot open {url}: {exc}") from None


def _enter_by_command(url: str, link_baud: int) -> None:
    try:
        with Link(url, link_baud) as link:
            link.connect(timeout=0.5, attempts=2)
            link.command("ENTER_BOOTLOADER")
            link.receive(0.1)  # the board resets now
    except protocol.CommandError as exc:
        raise FlashError(f"the board refused ENTER_BOOTLOADER ({exc.reason}): its firmware cannot start the "
                         "bootloader; set BOOT0 high and reset it by hand (--enter manual)") from None
    except LinkError as exc:
        raise FlashError(f"--enter command needs imulink firmware answering on {url}: {exc}") from None


def _pulse_reset(port, boot0_high: bool) -> None:
    """DTR -> NRST, RTS -> BOOT0, each pin low while its line is asserted."""
    port.rts = not boot0_high
    port.dtr = True  # NRST low
    time.sleep(0.05)
    port.dtr = False
    time.sleep(0.1)  # the chip starts: the bootloader needs a few ms before it listens


def flash_uart(image: FirmwareImage, url: str, *, enter: str = "manual", baud: int = BOOTLOADER_BAUD,
               link_baud: int = DEFAULT_BAUD, verify: bool = True, start: bool = True, dry_run: bool = False,
               force: bool = False, unprotect: bool = False, progress=None, log=print,
               lines: BootLines | None = None) -> FlashResult:
    """Flash `image` through the bootloader on `url` (see the module docstring). With
    enter="lines", `lines` drive the board's BOOT0 and reset: into the bootloader first, and
    after the flash (unless `start` is off) BOOT0 low and a reset start the flash's image; a
    dry run starts what the board held, and a failure leaves BOOT0 low (no reset)."""
    begun = time.monotonic()
    ident = check_identification(image, force)
    if enter not in ENTRIES:
        raise FlashError(f"unknown way into the bootloader {enter!r}; choose one of {', '.join(ENTRIES)}")
    if enter == "lines" and lines is None:
        raise FlashError("--enter lines needs the board's BOOT0 and reset lines: a labgrid place (lg://PLACE) "
                         "that has them (docs/farm.md)")
    if enter != "lines":
        lines = None
    if enter == "command":
        _enter_by_command(url, link_baud)
    if lines is not None:
        log(f"{lines.describe()}: BOOT0 high and a reset, into the bootloader")
        lines.enter_bootloader()
    finished = False
    try:
        result, started_at = _flash_through(image, url, enter, baud, ident, verify, start, dry_run, force, unprotect,
                                            progress, log, lines)
        finished = True
    finally:
        if lines is not None and not finished:  # the board stays in its bootloader until a reset; a power-on
            with contextlib.suppress(Exception):  # or reset later boots its flash
                lines.set_boot0(False)
    if lines is not None and (start or dry_run):  # --no-start: the board stays in its bootloader, BOOT0 high
        log(f"{lines.describe()}: BOOT0 low and a reset, " + ("back into its firmware" if dry_run else
                                                               "into the flash's image"))
        lines.start_application()
    note = ""
    if start and not dry_run and started_at is None and lines is not None and vector_table_start(image) is not None:
        note = (f"not started: the image starts at 0x{image.start:08X}, not at the flash's start, where a reset "
                "boots; the board was reset with BOOT0 low and runs what the flash's start holds")
    elif start and not dry_run and started_at is None:
        then = ("the board was reset with BOOT0 low and runs what it boots" if lines is not None
                else "reset the board with BOOT0 low to run what it boots")
        note = (f"not started: no vector table at the image's start 0x{image.start:08X} (a stack pointer in RAM, "
                f"a reset handler in the image); {then}")
    elif started_at is not None:
        note = unasked_hello(ident)
    hello = check_hello(url, link_baud, ident) if started_at is not None and not note else None
    return FlashResult(image, "uart", "/".join(CHIPS[result.device_id].names), result.bootloader_version,
                       result.sectors, 0 if dry_run else image.size, verify and not dry_run, started_at is not None,
                       hello, time.monotonic() - begun, dry_run, started_at, note)


def _flash_through(image: FirmwareImage, url: str, enter: str, baud: int, ident, verify: bool, start: bool,
                   dry_run: bool, force: bool, unprotect: bool, progress, log,
                   lines: BootLines | None) -> tuple[_Programmed, int | None]:
    """The bootloader's part: (what was programmed, where the image was started or None)."""
    port = _open(url, baud, serial.PARITY_EVEN, rts=False if enter == "dtr-rts" else None,
                 dtr=False if enter == "dtr-rts" else None)
    try:
        if enter == "dtr-rts":
            _pulse_reset(port, boot0_high=True)
        boot = Bootloader(port)
        try:
            result = _program(boot, image, ident, verify, dry_run, unprotect, force, progress, log)
            started_at = vector_table_start(image) if start and not dry_run else None
            if started_at is not None and lines is not None:
                # a reset with BOOT0 low boots the flash from its start, as a power-on does
                started_at = CHIPS[result.device_id].flash_base if started_at == image.start else None
            elif started_at is not None:
                boot.go(started_at)
            if start and not dry_run and enter == "dtr-rts":
                port.rts = True  # BOOT0 low again: the next reset starts the firmware too
        except NoAnswer as exc:
            if boot.info is None:  # it never answered: no bootloader there
                raise FlashError(str(exc)) from None
            raise FlashError(f"{exc}. The board stays in its bootloader: run imulink flash again (if it does not "
                             "answer then, reset it with BOOT0 still high)") from None
        except Refused as exc:
            raise FlashError(f"{exc}: a write-protected sector or readout protection? (--unprotect clears readout "
                             "protection, and the chip erases its whole flash first; docs/flashing.md)") from None
        except BootloaderError as exc:
            raise FlashError(str(exc)) from None
    finally:
        port.close()
    return result, started_at


@dataclass
class _Programmed:
    device_id: int
    bootloader_version: str
    sectors: list[int]


def _flashed_identification(boot: Bootloader, chip: Chip) -> Identification | None:
    """The identification block of the firmware the chip holds now, if any."""
    data = b"".join(boot.read_memory(chip.flash_base + offset, BLOCK)
                    for offset in range(0, FLASHED_ID_SEARCH, BLOCK))
    return identification_in(data)


def _program(boot: Bootloader, image: FirmwareImage, ident, verify: bool, dry_run: bool, unprotect: bool,
             force: bool, progress, log) -> _Programmed:
    boot.sync()
    info = boot.info
    assert info is not None  # sync() returns only once a Get answered
    device_id = boot.get_id()
    chip = CHIPS.get(device_id)
    flash_bytes = sum(chip.sector_sizes) if chip else 0
    if chip is not None:
        try:
            flash_bytes = int.from_bytes(boot.read_memory(chip.flash_size_register, 2), "little") * _KIB
        except Refused:
            if not unprotect:
                raise FlashError("the chip's readout protection is on (it refuses reads): --unprotect clears it, "
                                 "which ERASES THE WHOLE FLASH first (the chip's own rule)") from None
            log("readout protection on: clearing it, which erases the whole flash ...")
            boot.readout_unprotect()
            time.sleep(0.5)  # the chip resets after the erase
            boot.sync()
            flash_bytes = int.from_bytes(boot.read_memory(chip.flash_size_register, 2), "little") * _KIB
    chip = check_chip(image, ident, device_id, flash_bytes)
    current = _flashed_identification(boot, chip)
    if current is not None and ident is not None and current.board != ident.board and not force:
        raise FlashError(f"this board holds {current.board} firmware {current.version_text}, the image is for "
                         f"{ident.board}: wrong image? (--force flashes it anyway)")
    sectors = sectors_for(image, chip)
    log(f"chip: {'/'.join(chip.names)} (device id 0x{device_id:03X}), {flash_bytes // _KIB} KiB flash, "
        f"bootloader {info.version_text}; image: {image.size} bytes at 0x{image.start:08X}, sectors "
        f"{', '.join(map(str, sectors))}")
    if dry_run:
        return _Programmed(device_id, info.version_text, sectors)
    sector_total = sum(chip.sector_sizes[s] for s in sectors)
    erased = 0
    for number in sectors:  # one at a time, for the progress bar and a bounded wait each
        boot.erase_sectors([number])
        erased += chip.sector_sizes[number]
        _report(progress, "erase", erased, sector_total)
    blocks = list(_blocks(image))
    total = sum(len(b) for _, b in blocks)
    done = 0
    for address, data in blocks:
        boot.write_memory(address, data)
        done += len(data)
        _report(progress, "write", done, total)
    if verify:
        done = 0
        for address, data in blocks:
            back = boot.read_memory(address, len(data))
            if back != data:
                at = next(i for i, (a, b) in enumerate(zip(back, data)) if a != b)
                raise FlashError(f"verify failed at 0x{address + at:08X}: read 0x{back[at]:02X}, wrote "
                                 f"0x{data[at]:02X} (flash again; if it repeats, the flash may be worn or "
                                 "write-protected)")
            done += len(data)
            _report(progress, "verify", done, total)
    return _Programmed(device_id, info.version_text, sectors)


def check_hello(url: str, link_baud: int, ident: Identification | None) -> dict:
    """The firmware's HELLO after Go: it must be the image's."""
    try:
        with Link(url, link_baud) as link:
            hello = link.connect(timeout=HELLO_TIMEOUT_S / 3, attempts=3)
    except protocol.ProtocolMismatch as exc:
        raise FlashError(f"flashed and started, but {exc}") from None
    except LinkError as exc:
        raise FlashError(f"flashed and started, but no HELLO from the firmware on {url} at {link_baud} baud: {exc}") \
            from None
    if ident is not None:
        running = (hello["board"], (hello["firmware_major"], hello["firmware_minor"], hello["firmware_patch"]),
                   hello["schema_hash"])
        wanted = (ident.board, ident.firmware_version, ident.schema_hash)
        if running != wanted:
            raise FlashError(f"flashed and started, but the board runs {hello['board']} firmware "
                             f"{'.'.join(map(str, running[1]))} (schema 0x{running[2]:08X}), not the image's "
                             f"{ident.board} {ident.version_text} (schema 0x{ident.schema_hash:08X})")
    return hello
