"""Flashing over SWD (imulink.board.flash.swd) without a probe: both backends against stand-ins.

- OpenOCD: a fake `openocd` script first on the PATH. It checks its arguments as the real
  one would use them, copies the HEX file it is told to program to a file the test reads,
  prints OpenOCD's phase banners, and on request fails with OpenOCD's own error texts
  (src/jtag/drivers/stlink_usb.c, src/target/target.c, src/flash/startup.tcl).
- pyOCD: fake `pyocd` modules in sys.modules with the few names imulink.board.flash.swd uses
  (ConnectHelper, MemoryLoader, the exceptions) around a target whose flash is a
  bytearray, so that programming, verifying, resetting, dry runs and a verify mismatch
  all run. pyOCD itself is an optional dependency and is not needed here.
"""
from __future__ import annotations

import json
import os
import random
import sys
import time
import types
from types import SimpleNamespace

import pytest

from imulink.board.flash import swd
from imulink.board.flash.swd import SwdError, flash_swd
from imulink.io.firmware_image import FirmwareImage, Segment, load_image

FLASH_BASE, FLASH_SIZE = 0x0800_0000, 1 << 20

pytestmark = pytest.mark.skipif(os.name == "nt", reason="the fake openocd is a #! script")


@pytest.fixture
def image(tmp_path) -> FirmwareImage:
    """Two segments, the second across a 64 KiB boundary (an extended address record in HEX)."""
    rng = random.Random(7)
    first = Segment(FLASH_BASE, bytes(rng.randrange(256) for _ in range(3000)))
    second = Segment(FLASH_BASE + 0x1_0000 - 40, bytes(rng.randrange(256) for _ in range(200)))
    return FirmwareImage(tmp_path / "firmware.elf", "elf", (first, second), None)


class Recorder:
    """A progress callback that keeps every call."""

    def __init__(self):
        self.calls: list[tuple[str, int, int]] = []

    def __call__(self, phase: str, done: int, total: int) -> None:
        assert phase in swd.PHASES and 0 <= done <= total
        self.calls.append((phase, done, total))

    def phases(self) -> list[str]:
        names: list[str] = []
        for phase, _, _ in self.calls:
            if not names or names[-1] != phase:
                names.append(phase)
        return names

    def finished(self) -> list[str]:
        return [phase for phase, done, total in self.calls if done == total]


def one_line(error: pytest.ExceptionInfo) -> str:
    text = str(error.value)
    assert text and "\n" not in text
    return text


# ---------------------------------------------------------------------------- Intel HEX


def test_intel_hex_round_trips_through_the_image_reader(image, tmp_path):
    path = tmp_path / "copy.hex"
    path.write_text(swd.intel_hex(image.segments))
    again = load_image(path)
    assert again.segments == image.segments
    lines = path.read_text().splitlines()
    assert lines[0] == ":020000040800F2" and lines[-1] == ":00000001FF"
    assert ":020000040801F1" in lines  # the upper address bits change mid-segment


@pytest.mark.parametrize("name, config", [
    ("stm32f407vg", "target/stm32f4x.cfg"), ("STM32F405RG", "target/stm32f4x.cfg"),
    ("stm32l476rg", "target/stm32l4x.cfg"), ("stm32g474re", "target/stm32g4x.cfg"),
    ("target/stm32f4x.cfg", "target/stm32f4x.cfg"), ("boards/my.cfg", "boards/my.cfg")])
def test_openocd_target_configs(name, config):
    assert swd.openocd_config(name, "target") == config


def test_openocd_interface_names():
    assert swd.openocd_config("cmsis-dap", "interface") == "interface/cmsis-dap.cfg"
    assert swd.openocd_config("interface/stlink.cfg", "interface") == "interface/stlink.cfg"
    with pytest.raises(SwdError) as error:
        swd.openocd_config("nrf52", "target")
    assert "--target target/" in one_line(error)


def test_bad_arguments_are_refused(image):
    with pytest.raises(SwdError) as error:
        flash_swd(image, "jlink")
    assert "pyocd, openocd" in one_line(error)
    with pytest.raises(SwdError) as error:
        flash_swd(image, "openocd", probe="0669; shutdown")
    assert "not a debug probe id" in one_line(error)


# ---------------------------------------------------------------------------- OpenOCD

FAKE_OPENOCD = '''\
#!{python}
"""A stand-in for openocd (see tests/test_swd.py)."""
import json, os, re, shutil, sys, time

args = sys.argv[1:]
with open(os.environ["FAKE_OPENOCD_LOG"], "a") as log:
    log.write(json.dumps(args) + "\\n")
mode = os.environ.get("FAKE_OPENOCD_MODE", "ok")


def say(*lines):
    for line in lines:
        print(line, file=sys.stderr, flush=True)


def end(code, *lines):
    say(*lines, "shutdown command invoked")
    sys.exit(code)


def refuse(what):
    say("fake openocd: " + what)
    sys.exit(2)


pairs = list(zip(args[0::2], args[1::2]))
if len(args) % 2 or any(flag not in ("-f", "-c") for flag, _ in pairs) or pairs[0][0] != "-f" \\
        or not pairs[0][1].startswith("interface/"):
    refuse("unexpected arguments " + repr(args))
say("Open On-Chip Debugger 0.12.0", "Licensed under GNU GPL v2")
for flag, value in pairs:
    if flag == "-f" and value not in ("interface/stlink.cfg", "interface/cmsis-dap.cfg", "target/stm32f4x.cfg"):
        say("embedded:startup.tcl:28: Error: Can't find " + value, "in procedure 'script'")
        sys.exit(1)
    if flag == "-c" and value.startswith("adapter serial ") and [f for f, _ in pairs].index("-c") != 1:
        refuse("adapter serial must follow the interface config")
command = pairs[-1][1]
if command == "shutdown":
    end(0)
program = re.fullmatch(r"program \\{{(.+)\\}} (verify )?reset exit", command)
if program is None:
    refuse("unexpected command " + repr(command))
shutil.copy(program.group(1), os.environ["FAKE_OPENOCD_OUT"])
init_failed = "** OpenOCD init failed **"
if mode == "hang":
    time.sleep(60)
if mode == "no-probe":
    end(1, "Info : clock speed 2000 kHz", "Error: open failed", init_failed)
if mode == "access":
    end(1, "Error: libusb_open() failed with LIBUSB_ERROR_ACCESS", "Error: open failed", init_failed)
if mode == "wrong-serial":
    end(1, "Info : No device matches the serial string", "Error: open failed", init_failed)
say("Info : STLINK V2J37M26 (API v2) VID:PID 0483:374B")
if mode == "no-power":
    end(1, "Info : Target voltage: 0.006385", "Error: target voltage may be too low for reliable debugging",
        "Error: init mode failed (unable to connect to the target)", init_failed)
say("Info : Target voltage: 3.240000")
if mode == "no-target":
    end(1, "Error: init mode failed (unable to connect to the target)", init_failed)
say("Info : [stm32f4x.cpu] Cortex-M4 r0p1 processor detected", "** Programming Started **",
    "Info : device id = 0x10076413", "Info : flash size = 1024 KiB")
if mode == "protected":
    end(1, "Error: stm32x device protected", "Error: failed erasing sectors 0 to 1", "** Programming Failed **")
say("** Programming Finished **")
if program.group(2):
    say("** Verify Started **")
    if mode == "verify-fail":
        end(1, "Error: checksum mismatch - attempting binary compare",
            "diff 0 address 0x08000004. Was 0x00 instead of 0xc1", "No more differences found.",
            "** Verify Failed **")
    say("** Verified OK **")
end(0, "** Resetting Target **")
'''


@pytest.fixture
def openocd(tmp_path, monkeypatch):
    """The fake openocd on the PATH; `.mode` picks its behaviour, `.calls()` its argument lists."""
    folder = tmp_path / "bin"
    folder.mkdir()
    script = folder / "openocd"
    script.write_text(FAKE_OPENOCD.format(python=sys.executable))
    script.chmod(0o755)
    monkeypatch.setenv("PATH", f"{folder}{os.pathsep}{os.environ.get('PATH', '')}")
    log, out = tmp_path / "openocd-calls.jsonl", tmp_path / "programmed.hex"
    monkeypatch.setenv("FAKE_OPENOCD_LOG", str(log))
    monkeypatch.setenv("FAKE_OPENOCD_OUT", str(out))

    class Fake:
        path = script
        programmed = out

        @staticmethod
        def mode(name: str) -> None:
            monkeypatch.setenv("FAKE_OPENOCD_MODE", name)

        @staticmethod
        def calls() -> list[list[str]]:
            return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []

    return Fake


def test_openocd_programs_verifies_and_resets(image, openocd):
    progress = Recorder()
    summary = flash_swd(image, "openocd", progress=progress)
    [args] = openocd.calls()
    assert args[:4] == ["-f", "interface/stlink.cfg", "-f", "target/stm32f4x.cfg"]
    assert args[4] == "-c" and args[5].startswith("program {") and args[5].endswith("} verify reset exit")
    assert load_image(openocd.programmed).segments == image.segments
    total = image.size
    assert progress.calls == [("erase", 0, total), ("erase", total, total), ("write", total, total),
                              ("verify", 0, total), ("verify", total, total)]
    assert "3200 bytes" in summary and "verified" in summary and "\n" not in summary


def test_openocd_options(image, openocd):
    flash_swd(image, "openocd", probe="0669FF555052836687031845", interface="cmsis-dap", verify=False)
    [args] = openocd.calls()
    assert args[:6] == ["-f", "interface/cmsis-dap.cfg", "-c", "adapter serial 0669FF555052836687031845",
                        "-f", "target/stm32f4x.cfg"]
    assert args[7].endswith("} reset exit") and "verify" not in args[7]


def test_openocd_dry_run_writes_nothing(image, openocd):
    progress = Recorder()
    summary = flash_swd(image, "openocd", dry_run=True, progress=progress)
    [args] = openocd.calls()
    assert args[-2:] == ["-c", "shutdown"] and not any(a.startswith("program") for a in args)
    assert not openocd.programmed.exists() and progress.calls == []
    assert summary.startswith("dry run") and "nothing written" in summary


def test_openocd_dry_run_finds_a_missing_config(image, openocd):
    with pytest.raises(SwdError) as error:
        flash_swd(image, "openocd", dry_run=True, interface="interface/stlnk.cfg")
    assert "openocd has no config file interface/stlnk.cfg" in one_line(error)


@pytest.mark.parametrize("mode, probe, expected", [
    ("no-probe", None, "no debug probe found: plug in the ST-Link"),
    ("access", None, "permission denied"),
    ("wrong-serial", "066DFF", "no debug probe with serial 066DFF found"),
    ("no-power", None, "the target has no power (the probe reads 0.01 V)"),
    ("no-target", None, "the target does not answer over SWD: check the SWDIO, SWCLK and GND wires"),
    ("verify-fail", None, "verify failed at address 0x08000004: the flash holds 0x00 where the image has 0xc1"),
    ("protected", None, "the chip is read-protected"),
])
def test_openocd_failures_become_one_line(image, openocd, mode, probe, expected):
    openocd.mode(mode)
    progress = Recorder()
    with pytest.raises(SwdError) as error:
        flash_swd(image, "openocd", probe=probe, progress=progress)
    assert expected in one_line(error)
    assert "verify" not in progress.finished()


def test_openocd_missing(image, tmp_path, monkeypatch):
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    assert swd.available_methods()["openocd"] is None
    with pytest.raises(SwdError) as error:
        flash_swd(image, "openocd")
    assert "openocd is not on the PATH" in one_line(error)


def test_openocd_that_hangs_is_stopped(image, openocd, monkeypatch):
    openocd.mode("hang")
    monkeypatch.setattr(swd, "OPENOCD_TIMEOUT_S", 1.0)
    started = time.monotonic()
    with pytest.raises(SwdError) as error:
        flash_swd(image, "openocd")
    assert time.monotonic() - started < 10
    assert "did not finish within 1 s" in one_line(error)


def test_available_methods_finds_openocd(openocd):
    assert swd.available_methods()["openocd"] == str(openocd.path)


# ---------------------------------------------------------------------------- pyOCD


class FakeTarget:
    """A chip: 1 MiB of flash at 0x08000000 in a bytearray, 128 KiB of RAM that is not flash."""

    def __init__(self):
        self.flash = bytearray(b"\xff" * FLASH_SIZE)
        self.resets = 0
        self.reads = 0
        regions = [SimpleNamespace(start=FLASH_BASE, length=FLASH_SIZE, is_flash=True),
                   SimpleNamespace(start=0x2000_0000, length=128 << 10, is_flash=False)]
        self.memory_map = SimpleNamespace(get_region_for_address=lambda address: next(
            (r for r in regions if r.start <= address < r.start + r.length), None))

    def read_memory_block8(self, address: int, size: int) -> list[int]:
        assert FLASH_BASE <= address and address + size <= FLASH_BASE + FLASH_SIZE
        self.reads += 1
        return list(self.flash[address - FLASH_BASE:address - FLASH_BASE + size])

    def reset(self, reset_type=None) -> None:
        self.resets += 1


def make_fake_pyocd(world: SimpleNamespace) -> dict[str, types.ModuleType]:
    """The modules `pyocd...` that imulink.board.flash.swd imports, acting on `world`."""
    exceptions = types.ModuleType("pyocd.core.exceptions")

    class Error(RuntimeError):
        pass

    class FlashFailure(Error):
        def __init__(self, *args, address=None):
            super().__init__(*args)
            self.address = address

    exceptions.Error = Error
    exceptions.TimeoutError = type("TimeoutError", (Error,), {})
    exceptions.TargetSupportError = type("TargetSupportError", (Error,), {})
    exceptions.ProbeError = type("ProbeError", (Error,), {})
    exceptions.ProbeDisconnected = type("ProbeDisconnected", (exceptions.ProbeError,), {})
    exceptions.TransferError = type("TransferError", (Error,), {})
    exceptions.FlashFailure = FlashFailure
    world.exceptions = exceptions

    class Session:
        def __init__(self):
            self.target = world.target
            world.open_sessions += 1

        def __enter__(self):
            return self

        def __exit__(self, *exc_info):
            world.open_sessions -= 1
            return False

    class ConnectHelper:
        @staticmethod
        def get_all_connected_probes(blocking=True, unique_id=None, print_wait_message=True):
            assert blocking is False  # never wait for a probe to be plugged in
            return [p for p in world.probes if unique_id is None or unique_id in p.unique_id]

        @staticmethod
        def session_with_chosen_probe(blocking=True, return_first=False, unique_id=None, auto_open=True,
                                      options=None, **kwargs):
            assert blocking is False and return_first is True  # never prompt
            world.session_args = dict(unique_id=unique_id, options=options, **kwargs)
            if world.connect_error is not None:
                raise world.connect_error
            return Session()

    class MemoryLoader:
        def __init__(self, session, progress=None, chip_erase=None, **kwargs):
            self.progress, self.chunks = progress, []
            world.chip_erase = chip_erase

        def add_data(self, address, data):
            assert isinstance(data, list)
            self.chunks.append((address, data))

        def commit(self):
            flash = world.target.flash
            for step in range(5):  # erase: the sectors touched, 0 -> 1
                self.progress(step / 4)
            for address, data in self.chunks:
                flash[address - FLASH_BASE:address - FLASH_BASE + len(data)] = bytes(data)
                if world.write_error is not None:
                    raise world.write_error
                self.progress(0.5)
            self.progress(1.0)
            if world.corrupt_at is not None:
                flash[world.corrupt_at - FLASH_BASE] ^= 0x10

    modules = {name: types.ModuleType(name) for name in ("pyocd", "pyocd.core", "pyocd.core.helpers",
                                                         "pyocd.flash", "pyocd.flash.loader")}
    modules["pyocd.core.exceptions"] = exceptions
    modules["pyocd"].__version__ = "0.46.0"
    modules["pyocd"].core, modules["pyocd"].flash = modules["pyocd.core"], modules["pyocd.flash"]
    modules["pyocd.core"].helpers, modules["pyocd.core"].exceptions = modules["pyocd.core.helpers"], exceptions
    modules["pyocd.core.helpers"].ConnectHelper = ConnectHelper
    modules["pyocd.flash"].loader = modules["pyocd.flash.loader"]
    modules["pyocd.flash.loader"].MemoryLoader = MemoryLoader
    return modules


@pytest.fixture
def pyocd(monkeypatch):
    """A fake pyOCD with one ST-Link and a blank STM32F407; the returned namespace is its world."""
    world = SimpleNamespace(
        target=FakeTarget(), probes=[SimpleNamespace(unique_id="0669FF555052836687031845",
                                                     description="STM32 STLink")],
        connect_error=None, write_error=None, corrupt_at=None, session_args=None, chip_erase=None, open_sessions=0)
    for name, module in make_fake_pyocd(world).items():
        monkeypatch.setitem(sys.modules, name, module)
    yield world
    assert world.open_sessions == 0  # every session closed, also on errors


def flash_bytes(world, image: FirmwareImage) -> list[bytes]:
    return [bytes(world.target.flash[s.address - FLASH_BASE:s.end - FLASH_BASE]) for s in image.segments]


def test_pyocd_programs_verifies_and_resets(image, pyocd):
    progress = Recorder()
    summary = flash_swd(image, "pyocd", progress=progress)
    assert flash_bytes(pyocd, image) == [s.data for s in image.segments]
    assert pyocd.target.resets == 1 and pyocd.chip_erase == "sector"
    assert pyocd.session_args["target_override"] == "stm32f407vg"
    assert pyocd.session_args["unique_id"] == "0669FF555052836687031845"
    assert progress.phases() == ["erase", "write", "verify"]
    assert progress.finished() == ["erase", "write", "verify"]
    for phase in swd.PHASES:
        done = [d for p, d, _ in progress.calls if p == phase]
        assert done == sorted(done)
    assert pyocd.target.reads == 2  # one 4 KiB chunk per segment
    assert "verified" in summary and "STM32 STLink" in summary


def test_pyocd_without_verify_reads_nothing(image, pyocd):
    progress = Recorder()
    flash_swd(image, "pyocd", verify=False, progress=progress)
    assert pyocd.target.reads == 0 and pyocd.target.resets == 1
    assert progress.finished() == ["erase", "write"]


def test_pyocd_dry_run_writes_nothing(image, pyocd):
    progress = Recorder()
    summary = flash_swd(image, "pyocd", dry_run=True, progress=progress)
    assert pyocd.target.flash == bytearray(b"\xff" * FLASH_SIZE)
    assert pyocd.target.resets == 0 and progress.calls == []
    assert pyocd.session_args["connect_mode"] == "attach"  # looks, does not halt the running firmware
    assert summary.startswith("dry run") and "0x08000000-0x08000bb7" in summary


def test_pyocd_verify_names_the_first_differing_address(image, pyocd):
    pyocd.corrupt_at = FLASH_BASE + 0x123
    with pytest.raises(SwdError) as error:
        flash_swd(image, "pyocd")
    text = one_line(error)
    assert text.startswith("verify failed at address 0x08000123")
    assert pyocd.target.resets == 0  # not started with a broken image


def test_pyocd_refuses_an_image_outside_flash(tmp_path, pyocd):
    ram_image = FirmwareImage(tmp_path / "ram.elf", "elf", (Segment(0x2000_0000, b"\0" * 64),), None)
    with pytest.raises(SwdError) as error:
        flash_swd(ram_image, "pyocd")
    assert "0x20000000, which is not flash on stm32f407vg" in one_line(error)
    assert pyocd.target.flash == bytearray(b"\xff" * FLASH_SIZE)


def test_pyocd_probe_choice(image, pyocd):
    pyocd.probes.append(SimpleNamespace(unique_id="004800283137510A39383538", description="STLINK-V3"))
    with pytest.raises(SwdError) as error:
        flash_swd(image, "pyocd")
    assert "2 debug probes are connected" in one_line(error) and "--probe" in str(error.value)
    flash_swd(image, "pyocd", probe="0048")
    assert pyocd.session_args["unique_id"] == "004800283137510A39383538"
    with pytest.raises(SwdError) as error:
        flash_swd(image, "pyocd", probe="12345")
    assert "no debug probe with id 12345 found" in one_line(error)
    pyocd.probes.clear()
    with pytest.raises(SwdError) as error:
        flash_swd(image, "pyocd")
    assert "no debug probe found: plug in the ST-Link" in one_line(error) and "udev" in str(error.value)


@pytest.mark.parametrize("raised, expected", [
    (lambda e: e.TargetSupportError("Target type stm32f407vg not recognized. Use 'pyocd list --targets' to see\n"
                                    "currently available target types."), "pyocd pack install stm32f407vg"),
    (lambda e: e.ProbeError("STLink error (9): Get IDCODE error"), "the target does not answer over SWD"),
    (lambda e: e.TransferError("No ACK received"), "check the SWDIO, SWCLK and GND wires"),
    (lambda e: e.ProbeDisconnected("device disconnected"), "the debug probe disconnected"),
    (lambda e: e.ProbeError("Access denied (insufficient permissions)"), "permission denied"),
])
def test_pyocd_connection_failures_become_one_line(image, pyocd, raised, expected):
    pyocd.connect_error = raised(pyocd.exceptions)
    with pytest.raises(SwdError) as error:
        flash_swd(image, "pyocd")
    assert expected in one_line(error)


def test_pyocd_flash_failure(image, pyocd):
    pyocd.write_error = pyocd.exceptions.FlashFailure("program page error", address=FLASH_BASE + 0x800)
    with pytest.raises(SwdError) as error:
        flash_swd(image, "pyocd")
    assert "writing the flash failed at 0x08000800: program page error" in one_line(error)


def test_pyocd_missing(image, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyocd", None)  # import pyocd now fails as if it were not installed
    assert swd.available_methods()["pyocd"] is None
    with pytest.raises(SwdError) as error:
        flash_swd(image, "pyocd")
    assert "pip install 'imulink[swd]'" in one_line(error)


def test_available_methods_reports_pyocds_version(pyocd):
    assert swd.available_methods()["pyocd"] == "0.46.0"
