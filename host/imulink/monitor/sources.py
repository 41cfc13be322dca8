"""What the monitor window shows, without Qt: a live board (:class:`LiveSource`) or a
recording (:class:`ReplaySource`), both read through the same small interface.

A live source owns one worker thread that alone talks to the link: it connects, reads
the board's settings and starts the stream, turns received frames into rows of physical
units in ring buffers, runs the live bit-exact check, asks for STATUS once a second,
carries out the commands the window queues (:meth:`LiveSource.request`), and when the
port fails it closes it and tries again every RETRY_S until the board is back. The
window only reads: nothing it does waits for the serial port.

Rows (float64, time in seconds since the source started):

- samples: t, gyroscope x y z (deg/s), accelerometer x y z (m/s^2), magnetometer x y z (uT)
- estimates: t, roll pitch heading (deg), gyro bias x y z (deg/s), standard deviations of
  the ESKF's attitude error x y z (deg) and gyro bias x y z (deg/s) from the covariance
  diagonal the board sends (NaN for filters without one), and the angle between the
  board's quaternion and the float twin's on the same samples (deg; NaN where the host
  cannot reproduce the estimate).
"""
from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imulink import core, hil, protocol
from imulink.analysis.attitude import angle_difference
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import DEFAULT_BAUD, Link, LinkError
from imulink.core.counts import DEFAULT_PROFILE, SensorProfile
from imulink.io.files import FileError, check_writable_target, create_beside, publish
from imulink.io.recording import RecordingError, RecordingWriter, load_recording, sample_times
from imulink.io.recording import sample_rows as recorded_sample_rows
from imulink.monitor.check import CheckSummary, LiveCheck
from imulink.monitor.ring import RingBuffer
from imulink.sim.navigation import local_offsets

SAMPLE_COLUMNS = ("t", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z")
ESTIMATE_COLUMNS = ("t", "roll", "pitch", "heading", "bias_x", "bias_y", "bias_z", "sigma_att_x", "sigma_att_y",
                    "sigma_att_z", "sigma_bias_x", "sigma_bias_y", "sigma_bias_z", "fixed_float", "gravity_weight",
                    "heading_weight")
#: The nav filter's position (NAV_STATE frames that have one): east and north (m) from the
#: first position the source saw, height above the ellipsoid (m), speed (m/s).
NAV_COLUMNS = ("t", "east", "north", "height", "speed")
#: Rows kept per ring buffer: the longest time span (MAX_SPAN_S) at up to 2 kHz.
MAX_SPAN_S = 60.0
RING_ROWS = 1 << 17
#: Seconds between attempts to reopen a port that failed, and between STATUS requests.
RETRY_S = 0.5
STATUS_INTERVAL_S = 1.0
#: The worker takes what arrived every BATCH_S: the per-batch work (both host builds of the
#: filter, numpy) is then paid some 50 times a second instead of once per sample, which at
#: 1 kHz would take most of a core. The window draws at 30 frames/s: nobody sees the delay.
BATCH_S = 0.02
_DEG = 180.0 / math.pi
#: Q format of NAV_STATE's velocity (m/s).
_NAV_VEL_Q = protocol.frac_bits("NAV_STATE", "vel")


def sample_rows(times, gyr, acc, mag, profile: SensorProfile) -> np.ndarray:
    """Rows of SAMPLE_COLUMNS from counts ((N,3) each) in the board's sensor profile."""
    return np.column_stack([times, np.asarray(gyr) * profile.gyro_scale * _DEG, np.asarray(acc) * profile.acc_scale,
                            np.asarray(mag) * profile.mag_scale])


def estimate_rows(times, filter_id, euler, gyro_bias, cov_mantissa, cov_exponent, weights, fixed_float) -> np.ndarray:
    """Rows of ESTIMATE_COLUMNS from the raw ESTIMATE fields ((N,k) integer arrays); the
    weights are NaN where a filter other than the ESKF (which has none) sent them."""
    euler = np.asarray(euler) * (_DEG / 2.0**core.EULER_FRAC_BITS)
    bias = np.asarray(gyro_bias) * (_DEG / 2.0**core.RATE_FRAC_BITS)
    mantissa = np.asarray(cov_mantissa, np.float64)[:, :6]
    variance = mantissa * np.exp2(np.asarray(cov_exponent, np.float64)[:, :6] - core.COV_FRAC_BITS)
    sigma = np.where(mantissa > 0, np.sqrt(np.maximum(variance, 0.0)) * _DEG, np.nan)  # rad -> deg, rad/s -> deg/s
    eskf = (np.asarray(filter_id) == core.FILTERS["eskf"][0])[:, None]
    weights = np.where(eskf, np.asarray(weights, np.float64) * 2.0**-core.WEIGHT_FRAC_BITS, np.nan)
    return np.column_stack([times, euler, bias, sigma, fixed_float, weights])


def nav_rows(times, mode, lat, lon, height_mm, vel, origin: tuple[float, float, float] | None):
    """Rows of NAV_COLUMNS from raw NAV_STATE fields ((N,) and (N,3) integer arrays), those
    with a position (mode 2), east and north from `origin` (lat, lon deg, height m; None:
    the first of these). Returns the rows and the origin."""
    has = np.asarray(mode) == 2
    if not has.any():
        return np.empty((0, len(NAV_COLUMNS))), origin
    lat_deg, lon_deg, height = hil.nav_state_position(
        {"lat": np.asarray(lat), "lon": np.asarray(lon), "height_mm": np.asarray(height_mm)}, has)
    if origin is None:
        origin = (float(lat_deg[0]), float(lon_deg[0]), float(height[0]))
    offsets = local_offsets(lat_deg, lon_deg, height, *origin)
    speed = np.linalg.norm(np.asarray(vel, np.float64).reshape(-1, 3)[has], axis=1) / 2.0**_NAV_VEL_Q
    return np.column_stack([np.asarray(times)[has], offsets[:, 0], offsets[:, 1], height, speed]), origin


@dataclass
class Health:
    """The link health panel's contents."""

    state: str  # "connecting", "connected", "disconnected", "replay"
    detail: str = ""
    counters: dict = field(default_factory=dict)
    hello: dict | None = None
    status: dict | None = None
    check: CheckSummary = field(default_factory=CheckSummary)
    reconnects: int = 0
    recording: str | None = None


class LiveSource:
    """A board on `url` (any pyserial URL), connected and streaming until :meth:`close`.

    The sensor profile is the one the board states in its HELLO; `profile` (None: any) is
    the one expected: a board that states another is refused (shown, and tried again).
    `emulated`: an :class:`imulink.board.emulator.EmulatedBoard` the source owns and stops on close.
    `listen`: show a board another client commands (a fan-out TCP front) without sending
    it anything: its settings and calibration are the frames that pass, the window's board
    controls are refused.
    """

    live = True

    def __init__(self, url: str, baud: int = DEFAULT_BAUD, profile: SensorProfile | None = None, emulated=None,
                 listen: bool = False):
        self.url, self.baud, self.emulated, self.listen = url, baud, emulated, listen
        self.expected_profile = profile
        self.profile = profile or DEFAULT_PROFILE  # until the board states its own
        self.samples = RingBuffer(RING_ROWS, len(SAMPLE_COLUMNS))
        self.estimates = RingBuffer(RING_ROWS, len(ESTIMATE_COLUMNS))
        self.nav = RingBuffer(RING_ROWS, len(NAV_COLUMNS))
        self._nav_origin: tuple[float, float, float] | None = None
        self.check = LiveCheck(self.profile)
        self._health = Health("connecting", f"opening {url}")
        self._lock = threading.Lock()
        self._requests: queue.Queue = queue.Queue()
        self._events: deque[str] = deque(maxlen=200)
        self._settings: list[dict] = []
        self._link: Link | None = None
        self._writer: RecordingWriter | None = None
        self._started = time.time()
        self._attitude = (0.0, 0.0, 0.0)
        self._greeted = self._status_due = 0.0
        self._stopping = threading.Event()
        self._worker = threading.Thread(target=self._run, name=f"imulink-monitor {url}", daemon=True)
        self._worker.start()

    # ------------------------------------------------------------------ what the window reads

    def now(self) -> float:
        """The right end of the time axis."""
        return time.time() - self._started

    def window(self, span_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample, estimate and nav rows of the last `span_s` seconds."""
        low = self.now() - span_s
        return self.samples.since(0, low), self.estimates.since(0, low), self.nav.since(0, low)

    def health(self) -> Health:
        with self._lock:
            health = Health(**vars(self._health))
        link = self._link  # the worker may drop it meanwhile
        if link is not None and health.state == "connected":
            health.counters = link.counters()
        health.check = CheckSummary(**vars(self.check.summary))
        return health

    def attitude(self) -> tuple[float, float, float]:
        """The newest roll, pitch, heading (deg)."""
        return self._attitude

    def settings(self) -> list[dict]:
        """The active filter's settings as the board describes them (SETTING fields)."""
        with self._lock:
            return list(self._settings)

    def events(self) -> list[str]:
        """Messages for the user since the last call (board LOG lines, command results)."""
        out = []
        while self._events:
            out.append(self._events.popleft())
        return out

    def request(self, action: str, *args) -> None:
        """Queue a command for the worker: ("select_filter", name), ("set_setting", index, raw),
        ("start_stream",), ("stop_stream",), ("reset",), ("start_recording", path), ("stop_recording",)."""
        self._requests.put((action, args))

    def close(self) -> None:
        self._stopping.set()
        self._worker.join(timeout=5.0)
        if self.emulated is not None:
            self.emulated.stop()

    # ------------------------------------------------------------------ the worker

    def _set_state(self, state: str, detail: str = "", **changes) -> None:
        with self._lock:
            self._health.state, self._health.detail = state, detail
            for key, value in changes.items():
                setattr(self._health, key, value)

    def _run(self) -> None:
        failures = 0
        while not self._stopping.is_set():
            if self._link is None:
                try:
                    self._open()
                    failures = 0
                except (LinkError, protocol.ProtocolError, hil.HilError) as exc:
                    failures += 1
                    self._set_state("disconnected", f"{exc}; retrying" if failures == 1 else
                                    f"{exc}; retrying ({failures} attempts)")
                    self._close_link()
                    self._stopping.wait(RETRY_S)
                continue
            try:
                self._serve_requests()
                self._ingest(self._link.receive(timeout=0.05))
                self._poll_status()
                self._stopping.wait(BATCH_S)
            except (LinkError, protocol.ProtocolError) as exc:
                self._lost(str(exc))
        self._stop_recording("the monitor was closed")
        self._close_link()

    @property
    def _open_link(self) -> Link:
        """The link to the board: the worker thread opens it (_open) and runs everything that
        uses it until it drops it (_close_link)."""
        link = self._link
        assert link is not None  # only the worker thread uses this, between _open and _close_link
        return link

    def _open(self) -> None:
        link = self._link = Link(self.url, self.baud)
        self._set_state("connecting", f"{self.url}: handshake")
        self._restart_stream()
        hello = link.hello
        assert hello is not None  # _restart_stream greeted the board (connect or listen)
        with self._lock:
            reconnects = self._health.reconnects
        self._set_state("connected", f"{self.url}" + (" (listening)" if self.listen else ""), hello=hello)
        self._events.append(f"connected to {hello['board']} on {self.url}"
                            + (f" (reconnected, {reconnects} time(s) so far)" if reconnects else ""))

    def _restart_stream(self, writer: RecordingWriter | None = None) -> None:
        """Handshake, the board's state, settings and calibration, its filter restarted at
        sample 0 and the stream started: hil.snapshot, as `imulink record` begins (into
        `writer` when recording). The answers also reach the live check through the stream.
        A listener only waits for the board's HELLO (the front passes on its last one)."""
        if self.listen:
            hello = self._open_link.listen()
            self.profile = self.check.profile = hil.check_profile(self.expected_profile, hello)
            self._greeted = time.time()
            return
        hello, filter_id, _, status = hil.snapshot(self._open_link, writer, profile=self.expected_profile)
        self.profile = self.check.profile = hil.board_profile(hello)
        if writer is None:  # with a writer the snapshot read it already, for the file
            hil.read_calibration(self._open_link)
        # the live check learnt the calibration from the CALIBRATION answers: a run from sample 0 with it
        self.check.expect(self._open_link.command("SELECT_FILTER", filter_id=filter_id).ack, ("filter", filter_id, 0))
        try:  # a checkpoint of the filter state a second: the live check resumes there after a lost sample
            self._open_link.command("SET_CHECKPOINT_PERIOD", period=max(1, round(status["sample_rate_mhz"] / 1000)))
        except protocol.CommandError:
            pass  # a board built before checkpoints
        self._open_link.command("START_STREAM")
        if writer is not None:
            writer.event("stream_started", filter=core.filter_name_of(filter_id))
        self._status_due = time.monotonic() + STATUS_INTERVAL_S
        with self._lock:
            self._health.status = status
        self._refresh_settings()
        self._greeted = time.time()  # a start-up HELLO read before this was part of the handshake

    def _refresh_settings(self) -> None:
        _, settings = hil.read_settings(self._open_link)
        with self._lock:
            self._settings = [settings[i] for i in sorted(settings)]

    def _lost(self, reason: str) -> None:
        self._stop_recording(f"the link failed: {reason}")
        self._close_link()
        with self._lock:
            self._health.reconnects += 1
        self._set_state("disconnected", f"{reason}; waiting for the board to come back")
        self._events.append(f"disconnected: {reason}")

    def _close_link(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None

    def _poll_status(self) -> None:
        if not self.listen and time.monotonic() >= self._status_due:
            self._status_due = time.monotonic() + STATUS_INTERVAL_S
            self._open_link.command("GET_STATUS")  # the STATUS itself is taken from the stream

    def _ingest(self, received) -> None:
        if not received:
            return
        messages = [r.message for r in received]
        angles = self.check.feed(messages)
        t0 = self._started
        samples, estimates, states = [], [], []
        for item in received:
            name, fields = item.message.name, item.message.fields
            if name == "SAMPLE":
                samples.append((item.time - t0, fields["gyr"], fields["acc"], fields["mag"]))
            elif name == "ESTIMATE":
                estimates.append((item.time - t0, fields["filter_id"], fields["euler"], fields["gyro_bias"],
                                  fields["cov_mantissa"], fields["cov_exponent"], fields["weights"]))
            elif name == "NAV_STATE":
                states.append((item.time - t0, fields["mode"], fields["lat"], fields["lon"], fields["height_mm"],
                               fields["vel"]))
            elif name == "STATUS":
                with self._lock:
                    self._health.status = fields
            elif name == "SETTING" and self.listen:  # a listener's settings table: what passes
                self._show_followed_settings(fields["filter_id"])
            elif name == "LOG":
                level = {v: k for k, v in protocol.LOG_LEVELS.items()}.get(fields["level"], str(fields["level"]))
                self._events.append(f"board: {level} {fields['text']}")
            elif name == "HELLO" and item.message.seq == 0 and item.time > self._greeted:
                self._events.append("the board started again (HELLO with sequence number 0)")
                if not self.listen:
                    self.request("resume")
        if samples:
            times, gyr, acc, mag = (np.array([s[k] for s in samples]) for k in range(4))
            self.samples.append(sample_rows(times, gyr, acc, mag, self.profile))
        if estimates:
            times, filter_id, euler, gyro_bias, mantissa, exponent, weights = (
                np.array([e[k] for e in estimates]) for k in range(7))
            rows = estimate_rows(times, filter_id, euler, gyro_bias, mantissa, exponent, weights, np.array(angles))
            self.estimates.append(rows)
            self._attitude = tuple(rows[-1, 1:4])
        if states:
            times, mode, lat, lon, height_mm, vel = (np.array([e[k] for e in states]) for k in range(6))
            rows, self._nav_origin = nav_rows(times, mode, lat, lon, height_mm, vel, self._nav_origin)
            if len(rows):
                self.nav.append(rows)

    # ------------------------------------------------------------------ commands from the window

    def _show_followed_settings(self, filter_id: int) -> None:
        """The settings table of a filter as the stream reported them since the board started."""
        reported = self.check.follower.settings_since_reset.get(filter_id, {})
        with self._lock:
            self._settings = [reported[i] for i in sorted(reported)]

    def _serve_requests(self) -> None:
        while True:
            try:
                action, args = self._requests.get_nowait()
            except queue.Empty:
                return
            if self.listen and action != "stop_recording":
                self._events.append(f"{action.replace('_', ' ')}: refused, this monitor only listens (another client "
                                    "commands the board)")
                continue
            try:
                getattr(self, f"_do_{action}")(*args)
            except protocol.CommandError as exc:
                self._events.append(f"{action.replace('_', ' ')}: {exc}")
            except (RecordingError, FileError, core.SettingsError) as exc:
                self._events.append(f"{action.replace('_', ' ')}: {exc}")

    def _do_select_filter(self, name: str) -> None:
        filter_id = core.BOARD_FILTERS[name][0]
        reply = self._open_link.command("SELECT_FILTER", filter_id=filter_id)
        self.check.expect(reply.ack, ("filter", filter_id, 0))
        self._refresh_settings()
        # The new filter's settings were read after its run began: restart it once more so
        # that the live check knows them from sample 0.
        self.check.expect(self._open_link.command("SELECT_FILTER", filter_id=filter_id).ack, ("filter", filter_id, 0))
        self._events.append(f"filter {name} selected")

    def _do_set_setting(self, index: int, value: int) -> None:
        reply = self._open_link.command("SET_SETTING", index=index, value=value)
        self.check.expect(reply.ack, ("setting", index, value))
        self._refresh_settings()
        setting = next((s for s in self.settings() if s["index"] == index), None)
        if setting is not None:
            self._events.append(f"{setting['name']} = {setting['value'] / 2.0**setting['frac_bits']:.6g} "
                                f"{setting['unit']} (raw {setting['value']}); the filter restarted")

    def _do_start_stream(self) -> None:
        self._open_link.command("START_STREAM")
        self._events.append("stream started")

    def _do_stop_stream(self) -> None:
        self._open_link.command("STOP_STREAM")
        self._events.append("stream stopped")

    def _do_reset(self) -> None:
        self._open_link.command("RESET")  # the board's start-up HELLO then resumes the stream
        self._events.append("board reset")

    def _do_resume(self) -> None:
        self._restart_stream(self._writer)

    def _do_start_recording(self, path) -> None:
        if self._writer is not None:
            raise RecordingError(f"already recording to {self._writer.path}")
        path = Path(path)
        check_writable_target(path, replace=False)
        fd, temporary = create_beside(path)
        writer = RecordingWriter(path, self.url, self.profile, fd=fd)
        try:
            self._open_link.tap = writer.received  # every byte from here on, as `imulink record` keeps them
            self._restart_stream(writer)
            writer.check()
            publish(temporary, path, replace=False)
        except BaseException:
            self._open_link.tap = None
            writer.close()
            temporary.unlink(missing_ok=True)
            raise
        self._writer = writer
        with self._lock:
            self._health.recording = str(path)
        self._events.append(f"recording to {path}")

    def _do_stop_recording(self) -> None:
        self._stop_recording("stopped in the monitor")

    def _stop_recording(self, reason: str) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        if self._link is not None:
            self._link.tap = None
            writer.event("stopped", reason=reason, counters=self._link.counters())
        else:
            writer.event("stopped", reason=reason)
        writer.close()
        with self._lock:
            self._health.recording = None
        self._events.append(f"recording {writer.path} ended ({reason})"
                            + (f": {writer.failure}" if writer.failure else ""))


class ReplaySource:
    """A recording played back at `speed` times its own pace, from a position the
    window's time slider sets. The bit-exact check is `imulink compare`'s, done once on
    loading; the health panel shows its verdict up to the playback position."""

    live = False

    def __init__(self, path, speed: float = 1.0):
        self.path = Path(path)
        self.recording = load_recording(self.path)
        if not len(self.recording.samples):
            raise RecordingError(f"{self.path} holds no samples")
        run = hil.host_run(self.recording)
        self.comparison = hil.compare(self.recording, run)
        s, e = self.recording.samples, self.recording.estimates
        self.sample_rows = sample_rows(sample_times(self.recording), s.gyr, s.acc, s.mag, self.recording.profile)
        angle = np.full(len(e), np.nan)
        verified = self.comparison.verified
        angle[verified] = angle_difference(e.quat[verified] / 2.0**core.QUAT_FRAC_BITS,
                                           run.float_quat[self.comparison.sample_row[verified]])
        self.estimate_rows = estimate_rows(self._estimate_times(), e.filter_id, e.euler, e.gyro_bias, e.cov_mantissa,
                                           e.cov_exponent, e.weights, angle)
        states = self.recording.nav_states
        f = states.fields
        self.nav_rows, _ = nav_rows(self._nav_times(), f["mode"], f["lat"], f["lon"], f["height_mm"], f["vel"], None)
        self.duration = float(max(self.sample_rows[-1, 0], self.estimate_rows[-1, 0] if len(e) else 0.0))
        self.speed = speed
        self.playing = True
        self._position = 0.0
        self._clock = time.monotonic()

    def _playback_times(self, host_time: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Frames (their receive times, their samples' rows: -1 lost) at their samples'
        playback times, their receive times where the SAMPLE was lost."""
        times = np.interp(host_time, self.recording.samples.host_time, self.sample_rows[:, 0])
        have = rows >= 0
        times[have] = self.sample_rows[rows[have], 0]
        return times

    def _estimate_times(self) -> np.ndarray:
        """Each estimate at its sample's playback time."""
        return self._playback_times(self.recording.estimates.host_time, self.comparison.sample_row)

    def _nav_times(self) -> np.ndarray:
        """Each NAV_STATE at its sample's playback time."""
        states = self.recording.nav_states
        rows = recorded_sample_rows(self.recording, states.segment, states.index)
        return self._playback_times(states.host_time, rows)

    def now(self) -> float:
        if self.playing:
            now = time.monotonic()
            self._position = min(self.duration, self._position + (now - self._clock) * self.speed)
            self._clock = now
        return self._position

    def seek(self, position: float) -> None:
        self._position = min(max(0.0, position), self.duration)
        self._clock = time.monotonic()

    def set_playing(self, playing: bool) -> None:
        self.now()
        self.playing = playing
        self._clock = time.monotonic()

    def window(self, span_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        now = self.now()
        out = []
        for rows in (self.sample_rows, self.estimate_rows, self.nav_rows):
            low, high = np.searchsorted(rows[:, 0], [now - span_s, now], side="right")
            out.append(rows[low:high])
        return out[0], out[1], out[2]

    def attitude(self) -> tuple[float, float, float]:
        rows = self.window(1.0)[1]
        return tuple(rows[-1, 1:4]) if len(rows) else (0.0, 0.0, 0.0)

    def health(self) -> Health:
        c, rec = self.comparison, self.recording
        shown = self.estimate_rows[:, 0] <= self._position
        summary = CheckSummary(identical=int((c.identical & shown).sum()),
                               different=int((c.verified & ~c.identical & shown).sum()),
                               unverifiable=int((~c.verified & shown).sum()),
                               first_difference=str(c.first_difference) if c.first_difference else None,
                               fixed_float_max_deg=float(np.nanmax(
                                   self.estimate_rows[shown, ESTIMATE_COLUMNS.index("fixed_float")], initial=0.0)),
                               resumed=c.states.resumed, recovered=rec.recovered.get("SAMPLE", 0))
        return Health("replay", f"{self.path.name}: {self._position:.1f} of {self.duration:.1f} s at "
                                f"{self.speed:g}x", counters=rec.counters, hello=rec.hello, status=rec.status,
                      check=summary)

    def settings(self) -> list[dict]:
        filter_id = self.recording.active_filter
        table = self.recording.settings.get(filter_id, {}) if filter_id is not None else {}
        return [table[i] for i in sorted(table)]

    def events(self) -> list[str]:
        return []

    def request(self, action: str, *args) -> None:
        raise RecordingError(f"a recording cannot {action.replace('_', ' ')}")

    def close(self) -> None:
        pass


def open_source(target: str | None, *, emulate: bool = False, baud: int = DEFAULT_BAUD,
                profile: SensorProfile | None = None, speed: float = 1.0, emulation: dict | None = None,
                listen: bool = False):
    """The source `imulink monitor` shows: a recording when `target` is a regular file, an
    emulated board started here when `emulate` (`emulation`: EmulatedBoard's options; with
    `profile`, default gy86-default), else the board on the port `target` (`profile`: the
    one it must state, None: any)."""
    if emulate:

        board = EmulatedBoard(front="tcp", realtime=True, profile=profile or DEFAULT_PROFILE,
                              **(emulation or {})).start()
        assert board.address is not None  # set by start()
        return LiveSource(board.address, profile=profile, emulated=board)
    if target is not None and Path(target).is_file():
        return ReplaySource(target, speed)
    if target is None:
        raise ValueError("open_source needs a target (a board's port or a recording) unless it emulates a board")
    return LiveSource(target, baud, profile, listen=listen)
