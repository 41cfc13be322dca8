"""`imulink monitor` against the emulated board (the firmware as a native process), offscreen.

Shown here: the ring buffers keep exactly the newest rows; the live check agrees with
`imulink compare` on a board's stream and names a changed estimate; the window connects,
its plots fill and its panel says bit-exact; a recording made from the window is
bit-exact for `imulink compare`; a board that goes away and comes back is shown
disconnected, then reconnected; a setting edited in the window reaches the board; a
recording replays with its verdict; the layout survives a restart; --screenshot writes
a PNG. The window tests need the monitor extra (PyQt6, pyqtgraph), which the test extra
installs; they skip only where the binding is absent.
"""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from imulink import hil, protocol
from imulink.board.emulator import EmulatedBoard
from imulink.cli import main
from imulink.io.recording import KIND_RECEIVED, load_recording, read_records
from imulink.monitor import missing_dependencies
from imulink.monitor.check import LiveCheck
from imulink.monitor.decimate import peaks
from imulink.monitor.ring import RingBuffer

# ---------------------------------------------------------------------------- without Qt


def test_ring_buffer_keeps_the_newest_rows_in_order():
    ring = RingBuffer(7, 2)
    everything = np.empty((0, 2))
    rng = np.random.default_rng(1)
    for size in (3, 1, 5, 0, 7, 2, 11, 4):
        rows = np.column_stack([np.arange(len(everything), len(everything) + size), rng.normal(size=size)])
        ring.append(rows)
        everything = np.concatenate([everything, rows])
        np.testing.assert_array_equal(ring.latest(), everything[-7:])
        np.testing.assert_array_equal(ring.latest(2), everything[-2:][-min(2, len(everything)):])
        assert ring.appended == len(everything)
    low = everything[-5, 0] + 0.5  # times are the row numbers: rows from the 4th newest on
    np.testing.assert_array_equal(ring.since(0, low), everything[-4:])
    np.testing.assert_array_equal(ring.since(0, -1.0), everything[-7:])
    assert len(ring.since(0, everything[-1, 0] + 1)) == 0
    ring.clear()
    assert len(ring) == 0 and len(ring.latest()) == 0


def _recorded_messages(path) -> list[protocol.Message]:
    decoder = protocol.FrameDecoder()
    return [m for r in read_records(path).records if r.kind == KIND_RECEIVED for m in decoder.feed(r.body)]


@pytest.fixture(scope="module")
def eskf_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("monitor") / "eskf.imulog"
    with EmulatedBoard(front="tcp", duration_s=5.0, filter_name="eskf") as board:
        hil.record(board.address, path)
    return path


def test_live_check_agrees_with_compare_and_names_a_difference(eskf_recording):
    messages = _recorded_messages(eskf_recording)
    comparison = hil.compare(load_recording(eskf_recording))
    check = LiveCheck(load_recording(eskf_recording).profile)
    angles = np.concatenate([check.feed(messages[k:k + 37]) for k in range(0, len(messages), 37)])  # any batching
    assert check.summary.identical == comparison.verified_count == 500 and check.summary.different == 0
    assert np.nanmax(angles) == pytest.approx(comparison.fixed_vs_float["angle_max_deg"], rel=1e-9)

    position = next(k for k, m in enumerate(messages) if m.name == "ESTIMATE" and m.fields["index"] == 123)
    fields = dict(messages[position].fields)
    fields["euler"] = (fields["euler"][0], fields["euler"][1], fields["euler"][2] + 1)  # one LSB of heading
    messages[position] = protocol.Message("ESTIMATE", messages[position].seq, fields)
    check = LiveCheck(load_recording(eskf_recording).profile)
    check.feed(messages)
    assert check.summary.different == 1 and check.summary.identical == 499 and check.summary.verdict == "NO"
    assert check.summary.first_difference.startswith("sample index 123: euler: board")


def test_live_check_resumes_at_the_next_checkpoint_after_a_lost_sample(eskf_recording):
    """The recorder had the board send a checkpoint of its filter state every second (100
    samples): after a lost SAMPLE the live check resumes there, without the float twin."""
    messages = [m for m in _recorded_messages(eskf_recording)
                if not (m.name == "SAMPLE" and m.fields["index"] in (150, 151))]
    check = LiveCheck(load_recording(eskf_recording).profile)
    angles = np.array(check.feed(messages))
    assert check.resumed == 1
    assert check.summary.identical == 450 and check.summary.unverifiable == 50 and check.summary.different == 0
    assert np.isfinite(angles[:150]).all() and np.isnan(angles[150:]).all()  # no twin after the resumption


def wait_for(predicate, timeout: float = 20.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out after {timeout:g} s waiting for {what}"
        time.sleep(0.02)


def test_filter_select_and_reset_keep_the_live_check_going():
    from imulink.monitor.sources import LiveSource

    with EmulatedBoard(front="tcp", duration_s=60.0, rate_hz=200.0, realtime=True, filter_name="kf1d") as board:
        source = LiveSource(board.address)
        try:
            wait_for(lambda: source.health().check.identical > 100, what="verified KF1D estimates")
            source.request("select_filter", "eskf")
            wait_for(lambda: (source.health().status or {}).get("active_filter") == 3, what="the ESKF")
            before = source.health().check.identical
            wait_for(lambda: source.health().check.identical > before + 100, what="verified ESKF estimates")
            assert not np.isnan(source.estimates.latest(1)[0, 7])  # the ESKF sends a covariance
            source.request("reset")  # the board starts again with its start-up filter, the KF1D
            wait_for(lambda: "the board started again (HELLO with sequence number 0)" in source.events(),
                     what="the board's start-up HELLO")
            wait_for(lambda: (source.health().status or {}).get("active_filter") == 2, what="the KF1D again")
            before = source.health().check.identical
            wait_for(lambda: source.health().check.identical > before + 100, what="verified estimates after it")
            assert source.health().check.different == 0 and source.health().state == "connected"
        finally:
            source.close()


def test_the_live_check_follows_the_boards_calibration():
    """A board corrects its counts with a calibration before the filter: the monitor reads it
    (GET_CALIBRATION) and the host runs with it, so a calibrated board is bit-exact too."""
    from imulink.board.link import Link
    from imulink.core.calibration import Calibration, SensorCalibration
    from imulink.core.counts import DEFAULT_PROFILE
    from imulink.monitor.sources import LiveSource

    calibration = Calibration(DEFAULT_PROFILE, {
        "gyr": SensorCalibration("gyr", np.array([12.5, -7.25, 3.0]), np.eye(3)),
        "mag": SensorCalibration("mag", np.array([40.0, -25.0, 10.0]), np.diag([1.05, 0.97, 1.01]))})
    with EmulatedBoard(front="tcp", duration_s=60.0, rate_hz=200.0, realtime=True, filter_name="eskf") as board:
        with Link(board.address) as link:
            link.connect()
            hil.set_calibration(link, calibration)
        source = LiveSource(board.address)
        try:
            wait_for(lambda: source.health().check.identical > 300, what="verified estimates")
            assert source.health().check.different == 0
            assert source.check.calibration().sensor("mag").offset.tolist() == [40.0, -25.0, 10.0]
        finally:
            source.close()


def test_missing_qt_is_one_line_with_the_install_command(monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "PyQt6" else real(name, *a))
    assert missing_dependencies() == "imulink monitor needs PyQt6: pip install 'imulink[monitor]'"
    assert main(["monitor", "--emulate"]) == 2
    err = capsys.readouterr().err
    assert err == "imulink: error: imulink monitor needs PyQt6: pip install 'imulink[monitor]'\n"


# ---------------------------------------------------------------------------- the window, offscreen


@pytest.fixture(scope="module")
def qt():
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    pytest.importorskip("PyQt6", reason="the monitor extra (PyQt6) is not installed")
    pytest.importorskip("pyqtgraph", reason="the monitor extra (pyqtgraph) is not installed")
    from imulink.monitor.qt import QtWidgets

    return QtWidgets.QApplication.instance() or QtWidgets.QApplication([])


@pytest.fixture(autouse=True)
def own_settings(tmp_path, monkeypatch):
    """QSettings in a directory of the test's own, not the user's nor another test's (Qt reads
    XDG_CONFIG_HOME once a process: under pytest-xdist a worker runs many tests, so the path
    is set through QSettings too)."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    try:
        from imulink.monitor.qt import QtCore
    except Exception:  # noqa: BLE001 - without Qt there are no settings to keep apart
        return
    for fmt in (QtCore.QSettings.Format.NativeFormat, QtCore.QSettings.Format.IniFormat):
        QtCore.QSettings.setPath(fmt, QtCore.QSettings.Scope.UserScope, str(tmp_path / "config"))


def wait_until(app, predicate, timeout: float = 20.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what or predicate}")
        app.processEvents()
        time.sleep(0.01)
    app.processEvents()


def curve(window, name: str) -> tuple[np.ndarray, np.ndarray]:
    """A curve's data in the window's time span (what is drawn of it is decimated to the plot's width)."""
    _, table, column = window.curves[name]
    rows = window.data[table]
    return rows[:, 0], rows[:, column]


def test_peak_decimation_keeps_every_extreme():
    rng = np.random.default_rng(2)
    rows = np.column_stack([np.arange(1003.0), rng.normal(size=1003), rng.normal(size=1003)])
    rows[500:520, 2] = np.nan  # a gap
    out = peaks(rows, 100)
    step = 11  # ceil(1003 / 100)
    assert len(out) == 2 * (1003 // step) + 1003 % step
    np.testing.assert_array_equal(out[0::2][:91, 0], rows[::step][:91, 0])
    np.testing.assert_array_equal(out[0:182:2, 1], rows[:1001, 1].reshape(-1, step).min(axis=1))
    np.testing.assert_array_equal(out[1:182:2, 1], rows[:1001, 1].reshape(-1, step).max(axis=1))
    assert np.nanmax(out[:, 2]) == np.nanmax(rows[:, 2]) and np.isnan(out[:, 2]).sum() == 2  # a whole-NaN run
    np.testing.assert_array_equal(out[-2:], rows[-2:])  # the newest rows, fewer than a run
    assert peaks(rows[:200], 100) is not None and len(peaks(rows[:200], 100)) == 200


def open_window(source):
    from imulink.monitor.window import MonitorWindow

    window = MonitorWindow(source, "test")
    window.show()
    return window


def live_window(address: str):
    from imulink.monitor.sources import LiveSource

    return open_window(LiveSource(address))


def test_window_connects_fills_its_plots_and_says_bit_exact(qt):
    from imulink.monitor.window import DRAWN_BINS

    with EmulatedBoard(front="tcp", duration_s=60.0, rate_hz=1000.0, realtime=True) as board:
        window = live_window(board.address)
        try:
            wait_until(qt, lambda: len(curve(window, "gyr_x")[0]) > 1500, what="1.5 s of samples")
            wait_until(qt, lambda: window.source.health().check.identical > 1500, what="verified estimates")
            health = window.source.health()
            assert health.state == "connected" and health.check.different == 0
            assert health.counters["frame_rate"] > 1500  # SAMPLE + ESTIMATE at 1 kHz
            for name in ("gyr_x", "acc_z", "mag_y", "roll", "heading", "bias_z", "fixed_float"):
                x, y = curve(window, name)
                assert len(x) > 100 and np.isfinite(y).all(), name
                drawn = window.curves[name][0]
                assert 100 < len(drawn.xData) <= 2 * DRAWN_BINS + len(x) // DRAWN_BINS + 1, name  # decimated
                assert drawn.yData.min() == y.min() and drawn.yData.max() == y.max(), name  # every peak kept
            acc_z = curve(window, "acc_z")[1]
            assert 9.0 < np.median(acc_z) < 10.6  # the board lies flat in the simulated rests: +1 g, m/s^2
            assert np.isnan(curve(window, "sigma_att_x")[1]).all()  # the EECF has no covariance
            assert np.isnan(curve(window, "gravity_weight")[1]).all()  # nor measurement weights
            window.redraw()
            window.show_health(window.source.health())
            text = window.health_label.text()
            assert "CONNECTED" in text and "yes so far" in text and f"0x{protocol.SCHEMA_HASH:08X}" in text
            assert "(this host's)" in text and "filter eecf at 1000 Hz" in text
            assert "sensors gy86-default (16.4 LSB per deg/s, 4096 LSB/g, 1090 LSB/gauss)" in text  # its HELLO
        finally:
            window.close()


def test_recording_from_the_window_is_bit_exact(qt, tmp_path, capsys):
    path = tmp_path / "window.imulog"
    with EmulatedBoard(front="tcp", duration_s=60.0, rate_hz=500.0, realtime=True, filter_name="eskf") as board:
        window = live_window(board.address)
        try:
            wait_until(qt, lambda: window.source.health().state == "connected", what="the connection")
            window.start_recording(path)
            wait_until(qt, lambda: window.source.health().recording == str(path), what="the recording")
            time.sleep(1.5)
            window.source.request("stop_recording")
            wait_until(qt, lambda: window.source.health().recording is None, what="the end of the recording")
            window.redraw()
            for name in ("gravity_weight", "heading_weight"):  # the ESKF sends its measurement weights
                weights = curve(window, name)[1]
                assert np.isfinite(weights).all() and (weights >= 0).all() and (weights <= 1).all(), name
                assert (weights > 0).any(), name
        finally:
            window.close()
    assert main(["compare", str(path)]) == 0
    out = capsys.readouterr().out
    assert "bit-exact: yes" in out and "0 different" in out
    recording = load_recording(path)
    assert len(recording.estimates) > 500 and recording.events[-1]["reason"] == "stopped in the monitor"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_board_that_goes_away_and_comes_back_is_shown(qt):
    port = _free_port()
    board = EmulatedBoard(front="tcp", port=port, duration_s=60.0, rate_hz=200.0, realtime=True).start()
    window = live_window(f"socket://127.0.0.1:{port}")
    try:
        wait_until(qt, lambda: window.source.health().state == "connected", what="the connection")
        board.stop()  # the port disappears
        wait_until(qt, lambda: window.source.health().state == "disconnected", what="the disconnect")
        window.show_health(window.source.health())
        assert "DISCONNECTED" in window.health_label.text()
        time.sleep(1.2)  # a few attempts to reopen fail meanwhile
        board = EmulatedBoard(front="tcp", port=port, duration_s=60.0, rate_hz=200.0, realtime=True).start()
        wait_until(qt, lambda: window.source.health().state == "connected", what="the reconnection")
        samples_before = window.source.samples.appended
        wait_until(qt, lambda: window.source.samples.appended > samples_before + 100, what="samples after it")
        health = window.source.health()
        assert health.reconnects == 1 and health.check.different == 0
        window.redraw()
        window.show_health(health)
        assert "CONNECTED" in window.health_label.text() and "reconnects 1" in window.health_label.text()
        log = window.log.toPlainText()
        assert "disconnected:" in log and "(reconnected, 1 time(s) so far)" in log
    finally:
        window.close()
        board.stop()


def test_a_setting_edited_in_the_window_reaches_the_board(qt, tmp_path):
    path = tmp_path / "after.imulog"
    with EmulatedBoard(front="tcp", duration_s=60.0, rate_hz=200.0, realtime=True, filter_name="kf1d") as board:
        window = live_window(board.address)
        try:
            wait_until(qt, lambda: window.settings_table.rowCount() > 1, what="the settings table")
            row = next(r for r in range(window.settings_table.rowCount())
                       if window.settings_table.item(r, 0).text() == "q_angle")
            assert window.settings_table.item(row, 2).text() == window._shown_settings[row]["unit"]
            window.settings_table.item(row, 1).setText("0.0004")
            window.apply_settings()
            frac_bits = window._shown_settings[row]["frac_bits"]
            wanted = round(0.0004 * 2**frac_bits)
            wait_until(qt, lambda: any(s["name"] == "q_angle" and s["value"] == wanted
                                       for s in window.source.settings()), what="the board's new value")
            identical = window.source.health().check.identical
            wait_until(qt, lambda: window.source.health().check.identical > identical + 200, what="estimates after it")
            assert window.source.health().check.different == 0  # the board and the host ran the new value
            assert window.settings_table.item(row, 3).text() == "[0, 0.001]"  # the board's range (SETTING)
            window.settings_table.item(row, 1).setText("0.0015")  # fits Q40, but not the KF1D's range
            window.apply_settings()  # refused before it is sent
            assert "q_angle: 0.0015 is outside the board's range [0, 0.001]" in window.log.toPlainText()
            window.start_recording(path)  # and the board's own SETTING answers, in a file
            wait_until(qt, lambda: window.source.health().recording == str(path), what="the recording")
            window.source.request("stop_recording")
            wait_until(qt, lambda: window.source.health().recording is None, what="the end of the recording")
        finally:
            window.close()
    recording = load_recording(path)
    assert recording.filter_settings(recording.active_filter)[1]["q_angle"] == wanted


def test_a_recording_replays_with_its_verdict_and_a_time_slider(qt, eskf_recording):
    from imulink.monitor.sources import ReplaySource

    source = ReplaySource(eskf_recording, speed=10.0)
    assert source.duration == pytest.approx(5.0 - 0.01, abs=0.02)  # 500 samples at 100 Hz, by the board's clock
    window = open_window(source)
    try:
        wait_until(qt, lambda: source.now() >= source.duration, what="the end of the replay")
        window.redraw()
        health = source.health()
        assert health.state == "replay" and health.check.identical == 500 and health.check.different == 0
        assert window.slider.value() == int(source.duration * 10)
        assert len(curve(window, "sigma_att_x")[0]) == 500  # the ESKF's covariance
        window.set_paused(True)  # space
        window.slider.sliderMoved.emit(20)  # the user drags the slider to 2 s
        assert source.now() == 2.0 and not source.playing
        assert source.health().check.identical == 201  # estimates 0 .. 200 are at or before 2 s
        window.redraw()
        x = curve(window, "roll")[0]
        assert x[-1] == pytest.approx(2.0)
        rows = window.data["estimates"]
        k = int(np.argmin(np.abs(rows[:, 0] - 1.0)))  # the crosshair 1 s before the position: t = 1 s
        readout = window.readout_at(window.plots[1], 1.0)
        assert readout.startswith("Euler angles (deg): t = 1.000 s, ")
        assert f"roll = {rows[k, 1]:.5g}, pitch = {rows[k, 2]:.5g}, heading = {rows[k, 3]:.5g}" in readout
    finally:
        window.close()


def test_layout_is_remembered_between_runs(qt, eskf_recording):
    from imulink.monitor.sources import ReplaySource

    window = open_window(ReplaySource(eskf_recording))
    window.span_box.setCurrentIndex(window.span_box.findData(30.0))
    window.curve_actions["mag_z"].setChecked(False)
    window.close()
    window = open_window(ReplaySource(eskf_recording))
    try:
        assert window.span() == 30.0
        assert not window.curve_actions["mag_z"].isChecked() and not window.curves["mag_z"][0].isVisible()
        assert window.curve_actions["mag_y"].isChecked()
    finally:
        window.close()


def test_a_narrow_window_leaves_the_plots_the_room(qt, eskf_recording):
    """In a window 800 pixels wide the side column scrolls instead of taking its natural
    width (some 380 px: the plots got half the window), and it folds away entirely."""
    from imulink.monitor.sources import ReplaySource

    window = open_window(ReplaySource(eskf_recording))
    try:
        window.resize(800, 600)
        wait_until(qt, lambda: window.splitter.width() <= 800, what="the window narrowed")
        for _ in range(5):
            qt.processEvents()
        assert window.plots_widget.width() >= 0.7 * window.splitter.width()
        window.splitter.setSizes([800, 0])  # the column folded away
        qt.processEvents()
        assert window.splitter.sizes()[1] == 0 and window.plots_widget.width() >= 0.95 * window.splitter.width()
    finally:
        window.close()


def test_screenshot_from_the_command_line(qt, tmp_path, eskf_recording):
    """The command as a user runs it, in a process of its own: its Qt event loop (app.exec)
    is not the test worker's, and a crash in it fails this test instead of the worker."""
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", XDG_CONFIG_HOME=str(tmp_path / "config"))
    cli = [sys.executable, "-m", "imulink.cli"]
    png = tmp_path / "shot.png"
    shot = subprocess.run(cli + ["monitor", str(eskf_recording), "--speed", "5", "--screenshot", str(png),
                                 "--exit-after", "1"], env=env, capture_output=True, text=True, timeout=120)
    assert shot.returncode == 0, shot.stderr
    data = png.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 20_000
    assert [p.name for p in tmp_path.iterdir() if "partial" in p.name] == []
    missing = tmp_path / "no" / "x.png"
    refused = subprocess.run(cli + ["monitor", str(eskf_recording), "--screenshot", str(missing)], env=env,
                             capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2
    assert refused.stderr.endswith(f"imulink: error: cannot write {missing}: its directory does not exist\n")


# ---------------------------------------------------------------------------- the 3D board


def test_board_view_turns_the_board_by_the_estimate(qt):
    """The board's rotation from the Euler angles the window shows is the estimate's own
    (the sensor-to-earth rotation of the quaternion they came from)."""
    from imulink.analysis.attitude import quat_to_euler
    from imulink.monitor import board3d
    from imulink.sim import quat

    rng = np.random.default_rng(4)
    for q in rng.standard_normal((50, 4)):
        q /= np.linalg.norm(q)
        euler = np.degrees(quat_to_euler(q))
        np.testing.assert_allclose(board3d.rotation_matrix(*euler), quat.to_rotmat(q), atol=1e-12)


def test_offscreen_window_shows_the_horizon_and_says_why_there_is_no_3d_view(qt, eskf_recording):
    from imulink.monitor.sources import ReplaySource

    window = open_window(ReplaySource(eskf_recording))
    try:
        assert window.board_view is None and window.horizon.isVisible()
        assert "3D view not shown: Qt's offscreen platform has no OpenGL" in window.log.toPlainText()
    finally:
        window.close()


_XVFB_VIEW = """
import json, sys
import numpy as np
from imulink.monitor.qt import QtGui, QtWidgets
app = QtWidgets.QApplication([])
from imulink.monitor import board3d
problem = board3d.opengl_problem()
if problem:
    print(json.dumps({"problem": problem}))
    sys.exit(0)
view = board3d.make_view()
view.resize(320, 280)
view.show()
shots, transforms = [], []
for attitude in ((0, 0, 0), (0, 0, 90), (60, 0, 0)):
    view.set_attitude(*attitude)
    for _ in range(5):
        app.processEvents()
    image = view.grabFramebuffer().convertToFormat(QtGui.QImage.Format.Format_RGB888)
    bits = image.constBits()
    bits.setsize(image.sizeInBytes())
    rows = np.frombuffer(bits, np.uint8).reshape(image.height(), image.bytesPerLine())
    shots.append(rows[:, :3 * image.width()].reshape(image.height(), image.width(), 3).astype(int).tolist())
    transforms.append(np.array(view.board.transform().data()).reshape(4, 4).T.tolist())  # data() is by columns
print(json.dumps({"problem": None, "shots": shots, "transforms": transforms}))
"""


def test_board_view_draws_the_board_in_a_real_window(tmp_path):
    """In Xvfb (software OpenGL): the view draws the board, with its top face's green, and
    the board's transform is the attitude's rotation; a turn changes the picture."""
    import json
    import shutil
    import subprocess
    import sys

    pytest.importorskip("OpenGL", reason="the monitor extra (PyOpenGL) is not installed")
    from imulink.monitor import board3d

    xvfb = shutil.which("Xvfb")
    assert xvfb, "Xvfb is missing: tools/install-system-packages.sh installs it"
    read_end, write_end = os.pipe()
    server = subprocess.Popen([xvfb, "-displayfd", str(write_end), "-screen", "0", "800x600x24", "-nolisten", "tcp"],
                              pass_fds=(write_end,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_end)
    try:
        with os.fdopen(read_end) as ready:
            display = ready.readline().strip()
        env = dict(os.environ, DISPLAY=f":{display}", QT_QPA_PLATFORM="xcb", XDG_CONFIG_HOME=str(tmp_path))
        result = subprocess.run([sys.executable, "-c", _XVFB_VIEW], env=env, capture_output=True, text=True,
                                timeout=120)
    finally:
        server.terminate()
        server.wait()
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout.splitlines()[-1])
    assert out["problem"] is None, out["problem"]
    shots = [np.array(shot) for shot in out["shots"]]
    top = np.array([0.15, 0.55, 0.25]) * 255  # the top face's colour (flat, unlit)
    green = [int(np.sum(np.all(np.abs(shot - top) < 12, axis=2))) for shot in shots]
    assert green[0] > 2000, green  # the flat board shows its top to the camera above
    for k, attitude in enumerate(((0, 0, 0), (0, 0, 90), (60, 0, 0))):
        np.testing.assert_allclose(np.array(out["transforms"][k])[:3, :3], board3d.rotation_matrix(*attitude),
                                   atol=1e-6)
    for a in range(3):
        for b in range(a + 1, 3):
            assert np.sum(np.any(shots[a] != shots[b], axis=2)) > 500  # each turn moves the board on screen


def test_the_nav_filter_shows_its_track_and_height_and_is_checked_live(qt):
    """A board running the nav filter on a car drive with GNSS: the navigation panel shows
    the track from the first position and the height, and the live check verifies the
    estimates with the barometer readings and fixes the board took."""
    with EmulatedBoard(front="tcp", scenario="car", filter_name="nav", duration_s=60.0, realtime=True) as board:
        window = live_window(board.address)
        try:
            wait_until(qt, lambda: window.source.health().check.identical > 600, what="6 s of verified estimates")
            window.redraw()
            health = window.source.health()
            window.show_health(health)
            assert health.check.different == 0 and "filter nav at 100 Hz" in window.health_label.text()
            rows = window.data["nav"]
            assert window.nav_box.isVisible() and len(rows) > 500
            truth = board.trajectory
            # the track starts at the first fix (the drive's start, within the receiver's error)
            assert np.hypot(*rows[0, 1:3]) < 1e-6 and abs(rows[0, 3] - truth.height_m[0]) < 15.0
            x, y = window.track_curve.getData()
            assert len(x) == len(rows) and np.array_equal(y, rows[:, 2])
            assert np.isfinite(window.height_curve.yData).all()
        finally:
            window.close()


def test_a_nav_recording_replays_its_track(qt, tmp_path):
    from imulink.monitor.sources import NAV_COLUMNS, ReplaySource

    path = tmp_path / "nav.imulog"
    with EmulatedBoard(front="tcp", scenario="car", filter_name="nav", duration_s=20.0) as board:
        hil.record(board.address, path)
    source = ReplaySource(path, speed=100.0)
    window = open_window(source)
    try:
        wait_until(qt, lambda: source.now() >= source.duration, what="the end of the replay")
        window.redraw()
        assert source.health().check.identical == 2000 and source.health().check.different == 0
        rows = window.data["nav"]  # the window's time span of them
        assert len(rows) == min(2000, round(window.span() * 100.0) + 1) and window.nav_box.isVisible()
        assert rows[-1, 0] == pytest.approx(source.duration)
        speed = rows[:, NAV_COLUMNS.index("speed")]
        assert speed.max() > 1.0  # the car drives off
    finally:
        window.close()
