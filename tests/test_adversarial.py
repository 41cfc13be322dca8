"""The command line under faults and bad input, as a new user would meet them.

Every case runs `imulink` as its own process, with a time limit, and checks what a user
sees: the exit status (0 ok, 1 not proven bit-exact, 2 usage or I/O error, 130
interrupted), exactly one line `imulink: error: ...` and no traceback, and that no file
that was there before changed. The cases: every verb with bad ports, bad files and bad
numbers; recordings with a flipped bit, a cut or zero fill anywhere, or another schema;
a full disk (`ulimit -f`); a board that goes silent, disconnects, or whose recorder is
killed and restarted; Ctrl-C and SIGTERM.
"""
from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from scipy.io import savemat

from imulink import hil, protocol
from imulink.board.emulator import EmulatedBoard
from imulink.io.recording import KIND_HEADER, KIND_RECEIVED, MAGIC, load_recording, read_records

#: `imulink`, taking SIGINT as Ctrl-C even when the suite runs as a background job of a
#: non-interactive shell: such a job starts with SIGINT ignored, and Python then keeps it so.
CLI = [sys.executable, "-c", "import signal, sys\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"
       "from imulink.cli import main\nsys.exit(main())"]
#: Seconds any command may take here; none should come near it (a hang shows as a failure).
TIME_LIMIT_S = 60


def imulink(*args, cwd=None, limit_file_kib: int | None = None) -> subprocess.CompletedProcess:
    """Run the command line to its end (TimeoutExpired, a test failure, if it hangs)."""
    command = CLI + [str(a) for a in args]
    if limit_file_kib is not None:  # the file-size limit of a full disk, for this process only
        command = ["bash", "-c", f'ulimit -f {limit_file_kib} && exec "$@"', "bash"] + command
    return subprocess.run(command, capture_output=True, text=True, timeout=TIME_LIMIT_S, cwd=cwd,
                          stdin=subprocess.DEVNULL)


def assert_error(result: subprocess.CompletedProcess, *fragments: str, status: int = 2) -> None:
    """A failure as the user sees it: the status, one last line `imulink: error: ...`, no traceback."""
    err = result.stderr
    errors = [line for line in err.splitlines() if line.startswith("imulink: error: ")]
    assert result.returncode == status, (result.returncode, err)
    assert len(errors) == 1 and err.rstrip().endswith(errors[0]) and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in errors[0], errors[0]


class Unchanged:
    """Asserts on exit that the files under a directory are byte for byte what they were
    (none changed, none removed; new ones only where `allow_new`)."""

    def __init__(self, directory: Path, allow_new: bool = False):
        self.directory, self.allow_new = directory, allow_new

    def _files(self) -> dict[str, bytes]:
        return {str(p.relative_to(self.directory)): p.read_bytes()
                for p in sorted(self.directory.rglob("*")) if p.is_file() and not p.is_symlink()}

    def __enter__(self):
        self.before = self._files()
        return self

    def __exit__(self, *exc_info):
        after = self._files()
        assert {k: after.get(k) for k in self.before} == self.before, "a file that was there changed"
        if not self.allow_new:
            assert sorted(after) == sorted(self.before), f"new files: {sorted(set(after) - set(self.before))}"


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A real recording of the emulated board: 2 s at 100 Hz of the ESKF, in real time (so
    that the stream is spread over many records)."""
    path = tmp_path_factory.mktemp("good") / "good.imulog"
    with EmulatedBoard(front="tcp", duration_s=60.0, filter_name="eskf", realtime=True) as board:
        hil.record(board.address, path, duration_s=2.0)
    return path


@pytest.fixture
def files(tmp_path, recording) -> Path:
    """A directory with every kind of file a user might hand over by mistake."""
    (tmp_path / "good.imulog").write_bytes(recording.read_bytes())
    (tmp_path / "empty.imulog").write_bytes(b"")
    (tmp_path / "text.imulog").write_text("hello\n")
    (tmp_path / "magic-only.imulog").write_bytes(MAGIC)
    (tmp_path / "empty.mat").write_bytes(b"")
    (tmp_path / "garbage.mat").write_bytes(os.urandom(3000))
    (tmp_path / "text.mat").write_text("MATLAB 5.0 MAT-file, but not really" * 10)
    savemat(tmp_path / "nokeys.mat", {"x": np.ones(3)})
    savemat(tmp_path / "shape.mat", {"imu_gyr": np.ones((10, 2)), "imu_acc": np.ones((10, 3)),
                                     "imu_mag": np.ones((10, 3)), "sampling_rate": 100.0})
    savemat(tmp_path / "one-sample.mat", {"imu_gyr": np.ones((1, 3)), "imu_acc": np.ones((1, 3)),
                                          "imu_mag": np.ones((1, 3)), "sampling_rate": 100.0})
    nan = np.ones((50, 3))
    nan[7, 1] = np.nan
    savemat(tmp_path / "nan.mat", {"imu_gyr": nan, "imu_acc": np.ones((50, 3)), "imu_mag": np.ones((50, 3)),
                                   "sampling_rate": 100.0})
    savemat(tmp_path / "rate-inf.mat", {"imu_gyr": np.ones((50, 3)), "imu_acc": np.ones((50, 3)),
                                        "imu_mag": np.ones((50, 3)), "sampling_rate": np.inf})
    savemat(tmp_path / "rate-text.mat", {"imu_gyr": np.ones((50, 3)), "imu_acc": np.ones((50, 3)),
                                         "imu_mag": np.ones((50, 3)), "sampling_rate": "fast"})
    (tmp_path / "not-an-image.elf").write_bytes(b"\x7fELF" + bytes(60))
    (tmp_path / "dir").mkdir()
    os.mkfifo(tmp_path / "fifo.imulog")
    os.mkfifo(tmp_path / "fifo.mat")
    return tmp_path


# ---------------------------------------------------------------------------- bad numbers and names


BAD_ARGUMENTS = [
    # (argv, what the error line says)
    (["simulate", "--duration", "inf"], "--duration: must be a positive finite number"),
    (["simulate", "--duration", "nan"], "--duration: must be a positive finite number"),
    (["simulate", "--duration", "-3"], "--duration: must be a positive finite number"),
    (["simulate", "--duration", "1e400"], "--duration: must be a positive finite number"),
    (["simulate", "--rate", "inf", "--duration", "1"], "--rate: must be a positive finite number"),
    (["simulate", "--rate", "0"], "--rate: must be a positive finite number"),
    (["simulate", "--rate", "1e9", "--duration", "20"], "a trajectory needs from 2 to 18000000 samples"),
    (["simulate", "--rate", "0.5", "--duration", "2", "--settle", "0"], "a trajectory needs from 2"),
    (["simulate", "--rate", "5", "--duration", "20", "--settle", "1"], "sample_rate=5.0 Hz"),
    (["simulate", "--seed", "-1"], "--seed: must be an integer from 0 to 4294967295"),
    (["simulate", "--seed", "1.5"], "--seed: must be an integer"),
    (["simulate", "--seed", str(2**40)], "--seed: must be an integer"),
    (["simulate", "--settle", "-5", "--duration", "2"], "--settle: must be a finite number from 0"),
    (["simulate", "--settle", "nan"], "--settle: must be a finite number from 0"),
    (["simulate", "--settle", "30", "--duration", "20"], "--settle 30 s leaves nothing of the 20 s run"),
    (["simulate", "--filters", ",", "--duration", "1"], "unknown filter(s) ','"),
    (["simulate", "--filters", "eskf,bogus"], "unknown filter(s) bogus"),
    (["simulate", "--scenario", "moon"], "--scenario: invalid choice"),
    (["filters", "--filters", ""], "unknown filter(s) ''"),
    (["bogus-command"], "invalid choice: 'bogus-command'"),
    (["emulate", "--tcp", "70000"], "--tcp: must be a TCP port from 0 to 65535"),
    (["emulate", "--tcp", "-1"], "--tcp: must be a TCP port"),
    (["emulate", "--serial", "foo://x"], "cannot open foo://x"),
    (["emulate", "--seed", "-1"], "--seed: must be an integer from 0"),
    (["emulate", "--schema-hash", "0x1FFFFFFFF"], "--schema-hash: must be an integer from 0 to 0xFFFFFFFF"),
    (["emulate", "--schema-hash", "-1"], "--schema-hash: must be an integer from 0 to 0xFFFFFFFF"),
    (["emulate", "--schema-hash", "zz"], "--schema-hash: must be an integer"),
    (["emulate", "--rate", "1e9"], "sample_rate=1000000000.0 does not fit the fixed-point format Q16"),
    (["emulate", "--rate", "1000", "--duration", "1e6"], "a trajectory needs from 2 to 18000000 samples"),
    (["emulate", "--rate", "5", "--filter", "eskf"], "setting out of range for 'eskf': sample_rate=5.0 Hz"),
    (["emulate", "--duration", "nan"], "--duration: must be a positive finite number"),
    (["emulate", "--duration", "0.01"], "a trajectory needs from 2"),
    (["emulate", "--drop-byte", "2"], "--drop-byte: must be a probability from 0 to 1"),
    (["emulate", "--flip-bit", "nan"], "--flip-bit: must be a probability"),
    (["emulate", "--stall-duration", "inf"], "--stall-duration: must be a finite number from 0"),
    (["emulate", "--fault-seed", "-4"], "--fault-seed: must be an integer from 0"),
    (["emulate", "--profile", "gy99"], "unknown sensor profile 'gy99'"),
    (["emulate", "--baud", "0", "--serial", "loop://"], "--baud: must be a baud rate from 1"),
    (["emulate", "--image", "/dev/zero"], "/dev/zero is not a regular file"),
    (["emulate", "--image", "nothing"], "cannot read nothing: No such file or directory"),
    (["demo", "--rate", "1e9"], "sample_rate=1000000000.0 does not fit the fixed-point format Q16"),
    (["demo", "--rate", "1000", "--duration", "1e6"], "a trajectory needs from 2 to 18000000 samples"),
    (["demo", "--duration", "inf"], "--duration: must be a positive finite number"),
    (["demo", "--rate", "20"], "setting out of range for 'eskf': sample_rate=20.0 Hz"),
    (["demo", "--seed", "-1"], "--seed: must be an integer from 0"),
    (["demo", "--output", "/dev/null"], "/dev/null exists and is not a regular file"),
    (["proxy", "foo://x"], "cannot open foo://x"),
    (["proxy", "/dev/imulink-no-such-port"], "cannot open /dev/imulink-no-such-port"),
    (["proxy", "loop://", "--tcp", "99999"], "--tcp: must be a TCP port"),
    (["proxy", "loop://", "--serial", "foo://x"], "cannot open foo://x"),
    (["record", "/dev/imulink-no-such-port", "-o", "x.imulog"], "no such port"),
    (["record", "foo://x", "-o", "x.imulog"], "cannot open foo://x"),
    (["record", "socket://127.0.0.1:1", "-o", "x.imulog"], "connection refused"),
    (["record", "socket://nowhere", "-o", "x.imulog"], "cannot open socket://nowhere"),
    (["record", "loop://", "-o", "x.imulog", "--baud", "0"], "--baud: must be a baud rate from 1"),
    (["record", "loop://", "-o", "x.imulog", "--baud", "-9600"], "--baud: must be a baud rate"),
    (["record", "loop://", "-o", "x.imulog", "--duration", "inf"], "--duration: must be a positive finite number"),
    (["record", "loop://", "-o", "x.imulog", "--duration", "0"], "--duration: must be a positive finite number"),
    (["record", "loop://", "-o", "x.imulog", "--silence-timeout", "nan"], "--silence-timeout: must be a positive"),
    (["record", "loop://", "-o", "x.imulog", "--checkpoint", "-1"], "--checkpoint: must be a number of seconds"),
    (["record", "loop://", "-o", "x.imulog", "--checkpoint", "inf"], "--checkpoint: must be a number of seconds"),
    (["record", "loop://", "-o", "x.imulog", "--profile", "x"], "unknown sensor profile 'x'"),
    (["record", "loop://", "-o", "/dev/null"], "/dev/null exists and is not a regular file"),
    (["record", "loop://", "-o", "/dev/null", "--force"], "/dev/null exists and is not a regular file"),
    (["record", "loop://", "-o", "no/such/dir/x.imulog"], "cannot create a file in no/such/dir"),
    (["record", "loop://"], "the following arguments are required: --output/-o"),
    (["inject", "loop://", "--input", "sim:rests:nan"], "duration nan s and rate 100.0 Hz must be positive finite"),
    (["inject", "loop://", "--input", "sim:rests:inf"], "must be positive finite numbers"),
    (["inject", "loop://", "--input", "sim:rests:-5"], "must be positive finite numbers"),
    (["inject", "loop://", "--input", "sim:rests:0.01"], "a trajectory needs from 2"),
    (["inject", "loop://", "--input", "sim:rests:10:1e9"], "a trajectory needs from 2 to 18000000 samples"),
    (["inject", "loop://", "--input", "sim:rests:10:100:-1"], "the seed must be an integer from 0"),
    (["inject", "loop://", "--input", "sim:rests:10:100:x"], "seed an integer"),
    (["inject", "loop://", "--input", "sim:rests:a:b"], "duration and rate must be numbers"),
    (["inject", "loop://", "--input", "sim:"], "bad simulated input 'sim:'"),
    (["inject", "loop://", "--input", "sim:rests:1:2:3:4"], "bad simulated input"),
    (["inject", "loop://", "--input", "sim:moon"], "bad simulated input"),
    (["inject", "loop://", "--input", "nothing.imulog"], "not found"),
    (["record", "loop://", "--profile", "x"], "unknown sensor profile"),
    (["inject", "loop://", "--input", "sim:rests:20", "--filter", "x"], "--filter: invalid choice"),
    (["inject", "loop://", "--input", "sim:rests:20"], "no imulink board answered on loop://"),
    (["inject", "/dev/imulink-no-such-port", "--input", "sim:rests:20"], "no such port"),
    (["flash", "/dev/zero", "--dry-run"], "/dev/zero is not a regular file"),
    (["flash", "nothing.elf", "--dry-run"], "cannot read nothing.elf"),
    (["flash", "x.bin", "--address", "0x1FFFFFFFF", "--dry-run"], "--address: must be an integer from 0"),
    (["flash", "x.elf", "/dev/ttyX", "--baud", "0"], "--baud: must be a baud rate"),
    (["flash", "x.elf", "/dev/ttyX", "--link-baud", "nan"], "--link-baud: must be a baud rate"),
]


@pytest.mark.parametrize("argv, message", BAD_ARGUMENTS, ids=[" ".join(a) for a, _ in BAD_ARGUMENTS])
def test_bad_arguments_are_one_line_errors(tmp_path, argv, message):
    with Unchanged(tmp_path):
        result = imulink(*argv, cwd=tmp_path)
    assert_error(result, message)


def test_exit_statuses_are_documented():
    result = imulink("--help")
    assert result.returncode == 0
    for line in ("0    success", "1    not proven bit-exact", "2    a usage error or a failure",
                 "130  interrupted (Ctrl-C or SIGTERM)"):
        assert line in result.stdout


# ---------------------------------------------------------------------------- bad files


BAD_RECORDINGS = [
    ("/dev/zero", "/dev/zero is not a regular file"),
    ("fifo.imulog", "fifo.imulog is not a regular file"),
    ("dir", "dir is not a regular file"),
    ("nothing.imulog", "cannot read nothing.imulog: No such file or directory"),
    ("empty.imulog", "empty.imulog is not an imulink recording"),
    ("text.imulog", "text.imulog is not an imulink recording"),
    ("magic-only.imulog", "magic-only.imulog has no header record"),
]


@pytest.mark.parametrize("verb", ["compare", "replay"])
@pytest.mark.parametrize("name, message", BAD_RECORDINGS, ids=[n for n, _ in BAD_RECORDINGS])
def test_compare_and_replay_refuse_what_is_not_a_recording(files, verb, name, message):
    if verb == "compare" and name == "dir":
        message = "the directory dir holds no file"  # compare takes a directory's recordings
    with Unchanged(files):
        result = imulink(verb, name, cwd=files)
    assert_error(result, message)


BAD_INJECTION_FILES = [
    ("empty.mat", "empty.mat is not a readable .mat file"),
    ("garbage.mat", "garbage.mat is not a readable .mat file"),
    ("text.mat", "text.mat is not a readable .mat file"),
    ("nokeys.mat", "nokeys.mat is not a BROAD trial"),
    ("shape.mat", "the arrays are imu_gyr (10, 2)"),
    ("one-sample.mat", "the arrays are imu_gyr (1, 3)"),
    ("nan.mat", "gyr: 1 value(s) are NaN or infinite (the first in sample 7)"),
    ("rate-inf.mat", "sampling_rate inf is not a positive number of Hz"),
    ("rate-text.mat", "rate-text.mat is not a BROAD trial"),
    ("fifo.mat", "fifo.mat is not a regular file"),
    ("fifo.imulog", "fifo.imulog is not a regular file"),
    ("/dev/zero", "/dev/zero is not a regular file"),
    ("empty.imulog", "is not an imulink recording"),
]


@pytest.mark.parametrize("name, message", BAD_INJECTION_FILES, ids=[n for n, _ in BAD_INJECTION_FILES])
def test_inject_refuses_bad_input_files(files, name, message):
    with Unchanged(files):
        result = imulink("inject", "loop://", "--input", name, cwd=files)
    assert_error(result, message)


def test_flash_refuses_bad_images(files):
    with Unchanged(files):
        for name, message in (("fifo.imulog", "is not a regular file"), ("dir", "is not a regular file"),
                              ("text.imulog", "is not a firmware image"),
                              ("not-an-image.elf", "not a 32-bit little-endian ELF")):
            assert_error(imulink("flash", name, "--dry-run", cwd=files), message)
        assert_error(imulink("emulate", "--image", "text.imulog", cwd=files), "is not a firmware image")


def test_outputs_never_overwrite_their_input(files):
    recording = files / "good.imulog"
    as_csv = files / "run.csv"  # a recording named *.csv: replay's default output would be itself
    as_csv.write_bytes(recording.read_bytes())
    with Unchanged(files):
        assert_error(imulink("replay", "run.csv", cwd=files), "run.csv is an input of this command")
        assert_error(imulink("replay", "good.imulog", "--csv", "good.imulog", cwd=files), "is an input")
        assert_error(imulink("replay", "good.imulog", "--npz", "./good.imulog", cwd=files), "is an input")
        assert_error(imulink("replay", "good.imulog", "--csv", "dir", cwd=files), "dir exists and is not a regular")
        assert_error(imulink("replay", "good.imulog", "--csv", "/dev/null", cwd=files), "not a regular file")
        assert_error(imulink("record", "loop://", "-o", "good.imulog", cwd=files), "good.imulog exists")
        assert_error(imulink("demo", "-o", "good.imulog", cwd=files), "good.imulog exists")
        assert_error(imulink("record", "/dev/imulink-no-such-port", "-o", "good.imulog", "--force", cwd=files),
                     "no such port")


# ---------------------------------------------------------------------------- damaged recordings


def _damaged(files: Path, name: str, change) -> Path:
    data = bytearray((files / "good.imulog").read_bytes())
    path = files / name
    path.write_bytes(bytes(change(data) or data))
    return path


def _spans(path: Path) -> list[tuple[int, int]]:
    return [(r.offset, 17 + len(r.body)) for r in read_records(path).records]


def _flip(position: int):
    def change(data):
        data[position] ^= 0x10
    return change


def test_a_flipped_bit_anywhere_is_reported_and_never_passes_as_bit_exact(files):
    """A bit flipped in the header, in a length field, in a body, in a CRC, at the end:
    never a traceback or a hang; before the tail, compare reports the damaged span and
    exits 1; in the last record it is a truncated tail; in the header, a clear refusal."""
    records = read_records(files / "good.imulog").records
    spans = _spans(files / "good.imulog")
    total = len(load_recording(files / "good.imulog").estimates)
    settings = next(k for k, r in enumerate(records)
                    if r.kind == KIND_RECEIVED
                    and any(m.name == "SETTING" for m in protocol.FrameDecoder().feed(r.body)))
    stream = [k for k, r in enumerate(records) if r.kind == KIND_RECEIVED and k > settings + 30]
    middle = stream[len(stream) // 2]
    positions = {"header": spans[0][0] + 30, "length": spans[middle][0] + 1, "body": spans[middle + 3][0] + 20,
                 "crc": sum(spans[stream[-3]]) - 2, "last record": spans[-1][0] + 14, "magic": 3,
                 "settings": spans[settings][0] + 20}
    for name, position in positions.items():
        path = _damaged(files, f"{name}.imulog", _flip(position))
        with Unchanged(files):
            result = imulink("compare", path.name, cwd=files)
        assert "Traceback" not in result.stderr
        if name == "header":
            assert_error(result, "has no header record (the record at byte 8 is missing or damaged)")
        elif name == "magic":
            assert_error(result, "is not an imulink recording")
        elif name == "last record":
            assert result.returncode == 0 and "ignored a truncated tail" in result.stdout
        elif name == "settings":  # the snapshot is gone: nothing can be re-run, and the reason is given
            assert_error(result, "settings of eskf were not recorded", "the file is damaged")
        else:
            assert result.returncode == 1 and "bit-exact: yes" not in result.stdout, result.stdout
            assert "DAMAGED FILE: skipped 1 span(s)" in result.stdout
            kept = len(load_recording(path).estimates)
            assert total - kept <= 50  # one record's worth of frames lost, not the rest of the file


def test_a_cut_anywhere_keeps_everything_before_it(files):
    data = (files / "good.imulog").read_bytes()
    spans = _spans(files / "good.imulog")

    def inside_a_record(position: int) -> int:
        """A cut in the middle of the record at `position` (a cut on a record boundary
        leaves a whole file, with no tail to report: the recording differs run to run)."""
        offset, length = next((o, n) for o, n in spans if o <= position < o + n)
        return offset + max(1, length // 2)

    for cut in (len(MAGIC) + 5, *(inside_a_record(p) for p in (len(data) // 3, len(data) // 2 + 7, len(data) - 3))):
        path = files / f"cut{cut}.imulog"
        path.write_bytes(data[:cut])
        with Unchanged(files):
            result = imulink("compare", path.name, cwd=files)
        if cut < 100:
            assert_error(result, "has no header record")
        else:
            assert result.returncode == 0 and "ignored a truncated tail" in result.stdout, result.stdout
            assert "bit-exact: yes" in result.stdout


def test_zero_fill_mid_file_and_at_the_end(files):
    size = len((files / "good.imulog").read_bytes())

    def zero_middle(data):
        data[size // 2:size // 2 + 3000] = bytes(3000)

    middle = _damaged(files, "zero-middle.imulog", zero_middle)
    tail = _damaged(files, "zero-tail.imulog", lambda data: data + bytes(8192))
    with Unchanged(files, allow_new=True):
        result = imulink("compare", middle.name, cwd=files)
        assert result.returncode == 1 and "DAMAGED FILE: skipped 1 span(s)" in result.stdout
        result = imulink("compare", tail.name, cwd=files)
        assert result.returncode == 0 and "ignored a truncated tail of 8192 bytes" in result.stdout
        result = imulink("replay", middle.name, cwd=files)  # replay still exports what is there, exit as compare
        assert result.returncode == 1 and "DAMAGED FILE" in result.stdout
    assert (files / "zero-middle.csv").exists()


def _rewrite_header(files: Path, name: str, header: bytes) -> Path:
    records = read_records(files / "good.imulog").records
    head = struct.pack("<IBd", len(header), KIND_HEADER, 0.0)
    rest = (files / "good.imulog").read_bytes()[records[1].offset:]
    path = files / name
    path.write_bytes(MAGIC + head + header + struct.pack("<I", zlib.crc32(header, zlib.crc32(head))) + rest)
    return path


def test_a_recording_of_another_schema_or_with_a_malformed_header_is_refused(files):
    header = json.loads(read_records(files / "good.imulog").records[0].body)
    cases = {"schema.imulog": (json.dumps({**header, "schema_hash": 0x0BADF00D}).encode(),
                               "schema hash 0x0BADF00D; this imulink decodes"),
             "version.imulog": (json.dumps({**header, "protocol_version": 99}).encode(), "protocol v99"),
             "json.imulog": (b'{"format": ', "header record at byte 8 is not a JSON object"),
             "profile.imulog": (json.dumps({**header, "profile": {"name": 1}}).encode(),
                                "header without a valid sensor profile")}
    for name, (body, message) in cases.items():
        _rewrite_header(files, name, body)
        with Unchanged(files):
            for verb in ("compare", "replay"):
                assert_error(imulink(verb, name, cwd=files), message)
            assert_error(imulink("inject", "loop://", "--input", name, cwd=files), message)


def test_a_recording_of_an_earlier_schema_this_one_only_adds_to_is_read(files):
    """shared/protocol.toml [protocol] earlier_hashes: recordings made before RESEND and
    CHECKPOINT decode the same."""
    header = json.loads(read_records(files / "good.imulog").records[0].body)
    assert protocol.READABLE_SCHEMA_HASHES == {protocol.SCHEMA_HASH, 0xA373C5B8}
    _rewrite_header(files, "earlier.imulog", json.dumps({**header, "schema_hash": 0xA373C5B8}).encode())
    result = imulink("compare", "earlier.imulog", cwd=files)
    assert result.returncode == 0 and "bit-exact: yes" in result.stdout


def test_a_malformed_event_behind_a_valid_crc_is_refused(files):
    head = struct.pack("<IBd", 4, 3, 0.0)  # an EVENT record whose JSON is a number
    path = files / "event.imulog"
    path.write_bytes((files / "good.imulog").read_bytes() + head + b"1234"
                     + struct.pack("<I", zlib.crc32(b"1234", zlib.crc32(head))))
    with Unchanged(files):
        assert_error(imulink("compare", path.name, cwd=files), "event record at byte")


# ---------------------------------------------------------------------------- a full disk


def test_a_full_disk_ends_the_recording_at_once_with_a_readable_file(tmp_path):
    """The file-size limit (`ulimit -f`) as a full disk: one line, exit 2, a readable file,
    no hang (a reader thread that dies must not leave the recorder waiting forever)."""
    path = tmp_path / "full.imulog"
    with EmulatedBoard(front="tcp", duration_s=60.0, rate_hz=1000.0) as board:
        result = imulink("record", board.address, "-o", path, limit_file_kib=256)
    assert_error(result, f"cannot write {path}: File too large; the recording ends there; {path} is readable")
    assert path.stat().st_size <= 256 * 1024
    recording = load_recording(path)
    assert len(recording.samples) > 0 and recording.damaged == []
    assert hil.compare(recording).bit_exact
    with EmulatedBoard(front="tcp", duration_s=1.0) as board:  # full before the board has answered: no file
        result = imulink("record", board.address, "-o", tmp_path / "none.imulog", limit_file_kib=1)
    assert_error(result, "File too large")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full.imulog"]


def test_a_full_disk_leaves_an_existing_export_as_it_was(files):
    (files / "good.csv").write_text("yesterday's export\n")
    with Unchanged(files):
        result = imulink("replay", "good.imulog", limit_file_kib=4, cwd=files)
    assert_error(result, "cannot write good.csv: File too large")


# ---------------------------------------------------------------------------- boards that fail


def _start_record(address: str, path: Path, *extra) -> subprocess.Popen:
    return subprocess.Popen(CLI + ["record", address, "-o", str(path), *extra], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)


def _wait_for(path: Path, samples: int) -> None:
    """Until the recording holds some samples (or the time limit)."""
    deadline = time.monotonic() + TIME_LIMIT_S
    while time.monotonic() < deadline:
        if path.exists() and path.stat().st_size > samples * 200:
            return
        time.sleep(0.1)
    raise AssertionError(f"{path} did not grow")


def _finish(process: subprocess.Popen) -> subprocess.CompletedProcess:
    out, err = process.communicate(timeout=TIME_LIMIT_S)
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def test_a_silent_board_ends_the_recording(tmp_path):
    """A board that stops sending (here: its process stopped) is noticed after the silence
    timeout, not waited for forever."""
    path = tmp_path / "silent.imulog"
    with EmulatedBoard(front="tcp", duration_s=600.0, realtime=True) as board:
        process = _start_record(board.address, path, "--silence-timeout", "1")
        try:
            _wait_for(path, 50)
            os.kill(board._process.pid, signal.SIGSTOP)
            result = _finish(process)
        finally:
            os.kill(board._process.pid, signal.SIGCONT)
            process.kill()
    assert_error(result, "sent nothing for 1 s: the board stopped streaming unannounced or hangs",
                 "frames received before (complete and readable)")
    recording = load_recording(path)
    assert recording.truncated_bytes == 0 and "sent nothing" in recording.events[-1]["reason"]
    assert hil.compare(recording).bit_exact


def test_a_board_that_disconnects(tmp_path):
    path = tmp_path / "gone.imulog"
    board = EmulatedBoard(front="pty", duration_s=600.0, realtime=True).start()
    try:
        process = _start_record(board.address, path, "--reconnect", "2")  # not the default 30 s wait for it
        _wait_for(path, 50)
    finally:
        board.stop()
    result = _finish(process)
    assert_error(result, "disconnected", "complete and readable")
    assert hil.compare(load_recording(path)).bit_exact
    with Unchanged(tmp_path):
        assert_error(imulink("record", board.address, "-o", path), f"{path} exists")
        assert_error(imulink("inject", board.address, "--input", "sim:rests:20"), "cannot open")


@pytest.mark.parametrize("how", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_interrupting_the_recorder_exits_130_with_a_closed_file(tmp_path, how):
    path = tmp_path / "stopped.imulog"
    with EmulatedBoard(front="tcp", duration_s=600.0, realtime=True) as board:
        process = _start_record(board.address, path)
        try:
            _wait_for(path, 50)
            process.send_signal(how)
            result = _finish(process)
        finally:
            process.kill()
    assert result.returncode == 130 and "Traceback" not in result.stderr, result.stderr
    assert f"to {path} (interrupted)" in result.stdout
    recording = load_recording(path)
    assert recording.truncated_bytes == 0 and recording.events[-1]["reason"] == "interrupted"
    assert hil.compare(recording).bit_exact


def test_a_killed_recorder_leaves_a_readable_file_and_the_next_one_names_the_leftovers(tmp_path):
    """The board streams on after its recorder is killed; the next recorder receives what
    it sent meanwhile before its own snapshot, and compare says so."""
    first, second = tmp_path / "killed.imulog", tmp_path / "next.imulog"
    with EmulatedBoard(front="pty", duration_s=600.0, rate_hz=200.0, realtime=True) as board:
        process = _start_record(board.address, first)
        _wait_for(first, 50)
        process.kill()
        process.communicate(timeout=TIME_LIMIT_S)
        time.sleep(0.5)  # the board streams into the port meanwhile
        result = imulink("record", board.address, "-o", second, "--duration", "1")
    assert result.returncode == 0, result.stderr
    assert hil.compare(load_recording(first)).bit_exact
    result = imulink("compare", second)
    assert result.returncode == 0 and "bit-exact: yes" in result.stdout
    assert "left over from a stream the board was already sending when the recording began)" in result.stdout
    assert "lost sample" not in result.stdout


def _wait_for_client(address: str, timeout_s: float = TIME_LIMIT_S) -> None:
    """Until a TCP connection to the board's port is established (Linux: /proc/net/tcp*):
    on a loaded machine the CLI may take seconds to start and connect."""
    port = int(address.rsplit(":", 1)[1])
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for table in ("/proc/net/tcp", "/proc/net/tcp6"):
            with open(table) as f:
                rows = [line.split() for line in f.readlines()[1:]]
            if any(int(row[1].rsplit(":", 1)[1], 16) == port and row[3] == "01" for row in rows):
                return
        time.sleep(0.1)
    raise AssertionError(f"nothing connected to {address} within {timeout_s} s")


def test_inject_into_a_board_that_disconnects(tmp_path):
    board = EmulatedBoard(front="tcp", duration_s=600.0).start()
    process = subprocess.Popen(CLI + ["inject", board.address, "--input", "sim:rests:600:100"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_client(board.address)
    time.sleep(1.0)  # mid-run: the injection has begun
    board.stop()
    result = _finish(process)
    assert_error(result, "disconnected")

