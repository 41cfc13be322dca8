"""The host side of the STM32 system-memory bootloader's USART protocol (ST application
note AN3155), as `imulink flash` uses it.

Line: 8 data bits, even parity, 1 stop bit, 1200-115200 baud; the bootloader measures the
rate from the first byte, 0x7F, and answers ACK (0x79). Every command is a byte followed
by its complement; every answer is ACK or NACK (0x1F). Addresses go MSB first followed by
their XOR checksum; data blocks are at most 256 bytes. The commands used here: Get (0x00),
Get ID (0x02), Read Memory (0x11), Go (0x21), Write Memory (0x31), Extended Erase (0x44)
or the older Erase (0x43), Readout Unprotect (0x92).

:class:`Bootloader` speaks it over any pyserial port object; every failure is a
:class:`BootloaderError` with a message fit for a user.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from functools import reduce

from imulink.errors import ImulinkError

ACK = 0x79
NACK = 0x1F
SYNC = 0x7F

CMD_GET = 0x00
CMD_GET_ID = 0x02
CMD_READ_MEMORY = 0x11
CMD_GO = 0x21
CMD_WRITE_MEMORY = 0x31
CMD_ERASE = 0x43
CMD_EXTENDED_ERASE = 0x44
CMD_READOUT_UNPROTECT = 0x92

#: Largest block of Read Memory and Write Memory.
BLOCK = 256
#: 0x7F bytes sync() sends at most: enough to end an interrupted Write Memory (258 bytes).
SYNC_BYTES = 320
#: Seconds an answer may take: a command's ACK, a block write (flash programming takes
#: about 16 us a word on the F4, a 256-byte block well under 10 ms).
ANSWER_TIMEOUT_S = 1.0
#: Seconds one sector's erase may take (RM0090 / DS8626: a 128 KiB sector up to 2 s at x32
#: parallelism, longer at lower supply voltages), and a whole mass erase.
SECTOR_ERASE_TIMEOUT_S = 5.0
MASS_ERASE_TIMEOUT_S = 40.0

NAMES = {CMD_GET: "Get", CMD_GET_ID: "Get ID", CMD_READ_MEMORY: "Read Memory", CMD_GO: "Go",
         CMD_WRITE_MEMORY: "Write Memory", CMD_ERASE: "Erase", CMD_EXTENDED_ERASE: "Extended Erase",
         CMD_READOUT_UNPROTECT: "Readout Unprotect"}


class BootloaderError(ImulinkError):
    """The bootloader did not do what was asked (one line, with what to do)."""


class NoAnswer(BootloaderError):
    """Nothing answered where the bootloader should have."""


class Refused(BootloaderError):
    """A NACK."""


@dataclass(frozen=True)
class BootloaderInfo:
    version: int  # e.g. 0x31 for 3.1
    commands: tuple[int, ...]

    @property
    def version_text(self) -> str:
        return f"{self.version >> 4}.{self.version & 0xF}"


def checksum(data: bytes) -> int:
    """XOR of all bytes (AN3155's checksum of addresses, counts and data)."""
    return reduce(lambda a, b: a ^ b, data, 0)


class Bootloader:
    """An STM32 bootloader on `port`: a pyserial port opened at 8E1 with a short read timeout
    (about 0.1 s; it is not changed here: some drivers, ptys among them, refuse to set
    line parameters again on an open port)."""

    def __init__(self, port, timeout_s: float = ANSWER_TIMEOUT_S):
        self.port = port
        self.timeout_s = timeout_s
        self.info: BootloaderInfo | None = None

    # ------------------------------------------------------------------ bytes

    def _read(self, n: int, timeout_s: float | None = None, what: str = "an answer") -> bytes:
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        out = bytearray()
        while len(out) < n:
            left = deadline - time.monotonic()
            if left <= 0:
                raise NoAnswer(f"the bootloader stopped answering ({what}; got {len(out)} of {n} bytes)")
            out += self.port.read(n - len(out))
        return bytes(out)

    def _write(self, data: bytes) -> None:
        self.port.write(data)
        self.port.flush()

    def _expect_ack(self, what: str, timeout_s: float | None = None) -> None:
        answer = self._read(1, timeout_s, what)[0]
        if answer == NACK:
            raise Refused(f"the bootloader refused {what} (NACK)")
        if answer != ACK:
            raise BootloaderError(f"the bootloader answered {what} with 0x{answer:02X}, neither ACK nor NACK "
                                  "(noise on the line, or not a bootloader?)")

    def _command(self, code: int) -> None:
        self._write(bytes((code, code ^ 0xFF)))
        self._expect_ack(f"the {NAMES.get(code, hex(code))} command")

    def _address(self, address: int, what: str) -> None:
        raw = address.to_bytes(4, "big")
        self._write(raw + bytes((checksum(raw),)))
        self._expect_ack(f"the address 0x{address:08X} of {what}")

    # ------------------------------------------------------------------ commands

    def sync(self) -> None:
        """Make the bootloader measure the baud rate (0x7F -> ACK), or find the start of a command
        again when an earlier run stopped midway: the bootloader then takes the 0x7F bytes as the
        rest of the interrupted command (or as a command with a wrong complement) and answers NACK
        once that ends. Either answer is followed by a Get, which must come back whole."""
        self.port.reset_input_buffer()
        sent = 0
        while sent < SYNC_BYTES:
            burst = 1 if sent < 8 else 16  # one at a time first: a fresh bootloader answers the first
            self._write(bytes((SYNC,)) * burst)
            sent += burst
            if self._drain(0.05) and self._answers_get():
                return
        raise NoAnswer("no STM32 bootloader answered the synchronisation byte 0x7F: is BOOT0 high and was the "
                       "board reset (or use --enter), is this the port wired to USART1 (PA9/PA10)?")

    def _drain(self, quiet_s: float) -> bytes:
        """Everything that arrives until the line has been quiet for `quiet_s`."""
        out = bytearray()
        while True:
            deadline = time.monotonic() + quiet_s
            chunk = b""
            while not chunk and time.monotonic() < deadline:
                chunk = self.port.read(256)
            if not chunk:
                return bytes(out)
            out += chunk

    def _answers_get(self) -> bool:
        try:
            self.get()
        except BootloaderError:
            self._drain(0.05)
            return False
        return True

    def get(self) -> BootloaderInfo:
        """Get (0x00): the bootloader version and the commands it knows."""
        self._command(CMD_GET)
        n = self._read(1, what="the length of Get's answer")[0]
        body = self._read(n + 1, what="Get's answer")
        self._expect_ack("Get")
        self.info = BootloaderInfo(body[0], tuple(body[1:]))
        return self.info

    def get_id(self) -> int:
        """Get ID (0x02): the device id (0x413 for the STM32F405/407)."""
        self._command(CMD_GET_ID)
        n = self._read(1, what="the length of Get ID's answer")[0]
        pid = self._read(n + 1, what="Get ID's answer")
        self._expect_ack("Get ID")
        return int.from_bytes(pid, "big")

    def read_memory(self, address: int, length: int) -> bytes:
        """Read Memory (0x11), at most 256 bytes. A NACK on a readable address means readout
        protection is on."""
        if not 0 < length <= BLOCK:
            raise ValueError(f"read length {length} outside 1..{BLOCK}")
        self._command(CMD_READ_MEMORY)
        self._address(address, "Read Memory")
        self._write(bytes((length - 1, (length - 1) ^ 0xFF)))
        self._expect_ack("the length of Read Memory")
        return self._read(length, what=f"the bytes at 0x{address:08X}")

    def write_memory(self, address: int, data: bytes) -> None:
        """Write Memory (0x31), at most 256 bytes, a multiple of 4 (flash is programmed in words)."""
        if not 0 < len(data) <= BLOCK or len(data) % 4:
            raise ValueError(f"write block of {len(data)} bytes: must be 4..{BLOCK} and a multiple of 4")
        self._command(CMD_WRITE_MEMORY)
        self._address(address, "Write Memory")
        block = bytes((len(data) - 1,)) + data
        self._write(block + bytes((checksum(block),)))
        self._expect_ack(f"the {len(data)} bytes written at 0x{address:08X}")

    def erase_sectors(self, sectors: list[int]) -> None:
        """Erase flash sectors (pages): Extended Erase (0x44) where the bootloader has it, else
        the original Erase (0x43, one byte per page)."""
        commands = self.info.commands if self.info else ()
        timeout = SECTOR_ERASE_TIMEOUT_S * len(sectors)
        if CMD_EXTENDED_ERASE in commands or not commands:
            self._command(CMD_EXTENDED_ERASE)
            body = (len(sectors) - 1).to_bytes(2, "big") + b"".join(s.to_bytes(2, "big") for s in sectors)
        elif CMD_ERASE in commands:
            self._command(CMD_ERASE)
            body = bytes((len(sectors) - 1, *sectors))
        else:
            raise BootloaderError("this bootloader has no erase command")
        self._write(body + bytes((checksum(body),)))
        self._expect_ack(f"the erase of sector(s) {', '.join(map(str, sectors))}", timeout)

    def go(self, address: int) -> None:
        """Go (0x21): start the code whose vector table is at `address`."""
        self._command(CMD_GO)
        self._address(address, "Go")

    def readout_unprotect(self) -> None:
        """Readout Unprotect (0x92): erase the whole flash and clear the protection; the chip
        resets and the bootloader must be synchronised again."""
        self._command(CMD_READOUT_UNPROTECT)
        self._expect_ack("Readout Unprotect (the flash was being erased)", MASS_ERASE_TIMEOUT_S)
