"""The `imulink` command line.

Every command ends with one of the exit statuses in EXIT_STATUS_HELP; every failure is one
line `imulink: error: ...` on stderr, never a traceback.
"""
from __future__ import annotations

import argparse

from imulink import __version__
from imulink.cli import (
    allan,
    calibrate,
    compare,
    demo,
    emulate,
    farm,
    filters,
    flash,
    inject,
    monitor,
    nav,
    plot,
    ports,
    proxy,
    record,
    replay,
    settings,
    simulate,
)
from imulink.cli.common import EXIT_STATUS_HELP, Parser

#: The commands in the order `imulink --help` lists them.
COMMANDS = (simulate, filters, allan, nav, calibrate, demo, emulate, proxy, flash, settings, ports, record, replay,
            plot, compare, monitor, inject, farm)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="imulink",
        description="Hardware-in-the-loop companion for fixed-point MEMS attitude-estimation firmware.",
        epilog=EXIT_STATUS_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"imulink {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extras = parser.parse_known_args(argv)
    if extras and getattr(args, "assignments", None) is not None and not any(e.startswith("-") for e in extras):
        args.assignments += extras  # `settings PORT --filter kf1d q_angle=...`: argparse stops at the option
    elif extras:
        parser.error(f"unrecognized arguments: {' '.join(extras)}")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return args.func(args)


