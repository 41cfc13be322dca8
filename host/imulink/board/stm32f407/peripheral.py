"""The base of every peripheral model: a register block on the bus, its RCC clock enable and
reset bits, and the registers code waits on (see imulink.board.stm32f407.soc)."""
from __future__ import annotations

from typing import Any


class Peripheral:
    """A register block at `base` (size bytes). ``gate``: the RCC enable register and bit
    that clock it, e.g. ("APB2ENR", 4); ``reset_bit``: its RCC reset register and bit."""

    name = "?"
    size = 0x400
    gate: tuple[str, int] | None = None
    reset_bit: tuple[str, int] | None = None
    #: Offsets of registers code waits on: status flags (unchanged until an event) and
    #: counters (fast-forward candidates).
    status: frozenset[int] = frozenset()
    counters: frozenset[int] = frozenset()
    gate_bits: tuple[int, int] | None = None  # (RCC register offset, mask), set by Soc.add
    reset_bits: tuple[int, int] | None = None

    def __init__(self, soc: Any, base: int):
        self.soc = soc
        self.base = base

    def reset(self) -> None:
        """Reset values (a system reset or the RCC reset bit)."""

    def read(self, offset: int) -> int:
        raise NotImplementedError

    def write(self, offset: int, value: int) -> None:
        raise NotImplementedError

    def report(self, text: str) -> None:
        self.soc.report(self.name, text)

    def unmodelled(self, offset: int, write: bool) -> int:
        self.report(f"{'write to' if write else 'read of'} unmodelled register offset 0x{offset:02X}")
        return 0
