"""The same verification over many boards of a labgrid farm at once (`imulink farm verify`).

Each matching place is verified in a worker process of its own, so one board that fails,
hangs up or is held by another job is that place's row and never stops the others:

1. the place is acquired (imulink.board.lab.held_place: locked against every other client
   of the coordinator, released at the end whatever happens);
2. with `flash`, the image is flashed into the held place's board first (no second
   acquisition): through the chip's UART bootloader on the place's serial port, entered by
   the place's BOOT0 and reset lines (or power switch) when it has them, else by the
   imulink firmware's ENTER_BOOTLOADER (imulink.board.flash.flash_uart); an emulated board
   (native, QEMU) cannot be flashed and is its place's error;
3. the board's HELLO is read; with an image, the board must run that image's firmware
   (board, version, protocol schema). Without `flash`, a board is flashed with
   `imulink flash IMAGE lg://PLACE` before, and an emulated board runs the image it was
   started with;
4. the injection test (imulink.hil.injection.inject): every sample of a simulated run is
   injected and every estimate compared bit for bit with the host build, and the attitude
   compared with the simulated truth.

Workers are started with the spawn method: the parent's gRPC session to the coordinator
must not be forked.
"""
from __future__ import annotations

import fnmatch
import multiprocessing
import signal
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from imulink.board import flash as flashing
from imulink.board import lab
from imulink.board.link import Link, LinkError
from imulink.errors import ImulinkError
from imulink.hil.common import rows_in_order, verdict_mark
from imulink.hil.comparison import MIN_VERIFIED
from imulink.hil.injection import inject, load_injection_input
from imulink.io.firmware_image import FirmwareImage, Identification, ImageError, load_image

#: What each board gets when nothing else is asked: 30 s of rests (10 s to settle, 20 s of
#: attitude to compare with the truth), 3000 samples at 100 Hz.
DEFAULT_INPUT = "sim:rests:30"


class FarmError(ImulinkError):
    """Arguments that name no place to verify, or an image that cannot be checked."""


def image_identity(path: str | Path) -> Identification:
    """The identification block of a firmware image (FarmError without one)."""
    try:
        image = load_image(path)
    except ImageError as exc:
        raise FarmError(str(exc)) from None
    if image.identification is None:
        raise FarmError(f"{path} has no imulink identification block: nothing to check a board's HELLO against")
    return image.identification


def select_places(pattern: str, tags: dict[str, str], coordinator: str | None = None,
                  timeout_s: float = lab.TIMEOUT_S) -> list[lab.PlaceInfo]:
    """The coordinator's places whose name matches the glob `pattern` and that carry every tag
    of `tags`; FarmError when none does (naming the places there are)."""
    with lab.Coordinator(coordinator, timeout_s) as session:
        every = session.places()
        address = session.address
    chosen = [p for p in every if fnmatch.fnmatchcase(p.name, pattern)
              and all(p.tags.get(k) == v for k, v in tags.items())]
    if not chosen:
        wanted = repr(pattern) + "".join(f" with {k}={v}" for k, v in tags.items())
        known = ", ".join(p.name for p in every) or "none"
        raise FarmError(f"no place matches {wanted} on the labgrid coordinator at {address} (places: {known})")
    return chosen


def _hello_firmware(hello: dict) -> str:
    return f"{hello['firmware_major']}.{hello['firmware_minor']}.{hello['firmware_patch']}"


def _check_image(hello: dict, ident: Identification) -> None:
    """FarmError unless the board's HELLO is the image's: board, firmware version, schema."""
    runs = f"{hello['board']} {_hello_firmware(hello)} (schema 0x{hello['schema_hash']:08X})"
    wants = f"{ident.board} {ident.version_text} (schema 0x{ident.schema_hash:08X})"
    same = (hello["board"] == ident.board and tuple(ident.firmware_version) == (
        hello["firmware_major"], hello["firmware_minor"], hello["firmware_patch"])
        and hello["schema_hash"] == ident.schema_hash)
    if not same:
        raise FarmError(f"the board runs {runs}, the image is {wants}: flash it first "
                        "(imulink flash IMAGE lg://PLACE)")


def _unverified_row(place: str, flash: bool = False) -> dict:
    """A place's row before anything is known of its board (verify_place's keys)."""
    return {"place": place, "port": None, "board": None, "firmware": None, "image": None,
            "flashed": "no" if flash else None, "samples": 0, "answered": 0, "identical": 0, "bit_exact": False,
            "passed": False, "verdict": None, "accuracy": None, "first_difference": None, "error": None}


#: Board names (HELLO) of emulated boards: they run the image they were started with and
#: have no bootloader to flash through.
EMULATED_BOARDS = ("native",)


def _is_emulated(board: str) -> bool:
    return board in EMULATED_BOARDS or board.startswith(flashing.EMULATED_BOARD_PREFIX)


def flash_place(held: lab.HeldPlace, image: FirmwareImage, log: Callable[[str], None]) -> flashing.FlashResult:
    """Flash `image` into the board of held place `held` (acquired with its lines): through its
    BOOT0 and reset lines (or power switch) when it has them, else by the imulink firmware's
    ENTER_BOOTLOADER. FarmError for an emulated board (checked by its HELLO first: it has no
    bootloader) or a board that does not answer; FlashError as flash_uart."""
    lines = held.lines if held.lines is not None and held.lines.usable else None
    if lines is None:  # the firmware must take the board into its bootloader: is it one that can?
        try:
            with Link(held.url, held.speed) as link:
                hello = link.connect(timeout=1.0, attempts=2)
        except LinkError as exc:
            raise FarmError(f"cannot flash: the place has no BOOT0 and reset lines, and no imulink firmware answers "
                            f"to take the board into its bootloader ({exc})") from None
        if _is_emulated(hello["board"]):
            raise FarmError(f"cannot flash: the board is the emulated {hello['board']} board, which runs the image "
                            "it was started with (no bootloader to flash through)")
    try:
        return flashing.flash_uart(image, held.url, enter="lines" if lines is not None else "command",
                                   link_baud=held.speed, lines=lines, log=log)
    except (ImulinkError, OSError) as exc:
        raise FarmError(f"not flashed: {exc}") from None


def verify_place(place: str, *, input_spec: str = DEFAULT_INPUT, image: str | None = None, flash: bool = False,
                 filter_name: str | None = None, min_verified: float = MIN_VERIFIED,
                 coordinator: str | None = None, wait_s: float = 0.0, timeout_s: float = lab.TIMEOUT_S) -> dict:
    """One place's row: {"place", "port", "board", "firmware", "image" (None, or "matches"),
    "flashed" ("yes", "no", or None without `flash`), "samples", "answered", "identical",
    "bit_exact", "passed", "verdict", "accuracy" (RMS deg after the settling time, or None),
    "first_difference", "error" (None, or the one line that says why the place could not be
    verified: it then fails)}. With `flash`, `image` is flashed into the place's board first
    (flash_place), within the same acquisition."""
    row = _unverified_row(place, flash)
    try:
        source = load_injection_input(input_spec)
        ident = image_identity(image) if image is not None else None
        if flash and image is None:
            raise FarmError("flashing needs an image (--image ELF)")
        firmware = _flash_image(image) if flash else None
        with lab.held_place(f"{lab.SCHEME}{place}", coordinator, timeout_s, wait_s, lines=flash) as held:
            row["port"] = held.url
            if firmware is not None:
                flash_place(held, firmware, log=lambda line: print(f"{place}: {line}", file=sys.stderr, flush=True))
                row["flashed"] = "yes"
            with Link(held.url, held.speed) as link:
                hello = link.connect()
            row.update(board=hello["board"], firmware=_hello_firmware(hello))
            if ident is not None:
                _check_image(hello, ident)
                row["image"] = "matches"
            result = inject(held.url, source, baud=held.speed, filter_name=filter_name, min_verified=min_verified)
    except (ImulinkError, OSError) as exc:
        row["error"] = str(exc)
        return row
    verdict = result.verdict
    accuracy = result.accuracy
    row.update(samples=result.samples, answered=result.answered, identical=result.identical,
               bit_exact=result.bit_exact, passed=verdict.passed, verdict=str(verdict),
               accuracy=None if not accuracy else {"rms_total_deg": accuracy["total"],
                                                   "rms_heading_deg": accuracy["heading"],
                                                   "rms_inclination_deg": accuracy["inclination"]},
               first_difference=result.first_difference)
    return row


def _flash_image(path: str | None) -> FirmwareImage:
    try:
        return load_image(path)
    except ImageError as exc:
        raise FarmError(str(exc)) from None


def _worker_start() -> None:
    """A worker's SIGTERM is a KeyboardInterrupt, as in the command: its place is released."""
    signal.signal(signal.SIGTERM, _interrupt)


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def verify_places(places: Sequence[str], jobs: int, progress: Callable[[int, dict], None] | None = None,
                  **options) -> list[dict]:
    """verify_place for every place, `jobs` worker processes at a time; rows in the order of
    `places`; `progress(done, row)` as each place finishes. `options`: verify_place's."""
    pool = ProcessPoolExecutor(max_workers=max(1, min(jobs, len(places))),
                               mp_context=multiprocessing.get_context("spawn"), initializer=_worker_start)
    flash = bool(options.get("flash"))
    return rows_in_order(pool, verify_place, places, progress,
                         failed=lambda place, exc: _failed_row(place, exc, flash), **options)


def _failed_row(place, exc: BaseException, flash: bool = False) -> dict:
    """The row of a place whose worker died (killed, out of memory)."""
    return {**_unverified_row(place, flash), "error": f"the worker verifying it failed: {exc or type(exc).__name__}"}


def format_table(rows: Sequence[dict]) -> str:
    """One line per place and a summary: place, board, firmware, (flashed, when any place was
    to be flashed), samples, bit-exact, accuracy (RMS total, deg), and the error or what was not
    identical."""
    flashing_rows = any(r.get("flashed") is not None for r in rows)
    header = ("place", "board", "firmware", *(("flashed",) if flashing_rows else ()), "samples", "bit-exact",
              "accuracy", "errors")
    lines = [header]
    for r in rows:
        accuracy = f"{r['accuracy']['rms_total_deg']:.3f} deg" if r["accuracy"] else "-"
        detail = r["error"] or ""
        if not detail and r["first_difference"]:
            d = r["first_difference"]
            detail = f"first difference: sample {d['sample_index']}: {d['field']}"
        elif not detail and not r["passed"]:
            detail = r["verdict"] or ""
        flashed = (r.get("flashed") or "-",) if flashing_rows else ()
        lines.append((r["place"], r["board"] or "-", r["firmware"] or "-", *flashed, str(r["samples"]), verdict_mark(r),
                      accuracy, detail))
    widths = [max(len(line[k]) for line in lines) for k in range(len(header))]
    text = ["  ".join(cell.ljust(w) for cell, w in zip(line, widths)).rstrip() for line in lines]
    passed = sum(r["passed"] for r in rows)
    errors = sum(r["error"] is not None for r in rows)
    text.append(f"{len(rows)} places: {passed} proven bit-exact, {len(rows) - passed - errors} not, "
                f"{errors} could not be verified")
    return "\n".join(text)


def farm_json(rows: Sequence[dict], input_spec: str, image: str | None) -> dict:
    """What `imulink farm verify --json` prints."""
    passed = sum(r["passed"] for r in rows)
    errors = sum(r["error"] is not None for r in rows)
    return {"input": input_spec, "image": image, "places": list(rows), "count": len(rows), "passed": passed,
            "failed": len(rows) - passed - errors, "errors": errors}
