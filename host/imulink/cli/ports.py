"""`imulink ports`."""
from __future__ import annotations

from imulink.board import ports
from imulink.cli.common import one_line_errors


@one_line_errors
def run(args) -> int:
    print(ports.format_ports(ports.list_ports(probe=args.probe)))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "ports", help="list the serial ports and what is behind each",
        description="List the serial ports (pyserial's list_ports) with their USB VID:PID, description and a "
                    "guess of what is behind each (ST-Link virtual COM port, CP210x, CH340, FTDI, ...). --probe "
                    "also asks each one whether an imulink board answers (this writes a GET_VERSION frame to "
                    "every port).")
    p.add_argument("--probe", action="store_true", help="ask each port for an imulink HELLO (writes to the ports)")
    p.set_defaults(func=run)

