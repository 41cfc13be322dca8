"""A labgrid farm on this machine: a coordinator and exporters started here, emulated boards
(native processes, the ARM image in QEMU, and the reference image on the virtual STM32F407)
exported as network serial ports, places created and tagged with labgrid-client, and imulink
using them by lg://PLACE.

Needs labgrid (imulink[lab]): `make test-farm` runs this module in .venv-lab, where
IMULINK_REQUIRE_LABGRID=1 turns a missing labgrid into a failure instead of a skip.
"""
from __future__ import annotations

import contextlib
import http.server
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

try:
    import labgrid  # noqa: F401
except ImportError:
    if os.environ.get("IMULINK_REQUIRE_LABGRID"):
        raise
    pytest.skip("labgrid is not installed (pip install 'imulink[lab]'; `make test-farm` runs these tests)",
                allow_module_level=True)

from imulink.board import lab
from imulink.board.emulator import EmulatedBoard

# the boards, the coordinator and the farm's workers take the machine's cores
pytestmark = pytest.mark.xdist_group("takes-a-core")

BIN = Path(sys.executable).parent
#: The ser2net wrapper a lab puts on its exporters' PATH (docs/farm.md): TCP_NODELAY on.
SER2NET_NODELAY = Path(__file__).resolve().parents[1] / "tools" / "ser2net-nodelay"
IMULINK = [sys.executable, "-m", "imulink.cli"]
#: The same, taking SIGINT as Ctrl-C even when the suite runs as a background job of a
#: non-interactive shell (which starts it with SIGINT ignored, and Python keeps that).
IMULINK_CTRL_C = [sys.executable, "-c", "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
                  "from imulink.cli import main; sys.exit(main())"]
#: Seconds any one imulink or labgrid-client command of these tests may take.
COMMAND_TIMEOUT_S = 120


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} within {timeout:g} s")
        time.sleep(0.1)


class Lab:
    """A coordinator on a free port, its exporters, places made with labgrid-client."""

    def __init__(self, directory: Path):
        self.dir = directory
        self.address = f"127.0.0.1:{_free_port()}"
        self.env = {**os.environ, "LG_COORDINATOR": self.address}
        self.env.pop("LG_PROXY", None)
        self.processes: dict[str, subprocess.Popen] = {}
        self.coordinator = self._start("coordinator", [str(BIN / "labgrid-coordinator"), "-l", self.address])
        host, port = self.address.split(":")

        def listening() -> bool:
            with socket.socket() as s:
                return s.connect_ex((host, int(port))) == 0
        _wait_for(listening, 20, "the coordinator did not listen")

    def _start(self, name: str, command: list[str], env: dict | None = None) -> subprocess.Popen:
        log = open(self.dir / f"{name}.log", "wb")
        process = subprocess.Popen(command, cwd=self.dir, stdout=log, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, env=env or self.env)
        self.processes[name] = process
        return process

    def nodelay_env(self) -> dict:
        """The environment of an exporter whose ser2net is tools/ser2net-nodelay, as a lab
        installs it: `ser2net` ahead of the real one on its PATH."""
        real = shutil.which("ser2net") or "/usr/sbin/ser2net"
        wrapped = self.dir / "nodelay-bin"
        wrapped.mkdir(exist_ok=True)
        if not (wrapped / "ser2net").exists():
            (wrapped / "ser2net").symlink_to(SER2NET_NODELAY)
        return {**self.env, "PATH": f"{wrapped}{os.pathsep}{self.env.get('PATH', '')}", "SER2NET": real}

    def serial_device_exporter(self, name: str, group: str, device: str, nodelay: bool = False) -> subprocess.Popen:
        """An exporter `name` of a serial device as a RawSerialPort in `group` (shared through
        ser2net while its place is acquired), once the coordinator has it."""
        config = self.dir / f"{name}.yaml"
        config.write_text(f"{group}:\n  RawSerialPort:\n    port: {device}\n    speed: 921600\n")
        process = self._start(f"exporter-{name}", [str(BIN / "labgrid-exporter"), "-c", self.address, "-n", name,
                                                   "--hostname", "127.0.0.1", str(config)],
                              env=self.nodelay_env() if nodelay else None)

        def published() -> bool:
            with lab.Coordinator(self.address) as session:
                return group in session.session.resources.get(name, {})
        _wait_for(published, 30, f"exporter {name} did not publish its serial device")
        return process

    def exporter(self, name: str, ports: dict[str, str]) -> subprocess.Popen:
        """An exporter `name` with a NetworkSerialPort (raw TCP) per group: {group: socket://HOST:PORT}."""
        lines = []
        for group, url in ports.items():
            host, port = url.removeprefix("socket://").split(":")
            lines += [f"{group}:", "  NetworkSerialPort:", f"    host: {host}", f"    port: {port}",
                      "    speed: 921600", "    protocol: raw"]
        config = self.dir / f"{name}.yaml"
        config.write_text("\n".join(lines) + "\n")
        process = self._start(f"exporter-{name}", [str(BIN / "labgrid-exporter"), "-c", self.address, "-n", name,
                                                   "--hostname", "127.0.0.1", str(config)])

        def published() -> bool:
            with lab.Coordinator(self.address) as session:
                return set(session.session.resources.get(name, {})) >= set(ports)
        _wait_for(published, 30, f"exporter {name} did not publish its ports")
        return process

    def client(self, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([str(BIN / "labgrid-client"), "-x", self.address, *args], env=self.env,
                              capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S, check=True)

    def places(self, places: dict[str, tuple[str | list[str] | None, dict[str, str]]]) -> None:
        """Create places {name: (match, matches or None, tags)}, each step for all of them at once."""
        def matches(match: str | list[str] | None) -> list[str]:
            return [match] if isinstance(match, str) else list(match or [])
        steps = [[("-p", name, "create") for name in places],
                 [("-p", name, "add-match", *matches(match)) for name, (match, _) in places.items() if match],
                 [("-p", name, "set-tags", *(f"{k}={v}" for k, v in tags.items()))
                  for name, (_, tags) in places.items() if tags]]
        for step in steps:
            running = [subprocess.Popen([str(BIN / "labgrid-client"), "-x", self.address, *args], env=self.env,
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                       for args in step]
            for process in running:
                out, _ = process.communicate(timeout=COMMAND_TIMEOUT_S)
                assert process.returncode == 0, out

    def stop(self, name: str | None = None) -> None:
        for key in [name] if name else list(self.processes):
            process = self.processes.pop(key)
            process.terminate()
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def imulink(*args: str, env: dict | None = None, timeout: float = COMMAND_TIMEOUT_S) -> subprocess.CompletedProcess:
    return subprocess.run([*IMULINK, *args], capture_output=True, text=True, timeout=timeout, env=env,
                          stdin=subprocess.DEVNULL)


@contextlib.contextmanager
def running(*args: str, env: dict, command: list[str] = IMULINK, stdout=subprocess.PIPE) -> Iterator[subprocess.Popen]:
    """An imulink job running in the background while the body runs; killed after it unless it ended."""
    job = subprocess.Popen([*command, *args], stdout=stdout, stderr=subprocess.PIPE, text=True, env=env)
    try:
        yield job
    finally:
        if job.poll() is None:
            job.kill()


def _board(target: str = "native") -> EmulatedBoard:
    # the virtual reference board in real time, as a real board is: run flat out, it would take a
    # core for the whole module while it waits for its host
    return EmulatedBoard(target, front="tcp", duration_s=5.0, filter_name="eskf",
                         realtime=target == "stm32f407").start()


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    """A coordinator and exporter `rack1` with two native boards, the virtual reference board
    (the image that gets flashed, on the register-level STM32F407 + GY-86) and (where QEMU is)
    one QEMU board as places imu-native-1, imu-native-2, imu-stm32f407-1, imu-qemu-1, tagged by
    board; a place spare-empty with no resource at all."""
    directory = tmp_path_factory.mktemp("farm")
    boards = {"native-1": _board(), "native-2": _board(), "stm32f407-1": _board("stm32f407")}
    if shutil.which("qemu-system-arm"):
        boards["qemu-1"] = _board("qemu")
    the_lab = Lab(directory)
    try:
        the_lab.exporter("rack1", {name: board.address for name, board in boards.items()})
        places: dict[str, tuple[str | None, dict[str, str]]] = {
            f"imu-{name}": (f"rack1/{name}/NetworkSerialPort", {"board": name.split("-")[0], "rack": "rack1"})
            for name in boards}
        places["spare-empty"] = (None, {})
        the_lab.places(places)
        the_lab.boards = boards  # type: ignore[attr-defined]
        yield the_lab
    finally:
        the_lab.stop()
        for board in boards.values():
            board.stop()


def test_a_place_is_a_port_for_every_command(farm):
    """`imulink settings lg://PLACE`: acquired for the command, the board answers, released after."""
    done = imulink("settings", "lg://imu-native-1", "--json", env=farm.env)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["filter"] == "eskf"
    assert "place imu-native-1 acquired" in done.stderr
    with lab.Coordinator(farm.address) as session:
        assert {p.name: p.acquired for p in session.places("imu-*")}["imu-native-1"] is None  # released


def test_an_environment_s_remote_place_is_that_place(farm):
    """`imulink settings lg-env:FILE`: a labgrid environment whose target has a RemotePlace, on
    the coordinator its options name (no $LG_COORDINATOR), is that place: acquired for the
    command, released after; a place the coordinator lacks is lg://PLACE's one line."""
    env_file = farm.dir / "lg-env.yaml"
    env_file.write_text("targets:\n  main:\n    resources:\n      RemotePlace:\n        name: imu-native-1\n"
                        "  gone:\n    resources:\n      RemotePlace:\n        name: imu-nowhere\n"
                        f"options:\n  coordinator_address: {farm.address}\n")
    env = {k: v for k, v in farm.env.items() if k != "LG_COORDINATOR"}
    done = imulink("settings", f"lg-env:{env_file}", "--json", env=env)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["filter"] == "eskf"
    said = done.stderr.splitlines()
    assert len(said) == 1 and said[0].startswith(f"imulink: place imu-native-1 acquired from {farm.address}: "), said
    with lab.Coordinator(farm.address) as session:
        assert session.places("imu-native-1")[0].acquired is None  # released
    _one_error_line(imulink("settings", f"lg-env:{env_file}#gone", env=env), "no place 'imu-nowhere'", farm.address)


def test_the_board_fixture_takes_the_lab_s_place(farm, tmp_path):
    """A project's HIL test (tests/test_board_fixture.py) with LG_PLACE set gets the farm's board:
    the place is held for the test session and released after."""
    from test_board_fixture import run_project_tests

    done = run_project_tests(tmp_path, env={**farm.env, "LG_PLACE": "imu-native-2"})
    assert done.returncode == 0, done.stdout + done.stderr
    assert "BOARD place=imu-native-2 target=None" in done.stdout
    with lab.Coordinator(farm.address) as session:
        assert session.places("imu-native-2")[0].acquired is None


def test_a_farm_board_on_a_local_port(farm):
    """`imulink proxy lg://PLACE --tcp`: the place held while the proxy serves it, released when it stops."""
    proxy = subprocess.Popen([*IMULINK, "proxy", "lg://imu-native-1", "--tcp", "0"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=farm.env)
    try:
        assert proxy.stdout is not None
        address = proxy.stdout.readline().strip()
        assert address.startswith("socket://127.0.0.1:"), proxy.stderr.read() if proxy.poll() is not None else address
        done = imulink("settings", address, "--json", env=farm.env)
        assert done.returncode == 0, done.stderr
        with lab.Coordinator(farm.address) as session:
            assert session.places("imu-native-1")[0].acquired is not None
        proxy.terminate()
        proxy.wait(COMMAND_TIMEOUT_S)
    finally:
        if proxy.poll() is None:
            proxy.kill()
    assert proxy.returncode == 0
    with lab.Coordinator(farm.address) as session:
        assert session.places("imu-native-1")[0].acquired is None


def test_farm_verify_proves_every_board(farm):
    """Every place at once, the virtual reference board among them (about 150 injected samples/s
    in real time, the natives thousands: 12 s of rests keep the run short and still give the
    accuracy after the 10 s it takes to settle)."""
    done = imulink("farm", "verify", "--places", "imu-*", "--input", "sim:rests:12", "--json", env=farm.env)
    assert done.returncode == 0, done.stderr + done.stdout
    report = json.loads(done.stdout)
    rows = {row["place"]: row for row in report["places"]}
    assert set(rows) == {f"imu-{name}" for name in farm.boards}
    for place, row in rows.items():
        assert row["error"] is None and row["bit_exact"] and row["passed"], row
        assert row["samples"] == row["answered"] == row["identical"] == 1200
        assert row["accuracy"] is not None and row["accuracy"]["rms_total_deg"] < 5.0
    assert rows["imu-native-1"]["board"] == "native"
    assert rows["imu-stm32f407-1"]["board"] == "stm32f407-gy86"
    if "imu-qemu-1" in rows:
        assert rows["imu-qemu-1"]["board"] == "qemu-stm32f405"
    with lab.Coordinator(farm.address) as session:
        assert all(p.acquired is None for p in session.places("imu-*"))  # every place released


def test_farm_verify_checks_the_image_a_board_runs(farm):
    """--image: a board runs it (the virtual reference board: the image that gets flashed; the
    QEMU board, its own image) or its place is not proven."""
    image = str(farm.boards["stm32f407-1"].image)
    done = imulink("farm", "verify", "--places", "imu-*", "--image", image, "--input", "sim:rests:2", env=farm.env)
    assert done.returncode == 1, done.stderr
    lines = {line.split()[0]: line for line in done.stdout.splitlines()[1:-1]}
    assert " yes " in lines["imu-stm32f407-1"] and "stm32f407-gy86" in lines["imu-stm32f407-1"]
    assert "ERROR" in lines["imu-native-1"] and "the image is stm32f407-gy86" in lines["imu-native-1"]
    if "qemu-1" in farm.boards:
        assert "ERROR" in lines["imu-qemu-1"] and "the board runs qemu-stm32f405" in lines["imu-qemu-1"]
        qemu_image = str(farm.boards["qemu-1"].image)
        tagged = imulink("farm", "verify", "--tag", "board=qemu", "--image", qemu_image, "--input", "sim:rests:2",
                         env=farm.env)
        assert tagged.returncode == 0, tagged.stderr + tagged.stdout
        assert "1 places: 1 proven bit-exact" in tagged.stdout


def test_a_second_job_on_a_held_place_is_refused_then_waits(farm):
    """Two jobs on one place: the second is refused at once (naming the holder), or with
    --place-wait gets the board once the first is done; the first's run is untouched."""
    with running("inject", "lg://imu-native-2", "--input", "sim:rests:80", "--json", env=farm.env) as first:
        def held() -> bool:
            with lab.Coordinator(farm.address) as session:
                return any(p.acquired for p in session.places("imu-native-2"))
        _wait_for(held, 60, "the first job did not acquire the place")
        second = imulink("record", "lg://imu-native-2", "-o", str(farm.dir / "second.imulog"), env=farm.env)
        assert second.returncode == 2
        assert second.stderr.count("\n") == 1 and "place imu-native-2 is acquired by" in second.stderr, second.stderr
        assert not (farm.dir / "second.imulog").exists()
        waiting = imulink("settings", "lg://imu-native-2", "--place-wait", "90", "--json", env=farm.env)
        out, err = first.communicate(timeout=COMMAND_TIMEOUT_S)
    assert first.returncode == 0, err
    report = json.loads(out)
    assert report["answered"] == report["samples"] == 8000 and report["verdict"]["passed"]
    assert waiting.returncode == 0, waiting.stderr


@pytest.mark.parametrize("option", ["--place-wait", "--wait"])
def test_farm_verify_waits_for_a_held_place(farm, option):
    """farm verify names the wait --place-wait, as every command does; --wait, its old name, still
    works (with a warning). Without it, a held place is its row's error, naming the holder."""
    farm.client("-p", "imu-native-1", "acquire")
    held = True
    job = None
    said: list[str] = []
    try:
        refused = imulink("farm", "verify", "--places", "imu-native-1", "--input", "sim:rests:1", "--json",
                          env=farm.env)
        assert refused.returncode == 1, refused.stderr
        row = json.loads(refused.stdout)["places"][0]
        assert "place imu-native-1 is acquired by" in row["error"] and "--place-wait SECONDS" in row["error"], row
        job = subprocess.Popen([*IMULINK, "farm", "verify", "--places", "imu-native-1", "--input", "sim:rests:1",
                                option, "90", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=farm.env)
        assert job.stderr is not None
        for line in job.stderr:  # the worker says that it waits, then waits: the place is released
            said.append(line)
            if "waiting up to 90 s for it" in line:
                break
        assert said and "place imu-native-1 is acquired by" in said[-1], "".join(said)
        farm.client("-p", "imu-native-1", "release")
        held = False
        out, err = job.communicate(timeout=COMMAND_TIMEOUT_S)
    finally:
        if held:
            farm.client("-p", "imu-native-1", "release")
        if job is not None and job.poll() is None:
            job.kill()
    assert job.returncode == 0, "".join(said) + err
    report = json.loads(out)
    assert report["passed"] == 1 and report["places"][0]["identical"] == 100
    deprecated = [line for line in said if "--wait is deprecated" in line]
    assert len(deprecated) == (option == "--wait"), said


def test_ctrl_c_releases_the_place(farm):
    """A job stopped with Ctrl-C (SIGINT) in the middle of its run gives the place back."""
    # 300000 samples: minutes of injection even at full speed, stopped once it is under way
    lines: list[str] = []
    with running("inject", "lg://imu-native-1", "--input", "sim:rests:3000", env=farm.env, command=IMULINK_CTRL_C,
                 stdout=subprocess.DEVNULL) as job:
        reader = threading.Thread(target=lambda: lines.extend(job.stderr), daemon=True)
        reader.start()
        _wait_for(lambda: any("injecting:" in line for line in lines), 60, "the job did not start injecting")
        job.send_signal(signal.SIGINT)
        job.wait(timeout=COMMAND_TIMEOUT_S)
        reader.join(timeout=COMMAND_TIMEOUT_S)
    err = "".join(lines)
    assert job.returncode == 130, err
    assert "imulink: interrupted" in err
    with lab.Coordinator(farm.address) as session:
        assert session.places("imu-native-1")[0].acquired is None


def test_a_board_lost_mid_run_is_its_place_only(farm):
    """Two more boards on their own exporter; one is stopped while the farm verifies both:
    its row says so, the other is proven, the exit status is 1, both places are released."""
    boards = {"a": _board(), "b": _board()}
    try:
        farm.exporter("rack2", {name: board.address for name, board in boards.items()})
        farm.places({f"lost-{name}": (f"rack2/{name}/NetworkSerialPort", {}) for name in boards})
        with running("farm", "verify", "--places", "lost-*", "--input", "sim:rests:60", "--json",
                     env=farm.env) as run:
            def answering() -> bool:  # the board has been injected into for a while: it has sent estimates
                with lab.Coordinator(farm.address) as session:
                    return any(p.acquired for p in session.places("lost-b"))
            _wait_for(answering, 60, "the farm did not acquire lost-b")
            time.sleep(1.5)
            boards["b"].stop()
            out, err = run.communicate(timeout=COMMAND_TIMEOUT_S)
        assert run.returncode == 1, err
        rows = {row["place"]: row for row in json.loads(out)["places"]}
        assert rows["lost-a"]["passed"] and rows["lost-a"]["identical"] == 6000
        assert not rows["lost-b"]["passed"] and rows["lost-b"]["error"], rows["lost-b"]
        with lab.Coordinator(farm.address) as session:
            assert all(p.acquired is None for p in session.places("lost-*"))
    finally:
        farm.stop("exporter-rack2")
        for board in boards.values():
            board.stop()


@pytest.mark.parametrize("nodelay", [False, True], ids=["ser2net", "ser2net-nodelay"])
def test_a_usb_serial_board_through_ser2net(farm, nodelay):
    """A lab's usual board: a serial device (here the native board's pty; a USB serial adapter in
    a lab) exported as a RawSerialPort, which the exporter shares through ser2net (RFC 2217)
    while the place is acquired. The board is reached as rfc2217:// and proven bit-exact: by
    labgrid's own ser2net command, and with tools/ser2net-nodelay as the exporter's ser2net,
    whose accepter then has TCP_NODELAY."""
    _needs_ser2net()
    board = EmulatedBoard("native", front="pty", duration_s=5.0, filter_name="eskf").start()
    name = "usb-nd" if nodelay else "usb"
    try:
        exporter = farm.serial_device_exporter(f"{name}-rack", f"{name}-1", str(board.address), nodelay)
        farm.places({f"{name}-1": (f"{name}-rack/{name}-1/NetworkSerialPort", {"board": "native", "link": "usb"})})
        # each injected sample waits for its answer: without nodelay that is tens of ms, so a short run
        with running("inject", f"lg://{name}-1", "--input", "sim:rests:1", "--json", env=farm.env) as job:
            assert job.stderr is not None
            said = [job.stderr.readline(), job.stderr.readline()]  # the place acquired, the first sample answered
            assert "RawSerialPort at rfc2217://127.0.0.1:" in said[0] and said[1].startswith("injecting"), said
            ser2net = [Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") for pid in _children(exporter.pid)]
            assert len(ser2net) == 1 and Path(ser2net[0][0].decode()).name == "ser2net", ser2net
            accepters = [arg for arg in ser2net[0] if b"accepter:" in arg]
            assert len(accepters) == 1 and (b",tcp(nodelay)," in accepters[0]) == nodelay, accepters
            out, err = job.communicate(timeout=COMMAND_TIMEOUT_S)
        assert job.returncode == 0, err
        report = json.loads(out)
        assert report["samples"] == report["answered"] == 100 and report["verdict"]["passed"]
    finally:
        farm.stop(f"exporter-{name}-rack")
        board.stop()


def _needs_ser2net() -> None:
    if not (shutil.which("ser2net") or Path("/usr/sbin/ser2net").exists()):
        if os.environ.get("IMULINK_REQUIRE_LABGRID"):
            pytest.fail("ser2net is missing: tools/install-system-packages.sh installs it")
        pytest.skip("ser2net is not installed")


class GpioBox:
    """A lab's GPIO box and relay as labgrid's HttpDigitalOutput and its `rest` power backend
    speak to one: PUT /LINE with the body 1 or 0 sets a line, GET /LINE reads it. Its lines are
    wired to a virtual board: `boot0` to its BOOT0 pin, `reset` to NRST (asserted: NRST held
    low), and the relay `power1` to its supply (off: the chip does nothing, as held in reset;
    on: it starts, as from a reset). Every change is recorded."""

    def __init__(self, board: EmulatedBoard):
        assert board.virtual is not None
        virtual = board.virtual
        self.levels = {"boot0": False, "reset": False, "power1": True}
        self.changes: list[tuple[str, bool]] = []
        box = self

        def drive(line: str, level: bool) -> None:
            if line == "boot0":
                virtual.set_pins(boot0=level)
            elif line == "reset":
                virtual.set_pins(reset=level)
            else:
                virtual.set_pins(reset=not level)

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_PUT(self):
                line = self.path.strip("/")
                body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
                if line not in box.levels or body not in (b"0", b"1"):
                    self.send_error(404)
                    return
                level = body == b"1"
                box.levels[line] = level
                box.changes.append((line, level))
                drive(line, level)
                self.send_response(204)
                self.end_headers()

            def do_GET(self):
                line = self.path.strip("/")
                if line not in box.levels:
                    self.send_error(404)
                    return
                body = b"1" if box.levels[line] else b"0"
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


class LinesLab:
    """The virtual reference board's pty exported through ser2net (tools/ser2net-nodelay),
    with `boot0` and `reset` HttpDigitalOutput resources and a NetworkPowerPort (`rest`
    model) of a GpioBox wired to it; places ref-1 (serial port, boot0, reset), ref-boot0-only
    and ref-power (serial port, boot0, power)."""

    def __init__(self, farm: Lab, board: EmulatedBoard, box: GpioBox):
        self.farm, self.board, self.box = farm, board, box
        self.image = str(board.image)
        config = farm.dir / "lines.yaml"
        outputs = "".join(f"  {line}:\n    cls: HttpDigitalOutput\n    url: {box.url}/{line}\n"
                          f"    body_asserted: '1'\n    body_deasserted: '0'\n" for line in ("boot0", "reset"))
        power = (f"  power:\n    cls: NetworkPowerPort\n    model: rest\n    host: '{box.url}/power{{index}}'\n"
                 "    index: 1\n")
        config.write_text(f"board-1:\n  RawSerialPort:\n    port: {board.address}\n    speed: 921600\n{outputs}{power}")
        farm._start("exporter-lines", [str(BIN / "labgrid-exporter"), "-c", farm.address, "-n", "lines-rack",
                                       "--hostname", "127.0.0.1", str(config)],
                    env=farm.nodelay_env())  # as a lab's exporter: each bootloader read waits for its answer

        def published() -> bool:
            with lab.Coordinator(farm.address) as session:
                return set(session.session.resources.get("lines-rack", {}).get("board-1", {})) == {
                    "RawSerialPort", "boot0", "reset", "power"}
        _wait_for(published, 30, "the exporter did not publish the board and its lines")
        serial_match = "lines-rack/board-1/NetworkSerialPort"
        farm.places({"ref-1": ([serial_match, "lines-rack/board-1/HttpDigitalOutput/boot0",
                                "lines-rack/board-1/HttpDigitalOutput/reset"], {"board": "stm32f407"}),
                     "ref-boot0-only": ([serial_match, "lines-rack/board-1/HttpDigitalOutput/boot0"], {}),
                     "ref-power": ([serial_match, "lines-rack/board-1/HttpDigitalOutput/boot0",
                                    "lines-rack/board-1/NetworkPowerPort/power"], {})})


#: The line changes of one flash through ref-1's lines: BOOT0 high and a reset pulse into the
#: bootloader, BOOT0 low and a reset pulse into the flash's image.
FLASH_LINE_CHANGES = [("boot0", True), ("reset", True), ("reset", False),
                      ("boot0", False), ("reset", True), ("reset", False)]


@pytest.fixture(scope="class")
def lines_lab(farm):
    """A LinesLab for the tests of one class: its real-time board is stopped after them."""
    _needs_ser2net()
    board = EmulatedBoard("stm32f407", front="pty", duration_s=5.0, filter_name="eskf", realtime=True).start()
    box = GpioBox(board)
    try:
        yield LinesLab(farm, board, box)
    finally:
        if "exporter-lines" in farm.processes:
            farm.stop("exporter-lines")
        box.close()
        board.stop()


class TestAPlaceWithBoot0AndResetLines:
    """Flashing through a place's lines: `imulink flash` and `imulink farm verify --flash`
    (one board and its lines for both tests, stopped after them)."""

    def test_flash_drives_the_place_s_boot0_and_reset_lines(self, lines_lab):
        """`imulink flash IMAGE lg://PLACE` on a place with BOOT0 and reset lines (labgrid
        HttpDigitalOutput resources of a GPIO box wired to the virtual reference board) and its
        serial device through ser2net (tools/ser2net-nodelay): by default it drives the lines
        (BOOT0 high, a reset pulse), flashes over the chip's UART bootloader, then BOOT0 low and a
        reset start the flashed image, whose HELLO it checks; the board then answers as the
        application. A place with BOOT0 and a power switch (labgrid's NetworkPowerPort, `rest`
        model, a relay of the same box) power-cycles instead. A place without the lines, or with
        BOOT0 alone, is one line with --enter lines, exit 2."""
        farm, box, image = lines_lab.farm, lines_lab.box, lines_lab.image
        virtual = lines_lab.board.virtual
        assert virtual is not None
        changes, boots = len(box.changes), len(virtual.board.booted)
        done = imulink("flash", image, "lg://ref-1", env=farm.env)
        assert done.returncode == 0, done.stderr
        assert "boot0 (HttpDigitalOutput), reset (HttpDigitalOutput): BOOT0 high and a reset" in done.stderr
        assert "; running: stm32f407-gy86 firmware" in done.stdout and "as built" in done.stdout, done.stdout
        assert box.changes[changes:] == FLASH_LINE_CHANGES
        assert virtual.error is None
        assert virtual.board.booted[max(0, boots - 1):] == ["flash", "system memory", "flash"]
        bootloader = virtual.board.last_bootloader
        assert bootloader is not None and bootloader.erased_sectors > 0  # written, not only read
        answered = imulink("settings", "lg://ref-1", "--json", env=farm.env)  # the application answers
        assert answered.returncode == 0 and json.loads(answered.stdout)["filter"] == "eskf", answered.stderr

        changes = len(box.changes)
        _one_error_line(imulink("flash", image, "lg://ref-boot0-only", "--enter", "lines", env=farm.env),
                        "place ref-boot0-only has boot0 (HttpDigitalOutput)", "a digital output named 'reset'")
        _one_error_line(imulink("flash", image, "lg://imu-native-1", "--enter", "lines", env=farm.env),
                        "place imu-native-1 has no BOOT0, reset or power line", "'boot0'")
        assert box.changes[changes:] == []  # neither touched a line

        # BOOT0 and a power switch, no reset line: power cycles instead (a dry run: into the
        # bootloader, the chip checked, and back into the firmware)
        boots = len(virtual.board.booted)
        dry = imulink("flash", image, "lg://ref-power", "--dry-run", env=farm.env)
        assert dry.returncode == 0 and "dry run: nothing written" in dry.stdout, dry.stderr
        assert "boot0 (HttpDigitalOutput), power (NetworkPowerPort): BOOT0 high" in dry.stderr
        assert box.changes[changes:] == [("boot0", True), ("power1", False), ("power1", True),
                                         ("boot0", False), ("power1", False), ("power1", True)]
        assert virtual.board.booted[boots:] == ["system memory", "flash"]
        answered = imulink("settings", "lg://ref-power", "--json", env=farm.env)
        assert answered.returncode == 0 and json.loads(answered.stdout)["filter"] == "eskf", answered.stderr
        with lab.Coordinator(farm.address) as session:
            assert all(p.acquired is None for p in session.places())

    def test_farm_verify_flashes_then_proves_the_board(self, lines_lab):
        """`imulink farm verify --flash --image IMAGE`: the worker flashes the image into its held
        place through the place's lines (the same line changes as `imulink flash`, the chip's
        bootloader erasing and writing), then proves the board bit-exact; the row says flashed."""
        farm, box = lines_lab.farm, lines_lab.box
        virtual = lines_lab.board.virtual
        assert virtual is not None
        changes, boots = len(box.changes), len(virtual.board.booted)
        erased_before = virtual.board.last_bootloader
        done = imulink("farm", "verify", "--flash", "--image", lines_lab.image, "--places", "ref-1",
                       "--input", "sim:rests:2", "--json", env=farm.env)
        assert done.returncode == 0, done.stderr + done.stdout
        [row] = json.loads(done.stdout)["places"]
        assert row["flashed"] == "yes" and row["image"] == "matches" and row["error"] is None, row
        assert row["board"] == "stm32f407-gy86" and row["bit_exact"] and row["passed"], row
        assert row["samples"] == row["answered"] == row["identical"] == 200
        assert box.changes[changes:] == FLASH_LINE_CHANGES
        assert virtual.error is None and virtual.board.booted[boots:] == ["system memory", "flash"]
        bootloader = virtual.board.last_bootloader
        assert bootloader is not None and bootloader is not erased_before and bootloader.erased_sectors > 0
        assert "ref-1: boot0 (HttpDigitalOutput), reset (HttpDigitalOutput): BOOT0 high" in done.stderr
        with lab.Coordinator(farm.address) as session:
            assert session.places("ref-1")[0].acquired is None

    def test_the_board_fixture_flashes_the_image_first(self, lines_lab, tmp_path):
        """The `board` fixture with --imulink-image on a place with lines: the place is held, the
        image flashed through its lines (as farm verify --flash), then the project's test runs."""
        from test_board_fixture import run_project_tests

        farm, box = lines_lab.farm, lines_lab.box
        changes = len(box.changes)
        done = run_project_tests(tmp_path, "--imulink-image", lines_lab.image, env={**farm.env, "LG_PLACE": "ref-1"})
        assert done.returncode == 0, done.stdout + done.stderr
        assert "BOARD place=ref-1 target=None" in done.stdout
        assert box.changes[changes:] == FLASH_LINE_CHANGES
        with lab.Coordinator(farm.address) as session:
            assert session.places("ref-1")[0].acquired is None


def test_farm_verify_flash_on_boards_that_cannot_be_flashed(farm):
    """`farm verify --flash` on emulated boards (native, QEMU: no bootloader, they run the image
    they were started with): each place's row is ERROR with the one line that says so, at once
    (no flash attempted, nothing hangs), exit 1; every place released."""
    image = str(farm.boards["stm32f407-1"].image)
    started = time.monotonic()
    done = imulink("farm", "verify", "--flash", "--image", image, "--places", "imu-[nq]*-1", env=farm.env)
    took = time.monotonic() - started
    assert done.returncode == 1, done.stderr + done.stdout
    assert done.stdout.splitlines()[0].split()[:5] == ["place", "board", "firmware", "flashed", "samples"]
    lines = {line.split()[0]: line for line in done.stdout.splitlines()[1:-1]}
    expected = {"imu-native-1": "native", **({"imu-qemu-1": "qemu-stm32f405"} if "qemu-1" in farm.boards else {})}
    assert set(lines) == set(expected)
    for place, board in expected.items():
        assert " no " in lines[place] and "ERROR" in lines[place], lines[place]
        assert f"cannot flash: the board is the emulated {board} board" in lines[place], lines[place]
    assert f"{len(expected)} places: 0 proven bit-exact, 0 not, {len(expected)} could not be verified" in done.stdout
    assert took < 60, took
    with lab.Coordinator(farm.address) as session:
        assert all(p.acquired is None for p in session.places("imu-*"))
    usage = imulink("farm", "verify", "--flash", "--places", "imu-native-1", env=farm.env)
    _one_error_line(usage, "--flash flashes --image ELF")


#: Seconds a job may take to end after the exporter of its place is lost (docs/farm.md): the
#: link's silence limit and the command's last attempts, with room for a loaded machine.
LOST_EXPORTER_S = 30


def _children(pid: int) -> list[int]:
    """The processes `pid` started (Linux)."""
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _ended_on_one_error_line(job: subprocess.Popen, *words: str) -> tuple[str, float]:
    """(stderr, seconds) of a job that must end within LOST_EXPORTER_S with exit status 2 and
    one error line, its last, naming `words`."""
    started = time.monotonic()
    _, err = job.communicate(timeout=LOST_EXPORTER_S)
    took = time.monotonic() - started
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith(("imulink: error: ", "imulink: warning: "))]
    assert job.returncode == 2 and errors == lines[-1:] and errors[0].startswith("imulink: error: "), err
    for word in words:
        assert word in errors[0], errors[0]
    return err, took


def test_an_exporter_lost_while_a_job_holds_its_place(farm):
    """The exporter of a held place's board goes away in the middle of a job: frozen (its machine
    hangs, its network drops everything: SIGSTOP of the exporter and its ser2net), a recording
    ends as silent, and the release waits for the coordinator, which gives up on the frozen
    exporter after its own 10 s; killed (SIGKILL of both), an injection ends as disconnected.
    Each job ends within LOST_EXPORTER_S with one error line (no warning), exit 2, and the
    place is free when it has ended."""
    _needs_ser2net()
    board = EmulatedBoard("native", front="pty", duration_s=600.0, filter_name="eskf", realtime=True).start()
    config = farm.dir / "far.yaml"
    config.write_text(f"far-1:\n  RawSerialPort:\n    port: {board.address}\n    speed: 921600\n")
    exporter = farm._start("exporter-far", [str(BIN / "labgrid-exporter"), "-c", farm.address, "-n", "far-rack",
                                            "--hostname", "127.0.0.1", str(config)])
    stopped: list[int] = []
    try:
        def published() -> bool:
            with lab.Coordinator(farm.address) as session:
                return "far-1" in session.session.resources.get("far-rack", {})
        _wait_for(published, 30, "the exporter did not publish the serial device")
        farm.places({"far-1": ("far-rack/far-1/NetworkSerialPort", {})})

        def lose(job: subprocess.Popen, started_line: str, signum: int) -> None:
            """Once the job's link runs (its `started_line` on stderr), the exporter and its ser2net get `signum`."""
            assert job.stderr is not None
            for line in job.stderr:
                if line.startswith(started_line):
                    break
            else:
                raise AssertionError(f"the job ended before its link ran: {job.wait()}")
            processes = [exporter.pid, *_children(exporter.pid)]
            assert len(processes) == 2, processes  # the exporter and the ser2net it started for the place
            for pid in processes:
                os.kill(pid, signum)
            if signum == signal.SIGSTOP:
                stopped.extend(processes)

        recording = farm.dir / "far.imulog"
        with running("record", "lg://far-1", "-o", str(recording), "--duration", "600", env=farm.env) as job:
            lose(job, "recording", signal.SIGSTOP)
            err, took = _ended_on_one_error_line(job, "sent nothing for", "keeps the")
        assert recording.exists()  # what came before is kept
        with lab.Coordinator(farm.address) as session:
            assert session.places("far-1")[0].acquired is None, (err, took)
        for pid in stopped:
            os.kill(pid, signal.SIGCONT)
        stopped.clear()

        with running("inject", "lg://far-1", "--input", "sim:rests:600", env=farm.env) as job:
            lose(job, "injecting", signal.SIGKILL)
            _ended_on_one_error_line(job, "disconnected")
        with lab.Coordinator(farm.address) as session:
            assert session.places("far-1")[0].acquired is None
    finally:
        for pid in stopped:
            os.kill(pid, signal.SIGCONT)
        farm.stop("exporter-far")
        board.stop()


def _one_error_line(done: subprocess.CompletedProcess, *words: str) -> None:
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imulink: error: "), done.stderr
    for word in words:
        assert word in lines[0], lines[0]


def test_an_unknown_place(farm):
    _one_error_line(imulink("record", "lg://imu-nowhere", "-o", str(farm.dir / "x.imulog"), env=farm.env),
                    "no place 'imu-nowhere'", "imu-native-1")
    _one_error_line(imulink("farm", "verify", "--places", "nowhere-*", env=farm.env), "no place matches")


def test_a_place_without_a_serial_port(farm):
    _one_error_line(imulink("inject", "lg://spare-empty", "--input", "sim:rests:1", env=farm.env),
                    "place spare-empty has no serial port")


def test_a_place_whose_board_another_place_holds(farm):
    """Two places that share one serial port: while one is held, the other is refused, naming it."""
    farm.places({"alias-native-1": ("rack1/native-1/NetworkSerialPort", {})})
    farm.client("-p", "imu-native-1", "acquire")
    try:
        _one_error_line(imulink("settings", "lg://alias-native-1", env=farm.env),
                        "place alias-native-1: the coordinator refused to acquire it", "imu-native-1")
    finally:
        farm.client("-p", "imu-native-1", "release")


def test_a_coordinator_that_is_down(farm):
    """Nothing listens at the address: one line within the stated timeout."""
    down = f"127.0.0.1:{_free_port()}"
    started = time.monotonic()
    _one_error_line(imulink("settings", "lg://imu-native-1", "--coordinator", down, env=farm.env),
                    f"coordinator at {down} does not answer")
    _one_error_line(imulink("farm", "verify", "--coordinator", down, "--timeout", "3", env=farm.env),
                    f"coordinator at {down} does not answer", "the limit is 3 s")
    assert time.monotonic() - started < 2 * (lab.TIMEOUT_S + 10)


def test_a_coordinator_that_never_answers(farm):
    """Something listens at the address but never speaks gRPC: the stated timeout, then one line."""
    silent = socket.create_server(("127.0.0.1", 0))
    address = f"127.0.0.1:{silent.getsockname()[1]}"
    try:
        started = time.monotonic()
        _one_error_line(imulink("farm", "places", "--coordinator", address, "--timeout", "2", env=farm.env),
                        f"coordinator at {address} does not answer", "no answer within 2 s")
        assert time.monotonic() - started < 2 + 15  # the timeout, the interpreter's start, the session's end
    finally:
        silent.close()


def test_a_lost_exporter(farm):
    """The exporter of a place's board goes away: the place's serial port is gone, in one line."""
    board = _board()
    try:
        farm.exporter("rack3", {"c": board.address})
        farm.places({"gone-c": ("rack3/c/NetworkSerialPort", {})})
        assert imulink("settings", "lg://gone-c", env=farm.env).returncode == 0
        farm.stop("exporter-rack3")

        def forgotten() -> bool:
            with lab.Coordinator(farm.address) as session:
                return "rack3" not in session.session.resources or not any(
                    entry.avail for group in session.session.resources["rack3"].values() for entry in group.values())
        _wait_for(forgotten, 30, "the coordinator did not notice the exporter's end")
        _one_error_line(imulink("settings", "lg://gone-c", env=farm.env), "place gone-c", "exporter")
    finally:
        board.stop()


def test_labgrids_serial_module_is_the_lab_environments():
    """In the lab's environment (`make test-farm`), the `serial` module on disk is
    pyserial-labgrid's (reinstalled last by the Makefile), which labgrid is tested with."""
    if not os.environ.get("IMULINK_REQUIRE_LABGRID"):
        pytest.skip("only in the lab environment of `make test-farm`")
    from importlib.metadata import distribution

    import serial

    dist = distribution("pyserial-labgrid")
    record = {str(f): f.hash.value for f in dist.files or [] if f.hash is not None}
    module = Path(serial.__file__)
    import base64
    import hashlib

    digest = base64.urlsafe_b64encode(hashlib.sha256(module.read_bytes()).digest()).rstrip(b"=").decode()
    assert record["serial/__init__.py"] == digest
