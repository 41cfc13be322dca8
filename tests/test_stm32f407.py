"""The reference board's image (firmware/boards/stm32f407: STM32F407 + GY-86).

(a) Build: `make -C firmware stm32f407` gives the ELF, map, .bin and .hex, with no
    floating point linked (the Makefile refuses it; checked again here), the vector table
    at the start of flash and the bootloader request word in RAM that no loader writes.
(b) The image in QEMU's netduinoplus2 (an STM32F405: the same memory map for these
    peripherals; RCC, GPIO, I2C, PWR, the flash interface and the DWT read as zero, so the
    crystal never starts, the PLL never locks and every I2C transfer times out): it starts
    and says HELLO within a few seconds, warns about the clock, reports the sensors' I2C
    timeout, answers commands, streams without hanging (every sample a counted sensor
    error), injection is bit-exact with the host fixed-point build for every filter,
    RESET restarts it, ENTER_BOOTLOADER restarts it through the system-memory jump.
(c) The I2C code against the virtual board's register-level models (imulink.board.stm32f407:
    I2C1 after RM0090 section 27, GPIOB, TIM5, RCC) with the GY-86 chip models
    (imulink.board.chips) behind it, the harness's functions called one at a time in unicorn:
    the GY-86 bring-up and reads over the real board code, every receive length's ending,
    NACKs, timeouts, bus errors, recovery and the start-up bus clear. (The whole image on
    those models: tests/test_virtual_board.py.)

Needs arm-none-eabi-gcc (with newlib), qemu-system-arm and the Python package unicorn:
without them the tests fail with a message saying what to install; they do not skip
(CI installs them).
"""
from __future__ import annotations

import re
import shutil
import socket
import struct
import subprocess
import time
from pathlib import Path

import pytest

from imulink import core, protocol
from imulink.board.chips import HMC5883L, MPU6050, MS5611, STATUS_CODES, I2CBus, RegisterDevice
from imulink.board.link import Link, LinkError
from imulink.board.stm32f407.core import FLASH_BASE
from imulink.board.stm32f407.gpio import GpioPort
from imulink.board.stm32f407.i2c import I2CLines, I2CPeripheral
from imulink.board.stm32f407.soc import Soc
from imulink.board.stm32f407.timers import GeneralTimer
from imulink.core.counts import DEFAULT_PROFILE
from imulink.hil import load_injection_input
from imulink.hil.replica import FirmwareFilter

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
BUILD = FIRMWARE / "build" / "stm32f407"
ELF = BUILD / "imulink-stm32f407-gy86.elf"
ARM_PREFIX = "arm-none-eabi-"
QEMU = "qemu-system-arm"
BOARD_NAME = "stm32f407-gy86"
#: QEMU's RCC reads as zero: SWS says HSI, so the board runs (and counts cycles) at 16 MHz.
HSI_HZ = 16_000_000
#: From the QEMU socket's connection (QEMU starts the VM then) to the start-up LOGs.
START_UP_LIMIT_S = 5.0
INJECTED = "sim:rests:3:100:0"  # 300 samples at 100 Hz


def _need(program: str, install: str) -> str:
    path = shutil.which(program)
    assert path, f"{program} not found: install {install}"
    return path


def _toolchain() -> None:
    _need(ARM_PREFIX + "gcc", "the GNU Arm Embedded toolchain with newlib "
          "(Debian/Ubuntu: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)")


def test_toolchain_and_emulators_are_installed():
    _toolchain()
    _need(QEMU, "QEMU's Arm system emulator (Debian/Ubuntu: apt-get install qemu-system-arm)")
    try:
        import unicorn  # noqa: F401
    except ImportError:
        pytest.fail("the Python package unicorn is missing: .venv/bin/pip install unicorn")


# --------------------------------------------------------------------------- (a) the build


@pytest.fixture(scope="module")
def image() -> Path:
    _toolchain()
    proc = subprocess.run(["make", "-C", str(FIRMWARE), "stm32f407"], capture_output=True, text=True)
    assert proc.returncode == 0, f"make -C firmware stm32f407 failed:\n{proc.stdout}{proc.stderr}"
    return ELF


def _tool(name: str, *args) -> str:
    return subprocess.run([ARM_PREFIX + name, *map(str, args)], capture_output=True, text=True, check=True).stdout


def test_build_gives_elf_map_bin_and_hex(image):
    assert "stm32f407" in image.name and image.is_file()
    for suffix in (".map", ".bin", ".hex"):
        assert image.with_suffix(suffix).is_file(), f"{image.with_suffix(suffix)} missing"
    assert image.with_suffix(".hex").read_text().rstrip().endswith(":00000001FF")
    assert 16_000 < image.with_suffix(".bin").stat().st_size < 128 * 1024


def test_image_links_no_floating_point(image):
    symbols = _tool("nm", image)
    assert not re.search(r" (__aeabi_[fd]\w*|__\w+[sd]f[23]?)$", symbols, re.M)
    assert not re.search(r"\sv(add|sub|mul|div|sqrt|cvt|ldr|str|mov)\.", _tool("objdump", "-d", image))


def test_image_layout(image):
    """The vector table is at the start of flash, the bootloader request is in RAM after .bss
    and in no loadable segment (a loader that zeroes RAM at reset must not clear it)."""
    sections = {m[1]: (int(m[2], 16), int(m[3], 16)) for m in
                re.finditer(r"^\s*\d+\s+(\S+)\s+([0-9a-f]+)\s+([0-9a-f]+)", _tool("objdump", "-h", image), re.M)}
    assert sections[".isr_vector"][1] == 0x0800_0000
    bss_end = sum(sections[".bss"])
    noinit = sections[".noinit"]
    assert noinit[0] >= 8 and bss_end <= noinit[1] < 0x2002_0000 - 8 * 1024
    program_headers = _tool("readelf", "-lW", image)
    mapping = program_headers[program_headers.index("Segment Sections"):]
    assert ".noinit" not in mapping
    vectors = image.with_suffix(".bin").read_bytes()[:8]
    assert int.from_bytes(vectors[:4], "little") == 0x2002_0000  # initial SP: the end of the 128 KB SRAM


# --------------------------------------------------------------------------- (b) in QEMU


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class QemuBoard:
    """The stm32f407 image in QEMU, its USART1 a TCP socket the link connects to."""

    def __init__(self, elf: Path, log: Path):
        _need(QEMU, "QEMU's Arm system emulator (Debian/Ubuntu: apt-get install qemu-system-arm)")
        self.log = log
        self.port = _free_port()
        self.process = subprocess.Popen(
            [QEMU, "-M", "netduinoplus2", "-nographic", "-monitor", "none", "-kernel", str(elf),
             "-d", "guest_errors", "-D", str(log),
             "-serial", f"tcp:127.0.0.1:{self.port},server=on,wait=on,nodelay=on"],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 10
        while True:
            try:
                self.link = Link(f"socket://127.0.0.1:{self.port}")  # QEMU starts the VM now
                break
            except LinkError:
                assert self.process.poll() is None, f"QEMU exited: {self.process.communicate()[1].decode()}"
                assert time.monotonic() < deadline, "QEMU does not listen on its serial socket"
                time.sleep(0.05)
        self.connected = time.monotonic()

    def close(self) -> None:
        self.link.close()
        self.process.kill()
        self.process.communicate()

    def log_text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""


def start_up_messages(link: Link, timeout: float = START_UP_LIMIT_S) -> list[protocol.Message]:
    """HELLO and the start-up LOGs: a WARNING (the clock) and the sensors' ERROR."""
    return link.receive_until(lambda m: m.name == "LOG" and m.fields["level"] == protocol.LOG_LEVELS["ERROR"], timeout)


@pytest.fixture(scope="module")
def board(image, tmp_path_factory):
    qemu = QemuBoard(image, tmp_path_factory.mktemp("qemu") / "guest_errors.log")
    try:
        qemu.first_messages = start_up_messages(qemu.link)
        qemu.start_up_s = time.monotonic() - qemu.connected
        qemu.link.connect()
        yield qemu
    finally:
        qemu.close()


@pytest.fixture
def link(board):
    """The board's link, the board freshly RESET (defaults, sequence numbers from 0)."""
    board.link.receive(0)
    board.link.command("RESET")
    start_up_messages(board.link)
    board.link.receive(0)
    return board.link


def _logs(messages, level: str) -> list[str]:
    return [m.fields["text"] for m in messages if m.name == "LOG" and m.fields["level"] == protocol.LOG_LEVELS[level]]


def test_starts_without_hanging_and_says_what_failed(board):
    messages = board.first_messages
    assert board.start_up_s < START_UP_LIMIT_S
    assert [m.name for m in messages[:3]] == ["HELLO", "LOG", "LOG"], [m.name for m in messages]
    hello = messages[0]
    assert hello.seq == 0 and hello.fields["board"] == BOARD_NAME
    assert hello.fields["schema_hash"] == protocol.SCHEMA_HASH
    assert hello.fields["filters"] == sum(1 << fid for fid, _ in core.BOARD_FILTERS.values())
    warning, = _logs(messages, "WARNING")
    # QEMU models no RCC: no HSERDY, no PLLRDY; SWS reads HSI. The baud rate that follows is named.
    assert warning.startswith("clock: the 8 MHz crystal (HSE) did not start and the PLL did not lock: "
                              "running on the 16 MHz HSI"), warning
    assert "USART1 at 941176 baud" in warning
    error, = _logs(messages, "ERROR")
    assert error.startswith("GY-86 not ready: MPU6050: timeout"), error  # I2C1 never answers: bounded


def test_status_reports_the_clocks_in_use(link):
    status = link.command("GET_STATUS").data.fields
    assert status["cycle_hz"] == HSI_HZ  # SYSCLK as decoded from RCC_CFGR, not the intended 168 MHz
    assert status["active_filter"] == core.FILTERS["eskf"][0]
    assert status["sample_rate_mhz"] == 100_000
    assert status["streaming"] == 0 and status["injection_mode"] == 0
    assert status["dropped_samples"] == status["sensor_errors"] == 0


def test_stream_counts_failed_sensor_reads_and_stops(link):
    link.command("START_STREAM")
    messages = link.receive_until(lambda m: m.name == "LOG" and "failed reads" in m.fields["text"], timeout=5.0)
    time.sleep(0.3)
    messages += [r.message for r in link.receive(0)]
    link.command("STOP_STREAM")
    status = link.command("GET_STATUS").data.fields
    assert status["streaming"] == 0
    assert status["sensor_errors"] > 0 and status["dropped_samples"] >= status["sensor_errors"]
    assert not [m for m in messages if m.name in ("SAMPLE", "ESTIMATE")]
    errors = _logs(messages, "ERROR")
    assert errors and all(e.startswith("GY-86 not ready: MPU6050: timeout") for e in errors), errors[:3]
    # Stopped means stopped: no more failures are counted.
    time.sleep(0.2)
    again = link.command("GET_STATUS").data.fields
    assert again["sensor_errors"] == status["sensor_errors"]


def test_resend_answers_for_every_seq_asked(link):
    """Without samples the ring holds nothing and has forgotten nothing: every frame sent
    was an output (NOT_KEPT); a seq not sent yet is GONE. Every seq gets its RESENT before the ACK."""
    latest = link.command("GET_STATUS").ack.seq
    link.receive(0)
    link.command("RESEND", first_seq=(latest - 1) & 0xFFFF, count=3)
    answers = [r.message.fields for r in link.receive(0.2) if r.message.name == "RESENT"]
    assert [(a["original_seq"], a["status"]) for a in answers] == [
        ((latest - 1) & 0xFFFF, 1), (latest, 1), ((latest + 1) & 0xFFFF, 2)]


@pytest.mark.parametrize("filter_name", list(core.FILTERS))
def test_injection_is_bit_exact_with_the_host(link, filter_name):
    source = load_injection_input(INJECTED)
    assert source.profile == DEFAULT_PROFILE and len(source.gyr) == 300
    link.command("SELECT_FILTER", filter_id=core.FILTERS[filter_name][0])
    link.command("SET_INJECTION_MODE", enabled=1)
    reference = FirmwareFilter(filter_name, FirmwareFilter.default_raw_settings(filter_name, source.rate_hz))
    gyr, acc, mag = source.gyr.tolist(), source.acc.tolist(), source.mag.tolist()
    for k in range(len(gyr)):
        reply = link.command("INJECT_SAMPLE", timestamp_us=k * 10_000, index=k, gyr=gyr[k], acc=acc[k], mag=mag[k],
                             temperature=0)
        expected = reference.step(k, gyr[k], acc[k], mag[k])
        got = {name: list(value) if isinstance(value, tuple) else value for name, value in reply.data.fields.items()}
        assert got == expected, f"{filter_name}, sample {k}"
    link.command("SET_INJECTION_MODE", enabled=0)


def test_reset_starts_again_from_sequence_zero(board, link):
    link.command("SELECT_FILTER", filter_id=core.FILTERS["kf1d"][0])
    link.receive(0)
    link.command("RESET")
    messages = start_up_messages(link)
    assert [m.name for m in messages[:4]] == ["ACK", "HELLO", "LOG", "LOG"]  # the ACK left before the reset
    assert messages[1].seq == 0
    assert _logs(messages, "WARNING") and _logs(messages, "ERROR")
    assert link.command("GET_STATUS").data.fields["active_filter"] == core.FILTERS["eskf"][0]


def test_enter_bootloader_resets_into_the_system_memory(board, link):
    """ENTER_BOOTLOADER is ACKed; the next start jumps to the vector table at 0x1FFF0000
    (AN2606). QEMU has no system memory there: the read faults (QEMU logs it as a guest
    error), the fault handler resets, and since the request was cleared before the jump the
    firmware starts normally."""
    def jumps() -> int:
        return len(re.findall(r"invalid (?:read|access) at addr 0x1FFF0000\b", board.log_text(), re.I))

    before = jumps()
    reply = link.command("ENTER_BOOTLOADER")
    assert reply.ack.name == "ACK"
    messages = start_up_messages(link)
    assert [m.name for m in messages[:4]] == ["ACK", "HELLO", "LOG", "LOG"] and messages[1].seq == 0
    assert link.command("GET_STATUS").data.fields["streaming"] == 0
    deadline = time.monotonic() + 2
    while jumps() == before and time.monotonic() < deadline:
        time.sleep(0.05)
    assert jumps() == before + 1  # one jump, not a loop: the request does not survive it
    link.command("RESET")
    start_up_messages(link)
    time.sleep(0.1)
    assert jumps() == before + 1  # a plain RESET does not start the bootloader


# --------------------------------------------------------------------------- (c) I2C against a register-level model

#: The harness: the board's I2C code and the GY-86 drivers, called one function at a time.
HARNESS_C = r"""
#include "gy86.h"
#include "i2c_stm32f4.h"
#include "ms5611.h"

i2c_stm32f4_t h_dev;
i2c_bus_t h_bus;
gy86_t h_gy86;
sensor_status_t h_status;
imu_raw_sample_t h_raw;
int16_t h_temperature;
uint8_t h_out[32];
uint8_t h_in[32];
int32_t h_result;
ms5611_t h_baro;
ms5611_reading_t h_reading;
int h_ready;

void h_halt(void);
void h_init(uint32_t pclk1_hz, uint32_t cpu_hz);
void h_write(uint32_t address, uint32_t len);
void h_write_read(uint32_t address, uint32_t write_len, uint32_t read_len);
void h_delay_ms(uint32_t ms);
void h_gy86_init(void);
void h_gy86_read(void);
void h_ms5611_init(void);
void h_ms5611_poll(uint32_t now_us);

void h_halt(void) { for (;;) { } }
void h_init(uint32_t pclk1_hz, uint32_t cpu_hz)
{
    h_result = (int32_t)i2c_stm32f4_init(&h_dev, pclk1_hz, cpu_hz, &h_bus);
}
void h_write(uint32_t address, uint32_t len) { h_result = h_bus.write(h_bus.context, (uint8_t)address, h_out, len); }
void h_write_read(uint32_t address, uint32_t write_len, uint32_t read_len)
{
    h_result = h_bus.write_read(h_bus.context, (uint8_t)address, h_out, write_len, h_in, read_len);
}
void h_delay_ms(uint32_t ms) { h_bus.delay_ms(h_bus.context, ms); }
void h_gy86_init(void) { h_status = gy86_init(&h_gy86, &h_bus, &gy86_default_config); h_result = h_status.result; }
void h_gy86_read(void) { h_status = gy86_read(&h_gy86, &h_raw, &h_temperature); h_result = h_status.result; }
void h_ms5611_init(void)
{
    h_status = ms5611_init(&h_baro, &h_bus, MS5611_ADDRESS, MS5611_OSR_4096);
    h_result = h_status.result;
}
void h_ms5611_poll(uint32_t now_us)
{
    h_status = ms5611_poll(&h_baro, now_us, &h_reading, &h_ready);
    h_result = h_status.result;
}
"""

HARNESS_LD = (ROOT / "tests" / "c" / "arm_harness.ld").read_text()  # flash, RAM and h_halt as the entry

HARNESS_SOURCES = [*sorted((FIRMWARE / "drivers").glob("*.c")), FIRMWARE / "core" / "imu_sensor.c",
                   FIRMWARE / "core" / "imu_math.c", FIRMWARE / "boards" / "stm32f4" / "timers.c",
                   FIRMWARE / "boards" / "stm32f407" / "i2c_stm32f4.c"]

MPU, HMC = 0x68, 0x1E
STATUS = STATUS_CODES  # i2c_status_t by name
LINES = {"IDLE": 0, "FREED": 1, "SCL_LOW": 2, "SDA_LOW": 3}
CR1_PE = 1
SCL, SDA = 8, 9
#: RCC as the reference board's clock set-up leaves it (RM0090 7.3): the PLL from the 8 MHz
#: crystal at 168 MHz, APB1 /4 (42 MHz), APB2 /2; five flash wait states.
RCC_168_MHZ = {0x00: 0x0303_0083, 0x04: 0x2740_5408, 0x08: 0x0000_940A}


def _load_segments(elf: bytes):
    """(run address, bytes) of every PT_LOAD with file contents (ELF32 little-endian)."""
    phoff, = struct.unpack_from("<I", elf, 0x1C)
    phentsize, phnum = struct.unpack_from("<HH", elf, 0x2A)
    for i in range(phnum):
        p_type, offset, vaddr, _paddr, filesz = struct.unpack_from("<5I", elf, phoff + i * phentsize)
        if p_type == 1 and filesz:
            yield vaddr, elf[offset:offset + filesz]


@pytest.fixture(scope="module")
def harness(tmp_path_factory) -> tuple[Path, dict[str, int]]:
    _toolchain()
    work = tmp_path_factory.mktemp("i2c_harness")
    (work / "harness.c").write_text(HARNESS_C)
    (work / "harness.ld").write_text(HARNESS_LD)
    elf = work / "harness.elf"
    cmd = [ARM_PREFIX + "gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-DIMU_FIXED",
           "-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=soft", "-nostartfiles", "--specs=nano.specs",
           *(f"-I{FIRMWARE / d}" for d in ("core", "app", "drivers", "boards/stm32f4", "boards/stm32f407")),
           "-T", str(work / "harness.ld"), "-o", str(elf), str(work / "harness.c"), *map(str, HARNESS_SOURCES)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, f"building the I2C harness failed:\n{proc.stderr}"
    symbols = {}
    for line in _tool("nm", elf).splitlines():
        parts = line.split()
        if len(parts) == 3:
            symbols[parts[2]] = int(parts[0], 16)
    return elf, symbols


class Board:
    """The harness on the virtual STM32F407 (imulink.board.stm32f407: the same register-level
    models the reference image runs on) with GPIOB, TIM5 as the microsecond clock (set up as
    timers_clock_init does) and I2C1, a GY-86 on the bus. Functions are called one at a time."""

    INSTRUCTION_LIMIT = 30_000_000  # a call that runs longer has hung

    def __init__(self, harness, pclk1_hz: int = 42_000_000):
        from unicorn import arm_const
        self.arm = arm_const
        elf, self.symbols = harness
        segments = list(_load_segments(elf.read_bytes()))
        flash = bytearray(b"\xff" * (256 << 10))
        for address, data in segments:
            if address >= FLASH_BASE:
                flash[address - FLASH_BASE:address - FLASH_BASE + len(data)] = data
        soc = self.soc = Soc(bytes(flash), boots=False)
        self.uc = soc.core.uc
        for address, data in segments:
            if address < FLASH_BASE:
                self.uc.mem_write(address, bytes(data))
        if pclk1_hz == 42_000_000:
            soc.rcc.regs.update(RCC_168_MHZ)
            soc.flash_interface.regs[0x00] = 5
            soc.rcc.clocks_changed()
        soc.rcc.regs[0x30] |= 1 << 1  # GPIOBEN
        soc.rcc.regs[0x40] |= 1 << 3  # TIM5EN
        self.gpio = soc.add(GpioPort(soc, "B"))
        self.lines = I2CLines(self.gpio, SCL, SDA)
        self.bus = I2CBus()
        self.mpu = self.bus.attach(MPU, MPU6050())
        self.hmc = self.mpu.aux_bus.attach(HMC, HMC5883L())
        self.i2c = soc.add(I2CPeripheral(soc, 1, 0x4000_5400, self.bus, self.lines, (31, 32)))
        tim5 = soc.add(GeneralTimer(soc, 5, 0x4000_0C00, 50))
        for offset, value in ((0x28, int(soc.rcc.timer_hz(1)) // 1_000_000 - 1), (0x2C, 0xFFFF_FFFF), (0x14, 1),
                              (0x10, 0), (0x00, 0x5)):  # PSC (1 us), ARR, EGR.UG, SR, CR1 = URS | CEN
            soc.write(tim5.base + offset, value)

    @property
    def now(self) -> float:
        """Virtual time, us."""
        return self.soc.scheduler.now / 1e6

    def problems(self) -> list[str]:
        return self.soc.problems

    def call(self, function: str, *args: int) -> int:
        for register, value in zip((self.arm.UC_ARM_REG_R0, self.arm.UC_ARM_REG_R1, self.arm.UC_ARM_REG_R2), args):
            self.uc.reg_write(register, value)
        halt = self.symbols["h_halt"]
        self.uc.reg_write(self.arm.UC_ARM_REG_SP, 0x2002_0000)
        self.uc.reg_write(self.arm.UC_ARM_REG_LR, halt | 1)
        self.uc.emu_start(self.symbols[function] | 1, halt, count=self.INSTRUCTION_LIMIT)
        pc = self.uc.reg_read(self.arm.UC_ARM_REG_PC)
        assert pc == halt, f"{function} did not return within {self.INSTRUCTION_LIMIT} instructions (pc 0x{pc:08x})"
        return self.result()

    def result(self) -> int:
        return int.from_bytes(self.read("h_result", 4), "little", signed=True)

    def read(self, name: str, size: int, offset: int = 0) -> bytes:
        return bytes(self.uc.mem_read(self.symbols[name] + offset, size))

    def write(self, name: str, data: bytes) -> None:
        self.uc.mem_write(self.symbols[name], bytes(data))

    def counters(self) -> dict[str, int]:
        names = ("pclk1_hz", "cpu_mhz", "transfers", "failures", "recoveries", "bus_clears", "start_lines")
        return dict(zip(names, struct.unpack("<7I", self.read("h_dev", 28))))

    def init(self, pclk1_hz: int = 42_000_000, cpu_hz: int = 168_000_000) -> int:
        return self.call("h_init", pclk1_hz, cpu_hz)

    def write_read(self, address: int, out: bytes, n: int) -> tuple[int, bytes]:
        self.write("h_out", out)
        status = self.call("h_write_read", address, len(out), n)
        return status, self.read("h_in", n)

    def i2c_write(self, address: int, out: bytes) -> int:
        self.write("h_out", out)
        return self.call("h_write", address, len(out))

    def events_since(self, mark: int) -> list[tuple]:
        return self.i2c.events[mark:]


def _rx_bytes(events) -> list[tuple[int, bool]]:
    return [(e[1], e[2]) for e in events if e[0] == "RX"]


def test_i2c_set_up_follows_rm0090(harness):
    b = Board(harness)
    assert b.init() == LINES["IDLE"]
    i2c, gpio = b.i2c, b.gpio
    assert i2c.cr2 & 0x3F == 42 and i2c.cr2 & 0x1F00 == 0  # FREQ = 42 MHz, no interrupts, no DMA
    assert i2c.ccr == 0x8000 | 35  # fast mode, DUTY 0: 3 * 35 / 42 MHz = 2.5 us, 400 kHz
    assert i2c.trise == 13  # 300 ns * 42 MHz + 1
    assert i2c.oar1 & 0x4000 and i2c.cr1 == CR1_PE
    for pin in (SCL, SDA):
        assert gpio.mode(pin) == 2 and (gpio.regs[0x04] >> pin) & 1  # AF, open-drain
        assert (gpio.regs[0x24] >> (4 * (pin - 8))) & 0xF == 4  # AF4
        assert (gpio.regs[0x0C] >> (2 * pin)) & 3 == 1  # pull-up
    assert b.lines.scl_rises == 0  # an idle bus is not clocked
    assert b.problems() == []
    # The HSI fall-back: APB1 at 16 MHz (CCR rounded up: 381 kHz, never above 400 kHz).
    slow = Board(harness, pclk1_hz=16_000_000)  # RCC as reset leaves it: the HSI for everything
    assert slow.init(16_000_000, 16_000_000) == LINES["IDLE"]
    assert (slow.i2c.cr2 & 0x3F, slow.i2c.ccr, slow.i2c.trise) == (16, 0x8000 | 14, 5)
    assert slow.problems() == []


class Memory(RegisterDevice):
    """A plain register chip (a pointer and 256 registers) with a recognisable content."""

    def __init__(self):
        super().__init__()
        self.regs = bytearray((7 * r + 3) & 0xFF for r in range(256))

    def read_register(self, register: int) -> int:
        return self.regs[register]

    def write_register(self, register: int, value: int) -> None:
        self.regs[register] = value


MEMORY = 0x50


@pytest.fixture
def ready(harness):
    """A board model with I2C1 set up and a plain register chip at 0x50 beside the GY-86."""
    b = Board(harness)
    b.memory = b.bus.attach(MEMORY, Memory())
    assert b.init() == LINES["IDLE"]
    return b


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6, 14])
def test_i2c_receive_endings(ready, n):
    """1 byte (ACK cleared at EV6, STOP), 2 bytes (POS), N > 2 (BTF, the last three): every
    byte arrives, all but the last are ACKed, the last NACKed, no byte more is clocked out."""
    b, start = ready, 0x20
    mark = len(b.i2c.events)
    status, data = b.write_read(MEMORY, bytes([start]), n)
    assert status == STATUS["OK"]
    assert list(data) == [(7 * r + 3) & 0xFF for r in range(start, start + n)]
    events = b.events_since(mark)
    assert events[:4] == [("START",), ("ADDR", MEMORY, False, True), ("TX", start, True), ("START",)]
    assert events[4] == ("ADDR", MEMORY, True, True) and events[-1] == ("STOP",)
    assert [ack for _, ack in _rx_bytes(events)] == [True] * (n - 1) + [False]
    assert b.memory.pointer == start + n  # the chip sent exactly n bytes
    assert b.problems() == []
    assert b.counters()["recoveries"] == 0


@pytest.mark.parametrize("payload", [b"\x10", b"\x10\xAA", b"\x40\x01\x02\x03\x04\x05\x06"])
def test_i2c_transmit(ready, payload):
    b = ready
    mark = len(b.i2c.events)
    assert b.i2c_write(MEMORY, payload) == STATUS["OK"]
    assert b.events_since(mark) == [("START",), ("ADDR", MEMORY, False, True),
                                    *[("TX", v, True) for v in payload], ("STOP",)]
    assert bytes(b.memory.regs[payload[0]:payload[0] + len(payload) - 1]) == payload[1:]
    assert b.problems() == []


def _still_works(b: Board) -> None:
    status, data = b.write_read(MPU, b"\x75", 1)  # WHO_AM_I
    assert (status, data) == (STATUS["OK"], b"\x68")


def test_i2c_address_nack_is_not_a_data_nack(ready):
    b = ready
    mark = len(b.i2c.events)
    status, _ = b.write_read(0x33, b"\x00", 1)
    assert status == STATUS["NACK_ADDRESS"]
    assert b.events_since(mark) == [("START",), ("ADDR", 0x33, False, False), ("STOP",)]
    assert not b.i2c.af and not b.i2c.busy  # AF cleared, STOP sent
    assert b.counters()["recoveries"] == 0  # after an address NACK a STOP is all it takes
    b.i2c.inject(nack_data=1)
    mark = len(b.i2c.events)
    assert b.i2c_write(MEMORY, b"\x10\x01\x02") == STATUS["NACK_DATA"]
    assert b.events_since(mark) == [("START",), ("ADDR", MEMORY, False, True), ("TX", 0x10, True),
                                    ("TX", 0x01, False), ("STOP",)]
    # The next byte was already in DR when the NACK came: the peripheral is reset to empty it.
    assert b.counters()["recoveries"] == 1
    mark = len(b.i2c.events)
    _still_works(b)
    assert b.events_since(mark)[:3] == [("START",), ("ADDR", MPU, False, True), ("TX", 0x75, True)]
    assert b.problems() == []


@pytest.mark.parametrize("fault, status", [("dead", "TIMEOUT"), ("berr", "BUS"), ("arlo", "ARBITRATION")])
def test_i2c_errors_recover_the_peripheral(ready, fault, status):
    b = ready
    b.i2c.inject(**{fault: "until_reset" if fault == "dead" else True})
    started = b.now
    result, _ = b.write_read(MPU, b"\x3B", 14)
    assert result == STATUS[status]
    assert b.now - started < 5_000  # bounded: within a few ms of bus time
    assert b.counters()["recoveries"] == 1 and b.counters()["failures"] == 1
    _still_works(b)
    assert b.problems() == []


@pytest.mark.parametrize("fault", ["dead", "zero"])
def test_i2c_never_hangs_on_a_dead_peripheral(ready, fault):
    """SB never sets (the peripheral stuck, or every register reading zero as in QEMU): every
    transfer times out within a bounded time, again and again."""
    b = ready
    b.i2c.inject(**{fault: "forever"})
    for _ in range(3):
        started = b.now
        assert b.write_read(MPU, b"\x75", 1)[0] == STATUS["TIMEOUT"]
        assert b.i2c_write(MPU, b"\x6B\x00") == STATUS["TIMEOUT"]
        assert b.now - started < 20_000
    del b.i2c.faults[fault]
    _still_works(b)


@pytest.mark.parametrize("rises, lines", [(3, "FREED"), (None, "SDA_LOW")])
def test_i2c_start_up_bus_clear(harness, rises, lines):
    """A slave stopped mid-byte holds SDA low: SCL is pulsed by hand (at most 9 times) and a
    STOP sent before the peripheral takes the pins."""
    b = Board(harness)
    b.lines.hold_sda(rises)
    assert b.init() == LINES[lines]
    bus_lines = b.lines
    assert bus_lines.scl_rises == (3 + 1 if rises else 9) and bus_lines.starts == 0  # + the STOP's own SCL rise
    assert bus_lines.stops == (1 if rises else 0)
    assert b.counters()["bus_clears"] == 1 and b.counters()["start_lines"] == LINES[lines]
    assert b.gpio.mode(SCL) == b.gpio.mode(SDA) == 2  # back to I2C1
    if rises:
        _still_works(b)
    assert b.problems() == []


def test_i2c_scl_held_low_at_start_up(harness):
    b = Board(harness)
    b.lines.scl_stuck = True
    assert b.init() == LINES["SCL_LOW"]
    assert b.lines.scl_rises == 0 and b.problems() == []


def test_i2c_delay(ready):
    started = ready.now
    ready.call("h_delay_ms", 5)
    # at least 5 ms; the virtual clock moves through a wait loop in steps that grow to 50 us,
    # so it may end a step or two (2 %) late
    assert 5_000 <= ready.now - started < 5_100


def test_ms5611_over_the_board_i2c(ready):
    """The barometer's bring-up (reset, PROM and its CRC) and its measurement cycle over the
    board's I2C code and the chip model at 0x77, polled as the sample loop polls it: D1 and
    D2 at OSR 4096, each read once its 9.04 ms conversion is over, compensated to the data
    sheet's worked example."""
    b = ready
    baro = b.bus.attach(0x77, MS5611())
    assert b.call("h_ms5611_init") == 0, b.read("h_status", 16).hex()
    readings = []
    for _ in range(45):  # 45 ms: two measurements
        assert b.call("h_ms5611_poll", int(b.now)) == 0, b.read("h_status", 16).hex()
        if struct.unpack("<i", b.read("h_ready", 4))[0]:
            readings.append(struct.unpack("<iiII", b.read("h_reading", 16)))
        b.call("h_delay_ms", 1)
    assert readings == [(100009, 2007, 9085466, 8569150)] * 2
    assert baro.conversions[:4] == [0x48, 0x58, 0x48, 0x58]
    counters = b.counters()
    assert counters["failures"] == 0 and b.problems() == []


def test_gy86_over_the_board_i2c(ready):
    """The GY-86 bring-up and a sample over the board's I2C code and the register model."""
    b = ready
    started = b.now
    assert b.call("h_gy86_init") == 0, b.read("h_status", 16).hex()
    assert b.now - started >= 136_000  # reset 100 ms + gyro start 30 ms + first field 6 ms
    mpu, hmc = b.mpu, b.hmc
    assert mpu.peek("GYRO_CONFIG") == 3 << 3 and mpu.peek("ACCEL_CONFIG") == 2 << 3
    assert mpu.peek("SMPLRT_DIV") == 9 and mpu.peek("CONFIG") & 7 == 3 and mpu.bypass_enabled
    assert hmc.regs[1] >> 5 == 1  # gain 1090 LSB/gauss
    mpu.set_sample(acc=(100, -200, 4096), gyro=(1, -2, 3), temperature=-3920)
    hmc.set_field(120, -340, 560)
    b.call("h_delay_ms", 20)  # the magnetometer measures at 75 Hz
    assert b.call("h_gy86_read") == 0
    raw = struct.unpack("<9h", b.read("h_raw", 18))
    assert raw == (1, -2, 3, 100, -200, 4096, 120, -340, 560)
    assert struct.unpack("<h", b.read("h_temperature", 2))[0] == -3920
    counters = b.counters()
    assert counters["failures"] == counters["recoveries"] == 0 and counters["transfers"] > 10
    assert b.problems() == []
