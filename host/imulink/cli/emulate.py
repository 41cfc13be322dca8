"""`imulink emulate`."""
from __future__ import annotations

import sys

from imulink import hil
from imulink.board.emulator import EmulatedBoard, EmulatorError
from imulink.board.link import Link
from imulink.board.stm32f407 import ChipFaults
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


def chip_faults(args) -> ChipFaults | None:
    if not args.chip_fault:
        return None
    faults = ChipFaults()
    for spec in args.chip_fault:
        try:
            faults.add(spec)
        except ValueError as exc:
            raise EmulatorError(str(exc)) from None
    return faults


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
                          image=args.image, baud=args.baud, chip_faults=chip_faults(args))
    with board:
        if board.virtual is not None:  # what the register-level models find wrong, as it happens
            board.virtual.board.on_problem = lambda line: print(f"problem: {line}", file=sys.stderr, flush=True)
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
            + (f", faults {faults.describe()}" if faults.active else "")
            + (f", chip faults {board.chip_faults.describe()}" if board.chip_faults and board.chip_faults.active
               else ""), lambda: board.error)


def add_parser(sub) -> None:
    p = sub.add_parser(
        "emulate", help="run an emulated board (native, QEMU or the virtual reference board) on a pty, a TCP port "
                        "or a serial port",
        description="Run an emulated board until Ctrl-C: the firmware application itself, as a native process "
                    "(default), as its ARM image in QEMU (--target qemu), or as the reference board's image on a "
                    "register-level STM32F407 with the GY-86 chips and a u-blox receiver (--target stm32f407), its "
                    "sensors fed by the simulator, on "
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
    p.add_argument("--chip-fault", action="append", default=[], metavar="FAULT",
                   help="a fault of the virtual reference board's chips (stm32f407; repeatable): CHIP:nack, "
                        "CHIP:identity (a wrong WHO_AM_I / identification), CHIP:silent:N (stops answering after N "
                        "address phases), sda-low (a chip holds SDA low), gnss:absent, gnss:baud (the receiver at "
                        "another baud), gnss:damaged (damaged frames); CHIP is mpu6050, hmc5883l or ms5611")
    settings_argument(p, "the board starts with them (its filter active, instead of --filter)")
    p.set_defaults(func=run)

