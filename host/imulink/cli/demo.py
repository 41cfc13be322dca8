"""`imulink demo`."""
from __future__ import annotations

from imulink import hil
from imulink.cli.common import (
    EXIT_INTERRUPTED,
    EXIT_MISMATCH,
    json_argument,
    min_verified_argument,
    one_line_errors,
    print_json,
    scenario_for,
    simulation_arguments,
    target_arguments,
)
from imulink.progress import StatusLine


@one_line_errors
def run(args) -> int:
    report = hil.demo(target=args.target, transport=args.transport, scenario=scenario_for(args),
                      duration_s=args.duration, rate_hz=args.rate, seed=args.seed, filter_name=args.filter,
                      output=args.output, force=args.force, progress=StatusLine(), min_verified=args.min_verified)
    if args.json:
        print_json(report.to_json())
    else:
        print(report.format())
    if report.record.interrupted:
        return EXIT_INTERRUPTED
    return 0 if report.comparison.verdict.passed else EXIT_MISMATCH


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo", help="no hardware: record an emulated board's simulated run and prove it bit-exact",
        description="Start an emulated board (the firmware application as a native process, or its ARM image in "
                    "QEMU with --target qemu, its sensors fed by the simulator), record its simulated run over a "
                    "TCP loopback or a pty as fast as the link goes, replay the recording through the host build "
                    "of the same C, and report: frames and losses, bit-exactness, the fixed-vs-float difference, "
                    "and the accuracy against the simulated truth. Exit status 0 when every verified estimate is "
                    "bit-exact and at least --min-verified of them were verified, 1 otherwise.")
    simulation_arguments(p, 60.0)
    target_arguments(p)
    p.add_argument("--transport", choices=("tcp", "pty"), default="tcp", help="link to the board (default: tcp)")
    p.add_argument("--output", "-o", metavar="FILE", help="keep the recording here (default: not kept)")
    p.add_argument("--force", action="store_true", help="replace an existing --output file")
    min_verified_argument(p, "the recorded estimates")
    json_argument(p, "the report")
    p.set_defaults(func=run)

