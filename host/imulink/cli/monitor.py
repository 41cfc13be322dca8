"""`imulink monitor`."""
from __future__ import annotations

import sys

from imulink.board.link import DEFAULT_BAUD
from imulink.cli.common import (
    EXIT_ERROR,
    PORT_HELP,
    UsageError,
    baud_rate,
    one_line_errors,
    place_arguments,
    positive_float,
    profile_list,
    profile_named,
    scenario_for,
    simulation_arguments,
    target_arguments,
)
from imulink.io.files import check_output


@one_line_errors
def run(args) -> int:
    from imulink import monitor  # here: the monitor extra (Qt) is optional, and checked first

    missing = monitor.missing_dependencies()
    if missing:
        print(f"imulink: error: {missing}", file=sys.stderr)
        return EXIT_ERROR
    if args.port is None and not args.emulate:
        raise UsageError("give a PORT, a recording FILE, or --emulate")
    from pathlib import Path

    from imulink.monitor import sources, window

    if args.screenshot:  # before the window opens: a PNG that cannot be written is known at once
        check_output(args.screenshot)
        if not Path(args.screenshot).parent.is_dir():
            raise UsageError(f"cannot write {args.screenshot}: its directory does not exist")
    emulation = dict(scenario=scenario_for(args), duration_s=args.duration, rate_hz=args.rate, seed=args.seed,
                     filter_name=args.filter, target=args.target, image=args.image)
    if args.listen and (args.emulate or args.port is None or Path(args.port).is_file()):
        raise UsageError("--listen is for a board's PORT that another client commands")
    source = sources.open_source(args.port, emulate=args.emulate, baud=args.baud, profile=args.profile,
                                 speed=args.speed, emulation=emulation, listen=args.listen)
    title = "emulated board" if args.emulate else args.port
    exit_after = args.exit_after if args.exit_after or not args.screenshot else 5.0
    return window.run(source, title, screenshot=args.screenshot, exit_after=exit_after, view_3d=not args.no_3d)


def add_parser(sub) -> None:
    p = sub.add_parser(
        "monitor", help="a live window on a board, an emulated board or a recording",
        description="Open a window on a board (PORT), an emulated board started here (--emulate, real time) or "
                    "a recording (FILE, played at its own pace or --speed times it, with a time slider): "
                    "scrolling plots of the raw sensors in physical units, the Euler angles, gyro bias and "
                    "ESKF covariance the filter sends and the live fixed-vs-float difference; a 3D board in "
                    "the earth's axes (where OpenGL is) and an artificial horizon with a heading tape; link "
                    "health with the bit-exact verdict so far; filter, "
                    "settings, stream, record and reset controls. A lost port is reopened when it comes back. "
                    "Needs the monitor extra: pip install 'imulink[monitor]'. docs/monitor.md describes it.")
    p.add_argument("port", metavar="PORT|FILE", nargs="?",
                   help=f"a recording to replay, or the board: {PORT_HELP}")
    p.add_argument("--baud", type=baud_rate, default=DEFAULT_BAUD,
                   help=f"line rate of a real serial port (default: {DEFAULT_BAUD})")
    place_arguments(p)
    p.add_argument("--profile", type=profile_named, default=None,
                   help=f"refuse a board that states another sensor profile than this one (default: whatever "
                        f"the board states; profiles: {profile_list()})")
    p.add_argument("--emulate", action="store_true", help="start an emulated board (the native firmware, or "
                                                          "--target qemu / stm32f407) and show it")
    target_arguments(p)
    p.add_argument("--listen", action="store_true",
                   help="show a board another client commands (the TCP front of imulink emulate or imulink proxy "
                        "takes several clients) without sending it anything; its controls are then off")
    simulation_arguments(p, 600.0)
    p.add_argument("--speed", type=positive_float, default=1.0, help="replay speed of a recording (default: 1)")
    p.add_argument("--screenshot", metavar="FILE", help="write the window to FILE (PNG) after --exit-after "
                                                        "seconds (default 5), then exit")
    p.add_argument("--exit-after", type=positive_float, metavar="S", help="close the window after S seconds")
    p.add_argument("--no-3d", action="store_true",
                   help="no 3D board view (it needs OpenGL; without it the window shows the horizon alone)")
    p.set_defaults(func=run)

