"""`imulink proxy`."""
from __future__ import annotations

from imulink.board import proxy
from imulink.cli.common import (
    fault_arguments,
    fault_config,
    front_arguments,
    one_line_errors,
    port_arguments,
    serve_until_interrupted,
)


@one_line_errors
def run(args) -> int:
    faults = fault_config(args)
    front = args.serial if args.serial is not None else ("tcp" if args.tcp is not None else "pty")
    server = proxy.Proxy(args.port, proxy.make_front(front, args.tcp or 0, args.baud), faults=faults,
                         schema_hash=args.schema_hash, baud=args.baud, connect_timeout_s=0)
    with server:
        print(server.address, flush=True)
        return serve_until_interrupted(
            f"proxy for {args.port}" + (f" with faults {faults.describe()}" if faults.active else "")
            + (f", HELLO schema hash 0x{args.schema_hash:08X}" if args.schema_hash is not None else ""),
            lambda: server.error and f"{args.port} failed: {server.error}")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "proxy", help="put a fault-injecting proxy in front of any board",
        description="Hold PORT (a real board, an emulated one, any pyserial URL) open and serve it on a pty "
                    "(default; its path is printed), a TCP port or a serial port, passing bytes both ways. The "
                    "fault options damage what the board sends (dropped bytes, flipped bits, garbage, stalls) "
                    "and --schema-hash rewrites its HELLO: a host's error handling tested on a real board.")
    port_arguments(p)
    front_arguments(p, "the proxy", baud=False)
    fault_arguments(p)
    p.set_defaults(func=run)

