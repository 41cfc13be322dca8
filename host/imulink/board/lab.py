"""Boards of a labgrid farm: `lg://PLACE` as a board address.

A lab shares its boards through labgrid (the optional extra ``imulink[lab]``): exporters
publish each board's serial port (a USB serial adapter behind ser2net, or any network
serial port) to a coordinator, and a *place* names one board's resources. A job acquires
the place, which locks it against every other client of the coordinator, uses the board
and releases it. This module is the only one that speaks to labgrid:

    with held_place("lg://imu-3") as place:     # acquired here, released on leaving (errors, Ctrl-C too)
        Link(place.url)                         # socket://HOST:PORT or rfc2217://HOST:PORT

- ``lg://PLACE`` takes the place's one serial port; ``lg://PLACE/NAME`` the one whose
  resource name (or its match's rename) is NAME, when the place has several.
- The coordinator is the one labgrid's own tools use: the ``coordinator`` argument, else
  ``$LG_COORDINATOR``, else labgrid's default 127.0.0.1:20408.
- A place that another job holds is never shared: acquisition is refused at once with who
  holds it (LabBusy), or after ``wait_s`` seconds of waiting for it.
- Every failure is a :class:`LabError` in one line: labgrid missing (the extra to install),
  a coordinator that does not answer within ``timeout_s``, an unknown place, a place
  without a serial port, an exporter that is gone.
- ``held_place(..., lines=True)`` also binds labgrid's own drivers to the place's BOOT0 and
  reset lines and its power switch (:class:`PlaceLines`: digital outputs named ``boot0`` and
  ``reset``, a power port), which `imulink flash --enter lines` drives.
- ``lg-env:PATH[#TARGET]`` is a labgrid environment file (what labgrid's own tools take as
  ``--lg-env`` or ``$LG_ENV``) and the target in it (default ``main``): :func:`environment_board`
  says what it names, the place of its ``RemotePlace`` (and its coordinator) or a serial port
  of this machine (``RawSerialPort``, ``NetworkSerialPort``, ``USBSerialPort``).
- ``held_probe("lg://PLACE")`` acquires a place for its SWD debug probe instead (a
  NetworkUSBDebugger: an exporter's USBDebugger) and hands back :class:`HeldProbe`, which
  runs a tool for the probe as labgrid's own drivers do: on the exporter's host, through
  labgrid's SSH connection to it, the files the tool reads copied there by labgrid.
"""
from __future__ import annotations

import asyncio
import contextlib
import fnmatch
import io
import logging
import os
import re
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, TypeVar

from imulink.errors import ImulinkError

T = TypeVar("T")

#: The scheme of a place address.
SCHEME = "lg://"
#: The prefix of a labgrid environment address, lg-env:PATH[#TARGET].
ENV_SCHEME = "lg-env:"
#: The environment's target when the address names none: labgrid's own default role.
DEFAULT_TARGET = "main"
#: labgrid's resources of a serial port on this machine (or reached directly over the
#: network), which an environment's target may have instead of a RemotePlace.
LOCAL_SERIAL_CLASSES = ("RawSerialPort", "NetworkSerialPort", "USBSerialPort")
#: labgrid's coordinator port when an address names none (labgrid-coordinator's default).
DEFAULT_COORDINATOR = "127.0.0.1:20408"
#: Seconds a coordinator has to answer before it counts as down.
TIMEOUT_S = 10.0
#: Seconds labgrid's coordinator waits for an exporter to answer a command (its
#: ExporterCommand.wait), e.g. to give back a released resource: then it goes on without it.
EXPORTER_ANSWER_S = 10.0
#: Seconds between two looks at a busy place while waiting for it.
_WAIT_POLL_S = 0.25
#: The resource class a place's serial port has on the coordinator: what an exporter
#: publishes for a RawSerialPort or USBSerialPort (through ser2net) and for a network
#: serial port given as such.
SERIAL_CLASS = "NetworkSerialPort"
#: The resource class a place's SWD/JTAG debug probe has on the coordinator: what an exporter
#: publishes for a USBDebugger (an ST-Link, a CMSIS-DAP, a J-Link ... on its USB), by the
#: probe's USB bus path on the exporter's host.
PROBE_CLASS = "NetworkUSBDebugger"


class LabError(ImulinkError):
    """A place that cannot be used, said in one line."""


class LabBusy(LabError):
    """The place is acquired by another job."""


@dataclass
class PlaceInfo:
    """A place as the coordinator lists it."""

    name: str
    tags: dict[str, str] = field(default_factory=dict)
    #: who holds it ("HOST/USER"), or None when it is free
    acquired: str | None = None
    comment: str = ""


@dataclass
class HeldPlace:
    """An acquired place and its serial port as a pyserial URL."""

    name: str
    url: str
    resource: str
    speed: int
    tags: dict[str, str]
    coordinator: str
    #: its BOOT0 and reset lines and power switch, when asked for (held_place's `lines`)
    lines: "PlaceLines | None" = None


def is_place(address: str | None) -> bool:
    """Whether a PORT argument is a place address (lg://...)."""
    return isinstance(address, str) and address.startswith(SCHEME)


def parse_place(address: str) -> tuple[str, str | None]:
    """(place, resource name or None) of `lg://PLACE[/NAME]`; LabError when malformed."""
    rest = address[len(SCHEME):] if address.startswith(SCHEME) else ""
    name, _, resource = rest.partition("/")
    if not name or "/" in resource or any(c in name for c in "*?[ "):
        raise LabError(f"{address!r} is not a place address: use lg://PLACE or lg://PLACE/RESOURCE")
    return name, resource or None


def is_environment(address: str | None) -> bool:
    """Whether a PORT argument is a labgrid environment address (lg-env:...)."""
    return isinstance(address, str) and address.startswith(ENV_SCHEME)


def parse_environment(address: str) -> tuple[str, str]:
    """(file, target) of `lg-env:PATH[#TARGET]`; LabError when malformed."""
    rest = address[len(ENV_SCHEME):] if address.startswith(ENV_SCHEME) else ""
    path, sep, target = rest.rpartition("#") if "#" in rest else (rest, "", DEFAULT_TARGET)
    if not path or (sep and not target):
        raise LabError(f"{address!r} is not a labgrid environment address: use lg-env:FILE or lg-env:FILE#TARGET")
    return path, target


def coordinator_address(given: str | None = None) -> str:
    """The coordinator: `given`, else $LG_COORDINATOR (labgrid's convention), else DEFAULT_COORDINATOR."""
    return given or os.environ.get("LG_COORDINATOR") or DEFAULT_COORDINATOR


def _labgrid(what: str = "lg:// places"):
    """labgrid's client module; LabError naming the extra when labgrid is not installed."""
    try:
        from labgrid.remote import client
    except ImportError as exc:
        raise LabError(f"{what} need labgrid, which is not installed ({exc}): pip install 'imulink[lab]' "
                       "(docs/farm.md)") from None
    return client


@dataclass
class EnvironmentBoard:
    """The board a target of a labgrid environment names: its RemotePlace (`place`, on the
    environment's `coordinator` if it names one), or a serial port of this machine (`url`)."""

    path: str
    target: str
    #: the place address lg://NAME of the target's RemotePlace, or None
    place: str | None = None
    #: the environment's `options: coordinator_address`, or None (the usual default then)
    coordinator: str | None = None
    #: the serial port's pyserial URL (a device path, socket:// or rfc2217://), or None for a place
    url: str | None = None
    #: the serial port's resource class and speed, as the environment gives them
    resource: str = ""
    speed: int | None = None

    def describe(self) -> str:
        """E.g. `labgrid environment env.yaml, target main: RawSerialPort at /dev/ttyUSB0`."""
        board = f"place {self.place[len(SCHEME):]}" if self.place else f"{self.resource} at {self.url}"
        return f"labgrid environment {self.path}, target {self.target}: {board}"


def environment_board(address: str) -> EnvironmentBoard:
    """What `lg-env:PATH[#TARGET]` names, read with labgrid's own Environment: the target's
    RemotePlace (found without instantiating it, as labgrid-client does: instantiating one
    connects to the coordinator, which the place's own acquisition does later), else its
    one serial port. LabError in one line for a file that is missing or not a labgrid
    environment, a target it lacks, or a target with neither."""
    path, role = parse_environment(address)
    _labgrid("lg-env: environments")
    from labgrid import Environment
    from labgrid.exceptions import InvalidConfigError, NoConfigFoundError
    from labgrid.factory import target_factory
    from yaml import YAMLError  # labgrid's own YAML library

    where = f"labgrid environment {path}"
    try:
        env = Environment(config_file=path)
        targets = env.config.get_targets()
    except NoConfigFoundError:
        raise LabError(f"{where}: no such file") from None
    except InvalidConfigError as exc:
        if isinstance(exc.__context__, YAMLError):  # labgrid's own words add nothing to YAML's
            raise LabError(f"{where} is not valid YAML: {_one_line(exc.__context__)}") from None
        raise LabError(f"{where} cannot be read: {_one_line(exc)}") from None
    except Exception as exc:  # an OS error (a directory, no permission), an error of a file its `imports` run
        raise LabError(f"{where} cannot be read: {_one_line(exc)}") from None
    if not isinstance(targets, dict) or not isinstance(targets.get(role), dict):
        names = ", ".join(map(str, targets)) if isinstance(targets, dict) and targets else "none"
        raise LabError(f"{where} has no target {role!r} (its targets: {names}); name one, lg-env:{path}#TARGET")
    try:
        resources, _ = target_factory.normalize_config(targets[role])
    except Exception as exc:  # labgrid's InvalidConfigError: resources that are neither a dict nor a list of them
        raise LabError(f"{where}, target {role}: {_one_line(exc)}") from None
    places = list(resources.get("RemotePlace", {}))
    if places:
        if len(places) > 1 or not places[0]:
            raise LabError(f"{where}, target {role}: its RemotePlace must be one, with a name (it has "
                           f"{', '.join(map(str, places))})")
        # labgrid-client's precedence: its --coordinator, then the environment's option, then $LG_COORDINATOR
        coordinator = env.config.get_option("coordinator_address", "")
        return EnvironmentBoard(path, role, place=f"{SCHEME}{places[0]}",
                                coordinator=str(coordinator) if coordinator else None)
    try:
        target = env.get_target(role)
    except Exception as exc:  # labgrid's own errors: an unknown resource class, arguments it refuses
        raise LabError(f"{where}, target {role}: {_one_line(exc)}") from None
    assert target is not None  # the role is in the environment
    ports = [r for r in target.resources if type(r).__name__ in LOCAL_SERIAL_CLASSES]
    if len(ports) != 1:
        has = ", ".join(sorted(f"{type(r).__name__}/{r.name}" if r.name else type(r).__name__
                               for r in target.resources)) or "no resources"
        wanted = "one serial port" if ports else f"a RemotePlace or a serial port ({', '.join(LOCAL_SERIAL_CLASSES)})"
        raise LabError(f"{where}, target {role}: imulink needs {wanted}; it has {has}")
    [port] = ports
    kind = type(port).__name__
    if kind == "NetworkSerialPort":
        params = {"host": port.host, "port": port.port, "speed": port.speed, "protocol": port.protocol}
        url = _serial_url(params, getattr(port, "extra", None) or {}, f"{where}, target {role}")
    else:
        if kind == "USBSerialPort":  # found through udev: wait for it as labgrid's serial driver would
            try:
                target.await_resources([port])
            except Exception:  # labgrid's NoResourceFoundError
                raise LabError(f"{where}, target {role}: no serial device matches its USBSerialPort "
                               f"{dict(port.match)} (unplugged?)") from None
        url = str(port.port)
    return EnvironmentBoard(path, role, url=url, resource=kind, speed=int(port.speed))


class _QuietLabgrid(logging.Filter):
    """labgrid's client logs a lost coordinator on the root logger (and Python prints that
    as a bare line when nothing is configured); imulink reports it as its own error line."""

    def filter(self, record: logging.LogRecord) -> bool:
        return f"{os.sep}labgrid{os.sep}" not in record.pathname


_loops = threading.local()


def _event_loop() -> asyncio.AbstractEventLoop:
    """This thread's event loop for coordinator sessions, made once and never closed: gRPC's
    asyncio poller stays bound to a loop after its channel is closed, and reports (on
    stderr) every later event of a loop closed under it."""
    loop = getattr(_loops, "loop", None)
    if loop is None:
        loop = _loops.loop = asyncio.new_event_loop()
    return loop


class Coordinator:
    """A client session with a labgrid coordinator, synchronous: each call runs the thread's
    session loop until the coordinator has answered (or `timeout_s` has passed).
    Close it (or use it as a context manager) when done."""

    def __init__(self, address: str | None = None, timeout_s: float = TIMEOUT_S):
        client = _labgrid()
        self.address = coordinator_address(address)
        self.timeout_s = timeout_s
        self._quiet = _QuietLabgrid()
        logging.getLogger().addFilter(self._quiet)
        self._loop = _event_loop()
        self._session = None
        try:
            from labgrid.util.proxy import proxymanager

            target = proxymanager.get_grpc_address(self.address, default_port=20408)

            async def make():  # the gRPC channel belongs to the loop it is made in: this session's
                return client.ClientSession(target, self._loop)

            session = self._loop.run_until_complete(make())
            self._session = session  # stop() is safe from here on
            self._run(session.start(), "connect")
        except BaseException:
            self.close()
            raise

    def _run(self, coroutine, doing: str, timeout_s: float | None = None):
        client = _labgrid()
        limit = self.timeout_s if timeout_s is None else timeout_s
        try:
            return self._loop.run_until_complete(asyncio.wait_for(coroutine, limit))
        except (asyncio.TimeoutError, client.ServerError) as exc:
            if isinstance(exc, asyncio.TimeoutError):
                detail = f"no answer within {limit:g} s"
            else:  # labgrid's "Error: Could not connect to coordinator": refused, unreachable
                detail = str(exc).strip().removeprefix("Error: ").lower() or "no answer"
            raise LabError(f"the labgrid coordinator at {self.address} does not answer ({detail}, trying to "
                           f"{doing}; the limit is {limit:g} s): is labgrid-coordinator running there? "
                           "(set LG_COORDINATOR or --coordinator)") from None

    def __enter__(self) -> "Coordinator":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self) -> None:
        """End the session (idempotent); never raises."""
        session, self._session = self._session, None
        try:
            if session is not None:
                with contextlib.suppress(Exception):
                    self._loop.run_until_complete(asyncio.wait_for(session.stop(), 2.0))
                with contextlib.suppress(Exception):
                    self._loop.run_until_complete(asyncio.wait_for(session.close(), 2.0))
        finally:
            logging.getLogger().removeFilter(self._quiet)

    @property
    def session(self):
        if self._session is None:
            raise LabError("the session with the labgrid coordinator is closed")
        return self._session

    def sync(self) -> None:
        """Wait until the coordinator has sent every change of places and resources so far."""
        if not self._run(self.session.sync_with_coordinator(), "synchronise"):
            raise LabError(f"the labgrid coordinator at {self.address} went away")

    # ------------------------------------------------------------------ places

    def places(self, pattern: str = "*") -> list[PlaceInfo]:
        """The places whose name matches the glob `pattern`, sorted by name."""
        return [PlaceInfo(name, dict(place.tags), place.acquired or None, place.comment or "")
                for name, place in sorted(self.session.places.items()) if fnmatch.fnmatchcase(name, pattern)]

    def _place(self, name: str):
        place = self.session.places.get(name)
        if place is None:
            known = ", ".join(sorted(self.session.places)) or "none"
            raise LabError(f"no place {name!r} on the labgrid coordinator at {self.address} (places: {known})")
        return place

    def _serial_resources(self, place, paths) -> list[tuple[str, object]]:
        """(name, resource entry) of the serial ports among resource `paths` of `place`."""
        found = []
        for path in paths:
            exporter, group, cls, resource_name = path
            if cls != SERIAL_CLASS:
                continue
            entry = self.session.resources.get(exporter, {}).get(group, {}).get(resource_name)
            found.append((_name_in_place(place, path), entry))
        return found

    def _matched_paths(self, place) -> list[tuple[str, str, str, str]]:
        return [(exporter, group_name, entry.cls, resource_name)
                for exporter, groups in self.session.resources.items()
                for group_name, group in groups.items()
                for resource_name, entry in group.items()
                if place.hasmatch((exporter, group_name, entry.cls, resource_name))]

    def check_serial(self, name: str, resource: str | None = None) -> None:
        """LabError unless place `name` exists and one of its matches is a connected serial port
        (named `resource` if given): an unknown place, a place without a serial port and one
        whose exporter is not connected are told apart."""
        place = self._place(name)
        paths = self._matched_paths(place)
        serial = [n for n, _ in self._serial_resources(place, paths)]
        if resource is not None and resource not in serial:
            serial = []
        if serial:
            return
        missing = place.unmatched(paths)
        if missing is not None:
            raise LabError(f"place {name}: nothing on the coordinator matches {missing}: its exporter is not "
                           "connected (exporter down or lost?)")
        what = f"serial port named {resource!r}" if resource else "serial port"
        raise LabError(f"place {name} has no {what} ({SERIAL_CLASS}: an exported RawSerialPort, USBSerialPort or "
                       f"NetworkSerialPort); add one with `labgrid-client -p {name} add-match EXPORTER/GROUP/"
                       f"{SERIAL_CLASS}/NAME`")

    def check_probe(self, name: str, resource: str | None = None) -> None:
        """LabError unless place `name` exists and one of its matches is a connected debug probe
        (named `resource` if given); the error names the resources the place has instead."""
        place = self._place(name)
        paths = self._matched_paths(place)
        if any(path[2] == PROBE_CLASS and resource in (None, _name_in_place(place, path)) for path in paths):
            return
        missing = place.unmatched(paths)
        if missing is not None:
            raise LabError(f"place {name}: nothing on the coordinator matches {missing}: its exporter is not "
                           "connected (exporter down or lost?)")
        has = ", ".join(sorted(f"{path[2]}/{_name_in_place(place, path)}" for path in paths)) or "none"
        what = f"debug probe named {resource!r}" if resource else "debug probe"
        raise LabError(f"place {name} has no {what} ({PROBE_CLASS}: an exported USBDebugger; its resources: "
                       f"{has}); add one with `labgrid-client -p {name} add-match EXPORTER/GROUP/{PROBE_CLASS}/NAME`")

    def acquire(self, name: str, resource: str | None = None, wait_s: float = 0.0, probe: bool = False) -> None:
        """Acquire place `name` for this job. LabBusy (with who holds it) when another job has
        it and it is not released within `wait_s` s; LabError as check_serial (check_probe
        with `probe`: the place is wanted for its debug probe, `resource` names that)."""
        client = _labgrid()
        deadline = time.monotonic() + wait_s
        said_waiting = False
        check = self.check_probe if probe else self.check_serial
        while True:
            check(name, resource)
            holder = self._place(name).acquired
            if holder and wait_s > 0 and not said_waiting:  # a job that waits says for what
                print(f"imulink: place {name} is acquired by {holder}: waiting up to {wait_s:g} s for it",
                      file=sys.stderr, flush=True)
                said_waiting = True
            if not holder:
                self.session.args = _Args(place=name)
                said = io.StringIO()  # labgrid-client's own messages: why a refusal was
                try:
                    with contextlib.redirect_stdout(said):
                        self._loop.run_until_complete(asyncio.wait_for(self.session.acquire(), self.timeout_s))
                    return
                except client.UserError as exc:
                    raise LabError(f"place {name}: {exc}") from None
                except asyncio.TimeoutError:
                    raise LabError(f"the labgrid coordinator at {self.address} does not answer (no answer within "
                                   f"{self.timeout_s:g} s, trying to acquire {name})") from None
                except client.ServerError as exc:
                    self.sync()  # another job may have come first: who?
                    holder = self._place(name).acquired
                    if not holder:  # e.g. a resource it shares with another place, acquired with that one
                        why = " ".join([str(exc).strip(), *said.getvalue().split("\n")[-2:]]).strip()
                        raise LabError(f"place {name}: the coordinator refused to acquire it: {why}") from None
            if time.monotonic() >= deadline:
                waited = f" (waited {wait_s:g} s)" if wait_s > 0 else ""
                raise LabBusy(f"place {name} is acquired by {holder}: another job holds the board{waited}; try "
                              "later, or wait for it (--place-wait SECONDS)")
            self._loop.run_until_complete(asyncio.sleep(_WAIT_POLL_S))  # the session takes the place's updates
            self.sync()

    def release(self, name: str) -> None:
        """Release place `name` (acquired by this job). The coordinator answers once each of the
        place's exporters has given its resources back, or has not answered within labgrid's own
        limit (a frozen exporter): the wait allows for that, resource by resource."""
        self.session.args = _Args(place=name)
        place = self.session.places.get(name)
        resources = len(place.acquired_resources) if place is not None else 0
        with contextlib.redirect_stdout(io.StringIO()):
            self._run(self.session.release(), f"release {name}", self.timeout_s + EXPORTER_ANSWER_S * resources)

    def serial_port(self, name: str, resource: str | None = None) -> tuple[str, str, int]:
        """(resource name, pyserial URL, speed) of the serial port of acquired place `name`."""
        place = self._place(name)
        ports = self._serial_resources(place, [tuple(p) for p in place.acquired_resources])
        if resource is not None:
            ports = [(n, entry) for n, entry in ports if n == resource]
        port_name, entry = self._the_one(name, "serial port", "adapter", ports, self.check_serial, resource)
        params = entry.args  # type: ignore[attr-defined]
        url = _serial_url(params, entry.extra, f"place {name}")  # type: ignore[attr-defined]
        return port_name, url, int(params.get("speed") or 115200)

    def board_link(self, name: str) -> str | None:
        """The pyserial URL of acquired place `name`'s serial port when it has exactly one and it is
        available, else None: the board's link beside its debug probe."""
        place = self._place(name)
        ports = self._serial_resources(place, [tuple(p) for p in place.acquired_resources])
        if len(ports) != 1 or not getattr(ports[0][1], "avail", False):
            return None
        return self.serial_port(name)[1]

    def _place_resources(self, target) -> list:
        """The resources of the acquired place named as labgrid Target `target`, as labgrid's
        own objects, added to the target: what labgrid-client makes of a place, from this session."""
        from labgrid.resource.remote import RemotePlace, RemotePlaceManager

        manager = RemotePlaceManager.get()
        manager.session = self.session
        manager.loop = self._loop
        with contextlib.redirect_stdout(io.StringIO()):
            RemotePlace(target, name=target.name)
        return [r for r in target.resources if not isinstance(r, RemotePlace)]

    def probe(self, name: str, resource: str | None = None) -> "HeldProbe":
        """The debug probe of acquired place `name` (the one named `resource`, if given)."""
        from labgrid import Target

        try:
            resources = self._place_resources(Target(name))
        except Exception as exc:  # labgrid's own errors (an orphaned resource, a class it cannot make)
            raise LabError(f"place {name}: its debug probe cannot be used through labgrid: {_one_line(exc)}") from None
        wanted = [r for r in resources if type(r).__name__ == PROBE_CLASS and resource in (None, r.name)]
        probes = sorted(((r.name, r) for r in wanted), key=lambda named: named[0])
        _, found = self._the_one(name, "debug probe", "probe", probes, self.check_probe, resource)
        return HeldProbe(name, self.address, found)

    @staticmethod
    def _the_one(name: str, kind: str, device: str, found: list, check: Callable[[str, str | None], None],
                 resource: str | None) -> tuple[str, Any]:
        """The one (resource name, entry) of `found`, place `name`'s acquired resources of a
        `kind` (the `resource` named, if given); LabError when there is none (`check` says
        why), several, or the one is not available (its exporter gone, its `device` unplugged)."""
        if not found:
            check(name, resource)  # says why
            raise LabError(f"place {name}: its {kind} was not acquired with it")
        if len(found) > 1:
            raise LabError(f"place {name} has several {kind}s ({', '.join(n for n, _ in found)}): name one, "
                           f"lg://{name}/NAME")
        found_name, entry = found[0]
        if entry is None or not getattr(entry, "avail", False):
            raise LabError(f"place {name}: its {kind} {found_name} is not available (its exporter is gone, or the "
                           f"{device} is unplugged)")
        return found_name, entry

    def lines(self, name: str) -> "PlaceLines":
        """The BOOT0 and reset lines and the power switch of acquired place `name`, each bound to
        labgrid's own driver for its resource class (as `labgrid-client io` and `power` bind
        them); parts the place does not have are None."""
        from labgrid import Target

        target = Target(name)
        lines = PlaceLines(name, target)
        try:
            resources = self._place_resources(target)
            for line in (BOOT0_LINE, RESET_LINE):
                found = [r for r in resources if r.name is not None and r.name.lower() == line
                         and type(r).__name__ in OUTPUT_DRIVERS]
                if found:
                    setattr(lines, line, lines.bind(found[0], OUTPUT_DRIVERS[type(found[0]).__name__]))
            power = [r for r in resources if type(r).__name__ in POWER_DRIVERS]
            if len(power) > 1:
                power = [r for r in power if r.name == POWER_NAME]
                if len(power) != 1:
                    raise LabError(f"place {name} has several power ports: name the board's {POWER_NAME!r} "
                                   f"(labgrid-client -p {name} add-named-match PATTERN {POWER_NAME})")
            if power:
                lines.power = lines.bind(power[0], POWER_DRIVERS[type(power[0]).__name__])
        except LabError:
            lines.close()
            raise
        except Exception as exc:  # labgrid's own errors (a resource it cannot make, a driver it cannot activate)
            lines.close()
            raise LabError(f"place {name}: its BOOT0, reset or power lines cannot be used through labgrid: "
                           f"{_one_line(exc)} (imulink flash --enter command or manual does without them)") from None
        return lines


#: A place's digital outputs that imulink drives, by resource name (or the match's rename):
#: BOOT0 (asserted: high, the chip boots its system-memory bootloader) and reset (asserted:
#: the board held in reset, NRST low). Polarity is the resource's own (`invert` where labgrid
#: has it).
BOOT0_LINE = "boot0"
RESET_LINE = "reset"
#: The power port's name when a place has several.
POWER_NAME = "power"
#: labgrid's digital-output resources (as a place holds them) and their drivers: the pairs
#: labgrid-client's `io` command binds.
OUTPUT_DRIVERS = {
    "HttpDigitalOutput": "HttpDigitalOutputDriver",
    "ModbusTCPCoil": "ModbusCoilDriver",
    "WaveshareModbusTCPCoil": "WaveShareModbusCoilDriver",
    "Eth008DigitalOutput": "Eth008DigitalOutputDriver",
    "OneWirePIO": "OneWirePIODriver",
    "NetworkDeditecRelais8": "DeditecRelaisDriver",
    "NetworkSysfsGPIO": "GpioDigitalOutputDriver",
    "NetworkLXAIOBusPIO": "LXAIOBusPIODriver",
    "NetworkHIDRelay": "HIDRelayDriver",
}
#: labgrid's power resources and their drivers: the pairs labgrid-client's `power` command binds.
POWER_DRIVERS = {
    "NetworkPowerPort": "NetworkPowerDriver",
    "NetworkUSBPowerPort": "USBPowerDriver",
    "NetworkSiSPMPowerPort": "SiSPMPowerDriver",
    "PDUDaemonPort": "PDUDaemonDriver",
    "TasmotaPowerPort": "TasmotaPowerDriver",
    "NetworkYKUSHPowerPort": "YKUSHPowerDriver",
}
#: Seconds reset is held (NRST needs microseconds; a relay or a slow GPIO box more).
RESET_PULSE_S = 0.1
#: Seconds from the end of a reset or a power cycle to the bootloader listening (AN2606: well
#: under 100 ms on the F4).
START_S = 0.1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _name_in_place(place, path) -> str:
    """A resource's name in a place: its match's rename, else its own name."""
    match = place.getmatch(path)
    return match.rename if match is not None and match.rename else path[3]


class PlaceLines:
    """A held place's BOOT0 and reset lines and its power switch, through labgrid's drivers:
    what brings its board into the STM32 system bootloader and back into its firmware, with
    nobody at the bench. Each step is one line on failure (LabError)."""

    def __init__(self, place: str, target):
        self.place = place
        self.target = target
        self.boot0: Any = None
        self.reset: Any = None
        self.power: Any = None
        self._kinds: dict[str, str] = {}

    def bind(self, resource, driver_name: str):
        """labgrid's `driver_name` bound to `resource` of the place and activated."""
        from labgrid.factory import target_factory

        cls = target_factory.class_from_string(driver_name)
        [binding] = cls.bindings  # a digital output's and a power port's drivers bind one resource
        self.target.set_binding_map({binding: resource.name})
        driver = cls(self.target, name=resource.name)
        self.target.activate(driver)
        self._kinds[resource.name] = type(resource).__name__
        return driver

    @property
    def usable(self) -> bool:
        """A BOOT0 line and a way to restart the board (a reset line or a power switch)."""
        return self.boot0 is not None and (self.reset is not None or self.power is not None)

    def describe(self) -> str:
        """What the place has, e.g. `boot0 (HttpDigitalOutput), reset (HttpDigitalOutput)`."""
        parts = [f"{driver.name} ({self._kinds.get(driver.name, type(driver).__name__)})"
                 for driver in (self.boot0, self.reset, self.power) if driver is not None]
        return ", ".join(parts) or "no BOOT0, reset or power line"

    def missing(self) -> str:
        """Why the lines cannot flash the board ("" when they can)."""
        if self.usable:
            return ""
        lacking = (f"a digital output named {BOOT0_LINE!r}" if self.boot0 is None
                   else f"a digital output named {RESET_LINE!r} or a power port")
        return (f"place {self.place} has {self.describe()}: --enter lines needs {lacking} (docs/farm.md: a place's "
                "BOOT0 and reset lines)")

    def _do(self, what: str, step) -> None:
        try:
            step()
        except Exception as exc:  # requests', pymodbus', labgrid's own errors
            raise LabError(f"place {self.place}: {what} failed: {_one_line(exc)}") from None

    def set_boot0(self, high: bool) -> None:
        boot0 = self.boot0
        assert boot0 is not None
        self._do(f"setting {boot0.name} {'high' if high else 'low'}", lambda: boot0.set(high))

    def restart(self) -> None:
        """A reset pulse on the reset line, else a power cycle; then the time the chip takes to start."""
        if self.reset is not None:
            reset = self.reset
            self._do(f"asserting {reset.name}", lambda: reset.set(True))
            time.sleep(RESET_PULSE_S)
            self._do(f"releasing {reset.name}", lambda: reset.set(False))
        elif self.power is not None:
            self._do(f"power-cycling {self.power.name}", self.power.cycle)
        time.sleep(START_S)

    def enter_bootloader(self) -> None:
        """BOOT0 high, then a reset (or a power cycle): the chip starts its system bootloader."""
        if not self.usable:
            raise LabError(self.missing())
        self.set_boot0(True)
        self.restart()

    def start_application(self) -> None:
        """BOOT0 low, then a reset (or a power cycle): the chip starts what its flash holds."""
        self.set_boot0(False)
        self.restart()

    def close(self) -> None:
        """Deactivate the drivers (idempotent); never raises."""
        with contextlib.suppress(Exception):
            self.target.cleanup()


class HeldProbe:
    """A held place's debug probe (a NetworkUSBDebugger), used as labgrid's own OpenOCDDriver
    uses one: a tool for the probe runs on the exporter's host, through labgrid's SSH connection
    to that host (the resource's command prefix: through the exporter's proxy where it asks for
    one), and the files the tool reads are copied there first by labgrid (ManagedFile: into
    /var/cache/labgrid/USER/, or left where they are when that host shares the file). The USB
    path tells the tool which probe of that host is the place's. Each step is one line on
    failure (LabError)."""

    def __init__(self, place: str, coordinator: str, resource: Any):
        self.place = place
        self.coordinator = coordinator
        self.name: str = resource.name
        self.host: str = resource.host
        self.usb_path: str | None = resource.path
        #: the place's serial port (pyserial URL), or None when it has none or several
        self.link_url: str | None = None
        self._resource = resource

    def describe(self) -> str:
        """E.g. `debug probe USBDebugger on rack1 (USB 1-3.2)`."""
        usb = f" (USB {self.usb_path})" if self.usb_path else ""
        return f"debug probe {self.name} on {self.host}{usb}"

    def _reach(self) -> None:
        """labgrid's SSH connection to the probe's host, opened once and kept for the process
        (labgrid closes its connections when the process ends)."""
        try:
            _ = self._resource.command_prefix  # the property opens the connection
        except Exception as exc:  # labgrid's ExecutionError of ssh, or an OS error (no ssh client)
            raise LabError(f"place {self.place}: its {self.describe()} cannot be reached: {_ssh_words(exc)}; "
                           f"a probe's tools run on its exporter's host, through ssh, as labgrid runs them: "
                           f"`ssh {self.host} true` must log in without a password (docs/farm.md)") from None

    def command(self, argv: list[str]) -> list[str]:
        """`argv` as a command line that runs it on the probe's host."""
        self._reach()
        return list(self._resource.wrap_command(argv))

    def stage(self, path: str) -> str:
        """The path on the probe's host of the local file `path`, copied there if need be."""
        from labgrid.util.managedfile import ManagedFile

        self._reach()
        managed = ManagedFile(path, self._resource)
        try:
            managed.sync_to_resource()
        except Exception as exc:  # ssh's or rsync's failure, as labgrid's ExecutionError or an OS error
            raise LabError(f"place {self.place}: {os.path.basename(path)} could not be copied to {self.host} for "
                           f"its {self.describe()} ({_ssh_words(exc)}): labgrid copies it into "
                           "/var/cache/labgrid/ there with rsync over ssh") from None
        return str(managed.get_remote_path())


def _ssh_words(exc: BaseException) -> str:
    """What ssh (or rsync) said in a labgrid error about it, in one line; else the error itself."""
    text = str(exc)
    said = re.findall(r"(?:ssh|rsync|scp): [^'\\\n]+", text)
    return said[-1].strip() if said else _one_line(exc)


@dataclass
class _Args:
    """The arguments labgrid-client's place commands read (its argparse namespace)."""

    place: str
    allow_unmatched: bool = False
    kick: bool = False


def _host_and_port(params: dict, extra: dict) -> tuple[str, int]:
    """The address to open, through labgrid's SSH proxy when the exporter asks for one
    (or $LG_PROXY is set): labgrid's own rule for network resources."""
    from labgrid.resource.serialport import NetworkSerialPort
    from labgrid.util.proxy import proxymanager

    resource = NetworkSerialPort(None, None, host=params["host"], port=int(params["port"]),
                                 speed=int(params.get("speed") or 115200), protocol=params.get("protocol", "rfc2217"))
    resource.extra = extra
    try:
        host, port = proxymanager.get_host_and_port(resource)
    except Exception as exc:  # labgrid's ExecutionError of an SSH forward, or an OS error
        raise LabError(f"cannot reach {params['host']}:{params['port']} through labgrid's proxy: {exc}") from None
    return host, int(port)


def _serial_url(params: dict, extra: dict, where: str) -> str:
    """The pyserial URL of a NetworkSerialPort's `params` (host, port, protocol)."""
    protocol = params.get("protocol", "rfc2217")
    scheme = {"raw": "socket", "rfc2217": "rfc2217"}.get(protocol)
    if scheme is None:
        raise LabError(f"{where}: its serial port speaks {protocol!r}, neither raw nor rfc2217")
    host, port = _host_and_port(params, extra)
    # ser2net answers no SET_CONTROL (modem lines) of RFC 2217: labgrid's own serial driver
    # tells pyserial not to wait for it, and so does imulink
    options = "?ign_set_control" if scheme == "rfc2217" else ""
    return f"{scheme}://{host}:{port}{options}"


@contextlib.contextmanager
def _holding(name: str, resource: str | None, coordinator: str | None, timeout_s: float, wait_s: float,
             probe: bool, take: Callable[[Coordinator], T]) -> Iterator[T]:
    """Place `name` acquired (for its serial port, or with `probe` for its debug probe; `resource`
    names the one) and what `take` makes of it while the coordinator session is open, for the body
    of the with statement; released after, whatever ends the body (an error, Ctrl-C), or at once
    when `take` fails. The session is closed while the body runs: an acquired place stays
    acquired until released."""
    with Coordinator(coordinator, timeout_s) as lab:
        lab.acquire(name, resource, wait_s, probe=probe)
        try:
            taken = take(lab)
        except BaseException:
            _release(lab.address, name, timeout_s, lab)
            raise
        address_used = lab.address
    try:
        yield taken
    finally:
        _release(address_used, name, timeout_s)


@contextlib.contextmanager
def held_place(address: str, coordinator: str | None = None, timeout_s: float = TIMEOUT_S,
               wait_s: float = 0.0, lines: bool = False) -> Iterator[HeldPlace]:
    """Acquire the place of `address` (lg://PLACE[/NAME]) for the body of the with statement
    and release it after, whatever ends the body (an error, Ctrl-C). The coordinator
    session is closed while the body runs: an acquired place stays acquired until released.
    With `lines`, the held place's `lines` are its BOOT0 and reset lines and power switch
    (:class:`PlaceLines`, bound while the session is open)."""
    name, resource = parse_place(address)

    def take(lab: Coordinator) -> HeldPlace:
        port_name, url, speed = lab.serial_port(name, resource)
        tags = dict(lab._place(name).tags)
        return HeldPlace(name, url, port_name, speed, tags, lab.address, lab.lines(name) if lines else None)

    with _holding(name, resource, coordinator, timeout_s, wait_s, False, take) as held:
        try:
            yield held
        finally:
            if held.lines is not None:
                held.lines.close()


@contextlib.contextmanager
def held_probe(address: str, coordinator: str | None = None, timeout_s: float = TIMEOUT_S,
               wait_s: float = 0.0) -> Iterator[HeldProbe]:
    """Acquire the place of `address` (lg://PLACE[/NAME], NAME the name of its debug probe) for
    its debug probe, as held_place does for a serial port: released after the body, whatever
    ends it. The probe's `link_url` is the place's serial port when it has exactly one (the
    board's link, where a flashed image says HELLO), else None."""
    name, resource = parse_place(address)

    def take(lab: Coordinator) -> HeldProbe:
        probe = lab.probe(name, resource)
        probe.link_url = lab.board_link(name)
        return probe

    with _holding(name, resource, coordinator, timeout_s, wait_s, True, take) as held:
        yield held


def _release(address: str, name: str, timeout_s: float, lab: Coordinator | None = None) -> None:
    """Release a place; a failure is one warning line (the job's own outcome stands)."""
    try:
        if lab is not None:
            lab.release(name)
            return
        with Coordinator(address, timeout_s) as again:
            again.release(name)
    except (ImulinkError, Exception) as exc:  # labgrid's own errors are plain Exceptions
        print(f"imulink: warning: place {name} was not released ({exc}); release it with "
              f"`labgrid-client -x {address} -p {name} release`", file=sys.stderr)
