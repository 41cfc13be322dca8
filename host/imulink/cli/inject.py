"""`imulink inject`."""
from __future__ import annotations

import argparse

from imulink import core, hil
from imulink.cli.common import (
    EXIT_MISMATCH,
    json_argument,
    min_verified_argument,
    one_line_errors,
    port_arguments,
    print_json,
    settings_argument,
    settings_from_file,
)
from imulink.progress import StatusLine


@one_line_errors
def run(args) -> int:
    source = hil.load_injection_input(args.input)
    result = hil.inject(args.port, source, baud=args.baud, filter_name=args.filter, progress=StatusLine(),
                        settings=settings_from_file(args), min_verified=args.min_verified)
    if args.json:
        print_json(result.to_json())
    else:
        print(hil.format_inject(result))
    return 0 if result.verdict.passed else EXIT_MISMATCH


def add_parser(sub) -> None:
    p = sub.add_parser(
        "inject", help="stream samples into a board in injection mode and check every answer",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Put the board in injection mode, send every sample of the input with INJECT_SAMPLE\n"
                    "and compare each ESTIMATE with the host fixed-point build as it arrives. The board's\n"
                    "sample_rate is set to the input's (and, for a recording, its filter and settings are\n"
                    "applied); changed settings are restored afterwards. Exit status 1 on any difference,\n"
                    "or when fewer than --min-verified of the samples were answered and verified.\n\n"
                    "INPUT is one of:\n"
                    "  sim:SCENARIO[:SECONDS[:RATE_HZ[:SEED]]]  a simulated run, e.g. sim:rests:60\n"
                    "  FILE.mat                                 a BROAD trial (counts with profile gy86-broad)\n"
                    "  FILE                                     a recording\n\n"
                    "The input's sensor profile must be the one the board states (an emulated board\n"
                    "takes it with `imulink emulate --profile`).")
    port_arguments(p)
    p.add_argument("--input", "-i", required=True, help="what to inject (see above)")
    p.add_argument("--filter", choices=list(core.FILTERS), help="select this filter first (default: the board's "
                                                                 "active filter, or the recording's)")
    settings_argument(p, "the injection runs with them (its filter, over a recording's settings); the board's "
                         "changed settings are restored afterwards")
    min_verified_argument(p, "the injected samples (answered and compared)")
    json_argument(p, "the report")
    p.set_defaults(func=run)

