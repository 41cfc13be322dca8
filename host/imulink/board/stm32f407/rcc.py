"""Reset and clock control, the power controller and the flash interface's access control
(RM0090 rev 19: RCC section 7, PWR section 5, FLASH section 3; DS8626 for the oscillators).

RCC: the HSI (16 MHz, ready from reset), the HSE (the board's 8 MHz crystal: HSERDY 2 ms after
HSEON, DS8626 "HSE 4-26 MHz oscillator characteristics", typical start-up; or never, when the
board has no crystal), the main PLL (PLLRDY 100 us after PLLON when its input runs; RCC_PLLCFGR
checked against section 7.3.2: M 2..63, VCO input 1..2 MHz, N 50..432, VCO 100..432 MHz, the
system clock at most 168 MHz, the 48 MHz clock at most 48 MHz), the system clock switch (SWS
follows SW a few cycles later, and only to a clock that is ready), the AHB and APB prescalers
(at most 168, 42 and 84 MHz), the enable and reset bits of every bus (section 7.3.10-7.3.14),
the reset flags in RCC_CSR (section 7.3.21). The flash wait states are checked at the moment
HCLK rises (section 3.5.1, table 10 at 2.7-3.6 V), and VOS (PWR_CR) above 144 MHz (5.1.4).

Not modelled: the low-power enable registers' effect (they read their reset values and keep
what is written), the clock security system, the I2S PLL, MCO outputs, the RTC domain,
flash programming and option bytes (FLASH_CR / OPTCR keep what is written; a program or
erase request is reported).
"""
from __future__ import annotations

from collections.abc import Callable

from imulink.board.stm32f407.clock import PS_PER_S, PS_PER_US, period_ps
from imulink.board.stm32f407.peripheral import Peripheral

HSI_HZ = 16_000_000
HSE_START_US = 2000
PLL_LOCK_US = 100
SWITCH_CYCLES = 4

CR, PLLCFGR, CFGR, CIR = 0x00, 0x04, 0x08, 0x0C
RSTR = {0x10: "AHB1RSTR", 0x14: "AHB2RSTR", 0x18: "AHB3RSTR", 0x20: "APB1RSTR", 0x24: "APB2RSTR"}
ENR = {0x30: "AHB1ENR", 0x34: "AHB2ENR", 0x38: "AHB3ENR", 0x40: "APB1ENR", 0x44: "APB2ENR"}
LPENR_RESET = {0x50: 0x7E67_91FF, 0x54: 0x0000_00F1, 0x58: 0x0000_0001, 0x60: 0x36FE_C9FF, 0x64: 0x0007_5F33}
BDCR, CSR, SSCGR, PLLI2SCFGR = 0x70, 0x74, 0x80, 0x84
#: Writable bits of the enable registers (the peripherals the F407 has; section 7.3.10-7.3.14).
ENR_MASK = {"AHB1ENR": 0x7E7C_11FF, "AHB2ENR": 0x0000_00F1, "AHB3ENR": 0x0000_0001,
            "APB1ENR": 0x36FE_C9FF, "APB2ENR": 0x0007_5F33}
RSTR_MASK = {"AHB1RSTR": 0x2260_11FF, "AHB2RSTR": 0x0000_00F1, "AHB3RSTR": 0x0000_0001,
             "APB1RSTR": 0x36FE_C9FF, "APB2RSTR": 0x0007_5933}
#: Flash wait states needed per HCLK at 2.7-3.6 V (RM0090 table 10): the upper bounds.
WAIT_STATE_LIMITS_HZ = (30e6, 60e6, 90e6, 120e6, 150e6, 168e6)
AHB_DIV = (1, 1, 1, 1, 1, 1, 1, 1, 2, 4, 8, 16, 64, 128, 256, 512)
APB_DIV = (1, 1, 1, 1, 2, 4, 8, 16)
SYSCLK_MAX, APB1_MAX, APB2_MAX = 168e6, 42e6, 84e6


class Rcc(Peripheral):
    name = "RCC"
    status = frozenset({CR, CFGR})

    def __init__(self, soc, base: int, *, hse_hz: int = 8_000_000, hse_present: bool = True):
        self.hse_hz, self.hse_present = hse_hz, hse_present
        self.listeners: list[Callable[[], None]] = []  # told after any clock changed
        self.csr = 0x0E00_0000  # PORRSTF, PINRSTF, BORRSTF: a power-on reset
        self._cycles_at, self._cycles_from = 0, 0
        super().__init__(soc, base)

    def reset(self) -> None:
        self.regs = {CR: 0x0000_0083, PLLCFGR: 0x2400_3010, CFGR: 0, CIR: 0, BDCR: 0, SSCGR: 0,
                     PLLI2SCFGR: 0x2000_3000, **{o: 0 for o in RSTR}, **{o: 0 for o in ENR}, **LPENR_RESET}
        self.regs[0x30] = 0x0010_0000  # CCMDATARAMEN
        for event in getattr(self, "_events", {}).values():
            event.cancel()  # type: ignore[attr-defined]
        self._events: dict[str, object] = {}
        self._rebase()
        self._hz = self._compute()

    def note_software_reset(self) -> None:
        self.csr |= 1 << 28 | 1 << 26  # SFTRSTF, PINRSTF (the reset drives NRST: section 7.1.2)

    # ------------------------------------------------------------------ clocks

    def _compute(self) -> dict[str, float]:
        cfgr = self.regs[CFGR]
        sws = (cfgr >> 2) & 3
        sysclk = {0: HSI_HZ, 1: self.hse_hz}.get(sws, self.pll_hz()) or HSI_HZ
        hclk = sysclk / AHB_DIV[(cfgr >> 4) & 0xF]
        d1, d2 = APB_DIV[(cfgr >> 10) & 7], APB_DIV[(cfgr >> 13) & 7]
        return dict(sysclk=sysclk, hclk=hclk, pclk1=hclk / d1, pclk2=hclk / d2,
                    tim1=hclk / d1 * (1 if d1 == 1 else 2), tim2=hclk / d2 * (1 if d2 == 1 else 2))

    def pll_hz(self) -> float:
        pll = self.regs[PLLCFGR]
        m, n, p = pll & 0x3F, (pll >> 6) & 0x1FF, 2 * (((pll >> 16) & 3) + 1)
        source = self.hse_hz if pll & (1 << 22) else HSI_HZ
        return source / m * n / p if m else 0.0

    @property
    def sysclk_hz(self) -> float:
        return self._hz["sysclk"]

    @property
    def hclk_hz(self) -> float:
        return self._hz["hclk"]

    @property
    def pclk1_hz(self) -> float:
        return self._hz["pclk1"]

    @property
    def pclk2_hz(self) -> float:
        return self._hz["pclk2"]

    def timer_hz(self, bus: int) -> float:
        """The clock of the timers on APB`bus` (twice the bus clock when its prescaler is not 1)."""
        return self._hz["tim1" if bus == 1 else "tim2"]

    def bus_hz(self, bus: int) -> float:
        return self._hz["pclk1" if bus == 1 else "pclk2"]

    def hclk_cycles(self) -> int:
        """HCLK cycles since power-on."""
        return self._cycles_at + (self.soc.scheduler.now - self._cycles_from) // period_ps(self._hz["hclk"]) \
            if hasattr(self, "_hz") else 0

    def _rebase(self) -> None:
        self._cycles_at = self.hclk_cycles()
        self._cycles_from = self.soc.scheduler.now

    def clocks_changed(self) -> None:
        self._rebase()
        old = self._hz
        self._hz = self._compute()
        if self._hz == old:
            return
        hz = self._hz
        if hz["hclk"] > old["hclk"]:
            latency = self.soc.flash_interface.latency()  # type: ignore[attr-defined]
            needed = next(k for k, limit in enumerate(WAIT_STATE_LIMITS_HZ) if hz["hclk"] <= limit + 0.5) \
                if hz["hclk"] <= WAIT_STATE_LIMITS_HZ[-1] + 0.5 else len(WAIT_STATE_LIMITS_HZ)
            if latency < needed:
                self.report(f"HCLK rose to {hz['hclk'] / 1e6:g} MHz with {latency} flash wait states; "
                            f"{needed} are needed (RM0090 3.5.1, table 10): the core reads wrong instructions")
        for name, limit in (("SYSCLK", SYSCLK_MAX), ("APB1", APB1_MAX), ("APB2", APB2_MAX)):
            value = hz["sysclk" if name == "SYSCLK" else "pclk1" if name == "APB1" else "pclk2"]
            if value > limit + 0.5:
                self.report(f"{name} at {value / 1e6:g} MHz, above its maximum of {limit / 1e6:g} MHz (RM0090 7.2)")
        if hz["sysclk"] > 144e6 and not self.soc._blocks[0x4000_7000 >> 10].vos_scale1():  # type: ignore[attr-defined]
            self.report("SYSCLK above 144 MHz with PWR_CR.VOS = 0 (RM0090 5.1.4)")
        for listener in self.listeners:
            listener()

    # ------------------------------------------------------------------ registers

    def enabled(self, register: str, bit: int) -> bool:
        offset = next(o for o, n in ENR.items() if n == register)
        return bool(self.regs[offset] >> bit & 1)

    def in_reset(self, register: str, bit: int) -> bool:
        offset = next(o for o, n in RSTR.items() if n == register)
        return bool(self.regs[offset] >> bit & 1)

    def read(self, offset: int) -> int:
        if offset == CSR:
            return self.csr
        if offset in self.regs:
            return self.regs[offset]
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == CR:
            self._write_cr(value)
        elif offset == PLLCFGR:
            if self.regs[CR] & (1 << 24):
                self.report("RCC_PLLCFGR written while the PLL is on (RM0090 7.3.2: only with the PLL off)")
                return
            self.regs[PLLCFGR] = (value & 0x0F43_7FFF) | 0x2000_0000
        elif offset == CFGR:
            self._write_cfgr(value)
        elif offset in ENR:
            name = ENR[offset]
            old = self.regs[offset]
            self.regs[offset] = value & ENR_MASK[name]
            for bit in range(32):
                if (self.regs[offset] & ~old) >> bit & 1:
                    peripheral = self.soc.by_gate(name, bit)
                    if peripheral is not None:
                        self.soc.clock_enabled(peripheral)
        elif offset in RSTR:
            name = RSTR[offset]
            old = self.regs[offset]
            self.regs[offset] = value & RSTR_MASK[name]
            for bit in range(32):
                if (self.regs[offset] & ~old) >> bit & 1:
                    peripheral = self.soc.by_reset(name, bit)
                    if peripheral is not None:
                        peripheral.reset()
        elif offset == CSR:
            if value & (1 << 24):  # RMVF
                self.csr &= 0x00FF_FFFF
            self.csr = (self.csr & ~1) | (value & 1)  # LSION
        elif offset in (CIR, BDCR, SSCGR, PLLI2SCFGR) or offset in LPENR_RESET:
            self.regs[offset] = value
        else:
            self.unmodelled(offset, True)

    def _write_cr(self, value: int) -> None:
        old = self.regs[CR]
        sws = (self.regs[CFGR] >> 2) & 3
        pll_on = bool(old & (1 << 24))
        pll_source_hse = bool(self.regs[PLLCFGR] & (1 << 22))
        new = (old & ~0x0D0D_00F9) | (value & 0x0D0D_00F9)  # HSION, HSITRIM, HSEON, HSEBYP, CSSON, PLLON, PLLI2SON
        if not new & 1 and (sws == 0 or pll_on and not pll_source_hse):
            new |= 1  # the HSI in use cannot be stopped (section 7.3.1)
        if not new & (1 << 16) and (sws == 1 or pll_on and pll_source_hse and sws == 2):
            new |= 1 << 16
        if (new ^ old) & (1 << 18) and old & (1 << 16):
            self.report("RCC_CR.HSEBYP changed while HSEON = 1 (section 7.3.1: only with the HSE off)")
            new = (new & ~(1 << 18)) | (old & (1 << 18))
        if not new & (1 << 24) and sws == 2:
            new |= 1 << 24  # the PLL that clocks the system cannot be stopped
        self.regs[CR] = new
        if new & (1 << 16) and not old & (1 << 16):
            self._later("hse", HSE_START_US, self._hse_ready)
        if not new & (1 << 16):
            self._cancel("hse")
            self.regs[CR] &= ~(1 << 17)
        if new & (1 << 24) and not old & (1 << 24):
            self._check_pll()
            self._later("pll", PLL_LOCK_US, self._pll_lock)
        if not new & (1 << 24):
            self._cancel("pll")
            self.regs[CR] &= ~(1 << 25)

    def _later(self, name: str, us: int, action: Callable[[], None]) -> None:
        self._cancel(name)
        self._events[name] = self.soc.scheduler.after(us * PS_PER_US, action)

    def _cancel(self, name: str) -> None:
        event = self._events.pop(name, None)
        if event is not None:
            event.cancel()  # type: ignore[attr-defined]

    def _hse_ready(self) -> None:
        self._events.pop("hse", None)
        if self.hse_present:
            self.regs[CR] |= 1 << 17

    def _pll_lock(self) -> None:
        self._events.pop("pll", None)
        source_ready = self.regs[CR] & (1 << 17) if self.regs[PLLCFGR] & (1 << 22) else self.regs[CR] & 2
        if source_ready:
            self.regs[CR] |= 1 << 25
        else:
            self._later("pll", PLL_LOCK_US, self._pll_lock)  # it locks once its input runs

    def _check_pll(self) -> None:
        pll = self.regs[PLLCFGR]
        m, n, q = pll & 0x3F, (pll >> 6) & 0x1FF, (pll >> 24) & 0xF
        source = self.hse_hz if pll & (1 << 22) else HSI_HZ
        problems = []
        if not 2 <= m <= 63:
            problems.append(f"PLLM = {m} (2..63)")
        elif not 0.95e6 <= source / m <= 2.1e6:
            problems.append(f"VCO input {source / m / 1e6:g} MHz (1..2 MHz)")
        if not 50 <= n <= 432:
            problems.append(f"PLLN = {n} (50..432)")
        elif m and not 100e6 <= source / m * n <= 432e6:
            problems.append(f"VCO {source / m * n / 1e6:g} MHz (100..432 MHz)")
        if m and self.pll_hz() > SYSCLK_MAX:
            problems.append(f"PLL output {self.pll_hz() / 1e6:g} MHz (at most 168 MHz)")
        if q < 2:
            problems.append(f"PLLQ = {q} (2..15)")
        elif m and source / m * n / q > 48e6 + 0.5:
            problems.append(f"48 MHz clock at {source / m * n / q / 1e6:g} MHz (at most 48 MHz)")
        if problems:
            self.report("PLL switched on with " + ", ".join(problems) + " (RM0090 7.3.2)")

    def _write_cfgr(self, value: int) -> None:
        old = self.regs[CFGR]
        self.regs[CFGR] = (old & 0xC) | (value & ~0xC)
        if (value ^ old) & 3:
            self._cancel("switch")
            self._events["switch"] = self.soc.scheduler.after(int(SWITCH_CYCLES * 1e12 / self.hclk_hz), self._switch)
        self.clocks_changed()

    def _switch(self) -> None:
        self._events.pop("switch", None)
        sw = self.regs[CFGR] & 3
        ready = {0: self.regs[CR] & 2, 1: self.regs[CR] & (1 << 17), 2: self.regs[CR] & (1 << 25)}.get(sw, 0)
        if sw == 3:
            self.report("RCC_CFGR.SW = 3: not allowed")
        if ready:
            self.regs[CFGR] = (self.regs[CFGR] & ~0xC) | sw << 2
            self.clocks_changed()


class Pwr(Peripheral):
    """PWR_CR (VOS, reset 1 on the F405/407) and PWR_CSR (VOSRDY; RM0090 5.4)."""

    name = "PWR"
    gate = ("APB1ENR", 28)

    def reset(self) -> None:
        self.cr = 0x4000

    def vos_scale1(self) -> bool:
        return bool(self.cr & 0x4000)

    def read(self, offset: int) -> int:
        if offset == 0x00:
            return self.cr
        if offset == 0x04:
            return 1 << 14  # VOSRDY
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == 0x00:
            if (value ^ self.cr) & 0x4000 and self.soc.rcc.regs[CR] & (1 << 24):
                self.report("PWR_CR.VOS changed while the PLL is on (RM0090 5.4.1)")
            self.cr = value & 0x0000_43FF & ~0xC  # CWUF, CSBF read as 0
        elif offset == 0x04:
            pass  # EWUP, BRE: not modelled
        else:
            self.unmodelled(offset, True)


class Flash(Peripheral):
    """The flash interface's registers (RM0090 3.9): ACR (latency, prefetch, caches) checked
    against HCLK; KEYR, OPTKEYR, SR, CR, OPTCR kept (programming is not modelled)."""

    name = "FLASH"
    status = frozenset({0x00})

    def reset(self) -> None:
        self.regs = {0x00: 0, 0x0C: 0, 0x10: 0x8000_0000, 0x14: 0x0FFF_AAED}

    def latency(self) -> int:
        return self.regs[0x00] & 7

    def read(self, offset: int) -> int:
        if offset in (0x04, 0x08):
            return 0  # write-only key registers
        if offset in self.regs:
            return self.regs[offset]
        return self.unmodelled(offset, False)

    def write(self, offset: int, value: int) -> None:
        if offset == 0x00:
            if value & (1 << 11) and self.regs[0] & (1 << 9):
                self.report("FLASH_ACR.ICRST set while the instruction cache is on (RM0090 3.5.2)")
            if value & (1 << 12) and self.regs[0] & (1 << 10):
                self.report("FLASH_ACR.DCRST set while the data cache is on (RM0090 3.5.2)")
            latency = value & 7
            hclk = self.soc.rcc.hclk_hz
            needed = next((k for k, limit in enumerate(WAIT_STATE_LIMITS_HZ) if hclk <= limit + 0.5), 5)
            if latency < needed:
                self.report(f"FLASH_ACR.LATENCY = {latency} at HCLK {hclk / 1e6:g} MHz; {needed} needed")
            self.regs[0] = value & 0x1F07
        elif offset in (0x04, 0x08):
            pass
        elif offset == 0x10:
            if value & 0x3:  # PG, SER
                self.report("flash programming or erase requested: not modelled")
            self.regs[0x10] = value
        elif offset in self.regs:
            self.regs[offset] = value
        else:
            self.unmodelled(offset, True)


__all__ = ["Flash", "HSI_HZ", "PS_PER_S", "Pwr", "Rcc"]
