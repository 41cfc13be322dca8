"""Byte-level model of the STM32F405/407 system-memory bootloader on USART1, for the
tests of a flashing tool: ST application note AN3155 "USART protocol used in the STM32
bootloader" (Rev 20; sections cited as "AN3155 §n"), with the product facts of AN2606
"STM32 microcontroller system memory boot mode" (STM32F40xxx/41xxx: USART bootloader
V3.1, device ID 0x413) and of RM0090 (the STM32F405/407 reference manual) for the flash.

:class:`Stm32Bootloader` is a pure state machine: :meth:`Stm32Bootloader.receive` takes
the bytes the host sent (in any chunking, one byte at a time included) and returns the
bytes the chip answers. :class:`BootloaderPort` runs one behind a pseudo-terminal that a
host opens with pyserial, and after Go can bridge the port to a "booted" firmware.

What is modelled:

* the code sequence (AN3155 §1): after reset the chip waits for the 0x7F autobaud byte;
  anything received before it is ignored; 0x7F is answered with ACK (0x79) and the chip
  then waits for commands;
* every command is a byte and its complement (AN3155 §3 "Communication safety"); a pair
  whose XOR is not 0xFF, a command this bootloader does not have and a command refused
  by read protection are answered with one NACK (0x1F) and the chip goes back to
  command checking (AN3155 §3 Table 2 note 1). In command checking a second 0x7F is not
  special: it is the first byte of a command pair, and the byte after it decides
  (0x7F 0x7F: bad complement; 0x7F 0x80: no such command; NACK either way);
* the V3.1 command set (AN3155 §3.1 byte list, §4 Table 3): Get 0x00, Get Version
  0x01, Get ID 0x02, Read Memory 0x11, Go 0x21, Write Memory 0x31, Extended Erase 0x44,
  Write Protect 0x63, Write Unprotect 0x73, Readout Protect 0x82, Readout Unprotect 0x92.
  The legacy Erase 0x43 is NACKed: Erase and Extended Erase are exclusive and V3.0 on
  has the extended one only (AN3155 §4 Table 3, V3.0). Get Checksum 0xA1 (V3.3 on),
  Special 0x50 and Extended Special 0x51 (not in the §3.1 list) are NACKed too;
* read protection (AN3155 §3 "Protection", Table 2 note 2): while RDP is active only
  Get, Get Version, Get ID and Readout Unprotect are served; every other command is
  NACKed at its command byte (one NACK: AN3155 §3.4-§3.6 say some products send two,
  AN2606 lists which; the model sends one);
* memory (AN2606 STM32F40xxx/41xxx, RM0090 §2.2-2.3 and §3.3): flash at 0x08000000
  (1 MiB by default, sectors 4 x 16 KiB, 64 KiB, 7 x 128 KiB), SRAM1+SRAM2 at 0x20000000 (128 KiB)
  of which the first 12 KiB belong to the bootloader (AN2606: "12 Kbytes starting from
  address 0x20000000 are used by the bootloader firmware"; V2.2 on NACKs Read, Write
  and Go there, AN3155 §4 Table 3), system memory at 0x1FFF0000 (30 KiB, read-only,
  its content is not modelled: it reads 0x00), OTP at 0x1FFF7800 (528 bytes, read-only
  in the model, 0xFF), the unique ID and the flash size register (KiB) at 0x1FFF7A10 and
  0x1FFF7A22 (RM0090 §39, read-only), option bytes at 0x1FFFC000 (16 bytes);
* flash programming (RM0090 §3.5, erase and program operations): programming can only
  change bits from 1 to 0, writing a 1 where a 0 is needs an erase. The model programs
  ``old & new``;
  AN3155 §3.6 ACKs a Write Memory only "if the write operation was successful", so a
  write whose bytes do not read back as sent (they needed a 0 -> 1 change: the flash
  was not erased) is NACKed -- the bits that could be cleared are cleared, as on the
  chip. Writing bytes that only clear bits (or the same bytes again) is ACKed;
* write protection: the nWRP option bits (RM0090 §3.6.1); writes and erases that touch
  a protected sector return no error and leave it unchanged (AN3155 §3.6, §3.8 notes);
* resets: Write Protect, Write Unprotect, Readout Protect, Readout Unprotect and a Write
  Memory to the option bytes end with a system reset on the F4 (AN3155 §3.6, §3.9-§3.12
  and their figure footnotes): the chip is back to waiting for 0x7F (BOOT0 still
  selects system memory), memory keeps what was written.

Not modelled: timing (erases are instant), the baud rate (any rate syncs), parity and
framing errors, CCM RAM, OTP programming (NACKed), the content of system memory.

Fault injection (for the flashing tool's tests): ``nack_commands`` (command codes NACKed
at their command byte), ``silent_after_bytes`` (the chip hangs: from that byte on
nothing is processed or answered), ``reset_after_bytes`` (one chip reset once that many
bytes were received: pending command state is lost, memory is kept), and any
``device_id``.
"""
from __future__ import annotations

import select
import threading
from collections.abc import Callable, Generator, Iterable
from typing import Any, NamedTuple

from imulink.board.proxy import PtyFront

ACK = 0x79
NACK = 0x1F
SYNC = 0x7F  # the autobaud byte (AN3155 §1)

#: Command codes of AN3155 §3 Table 2, by name.
COMMANDS = {
    "Get": 0x00,
    "Get Version": 0x01,
    "Get ID": 0x02,
    "Read Memory": 0x11,
    "Go": 0x21,
    "Write Memory": 0x31,
    "Erase": 0x43,
    "Extended Erase": 0x44,
    "Special": 0x50,
    "Extended Special": 0x51,
    "Write Protect": 0x63,
    "Write Unprotect": 0x73,
    "Readout Protect": 0x82,
    "Readout Unprotect": 0x92,
    "Get Checksum": 0xA1,
}
COMMAND_NAMES = {code: name for name, code in COMMANDS.items()}
#: What a V3.x bootloader with Extended Erase lists in its Get answer (AN3155 §3.1, in
#: that order; byte 10 is 0x44 and there is no Get Checksum before V3.3).
SUPPORTED_COMMANDS = (0x00, 0x01, 0x02, 0x11, 0x21, 0x31, 0x44, 0x63, 0x73, 0x82, 0x92)
#: Served while read protection is active (AN3155 §3 Table 2 note 2).
ALLOWED_WHEN_PROTECTED = frozenset({0x00, 0x01, 0x02, 0x92})

# Memory map of the STM32F405/407 (RM0090 §2.3, AN2606 STM32F40xxx/41xxx).
FLASH_BASE = 0x0800_0000
RAM_BASE = 0x2000_0000
RAM_SIZE = 128 * 1024  # SRAM1 (112 KiB) + SRAM2 (16 KiB), contiguous
BOOTLOADER_RAM_SIZE = 12 * 1024  # 0x20000000..0x20002FFF belong to the bootloader
USER_RAM_BASE = RAM_BASE + BOOTLOADER_RAM_SIZE
SYSTEM_MEMORY_BASE = 0x1FFF_0000
SYSTEM_MEMORY_SIZE = 30 * 1024
OTP_BASE = 0x1FFF_7800
OTP_SIZE = 528
#: Device electronic signature (RM0090 §39): the 96-bit unique ID at 0x1FFF7A10 and the
#: flash size register (u16, KiB) at 0x1FFF7A22, read-only.
DEVICE_INFO_BASE = 0x1FFF_7A10
DEVICE_INFO_SIZE = 0x14
FLASH_SIZE_OFFSET = 0x12
OPTION_BYTES_BASE = 0x1FFF_C000
OPTION_BYTES_SIZE = 16
#: Sector sizes of the 1 MiB STM32F405/407 (RM0090 §3.3 Table 5); a smaller flash_size
#: keeps the sectors that fit (512 KiB: sectors 0..7).
F405_SECTOR_SIZES = (16 * 1024,) * 4 + (64 * 1024,) + (128 * 1024,) * 7

# Option bytes as the model lays them out (RM0090 §3.6.1): USER at 0x1FFFC000, RDP at
# 0x1FFFC001, nWRP (one bit per sector, 0 = protected) at 0x1FFFC008..9, little-endian.
# The default values follow the FLASH_OPTCR reset value 0x0FFFAAED; the bytes the model
# does not interpret read 0xFF.
OB_USER, OB_RDP, OB_NWRP = 0, 1, 8
RDP_LEVEL0 = 0xAA
RDP_LEVEL2 = 0xCC
#: What the model writes for level 1 (any value but 0xAA and 0xCC is level 1; the value
#: the ROM writes cannot be read back over the protocol and is not documented).
RDP_LEVEL1 = 0x55
DEFAULT_OPTION_BYTES = bytes([0xEC, RDP_LEVEL0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
                              0xFF, 0x0F, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF])

#: Extended Erase special codes (AN3155 §3.8); 0xFFF0..0xFFFC are reserved.
MASS_ERASE, BANK1_ERASE, BANK2_ERASE = 0xFFFF, 0xFFFE, 0xFFFD

_RESET = "reset"
_GO = "go"


def xor(data: Iterable[int]) -> int:
    """The XOR of the bytes: AN3155's checksum."""
    value = 0
    for byte in data:
        value ^= byte
    return value


class LogEntry(NamedTuple):
    """One exchange: the command (its AN3155 name, "Sync", "Reset", or "0xNN" for an
    unknown code), what it asked (address, length, sectors, ...; ``reason`` says why a
    NACK was sent) and the result ("ACK", "NACK" or, for "Reset", "reset")."""

    command: str
    args: dict
    result: str


class Stm32Bootloader:
    """The bootloader of one STM32F405/407 (see the module docstring for what is modelled).

    Args:
        device_id: what Get ID answers (0x413 for the STM32F40xxx/41xxx).
        flash_size: bytes of flash (1 MiB; 512 KiB parts keep sectors 0..7).
        sector_sizes: the flash sectors, in order from 0x08000000.
        read_protected: start with RDP level 1.
        bootloader_version: the version byte of Get and Get Version (0x31 = V3.1).
        flash: initial flash contents from 0x08000000 (the rest erased, 0xFF).
        nack_commands: command codes NACKed at their command byte (fault injection).
        silent_after_bytes: after this many received bytes nothing more is processed or
            answered (a hung board).
        reset_after_bytes: the chip resets once this many bytes were received (once).

    Observables: ``flash``, ``ram`` (128 KiB from 0x20000000), ``option_bytes``,
    ``read_protected``, ``write_protected`` (sector numbers), ``go_address`` (the last
    Go's address, None before; from then on the application runs and nothing is
    answered), ``log`` (:class:`LogEntry` list), ``erase_counts`` (per sector),
    ``erased_sectors``, ``written_bytes`` (data bytes of ACKed Write Memory commands),
    ``resets``, ``received_bytes`` and ``state``.
    """

    def __init__(self, *, device_id: int = 0x413, flash_size: int = 1 << 20,
                 sector_sizes: Iterable[int] = F405_SECTOR_SIZES, read_protected: bool = False,
                 bootloader_version: int = 0x31, flash: bytes | None = None,
                 nack_commands: Iterable[int] = (), silent_after_bytes: int | None = None,
                 reset_after_bytes: int | None = None):
        if not 0 <= device_id <= 0xFFFF:
            raise ValueError("device_id is two bytes")
        if not 0 < bootloader_version <= 0xFF:
            raise ValueError("bootloader_version is one byte")
        self.device_id = device_id
        self.bootloader_version = bootloader_version
        self.sectors = self._sector_table(flash_size, tuple(sector_sizes))
        self.flash = bytearray(b"\xff" * flash_size)
        if flash is not None:
            if len(flash) > flash_size:
                raise ValueError("initial flash contents larger than the flash")
            self.flash[:len(flash)] = flash
        self.ram = bytearray(RAM_SIZE)
        self.system_memory = bytes(SYSTEM_MEMORY_SIZE)
        self.otp = bytes(b"\xff" * OTP_SIZE)
        info = bytearray(range(1, 13)) + bytes(DEVICE_INFO_SIZE - 12)  # a made-up unique ID
        info[FLASH_SIZE_OFFSET:FLASH_SIZE_OFFSET + 2] = (flash_size // 1024).to_bytes(2, "little")
        self.device_info = bytes(info)
        self.option_bytes = bytearray(DEFAULT_OPTION_BYTES)
        self.read_protected = read_protected
        self.nack_commands = set(nack_commands)
        self.silent_after_bytes = silent_after_bytes
        self.reset_after_bytes = reset_after_bytes
        self.go_address: int | None = None
        self.log: list[LogEntry] = []
        self.erase_counts = [0] * len(self.sectors)
        self.written_bytes = 0
        self.resets = 0
        self.received_bytes = 0
        self._out = bytearray()
        self._state = "sync"
        self._machine = self._start()

    @staticmethod
    def _sector_table(flash_size: int, sizes: tuple[int, ...]) -> tuple[tuple[int, int], ...]:
        sectors, offset = [], 0
        for size in sizes:
            if offset + size > flash_size:
                break
            sectors.append((offset, size))
            offset += size
        if offset != flash_size:
            raise ValueError(f"flash_size {flash_size:#x} is not a whole number of sectors")
        return tuple(sectors)

    # ------------------------------------------------------------------ observables

    @property
    def read_protected(self) -> bool:
        """RDP level 1 or 2: the RDP option byte is not 0xAA."""
        return self.option_bytes[OB_RDP] != RDP_LEVEL0

    @read_protected.setter
    def read_protected(self, value: bool) -> None:
        self.option_bytes[OB_RDP] = RDP_LEVEL1 if value else RDP_LEVEL0

    @property
    def write_protected(self) -> frozenset[int]:
        """Sectors whose nWRP bit is 0."""
        nwrp = int.from_bytes(self.option_bytes[OB_NWRP:OB_NWRP + 2], "little")
        return frozenset(i for i in range(len(self.sectors)) if not nwrp >> i & 1)

    @property
    def erased_sectors(self) -> int:
        """Sector erases done so far (all sectors together)."""
        return sum(self.erase_counts)

    @property
    def running(self) -> bool:
        """A Go was accepted: the application runs, the bootloader answers nothing."""
        return self._state == "running"

    @property
    def state(self) -> str:
        """"sync" (waiting for 0x7F), "command" (waiting for a command byte), "busy" (in a
        command), "running" (after Go) or "silent" (hung by ``silent_after_bytes``)."""
        if self.silent_after_bytes is not None and self.received_bytes >= self.silent_after_bytes:
            return "silent"
        return self._state

    def go_vector(self) -> tuple[int, int] | None:
        """(initial stack pointer, reset handler) the last Go branched with: the words at
        go_address and go_address + 4 (AN3155 §3.5), or None before a Go."""
        if self.go_address is None:
            return None
        words = self.peek(self.go_address, 8)
        return int.from_bytes(words[:4], "little"), int.from_bytes(words[4:], "little")

    def peek(self, address: int, length: int) -> bytes:
        """Memory as the chip holds it (any region, the bootloader's RAM included)."""
        found = self._locate(address, length, ("flash", "ram", "bootloader ram", "system memory",
                                               "otp", "option bytes"))
        if found is None:
            raise ValueError(f"{length} bytes at {address:#010x} are not in one memory region")
        _, buffer, offset = found
        return bytes(buffer[offset:offset + length])

    # ------------------------------------------------------------------ the wire

    def receive(self, data: bytes) -> bytes:
        """Bytes from the host; returns the bytes the chip sends back meanwhile."""
        for byte in bytes(data):
            if self.silent_after_bytes is not None and self.received_bytes >= self.silent_after_bytes:
                self.received_bytes += 1
                continue
            self.received_bytes += 1
            self._machine.send(byte)
            if self.reset_after_bytes is not None and self.received_bytes == self.reset_after_bytes:
                self.reset("injected")
        answer = bytes(self._out)
        self._out.clear()
        return answer

    def reset(self, cause: str = "external") -> None:
        """A chip reset (NRST): back to waiting for 0x7F; memory is kept, a command in
        progress is lost."""
        self._count_reset(cause)
        self._machine = self._start()

    def _count_reset(self, cause: str) -> None:
        self.resets += 1
        self.log.append(LogEntry("Reset", {"cause": cause}, "reset"))

    def _start(self) -> Generator[None, int, None]:
        machine = self._session()
        next(machine)
        return machine

    def _send(self, *data: int | bytes) -> None:
        for item in data:
            if isinstance(item, int):
                self._out.append(item)
            else:
                self._out += item

    def _refuse(self, command: str, args: dict, reason: str) -> None:
        self._send(NACK)
        self.log.append(LogEntry(command, {**args, "reason": reason}, "NACK"))

    def _accept(self, command: str, args: dict | None = None) -> None:
        self._send(ACK)
        self.log.append(LogEntry(command, args or {}, "ACK"))

    def _session(self) -> Generator[None, int, None]:
        """The bootloader from reset on: a generator fed one received byte per send()."""
        handlers = {
            0x00: self._get, 0x01: self._get_version, 0x02: self._get_id,
            0x11: self._read_memory, 0x21: self._go, 0x31: self._write_memory,
            0x44: self._extended_erase, 0x63: self._write_protect,
            0x73: self._write_unprotect, 0x82: self._readout_protect,
            0x92: self._readout_unprotect,
        }
        while True:
            self._state = "sync"
            # AN3155 §1: wait for 0x7F, ignore anything else. RDP level 2 disables boot
            # from system memory (RM0090 §3.6.3): the bootloader never answers.
            while (yield) != SYNC or self.option_bytes[OB_RDP] == RDP_LEVEL2:
                pass
            self._accept("Sync")
            outcome = None
            while outcome != _RESET:
                self._state = "command"
                code = yield
                complement = yield
                name = COMMAND_NAMES.get(code, f"0x{code:02X}")
                self._state = "busy"
                if code ^ complement != 0xFF:
                    self._refuse(name, {"bytes": (code, complement)}, "bad complement")
                    continue
                handler = handlers.get(code)
                if handler is None:
                    self._refuse(name, {}, "not supported")
                elif code in self.nack_commands:
                    self._refuse(name, {}, "injected")
                elif self.read_protected and code not in ALLOWED_WHEN_PROTECTED:
                    self._refuse(name, {}, "read protection")
                else:
                    outcome = yield from handler()
                    if outcome == _GO:
                        self._state = "running"
                        while True:  # the application runs: nothing reaches the bootloader
                            yield
            self._count_reset(self.log[-1].command)  # the command that reset the chip

    # ------------------------------------------------------------------ memory map

    def _regions(self) -> tuple[tuple[str, int, bytearray | bytes, int], ...]:
        """(kind, start address, buffer, buffer offset of the start) of every region."""
        return (
            ("flash", FLASH_BASE, self.flash, 0),
            ("ram", USER_RAM_BASE, self.ram, BOOTLOADER_RAM_SIZE),
            ("bootloader ram", RAM_BASE, self.ram, 0),
            ("system memory", SYSTEM_MEMORY_BASE, self.system_memory, 0),
            ("otp", OTP_BASE, self.otp, 0),
            ("device info", DEVICE_INFO_BASE, self.device_info, 0),
            ("option bytes", OPTION_BYTES_BASE, self.option_bytes, 0),
        )

    def _locate(self, address: int, length: int, kinds: Iterable[str]):
        """(kind, buffer, offset) when [address, address + length) lies in one region of
        one of `kinds`, else None."""
        for kind, start, buffer, base in self._regions():
            size = len(buffer) - base if kind != "bootloader ram" else BOOTLOADER_RAM_SIZE
            if kind in kinds and start <= address and address + length <= start + size:
                return kind, buffer, base + address - start
        return None

    def _sector_of(self, offset: int) -> int:
        for index, (start, size) in enumerate(self.sectors):
            if start <= offset < start + size:
                return index
        raise ValueError(offset)

    def _erase_sector(self, index: int, *, force: bool = False) -> None:
        if index in self.write_protected and not force:
            return  # no error, nothing erased (AN3155 §3.8 note)
        start, size = self.sectors[index]
        self.flash[start:start + size] = b"\xff" * size
        self.erase_counts[index] += 1

    # ------------------------------------------------------------------ receiving

    @staticmethod
    def _bytes(n: int) -> Generator[None, int, bytes]:
        data = bytearray()
        for _ in range(n):
            data.append((yield))
        return bytes(data)

    def _address(self) -> Generator[None, int, tuple[int, bool]]:
        """Four address bytes, MSB first, and their XOR checksum (AN3155 §3.4-§3.6)."""
        data = yield from self._bytes(5)
        return int.from_bytes(data[:4], "big"), xor(data[:4]) == data[4]

    # ------------------------------------------------------------------ the commands

    def _get(self):
        """AN3155 §3.1: ACK, N = 11 (bytes that follow - 1), version, the commands, ACK."""
        yield from ()  # every handler is a generator (most of them receive more bytes)
        self._send(ACK, len(SUPPORTED_COMMANDS), self.bootloader_version, bytes(SUPPORTED_COMMANDS), ACK)
        self.log.append(LogEntry("Get", {}, "ACK"))
        return None

    def _get_version(self):
        """AN3155 §3.2: ACK, version, two option bytes 0x00 (legacy compatibility), ACK."""
        yield from ()
        self._send(ACK, self.bootloader_version, 0x00, 0x00, ACK)
        self.log.append(LogEntry("Get Version", {}, "ACK"))
        return None

    def _get_id(self):
        """AN3155 §3.3: ACK, N = 1, the product ID MSB first, ACK."""
        yield from ()
        self._send(ACK, 0x01, self.device_id.to_bytes(2, "big"), ACK)
        self.log.append(LogEntry("Get ID", {}, "ACK"))
        return None

    def _read_memory(self):
        """AN3155 §3.4: ACK; address + checksum -> ACK if readable; N + ~N -> ACK and N + 1
        bytes. The whole range must lie in one readable region (else NACK after N)."""
        readable = ("flash", "ram", "system memory", "otp", "device info", "option bytes")
        self._send(ACK)
        address, ok = yield from self._address()
        args = {"address": address}
        if not ok:
            return self._refuse("Read Memory", args, "address checksum")
        if self._locate(address, 1, readable) is None:
            return self._refuse("Read Memory", args, "address not readable")
        self._send(ACK)
        n = yield
        complement = yield
        args["length"] = n + 1
        if n ^ complement != 0xFF:
            return self._refuse("Read Memory", args, "length checksum")
        found = self._locate(address, n + 1, readable)
        if found is None:
            return self._refuse("Read Memory", args, "range not readable")
        _, buffer, offset = found
        self._accept("Read Memory", args)
        self._send(bytes(buffer[offset:offset + n + 1]))
        return None

    def _go(self):
        """AN3155 §3.5: ACK; address + checksum -> ACK and the jump when the address is in
        flash or in the RAM the bootloader does not use (else NACK)."""
        self._send(ACK)
        address, ok = yield from self._address()
        args = {"address": address}
        if not ok:
            return self._refuse("Go", args, "address checksum")
        if self._locate(address, 1, ("flash", "ram")) is None:
            return self._refuse("Go", args, "address not valid")
        self._accept("Go", args)
        self.go_address = address
        return _GO

    def _write_memory(self):
        """AN3155 §3.6: ACK; address + checksum -> ACK if writable; N, N + 1 bytes,
        XOR(N, data) -> ACK once written.

        The start address must be in flash, in the RAM the bootloader does not use, or be
        the option bytes' base address (AN3155 §3.6); else NACK after the address. After
        the data: NACK for a bad checksum, N + 1 not a multiple of 4 (AN3155 Figures 12
        and 13), a range leaving its region, or flash bytes that do not read back as sent
        (not erased: see the module docstring). AN3155 §3.6 also notes "no error is
        returned when the start address is invalid"; the model follows the section's
        text and V3.1's fix (§4 Table 3) instead: NACK. No alignment of the address is required
        (AN3155 states none; the F4 flash programs bytes). Bytes of write-protected
        sectors are left as they are, without error. Option bytes: all 16 are erased,
        the data written from 0x1FFFC000, then ACK and a system reset (F4)."""
        self._send(ACK)
        address, ok = yield from self._address()
        args = {"address": address}
        if not ok:
            return self._refuse("Write Memory", args, "address checksum")
        target = self._locate(address, 1, ("flash", "ram", "option bytes"))
        if target is None or (target[0] == "option bytes" and address != OPTION_BYTES_BASE):
            return self._refuse("Write Memory", args, "address not writable")
        self._send(ACK)
        n = yield
        data = yield from self._bytes(n + 1)
        checksum = yield
        args["length"] = n + 1
        if xor(data) ^ n != checksum:
            return self._refuse("Write Memory", args, "data checksum")
        if (n + 1) % 4:
            return self._refuse("Write Memory", args, "length not a multiple of 4")
        found = self._locate(address, n + 1, (target[0],))
        if found is None:
            return self._refuse("Write Memory", args, "range leaves the memory")
        kind, buffer, offset = found
        if kind == "option bytes":
            self.option_bytes[:] = b"\xff" * OPTION_BYTES_SIZE
            self.option_bytes[:n + 1] = data
            self.written_bytes += n + 1
            self._accept("Write Memory", args)
            return _RESET
        if kind == "ram":
            buffer[offset:offset + n + 1] = data
        else:
            protected = self.write_protected
            failed = False
            for i, value in enumerate(data):
                if self._sector_of(offset + i) in protected:
                    continue
                self.flash[offset + i] &= value
                failed |= self.flash[offset + i] != value
            if failed:
                return self._refuse("Write Memory", args, "flash not erased")
        self.written_bytes += n + 1
        self._accept("Write Memory", args)
        return None

    def _extended_erase(self):
        """AN3155 §3.8: ACK; N on two bytes MSB first; for N = 0xFFFY one checksum byte
        (XOR of the two), else N + 1 sector numbers on two bytes MSB first and the XOR of
        every byte from N on; ACK once erased.

        0xFFFF erases every sector. The F405/407 has one bank (RM0090 §3.3): the bank
        erases 0xFFFE and 0xFFFD are NACKed, like the reserved 0xFFF0..0xFFFC. A page
        count beyond the sectors or a sector number that does not exist is NACKed and
        nothing is erased. Write-protected sectors stay as they are, without error."""
        self._send(ACK)
        head = yield from self._bytes(2)
        n = int.from_bytes(head, "big")
        if n >= 0xFFF0:
            checksum = yield
            args = {"special": n}
            if checksum != xor(head):
                return self._refuse("Extended Erase", args, "checksum")
            if n != MASS_ERASE:
                reason = "single-bank device" if n in (BANK1_ERASE, BANK2_ERASE) else "reserved code"
                return self._refuse("Extended Erase", args, reason)
            for index in range(len(self.sectors)):
                self._erase_sector(index)
            self._accept("Extended Erase", args)
            return None
        codes = yield from self._bytes(2 * (n + 1))
        checksum = yield
        sectors = [int.from_bytes(codes[i:i + 2], "big") for i in range(0, len(codes), 2)]
        args = {"sectors": sectors}
        if checksum != xor(head) ^ xor(codes):
            return self._refuse("Extended Erase", args, "checksum")
        if n + 1 > len(self.sectors) or any(s >= len(self.sectors) for s in sectors):
            return self._refuse("Extended Erase", args, "no such sector")
        for index in sectors:
            self._erase_sector(index)
        self._accept("Extended Erase", args)
        return None

    def _write_protect(self):
        """AN3155 §3.9: ACK; N, N + 1 sector codes, XOR(N, codes) -> ACK, system reset.

        The sectors listed become the only protected ones (a second Write Protect
        replaces the first). Numbers of sectors that do not exist are not checked and
        have no effect (AN3155 §3.9 note). A bad checksum is NACKed, without reset."""
        self._send(ACK)
        n = yield
        codes = yield from self._bytes(n + 1)
        checksum = yield
        args = {"sectors": list(codes)}
        if xor(codes) ^ n != checksum:
            return self._refuse("Write Protect", args, "checksum")
        nwrp = 0x0FFF
        for code in codes:
            if code < len(self.sectors):
                nwrp &= ~(1 << code)
        self.option_bytes[OB_NWRP:OB_NWRP + 2] = nwrp.to_bytes(2, "little")
        self._accept("Write Protect", args)
        return _RESET

    def _write_unprotect(self):
        """AN3155 §3.10: ACK, every sector unprotected, ACK, system reset."""
        yield from ()
        self._send(ACK)
        self.option_bytes[OB_NWRP:OB_NWRP + 2] = (0x0FFF).to_bytes(2, "little")
        self._accept("Write Unprotect")
        return _RESET

    def _readout_protect(self):
        """AN3155 §3.11: ACK, RDP level 1, ACK, system reset."""
        yield from ()
        self._send(ACK)
        self.read_protected = True
        self._accept("Readout Protect")
        return _RESET

    def _readout_unprotect(self):
        """AN3155 §3.12: ACK, every flash sector erased (write protection or not: the RDP
        regression mass-erases the flash), RAM cleared to 0 (AN3155 §4 Table 3, V2.2),
        RDP level 0, ACK, system reset. Served with or without read protection."""
        yield from ()
        self._send(ACK)
        for index in range(len(self.sectors)):
            self._erase_sector(index, force=True)
        self.ram[:] = bytes(RAM_SIZE)
        self.read_protected = False
        self._accept("Readout Unprotect")
        return _RESET


# ---------------------------------------------------------------------------- on a pty

_POLL_S = 0.05


class _Stream:
    """What on_go returned, as read() / write() / fileno() / close(); a socket (recv and
    send) is accepted too and made non-blocking."""

    def __init__(self, obj: Any):
        self.obj = obj
        if hasattr(obj, "recv") and hasattr(obj, "send"):
            obj.setblocking(False)
            self._read: Callable[[], bytes] = lambda: obj.recv(65536)
            self._write: Callable[[bytes], int] = obj.send
        else:
            self._read, self._write = obj.read, obj.write

    def fileno(self) -> int:
        return self.obj.fileno()

    def read(self) -> bytes | None:
        """Bytes, b"" at end of stream, None when nothing is there after all."""
        try:
            return self._read()
        except (BlockingIOError, InterruptedError):
            return None
        except OSError:
            return b""

    def write(self, data: bytes) -> int:
        try:
            return self._write(data) or 0
        except (BlockingIOError, InterruptedError):
            return 0

    def close(self) -> None:
        try:
            self.obj.close()
        except OSError:
            pass


class BootloaderPort:
    """A :class:`Stm32Bootloader` behind a pseudo-terminal, served by a thread.

    A host opens ``address`` with pyserial (115200 8E1 as AN3155 asks: a pty ignores the
    line settings) and talks AN3155 to ``bootloader``. After a Go, ``on_go(address,
    flash_bytes)`` is called once (address: the Go address; flash_bytes: a copy of the
    flash); it may return an object with ``fileno()``, ``read() -> bytes``,
    ``write(bytes) -> int`` and ``close()``, or a socket: from then on the port carries
    bytes both ways between the pty and that object (the firmware the host just flashed
    answers on the same port). Without a callback, or when it returns None, or when the
    object reaches its end, the port stays silent after Go.

    ``start()`` / ``stop()``, or use it as a context manager. ``error`` holds what
    stopped the thread early, ``bridge`` the object on_go returned.

    Line settings: a pty has no parity. Linux clears PARENB on a pty, and some kernels
    (this project's machines among them) then answer EINVAL to a tcsetattr whose only
    change is PARENB: pyserial's open at 8E1 works (it changes the speed too), but a
    later reconfiguration that changes nothing else (setting ``timeout`` after open,
    reopening at the same settings) raises ``termios.error`` / SerialException. Give
    pyserial every setting when opening.
    """

    def __init__(self, bootloader: Stm32Bootloader | None = None, *,
                 on_go: Callable[[int, bytes], Any] | None = None):

        self.bootloader = bootloader if bootloader is not None else Stm32Bootloader()
        self.on_go = on_go
        self._front = PtyFront()
        self.address = self._front.address
        self.bridge: _Stream | None = None
        self.error: BaseException | None = None
        self._went = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> BootloaderPort:
        self._thread = threading.Thread(target=self._run, name=f"stm32 bootloader {self.address}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self.bridge is not None:
            self.bridge.close()
        self._front.close()

    def __enter__(self) -> BootloaderPort:
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # surfaced through .error
            self.error = exc

    def _loop(self) -> None:
        master = self._front.fileno()
        to_host = bytearray()
        to_bridge = bytearray()
        while not self._stop.is_set():
            bridge = self.bridge
            readable = [master] + ([bridge.fileno()] if bridge is not None else [])
            writable = ([master] if to_host else []) + (
                [bridge.fileno()] if bridge is not None and to_bridge else [])
            ready_r, _, _ = select.select(readable, writable, [], _POLL_S)
            if master in ready_r:
                data = self._front.read()
                if bridge is not None:
                    to_bridge += data
                elif data:
                    to_host += self.bootloader.receive(data)
                    if self.bootloader.running and not self._went:
                        self._went = True
                        self._boot()
            if bridge is not None and bridge.fileno() in ready_r:
                answer = bridge.read()
                if answer == b"":
                    bridge.close()
                    self.bridge = bridge = None
                    to_bridge.clear()
                elif answer:
                    to_host += answer
            if to_host:
                del to_host[:self._front.write(bytes(to_host))]
            if bridge is not None and to_bridge:
                del to_bridge[:bridge.write(bytes(to_bridge))]

    def _boot(self) -> None:
        if self.on_go is None:
            return
        assert self.bootloader.go_address is not None  # called once the bootloader runs: after a Go
        target = self.on_go(self.bootloader.go_address, bytes(self.bootloader.flash))
        if target is not None:
            self.bridge = _Stream(target)


__all__ = ["ACK", "NACK", "SYNC", "BootloaderPort", "LogEntry", "Stm32Bootloader", "xor"]
