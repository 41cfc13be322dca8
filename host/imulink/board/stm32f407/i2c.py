"""I2C1..3 in master mode (RM0090 section 27) at the level of its registers and of whole bytes
on the bus, in front of an :class:`imulink.board.chips.I2CBus`, and the two bus lines.

Modelled from the reference manual: START -> SB (+MSL, BUSY), SB cleared by an SR1 read
then a DR write (the address byte); address ACK -> ADDR (TRA = write) or NACK -> AF;
ADDR cleared by an SR1 read then an SR2 read, which releases SCL; transmitter: DR -> shift
register, TxE when DR is empty, BTF when both are empty after a byte, a data NACK -> AF;
receiver: every byte is (N)ACKed at its end with the ACK bit of that moment (POS = 0) or
the value ACK had when the previous byte ended (POS = 1), goes to DR (RxNE) or, DR being
full, stays in the shift register (BTF, SCL held) until DR is read; the next byte is clocked
in only after an ACK and while the shift register is free; STOP / repeated START are
generated after the byte in progress (at once when none is); STOP and START in CR1 clear
when generated; rc_w0 error flags; PE = 0 and SWRST; an RCC reset; the event and error
interrupt lines (CR2.ITEVTEN, ITBUFEN, ITERREN: 27.4).

Timing: SCL's period from CCR and the clock APB1 really gives (27.6.8: standard mode
2 x CCR, fast mode 3 x CCR (DUTY 0) or 25 x CCR (DUTY 1) periods of PCLK1), a byte and its
acknowledge 9 periods. Rules checked (each breach is reported): CR2.FREQ not the APB1 clock in
MHz, SCL above 100 / 400 kHz, TRISE below the rise time's needs (27.6.9), CCR below its
minimum, CR1 written while START or STOP is pending (27.6.1), STOP or repeated START in
transmission before BTF (EV8_2), CCR / TRISE / CR2.FREQ written with PE = 1, reserved bits
written 1, DR read without RxNE or written without TxE, a received byte ACKed before a STOP
(the master receiver must NACK the last byte), a received byte never read, a transmitted
byte dropped by a STOP, START with PE = 0, a transfer with the pins not in their I2C
alternate function (open drain).

Failure injection (`inject`): nack_data (the k-th byte written), berr (at the next address),
arlo (at the next START), dead (no START is ever generated: SB never sets, until the next
RCC reset, or for ever), zero (every register reads 0 and ignores writes, like QEMU).
Not modelled: slave mode, SMBus, PEC, DMA, 10-bit addresses, clock stretching by the slaves
(the bus-clear code sees a stretched SCL through :class:`I2CLines`).
"""
from __future__ import annotations

from typing import Any

from imulink.board.stm32f407.clock import PS_PER_S, PS_PER_US, Event
from imulink.board.stm32f407.peripheral import Peripheral

# RM0090 section 27.6 bit positions.
CR1_PE, CR1_START, CR1_STOP, CR1_ACK, CR1_POS, CR1_SWRST = 1, 1 << 8, 1 << 9, 1 << 10, 1 << 11, 1 << 15
SR1_SB, SR1_ADDR, SR1_BTF, SR1_RXNE, SR1_TXE = 1, 2, 4, 1 << 6, 1 << 7
SR1_BERR, SR1_ARLO, SR1_AF, SR1_OVR = 1 << 8, 1 << 9, 1 << 10, 1 << 11
SR2_MSL, SR2_BUSY, SR2_TRA = 1, 2, 4
CR2_ITERREN, CR2_ITEVTEN, CR2_ITBUFEN = 1 << 8, 1 << 9, 1 << 10
#: Reserved bits ("must be kept at reset value": 0) of the registers the code writes.
RESERVED = {0x00: (1 << 2) | (1 << 14), 0x04: 0xE0C0, 0x14: (1 << 5) | (1 << 13), 0x1C: 0x3000, 0x20: 0xFFC0}
#: The slowest rise time each mode allows (UM10204 table 10): TRISE must cover it.
RISE_NS = {False: 1000, True: 300}


class I2CLines:
    """SCL and SDA of a bus on two open-drain pins of a GPIO port, with the module's pull-ups
    (the lines are high unless pulled low, whatever the pins' own pull settings): a line reads
    low when the pin drives it low (output mode, ODR = 0) or a chip holds it. A
    slave stuck mid-byte (`hold_sda`) holds SDA low until SCL has risen that many times (None:
    for ever). Edges while SCL is high count as STOP / START."""

    def __init__(self, port, scl: int, sda: int):
        self.port, self.scl, self.sda = port, scl, sda
        self.sda_hold: int | None = 0  # SCL rises left before the slave lets SDA go; None: never
        self.scl_stuck = False
        self.scl_rises = self.stops = self.starts = 0
        self.levels = (1, 1)
        port.connect(scl, lambda: 0 if self.scl_stuck else 1)
        port.connect(sda, lambda: 0 if self.sda_hold != 0 else 1)
        port.watchers.append(self._update)

    def hold_sda(self, rises: int | None) -> None:
        self.sda_hold = rises
        self.levels = (self.levels[0], self.port.level(self.sda))

    def _update(self) -> None:
        scl, sda = self.port.level(self.scl), self.port.level(self.sda)
        old_scl, old_sda = self.levels
        for pin in (self.scl, self.sda):
            if self.port.mode(pin) == 1 and not self.port.open_drain(pin):
                self.port.report(f"P{self.port.letter}{pin} is a push-pull output on the I2C bus")
        if scl and not old_scl:
            self.scl_rises += 1
            if self.sda_hold:  # the slave clocks out one more bit and lets go after the last
                self.sda_hold -= 1
                if self.sda_hold == 0:
                    old_sda = sda = self.port.level(self.sda)
        elif scl and old_scl and sda != old_sda:
            if sda:
                self.stops += 1
            else:
                self.starts += 1
        self.levels = (scl, sda)

    def routed(self, af: int) -> bool:
        return all(self.port.routed(pin, af) and self.port.open_drain(pin) for pin in (self.scl, self.sda))


class I2CPeripheral(Peripheral):
    """An I2C peripheral (see the module docstring): I2C`number` at `base`, its lines `lines`,
    the chips on `bus`, its event and error interrupts `irqs`."""

    status = frozenset({0x00, 0x14, 0x18})  # CR1 (START / STOP pending), SR1, SR2
    AF = 4

    def __init__(self, soc, number: int, base: int, bus, lines: I2CLines, irqs: tuple[int, int]):
        self.name = f"I2C{number}"
        self.gate = ("APB1ENR", 20 + number)
        self.reset_bit = ("APB1RSTR", 20 + number)
        self.bus, self.lines, self.irqs = bus, lines, irqs
        # ("START",) ("ADDR", address, read, ack) ("TX", byte, ack) ("RX", byte, ack) ("STOP",)
        self.events: list[tuple] = []
        self.faults: dict = {}
        self.pending: Event | None = None
        self.device: Any = None
        self.tx_value = 0
        self.dr_tx: int | None = None
        self.dr_rx: int | None = None
        self.shift_rx: int | None = None
        self._bus_time = 0
        self._warned_pins = False
        super().__init__(soc, base)

    def reset(self) -> None:
        if self.pending is not None:
            self.pending.cancel()
        self.cr1 = self.cr2 = self.oar1 = self.oar2 = self.ccr = 0
        self.trise = 2
        self.sb = self.addr = self.btf = self.rxne = self.txe = False
        self.berr = self.arlo = self.af = self.ovr = False
        self.msl = self.busy = self.tra = False
        self.sr1_saw_sb = self.sr1_saw_addr = False
        self.pending = None  # the bus event in progress
        self.dr_rx = self.shift_rx = self.dr_tx = None
        self.reading = False  # a receive phase is active
        self.last_ack = True
        self.pos_latch = True
        self.device = None
        self.write_buf = bytearray()
        self.tx_index = 0
        if self.faults.get("dead") == "until_reset":
            del self.faults["dead"]
        if hasattr(self.soc, "core"):
            self._irq()

    def inject(self, **faults) -> None:
        self.faults.update(faults)

    def violation(self, text: str) -> None:
        self.report(text)

    # ---------------------------------------------------------------- timing

    def scl_hz(self) -> float:
        """SCL's frequency from CCR and the APB1 clock in use (27.6.8)."""
        ccr = self.ccr & 0xFFF
        periods = (25 if self.ccr & 0x4000 else 3) if self.ccr & 0x8000 else 2
        return self.soc.rcc.pclk1_hz / (periods * ccr) if ccr else 0.0

    def _check_timing(self) -> None:
        pclk1 = self.soc.rcc.pclk1_hz
        freq = self.cr2 & 0x3F
        fast = bool(self.ccr & 0x8000)
        if freq != int(pclk1 // 1_000_000):
            self.violation(f"CR2.FREQ = {freq} MHz, but APB1 runs at {pclk1 / 1e6:g} MHz (27.6.2)")
        scl = self.scl_hz()
        if scl > (400_000 if fast else 100_000) * 1.001:
            self.violation(f"SCL at {scl / 1e3:.0f} kHz, above {'fast' if fast else 'standard'} mode's "
                           f"{400 if fast else 100} kHz (27.6.8)")
        if (self.ccr & 0xFFF) < (1 if fast else 4):
            self.violation(f"CCR = {self.ccr & 0xFFF}, below its minimum (27.6.8)")
        needed = int(RISE_NS[fast] * pclk1 / 1e9) + 1
        if (self.trise & 0x3F) < needed:
            self.violation(f"TRISE = {self.trise & 0x3F}, below {needed} for the {RISE_NS[fast]} ns rise time "
                           f"at {pclk1 / 1e6:g} MHz (27.6.9)")

    def schedule(self, kind: str, bits: float) -> None:
        """The bus event `kind` ends after `bits` SCL periods."""
        scl = self.scl_hz() or 100_000.0
        self.pending = self.soc.scheduler.after(int(bits * PS_PER_S / scl), lambda: self._done(kind))

    def _done(self, kind: str) -> None:
        self.pending = None
        self._chips_catch_up()
        getattr(self, "_done_" + kind)()
        self._irq()

    def _chips_catch_up(self) -> None:
        now = self.soc.scheduler.now
        if now > self._bus_time:
            self.bus.advance((now - self._bus_time) / (1000 * PS_PER_US))
            self._bus_time = now

    def _irq(self) -> None:
        cr2 = self.cr2
        event = bool(cr2 & CR2_ITEVTEN and (self.sb or self.addr or self.btf
                                             or cr2 & CR2_ITBUFEN and (self.rxne or self.txe)))
        error = bool(cr2 & CR2_ITERREN and (self.berr or self.arlo or self.af or self.ovr))
        self.soc.core.raise_line(self.irqs[0], event)
        self.soc.core.raise_line(self.irqs[1], error)

    def _deliver_writes(self) -> None:
        if self.device is not None and not self.reading and self.write_buf:
            self.device.i2c_write(bytes(self.write_buf))
        self.write_buf = bytearray()

    def _request_start_or_stop(self) -> None:
        """Generate a requested STOP / repeated START when no byte is in progress."""
        if self.pending is not None:
            return
        if self.cr1 & CR1_STOP and (self.msl or self.af):
            self.schedule("stop", 0.5)
        elif self.cr1 & CR1_START and self.cr1 & CR1_PE and "dead" not in self.faults:
            if not self.busy or self.msl:
                self.schedule("start", 0.5)

    def _done_start(self) -> None:
        if self.dr_rx is not None or self.shift_rx is not None:
            self.violation("received byte(s) never read before the next START")
            self.dr_rx = self.shift_rx = None
            self.rxne = False
        self._deliver_writes()
        self.cr1 &= ~CR1_START
        self.events.append(("START",))
        if self.faults.pop("arlo", False):
            self.arlo, self.msl, self.busy = True, False, False
            return
        self.sb, self.msl, self.busy = True, True, True
        self.btf = self.txe = self.af = False
        self.reading = False

    def _done_address(self) -> None:
        address, read = self.address_byte >> 1, bool(self.address_byte & 1)
        if self.faults.pop("berr", False):
            self.berr = True
            return
        routed = self.lines.routed(self.AF)
        if not routed and not self._warned_pins:
            self._warned_pins = True
            self.violation(f"a transfer with SCL / SDA not in AF{self.AF} open-drain: nothing reaches the bus")
        self.device = self.bus.find(address) if routed else None
        ack = self.device is not None
        self.events.append(("ADDR", address, read, ack))
        if not ack:
            self.af = True
            return
        self.addr, self.tra, self.reading = True, not read, read
        self.tx_index = 0
        self.pos_latch = bool(self.cr1 & CR1_ACK)  # with POS: the ACK in force when the first byte begins

    def _start_rx(self) -> None:
        self._chips_catch_up()
        self.rx_value = self.device.i2c_read(1)[0]
        self.schedule("rx", 9)

    def _done_rx(self) -> None:
        if self.cr1 & CR1_POS:
            ack, self.pos_latch = self.pos_latch, bool(self.cr1 & CR1_ACK)
        else:
            ack = bool(self.cr1 & CR1_ACK)
        self.events.append(("RX", self.rx_value, ack))
        self.last_ack = ack
        if self.dr_rx is None:
            self.dr_rx, self.rxne = self.rx_value, True
        else:
            self.shift_rx, self.btf = self.rx_value, True
        if ack and self.cr1 & (CR1_STOP | CR1_START):
            self.violation("a received byte was ACKed and then the transfer ended: the last byte must be NACKed")
        if self.cr1 & (CR1_STOP | CR1_START):
            self._request_start_or_stop()
        elif ack and self.shift_rx is None:
            self._start_rx()

    def _done_tx(self) -> None:
        index = self.tx_index
        self.tx_index += 1
        nack = self.faults.get("nack_data") == index
        if nack:
            del self.faults["nack_data"]
        self.events.append(("TX", self.tx_value, not nack))
        if nack:
            self.af = True
            return
        self.write_buf.append(self.tx_value)
        if self.cr1 & (CR1_STOP | CR1_START):
            if self.dr_tx is not None:
                self.violation("a byte written to DR was dropped by a STOP / START")
                self.dr_tx = None
            self._request_start_or_stop()
        elif self.dr_tx is not None:
            self.tx_value, self.dr_tx, self.txe = self.dr_tx, None, True
            self.schedule("tx", 9)
        else:
            self.btf = True

    def _done_stop(self) -> None:
        self._deliver_writes()
        self.events.append(("STOP",))
        self.cr1 &= ~CR1_STOP
        self.msl = self.busy = self.tra = False
        self.sb = self.addr = False
        if not self.reading:
            self.txe = self.btf = False

    # ---------------------------------------------------------------- the register side

    def read(self, offset: int) -> int:
        if "zero" in self.faults:
            return 0
        if offset == 0x00:
            return self.cr1
        if offset == 0x04:
            return self.cr2
        if offset == 0x08:
            return self.oar1
        if offset == 0x10:
            if not self.rxne:
                self.violation("DR read without RxNE")
                return 0
            value = self.dr_rx
            if self.shift_rx is not None:
                self.dr_rx, self.shift_rx, self.btf = self.shift_rx, None, False
                if self.reading and self.last_ack and not self.cr1 & (CR1_STOP | CR1_START) and self.msl:
                    self._start_rx()
            else:
                self.dr_rx, self.rxne = None, False
            self._irq()
            return value or 0
        if offset == 0x14:
            value = (self.sb * SR1_SB | self.addr * SR1_ADDR | self.btf * SR1_BTF | self.rxne * SR1_RXNE
                     | self.txe * SR1_TXE | self.berr * SR1_BERR | self.arlo * SR1_ARLO | self.af * SR1_AF)
            self.sr1_saw_sb, self.sr1_saw_addr = self.sb, self.addr
            return value
        if offset == 0x18:
            value = self.msl * SR2_MSL | self.busy * SR2_BUSY | self.tra * SR2_TRA
            if self.addr and self.sr1_saw_addr:
                self.addr = self.sr1_saw_addr = False
                if self.reading:
                    self._start_rx()
                else:
                    self.txe = True
                    if self.dr_tx is not None:  # a byte left in DR (after a NACK): nothing in
                        self.tx_value, self.dr_tx = self.dr_tx, None  # the RM empties DR at a STOP
                        self.schedule("tx", 9)
            self._irq()
            return value
        if offset == 0x1C:
            return self.ccr
        if offset == 0x20:
            return self.trise
        if offset == 0x0C:
            return self.oar2
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if "zero" in self.faults:
            return
        if value & RESERVED.get(offset, 0):
            self.violation(f"reserved bits 0x{value & RESERVED[offset]:04X} written at offset 0x{offset:02X}")
        if offset == 0x00:
            if self.cr1 & (CR1_START | CR1_STOP):
                self.violation(f"CR1 written (0x{value:04X}) while START/STOP is pending (0x{self.cr1:04X})")
            if value & CR1_SWRST:
                self.reset()
                self.cr1 = value
                return
            if value & CR1_START and not value & CR1_PE:
                self.violation("START with PE = 0")
            ending = value & ~self.cr1 & (CR1_STOP | CR1_START)
            if ending and self.msl and self.tra and not self.af and not self.btf:
                self.violation("STOP / repeated START programmed in transmission before TxE and BTF (EV8_2)")
            if value & CR1_PE and not self.cr1 & CR1_PE:
                self._check_timing()
            self.cr1 = value & 0xFFFF
            if not value & CR1_PE:
                self.msl = self.busy = False
                if self.pending is not None:
                    self.pending.cancel()
                    self.pending = None
            self._request_start_or_stop()
        elif offset == 0x04:
            if self.cr1 & CR1_PE and (value ^ self.cr2) & 0x3F:
                self.violation("CR2.FREQ written with PE = 1")
            self.cr2 = value
        elif offset == 0x08:
            self.oar1 = value
        elif offset == 0x0C:
            self.oar2 = value & 0xFF
        elif offset == 0x10:
            self._write_dr(value & 0xFF)
        elif offset == 0x14:
            for flag, name in ((SR1_BERR, "berr"), (SR1_ARLO, "arlo"), (SR1_AF, "af"), (SR1_OVR, "ovr")):
                if not value & flag:
                    setattr(self, name, False)
        elif offset in (0x1C, 0x20):
            if self.cr1 & CR1_PE:
                self.violation(f"{'CCR' if offset == 0x1C else 'TRISE'} written with PE = 1")
            if offset == 0x1C:
                self.ccr = value
            else:
                self.trise = value
        else:
            self.unmodelled(offset, True)
        self._irq()

    def _write_dr(self, value: int) -> None:
        if self.sb:
            if not self.sr1_saw_sb:
                self.violation("DR written while SB is set without reading SR1 first")
            self.sb = self.sr1_saw_sb = False
            self.address_byte = value
            self.schedule("address", 9)
            return
        if not (self.msl and self.tra) or self.addr:
            self.violation(f"DR written (0x{value:02X}) outside a transmission")
            return
        if not self.txe:
            self.violation(f"DR written (0x{value:02X}) while TxE = 0: a byte is overwritten")
        if self.pending is None and not self.cr1 & (CR1_STOP | CR1_START):
            self.tx_value, self.btf, self.txe = value, False, True
            self.schedule("tx", 9)
        else:
            self.dr_tx, self.txe = value, False


