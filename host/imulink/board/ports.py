"""The serial ports of this computer and what is behind them, for `imulink ports`.

:func:`list_ports` lists pyserial's ports with their USB vendor:product id and a guess of
the adapter from :data:`USB_ADAPTERS`, the USB-to-serial chips an imulink board is usually
reached through. With ``probe=True`` it also asks every port whether an imulink board
answers: it opens the port at the board's line rate, sends GET_VERSION and waits a
moment for HELLO (imulink.board.link). Probing writes bytes to every port, which may disturb
whatever else is plugged in (a modem, a GPS, a printer), so it is asked for explicitly.
Ports are probed in parallel, each within PROBE_TIMEOUT_S plus a grace for opening and
closing; a port that does not open, does not answer or hangs is reported as such, never
raised.

:func:`format_ports` makes the table the command prints.
"""
from __future__ import annotations

import re
import sys
import threading
import time
from dataclasses import dataclass, replace
from typing import Optional

from serial.tools import list_ports as serial_ports

from imulink import protocol
from imulink.board.link import DEFAULT_BAUD, Link, LinkError, NotABoard, PortError

#: What usually sits behind a USB vendor:product id (pyserial reports them for USB ports).
USB_ADAPTERS: dict[tuple[int, int], str] = {
    (0x0483, 0x374B): "ST-Link/V2-1 virtual COM port",
    (0x0483, 0x3752): "ST-Link/V2-1 virtual COM port",
    (0x0483, 0x374E): "STLINK-V3 virtual COM port",
    (0x0483, 0x374F): "STLINK-V3 virtual COM port",
    (0x0483, 0x3753): "STLINK-V3 virtual COM port",
    (0x0483, 0x3754): "STLINK-V3 virtual COM port",
    (0x0483, 0x5740): "STM32 USB CDC (an STM32's own USB port)",
    (0x10C4, 0xEA60): "Silicon Labs CP210x USB-UART",
    (0x10C4, 0xEA70): "Silicon Labs CP2105 dual USB-UART",
    (0x1A86, 0x7523): "WCH CH340 USB-UART",
    (0x1A86, 0x5523): "WCH CH341 USB-UART",
    (0x1A86, 0x55D4): "WCH CH9102 USB-UART",
    (0x0403, 0x6001): "FTDI FT232R USB-UART",
    (0x0403, 0x6010): "FTDI FT2232 dual USB-UART",
    (0x0403, 0x6014): "FTDI FT232H USB-UART",
    (0x0403, 0x6015): "FTDI FT231X USB-UART",
    (0x067B, 0x2303): "Prolific PL2303 USB-UART",
}
#: Seconds a probed port has to answer GET_VERSION with HELLO.
PROBE_TIMEOUT_S = 0.4
#: Extra seconds a probe may take to open and close its port before it is given up.
PROBE_GRACE_S = 1.0


@dataclass(frozen=True)
class PortInfo:
    """One serial port.

    usb_id: "VVVV:PPPP" for a USB port, else None. kind: a guess of what it is.
    answer: after probing, who answered ("imulink board stm32f407, firmware 0.1.0") or
    why nothing did; None when not probed. hello: the HELLO fields of a board that answered.
    """

    device: str
    usb_id: Optional[str]
    kind: str
    description: str
    serial_number: Optional[str]
    answer: Optional[str] = None
    hello: Optional[dict] = None


def guess_kind(vid: Optional[int], pid: Optional[int]) -> str:
    """What a port with this USB id probably is."""
    if vid is None or pid is None:
        return "serial port (not USB)"
    if (vid, pid) in USB_ADAPTERS:
        return USB_ADAPTERS[(vid, pid)]
    if vid == 0x0483:
        return "STMicroelectronics USB device"
    return "USB serial device"


def describe_port(port) -> PortInfo:
    """A PortInfo for one of pyserial's ListPortInfo objects."""
    vid, pid = port.vid, port.pid
    usb_id = f"{vid:04X}:{pid:04X}" if vid is not None and pid is not None else None
    description = port.description if port.description and port.description != "n/a" else ""
    if description == port.device:  # pyserial's placeholder when it knows nothing
        description = ""
    return PortInfo(port.device, usb_id, guess_kind(vid, pid), description, port.serial_number or None)


def list_ports(probe: bool = False) -> list[PortInfo]:
    """The serial ports, sorted by device name; with `probe`, each asked for an imulink board."""
    ports = sorted((describe_port(port) for port in serial_ports.comports()), key=lambda p: _natural(p.device))
    return probe_ports(ports) if probe else ports


def probe_ports(ports: list[PortInfo], timeout: float = PROBE_TIMEOUT_S) -> list[PortInfo]:
    """The ports with `answer` (and `hello`) filled in; all probed at once, in bounded time."""
    results: dict[str, tuple[Optional[dict], str]] = {}
    threads = []
    for port in ports:
        def run(device=port.device):
            results[device] = probe_port(device, timeout)
        thread = threading.Thread(target=run, name=f"imulink-probe {port.device}", daemon=True)
        thread.start()
        threads.append(thread)
    deadline = time.monotonic() + timeout + PROBE_GRACE_S
    for thread in threads:
        thread.join(max(0.0, deadline - time.monotonic()))
    stuck = (None, f"no answer (the port hung for more than {timeout + PROBE_GRACE_S:g} s)")
    return [replace(port, hello=hello, answer=answer)
            for port in ports for hello, answer in [results.get(port.device, stuck)]]


def probe_port(device: str, timeout: float = PROBE_TIMEOUT_S) -> tuple[Optional[dict], str]:
    """Ask one port for an imulink board: (its HELLO fields or None, one line saying what answered)."""
    try:
        link = Link(device, baud=DEFAULT_BAUD)
    except PortError as exc:
        return None, re.sub(r"^cannot open .*?: ", "", str(exc))
    except Exception as exc:  # noqa: BLE001 -- one bad port must not stop the listing
        return None, f"cannot open: {exc}"
    try:
        hello = link.connect(timeout=timeout, attempts=1)
        return hello, f"imulink board {_board_text(hello)}"
    except protocol.ProtocolMismatch:
        assert link.hello is not None  # connect() checks the HELLO it stored
        return link.hello, (f"imulink board {_board_text(link.hello)}, but another protocol version "
                            f"(schema hash 0x{link.hello['schema_hash']:08X}): update the firmware or the host")
    except NotABoard:
        counters = link.counters()
        if counters["bytes"] == 0:
            return None, "no answer"
        if counters["frames"] == 0:
            return None, (f"not an imulink board (sent {counters['bytes']} bytes, no valid frame: another "
                          f"device, or not at {DEFAULT_BAUD} baud)")
        return None, "imulink frames, but no HELLO"
    except (LinkError, protocol.ProtocolError, OSError) as exc:
        return None, str(exc)
    except Exception as exc:  # noqa: BLE001
        return None, f"error: {exc}"
    finally:
        link.close()


def _board_text(hello: dict) -> str:
    return (f"{hello['board']}, firmware "
            f"{hello['firmware_major']}.{hello['firmware_minor']}.{hello['firmware_patch']}")


def _natural(text: str) -> list:
    """Sort key putting ttyACM2 before ttyACM10 and COM3 before COM12."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]


def format_ports(ports: list[PortInfo], platform: str = sys.platform) -> str:
    """The ports as a table for the terminal (or why there is none)."""
    if not ports:
        lines = ["No serial ports found."]
        if platform.startswith("linux"):
            lines.append("USB serial adapters appear as /dev/ttyUSB* (CP210x, CH340, FTDI, PL2303) or /dev/ttyACM* "
                         "(ST-Link, STM32 USB) when plugged in; opening them needs the 'dialout' group "
                         "(sudo usermod -aG dialout $USER, then log in again).")
        return "\n".join(lines)
    columns = [("DEVICE", lambda p: p.device), ("USB ID", lambda p: p.usb_id or "-"), ("WHAT", lambda p: p.kind),
               ("SERIAL", lambda p: p.serial_number or "-")]
    if any(p.answer is not None for p in ports):
        columns.append(("IMULINK", lambda p: p.answer or "-"))
    columns.append(("DESCRIPTION", lambda p: p.description or "-"))
    rows = [[title for title, _ in columns]] + [[cell(p) for _, cell in columns] for p in ports]
    widths = [max(len(row[i]) for row in rows) for i in range(len(columns) - 1)]
    return "\n".join("  ".join([*(text.ljust(width) for text, width in zip(row, widths)), row[-1]]).rstrip()
                     for row in rows)
