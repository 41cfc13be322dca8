"""`imulink calibrate`."""
from __future__ import annotations

import argparse
import os
import re
import sys

from imulink import hil
from imulink.analysis import calibration as cal
from imulink.board.link import DEFAULT_BAUD, Link
from imulink.cli.common import (
    PORT_HELP,
    UsageError,
    baud_rate,
    late_progress,
    one_line_errors,
    place_arguments,
    positive_float,
    profile_list,
    profile_named,
)
from imulink.core import calibration as calfmt
from imulink.core.counts import DEFAULT_PROFILE
from imulink.hil import live_calibration
from imulink.hil.live_calibration import DEFAULT_MAX_DURATION_S
from imulink.io import calibration_file, sensor_input
from imulink.io.files import check_output
from imulink.progress import StatusLine

#: `imulink calibrate` sensor names -> the calibration's sensor key
CALIBRATE_SENSORS = {"gyro": "gyr", "accel": "acc", "mag": "mag"}


def _give_calibration(port: str, baud: int, calibration) -> str:
    """Give the board at `port` `calibration` (None: the identity) and read it back; the
    board's calibration as text. HilError when the board states another sensor profile
    than the calibration's, or reports another calibration."""
    with Link(port, baud) as link:
        hello = link.connect()
        if calibration is None:
            calibration = calfmt.Calibration(hil.board_profile(hello))
        hil.check_profile(calibration.profile, hello, "the calibration")
        hil.set_calibration(link, calibration)
        board = hil.read_calibration(link)
    expected = {name: calfmt.to_fixed(calibration.sensor(name)) for name in calfmt.SENSORS}
    if {name: calfmt.to_fixed(board.sensor(name)) for name in calfmt.SENSORS} != expected:
        raise hil.HilError(f"{port} reports another calibration than it was given")
    return cal.format_calibration(board)


@one_line_errors
def run_apply(args) -> int:
    if (args.file is None) == (not args.identity):
        raise UsageError("give a calibration FILE or --identity (not both)")
    calibration = None if args.identity else calibration_file.load(args.file)
    print(_give_calibration(args.port, args.baud, calibration))
    print(f"{args.port}: calibration " + ("identity" if args.identity else f"of {args.file}")
          + " applied and read back (kept until a RESET)")
    return 0


def _is_port(text: str) -> bool:
    """Whether `calibrate mag`'s INPUT names a board (a pyserial URL, a device) rather than a file."""
    import stat

    if "://" in text or re.fullmatch(r"COM\d+", text, re.IGNORECASE):
        return True
    try:
        return stat.S_ISCHR(os.stat(text).st_mode)
    except OSError:
        return text.startswith("/dev/")


def _live_mag_record(args):
    """The magnetometer readings of the board at args.input, collected while the user turns it."""
    print(f"{args.input}: turn the board slowly through every direction (each axis up and down, and the "
          f"diagonals between); it stops when all 26 directions are covered, after {args.max_duration:g} s, or "
          "on Ctrl-C", file=sys.stderr)
    collected = live_calibration.collect_mag(args.input, args.profile, baud=args.baud,
                                             max_duration_s=args.max_duration, progress=StatusLine())
    seconds = collected.time_s[-1] if len(collected.time_s) else 0.0
    print(f"{args.input}: {len(collected.counts)} samples in {seconds:.1f} s ({collected.stop_reason})",
          file=sys.stderr)
    return collected.record()


@one_line_errors
def run(args) -> int:
    import json


    live = args.sensor == "mag" and _is_port(args.input)
    if args.apply and not live:
        raise UsageError("--apply is for a board (calibrate mag PORT); give a file's calibration to a board with "
                         "`imulink calibrate apply FILE PORT`")
    check_output(args.output, inputs=[] if live else [args.input])  # before the work
    if live:
        record = _live_mag_record(args)
    else:
        status, phase = late_progress()
        try:
            record = sensor_input.read(args.input, progress=phase(f"reading {args.input}"))
        finally:
            status.done()
    profile = record.profile or args.profile or DEFAULT_PROFILE
    if args.profile is not None and record.profile is not None and args.profile != record.profile:
        raise UsageError(f"{args.input} holds counts of profile {record.profile.name}; --profile "
                         f"{args.profile.name} contradicts it (--profile is for a CSV, which does not say)")
    sensor = CALIBRATE_SENSORS[args.sensor]
    if sensor == "gyr":
        result = cal.gyro_bias(record, profile)
    elif sensor == "acc":
        result = cal.accel_six_position(record, profile, misalignment=args.misalignment)
    else:
        result = cal.mag_ellipsoid(record, profile)
    missing = result.report["coverage"]["missing"] if sensor == "mag" else []
    axes = [name for name in missing if len(name) == 2]
    result.report = {"input": record.description, **result.report}
    if args.json:
        print(json.dumps({"sensor": sensor, "profile": profile.name, "offset_counts": result.offset.tolist(),
                          "matrix": result.matrix.tolist(), "report": result.report}, indent=1))
    else:
        print(cal.format_report(result, profile))
    if axes and not args.allow_gaps:
        raise calfmt.CalibrationError(f"{cal.missing_advice(axes)}; {args.output} is left as it is "
                                   "(--allow-gaps writes it anyway)")
    merged, replaced = calibration_file.merged(args.output, result, profile)
    calibration_file.save(merged, args.output, inputs=[] if live else [args.input])
    others = [calfmt.SENSOR_NAMES[s] for s in calfmt.SENSORS if s in merged.sensors and s != sensor]
    out = sys.stderr if args.json else sys.stdout
    print(f"calibration: {args.output} ({calfmt.SENSOR_NAMES[sensor]} {'replaced' if replaced else 'written'}"
          + (f"; {', '.join(others)} kept" if others else "") + ")", file=out)
    if args.apply:
        print(_give_calibration(args.input, args.baud, merged), file=out)
        print(f"{args.input}: calibration of {args.output} applied and read back (kept until a RESET)", file=out)
    return 0


def add_parser(sub) -> None:
    calibrate = sub.add_parser(
        "calibrate", help="calibrate a sensor from a recording; give a board a calibration file",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Compute a sensor's calibration from recorded data into a calibration file (JSON), or give\n"
                    "a board the calibration of a file. The board applies it to the raw counts before the\n"
                    "filter: corrected = M (counts - offset), offsets in Q8 counts, M in Q24.\n\n"
                    "  imulink calibrate gyro INPUT    the bias: the mean rate over the rests (the board lying\n"
                    "                                  still, 5 s or more)\n"
                    "  imulink calibrate accel INPUT   offset and scale per axis from six rests, each axis up\n"
                    "                                  and down, a few seconds each\n"
                    "  imulink calibrate mag INPUT     hard and soft iron: an ellipsoid fit to the board turned\n"
                    "                                  slowly in every direction\n"
                    "  imulink calibrate mag PORT      the same, live: turn a connected board until every\n"
                    "                                  direction is covered (--apply: the board takes it)\n"
                    "  imulink calibrate apply FILE PORT   the board takes the calibration of FILE\n\n"
                    "docs/calibration.md gives the procedure for each sensor.")
    kinds = calibrate.add_subparsers(dest="sensor", metavar="SENSOR")
    kinds.required = True
    inputs_help = ("INPUT is a recording (imulink record PORT -o calib.imulog), a CSV of `imulink replay --csv` "
                   "(or any with timestamp_us or time_s and the SI columns gyr_x_rad_s.., acc_x_m_s2.., "
                   "mag_x_uT..; give its --profile), or a BROAD trial (.mat). The calibration goes into --output; "
                   "the other sensors' entries of an existing file are kept.")
    live_help = ("With a board's PORT (a serial device or pyserial URL) instead of INPUT, the board streams while "
                 "you turn it; the directions covered so far are shown, and it stops when all 26 are covered "
                 "(--max-duration, Ctrl-C: sooner). The board's calibration is not changed unless --apply; the "
                 "SAMPLE frames carry raw counts, so an old calibration on the board does not matter.")
    for kind, summary in (("gyro", "gyroscope bias: the mean rate over the rests (5 s still or more in all)"),
                          ("accel", "accelerometer offset and scale per axis: six rests, each axis up and down "
                                    "(a few seconds each); --misalignment: a symmetric matrix from 9 positions "
                                    "or more, some tilted between the axes"),
                          ("mag", "magnetometer hard and soft iron: an ellipsoid fit to the board turned slowly "
                                  "in every direction; reports the coverage of 26 directions and the spread of "
                                  "the field norm before and after, and refuses when the field never lay along "
                                  "one of the board's axes (--allow-gaps writes it anyway)")):
        p = kinds.add_parser(kind, help=summary, description=f"{summary[0].upper()}{summary[1:]}. {inputs_help}"
                             + (f" {live_help}" if kind == "mag" else ""))
        p.add_argument("input", metavar="INPUT" if kind != "mag" else "INPUT|PORT",
                       help="a recording, a replay CSV or a BROAD .mat" + (f", or the board: {PORT_HELP}"
                                                                           if kind == "mag" else ""))
        p.add_argument("--output", "-o", default="calibration.json",
                       help="calibration file to write or update (default: calibration.json)")
        p.add_argument("--profile", type=profile_named, default=None,
                       help=f"sensor profile of a CSV's data (default: gy86-default; a recording, a BROAD trial "
                            f"and a board state theirs, and this must agree; profiles: {profile_list()})")
        p.add_argument("--json", action="store_true", help="print the calibration and its report as JSON")
        if kind == "accel":
            p.add_argument("--misalignment", action="store_true",
                           help="fit a symmetric matrix (misalignment, cross-axis) instead of a scale per axis")
        if kind == "mag":
            p.add_argument("--allow-gaps", action="store_true",
                           help="write the calibration even when the field never lay along some axis")
            p.add_argument("--apply", action="store_true",
                           help="with a PORT: also give the board the calibration written (read back to check)")
            p.add_argument("--max-duration", type=positive_float, default=DEFAULT_MAX_DURATION_S, metavar="S",
                           help="with a PORT: stop turning after S seconds even when directions are missing "
                                f"(default: {DEFAULT_MAX_DURATION_S:g})")
            p.add_argument("--baud", type=baud_rate, default=DEFAULT_BAUD,
                           help=f"with a PORT: line rate of a real serial port (default: {DEFAULT_BAUD})")
            place_arguments(p)
            p.set_defaults(place_attribute="input")
        p.set_defaults(func=run, misalignment=False, allow_gaps=False, apply=False)
    p = kinds.add_parser(
        "apply", help="give a board the calibration of a file",
        description="Send the calibration of FILE to the board (SET_CALIBRATION for every sensor and axis; a "
                    "sensor the file lacks gets the identity), read it back to check it, and print it. The board "
                    "keeps it until a RESET or a power cycle; `imulink record` stores it in the recording, so "
                    "replay and compare reproduce the board bit for bit. --identity takes it away.")
    p.add_argument("file", metavar="FILE", nargs="?", help="calibration file (imulink calibrate ... -o FILE)")
    p.add_argument("port", metavar="PORT", help=PORT_HELP)
    p.add_argument("--identity", action="store_true", help="give the board the identity calibration instead of FILE")
    p.add_argument("--baud", type=baud_rate, default=DEFAULT_BAUD,
                   help=f"line rate of a real serial port (default: {DEFAULT_BAUD}; ignored by sockets and ptys)")
    place_arguments(p)
    p.set_defaults(func=run_apply)

