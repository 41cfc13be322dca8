"""The STM32F407 around the core: the bus matrix's peripheral map (RM0090 2.3, table 1), clock
gating, peripheral resets, the problems the models report, and the fast-forward of busy-waits.

Every peripheral register access goes through :meth:`Soc.read` / :meth:`Soc.write`:

- an address no model covers is reported ("unmodelled") and reads 0;
- a peripheral whose clock enable bit is 0 is reported and does not respond (reads 0, writes
  are lost), as on the chip;
- an access to a peripheral right after its clock enable, with no read of RCC in between, is
  reported (RM0090 7.3: the clock is active 2 peripheral clock cycles after the enable bit is
  set; a read back of the enable register is the usual wait);
- a peripheral held in reset by its RCC reset bit does not respond;
- every access takes ACCESS_CYCLES of HCLK.

Busy-waits are fast-forwarded, so time moves at the pace the code waits, not at one
instruction a cycle (:meth:`Soc._poll`): the turns of a wait loop are recognised by its reads
of status and counter registers; a turn whose status registers read what they read the turn
before jumps the clock to the next event (never past it: events and interrupts stay on time),
a turn on a counter moves it by a step that grows with the wait. A status wait that goes on
for POLL_HANG_S of virtual time is a hang, reported with the function.
"""
from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any, TypeVar

from unicorn.arm_const import UC_ARM_REG_PC

from imulink.board.stm32f407.clock import PS_PER_S, PS_PER_US, Scheduler, period_ps
from imulink.board.stm32f407.core import SYSTEM_BASE, TRAMPOLINE, TRAMPOLINE_CODE, Cortex, Fault, functions_of
from imulink.board.stm32f407.peripheral import Peripheral
from imulink.board.stm32f407.rcc import ENR, RSTR, Flash, Pwr, Rcc

P = TypeVar("P", bound=Peripheral)

#: A poll that has waited this long with the same value and no event to wait for has hung.
POLL_HANG_S = 2.0
#: HCLK cycles one peripheral register access takes (an APB access: a few bus cycles).
ACCESS_CYCLES = 6
#: The longest step one poll of a counter moves the clock (us); shorter when it has waited less.
POLL_STEP_MAX_US = 50


class Soc:
    """The chip: core, clocks, peripherals, time. Peripherals are added by the board."""

    def __init__(self, flash: bytes, *, elf: bytes | None = None, unique_id: bytes = bytes(range(1, 13)),
                 boots: bool = True):
        self.scheduler = Scheduler()
        self.problems: list[str] = []
        self.on_problem: Callable[[str], None] | None = None
        self.unique_id = unique_id
        self.accesses = 0
        self._blocks: dict[int, Peripheral] = {}
        self.peripherals: list[Peripheral] = []
        self._fresh_enable: Peripheral | None = None
        self._streak: dict[int, tuple[int, bool]] = {}  # this turn: register -> (value, a counter)
        self._last_turn: dict[int, tuple[int, bool]] | None = None
        self._turn_started = 0
        self._poll_since = 0
        self._access_ps = 0
        self.cycle_ps = 1
        self.rcc = Rcc(self, 0x4002_3800)
        self.add(self.rcc)
        self.add(Pwr(self, 0x4000_7000))
        self.flash_interface = self.add(Flash(self, 0x4002_3C00))
        self.syscfg: Any = None  # the board's SYSCFG (EXTI asks it which port a line has)
        self.core = Cortex(self, flash, functions_of(elf) if elf else None, boots=boots)
        self.rcc.listeners.append(self._clock_changed)
        self._clock_changed()
        for base, size in ((0x4000_0000, 0x8_0000), (0x5000_0000, 0x6_1000)):  # APB1, APB2, AHB1; AHB2
            self.core.uc.mmio_map(base, size, self._mmio_read, base, self._mmio_write, base)

    # ------------------------------------------------------------------ assembly

    def add(self, peripheral: P) -> P:
        def bits(where, registers):
            return None if where is None else (next(o for o, n in registers.items() if n == where[0]), 1 << where[1])

        peripheral.gate_bits = bits(peripheral.gate, ENR)
        peripheral.reset_bits = bits(peripheral.reset_bit, RSTR)
        for k in range(peripheral.size // 0x400 or 1):
            self._blocks[(peripheral.base >> 10) + k] = peripheral
        self.peripherals.append(peripheral)
        peripheral.reset()
        return peripheral

    def system_memory(self) -> bytes:
        """System memory (RM0090 2.3, table 3): the bootloader's vector table and a parking loop
        in place of its code (the board's bootloader model takes over when the core gets there),
        OTP (erased), the 96-bit unique ID (39.1) at 0x1FFF7A10 and the flash size in KiB (39.2)
        at 0x1FFF7A22."""
        memory = bytearray(32 << 10)
        struct.pack_into("<II", memory, 0, 0x2000_3000, SYSTEM_BASE + 0x201)
        memory[0x200:0x202] = b"\xfe\xe7"  # b .
        memory[TRAMPOLINE - SYSTEM_BASE:TRAMPOLINE - SYSTEM_BASE + len(TRAMPOLINE_CODE)] = TRAMPOLINE_CODE
        memory[0x7800:0x7A10] = b"\xff" * 0x210
        memory[0x7A10:0x7A1C] = self.unique_id
        memory[0x7A22:0x7A24] = struct.pack("<H", 1024)
        return bytes(memory)

    # ------------------------------------------------------------------ problems

    def report(self, unit: str, text: str) -> None:
        line = f"{self.scheduler.now / PS_PER_S:.6f} s {unit}: {text}"
        if self.problems and self.problems[-1].split(": ", 1)[-1] == line.split(": ", 1)[-1]:
            return  # the same problem again at once (a loop): once is enough
        self.problems.append(line)
        if self.on_problem is not None:
            self.on_problem(line)

    # ------------------------------------------------------------------ resets

    def system_reset(self) -> None:
        """SYSRESETREQ (RM0090 7.1.2): every peripheral and the core reset (each cancels its own
        events); SRAM keeps its content, and what is outside the chip runs on."""
        for peripheral in self.peripherals:
            peripheral.reset()
        self.rcc.note_software_reset()
        self.core.cold_reset()

    # ------------------------------------------------------------------ the bus

    def _peripheral(self, address: int, write: bool) -> Peripheral | None:
        peripheral = self._blocks.get(address >> 10)
        if peripheral is None:
            self.report("bus", f"{'write to' if write else 'read of'} 0x{address:08X}: no peripheral modelled there")
            return None
        regs = self.rcc.regs
        gate = peripheral.gate_bits
        if gate is not None and not regs[gate[0]] & gate[1]:
            self.report(peripheral.name, f"accessed with its clock off (RCC_{peripheral.gate[0]} bit "  # type: ignore[index]
                                         f"{peripheral.gate[1]} = 0): no response")  # type: ignore[index]
            return None
        if self._fresh_enable is peripheral:
            self.report(peripheral.name, "accessed right after its clock enable, without a read of RCC in between "
                                         "(RM0090 7.3: the clock starts 2 cycles later)")
        held = peripheral.reset_bits
        if held is not None and regs[held[0]] & held[1]:
            self.report(peripheral.name, "accessed while held in reset by RCC")
            return None
        return peripheral

    def _mmio_read(self, uc, offset, size, base) -> int:
        return self.read(base + offset, size)

    def _mmio_write(self, uc, offset, size, value, base) -> None:
        self.write(base + offset, value, size)

    def new_slice(self) -> None:
        """The core starts a slice of instructions: a wait loop is recognised within one."""
        self._streak.clear()
        self._last_turn = None
        self.accesses = 0

    def _bus_time(self) -> None:
        """A peripheral access takes ACCESS_CYCLES of HCLK (the bridge to the APB)."""
        sched = self.scheduler
        then = sched.now + self._access_ps
        due = sched.next_time()
        if due is None or due > then:
            sched.now = then
        else:
            sched.advance(then)

    def read(self, address: int, size: int = 4) -> int:
        self.accesses += 1
        self._bus_time()
        peripheral = self._peripheral(address, False)
        self._fresh_enable = None
        if peripheral is None:
            return 0
        offset = (address - peripheral.base) & ~3
        value = peripheral.read(offset)
        if offset in peripheral.status or offset in peripheral.counters:
            self._poll(address, value, offset in peripheral.counters)
        else:
            self._streak.clear()
            self._last_turn = None
        shift = 8 * (address & 3)
        return (value >> shift) & ((1 << (8 * size)) - 1)

    def write(self, address: int, value: int, size: int = 4) -> None:
        self.accesses += 1
        self._bus_time()
        self._streak.clear()
        self._last_turn = None
        self.core.progress()
        peripheral = self._peripheral(address, True)
        self._fresh_enable = None
        if peripheral is None:
            return
        offset = address - peripheral.base
        if size != 4:
            if not getattr(peripheral, "byte_access", False):
                self.report(peripheral.name, f"{size}-byte write at offset 0x{offset:02X}")
            shift = 8 * (offset & 3)
            mask = ((1 << (8 * size)) - 1) << shift
            offset &= ~3
            value = (peripheral.read(offset) & ~mask) | ((value << shift) & mask)
        peripheral.write(offset, value)

    def clock_enabled(self, peripheral: Peripheral) -> None:
        """RCC says `peripheral`'s clock was just switched on."""
        self._fresh_enable = peripheral

    def by_gate(self, register: str, bit: int) -> Peripheral | None:
        return next((p for p in self.peripherals if p.gate == (register, bit)), None)

    def by_reset(self, register: str, bit: int) -> Peripheral | None:
        return next((p for p in self.peripherals if p.reset_bit == (register, bit)), None)

    # ------------------------------------------------------------------ busy-waits

    def _poll(self, address: int, value: int, counter: bool) -> None:
        """A read of a register code waits on. Such reads with nothing written in between
        form the turns of a wait loop: a turn ends when a register of it is read again. When
        every status register of a turn reads what it read in the turn before, only an event
        can change them: the clock jumps to the next event. A turn that reads a counter moves
        the clock by a step that grows with the wait."""
        sched = self.scheduler
        turn = self._streak
        if address not in turn:
            if not turn:
                self._turn_started = sched.now
            turn[address] = (value, counter)
            return
        previous, self._last_turn = self._last_turn, dict(turn)
        turn.clear()
        turn[address] = (value, counter)
        ended = self._last_turn
        stalled = previous is not None and previous.keys() == ended.keys() and all(
            is_counter or previous[a][0] == v for a, (v, is_counter) in ended.items())
        waits_on_status = any(not is_counter for _, is_counter in ended.values())
        if not stalled:
            self._poll_since = sched.now
        due = sched.next_time()
        if stalled and waits_on_status and due is not None and due <= sched.now + 1000 * PS_PER_US:
            target = due  # status flags: nothing changes them before the next event
        elif any(is_counter for _, is_counter in ended.values()):
            step = min(POLL_STEP_MAX_US * PS_PER_US, max(PS_PER_US // 4, (sched.now - self._poll_since) // 16))
            target = sched.now + step if due is None else min(due, sched.now + step)
        else:
            return
        sched.advance(target)
        core = self.core
        if core.uc_running and (core.pending or core.lines) and core.next_exception() is not None:
            core.request_stop("interrupt")
        if stalled and waits_on_status and sched.now - self._poll_since > POLL_HANG_S * PS_PER_S:
            where = core.function_at(core.uc.reg_read(UC_ARM_REG_PC))
            self.report("core", f"hang: polling 0x{address:08X} (reads 0x{value:X}) for {POLL_HANG_S:g} s in {where}")
            raise Fault(f"the firmware hangs polling 0x{address:08X} in {where}")

    def _clock_changed(self) -> None:
        self.cycle_ps = period_ps(self.rcc.hclk_hz)
        self._access_ps = ACCESS_CYCLES * self.cycle_ps
