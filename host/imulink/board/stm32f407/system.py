"""SYSCFG and EXTI (RM0090 sections 9 and 12).

- SYSCFG_MEMRMP (9.2.1): what the boot alias at 0 shows (main flash, system memory); EXTICR1-4
  (9.2.3-9.2.6): the port of each EXTI line 0-15; CMPCR, PMC kept.
- EXTI (12.3): IMR, EMR, RTSR, FTSR, SWIER, PR (rc_w1); a GPIO pin's edge on a line whose
  trigger is enabled sets PR, and PR & IMR is the line's interrupt (EXTI0-4, EXTI9_5,
  EXTI15_10: RM0090 table 61). The board calls :meth:`Exti.pin_changed` for the pins it drives.
"""
from __future__ import annotations

from imulink.board.stm32f407.peripheral import Peripheral

EXTI_IRQ = {0: 6, 1: 7, 2: 8, 3: 9, 4: 10, **{k: 23 for k in range(5, 10)}, **{k: 40 for k in range(10, 16)}}


class Syscfg(Peripheral):
    name = "SYSCFG"
    gate = ("APB2ENR", 14)
    reset_bit = ("APB2RSTR", 14)

    def __init__(self, soc, base: int, views: dict[int, bytes]):
        self.views = views  # MEM_MODE -> what address 0 shows
        super().__init__(soc, base)

    def reset(self) -> None:
        self.regs = {0x00: 0, 0x04: 0, 0x08: 0, 0x0C: 0, 0x10: 0, 0x14: 0, 0x20: 0}
        if hasattr(self.soc, "core"):
            self.soc.core.remap_zero(self.views[0])

    def port_of(self, line: int) -> int:
        return (self.regs[0x08 + 4 * (line // 4)] >> (4 * (line % 4))) & 0xF

    def read(self, offset: int) -> int:
        if offset in self.regs:
            return self.regs[offset]
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == 0x00:
            mode = value & 3
            if mode not in self.views:
                self.report(f"MEMRMP.MEM_MODE = {mode}: FSMC / SRAM at 0 are not modelled")
            else:
                self.soc.core.remap_zero(self.views[mode])
            self.regs[0x00] = value & 3
        elif offset in self.regs:
            self.regs[offset] = value & (0xFFFF if 0x08 <= offset <= 0x14 else 0xFFFF_FFFF)
        else:
            self.unmodelled(offset, True)


class Exti(Peripheral):
    name = "EXTI"  # always clocked (it sits on APB2 without an enable bit)

    def reset(self) -> None:
        self.regs = {0x00: 0, 0x04: 0, 0x08: 0, 0x0C: 0, 0x10: 0, 0x14: 0}
        if hasattr(self.soc, "core"):
            self._lines()

    def pin_changed(self, port: int, pin: int, level: int) -> None:
        """GPIO port `port` (0 = A) pin `pin` went to `level`."""
        syscfg = self.soc.syscfg
        if syscfg.port_of(pin) != port:
            return
        trigger = self.regs[0x08] if level else self.regs[0x0C]
        if trigger >> pin & 1:
            self.regs[0x14] |= 1 << pin
            self._lines()

    def _lines(self) -> None:
        raised = self.regs[0x14] & self.regs[0x00]
        for irq in set(EXTI_IRQ.values()):
            self.soc.core.raise_line(irq, any(raised >> k & 1 for k, i in EXTI_IRQ.items() if i == irq))

    def read(self, offset: int) -> int:
        if offset in self.regs:
            return self.regs[offset]
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == 0x14:
            self.regs[0x14] &= ~value  # rc_w1
        elif offset == 0x10:
            self.regs[0x14] |= value & self.regs[0x00]
        elif offset in self.regs:
            self.regs[offset] = value & 0x7F_FFFF
        else:
            self.unmodelled(offset, True)
        self._lines()
