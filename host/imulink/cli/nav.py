"""`imulink nav`."""
from __future__ import annotations

import argparse
import math

from imulink import core
from imulink.analysis import nav
from imulink.analysis.nav import DEFAULT_START_ACCURACY_M, MAX_LEVER_ARM_M, TUNING_NAMES, start_error
from imulink.cli.common import (
    EXIT_STATUS_HELP,
    UsageError,
    assignments_of,
    in_range,
    json_argument,
    late_progress,
    one_line_errors,
    print_json,
    settings_from_file,
)
from imulink.io.files import check_output
from imulink.io.nav_input import BARO, GNSS_POSITION, GNSS_VELOCITY, MAG, REQUIRED, column_unit, read_nav_csv
from imulink.io.recording import load_recording
from imulink.io.sensor_input import InputError


def _nav_tuning_help() -> str:
    """The nav filter's tuning settings with their defaults, units and ranges (from the C core)."""
    defaults = core.default_settings("nav")
    return "; ".join(f"{f.name} (default {defaults[f.name]:.4g} {f.unit}, {f.minimum:.3g} to {f.maximum:.3g})"
                     for f in core.settings_fields("nav", "float") if f.name in TUNING_NAMES)


@one_line_errors
def run(args) -> int:
    from pathlib import Path


    check_output(args.csv, inputs=[args.input])
    path = Path(args.input)
    if not path.is_file():
        raise UsageError(f"{args.input}: no such file")
    status, phase = late_progress()
    try:
        if path.suffix.lower() == ".csv":
            if args.gnss_latency:
                raise UsageError("--gnss-latency is for a recording: a CSV puts each fix in the row it was measured at")
            inp = read_nav_csv(path)
        else:
            inp = nav.input_from_recording(load_recording(path, progress=phase(f"reading {path.name}")),
                                           args.gnss_latency)
        if args.start is not None:
            inp = nav.with_start(inp, *args.start)
        elif len(inp.fix_index) == 0:
            raise InputError(f"{path} has no GNSS or position fix: the nav filter starts at the first one, or "
                             "give the place of the first sample with --start LAT,LON,HEIGHT[,ACCURACY]")
        settings = dict(core.plain_settings(settings_from_file(args), "nav") or {})
        settings.update(assignments_of(args.assignments))
        result = nav.run(inp, args.arith, args.lever_arm, settings=settings)
        nav.write_csv(result, args.csv, inputs=[args.input])
    finally:
        status.done()
    used = int(result.fix_accepted.sum()) + 1
    report = {"input": str(path), "output": args.csv, "arithmetic": args.arith, "samples": len(inp),
              "start_sample": result.start, "rows_written": len(result),
              "rate_hz": nav.sample_rate_hz(inp.timestamp_us),
              "fixes": len(inp.fix_index), "fixes_used": used, "fixes_gated": result.rejected,
              "resets": result.resets, "fades": result.fades, "settings": settings,
              "zero_velocity_updates": result.zero_velocity, "saturations": result.saturations,
              "start_marker": None if args.start is None else dict(zip(
                  ("lat_deg", "lon_deg", "height_m", "accuracy_m"), args.start)),
              "end": {"lat_deg": float(result.lat_deg[-1]), "lon_deg": float(result.lon_deg[-1]),
                      "height_m": float(result.height_m[-1]),
                      "sd_horizontal_m": float(math.hypot(result.sigma[-1, 0], result.sigma[-1, 1])),
                      "sd_up_m": float(result.sigma[-1, 2])}}
    if args.json:
        print_json(report)
        return 0
    end = report["end"]
    print(f"{args.csv}: {len(result)} rows ({args.arith} build, {report['rate_hz']:g} Hz, from line "
          f"{result.start + 2}, {'the --start marker' if args.start is not None else 'the first fix'})")
    print(f"fixes: {used} of {report['fixes']} used, {result.rejected} gated, {result.resets} resets to them, "
          f"{result.fades} scaled the covariance up; zero-velocity updates: {result.zero_velocity}; "
          f"saturations: {result.saturations}")
    print(f"end: {end['lat_deg']:.7f} deg, {end['lon_deg']:.7f} deg, {end['height_m']:.2f} m "
          f"(sd {end['sd_horizontal_m']:.2f} m horizontal, {end['sd_up_m']:.2f} m up)")
    return 0


def _lever_arm(text: str) -> tuple[float, float, float]:
    """X,Y,Z in metres, each finite and within the nav filter's limit."""
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) and abs(v) <= MAX_LEVER_ARM_M for v in values):
        raise argparse.ArgumentTypeError(f"{text!r} is not X,Y,Z in metres, each within +-{MAX_LEVER_ARM_M:g}")
    return values


def _nav_start(text: str) -> tuple[float, float, float, float]:
    """LAT,LON,HEIGHT[,ACCURACY] (deg, deg, m, m): a place the nav filter can start at."""
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (3, 4):
        raise argparse.ArgumentTypeError(f"{text!r} is not LAT,LON,HEIGHT[,ACCURACY]: three or four numbers "
                                         "(degrees, degrees, metres, metres)")
    if len(values) == 3:
        values.append(DEFAULT_START_ACCURACY_M)
    problem = start_error(*values)
    if problem is not None:
        raise argparse.ArgumentTypeError(f"{text!r}: {problem}")
    lat, lon, height, accuracy = values
    return lat, lon, height, accuracy


def _nav_columns_help() -> str:
    """The navigation CSV's columns (imulink.io.nav_input's tuples) with their units, for `nav --help`."""
    import textwrap


    groups = (("required, in every row", REQUIRED), ("magnetometer, in every row or in none", MAG),
              ("barometer, in the row of each sample it took", BARO),
              ("a fix, in the row it was measured at", GNSS_POSITION),
              ("its velocity, beside a receiver's fix (a marker's leaves these empty)", GNSS_VELOCITY))
    lines = []
    for label, names in groups:
        parts, run = [], []
        for k, name in enumerate(names):
            run.append(name)
            if k + 1 == len(names) or column_unit(names[k + 1]) != column_unit(name):
                parts.append(f"{', '.join(run)} ({column_unit(name)})".replace(" C)", "\N{NO-BREAK SPACE}C)"))
                run = []
        lines.append(textwrap.fill(f"{label}: {'; '.join(parts)}", width=92, initial_indent=" " * 16,
                                   subsequent_indent=" " * 18, break_on_hyphens=False))
    return "\n".join(lines).replace("\N{NO-BREAK SPACE}", " ")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "nav", help="run the nav filter (GNSS/INS navigation) offline over a recording or a navigation CSV",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run the `nav` filter (docs/navigation.md: a loosely coupled GNSS/INS error-state Kalman\n"
                    "filter, the C core the board runs) over INPUT and write its estimate for every sample\n"
                    "from the first fix on (with --start: from the first sample on).\n\n"
                    "INPUT is one of:\n"
                    "  FILE.csv      a navigation CSV: a header and one row per IMU sample, columns in any\n"
                    "                order (others, such as truth_*, are ignored; sensor frame x right,\n"
                    "                y forward, z up; velocities east, north, up):\n"
                    f"{_nav_columns_help()}\n"
                    "  FILE.imulog   a recording (imulink record): its samples, its barometer readings and\n"
                    "                the receiver's 3-D fixes in the rows they arrived with\n"
                    "The filter starts at the first fix, at rest (attitude from the accelerometer and\n"
                    "the magnetometer), or with --start at the first sample, at that place. A fix without\n"
                    "velocity is a marker's: trusted, never gated.\n\n"
                    "Output (--csv): timestamp_us, lat_deg, lon_deg, height_m, vel_e_m_s, vel_n_m_s,\n"
                    "vel_u_m_s, qw, qx, qy, qz (sensor to east-north-up), the standard deviations of the\n"
                    "error state (sd_*), fix_age_s (since the last fix used) and gated (fixes rejected so\n"
                    "far).",
        epilog=EXIT_STATUS_HELP)
    p.add_argument("input", metavar="INPUT", help="a navigation CSV (.csv) or a recording")
    p.add_argument("--csv", metavar="OUT", required=True, help="write the estimate to OUT (CSV)")
    p.add_argument("--arith", choices=("fixed", "float"), default="fixed",
                   help="the firmware's fixed point (default) or the float twin")
    p.add_argument("--start", type=_nav_start, metavar="LAT,LON,HEIGHT[,ACCURACY]",
                   help="start at the first sample at this place, as a marker's fix in the first row would: "
                        "latitude and longitude in degrees (within +-85 and +-180), height in metres above the "
                        "ellipsoid (within +-10 km), ACCURACY the place's standard deviation on each axis in "
                        f"metres (default {DEFAULT_START_ACCURACY_M:g}); position only, trusted as its accuracy "
                        "says. The input's own fixes are used as well (one in the first row right after the "
                        "start). A negative latitude: --start=-33.9,18.4,10")
    p.add_argument("--lever-arm", type=_lever_arm, metavar="X,Y,Z",
                   help="the GNSS antenna's position in the sensor frame (x right, y forward, z up), m, each within "
                        "+-10 (default: at the sensor)")
    p.add_argument("--gnss-latency", type=in_range(float, 0.0, 1.0, "must be 0 to 1 s"), default=0.0,
                   metavar="SECONDS", help="a recording's receiver latency: how long before its arrival each fix "
                                           "was valid (default 0)")
    p.add_argument("--settings", metavar="FILE",
                   help="the nav filter's settings file (JSON, as `imulink settings PORT --save FILE` writes a "
                        "board's): its tuning and lever arm")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="NAME=VALUE",
                   help="one of the nav filter's settings in SI units, after --settings (repeat for more): "
                        + _nav_tuning_help())
    json_argument(p, "a summary of the run")
    p.set_defaults(func=run)

