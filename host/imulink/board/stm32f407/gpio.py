"""GPIO ports A to I (RM0090 section 8.4): MODER, OTYPER, OSPEEDR, PUPDR, IDR, ODR, BSRR, LCKR,
AFRL/AFRH with their reset values (8.4.1-8.4.10; port A and B differ: the debug pins).

A pin's level (IDR) is what drives it: the pin itself in output mode (push-pull: ODR; open
drain: ODR = 0 pulls low), else whatever the board connects to it (``connect``: a function
giving 0, 1 or None when not driving), else the pull-up / pull-down, else 0 (a floating input
is read as 0 here; on the chip it is undefined). Open-drain lines are wired-AND.
Peripherals ask :meth:`routed` whether their pin is in alternate-function mode with their
AF number: a USART whose TX pin is not routed sends nothing off the chip.
"""
from __future__ import annotations

from collections.abc import Callable

from imulink.board.stm32f407.peripheral import Peripheral

MODER, OTYPER, OSPEEDR, PUPDR, IDR, ODR, BSRR, LCKR, AFRL, AFRH = range(0, 0x28, 4)
RESET = {"A": (0xA800_0000, 0x0C00_0000, 0x6400_0000), "B": (0x0000_0280, 0x0000_00C0, 0x0000_0100)}
MODE_INPUT, MODE_OUTPUT, MODE_AF, MODE_ANALOG = range(4)


class GpioPort(Peripheral):
    byte_access = True
    status = frozenset({IDR})

    def __init__(self, soc, letter: str):
        index = ord(letter) - ord("A")
        self.letter = letter
        self.name = f"GPIO{letter}"
        self.gate = ("AHB1ENR", index)
        self.reset_bit = ("AHB1RSTR", index)
        self.inputs: dict[int, Callable[[], int | None]] = {}
        self.watchers: list[Callable[[], None]] = []  # told when a pin's drive may have changed
        super().__init__(soc, 0x4002_0000 + 0x400 * index)

    def reset(self) -> None:
        moder, ospeedr, pupdr = RESET.get(self.letter, (0, 0, 0))
        self.regs = {MODER: moder, OTYPER: 0, OSPEEDR: ospeedr, PUPDR: pupdr, ODR: 0, LCKR: 0, AFRL: 0, AFRH: 0}
        for watch in getattr(self, "watchers", []):
            watch()

    def connect(self, pin: int, level: Callable[[], int | None]) -> None:
        self.inputs[pin] = level

    def mode(self, pin: int) -> int:
        return (self.regs[MODER] >> (2 * pin)) & 3

    def alternate(self, pin: int) -> int:
        return (self.regs[AFRL if pin < 8 else AFRH] >> (4 * (pin % 8))) & 0xF

    def open_drain(self, pin: int) -> bool:
        return bool(self.regs[OTYPER] >> pin & 1)

    def pull(self, pin: int) -> int:
        return (self.regs[PUPDR] >> (2 * pin)) & 3

    def routed(self, pin: int, af: int) -> bool:
        return self.mode(pin) == MODE_AF and self.alternate(pin) == af

    def drives_low(self, pin: int) -> bool:
        """The pin pulls its line low itself (output mode, ODR = 0)."""
        return self.mode(pin) == MODE_OUTPUT and not self.regs[ODR] >> pin & 1

    def level(self, pin: int) -> int:
        mode = self.mode(pin)
        if mode == MODE_OUTPUT and not self.open_drain(pin):
            return self.regs[ODR] >> pin & 1
        outside = self.inputs[pin]() if pin in self.inputs else None
        if mode == MODE_OUTPUT and not self.regs[ODR] >> pin & 1:
            return 0
        if outside is not None:
            return outside
        return 1 if self.pull(pin) == 1 else 0

    def read(self, offset: int) -> int:
        if offset == IDR:
            return sum(self.level(pin) << pin for pin in range(16))
        if offset == BSRR:
            return 0
        if offset in self.regs:
            return self.regs[offset]
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == BSRR:
            self.regs[ODR] = (self.regs[ODR] | (value & 0xFFFF)) & ~(value >> 16 & ~value & 0xFFFF)
        elif offset == IDR:
            self.report("write to IDR (read-only)")
            return
        elif offset == LCKR:
            self.regs[LCKR] = value & 0x1_FFFF
            return
        elif offset in self.regs:
            if offset in (OTYPER, ODR):
                value &= 0xFFFF
            self.regs[offset] = value
        else:
            self.unmodelled(offset, True)
            return
        for watch in self.watchers:
            watch()
