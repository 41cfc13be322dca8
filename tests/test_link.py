"""The host link (imulink.board.link): ports, the handshake, commands, counters, failures.

Peers: the emulated board (the firmware as a native process) over a pty, pyserial's loop://, and scripted TCP peers on
127.0.0.1 that answer (or not) exactly as each test needs.
"""
from __future__ import annotations

import os
import socket
import threading
import time

import pytest

from imulink import protocol
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import CommandTimeout, Disconnected, Link, NotABoard, PortError, ReceiveTimeout
from imulink.board.proxy import FaultConfig


class ScriptedPeer:
    """A TCP peer on 127.0.0.1: for every COMMAND frame it receives it sends
    ``answer(command, attempt)`` (wire bytes, maybe none); attempt counts earlier
    commands of the same name."""

    def __init__(self, answer=None):
        self.answer = answer or (lambda command, attempt: b"")
        self.commands: list[protocol.Command] = []
        self._server = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self._server.getsockname()[1]}"
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        client, _ = self._server.accept()
        self._server.close()  # one client per peer
        decoder = protocol.FrameDecoder()
        with client:
            while True:
                data = client.recv(4096)
                if not data:
                    return
                for message in decoder.feed(data):
                    command = protocol.decode_command(message)
                    attempt = sum(c.name == command.name for c in self.commands)
                    self.commands.append(command)
                    client.sendall(self.answer(command, attempt))


def hello(seq: int = 0, schema_hash: int = protocol.SCHEMA_HASH) -> bytes:
    return protocol.encode("HELLO", seq, firmware_major=9, firmware_minor=8, firmware_patch=7,
                           protocol_version=protocol.PROTOCOL_VERSION, schema_hash=schema_hash, board="scripted",
                           filters=2, gyro_scale=1, acc_scale=2, mag_scale=3)


def ack(command: protocol.Command, seq: int = 1) -> bytes:
    return protocol.encode("ACK", seq, command_seq=command.command_seq, command=protocol.COMMAND_IDS[command.name],
                           reason=0)


STATUS = dict(uptime_ms=1, active_filter=1, sample_rate_mhz=100_000, dropped_samples=0, cpu_load_permille=0,
              filter_saturations=0, sensor_saturations=0, streaming=0, injection_mode=0, filter_cycles=0,
              cycle_hz=0, sensor_errors=0)


@pytest.fixture
def board():
    with EmulatedBoard(duration_s=30.0) as emulated:
        yield emulated


def test_connect_checks_hello(board):
    with Link(board.address) as link:
        fields = link.connect()
        assert fields["board"] == "native" and link.hello == fields


@pytest.mark.parametrize("command, args, reason", [
    ("SELECT_FILTER", {"filter_id": 99}, "UNKNOWN_FILTER"),
    ("SET_SETTING", {"index": 1, "value": -1}, "OUT_OF_RANGE"),
    ("GET_SETTING", {"index": 200}, "UNKNOWN_SETTING"),
    ("SET_INJECTION_MODE", {"enabled": 7}, "BAD_ARGUMENT"),
])
def test_nack_raises_command_error_naming_the_reason(board, command, args, reason):
    with Link(board.address) as link:
        link.connect()
        with pytest.raises(protocol.CommandError) as error:
            link.command(command, **args)
    assert error.value.reason == reason
    assert str(error.value).startswith(f"{reason}: the board refused {command}(")


def test_nonexistent_port():
    with pytest.raises(PortError, match="no such port"):
        Link("/dev/imulink-does-not-exist")


def test_busy_port(board):
    with Link(board.address):
        with pytest.raises(PortError, match="busy"):
            Link(board.address)


def test_refused_connection_and_bad_url():
    with socket.create_server(("127.0.0.1", 0)) as probe:
        port = probe.getsockname()[1]  # closed again when the block ends: nobody listens there
    with pytest.raises(PortError, match="connection refused"):
        Link(f"socket://127.0.0.1:{port}")
    with pytest.raises(PortError, match="protocol 'nonsense' not known"):
        Link("nonsense://x")


def test_silent_peer_is_not_a_board():
    peer = ScriptedPeer()
    with Link(peer.url) as link, pytest.raises(NotABoard, match="received nothing"):
        link.connect(timeout=0.1)
    assert [c.name for c in peer.commands] == ["GET_VERSION"] * 3


def test_peer_sending_garbage_is_not_a_board():
    garbage = bytes(range(1, 256)) * 20 + b"\0" + os.urandom(500).replace(b"\0", b"\1") + b"\0"
    peer = ScriptedPeer(answer=lambda command, attempt: garbage)
    with Link(peer.url) as link, pytest.raises(NotABoard, match=r"bytes but no valid frame .*resyncs"):
        link.connect(timeout=0.1)


def test_loop_url_echoes_commands_and_is_not_a_board():
    with Link("loop://") as link, pytest.raises(NotABoard, match="frames but no HELLO"):
        link.connect(timeout=0.1)


def test_schema_mismatch_is_refused():
    with EmulatedBoard(duration_s=1.0, schema_hash=0x12345678) as emulated, Link(emulated.address) as link:
        with pytest.raises(protocol.ProtocolMismatch, match=f"0x12345678.*0x{protocol.SCHEMA_HASH:08X}"):
            link.connect()


def test_hello_without_an_ack_of_our_schema_is_a_mismatch():
    """A board built from another definition may answer GET_VERSION with its HELLO but
    nothing else this host can decode: the HELLO alone is enough to refuse it clearly."""
    peer = ScriptedPeer(answer=lambda command, attempt: hello(schema_hash=0xDEADBEEF))
    with Link(peer.url) as link, pytest.raises(protocol.ProtocolMismatch, match="0xDEADBEEF"):
        link.connect(timeout=0.1)


def test_idempotent_command_is_retried_with_a_new_command_seq():
    def answer(command, attempt):
        if command.name == "GET_VERSION":
            return hello() + ack(command)
        if attempt == 0:
            return b""  # lost
        if attempt == 1:
            return ack(command)  # the ACK without the STATUS it promises: lost data
        return protocol.encode("STATUS", 2, **STATUS) + ack(command, 3)

    peer = ScriptedPeer(answer)
    with Link(peer.url) as link:
        link.connect()
        reply = link.command("GET_STATUS", timeout=0.2)
    assert reply.data.fields == STATUS and reply.ack.name == "ACK"
    seqs = [c.command_seq for c in peer.commands if c.name == "GET_STATUS"]
    assert len(seqs) == 3 and len(set(seqs)) == 3


def test_inject_sample_is_never_repeated():
    def answer(command, attempt):
        return hello() + ack(command) if command.name == "GET_VERSION" else b""

    peer = ScriptedPeer(answer)
    with Link(peer.url) as link:
        link.connect()
        with pytest.raises(CommandTimeout, match=r"INJECT_SAMPLE\(.*after 1 attempt"):
            link.command("INJECT_SAMPLE", timeout=0.1, timestamp_us=0, index=5, gyr=(0, 0, 0), acc=(0, 0, 0),
                         mag=(0, 0, 0), temperature=0)
    time.sleep(0.1)
    assert [c.name for c in peer.commands].count("INJECT_SAMPLE") == 1


def test_counters_tap_and_queue(board):
    tapped = []
    with Link(board.address, tap=lambda chunk, t: tapped.append(len(chunk)), queue_size=50) as link:
        link.connect()
        link.command("START_STREAM")
        time.sleep(0.3)
        counters = link.counters()
        received = link.receive(0)
    assert counters["frames"] > 500 and counters["crc_errors"] == counters["resyncs"] == counters["lost_frames"] == 0
    assert counters["frame_rate"] > 0 and counters["byte_rate"] > counters["frame_rate"]
    assert sum(tapped) >= counters["bytes"] > 0
    assert len(received) == 50 and counters["queue_overflows"] > 0  # the oldest were dropped
    assert received[-1].time >= received[0].time > 0


def test_counters_see_damage():
    faults = FaultConfig(drop_byte=2e-3, flip_bit=2e-3, seed=5)
    with EmulatedBoard(duration_s=5.0, faults=faults) as emulated, Link(emulated.address) as link:
        link.connect(attempts=10)
        link.command("START_STREAM", attempts=10)
        time.sleep(0.3)
        counters = link.counters()
    assert counters["crc_errors"] + counters["resyncs"] > 0 and counters["lost_frames"] > 0


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_disconnect_is_reported_after_the_queued_messages(transport):
    emulated = EmulatedBoard(front=transport, duration_s=30.0).start()
    with Link(emulated.address) as link:
        link.connect()
        link.command("START_STREAM")
        time.sleep(0.1)
        emulated.stop()
        received = 0
        with pytest.raises(Disconnected, match="disconnected"):
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                received += len(link.receive(0.1))
        assert received > 0 and link.failure is not None
        with pytest.raises(Disconnected):
            link.command("GET_STATUS")


def test_receive_until_returns_up_to_the_wanted_message_or_names_what_came(board):
    with Link(board.address) as link:
        link.connect()
        link.receive(0)
        link.send_command("GET_STATUS")
        messages = link.receive_until(lambda m: m.name == "ACK", 2.0)
        assert [m.name for m in messages] == ["STATUS", "ACK"]
        link.send_command("GET_VERSION")
        with pytest.raises(ReceiveTimeout, match=r"within 0.3 s \(received: HELLO, ACK\)"):
            link.receive_until(lambda m: m.name == "ESTIMATE", 0.3)


@pytest.mark.parametrize("opener", ["link", "proxy"])
def test_a_greeting_that_comes_at_once_is_kept(monkeypatch, opener):
    """A peer that greets each new client at once (the native board greets the proxy, the
    proxy's TCP front greets every client): pyserial's socket port empties its input at the
    end of open(), which lost a greeting already in (the proxy's board greeting: one run in
    six under load, and test_tcp_board_greets_every_client with it). The connection is slowed
    here so that the greeting is always in before open() ends."""
    import serial.urlhandler.protocol_socket as pyserial_socket

    from imulink.board.proxy import Proxy

    server = socket.create_server(("127.0.0.1", 0))
    greeting = hello()

    def serve():
        client, _ = server.accept()
        client.sendall(greeting)
        time.sleep(2.0)
        client.close()

    threading.Thread(target=serve, daemon=True).start()
    connect = pyserial_socket.socket.create_connection

    def slow_connect(*args, **kwargs):
        sock = connect(*args, **kwargs)
        time.sleep(0.3)  # the greeting arrives meanwhile
        return sock

    monkeypatch.setattr(pyserial_socket.socket, "create_connection", slow_connect)
    url = f"socket://127.0.0.1:{server.getsockname()[1]}"
    try:
        if opener == "link":
            with Link(url) as link:
                assert [r.message.name for r in link.receive(1.0)] == ["HELLO"]
        else:
            port = Proxy._open_board(url, 921600, 2.0)
            try:
                received, deadline = b"", time.monotonic() + 1.0
                while len(received) < len(greeting) and time.monotonic() < deadline:
                    received += port.read(4096)
                    time.sleep(0.01)
                assert received == greeting
            finally:
                port.close()
    finally:
        server.close()
