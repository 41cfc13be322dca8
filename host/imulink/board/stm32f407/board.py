"""The reference board, virtual: the STM32F407 (imulink.board.stm32f407.soc and its peripheral
models) running the exact image that gets flashed, with the GY-86 chips on I2C1 (PB8/PB9),
a u-blox receiver on USART2 (PA2/PA3) and the host on USART1 (PA9/PA10), the chips fed
from a simulated run.

- The MPU6050's data registers take simulated sample k at t = (k + 1/2) / rate after power-on
  (the simulation runs at the board's sample rate; its own clock, not the board's: a sample may
  be read twice or skipped where the two meet), later while the bus is busy (the chip's user
  registers hold still during a burst read), the HMC5883L's field the same sample
  (it measures at its own rate), the MS5611's D1 and D2 those of the barometer model, the
  receiver's fix the latest simulated fix. The MPU6050's INT pin is not connected (as on the
  reference board: board_stm32f407.h).
- The host line runs at `line_baud` (921 600 by default): bytes the USART sends at a baud more
  than 3 % off arrive damaged, and so do bytes it receives.
- When the core reaches the system memory (ENTER_BOOTLOADER), the AN3155 bootloader model
  (imulink.board.chips.stm32_bootloader) answers on USART1's line; its Go starts the flashed
  bytes from power-on.
- The BOOT0 pin and NRST (:meth:`ReferenceBoard.set_boot0`, :meth:`ReferenceBoard.hold_reset`):
  held in reset the chip stops and its line is silent; released, it starts again and boots
  what BOOT0 selects then (RM0090 2.4: BOOT0 high, BOOT1 low: the system memory, i.e. the
  bootloader; low: the flash), as a lab's GPIO lines drive a real board's.
- Faults (:class:`ChipFaults`): a chip that NACKs, answers a wrong identity, stops answering
  after N transfers, SDA held low, a receiver that is absent, at another baud or sends damaged
  frames.

Time: :meth:`ReferenceBoard.run_for` runs in virtual time (deterministic: the same inputs at
the same virtual times give the same bytes); :class:`BoardServer` runs it behind a TCP socket,
in real time or as fast as it goes.
"""
from __future__ import annotations

import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from imulink.board.chips import HMC5883L, MPU6050, MS5611, I2CBus
from imulink.board.chips.stm32_bootloader import Stm32Bootloader
from imulink.board.chips.ublox import DEFAULT_BAUD as UBLOX_BAUD
from imulink.board.chips.ublox import UbloxReceiver
from imulink.board.stm32f407.clock import PS_PER_S, ps
from imulink.board.stm32f407.core import FLASH_BASE, FLASH_SIZE, SYSTEM_BASE, Fault
from imulink.board.stm32f407.dma import Dma
from imulink.board.stm32f407.gpio import GpioPort
from imulink.board.stm32f407.i2c import I2CLines, I2CPeripheral
from imulink.board.stm32f407.soc import Soc
from imulink.board.stm32f407.system import Exti, Syscfg
from imulink.board.stm32f407.timers import GeneralTimer
from imulink.board.stm32f407.usart import BAUD_TOLERANCE, Usart

MPU_ADDRESS, HMC_ADDRESS, BARO_ADDRESS = 0x68, 0x1E, 0x77
CHIPS = {"mpu6050": MPU_ADDRESS, "hmc5883l": HMC_ADDRESS, "ms5611": BARO_ADDRESS}
LINE_BAUD = 921_600
BOOTLOADER_PARK = SYSTEM_BASE + 0x200
#: MPU6050 temperature register at 25 degC ((25 - 36.53) * 340).
TEMPERATURE_25C = -3920


@dataclass
class ChipFaults:
    """What is wrong with the board's chips and receiver (all optional)."""

    nack: set[str] = field(default_factory=set)           # chips that never acknowledge
    identity: set[str] = field(default_factory=set)       # chips that answer a wrong identity
    silent_after: dict[str, int] = field(default_factory=dict)  # chip -> address phases before it stops
    sda_low: bool = False                                 # a chip holds SDA low at power-on, for ever
    receiver: str | None = None                           # "absent", "baud" (38400) or "damaged"

    SPECS = ("CHIP:nack", "CHIP:identity", "CHIP:silent:N", "sda-low",
             "gnss:absent", "gnss:baud", "gnss:damaged")

    def add(self, spec: str) -> None:
        """One fault as the command line names it (SPECS; CHIP: mpu6050, hmc5883l, ms5611)."""
        parts = spec.lower().split(":")
        if parts == ["sda-low"]:
            self.sda_low = True
        elif parts[0] == "gnss" and len(parts) == 2 and parts[1] in ("absent", "baud", "damaged"):
            self.receiver = parts[1]
        elif parts[0] in CHIPS and parts[1:] in (["nack"], ["identity"]):
            (self.nack if parts[1] == "nack" else self.identity).add(parts[0])
        elif parts[0] in CHIPS and len(parts) == 3 and parts[1] == "silent" and parts[2].isdigit():
            self.silent_after[parts[0]] = int(parts[2])
        else:
            raise ValueError(f"unknown chip fault {spec!r}; one of {', '.join(self.SPECS)} "
                             f"(CHIP: {', '.join(CHIPS)})")

    @property
    def active(self) -> bool:
        return bool(self.nack or self.identity or self.silent_after or self.sda_low or self.receiver)

    def describe(self) -> str:
        parts = [f"{c}:nack" for c in sorted(self.nack)] + [f"{c}:identity" for c in sorted(self.identity)]
        parts += [f"{c}:silent:{n}" for c, n in sorted(self.silent_after.items())]
        parts += ["sda-low"] * self.sda_low + ([f"gnss:{self.receiver}"] if self.receiver else [])
        return ", ".join(parts)


class FaultyBus(I2CBus):
    """The GY-86's bus, where chips can stop acknowledging (ChipFaults)."""

    def __init__(self, faults: ChipFaults):
        super().__init__()
        self.faults = faults
        self.phases: dict[int, int] = {}

    def find(self, address: int):
        name = next((n for n, a in CHIPS.items() if a == address), None)
        if name is not None:
            self.phases[address] = self.phases.get(address, 0) + 1
            if name in self.faults.nack:
                return None
            limit = self.faults.silent_after.get(name)
            if limit is not None and self.phases[address] > limit:
                return None
        return super().find(address)


@dataclass
class Feed:
    """What the chips measure: counts per sample (N,3 each) at `rate_hz`, the barometer's
    (D1, D2) by sample, the receiver's fixes (field dicts of imulink.board.emulator.gnss_messages
    with their arrival sample)."""

    rate_hz: float
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    baro: dict[int, tuple[int, int]] = field(default_factory=dict)
    gnss: dict[int, dict] = field(default_factory=dict)


class HostLine:
    """USART1's other end: what the board sends (``take``) and what the host sends (``put``)."""

    def __init__(self, baud: float):
        self.baud = baud
        self.out = bytearray()
        self.lock = threading.Lock()

    def receive(self, byte: int, baud: float) -> None:
        if abs(baud - self.baud) > BAUD_TOLERANCE * self.baud:
            byte = (byte * 0x9D + 0x35) & 0xFF
        with self.lock:
            self.out.append(byte)

    def take(self) -> bytes:
        with self.lock:
            data = bytes(self.out)
            self.out.clear()
        return data


class ReceiverLine:
    """USART2's other end: the u-blox receiver model, its time kept with the board's."""

    def __init__(self, receiver: UbloxReceiver, usart: Usart):
        self.receiver, self.usart = receiver, usart

    def receive(self, byte: int, baud: float) -> None:
        own = self.receiver.baud
        self.receiver.receive(bytes([byte]), own if abs(baud - own) <= BAUD_TOLERANCE * own else int(baud))

    def tick(self, ms: int) -> None:
        baud = self.usart.baud()
        own = self.receiver.baud
        data = self.receiver.advance(ms, own if abs(baud - own) <= BAUD_TOLERANCE * own else int(baud))
        if data:
            self.usart.send(data, own)


class ReferenceBoard:
    """The virtual board (see the module docstring).

    Args:
        flash: the bytes of flash from 0x08000000 (an image's, e.g. FirmwareImage.bytes_at).
        elf: the ELF, for function names in hang reports (optional).
        feed: what the chips measure (None: a board at rest, level, 25 degC).
        faults: chip and receiver faults.
        line_baud: the host line's rate.
        receiver: a u-blox receiver on USART2 (otherwise nothing is connected there).
    """

    def __init__(self, flash: bytes, *, elf: bytes | None = None, feed: Feed | None = None,
                 faults: ChipFaults | None = None, line_baud: float = LINE_BAUD, receiver: bool = True,
                 seed: int = 0):
        self.flash = bytes(flash)
        self.elf = elf
        self.feed = feed
        self.faults = faults or ChipFaults()
        self.line = HostLine(line_baud)
        self.with_receiver = receiver
        self.seed = seed
        self.bootloader: Stm32Bootloader | None = None
        self.boots = 0
        #: what each start booted, in order: "flash" or "system memory" (the bootloader)
        self.booted: list[str] = []
        #: the BOOT0 pin's level (BOOT1, PB2, is low on the reference board)
        self.boot0 = False
        #: NRST held low: nothing runs
        self.in_reset = False
        #: the bootloader model of the last session in system memory (its erase counts, its log)
        self.last_bootloader: Stm32Bootloader | None = None
        #: told every problem the models report, as a line (the chip's, also after a Go rebuilt it)
        self.on_problem: Callable[[str], None] | None = None
        self._build()

    # ------------------------------------------------------------------ assembly

    def _build(self) -> None:
        soc = self.soc = Soc(self.flash, elf=self.elf)
        soc.on_problem = lambda line: self.on_problem(line) if self.on_problem is not None else None
        self.boots += 1
        self.gpio = {letter: soc.add(GpioPort(soc, letter)) for letter in "ABCDEFGHI"}
        a, b = self.gpio["A"], self.gpio["B"]
        self.usart1 = soc.add(Usart(soc, "USART1", 0x4001_1000, 2, 4, 37, (a, 9, 10, 7)))
        self.usart2 = soc.add(Usart(soc, "USART2", 0x4000_4400, 1, 17, 38, (a, 2, 3, 7)))
        soc.add(Usart(soc, "USART3", 0x4000_4800, 1, 18, 39, (b, 10, 11, 7)))
        soc.add(Usart(soc, "USART6", 0x4001_1400, 2, 5, 71, (self.gpio["C"], 6, 7, 8)))
        self.timers = {n: soc.add(GeneralTimer(soc, n, base, irq)) for n, base, irq in
                       ((2, 0x4000_0000, 28), (3, 0x4000_0400, 29), (4, 0x4000_0800, 30), (5, 0x4000_0C00, 50))}
        self.bus = FaultyBus(self.faults)
        self.lines = I2CLines(b, 8, 9)
        self.i2c1 = soc.add(I2CPeripheral(soc, 1, 0x4000_5400, self.bus, self.lines, (31, 32)))
        soc.syscfg = soc.add(Syscfg(soc, 0x4001_3800, {0: self.flash.ljust(FLASH_SIZE, b"\xff"),  # type: ignore[attr-defined]
                                                          1: soc.system_memory()}))
        soc.add(Exti(soc, 0x4001_3C00))
        soc.add(Dma(soc, 1, 0x4002_6000))
        dma2 = soc.add(Dma(soc, 2, 0x4002_6400))
        dma2.requests[(7, 4)] = self.usart1.tx_requesting  # USART1_TX: DMA2 stream 7, channel 4 (table 43)
        self.usart1.tx_dma = lambda: dma2.request(7, 4)
        self.mpu = MPU6050(who_am_i=0x70 if "mpu6050" in self.faults.identity else 0x68)
        self.hmc = HMC5883L(identity=b"H44" if "hmc5883l" in self.faults.identity else b"H43")
        self.baro = MS5611(prom=[0] * 8 if "ms5611" in self.faults.identity else None)
        self.bus.attach(MPU_ADDRESS, self.mpu)
        self.mpu.aux_bus.attach(HMC_ADDRESS, self.hmc)
        self.bus.attach(BARO_ADDRESS, self.baro)
        if self.faults.sda_low:
            self.lines.hold_sda(None)
        self.usart1.peer = self.line
        self.receiver: UbloxReceiver | None = None
        if self.with_receiver:
            fault = self.faults.receiver
            self.receiver = UbloxReceiver(present=fault != "absent", baud=38400 if fault == "baud" else UBLOX_BAUD,
                                          damage=0.3 if fault == "damaged" else 0.0, seed=self.seed)
            self.usart2.peer = self.receiver_line = ReceiverLine(self.receiver, self.usart2)
        soc.core.system_hooks.append(self._watch_pc)
        self._start_feeds()
        self.booted.append("flash")

    def _start_feeds(self) -> None:
        """The chips' own timelines (they run from power-on, whatever the core does)."""
        sched = self.soc.scheduler
        feed = self.feed
        self._sample = -1
        if feed is None:
            self.mpu.set_sample(acc=(0, 0, 4096), gyro=(0, 0, 0), temperature=TEMPERATURE_25C)
            self.hmc.set_field(200, 0, -400)
        else:
            sched.at(ps(0.5 / feed.rate_hz), self._next_sample)
        if self.receiver is not None:
            sched.at(sched.now + ps(0.001), self._receiver_tick)

    def _next_sample(self) -> None:
        feed = self.feed
        assert feed is not None
        if self.i2c1.busy:  # the MPU6050's user registers hold still while its serial interface is
            self.soc.scheduler.after(ps(20e-6), self._next_sample)  # active (register map 4.17)
            return
        k = self._sample = self._sample + 1
        if k >= len(feed.gyr):
            return  # the run is over: the chips keep their last sample
        self.mpu.set_sample(acc=tuple(feed.acc[k]), gyro=tuple(feed.gyr[k]), temperature=TEMPERATURE_25C)
        self.hmc.set_field(*feed.mag[k])
        if k in feed.baro:
            self.baro.d1, self.baro.d2 = feed.baro[k]
        if k in feed.gnss and self.receiver is not None:
            f = feed.gnss[k]
            self.receiver.set_fix(lat_deg=f["lat_1e7deg"] / 1e7, lon_deg=f["lon_1e7deg"] / 1e7,
                                  height_m=f["height_mm"] / 1e3, h_acc_m=f["h_acc_mm"] / 1e3,
                                  v_acc_m=f["v_acc_mm"] / 1e3, s_acc_m_s=f["s_acc_mm_s"] / 1e3,
                                  vel_ned_m_s=tuple(v / 1e3 for v in f["vel_ned_mm_s"]), fix_type=f["fix_type"],
                                  num_sv=f["num_sv"])
        self.soc.scheduler.at(max(ps((k + 1.5) / feed.rate_hz), self.soc.scheduler.now + 1), self._next_sample)

    def _receiver_tick(self) -> None:
        self.receiver_line.tick(1)
        self.soc.scheduler.after(ps(0.001), self._receiver_tick)

    # ------------------------------------------------------------------ the bootloader

    def _watch_pc(self, pc: int) -> None:
        if pc == BOOTLOADER_PARK and self.bootloader is None:
            self._enter_bootloader()

    def _enter_bootloader(self) -> None:
        self.bootloader = self.last_bootloader = Stm32Bootloader(flash=self.flash.ljust(FLASH_SIZE, b"\xff"))

    # ------------------------------------------------------------------ BOOT0 and NRST

    def set_boot0(self, high: bool) -> None:
        """The BOOT0 pin: read when the chip leaves reset."""
        self.boot0 = bool(high)

    def hold_reset(self, held: bool) -> None:
        """NRST: held low, the chip stops (nothing runs, nothing is sent, bytes from the host are
        lost); released, it starts from reset: the system memory's bootloader with BOOT0 high,
        else the flash (what the bootloader wrote included)."""
        if held:
            self.in_reset = True
            return
        if not self.in_reset:
            return
        self.in_reset = False
        if self.bootloader is not None:
            self.flash = bytes(self.bootloader.flash)
            self.bootloader = None
        self._build()
        if self.boot0:
            self.booted[-1] = "system memory"
            self._enter_bootloader()

    def _bootloader_input(self, data: bytes) -> None:
        assert self.bootloader is not None
        answer = self.bootloader.receive(data)
        with self.line.lock:
            self.line.out += answer
        if self.bootloader.running:
            go = self.bootloader.go_address
            self.flash = bytes(self.bootloader.flash)
            self.bootloader = None
            self._build()  # the flashed bytes from power-on (the Go address is the flash start)
            if go != FLASH_BASE:
                self.soc.report("bootloader", f"Go to 0x{go:08X}: started from the flash's vector table instead")

    # ------------------------------------------------------------------ running

    @property
    def now_s(self) -> float:
        return self.soc.scheduler.now / PS_PER_S

    def put(self, data: bytes) -> None:
        """Bytes from the host, arriving on the line from now on."""
        if self.in_reset:
            return
        if self.bootloader is not None:
            self._bootloader_input(data)
        else:
            self.usart1.send(data, self.line.baud)

    def take(self) -> bytes:
        """Bytes the board has sent since the last call."""
        return self.line.take()

    def run_until(self, t_s: float) -> None:
        """Run the board to virtual time `t_s` (s since power-on)."""
        until = ps(t_s)
        sched = self.soc.scheduler

        def sleep(wake: int | None) -> bool:
            target = until if wake is None or wake > until else wake
            sched.advance(target)
            return target < until

        while sched.now < until:
            if self.bootloader is not None or self.in_reset:
                sched.advance(until)
                break
            self.soc.core.run(until, sleep=sleep)

    def run_for(self, seconds: float) -> None:
        self.run_until(self.now_s + seconds)


class BoardServer:
    """A ReferenceBoard run by a thread in real time (virtual time follows the wall clock) or as
    fast as it goes, its host line served on a TCP socket on 127.0.0.1 (``port``; the first
    client), on a given connected socket (`sock`), or on a pseudo-terminal (`pty`: an
    imulink.board.proxy.PtyFront; raw bytes both ways, so the AN3155 bootloader answers too).
    ``error``: why it stopped (a hang, a fault), or None."""

    CHUNK_S = 0.002

    def __init__(self, board: ReferenceBoard, *, realtime: bool = True, sock: socket.socket | None = None,
                 pty=None):
        self.board = board
        self.realtime = realtime
        self.error: str | None = None
        self._stop = threading.Event()
        self._client: socket.socket | None = sock
        self._pty = pty
        self._server: socket.socket | None = None
        if sock is None and pty is None:
            self._server = socket.create_server(("127.0.0.1", 0))
            self.port = self._server.getsockname()[1]
        self._pins: deque[tuple[bool | None, bool | None]] = deque()
        self._thread = threading.Thread(target=self._run, name="imulink-stm32f407", daemon=True)

    def set_pins(self, *, boot0: bool | None = None, reset: bool | None = None) -> None:
        """Drive the board's BOOT0 pin and NRST (`reset`: held or released) from any thread: the
        board's own thread applies them, in order, before its next step (None: unchanged)."""
        self._pins.append((boot0, reset))

    def start(self) -> "BoardServer":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._server is not None:
            self._server.close()
        self._thread.join(timeout=5)
        if self._client is not None:
            self._client.close()
        if self._pty is not None:
            self._pty.close()

    def _run(self) -> None:
        try:
            if self._pty is not None:
                self._serve(self._pty.read, self._pty.write)
                return
            client = self._client if self._client is not None else self._accept()
            if client is None:
                return
            self._client = client
            if client.family != socket.AF_UNIX:
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client.setblocking(False)
            self._serve(lambda: _receive(client), lambda data: _send(client, data))
        except Fault as exc:
            self.error = str(exc)
        except Exception as exc:  # surfaced through .error
            self.error = f"the virtual board stopped: {exc!r}"

    def _accept(self) -> socket.socket | None:
        assert self._server is not None
        self._server.settimeout(0.2)
        while not self._stop.is_set():
            try:
                return self._server.accept()[0]
            except TimeoutError:
                continue
            except OSError:
                return None
        return None

    def _serve(self, receive: Callable[[], bytes | None], send: Callable[[bytes], int]) -> None:
        """Run the board in chunks of CHUNK_S, passing the line's bytes (`receive` gives b"" when
        nothing came, None when the host has gone; `send` says how many bytes it took)."""
        board = self.board
        start_wall = time.monotonic()
        elapsed = 0.0  # virtual seconds run (the board's own clock starts again at each reset and Go)
        pending: deque[bytes] = deque()
        while not self._stop.is_set():
            while self._pins:
                boot0, reset = self._pins.popleft()
                if boot0 is not None:
                    board.set_boot0(boot0)
                if reset is not None:
                    board.hold_reset(reset)
            data = receive()
            if data is None:
                return  # the host closed the line
            if data:
                board.put(data)
            before = board.now_s
            board.run_for(self.CHUNK_S)
            elapsed += board.now_s - before
            out = board.take()
            if out:
                pending.append(out)
            while pending:
                sent = send(pending[0])
                if sent < len(pending[0]):
                    pending[0] = pending[0][sent:]
                    break
                pending.popleft()
            if self.realtime:
                ahead = elapsed - (time.monotonic() - start_wall)
                if ahead > 0:
                    time.sleep(ahead)


def _receive(client: socket.socket) -> bytes | None:
    try:
        data = client.recv(65536)
    except BlockingIOError:
        return b""
    return data or None


def _send(client: socket.socket, data: bytes) -> int:
    try:
        return client.send(data)
    except BlockingIOError:
        return 0
