"""lg://PLACE addresses without a farm: what is checked before labgrid is asked anything, and
the one line a machine without labgrid gets (tests/test_farm.py has the farm itself)."""
from __future__ import annotations

import importlib.util
import subprocess
import sys

import pytest

from imulink.board import lab
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
@pytest.mark.parametrize("command", [["settings", "lg://imu-1"], ["farm", "verify", "--places", "imu-*"]])
def test_without_labgrid_a_place_names_the_extra_to_install(command):
    done = subprocess.run([*IMULINK, *command], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'imulink[lab]'" in lines[0], done.stderr
