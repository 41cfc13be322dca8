"""`imulink emulate`."""
from __future__ import annotations

from imulink import hil
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Link
from imulink.cli.common import (
    fault_arguments,
    fault_config,
    front_arguments,
    one_line_errors,
    profile_list,
    profile_named,
    scenario_for,
    serve_until_interrupted,
    settings_argument,
    settings_from_file,
    simulation_arguments,
    target_arguments,
)
from imulink.core.counts import DEFAULT_PROFILE


@one_line_errors
def run(args) -> int:
    faults = fault_config(args)
    settings = settings_from_file(args)
    filter_name = settings.filter_name if settings is not None else args.filter
    front = args.serial if args.serial is not None else ("tcp" if args.tcp is not None else "pty")
    scenario = scenario_for(args, filter_name)
    board = EmulatedBoard(args.target, front=front, port=args.tcp or 0, scenario=scenario,
                          duration_s=args.duration, rate_hz=args.rate, seed=args.seed, filter_name=filter_name,
                          realtime=not args.fast, profile=args.profile, faults=faults, schema_hash=args.schema_hash,
                          image=args.image, baud=args.baud)
    with board:
        if settings is not None:
            assert board.address is not None  # set by the board's start (the with statement)
            with Link(board.address, args.baud) as link:
                link.connect()
                hil.apply_settings(link, settings)
        print(board.address, flush=True)
        pace = "as fast as the link drains" if args.fast else "in real time"
        return serve_until_interrupted(
            f"emulated board ({args.target}: {board.image}): {scenario} {args.duration:g} s at {args.rate:g} Hz "
            f"{pace}, filter {filter_name}, profile {args.profile.name}"
            + (f", settings of {args.settings}" if settings is not None else "")
            + (f", faults {faults.describe()}" if faults.active else ""), lambda: board.error)


def add_parser(sub) -> None:
    p = sub.add_parser(
        "emulate", help="run an emulated board (native or QEMU) on a pty, a TCP port or a serial port",
        description="Run an emulated board until Ctrl-C: the firmware application itself, as a native process "
                    "(default) or as its ARM image in QEMU (--target qemu), its sensors fed by the simulator, on "
                    "a pty (default; its path is printed), a TCP port (socket://127.0.0.1:PORT is printed) or a "
                    "serial port. Every imulink command works against it. Fault options put a proxy in front "
                    "that damages what the board sends, to test a host.")
    simulation_arguments(p, 600.0)
    target_arguments(p)
    front_arguments(p, "the board")
    p.add_argument("--fast", action="store_true", help="a sample whenever the host has read the last ones "
                                                       "(default: real time)")
    p.add_argument("--profile", type=profile_named, default=DEFAULT_PROFILE,
                   help=f"the board's sensor profile, which it states in HELLO (default: gy86-default; "
                        f"profiles: {profile_list()})")
    fault_arguments(p)
    settings_argument(p, "the board starts with them (its filter active, instead of --filter)")
    p.set_defaults(func=run)

