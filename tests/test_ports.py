"""`imulink ports` (imulink.board.ports): the listing from pyserial's comports(), the adapter
guesses, the table, and probing: an emulated board on a pty answers, a pty nobody
reads stays silent and must be reported within the bound, a port in use is busy.
"""
from __future__ import annotations

import os
import threading
import time

import pytest
import serial
from serial.tools import list_ports as serial_ports
from serial.tools.list_ports_common import ListPortInfo

from imulink.board import ports
from imulink.board.emulator import EmulatedBoard


def fake_port(device: str, vid=None, pid=None, serial_number=None, description="n/a") -> ListPortInfo:
    port = ListPortInfo(device, skip_link_detection=True)
    port.vid, port.pid, port.serial_number, port.description = vid, pid, serial_number, description
    return port


@pytest.fixture
def comports(monkeypatch):
    """Replace pyserial's port list: call the fixture with the ports to report."""
    def install(*listed):
        monkeypatch.setattr(serial_ports, "comports", lambda *args, **kwargs: list(listed))
    return install


@pytest.mark.parametrize("vid, pid, kind", [
    (0x0483, 0x374B, "ST-Link/V2-1 virtual COM port"), (0x0483, 0x3752, "ST-Link/V2-1 virtual COM port"),
    (0x0483, 0x374E, "STLINK-V3 virtual COM port"), (0x0483, 0x3754, "STLINK-V3 virtual COM port"),
    (0x0483, 0x5740, "STM32 USB CDC (an STM32's own USB port)"), (0x10C4, 0xEA60, "Silicon Labs CP210x USB-UART"),
    (0x1A86, 0x7523, "WCH CH340 USB-UART"), (0x1A86, 0x55D4, "WCH CH9102 USB-UART"),
    (0x0403, 0x6001, "FTDI FT232R USB-UART"), (0x0403, 0x6015, "FTDI FT231X USB-UART"),
    (0x067B, 0x2303, "Prolific PL2303 USB-UART"), (0x0483, 0x1234, "STMicroelectronics USB device"),
    (0x2341, 0x0043, "USB serial device"), (None, None, "serial port (not USB)"),
])
def test_guesses(vid, pid, kind):
    assert ports.guess_kind(vid, pid) == kind


def test_listing_and_table(comports):
    comports(fake_port("/dev/ttyACM10", 0x0483, 0x374B, "0669FF555052836687031845", "STM32 STLink - ST-Link VCP Data"),
             fake_port("/dev/ttyUSB0", 0x10C4, 0xEA60, "0001", "CP2102 USB to UART Bridge Controller"),
             fake_port("/dev/ttyACM2", 0x0483, 0x5740, None, "STM32 Virtual ComPort"),
             fake_port("/dev/ttyS0"))
    listed = ports.list_ports()
    assert [p.device for p in listed] == ["/dev/ttyACM2", "/dev/ttyACM10", "/dev/ttyS0", "/dev/ttyUSB0"]
    stlink = listed[1]
    assert (stlink.usb_id, stlink.kind, stlink.serial_number) == ("0483:374B", "ST-Link/V2-1 virtual COM port",
                                                                  "0669FF555052836687031845")
    assert listed[2].usb_id is None and listed[2].description == "" and listed[2].answer is None
    table = ports.format_ports(listed).splitlines()
    assert table[0].split() == ["DEVICE", "USB", "ID", "WHAT", "SERIAL", "DESCRIPTION"]
    assert len(table) == 5 and "IMULINK" not in table[0]
    assert table[2].split()[:2] == ["/dev/ttyACM10", "0483:374B"] and "ST-Link VCP Data" in table[2]
    assert table[3].startswith("/dev/ttyS0") and "serial port (not USB)" in table[3]
    for title, cells in (("USB ID", ["0483:5740", "0483:374B", "-", "10C4:EA60"]),
                         ("WHAT", [p.kind for p in listed]), ("SERIAL", ["-", "0669FF", "-", "0001"])):
        at = table[0].index(title)  # every column lines up under its title
        assert [line[at:].startswith(cell) for line, cell in zip(table[1:], cells)] == [True] * 4


def test_no_ports(comports):
    comports()
    assert ports.list_ports(probe=True) == []
    linux = ports.format_ports([], platform="linux")
    assert linux.startswith("No serial ports found.") and "/dev/ttyUSB*" in linux and "dialout" in linux
    assert ports.format_ports([], platform="win32") == "No serial ports found."


def test_probing_finds_the_board_and_bounds_the_silent_port(comports):
    master, slave = os.openpty()  # a port nobody answers on
    silent = os.ttyname(slave)
    try:
        with EmulatedBoard("native", duration_s=5.0) as board:
            comports(fake_port(board.address, description="emulated board"), fake_port(silent),
                     fake_port("/dev/imulink-no-such-port"))
            started = time.monotonic()
            listed = {p.device: p for p in ports.list_ports(probe=True)}
            elapsed = time.monotonic() - started
            table = ports.format_ports(list(listed.values()))
    finally:
        os.close(master)
        os.close(slave)
    found = listed[board.address]
    assert found.answer == "imulink board native, firmware 0.1.0" and found.hello["board"] == "native"
    assert listed[silent].answer == "no answer" and listed[silent].hello is None
    assert listed["/dev/imulink-no-such-port"].answer.startswith("no such port")
    assert elapsed < ports.PROBE_TIMEOUT_S + ports.PROBE_GRACE_S  # probed at once, each within its bound
    assert "IMULINK" in table.splitlines()[0] and "imulink board native, firmware 0.1.0" in table


def test_probing_reports_a_busy_port(comports):
    with EmulatedBoard("native", duration_s=5.0) as board:
        holder = serial.Serial()
        holder.port, holder.exclusive = board.address, True
        holder.open()
        try:
            comports(fake_port(board.address))
            [port] = ports.list_ports(probe=True)
        finally:
            holder.close()
    assert port.answer.startswith("the port is busy") and port.hello is None


def test_a_port_that_hangs_is_given_up(comports, monkeypatch):
    def hang(device, timeout):
        time.sleep(5)
    monkeypatch.setattr(ports, "probe_port", hang)
    monkeypatch.setattr(ports, "PROBE_GRACE_S", 0.2)
    comports(fake_port("/dev/ttyUSB7", 0x1A86, 0x7523))
    started = time.monotonic()
    [port] = ports.list_ports(probe=True)
    assert time.monotonic() - started < 1.5
    assert port.answer.startswith("no answer (the port hung") and port.kind == "WCH CH340 USB-UART"


def test_a_stranger_is_not_mistaken_for_a_board():
    """A device that talks, but not the protocol (a GPS printing NMEA sentences)."""
    master, slave = os.openpty()
    stop = threading.Event()

    def chatter():
        while not stop.wait(0.02):
            os.write(master, b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n")

    talker = threading.Thread(target=chatter, daemon=True)
    talker.start()
    try:
        hello, answer = ports.probe_port(os.ttyname(slave), timeout=0.3)
    finally:
        stop.set()
        talker.join()
        os.close(master)
        os.close(slave)
    assert hello is None and answer.startswith("not an imulink board (sent")


def test_a_board_of_another_protocol_is_named_as_such():
    with EmulatedBoard("native", duration_s=5.0, schema_hash=0x12345678) as board:
        hello, answer = ports.probe_port(board.address)
    assert hello["board"] == "native"
    assert answer.startswith("imulink board native, firmware 0.1.0, but another protocol version (schema hash "
                             "0x12345678)")
