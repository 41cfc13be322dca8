"""A byte-stream proxy in front of any board (real, native or QEMU): the host side of
faults, and a steady peer for boards that must never lose their link.

:class:`Proxy` holds one connection to the board (any pyserial URL) for its whole life
and serves the host on a pseudo-terminal, a TCP port on 127.0.0.1 or a serial port
(the `front`). Bytes pass through unchanged, except:

- :class:`FaultConfig` damages the board-to-host stream frame by frame (dropped bytes,
  flipped bits, garbage bursts) and stalls it (the proxy then holds both directions:
  the board seems to stop answering), deterministically for a seed;
- `schema_hash` rewrites every HELLO to report another schema hash (a board built from
  another protocol definition), with a valid CRC.

A TCP front takes several clients (fan-out, see :class:`TcpFront`): the first commands
the board, the others listen. While no host is connected to it, what the board sends is
dropped, as on a UART with nothing attached. The proxy reads the board only while less than
BACKLOG_BYTES wait for the host, so a board that waits for its link (QEMU) waits for
the host, and a real-time board drops samples itself, as it would on a slow host.
"""
from __future__ import annotations

import os
import select
import socket
import threading
import time
import tty
from dataclasses import dataclass

import numpy as np
import serial
from cobs import cobs

from imulink import protocol
from imulink.board.link import PortError, open_keeping_input

#: Bytes from the board that may wait for a slow host before the proxy stops reading the board.
BACKLOG_BYTES = 1 << 16
_POLL_S = 0.05


# ---------------------------------------------------------------------------- faults


@dataclass(frozen=True)
class FaultConfig:
    """Damage applied to the board-to-host byte stream, frame by frame.

    drop_byte / flip_bit: probability that each byte is dropped / has one random bit
    flipped. garbage: probability that a burst of 1..garbage_max random bytes precedes a
    frame. stall: probability that the board goes silent for stall_s seconds before a
    frame (nothing passes either way meanwhile); stalls do not follow each other: after one,
    the frames of the next stall_s seconds pass (the frames held up by one would otherwise
    draw the next at once, and stalls would chain into one long outage). seed makes it
    reproducible.
    drop_samples: indices of SAMPLE frames dropped whole, the first time each passes (a
    loss placed exactly, for tests).
    """

    drop_byte: float = 0.0
    flip_bit: float = 0.0
    garbage: float = 0.0
    garbage_max: int = 32
    stall: float = 0.0
    stall_s: float = 0.05
    seed: int = 0
    drop_samples: tuple[int, ...] = ()

    def __post_init__(self):
        for name in ("drop_byte", "flip_bit", "garbage", "stall"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"fault probability {name}={getattr(self, name)!r} is not in [0, 1]")
        if self.garbage_max < 1 or self.stall_s < 0:
            raise ValueError("garbage_max must be >= 1 and stall_s >= 0")

    @property
    def active(self) -> bool:
        return any((self.drop_byte, self.flip_bit, self.garbage, self.stall, self.drop_samples))

    def describe(self) -> str:
        parts = [f"{name} {getattr(self, name):g}" for name in ("drop_byte", "flip_bit", "garbage", "stall")
                 if getattr(self, name)]
        if self.drop_samples:
            parts.append(f"SAMPLE {', '.join(map(str, self.drop_samples))} dropped")
        return ", ".join(parts) + f" (seed {self.seed})"


class FaultInjector:
    """Applies a FaultConfig and counts what it did (dropped_bytes, flipped_bits,
    garbage_bursts, garbage_bytes, stalls, damaged_frames)."""

    def __init__(self, config: FaultConfig):
        self.config = config
        self._rng = np.random.default_rng(config.seed)
        self.counts = dict.fromkeys(
            ("dropped_bytes", "flipped_bits", "garbage_bursts", "garbage_bytes", "stalls", "damaged_frames",
             "dropped_samples"), 0)
        self._samples_to_drop = set(config.drop_samples)
        self._calm_until = 0.0  # no stall before this time.monotonic()

    def damage(self, wire: bytes) -> bytes:
        """The bytes actually sent for one frame."""
        cfg, rng = self.config, self._rng
        if self._samples_to_drop and self._drops_sample(wire):
            return b""
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

    def _drops_sample(self, wire: bytes) -> bool:
        try:
            message = protocol.decode(wire)
        except protocol.FrameError:
            return False
        if message.name != "SAMPLE" or message.fields["index"] not in self._samples_to_drop:
            return False
        self._samples_to_drop.discard(message.fields["index"])
        self.counts["dropped_samples"] += 1
        return True

    def stall(self) -> float:
        """Seconds to stay silent before the next frame (0 almost always)."""
        if self.config.stall and self._rng.random() < self.config.stall and time.monotonic() >= self._calm_until:
            self.counts["stalls"] += 1
            self._calm_until = time.monotonic() + 2 * self.config.stall_s  # the stall, then as long again
            return self.config.stall_s
        return 0.0


def rewrite_schema_hash(frame: bytes, schema_hash: int) -> bytes:
    """A HELLO frame (delimiter included) reporting `schema_hash`; any other frame unchanged."""
    try:
        message = protocol.decode(frame)
    except protocol.FrameError:
        return frame
    if message.name != "HELLO":
        return frame
    return protocol.encode("HELLO", message.seq, **{**message.fields, "schema_hash": schema_hash})


# ---------------------------------------------------------------------------- fronts (the host's side)


class PtyFront:
    """A pseudo-terminal: the proxy owns the master, the host opens `address`."""

    def __init__(self):
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing, no CR/LF translation
        os.set_blocking(self._master, False)
        self.address = os.ttyname(self._slave)
        self.connections = 1

    def fileno(self) -> int:
        return self._master

    def poll(self, timeout: float) -> None:
        """Nothing to accept: a pty is always 'connected'."""

    def write_fds(self) -> list[int]:
        return []  # what waits for the host is the proxy's

    def pending_bytes(self) -> int:
        return 0

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

    @property
    def connected(self) -> bool:
        return True

    def close(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


class _Client:
    """One TCP client of a TcpFront: its socket and the bytes waiting for it."""

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.pending = bytearray()   # frames on their way to it
        self.received = bytearray()  # a listener's bytes after its last delimiter
        self.dropped_bytes = 0       # a listener's frames dropped because it did not keep up


#: Messages a TcpFront keeps the last of (per key) and gives a listener when it connects, so
#: that it knows the board: HELLO, STATUS, SETTING (per filter and index), CALIBRATION (per
#: sensor and axis).
_KEPT_IDS = {protocol.MESSAGE_IDS[name] for name in ("HELLO", "STATUS", "SETTING", "CALIBRATION")}
_BUSY = protocol.REASONS["BUSY"]


class TcpFront:
    """A TCP server on `host`:`port` (0: a free port); `address` is the pyserial URL.

    Several clients at once (fan-out): the first connected, the *commander*, talks with
    the board; every other one *listens*. Every client gets first the board's last HELLO,
    STATUS, SETTING and CALIBRATION frames seen, renumbered to run into the stream, so that
    it knows the board (a greeting, as the native board gives each client of its own TCP
    port), then every frame the board sends (from a frame boundary on);
    the proxy answers a COMMAND of a listener itself with NACK BUSY (a duplicate of the
    stream's last sequence number), and the board never sees it. A listener that does not
    keep up loses frames (its sequence numbers show the gap); the commander never does: the
    proxy stops reading the board instead. When the commander leaves, the listener
    connected longest takes its place. ``connections`` counts the clients accepted so far.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self._server = socket.create_server((host, port))
        self._server.setblocking(False)
        self.address = f"socket://{host}:{self._server.getsockname()[1]}"
        self._clients: list[_Client] = []  # the commander first
        self._partial = bytearray()        # board bytes after the last delimiter
        self._kept: dict[tuple, bytes] = {}  # key -> the last frame of a kept message
        self._last_seq = 0                 # of the board's last frame
        self.connections = 0

    def fileno(self) -> int | None:
        return self._clients[0].sock.fileno() if self._clients else None

    def write_fds(self) -> list[int]:
        return [c.sock.fileno() for c in self._clients if c.pending]

    def pending_bytes(self) -> int:
        """Bytes waiting for the commander (the proxy reads the board only while few do)."""
        return len(self._clients[0].pending) if self._clients else 0

    def listeners(self) -> int:
        return max(0, len(self._clients) - 1)

    def poll(self, timeout: float) -> None:
        """Accept clients (waiting up to `timeout` s while there is none), answer the
        listeners' commands, send what waits."""
        ready = select.select([self._server], [], [], 0.0 if self._clients else timeout)[0]
        if ready:
            try:
                sock, _ = self._server.accept()
            except BlockingIOError:
                sock = None
            if sock is not None:
                sock.setblocking(False)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                client = _Client(sock)
                # first what is known of the board: a greeting, as the native board gives every client
                kept = list(self._kept.values())
                first = (self._last_seq - len(kept) + 1) & 0xFFFF
                client.pending += b"".join(_renumber(frame, (first + k) & 0xFFFF) for k, frame in enumerate(kept))
                self._clients.append(client)
                self.connections += 1
        for client in self._clients[1:]:
            self._serve_listener(client)
        self._flush()

    def _serve_listener(self, client: _Client) -> None:
        try:
            data = client.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(client)
            return
        client.received += data
        *frames, rest = bytes(client.received).split(b"\0")
        client.received[:] = rest
        for frame in frames:
            try:
                message = protocol.decode(frame + b"\0")
            except protocol.FrameError:
                continue
            if message.name == "COMMAND":
                client.pending += protocol.encode("NACK", self._last_seq, command_seq=message.fields["command_seq"],
                                                  command=message.fields["command"], reason=_BUSY)

    @property
    def connected(self) -> bool:
        return bool(self._clients)

    def _drop(self, client: _Client) -> None:
        client.sock.close()
        self._clients.remove(client)  # the commander's successor: the listener connected longest

    def read(self) -> bytes:
        """What the commander sent (for the board)."""
        if not self._clients:
            return b""
        commander = self._clients[0]
        try:
            data = commander.sock.recv(65536)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            self._drop(commander)
        return data

    def write(self, data: bytes) -> int:
        """Take board bytes: every complete frame goes to every client (nobody connected:
        they are gone, as on a UART with nothing attached). Returns len(data)."""
        self._partial += data
        end = self._partial.rfind(0)
        if end < 0:
            return len(data)
        complete = bytes(self._partial[:end + 1])
        del self._partial[:end + 1]
        self._note(complete)
        for k, client in enumerate(self._clients):
            if k > 0 and len(client.pending) > BACKLOG_BYTES:
                client.dropped_bytes += len(complete)
            else:
                client.pending += complete
        self._flush()
        return len(data)

    def _note(self, frames: bytes) -> None:
        """The last sequence number, and the last frame of each kept message."""
        spans = frames.split(b"\0")[:-1]
        for span in spans:
            if len(span) > 1 and span[1] in _KEPT_IDS:  # COBS leaves a non-zero first byte (the id) in place
                try:
                    message = protocol.decode(span + b"\0")
                except protocol.FrameError:
                    continue
                f = message.fields
                key = {"SETTING": (f.get("filter_id"), f.get("index")),
                       "CALIBRATION": (f.get("sensor"), f.get("axis"))}.get(message.name, ())
                kept_key = (message.name, *key)
                self._kept.pop(kept_key, None)  # re-inserted last: the order they came in
                self._kept[kept_key] = span + b"\0"
        for span in reversed(spans):
            try:
                raw = cobs.decode(span)
            except cobs.DecodeError:
                continue
            if len(raw) >= 3:
                self._last_seq = raw[1] | raw[2] << 8
                break

    def _flush(self) -> None:
        for client in list(self._clients):
            if not client.pending:
                continue
            try:
                sent = client.sock.send(client.pending)
            except BlockingIOError:
                continue
            except OSError:
                self._drop(client)
                continue
            del client.pending[:sent]

    def close(self) -> None:
        for client in list(self._clients):
            self._drop(client)
        self._server.close()


def _renumber(frame: bytes, seq: int) -> bytes:
    """A frame (delimiter included) with another sequence number."""
    message = protocol.decode(frame)
    return protocol.encode(message.name, seq, **message.fields)


class SerialFront:
    """Any pyserial URL or device (one end of a null-modem cable, for example), polled.
    Raises PortError when the port cannot be opened."""

    def __init__(self, url: str, baud: int = 921600):
        try:
            self._port = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0)
        except (serial.SerialException, ValueError) as exc:  # ValueError: an unknown URL scheme, a bad baud rate
            raise PortError(f"cannot open {url}: {exc}") from None
        self.address = url
        self.connections = 1

    def fileno(self) -> int | None:
        try:
            return self._port.fileno()
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            return None

    def poll(self, timeout: float) -> None:
        pass

    def write_fds(self) -> list[int]:
        return []  # what waits for the host is the proxy's

    def pending_bytes(self) -> int:
        return 0

    @property
    def connected(self) -> bool:
        return True

    def read(self) -> bytes:
        return self._port.read(self._port.in_waiting or 1)

    def write(self, data: bytes) -> int:
        try:
            return self._port.write(data) or 0
        except serial.SerialTimeoutException:
            return 0

    def close(self) -> None:
        self._port.close()


def make_front(front: str, port: int = 0, baud: int = 921600):
    """'pty', 'tcp' (with `port`) or a serial URL."""
    if front == "pty":
        return PtyFront()
    if front == "tcp":
        return TcpFront(port=port)
    return SerialFront(front, baud)


# ---------------------------------------------------------------------------- the proxy


class Proxy:
    """Forward bytes between a board (`board_url`) and a front; see the module docstring.

    ``start()`` runs it in a thread, ``stop()`` ends it (also a context manager);
    ``error`` holds what stopped it early (the board's port failed), else None.
    """

    def __init__(self, board_url: str, front=None, *, faults: FaultConfig | None = None,
                 schema_hash: int | None = None, baud: int = 921600, connect_timeout_s: float = 10.0):
        self.front = front if front is not None else PtyFront()
        self.board_url = board_url
        self.faults = FaultInjector(faults) if faults is not None and faults.active else None
        self.schema_hash = schema_hash
        self._board = self._open_board(board_url, baud, connect_timeout_s)
        try:
            self._board_fd = self._board.fileno()
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            self._board_fd = None
            self._board.timeout = _POLL_S
        self._to_host = bytearray()   # bytes on their way to the host
        self._partial = bytearray()   # board bytes after the last delimiter (when frames are inspected)
        self._stall_until = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    @staticmethod
    def _open_board(url: str, baud: int, timeout_s: float):
        """Open the board's port; a socket that is not listening yet is retried until
        `timeout_s`, then PortError (at once for a URL pyserial does not know)."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                port = serial.serial_for_url(url, baudrate=baud, timeout=0, do_not_open=True)
                open_keeping_input(port, url)  # the board greets the proxy at once
                if url.startswith("socket://"):
                    port._socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                return port
            except (serial.SerialException, ValueError) as exc:
                if isinstance(exc, ValueError) or time.monotonic() > deadline:
                    raise PortError(f"cannot open {url}: {exc}") from None
                time.sleep(0.02)

    @property
    def address(self) -> str:
        return self.front.address

    def start(self) -> "Proxy":
        self._thread = threading.Thread(target=self._run, name=f"imulink-proxy {self.board_url}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.front.close()
        if self.board_url.startswith("socket://") and self._board.is_open:
            # pyserial's socket close sleeps 0.3 s "in case of quick reconnects"; the proxy
            # never reconnects: close the socket itself and mark the port closed
            self._board._socket.close()
            self._board.is_open = False
        self._board.close()

    def __enter__(self) -> "Proxy":
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._step()
        except (serial.SerialException, OSError) as exc:
            if not self._stop.is_set():
                self.error = exc
        except BaseException as exc:  # surfaced through .error; the thread must not die silently
            self.error = exc
            raise

    def _step(self) -> None:
        front = self.front
        front.poll(0.0 if front.connected else _POLL_S)
        if time.monotonic() < self._stall_until:
            self._stop.wait(min(_POLL_S, self._stall_until - time.monotonic()))
            return
        readable: list[int | None] = []
        room = len(self._to_host) + front.pending_bytes() < BACKLOG_BYTES
        fds = [fd for fd in (self._board_fd if room else None, front.fileno()) if fd is not None]
        writable = front.write_fds() + ([front.fileno()] if self._to_host and front.fileno() is not None else [])
        if fds or writable:
            readable, _, _ = select.select(fds, writable, [], _POLL_S)
        if self._board_fd is None and room:
            readable.append(None)  # a port without a file descriptor: polled
        if self._board_fd in readable or None in readable:
            data = self._board.read(65536) if self._board_fd is not None else self._board.read(
                max(1, self._board.in_waiting))
            if self._board_fd is not None and not data:
                raise OSError(f"{self.board_url} closed the connection")
            self._from_board(data)
        if (front.fileno() is not None and front.fileno() in readable) or isinstance(front, SerialFront):
            data = front.read()
            if data:
                self._board.write(data)
        if self._to_host:
            sent = front.write(bytes(self._to_host[:65536]))
            del self._to_host[:sent]

    def _from_board(self, data: bytes) -> None:
        if self.faults is None and self.schema_hash is None:
            self._to_host += data
            return
        self._partial += data
        while True:
            end = self._partial.find(0)
            if end < 0:
                return
            frame = bytes(self._partial[:end + 1])
            del self._partial[:end + 1]
            if self.schema_hash is not None:
                frame = rewrite_schema_hash(frame, self.schema_hash)
            if self.faults is not None:
                pause = self.faults.stall()
                if pause:
                    self._stall_until = time.monotonic() + pause
                frame = self.faults.damage(frame)
            self._to_host += frame
