"""The Cortex-M4 of the virtual STM32F407: unicorn executes the instructions; this module adds
what unicorn leaves to the system around it, after the ARMv7-M architecture reference manual
(ARM DDI 0403E, "ARMv7-M ARM") and the Cortex-M4 generic user guide (ARM DUI 0553, "the
DUI"), and PM0214 (the STM32F4 programming manual):

- exception entry and return (ARMv7-M ARM B1.5.6-B1.5.8): the eight-word frame on the main
  stack, 8-byte aligned with bit 9 of the stacked xPSR (CCR.STKALIGN = 1 from reset), the
  vector from the table at VTOR; nesting by group priority (AIRCR.PRIGROUP, four priority
  bits: PM0214 4.3.7). Unicorn cannot leave handler mode, so handlers run with IPSR = 0, this
  module keeps the active exceptions itself, and LR holds the address of TRAMPOLINE (below),
  which unstacks as EXC_RETURN 0xFFFFFFF9 would; a handler that loads an EXC_RETURN value
  into the PC is unstacked here too. The image must not read IPSR or compare LR with
  EXC_RETURN values (it does neither);
- PRIMASK and BASEPRI mask (B1.5.4); an interrupt is taken the instant the instruction that
  clears PRIMASK (CPSIE i, MSR PRIMASK) has executed: those instructions are hooked where they
  are in the image;
- WFI (B1.5.19): the core sleeps until an interrupt is pending that would preempt if PRIMASK
  were clear, so a masked pending interrupt wakes it without being taken;
- the NVIC (ISER, ICER, ISPR, ICPR, IABR, IPR, STIR; ICTR), peripheral interrupt lines as
  levels (a line still raised after its handler pends it again), the system control block
  (CPUID, ICSR, VTOR, AIRCR with its VECTKEY and SYSRESETREQ, SCR, CCR, SHPR1-3, SHCSR, the
  fault status registers, CPACR), SysTick (B3.3) and the DWT cycle counter behind DEMCR.TRCENA
  (C1.8); DBGMCU_IDCODE (RM0090 38.6.1);
- faults: an access to unmapped memory, a write to flash or an undefined instruction is
  reported and taken as a HardFault (the image's handler resets the chip);
- a hang: a loop that runs more than HANG_CYCLES without touching a peripheral, taking an
  exception or sleeping is reported with the function it is in.

Not modelled: the FP extension's lazy context (the image is built for soft float; an
image that sets CONTROL.FPCA is reported), the process stack in handlers, MPU, SVCall
(unicorn cannot raise it), debug and trace units other than the DWT cycle counter, flash wait
states and the cache (one instruction counts one cycle of HCLK).
"""
from __future__ import annotations

import ctypes
import struct
from bisect import bisect_right
from collections.abc import Callable
from typing import Any

import unicorn
from unicorn import arm_const as A

from imulink.board.stm32f407.clock import Event, period_ps

FLASH_BASE, FLASH_SIZE = 0x0800_0000, 1 << 20
SRAM_BASE, SRAM_SIZE = 0x2000_0000, 128 << 10
CCM_BASE, CCM_SIZE = 0x1000_0000, 64 << 10
SYSTEM_BASE, SYSTEM_SIZE = 0x1FFF_0000, 32 << 10  # system memory (30 KiB), OTP, unique ID, flash size
OPTION_BASE, OPTION_SIZE = 0x1FFF_C000, 4 << 10
PPB_BASE, PPB_SIZE = 0xE000_0000, 1 << 20
#: Where exception handlers return to: a routine (below) in the system memory's unused space.
TRAMPOLINE = SYSTEM_BASE + 0x7000
#: The return from an exception in Thumb code: unstack R0-R3, R12, LR, the return address and
#: the APSR flags from the eight-word frame (with the 4-byte pad when bit 9 of the stacked xPSR
#: says so), as the EXC_RETURN 0xFFFFFFF9 would:
#:   ldr r0,[sp,#28]; ubfx r1,r0,#9,#1; add.w r1,sp,r1,lsl #2; add.w r1,r1,#24; ldr r2,[sp,#24]
#:   orr r2,r2,#1; ldr r3,[sp,#4]; msr APSR_nzcvqg,r0; str r2,[r1,#4]; str r3,[r1]
#:   ldr r0,[sp]; ldr r2,[sp,#8]; ldr r3,[sp,#12]; ldr.w r12,[sp,#16]; ldr.w lr,[sp,#20]
#:   mov sp,r1; pop {r1,pc}
#: Handlers get its address in LR instead of an EXC_RETURN value: unicorn ends emulation at
#: an EXC_RETURN, and a return that stays in the emulator is several times faster. Exceptions
#: are never taken inside an IT block, whose state the routine cannot restore.
TRAMPOLINE_CODE = bytes.fromhex("0798c0f340210deb810101f11801069a42f00102019b80f3008c4a600b600098029a039b"
                                "ddf810c0ddf814e08d4602bd")
TRAMPOLINE_LAST = TRAMPOLINE + len(TRAMPOLINE_CODE) - 2  # pop {r1, pc}
EXC_RETURN_BASE = 0xFFFF_0000  # a branch here is an exception return (ARMv7-M ARM B1.5.8)

#: Instructions in one slice of emulation at most: the latency of an interrupt that a
#: peripheral raises in the middle of a slice (2 000 cycles: 12 us at 168 MHz).
MAX_SLICE = 2000
#: A loop that runs this many cycles in one place without a peripheral access, an exception
#: or a sleep has hung (0.1 s at 168 MHz: nothing in the image computes that long).
HANG_CYCLES = 16_800_000

IRQ_COUNT = 82  # RM0090 table 61
HARD_FAULT, SYSTICK = 3, 15
CPUID = 0x410F_C241  # Cortex-M4 r0p1 (PM0214 4.4.1)
DBGMCU_IDCODE = 0x1007_6413  # DEV_ID 0x413 (STM32F405/407), REV_ID 0x1007 (revision 1; RM0090 38.6.1)
AIRCR_VECTKEY = 0x05FA

_THUMB_CPSIE_I = 0xB662
_THUMB_WFI = 0xBF30
_REGS_FRAME = (A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3, A.UC_ARM_REG_R12,
               A.UC_ARM_REG_LR, A.UC_ARM_REG_PC, A.UC_ARM_REG_XPSR)
_ENTRY_READ = (*_REGS_FRAME, A.UC_ARM_REG_SP, A.UC_ARM_REG_CONTROL)
_R = [getattr(A, f"UC_ARM_REG_R{n}") for n in range(13)] + [A.UC_ARM_REG_SP, A.UC_ARM_REG_LR, A.UC_ARM_REG_PC]


class _Registers:
    """Batched register reads and writes through unicorn's C interface (the Python binding's
    generic path costs tens of microseconds a call, and exceptions need a dozen registers)."""

    def __init__(self, uc):
        self.uc = uc
        try:
            from unicorn.unicorn_py3.unicorn import uclib
            self._lib, self._handle = uclib, uc._uch
        except (ImportError, AttributeError):  # another binding: its public (slower) calls
            self._lib = None

    def reader(self, registers) -> Callable[[], list[int]]:
        if self._lib is None:
            return lambda: list(self.uc.reg_read_batch(registers))
        n = len(registers)
        ids = (ctypes.c_int * n)(*registers)
        values = (ctypes.c_uint32 * n)()
        pointers = (ctypes.c_void_p * n)(*(ctypes.addressof(values) + 4 * k for k in range(n)))
        lib, handle = self._lib, self._handle

        def read() -> list[int]:
            lib.uc_reg_read_batch(handle, ids, pointers, n)
            return values[:]
        return read

    def writer(self, registers) -> Callable[..., None]:
        if self._lib is None:
            return lambda *vals: self.uc.reg_write_batch(tuple(zip(registers, vals)))
        n = len(registers)
        ids = (ctypes.c_int * n)(*registers)
        values = (ctypes.c_uint32 * n)()
        pointers = (ctypes.c_void_p * n)(*(ctypes.addressof(values) + 4 * k for k in range(n)))
        lib, handle = self._lib, self._handle

        def write(*vals: int) -> None:
            values[:] = list(vals)
            lib.uc_reg_write_batch(handle, ids, pointers, n)
        return write


class Fault(Exception):
    """The virtual board cannot go on (a hang, a lock-up): the text says where."""


def functions_of(elf: bytes) -> list[tuple[int, int, str]]:
    """(address, size, name) of every function symbol in an ELF32 image, sorted."""
    if elf[:4] != b"\x7fELF":
        return []
    shoff, = struct.unpack_from("<I", elf, 0x20)
    shentsize, shnum = struct.unpack_from("<HH", elf, 0x2E)
    sections = [struct.unpack_from("<10I", elf, shoff + i * shentsize) for i in range(shnum)]
    out = []
    for s in sections:
        if s[1] != 2:  # SHT_SYMTAB
            continue
        strtab = sections[s[6]]
        for k in range(s[5] // 16):
            name, value, size, info = struct.unpack_from("<IIIB", elf, s[4] + k * 16)
            if info & 0xF == 2:  # STT_FUNC
                end = elf.index(b"\0", strtab[4] + name)
                out.append((value & ~1, size, elf[strtab[4] + name:end].decode(errors="replace")))
    return sorted(out)


class Cortex:
    """The core, its memory and its system peripherals; `soc` (imulink.board.stm32f407.soc.Soc)
    supplies time, clocks and the peripherals on the buses. ``run(until)`` executes up to a virtual time."""

    def __init__(self, soc: Any, flash: bytes, functions: list[tuple[int, int, str]] | None = None,
                 boots: bool = True):
        self.soc = soc
        self.boots = boots  # False: no vector table; a test harness calls the image's functions itself
        self.functions = functions or []
        self._starts = [f[0] for f in self.functions]
        uc = self.uc = unicorn.Uc(unicorn.UC_ARCH_ARM, unicorn.UC_MODE_THUMB | unicorn.UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(A.UC_CPU_ARM_CORTEX_M4)
        rx, rw = unicorn.UC_PROT_READ | unicorn.UC_PROT_EXEC, unicorn.UC_PROT_ALL
        self.flash = bytearray(flash[:FLASH_SIZE].ljust(FLASH_SIZE, b"\xff"))
        uc.mem_map(FLASH_BASE, FLASH_SIZE, rx)
        uc.mem_write(FLASH_BASE, bytes(self.flash))
        uc.mem_map(0, FLASH_SIZE, rx)  # the boot alias (BOOT0 = 0: main flash at 0, RM0090 2.4)
        uc.mem_write(0, bytes(self.flash))
        uc.mem_map(SRAM_BASE, SRAM_SIZE, rw)
        uc.mem_map(CCM_BASE, CCM_SIZE, unicorn.UC_PROT_READ | unicorn.UC_PROT_WRITE)
        uc.mem_map(SYSTEM_BASE, SYSTEM_SIZE, rx)
        uc.mem_write(SYSTEM_BASE, soc.system_memory())
        uc.mem_map(OPTION_BASE, OPTION_SIZE, unicorn.UC_PROT_READ)
        uc.mem_write(OPTION_BASE, struct.pack("<4H", 0xAAEC, 0x5513, 0x0FFF, 0xF000))  # RM0090 3.6.1 defaults
        uc.mmio_map(PPB_BASE, PPB_SIZE, self._ppb_read, None, self._ppb_write, None)
        for address in self._find(flash, (_THUMB_CPSIE_I,)):
            uc.hook_add(unicorn.UC_HOOK_CODE, self._cpsie_hook, begin=address, end=address)
        for address, register in self._find_msr_primask(flash):
            uc.hook_add(unicorn.UC_HOOK_CODE, self._msr_hook, register, begin=address, end=address)
        uc.hook_add(unicorn.UC_HOOK_CODE, self._returned, begin=TRAMPOLINE, end=TRAMPOLINE)
        uc.hook_add(unicorn.UC_HOOK_CODE, self._tail_chain, begin=TRAMPOLINE_LAST, end=TRAMPOLINE_LAST)
        for address in self._find(flash, (_THUMB_WFI,)):
            uc.hook_add(unicorn.UC_HOOK_CODE, self._wfi_hook, begin=address, end=address)
        uc.hook_add(unicorn.UC_HOOK_MEM_UNMAPPED | unicorn.UC_HOOK_MEM_PROT, self._bad_access)
        registers = _Registers(uc)
        self._read_entry = registers.reader(_ENTRY_READ)
        self._write_entry = registers.writer((A.UC_ARM_REG_SP, A.UC_ARM_REG_LR))
        self._write_return = registers.writer((*_REGS_FRAME[:6], A.UC_ARM_REG_XPSR, A.UC_ARM_REG_SP))
        self._read_sp = registers.reader((A.UC_ARM_REG_SP,))
        self._read_pc = registers.reader((A.UC_ARM_REG_PC,))
        self._read_xpsr = registers.reader((A.UC_ARM_REG_XPSR,))
        self._read_masks = registers.reader((A.UC_ARM_REG_PRIMASK, A.UC_ARM_REG_BASEPRI))
        self._read_control = registers.reader((A.UC_ARM_REG_CONTROL,))
        self.system_hooks: list[Callable[[int], None]] = []
        self.taken: dict[int, int] = {}  # exception number -> times taken
        self.cycles_since_progress = 0
        self.cold_reset()

    # ------------------------------------------------------------------ the image's special instructions

    @staticmethod
    def _find(image: bytes, codes: tuple[int, ...]) -> list[int]:
        halves = struct.unpack_from(f"<{len(image) // 2}H", image)
        return [FLASH_BASE + 2 * k for k, h in enumerate(halves) if h in codes]

    @staticmethod
    def _find_msr_primask(image: bytes) -> list[tuple[int, int]]:
        """MSR PRIMASK, Rn (T1: 0xF38n 0x8810) with its register n."""
        halves = struct.unpack_from(f"<{len(image) // 2}H", image)
        return [(FLASH_BASE + 2 * k, h & 0xF) for k, h in enumerate(halves[:-1])
                if h & 0xFFF0 == 0xF380 and halves[k + 1] == 0x8810]

    # ------------------------------------------------------------------ reset

    def cold_reset(self) -> None:
        self.vtor = 0
        self.aircr_prigroup = 0
        self.scr = 0
        self.ccr = 0x200  # STKALIGN
        self.shpr = bytearray(12)
        self.shcsr = 0
        self.cfsr = self.hfsr = 0
        self.cpacr = 0
        self.demcr = 0
        self.dwt_ctrl = 0x4000_0000  # NUMCOMP = 4
        self.cyccnt_base = 0
        self.cyccnt_since: int | None = None  # the HCLK cycle count when CYCCNT last started
        self.systick_ctrl = self.systick_load = 0
        self.systick_base = 0  # VAL when written, at systick_from (SysTick clock cycles)
        self.systick_from = 0
        event: Event | None = getattr(self, "systick_event", None)
        if event is not None:
            event.cancel()
        self.systick_event: Event | None = None
        self.enabled = [False] * IRQ_COUNT
        self.pending: set[int] = set()  # exception numbers pended by software or by an edge
        self.lines: set[int] = set()  # peripheral interrupt lines raised now (exception numbers)
        self.priority = bytearray(IRQ_COUNT)
        self.active: list[int] = []
        self._priorities: dict[int, int] = {}  # exception -> group priority, until IPR / SHPR / AIRCR change
        self.stop_reason: str | None = None
        self.resume_at: int | None = None
        self.cycles_since_progress = 0
        uc = self.uc
        uc.reg_write(A.UC_ARM_REG_PRIMASK, 0)
        uc.reg_write(A.UC_ARM_REG_BASEPRI, 0)
        uc.reg_write(A.UC_ARM_REG_CONTROL, 0)
        if not self.boots:
            return
        sp, entry = struct.unpack("<II", bytes(uc.mem_read(0, 8)))
        uc.reg_write(A.UC_ARM_REG_MSP, sp)
        uc.reg_write(A.UC_ARM_REG_SP, sp)
        uc.reg_write(A.UC_ARM_REG_LR, 0xFFFF_FFFF)
        uc.reg_write(A.UC_ARM_REG_XPSR, 0x0100_0000)
        self.pc = entry & ~1
        if not entry & 1:
            self.soc.report("core", f"the reset vector 0x{entry:08X} is not a Thumb address: the core locks up")
            raise Fault(f"lock-up at reset: reset vector 0x{entry:08X} has bit 0 clear")

    def remap_zero(self, data: bytes) -> None:
        """What the boot alias at 0 shows (SYSCFG_MEMRMP: main flash or system memory)."""
        self.uc.mem_write(0, data[:FLASH_SIZE].ljust(FLASH_SIZE, b"\0"))

    def function_at(self, address: int) -> str:
        k = bisect_right(self._starts, address) - 1
        if k >= 0:
            start, size, name = self.functions[k]
            if address < start + max(size, 2):
                return f"{name}+0x{address - start:X}"
        return f"0x{address:08X}"

    # ------------------------------------------------------------------ priorities

    def _group(self, value: int) -> int:
        """The group (preemption) priority of a priority byte (four bits implemented)."""
        return value >> max(self.aircr_prigroup + 1, 4)

    def exception_priority(self, number: int) -> int:
        cached = self._priorities.get(number)
        if cached is None:
            cached = self._priorities[number] = self._priority_of(number)
        return cached

    def _priority_of(self, number: int) -> int:
        if number == HARD_FAULT:
            return -1
        if number >= 16:
            return self._group(self.priority[number - 16])
        if 4 <= number <= 15:
            return self._group(self.shpr[number - 4])
        return -2

    def execution_priority(self, primask: int | None = None) -> int:
        running = min((self.exception_priority(n) for n in self.active), default=256)
        mask, basepri = self._read_masks()
        if primask is None:
            primask = mask
        if primask & 1:
            running = min(running, 0)
        basepri &= 0xF0
        if basepri:
            running = min(running, self._group(basepri))
        return running

    def _candidates(self) -> set[int]:
        if not self.pending and not self.lines:
            return set()
        raised = {n for n in self.lines if n not in self.active}
        pending = self.pending | raised
        return {n for n in pending if n < 16 or self.enabled[n - 16]}

    def next_exception(self, primask: int | None = None) -> int | None:
        """The pending exception that would be taken now (PRIMASK as given), or None."""
        candidates = self._candidates()
        if not candidates:
            return None
        best = min(candidates, key=lambda n: (self.exception_priority(n), n))
        return best if self.exception_priority(best) < self.execution_priority(primask) else None

    def raise_line(self, irq: int, level: bool) -> None:
        """A peripheral's interrupt request line `irq` (RM0090 table 61) rises or falls."""
        number = irq + 16
        if level:
            if number not in self.lines:
                self.lines.add(number)
                if self.uc_running and self.next_exception() is not None:
                    self.request_stop("interrupt")
        else:
            self.lines.discard(number)

    uc_running = False

    def request_stop(self, reason: str) -> None:
        if self.stop_reason is None:
            self.stop_reason = reason
        self.uc.emu_stop()

    # ------------------------------------------------------------------ hooks

    def _cpsie_hook(self, uc, address, size, _user) -> None:
        self._primask_cleared(address, size, 0)

    def _msr_hook(self, uc, address, size, register) -> None:
        self._primask_cleared(address, size, uc.reg_read(_R[register]) & 1)

    def _primask_cleared(self, address: int, size: int, value: int) -> None:
        if value == 0 and (self.pending or self.lines) and self.next_exception(primask=0) is not None:
            self.resume_at = address + size
            self.request_stop("primask")

    def _returned(self, uc, address, size, _user) -> None:
        if self.active:
            self.active.pop()

    def _tail_chain(self, uc, address, size, _user) -> None:
        if (self.pending or self.lines) and self.next_exception() is not None:
            self.request_stop("interrupt")

    def _wfi_hook(self, uc, address, size, _user) -> None:
        self.resume_at = address + size
        self.request_stop("wfi")

    def _bad_access(self, uc, access, address, size, value, _user) -> bool:
        kind = "write" if access in (unicorn.UC_MEM_WRITE_UNMAPPED, unicorn.UC_MEM_WRITE_PROT) else "read"
        if access in (unicorn.UC_MEM_FETCH_UNMAPPED, unicorn.UC_MEM_FETCH_PROT):
            kind = "instruction fetch"
        where = self.function_at(uc.reg_read(A.UC_ARM_REG_PC))
        self.soc.report("core", f"bus fault: {kind} of {size} bytes at 0x{address:08X} in {where}")
        self.stop_reason = "fault"
        return False

    # ------------------------------------------------------------------ exceptions

    def _enter(self, number: int) -> None:
        uc = self.uc
        *regs, sp, control = self._read_entry()
        if control & 0b110:
            self.soc.report("core", "exception entry with the process stack or an FP context: not modelled")
        regs[6] = self.pc
        align = (sp >> 2) & 1 if self.ccr & 0x200 else 0
        sp = (sp - 32) & ~(4 if align else 0)
        regs[7] = (regs[7] & ~0x1FF & ~(1 << 9)) | (self.active[-1] if self.active else 0) | (align << 9)
        uc.mem_write(sp, struct.pack("<8I", *regs))
        self._write_entry(sp, TRAMPOLINE | 1)
        vector, = struct.unpack("<I", bytes(uc.mem_read(self.vtor + 4 * number, 4)))
        self.pending.discard(number)
        self.active.append(number)
        self.taken[number] = self.taken.get(number, 0) + 1
        self.cycles_since_progress = 0
        if not vector & 1:
            self.soc.report("core", f"exception {number}: vector 0x{vector:08X} is not a Thumb address")
            raise Fault(f"lock-up: exception {number} has vector 0x{vector:08X}")
        self.pc = vector & ~1

    def _return(self, exc_return: int) -> None:
        uc = self.uc
        if not self.active:
            self.soc.report("core", f"EXC_RETURN 0x{exc_return:08X} in thread mode")
            raise Fault(f"lock-up: return from no exception ({self.function_at(self.pc)})")
        if exc_return not in (0xFFFF_FFF1, 0xFFFF_FFF9):
            self.soc.report("core", f"EXC_RETURN 0x{exc_return:08X} (process stack or FP frame): not modelled")
        sp, = self._read_sp()
        regs = struct.unpack("<8I", bytes(uc.mem_read(sp, 32)))
        self._write_return(*regs[:6], regs[7] & ~0x1FF, sp + 32 + (4 if regs[7] & (1 << 9) else 0))
        self.active.pop()
        self.pc = regs[6] & ~1

    def take_due_exception(self) -> bool:
        if not self.pending and not self.lines:
            return False
        number = self.next_exception()
        if number is None:
            return False
        while True:  # not inside an IT block: step out of it first
            xpsr, = self._read_xpsr()
            if not (xpsr >> 25 & 3 or xpsr >> 10 & 0x3F):
                break
            self.uc.emu_start(self.pc | 1, 0, count=1)
            self.pc, = self._read_pc()
        self._enter(number)
        return True

    def pend(self, number: int) -> None:
        self.pending.add(number)

    # ------------------------------------------------------------------ running

    def run(self, until: int, *, sleep: Callable[[int | None], bool]) -> None:
        """Execute until virtual time `until` (ps). `sleep(wake_time)` is called when the core
        waits for an interrupt (wake_time: the next event, None if none); it returns False when
        nothing will ever come."""
        soc, sched, uc = self.soc, self.soc.scheduler, self.uc
        while sched.now < until:
            self.take_due_exception()
            cycle = soc.cycle_ps
            due = sched.next_time()
            limit = until if due is None else min(due, until)
            n = max(1, min(MAX_SLICE, -(-(limit - sched.now) // cycle)))
            self.stop_reason = None
            self.resume_at = None
            soc.new_slice()
            self.uc_running = True
            try:
                uc.emu_start(self.pc | 1, 0, count=n)
            except unicorn.UcError as error:
                self.uc_running = False
                self.pc = uc.reg_read(A.UC_ARM_REG_PC)
                if error.errno == unicorn.UC_ERR_EXCEPTION and self.pc >= EXC_RETURN_BASE:
                    self._return(self.pc | 1)  # unicorn raises at a fetch from the EXC_RETURN range
                    continue
                if self.stop_reason != "fault":
                    self.soc.report("core", f"{error} at {self.function_at(self.pc)}")
                self._hard_fault()
                continue
            self.uc_running = False
            reason = self.stop_reason
            self.pc, = self._read_pc()
            if reason is None:
                sched.advance(sched.now + n * cycle)
                self._watch_progress(n, soc.accesses)
            elif reason == "primask":
                uc.reg_write(A.UC_ARM_REG_PRIMASK, 0)
                assert self.resume_at is not None
                self.pc = self.resume_at
            elif reason == "wfi":
                assert self.resume_at is not None
                self.pc = self.resume_at
                self.cycles_since_progress = 0
                while self.next_exception(primask=0) is None:
                    if not sleep(sched.next_time()):
                        return
            elif reason == "reset":
                soc.system_reset()
            elif reason == "fault":
                self._hard_fault()
            for hook in self.system_hooks:
                hook(self.pc)
            if self._read_control()[0] & 0b100:
                soc.report("core", "CONTROL.FPCA set: the image uses the FPU, whose context is not modelled")

    def _hard_fault(self) -> None:
        self.cfsr |= 1 << 17  # INVSTATE-like marker; the handler only resets
        self.hfsr |= 1 << 30  # FORCED
        if HARD_FAULT in self.active:
            raise Fault(f"lock-up: a fault in the HardFault handler at {self.function_at(self.pc)}")
        self._enter(HARD_FAULT)

    def _watch_progress(self, cycles: int, accesses: int) -> None:
        if accesses:
            self.cycles_since_progress = 0
            return
        self.cycles_since_progress += cycles
        if self.cycles_since_progress > HANG_CYCLES:
            where = self.function_at(self.pc)
            self.soc.report("core", f"hang: {self.cycles_since_progress} cycles without progress in {where}")
            raise Fault(f"the firmware hangs in {where}")

    def progress(self) -> None:
        """Something happened that a loop waits for (a peripheral access, a received byte)."""
        self.cycles_since_progress = 0

    # ------------------------------------------------------------------ time-based system peripherals

    def hclk_cycles(self) -> int:
        return self.soc.rcc.hclk_cycles()

    def _cyccnt(self) -> int:
        if self.cyccnt_since is None:
            return self.cyccnt_base
        return (self.cyccnt_base + self.hclk_cycles() - self.cyccnt_since) & 0xFFFF_FFFF

    def _cyccnt_update(self) -> None:
        running = bool(self.dwt_ctrl & 1) and bool(self.demcr & (1 << 24))
        if running and self.cyccnt_since is None:
            self.cyccnt_since = self.hclk_cycles()
        elif not running and self.cyccnt_since is not None:
            self.cyccnt_base, self.cyccnt_since = self._cyccnt(), None

    def _systick_hz(self) -> float:
        return self.soc.rcc.hclk_hz / (1 if self.systick_ctrl & 4 else 8)

    def _systick_val(self) -> int:
        if not self.systick_ctrl & 1:
            return self.systick_base
        elapsed = int((self.soc.scheduler.now - self.systick_from) / period_ps(self._systick_hz()))
        if elapsed <= self.systick_base:
            return self.systick_base - elapsed
        reload = self.systick_load + 1
        return self.systick_load - (elapsed - self.systick_base - 1) % reload if reload > 1 else 0

    def _systick_restart(self) -> None:
        if self.systick_event is not None:
            self.systick_event.cancel()
            self.systick_event = None
        self.systick_from = self.soc.scheduler.now
        if self.systick_ctrl & 1 and self.systick_load:
            cycles = self.systick_base if self.systick_base else self.systick_load + 1
            self.systick_event = self.soc.scheduler.after(cycles * period_ps(self._systick_hz()), self._systick_wrap)

    def _systick_wrap(self) -> None:
        self.systick_ctrl |= 1 << 16  # COUNTFLAG
        if self.systick_ctrl & 2:
            self.pend(SYSTICK)
            if self.uc_running and self.next_exception() is not None:
                self.request_stop("interrupt")
        self.systick_base = self.systick_load
        self.systick_from = self.soc.scheduler.now
        self.systick_event = self.soc.scheduler.after((self.systick_load + 1) * period_ps(self._systick_hz()),
                                                      self._systick_wrap)

    # ------------------------------------------------------------------ the private peripheral bus

    def _ppb_read(self, uc, offset, size, _user) -> int:
        self.soc.accesses += 1
        value = self._ppb_word(offset & ~3)
        shift = 8 * (offset & 3)
        return (value >> shift) & ((1 << (8 * size)) - 1)

    def _ppb_word(self, offset: int) -> int:
        address = PPB_BASE + offset
        if 0xE000_E100 <= address < 0xE000_E120:
            return sum(1 << b for b in range(32) if 32 * ((address - 0xE000_E100) // 4) + b < IRQ_COUNT
                       and self.enabled[32 * ((address - 0xE000_E100) // 4) + b])
        if 0xE000_E180 <= address < 0xE000_E1A0:
            return self._ppb_word(offset - 0x80)
        if 0xE000_E200 <= address < 0xE000_E300:
            first = 16 + 32 * ((address & 0x7F) // 4)
            group = self.pending | self.lines if address < 0xE000_E280 + 0x20 else set()
            return sum(1 << b for b in range(32) if first + b in group)
        if 0xE000_E300 <= address < 0xE000_E320:
            first = 16 + 32 * ((address - 0xE000_E300) // 4)
            return sum(1 << b for b in range(32) if first + b in self.active)
        if 0xE000_E400 <= address < 0xE000_E400 + IRQ_COUNT:
            k = address - 0xE000_E400
            return int.from_bytes(bytes(self.priority[k:k + 4]).ljust(4, b"\0"), "little")
        if 0xE000_ED18 <= address < 0xE000_ED24:
            k = address - 0xE000_ED18
            return int.from_bytes(self.shpr[k:k + 4], "little")
        simple = {
            0xE000_E004: lambda: (IRQ_COUNT - 1) // 32,
            0xE000_E010: lambda: self.systick_ctrl,
            0xE000_E014: lambda: self.systick_load,
            0xE000_E018: self._systick_val,
            0xE000_E01C: lambda: 18750,  # PM0214 4.5.4: 1 ms at HCLK/8 = 18.75 MHz
            0xE000_ED00: lambda: CPUID,
            0xE000_ED04: self._icsr,
            0xE000_ED08: lambda: self.vtor,
            0xE000_ED0C: lambda: 0xFA05_0000 | self.aircr_prigroup << 8,
            0xE000_ED10: lambda: self.scr,
            0xE000_ED14: lambda: self.ccr,
            0xE000_ED24: lambda: self.shcsr,
            0xE000_ED28: lambda: self.cfsr,
            0xE000_ED2C: lambda: self.hfsr,
            0xE000_ED34: lambda: 0,
            0xE000_ED38: lambda: 0,
            0xE000_ED88: lambda: self.cpacr,
            0xE000_EDFC: lambda: self.demcr,
            0xE000_1000: lambda: self.dwt_ctrl,
            0xE000_1004: self._cyccnt,
            0xE004_2000: lambda: DBGMCU_IDCODE,
        }
        if address in simple:
            if address == 0xE000_E010:
                value = self.systick_ctrl
                self.systick_ctrl &= ~(1 << 16)  # COUNTFLAG clears on read
                return value
            if address == 0xE000_1004 and not self.demcr & (1 << 24):
                self.soc.report("DWT", "CYCCNT read with DEMCR.TRCENA = 0: the DWT is off and reads 0")
                return 0
            return simple[address]()
        self.soc.report("core", f"read of an unmodelled system register 0x{address:08X}")
        return 0

    def _icsr(self) -> int:
        active = self.active[-1] if self.active else 0
        waiting = self._candidates()
        vectpending = min(waiting, key=lambda n: (self.exception_priority(n), n)) if waiting else 0
        return active | vectpending << 12 | (1 << 22 if any(n >= 16 for n in waiting) else 0)

    def _ppb_write(self, uc, offset, size, value, _user) -> None:
        self.soc.accesses += 1
        address = PPB_BASE + offset
        if 0xE000_E400 <= address < 0xE000_E400 + IRQ_COUNT:
            for k in range(size):
                if address - 0xE000_E400 + k < IRQ_COUNT:
                    self.priority[address - 0xE000_E400 + k] = (value >> (8 * k)) & 0xF0
            self._priorities.clear()
            return
        if 0xE000_ED18 <= address < 0xE000_ED24:
            for k in range(size):
                self.shpr[address - 0xE000_ED18 + k] = (value >> (8 * k)) & 0xF0
            self._priorities.clear()
            return
        if size != 4:
            self.soc.report("core", f"{size}-byte write to system register 0x{address:08X} (word access only)")
            return
        if 0xE000_E100 <= address < 0xE000_E120 or 0xE000_E180 <= address < 0xE000_E1A0:
            first = 32 * ((address & 0x7F) // 4)
            for b in range(32):
                if value >> b & 1 and first + b < IRQ_COUNT:
                    self.enabled[first + b] = address < 0xE000_E180
        elif 0xE000_E200 <= address < 0xE000_E220 or 0xE000_E280 <= address < 0xE000_E2A0:
            first = 16 + 32 * ((address & 0x7F) // 4)
            for b in range(32):
                if value >> b & 1 and first + b < 16 + IRQ_COUNT:
                    (self.pending.add if address < 0xE000_E280 else self.pending.discard)(first + b)
        elif address == 0xE000_EF00:  # STIR
            self.pending.add(16 + (value & 0x1FF))
        elif address == 0xE000_E010:
            self.systick_base = self._systick_val()
            self.systick_ctrl = (self.systick_ctrl & (1 << 16)) | (value & 7)
            self._systick_restart()
        elif address == 0xE000_E014:
            self.systick_load = value & 0xFF_FFFF
        elif address == 0xE000_E018:
            self.systick_base = 0
            self.systick_ctrl &= ~(1 << 16)
            self._systick_restart()
        elif address == 0xE000_ED04:
            if value & (1 << 28):
                self.pending.add(14)  # PENDSVSET
            if value & (1 << 27):
                self.pending.discard(14)
            if value & (1 << 26):
                self.pending.add(SYSTICK)
            if value & (1 << 25):
                self.pending.discard(SYSTICK)
        elif address == 0xE000_ED08:
            self.vtor = value & 0x3FFF_FF80
        elif address == 0xE000_ED0C:
            if value >> 16 != AIRCR_VECTKEY:
                self.soc.report("SCB", f"AIRCR written without VECTKEY 0x05FA (0x{value:08X}): ignored")
                return
            self.aircr_prigroup = (value >> 8) & 7
            self._priorities.clear()
            if value & (1 << 2):
                self.request_stop("reset")
        elif address == 0xE000_ED10:
            self.scr = value & 0x16
        elif address == 0xE000_ED14:
            self.ccr = value & 0x31B | 0x200
        elif address == 0xE000_ED24:
            self.shcsr = value
        elif address in (0xE000_ED28, 0xE000_ED2C):
            if address == 0xE000_ED28:
                self.cfsr &= ~value
            else:
                self.hfsr &= ~value
        elif address == 0xE000_ED88:
            self.cpacr = value & 0x00F0_0000
        elif address == 0xE000_EDFC:
            self.demcr = value & 0x010F_07F1
            self._cyccnt_update()
        elif address == 0xE000_1000:
            self.dwt_ctrl = (self.dwt_ctrl & 0xF000_0000) | (value & 0x0FFF_FFFF)
            self._cyccnt_update()
        elif address == 0xE000_1004:
            if self.cyccnt_since is not None:
                self.cyccnt_since = self.hclk_cycles()
            self.cyccnt_base = value
        else:
            self.soc.report("core", f"write of an unmodelled system register 0x{address:08X} (0x{value:08X})")
