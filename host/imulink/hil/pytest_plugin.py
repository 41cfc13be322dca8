"""A pytest plugin for a project's hardware-in-the-loop tests: the `board` fixture, a real
board of the lab's labgrid farm where there is one and an emulated board where there is not
(CI), with the same test code::

    # conftest.py
    pytest_plugins = ["imulink.hil.pytest_plugin"]

    # test_firmware.py
    def test_bit_exact(board):
        result = hil.inject(board.url, hil.load_injection_input("sim:rests:20"))
        assert result.verdict.passed

Which board, in this order: ``--imulink-board BOARD``, ``$IMULINK_BOARD``, ``lg://$LG_PLACE``
(labgrid's variable for the place a developer works with), ``lg-env:$LG_ENV`` (labgrid's
variable for its environment file), else ``native``. BOARD is a place (lg://PLACE[/RESOURCE]:
acquired for the test session, released after; needs imulink[lab]), a labgrid environment
(lg-env:FILE[#TARGET]: its RemotePlace, as that place, or its serial port), an emulated
target (native, qemu, stm32f407: started for the session, on a TCP port) or any PORT the
commands take (a device, socket://, rfc2217://: used as it is).

With ``--imulink-image IMAGE`` (or ``$IMULINK_IMAGE``) the session's board runs IMAGE before
any test: a place's board is flashed with it once acquired, as ``imulink farm verify --flash``
does (through the place's BOOT0 and reset lines when it has them, else the firmware's
ENTER_BOOTLOADER); a PORT's board is flashed by ENTER_BOOTLOADER; an emulated board is started
with it. A flash that fails fails the tests that use the board, in one line.

labgrid's own pytest plugin (``--lg-env``) hands a test drivers of a place acquired beforehand
with labgrid-client; this fixture acquires and releases the place itself and hands the one
thing imulink needs, the board's serial port, so a CI job needs no labgrid-client step.
"""
from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from imulink.board import flash, lab
from imulink.board.emulator import TARGETS, EmulatedBoard, EmulatorError
from imulink.board.link import DEFAULT_BAUD, Link
from imulink.errors import ImulinkError
from imulink.io.firmware_image import ImageError, load_image

#: The board when nothing names one: the firmware as a native process.
DEFAULT_BOARD = "native"
#: Seconds of simulated sensors an emulated board of a test session has (it streams only when
#: asked; injection does not use them).
EMULATED_RUN_S = 600.0


@dataclass
class Board:
    """The board of a test session: its serial port as a URL every imulink function opens."""

    url: str
    #: the labgrid place it belongs to, or None
    place: str | None = None
    #: the emulated target it is (native, qemu, stm32f407), or None for a real board
    target: str | None = None
    baud: int = DEFAULT_BAUD

    def link(self, **options) -> Link:
        """A new link to the board (close it, or use it in a with statement)."""
        return Link(self.url, self.baud, **options)


def pytest_addoption(parser) -> None:
    group = parser.getgroup("imulink", "imulink's board fixture")
    group.addoption("--imulink-board", metavar="BOARD", default=None,
                    help="the `board` fixture's board: lg://PLACE (a labgrid place), lg-env:FILE[#TARGET] (a labgrid "
                         "environment: its RemotePlace or serial port), native / qemu / stm32f407 (an emulated board) "
                         "or a PORT (default: $IMULINK_BOARD, else lg://$LG_PLACE, else lg-env:$LG_ENV, else native)")
    group.addoption("--imulink-image", metavar="IMAGE", default=None,
                    help="flash IMAGE into the `board` fixture's board before the tests (an emulated board is "
                         "started with it; default: $IMULINK_IMAGE, else the board runs what it has)")


def board_address(config) -> str:
    """The BOARD a session uses (see the module's docstring)."""
    given = config.getoption("imulink_board", default=None) or os.environ.get("IMULINK_BOARD")
    if given:
        return given
    if os.environ.get("LG_PLACE"):
        return f"{lab.SCHEME}{os.environ['LG_PLACE']}"
    if os.environ.get("LG_ENV"):  # labgrid's own pytest plugin takes the same file (--lg-env)
        return f"{lab.ENV_SCHEME}{os.environ['LG_ENV']}"
    return DEFAULT_BOARD


def board_image(config) -> str | None:
    """The IMAGE a session flashes first: --imulink-image, else $IMULINK_IMAGE, else None."""
    return config.getoption("imulink_image", default=None) or os.environ.get("IMULINK_IMAGE") or None


def _log(line: str) -> None:
    print(f"imulink: {line}", file=sys.stderr, flush=True)


@pytest.fixture(scope="session")
def board(request) -> Iterator[Board]:
    """The session's board: a labgrid place held for the session, an emulated board started for
    it, or a port as given; with an image (board_image), flashed with it first. A place that
    cannot be had, or a flash that fails, fails the tests that use it, in one line."""
    from imulink.hil import farm  # its worker machinery is not needed otherwise

    address = board_address(request.config)
    image_path = board_image(request.config)
    if address in TARGETS:
        with contextlib.ExitStack() as stack:
            try:
                emulated = stack.enter_context(EmulatedBoard(address, front="tcp", duration_s=EMULATED_RUN_S,
                                                             image=image_path))
            except EmulatorError as exc:
                pytest.fail(f"the board {address}: {exc}", pytrace=False)
            assert emulated.address is not None  # set by start()
            yield Board(emulated.address, target=address)
        return
    try:
        image = load_image(image_path) if image_path is not None else None
    except ImageError as exc:
        pytest.fail(f"the board {address}: {exc}", pytrace=False)
    given, coordinator, baud = address, None, DEFAULT_BAUD
    if lab.is_environment(address):  # its place or its serial port, then as lg://PLACE or a PORT
        try:
            named = lab.environment_board(address)
        except ImulinkError as exc:
            pytest.fail(f"the board {address}: {exc}", pytrace=False)
        _log(named.describe())
        address = named.place or named.url or address
        coordinator, baud = named.coordinator, named.speed or DEFAULT_BAUD
    if lab.is_place(address):
        with contextlib.ExitStack() as stack:
            try:
                place = stack.enter_context(lab.held_place(address, coordinator, lines=image is not None))
                if image is not None:
                    farm.flash_place(place, image, log=_log)
            except ImulinkError as exc:
                pytest.fail(f"the board {given}: {exc}", pytrace=False)
            yield Board(place.url, place=place.name, baud=place.speed)
    else:
        if image is not None:
            try:
                flash.flash_uart(image, address, enter="command", link_baud=baud, log=_log)
            except (ImulinkError, OSError) as exc:
                pytest.fail(f"the board {given}: not flashed: {exc}", pytrace=False)
        yield Board(address, baud=baud)
