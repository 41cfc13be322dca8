"""The DMA controllers DMA1 and DMA2 (RM0090 section 10): LISR/HISR, LIFCR/HIFCR and the eight
streams' CR, NDTR, PAR, M0AR, M1AR, FCR with their reset values (10.5).

Modelled: memory-to-peripheral transfers in direct mode, one byte per request of the
peripheral the stream's CHSEL selects (a USART's TX request while TXE is set: 30.3.13),
MINC, the transfer-complete and half-transfer flags and interrupts, EN cleared by the hardware
at the end, a transfer error (TEIF) when the memory cannot be read. Checked (each breach
reported): a stream's configuration written while it is enabled (10.3.17), EN set while its
flags from the last transfer are not cleared (10.5.5), EN set with NDTR = 0.
Not modelled (reported when used): peripheral-to-memory and memory-to-memory transfers,
circular and double-buffer modes, the FIFO, bursts, items wider than a byte, priorities
between streams.
"""
from __future__ import annotations

from collections.abc import Callable

import unicorn

from imulink.board.stm32f407.peripheral import Peripheral

EN, HTIE, TCIE, TEIE = 1, 1 << 3, 1 << 4, 1 << 2
DIR_MASK, DIR_M2P = 3 << 6, 1 << 6
MINC, CIRC, DBM = 1 << 10, 1 << 8, 1 << 18
FEIF, DMEIF, TEIF, HTIF, TCIF = 0x01, 0x04, 0x08, 0x10, 0x20
SHIFTS = (0, 6, 16, 22)
#: The streams' interrupts (RM0090 table 61).
IRQS = {1: (11, 12, 13, 14, 15, 16, 17, 47), 2: (56, 57, 58, 59, 60, 68, 69, 70)}


class Stream:
    def __init__(self) -> None:
        self.cr = self.ndtr = self.par = self.m0ar = self.m1ar = 0
        self.fcr = 0x21
        self.flags = 0
        self.done = 0  # items moved in this transfer
        self.length = 0


class Dma(Peripheral):
    def __init__(self, soc, number: int, base: int):
        self.name = f"DMA{number}"
        self.number = number
        self.gate = ("AHB1ENR", 20 + number)
        self.reset_bit = ("AHB1RSTR", 20 + number)
        #: (stream, channel) -> whether that peripheral's request is raised now
        self.requests: dict[tuple[int, int], Callable[[], bool]] = {}
        super().__init__(soc, base)

    def reset(self) -> None:
        self.streams = [Stream() for _ in range(8)]
        if hasattr(self.soc, "core"):
            for k in range(8):
                self._line(k)

    # ------------------------------------------------------------------ transfers

    def request(self, stream: int, channel: int) -> None:
        """The peripheral on `channel` of `stream` asks for a data item."""
        s = self.streams[stream]
        if not s.cr & EN or (s.cr >> 25) & 7 != channel or s.ndtr == 0:
            return
        address = s.m0ar + (s.done if s.cr & MINC else 0)
        try:
            byte = bytes(self.soc.core.uc.mem_read(address, 1))[0]
        except unicorn.UcError:
            self.report(f"stream {stream}: transfer error reading 0x{address:08X}")
            s.flags |= TEIF
            s.cr &= ~EN
            self._line(stream)
            return
        s.done += 1
        s.ndtr -= 1
        if s.done * 2 == s.length:
            s.flags |= HTIF
        if s.ndtr == 0:
            s.flags |= TCIF
            s.cr &= ~EN
        self._line(stream)
        self.soc.write(s.par, byte)

    def _line(self, stream: int) -> None:
        s = self.streams[stream]
        raised = (s.flags & TCIF and s.cr & TCIE or s.flags & HTIF and s.cr & HTIE
                  or s.flags & TEIF and s.cr & TEIE)
        self.soc.core.raise_line(IRQS[self.number][stream], bool(raised))

    def _start(self, stream: int) -> None:
        s = self.streams[stream]
        if s.flags:
            self.report(f"stream {stream} enabled with its flags from the last transfer set (RM0090 10.5.5)")
        if s.ndtr == 0:
            self.report(f"stream {stream} enabled with NDTR = 0")
        if s.cr & DIR_MASK != DIR_M2P or s.cr & (CIRC | DBM) or s.fcr & 0x4 or s.cr & (0xF << 11):
            self.report(f"stream {stream}: only byte-wide memory-to-peripheral transfers in direct mode are modelled")
        s.done, s.length = 0, s.ndtr
        active = self.requests.get((stream, (s.cr >> 25) & 7))
        if active is not None and active():
            self.request(stream, (s.cr >> 25) & 7)

    # ------------------------------------------------------------------ registers

    def read(self, offset: int) -> int:
        if offset in (0x00, 0x04):
            first = 0 if offset == 0x00 else 4
            return sum(self.streams[first + k].flags << SHIFTS[k] for k in range(4))
        if offset in (0x08, 0x0C):
            return 0  # write-only
        if 0x10 <= offset < 0xD0:
            s = self.streams[(offset - 0x10) // 0x18]
            return (s.cr, s.ndtr, s.par, s.m0ar, s.m1ar, s.fcr)[(offset - 0x10) % 0x18 // 4]
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset in (0x08, 0x0C):
            first = 0 if offset == 0x08 else 4
            for k in range(4):
                stream = self.streams[first + k]
                stream.flags &= ~(value >> SHIFTS[k] & 0x3D)
                self._line(first + k)
            return
        if offset in (0x00, 0x04) or not 0x10 <= offset < 0xD0:
            self.unmodelled(offset, True)
            return
        index = (offset - 0x10) // 0x18
        s = self.streams[index]
        register = (offset - 0x10) % 0x18 // 4
        if s.cr & EN and not (register == 0 and value & ~EN == s.cr & ~EN):
            self.report(f"stream {index}: register offset 0x{offset:02X} written while the stream is enabled "
                        "(RM0090 10.3.17: only EN may be cleared)")
            if register == 0 and not value & EN:
                s.cr &= ~EN
            return
        if register == 0:
            starting = value & EN and not s.cr & EN
            s.cr = value & 0x0FEF_FFFF
            if starting:
                self._start(index)
            self._line(index)
        elif register == 1:
            s.ndtr = value & 0xFFFF
        elif register == 2:
            s.par = value
        elif register == 3:
            s.m0ar = value
        elif register == 4:
            s.m1ar = value
        else:
            s.fcr = (value & 0x87) | (s.fcr & 0x38)  # FS (the FIFO's level) is read-only
