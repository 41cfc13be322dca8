"""NMEA 0183 GGA, RMC and VTG (firmware/drivers/nmea.c): the classic examples of the
sentences, random sentences against an exact reference conversion, and damage."""
from __future__ import annotations

import random
from fractions import Fraction
from functools import reduce
from pathlib import Path

import pytest

from cffi_module import build

ROOT = Path(__file__).resolve().parents[1]
DRIVERS = ROOT / "firmware" / "drivers"

CDEF = """
    typedef struct { uint32_t sentences; uint32_t checksum_errors; uint32_t too_long; ...; } nmea_parser_t;
    void nmea_parser_init(nmea_parser_t *p);
    int nmea_parser_push(nmea_parser_t *p, uint8_t byte);
    typedef struct {
        uint32_t time_ms; int32_t lat_1e7deg; int32_t lon_1e7deg; uint8_t quality; uint8_t num_sv;
        uint16_t hdop_cent; int32_t alt_msl_mm; int32_t geoid_sep_mm;
    } nmea_gga_t;
    typedef struct {
        uint32_t time_ms; uint8_t active; int32_t lat_1e7deg; int32_t lon_1e7deg; uint32_t speed_mm_s;
        uint32_t course_1e5deg; uint32_t date_ddmmyy;
    } nmea_rmc_t;
    typedef struct { uint32_t course_1e5deg; uint32_t speed_mm_s; } nmea_vtg_t;
    int nmea_is(const nmea_parser_t *p, const char *type);
    int nmea_gga(const nmea_parser_t *p, nmea_gga_t *out);
    int nmea_rmc(const nmea_parser_t *p, nmea_rmc_t *out);
    int nmea_vtg(const nmea_parser_t *p, nmea_vtg_t *out);
"""


@pytest.fixture(scope="module")
def nmea(tmp_path_factory):
    return build("_imulink_nmea", CDEF, '#include "nmea.h"\n', [DRIVERS / "nmea.c"], [DRIVERS],
                 tmp_path_factory.mktemp("nmea"))


def sentence(body: str) -> bytes:
    return f"${body}*{reduce(lambda a, c: a ^ ord(c), body, 0):02X}\r\n".encode()


def parse(nmea, data: bytes):
    """(parser, [decoded sentence results]) for every valid sentence in `data`."""
    p = nmea.ffi.new("nmea_parser_t *")
    nmea.lib.nmea_parser_init(p)
    out = []
    for byte in data:
        if nmea.lib.nmea_parser_push(p, byte):
            for kind, ctype, decode in (("GGA", "nmea_gga_t *", nmea.lib.nmea_gga),
                                        ("RMC", "nmea_rmc_t *", nmea.lib.nmea_rmc),
                                        ("VTG", "nmea_vtg_t *", nmea.lib.nmea_vtg)):
                if nmea.lib.nmea_is(p, kind.encode()):
                    value = nmea.ffi.new(ctype)
                    out.append((kind, value if decode(p, value) else None))
    return p, out


def angle_1e7(text: str, hemisphere: str) -> int:
    """The exact conversion of (d)ddmm.mmmmm: degrees + minutes / 60, in 1e-7 deg, rounded half up."""
    whole, _, frac = text.partition(".")
    deg, minutes = int(whole[:-2]), Fraction(whole[-2:] + "." + (frac or "0"))
    value = deg * 10**7 + int(minutes * 10**7 / 60 + Fraction(1, 2))
    return -value if hemisphere in "SW" else value


def test_the_classic_examples(nmea):
    """GGA and RMC as NMEA 0183 references print them (their checksums *47 and *6A)."""
    gga = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
    rmc = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n"
    vtg = sentence("GPVTG,054.7,T,034.4,M,005.5,N,010.2,K")
    p, out = parse(nmea, gga + rmc + vtg)
    assert [k for k, _ in out] == ["GGA", "RMC", "VTG"] and p.sentences == 3 and p.checksum_errors == 0
    g, r, v = (value for _, value in out)
    assert (g.time_ms, g.lat_1e7deg, g.lon_1e7deg, g.quality, g.num_sv, g.hdop_cent, g.alt_msl_mm,
            g.geoid_sep_mm) == (45319000, 481173000, 115166667, 1, 8, 90, 545400, 46900)
    assert (r.time_ms, r.active, r.lat_1e7deg, r.lon_1e7deg, r.speed_mm_s, r.course_1e5deg, r.date_ddmmyy) == (
        45319000, 1, 481173000, 115166667, 11524, 8440000, 230394)  # 22.4 kn = 11523.6 mm/s
    assert (v.course_1e5deg, v.speed_mm_s) == (5470000, 2833)  # 10.2 km/h = 2833.3 mm/s


def test_random_sentences_against_the_exact_conversion(nmea):
    rng = random.Random(183)
    stream, expected = b"", []
    for _ in range(400):
        lat = f"{rng.randrange(90):02d}{rng.randrange(60):02d}.{rng.randrange(10**5):05d}"
        lon = f"{rng.randrange(180):03d}{rng.randrange(60):02d}.{rng.randrange(10**5):05d}"
        ns, ew = rng.choice("NS"), rng.choice("EW")
        alt = f"{rng.uniform(-400, 9000):.1f}"
        time = f"{rng.randrange(24):02d}{rng.randrange(60):02d}{rng.randrange(60):02d}.{rng.randrange(100):02d}"
        talker = rng.choice(["GP", "GN", "GL", "GA"])
        stream += sentence(f"{talker}GGA,{time},{lat},{ns},{lon},{ew},1,{rng.randrange(40):02d},1.2,{alt},M,-3.5,M,,")
        h, m, s = int(time[:2]), int(time[2:4]), Fraction(time[4:])
        expected.append((int((h * 3600 + m * 60 + s) * 1000), angle_1e7(lat, ns), angle_1e7(lon, ew),
                         int(Fraction(alt) * 1000)))
        if rng.random() < 0.3:  # a UBX frame between sentences: skipped
            stream += bytes([0xB5, 0x62, 0x01, 0x07, 0x02, 0x00, 0x24, 0x2A, 0x8E, 0x59])
    p, out = parse(nmea, stream)
    assert len(out) == 400 and all(value is not None for _, value in out)
    assert [(g.time_ms, g.lat_1e7deg, g.lon_1e7deg, g.alt_msl_mm) for _, g in out] == expected


def test_damage_and_receivers_without_a_fix(nmea):
    good = sentence("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
    bad = bytearray(good)
    bad[10] ^= 0x01  # one bit of the time: the checksum no longer matches
    no_checksum = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,\r\n"
    too_long = sentence("GPTXT," + "x" * 90)
    no_fix = sentence("GPGGA,123520,,,,,0,00,99.99,,,,,,")
    void_rmc = sentence("GPRMC,123521,V,,,,,,,230394,,,N")
    p, out = parse(nmea, bytes(bad) + no_checksum + too_long + no_fix + void_rmc + good)
    assert p.checksum_errors == 2 and p.too_long == 1 and p.sentences == 3
    assert [(k, v is None) for k, v in out] == [("GGA", True), ("RMC", True), ("GGA", False)]
