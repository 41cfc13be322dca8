"""`imulink compare`: one recording's report, or a table over many recordings."""
from __future__ import annotations

import os
import sys

from imulink import hil
from imulink.cli.common import (
    EXIT_MISMATCH,
    json_argument,
    min_verified_argument,
    one_line_errors,
    print_json,
    worker_count,
)
from imulink.hil import batch
from imulink.io.recording import load_recording


@one_line_errors
def run(args) -> int:
    single = len(args.files) == 1 and not os.path.isdir(args.files[0]) and not batch.is_pattern(args.files[0])
    if single:
        recording = load_recording(args.files[0])
        comparison = hil.compare(recording, min_verified=args.min_verified)
        if args.json:
            print_json(hil.comparison_json(recording, comparison))
        else:
            print(hil.format_comparison(recording, comparison))
        return 0 if comparison.verdict.passed else EXIT_MISMATCH
    paths = batch.expand(args.files)
    jobs = args.jobs or os.cpu_count() or 1
    print(f"comparing {len(paths)} recordings, {min(jobs, len(paths))} at a time", file=sys.stderr)

    def progress(done: int, row: dict) -> None:
        print(f"\r{done}/{len(paths)} compared", end="" if done < len(paths) else "\n", file=sys.stderr, flush=True)

    rows = batch.compare_many(paths, args.min_verified, jobs, progress)
    if args.json:
        print_json(batch.batch_json(rows))
    else:
        print(batch.format_table(rows))
    return 0 if all(r["passed"] for r in rows) else EXIT_MISMATCH


def add_parser(sub) -> None:
    p = sub.add_parser(
        "compare", help="bit-exactness verdict of a recording, or of many",
        description="Compare every estimate of a recording with the host fixed-point build, bit for bit, and "
                    "report the counts of identical frames, the first differing frame and field with both "
                    "values, and the fixed-vs-float statistics. Estimates after a lost sample of their filter "
                    "run cannot be reproduced and are reported as unverifiable. Damaged parts of the file are "
                    "skipped and reported by offset. The verdict line says how many of the recorded estimates "
                    "were verified. Exit status 0 when every verified estimate is identical and they are at "
                    "least --min-verified of the recorded ones; 1 on any difference, on fewer verified, when "
                    "none can be verified, or when the file is damaged. Given several files, a directory (its "
                    "files) or a glob pattern (quoted, for many files), it compares them all in worker "
                    "processes and prints one line per recording and a summary; exit status 1 if any is not "
                    "proven bit-exact or cannot be read.")
    p.add_argument("files", metavar="FILE", nargs="+",
                   help="recording to check; several, a directory or a quoted glob pattern ('runs/*.bin') for many")
    min_verified_argument(p, "the recorded estimates")
    p.add_argument("--jobs", type=worker_count, default=0, metavar="N",
                   help="recordings compared at once, each in a worker process (default: one per CPU core)")
    json_argument(p, "the comparison")
    p.set_defaults(func=run)
