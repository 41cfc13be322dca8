"""`imulink farm`: the boards of a labgrid farm (needs imulink[lab])."""
from __future__ import annotations

import argparse
import sys

from imulink import core
from imulink.board import lab
from imulink.cli.common import (
    EXIT_MISMATCH,
    UsageError,
    coordinator_argument,
    json_argument,
    min_verified_argument,
    non_negative_float,
    one_line_errors,
    place_wait_argument,
    positive_float,
    print_json,
    text_columns,
    worker_count,
)
from imulink.hil import farm

#: Places verified at once unless --jobs says: each is a worker process (an interpreter, the
#: host build replaying its board), and a board waits on its link far more than it computes.
DEFAULT_JOBS = 16


def _tags(texts: list[str]) -> dict[str, str]:
    tags = {}
    for text in texts:
        key, sep, value = text.partition("=")
        if not sep or not key:
            raise UsageError(f"{text!r} is not a tag KEY=VALUE (e.g. board=stm32f407-gy86)")
        tags[key] = value
    return tags


@one_line_errors
def run_verify(args) -> int:
    if args.flash and args.image is None:
        raise UsageError("--flash flashes --image ELF into every place's board: give the image")
    if args.image is not None:
        farm.image_identity(args.image)  # an image without identification is a usage error, before any place
    places = farm.select_places(args.places, _tags(args.tag), args.coordinator, args.timeout)
    jobs = args.jobs or min(len(places), DEFAULT_JOBS)
    names = ", ".join(p.name for p in places)
    print(f"{'flashing and ' if args.flash else ''}verifying {len(places)} places ({names}), "
          f"{min(jobs, len(places))} at a time, with {args.input}", file=sys.stderr)

    def progress(done: int, row: dict) -> None:
        outcome = row["error"] or row["verdict"]
        print(f"[{done}/{len(places)}] {row['place']}: {outcome}", file=sys.stderr, flush=True)

    rows = farm.verify_places([p.name for p in places], jobs, progress, input_spec=args.input, image=args.image,
                              flash=args.flash, filter_name=args.filter, min_verified=args.min_verified,
                              coordinator=args.coordinator, wait_s=args.place_wait, timeout_s=args.timeout)
    if args.json:
        print_json(farm.farm_json(rows, args.input, args.image))
    else:
        print(farm.format_table(rows))
    return 0 if all(r["passed"] for r in rows) else EXIT_MISMATCH


@one_line_errors
def run_places(args) -> int:
    places = farm.select_places(args.places, _tags(args.tag), args.coordinator, args.timeout)
    if args.json:
        print_json({"places": [{"name": p.name, "tags": p.tags, "acquired": p.acquired, "comment": p.comment}
                               for p in places]})
        return 0
    rows: list[tuple[str, ...]] = [("place", "tags", "acquired by")]
    rows += [(p.name, ",".join(f"{k}={v}" for k, v in sorted(p.tags.items())) or "-", p.acquired or "-")
             for p in places]
    print(text_columns(rows))
    return 0


class _DeprecatedWait(argparse.Action):
    """`farm verify --wait S`: --place-wait's old name, kept working, with a one-line warning."""

    def __call__(self, parser, namespace, values, option_string=None):
        print("imulink: warning: farm verify --wait is deprecated: it is --place-wait, as in every other command",
              file=sys.stderr)
        setattr(namespace, self.dest, values)


def _common(p, default_places: str) -> None:
    p.add_argument("--places", default=default_places, metavar="GLOB",
                   help=f"the places whose name matches this glob pattern (quoted; default: {default_places!r})")
    p.add_argument("--tag", action="append", default=[], metavar="KEY=VALUE",
                   help="only places with this tag (repeatable: all of them)")
    coordinator_argument(p, "each request within --timeout S")
    p.add_argument("--timeout", type=positive_float, default=lab.TIMEOUT_S, metavar="S",
                   help=f"seconds the coordinator has to answer each request (default: {lab.TIMEOUT_S:g})")


def add_parser(sub) -> None:
    p = sub.add_parser("farm", help="the boards of a labgrid farm: list them, verify many at once",
                       description="The places of a labgrid coordinator (a lab's shared boards, docs/farm.md); "
                                   "needs the lab extra: pip install 'imulink[lab]'.")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    v = actions.add_parser(
        "verify", help="verify every matching place's board in parallel, one table",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="For every place that matches --places (and --tag), in parallel, each in a worker process:\n"
                    "acquire the place (locked against every other job; released at the end, also on errors\n"
                    "and Ctrl-C), with --flash flash --image into its board (through the place's BOOT0 and\n"
                    "reset lines when it has them, else the imulink firmware's ENTER_BOOTLOADER), read its\n"
                    "board's HELLO, check it runs --image's firmware (board, version, protocol schema), then\n"
                    "inject --input's samples and compare every estimate with the host build bit for bit\n"
                    "(imulink inject) and the attitude with the simulated truth. One table: place, board,\n"
                    "firmware, flashed (with --flash), samples, bit-exact, accuracy (RMS attitude error\n"
                    "after the settling time), errors. A place that fails (held by another job, board gone\n"
                    "mid-run, no serial port, a failed flash, an emulated board that cannot be flashed) is\n"
                    "its own row; the others finish.\n\n"
                    "exit status: 0 every board proven bit-exact; 1 any not proven (a difference, too few\n"
                    "verified, or an error on its place); 2 no place to verify, coordinator down, bad\n"
                    "arguments; 130 interrupted (every acquired place is released).")
    _common(v, "*")
    v.add_argument("--image", metavar="ELF", help="firmware image (.elf, .hex, .bin with an imulink identification "
                                                  "block) every board must run")
    v.add_argument("--flash", action="store_true",
                   help="flash --image into each place's board first, within the same acquisition: through the "
                        "place's BOOT0 and reset lines (or power switch) when it has them, else the imulink "
                        "firmware's ENTER_BOOTLOADER (imulink flash --enter lines / command)")
    v.add_argument("--input", "-i", default=farm.DEFAULT_INPUT,
                   help=f"what to inject into each board, as `imulink inject --input` takes it (default: "
                        f"{farm.DEFAULT_INPUT}: 30 s of rests at 100 Hz)")
    v.add_argument("--filter", choices=list(core.FILTERS), help="select this filter first (default: each board's "
                                                                 "active filter)")
    v.add_argument("--jobs", type=worker_count, default=0, metavar="N",
                   help=f"places verified at once, each in a worker process (default: all of them, up to "
                        f"{DEFAULT_JOBS})")
    place_wait_argument(v, "that place fails at once, naming who holds it")
    v.add_argument("--wait", type=non_negative_float, dest="place_wait", action=_DeprecatedWait, metavar="S",
                   help=argparse.SUPPRESS)  # its name until every command's --place-wait said the same
    min_verified_argument(v, "the injected samples (answered and compared)")
    json_argument(v, "the table")
    v.set_defaults(func=run_verify)
    ls = actions.add_parser("places", help="list the coordinator's places, their tags and who holds them",
                            description="List the places of the labgrid coordinator that match --places and "
                                        "--tag: name, tags, who has acquired it.")
    _common(ls, "*")
    json_argument(ls, "the places")
    ls.set_defaults(func=run_places)
