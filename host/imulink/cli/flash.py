"""`imulink flash`."""
from __future__ import annotations

import argparse
import sys
import time

from imulink.board import flash
from imulink.board.flash import FlashError, swd
from imulink.board.flash.swd import available_methods
from imulink.board.link import DEFAULT_BAUD
from imulink.cli.common import baud_rate, one_line_errors, place_arguments, u32_number
from imulink.io.firmware_image import ImageError, load_image
from imulink.progress import Bars

SWD_PORTS = ("swd", "pyocd", "openocd")


def _flash_method(args) -> str:
    """uart, pyocd or openocd: --method, else from PORT (swd, pyocd[:PROBE], openocd, or a serial port)."""
    if args.method:
        return args.method

    if args.port is None:
        raise FlashError("give the serial port wired to the board's USART1 (PA9/PA10), or swd / pyocd / openocd "
                         "to flash over SWD (see imulink flash --help)")
    name = args.port.split(":", 1)[0]
    if name == "swd":
        found = [method for method, version in available_methods().items() if version]
        if not found:
            raise FlashError("no SWD tool found: pip install 'imulink[swd]' (pyOCD), or put openocd on the PATH")
        return found[0]
    return name if name in SWD_PORTS else "uart"


def _wants_place_lines(args) -> bool:
    """Whether a place's BOOT0 and reset lines are looked for: --enter lines, or no --enter (then
    they are the way in where the place has them)."""
    return args.enter in (None, "lines")


def _wants_place_probe(args) -> bool:
    """Whether a place is acquired for its debug probe (--method openocd) rather than its serial
    port. pyOCD cannot use a place's probe: said before the place is acquired."""
    if args.method == "pyocd":
        raise FlashError(swd.PYOCD_REMOTE)
    return args.method == "openocd"


def _check_place_lines(args, place) -> None:
    """--enter lines on a place without the lines: one line, before anything else is done."""
    if args.enter == "lines" and args.method in (None, "uart") and (place.lines is None or not place.lines.usable):
        missing = place.lines.missing() if place.lines is not None else f"place {place.name} has no lines"
        raise FlashError(f"{missing}; or choose another --enter (command: the board runs imulink firmware)")


def _entry(args) -> tuple[str, flash.BootLines | None]:
    """(--enter, the place's lines or None): --enter as given, else `lines` for a place that has
    a BOOT0 line and a reset line or power switch, else `manual`."""
    place = getattr(args, "held_place", None)
    lines = place.lines if place is not None else None
    if args.enter is None:
        return ("lines", lines) if lines is not None and lines.usable else ("manual", None)
    if args.enter != "lines":
        return args.enter, None
    if lines is None:
        raise FlashError("--enter lines drives a labgrid place's BOOT0 and reset lines: give the board as "
                               "lg://PLACE (docs/farm.md), or choose another --enter")
    return "lines", lines


@one_line_errors
def run(args) -> int:
    try:
        image = load_image(args.image, args.address)
    except ImageError as exc:
        raise FlashError(str(exc)) from None
    method = _flash_method(args) if args.port is not None or args.method or not args.dry_run else None
    enter, lines = _entry(args) if method == "uart" else (args.enter or "manual", None)
    ident = flash.check_identification(image, args.force)
    what = (f"{ident.board} firmware {ident.version_text} for {ident.chip}" if ident is not None
            else "an image without identification")
    print(f"image: {image.path} ({image.format}, {what}): {image.size} bytes at 0x{image.start:08X}..0x{image.end:08X}",
          file=sys.stderr)
    if method is None:  # --dry-run without a board: the image checks only
        chip = flash.CHIPS.get(ident.device_id) if ident is not None else None
        if ident is not None and chip is not None:
            flash.check_chip(image, ident, ident.device_id, ident.flash_kib * 1024)
            print(f"would erase sectors {', '.join(map(str, flash.sectors_for(image, chip)))} of the "
                  f"{'/'.join(chip.names)} and write {image.size} bytes (no board given: nothing done)")
        return 0
    progress = Bars()
    if method == "uart":
        result = flash.flash_uart(image, args.port, enter=enter, baud=args.baud, link_baud=args.link_baud,
                                  verify=not args.no_verify, start=not args.no_start, dry_run=args.dry_run,
                                  force=args.force, unprotect=args.unprotect, progress=progress,
                                  log=lambda line: print(line, file=sys.stderr), lines=lines)
        hello = result.hello
    else:
        started = time.monotonic()
        probe = args.port.split(":", 1)[1] if args.port and ":" in args.port else None
        place_probe = getattr(args, "held_probe", None)  # a labgrid place's probe: openocd runs on its machine
        link = args.link or (place_probe.link_url if place_probe is not None else None)
        try:
            summary = swd.flash_swd(image, method, target=args.target, probe=probe, verify=not args.no_verify,
                                    dry_run=args.dry_run, progress=progress, interface=args.interface,
                                    remote=place_probe)
        except swd.SwdError as exc:
            raise FlashError(str(exc)) from None
        print(summary, file=sys.stderr)
        note = flash.unasked_hello(ident)
        hello = (flash.check_hello(link, args.link_baud, ident)
                 if link and not args.dry_run and not note else None)
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


def add_parser(sub) -> None:
    p = sub.add_parser(
        "flash", help="put a firmware image on the board (UART bootloader or SWD), verified",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Flash IMAGE (ELF, Intel HEX, or .bin with --address) and check that what runs is what was\n"
                    "built: the image's identification block (board, chip, version, schema hash) must suit the\n"
                    "chip, only the sectors it needs are erased, every byte is read back, and after the start (at\n"
                    "the image's own vector table) the firmware's HELLO must report the image's board, version and\n"
                    "schema hash. An image flashed with --force that is not imulink's is started, not asked for "
                    "one.\n\n"
                    "PORT is one of:\n"
                    "  /dev/ttyUSB0, COM3, ...   the serial port wired to USART1 (PA9/PA10): the chip's system\n"
                    "                            bootloader (AN3155), at --baud; the same port carries the\n"
                    "                            firmware's HELLO afterwards\n"
                    "  swd                       over SWD with pyOCD (pip install 'imulink[swd]') or openocd\n"
                    "  pyocd[:PROBE] | openocd   that SWD tool (PROBE: the probe's serial number)\n"
                    "  lg://PLACE[/NAME]         a labgrid place, acquired for the flash and released after:\n"
                    "                            its serial port for the UART bootloader (and its lines, below);\n"
                    "                            with --method openocd its debug probe (a USBDebugger its exporter\n"
                    "                            shares; NAME: the probe's name), openocd run on the exporter's host\n"
                    "                            through ssh as labgrid runs it, the board's HELLO then checked on\n"
                    "                            the place's serial port if it has one; pyOCD cannot use a place's\n"
                    "                            probe\n"
                    "  lg-env:FILE[#TARGET]      a labgrid environment (labgrid's --lg-env file; TARGET: main):\n"
                    "                            its RemotePlace as lg://PLACE, or its serial port as that PORT\n\n"
                    "Into the bootloader (--enter): manual = BOOT0 high and a reset by hand; command = the board\n"
                    "runs imulink firmware, which gets ENTER_BOOTLOADER; dtr-rts = the adapter's DTR drives NRST\n"
                    "and RTS drives BOOT0; lines = a labgrid place's digital outputs named boot0 and reset (or its\n"
                    "power switch) drive them: BOOT0 high and a reset, the flash, BOOT0 low and a reset into the\n"
                    "image. The default is lines for a place that has them, else manual. docs/flashing.md has the\n"
                    "wiring and troubleshooting, docs/farm.md the place's lines.\n"
                    "Without PORT, --dry-run checks the image alone.")
    p.add_argument("image", metavar="IMAGE", help="firmware image: .elf, .hex or .bin")
    p.add_argument("port", metavar="PORT", nargs="?",
                   help="serial port of the UART bootloader (a device, a pyserial URL or a labgrid place "
                        "lg://PLACE[/RESOURCE]: its serial port; with --method openocd its debug probe; or a labgrid "
                        "environment lg-env:FILE[#TARGET]: its RemotePlace or serial port), or swd / "
                        "pyocd / openocd")
    p.add_argument("--method", choices=("uart", "pyocd", "openocd"), help="how to flash (default: from PORT)")
    p.add_argument("--address", type=u32_number, help="load address of a raw .bin image (e.g. 0x08000000)")
    p.add_argument("--enter", choices=flash.ENTRIES, default=None,
                   help="how the board gets into its bootloader (default: lines for a labgrid place with BOOT0 and "
                        "reset lines or a power switch, else manual)")
    p.add_argument("--baud", type=baud_rate, default=115200,
                   help="bootloader baud rate (default: 115200, AN3155's highest)")
    p.add_argument("--link-baud", type=baud_rate, default=DEFAULT_BAUD,
                   help=f"the firmware's link rate, for its HELLO after the start (default: {DEFAULT_BAUD})")
    p.add_argument("--link", metavar="PORT", help="SWD: the board's serial port, to check its HELLO after the start "
                                                  "(default for a place: its serial port, if it has one)")
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
    place_arguments(p)
    p.set_defaults(func=run, place_lines=_wants_place_lines, place_check=_check_place_lines,
                   place_probe=_wants_place_probe)

