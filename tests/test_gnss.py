"""The GNSS receiver driver (firmware/drivers/gnss.c) against the u-blox receiver model
(imulink.board.chips.ublox): found at any baud, configured with ACKs, fixes delivered; an absent
receiver, damaged checksums, a receiver at another baud, a lost fix, a reboot, a receiver
that speaks NMEA only and one that refuses the rate."""
from __future__ import annotations

from pathlib import Path

import pytest

from cffi_module import build
from imulink.board.chips.ublox import UbloxReceiver

ROOT = Path(__file__).resolve().parents[1]
DRIVERS = ROOT / "firmware" / "drivers"

CDEF = """
    typedef struct { uint32_t baud; uint16_t meas_rate_ms; } gnss_config_t;
    typedef struct {
        uint32_t time_ms; uint8_t fix_type; uint8_t fix_ok; uint8_t num_sv; uint8_t has_velocity;
        int32_t lat_1e7deg; int32_t lon_1e7deg; int32_t height_mm; uint32_t h_acc_mm; uint32_t v_acc_mm;
        int32_t vel_ned_mm_s[3]; uint32_t s_acc_mm_s; uint32_t speed_mm_s; uint32_t course_1e5deg;
        uint16_t hdop_cent;
    } gnss_fix_t;
    typedef struct {
        uint32_t searches; uint32_t found; uint32_t lost; uint32_t timeouts; uint32_t naks; uint32_t fixes;
    } gnss_counters_t;
    typedef struct { uint32_t frames; uint32_t checksum_errors; ...; } ubx_parser_t;
    typedef struct { uint32_t sentences; uint32_t checksum_errors; ...; } nmea_parser_t;
    typedef struct { ubx_parser_t ubx; nmea_parser_t nmea; gnss_counters_t counters; ...; } gnss_t;
    void gnss_init(gnss_t *g, const gnss_config_t *config, uint32_t now_ms);
    int gnss_push(gnss_t *g, uint8_t byte);
    void gnss_poll(gnss_t *g, uint32_t now_ms);
    size_t gnss_take_tx(gnss_t *g, uint8_t *out, size_t cap);
    uint32_t gnss_baud(const gnss_t *g);
    int gnss_state(const gnss_t *g);
    const gnss_fix_t *gnss_fix(const gnss_t *g);
"""

SEARCHING, CONFIGURING, RUNNING_UBX, RUNNING_NMEA = range(4)
STEP_MS = 10


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    return build("_imulink_gnss", CDEF, '#include "gnss.h"\n',
                 [DRIVERS / name for name in ("gnss.c", "ubx.c", "nmea.c")], [DRIVERS],
                 tmp_path_factory.mktemp("gnss"))


class Board:
    """The board's side: its UART between the driver and the receiver, time in 10 ms steps."""

    def __init__(self, lib, receiver: UbloxReceiver, baud: int = 115200, rate_ms: int = 100):
        self.lib, self.ffi, self.receiver = lib.lib, lib.ffi, receiver
        self.g = self.ffi.new("gnss_t *")
        self.config = self.ffi.new("gnss_config_t *", {"baud": baud, "meas_rate_ms": rate_ms})
        self.now = 0
        self.lib.gnss_init(self.g, self.config, self.now)
        self.fixes: list[dict] = []
        self.tx = self.ffi.new("uint8_t[64]")
        self.states: list[int] = []

    @property
    def state(self) -> int:
        return self.lib.gnss_state(self.g)

    @property
    def counters(self):
        return self.g.counters

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds * 1000 / STEP_MS)):
            self.now += STEP_MS
            baud = self.lib.gnss_baud(self.g)
            for byte in self.receiver.advance(STEP_MS, baud):
                if self.lib.gnss_push(self.g, byte):
                    f = self.lib.gnss_fix(self.g)
                    self.fixes.append({name: getattr(f, name) for name in dir(f)} | {"at_ms": self.now})
            self.lib.gnss_poll(self.g, self.now)
            n = self.lib.gnss_take_tx(self.g, self.tx, 64)
            if n:
                self.receiver.receive(bytes(self.ffi.buffer(self.tx, n)), self.lib.gnss_baud(self.g))
            if not self.states or self.states[-1] != self.state:
                self.states.append(self.state)


def test_a_receiver_out_of_the_box_is_found_configured_and_delivers_nav_pvt_at_10_hz(lib):
    receiver = UbloxReceiver()
    board = Board(lib, receiver)
    board.run(8.0)
    assert board.states == [SEARCHING, CONFIGURING, RUNNING_UBX]
    assert receiver.baud == 115200 and receiver.nav_pvt_on and receiver.period_ms == 100
    assert (0x06, 0x01) in receiver.acked and (0x06, 0x08) in receiver.acked
    assert board.counters.found == 1 and board.counters.timeouts == 0 and board.counters.naks == 0
    fixes = board.fixes
    # the first 115200 listen (1.5 s) finds nothing, 9600 finds NMEA; then 10 fixes a second
    assert len(fixes) >= 10 * 5
    assert all(f["has_velocity"] for f in fixes)
    intervals = {b["time_ms"] - a["time_ms"] for a, b in zip(fixes, fixes[1:])}
    assert intervals == {100}
    f = fixes[-1]
    assert (f["lat_1e7deg"], f["lon_1e7deg"], f["height_mm"]) == (round(47.3769e7), round(8.5417e7), 450_000)
    assert (f["fix_type"], f["fix_ok"], f["num_sv"], f["h_acc_mm"], f["v_acc_mm"]) == (3, 1, 9, 2500, 5000)


def test_a_receiver_already_configured_is_found_at_once(lib):
    receiver = UbloxReceiver(baud=115200)
    board = Board(lib, receiver)
    board.run(3.0)
    assert board.counters.searches == 1 and board.state == RUNNING_UBX
    assert len(board.fixes) >= 15  # its first NMEA sentence comes at 1 s, NAV-PVT at 10 Hz from about 1.2 s


def test_a_receiver_at_an_unusual_baud_is_found_on_its_candidate(lib):
    receiver = UbloxReceiver(baud=38400)
    board = Board(lib, receiver)
    board.run(10.0)
    assert board.state == RUNNING_UBX and receiver.baud == 115200
    assert board.counters.searches == 3  # 115200, 9600, then 38400
    assert len(board.fixes) > 30


def test_an_absent_receiver_is_searched_for_at_every_baud_and_gives_no_fix(lib):
    board = Board(lib, UbloxReceiver(present=False))
    board.run(30.0)
    assert board.states == [SEARCHING] and board.fixes == []
    assert board.counters.found == 0 and board.counters.searches == 1 + 20  # then one every 1.5 s, 8 bauds in turn


def test_damaged_frames_are_counted_and_the_others_delivered(lib):
    receiver = UbloxReceiver(damage=0.2, seed=3)
    board = Board(lib, receiver)
    board.run(20.0)
    assert board.state == RUNNING_UBX
    assert board.g.ubx.checksum_errors > 0
    delivered = [f for f in board.fixes if f["has_velocity"]]
    assert 0.6 * 10 * 14 < len(delivered) < 10 * 18  # about 80 % of the NAV-PVT epochs after start-up


def test_a_lost_fix_is_delivered_as_such_and_a_regained_one_after_it(lib):
    receiver = UbloxReceiver(baud=115200)
    board = Board(lib, receiver)
    board.run(3.0)
    receiver.set_fix(fix_type=0)
    board.run(1.0)
    receiver.set_fix(fix_type=3)
    board.run(1.0)
    kinds = [(f["fix_type"], f["fix_ok"]) for f in board.fixes]
    lost = kinds.index((0, 0))
    assert all(k == (3, 1) for k in kinds[:lost])
    assert (3, 1) in kinds[lost:] and board.state == RUNNING_UBX


def test_a_receiver_that_reboots_is_found_and_configured_again(lib):
    receiver = UbloxReceiver()
    board = Board(lib, receiver)
    board.run(8.0)
    before = len(board.fixes)
    receiver.reboot()  # back at 9600 with NMEA only
    board.run(12.0)
    assert board.counters.lost == 1 and board.counters.found == 2
    assert board.state == RUNNING_UBX and receiver.baud == 115200 and receiver.nav_pvt_on
    last_second = [f for f in board.fixes[before:] if f["at_ms"] > board.now - 1000]
    assert len(last_second) >= 9


def test_an_nmea_only_receiver_runs_on_gga_and_rmc(lib):
    receiver = UbloxReceiver(ubx=False)
    receiver.set_fix(vel_ned_m_s=(3.0, 4.0, 0.0))
    board = Board(lib, receiver)
    board.run(16.0)
    assert board.state == RUNNING_NMEA and board.lib.gnss_baud(board.g) == 9600
    assert board.counters.timeouts == 2 * 3  # CFG-MSG three times at 115200, three times at 9600
    fixes = board.fixes
    assert len(fixes) >= 5 and not any(f["has_velocity"] for f in fixes)
    f = fixes[-1]
    assert (f["lat_1e7deg"], f["lon_1e7deg"]) == (round(47.3769e7), round(8.5417e7))
    assert f["height_mm"] == 450_000 and f["speed_mm_s"] == 5000 and f["fix_ok"] == 1
    assert abs(f["course_1e5deg"] - 5_313_010) <= 1_000  # atan2(4, 3) = 53.1301 deg, sent with two decimals


def test_a_rate_the_receiver_cannot_do_is_refused_and_its_own_kept(lib):
    receiver = UbloxReceiver(min_period_ms=200)
    board = Board(lib, receiver, rate_ms=100)
    board.run(8.0)
    assert board.counters.naks == 1 and (0x06, 0x08) in receiver.naked
    assert board.state == RUNNING_UBX
    intervals = {b["time_ms"] - a["time_ms"] for a, b in zip(board.fixes, board.fixes[1:])}
    assert intervals == {1000}  # NAV-PVT on, at the receiver's default period
