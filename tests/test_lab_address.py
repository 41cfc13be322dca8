"""lg://PLACE and lg-env:FILE addresses without a farm: what is checked before labgrid is asked
anything, the one line a machine without labgrid gets, and labgrid environments whose board is a
serial port of this machine (tests/test_farm.py has the farm itself, and an environment's
RemotePlace)."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from imulink.board import lab
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Link, PortError

IMULINK = [sys.executable, "-m", "imulink.cli"]


@pytest.mark.parametrize("address, expected", [
    ("lg://imu-1", ("imu-1", None)),
    ("lg://imu-1/console", ("imu-1", "console")),
])
def test_a_place_address_names_a_place_and_maybe_its_port(address, expected):
    assert lab.is_place(address)
    assert lab.parse_place(address) == expected


@pytest.mark.parametrize("address", ["lg://", "lg:///port", "lg://a/b/c", "lg://imu-*"])
def test_a_malformed_place_address_is_refused(address):
    with pytest.raises(lab.LabError, match="not a place address"):
        lab.parse_place(address)


@pytest.mark.parametrize("address", ["/dev/ttyACM0", "socket://127.0.0.1:5760", "rfc2217://h:1", None])
def test_other_ports_are_not_places(address):
    assert not lab.is_place(address)


def test_the_coordinator_follows_labgrid_s_convention(monkeypatch):
    monkeypatch.delenv("LG_COORDINATOR", raising=False)
    assert lab.coordinator_address() == lab.DEFAULT_COORDINATOR
    monkeypatch.setenv("LG_COORDINATOR", "lab.example:20408")
    assert lab.coordinator_address() == "lab.example:20408"
    assert lab.coordinator_address("10.0.0.1:1") == "10.0.0.1:1"


def test_a_link_does_not_open_a_place_by_itself():
    with pytest.raises(PortError, match="labgrid place is acquired first"):
        Link("lg://imu-1")


def test_a_malformed_place_is_one_line_before_labgrid_is_needed(tmp_path):
    done = subprocess.run([*IMULINK, "record", "lg://imu-*", "-o", str(tmp_path / "r.imulog")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "imulink: error: 'lg://imu-*' is not a place address: use lg://PLACE or lg://PLACE/RESOURCE"]


@pytest.mark.skipif(importlib.util.find_spec("labgrid") is not None, reason="labgrid is installed here")
@pytest.mark.parametrize("command", [["settings", "lg://imu-1"], ["farm", "verify", "--places", "imu-*"],
                                     ["settings", "lg-env:env.yaml"]])
def test_without_labgrid_a_place_names_the_extra_to_install(command):
    done = subprocess.run([*IMULINK, *command], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'imulink[lab]'" in lines[0], done.stderr


@pytest.mark.parametrize("address, expected", [
    ("lg-env:env.yaml", ("env.yaml", "main")),
    ("lg-env:/lab/env.yaml#imu", ("/lab/env.yaml", "imu")),
    ("lg-env:a#b.yaml#imu", ("a#b.yaml", "imu")),
])
def test_an_environment_address_names_a_file_and_its_target(address, expected):
    assert lab.is_environment(address) and not lab.is_place(address)
    assert lab.parse_environment(address) == expected


@pytest.mark.parametrize("address", ["lg-env:", "lg-env:#main", "lg-env:env.yaml#"])
def test_a_malformed_environment_address_is_refused(address):
    with pytest.raises(lab.LabError, match="not a labgrid environment address"):
        lab.parse_environment(address)


needs_labgrid = pytest.mark.skipif(
    importlib.util.find_spec("labgrid") is None and not os.environ.get("IMULINK_REQUIRE_LABGRID"),
    reason="labgrid is not installed (pip install 'imulink[lab]'; `make test-farm` runs these tests)")


def _imulink(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("LG_")}
    return subprocess.run([*IMULINK, *args], capture_output=True, text=True, timeout=60, cwd=cwd, env=env)


@pytest.fixture(scope="module")
def native_board() -> Iterator[EmulatedBoard]:
    board = EmulatedBoard("native", front="pty", duration_s=5.0, filter_name="eskf").start()
    try:
        yield board
    finally:
        board.stop()


@needs_labgrid
def test_an_environment_s_raw_serial_port_is_the_board(native_board, tmp_path):
    """An environment whose target has a RawSerialPort (the emulated board's pty, a USB serial
    adapter's device in a lab): `lg-env:FILE` is that port, no coordinator asked."""
    (tmp_path / "env.yaml").write_text(
        "targets:\n  main:\n    resources:\n      RawSerialPort:\n"
        f"        port: {native_board.address}\n        speed: 921600\n"
        "options:\n  coordinator_address: 127.0.0.1:1\n")  # never asked: a port needs no coordinator
    done = _imulink("settings", "lg-env:env.yaml", "--json", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["filter"] == "eskf"
    assert done.stderr.splitlines() == [
        f"imulink: labgrid environment env.yaml, target main: RawSerialPort at {native_board.address}"]


@needs_labgrid
def test_an_environment_s_network_serial_port_is_the_board(tmp_path):
    """A NetworkSerialPort (raw TCP: socket://) of a target named in the address."""
    board = EmulatedBoard("native", front="tcp", duration_s=5.0, filter_name="eskf").start()
    try:
        assert board.address is not None
        host, port = board.address.removeprefix("socket://").split(":")
        (tmp_path / "env.yaml").write_text(
            "targets:\n  main:\n    resources: {}\n  imu:\n    resources:\n      NetworkSerialPort:\n"
            f"        host: {host}\n        port: {port}\n        protocol: raw\n")
        done = _imulink("record", "lg-env:env.yaml#imu", "-o", str(tmp_path / "run.imulog"), "--duration", "1",
                        cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        assert done.stderr.splitlines()[0] == (
            f"imulink: labgrid environment env.yaml, target imu: NetworkSerialPort at {board.address}")
        compared = _imulink("compare", str(tmp_path / "run.imulog"), cwd=tmp_path)
        assert compared.returncode == 0, compared.stdout + compared.stderr
    finally:
        board.stop()


@needs_labgrid
def test_the_board_fixture_takes_labgrid_s_environment(native_board, tmp_path):
    """A project's HIL tests with $LG_ENV set (as labgrid's own pytest plugin takes it) get the
    environment's board."""
    from test_board_fixture import run_project_tests

    (tmp_path / "env.yaml").write_text(
        f"targets:\n  main:\n    resources:\n      RawSerialPort: {{port: {native_board.address}}}\n")
    env = {k: v for k, v in os.environ.items() if k not in ("LG_PLACE", "IMULINK_BOARD", "IMULINK_IMAGE")}
    done = run_project_tests(tmp_path, env={**env, "LG_ENV": str(tmp_path / "env.yaml")})
    assert done.returncode == 0, done.stdout + done.stderr
    assert "BOARD place=None target=None" in done.stdout


ENVIRONMENTS = {
    "bad.yaml": "targets:\n  main: [\n",
    "power.yaml": ("targets:\n  main:\n    resources:\n      NetworkPowerPort: {model: gude, host: pdu-1, index: 3}\n"
                   "  spare:\n    resources: {}\n"),
}


@needs_labgrid
@pytest.mark.parametrize("address, line", [
    ("lg-env:missing.yaml", "labgrid environment missing.yaml: no such file"),
    ("lg-env:bad.yaml", "labgrid environment bad.yaml is not valid YAML: while parsing a flow node expected the "
                        "node content, but found '<stream end>' in \"bad.yaml\", line 3, column 1"),
    ("lg-env:power.yaml#imu", "labgrid environment power.yaml has no target 'imu' (its targets: main, spare); name "
                              "one, lg-env:power.yaml#TARGET"),
    ("lg-env:power.yaml", "labgrid environment power.yaml, target main: imulink needs a RemotePlace or a serial port "
                          "(RawSerialPort, NetworkSerialPort, USBSerialPort); it has NetworkPowerPort"),
    ("lg-env:power.yaml#spare", "labgrid environment power.yaml, target spare: imulink needs a RemotePlace or a "
                                "serial port (RawSerialPort, NetworkSerialPort, USBSerialPort); it has no resources"),
])
def test_an_environment_without_a_board_is_one_line(tmp_path, address, line):
    for name, text in ENVIRONMENTS.items():
        (tmp_path / name).write_text(text)
    done = _imulink("settings", address, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [f"imulink: error: {line}"]
