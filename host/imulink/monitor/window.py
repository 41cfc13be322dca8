"""The monitor window (Qt through pyqtgraph): plots, attitude, link health, controls.

The window only reads its source (:mod:`imulink.monitor.sources`) on a QTimer at
FRAME_HZ, whatever the sample rate: the source's worker thread does all the link work,
so nothing here waits for the serial port. Layout, time span and hidden curves are kept
with QSettings between runs.
"""
from __future__ import annotations

import math
import os
import signal
import sys
from pathlib import Path

import numpy as np

from imulink import core, hil, protocol
from imulink.core.counts import describe_profile
from imulink.io.files import FileError, create_beside
from imulink.monitor import board3d
from imulink.monitor.decimate import peaks
from imulink.monitor.horizon import HorizonWidget
from imulink.monitor.qt import QtCore, QtGui, QtWidgets, pg
from imulink.monitor.sources import ESTIMATE_COLUMNS, MAX_SPAN_S, NAV_COLUMNS, SAMPLE_COLUMNS, Health

#: Redraws per second, whatever the sample rate.
FRAME_HZ = 30
SPANS_S = (2.0, 5.0, 10.0, 30.0, MAX_SPAN_S)
HEALTH_EVERY = 8  # frames between health panel updates (about 4 a second)
#: The side column's narrowest (px): it scrolls below its natural width.
SIDE_MIN_WIDTH = 160
#: Bins per curve handed to pyqtgraph (two points each, decimate.peaks): a plot is some 450 pixels wide.
DRAWN_BINS = 300
_COLORS = ("#e41a1c", "#4daf4a", "#377eb8")
#: (title, unit, "samples" | "estimates", [(column, curve name)]): one plot each.
PLOTS = (
    ("gyroscope", "deg/s", "samples", ("gyr_x", "gyr_y", "gyr_z")),
    ("Euler angles", "deg", "estimates", ("roll", "pitch", "heading")),
    ("accelerometer", "m/s²", "samples", ("acc_x", "acc_y", "acc_z")),
    ("gyro bias estimate", "deg/s", "estimates", ("bias_x", "bias_y", "bias_z")),
    ("magnetometer", "µT", "samples", ("mag_x", "mag_y", "mag_z")),
    ("ESKF σ attitude error", "deg", "estimates", ("sigma_att_x", "sigma_att_y", "sigma_att_z")),
    ("fixed vs float twin", "deg", "estimates", ("fixed_float",)),
    ("ESKF σ gyro bias", "deg/s", "estimates", ("sigma_bias_x", "sigma_bias_y", "sigma_bias_z")),
    ("ESKF weights", "1", "estimates", ("gravity_weight", "heading_weight")),
)
_COLUMNS = {"samples": SAMPLE_COLUMNS, "estimates": ESTIMATE_COLUMNS, "nav": NAV_COLUMNS}
#: Points of the track handed to pyqtgraph at most (every k-th row of the time span).
TRACK_POINTS = 2000
#: Angles that wrap at +-180 deg: the curve is broken there instead of drawn across the plot.
_WRAPPING = ("roll", "heading")


def break_wraps(y: np.ndarray) -> np.ndarray:
    """`y` with NaN where it jumps by more than 180 (a wrap), so the curve has a gap there."""
    jumps = np.flatnonzero(np.abs(np.diff(y)) > 180.0)
    if not len(jumps):
        return y
    y = y.copy()
    y[jumps + 1] = np.nan
    return y


class Curve(pg.PlotCurveItem):
    """A curve whose bounds are computed once per frame, when its data are set: Qt asks a
    curve for its bounding rectangle several times per frame, and pyqtgraph would compute
    them again from the data each time (NaN-aware, a third of a frame's cost here)."""

    def show_data(self, x: np.ndarray, y: np.ndarray) -> None:
        finite = np.isfinite(y)
        gaps = not finite.all()
        self._bounds = ((float(x[0]), float(x[-1])) if len(x) else (None, None),
                        (float(y[finite].min()), float(y[finite].max())) if finite.any() else (None, None))
        # "finite" splits the path at NaN (wraps, estimates without a covariance) but costs a pass over the points
        self.setData(x, y, connect="finite" if gaps else "all", skipFiniteCheck=True)

    def dataBounds(self, ax, frac=1.0, orthoRange=None):
        bounds = getattr(self, "_bounds", None)
        return bounds[ax] if bounds is not None else (None, None)


class MonitorWindow(QtWidgets.QMainWindow):
    """The window on one source (a LiveSource or a ReplaySource)."""

    def __init__(self, source, title: str, view_3d: bool = True):
        super().__init__()
        self.source = source
        self.view_3d = view_3d
        self.setWindowTitle(f"imulink monitor: {title}")
        self.store = QtCore.QSettings("imulink", "monitor")
        self.paused = False
        self.frames = 0
        self.frame_times: list[float] = []  # seconds per redraw, newest last (bench_monitor.py reads them)
        self._shown_settings: list = []
        self._build()
        self._restore()
        self.timer = QtCore.QTimer(self)
        self.timer.setTimerType(QtCore.Qt.TimerType.PreciseTimer)
        self.timer.timeout.connect(self.redraw)
        self.timer.start(int(1000 / FRAME_HZ))

    # ------------------------------------------------------------------ building

    def _build(self) -> None:
        pg.setConfigOptions(antialias=False, background="w", foreground="k")
        self.plots_widget = pg.GraphicsLayoutWidget()
        self.plots: list[pg.PlotItem] = []
        self.curves: dict[str, tuple[Curve, str, int]] = {}  # name -> (curve, table, column)
        self.data: dict[str, np.ndarray] = {name: np.empty((0, len(columns)))
                                             for name, columns in _COLUMNS.items()}  # shown, undecimated
        self._drawn: tuple = ()
        self._drawn_at = 0.0  # the time (source.now()) at the right end of the plots
        self.autoscaled = [True] * len(PLOTS)  # per plot: its y range follows the data
        self.cursors: list[pg.InfiniteLine] = []
        for k, (title, unit, table, columns) in enumerate(PLOTS):
            # the curves' names in the title, in their colours: a legend would be redrawn with every frame
            names = " ".join(f"<span style='color:{_COLORS[n]}'>{c}</span>" for n, c in enumerate(columns))
            # one column's width each: linked x axes of other widths would not show the same times
            plot = self.plots_widget.addPlot(row=k // 2, col=k % 2, title=f"{title} &nbsp; {names}")
            plot.disableAutoRange()  # the y ranges follow the drawn data (_autoscale_y): far cheaper per frame
            plot.vb.sigRangeChangedManually.connect(lambda _, k=k: self.autoscaled.__setitem__(k, False))
            plot.setLabel("left", units=None, text=unit)
            plot.showGrid(x=True, y=True, alpha=0.3)
            for side in ("left", "bottom"):  # a grid at the major ticks only: the grid is half the cost of a frame
                axis = plot.getAxis(side)
                axis.setStyle(maxTickLevel=0)
                axis.enableAutoSIPrefix(False)  # else the label is re-rendered whenever the range moves
                # the axis with its grid kept as a pixmap while its ticks stay: a frame that only moves the
                # curves blits it instead of replaying every line and label (a third of a frame's cost)
                axis.setCacheMode(QtWidgets.QGraphicsItem.CacheMode.DeviceCoordinateCache)
            if self.plots:
                plot.setXLink(self.plots[0])
            for n, column in enumerate(columns):
                # a PlotCurveItem rather than plot()'s PlotDataItem: no symbols to manage, a third of the cost
                curve = Curve(name=column, pen=pg.mkPen(_COLORS[n], width=1))
                plot.addItem(curve)
                self.curves[column] = (curve, table, _COLUMNS[table].index(column))
            cursor = pg.InfiniteLine(angle=90, movable=False, pen=pg.mkPen("#888", style=QtCore.Qt.PenStyle.DashLine))
            cursor.setVisible(False)  # until the mouse is over a plot
            plot.addItem(cursor, ignoreBounds=True)
            self.cursors.append(cursor)
            self.plots.append(plot)
        self._navigation(len(PLOTS))
        for plot in self.plots[:-2]:  # time labels on the bottom row only: text is most of an axis's cost
            plot.getAxis("bottom").setStyle(showValues=False)
        self.plots[-1].setLabel("bottom", "time before now (s)")
        self.plots[-2].setLabel("bottom", "time before now (s)")
        self._mouse = pg.SignalProxy(self.plots_widget.scene().sigMouseMoved, rateLimit=30, slot=self._on_mouse)

        side = QtWidgets.QWidget()
        column = QtWidgets.QVBoxLayout(side)
        self.board_view = None  # the 3D board, where OpenGL is
        problem = board3d.opengl_problem() if self.view_3d else "--no-3d"
        if problem is None:
            self.board_view = board3d.make_view()
            column.addWidget(self.board_view, 3)
        self.horizon = HorizonWidget()  # always: it reads at a glance what the 3D view shows
        if self.board_view is not None:
            self.horizon.setMinimumSize(200, 150)  # room for both in the side column
        column.addWidget(self.horizon, 2 if self.board_view else 3)
        self.health_label = QtWidgets.QLabel()
        self.health_label.setTextFormat(QtCore.Qt.TextFormat.RichText)
        self.health_label.setAlignment(QtCore.Qt.AlignmentFlag.AlignTop)
        self.health_label.setWordWrap(True)
        health_box = QtWidgets.QGroupBox("link health")
        QtWidgets.QVBoxLayout(health_box).addWidget(self.health_label)
        column.addWidget(health_box, 2)
        column.addWidget(self._controls(), 3)
        self.log = QtWidgets.QPlainTextEdit(readOnly=True)
        self.log.setMaximumBlockCount(500)
        self.log.setFixedHeight(70)
        column.addWidget(self.log)
        if problem is not None and self.view_3d:
            self._log(f"3D view not shown: {problem}")

        # The side column scrolls rather than taking its natural width (some 380 px of controls):
        # in a narrow window the plots keep three quarters of it; the splitter can also fold the
        # column away (drag it to the edge)
        side_scroll = QtWidgets.QScrollArea()
        side_scroll.setWidget(side)
        side_scroll.setWidgetResizable(True)
        side_scroll.setMinimumWidth(SIDE_MIN_WIDTH)
        self.splitter = QtWidgets.QSplitter()
        self.splitter.addWidget(self.plots_widget)
        self.splitter.addWidget(side_scroll)
        self.splitter.setStretchFactor(0, 3)
        self.splitter.setStretchFactor(1, 1)
        self.splitter.setCollapsible(0, False)
        self.splitter.setCollapsible(1, True)
        self.setCentralWidget(self.splitter)
        self._toolbar()
        self.readout = QtWidgets.QLabel()
        self.statusBar().addWidget(self.readout, 1)

    def _navigation(self, slot: int) -> None:
        """The nav filter's track (east and north from its first position, m) and height over
        the time span, side by side in the plot grid's cell `slot` (the one after the last
        plot); shown while NAV_STATEs with a position arrive."""
        self.nav_box = self.plots_widget.addLayout(row=slot // 2, col=slot % 2)
        self.track_plot = self.nav_box.addPlot(row=0, col=0, title="nav track")
        self.track_plot.setAspectLocked(True)
        self.track_plot.showGrid(x=True, y=True, alpha=0.3)
        self.track_plot.setLabel("bottom", "east (m)")
        self.track_plot.setLabel("left", "north (m)")
        self.track_curve = pg.PlotCurveItem(pen=pg.mkPen(_COLORS[2], width=1))
        self.track_now = pg.ScatterPlotItem(size=8, brush=pg.mkBrush(_COLORS[0]), pen=None)
        self.track_plot.addItem(self.track_curve)
        self.track_plot.addItem(self.track_now)
        self.height_plot = self.nav_box.addPlot(row=0, col=1, title="nav height")
        self.height_plot.showGrid(x=True, y=True, alpha=0.3)
        self.height_plot.setLabel("left", "height (m)")
        self.height_plot.setLabel("bottom", "time before now (s)")
        self.height_curve = Curve(name="height", pen=pg.mkPen(_COLORS[1], width=1))
        self.height_plot.addItem(self.height_curve)
        self.nav_box.setVisible(False)

    def _show_navigation(self, rows: np.ndarray, now: float) -> None:
        """The track and the height of the shown time span (nav rows); hidden without any."""
        self.nav_box.setVisible(len(rows) > 0)
        if not len(rows):
            return
        east, north = NAV_COLUMNS.index("east"), NAV_COLUMNS.index("north")
        track = rows[::max(1, len(rows) // TRACK_POINTS)]
        self.track_curve.setData(track[:, east], track[:, north])
        self.track_now.setData([rows[-1, east]], [rows[-1, north]])
        drawn = peaks(rows, DRAWN_BINS)
        self.height_curve.show_data(drawn[:, 0] - now, drawn[:, NAV_COLUMNS.index("height")])
        self.height_plot.setXRange(-self.span(), 0.0, padding=0)

    def _toolbar(self) -> None:
        bar = self.addToolBar("view")
        bar.setObjectName("view")
        bar.addWidget(QtWidgets.QLabel(" span "))
        self.span_box = QtWidgets.QComboBox()
        for span in SPANS_S:
            self.span_box.addItem(f"{span:g} s", span)
        self.span_box.setCurrentIndex(2)
        bar.addWidget(self.span_box)
        self.pause_action = bar.addAction("pause (space)")
        self.pause_action.setCheckable(True)
        self.pause_action.setShortcut(QtGui.QKeySequence(QtCore.Qt.Key.Key_Space))
        self.pause_action.toggled.connect(self.set_paused)
        bar.addAction("autoscale").triggered.connect(self.autoscale)
        curves_button = QtWidgets.QToolButton(text="curves")
        curves_button.setPopupMode(QtWidgets.QToolButton.ToolButtonPopupMode.InstantPopup)
        menu = QtWidgets.QMenu(curves_button)
        self.curve_actions: dict[str, QtGui.QAction] = {}
        for name, (curve, _, _) in self.curves.items():
            action = menu.addAction(name)
            action.setCheckable(True)
            action.setChecked(True)
            action.toggled.connect(curve.setVisible)
            action.toggled.connect(self._redraw_all)
            self.curve_actions[name] = action
        curves_button.setMenu(menu)
        bar.addWidget(curves_button)
        if not self.source.live:  # a recording: play/pause, speed and the time slider
            bar.addSeparator()
            self.speed_box = QtWidgets.QComboBox()
            for speed in (0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 50.0):
                self.speed_box.addItem(f"{speed:g}x", speed)
            self.speed_box.setCurrentIndex(self.speed_box.findData(self.source.speed)
                                           if self.speed_box.findData(self.source.speed) >= 0 else 2)
            self.speed_box.currentIndexChanged.connect(
                lambda _: setattr(self.source, "speed", self.speed_box.currentData()))
            bar.addWidget(self.speed_box)
            self.slider = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
            self.slider.setRange(0, max(1, int(self.source.duration * 10)))
            self.slider.setMinimumWidth(300)
            self.slider.sliderMoved.connect(lambda value: self.source.seek(value / 10.0))
            bar.addWidget(self.slider)

    def _controls(self) -> QtWidgets.QWidget:
        box = QtWidgets.QGroupBox("board")
        grid = QtWidgets.QGridLayout(box)
        self.filter_box = QtWidgets.QComboBox()
        self.filter_box.addItems(list(core.BOARD_FILTERS))
        self.filter_box.activated.connect(lambda _: self.source.request("select_filter", self.filter_box.currentText()))
        grid.addWidget(QtWidgets.QLabel("filter"), 0, 0)
        grid.addWidget(self.filter_box, 0, 1, 1, 3)
        buttons = (("start", "start_stream"), ("stop", "stop_stream"), ("reset", "reset"))
        for k, (text, action) in enumerate(buttons):
            button = QtWidgets.QPushButton(text)
            button.clicked.connect(lambda _=False, a=action: self.source.request(a))
            grid.addWidget(button, 1, k)
        self.record_button = QtWidgets.QPushButton("record…")
        self.record_button.setCheckable(True)
        self.record_button.clicked.connect(self._on_record)
        grid.addWidget(self.record_button, 1, 3)
        self.settings_table = QtWidgets.QTableWidget(0, 5)
        self.settings_table.setHorizontalHeaderLabels(["setting", "value", "unit", "range", "format"])
        self.settings_table.horizontalHeader().setStretchLastSection(True)
        self.settings_table.verticalHeader().setVisible(False)
        grid.addWidget(self.settings_table, 2, 0, 1, 4)
        apply = QtWidgets.QPushButton("apply settings")
        apply.clicked.connect(self.apply_settings)
        grid.addWidget(apply, 3, 0, 1, 4)
        box.setEnabled(self.source.live and not getattr(self.source, "listen", False))  # a listener may not command
        return box

    # ------------------------------------------------------------------ state kept between runs

    def _restore(self) -> None:
        geometry = self.store.value("geometry")
        if geometry is not None:
            self.restoreGeometry(geometry)
        else:
            self.resize(1400, 860)
        state = self.store.value("splitter")
        if state is not None:
            self.splitter.restoreState(state)
        span = self.store.value("span")
        if span is not None and self.span_box.findData(float(span)) >= 0:
            self.span_box.setCurrentIndex(self.span_box.findData(float(span)))
        hidden = self.store.value("hidden") or []
        for name in [hidden] if isinstance(hidden, str) else hidden:
            if name in self.curve_actions:
                self.curve_actions[name].setChecked(False)

    def save_state(self) -> None:
        self.store.setValue("geometry", self.saveGeometry())
        self.store.setValue("splitter", self.splitter.saveState())
        self.store.setValue("span", self.span_box.currentData())
        self.store.setValue("hidden", [n for n, a in self.curve_actions.items() if not a.isChecked()])
        self.store.sync()

    def closeEvent(self, event) -> None:
        self.timer.stop()
        self.save_state()
        self.source.close()
        super().closeEvent(event)

    # ------------------------------------------------------------------ actions

    def set_paused(self, paused: bool) -> None:
        self.paused = paused
        if not self.source.live:
            self.source.set_playing(not paused)
        if self.pause_action.isChecked() != paused:
            self.pause_action.setChecked(paused)

    def _redraw_all(self) -> None:
        self._drawn = ()  # the next frame gives every visible curve its data again

    def autoscale(self) -> None:
        """Every plot's y range follows its data again (zooming or panning a plot stops that)."""
        self.autoscaled = [True] * len(self.plots)
        self._drawn = ()

    def _autoscale_y(self, drawn: dict[str, np.ndarray]) -> None:
        """Each autoscaled plot's y range: its visible curves' drawn extremes (the peaks of the data)."""
        for k, (plot, (_, _, table, columns)) in enumerate(zip(self.plots, PLOTS)):
            if not self.autoscaled[k]:
                continue
            shown = [drawn[table][:, self.curves[c][2]] for c in columns if self.curves[c][0].isVisible()]
            values = np.concatenate(shown) if shown else np.empty(0)
            values = values[np.isfinite(values)]
            if not len(values):
                continue
            low, high = float(values.min()), float(values.max())
            shown_low, shown_high = plot.vb.viewRange()[1]
            # a new range only when the data leave the shown one or fill less than half of it: a
            # range that moves every frame would make the axis draw its ticks and labels again
            if low < shown_low or high > shown_high or (high - low) < 0.5 * (shown_high - shown_low):
                margin = 0.1 * (high - low) or 0.5 * max(abs(high), 1e-6)
                plot.setYRange(low - margin, high + margin, padding=0)

    def _on_record(self, checked: bool) -> None:
        if not checked:
            self.source.request("stop_recording")
            return
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "record to", "run.imulog", "recordings (*.imulog)")
        if path:
            self.start_recording(path)
        else:
            self.record_button.setChecked(False)

    def start_recording(self, path) -> None:
        """Record the board from now on (the same file as `imulink record`)."""
        self.source.request("start_recording", str(path))

    def apply_settings(self) -> None:
        """Send every edited setting (SET_SETTING with the raw value in the board's Q format)."""
        for row, setting in enumerate(self._shown_settings):
            item = self.settings_table.item(row, 1)
            try:
                value = float(item.text())
            except (AttributeError, ValueError):
                self._log(f"{setting['name']}: {item.text() if item else ''!r} is not a number")
                continue
            if not math.isfinite(value):
                self._log(f"{setting['name']}: {value} is not a finite number")
                continue
            raw = round(value * 2.0**setting["frac_bits"])
            if raw != setting["value"]:
                if not setting["min"] <= raw <= setting["max"]:  # the board's own range (SETTING.min/max)
                    self._log(f"{setting['name']}: {value:g} is outside the board's range "
                              f"{hil.setting_range_text(setting)}")
                    continue
                self.source.request("set_setting", setting["index"], raw)

    # ------------------------------------------------------------------ drawing

    def span(self) -> float:
        return float(self.span_box.currentData())

    def redraw(self) -> None:
        """One frame: curves, attitude, and every HEALTH_EVERY frames the panels."""
        started = QtCore.QElapsedTimer()
        started.start()
        for line in self.source.events():
            self._log(line)
        if not (self.paused and self.source.live):  # a paused replay still follows its slider
            now = self.source.now()
            span = self.span()
            tables = dict(zip(("samples", "estimates", "nav"), self.source.window(span)))
            # a live view moves with its data, a replay with its clock; when neither moved (a stopped
            # stream, a paused replay) there is nothing to draw
            fresh = (span, None if self.source.live else now, *(len(t) and t[-1, 0] for t in tables.values()))
            if fresh != self._drawn:
                self._drawn = fresh
                self.data = tables
                drawn = {name: peaks(rows, DRAWN_BINS) for name, rows in tables.items()}
                self._drawn_at = now
                for name, (curve, table, column) in self.curves.items():
                    if curve.isVisible():
                        y = drawn[table][:, column]
                        curve.show_data(drawn[table][:, 0] - now, break_wraps(y) if name in _WRAPPING else y)
                if self.plots[0].vb.viewRange()[0] != [-span, 0.0]:  # seconds before now: the time axes stand still
                    self.plots[0].setXRange(-span, 0.0, padding=0)
                self._autoscale_y(drawn)
                self._show_navigation(tables["nav"], now)
                attitude = self.source.attitude()
                self.horizon.set_attitude(*attitude)
                if self.board_view is not None:
                    self.board_view.set_attitude(*attitude)
            if not self.source.live and not self.slider.isSliderDown():
                self.slider.setValue(int(now * 10))
        if self.frames % HEALTH_EVERY == 0:
            self.show_health(self.source.health())
            self._show_settings(self.source.settings())
        self.frames += 1
        self.frame_times.append(started.nsecsElapsed() / 1e9)
        del self.frame_times[:-1000]

    def show_health(self, h: Health) -> None:
        colors = {"connected": "#2a7", "replay": "#27a", "connecting": "#c80", "disconnected": "#c22"}
        rows = [f"<b style='color:{colors.get(h.state, '#000')}'>{h.state.upper()}</b> {_escape(h.detail)}"]
        c = h.counters
        if c:
            rows.append(f"{c.get('frame_rate', 0.0):.0f} frames/s, {c.get('byte_rate', 0.0) / 1e3:.1f} kB/s; "
                        f"{c['frames']} frames, {c['bytes'] / 1e3:.0f} kB")
            rows.append(f"CRC errors {c['crc_errors']}, resyncs {c['resyncs']}, lost frames {c['lost_frames']}"
                        + (f", reconnects {h.reconnects}" if h.reconnects else ""))
        if h.hello:
            rows.append(f"{_escape(h.hello['board'])} firmware {h.hello['firmware_major']}.{h.hello['firmware_minor']}."
                        f"{h.hello['firmware_patch']}, protocol v{h.hello['protocol_version']} schema "
                        f"0x{h.hello['schema_hash']:08X}"
                        + (" (this host's)" if h.hello["schema_hash"] == protocol.SCHEMA_HASH
                           else " (NOT this host's)"))
            try:
                rows.append("sensors " + _escape(describe_profile(hil.board_profile(h.hello))))
            except hil.HilError as exc:  # a board that states no usable sensitivities
                rows.append(_escape(str(exc)))
        s = h.status
        if s:
            name = core.filter_name_of(s["active_filter"])
            cost = (f", filter {s['filter_cycles'] / s['cycle_hz'] * 1e6:.1f} µs/sample" if s["cycle_hz"] else "")
            rows.append(f"filter {name} at {s['sample_rate_mhz'] / 1000:g} Hz, "
                        f"CPU load {s['cpu_load_permille'] / 10:.1f} %"
                        f"{cost}; dropped samples {s['dropped_samples']}, saturations {s['filter_saturations']}")
            if self.source.live and self.filter_box.currentText() != name and not self.filter_box.view().isVisible():
                self.filter_box.setCurrentText(name)
        k = h.check
        colour = "#c22" if k.different else ("#2a7" if k.identical else "#888")
        rows.append(f"bit-exact: <b style='color:{colour}'>{k.verdict}</b> ({k.identical} identical, "
                    f"{k.different} different, {k.unverifiable} unverifiable"
                    + (f", {k.recovered} samples recovered" if k.recovered else "")
                    + (f", resumed from {k.resumed} checkpoint(s)" if k.resumed else "")
                    + f"); fixed vs float max {k.fixed_float_max_deg:.5f}°")
        if k.first_difference:
            rows.append(f"first difference: {_escape(k.first_difference)}")
        if h.recording:
            rows.append(f"<b style='color:#c22'>● recording</b> {_escape(h.recording)}")
        if self.source.live and self.record_button.isChecked() != bool(h.recording) and h.state == "connected":
            self.record_button.setChecked(bool(h.recording))
        self.health_label.setText("<br>".join(rows))

    def _show_settings(self, settings: list[dict]) -> None:
        key = [(s["index"], s["filter_id"], s["value"]) for s in settings]
        if key == [(s["index"], s["filter_id"], s["value"]) for s in self._shown_settings]:
            return
        if self.settings_table.state() == QtWidgets.QAbstractItemView.State.EditingState:
            return  # not under the user's fingers
        self._shown_settings = settings
        table = self.settings_table
        table.setRowCount(len(settings))
        for row, s in enumerate(settings):
            fixed = QtCore.Qt.ItemFlag.ItemIsEnabled | QtCore.Qt.ItemFlag.ItemIsSelectable
            for col, text in enumerate((s["name"], f"{s['value'] / 2.0**s['frac_bits']:.6g}", s["unit"],
                                        hil.setting_range_text(s), f"Q{s['frac_bits']}")):
                item = QtWidgets.QTableWidgetItem(text)
                if col != 1:
                    item.setFlags(fixed)
                table.setItem(row, col, item)
        table.resizeColumnsToContents()

    def _on_mouse(self, event) -> None:
        position = event[0]
        for plot, cursor in zip(self.plots, self.cursors):
            if plot.sceneBoundingRect().contains(position):
                before = plot.vb.mapSceneToView(position).x()
                for other in self.cursors:
                    other.setPos(before)
                    other.setVisible(True)
                self.readout.setText(self.readout_at(plot, self._drawn_at + before))
                return

    def readout_at(self, plot: pg.PlotItem, t: float) -> str:
        """The crosshair readout: each visible curve of `plot` at time `t` (its nearest point)."""
        title, unit, _, columns = PLOTS[self.plots.index(plot)]
        parts = [f"t = {t:.3f} s"]
        for name in columns:
            curve = self.curves[name][0]
            rows, column = self.data[self.curves[name][1]], self.curves[name][2]
            x, y = rows[:, 0], rows[:, column]  # the data itself, not what is drawn of it
            if curve.isVisible() and len(x):
                k = int(np.clip(np.searchsorted(x, t), 0, len(x) - 1))
                parts.append(f"{name} = {y[k]:.5g}")
        return f"{title} ({unit}): " + ", ".join(parts)

    def _log(self, line: str) -> None:
        self.log.appendPlainText(line)

    # ------------------------------------------------------------------ screenshots

    def screenshot(self, path) -> None:
        """Write the window as a PNG (under a temporary name, then renamed)."""
        path = Path(path)
        fd, temporary = create_beside(path.with_suffix(".png"))
        os.close(fd)
        try:
            if not self.grab().save(str(temporary), "PNG"):
                raise OSError(f"cannot write {path}: Qt could not save the PNG")
            os.replace(temporary, path)
        finally:
            temporary.unlink(missing_ok=True)


def _escape(text: str) -> str:
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def run(source, title: str, screenshot=None, exit_after: float | None = None, view_3d: bool = True) -> int:
    """Show the window until it is closed (or `exit_after` s, writing `screenshot` first). Exit status."""
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(sys.argv[:1])
    app.setApplicationName("imulink monitor")
    window = MonitorWindow(source, title, view_3d=view_3d)
    window.show()
    status = {"code": 0}

    def interrupt(signum, frame) -> None:  # Ctrl-C, SIGTERM: close as the window's button would
        status["code"] = 130
        window.close()
        app.quit()

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, interrupt)
    ticker = QtCore.QTimer()
    ticker.timeout.connect(lambda: None)  # Python runs signal handlers only between its own bytecodes
    ticker.start(200)

    def finish() -> None:
        try:
            if screenshot is not None:
                window.redraw()
                window.screenshot(screenshot)
        except (OSError, FileError) as exc:
            print(f"imulink: error: {exc}", file=sys.stderr)
            status["code"] = 2
        finally:  # whatever happened, the window closes and the command ends
            window.close()
            app.quit()

    if exit_after is not None:
        QtCore.QTimer.singleShot(int(exit_after * 1000), finish)
    app.exec()
    return status["code"]
