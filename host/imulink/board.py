"""A virtual board: the fixed-point C core and the sensor simulator behind the frame protocol.

The board computes exactly what the firmware computes (the same C, fixed-point build,
through :class:`imulink.core.Filter`, one sample at a time) and answers every command
of shared/protocol.toml. It runs in its own thread over a transport:

- :class:`PtyTransport`: a pseudo-terminal; the host opens ``transport.address``
  (``/dev/pts/N``) like a serial port.
- :class:`TcpTransport`: a TCP server on 127.0.0.1; the host opens
  ``socket://127.0.0.1:PORT``. One client at a time; the board keeps running when a
  client leaves and greets the next one with HELLO.
- :class:`SerialTransport`: any pyserial URL or device (a real UART through a
  null-modem cable, for example), polled.

Live mode streams SAMPLE + ESTIMATE for every simulated sample and STATUS once per
simulated second, in real time or as fast as the link drains (back-pressure). When the
simulated run is exhausted the board stops streaming, says so in a LOG line and sends
STATUS with ``streaming = 0``. In injection mode the filter runs on INJECT_SAMPLE data.

:class:`FaultConfig` damages the board-to-host byte stream (dropped bytes, flipped bits,
garbage bursts, stalls), deterministically for a seed, to test the host.

The board keeps the simulation (``board.simulation``): :meth:`VirtualBoard.truth`
gives the true attitude of any SAMPLE by its ``timestamp_us``.
"""
from __future__ import annotations

import math
import os
import select
import socket
import threading
import time
import tty
from dataclasses import dataclass

import numpy as np
import serial

from . import __version__, core, protocol, sim
from .counts import DEFAULT_PROFILE, SensorProfile, si_to_counts

#: HELLO.board of the virtual board.
BOARD_NAME = "emulator"
#: MPU6050 temperature register at 25 degC ((25 - 36.53) * 340).
TEMPERATURE_25C = -3920
#: Output bytes a real-time board buffers for a slow or absent host before dropping samples.
REALTIME_BACKLOG_BYTES = 1 << 16
#: Output bytes a fast board produces ahead of the link before waiting for it to drain.
FAST_BACKLOG_BYTES = 1 << 14

_FILTER_NAMES = {filter_id: name for name, (filter_id, _) in core.FILTERS.items()}
_LOG = protocol.LOG_LEVELS
#: Commands after which the active filter starts again from sample index 0.
RESTARTING_COMMANDS = frozenset({"SELECT_FILTER", "SET_SETTING", "SET_INJECTION_MODE", "RESET"})


# ---------------------------------------------------------------------------- the firmware's filter


class FirmwareFilter:
    """One filter of the fixed-point core, configured by raw settings (the integers of
    SET_SETTING) and stepped one sample at a time, as the firmware runs it.

    Raises core.SettingsError when the core refuses the settings.
    """

    def __init__(self, filter_name: str, raw_settings: dict[str, int], profile: SensorProfile = DEFAULT_PROFILE):
        self.filter_name = filter_name
        self.filter_id = core.FILTERS[filter_name][0]
        self.fields = core.settings_fields(filter_name)
        self.raw_settings = dict(raw_settings)
        values = {f.name: raw_settings[f.name] / 2.0**f.frac_bits for f in self.fields}
        self.si_settings = values
        self.core = core.Filter(filter_name, values["sample_rate"], "fixed", values, profile)
        self.saturations = 0
        self._has_covariance = filter_name == "eskf"

    @staticmethod
    def default_raw_settings(filter_name: str, rate_hz: float) -> dict[str, int]:
        """The core's default settings (with `rate_hz`) as raw fixed-point integers."""
        values = core.resolve_settings(filter_name, rate_hz, None)
        return {f.name: core.to_fixed(values[f.name], f.frac_bits, f.name) for f in core.settings_fields(filter_name)}

    def step(self, index: int, gyr, acc, mag) -> dict:
        """Run one sample (three int16 triples) and return the ESTIMATE fields for it."""
        result = self.core.run_counts(np.array([gyr], np.int16), np.array([acc], np.int16),
                                      np.array([mag], np.int16))
        self.saturations = result.saturations
        if self._has_covariance:
            mantissas, exponents = self.core.covariance_diagonal_raw()
        else:
            mantissas, exponents = [0] * 9, [0] * 9
        raw = result.raw
        return {"index": index, "filter_id": self.filter_id, "quat": raw["quat"][0].tolist(),
                "gyro_bias": raw["gyro_bias"][0].tolist(), "euler": raw["euler"][0].tolist(),
                "cov_mantissa": mantissas, "cov_exponent": exponents, "saturations": result.saturations}


# ---------------------------------------------------------------------------- faults


@dataclass(frozen=True)
class FaultConfig:
    """Damage applied to the board-to-host byte stream, frame by frame.

    drop_byte / flip_bit: probability that each byte is dropped / has one random bit
    flipped. garbage: probability that a burst of 1..garbage_max random bytes precedes a
    frame. stall: probability that the board goes silent for stall_s seconds before a
    frame (it also stops answering commands meanwhile). seed makes it reproducible.
    """

    drop_byte: float = 0.0
    flip_bit: float = 0.0
    garbage: float = 0.0
    garbage_max: int = 32
    stall: float = 0.0
    stall_s: float = 0.05
    seed: int = 0

    def __post_init__(self):
        for name in ("drop_byte", "flip_bit", "garbage", "stall"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"fault probability {name}={getattr(self, name)!r} is not in [0, 1]")
        if self.garbage_max < 1 or self.stall_s < 0:
            raise ValueError("garbage_max must be >= 1 and stall_s >= 0")

    @property
    def active(self) -> bool:
        return any((self.drop_byte, self.flip_bit, self.garbage, self.stall))


class FaultInjector:
    """Applies a FaultConfig and counts what it did (dropped_bytes, flipped_bits,
    garbage_bursts, garbage_bytes, stalls, damaged_frames)."""

    def __init__(self, config: FaultConfig):
        self.config = config
        self._rng = np.random.default_rng(config.seed)
        self.counts = dict.fromkeys(
            ("dropped_bytes", "flipped_bits", "garbage_bursts", "garbage_bytes", "stalls", "damaged_frames"), 0)

    def damage(self, wire: bytes) -> bytes:
        """The bytes actually sent for one frame."""
        cfg, rng = self.config, self._rng
        data = np.frombuffer(wire, np.uint8).copy()
        damaged = False
        if cfg.flip_bit:
            flips = rng.random(data.size) < cfg.flip_bit
            if flips.any():
                data[flips] ^= (1 << rng.integers(0, 8, int(flips.sum()))).astype(np.uint8)
                self.counts["flipped_bits"] += int(flips.sum())
                damaged = True
        if cfg.drop_byte:
            keep = rng.random(data.size) >= cfg.drop_byte
            if not keep.all():
                self.counts["dropped_bytes"] += int(data.size - keep.sum())
                data = data[keep]
                damaged = True
        out = data.tobytes()
        if cfg.garbage and rng.random() < cfg.garbage:
            burst = rng.integers(0, 256, int(rng.integers(1, cfg.garbage_max + 1)), dtype=np.uint8).tobytes()
            self.counts["garbage_bursts"] += 1
            self.counts["garbage_bytes"] += len(burst)
            out = burst + out
        self.counts["damaged_frames"] += damaged
        return out

    def stall(self) -> float:
        """Seconds to stay silent before the next frame (0 almost always)."""
        if self.config.stall and self._rng.random() < self.config.stall:
            self.counts["stalls"] += 1
            return self.config.stall_s
        return 0.0


# ---------------------------------------------------------------------------- transports


class PtyTransport:
    """A pseudo-terminal pair: the board owns the master, the host opens `address`."""

    def __init__(self):
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing, no CR/LF translation
        os.set_blocking(self._master, False)
        self.address = os.ttyname(self._slave)
        self.connections = 1

    def wait(self, want_write: bool, timeout: float) -> None:
        select.select([self._master], [self._master] if want_write else [], [], timeout)

    def read(self) -> bytes:
        try:
            return os.read(self._master, 65536)
        except (BlockingIOError, OSError):
            return b""

    def write(self, data: bytes) -> int:
        try:
            return os.write(self._master, data)
        except (BlockingIOError, OSError):
            return 0

    def close(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


class TcpTransport:
    """A TCP server on `host`:`port` (0: a free port); `address` is the pyserial URL.

    One client at a time; ``connections`` counts the clients accepted so far.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self._server = socket.create_server((host, port))
        self._server.setblocking(False)
        self.address = f"socket://{host}:{self._server.getsockname()[1]}"
        self._client: socket.socket | None = None
        self.connections = 0

    def wait(self, want_write: bool, timeout: float) -> None:
        if self._client is None:
            ready, _, _ = select.select([self._server], [], [], timeout)
            if ready:
                self._accept()
            return
        select.select([self._client], [self._client] if want_write else [], [], timeout)

    def _accept(self) -> None:
        try:
            client, _ = self._server.accept()
        except BlockingIOError:
            return
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = client
        self.connections += 1

    def _drop_client(self) -> None:
        self._client.close()
        self._client = None

    def read(self) -> bytes:
        if self._client is None:
            return b""
        try:
            data = self._client.recv(65536)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            self._drop_client()
        return data

    def write(self, data: bytes) -> int:
        if self._client is None:
            return 0
        try:
            return self._client.send(data)
        except BlockingIOError:
            return 0
        except OSError:
            self._drop_client()
            return 0

    def close(self) -> None:
        if self._client is not None:
            self._drop_client()
        self._server.close()


class SerialTransport:
    """Any pyserial URL or device (a real UART to a host through a null-modem cable, for
    example), polled every `poll_s` seconds. Raises serial.SerialException when the port
    cannot be opened."""

    def __init__(self, url: str, baud: int = 921600, poll_s: float = 0.002):
        self._port = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0)
        self._poll_s = poll_s
        self.address = url
        self.connections = 1

    def wait(self, want_write: bool, timeout: float) -> None:
        if not self._port.in_waiting:
            time.sleep(min(timeout, self._poll_s))

    def read(self) -> bytes:
        return self._port.read(self._port.in_waiting or 1)

    def write(self, data: bytes) -> int:
        try:
            return self._port.write(data) or 0
        except serial.SerialTimeoutException:
            return 0

    def close(self) -> None:
        self._port.close()


# ---------------------------------------------------------------------------- the board


class VirtualBoard:
    """The emulated board. ``start()`` runs it in a thread, ``stop()`` ends it (also a
    context manager).

    Args:
        transport: PtyTransport, TcpTransport or SerialTransport.
        scenario, duration_s, rate_hz, seed: the simulated run the sensors deliver
            (:func:`imulink.sim.make_scenario`).
        filter_name: filter active after start-up and RESET.
        realtime: pace samples at rate_hz; otherwise as fast as the link drains.
        profile: sensor full-scale profile of the simulated GY-86 (its counts and the
            core's sensor scales).
        faults: damage to apply to the outgoing bytes.
        schema_hash: the hash HELLO reports (None: this host's; another value emulates a
            board built from another protocol definition).
    """

    def __init__(self, transport, *, scenario: str = "rests", duration_s: float = 600.0, rate_hz: float = 100.0,
                 seed: int = 0, filter_name: str = "eecf", realtime: bool = False,
                 profile: SensorProfile = DEFAULT_PROFILE, faults: FaultConfig | None = None,
                 schema_hash: int | None = None):
        if filter_name not in core.FILTERS:
            raise ValueError(f"unknown filter {filter_name!r}; choose one of {', '.join(core.FILTERS)}")
        self.transport = transport
        self.rate_hz = float(rate_hz)
        self.realtime = realtime
        self.profile = profile
        self.schema_hash = protocol.SCHEMA_HASH if schema_hash is None else schema_hash
        self.initial_filter = filter_name
        self.simulation = sim.make_scenario(scenario, duration_s, rate_hz, seed)
        counts = (self.simulation.gyr_counts, self.simulation.acc_counts, self.simulation.mag_counts)
        if profile != self.simulation.profile:
            counts = si_to_counts(self.simulation.gyr, self.simulation.acc, self.simulation.mag, profile)
        self._gyr, self._acc, self._mag = (c.tolist() for c in counts)
        limits = (profile.gyro_limits, profile.acc_limits, profile.mag_limits)
        self._saturated = np.any([(np.asarray(c) <= lo) | (np.asarray(c) >= hi) for c, (lo, hi)
                                  in zip(counts, limits)], axis=(0, 2)).tolist()
        self.faults = FaultInjector(faults) if faults is not None and faults.active else None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._position = 0  # next simulated sample: the simulated world keeps going through a RESET
        self._out = bytearray()
        self._boot()

    # ------------------------------------------------------------------ state

    def _boot(self) -> None:
        """Power-on state, also after RESET: default settings, not streaming, sequence 0, HELLO."""
        self._tx_seq = 0
        self._settings = {name: FirmwareFilter.default_raw_settings(name, self.rate_hz) for name in core.FILTERS}
        self._start_filter(FirmwareFilter(self.initial_filter, self._settings[self.initial_filter], self.profile))
        self._streaming = False
        self._stream_start, self._stream_first = 0.0, 0  # when streaming started, and at which sample
        self._injection = False
        self._decoder = protocol.FrameDecoder()
        self._booted = time.monotonic()
        self._cpu_load = 0.0
        self._dropped_samples = 0
        self._sensor_saturations = 0
        self._hello_pending = True

    def _start_filter(self, filter_: FirmwareFilter) -> None:
        """Make `filter_` active, from sample index 0."""
        self._filter = filter_
        self._index = 0

    @property
    def address(self) -> str:
        """What the host opens: a pty path or a socket:// URL."""
        return self.transport.address

    def truth(self, timestamps_us) -> np.ndarray:
        """True attitude (N,4) (w-first, sensor-to-earth ENU) of the samples with these
        SAMPLE.timestamp_us values (u32, unwrapped here)."""
        stamps = np.asarray(timestamps_us, dtype=np.int64)
        stamps = stamps + (np.cumsum(np.diff(stamps, prepend=stamps[:1]) < -(1 << 31)) << 32)
        positions = np.rint(stamps * self.rate_hz / 1e6).astype(np.int64)
        return self.simulation.quat_true[np.clip(positions, 0, len(self.simulation.quat_true) - 1)]

    # ------------------------------------------------------------------ thread

    def start(self) -> "VirtualBoard":
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"imulink-board {self.address}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close the transport (a host on it sees a disconnect)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.transport.close()

    def __enter__(self) -> "VirtualBoard":
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # surfaced through .error; the thread must not die silently
            self.error = exc
            raise

    def _loop(self) -> None:
        connections = self.transport.connections
        while not self._stop.is_set():
            if self._hello_pending:
                self._hello_pending = False
                self._emit("HELLO", **self._hello_fields())
            self._flush()
            self.transport.wait(bool(self._out), self._wait_time())
            if self.transport.connections != connections:  # a new client: forget the old one's output, greet it
                connections = self.transport.connections
                self._out.clear()
                self._emit("HELLO", **self._hello_fields())
            data = self.transport.read()
            if data:
                for message in self._decoder.feed(data):
                    if message.name == "COMMAND":
                        self._handle(message)
            if self._streaming:
                self._produce()

    def _wait_time(self) -> float:
        if not self._streaming:
            return 0.05
        if not self.realtime:
            return 0.0 if len(self._out) < FAST_BACKLOG_BYTES else 0.05
        due = self._stream_start + (self._position - self._stream_first) / self.rate_hz
        return min(0.05, max(0.0, due - time.monotonic()))

    # ------------------------------------------------------------------ output

    def _emit(self, message_name: str, /, **fields) -> None:
        wire = protocol.encode(message_name, self._tx_seq, **fields)
        self._tx_seq = (self._tx_seq + 1) & 0xFFFF
        if self.faults is not None:
            pause = self.faults.stall()
            if pause:
                self._flush(block=True)
                self._stop.wait(pause)
            wire = self.faults.damage(wire)
        self._out += wire

    def _flush(self, block: bool = False) -> None:
        while self._out and not self._stop.is_set():
            sent = self.transport.write(bytes(self._out[:65536]))
            del self._out[:sent]
            if not sent:
                if not block:
                    return
                self.transport.wait(True, 0.05)

    def _log(self, level: str, text: str) -> None:
        self._emit("LOG", level=_LOG[level], text=text)

    def _hello_fields(self) -> dict:
        major, minor, patch = (int(part) for part in __version__.split(".")[:3])
        return {"firmware_major": major, "firmware_minor": minor, "firmware_patch": patch,
                "protocol_version": protocol.PROTOCOL_VERSION, "schema_hash": self.schema_hash,
                "board": BOARD_NAME, "filters": sum(1 << filter_id for filter_id, _ in core.FILTERS.values())}

    def _status_fields(self) -> dict:
        sample_rate = self._filter.raw_settings["sample_rate"] / 2.0**16
        return {"uptime_ms": int((time.monotonic() - self._booted) * 1000) & 0xFFFFFFFF,
                "active_filter": self._filter.filter_id, "sample_rate_mhz": round(sample_rate * 1000),
                "dropped_samples": self._dropped_samples, "cpu_load_permille": min(1000, round(self._cpu_load)),
                "filter_saturations": self._filter.saturations, "sensor_saturations": self._sensor_saturations,
                "streaming": int(self._streaming), "injection_mode": int(self._injection)}

    # ------------------------------------------------------------------ live stream

    def _produce(self) -> None:
        """Stream the samples that are due (real time) or that the link has room for (fast)."""
        if self.realtime:
            elapsed = time.monotonic() - self._stream_start
            count = self._stream_first + int(elapsed * self.rate_hz) + 1 - self._position
        else:
            count = 0 if len(self._out) >= FAST_BACKLOG_BYTES else 32
        for _ in range(max(0, count)):
            if self._position >= len(self._gyr):
                self._streaming = False
                self._log("INFO", f"end of the simulated run ({self._position} samples): streaming stopped")
                self._emit("STATUS", **self._status_fields())
                return
            self._sample()

    def _sample(self) -> None:
        k = self._position
        self._position += 1
        started = time.perf_counter()
        estimate = self._filter.step(self._index, self._gyr[k], self._acc[k], self._mag[k])
        self._cpu_load = 0.99 * self._cpu_load + 0.01 * (time.perf_counter() - started) * self.rate_hz * 1000
        self._sensor_saturations += self._saturated[k]
        if self.realtime and len(self._out) > REALTIME_BACKLOG_BYTES:
            self._dropped_samples += 1  # the host does not keep up: like a full UART buffer
        else:
            self._emit("SAMPLE", timestamp_us=round(k * 1e6 / self.rate_hz) & 0xFFFFFFFF, index=self._index,
                       gyr=self._gyr[k], acc=self._acc[k], mag=self._mag[k], temperature=TEMPERATURE_25C)
            self._emit("ESTIMATE", **estimate)
        self._index += 1
        if self._position % max(1, round(self.rate_hz)) == 0:
            self._emit("STATUS", **self._status_fields())

    # ------------------------------------------------------------------ commands

    def _handle(self, message: protocol.Message) -> None:
        """Answer one COMMAND: its data (if any), then ACK or NACK, then its after-effect."""
        fields = message.fields
        after = None
        try:
            command = protocol.decode_command(message)
            handler = getattr(self, f"_cmd_{command.name.lower()}")
            data, after = handler(**command.args)
            replies = data + [("ACK", protocol.REASONS["OK"])]
        except protocol.CommandError as exc:
            replies = [("NACK", protocol.REASONS[exc.reason])]
        for name, payload in replies:
            if name in ("ACK", "NACK"):
                self._emit(name, command_seq=fields["command_seq"], command=fields["command"], reason=payload)
            else:
                self._emit(name, **payload)
        if after is not None:
            after()

    def _restart_filter(self, name: str) -> None:
        self._start_filter(FirmwareFilter(name, self._settings[name], self.profile))

    def _cmd_start_stream(self):
        if self._injection:
            raise protocol.CommandError("BUSY", "injection mode is on")
        if not self._streaming:
            self._streaming = True
            self._stream_start = time.monotonic()
            self._stream_first = self._position
        return [], None

    def _cmd_stop_stream(self):
        self._streaming = False
        return [], None

    def _cmd_select_filter(self, filter_id: int):
        if filter_id not in _FILTER_NAMES:
            raise protocol.CommandError("UNKNOWN_FILTER", f"no filter {filter_id}")
        self._restart_filter(_FILTER_NAMES[filter_id])
        return [], None

    def _setting_field(self, index: int) -> core.SettingField:
        if index >= len(self._filter.fields):
            raise protocol.CommandError("UNKNOWN_SETTING", f"no setting {index}")
        return self._filter.fields[index]

    def _cmd_get_setting(self, index: int):
        field = self._setting_field(index)
        data = {"filter_id": self._filter.filter_id, "index": index, "setting_count": len(self._filter.fields),
                "value": self._filter.raw_settings[field.name], "frac_bits": field.frac_bits,
                "name": field.name, "unit": field.unit}
        return [("SETTING", data)], None

    def _cmd_set_setting(self, index: int, value: int):
        field = self._setting_field(index)
        name = self._filter.filter_name
        settings = {**self._settings[name], field.name: value}
        try:
            filter_ = FirmwareFilter(name, settings, self.profile)
        except core.SettingsError as exc:
            raise protocol.CommandError("OUT_OF_RANGE", str(exc)) from None
        self._settings[name] = settings
        self._start_filter(filter_)
        return [], None

    def _cmd_inject_sample(self, timestamp_us, index, gyr, acc, mag, temperature):
        if not self._injection:
            raise protocol.CommandError("NOT_IN_INJECTION_MODE", "injection mode is off")
        return [("ESTIMATE", self._filter.step(index, gyr, acc, mag))], None

    def _cmd_reset(self):
        return [], self._boot

    def _cmd_enter_bootloader(self):
        return [], lambda: self._log("WARNING", "the virtual board has no bootloader: ENTER_BOOTLOADER ignored")

    def _cmd_get_version(self):
        return [("HELLO", self._hello_fields())], None

    def _cmd_get_status(self):
        return [("STATUS", self._status_fields())], None

    def _cmd_set_injection_mode(self, enabled: int):
        if enabled not in (0, 1):
            raise protocol.CommandError("BAD_ARGUMENT", f"enabled must be 0 or 1, not {enabled}")
        if self._streaming:
            raise protocol.CommandError("BUSY", "stop the stream first")
        self._injection = bool(enabled)
        self._restart_filter(self._filter.filter_name)
        return [], None
