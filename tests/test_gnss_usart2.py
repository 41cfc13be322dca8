"""The reference board's GNSS receiver on USART2 (firmware/boards/stm32f407/gnss_usart2.c):
the board's own code, built for the Cortex-M4, run in the unicorn emulator against a
register-level model of the STM32F4 USART (RM0090 section 30.6) with the message-level
u-blox receiver model (imulink.board.chips.ublox) on its lines.

The USART model: SR, DR, BRR, CR1-CR3; a byte written to DR leaves at once (TXE and TC stay
set: a synchronous model, as uart.h allows) at the baud BRR gives from the bus clock, a
received byte sets RXNE until DR is read, and the receive interrupt is taken by calling
the board's USART2 handler while RXNEIE is set. It records as violations a DR write with
UE or TE clear, a BRR write while UE is set (RM0090 30.6.3: the baud must not change while
the USART runs) and writes to reserved bits; the peripheral clock and the pins are the
board's start-up code's, outside this module. The receiver hears the board at the standard
baud within 2 % of pclk / BRR, and noise otherwise.
"""
from __future__ import annotations

import struct
import subprocess
from pathlib import Path

import pytest

from imulink.board.chips.ublox import UbloxReceiver

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
ARM_GCC = "arm-none-eabi-gcc"
PCLK1_HZ = 42_000_000  # the reference board's APB1 at 168 MHz
USART2_BASE = 0x4000_4400
SR_RXNE, SR_TC, SR_TXE = 1 << 5, 1 << 6, 1 << 7
CR1_RE, CR1_TE, CR1_RXNEIE, CR1_UE = 1 << 2, 1 << 3, 1 << 5, 1 << 13
#: Reserved bits of the control registers (RM0090 30.6.4 - 30.6.6): must be kept at reset value (0).
RESERVED = {0x0C: 0xFFFF_4000, 0x10: 0xFFFF_8090, 0x14: 0xFFFF_F000}
STANDARD_BAUDS = (4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)

HARNESS_C = r"""
#include <stdint.h>
#include "gnss_usart2.h"

volatile int32_t h_out[8];

void h_halt(void);
void h_halt(void)
{
    for (;;) {
    }
}

void h_init(uint32_t pclk1_hz, uint32_t now_ms);
void h_init(uint32_t pclk1_hz, uint32_t now_ms)
{
    gnss_usart2_init(pclk1_hz, 1u, now_ms);
}

/* h_out: completed, fix_type, fix_ok, lat, lon, height, has_velocity, h_acc */
void h_poll(uint32_t now_ms);
void h_poll(uint32_t now_ms)
{
    imu_proto_gnss_t fix;
    h_out[0] = gnss_usart2_poll(now_ms, &fix);
    if (h_out[0]) {
        h_out[1] = fix.fix_type;
        h_out[2] = fix.fix_ok;
        h_out[3] = fix.lat_1e7deg;
        h_out[4] = fix.lon_1e7deg;
        h_out[5] = fix.height_mm;
        h_out[6] = fix.has_velocity;
        h_out[7] = (int32_t)fix.h_acc_mm;
    }
}
"""

HARNESS_LD = (ROOT / "tests" / "c" / "arm_harness.ld").read_text()

SOURCES = [FIRMWARE / "boards" / "stm32f407" / "gnss_usart2.c", FIRMWARE / "boards" / "stm32f4" / "uart.c",
           FIRMWARE / "app" / "text.c", *(FIRMWARE / "drivers" / name for name in ("gnss.c", "ubx.c", "nmea.c"))]


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    work = tmp_path_factory.mktemp("gnss_usart2")
    (work / "harness.c").write_text(HARNESS_C)
    (work / "harness.ld").write_text(HARNESS_LD)
    elf = work / "harness.elf"
    cmd = [ARM_GCC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-DIMU_FIXED", "-mcpu=cortex-m4",
           "-mthumb", "-mfloat-abi=soft", "-nostartfiles", "--specs=nano.specs",
           *(f"-I{FIRMWARE / d}" for d in ("core", "app", "drivers", "boards/stm32f4", "boards/stm32f407")),
           "-T", str(work / "harness.ld"), "-o", str(elf), str(work / "harness.c"), *map(str, SOURCES)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, f"building the USART2 harness failed:\n{proc.stderr}"
    nm = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    symbols = {p[2]: int(p[0], 16) for p in (line.split() for line in nm.splitlines()) if len(p) == 3}
    return elf, symbols


class Usart:
    """STM32F4 USART2 at register level (see the module docstring)."""

    def __init__(self):
        self.regs = {0x00: SR_TXE | SR_TC, 0x04: 0, 0x08: 0, 0x0C: 0, 0x10: 0, 0x14: 0, 0x18: 0}
        self.rx: list[int] = []            # bytes on the RX line, not yet in DR
        self.tx: list[tuple[int | None, int]] = []  # (baud, byte) sent
        self.brr_history: list[int] = []
        self.violations: list[str] = []

    def baud(self) -> int | None:
        """The standard baud the USART runs at (within 2 %), None for another or none."""
        brr = self.regs[0x08]
        if not brr or not self.regs[0x0C] & CR1_UE:
            return None
        actual = PCLK1_HZ / brr  # oversampling by 16: USARTDIV = BRR / 16, baud = pclk / (16 USARTDIV)
        return next((b for b in STANDARD_BAUDS if abs(actual - b) <= 0.02 * b), None)

    def read(self, offset: int) -> int:
        if offset == 0x04:
            value = self.regs[0x04]
            self.regs[0x00] &= ~SR_RXNE
            return value
        return self.regs.get(offset, 0)

    def write(self, offset: int, value: int) -> None:
        if offset in RESERVED and value & RESERVED[offset]:
            self.violations.append(f"reserved bits 0x{value & RESERVED[offset]:08X} written at offset 0x{offset:02X}")
        if offset == 0x04:
            cr1 = self.regs[0x0C]
            if not (cr1 & CR1_UE and cr1 & CR1_TE):
                self.violations.append("DR written with UE or TE clear")
            self.tx.append((self.baud(), value & 0xFF))
        elif offset == 0x08:
            if self.regs[0x0C] & CR1_UE:
                self.violations.append("BRR written while UE is set")
            self.regs[0x08] = value & 0xFFFF
            self.brr_history.append(value & 0xFFFF)
        elif offset == 0x00:
            self.regs[0x00] &= value | ~(SR_RXNE | SR_TC)  # rc_w0 bits
        elif offset in self.regs:
            self.regs[offset] = value

    def rx_ready(self) -> bool:
        """A byte waits and the receive interrupt is on: load it into DR (RXNE)."""
        cr1 = self.regs[0x0C]
        if not self.rx or self.regs[0x00] & SR_RXNE or not (cr1 & CR1_UE and cr1 & CR1_RE and cr1 & CR1_RXNEIE):
            return False
        self.regs[0x04] = self.rx.pop(0)
        self.regs[0x00] |= SR_RXNE
        return True


class Board:
    """The harness in unicorn with USART2 the model above; NVIC and SCB as plain memory."""

    LIMIT = 5_000_000

    def __init__(self, harness):
        try:
            import unicorn
            from unicorn import arm_const
        except ImportError:
            pytest.fail("the Python package unicorn is missing: .venv/bin/pip install unicorn")

        self.arm = arm_const
        elf, self.symbols = harness
        self.usart = Usart()
        uc = self.uc = unicorn.Uc(unicorn.UC_ARCH_ARM, unicorn.UC_MODE_THUMB | unicorn.UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(arm_const.UC_CPU_ARM_CORTEX_M4)
        uc.mem_map(0x0800_0000, 1024 * 1024, unicorn.UC_PROT_READ | unicorn.UC_PROT_EXEC)
        uc.mem_map(0x2000_0000, 128 * 1024, unicorn.UC_PROT_READ | unicorn.UC_PROT_WRITE)
        uc.mem_map(0xE000_0000, 0x10_0000, unicorn.UC_PROT_READ | unicorn.UC_PROT_WRITE)
        self.unexpected: list[int] = []
        uc.mmio_map(0x4000_0000, 0x3_0000, self._read, None, self._write, None)
        data = elf.read_bytes()
        phoff, = struct.unpack_from("<I", data, 0x1C)
        phentsize, phnum = struct.unpack_from("<HH", data, 0x2A)
        for i in range(phnum):
            p_type, offset, vaddr, _, filesz = struct.unpack_from("<5I", data, phoff + i * phentsize)
            if p_type == 1 and filesz:
                uc.mem_write(vaddr, data[offset:offset + filesz])

    def _read(self, uc, offset, size, _user) -> int:
        address = 0x4000_0000 + offset
        if USART2_BASE <= address < USART2_BASE + 0x400:
            return self.usart.read(address - USART2_BASE)
        self.unexpected.append(address)
        return 0

    def _write(self, uc, offset, size, value, _user) -> None:
        address = 0x4000_0000 + offset
        if USART2_BASE <= address < USART2_BASE + 0x400:
            self.usart.write(address - USART2_BASE, value)
        else:
            self.unexpected.append(address)

    def call(self, function: str, *args: int) -> None:
        for register, value in zip((self.arm.UC_ARM_REG_R0, self.arm.UC_ARM_REG_R1), args):
            self.uc.reg_write(register, value)
        halt = self.symbols["h_halt"]
        self.uc.reg_write(self.arm.UC_ARM_REG_SP, 0x2002_0000)
        self.uc.reg_write(self.arm.UC_ARM_REG_LR, halt | 1)
        self.uc.emu_start(self.symbols[function] | 1, halt, count=self.LIMIT)
        assert self.uc.reg_read(self.arm.UC_ARM_REG_PC) == halt, f"{function} did not return"

    def out(self) -> list[int]:
        return list(struct.unpack("<8i", bytes(self.uc.mem_read(self.symbols["h_out"], 32))))


def run(board: Board, receiver: UbloxReceiver, seconds: float, step_ms: int = 10) -> list[list[int]]:
    """Drive the board's poll every `step_ms` with the receiver on the lines; the fixes it gave."""
    fixes = []
    board.call("h_init", PCLK1_HZ, 0)
    for now in range(step_ms, int(seconds * 1000) + 1, step_ms):
        board.usart.rx += list(receiver.advance(step_ms, board.usart.baud() or -1))
        while board.usart.rx_ready():
            board.call("usart2_irq_handler")  # RXNE with RXNEIE set: the interrupt
        board.call("h_poll", now)
        sent, board.usart.tx = board.usart.tx, []
        for baud, byte in sent:
            receiver.receive(bytes([byte]), baud or -1)
        out = board.out()
        if out[0]:
            fixes.append(out)
    return fixes


def test_a_receiver_out_of_the_box_is_configured_and_delivers_fixes(harness):
    board, receiver = Board(harness), UbloxReceiver(seed=1)
    receiver.set_fix(lat_deg=48.1234567, lon_deg=-11.7654321, height_m=321.5)
    fixes = run(board, receiver, 8.0)
    u = board.usart
    assert u.violations == [] and board.unexpected == []
    # found at 9600 (a u-blox receiver's default), moved to 115200 with CFG-PRT, the USART after it
    assert u.brr_history[0] == round(PCLK1_HZ / 115200) and round(PCLK1_HZ / 9600) in u.brr_history
    assert u.brr_history[-1] == round(PCLK1_HZ / 115200) and receiver.baud == 115200
    assert receiver.nav_pvt_on and receiver.period_ms == 100
    ubx = [f for f in fixes if f[6] == 1]  # NAV-PVT's (NMEA's have no velocity)
    assert len(ubx) > 30  # 10 Hz once configured
    assert ubx[-1][1:6] == [3, 1, 481234567, -117654321, 321500] and ubx[-1][7] == 2500


def test_an_absent_receiver_is_searched_for_baud_by_baud_without_waiting(harness):
    board = Board(harness)
    fixes = run(board, UbloxReceiver(present=False), 13.0)
    bauds = {round(PCLK1_HZ / brr) for brr in board.usart.brr_history}
    assert fixes == [] and board.usart.violations == [] and board.usart.tx == []
    assert {9600, 38400, 57600, 115200, 230400, 19200, 4800} <= {next(b for b in STANDARD_BAUDS
                                                                       if abs(b - x) <= 0.02 * b) for x in bauds}
