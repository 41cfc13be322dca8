"""The UBX protocol code (firmware/drivers/ubx.c) against the u-blox M8 protocol
specification: frames written by the test from the spec's layout, in any chunking, with
NMEA sentences, noise and damaged frames between them."""
from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest

from cffi_module import build

ROOT = Path(__file__).resolve().parents[1]
DRIVERS = ROOT / "firmware" / "drivers"

CDEF = """
    typedef struct {
        uint32_t frames; uint32_t checksum_errors; uint32_t oversized; uint32_t skipped_bytes; ...;
    } ubx_parser_t;
    void ubx_parser_init(ubx_parser_t *p);
    int ubx_parser_push(ubx_parser_t *p, uint8_t byte);
    uint8_t ubx_frame_class(const ubx_parser_t *p);
    uint8_t ubx_frame_id(const ubx_parser_t *p);
    const uint8_t *ubx_frame_payload(const ubx_parser_t *p, uint16_t *length);
    uint16_t ubx_checksum(const uint8_t *data, size_t len);
    size_t ubx_encode(uint8_t msg_class, uint8_t msg_id, const uint8_t *payload, uint16_t len, uint8_t *out,
                      size_t cap);
    typedef struct {
        uint32_t itow_ms; uint8_t fix_type; uint8_t fix_ok; uint8_t num_sv; int32_t lon_1e7deg; int32_t lat_1e7deg;
        int32_t height_mm; int32_t hmsl_mm; uint32_t h_acc_mm; uint32_t v_acc_mm; int32_t vel_ned_mm_s[3];
        uint32_t s_acc_mm_s; uint16_t p_dop_cent;
    } ubx_nav_pvt_t;
    int ubx_nav_pvt(const uint8_t *payload, uint16_t len, ubx_nav_pvt_t *out);
"""

#: NAV-PVT's payload, the spec's table: (name, struct format) in order, 92 bytes.
NAV_PVT_LAYOUT = (("itow_ms", "I"), ("year", "H"), ("month", "B"), ("day", "B"), ("hour", "B"), ("min", "B"),
                  ("sec", "B"), ("valid", "B"), ("t_acc", "I"), ("nano", "i"), ("fix_type", "B"), ("flags", "B"),
                  ("flags2", "B"), ("num_sv", "B"), ("lon_1e7deg", "i"), ("lat_1e7deg", "i"), ("height_mm", "i"),
                  ("hmsl_mm", "i"), ("h_acc_mm", "I"), ("v_acc_mm", "I"), ("vel_n", "i"), ("vel_e", "i"),
                  ("vel_d", "i"), ("g_speed", "i"), ("head_mot", "i"), ("s_acc_mm_s", "I"), ("head_acc", "I"),
                  ("p_dop_cent", "H"), ("flags3", "H"), ("reserved", "4s"), ("head_veh", "i"), ("mag_dec", "h"),
                  ("mag_acc", "H"))
NAV_PVT = struct.Struct("<" + "".join(f for _, f in NAV_PVT_LAYOUT))


@pytest.fixture(scope="module")
def ubx(tmp_path_factory):
    return build("_imulink_ubx", CDEF, '#include "ubx.h"\n', [DRIVERS / "ubx.c"], [DRIVERS],
                 tmp_path_factory.mktemp("ubx"))


def frame(msg_class: int, msg_id: int, payload: bytes) -> bytes:
    """A UBX frame as the spec writes it (the test's own encoder)."""
    body = bytes([msg_class, msg_id]) + struct.pack("<H", len(payload)) + payload
    a = b = 0
    for byte in body:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


def random_pvt(rng: random.Random) -> dict:
    values = {}
    for name, fmt in NAV_PVT_LAYOUT:
        if fmt == "4s":
            values[name] = bytes(4)
        else:
            size = struct.calcsize(fmt)
            signed = (-(1 << (8 * size - 1)), (1 << (8 * size - 1)) - 1)
            low, high = signed if fmt.islower() else (0, (1 << (8 * size)) - 1)
            values[name] = rng.randint(low, high)
    values["fix_type"] = rng.randrange(6)
    return values


def feed(ubx, parser, data: bytes) -> list[tuple[int, int, bytes]]:
    out = []
    length = ubx.ffi.new("uint16_t *")
    for byte in data:
        if ubx.lib.ubx_parser_push(parser, byte):
            payload = ubx.lib.ubx_frame_payload(parser, length)
            out.append((ubx.lib.ubx_frame_class(parser), ubx.lib.ubx_frame_id(parser),
                        bytes(ubx.ffi.buffer(payload, length[0]))))
    return out


def test_checksum_and_encoding_match_the_spec_example(ubx):
    """The spec's CFG-RATE example (200 ms measurement rate, navigation rate 1, GPS time):
    B5 62 06 08 06 00 C8 00 01 00 01 00 DE 6A."""
    payload = bytes([0xC8, 0x00, 0x01, 0x00, 0x01, 0x00])
    expected = bytes.fromhex("b562060806 00c8000100010 0de6a".replace(" ", ""))
    assert frame(0x06, 0x08, payload) == expected
    out = ubx.ffi.new("uint8_t[32]")
    n = ubx.lib.ubx_encode(0x06, 0x08, payload, len(payload), out, 32)
    assert bytes(out[0:n]) == expected
    assert ubx.lib.ubx_encode(0x06, 0x08, payload, len(payload), out, 13) == 0  # one byte short: nothing
    assert ubx.lib.ubx_checksum(expected[2:-2], len(expected) - 4) == 0x6ADE


def test_nav_pvt_frames_among_nmea_noise_and_damage_in_any_chunking(ubx):
    rng = random.Random(8)
    parser = ubx.ffi.new("ubx_parser_t *")
    ubx.lib.ubx_parser_init(parser)
    stream, expected, damaged = b"", [], 0
    for k in range(300):
        values = random_pvt(rng)
        wire = frame(0x01, 0x07, NAV_PVT.pack(*values.values()))
        kind = rng.random()
        if kind < 0.1:  # a flipped bit in the payload or checksum: counted, skipped
            position = rng.randrange(6, len(wire))
            wire = wire[:position] + bytes([wire[position] ^ (1 << rng.randrange(8))]) + wire[position + 1:]
            damaged += 1
        else:
            expected.append(values)
        stream += wire
        if rng.random() < 0.3:
            stream += b"$GNGGA,123519.00,4807.03,N,01131.00,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
        if rng.random() < 0.2:
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 20))).replace(b"\xb5", b"\x00")
    got = feed(ubx, parser, stream)
    assert [(c, i) for c, i, _ in got] == [(0x01, 0x07)] * len(expected)
    assert parser.frames == len(expected) and parser.checksum_errors == damaged
    pvt = ubx.ffi.new("ubx_nav_pvt_t *")
    for (_, _, payload), values in zip(got, expected):
        assert ubx.lib.ubx_nav_pvt(payload, len(payload), pvt) == 1
        assert (pvt.itow_ms, pvt.fix_type, pvt.num_sv, pvt.lon_1e7deg, pvt.lat_1e7deg, pvt.height_mm,
                pvt.hmsl_mm, pvt.h_acc_mm, pvt.v_acc_mm, list(pvt.vel_ned_mm_s), pvt.s_acc_mm_s, pvt.p_dop_cent) == (
            values["itow_ms"], values["fix_type"], values["num_sv"], values["lon_1e7deg"], values["lat_1e7deg"],
            values["height_mm"], values["hmsl_mm"], values["h_acc_mm"], values["v_acc_mm"],
            [values["vel_n"], values["vel_e"], values["vel_d"]], values["s_acc_mm_s"], values["p_dop_cent"])
        assert pvt.fix_ok == values["flags"] & 1
    # the same stream in other chunkings gives the same frames (the parser keeps its state)
    parser2 = ubx.ffi.new("ubx_parser_t *")
    ubx.lib.ubx_parser_init(parser2)
    again, position = [], 0
    while position < len(stream):
        step = rng.randrange(1, 200)
        again += feed(ubx, parser2, stream[position:position + step])
        position += step
    assert again == got


def test_ack_frames_an_oversized_frame_and_a_short_payload(ubx):
    parser = ubx.ffi.new("ubx_parser_t *")
    ubx.lib.ubx_parser_init(parser)
    ack = frame(0x05, 0x01, bytes([0x06, 0x08]))
    nak = frame(0x05, 0x00, bytes([0x06, 0x01]))
    big = frame(0x02, 0x15, bytes(300))  # longer than the parser keeps: skipped
    got = feed(ubx, parser, ack + big + nak)
    assert got == [(0x05, 0x01, bytes([0x06, 0x08])), (0x05, 0x00, bytes([0x06, 0x01]))]
    assert parser.oversized == 1 and parser.checksum_errors == 0
    pvt = ubx.ffi.new("ubx_nav_pvt_t *")
    assert ubx.lib.ubx_nav_pvt(bytes(91), 91, pvt) == 0  # NAV-PVT is 92 bytes
