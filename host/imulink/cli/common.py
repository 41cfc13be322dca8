"""What every command shares: exit statuses, the one-line error, argument types
and the arguments several commands take."""
from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import time

from imulink import core, hil
from imulink.board import emulator, lab
from imulink.board.emulator import NAV_SCENARIO
from imulink.board.link import DEFAULT_BAUD
from imulink.board.proxy import FaultConfig
from imulink.core.counts import PROFILES, describe_profile
from imulink.errors import ImulinkError
from imulink.io import settings_file
from imulink.progress import StatusLine

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


class UsageError(ImulinkError):
    """Arguments that do not make sense together (each alone passed its type check)."""


class Parser(argparse.ArgumentParser):
    """Usage errors in one line, like every other error."""

    def error(self, message):
        self.exit(EXIT_ERROR, f"imulink: error: {message} (see `{self.prog} --help`)\n")


def one_line_errors(func):
    """Run a command: an ImulinkError (every error imulink raises for a user) or an OSError
    prints `imulink: error: ...` and exits 2; Ctrl-C and SIGTERM exit 130."""

    def run(args) -> int:
        signal.signal(signal.SIGTERM, interrupt)  # `kill` stops a command as cleanly as Ctrl-C
        try:
            with held_port(args):
                return func(args)
        except (ImulinkError, OSError) as exc:
            print(f"imulink: error: {exc}", file=sys.stderr)
            return EXIT_ERROR
        except KeyboardInterrupt:
            print("imulink: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED

    run.__doc__ = func.__doc__
    return run


def interrupt(signum, frame):
    raise KeyboardInterrupt


@contextlib.contextmanager
def held_port(args):
    """A command's PORT that is a labgrid place (lg://PLACE[/NAME]): the place is acquired
    for the whole command, `args.port` becomes its serial port's URL, and the place is
    released when the command ends, however it ends (imulink.board.lab.held_place). A command
    that wants the place's debug probe instead (flash --method openocd) gets it as
    `args.held_probe` and `args.port` None (imulink.board.lab.held_probe). A PORT that is a
    labgrid environment (lg-env:FILE[#TARGET]) is the place of its RemotePlace, held as
    above, or its serial port on this machine, used as that PORT. Any other PORT is left as
    it is."""
    attribute = getattr(args, "place_attribute", "port")  # calibrate mag: its INPUT may be a PORT
    given = address = getattr(args, attribute, None)
    coordinator, wait_s = getattr(args, "coordinator", None), getattr(args, "place_wait", 0.0)
    if lab.is_environment(address):
        board = lab.environment_board(address)
        if board.place is None:  # a serial port of this machine: no coordinator, nothing to hold
            print(f"imulink: {board.describe()}", file=sys.stderr)  # which port, as a place's line says
            setattr(args, attribute, board.url)
            try:
                yield
            finally:
                setattr(args, attribute, given)
            return
        # then the place as lg://PLACE; --coordinator still comes before the environment's, as in labgrid-client
        address, coordinator = board.place, coordinator or board.coordinator
    if not lab.is_place(address):
        yield
        return
    wants_probe = getattr(args, "place_probe", None)  # flash: whether it flashes through the place's probe
    if callable(wants_probe) and wants_probe(args):
        with lab.held_probe(address, coordinator, wait_s=wait_s) as probe:
            link = f"; the board's link {probe.link_url}" if probe.link_url else ""
            print(f"imulink: place {probe.place} acquired from {probe.coordinator}: its {probe.describe()}{link}",
                  file=sys.stderr)
            setattr(args, attribute, None)
            args.held_probe = probe
            try:
                yield
            finally:
                setattr(args, attribute, given)
                args.held_probe = None
        return
    wants_lines = getattr(args, "place_lines", None)  # flash: whether it drives the place's BOOT0 and reset
    lines = bool(wants_lines(args)) if callable(wants_lines) else False
    with lab.held_place(address, coordinator, wait_s=wait_s, lines=lines) as place:
        check = getattr(args, "place_check", None)  # what the command needs of the place, before it says it has it
        if check is not None:
            check(args, place)
        print(f"imulink: place {place.name} acquired from {place.coordinator}: {place.resource} at {place.url}",
              file=sys.stderr)
        setattr(args, attribute, place.url)
        args.held_place = place
        try:
            yield
        finally:
            setattr(args, attribute, given)
            args.held_place = None


def json_value(value):
    """`value` with every non-finite float as null: JSON has no NaN or infinity."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: json_value(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_value(item) for item in value]
    return value


def print_json(report: dict) -> None:
    """--json: the command's one JSON object, alone on stdout (progress and messages are on stderr)."""
    import json

    print(json.dumps(json_value(report), indent=1, allow_nan=False))


def json_argument(p, what: str) -> None:
    p.add_argument("--json", action="store_true",
                   help=f"print {what} as one JSON object on stdout (progress and messages on stderr; keys in "
                        "docs/cli.md)")


def text_columns(rows: list[tuple[str, ...]]) -> str:
    """Rows of cells as lines, each column as wide as its widest cell (names of any length line up)."""
    widths = [max(len(row[k]) for row in rows) for k in range(len(rows[0]))]
    return "\n".join(" ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows)


def assignments_of(texts: list[str]) -> dict[str, float]:
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


#: A job that ends within this many seconds shows no progress at all.
PROGRESS_AFTER_S = 2.0


def late_progress():
    """A status line on stderr (imulink.progress.StatusLine) that appears only once the job has run for
    PROGRESS_AFTER_S: returns (status, phase), phase(name) giving a (done, total) callback."""
    status, started = StatusLine(), time.monotonic()

    def phase(name: str):
        def report(done: int, total: int) -> None:
            if time.monotonic() - started >= PROGRESS_AFTER_S:
                status.update(f"{name}: {100.0 * done / max(total, 1):3.0f} %")
        return report

    return status, phase


def parse_filters(text: str, known=None) -> list[str]:
    """Filter names (comma-separated, or all) among `known` (default: the attitude filters)."""
    known = core.FILTERS if known is None else known
    names = [n.strip() for n in text.split(",") if n.strip()] if text != "all" else list(known)
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise UsageError(f"unknown filter(s) {', '.join(unknown) or repr(text)}; choose from "
                         f"{', '.join(known)} (comma-separated) or all")
    return names


def profile_list() -> str:
    return ", ".join(describe_profile(p) for p in PROFILES.values())


def profile_named(name: str):
    try:
        return PROFILES[name]
    except KeyError:
        raise argparse.ArgumentTypeError(f"unknown sensor profile {name!r}; choose from {', '.join(PROFILES)}") \
            from None


def in_range(parse, low, high, requirement: str):
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


positive_float = in_range(float, math.ulp(0.0), sys.float_info.max, "must be a positive finite number")
non_negative_float = in_range(float, 0.0, sys.float_info.max, "must be a finite number from 0")
probability = in_range(float, 0.0, 1.0, "must be a probability from 0 to 1")
seed_number = in_range(int, 0, 2**32 - 1, "must be an integer from 0 to 4294967295")
tcp_port = in_range(int, 0, 65535, "must be a TCP port from 0 to 65535 (0: any free port)")
baud_rate = in_range(int, 1, 100_000_000, "must be a baud rate from 1 to 100000000")
worker_count = in_range(int, 1, 256, "must be a number of workers from 1 to 256")
u32_number = in_range(lambda text: int(text, 0), 0, 0xFFFFFFFF,
                 "must be an integer from 0 to 0xFFFFFFFF (e.g. 0x1234ABCD)")


def fault_config(args):
    return FaultConfig(drop_byte=args.drop_byte, flip_bit=args.flip_bit, garbage=args.garbage, stall=args.stall,
                       stall_s=args.stall_duration, seed=args.fault_seed)


def serve_until_interrupted(describe: str, error) -> int:
    """Wait for Ctrl-C or SIGTERM (or a failure that `error()` reports); 0 when stopped by the user."""
    print(describe + " Ctrl-C stops it.", file=sys.stderr)
    try:
        while error() is None:
            time.sleep(0.2)
    except KeyboardInterrupt:
        return 0
    print(f"imulink: error: {error()}", file=sys.stderr)
    return EXIT_ERROR


def settings_from_file(args):
    """The --settings FILE of a command, loaded (None without it)."""
    if args.settings is None:
        return None

    return settings_file.load(args.settings)


def scenario_for(args, filter_name: str | None = None) -> str:
    """The emulated board's simulated run: --scenario, else the car drive for the nav filter
    (its GNSS receiver and barometer) and rests for the others."""
    if args.scenario is not None:
        return args.scenario
    return NAV_SCENARIO if (filter_name or args.filter) == "nav" else "rests"


def settings_argument(p, what: str):
    p.add_argument("--settings", metavar="FILE",
                   help=f"a settings file (JSON: a filter and its settings by name in SI, as `imulink allan "
                        f"--settings FILTER --write FILE` writes it): {what}")


#: What a PORT argument may be, for the commands' help.
PORT_HELP = ("serial device (/dev/ttyACM0, COM3), pyserial URL (socket://HOST:PORT, rfc2217://HOST:PORT, loop://), "
             "labgrid place (lg://PLACE[/RESOURCE], acquired for the command) or labgrid environment "
             "(lg-env:FILE[#TARGET]: its RemotePlace, or its serial port; docs/farm.md)")


def coordinator_argument(p, answers: str = f"within {lab.TIMEOUT_S:g} s", environment: bool = False) -> None:
    """--coordinator: the labgrid coordinator of the places, as labgrid's own tools find it
    (`environment`: a PORT lg-env:FILE may name one too, as labgrid-client takes it)."""
    option = "an lg-env: FILE's coordinator_address option, else " if environment else ""
    p.add_argument("--coordinator", metavar="HOST:PORT",
                   help=f"the labgrid coordinator (default: {option}$LG_COORDINATOR, else {lab.DEFAULT_COORDINATOR}); "
                        f"it must answer {answers}")


def place_wait_argument(p, refused: str = "refuse at once with who holds it") -> None:
    """--place-wait S: how long to wait for a place another job holds."""
    p.add_argument("--place-wait", type=non_negative_float, default=0.0, metavar="S",
                   help=f"wait up to S seconds for a place another job holds (default: 0, {refused})")


def place_arguments(p):
    """--coordinator and --place-wait: where a PORT lg://PLACE is looked up, how long to wait for it."""
    group = p.add_argument_group("labgrid places (a PORT lg://PLACE or lg-env:FILE; needs imulink[lab])")
    coordinator_argument(group, environment=True)
    place_wait_argument(group)


def port_arguments(p):
    p.add_argument("port", metavar="PORT", help=PORT_HELP)
    p.add_argument("--baud", type=baud_rate, default=DEFAULT_BAUD,
                   help=f"line rate of a real serial port (default: {DEFAULT_BAUD}; ignored by sockets and ptys)")
    place_arguments(p)


def simulation_arguments(p, duration: float):
    p.add_argument("--scenario", choices=emulator.SCENARIOS,
                   help=f"simulated run (default: {emulator.NAV_SCENARIO} for --filter nav, rests for the "
                        f"others); {emulator.NAV_SCENARIO}: a drive with a GNSS receiver at 1 Hz and the "
                        f"barometer")
    p.add_argument("--duration", type=positive_float, default=duration,
                   help=f"seconds of simulated data (default: {duration:g})")
    p.add_argument("--rate", type=positive_float, default=100.0, help="sample rate in Hz (default: 100)")
    p.add_argument("--seed", type=seed_number, default=0, help="seed of the simulation (default: 0)")
    p.add_argument("--filter", default="eskf", choices=list(core.BOARD_FILTERS),
                   help="filter active at start-up (default: eskf)")


def target_arguments(p):
    p.add_argument("--target", choices=("native", "qemu", "stm32f407"), default="native",
                   help="the firmware as a native process (default), its ARM image in QEMU's netduinoplus2, or the "
                        "reference board's image (the one that gets flashed) on the virtual STM32F407 + GY-86")
    p.add_argument("--image", metavar="FILE", help="firmware to run instead of the built one "
                                                   "(the native executable, the QEMU ELF, or for stm32f407 the "
                                                   "reference image as ELF, .hex or .bin)")


def front_arguments(p, what: str, baud: bool = True):
    where = p.add_mutually_exclusive_group()
    where.add_argument("--tcp", type=tcp_port, nargs="?", const=0, metavar="PORT",
                       help=f"serve {what} on 127.0.0.1:PORT instead of a pty (no PORT: any free port)")
    where.add_argument("--serial", metavar="URL", help=f"serve {what} on this serial port or pyserial URL (e.g. "
                                                       "one end of a null-modem cable)")
    if baud:
        p.add_argument("--baud", type=baud_rate, default=DEFAULT_BAUD,
                       help=f"line rate for --serial (default: {DEFAULT_BAUD})")


def min_verified_argument(p, what: str):
    p.add_argument("--min-verified", type=probability, default=hil.MIN_VERIFIED, metavar="FRACTION",
                   help=f"the least share of {what} that must be verified for a bit-exact pass (default: "
                        f"{hil.MIN_VERIFIED:g}); below it the verdict is \"not proven\" and the exit status 1, "
                        "even when every verified one is identical")


def fault_arguments(p):
    p.add_argument("--schema-hash", type=u32_number, default=None,
                   help="rewrite HELLO to report this schema hash (a board built from another protocol definition)")
    faults = p.add_argument_group("fault injection (board-to-host bytes; deterministic for a seed)")
    faults.add_argument("--drop-byte", type=probability, default=0.0, metavar="P",
                        help="probability that each byte is dropped")
    faults.add_argument("--flip-bit", type=probability, default=0.0, metavar="P",
                        help="probability that each byte has a bit flipped")
    faults.add_argument("--garbage", type=probability, default=0.0, metavar="P",
                        help="probability that random bytes precede a frame")
    faults.add_argument("--stall", type=probability, default=0.0, metavar="P",
                        help="probability that the board goes silent (both ways) before a frame")
    faults.add_argument("--stall-duration", type=non_negative_float, default=0.05, metavar="S",
                        help="length of a stall in s (default: 0.05)")
    faults.add_argument("--fault-seed", type=seed_number, default=0, metavar="N",
                        help="seed of the faults (default: 0)")


