"""Fan-out: one board, several clients on its TCP front (imulink.board.proxy.TcpFront), the
first commanding and the others listening, with the emulated board behind the proxy."""
from __future__ import annotations

import threading
import time

import pytest

from imulink import hil, protocol
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Busy, Link
from imulink.cli import main
from imulink.io.recording import load_recording


@pytest.fixture
def board():
    with EmulatedBoard(front="tcp", duration_s=120.0, rate_hz=200.0, realtime=True, filter_name="eskf") as board:
        yield board


def _start_streaming(link: Link) -> None:
    """What a commanding client does (as `imulink record` begins): snapshot, stream."""
    hil.snapshot(link, None)
    link.command("START_STREAM")


def _samples(link: Link, seconds: float) -> list[protocol.Message]:
    deadline, out = time.monotonic() + seconds, []
    while time.monotonic() < deadline:
        out += [r.message for r in link.receive(timeout=0.1) if r.message.name == "SAMPLE"]
    return out


def test_a_listener_receives_the_stream_and_may_not_command(board):
    with Link(board.address) as commander:
        _start_streaming(commander)
        with Link(board.address) as listener:
            hello = listener.listen()  # the board's last HELLO, passed on by the front
            assert hello == commander.hello
            with pytest.raises(Busy, match="busy: another client is connected to .* and commands the board"):
                listener.connect(timeout=0.5, attempts=1)
            with pytest.raises(protocol.CommandError) as refused:
                listener.command("STOP_STREAM", timeout=0.5, attempts=1)
            assert refused.value.reason == "BUSY"
            samples = _samples(listener, 1.0)
            assert len(samples) > 100  # 200 Hz: the board never saw the STOP_STREAM
            indices = [m.fields["index"] for m in samples]
            assert indices == list(range(indices[0], indices[0] + len(indices)))
            counters = listener.counters()
            # the front's copies of HELLO, STATUS, SETTING and CALIBRATION run into the stream's numbering
            assert counters["lost_frames"] == 0 and counters["crc_errors"] == 0 and counters["resyncs"] == 0
            assert len(_samples(commander, 0.3)) > 20  # the commander's stream goes on meanwhile


def test_when_the_commander_leaves_the_oldest_listener_commands(board):
    commander = Link(board.address)
    commander.connect()
    with Link(board.address) as first, Link(board.address) as second:
        first.listen(), second.listen()
        commander.close()
        time.sleep(0.3)  # the front notices the commander is gone at its next poll
        assert first.connect()["schema_hash"] == protocol.SCHEMA_HASH
        with pytest.raises(Busy):
            second.connect(timeout=0.5, attempts=1)


def _wait_for_sample(link: Link, index: int, timeout_s: float = 30.0) -> None:
    """Until `link` receives the SAMPLE of `index` or a later one (on a loaded machine a
    board may take seconds to stream its first)."""
    deadline = time.monotonic() + timeout_s
    while not any(m.fields["index"] >= index for m in _samples(link, 0.1)):
        assert time.monotonic() < deadline, f"no SAMPLE {index} within {timeout_s} s"


def _wait_until_recording(path, timeout_s: float = 30.0) -> None:
    """Until the recording at `path` holds some frames (about 20 samples' bytes)."""
    deadline = time.monotonic() + timeout_s
    while not (path.exists() and path.stat().st_size > 4000):
        assert time.monotonic() < deadline, f"{path} did not grow within {timeout_s} s"
        time.sleep(0.05)


def test_one_commander_and_two_readers_a_listening_recorder_verifies_after_a_restart(board, tmp_path):
    """A script commands; `record --listen` and a raw listener read. The recording starts
    mid-run (unverifiable), and the filter run the commander starts after it is verified
    bit for bit."""
    path = tmp_path / "listener.imulog"
    with Link(board.address) as commander:
        _start_streaming(commander)
        _wait_for_sample(commander, 50)  # the run is under way before the recorder joins: mid-run for it
        outcome = {}
        recorder = threading.Thread(target=lambda: outcome.update(
            result=hil.record(board.address, path, duration_s=4.0, listen=True)))
        recorder.start()
        with Link(board.address) as reader:
            reader.listen()
            _wait_until_recording(path)  # on a loaded machine the recorder may take seconds to join
            time.sleep(0.5)
            commander.command("SELECT_FILTER", filter_id=protocol.FILTER_IDS["ESKF"])  # a new run from sample 0
            seen = _samples(reader, 1.5)
        recorder.join(timeout=30)
    assert 0 in [m.fields["index"] for m in seen]  # the reader saw the restart too
    result = outcome["result"]
    assert result.filter_name == "eskf" and result.samples > 500
    recording = load_recording(path)
    assert recording.hello == commander.hello and recording.events[0]["listening"] is True
    comparison = hil.compare(recording)
    assert comparison.bit_exact and 300 < comparison.verified_count < comparison.recorded_count


def test_record_on_a_board_another_client_commands_says_busy(board, tmp_path, capsys):
    with Link(board.address) as commander:
        commander.connect()
        assert main(["record", board.address, "-o", str(tmp_path / "x.imulog")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("imulink: error: busy: another client is connected") and err.count("\n") == 1, err
    assert "imulink record --listen" in err and not (tmp_path / "x.imulog").exists()


def test_a_listening_monitor_shows_and_verifies_what_another_client_commands(board):
    """The monitor as a listener beside a commanding script: it shows the stream, verifies
    the filter run the commander starts, and refuses the window's board controls."""
    pytest.importorskip("PyQt6", reason="the monitor extra (PyQt6) is not installed")
    pytest.importorskip("pyqtgraph", reason="the monitor extra (pyqtgraph) is not installed")
    import os

    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from imulink.monitor.qt import QtWidgets
    from imulink.monitor.sources import LiveSource
    from imulink.monitor.window import MonitorWindow

    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication([])

    def wait_until(predicate, what: str, timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            app.processEvents()
            time.sleep(0.01)

    with Link(board.address) as commander:
        _start_streaming(commander)
        window = MonitorWindow(LiveSource(board.address, listen=True), "listener")
        try:
            wait_until(lambda: window.source.health().state == "connected", "the connection")
            assert "(listening)" in window.source.health().detail
            assert not window.filter_box.isEnabled()  # the board controls are off
            commander.command("SELECT_FILTER", filter_id=protocol.FILTER_IDS["ESKF"])  # a run the monitor sees start
            wait_until(lambda: window.source.health().check.identical > 200, "verified estimates")
            assert window.source.health().check.different == 0
            assert [s["name"] for s in window.source.settings()][:2] == ["sample_rate", "gyro_arw"]  # what passed
            window.source.request("stop_stream")
            wait_until(lambda: window.redraw() or "only listens" in window.log.toPlainText(), "the refusal")
            assert len(_samples(commander, 0.5)) > 50  # the board never got the STOP_STREAM
        finally:
            window.close()
