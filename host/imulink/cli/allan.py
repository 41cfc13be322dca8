"""`imulink allan`."""
from __future__ import annotations

import argparse
import sys

from imulink import core
from imulink.cli.common import UsageError, in_range, late_progress, one_line_errors
from imulink.io import settings_file
from imulink.io.files import check_output, write_replacing


@one_line_errors
def run(args) -> int:
    import json
    from pathlib import Path

    from imulink.analysis import allan, plotting  # here, not at the top: scipy.stats takes a second to load

    if args.write and not args.settings:
        raise UsageError("--write needs --settings FILTER (the filter whose settings it writes)")
    if args.sensor_only and not args.settings:
        raise UsageError("--sensor-only needs --settings FILTER (it changes the settings derived)")
    if args.write:
        check_output(args.write, inputs=[args.input])
    if args.plot:  # before the work: a plot that cannot be written is known at once
        plotting.plot_format(args.plot)
        plotting.check_plotting()
        check_output(args.plot, inputs=[args.input])
    status, phase = late_progress()
    try:
        record = allan.load_static(args.input, progress=phase(f"reading {Path(args.input).name}"))
        result = allan.analyse(record, args.confidence, progress=phase("Allan deviation"))
    finally:
        status.done()
    derived = (allan.derive_settings(allan.to_json(result), args.settings, args.sensor_only) if args.settings
               else None)
    units = {f.name: f.unit for f in core.settings_fields(args.settings)} if args.settings else {}
    if args.json:
        out = allan.to_json(result)
        if derived is not None:
            out["settings"] = {"filter": args.settings, "values": derived.values,
                               "units": {name: units[name] for name in derived.values}, "notes": derived.notes}
        print(json.dumps(out, indent=1))
    else:
        print(allan.format_report(result))
        if derived is not None:
            print(f"\n{args.settings} settings from the noise terms (SI):")
            for name, value in derived.values.items():
                print(f"{name}={value:.6g}  # {units[name]}")
            for note in derived.notes:
                print(f"# {note}")
    if args.plot:
        write_replacing(args.plot, lambda path: allan.plot(result, path), inputs=[args.input])
        print(f"plot: {args.plot}", file=sys.stderr if args.json else sys.stdout)
    if args.write:
        assert derived is not None  # --write needs --settings (checked above)
        settings_file.save(settings_file.FilterSettings(args.settings, derived.values), args.write,
                           inputs=[args.input])
        print(f"settings file: {args.write}", file=sys.stderr if args.json else sys.stdout)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "allan", help="Allan deviation of a static recording: the sensors' noise terms",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Compute the overlapping Allan deviation of every gyroscope and accelerometer axis of a\n"
                    "STATIC recording (the board lies still on a steady surface the whole time; an hour or\n"
                    "two shows all three terms) at averaging times tau = 1, 2, 4, ... samples up to a ninth\n"
                    "of the record, with chi-square intervals, and read the noise terms off the curve as\n"
                    "IEEE Std 952 does:\n"
                    "  white noise       the -1/2 slope's value at tau = 1 s: angle random walk (gyroscope,\n"
                    "                    rad/sqrt(s), deg/sqrt(h)), velocity random walk (accelerometer)\n"
                    "  bias instability  the floor of the curve / 0.664 (rad/s, deg/h; m/s^2)\n"
                    "  rate random walk  the +1/2 slope's value at tau = 3 s (rad/s/sqrt(s), deg/h/sqrt(h))\n"
                    "A term the curve does not show (a record too short for the +1/2 slope, a curve still\n"
                    "falling at its end) is reported as not identified, with the reason.\n\n"
                    "INPUT is one of:\n"
                    "  FILE.imulog (any name)  a recording: imulink record PORT -o still.imulog --duration 7200\n"
                    "  FILE.csv                a CSV of `imulink replay --csv` (timestamp_us or time_s, and\n"
                    "                          gyr_x_rad_s.. and/or acc_x_m_s2.. columns)\n"
                    "  FILE.mat                a BROAD trial: its longest rest (where movement is false)\n"
                    "The samples must be evenly spaced, without gaps (the rate comes from the timestamps).\n\n"
                    "Outputs: a table of the deviation per tau and the terms per axis with their\n"
                    "uncertainty (half the interval at --confidence); --json the same in SI; --plot the\n"
                    "curves; --settings a filter's settings that follow from the terms (name=value, SI).\n"
                    "docs/calibration.md explains the method and the settings.")
    p.add_argument("input", metavar="INPUT", help="the static recording: a recording, a replay CSV or a BROAD .mat")
    p.add_argument("--json", action="store_true", help="print the curves and the terms as JSON, in SI units")
    p.add_argument("--plot", metavar="FILE", help="draw the curves to FILE, .png or .svg (needs matplotlib: "
                                                  "pip install 'imulink[plot]')")
    p.add_argument("--settings", metavar="FILTER", choices=("eskf", "kf1d"),
                   help="also print the settings of FILTER (eskf or kf1d) that follow from the terms")
    p.add_argument("--sensor-only", action="store_true",
                   help="with --settings: the sensor's noise alone, without the allowance for a moving board that "
                        "the white-noise settings get otherwise (for a board that barely moves)")
    p.add_argument("--write", metavar="FILE",
                   help="with --settings: write them to a settings file (JSON) that record, inject, emulate and "
                        "core.run take with --settings FILE")
    p.add_argument("--confidence", type=in_range(float, 0.01, 0.999, "must be a probability from 0.01 to 0.999"),
                   default=0.683, help="confidence of the intervals (default: 0.683, one standard deviation)")
    p.set_defaults(func=run)

