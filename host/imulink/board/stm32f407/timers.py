"""General-purpose timers TIM2 to TIM5 (RM0090 section 18) as up-counters: CR1 (CEN, UDIS, URS,
OPM, ARPE), DIER, SR (rc_w0), EGR (UG), CNT, PSC, ARR, CCR1-4, with the counter clock from the
APB1 timer clock RCC gives (twice PCLK1 when the APB1 prescaler is not 1: RM0090 7.2), the
prescaler and (with ARPE) the auto-reload loaded at each update event (18.3.1-18.3.2), the
update event at the overflow (UIF and the interrupt unless UDIS; UG sets UIF only with URS =
0), one-pulse mode, 32-bit counters on TIM2 and TIM5 and 16-bit ones on TIM3 and TIM4.

The counter is not stepped: its value is computed from the virtual time when read, and its
overflow is an event on the clock. Not modelled (reported when enabled): down and centre-
aligned counting, capture/compare channels and their interrupts, slave modes, DMA.
"""
from __future__ import annotations

from imulink.board.stm32f407.clock import PS_PER_S, Event
from imulink.board.stm32f407.peripheral import Peripheral

CR1, CR2, SMCR, DIER, SR, EGR, CCMR1, CCMR2, CCER, CNT, PSC, ARR = range(0, 0x30, 4)
CCR = (0x34, 0x38, 0x3C, 0x40)
DCR, DMAR, OR = 0x48, 0x4C, 0x50
CEN, UDIS, URS, OPM, DIR = 1, 2, 4, 8, 16
UIF = 1


class GeneralTimer(Peripheral):
    status = frozenset({SR})
    counters = frozenset({CNT})

    def __init__(self, soc, number: int, base: int, irq: int):
        self.name = f"TIM{number}"
        self.gate = ("APB1ENR", number - 2)
        self.reset_bit = ("APB1RSTR", number - 2)
        self.irq = irq
        self.width = 32 if number in (2, 5) else 16
        self._overflow: Event | None = None
        super().__init__(soc, base)
        soc.rcc.listeners.append(self._rebase)

    def reset(self) -> None:
        if self._overflow is not None:
            self._overflow.cancel()
            self._overflow = None
        self.cr1 = self.cr2 = self.smcr = self.dier = self.sr = 0
        self.ccmr = [0, 0]
        self.ccer = 0
        self.ccr = [0, 0, 0, 0]
        self.psc = self.psc_active = 0
        self.arr = self.arr_active = (1 << self.width) - 1
        self.count_at = 0  # CNT at time `since`
        self.since = self.soc.scheduler.now
        self.other = {DCR: 0, DMAR: 0, OR: 0}
        if hasattr(self.soc, "core"):
            self._line()

    # ------------------------------------------------------------------ counting

    def _tick_ps(self) -> float:
        return PS_PER_S * (self.psc_active + 1) / self.soc.rcc.timer_hz(1)

    def counter(self) -> int:
        if not self.cr1 & CEN:
            return self.count_at
        ticks = int((self.soc.scheduler.now - self.since) / self._tick_ps())
        return (self.count_at + ticks) % (self.arr_active + 1) if self.arr_active else 0

    def _rebase(self) -> None:
        self.count_at = self.counter()
        self.since = self.soc.scheduler.now
        self._schedule()

    def _schedule(self) -> None:
        if self._overflow is not None:
            self._overflow.cancel()
            self._overflow = None
        if self.cr1 & CEN:
            left = self.arr_active + 1 - self.count_at
            self._overflow = self.soc.scheduler.at(self.since + int(left * self._tick_ps() + 0.5), self._overflowed)

    def _update_event(self) -> None:
        self.psc_active = self.psc
        self.arr_active = self.arr

    def _overflowed(self) -> None:
        self._overflow = None
        self.count_at, self.since = 0, self.soc.scheduler.now
        if not self.cr1 & UDIS:
            self._update_event()
            self.sr |= UIF
            self._line()
        if self.cr1 & OPM:
            self.cr1 &= ~CEN
        self._schedule()

    def _line(self) -> None:
        self.soc.core.raise_line(self.irq, bool(self.dier & self.sr & 0x5F))

    # ------------------------------------------------------------------ registers

    def read(self, offset: int) -> int:
        if offset == CNT:
            return self.counter()
        values = {CR1: self.cr1, CR2: self.cr2, SMCR: self.smcr, DIER: self.dier, SR: self.sr, EGR: 0,
                  CCMR1: self.ccmr[0], CCMR2: self.ccmr[1], CCER: self.ccer, PSC: self.psc, ARR: self.arr}
        if offset in values:
            return values[offset]
        if offset in CCR:
            return self.ccr[CCR.index(offset)]
        if offset in self.other:
            return self.other[offset]
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == CR1:
            self.count_at, self.since = self.counter(), self.soc.scheduler.now
            if value & (DIR | 0x60):
                self.report("down or centre-aligned counting: not modelled")
            self.cr1 = value & 0x3FF
            if not self.cr1 & 0x80:  # ARPE = 0: ARR takes effect at once
                self.arr_active = self.arr
            self._schedule()
        elif offset == DIER:
            if value & ~0x1:
                self.report(f"DIER 0x{value:04X}: only the update interrupt is modelled")
            self.dier = value & 0x5F5F
            self._line()
        elif offset == SR:
            self.sr &= value | ~0x1E5F
            self._line()
        elif offset == EGR:
            if value & UG_MASK:
                self.count_at, self.since = 0, self.soc.scheduler.now
                self._update_event()
                if not self.cr1 & URS:
                    self.sr |= UIF
                    self._line()
                self._schedule()
        elif offset == CNT:
            self.count_at, self.since = value & ((1 << self.width) - 1), self.soc.scheduler.now
            self._schedule()
        elif offset == PSC:
            self.psc = value & 0xFFFF
        elif offset == ARR:
            self.arr = value & ((1 << self.width) - 1)
            if not self.cr1 & 0x80:
                self.count_at, self.since = self.counter(), self.soc.scheduler.now
                self.arr_active = self.arr
                self._schedule()
        elif offset in (CR2, SMCR, CCMR1, CCMR2, CCER):
            if value:
                self.report(f"register offset 0x{offset:02X} = 0x{value:X}: capture/compare, slave modes "
                            "and triggers are not modelled")
            if offset == CR2:
                self.cr2 = value
            elif offset == SMCR:
                self.smcr = value
            elif offset == CCER:
                self.ccer = value
            else:
                self.ccmr[(offset - CCMR1) // 4] = value
        elif offset in CCR:
            self.ccr[CCR.index(offset)] = value & ((1 << self.width) - 1)
        elif offset in self.other:
            self.other[offset] = value
        else:
            self.unmodelled(offset, True)


UG_MASK = 1
