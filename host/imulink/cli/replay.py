"""`imulink replay`."""
from __future__ import annotations

import sys

from imulink import hil
from imulink.cli.common import (
    EXIT_MISMATCH,
    UsageError,
    json_argument,
    min_verified_argument,
    one_line_errors,
    print_json,
)
from imulink.io.files import check_output, write_replacing
from imulink.io.recording import load_recording


@one_line_errors
def run(args) -> int:
    from pathlib import Path


    csv_path = args.csv or (None if args.npz else Path(args.file).with_suffix(".csv"))
    if csv_path and args.npz and Path(csv_path).absolute() == Path(args.npz).absolute():
        raise UsageError(f"--csv and --npz name the same file {csv_path}")
    for output in (csv_path, args.npz):  # before the work: a replay never writes over its recording
        if output:
            check_output(output, inputs=[args.file])
    recording = load_recording(args.file)
    run = hil.host_run(recording)
    comparison = hil.compare(recording, run, min_verified=args.min_verified)
    columns = hil.replay_columns(recording, run, comparison)
    messages = sys.stderr if args.json else sys.stdout
    if not args.json:
        print(hil.format_comparison(recording, comparison))
    if csv_path:
        write_replacing(csv_path, lambda path: hil.export_csv(columns, path), inputs=[args.file])
        print(f"CSV: {csv_path} ({len(recording.samples)} rows, {len(columns)} columns)", file=messages)
    if args.npz:
        write_replacing(args.npz, lambda path: hil.export_npz(recording, run, columns, path), inputs=[args.file])
        print(f"NPZ: {args.npz}", file=messages)
    if args.json:
        print_json({**hil.comparison_json(recording, comparison), "outputs": {
            "csv": str(csv_path) if csv_path else None, "csv_rows": len(recording.samples) if csv_path else None,
            "csv_columns": len(columns) if csv_path else None, "npz": args.npz}})
    return 0 if comparison.verdict.passed else EXIT_MISMATCH


def add_parser(sub) -> None:
    p = sub.add_parser(
        "replay", help="re-run a recording through the host builds and export CSV / .npz",
        description="Decode a recording and re-run its raw samples through the host build of the filter the "
                    "board ran (fixed point and float twin, with the recorded settings and sensor profile). "
                    "Writes one row per sample: inputs in SI units, the board's estimate, the host fixed and "
                    "float outputs, and whether the board's estimate was identical; units are in the column "
                    "names. Without --csv or --npz the CSV goes next to the recording. An output is written "
                    "under a temporary name and renamed when complete; the recording itself is never written over. "
                    "The exit status is compare's: the outputs are written either way, and the status is 1 "
                    "unless the recording is proven bit-exact.")
    p.add_argument("file", metavar="FILE", help="recording written by `imulink record` or `imulink demo`")
    p.add_argument("--csv", help="CSV file to write")
    p.add_argument("--npz", help="numpy .npz file to write (also the raw integers and the metadata)")
    min_verified_argument(p, "the recorded estimates")
    json_argument(p, "the comparison and the outputs written")
    p.set_defaults(func=run)

