"""`imulink compare`."""
from __future__ import annotations

from imulink import hil
from imulink.cli.common import (
    EXIT_MISMATCH,
    json_argument,
    min_verified_argument,
    one_line_errors,
    print_json,
)
from imulink.io.recording import load_recording


@one_line_errors
def run(args) -> int:
    recording = load_recording(args.file)
    comparison = hil.compare(recording, min_verified=args.min_verified)
    if args.json:
        print_json(hil.comparison_json(recording, comparison))
    else:
        print(hil.format_comparison(recording, comparison))
    return 0 if comparison.verdict.passed else EXIT_MISMATCH


def add_parser(sub) -> None:
    p = sub.add_parser(
        "compare", help="bit-exactness verdict of a recording",
        description="Compare every estimate of a recording with the host fixed-point build, bit for bit, and "
                    "report the counts of identical frames, the first differing frame and field with both "
                    "values, and the fixed-vs-float statistics. Estimates after a lost sample of their filter "
                    "run cannot be reproduced and are reported as unverifiable. Damaged parts of the file are "
                    "skipped and reported by offset. The verdict line says how many of the recorded estimates "
                    "were verified. Exit status 0 when every verified estimate is identical and they are at "
                    "least --min-verified of the recorded ones; 1 on any difference, on fewer verified, when "
                    "none can be verified, or when the file is damaged.")
    p.add_argument("file", metavar="FILE", help="recording to check")
    min_verified_argument(p, "the recorded estimates")
    json_argument(p, "the comparison")
    p.set_defaults(func=run)

