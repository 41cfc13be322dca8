"""Flashing a firmware image over SWD with a debug probe (an ST-Link, or any probe the
backend knows), for `imulink flash IMAGE --method pyocd|openocd`.

Two backends behind one call, :func:`flash_swd`:

- ``pyocd``: the pyOCD library (Apache-2.0, an optional dependency: ``pip install
  'imulink[swd]'``), imported only here. The image's segments are handed to pyOCD's
  memory loader (not the file, so ELF, HEX and BIN images behave the same), which
  erases only the sectors they touch and skips pages already holding the same bytes;
  the flash is then read back and compared here, naming the first differing address;
  then the target is reset and runs. pyOCD knows the STM32F407 from its CMSIS pack
  (``pyocd pack install stm32f407vg``, once; `pyocd pack find stm32f407` shows the
  pack's exact name for the chip).
- ``openocd``: the OpenOCD program on the PATH. The segments are written to a
  temporary Intel HEX file (the bytes this tool read from the image, whatever its
  format, and a path free of characters Tcl would misread) and OpenOCD runs
  ``program <file> verify reset exit``. Its output is read as it comes: its phase
  banners become progress, its error texts become one SwdError line.

A probe on another machine (a labgrid place's, :class:`RemoteProbe`) is used as labgrid
uses one: OpenOCD runs on that machine, told the probe's USB path there (``adapter usb
location``), the HEX file copied there first. pyOCD cannot use such a probe (PYOCD_REMOTE).

Progress, used across the flashing code: ``progress(phase, done, total)`` with phase
"erase", "write" or "verify" and byte counts; each phase that runs ends with a call
with ``done == total``. pyOCD reports erase and write separately (0.44 and later);
OpenOCD erases while it writes, so both of its phases end together.

Every failure is a :class:`SwdError`: one line saying what went wrong and what to do.
"""
from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Optional, Protocol

from imulink.errors import ImulinkError
from imulink.io.firmware_image import FirmwareImage
from imulink.progress import PhaseProgress

METHODS = ("pyocd", "openocd")
PHASES = ("erase", "write", "verify")
#: pyOCD's name of the board's chip (needs its pack) and the interface OpenOCD talks through.
DEFAULT_TARGET = "stm32f407vg"
DEFAULT_INTERFACE = "interface/stlink.cfg"
#: Seconds OpenOCD may take for a whole program-verify-reset (1 MiB at ST-Link speed is ~30 s).
OPENOCD_TIMEOUT_S = 300.0
#: Bytes read back per request while verifying (one progress step).
VERIFY_CHUNK = 4096


_INSTALL_PYOCD = "pip install 'imulink[swd]'"
_NO_PROBE_HINT = ("plug in the ST-Link (on Linux, install the probe's udev rules and plug it in again; "
                  "`{tool}` lists the probes it sees)")
_NOT_RESPONDING = ("the target does not answer over SWD: check the SWDIO, SWCLK and GND wires and the board's power "
                   "(firmware that sleeps or reuses the SWD pins needs the probe's NRST wired: connect under reset)")
_NO_ACCESS = ("the debug probe is there but may not be opened: permission denied (on Linux, install the probe's "
              "udev rules, e.g. openocd's 60-openocd.rules, and plug it in again)")


#: Why pyOCD cannot flash through a labgrid place's probe.
PYOCD_REMOTE = ("pyOCD cannot flash through a labgrid place's debug probe: labgrid names the probe by its USB path "
                "on the exporter's host and runs a probe's tools there, while pyOCD runs here and reaches another "
                "machine's probe only through a pyOCD probe server, which labgrid neither exports nor starts; flash "
                "the place with --method openocd (docs/farm.md)")


class SwdError(ImulinkError):
    """Flashing over SWD failed; the message is one line, fit to print, saying what to do."""


class RemoteProbe(Protocol):
    """A debug probe on another machine, as a labgrid place has one
    (imulink.board.lab.HeldProbe): a tool for it runs on that machine."""

    host: str
    usb_path: str | None

    def describe(self) -> str:
        """The probe and its machine, for messages."""
        ...

    def command(self, argv: list[str]) -> list[str]:
        """`argv` as a command line that runs it on the probe's machine."""
        ...

    def stage(self, path: str) -> str:
        """The path on the probe's machine of local file `path`, copied there if need be."""
        ...


def available_methods() -> dict[str, Optional[str]]:
    """The SWD backends this computer has: pyOCD's version (None when it is not installed)
    and the path of the openocd executable (None when it is not on the PATH)."""
    try:
        import pyocd
        pyocd_version = str(getattr(pyocd, "__version__", "unknown version"))
    except Exception:  # not installed, or broken (flash_swd names the reason)
        pyocd_version = None
    return {"pyocd": pyocd_version, "openocd": shutil.which("openocd")}


def flash_swd(image: FirmwareImage, method: str, *, target: str = DEFAULT_TARGET, probe: Optional[str] = None,
              verify: bool = True, dry_run: bool = False, progress: Optional[PhaseProgress] = None,
              interface: str = DEFAULT_INTERFACE, remote: Optional[RemoteProbe] = None) -> str:
    """Write `image` to the target's flash over SWD, verify it, reset the target so it runs.

    Args:
        image: the segments to write (imulink.io.firmware_image.load_image).
        method: "pyocd" or "openocd".
        target: the chip: pyOCD's target name; for OpenOCD a name like stm32f407vg
            (its family's target/stm32f4x.cfg is used) or a .cfg file.
        probe: the probe's unique id / serial number when more than one is plugged in.
        verify: read the flash back and compare it with the image.
        dry_run: write nothing. pyOCD connects to the probe and the target and checks that
            the image lies in the target's flash; OpenOCD checks that the executable and
            its interface and target configs exist (it contacts no probe).
        progress: ``progress(phase, done, total)`` (see the module's docstring), or None.
        interface: OpenOCD only: the interface config (a name like "cmsis-dap" means
            interface/cmsis-dap.cfg).
        remote: a probe on another machine (a labgrid place's): OpenOCD runs there, on the
            probe at its USB path; the configs are that machine's. pyOCD cannot (PYOCD_REMOTE).

    Returns one line saying what was done (or, for a dry run, what would be).
    Raises SwdError.
    """
    if method not in METHODS:
        raise SwdError(f"unknown flashing method {method!r}; choose one of {', '.join(METHODS)}")
    if probe is not None and not re.fullmatch(r"[A-Za-z0-9_.:-]+", probe):
        raise SwdError(f"{probe!r} is not a debug probe id (letters, digits and _.:- only)")
    if remote is not None and method == "pyocd":
        raise SwdError(PYOCD_REMOTE)
    phases = _Phases(progress, image.size)
    if method == "pyocd":
        return _flash_pyocd(image, target, probe, verify, dry_run, phases)
    return _flash_openocd(image, target, probe, verify, dry_run, phases, interface, remote)


def describe_segments(image: FirmwareImage) -> str:
    """'N bytes at 0x08000000-0x0801e23f' (every range when there are a few, else the span)."""
    ranges = [f"{s.address:#010x}-{s.end - 1:#010x}" for s in image.segments]
    if len(ranges) > 3:
        ranges = [f"{len(ranges)} ranges in {image.start:#010x}-{image.end - 1:#010x}"]
    where = ", ".join(ranges)
    return f"{image.size} bytes at {where}"


class _Phases:
    """Our progress calls on top of a backend's: byte counts clamped to the total, each
    phase finished (done == total) exactly once, nothing at all without a callback."""

    def __init__(self, callback: Optional[PhaseProgress], total: int):
        self._callback = callback
        self.total = total
        self._finished: set[str] = set()
        self._pyocd_phase = "erase"
        self._pyocd_last = 0.0

    def update(self, phase: str, done: int) -> None:
        if phase in self._finished:
            return
        done = max(0, min(int(done), self.total))
        if done == self.total:
            self._finished.add(phase)
        if self._callback is not None:
            self._callback(phase, done, self.total)

    def finish(self, *phases: str) -> None:
        for phase in phases:
            self.update(phase, self.total)

    def pyocd_fraction(self, fraction: float) -> None:
        """pyOCD's loader reports a fraction rising from 0 to 1 while it erases, then again
        while it programs: a fall marks the start of programming."""
        if self._pyocd_phase == "erase" and fraction < self._pyocd_last - 1e-9:
            self.finish("erase")
            self._pyocd_phase = "write"
        self._pyocd_last = fraction
        self.update(self._pyocd_phase, round(fraction * self.total))


# ---------------------------------------------------------------------------- pyOCD


def _import_pyocd():
    try:
        from pyocd.core import exceptions
        from pyocd.core.helpers import ConnectHelper
        from pyocd.flash.loader import MemoryLoader
    except ImportError as exc:
        if (exc.name or "").split(".")[0] == "pyocd":
            raise SwdError(f"pyOCD is not installed: {_INSTALL_PYOCD} (or flash with --method openocd)") from None
        raise SwdError(f"pyOCD cannot be loaded ({exc}): reinstall it with {_INSTALL_PYOCD}") from None
    return ConnectHelper, MemoryLoader, exceptions


def _flash_pyocd(image: FirmwareImage, target: str, probe: Optional[str], verify: bool, dry_run: bool,
                 phases: _Phases) -> str:
    ConnectHelper, MemoryLoader, exceptions = _import_pyocd()
    try:
        probes = ConnectHelper.get_all_connected_probes(blocking=False, unique_id=probe, print_wait_message=False)
    except Exception as exc:
        raise SwdError(_describe_pyocd_error(exc, exceptions, target)) from None
    if not probes:
        what = f"no debug probe with id {probe} found" if probe else "no debug probe found"
        raise SwdError(f"{what}: {_NO_PROBE_HINT.format(tool='pyocd list')}")
    if len(probes) > 1:
        ids = ", ".join(f"{p.unique_id} ({p.description})" for p in probes)
        raise SwdError(f"{len(probes)} debug probes are connected ({ids}): choose one with --probe ID")
    chosen = probes[0]
    through = f"{target} through {chosen.description} {chosen.unique_id}"
    try:
        session = ConnectHelper.session_with_chosen_probe(
            blocking=False, return_first=True, unique_id=chosen.unique_id, target_override=target,
            connect_mode="attach" if dry_run else "halt", options={"hide_programming_progress": True})
        if session is None:
            raise SwdError(f"the debug probe {chosen.unique_id} went away: plug it in again")
        with session:
            chip = session.target
            _check_in_flash(image, chip.memory_map, target)
            if dry_run:
                return f"dry run: would write {describe_segments(image)} to {through}; nothing written"
            loader = MemoryLoader(session, progress=phases.pyocd_fraction, chip_erase="sector")
            for segment in image.segments:
                loader.add_data(segment.address, list(segment.data))
            loader.commit()
            phases.finish("erase", "write")
            if verify:
                _verify_pyocd(chip, image, phases)
            chip.reset()
    except SwdError:
        raise
    except Exception as exc:  # pyOCD's errors, and the USB library's beneath it
        raise SwdError(_describe_pyocd_error(exc, exceptions, target)) from None
    return f"wrote {describe_segments(image)} to {through}{', verified' if verify else ''}; reset, running"


def _check_in_flash(image: FirmwareImage, memory_map, target: str) -> None:
    """Every byte of the image must go to flash: anything else is an image for another chip."""
    for segment in image.segments:
        address = segment.address
        while address < segment.end:
            region = memory_map.get_region_for_address(address)
            if region is None or not region.is_flash:
                raise SwdError(f"the image has bytes at {address:#010x}, which is not flash on {target}: "
                               "is it built for this chip?")
            address = region.start + region.length


def _verify_pyocd(chip, image: FirmwareImage, phases: _Phases) -> None:
    checked = 0
    for segment in image.segments:
        for offset in range(0, len(segment.data), VERIFY_CHUNK):
            want = segment.data[offset:offset + VERIFY_CHUNK]
            address = segment.address + offset
            got = bytes(chip.read_memory_block8(address, len(want)))
            if got != want:
                at = next(i for i in range(len(want)) if i >= len(got) or got[i] != want[i])
                was = f"{got[at]:#04x}" if at < len(got) else "nothing"
                raise SwdError(f"verify failed at address {address + at:#010x}: the flash holds {was} where the "
                               f"image has {want[at]:#04x} (flash protected or worn? flash again, or erase the chip)")
            checked += len(want)
            phases.update("verify", checked)
    phases.finish("verify")


def _describe_pyocd_error(exc: Exception, exceptions, target: str) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    lowered = text.lower()
    if "not recognized" in lowered and "target" in lowered:
        return (f"pyOCD does not know the target {target}: install its pack once with `pyocd pack install "
                f"{target}`, then give the name `pyocd pack find {target}` shows (e.g. {target}tx) with --target")
    if any(word in lowered for word in ("access denied", "permission", "libusb_error_access", "insufficient")):
        return _NO_ACCESS
    if isinstance(exc, exceptions.ProbeDisconnected):
        return f"the debug probe disconnected ({text}): check its USB cable and plug it in again"
    if isinstance(exc, exceptions.FlashFailure):
        address = getattr(exc, "address", None)
        where = f" at {address:#010x}" if isinstance(address, int) else ""
        return (f"writing the flash failed{where}: {text} "
                "(is the flash read- or write-protected in the option bytes?)")
    if isinstance(exc, (exceptions.TransferError, exceptions.TimeoutError)) or any(
            word in lowered for word in ("no ack", "idcode", "no device connected", "debug power")):
        return f"{_NOT_RESPONDING} [{text}]"
    if isinstance(exc, exceptions.ProbeError):
        return f"the debug probe failed: {text}"
    return f"pyOCD: {text}"


# ---------------------------------------------------------------------------- OpenOCD


def openocd_config(name: str, kind: str) -> str:
    """The config file OpenOCD is given for an interface or target name: a path or a name
    ending in .cfg is used as it is; an interface name `x` means interface/x.cfg; a chip
    name like stm32f407vg means its family's target/stm32f4x.cfg."""
    if name.endswith(".cfg") or "/" in name or "\\" in name:
        return name
    if kind == "interface":
        return f"interface/{name}.cfg"
    family = re.fullmatch(r"stm32([a-z]+[0-9])[0-9a-z]*", name.lower())
    if family is None:
        raise SwdError(f"no OpenOCD target config known for {name!r}: give one, e.g. --target target/stm32f4x.cfg")
    return f"target/stm32{family.group(1)}x.cfg"


def intel_hex(segments) -> str:
    """The segments as Intel HEX text: 16-byte data records, an extended linear address
    record wherever the upper 16 address bits change, the end-of-file record."""
    lines = []
    upper = None

    def record(kind: int, address: int, payload: bytes) -> None:
        body = bytes([len(payload), (address >> 8) & 0xFF, address & 0xFF, kind]) + payload
        lines.append(":" + (body + bytes([-sum(body) & 0xFF])).hex().upper())

    for segment in segments:
        offset = 0
        while offset < len(segment.data):
            address = segment.address + offset
            if address >> 16 != upper:
                upper = address >> 16
                record(0x04, 0, upper.to_bytes(2, "big"))
            size = min(16, len(segment.data) - offset, 0x10000 - (address & 0xFFFF))
            record(0x00, address & 0xFFFF, segment.data[offset:offset + size])
            offset += size
    record(0x01, 0, b"")
    return "\n".join(lines) + "\n"


def _flash_openocd(image: FirmwareImage, target: str, probe: Optional[str], verify: bool, dry_run: bool,
                   phases: _Phases, interface: str, remote: Optional[RemoteProbe] = None) -> str:
    if remote is None:
        executable = shutil.which("openocd")
        if executable is None:
            raise SwdError("openocd is not on the PATH: install it (Debian/Ubuntu: apt install openocd) "
                           f"or flash with --method pyocd ({_INSTALL_PYOCD})")
    else:
        executable = "openocd"  # the probe's machine finds it on its own PATH
    interface_cfg, target_cfg = openocd_config(interface, "interface"), openocd_config(target, "target")
    command = [executable, "-f", interface_cfg]
    if probe is not None:
        command += ["-c", f"adapter serial {probe}"]
    if remote is not None and remote.usb_path:
        if not re.fullmatch(r"[0-9]+-[0-9.]+", remote.usb_path):
            raise SwdError(f"{remote.describe()}: {remote.usb_path!r} is not a USB path (BUS-PORT[.PORT...])")
        # the probe among those of its machine, by where it is plugged in: labgrid's own selection
        command += ["-c", f"adapter usb location {remote.usb_path}"]
    command += ["-f", target_cfg]
    through = f"{target} with openocd ({interface_cfg}, {target_cfg})"
    if remote is not None:
        through += f" through the {remote.describe()}"

    def run(argv: list[str]) -> tuple[int, list[str]]:
        return _run_openocd(argv if remote is None else remote.command(argv), phases)

    if dry_run:
        code, lines = run(command + ["-c", "shutdown"])
        if code != 0:
            raise SwdError(_describe_openocd_failure(lines, code, probe, remote))
        return f"dry run: would write {describe_segments(image)} to {through}; nothing written, no probe contacted"
    with tempfile.TemporaryDirectory(prefix="imulink-flash-") as folder:
        hex_file = Path(folder) / "image.hex"
        hex_file.write_text(intel_hex(image.segments), encoding="ascii")
        programmed = str(hex_file) if remote is None else remote.stage(str(hex_file))
        steps = "verify reset exit" if verify else "reset exit"
        code, lines = run(command + ["-c", f"program {_tcl_word(programmed)} {steps}"])
    missing = [banner for banner, wanted in (("** Programming Finished **", True), ("** Verified OK **", verify))
               if wanted and banner not in lines]
    if code != 0 or missing:
        raise SwdError(_describe_openocd_failure(lines, code, probe, remote))
    return f"wrote {describe_segments(image)} to {through}{', verified' if verify else ''}; reset, running"


def _tcl_word(path: str) -> str:
    """A path as one word of an OpenOCD (Tcl) command line."""
    text = path.replace("\\", "/")  # OpenOCD on Windows takes forward slashes too
    if any(c in text for c in "{}"):
        raise SwdError(f"the temporary folder {text} has braces in its name: set TMPDIR to another folder")
    return "{" + text + "}"


#: OpenOCD's banners (src/flash/startup.tcl) -> the progress they mean.
_OPENOCD_BANNERS = {
    "** Programming Started **": lambda phases: phases.update("erase", 0),
    "** Programming Finished **": lambda phases: phases.finish("erase", "write"),
    "** Verify Started **": lambda phases: phases.update("verify", 0),
    "** Verified OK **": lambda phases: phases.finish("verify"),
}


def _run_openocd(command: list[str], phases: _Phases) -> tuple[int, list[str]]:
    """Run OpenOCD, turning its banners into progress as they come; its exit code and output lines."""
    try:
        process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, text=True, errors="replace")
    except OSError as exc:
        raise SwdError(f"cannot run {command[0]}: {exc.strerror or exc}") from None
    stdout = process.stdout
    assert stdout is not None  # stdout=PIPE
    timed_out = threading.Event()

    def kill() -> None:
        timed_out.set()
        process.kill()

    watchdog = threading.Timer(OPENOCD_TIMEOUT_S, kill)
    watchdog.start()
    lines: list[str] = []
    try:
        for line in stdout:
            line = line.strip()
            lines.append(line)
            if line in _OPENOCD_BANNERS:
                _OPENOCD_BANNERS[line](phases)
        code = process.wait()
    finally:
        watchdog.cancel()
        if process.poll() is None:
            process.kill()
            process.wait()
        stdout.close()
    if timed_out.is_set():
        raise SwdError(f"openocd did not finish within {OPENOCD_TIMEOUT_S:g} s and was stopped "
                       f"(last said: {_last_words(lines)}): unplug the probe, plug it in and try again")
    return code, lines


def _last_words(lines: list[str]) -> str:
    errors = [line for line in lines if line.startswith("Error")]
    chosen = errors[-1] if errors else next((line for line in reversed(lines) if line), "nothing")
    return re.sub(r"^Error:\s*", "", chosen)


def _describe_openocd_failure(lines: list[str], code: int, probe: Optional[str],
                              remote: Optional[RemoteProbe] = None) -> str:
    """One line for what went wrong, from OpenOCD's own messages (and, for a probe on another
    machine, the shell's and ssh's there)."""
    text = "\n".join(lines)
    if remote is not None and code == 127:  # the shell of the probe's machine found no openocd
        return (f"openocd is not installed on {remote.host}, where it runs for the place's debug probe: install it "
                f"there (Debian/Ubuntu: apt install openocd) [{_last_words(lines)}]")
    if remote is not None and code == 255:  # ssh's own status: the connection failed, not openocd
        return f"the connection to {remote.host} failed while openocd ran there: {_last_words(lines)}"
    missing = re.search(r"Can't find (\S+)", text)
    if missing:
        return (f"openocd has no config file {missing.group(1)}: check the name (its scripts folder, "
                "e.g. /usr/share/openocd/scripts, lists them) or give the path of a .cfg file")
    if "LIBUSB_ERROR_ACCESS" in text or "permission denied" in text.lower():
        return _NO_ACCESS
    if probe is not None and ("serial mismatch" in text or "No device matches the serial" in text
                              or "open failed" in text):
        return f"no debug probe with serial {probe} found: check the id, or plug that probe in"
    if any(s in text for s in ("open failed", "unable to find a matching CMSIS-DAP device", "No J-Link device found",
                               "Can't find a KitProg device", "unable to open ftdi device")):
        if remote is not None:
            return (f"openocd on {remote.host} found no probe at USB {remote.usb_path}, where the place's debug "
                    "probe was: is it plugged in there, and is --interface its kind of probe?")
        return f"no debug probe found: {_NO_PROBE_HINT.format(tool='lsusb')}"
    if "target voltage may be too low" in text:
        volts = re.search(r"Target voltage: ([0-9.]+)", text)
        reading = f" (the probe reads {float(volts.group(1)):.2f} V)" if volts else ""
        return (f"the target has no power{reading}: power the board and wire the probe's target-voltage pin "
                "(VAPP/3V3) to the board's 3.3 V")
    if any(s in text for s in ("init mode failed", "Error connecting DP", "invalid mode value",
                               "** Unable to reset target **")):
        return _NOT_RESPONDING
    if "** Verify Failed **" in text:
        diff = re.search(r"diff \d+ address (0x[0-9a-fA-F]+)\. Was (0x[0-9a-fA-F]+) instead of (0x[0-9a-fA-F]+)", text)
        if diff:
            return (f"verify failed at address {int(diff.group(1), 16):#010x}: the flash holds "
                    f"{int(diff.group(2), 16):#04x} where the image has {int(diff.group(3), 16):#04x} "
                    "(flash protected or worn? flash again, or erase the chip)")
        return "verify failed: the flash does not hold the image (flash again, or erase the chip)"
    if "** Programming Failed **" in text:
        if "device protected" in text:
            return ("writing the flash failed: the chip is read-protected; OpenOCD's `stm32f2x unlock 0` "
                    "removes the protection (and erases the whole flash), then power-cycle the board")
        unmapped = re.search(r"no flash bank found for address (0x[0-9a-fA-F]+)", text)
        if unmapped:
            return (f"the image has bytes at {int(unmapped.group(1), 16):#010x}, which is not flash on this target: "
                    "is it built for this chip?")
        return f"writing the flash failed: {_last_words(lines)}"
    if "** OpenOCD init failed **" in text:
        return f"openocd could not connect to the probe or the target: {_last_words(lines)}"
    if code == 0:
        return f"openocd ended without finishing the job (last said: {_last_words(lines)})"
    return f"openocd failed (exit status {code}): {_last_words(lines)}"
