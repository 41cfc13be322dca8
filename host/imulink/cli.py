"""The `imulink` command line.

Every command ends with one of the exit statuses in EXIT_STATUS_HELP; every failure is one
line `imulink: error: ...` on stderr, never a traceback.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import signal
import sys
import time

from . import __version__

EXIT_MISMATCH = 1
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_STATUS_HELP = """exit status:
  0    success
  1    not proven bit-exact: an estimate differs from the host build, fewer than
       --min-verified of them could be verified, or the recording is damaged
       (compare, replay, inject, demo)
  2    a usage error or a failure (argument, port, board, file, disk), said in one line
       "imulink: error: ..."
  130  interrupted (Ctrl-C or SIGTERM); a recording is closed and readable"""


class UsageError(Exception):
    """Arguments that do not make sense together (each alone passed its type check)."""


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line, like every other error."""

    def error(self, message):
        self.exit(EXIT_ERROR, f"imulink: error: {message} (see `{self.prog} --help`)\n")


def _command(func):
    """Run a command: known errors print `imulink: error: ...` and exit 2; Ctrl-C and
    SIGTERM exit 130."""

    def run(args) -> int:
        from . import core, protocol
        from .counts import SensorDataError
        from .emulator import EmulatorError
        from .files import FileError
        from .flash import FlashError
        from .hil import HilError
        from .link import LinkError
        from .plotting import PlotError
        from .recording import RecordingError
        from .sensor_input import InputError
        from .sim import ScenarioError

        signal.signal(signal.SIGTERM, _interrupt)  # `kill` stops a command as cleanly as Ctrl-C
        try:
            return func(args)
        except (LinkError, protocol.ProtocolError, RecordingError, HilError, EmulatorError, FlashError, FileError,
                core.SettingsError, ScenarioError, SensorDataError, InputError, PlotError, UsageError,
                OSError) as exc:
            print(f"imulink: error: {exc}", file=sys.stderr)
            return EXIT_ERROR
        except KeyboardInterrupt:
            print("imulink: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED

    run.__doc__ = func.__doc__
    return run


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _json_value(value):
    """`value` with every non-finite float as null: JSON has no NaN or infinity."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _json_value(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_value(item) for item in value]
    return value


def _print_json(report: dict) -> None:
    """--json: the command's one JSON object, alone on stdout (progress and messages are on stderr)."""
    import json

    print(json.dumps(_json_value(report), indent=1, allow_nan=False))


def _json_argument(p, what: str) -> None:
    p.add_argument("--json", action="store_true",
                   help=f"print {what} as one JSON object on stdout (progress and messages on stderr; keys in "
                        "docs/cli.md)")


@_command
def _cmd_simulate(args) -> int:
    from . import core, sim
    from .analysis import angle_difference, attitude_errors, rmse

    filters = _parse_filters(args.filters)
    if args.settle >= args.duration:
        raise UsageError(f"--settle {args.settle:g} s leaves nothing of the {args.duration:g} s run to evaluate")
    print(f"simulating {args.scenario!r}: {args.duration:g} s at {args.rate:g} Hz, seed {args.seed}", file=sys.stderr)
    result = sim.make_scenario(args.scenario, args.duration, args.rate, seed=args.seed)
    settle = int(args.settle * args.rate)
    report = {"scenario": args.scenario, "duration_s": args.duration, "rate_hz": args.rate, "seed": args.seed,
              "settle_s": args.settle, "samples": len(result.t), "filters": []}
    if not args.json:
        print(f"samples: {len(result.t)}; errors are RMS after the first {args.settle:g} s, in degrees")
        header = f"{'filter':<6} {'arith':<6} {'total':>8} {'heading':>8} {'incl.':>8} {'sat':>5} {'samples/s':>11}"
        print(header)
        print("-" * len(header))
    for name in filters:
        runs, entry = {}, {"filter": name}
        for arithmetic in core.ARITHMETICS:
            start = time.perf_counter()
            runs[arithmetic] = core.run(name, result.gyr, result.acc, result.mag, args.rate, arithmetic,
                                        profile=result.profile)
            speed = len(result.t) / (time.perf_counter() - start)
            err = rmse(attitude_errors(runs[arithmetic].quat[settle:], result.quat_true[settle:]))
            entry[arithmetic] = {"rms_total_deg": err["total"], "rms_heading_deg": err["heading"],
                                 "rms_inclination_deg": err["inclination"],
                                 "saturations": runs[arithmetic].saturations, "samples_per_s": speed}
            if not args.json:
                print(f"{name:<6} {arithmetic:<6} {err['total']:8.3f} {err['heading']:8.3f} "
                      f"{err['inclination']:8.3f} {runs[arithmetic].saturations:5d} {speed:11.0f}")
        diff = angle_difference(runs["fixed"].quat, runs["float"].quat)
        entry.update(fixed_vs_float_max_deg=float(diff.max()), fixed_vs_float_mean_deg=float(diff.mean()))
        report["filters"].append(entry)
        if not args.json:
            print(f"{name:<6} fixed vs float: max {diff.max():.5f} deg, mean {diff.mean():.5f} deg")
    if args.json:
        _print_json(report)
    return 0


@_command
def _cmd_filters(args) -> int:
    from . import core

    report = {"filters": []}
    for name in _parse_filters(args.filters, core.BOARD_FILTERS):
        defaults = core.default_settings(name)
        fields = core.settings_fields(name)
        report["filters"].append({"filter": name, "settings": [
            {"name": f.name, "default": defaults[f.name], "unit": f.unit, "frac_bits": f.frac_bits} for f in fields]})
        if args.json:
            continue
        print(f"{name}:")
        print(_columns([(f"  {f.name}", f"{defaults[f.name]:.6g}", f.unit, f"(fixed: Q{f.frac_bits})")
                        for f in fields]))
    if args.json:
        _print_json(report)
    return 0


def _columns(rows: list[tuple[str, ...]]) -> str:
    """Rows of cells as lines, each column as wide as its widest cell (names of any length line up)."""
    widths = [max(len(row[k]) for row in rows) for k in range(len(rows[0]))]
    return "\n".join(" ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows)


def _assignments(texts: list[str]) -> dict[str, float]:
    """NAME=VALUE arguments as a dict (UsageError for anything else)."""
    values = {}
    for text in texts:
        name, sep, value = text.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not name or not math.isfinite(number):
            raise UsageError(f"{text!r} is not NAME=VALUE with a finite number (e.g. acc_noise=0.4)")
        values[name.strip()] = number
    return values


@_command
def _cmd_settings(args) -> int:
    from . import core, hil, protocol, settings_file
    from .files import check_output
    from .link import Link

    wanted = _assignments(args.assignments)
    if args.save:
        check_output(args.save)
    loaded = settings_file.load(args.load) if args.load else None
    if loaded is not None and args.filter is not None and args.filter != loaded.filter_name:
        raise UsageError(f"{args.load} holds {loaded.filter_name} settings; --filter {args.filter} contradicts it")
    changed = set()
    with Link(args.port, args.baud) as link:
        link.connect()
        if loaded is not None:
            hil.apply_settings(link, loaded)
            changed |= set(loaded.values)
        elif args.filter is not None:
            link.command("SELECT_FILTER", filter_id=core.BOARD_FILTERS[args.filter][0])
        filter_id, board = hil.read_settings(link)
        by_name = {s["name"]: (index, s) for index, s in board.items()}
        unknown = [name for name in wanted if name not in by_name]
        if unknown:
            raise UsageError(f"the board's {hil.name_of_filter(filter_id)} has no setting {', '.join(unknown)}; "
                             f"it has {', '.join(by_name)}")
        for name, value in wanted.items():  # in the board's own formats and ranges (its SETTING answers)
            index, setting = by_name[name]
            low, high = hil.setting_range(setting)
            if not low <= value <= high:
                raise UsageError(f"{name} = {value:g} {setting['unit']} is outside the board's range "
                                 f"{hil.setting_range_text(setting)}"
                                 + ("; nothing was set" if not changed else "; nothing after it was set"))
            try:
                link.command("SET_SETTING", index=index, value=core.to_fixed(value, setting["frac_bits"], name))
            except protocol.CommandError as exc:
                raise hil.HilError(f"the board refuses {name} = {value:g} {setting['unit']} ({exc.reason}); "
                                   "nothing after it was set") from None
            changed.add(name)
        if changed:
            filter_id, board = hil.read_settings(link)  # read back: what the board now runs with
    name = hil.name_of_filter(filter_id)
    rows = [{"name": s["name"], "value": s["value"] / 2.0 ** s["frac_bits"], "raw": s["value"], "unit": s["unit"],
             "frac_bits": s["frac_bits"], "min": hil.setting_range(s)[0], "max": hil.setting_range(s)[1],
             "range": hil.setting_range_text(s), "changed": s["name"] in changed} for s in board.values()]
    if args.save:
        values = {r["name"]: r["value"] for r in rows if r["name"] != "sample_rate"}
        settings_file.save(settings_file.FilterSettings(name, values), args.save)
    if args.json:
        _print_json({"port": args.port, "filter": name, "settings": rows, "saved_to": args.save})
        return 0
    print(f"{args.port}: filter {name}" + (" (settings read back after the change)" if changed else ""))
    print(_columns([(f"  {r['name']}", f"{r['value']:.6g}", r["unit"], r["range"],
                     f"Q{r['frac_bits']}", "changed" if r["changed"] else "") for r in rows]))
    if args.save:
        print(f"settings file: {args.save} ({name}, every setting but sample_rate)")
    return 0


#: A job that ends within this many seconds shows no progress at all.
PROGRESS_AFTER_S = 2.0


def _late_progress():
    """A status line on stderr (hil.Progress) that appears only once the job has run for
    PROGRESS_AFTER_S: returns (status, phase), phase(name) giving a (done, total) callback."""
    from .hil import Progress

    status, started = Progress(), time.monotonic()

    def phase(name: str):
        def report(done: int, total: int) -> None:
            if time.monotonic() - started >= PROGRESS_AFTER_S:
                status.update(f"{name}: {100.0 * done / max(total, 1):3.0f} %")
        return report

    return status, phase


@_command
def _cmd_allan(args) -> int:
    import json
    from pathlib import Path

    from . import allan, core, plotting
    from .files import check_output, write_replacing

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
    status, phase = _late_progress()
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
        from . import settings_file

        settings_file.save(settings_file.FilterSettings(args.settings, derived.values), args.write,
                           inputs=[args.input])
        print(f"settings file: {args.write}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _nav_tuning_help() -> str:
    """The nav filter's tuning settings with their defaults, units and ranges (from the C core)."""
    from . import core
    from .nav import TUNING_NAMES

    defaults = core.default_settings("nav")
    return "; ".join(f"{f.name} (default {defaults[f.name]:.4g} {f.unit}, {f.minimum:.3g} to {f.maximum:.3g})"
                     for f in core.settings_fields("nav", "float") if f.name in TUNING_NAMES)


@_command
def _cmd_nav(args) -> int:
    from pathlib import Path

    from . import nav, settings_file
    from .files import check_output
    from .nav_input import read_nav_csv
    from .sensor_input import InputError

    check_output(args.csv, inputs=[args.input])
    path = Path(args.input)
    if not path.is_file():
        raise UsageError(f"{args.input}: no such file")
    status, phase = _late_progress()
    try:
        if path.suffix.lower() == ".csv":
            if args.gnss_latency:
                raise UsageError("--gnss-latency is for a recording: a CSV puts each fix in the row it was measured at")
            inp = read_nav_csv(path)
        else:
            from .recording import load_recording

            inp = nav.input_from_recording(load_recording(path, progress=phase(f"reading {path.name}")),
                                           args.gnss_latency)
        if args.start is not None:
            inp = nav.with_start(inp, *args.start)
        elif len(inp.fix_index) == 0:
            raise InputError(f"{path} has no GNSS or position fix: the nav filter starts at the first one, or "
                             "give the place of the first sample with --start LAT,LON,HEIGHT[,ACCURACY]")
        settings = dict(settings_file.for_filter(_settings_file(args), "nav") or {})
        settings.update(_assignments(args.assignments))
        result = nav.run(inp, args.arith, args.lever_arm, settings=settings)
        nav.write_csv(result, args.csv, inputs=[args.input])
    finally:
        status.done()
    used = int(result.fix_accepted.sum()) + 1
    report = {"input": str(path), "output": args.csv, "arithmetic": args.arith, "samples": len(inp),
              "start_sample": result.start, "rows_written": len(result), "rate_hz": nav.sample_rate_hz(inp.timestamp_us),
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
        _print_json(report)
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


#: `imulink calibrate` sensor names -> the calibration's sensor key
CALIBRATE_SENSORS = {"gyro": "gyr", "accel": "acc", "mag": "mag"}


def _give_calibration(port: str, baud: int, calibration) -> str:
    """Give the board at `port` `calibration` (None: the identity) and read it back; the
    board's calibration as text. HilError when the board states another sensor profile
    than the calibration's, or reports another calibration."""
    from . import calibration as cal, hil
    from .link import Link

    with Link(port, baud) as link:
        hello = link.connect()
        if calibration is None:
            calibration = cal.Calibration(hil.board_profile(hello))
        hil.check_profile(calibration.profile, hello, "the calibration")
        hil.set_calibration(link, calibration)
        board = hil.read_calibration(link)
    expected = {name: cal.to_fixed(calibration.sensor(name)) for name in cal.SENSORS}
    if {name: cal.to_fixed(board.sensor(name)) for name in cal.SENSORS} != expected:
        raise hil.HilError(f"{port} reports another calibration than it was given")
    return cal.format_calibration(board)


@_command
def _cmd_calibrate_apply(args) -> int:
    from . import calibration as cal

    if (args.file is None) == (not args.identity):
        raise UsageError("give a calibration FILE or --identity (not both)")
    calibration = None if args.identity else cal.load(args.file)
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
    from . import hil, live_calibration

    print(f"{args.input}: turn the board slowly through every direction (each axis up and down, and the "
          f"diagonals between); it stops when all 26 directions are covered, after {args.max_duration:g} s, or "
          "on Ctrl-C", file=sys.stderr)
    collected = live_calibration.collect_mag(args.input, args.profile, baud=args.baud,
                                             max_duration_s=args.max_duration, progress=hil.Progress())
    seconds = collected.time_s[-1] if len(collected.time_s) else 0.0
    print(f"{args.input}: {len(collected.counts)} samples in {seconds:.1f} s ({collected.stop_reason})",
          file=sys.stderr)
    return collected.record()


@_command
def _cmd_calibrate(args) -> int:
    import json

    from . import calibration as cal, sensor_input
    from .counts import DEFAULT_PROFILE
    from .files import check_output

    live = args.sensor == "mag" and _is_port(args.input)
    if args.apply and not live:
        raise UsageError("--apply is for a board (calibrate mag PORT); give a file's calibration to a board with "
                         "`imulink calibrate apply FILE PORT`")
    check_output(args.output, inputs=[] if live else [args.input])  # before the work
    if live:
        record = _live_mag_record(args)
    else:
        status, phase = _late_progress()
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
        raise cal.CalibrationError(f"{cal.missing_advice(axes)}; {args.output} is left as it is "
                                   "(--allow-gaps writes it anyway)")
    merged, replaced = cal.merged(args.output, result, profile)
    cal.save(merged, args.output, inputs=[] if live else [args.input])
    others = [cal.SENSOR_NAMES[s] for s in cal.SENSORS if s in merged.sensors and s != sensor]
    out = sys.stderr if args.json else sys.stdout
    print(f"calibration: {args.output} ({cal.SENSOR_NAMES[sensor]} {'replaced' if replaced else 'written'}"
          + (f"; {', '.join(others)} kept" if others else "") + ")", file=out)
    if args.apply:
        print(_give_calibration(args.input, args.baud, merged), file=out)
        print(f"{args.input}: calibration of {args.output} applied and read back (kept until a RESET)", file=out)
    return 0


def _parse_filters(text: str, known=None) -> list[str]:
    """Filter names (comma-separated, or all) among `known` (default: the attitude filters)."""
    from . import core

    known = core.FILTERS if known is None else known
    names = [n.strip() for n in text.split(",") if n.strip()] if text != "all" else list(known)
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise UsageError(f"unknown filter(s) {', '.join(unknown) or repr(text)}; choose from "
                         f"{', '.join(known)} (comma-separated) or all")
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="imulink",
        description="Hardware-in-the-loop companion for fixed-point MEMS attitude-estimation firmware.",
        epilog=EXIT_STATUS_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"imulink {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("simulate", help="run a simulated trajectory through every filter, fixed and float",
                       description="Simulate a trajectory with MEMS sensor errors, run each filter in the "
                                   "fixed-point build and its float twin, and print the accuracy against the "
                                   "simulated truth and the fixed-vs-float agreement.")
    p.add_argument("--scenario", default="random", choices=["static", "turntable", "random", "rests"],
                   help="trajectory (default: random)")
    p.add_argument("--duration", type=_positive_float, default=300.0, help="seconds to simulate (default: 300)")
    p.add_argument("--rate", type=_positive_float, default=100.0, help="sample rate in Hz (default: 100)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed (default: 0)")
    p.add_argument("--settle", type=_non_negative_float, default=10.0,
                   help="seconds excluded from the error statistics (alignment and convergence, default: 10); "
                        "shorter than --duration")
    p.add_argument("--filters", default="all", help="comma-separated filter names (default: all)")
    _json_argument(p, "the errors and the fixed-vs-float agreement")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("filters", help="list the filters and their default settings",
                       description="List each filter's settings: default value, SI unit and fixed-point format.")
    p.add_argument("--filters", default="all", help="comma-separated filter names (default: all)")
    _json_argument(p, "the settings")
    p.set_defaults(func=_cmd_filters)

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
    p.add_argument("--confidence", type=_in_range(float, 0.01, 0.999, "must be a probability from 0.01 to 0.999"),
                   default=0.683, help="confidence of the intervals (default: 0.683, one standard deviation)")
    p.set_defaults(func=_cmd_allan)

    from .nav import DEFAULT_START_ACCURACY_M

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
    p.add_argument("--gnss-latency", type=_in_range(float, 0.0, 1.0, "must be 0 to 1 s"), default=0.0,
                   metavar="SECONDS", help="a recording's receiver latency: how long before its arrival each fix "
                                           "was valid (default 0)")
    p.add_argument("--settings", metavar="FILE",
                   help="the nav filter's settings file (JSON, as `imulink settings PORT --save FILE` writes a "
                        "board's): its tuning and lever arm")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="NAME=VALUE",
                   help="one of the nav filter's settings in SI units, after --settings (repeat for more): "
                        + _nav_tuning_help())
    _json_argument(p, "a summary of the run")
    p.set_defaults(func=_cmd_nav)

    from .link import DEFAULT_BAUD
    from .live_calibration import DEFAULT_MAX_DURATION_S

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
                       help="a recording, a replay CSV or a BROAD .mat" + (", or a board's PORT" if kind == "mag"
                                                                           else ""))
        p.add_argument("--output", "-o", default="calibration.json",
                       help="calibration file to write or update (default: calibration.json)")
        p.add_argument("--profile", type=_profile, default=None,
                       help=f"sensor profile of a CSV's data (default: gy86-default; a recording, a BROAD trial "
                            f"and a board state theirs, and this must agree; profiles: {_profile_list()})")
        p.add_argument("--json", action="store_true", help="print the calibration and its report as JSON")
        if kind == "accel":
            p.add_argument("--misalignment", action="store_true",
                           help="fit a symmetric matrix (misalignment, cross-axis) instead of a scale per axis")
        if kind == "mag":
            p.add_argument("--allow-gaps", action="store_true",
                           help="write the calibration even when the field never lay along some axis")
            p.add_argument("--apply", action="store_true",
                           help="with a PORT: also give the board the calibration written (read back to check)")
            p.add_argument("--max-duration", type=_positive_float, default=DEFAULT_MAX_DURATION_S, metavar="S",
                           help="with a PORT: stop turning after S seconds even when directions are missing "
                                f"(default: {DEFAULT_MAX_DURATION_S:g})")
            p.add_argument("--baud", type=_baud, default=DEFAULT_BAUD,
                           help=f"with a PORT: line rate of a real serial port (default: {DEFAULT_BAUD})")
        p.set_defaults(func=_cmd_calibrate, misalignment=False, allow_gaps=False, apply=False)
    p = kinds.add_parser(
        "apply", help="give a board the calibration of a file",
        description="Send the calibration of FILE to the board (SET_CALIBRATION for every sensor and axis; a "
                    "sensor the file lacks gets the identity), read it back to check it, and print it. The board "
                    "keeps it until a RESET or a power cycle; `imulink record` stores it in the recording, so "
                    "replay and compare reproduce the board bit for bit. --identity takes it away.")
    p.add_argument("file", metavar="FILE", nargs="?", help="calibration file (imulink calibrate ... -o FILE)")
    p.add_argument("port", metavar="PORT", help="serial device or pyserial URL of the board")
    p.add_argument("--identity", action="store_true", help="give the board the identity calibration instead of FILE")
    p.add_argument("--baud", type=_baud, default=DEFAULT_BAUD,
                   help=f"line rate of a real serial port (default: {DEFAULT_BAUD}; ignored by sockets and ptys)")
    p.set_defaults(func=_cmd_calibrate_apply)
    _add_hil_commands(sub)
    return parser


# ---------------------------------------------------------------------------- hardware in the loop
# The logic lives in imulink.hil (record, replay, compare, inject, demo), imulink.emulator
# (emulate); these functions only parse and print.


def _profile_list() -> str:
    from .counts import PROFILES, describe_profile

    return ", ".join(describe_profile(p) for p in PROFILES.values())


def _profile(name: str):
    from .counts import PROFILES

    try:
        return PROFILES[name]
    except KeyError:
        raise argparse.ArgumentTypeError(f"unknown sensor profile {name!r}; choose from {', '.join(PROFILES)}") from None


def _lever_arm(text: str) -> tuple[float, float, float]:
    """X,Y,Z in metres, each finite and within the nav filter's limit."""
    from .nav import MAX_LEVER_ARM_M

    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) and abs(v) <= MAX_LEVER_ARM_M for v in values):
        raise argparse.ArgumentTypeError(f"{text!r} is not X,Y,Z in metres, each within +-{MAX_LEVER_ARM_M:g}")
    return values


def _nav_start(text: str) -> tuple[float, float, float, float]:
    """LAT,LON,HEIGHT[,ACCURACY] (deg, deg, m, m): a place the nav filter can start at."""
    from .nav import DEFAULT_START_ACCURACY_M, start_error

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
    return tuple(values)


def _nav_columns_help() -> str:
    """The navigation CSV's columns (imulink.nav_input's tuples) with their units, for `nav --help`."""
    import textwrap

    from .nav_input import BARO, GNSS_POSITION, GNSS_VELOCITY, MAG, REQUIRED, column_unit

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


def _in_range(parse, low, high, requirement: str):
    """An argument type: `parse(text)` within [low, high] (NaN never is), else `requirement`
    in the error. Every number from the user is bounded, so none can ask for an
    impossible allocation or wait."""

    def convert(text: str):
        try:
            value = parse(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{requirement}, not {text!r}")
        return value

    return convert


_positive_float = _in_range(float, math.ulp(0.0), sys.float_info.max, "must be a positive finite number")
_non_negative_float = _in_range(float, 0.0, sys.float_info.max, "must be a finite number from 0")
_reconnect_wait = _in_range(float, 0.0, 86400.0, "must be a number of seconds from 0 to 86400")
_probability = _in_range(float, 0.0, 1.0, "must be a probability from 0 to 1")
_seed = _in_range(int, 0, 2**32 - 1, "must be an integer from 0 to 4294967295")
_tcp_port = _in_range(int, 0, 65535, "must be a TCP port from 0 to 65535 (0: any free port)")
_baud = _in_range(int, 1, 100_000_000, "must be a baud rate from 1 to 100000000")
_u32 = _in_range(lambda text: int(text, 0), 0, 0xFFFFFFFF,
                 "must be an integer from 0 to 0xFFFFFFFF (e.g. 0x1234ABCD)")


def _faults(args):
    from .proxy import FaultConfig

    return FaultConfig(drop_byte=args.drop_byte, flip_bit=args.flip_bit, garbage=args.garbage, stall=args.stall,
                       stall_s=args.stall_duration, seed=args.fault_seed)


def _serve_until_interrupted(describe: str, error) -> int:
    """Wait for Ctrl-C or SIGTERM (or a failure that `error()` reports); 0 when stopped by the user."""
    print(describe + " Ctrl-C stops it.", file=sys.stderr)
    try:
        while error() is None:
            time.sleep(0.2)
    except KeyboardInterrupt:
        return 0
    print(f"imulink: error: {error()}", file=sys.stderr)
    return EXIT_ERROR


@_command
def _cmd_emulate(args) -> int:
    from .emulator import EmulatedBoard

    faults = _faults(args)
    settings = _settings_file(args)
    filter_name = settings.filter_name if settings is not None else args.filter
    front = args.serial if args.serial is not None else ("tcp" if args.tcp is not None else "pty")
    scenario = _scenario(args, filter_name)
    board = EmulatedBoard(args.target, front=front, port=args.tcp or 0, scenario=scenario,
                          duration_s=args.duration, rate_hz=args.rate, seed=args.seed, filter_name=filter_name,
                          realtime=not args.fast, profile=args.profile, faults=faults, schema_hash=args.schema_hash,
                          image=args.image, baud=args.baud)
    with board:
        if settings is not None:
            from . import hil
            from .link import Link

            with Link(board.address, args.baud) as link:
                link.connect()
                hil.apply_settings(link, settings)
        print(board.address, flush=True)
        pace = "as fast as the link drains" if args.fast else "in real time"
        return _serve_until_interrupted(
            f"emulated board ({args.target}: {board.image}): {scenario} {args.duration:g} s at {args.rate:g} Hz "
            f"{pace}, filter {filter_name}, profile {args.profile.name}"
            + (f", settings of {args.settings}" if settings is not None else "")
            + (f", faults {faults.describe()}" if faults.active else ""), lambda: board.error)


@_command
def _cmd_proxy(args) -> int:
    from . import proxy

    faults = _faults(args)
    front = args.serial if args.serial is not None else ("tcp" if args.tcp is not None else "pty")
    server = proxy.Proxy(args.port, proxy.make_front(front, args.tcp or 0, args.baud), faults=faults,
                         schema_hash=args.schema_hash, baud=args.baud, connect_timeout_s=0)
    with server:
        print(server.address, flush=True)
        return _serve_until_interrupted(
            f"proxy for {args.port}" + (f" with faults {faults.describe()}" if faults.active else "")
            + (f", HELLO schema hash 0x{args.schema_hash:08X}" if args.schema_hash is not None else ""),
            lambda: server.error and f"{args.port} failed: {server.error}")


@_command
def _cmd_record(args) -> int:
    from . import hil

    result = hil.record(args.port, args.output, duration_s=args.duration, baud=args.baud, profile=args.profile,
                        resync=not args.no_resync, silence_timeout_s=args.silence_timeout, force=args.force,
                        progress=hil.Progress(), settings=_settings_file(args), reconnect_s=args.reconnect,
                        listen=args.listen)
    if args.json:
        _print_json(result.to_json())
        return EXIT_INTERRUPTED if result.interrupted else 0
    print(f"recorded {result.samples} samples and {result.estimates} estimates of {result.filter_name} in "
          f"{result.duration_s:.1f} s to {result.path} ({result.stop_reason}); "
          f"{hil.link_summary(result.counters)}"
          + (f"; filter restarts after lost samples: {result.filter_restarts}" if result.filter_restarts else "")
          + (f"; the board came back {result.reconnects} time(s), each a new segment" if result.reconnects else ""))
    return EXIT_INTERRUPTED if result.interrupted else 0


@_command
def _cmd_replay(args) -> int:
    from pathlib import Path

    from . import hil
    from .files import check_output, write_replacing
    from .recording import load_recording

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
        _print_json({**hil.comparison_json(recording, comparison), "outputs": {
            "csv": str(csv_path) if csv_path else None, "csv_rows": len(recording.samples) if csv_path else None,
            "csv_columns": len(columns) if csv_path else None, "npz": args.npz}})
    return 0 if comparison.verdict.passed else EXIT_MISMATCH


@_command
def _cmd_plot(args) -> int:
    from . import hil, plotting
    from .files import check_output, write_replacing
    from .recording import load_recording

    plotting.plot_format(args.output)  # before the work: a figure that cannot be written is known at once
    plotting.check_plotting()
    check_output(args.output, inputs=[args.file])
    recording = load_recording(args.file)
    run = hil.host_run(recording)
    comparison = hil.compare(recording, run)
    columns = hil.replay_columns(recording, run, comparison)
    verdict = hil.format_comparison(recording, comparison).splitlines()
    line = next((text for text in verdict if text.startswith("bit-exact")), verdict[-1])
    write_replacing(args.output, lambda path: plotting.plot_recording(recording, columns, line, path),
                    inputs=[args.file])
    print(f"plot: {args.output} ({len(recording.samples)} samples; {line})")
    return 0


@_command
def _cmd_compare(args) -> int:
    from . import hil
    from .recording import load_recording

    recording = load_recording(args.file)
    comparison = hil.compare(recording, min_verified=args.min_verified)
    if args.json:
        _print_json(hil.comparison_json(recording, comparison))
    else:
        print(hil.format_comparison(recording, comparison))
    return 0 if comparison.verdict.passed else EXIT_MISMATCH


@_command
def _cmd_inject(args) -> int:
    from . import hil

    source = hil.load_injection_input(args.input)
    result = hil.inject(args.port, source, baud=args.baud, filter_name=args.filter, progress=hil.Progress(), settings=_settings_file(args), min_verified=args.min_verified)
    if args.json:
        _print_json(result.to_json())
    else:
        print(hil.format_inject(result))
    return 0 if result.verdict.passed else EXIT_MISMATCH


@_command
def _cmd_demo(args) -> int:
    from . import hil

    report = hil.demo(target=args.target, transport=args.transport, scenario=_scenario(args), duration_s=args.duration,
                      rate_hz=args.rate, seed=args.seed, filter_name=args.filter, output=args.output,
                      force=args.force, progress=hil.Progress(), min_verified=args.min_verified)
    if args.json:
        _print_json(report.to_json())
    else:
        print(report.format())
    if report.record.interrupted:
        return EXIT_INTERRUPTED
    return 0 if report.comparison.verdict.passed else EXIT_MISMATCH


@_command
def _cmd_monitor(args) -> int:
    from . import monitor

    missing = monitor.missing_dependencies()
    if missing:
        print(f"imulink: error: {missing}", file=sys.stderr)
        return EXIT_ERROR
    if args.port is None and not args.emulate:
        raise UsageError("give a PORT, a recording FILE, or --emulate")
    from pathlib import Path

    from .files import check_output
    from .monitor import sources, window

    if args.screenshot:  # before the window opens: a PNG that cannot be written is known at once
        check_output(args.screenshot)
        if not Path(args.screenshot).parent.is_dir():
            raise UsageError(f"cannot write {args.screenshot}: its directory does not exist")
    emulation = dict(scenario=_scenario(args), duration_s=args.duration, rate_hz=args.rate, seed=args.seed,
                     filter_name=args.filter)
    if args.listen and (args.emulate or args.port is None or Path(args.port).is_file()):
        raise UsageError("--listen is for a board's PORT that another client commands")
    source = sources.open_source(args.port, emulate=args.emulate, baud=args.baud, profile=args.profile,
                                 speed=args.speed, emulation=emulation, listen=args.listen)
    title = "emulated board" if args.emulate else args.port
    exit_after = args.exit_after if args.exit_after or not args.screenshot else 5.0
    return window.run(source, title, screenshot=args.screenshot, exit_after=exit_after, view_3d=not args.no_3d)


SWD_PORTS = ("swd", "pyocd", "openocd")


def _flash_method(args) -> str:
    """uart, pyocd or openocd: --method, else from PORT (swd, pyocd[:PROBE], openocd, or a serial port)."""
    if args.method:
        return args.method
    from .flash import FlashError

    if args.port is None:
        raise FlashError("give the serial port wired to the board's USART1 (PA9/PA10), or swd / pyocd / openocd "
                         "to flash over SWD (see imulink flash --help)")
    name = args.port.split(":", 1)[0]
    if name == "swd":
        from .swd import available_methods

        found = [method for method, version in available_methods().items() if version]
        if not found:
            raise FlashError("no SWD tool found: pip install 'imulink[swd]' (pyOCD), or put openocd on the PATH")
        return found[0]
    return name if name in SWD_PORTS else "uart"


@_command
def _cmd_flash(args) -> int:
    from . import flash
    from .firmware_image import ImageError, load_image
    from .progress import Bars

    try:
        image = load_image(args.image, args.address)
    except ImageError as exc:
        raise flash.FlashError(str(exc)) from None
    method = _flash_method(args) if args.port is not None or args.method or not args.dry_run else None
    ident = flash.check_identification(image, args.force)
    what = (f"{ident.board} firmware {ident.version_text} for {ident.chip}" if ident is not None
            else "an image without identification")
    print(f"image: {image.path} ({image.format}, {what}): {image.size} bytes at 0x{image.start:08X}..0x{image.end:08X}",
          file=sys.stderr)
    if method is None:  # --dry-run without a board: the image checks only
        chip = flash.CHIPS.get(ident.device_id) if ident is not None else None
        if chip is not None:
            flash.check_chip(image, ident, ident.device_id, ident.flash_kib * 1024)
            print(f"would erase sectors {', '.join(map(str, flash.sectors_for(image, chip)))} of the "
                  f"{'/'.join(chip.names)} and write {image.size} bytes (no board given: nothing done)")
        return 0
    progress = Bars()
    if method == "uart":
        result = flash.flash_uart(image, args.port, enter=args.enter, baud=args.baud, link_baud=args.link_baud,
                                  verify=not args.no_verify, start=not args.no_start, dry_run=args.dry_run,
                                  force=args.force, unprotect=args.unprotect, progress=progress,
                                  log=lambda line: print(line, file=sys.stderr))
        hello = result.hello
    else:
        from . import swd

        started = time.monotonic()
        probe = args.port.split(":", 1)[1] if args.port and ":" in args.port else None
        try:
            summary = swd.flash_swd(image, method, target=args.target, probe=probe, verify=not args.no_verify,
                                    dry_run=args.dry_run, progress=progress, interface=args.interface)
        except swd.SwdError as exc:
            raise flash.FlashError(str(exc)) from None
        print(summary, file=sys.stderr)
        note = flash.unasked_hello(ident)
        hello = (flash.check_hello(args.link, args.link_baud, ident)
                 if args.link and not args.dry_run and not note else None)
        result = flash.FlashResult(image, method, args.target, "", [], 0 if args.dry_run else image.size,
                                   not args.no_verify and not args.dry_run, not args.dry_run, hello,
                                   time.monotonic() - started, args.dry_run, note=note)
    if result.dry_run:
        print(f"dry run: nothing written ({result.method})")
        return 0
    line = (f"flashed {result.bytes_written} bytes over {result.method} in {result.duration_s:.1f} s"
            + (f" (sectors {', '.join(map(str, result.sectors))})" if result.sectors else "")
            + (", verified" if result.verified else ", not verified"))
    if hello is not None:
        line += (f"; running: {hello['board']} firmware {hello['firmware_major']}.{hello['firmware_minor']}."
                 f"{hello['firmware_patch']}, schema 0x{hello['schema_hash']:08X}, as built")
    elif result.started:
        line += "; started" + (f" at 0x{result.started_at:08X}" if result.started_at is not None else "")
        if result.note:
            line += f" ({result.note})"
        elif result.method != "uart":
            line += " (no --link port to check its HELLO)"
    elif result.note:
        line += f"; {result.note}"
    print(line)
    return 0


@_command
def _cmd_ports(args) -> int:
    from . import ports

    print(ports.format_ports(ports.list_ports(probe=args.probe)))
    return 0


def _settings_file(args):
    """The --settings FILE of a command, loaded (None without it)."""
    if args.settings is None:
        return None
    from . import settings_file

    return settings_file.load(args.settings)


def _scenario(args, filter_name: str | None = None) -> str:
    """The emulated board's simulated run: --scenario, else the car drive for the nav filter
    (its GNSS receiver and barometer) and rests for the others."""
    from .emulator import NAV_SCENARIO

    if args.scenario is not None:
        return args.scenario
    return NAV_SCENARIO if (filter_name or args.filter) == "nav" else "rests"


def _add_hil_commands(sub) -> None:
    from . import core, emulator, hil
    from .counts import DEFAULT_PROFILE
    from .link import DEFAULT_BAUD

    def settings_argument(p, what: str):
        p.add_argument("--settings", metavar="FILE",
                       help=f"a settings file (JSON: a filter and its settings by name in SI, as `imulink allan "
                            f"--settings FILTER --write FILE` writes it): {what}")

    def port_arguments(p):
        p.add_argument("port", metavar="PORT", help="serial device (/dev/ttyACM0, COM3) or pyserial URL "
                                                     "(socket://HOST:PORT, rfc2217://HOST:PORT, loop://)")
        p.add_argument("--baud", type=_baud, default=DEFAULT_BAUD,
                       help=f"line rate of a real serial port (default: {DEFAULT_BAUD}; ignored by sockets and ptys)")

    def simulation_arguments(p, duration: float):
        p.add_argument("--scenario", choices=emulator.SCENARIOS,
                       help=f"simulated run (default: {emulator.NAV_SCENARIO} for --filter nav, rests for the "
                            f"others); {emulator.NAV_SCENARIO}: a drive with a GNSS receiver at 1 Hz and the "
                            f"barometer")
        p.add_argument("--duration", type=_positive_float, default=duration,
                       help=f"seconds of simulated data (default: {duration:g})")
        p.add_argument("--rate", type=_positive_float, default=100.0, help="sample rate in Hz (default: 100)")
        p.add_argument("--seed", type=_seed, default=0, help="seed of the simulation (default: 0)")
        p.add_argument("--filter", default="eskf", choices=list(core.BOARD_FILTERS),
                       help="filter active at start-up (default: eskf)")

    def target_arguments(p):
        p.add_argument("--target", choices=("native", "qemu"), default="native",
                       help="the firmware as a native process (default) or its ARM image in QEMU's netduinoplus2")
        p.add_argument("--image", metavar="FILE", help="firmware to run instead of the built one "
                                                       "(the native executable or the QEMU ELF)")

    def front_arguments(p, what: str, baud: bool = True):
        where = p.add_mutually_exclusive_group()
        where.add_argument("--tcp", type=_tcp_port, nargs="?", const=0, metavar="PORT",
                           help=f"serve {what} on 127.0.0.1:PORT instead of a pty (no PORT: any free port)")
        where.add_argument("--serial", metavar="URL", help=f"serve {what} on this serial port or pyserial URL (e.g. "
                                                           "one end of a null-modem cable)")
        if baud:
            p.add_argument("--baud", type=_baud, default=DEFAULT_BAUD,
                           help=f"line rate for --serial (default: {DEFAULT_BAUD})")

    def min_verified_argument(p, what: str):
        p.add_argument("--min-verified", type=_probability, default=hil.MIN_VERIFIED, metavar="FRACTION",
                       help=f"the least share of {what} that must be verified for a bit-exact pass (default: "
                            f"{hil.MIN_VERIFIED:g}); below it the verdict is \"not proven\" and the exit status 1, "
                            "even when every verified one is identical")

    def fault_arguments(p):
        p.add_argument("--schema-hash", type=_u32, default=None,
                       help="rewrite HELLO to report this schema hash (a board built from another protocol definition)")
        faults = p.add_argument_group("fault injection (board-to-host bytes; deterministic for a seed)")
        faults.add_argument("--drop-byte", type=_probability, default=0.0, metavar="P",
                            help="probability that each byte is dropped")
        faults.add_argument("--flip-bit", type=_probability, default=0.0, metavar="P",
                            help="probability that each byte has a bit flipped")
        faults.add_argument("--garbage", type=_probability, default=0.0, metavar="P",
                            help="probability that random bytes precede a frame")
        faults.add_argument("--stall", type=_probability, default=0.0, metavar="P",
                            help="probability that the board goes silent (both ways) before a frame")
        faults.add_argument("--stall-duration", type=_non_negative_float, default=0.05, metavar="S",
                            help="length of a stall in s (default: 0.05)")
        faults.add_argument("--fault-seed", type=_seed, default=0, metavar="N", help="seed of the faults (default: 0)")

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
    _json_argument(p, "the report")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser(
        "emulate", help="run an emulated board (native or QEMU) on a pty, a TCP port or a serial port",
        description="Run an emulated board until Ctrl-C: the firmware application itself, as a native process "
                    "(default) or as its ARM image in QEMU (--target qemu), its sensors fed by the simulator, on "
                    "a pty (default; its path is printed), a TCP port (socket://127.0.0.1:PORT is printed) or a "
                    "serial port. Every imulink command works against it. Fault options put a proxy in front "
                    "that damages what the board sends, to test a host.")
    simulation_arguments(p, 600.0)
    target_arguments(p)
    front_arguments(p, "the board")
    p.add_argument("--fast", action="store_true", help="a sample whenever the host has read the last ones "
                                                       "(default: real time)")
    p.add_argument("--profile", type=_profile, default=DEFAULT_PROFILE,
                   help=f"the board's sensor profile, which it states in HELLO (default: gy86-default; "
                        f"profiles: {_profile_list()})")
    fault_arguments(p)
    settings_argument(p, "the board starts with them (its filter active, instead of --filter)")
    p.set_defaults(func=_cmd_emulate)

    p = sub.add_parser(
        "proxy", help="put a fault-injecting proxy in front of any board",
        description="Hold PORT (a real board, an emulated one, any pyserial URL) open and serve it on a pty "
                    "(default; its path is printed), a TCP port or a serial port, passing bytes both ways. The "
                    "fault options damage what the board sends (dropped bytes, flipped bits, garbage, stalls) "
                    "and --schema-hash rewrites its HELLO: a host's error handling tested on a real board.")
    port_arguments(p)
    front_arguments(p, "the proxy", baud=False)
    fault_arguments(p)
    p.set_defaults(func=_cmd_proxy)

    p = sub.add_parser(
        "flash", help="put a firmware image on the board (UART bootloader or SWD), verified",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Flash IMAGE (ELF, Intel HEX, or .bin with --address) and check that what runs is what was\n"
                    "built: the image's identification block (board, chip, version, schema hash) must suit the\n"
                    "chip, only the sectors it needs are erased, every byte is read back, and after the start (at\n"
                    "the image's own vector table) the firmware's HELLO must report the image's board, version and\n"
                    "schema hash. An image flashed with --force that is not imulink's is started, not asked for one.\n\n"
                    "PORT is one of:\n"
                    "  /dev/ttyUSB0, COM3, ...   the serial port wired to USART1 (PA9/PA10): the chip's system\n"
                    "                            bootloader (AN3155), at --baud; the same port carries the\n"
                    "                            firmware's HELLO afterwards\n"
                    "  swd                       over SWD with pyOCD (pip install 'imulink[swd]') or openocd\n"
                    "  pyocd[:PROBE] | openocd   that SWD tool (PROBE: the probe's serial number)\n\n"
                    "Into the bootloader (--enter): manual = BOOT0 high and a reset by hand; command = the board\n"
                    "runs imulink firmware, which gets ENTER_BOOTLOADER; dtr-rts = the adapter's DTR drives NRST\n"
                    "and RTS drives BOOT0. docs/flashing.md has the wiring and troubleshooting.\n"
                    "Without PORT, --dry-run checks the image alone.")
    p.add_argument("image", metavar="IMAGE", help="firmware image: .elf, .hex or .bin")
    p.add_argument("port", metavar="PORT", nargs="?", help="serial port of the UART bootloader, or swd / pyocd / openocd")
    p.add_argument("--method", choices=("uart", "pyocd", "openocd"), help="how to flash (default: from PORT)")
    p.add_argument("--address", type=_u32, help="load address of a raw .bin image (e.g. 0x08000000)")
    p.add_argument("--enter", choices=("manual", "command", "dtr-rts"), default="manual",
                   help="how the board gets into its bootloader (default: manual)")
    p.add_argument("--baud", type=_baud, default=115200, help="bootloader baud rate (default: 115200, AN3155's highest)")
    p.add_argument("--link-baud", type=_baud, default=DEFAULT_BAUD,
                   help=f"the firmware's link rate, for its HELLO after the start (default: {DEFAULT_BAUD})")
    p.add_argument("--link", metavar="PORT", help="SWD: the board's serial port, to check its HELLO after the start")
    p.add_argument("--target", default="stm32f407vg",
                   help="SWD target: pyOCD's target name (needs its pack: `pyocd pack install stm32f407vg`); for "
                        "openocd a chip name (its family's target/stm32f4x.cfg) or a .cfg file (default: stm32f407vg)")
    p.add_argument("--interface", default="interface/stlink.cfg",
                   help="openocd: the probe's interface config, a name (cmsis-dap, jlink) or a .cfg path "
                        "(default: interface/stlink.cfg)")
    p.add_argument("--no-verify", action="store_true", help="do not read the flash back")
    p.add_argument("--no-start", action="store_true", help="leave the board in its bootloader (no Go, no HELLO check)")
    p.add_argument("--dry-run", action="store_true", help="check the image and the chip, write nothing")
    p.add_argument("--force", action="store_true",
                   help="flash an image without identification, for another board, or of another schema")
    p.add_argument("--unprotect", action="store_true",
                   help="clear readout protection if it is on: the chip ERASES ITS WHOLE FLASH first")
    p.set_defaults(func=_cmd_flash)

    p = sub.add_parser(
        "settings", help="a board's filter settings: list them, set some by name, keep them in a file",
        description="Read the active filter's settings from the board (its own table: names, units, fixed-point "
                    "formats) and print them in SI units. NAME=VALUE arguments set settings first (SET_SETTING in "
                    "the board's format, then all are read back; the filter restarts with each), --filter makes "
                    "another filter active, --load gives the board a settings file (its filter and values), "
                    "--save writes what the board then runs with to a settings file (record, inject, emulate and "
                    "core.run take it with --settings FILE). A value the board refuses ends the command with its "
                    "reason; the settings set before it stay.")
    p.add_argument("port", metavar="PORT", help="serial device or pyserial URL of the board")
    p.add_argument("assignments", metavar="NAME=VALUE", nargs="*", help="settings to set, in SI units")
    p.add_argument("--filter", choices=list(core.BOARD_FILTERS), help="make this filter active first")
    p.add_argument("--load", metavar="FILE", help="give the board the settings of FILE (and make its filter active)")
    p.add_argument("--save", metavar="FILE", help="write the board's settings to FILE (a settings file)")
    p.add_argument("--baud", type=_baud, default=DEFAULT_BAUD,
                   help=f"line rate of a real serial port (default: {DEFAULT_BAUD}; ignored by sockets and ptys)")
    _json_argument(p, "the filter and its settings")
    p.set_defaults(func=_cmd_settings)

    p = sub.add_parser(
        "ports", help="list the serial ports and what is behind each",
        description="List the serial ports (pyserial's list_ports) with their USB VID:PID, description and a "
                    "guess of what is behind each (ST-Link virtual COM port, CP210x, CH340, FTDI, ...). --probe "
                    "also asks each one whether an imulink board answers (this writes a GET_VERSION frame to "
                    "every port).")
    p.add_argument("--probe", action="store_true", help="ask each port for an imulink HELLO (writes to the ports)")
    p.set_defaults(func=_cmd_ports)

    p = sub.add_parser(
        "record", help="record a board's stream to a file",
        description="Connect (GET_VERSION -> HELLO, schema hash checked), write the board's HELLO, STATUS and "
                    "every setting of its active filter into the recording, restart the filter so the "
                    "recording starts at sample 0, then stream and capture every received byte with its host "
                    "time until --duration, the end of the board's stream, or Ctrl-C (exit status 130). The file "
                    "is append-only and flushed as it grows: after a crash, a disconnect, a silent board or a "
                    "full disk everything received before is kept, and the command ends with one line saying "
                    "so (exit status 2). The file takes its name only once the board has answered. After a lost "
                    "SAMPLE the filter is restarted (unless --no-resync), so that the rest of the recording can "
                    "still be verified bit for bit.")
    port_arguments(p)
    p.add_argument("--output", "-o", required=True, help="recording file to write (e.g. run.imulog); an existing "
                                                          "file is refused unless --force")
    p.add_argument("--force", action="store_true", help="replace an existing output file (once the board has "
                                                        "answered: a wrong port leaves it untouched)")
    p.add_argument("--duration", type=_positive_float, help="seconds to record (default: until the stream ends "
                                                           "or Ctrl-C)")
    p.add_argument("--silence-timeout", type=_positive_float, metavar="S",
                   help=f"seconds without a frame after which the board counts as silent: the recording ends "
                        f"with an error (default: {hil.SILENCE_MIN_S:g} s or {hil.SILENCE_PERIODS} sample periods "
                        "at the board's rate, whichever is longer)")
    p.add_argument("--profile", type=_profile, default=None,
                   help=f"refuse a board that states another sensor profile than this one, before a file is "
                        f"written (default: whatever the board states; profiles: {_profile_list()})")
    p.add_argument("--no-resync", action="store_true", help="never restart the filter after a lost sample")
    p.add_argument("--listen", action="store_true",
                   help="record a board that another client commands (the TCP front of imulink emulate or imulink "
                        "proxy takes several clients: the first commands, the others listen) without sending it "
                        "anything; estimates verify from the next filter run that starts at sample 0")
    p.add_argument("--reconnect", type=_reconnect_wait, default=hil.RECONNECT_S, metavar="S",
                   help=f"wait up to S seconds for a board that went away (its port failed: a USB re-enumeration) "
                        f"or started again (a reset) to come back, then go on in a new segment of the same file "
                        f"(default: {hil.RECONNECT_S:g}; 0: end the recording)")
    _json_argument(p, "the summary")
    settings_argument(p, "the board gets them (its filter made active) before recording")
    p.set_defaults(func=_cmd_record)

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
    _json_argument(p, "the comparison and the outputs written")
    p.set_defaults(func=_cmd_replay)

    p = sub.add_parser(
        "plot", help="a recording as a figure (PNG or SVG): sensors, attitudes, differences, events",
        description="Draw a recording to one figure, without a display: the raw sensors in SI units; the Euler "
                    "angles of the board, the host fixed build and the float twin; the board-vs-host and "
                    "fixed-vs-float differences; the gyro-bias estimate; with filter restarts (dashed lines), lost "
                    "samples (red ticks), estimates the host could not verify (grey) or that differ (red dots) "
                    "marked, and the bit-exact verdict in the title. The format follows the name (.png, .svg); "
                    "needs matplotlib: pip install 'imulink[plot]'.")
    p.add_argument("file", metavar="FILE", help="recording written by `imulink record` or `imulink demo`")
    p.add_argument("--output", "-o", required=True, metavar="FILE.png|FILE.svg", help="the figure to write")
    p.set_defaults(func=_cmd_plot)

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
    _json_argument(p, "the comparison")
    p.set_defaults(func=_cmd_compare)

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
                   help="serial device or pyserial URL of a board, or a recording to replay")
    p.add_argument("--baud", type=_baud, default=DEFAULT_BAUD,
                   help=f"line rate of a real serial port (default: {DEFAULT_BAUD})")
    p.add_argument("--profile", type=_profile, default=None,
                   help=f"refuse a board that states another sensor profile than this one (default: whatever "
                        f"the board states; profiles: {_profile_list()})")
    p.add_argument("--emulate", action="store_true", help="start an emulated board (the native firmware) and show it")
    p.add_argument("--listen", action="store_true",
                   help="show a board another client commands (the TCP front of imulink emulate or imulink proxy "
                        "takes several clients) without sending it anything; its controls are then off")
    simulation_arguments(p, 600.0)
    p.add_argument("--speed", type=_positive_float, default=1.0, help="replay speed of a recording (default: 1)")
    p.add_argument("--screenshot", metavar="FILE", help="write the window to FILE (PNG) after --exit-after "
                                                        "seconds (default 5), then exit")
    p.add_argument("--exit-after", type=_positive_float, metavar="S", help="close the window after S seconds")
    p.add_argument("--no-3d", action="store_true",
                   help="no 3D board view (it needs OpenGL; without it the window shows the horizon alone)")
    p.set_defaults(func=_cmd_monitor)

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
    _json_argument(p, "the report")
    p.set_defaults(func=_cmd_inject)


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


if __name__ == "__main__":
    sys.exit(main())
