"""The reference board's image (firmware/build/stm32f407, the one that gets flashed) on the
virtual STM32F407 + GY-86 (imulink.board.stm32f407): register-level models of the chip's
peripherals (RM0090) and of the GY-86's chips, every problem they see reported.

- it boots with the clocks, baud rate and I2C speed its docs state, configures the chips as
  their data sheets require, and the models report nothing wrong;
- record + compare over the link is bit-exact for every filter, nav with the receiver and
  the barometer included; the sample rate from the board's own timestamps is the setting's;
- chip faults end in the board's report and the board goes on;
- the core's semantics: WFI wakes on a masked pending interrupt, an interrupt is taken the
  instant PRIMASK clears, a hang is reported with its function;
- the same scripted run gives the same bytes;
- a deliberately broken driver (I2C event order, a clock left off, a wrong BRR) is caught;
- `imulink flash` into the bootloader emulator, Go, and the flashed image's HELLO.

Needs arm-none-eabi-gcc (the image) and unicorn; CI installs both.
"""
from __future__ import annotations

import shutil
import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imulink import core, hil, protocol, sim
from imulink.analysis.attitude import attitude_errors, rmse
from imulink.board import flash as flashing
from imulink.board import stm32f407
from imulink.board.chips import BootloaderPort, Stm32Bootloader
from imulink.board.emulator import EmulatedBoard, reference_flash
from imulink.board.link import Link
from imulink.board.stm32f407.core import FLASH_BASE
from imulink.board.stm32f407.soc import Soc
from imulink.io.firmware_image import load_image
from imulink.io.recording import load_recording

#: The virtual board takes a core: these tests never run beside the real-time lossy-link tests
#: (tests/test_resend.py), whose 1 kHz boards lose samples when the machine is starved, nor
#: beside the QEMU board (tests/test_qemu.py) (`make test` runs with --dist loadgroup).
pytestmark = pytest.mark.xdist_group("takes-a-core")

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
ELF = FIRMWARE / "build" / "stm32f407" / "imulink-stm32f407-gy86.elf"
ARM_GCC = "arm-none-eabi-gcc"


@pytest.fixture(scope="module")
def image() -> Path:
    assert shutil.which(ARM_GCC), "arm-none-eabi-gcc not found: `make setup` installs it"
    proc = subprocess.run(["make", "-C", str(FIRMWARE), "stm32f407"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return ELF


def start(path: Path, **options) -> stm32f407.ReferenceBoard:
    flash, elf = reference_flash(path)
    return stm32f407.ReferenceBoard(flash, elf=elf, **options)


def messages(board: stm32f407.ReferenceBoard, decoder: protocol.FrameDecoder | None = None) -> list[protocol.Message]:
    decoder = decoder or protocol.FrameDecoder()
    return [m for m in decoder.feed(board.take()) if isinstance(m, protocol.Message)]


def command(board: stm32f407.ReferenceBoard, name: str, seq: int = 0, **args) -> list[protocol.Message]:
    board.put(protocol.encode_command(seq, name, seq + 1, **args))
    board.run_for(0.05)
    return messages(board)


def logs(found: list[protocol.Message]) -> list[str]:
    return [m.fields["text"] for m in found if m.name == "LOG"]


@pytest.fixture(scope="module")
def booted(image):
    """The image after 0.5 s of virtual time, streaming 2 s of a simulated run."""
    run = sim.make_scenario("random", 4.0, 100.0, 3)
    board = start(image, feed=stm32f407.Feed(100.0, run.gyr_counts, run.acc_counts, run.mag_counts))
    board.run_for(0.5)
    board.start_up = messages(board)
    board.put(protocol.encode_command(0, "START_STREAM", 1))
    board.run_for(2.0)
    board.streamed = messages(board)
    return board


# --------------------------------------------------------------------------- start-up


def test_boots_with_the_clocks_baud_and_i2c_speed_it_states(booted):
    soc = booted.soc
    assert soc.problems == []
    rcc = soc.rcc
    assert (rcc.sysclk_hz, rcc.hclk_hz, rcc.pclk1_hz, rcc.pclk2_hz) == (168e6, 168e6, 42e6, 84e6)
    assert soc.flash_interface.latency() == 5  # RM0090 table 10: 150-168 MHz
    assert abs(booted.usart1.baud() - 921_600) / 921_600 < 0.01  # 84 MHz / 91 = 923 077 baud
    assert booted.i2c1.scl_hz() == pytest.approx(400_000)  # CCR 35 at 42 MHz, fast mode DUTY 0
    assert booted.timers[5].psc == 83 and booted.timers[2].arr == 840_000 - 1  # 1 us; 100 Hz at 84 MHz
    hello = booted.start_up[0]
    assert hello.name == "HELLO" and hello.fields["board"] == "stm32f407-gy86"
    assert logs(booted.start_up) == ["GY-86: MPU6050 + HMC5883L ready, +-2000 deg/s, +-8 g, 1090 LSB/gauss; "
                                     "MS5611 ready"]  # no WARNING: the crystal started, the PLL locked


def test_the_chips_are_configured_as_their_data_sheets_require(booted):
    mpu, hmc, baro = booted.mpu, booted.hmc, booted.baro
    assert mpu.peek("PWR_MGMT_1") & 0x47 == 0x01  # awake, the X gyro's PLL as its clock (PS-MPU-6000A 4.28)
    assert mpu.peek("GYRO_CONFIG") == 3 << 3 and mpu.peek("ACCEL_CONFIG") == 2 << 3  # +-2000 dps, +-8 g
    assert mpu.peek("CONFIG") & 7 == 3 and mpu.peek("SMPLRT_DIV") == 9  # DLPF 44 Hz, 1 kHz / 10 = 100 Hz
    assert mpu.bypass_enabled  # the HMC5883L behind the MPU6050's auxiliary bus
    assert hmc.output_rate_hz == 75.0 and hmc.lsb_per_gauss == 1090 and hmc.mode == 0  # continuous
    assert set(baro.conversions) == {0x48, 0x58}  # D1 and D2 at OSR 4096
    assert booted.lines.routed(4)  # PB8/PB9 AF4 open drain


def test_streams_at_the_rate_it_is_set_to(booted):
    samples = [m.fields for m in booted.streamed if m.name == "SAMPLE"]
    estimates = [m for m in booted.streamed if m.name == "ESTIMATE"]
    assert len(samples) == len(estimates) >= 199
    stamps = np.array([s["timestamp_us"] for s in samples], float)
    period = np.diff(stamps)
    assert abs(period.mean() - 10_000.0) < 100.0  # within 1 % of 100 Hz, by the board's own clock
    # every sample on its tick but one: when the receiver's CFG-PRT switches USART2 to 115 200 baud,
    # uart_set_baud waits for the last bytes at 9 600 baud (2.9 ms) inside the sample loop
    assert np.count_nonzero(period != 10_000.0) <= 2 and period.min() > 5_000.0
    assert [s["index"] for s in samples] == list(range(len(samples)))
    baro = [m for m in booted.streamed if m.name == "BARO"]
    assert len(baro) >= 50  # a D1 + D2 cycle every 18 ms
    assert booted.soc.problems == []


def test_the_host_link_transmits_by_dma(booted):
    """USART1's transmitter on DMA2 stream 7 (channel 4): an interrupt per stretch of the ring,
    not per byte; USART1's own interrupt only for received bytes."""
    assert booted.usart1.cr3 & (1 << 7)  # DMAT
    taken = booted.soc.core.taken
    usart1, stream7 = 16 + 37, 16 + 70
    sent = booted.usart1.sent
    assert sent > 30_000
    assert taken.get(usart1, 0) <= booted.usart1.received  # one per byte of the host's command
    assert 200 <= taken[stream7] < sent // 20


def test_the_same_scripted_run_gives_the_same_bytes(image):
    def run() -> bytes:
        board = start(image)
        board.run_for(0.3)
        board.put(protocol.encode_command(0, "START_STREAM", 1))
        board.run_for(0.5)
        board.put(protocol.encode_command(1, "GET_STATUS", 2))
        board.run_for(0.1)
        return board.take()

    first = run()
    assert len(first) > 8_000 and run() == first  # HELLO, LOG, 50 SAMPLE + ESTIMATE, STATUS


# --------------------------------------------------------------------------- over the link


@pytest.mark.parametrize("filter_name", [f for f in core.BOARD_FILTERS if f != "nav"])
def test_record_and_compare_over_the_link_is_bit_exact(image, filter_name, tmp_path):
    with EmulatedBoard("stm32f407", front="tcp", scenario="random", duration_s=60.0, seed=2,
                       filter_name=filter_name, realtime=True) as board:  # real time: leaves the other tests a core
        path = tmp_path / "live.imulog"
        result = hil.record(board.address, path, duration_s=3.0)
        recording = load_recording(path)
        positions = board.positions(recording.samples.gyr, recording.samples.acc, recording.samples.mag)
        assert board.error is None
    comparison = hil.compare(recording)
    assert result.filter_name == filter_name and recording.hello["board"] == "stm32f407-gy86"
    assert recording.counters["lost_frames"] == 0 and recording.counters["crc_errors"] == 0
    assert comparison.verified_count == len(recording.estimates) > 100  # 3 s of wall time (see docs/performance.md)
    assert comparison.bit_exact, str(comparison.first_difference)
    # the simulated samples in order; the MPU6050 samples on its own clock, so where its updates
    # fall at the board's reads one may be read twice or skipped, as on the real board
    assert (positions >= 0).all() and set(np.diff(positions)) <= {0, 1, 2}
    assert np.count_nonzero(np.diff(positions) != 1) <= len(positions) // 20


def test_the_nav_filter_with_receiver_and_barometer_is_bit_exact(image, tmp_path):
    with EmulatedBoard("stm32f407", front="tcp", scenario="car", duration_s=60.0, seed=1,
                       filter_name="nav", realtime=True) as board:
        path = tmp_path / "nav.imulog"
        hil.record(board.address, path, duration_s=9.0)
        recording = load_recording(path)
    comparison = hil.compare(recording)
    assert len(recording.gnss) >= 10 and len(recording.baro) >= 100  # NAV-PVT at 10 Hz once configured
    assert len(recording.nav_states) == len(recording.estimates) > 250
    assert comparison.verified_count == len(recording.estimates)
    assert comparison.bit_exact, str(comparison.first_difference)


# --------------------------------------------------------------------------- faults


@pytest.mark.parametrize("fault, expected", [
    ("mpu6050:identity", "GY-86 not ready: MPU6050: wrong identity"),
    ("mpu6050:nack", "GY-86 not ready: MPU6050: address not acknowledged"),
    ("hmc5883l:nack", "GY-86 not ready: HMC5883L: address not acknowledged"),
    ("ms5611:nack", "; no MS5611: "),
    ("sda-low", "I2C1: SDA held low, not freed by 9 SCL pulses"),
])
def test_a_faulty_chip_is_reported_and_the_board_answers(image, fault, expected):
    faults = stm32f407.ChipFaults()
    faults.add(fault)
    board = start(image, faults=faults)
    board.run_for(0.6)
    found = messages(board)
    assert found[0].name == "HELLO"
    assert any(expected in text for text in logs(found)), logs(found)
    status = [m for m in command(board, "GET_STATUS") if m.name == "STATUS"]
    assert status and status[0].fields["streaming"] == 0  # it answers: no hang
    assert not [p for p in board.soc.problems if "hang" in p]


def test_a_chip_that_answers_again_is_set_up_again_and_the_stream_resumes(image):
    board = start(image, faults=stm32f407.ChipFaults(nack={"mpu6050"}))
    board.run_for(0.5)
    board.put(protocol.encode_command(0, "START_STREAM", 1))
    board.run_for(1.5)
    before = messages(board)
    assert not [m for m in before if m.name == "SAMPLE"]
    board.faults.nack.clear()  # the MPU6050 answers again (a loose wire pressed back)
    board.run_for(2.5)
    after = messages(board)
    assert any(text.startswith("GY-86: MPU6050 + HMC5883L ready") for text in logs(after)), logs(after)
    assert len([m for m in after if m.name == "SAMPLE"]) >= 100
    assert board.soc.problems == []


def test_a_magnetometer_that_stops_answering_is_counted_and_the_stream_goes_on(image):
    faults = stm32f407.ChipFaults(silent_after={"hmc5883l": 40})
    board = start(image, faults=faults)
    board.run_for(0.5)
    messages(board)
    board.put(protocol.encode_command(0, "START_STREAM", 1))
    board.run_for(2.0)
    found = messages(board)
    status = [m for m in command(board, "GET_STATUS", 1) if m.name == "STATUS"][0].fields
    assert status["sensor_errors"] > 100 and status["streaming"] == 1
    assert any("HMC5883L" in text for text in logs(found)), logs(found)
    assert not [p for p in board.soc.problems if "hang" in p]


@pytest.mark.long  # 12 s of the board flat out each: after `make test`, not beside its real-time tests
@pytest.mark.parametrize("fault, news", [
    (None, ["GNSS: receiver found at 9600 baud",
            "GNSS: u-blox receiver configured: NAV-PVT every 100 ms at 115200 baud"]),
    ("gnss:absent", ["GNSS: no receiver answers on USART2 (every baud tried; still searching)"]),
    ("gnss:baud", ["GNSS: receiver found at 38400 baud",
                   "GNSS: u-blox receiver configured: NAV-PVT every 100 ms at 115200 baud"]),
    ("gnss:damaged", ["GNSS: receiver found at 9600 baud", "damaged frames from the receiver (checksum)"]),
])
def test_the_receiver_is_reported_and_its_faults_never_stop_the_board(image, fault, news):
    faults = stm32f407.ChipFaults()
    if fault:
        faults.add(fault)
    board = start(image, faults=faults)
    board.run_for(0.5)
    board.put(protocol.encode_command(0, "START_STREAM", 1))
    board.run_for(14.0 if fault == "gnss:absent" else 12.0)
    found = messages(board)
    samples = [m for m in found if m.name == "SAMPLE"]
    assert len(samples) >= 1190  # 12 s at 100 Hz: the receiver never holds the sample loop up
    lines = [text for text in logs(found) if text.startswith("GNSS")]
    for expected in news:
        assert any(expected in line for line in lines), lines
    fixes = [m for m in found if m.name == "GNSS"]
    assert (len(fixes) == 0) if fault == "gnss:absent" else len(fixes) > 50  # 10 Hz once configured
    assert board.soc.problems == []


def test_chip_fault_names_are_checked():
    with pytest.raises(ValueError, match="unknown chip fault"):
        stm32f407.ChipFaults().add("mpu6050:melted")


# --------------------------------------------------------------------------- the core


def _assemble(tmp_path: Path, source: str) -> tuple[bytes, bytes]:
    """The flash bytes and the ELF of a little Thumb program linked at the flash."""
    (tmp_path / "t.s").write_text(".syntax unified\n.thumb\n" + source)
    subprocess.run([ARM_GCC, "-mcpu=cortex-m4", "-mthumb", "-nostdlib", "-Wl,-Ttext=0x08000000",
                    "-Wl,--entry=0x08000000", "-o", str(tmp_path / "t.elf"), str(tmp_path / "t.s")], check=True)
    subprocess.run(["arm-none-eabi-objcopy", "-O", "binary", str(tmp_path / "t.elf"), str(tmp_path / "t.bin")],
                   check=True)
    return (tmp_path / "t.bin").read_bytes(), (tmp_path / "t.elf").read_bytes()


#: A vector table (SP, reset, and exception 16 + 0 = IRQ 0), then: enable IRQ 0, mask, pend it,
#: WFI, record that the handler has not run, then CPSIE i, then a marker.
CORE_TEST = """
.word 0x20001000
.word reset + 1
.fill 14, 4, 0
.word handler + 1
reset:
    ldr r0, =0xE000E100
    movs r1, #1
    str r1, [r0]          @ NVIC_ISER0: IRQ 0 enabled
    cpsid i
    ldr r0, =0xE000E200
    str r1, [r0]          @ NVIC_ISPR0: IRQ 0 pending
    wfi                   @ wakes: pending and enabled, though masked
    ldr r2, =0x20000000
    ldr r3, [r2]          @ the handler's count, still 0
    str r3, [r2, #4]
    cpsie i               @ taken right after this
    ldr r3, [r2]
    str r3, [r2, #8]      @ 1: the handler ran before this instruction
    movs r4, #0x5A
    str r4, [r2, #12]
    wfi                   @ nothing pending: sleeps until the run ends
spin:
    b spin
handler:
    ldr r0, =0x20000000
    ldr r1, [r0]
    adds r1, r1, #1
    str r1, [r0]
    bx lr
.ltorg
"""


def test_wfi_wakes_on_a_masked_interrupt_and_cpsie_takes_it_at_once(tmp_path):
    soc = Soc(_assemble(tmp_path, CORE_TEST)[0])
    core = soc.core
    soc.core.run(soc.scheduler.now + 10**9, sleep=lambda wake: False)
    memory = core.uc.mem_read(0x2000_0000, 16)
    count, before, after, done = np.frombuffer(bytes(memory), "<u4")
    assert (count, before, after, done) == (1, 0, 1, 0x5A)
    assert soc.problems == [] and core.active == []


def test_a_loop_without_progress_is_reported_with_its_function(tmp_path):
    source = (".word 0x20001000\n.word reset + 1\n.type reset, %function\nreset:\n    nop\n"
              ".type waits_for_ever, %function\nwaits_for_ever:\n    b waits_for_ever\n.size waits_for_ever, 2\n")
    flash, elf = _assemble(tmp_path, source)
    soc = Soc(flash, elf=elf)
    with pytest.raises(stm32f407.Fault, match="hangs in waits_for_ever"):
        soc.core.run(10**13, sleep=lambda wake: False)
    assert any("hang" in p and "waits_for_ever" in p for p in soc.problems)


# --------------------------------------------------------------------------- broken drivers


def _broken_image(tmp_path: Path, file: str, old: str, new: str) -> Path:
    """The reference image built from a copy of the firmware with one change in `file`."""
    copy = tmp_path / "firmware"
    shutil.copytree(FIRMWARE, copy, ignore=shutil.ignore_patterns("build"))
    source = copy / file
    text = source.read_text()
    assert old in text, f"{old!r} is not in {file}"
    source.write_text(text.replace(old, new, 1))
    proc = subprocess.run(["make", "-C", str(copy), "stm32f407"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return copy / "build" / "stm32f407" / ELF.name


BROKEN = {
    # the address byte written without waiting for SB (EV5: RM0090 27.3.3, figure 243)
    "i2c event order": ("boards/stm32f407/i2c_stm32f4.c", "s = wait_sr1(dev, I2C_SR1_SB, 0);",
                        "s = I2C_OK;", "I2C1: DR written"),
    "clock left off": ("boards/stm32f407/board_stm32f407.c",
                       "RCC->APB2ENR |= RCC_APB2ENR_USART1EN;", "",
                       "USART1: accessed with its clock off"),
    "wrong BRR": ("boards/stm32f4/uart.c", "return (pclk_hz + baud / 2u) / baud;",
                  "return (pclk_hz + baud / 2u) / baud + 4u;", None),
}


@pytest.mark.parametrize("name", list(BROKEN))
def test_a_broken_driver_is_caught(image, tmp_path, name):
    file, old, new, problem = BROKEN[name]
    broken = start(_broken_image(tmp_path, file, old, new))
    try:
        broken.run_for(0.6)
    except stm32f407.Fault:
        pass
    received = messages(broken)
    if problem is not None:  # the models report the breach
        assert any(problem in p for p in broken.soc.problems), broken.soc.problems
    else:  # 84 MHz / 95: 884 211 baud, 4 % off: the host receives garbage, never a HELLO
        assert not [m for m in received if m.name == "HELLO"]


# --------------------------------------------------------------------------- flashing


def test_flash_go_and_the_flashed_images_hello(image):
    servers = []

    def boot(address: int, flash_bytes: bytes):
        assert address == FLASH_BASE
        ours, theirs = socket.socketpair()
        board = stm32f407.ReferenceBoard(flash_bytes.rstrip(b"\xff"))
        servers.append(stm32f407.BoardServer(board, realtime=False, sock=ours).start())
        return theirs

    chip = Stm32Bootloader()
    firmware = load_image(image)
    try:
        with BootloaderPort(chip, on_go=boot) as port:
            result = flashing.flash_uart(firmware, port.address, log=lambda *_: None)
    finally:
        for server in servers:
            server.stop()
    assert result.verified and result.started
    assert result.hello["board"] == "stm32f407-gy86" and result.hello["schema_hash"] == protocol.SCHEMA_HASH
    assert [s.error for s in servers] == [None]


def test_enter_bootloader_then_flash_over_the_same_line(image):
    """ENTER_BOOTLOADER resets into the system memory; the bootloader model answers AN3155 on
    USART1's line, and its Go starts the flashed image from power-on."""
    board = start(image)
    board.run_for(0.4)
    messages(board)
    found = command(board, "ENTER_BOOTLOADER")
    assert [m.name for m in found][:1] == ["ACK"]
    board.run_for(0.1)
    assert board.bootloader is not None
    board.put(b"\x7f")
    assert board.take() == b"\x79"  # AN3155: ACK to the sync byte
    boots = board.boots
    board.put(b"\x21\xde")  # Go
    assert board.take() == b"\x79"
    board.put((FLASH_BASE).to_bytes(4, "big") + bytes([0x08 ^ 0x00 ^ 0x00 ^ 0x00]))
    assert board.take() == b"\x79" and board.boots == boots + 1
    board.run_for(0.4)
    found = messages(board)
    assert found and found[0].name == "HELLO" and found[0].seq == 0


def test_boot0_and_a_reset_start_the_bootloader_and_boot0_low_the_flash(image):
    """The BOOT0 pin read as NRST is released: high, the system memory's bootloader answers
    AN3155; low, the flash's image starts (its HELLO). Held in reset, the chip is silent and
    what the host sends is lost."""
    board = start(image)
    board.run_for(0.4)
    assert any(m.name == "HELLO" for m in messages(board))
    board.set_boot0(True)
    board.hold_reset(True)
    board.put(b"\x7f")
    board.run_for(0.1)
    assert board.take() == b"" and board.bootloader is None  # held in reset: nothing runs
    board.hold_reset(False)
    assert board.bootloader is not None and board.booted == ["flash", "system memory"]
    board.put(b"\x7f")
    assert board.take() == b"\x79"  # AN3155: ACK to the sync byte
    board.set_boot0(False)
    board.hold_reset(True)
    board.hold_reset(False)
    assert board.bootloader is None and board.booted == ["flash", "system memory", "flash"]
    board.run_for(0.4)
    found = messages(board)
    assert found and found[0].name == "HELLO" and found[0].seq == 0


def test_the_board_server_drives_the_pins_from_another_thread(image):
    """BoardServer.set_pins: BOOT0 and NRST driven from another thread (a lab's GPIO box), applied
    by the board's own thread in order before its next step, the host line (a socket) connected
    throughout: pins set before the board runs its first step start it in its bootloader."""
    ours, theirs = socket.socketpair()
    server = stm32f407.BoardServer(start(image), realtime=False, sock=ours)
    server.set_pins(boot0=True, reset=True)
    server.set_pins(reset=False)
    server.start()
    try:
        theirs.settimeout(10.0)
        theirs.sendall(b"\x7f")
        assert theirs.recv(16) == b"\x79"  # AN3155: the bootloader's ACK, and nothing the application sent
        assert server.board.booted == ["flash", "system memory"] and server.error is None
        server.set_pins(boot0=False, reset=True)
        server.set_pins(reset=False)
        decoder = protocol.FrameDecoder()
        found: list[protocol.Message] = []
        while not found:  # the flash's image starts: its HELLO
            found = [m for m in decoder.feed(theirs.recv(4096)) if isinstance(m, protocol.Message)]
        assert found[0].name == "HELLO" and server.board.booted[-1] == "flash"
    finally:
        server.stop()
        theirs.close()


def test_demo_on_the_virtual_board_is_bit_exact(image):
    """`imulink demo --target stm32f407`: in real time (as far as the machine keeps up), for the
    run's length; every estimate verified."""
    report = hil.demo(target="stm32f407", duration_s=5.0)
    assert report.comparison.bit_exact and report.comparison.verified_count == len(report.recording.estimates)
    assert len(report.recording.samples) >= 250


@pytest.mark.long  # 14 s of the board flat out
def test_the_board_estimates_the_simulated_attitude(image):
    """The chips measure the simulated run, so the board's ESKF is as accurate as the filter is
    (the native board's demo: about 2 deg): RMS after 10 s, samples found by their counts."""
    run = sim.make_scenario("rests", 16.0, 100.0, 0)
    board = start(image, feed=stm32f407.Feed(100.0, run.gyr_counts, run.acc_counts, run.mag_counts))
    board.run_for(0.3)
    board.put(protocol.encode_command(0, "START_STREAM", 1))
    board.run_for(14.0)
    found = messages(board)
    samples = [m.fields for m in found if m.name == "SAMPLE"]
    quat = np.array([m.fields["quat"] for m in found if m.name == "ESTIMATE"], float) / 2.0**30
    fed = np.concatenate([run.gyr_counts, run.acc_counts], axis=1)
    positions = np.array([np.flatnonzero((fed == np.r_[s["gyr"], s["acc"]]).all(axis=1))[0] for s in samples])
    assert (np.diff(positions) >= 0).all() and len(quat) == len(positions) >= 1390
    settled = np.arange(len(positions)) >= 1000
    accuracy = rmse(attitude_errors(quat[settled], run.quat_true[positions[settled]]))
    assert accuracy["total"] < 5.0, accuracy


def test_imulink_flash_enters_the_bootloader_of_the_emulated_board(image):
    """`imulink emulate --target stm32f407` on a pty carries raw bytes: `imulink flash --enter
    command` sends ENTER_BOOTLOADER, talks AN3155 to the system memory's bootloader, and its Go
    starts the flashed bytes."""
    with EmulatedBoard("stm32f407", duration_s=5.0) as board:
        result = flashing.flash_uart(load_image(image), board.address, enter="command", log=lambda *_: None)
        assert board.virtual is not None and board.virtual.board.boots == 2 and board.error is None
    assert result.verified and result.started and result.hello["board"] == "stm32f407-gy86"


class PinLines:
    """BOOT0 and reset lines wired to the emulated board's pins (what a lab's GPIO box does for a
    labgrid place: imulink.board.lab.PlaceLines), every step recorded; `wired=False`: lines that
    lead nowhere."""

    def __init__(self, board: EmulatedBoard, wired: bool = True):
        assert board.virtual is not None
        self.pins = board.virtual
        self.wired = wired
        self.steps: list[str] = []

    def describe(self) -> str:
        return "boot0, reset (test)"

    def set_boot0(self, high: bool) -> None:
        self.steps.append(f"boot0 {'high' if high else 'low'}")
        if self.wired:
            self.pins.set_pins(boot0=high)

    def _reset(self) -> None:
        self.steps.append("reset")
        if self.wired:
            self.pins.set_pins(reset=True)
            self.pins.set_pins(reset=False)

    def enter_bootloader(self) -> None:
        self.set_boot0(True)
        self._reset()

    def start_application(self) -> None:
        self.set_boot0(False)
        self._reset()


def test_flash_with_lines_boots_the_bootloader_then_the_image(image):
    """--enter lines: BOOT0 high and a reset into the bootloader, the flash, then BOOT0 low and a
    reset (no Go) start the image, whose HELLO is checked."""
    with EmulatedBoard("stm32f407", duration_s=5.0) as board:
        lines = PinLines(board)
        result = flashing.flash_uart(load_image(image), board.address, enter="lines", lines=lines, log=lambda *_: None)
        assert board.virtual is not None and board.error is None
        assert board.virtual.board.booted == ["flash", "system memory", "flash"]
        bootloader = board.virtual.board.last_bootloader
        assert bootloader is not None and bootloader.go_address is None  # started by the reset, not by Go
    assert lines.steps == ["boot0 high", "reset", "boot0 low", "reset"]
    assert result.verified and result.started and result.started_at == FLASH_BASE
    assert result.hello["board"] == "stm32f407-gy86"


def test_flash_with_lines_dry_run_and_no_start(image):
    """A dry run through the lines resets the board back into its firmware; --no-start leaves it in
    its bootloader with BOOT0 high, as asked."""
    with EmulatedBoard("stm32f407", duration_s=5.0) as board:
        lines = PinLines(board)
        dry = flashing.flash_uart(load_image(image), board.address, enter="lines", lines=lines, dry_run=True,
                                  log=lambda *_: None)
        assert dry.dry_run and lines.steps == ["boot0 high", "reset", "boot0 low", "reset"]
        with Link(board.address) as link:
            assert link.connect()["board"] == "stm32f407-gy86"  # its firmware again
        lines.steps.clear()
        kept = flashing.flash_uart(load_image(image), board.address, enter="lines", lines=lines, start=False,
                                   log=lambda *_: None)
        assert not kept.started and lines.steps == ["boot0 high", "reset"]
        assert board.virtual is not None and board.virtual.board.bootloader is not None


def test_flash_with_lines_that_do_not_reach_the_board(image):
    """Lines wired to nothing: no bootloader answers, one error, and BOOT0 is driven low again."""
    with EmulatedBoard("stm32f407", duration_s=5.0) as board:
        lines = PinLines(board, wired=False)
        with pytest.raises(flashing.FlashError, match="no STM32 bootloader answered"):
            flashing.flash_uart(load_image(image), board.address, enter="lines", lines=lines, log=lambda *_: None)
    assert lines.steps == ["boot0 high", "reset", "boot0 low"]


def test_emulate_refuses_what_the_reference_image_cannot_do(image):
    with pytest.raises(Exception, match="samples at 100 Hz"):
        EmulatedBoard("stm32f407", rate_hz=200.0)
    with pytest.raises(Exception, match="chip faults need the virtual reference board"):
        EmulatedBoard("native", chip_faults=stm32f407.ChipFaults(nack={"ms5611"}))
    with pytest.raises(Exception, match="not the stm32f407-gy86 board's firmware"):
        EmulatedBoard("stm32f407", image=FIRMWARE / "build" / "qemu" / "imulink-qemu-netduinoplus2.elf")


def test_the_link_answers_through_imulink_emulate(image):
    with EmulatedBoard("stm32f407", front="tcp", duration_s=5.0, realtime=True) as board, \
            Link(board.address) as link:
        hello = link.connect()
        status = link.command("GET_STATUS").data.fields
    assert hello["board"] == "stm32f407-gy86" and status["cycle_hz"] == 168_000_000
