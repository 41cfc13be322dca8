"""The virtual board (imulink.board): every command of the protocol, the live stream,
injection, fault injection, and the firmware model it computes with.

The board is driven through imulink.link over a pty (os.openpty) or TCP on 127.0.0.1,
exactly as a host drives a real board.
"""
from __future__ import annotations

import math
import os
import select
import time
import tty

import numpy as np
import pytest
import serial

from imulink import core, protocol, sim
from imulink.board import (
    FaultConfig,
    FaultInjector,
    FirmwareFilter,
    PtyTransport,
    SerialTransport,
    TcpTransport,
    VirtualBoard,
)
from imulink.link import Link


@pytest.fixture
def board():
    """A virtual board on a pty: 20 s of the 'rests' scenario at 100 Hz, streaming fast."""
    with VirtualBoard(PtyTransport(), duration_s=20.0) as virtual:
        yield virtual


@pytest.fixture
def link(board):
    with Link(board.address) as connected:
        connected.connect()
        yield connected


def _stream(link: Link, count: int) -> list[protocol.Message]:
    """Start the stream and collect messages until `count` ESTIMATEs arrived; stop it."""
    link.receive(0)  # what an earlier stream left in the queue (it all arrived before STOP_STREAM's ACK)
    link.command("START_STREAM")
    messages = []
    deadline = time.monotonic() + 10
    while sum(m.name == "ESTIMATE" for m in messages) < count and time.monotonic() < deadline:
        messages += [r.message for r in link.receive(0.1)]
    link.command("STOP_STREAM")
    return messages


def test_hello_describes_the_board(link):
    hello = link.hello
    assert hello["board"] == "emulator"
    assert hello["schema_hash"] == protocol.SCHEMA_HASH and hello["protocol_version"] == protocol.PROTOCOL_VERSION
    assert hello["filters"] == sum(1 << fid for fid, _ in core.FILTERS.values())


def test_status_reports_the_configuration(link):
    status = link.command("GET_STATUS").data.fields
    assert status["active_filter"] == core.FILTERS["eecf"][0]
    assert status["sample_rate_mhz"] == 100_000
    assert status["streaming"] == 0 and status["injection_mode"] == 0


def test_settings_read_back_as_the_core_declares_them(link):
    fields = core.settings_fields("eecf")
    defaults = FirmwareFilter.default_raw_settings("eecf", 100.0)
    for index, field in enumerate(fields):
        setting = link.command("GET_SETTING", index=index).data.fields
        assert (setting["name"], setting["unit"], setting["frac_bits"]) == (field.name, field.unit, field.frac_bits)
        assert setting["value"] == defaults[field.name] and setting["setting_count"] == len(fields)
    with pytest.raises(protocol.CommandError) as error:
        link.command("GET_SETTING", index=len(fields))
    assert error.value.reason == "UNKNOWN_SETTING"


def test_set_setting_changes_the_value_and_restarts_the_filter(link):
    kp = [f.name for f in core.settings_fields("eecf")].index("kp")
    link.command("SET_SETTING", index=kp, value=core.to_fixed(0.5, 16))
    assert link.command("GET_SETTING", index=kp).data.fields["value"] == core.to_fixed(0.5, 16)
    first = [m for m in _stream(link, 3) if m.name == "SAMPLE"]
    assert first[0].fields["index"] == 0
    link.command("SET_SETTING", index=kp, value=core.to_fixed(0.6, 16))
    again = [m for m in _stream(link, 3) if m.name == "SAMPLE"]
    assert again[0].fields["index"] == 0  # the filter restarted with the new value


def test_set_setting_out_of_range_is_refused_and_changes_nothing(link):
    kp = [f.name for f in core.settings_fields("eecf")].index("kp")
    before = link.command("GET_SETTING", index=kp).data.fields["value"]
    with pytest.raises(protocol.CommandError) as error:
        link.command("SET_SETTING", index=kp, value=-1)
    assert error.value.reason == "OUT_OF_RANGE"
    assert link.command("GET_SETTING", index=kp).data.fields["value"] == before


def test_select_filter_switches_and_keeps_each_filters_settings(link):
    link.command("SELECT_FILTER", filter_id=core.FILTERS["eskf"][0])
    setting = link.command("GET_SETTING", index=1).data.fields
    assert setting["filter_id"] == core.FILTERS["eskf"][0] and setting["name"] == "gyro_arw"
    assert link.command("GET_STATUS").data.fields["active_filter"] == core.FILTERS["eskf"][0]
    with pytest.raises(protocol.CommandError) as error:
        link.command("SELECT_FILTER", filter_id=99)
    assert error.value.reason == "UNKNOWN_FILTER"


def test_stream_is_the_fixed_point_core_sample_by_sample(board, link):
    messages = _stream(link, 300)
    samples = [m.fields for m in messages if m.name == "SAMPLE"]
    estimates = [m.fields for m in messages if m.name == "ESTIMATE"]
    n = len(estimates)
    assert [s["index"] for s in samples[:n]] == list(range(n)) == [e["index"] for e in estimates]
    truth = board.simulation
    np.testing.assert_array_equal([s["gyr"] for s in samples[:n]], truth.gyr_counts[:n])
    reference = core.run_counts("eecf", truth.gyr_counts[:n], truth.acc_counts[:n], truth.mag_counts[:n], 100.0)
    np.testing.assert_array_equal([e["quat"] for e in estimates], reference.raw["quat"])
    np.testing.assert_array_equal([e["euler"] for e in estimates], reference.raw["euler"])
    np.testing.assert_array_equal([e["gyro_bias"] for e in estimates], reference.raw["gyro_bias"])
    statuses = [m.fields for m in messages if m.name == "STATUS"]
    assert len(statuses) >= n // 100 - 1 and all(s["streaming"] for s in statuses)  # once per simulated second


def test_timestamps_map_to_the_simulated_truth(board, link):
    samples = [m.fields for m in _stream(link, 50) if m.name == "SAMPLE"]
    stamps = [s["timestamp_us"] for s in samples]
    np.testing.assert_array_equal(board.truth(stamps), board.simulation.quat_true[:len(stamps)])


def test_end_of_the_simulated_run_stops_the_stream():
    with VirtualBoard(PtyTransport(), duration_s=1.0) as virtual, Link(virtual.address) as link:
        link.connect()
        link.command("START_STREAM")
        messages, deadline = [], time.monotonic() + 5
        while not any(m.name == "STATUS" and not m.fields["streaming"] for m in messages):
            assert time.monotonic() < deadline
            messages += [r.message for r in link.receive(0.1)]
    assert sum(m.name == "SAMPLE" for m in messages) == 100
    assert any(m.name == "LOG" and "end of the simulated run" in m.fields["text"] for m in messages)


def test_real_time_pacing():
    with VirtualBoard(PtyTransport(), duration_s=5.0, rate_hz=200.0, realtime=True) as virtual, \
            Link(virtual.address) as link:
        link.connect()
        link.command("START_STREAM")
        start = time.monotonic()
        count = 0
        while time.monotonic() - start < 0.5:
            count += sum(r.message.name == "SAMPLE" for r in link.receive(0.05))
        assert 70 <= count <= 130  # 0.5 s at 200 Hz


def test_injection_mode(link):
    with pytest.raises(protocol.CommandError) as error:
        link.command("INJECT_SAMPLE", timestamp_us=0, index=0, gyr=(0, 0, 0), acc=(0, 0, 4096), mag=(0, 100, -200),
                     temperature=0)
    assert error.value.reason == "NOT_IN_INJECTION_MODE"
    link.command("SET_INJECTION_MODE", enabled=1)
    assert link.command("GET_STATUS").data.fields["injection_mode"] == 1
    with pytest.raises(protocol.CommandError) as error:
        link.command("START_STREAM")
    assert error.value.reason == "BUSY"
    data = sim.make_scenario("random", 2.0, 100.0, seed=3)
    reference = FirmwareFilter("eecf", FirmwareFilter.default_raw_settings("eecf", 100.0))
    for k in range(len(data)):
        gyr, acc, mag = data.gyr_counts[k].tolist(), data.acc_counts[k].tolist(), data.mag_counts[k].tolist()
        reply = link.command("INJECT_SAMPLE", timestamp_us=k * 10_000, index=k + 1000, gyr=gyr, acc=acc, mag=mag,
                             temperature=0)
        expected = reference.step(k + 1000, gyr, acc, mag)
        assert {f: (list(v) if isinstance(v, tuple) else v) for f, v in reply.data.fields.items()} == expected


def test_injection_mode_arguments_and_busy(link):
    with pytest.raises(protocol.CommandError) as error:
        link.command("SET_INJECTION_MODE", enabled=2)
    assert error.value.reason == "BAD_ARGUMENT"
    link.command("START_STREAM")
    with pytest.raises(protocol.CommandError) as error:
        link.command("SET_INJECTION_MODE", enabled=1)
    assert error.value.reason == "BUSY"


def test_unknown_command_and_bad_length(board):
    """Commands outside the schema (sent as raw frames, which Link never produces) are NACKed."""
    port = serial.serial_for_url(board.address, timeout=0.1)
    decoder, nacks = protocol.FrameDecoder(), []
    try:
        for seq, (command, args) in enumerate(((200, b""), (protocol.COMMAND_IDS["SELECT_FILTER"], b"\x01\x02"))):
            port.write(protocol.encode("COMMAND", seq, command=command, command_seq=4242 + seq, args=args))
            deadline = time.monotonic() + 2
            while len(nacks) <= seq:
                assert time.monotonic() < deadline
                nacks += [m.fields for m in decoder.feed(port.read(4096)) if m.name == "NACK"]
    finally:
        port.close()
    assert [(n["command"], n["command_seq"], n["reason"]) for n in nacks] == [
        (200, 4242, protocol.REASONS["UNKNOWN_COMMAND"]),
        (protocol.COMMAND_IDS["SELECT_FILTER"], 4243, protocol.REASONS["BAD_LENGTH"])]


def test_reset_restores_defaults_and_says_hello(link):
    kp = [f.name for f in core.settings_fields("eecf")].index("kp")
    link.command("SELECT_FILTER", filter_id=core.FILTERS["kf1d"][0])
    link.command("SELECT_FILTER", filter_id=core.FILTERS["eecf"][0])
    link.command("SET_SETTING", index=kp, value=core.to_fixed(0.5, 16))
    link.receive(0)
    link.command("RESET")
    deadline = time.monotonic() + 2
    hellos = []
    while not hellos:
        assert time.monotonic() < deadline
        hellos = [r.message for r in link.receive(0.1) if r.message.name == "HELLO"]
    assert hellos[0].seq == 0  # the board's sequence restarts with HELLO
    assert link.command("GET_SETTING", index=kp).data.fields["value"] == \
        FirmwareFilter.default_raw_settings("eecf", 100.0)["kp"]


def test_enter_bootloader_is_acknowledged_and_explained(link):
    link.receive(0)
    link.command("ENTER_BOOTLOADER")
    deadline, logs = time.monotonic() + 2, []
    while not logs:
        assert time.monotonic() < deadline
        logs = [r.message.fields for r in link.receive(0.1) if r.message.name == "LOG"]
    assert "no bootloader" in logs[0]["text"] and logs[0]["level"] == protocol.LOG_LEVELS["WARNING"]


def test_board_on_a_serial_port():
    """SerialTransport: the board opens one end of a pty like a UART; the host speaks raw frames on the other."""
    master, slave = os.openpty()
    tty.setraw(slave)
    decoder, answers = protocol.FrameDecoder(), []
    with VirtualBoard(SerialTransport(os.ttyname(slave)), duration_s=1.0):
        os.write(master, protocol.encode_command(0, "GET_VERSION", 77))
        deadline = time.monotonic() + 2
        while not any(m.name == "ACK" for m in answers):
            assert time.monotonic() < deadline
            if select.select([master], [], [], 0.1)[0]:
                answers += decoder.feed(os.read(master, 4096))
    os.close(master)
    os.close(slave)
    assert [m.name for m in answers][-2:] == ["HELLO", "ACK"] and answers[-1].fields["command_seq"] == 77


def test_tcp_board_greets_every_client():
    with VirtualBoard(TcpTransport(), duration_s=5.0) as virtual:
        assert virtual.address.startswith("socket://127.0.0.1:")
        for _ in range(2):
            with Link(virtual.address) as link:
                assert link.connect()["board"] == "emulator"
                assert len([m for m in _stream(link, 20) if m.name == "ESTIMATE"]) >= 20
        assert virtual.transport.connections == 2


def test_fault_injector_is_deterministic_and_counts():
    frame = protocol.encode("ESTIMATE", 1, index=1, filter_id=1, quat=(1, 2, 3, 4), gyro_bias=(0, 0, 0),
                            euler=(0, 0, 0), cov_mantissa=(0,) * 9, cov_exponent=(0,) * 9, saturations=0)
    config = FaultConfig(drop_byte=0.01, flip_bit=0.01, garbage=0.05, seed=7)
    runs = []
    for _ in range(2):
        injector = FaultInjector(config)
        runs.append(([injector.damage(frame) for _ in range(500)], injector.counts))
    assert runs[0] == runs[1]
    sent, counts = runs[0]
    assert counts["dropped_bytes"] > 0 and counts["flipped_bits"] > 0 and counts["garbage_bursts"] > 0
    assert sum(map(len, sent)) == 500 * len(frame) - counts["dropped_bytes"] + counts["garbage_bytes"]
    assert 0 < counts["damaged_frames"] <= sum(s != frame for s in sent)


def test_fault_config_validates():
    with pytest.raises(ValueError, match="drop_byte"):
        FaultConfig(drop_byte=1.5)
    assert not FaultConfig().active and FaultConfig(stall=0.1).active


def test_covariance_diagonal_raw_is_the_block_floating_storage():
    data = sim.make_scenario("rests", 5.0, 100.0, seed=1)
    reference = FirmwareFilter("eskf", FirmwareFilter.default_raw_settings("eskf", 100.0))
    reference.core.run_counts(data.gyr_counts, data.acc_counts, data.mag_counts)
    mantissas, exponents = reference.core.covariance_diagonal_raw()
    diagonal = np.diag(reference.core.covariance())
    for i, value in enumerate(diagonal):
        assert 2**28 <= mantissas[i] < 2**30 and exponents[i] % 2 == 0  # the invariant of imu_cov.h
        assert mantissas[i] * 2.0 ** (exponents[i] - 30) == value
    assert mantissas[len(diagonal):] == [0] * (9 - len(diagonal))


def test_firmware_filter_uses_the_raw_settings_exactly():
    raw = FirmwareFilter.default_raw_settings("kf1d", 250.0)
    raw["q_angle"] += 1  # one LSB: a value no decimal setting would give
    firmware = FirmwareFilter("kf1d", raw)
    assert firmware.si_settings["q_angle"] * 2.0**40 == raw["q_angle"]
    assert math.isclose(firmware.si_settings["sample_rate"], 250.0)
