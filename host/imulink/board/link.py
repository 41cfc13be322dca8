"""The host end of a link to a board: a serial port (or any pyserial URL), a reader
thread, the frame decoder and its counters, and commands that wait for their answer.

Typical use::

    with Link("/dev/ttyACM0") as link:          # or socket://127.0.0.1:5760, loop://, rfc2217://...
        hello = link.connect()                  # GET_VERSION -> HELLO, schema hash checked
        link.command("START_STREAM")
        for received in link.receive(timeout=0.5):
            received.time, received.message.name, received.message.fields

- A reader thread does large reads, hands every received chunk to an optional `tap`
  (the recorder writes it to disk before anything else happens to it), decodes it with
  :class:`imulink.protocol.FrameDecoder`, resolves pending commands and puts every
  message, with its host receive time, into a bounded queue (when the queue is full the
  oldest message is dropped and counted in ``queue_overflows``).
- :meth:`Link.command` sends a COMMAND and waits for its ACK (and the data the command
  asks for, which the board sends before the ACK). A timeout retries with a new
  ``command_seq`` (docs/protocol.md) -- except for commands that are not idempotent
  (INJECT_SAMPLE, RESET), which are sent once. A NACK raises
  :class:`imulink.protocol.CommandError` naming the reason.
- Everything that can go wrong on a link is a :class:`LinkError` (or a
  :class:`imulink.protocol.ProtocolError`) with a message fit for a user, never a bare
  pyserial or OS exception.
"""
from __future__ import annotations

import errno
import os
import queue
import select
import threading
import time
from collections import deque
from typing import NamedTuple

import serial

from imulink import protocol
from imulink.errors import ImulinkError

#: Default line rate for real serial ports (ignored by socket://, loop:// and ptys).
DEFAULT_BAUD = 921600
#: Seconds one command attempt waits for its ACK or NACK.
COMMAND_TIMEOUT_S = 0.5
#: Attempts of an idempotent command before CommandTimeout (a Link's default).
COMMAND_ATTEMPTS = 3
#: Each retry waits this much longer than the attempt before, up to COMMAND_TIMEOUT_MAX_S:
#: a board that is slow to answer (still sending its stream at a low baud rate) gets time.
RETRY_BACKOFF = 1.5
COMMAND_TIMEOUT_MAX_S = 2.0
#: Messages the receive queue holds before it drops the oldest.
QUEUE_SIZE = 200_000

#: The data message a command asks for; the board sends it before the ACK (the command's
#: reply in shared/protocol.toml).
REPLY_MESSAGES = protocol.REPLY_MESSAGES
#: Commands that must not be repeated blindly (repeating them changes the board's state twice):
#: those without the idempotent flag in shared/protocol.toml.
NOT_IDEMPOTENT = protocol.NOT_IDEMPOTENT_COMMANDS

_REASON_NAMES = {value: name for name, value in protocol.REASONS.items()}
_READ_SIZE = 1 << 16
_POLL_S = 0.05
_RATE_WINDOW_S = 1.0


def open_keeping_input(port, url: str) -> None:
    """`port.open()` (a pyserial port made with do_not_open), keeping what the peer sent at
    once: pyserial's socket port empties its input at the end of open(), after the
    connection is made, and a board (or the proxy) that greets each new client (HELLO)
    would lose the greeting whenever it came that fast."""
    if url.startswith("socket://"):
        port.reset_input_buffer = lambda: None
    try:
        port.open()
    finally:
        port.__dict__.pop("reset_input_buffer", None)


class LinkError(ImulinkError):
    """A link problem reported to the user as one line (port, peer, disconnect, timeout)."""


class PortError(LinkError):
    """The port cannot be opened: it does not exist, is busy, or the URL is wrong."""


class NotABoard(LinkError):
    """The peer does not answer like an imulink board (no HELLO in time)."""


class Busy(LinkError):
    """Another client commands the board (a TCP front with fan-out): this one may only listen."""


class Disconnected(LinkError):
    """The port closed or failed while in use (cable pulled, board gone, socket closed)."""


class CommandTimeout(LinkError):
    """A command got no ACK/NACK after every attempt."""


class ReceiveTimeout(LinkError):
    """The message waited for did not come in time."""


class Received(NamedTuple):
    """A decoded message and the host time (time.time(), s) its last byte was read."""

    time: float
    message: protocol.Message


class Reply(NamedTuple):
    """The answer to a command: its ACK and the data message it asked for (or None)."""

    ack: protocol.Message
    data: protocol.Message | None


class PendingCommand:
    """A command sent and not yet answered. The reader thread fills it in."""

    def __init__(self, name: str, command_seq: int, args: dict):
        self.name = name
        self.command_seq = command_seq
        self.args = args
        self.reply_name = REPLY_MESSAGES.get(name)
        self.data: protocol.Message | None = None
        self.answer: protocol.Message | None = None  # the ACK or NACK
        self.done = threading.Event()

    def wants(self, message: protocol.Message) -> bool:
        """Whether `message` is the data this command waits for."""
        if message.name != self.reply_name or self.data is not None:
            return False
        if "index" in self.args:  # GET_SETTING, INJECT_SAMPLE: the answer repeats the index asked for
            return message.fields["index"] == self.args["index"]
        return True

    def describe(self) -> str:
        args = ", ".join(f"{k}={v}" for k, v in self.args.items())
        return f"{self.name}({args})"


def _describe_port_error(url: str, exc: Exception) -> str:
    """One line saying why a port did not open, with what to do about it."""
    text = str(exc)
    code = getattr(exc, "errno", None)
    lowered = text.lower()
    if code == errno.ENOENT or "no such file" in lowered:
        return f"cannot open {url}: no such port (is the board plugged in? `ls /dev/tty*` lists ports)"
    if code == errno.EACCES or "permission denied" in lowered:
        return f"cannot open {url}: permission denied (on Linux, add yourself to the 'dialout' group)"
    if code == errno.EBUSY or "busy" in lowered or "lock" in lowered:
        return f"cannot open {url}: the port is busy (another program has it open)"
    if "refused" in lowered:
        return f"cannot open {url}: connection refused (is the board or emulator listening?)"
    return f"cannot open {url}: {text}"


class Link:
    """An open link to a board. Close it (or use it as a context manager) when done.

    Args:
        url: a device path (/dev/ttyACM0, COM3) or any pyserial URL (socket://host:port,
            loop://, rfc2217://host:port).
        baud: line rate of a real serial port.
        tap: called in the reader thread as ``tap(chunk, host_time)`` for every chunk of
            received bytes, before they are decoded (used to record the raw stream); it
            must not raise.
        queue_size: messages kept for :meth:`receive` before the oldest are dropped.
        attempts: attempts of each idempotent command unless a call says otherwise
            (more for a link that loses many frames).
    """

    def __init__(self, url: str, baud: int = DEFAULT_BAUD, tap=None, queue_size: int = QUEUE_SIZE,
                 attempts: int = COMMAND_ATTEMPTS):
        self.url = url
        self.hello: dict | None = None
        self.tap = tap
        self.attempts = attempts
        self._port = self._open(url, baud)
        self._fileno = self._port_fileno()
        self._decoder = protocol.FrameDecoder()
        self._decoder_lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._queue: queue.Queue[Received] = queue.Queue(queue_size)
        self._queue_overflows = 0
        self._pending: dict[int, PendingCommand] = {}
        self._pending_lock = threading.Lock()
        self._tx_seq = 0
        self._command_seq = int.from_bytes(os.urandom(2), "little")  # a fresh session never reuses the last one's
        self._opened = time.monotonic()
        self._rate_points: deque[tuple[float, int, int]] = deque()
        self._failure: str | None = None
        self._stopping = threading.Event()
        self._reader = threading.Thread(target=self._read_loop, name=f"imulink-link {url}", daemon=True)
        self._reader.start()

    # ------------------------------------------------------------------ opening and closing

    @staticmethod
    def _open(url: str, baud: int):
        if url.startswith(("lg://", "lg-env:")):
            raise PortError(f"cannot open {url}: a labgrid place is acquired first (an environment read first) and "
                            "opened by its serial port's URL (imulink.board.lab.held_place, environment_board; every "
                            "imulink command that takes a PORT does it)")
        try:
            port = serial.serial_for_url(url, baudrate=baud, do_not_open=True)
        except (ValueError, serial.SerialException) as exc:
            raise PortError(f"cannot open {url}: {exc}") from None
        if hasattr(port, "exclusive"):
            port.exclusive = True  # a second program on the same device gets "busy", not half the bytes
        try:
            open_keeping_input(port, url)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PortError(_describe_port_error(url, exc)) from None
        return port

    def _port_fileno(self) -> int | None:
        """The port's file descriptor when it has one (device, pty, socket): the reader then
        waits with select() and reads everything available at once, without pyserial's
        wait-for-the-whole-size behaviour. Other ports (loop://, rfc2217://) are polled."""
        try:
            fileno = self._port.fileno()
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            self._port.timeout = _POLL_S
            return None
        self._port.timeout = 0
        return fileno

    def close(self) -> None:
        """Stop the reader thread and close the port (idempotent)."""
        self._stopping.set()
        if self._reader.is_alive() and self._reader is not threading.current_thread():
            self._reader.join(timeout=2.0)
        try:
            self._port.close()
        except (serial.SerialException, OSError):
            pass

    def __enter__(self) -> "Link":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # ------------------------------------------------------------------ the reader thread

    def _read_chunk(self) -> bytes:
        if self._fileno is not None:
            ready, _, _ = select.select([self._fileno], [], [], _POLL_S)
            return self._port.read(_READ_SIZE) if ready else b""
        first = self._port.read(1)
        return first + self._port.read(self._port.in_waiting) if first else b""

    def _read_loop(self) -> None:
        while not self._stopping.is_set():
            try:
                chunk = self._read_chunk()
            except (serial.SerialException, OSError, ValueError, TypeError) as exc:
                if not self._stopping.is_set():
                    self._fail(f"{self.url} disconnected ({exc})")
                return
            if not chunk:
                continue
            now = time.time()
            tap = self.tap
            if tap is not None:
                tap(chunk, now)
            with self._decoder_lock:
                messages = self._decoder.feed(chunk)
                self._rate_points.append((time.monotonic(), self._decoder.frames, self._decoder.bytes))
                while self._rate_points and self._rate_points[0][0] < time.monotonic() - 2 * _RATE_WINDOW_S:
                    self._rate_points.popleft()
            for message in messages:
                self._dispatch(message)
                self._enqueue(Received(now, message))

    def _dispatch(self, message: protocol.Message) -> None:
        """Attach command answers and data to the pending commands they belong to."""
        if message.name == "HELLO":
            self.hello = message.fields
        with self._pending_lock:
            if message.name in ("ACK", "NACK"):
                pending = self._pending.get(message.fields["command_seq"])
                if pending is not None and protocol.COMMAND_IDS[pending.name] == message.fields["command"]:
                    pending.answer = message
                    del self._pending[pending.command_seq]
                    pending.done.set()
                return
            for pending in self._pending.values():  # oldest first: dicts keep insertion order
                if pending.wants(message):
                    pending.data = message
                    return

    def _enqueue(self, item: Received) -> None:
        while True:
            try:
                self._queue.put_nowait(item)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self._queue_overflows += 1
                except queue.Empty:
                    pass

    def _fail(self, reason: str) -> None:
        self._failure = reason
        with self._pending_lock:
            for pending in self._pending.values():
                pending.done.set()

    # ------------------------------------------------------------------ receiving

    @property
    def failure(self) -> str | None:
        """Why the link stopped working (disconnect), or None while it is healthy."""
        return self._failure

    def receive(self, timeout: float = 0.1) -> list[Received]:
        """Every message received so far (waiting up to `timeout` s for the first one).

        Raises Disconnected once the link has failed and every message received before
        the failure has been returned.
        """
        items = []
        try:
            items.append(self._queue.get(timeout=timeout) if timeout > 0 else self._queue.get_nowait())
            while True:
                items.append(self._queue.get_nowait())
        except queue.Empty:
            pass
        if not items and self._failure is not None:
            raise Disconnected(self._failure)
        return items

    def receive_until(self, predicate, timeout: float = 5.0) -> list[protocol.Message]:
        """The messages received until one satisfies `predicate` (that one last included).

        Raises ReceiveTimeout after `timeout` s without it, naming what did arrive, and
        Disconnected like :meth:`receive`.
        """
        messages: list[protocol.Message] = []
        deadline = time.monotonic() + timeout
        while True:
            for received in self.receive(max(0.0, min(0.1, deadline - time.monotonic()))):
                messages.append(received.message)
                if predicate(received.message):
                    return messages
            if time.monotonic() >= deadline:
                names = ", ".join(m.name for m in messages[-20:]) or "nothing"
                raise ReceiveTimeout(f"{self.url}: the message waited for did not come within {timeout:g} s "
                                     f"(received: {names})")

    def counters(self) -> dict:
        """Link counters: the decoder's (frames, bytes, crc_errors, resyncs, lost_frames, lost,
        sequence_restarts) plus frame_rate and byte_rate (per second over the last second),
        queue_overflows and elapsed_s since the port was opened."""
        with self._decoder_lock:
            counters = self._decoder.counters()
            now = time.monotonic()
            frame_rate = byte_rate = 0.0
            window = [p for p in self._rate_points if p[0] >= now - _RATE_WINDOW_S]
            if len(window) >= 2 and window[-1][0] > window[0][0]:
                span = window[-1][0] - window[0][0]
                frame_rate = (window[-1][1] - window[0][1]) / span
                byte_rate = (window[-1][2] - window[0][2]) / span
        counters.update(frame_rate=frame_rate, byte_rate=byte_rate, queue_overflows=self._queue_overflows,
                        elapsed_s=now - self._opened)
        return counters

    # ------------------------------------------------------------------ commands

    def _write(self, wire: bytes) -> None:
        try:
            self._port.write(wire)
        except (serial.SerialException, OSError) as exc:
            self._fail(f"{self.url} disconnected ({exc})")
            raise Disconnected(self._failure) from None

    def send_command(self, name: str, **args) -> PendingCommand:
        """Send one COMMAND without waiting; the returned PendingCommand is answered later."""
        return self._send(name, args, track=True)

    def post(self, name: str, **args) -> None:
        """Send one COMMAND whose ACK nobody waits for (RESEND: the frames it brings back
        are the answer that matters, and the caller asks again for what does not come)."""
        self._send(name, args, track=False)

    def _send(self, name: str, args: dict, track: bool) -> PendingCommand:
        if self._failure is not None:
            raise Disconnected(self._failure)
        with self._write_lock:
            command_seq = self._command_seq
            self._command_seq = (self._command_seq + 1) & 0xFFFF
            wire = protocol.encode_command(self._tx_seq, name, command_seq, **args)
            self._tx_seq = (self._tx_seq + 1) & 0xFFFF
            pending = PendingCommand(name, command_seq, args)
            if track:
                with self._pending_lock:
                    self._pending[command_seq] = pending
            self._write(wire)
        return pending

    def wait(self, pending: PendingCommand, timeout: float = COMMAND_TIMEOUT_S) -> Reply | None:
        """The reply of a sent command, or None when nothing answered within `timeout` s.

        Raises CommandError on a NACK and Disconnected when the link fails meanwhile.
        """
        answered = pending.done.wait(timeout)
        if self._failure is not None and pending.answer is None:
            raise Disconnected(self._failure)
        if not answered:
            with self._pending_lock:
                self._pending.pop(pending.command_seq, None)
            return None
        answer = pending.answer
        assert answer is not None  # done is set with the answer, or by _fail (Disconnected above)
        if answer.name == "NACK":
            reason = _REASON_NAMES.get(answer.fields["reason"], f"reason {answer.fields['reason']}")
            raise protocol.CommandError(reason, f"the board refused {pending.describe()}")
        return Reply(answer, pending.data)

    def command(self, name: str, timeout: float = COMMAND_TIMEOUT_S, attempts: int | None = None,
                **args) -> Reply:
        """Send a command and wait for its ACK (and data); retry idempotent commands
        (`attempts`, default the link's), each retry waiting longer (RETRY_BACKOFF).

        A reply whose data message was lost on the way (ACK without it) counts as a
        failed attempt. Raises CommandError (NACK, with the reason), CommandTimeout or
        Disconnected.
        """
        tries = 1 if name in NOT_IDEMPOTENT else (attempts or self.attempts)
        wait = waited = 0.0
        for attempt in range(tries):
            wait = timeout if attempt == 0 else min(wait * RETRY_BACKOFF, max(timeout, COMMAND_TIMEOUT_MAX_S))
            pending = self.send_command(name, **args)
            reply = self.wait(pending, wait)
            if reply is not None and (pending.reply_name is None or reply.data is not None
                                      or name in NOT_IDEMPOTENT):
                return reply
            waited += wait
        raise CommandTimeout(f"no answer to {pending.describe()} from {self.url} after {tries} attempt(s) "
                             f"in {waited:.3g} s")

    def query(self, name: str, timeout: float = COMMAND_TIMEOUT_S, attempts: int | None = None,
              **args) -> dict:
        """The fields of the data message a command asks for (GET_VERSION, GET_STATUS,
        GET_SETTING, GET_CALIBRATION: REPLY_MESSAGES but the not idempotent INJECT_SAMPLE),
        which command() waits for; the same errors as command()."""
        if name not in REPLY_MESSAGES or name in NOT_IDEMPOTENT:
            raise ValueError(f"{name} is not a command whose data command() waits for")
        data = self.command(name, timeout, attempts, **args).data
        assert data is not None  # command() returns an idempotent command only with its data
        return data.fields

    def listen(self, timeout: float = COMMAND_TIMEOUT_S) -> dict:
        """Wait for the board's HELLO without sending anything (a listener of a fan-out
        front gets the last one on connecting), check its schema hash, return its fields.
        NotABoard when none comes within `timeout` s."""
        deadline = time.monotonic() + timeout
        while self.hello is None and time.monotonic() < deadline:
            if self._failure is not None:
                raise Disconnected(self._failure)
            time.sleep(0.01)
        if self.hello is None:
            raise NotABoard(f"no HELLO from {self.url} within {timeout:g} s: listening needs a board that has "
                            "greeted (a fan-out front passes on the board's last HELLO)")
        protocol.check_hello(self.hello)
        return self.hello

    def connect(self, timeout: float = COMMAND_TIMEOUT_S, attempts: int | None = None) -> dict:
        """The handshake: GET_VERSION, wait for HELLO, check its schema hash.

        Attempts beyond COMMAND_ATTEMPTS are made only while the peer sends something:
        they help a board on a lossy link, not a port where nothing answers.
        Returns the HELLO fields. Raises NotABoard when nothing answers like an imulink
        board, ProtocolMismatch when the board was built from another protocol definition.
        """
        attempts = attempts or self.attempts
        first = min(attempts, COMMAND_ATTEMPTS)
        started = time.monotonic()
        try:
            try:
                reply = self.command("GET_VERSION", timeout=timeout, attempts=first)
            except protocol.CommandError as exc:
                if exc.reason != "BUSY":  # a board answers GET_VERSION; only a fan-out front refuses it
                    raise
                raise Busy(f"busy: another client is connected to {self.url} and commands the board; this "
                           "connection may only listen (imulink record --listen)") from None
            except CommandTimeout:
                if attempts == first or not self.counters()["bytes"]:
                    raise
                reply = self.command("GET_VERSION", timeout=timeout, attempts=attempts - first)
        except CommandTimeout:
            if self.hello is not None:  # an unsolicited HELLO: a board that did not understand us
                protocol.check_hello(self.hello)
            counters = self.counters()
            if counters["bytes"] == 0:
                heard = "received nothing"
            elif counters["frames"] == 0:
                heard = (f"received {counters['bytes']} bytes but no valid frame "
                         f"({counters['crc_errors']} CRC errors, {counters['resyncs']} resyncs)")
            else:
                heard = f"received {counters['frames']} frames but no HELLO"
            raise NotABoard(f"no imulink board answered on {self.url} within {time.monotonic() - started:.1f} s: "
                            f"{heard}. Is it an imulink board, running, and (for a serial port) at the right baud "
                            "rate?") from None
        hello = reply.data
        assert hello is not None  # command() returns GET_VERSION only with its HELLO
        protocol.check_hello(hello.fields)
        self.hello = hello.fields
        return hello.fields
