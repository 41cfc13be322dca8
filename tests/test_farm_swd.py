"""`imulink flash IMAGE lg://PLACE --method openocd`: a place's debug probe, with no hardware.

A coordinator and an exporter start on this machine (as in tests/test_farm.py). The exporter
publishes NetworkUSBDebugger resources, what an exporter publishes for a USBDebugger (a probe
on its USB, found through udev: there is none here), with the same parameters: the exporter's
host, the probe's USB bus path there, its ids.

labgrid runs a probe's tools on the exporter's host through ssh (NetworkResource.command_prefix:
its own SSH connection manager, with a control master and a keepalive), and copies the files
they read there (ManagedFile). This machine has no SSH server, so a stand-in `ssh` (FAKE_SSH)
is first on the PATH of imulink: every host is this machine, as for an exporter on the
client's own machine reached through its sshd. It answers labgrid's control-master requests,
runs each command it is given on "the exporter's host" with that host's PATH (a folder with
the fake openocd of tests/test_swd.py, or without it, and the few tools labgrid runs there),
and refuses the hosts named unreachable as ssh does. Since the host shares this machine's files,
labgrid's ManagedFile sees the image's file there (it compares stat output on both sides) and
copies nothing: its copy into /var/cache/labgrid with rsync is not run here.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

# test_farm first: without labgrid it skips (or, in `make test-farm`, fails) this module too
from test_farm import BIN, COMMAND_TIMEOUT_S, IMULINK_CTRL_C, Lab, _wait_for, imulink, running  # isort: skip

from imulink.board import lab
from imulink.board.emulator import EmulatedBoard
from imulink.board.flash import swd
from imulink.io.firmware_image import load_image
from test_swd import FAKE_OPENOCD

pytestmark = [pytest.mark.xdist_group("takes-a-core"),
              pytest.mark.skipif(os.name == "nt", reason="the stand-ins are #! scripts")]

ROOT = Path(__file__).resolve().parents[1]
ELF = ROOT / "firmware" / "build" / "stm32f407" / "imulink-stm32f407-gy86.elf"
#: The probe's host as its exporter publishes it, and one that ssh cannot reach.
PROBE_HOST = "probe-host"
UNREACHABLE_HOST = "unreachable-host"
#: The probe's USB path on its host (what udev calls the device: bus 1, hub port 3, port 2).
USB_PATH = "1-3.2"

FAKE_SSH = '''
"""A stand-in for ssh whose every host is this machine (see tests/test_farm_swd.py)."""
import json, os, shlex, sys

args = sys.argv[1:]
TAKES_VALUE = {"-b", "-c", "-D", "-E", "-e", "-F", "-I", "-i", "-J", "-L", "-l", "-m", "-O", "-o", "-p", "-Q", "-R",
               "-S", "-W", "-w"}
control_command = control_path = host = None
i = 0
while host is None and i < len(args):  # ssh's options, then the host, then the command
    arg = args[i]
    if arg in TAKES_VALUE:
        if arg == "-O":
            control_command = args[i + 1]
        elif arg == "-o" and args[i + 1].startswith("ControlPath="):
            control_path = args[i + 1].split("=", 1)[1]
        i += 2
    elif arg.startswith("-"):
        i += 1
    else:
        host = arg
        i += 1
remote = args[i:]
if remote[:1] == ["--"]:
    remote = remote[1:]
with open(os.environ["FAKE_SSH_LOG"], "a") as log:
    log.write(json.dumps({"host": host, "control": control_command, "command": remote}) + "\\n")
if control_command == "check":  # no master of the user's own: labgrid starts one
    print("Control socket connect(" + str(control_path) + "): No such file or directory", file=sys.stderr)
    sys.exit(255)
if control_command is not None:  # cancel, exit: the master's end
    sys.exit(0)
if host in os.environ.get("FAKE_SSH_UNREACHABLE", "").split(","):
    print("ssh: Could not resolve hostname " + host + ": Name or service not known", file=sys.stderr)
    sys.exit(255)
if not remote:  # the master (-MN): labgrid looks for its control socket
    open(control_path, "w").close()
    sys.exit(0)
# the command line as the host's shell splits it, run with the host's PATH
words = shlex.split(" ".join(remote))
env = {**os.environ, "PATH": os.environ["FAKE_SSH_HOST_PATH"]}
try:
    os.execvpe(words[0], words, env)
except FileNotFoundError:
    print("sh: 1: " + words[0] + ": not found", file=sys.stderr)
    sys.exit(127)
'''


def _probe(host: str, path: str, name: str | None = None) -> str:
    """A NetworkUSBDebugger as an exporter publishes a USBDebugger (an ST-Link V2-1 here), named
    `name` or by its class."""
    head = f"  {name}:\n    cls: NetworkUSBDebugger\n" if name else "  NetworkUSBDebugger:\n"
    return (f"{head}    host: {host}\n    busnum: 1\n    devnum: 7\n    path: '{path}'\n"
            "    vendor_id: 0x0483\n    model_id: 0x374b\n")


class ProbeLab:
    """A coordinator and exporter `swd-rack` with places swd-1 (a probe), swd-linked (a probe and
    the serial port of `board`, the virtual reference board running the reference image),
    swd-pair (two probes, probe-a and probe-b), swd-far (a probe whose host ssh cannot reach)
    and swd-serial-only (a serial port, no probe); the stand-in ssh and the probe host's PATH
    (`host_bin`: the fake openocd; `tools`: what labgrid runs there)."""

    def __init__(self, directory: Path, board: EmulatedBoard):
        self.dir = directory
        self.farm = Lab(directory)
        try:
            self._export(board)
            self._stand_ins()
        except BaseException:  # the coordinator and the exporter would outlive the tests
            self.farm.stop()
            raise

    def _stand_ins(self) -> None:
        """The stand-in ssh, and the probe host's PATH: the fake openocd and the tools labgrid uses."""
        directory = self.dir
        self.client_bin, self.host_bin, self.tools = (directory / name for name in ("client-bin", "host-bin", "tools"))
        for folder in (self.client_bin, self.host_bin, self.tools):
            folder.mkdir()
        ssh, openocd = self.client_bin / "ssh", self.host_bin / "openocd"
        ssh.write_text(f"#!{sys.executable}\n{FAKE_SSH}")
        openocd.write_text(FAKE_OPENOCD.format(python=sys.executable))
        for script in (ssh, openocd):
            script.chmod(0o755)
        for tool in ("cat", "stat"):  # labgrid's keepalive and its look for a shared file
            found = shutil.which(tool)
            assert found is not None, tool
            (self.tools / tool).symlink_to(found)
        self.ssh_log, self.openocd_log = directory / "ssh.jsonl", directory / "openocd.jsonl"
        self.programmed = directory / "programmed.hex"

    def _export(self, board: EmulatedBoard) -> None:
        """The exporter of the probes and serial ports, and the places."""
        directory = self.dir
        host, port = str(board.address).removeprefix("socket://").split(":")
        config = directory / "swd-rack.yaml"
        config.write_text(f"probe-1:\n{_probe(PROBE_HOST, USB_PATH)}far-probe:\n{_probe(UNREACHABLE_HOST, '2-1')}"
                          f"linked:\n{_probe(PROBE_HOST, '1-4')}"
                          f"  NetworkSerialPort: {{host: {host}, port: {port}, speed: 921600, protocol: raw}}\n"
                          f"pair:\n{_probe(PROBE_HOST, '1-5', 'probe-a')}{_probe(PROBE_HOST, '1-6', 'probe-b')}"
                          "serial-only:\n  NetworkSerialPort: {host: 127.0.0.1, port: 9, speed: 921600, "
                          "protocol: raw}\n")
        self.farm._start("exporter-swd", [str(BIN / "labgrid-exporter"), "-c", self.farm.address, "-n", "swd-rack",
                                          "--hostname", "127.0.0.1", str(config)])

        exported = {"probe-1": {"NetworkUSBDebugger"}, "far-probe": {"NetworkUSBDebugger"},
                    "linked": {"NetworkUSBDebugger", "NetworkSerialPort"}, "pair": {"probe-a", "probe-b"},
                    "serial-only": {"NetworkSerialPort"}}

        def published() -> bool:  # every resource: a group is there as soon as its first one is
            with lab.Coordinator(self.farm.address) as session:
                groups = session.session.resources.get("swd-rack", {})
                return {group: set(resources) for group, resources in groups.items()} == exported
        _wait_for(published, 30, "the exporter did not publish its probes")
        self.farm.places({"swd-1": ("swd-rack/probe-1/NetworkUSBDebugger", {}),
                          "swd-far": ("swd-rack/far-probe/NetworkUSBDebugger", {}),
                          "swd-linked": (["swd-rack/linked/NetworkUSBDebugger", "swd-rack/linked/NetworkSerialPort"],
                                         {}),
                          "swd-pair": ("swd-rack/pair/NetworkUSBDebugger", {}),
                          "swd-serial-only": ("swd-rack/serial-only/NetworkSerialPort", {})})

    def env(self, openocd_mode: str = "ok", openocd_installed: bool = True) -> dict[str, str]:
        """imulink's environment: the stand-in ssh first on its PATH, the probe host's PATH with or
        without openocd, the fake openocd's behaviour; the logs and the programmed file emptied."""
        for path in (self.ssh_log, self.openocd_log, self.programmed):
            path.unlink(missing_ok=True)
        host_path = [str(self.host_bin)] if openocd_installed else []
        return {**self.farm.env, "PATH": f"{self.client_bin}{os.pathsep}{self.farm.env['PATH']}",
                "FAKE_SSH_LOG": str(self.ssh_log), "FAKE_SSH_UNREACHABLE": UNREACHABLE_HOST,
                "FAKE_SSH_HOST_PATH": os.pathsep.join([*host_path, str(self.tools)]),
                "FAKE_OPENOCD_LOG": str(self.openocd_log), "FAKE_OPENOCD_OUT": str(self.programmed),
                "FAKE_OPENOCD_MODE": openocd_mode}

    def openocd_calls(self) -> list[list[str]]:
        return [json.loads(line) for line in self.openocd_log.read_text().splitlines()] \
            if self.openocd_log.exists() else []

    def remote_commands(self) -> list[tuple[str, list[str]]]:
        """(host, command) of every command ssh was asked to run on a host."""
        calls = [json.loads(line) for line in self.ssh_log.read_text().splitlines()] if self.ssh_log.exists() else []
        return [(call["host"], call["command"]) for call in calls if call["control"] is None and call["command"]]

    def assert_released(self) -> None:
        with lab.Coordinator(self.farm.address) as session:
            held = {p.name: p.acquired for p in session.places("swd-*")}
        assert all(holder is None for holder in held.values()), held


@pytest.fixture(scope="module")
def probe_lab(tmp_path_factory):
    if not ELF.exists():
        pytest.fail(f"{ELF} is missing: `make setup` builds it")
    # in real time, as a real board is: it only has to answer the HELLO after the flash
    board = EmulatedBoard("stm32f407", front="tcp", duration_s=5.0, filter_name="eskf", realtime=True).start()
    the_lab = None
    try:
        the_lab = ProbeLab(tmp_path_factory.mktemp("swd"), board)
        yield the_lab
    finally:
        if the_lab is not None:
            the_lab.farm.stop()
        board.stop()


def _one_error_line(done: subprocess.CompletedProcess, *words: str) -> str:
    assert done.returncode == 2, done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("imulink: ")
              and not line.startswith("imulink: place ")]
    assert len(errors) == 1 and errors[0].startswith("imulink: error: "), done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    for word in words:
        assert word in errors[0], errors[0]
    return errors[0]


def _bytes_by_address(segments) -> dict[int, int]:
    return {segment.address + offset: byte for segment in segments for offset, byte in enumerate(segment.data)}


def test_flash_through_a_place_s_probe(probe_lab, tmp_path):
    """The place is acquired for its probe; openocd runs on the probe's host (through ssh, as
    labgrid runs it) with the interface and target configs, the probe's USB path, and a HEX
    file of exactly the ELF's loadable bytes to program, verify and reset; the place is released."""
    env = probe_lab.env()
    done = imulink("flash", str(ELF), "lg://swd-1", "--method", "openocd", env=env)
    assert done.returncode == 0, done.stderr
    assert (f"imulink: place swd-1 acquired from {probe_lab.farm.address}: its debug probe NetworkUSBDebugger on "
            f"{PROBE_HOST} (USB {USB_PATH})") in done.stderr
    assert f"through the debug probe NetworkUSBDebugger on {PROBE_HOST} (USB {USB_PATH}), verified" in done.stderr
    assert done.stdout.startswith(f"flashed {load_image(ELF).size} bytes over openocd"), done.stdout
    assert ", verified; started (no --link port to check its HELLO)" in done.stdout, done.stdout

    [args] = probe_lab.openocd_calls()
    assert args[:6] == ["-f", "interface/stlink.cfg", "-c", f"adapter usb location {USB_PATH}",
                        "-f", "target/stm32f4x.cfg"]
    assert args[6] == "-c" and args[7].startswith("program {") and args[7].endswith("} verify reset exit")
    assert len(args) == 8, args
    hosts = {host for host, _ in probe_lab.remote_commands()}
    openocd_runs = [command for _, command in probe_lab.remote_commands() if command[0] == "openocd"]
    assert hosts == {PROBE_HOST} and len(openocd_runs) == 1, probe_lab.remote_commands()

    # what openocd was given is the ELF's loadable bytes, no more, no fewer (as imulink reads
    # the ELF, and as binutils does)
    programmed = load_image(probe_lab.programmed)
    assert programmed.segments == load_image(ELF).segments
    objcopy = shutil.which("arm-none-eabi-objcopy")
    assert objcopy is not None, "arm-none-eabi-objcopy (make setup installs it)"
    reference = tmp_path / "objcopy.hex"
    subprocess.run([objcopy, "-O", "ihex", str(ELF), str(reference)], check=True, timeout=60)
    assert _bytes_by_address(programmed.segments) == _bytes_by_address(load_image(reference).segments)
    probe_lab.assert_released()

    dry = imulink("flash", str(ELF), "lg://swd-1", "--method", "openocd", "--dry-run", "--no-verify", env=env)
    assert dry.returncode == 0 and "dry run: nothing written (openocd)" in dry.stdout, dry.stderr
    assert probe_lab.openocd_calls()[-1] == ["-f", "interface/stlink.cfg", "-c", f"adapter usb location {USB_PATH}",
                                             "-f", "target/stm32f4x.cfg", "-c", "shutdown"]
    probe_lab.assert_released()


def test_the_board_s_hello_on_the_place_s_serial_port(probe_lab):
    """A place with a probe and a serial port: after openocd's flash, the image's HELLO is asked
    for on the place's serial port (the virtual reference board, which runs that image)."""
    done = imulink("flash", str(ELF), "lg://swd-linked", "--method", "openocd", env=probe_lab.env())
    assert done.returncode == 0, done.stderr
    assert "(USB 1-4); the board's link socket://127.0.0.1:" in done.stderr, done.stderr
    assert ", verified; running: stm32f407-gy86 firmware" in done.stdout and "as built" in done.stdout, done.stdout
    [args] = probe_lab.openocd_calls()
    assert args[2:4] == ["-c", "adapter usb location 1-4"]
    probe_lab.assert_released()


def test_a_place_with_two_probes_names_one(probe_lab):
    """lg://PLACE/NAME picks the probe of that name (its USB path given to openocd); without
    NAME, a place with two probes is one line that lists them."""
    _one_error_line(imulink("flash", str(ELF), "lg://swd-pair", "--method", "openocd", env=probe_lab.env()),
                    "place swd-pair has several debug probes (probe-a, probe-b): name one, lg://swd-pair/NAME")
    assert probe_lab.openocd_calls() == []
    done = imulink("flash", str(ELF), "lg://swd-pair/probe-b", "--method", "openocd", env=probe_lab.env())
    assert done.returncode == 0, done.stderr
    [args] = probe_lab.openocd_calls()
    assert args[2:4] == ["-c", "adapter usb location 1-6"]
    probe_lab.assert_released()


@pytest.mark.parametrize("mode, expected", [
    ("verify-fail", "verify failed at address 0x08000004: the flash holds 0x00 where the image has 0xc1"),
    ("no-probe", f"openocd on {PROBE_HOST} found no probe at USB {USB_PATH}"),
])
def test_a_failing_flash_is_one_line_and_the_place_is_released(probe_lab, mode, expected):
    done = imulink("flash", str(ELF), "lg://swd-1", "--method", "openocd", env=probe_lab.env(mode))
    _one_error_line(done, expected)
    assert len(probe_lab.openocd_calls()) == 1
    probe_lab.assert_released()


def test_openocd_missing_on_the_probe_s_host(probe_lab):
    done = imulink("flash", str(ELF), "lg://swd-1", "--method", "openocd", env=probe_lab.env(openocd_installed=False))
    _one_error_line(done, f"openocd is not installed on {PROBE_HOST}", "install it there", "openocd: not found")
    assert probe_lab.openocd_calls() == []
    probe_lab.assert_released()


def test_a_probe_whose_host_cannot_be_reached(probe_lab):
    done = imulink("flash", str(ELF), "lg://swd-far", "--method", "openocd", env=probe_lab.env())
    _one_error_line(done, f"place swd-far: its debug probe NetworkUSBDebugger on {UNREACHABLE_HOST} (USB 2-1) cannot "
                          f"be reached: ssh: Could not resolve hostname {UNREACHABLE_HOST}", f"ssh {UNREACHABLE_HOST}")
    assert probe_lab.openocd_calls() == []
    probe_lab.assert_released()


def test_a_place_without_a_probe(probe_lab):
    """Said with the resources the place has, before anything is acquired."""
    done = imulink("flash", str(ELF), "lg://swd-serial-only", "--method", "openocd", env=probe_lab.env())
    _one_error_line(done, "place swd-serial-only has no debug probe (NetworkUSBDebugger",
                    "its resources: NetworkSerialPort/NetworkSerialPort", "add-match")
    assert probe_lab.remote_commands() == [] and probe_lab.openocd_calls() == []
    probe_lab.assert_released()


def test_pyocd_cannot_use_a_place_s_probe(probe_lab):
    done = imulink("flash", str(ELF), "lg://swd-1", "--method", "pyocd", env=probe_lab.env())
    assert _one_error_line(done) == f"imulink: error: {swd.PYOCD_REMOTE}"
    assert "acquired" not in done.stderr and probe_lab.openocd_calls() == []
    probe_lab.assert_released()


def test_ctrl_c_during_the_flash_releases_the_place(probe_lab):
    """Ctrl-C while openocd runs on the probe's host: openocd is stopped, the place released."""
    lines: list[str] = []
    with running("flash", str(ELF), "lg://swd-1", "--method", "openocd", env=probe_lab.env("hang"),
                 command=IMULINK_CTRL_C, stdout=subprocess.DEVNULL) as job:
        reader = threading.Thread(target=lambda: lines.extend(job.stderr), daemon=True)
        reader.start()
        _wait_for(probe_lab.programmed.exists, 60, "openocd did not start programming")
        job.send_signal(signal.SIGINT)
        job.wait(timeout=COMMAND_TIMEOUT_S)
        reader.join(timeout=COMMAND_TIMEOUT_S)
    err = "".join(lines)
    assert job.returncode == 130 and "imulink: interrupted" in err, err
    probe_lab.assert_released()
    fake_openocd = str(probe_lab.host_bin / "openocd").encode()
    still = [pid for pid in os.listdir("/proc") if pid.isdigit() and fake_openocd in _command_line(pid)]
    assert still == [], "openocd was left running"


def _command_line(pid: str) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:  # ended meanwhile
        return b""
