"""Emulated boards: the firmware application itself, as a native process or as the ARM
image in QEMU, with the sensor simulator as its sensors.

The board's protocol behaviour has one implementation, in C (firmware/app); this
module only starts it and feeds it:

- ``target="native"``: firmware/boards/native, a host process serving a pty or a TCP
  port; it reads its sensor samples from a feed file written here.
- ``target="qemu"``: the netduinoplus2 image in ``qemu-system-arm``. Its USART1 (the
  link) is a TCP socket that a :class:`imulink.board.proxy.Proxy` connects to at once (QEMU
  starts the firmware only then, so its start-up HELLO and LOG are not lost) and serves
  to the host as a pty, a TCP port or a serial port, like the native board's; its
  USART2 (the sensors) is a TCP connection to a :class:`FeedServer` here, which
  answers every byte the board sends with the next sample frame.

The feed (docs/firmware.md) is one SAMPLE frame per simulated sample and a LOG frame
at the end. ``realtime=False`` (the default) lets the board take a sample whenever the
feed has one and the host has read the last ones, so a run goes as fast as the link;
``realtime=True`` paces samples by the board's own clock. Faults and another schema
hash are a :class:`~imulink.board.proxy.Proxy` in front of either target, and so is every TCP
front: it takes several clients, one of which commands while the others listen.
"""
from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import IO

import numpy as np

from imulink import core, protocol, sim
from imulink.board import stm32f407
from imulink.board.chips import ms5611
from imulink.board.proxy import FaultConfig, Proxy, PtyFront, make_front
from imulink.board.stm32f407.core import FLASH_BASE
from imulink.core.counts import DEFAULT_PROFILE, PROFILES, SensorProfile, si_to_counts
from imulink.errors import ImulinkError
from imulink.io.files import FileError, read_regular_file
from imulink.io.firmware_image import MAX_IMAGE_BYTES, ImageError, load_image
from imulink.sim import navigation

TARGETS = ("native", "qemu", "stm32f407")
#: The navigation scenario: a car drive (imulink.sim.navigation.car_drive) with the MPU6050's
#: data-sheet noise and turn-on biases, a GNSS receiver at 1 Hz (GnssModel's defaults) and
#: the barometer along it. SCENARIOS: the attitude scenarios (imulink.sim) and it.
NAV_SCENARIO = "car"
SCENARIOS = sim.SCENARIOS + (NAV_SCENARIO,)
#: MPU6050 temperature register at 25 degC ((25 - 36.53) * 340).
TEMPERATURE_25C = -3920

#: The emulated GY-86's barometer: an MS5611 with the data sheet's typical PROM (the board's
#: feed_baro_prom) measuring D1 and D2 at OSR 4096 (18 ms for both), read with the first
#: sample after each BARO_PERIOD_S; the air at BARO_HEIGHT_M (ISA) and 25 degC.
BARO_PERIOD_S = 0.02
BARO_HEIGHT_M = 450.0
BARO_TEMPERATURE_CDEG = 2500
#: QEMU machine of the qemu target and the ELF the firmware build names for it.
QEMU_MACHINE = "netduinoplus2"
_IMAGES = {"native": ("native", "imulink-native"), "qemu": ("qemu", "imulink-qemu-netduinoplus2.elf"),
           "stm32f407": ("stm32f407", "imulink-stm32f407-gy86.elf")}
#: The reference image's board name (its identification block and HELLO).
REFERENCE_BOARD = "stm32f407-gy86"
#: The reference image's sample rate after start-up (board_stm32f407.c): the virtual GY-86 is fed at it.
REFERENCE_RATE_HZ = 100.0
_START_TIMEOUT_S = 10.0


class EmulatorError(ImulinkError):
    """An emulated board that cannot be started (no image, no QEMU, a bad option)."""


# ---------------------------------------------------------------------------- firmware images


def firmware_build_dirs() -> list[Path]:
    """Where built firmware is looked for, in this order: $IMULINK_FIRMWARE_BUILD, the
    checkout's firmware/build (`make -C firmware` keeps it current), and the package's own
    copy of the native board (built when the package was installed)."""
    dirs = []
    if os.environ.get("IMULINK_FIRMWARE_BUILD"):
        dirs.append(Path(os.environ["IMULINK_FIRMWARE_BUILD"]))
    dirs.append(Path(__file__).resolve().parents[3] / "firmware" / "build")
    dirs.append(Path(__file__).resolve().parents[1] / "firmware")
    return dirs


def find_image(target: str, image: str | os.PathLike | None = None) -> Path:
    """The executable (native) or ELF (qemu) of a target; EmulatorError saying how to build it."""
    if target not in TARGETS:
        raise EmulatorError(f"unknown target {target!r}; choose one of {', '.join(TARGETS)}")
    if image is not None:
        path = Path(image)
        _check_image(target, path)
        return path
    subdir, name = _IMAGES[target]
    for base in firmware_build_dirs():
        for candidate in (base / subdir / name, base / name):
            if candidate.is_file():
                return candidate
    how = ("`make -C firmware native` (or reinstall the package)" if target == "native" else
           f"`make -C firmware {target}` (it needs arm-none-eabi-gcc: `make setup` installs it)")
    raise EmulatorError(f"the {target} board's firmware ({name}) is not built: run {how}")


#: ELF e_machine values (the ELF specification): what each target's image is built for.
_ELF_ARM = 40
#: A string each target's image holds: the QEMU board's HELLO name, the native board's usage line.
_IMAGE_MARKS = {"native": b"usage: imulink-native", "qemu": b"qemu-stm32f405"}


def _check_image(target: str, path: Path) -> None:
    """EmulatorError unless `path` is an image of `target`'s board (the reference board: an ELF,
    Intel HEX or raw .bin image whose identification block names it)."""
    if target == "stm32f407":
        reference_flash(path)
        return
    try:
        data = read_regular_file(path, MAX_IMAGE_BYTES)
    except FileError as exc:
        raise EmulatorError(str(exc)) from None
    if data[:4] != b"\x7fELF":
        raise EmulatorError(f"{path} is not a firmware image (not an ELF file)")
    arm = int.from_bytes(data[18:20], "little") == _ELF_ARM
    if arm != (target == "qemu") or _IMAGE_MARKS[target] not in data:
        raise EmulatorError(f"{path} is not the {target} board's firmware (an image for another board)")


def reference_flash(path: Path) -> tuple[bytes, bytes | None]:
    """The flash bytes from 0x08000000 of a reference-board image (ELF, HEX, or .bin placed
    there) and the ELF itself when it is one (for function names); EmulatorError otherwise."""
    try:
        image = load_image(path, FLASH_BASE if Path(path).suffix.lower() == ".bin" else None)
    except ImageError as exc:
        raise EmulatorError(str(exc)) from None
    ident = image.identification
    if ident is None or ident.board != REFERENCE_BOARD:
        raise EmulatorError(f"{path} is not the {REFERENCE_BOARD} board's firmware "
                            f"({'an image for ' + ident.board if ident else 'no imulink identification block'})")
    if image.start != FLASH_BASE:
        raise EmulatorError(f"{path} does not start at the flash (0x{FLASH_BASE:08X}) but at 0x{image.start:08X}")
    elf = Path(path).read_bytes() if image.format == "elf" else None
    return image.bytes_at(FLASH_BASE, image.end - FLASH_BASE), elf


def find_qemu() -> str:
    path = shutil.which("qemu-system-arm")
    if path is None:
        raise EmulatorError("qemu-system-arm not found: install it (Debian: apt-get install qemu-system-arm; "
                            "`make setup` does)")
    return path


# ---------------------------------------------------------------------------- the sensor feed


def baro_due(n: int, rate_hz: float) -> np.ndarray:
    """The samples the emulated barometer's measurements come with: the first of each
    BARO_PERIOD_S (every sample below 50 Hz)."""
    slot = np.floor(np.arange(n) / rate_hz / BARO_PERIOD_S + 1e-9)
    return np.r_[True, slot[1:] != slot[:-1]][:n] if n else np.zeros(0, bool)


def gnss_messages(fixes: navigation.GnssFixes, rate_hz: float, n: int) -> dict[int, dict]:
    """GNSS frames' fields by the sample each fix arrives with (the first at or after its
    arrival; fixes that arrive after the last sample are left out): the receiver's units,
    a 3-D fix with velocity, time_ms the time it is valid for."""
    out = {}
    for k in range(len(fixes)):
        sample = int(np.ceil(fixes.t_arrival[k] * rate_hz - 1e-9))
        if sample >= n:
            continue
        vel = fixes.vel_enu[k]
        out[sample] = dict(time_ms=int(round(fixes.t_valid[k] * 1000.0)) & 0xFFFFFFFF, fix_type=3, fix_ok=1, num_sv=12,
                           has_velocity=1, lat_1e7deg=int(round(fixes.lat_deg[k] * 1e7)),
                           lon_1e7deg=int(round(fixes.lon_deg[k] * 1e7)), height_mm=int(round(fixes.height_m[k] * 1e3)),
                           h_acc_mm=int(round(fixes.h_acc_m[k] * 1e3)), v_acc_mm=int(round(fixes.v_acc_m[k] * 1e3)),
                           vel_ned_mm_s=[int(round(v * 1e3)) for v in (vel[1], vel[0], -vel[2])],
                           s_acc_mm_s=int(round(fixes.s_acc_m_s[k] * 1e3)))
    return out


def baro_conversions(n: int, rate_hz: float, baro: navigation.BaroSamples | None = None) -> dict[int, tuple[int, int]]:
    """The emulated MS5611's D1 and D2 by the sample they are read with: those of `baro`'s
    pressures and temperatures (at its samples), or without it the still air of
    BARO_HEIGHT_M and BARO_TEMPERATURE_CDEG every BARO_PERIOD_S (baro_due)."""
    if baro is None:
        still = ms5611.raw_for(ms5611.EXAMPLE_C, float(navigation.pressure_at(BARO_HEIGHT_M)), BARO_TEMPERATURE_CDEG)
        return {int(k): still for k in np.flatnonzero(baro_due(n, rate_hz))}
    return {int(k): ms5611.raw_for(ms5611.EXAMPLE_C, float(pa), float(c) * 100.0)
            for k, pa, c in zip(baro.index, baro.pressure_pa, baro.temperature_c) if k < n}


def feed_frames(simulation: sim.SimResult, profile: SensorProfile = DEFAULT_PROFILE,
                gnss: navigation.GnssFixes | None = None, baro: navigation.BaroSamples | None = None) -> list[bytes]:
    """The feed of a simulated run: one SAMPLE frame per sample (counts in `profile`), with
    a BARO frame before it where the barometer has a measurement (baro_conversions) and a
    GNSS frame where a fix of `gnss` has arrived (gnss_messages), then a LOG frame saying
    the run is over. Each item of the list is what the board gets for one request
    (docs/firmware.md)."""
    counts = (simulation.gyr_counts, simulation.acc_counts, simulation.mag_counts)
    if profile != simulation.profile:
        counts = si_to_counts(simulation.gyr, simulation.acc, simulation.mag, profile)
    gyr, acc, mag = (c.tolist() for c in counts)
    period_us = 1e6 / simulation.rate_hz
    conversions = baro_conversions(len(gyr), simulation.rate_hz, baro)
    fixes = gnss_messages(gnss, simulation.rate_hz, len(gyr)) if gnss is not None else {}

    def stamp(k: int) -> dict:
        return dict(timestamp_us=round(k * period_us) & 0xFFFFFFFF, index=k)

    frames = [(protocol.encode("BARO", k & 0xFFFF, **stamp(k), d1=conversions[k][0], d2=conversions[k][1],
                               pressure_pa=0, temperature_cdeg=0) if k in conversions else b"")
              + (protocol.encode("GNSS", k & 0xFFFF, **stamp(k), **fixes[k]) if k in fixes else b"")
              + protocol.encode("SAMPLE", k & 0xFFFF, **stamp(k), gyr=gyr[k], acc=acc[k], mag=mag[k],
                                temperature=TEMPERATURE_25C)
              for k in range(len(gyr))]
    frames.append(protocol.encode("LOG", len(gyr) & 0xFFFF, level=protocol.LOG_LEVELS["INFO"],
                                  text=f"end of the simulated run ({len(gyr)} samples)"))
    return frames


class FeedServer:
    """The sensor feed of a QEMU board: a TCP server on 127.0.0.1 that answers every byte
    it receives with the next frame of `frames` (the last, the end, repeats).
    ``served`` counts the sample frames sent."""

    def __init__(self, frames: list[bytes]):
        self._frames = frames
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port = self._server.getsockname()[1]
        self.served = 0
        self._thread = threading.Thread(target=self._serve, name="imulink-feed", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        try:
            client, _ = self._server.accept()
        except OSError:
            return  # closed before QEMU connected
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        last = len(self._frames) - 1
        with client:
            while True:
                try:
                    requests = client.recv(4096)
                except OSError:
                    return
                if not requests:
                    return
                out = []
                for _ in requests:
                    out.append(self._frames[min(self.served, last)])
                    self.served = min(self.served + 1, last)
                try:
                    client.sendall(b"".join(out))
                except OSError:
                    return

    def close(self) -> None:
        self._server.close()


# ---------------------------------------------------------------------------- the board


class EmulatedBoard:
    """An emulated board. ``start()`` launches it (also a context manager), ``stop()`` ends it.

    Args:
        target: "native", "qemu" or "stm32f407" (the reference image on the virtual board:
            imulink.board.stm32f407; its rate is REFERENCE_RATE_HZ and its profile the default).
        front: what the host opens: "pty" (default), "tcp" (127.0.0.1:`port`, 0 any) or a
            serial port URL the board should be on (e.g. one end of a null-modem cable).
        scenario, duration_s, rate_hz, seed: the simulated run the sensors deliver
            (:func:`imulink.sim.make_scenario`, or NAV_SCENARIO: a car drive with a GNSS
            receiver and the barometer, its truth in ``trajectory``); rate_hz is also the
            filters' default rate.
        filter_name: filter active after start-up and RESET.
        realtime: samples at the board's clock rate; otherwise whenever the feed has one
            and the host has read the last ones.
        profile: sensor profile of the emulated GY-86 (its counts and the firmware's scales).
        faults, schema_hash: a fault proxy in front of the board.
        image: the firmware to run instead of the built one.
        simulation: a simulated run (imulink.sim.simulate) to feed instead of the scenario's,
            e.g. with other sensor errors; its rate must be rate_hz.
        gnss: fixes of a GNSS receiver to feed with the samples (imulink.sim.navigation.gnss_fixes
            of the simulation's trajectory); none by default.
        baro: the barometer's samples along the trajectory (imulink.sim.navigation.baro_samples);
            by default still air at BARO_HEIGHT_M every BARO_PERIOD_S.
        chip_faults: faults of the virtual reference board's chips and receiver (stm32f407 only).
    """

    def __init__(self, target: str = "native", *, front: str = "pty", port: int = 0, scenario: str = "rests",
                 duration_s: float = 600.0, rate_hz: float = 100.0, seed: int = 0, filter_name: str = "eecf",
                 realtime: bool = False, profile: SensorProfile = DEFAULT_PROFILE,
                 faults: FaultConfig | None = None, schema_hash: int | None = None,
                 image: str | os.PathLike | None = None, baud: int = 921600,
                 simulation: sim.SimResult | None = None, gnss: navigation.GnssFixes | None = None,
                 baro: navigation.BaroSamples | None = None,
                 chip_faults: stm32f407.ChipFaults | None = None):
        if filter_name not in core.BOARD_FILTERS:
            raise EmulatorError(f"unknown filter {filter_name!r}; choose one of {', '.join(core.BOARD_FILTERS)}")
        core.Filter(filter_name, rate_hz)  # SettingsError for a rate the filter is not made for (nor the host's replay)
        # the profiles the firmware's --profile option knows (boards/emulated/options.c)
        if profile.name not in PROFILES or PROFILES[profile.name] != profile:
            raise EmulatorError(f"the firmware knows the sensor profiles {', '.join(PROFILES)}, "
                                f"not {profile.name!r}")
        if target == "stm32f407":
            if rate_hz != REFERENCE_RATE_HZ:
                raise EmulatorError(f"the reference image samples at {REFERENCE_RATE_HZ:g} Hz after start-up, "
                                    f"not {rate_hz:g} Hz (change its rate with `imulink settings` once it runs)")
            if profile != DEFAULT_PROFILE:
                raise EmulatorError(f"the reference image configures its GY-86 as {DEFAULT_PROFILE.name}, "
                                    f"not {profile.name}")
        elif chip_faults is not None and chip_faults.active:
            raise EmulatorError("chip faults need the virtual reference board (--target stm32f407)")
        self.chip_faults = chip_faults
        self.target = target
        #: The board's stream ends with the simulated run (the feed's last frame says so); the
        #: virtual reference board's chips go on measuring their last sample instead.
        self.feed_ends = target != "stm32f407"
        self.image = find_image(target, image)
        self._qemu = find_qemu() if target == "qemu" else None
        self.front, self.port, self.baud = front, port, baud
        self.rate_hz = float(rate_hz)
        self.realtime = realtime
        self.profile = profile
        self.filter_name = filter_name
        self.faults = faults if faults is not None and faults.active else None
        self.schema_hash = schema_hash
        if simulation is not None and simulation.rate_hz != self.rate_hz:
            raise EmulatorError(f"the simulation runs at {simulation.rate_hz:g} Hz, the board at {rate_hz:g} Hz")
        if scenario not in SCENARIOS:
            raise EmulatorError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
        self.trajectory: navigation.NavTrajectory | None = None
        if simulation is None and scenario == NAV_SCENARIO:
            self.trajectory = navigation.car_drive(duration_s, rate_hz, seed=seed)
            simulation = sim.simulate(self.trajectory, navigation.datasheet_sensors(rate_hz), seed=seed)
            gnss = gnss if gnss is not None else navigation.gnss_fixes(self.trajectory, navigation.GnssModel(),
                                                                       seed=seed)
            baro = baro if baro is not None else navigation.baro_samples(self.trajectory, seed=seed)
        self.gnss, self.baro = gnss, baro
        self.simulation = simulation if simulation is not None else sim.make_scenario(scenario, duration_s, rate_hz,
                                                                                      seed)
        self._counts = (self.simulation.gyr_counts, self.simulation.acc_counts, self.simulation.mag_counts)
        if profile != self.simulation.profile:
            self._counts = si_to_counts(self.simulation.gyr, self.simulation.acc, self.simulation.mag, profile)
        self._dir: Path | None = None
        self._process: subprocess.Popen | None = None
        self._feed: FeedServer | None = None
        self.virtual: stm32f407.BoardServer | None = None
        self.proxy: Proxy | None = None
        self.address: str | None = None

    # ------------------------------------------------------------------ life

    def __enter__(self) -> "EmulatedBoard":
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def _firmware_options(self) -> list[str]:
        options = ["--profile", self.profile.name, "--rate", f"{self.rate_hz:.6f}", "--filter", self.filter_name]
        return options if self.realtime else options + ["--fast"]

    def start(self) -> "EmulatedBoard":
        self._dir = directory = Path(tempfile.mkdtemp(prefix="imulink-board-"))
        try:
            frames = feed_frames(self.simulation, self.profile, self.gnss, self.baro)
            if self.target == "native":
                self._start_native(frames, directory)
            elif self.target == "qemu":
                self._start_qemu(frames, directory)
            else:
                self._start_reference()
        except BaseException:
            self.stop()
            raise
        return self

    def _needs_proxy(self) -> bool:
        # a TCP front is always the proxy's: it takes several clients (one commands, the others listen)
        return self.faults is not None or self.schema_hash is not None or self.front != "pty"

    def _start_native(self, frames: list[bytes], directory: Path) -> None:
        feed = directory / "feed.bin"
        feed.write_bytes(b"".join(frames))
        direct = not self._needs_proxy()
        where = (["--pty"] if self.front == "pty" else ["--tcp", str(self.port)]) if direct else ["--tcp", "0"]
        command = [str(self.image), *where, "--feed", str(feed), *self._firmware_options()]
        self._process = process = subprocess.Popen(command, stdout=subprocess.PIPE,
                                                   stderr=open(directory / "board.log", "wb"), stdin=subprocess.DEVNULL)
        assert process.stdout is not None  # stdout=PIPE
        address = self._read_address(process.stdout)
        self.address = address if direct else self._start_proxy(address)

    def _read_address(self, stdout: IO[bytes]) -> str:
        """The first line the native board prints (on `stdout`): where it serves."""
        result: list[bytes] = []
        reader = threading.Thread(target=lambda: result.append(stdout.readline()), daemon=True)
        reader.start()
        reader.join(_START_TIMEOUT_S)
        line = result[0].decode(errors="replace").strip() if result else ""
        if not line:
            raise EmulatorError(f"the native board did not start: {self._log_tail()}")
        return line

    def _start_qemu(self, frames: list[bytes], directory: Path) -> None:
        assert self._qemu is not None  # found by __init__ for the qemu target
        self._feed = FeedServer(frames)
        link_port = _free_port()
        semihosting = ",".join(["enable=on", "target=native", "arg=imulink-qemu",
                                *(f"arg={word}" for word in self._firmware_options())])
        command = [self._qemu, "-M", QEMU_MACHINE, "-nographic", "-monitor", "none", "-kernel", str(self.image),
                   "-serial", f"tcp:127.0.0.1:{link_port},server=on,wait=on,nodelay=on",
                   "-serial", f"tcp:127.0.0.1:{self._feed.port},nodelay=on",
                   "-semihosting-config", semihosting]
        log = open(directory / "board.log", "wb")
        self._process = subprocess.Popen(command, stdout=log, stderr=log, stdin=subprocess.DEVNULL)
        try:
            self.address = self._start_proxy(f"socket://127.0.0.1:{link_port}")
        except Exception as exc:
            raise EmulatorError(f"QEMU did not start: {exc}; {self._log_tail()}") from None

    def _start_reference(self) -> None:
        flash, elf = reference_flash(self.image)
        sim = self.simulation
        gyr, acc, mag = self._counts
        feed = stm32f407.Feed(sim.rate_hz, gyr, acc, mag, baro=baro_conversions(len(gyr), sim.rate_hz, self.baro),
                              gnss=gnss_messages(self.gnss, sim.rate_hz, len(gyr)) if self.gnss is not None else {})
        board = stm32f407.ReferenceBoard(flash, elf=elf, feed=feed, faults=self.chip_faults, line_baud=self.baud)
        if self.filter_name != "eskf":  # the image starts with the ESKF: a first command selects another
            board.run_for(0.3)
            filter_id = core.BOARD_FILTERS[self.filter_name][0]
            board.put(protocol.encode_command(0, "SELECT_FILTER", 0xFFFF, filter_id=filter_id))
            board.run_for(0.05)
            board.take()  # its start-up messages and the ACK: the host asks for HELLO when it connects
        if self._needs_proxy():
            self.virtual = stm32f407.BoardServer(board, realtime=self.realtime).start()
            self.address = self._start_proxy(f"socket://127.0.0.1:{self.virtual.port}")
        else:  # a pty carries raw bytes both ways: `imulink flash --enter command` reaches the bootloader
            front = PtyFront()
            self.virtual = stm32f407.BoardServer(board, realtime=self.realtime, pty=front).start()
            self.address = front.address

    def _start_proxy(self, board_url: str) -> str:
        front = make_front(self.front, self.port, self.baud)
        self.proxy = Proxy(board_url, front, faults=self.faults, schema_hash=self.schema_hash,
                           connect_timeout_s=_START_TIMEOUT_S).start()
        return self.proxy.address

    def stop(self) -> None:
        """Stop the board and everything around it (idempotent)."""
        if self.proxy is not None:
            self.proxy.stop()
            self.proxy = None
        if self._process is not None:
            if self._process.poll() is None:
                self._process.terminate()
                try:
                    self._process.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self._process.kill()
                    self._process.wait()
            if self._process.stdout is not None:
                self._process.stdout.close()
            self._process = None
        if self._feed is not None:
            self._feed.close()
            self._feed = None
        if self.virtual is not None:
            self.virtual.stop()
            self.virtual = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    @property
    def error(self) -> str | None:
        """Why the board stopped on its own (its process exited, its proxy failed), or None."""
        if self._process is not None and self._process.poll() is not None:
            return f"the {self.target} board exited with status {self._process.returncode}: {self._log_tail()}"
        if self.virtual is not None and self.virtual.error is not None:
            return f"the virtual {self.target} board stopped: {self.virtual.error}"
        if self.proxy is not None and self.proxy.error is not None:
            return f"the link to the {self.target} board failed: {self.proxy.error}"
        return None

    def _log_tail(self) -> str:
        if self._dir is None:  # not started
            return "no output"
        try:
            text = (self._dir / "board.log").read_text(errors="replace").strip()
        except OSError:
            return "no output"
        return text.splitlines()[-1] if text else "no output"

    # ------------------------------------------------------------------ truth

    def truth(self, gyr, acc, mag) -> np.ndarray:
        """True attitude (N,4) of recorded samples, found by their counts: the board reads the
        feed in order, so each sample is the next simulated one with the same counts (NaN
        where none matches)."""
        positions = self.positions(gyr, acc, mag)
        truth = self.simulation.quat_true[np.maximum(positions, 0)].copy()
        truth[positions < 0] = np.nan
        return truth

    def positions(self, gyr, acc, mag) -> np.ndarray:
        """Position in the simulated run of each recorded sample (see :meth:`truth`); -1 where none."""
        # gyroscope and accelerometer: a magnetometer that measures at its own rate (the virtual
        # HMC5883L at 75 Hz) repeats its last field between measurements
        fed = np.concatenate(self._counts[:2], axis=1)
        got = np.concatenate([np.asarray(a, np.int16).reshape(-1, 3) for a in (gyr, acc)], axis=1)
        positions = np.full(len(got), -1, np.int64)
        start = 0
        for i, row in enumerate(got):
            if start < len(fed) and (fed[start] == row).all():  # the usual case: nothing was lost
                positions[i] = start
            elif start > 0 and positions[i - 1] == start - 1 != positions[i - 2] and (fed[start - 1] == row).all():
                positions[i] = start - 1  # read twice (a chip on its own clock); more often: the run is over
                continue
            else:
                ahead = np.flatnonzero((fed[start:] == row).all(axis=1))
                if not len(ahead):
                    continue
                positions[i] = start + ahead[0]
            start = positions[i] + 1
        return positions


def _free_port() -> int:
    """A TCP port on 127.0.0.1 that nobody listens on now (QEMU will)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
