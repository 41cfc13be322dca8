"""USART1..3, UART4/5, USART6 in asynchronous mode (RM0090 section 30): SR, DR, BRR, CR1-CR3,
GTPR; the baud rate from BRR and the clock the bus actually gives (30.3.4: Tx/Rx baud =
fCK / (8 x (2 - OVER8) x USARTDIV)); frames of 1 start, 8 or 9 data (M), 0.5-2 stop bits
(CR2.STOP); the transmitter (DR -> shift register, TXE, TC; an idle frame first after TE is
set, 30.3.2), the receiver (RXNE, ORE when a byte completes while RXNE is still set, 30.3.3;
FE for a byte sent at a baud more than 3 % off), the SR/DR read sequence that clears ORE,
IDLE, NF, FE and PE, TC cleared by SR read + DR write or by writing 0, the interrupt line
(TXEIE, TCIE, RXNEIE also for ORE, IDLEIE, PEIE: 30.4), and the pins (TX and RX must be in
their alternate function, or nothing leaves or arrives).

The other side of the line is ``peer``: ``receive(byte, baud)`` gets each byte that leaves
TX at the time it has left; :meth:`Usart.send` queues bytes that arrive on RX at the peer's
baud, one frame time apart. Not modelled: parity, LIN, smartcard, IrDA, hardware flow control,
DMA for reception (reported), synchronous mode. The transmitter's DMA request
(CR3.DMAT) goes to the stream the board wires it to (imulink.board.stm32f407.dma).
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Protocol

from imulink.board.stm32f407.clock import Event, period_ps
from imulink.board.stm32f407.gpio import GpioPort
from imulink.board.stm32f407.peripheral import Peripheral

SR, DR, BRR, CR1, CR2, CR3, GTPR = range(0, 0x1C, 4)
PE, FE, NF, ORE, IDLE, RXNE, TC, TXE = (1 << b for b in range(8))
DMAR, DMAT = 1 << 6, 1 << 7  # CR3
SBK, RWU, RE, TE, IDLEIE, RXNEIE, TCIE, TXEIE, PEIE, PS, PCE, WAKE, M, UE, _, OVER8 = (1 << b for b in range(16))
#: The largest baud error a receiver samples correctly (30.3.5 gives 3.75 % to 4.375 %).
BAUD_TOLERANCE = 0.03


class Peer(Protocol):
    def receive(self, byte: int, baud: float) -> None: ...


class Usart(Peripheral):
    def __init__(self, soc, name: str, base: int, bus: int, gate_bit: int, irq: int,
                 pins: tuple[GpioPort, int, int, int]):
        self.name = name
        self.bus = bus
        register = "APB1" if bus == 1 else "APB2"
        self.gate = (register + "ENR", gate_bit)
        self.reset_bit = (register + "RSTR", gate_bit)
        self.irq = irq
        self.port, self.tx_pin, self.rx_pin, self.af = pins
        self.peer: Peer | None = None
        self.incoming: deque[tuple[int, float]] = deque()  # (byte, baud) waiting to arrive on RX
        self.sent = 0
        self.received = 0
        self.overruns = 0
        self._tx_event: Event | None = None
        self._rx_event: Event | None = None
        #: Called when the transmitter requests DMA (CR3.DMAT and TXE): the DMA stream's request.
        self.tx_dma: Callable[[], None] | None = None  # kept over a reset: the line goes on delivering what is on it
        super().__init__(soc, base)
        self.status = frozenset({SR})

    def reset(self) -> None:
        if self._tx_event is not None:
            self._tx_event.cancel()
        self.sr = TXE | TC
        self.dr_rx = 0
        self.tdr: int | None = None
        self.shifting: int | None = None
        self.brr = self.cr1 = self.cr2 = self.cr3 = self.gtpr = 0
        self._sr_read = False
        self._tx_event = None
        self._warned_pins = False
        if hasattr(self, "incoming"):
            self._line()

    # ------------------------------------------------------------------ timing

    def baud(self) -> float:
        """The baud rate BRR gives with the bus clock in use (0 when BRR is 0)."""
        if self.cr1 & OVER8:
            div = (self.brr >> 4) + (self.brr & 7) / 8
            return self.soc.rcc.bus_hz(self.bus) / (8 * div) if div else 0.0
        return self.soc.rcc.bus_hz(self.bus) / self.brr if self.brr else 0.0

    def frame_bits(self) -> float:
        stop = {0: 1.0, 1: 0.5, 2: 2.0, 3: 1.5}[(self.cr2 >> 12) & 3]
        return 1 + (9 if self.cr1 & M else 8) + stop

    def _frame_ps(self, baud: float | None = None) -> int:
        return period_ps((baud or self.baud() or 1) / self.frame_bits())

    # ------------------------------------------------------------------ interrupts

    def _line(self) -> None:
        sr, cr1 = self.sr, self.cr1
        level = bool(cr1 & TXEIE and sr & TXE or cr1 & TCIE and sr & TC or cr1 & RXNEIE and sr & (RXNE | ORE)
                     or cr1 & IDLEIE and sr & IDLE or cr1 & PEIE and sr & PE)
        self.soc.core.raise_line(self.irq, level)

    # ------------------------------------------------------------------ transmitter

    def _can_send(self) -> bool:
        return bool(self.cr1 & UE and self.cr1 & TE)

    def _start_shift(self) -> None:
        if self.shifting is not None or self.tdr is None or not self._can_send():
            return
        self.shifting, self.tdr = self.tdr, None
        self.sr |= TXE  # TC stays as it is: only software clears it (SR read + DR write, or a 0)
        self._tx_event = self.soc.scheduler.after(self._frame_ps(), self._shift_done)
        self._line()
        self._dma_request()

    def tx_requesting(self) -> bool:
        """The transmitter's DMA request is raised (30.3.13: DMAT and TXE)."""
        return bool(self.cr3 & DMAT and self.sr & TXE)

    def _dma_request(self) -> None:
        if self.tx_dma is not None and self.tx_requesting():
            self.tx_dma()

    def _shift_done(self) -> None:
        byte, self.shifting = self.shifting, None
        self._tx_event = None
        if byte is not None and byte >= 0:
            if not self.port.routed(self.tx_pin, self.af):
                if not self._warned_pins:
                    self._warned_pins = True
                    self.report(f"a byte sent with P{self.port.letter}{self.tx_pin} not in AF{self.af}: "
                                "nothing leaves the chip")
            elif self.peer is not None:
                self.sent += 1
                self.peer.receive(byte, self.baud())
        if self.tdr is not None:
            self._start_shift()
        else:
            self.sr |= TC
            self._line()

    # ------------------------------------------------------------------ receiver

    def send(self, data: bytes, baud: float) -> None:
        """Bytes arrive on RX at `baud` (the peer's), one after another."""
        self.incoming.extend((b, baud) for b in data)
        if self._rx_event is None and self.incoming:
            self._rx_event = self.soc.scheduler.after(self._frame_ps(baud), self._byte_in)

    def _byte_in(self) -> None:
        byte, baud = self.incoming.popleft()
        self._rx_event = None
        if self.incoming:
            self._rx_event = self.soc.scheduler.after(self._frame_ps(self.incoming[0][1]), self._byte_in)
        if not (self.cr1 & UE and self.cr1 & RE) or not self.port.routed(self.rx_pin, self.af):
            return  # the receiver is off, or the pin is not connected to it: the byte is lost
        ours = self.baud()
        if not ours or abs(ours - baud) > BAUD_TOLERANCE * baud:
            byte = (byte * 0x9D + 0x35) & 0xFF  # sampled at the wrong rate: another byte, a framing error
            self.sr |= FE
        self.soc.core.progress()
        if self.sr & RXNE:
            self.sr |= ORE
            self.overruns += 1
        else:
            self.dr_rx = byte
            self.sr |= RXNE
            self.received += 1
        self._line()

    # ------------------------------------------------------------------ registers

    def read(self, offset: int) -> int:
        if offset == SR:
            self._sr_read = True
            return self.sr
        if offset == DR:
            value = self.dr_rx
            if self._sr_read:
                self.sr &= ~(ORE | IDLE | NF | FE | PE)
            self.sr &= ~RXNE
            self._sr_read = False
            self._line()
            return value
        if offset == BRR:
            return self.brr
        if offset == CR1:
            return self.cr1
        if offset == CR2:
            return self.cr2
        if offset == CR3:
            return self.cr3
        if offset == GTPR:
            return self.gtpr
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == SR:
            self.sr &= value | ~(RXNE | TC | (1 << 8) | (1 << 9))  # rc_w0: RXNE, TC, LBD, CTS
            self._line()
        elif offset == DR:
            if self._sr_read:
                self.sr &= ~TC
            self._sr_read = False
            if not self.sr & TXE:
                self.report(f"DR written while TXE = 0: the byte 0x{self.tdr or 0:02X} waiting is overwritten")
            self.tdr = value & (0x1FF if self.cr1 & M else 0xFF)
            self.sr &= ~TXE
            self._start_shift()
            self._line()
        elif offset == BRR:
            if self.shifting is not None:
                self.report("BRR changed during a transmission")
            self.brr = value & 0xFFFF
        elif offset == CR1:
            old = self.cr1
            self.cr1 = value & 0xBFFF
            if self.cr1 & UE and self.cr1 & (TE | RE) and not self.brr:
                self.report("enabled with BRR = 0")
            if self.cr1 & TE and not old & TE and self.cr1 & UE:
                # TE set: an idle frame goes out first (30.3.2); TXE stays set meanwhile
                self.shifting = -1
                self._tx_event = self.soc.scheduler.after(self._frame_ps(), self._shift_done)
            self._start_shift()
            self._line()
        elif offset == CR2:
            self.cr2 = value & 0x7F7F
        elif offset == CR3:
            if value & DMAR:
                self.report("DMA for reception (CR3.DMAR): not modelled")
            if value & 0x300:
                self.report("hardware flow control (CR3.RTSE / CTSE): not modelled")
            self.cr3 = value & 0x0FFF
            self._dma_request()
        elif offset == GTPR:
            self.gtpr = value & 0xFFFF
        else:
            self.unmodelled(offset, True)
