"""The core's one rest detector (firmware/core/imu_rest.c), which the ESKF and the EECF share,
compiled on the host in both builds (fixed point and the float twin), on synthetic readings:

(a) the ESKF's configuration is the constants of imu_rest.h, and with it rest is declared
    after the settling and IMU_REST_MIN_TIME whatever the update period (the ESKF updates once
    per three-sample group, the EECF every sample);
(b) the rate test (the ESKF's, with the turn tests): an offset the filter has not estimated is
    never rest, the same offset once estimated is; a turn slower than the limit passes the
    rate test alone (its known limit), not the ESKF's configuration;
(c) the turn tests (the EECF's and the ESKF's): a 20 deg/s offset (the MPU6050's limit) is
    rest, a turn about the vertical turns the field (quiet, not at rest), a turn about a
    horizontal axis turns gravity (neither), and rest waits for the references (tau) and
    min_time;
(d) motion restarts every count, the calm count says since when the board is still, and
    the unturned flag since when the turn tests have held their references;
(e) the two builds take the same decisions on noisy readings.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cffi_module import build

CORE = Path(__file__).resolve().parents[1] / "firmware" / "core"
DEG = np.pi / 180.0
GRAVITY = np.array([0.0, 0.0, 9.81])
#: Earth field (uT) at 67 deg dip, in the frame of a board lying flat facing north.
FIELD = 50.0 * np.array([0.0, np.cos(67 * DEG), -np.sin(67 * DEG)])

TYPEDEFS = {
    "fixed": "typedef int32_t imu_q30_t; typedef int32_t imu_rate_t; typedef int32_t imu_q16_t;",
    "float": "typedef double imu_q30_t; typedef double imu_rate_t; typedef double imu_q16_t;",
}
CDEF = """
    typedef struct { imu_rate_t gyro; imu_q16_t acc; imu_rate_t rate; imu_q30_t turn; imu_q16_t min_time;
                     imu_rate_t tau; } imu_rest_config_t;
    typedef struct { ...; } imu_rest_t;
    extern const imu_rest_config_t imu_rest_default_config;
    void imu_rest_init(imu_rest_t *r, const imu_rest_config_t *config, imu_q30_t period, uint32_t *sat);
    int imu_rest_update(imu_rest_t *r, const imu_rate_t gyr[3], const imu_rate_t bias[3], const imu_q16_t acc[3],
                        const imu_q16_t mag[3], uint32_t *sat);
    int imu_rest_quiet(const imu_rest_t *r);
    int32_t imu_rest_calm(const imu_rest_t *r);
    int imu_rest_unturned(const imu_rest_t *r);
    imu_q16_t imu_rest_gravity(const imu_rest_t *r);
"""
#: Q formats of the config fields (fixed build).
CONFIG_Q = {"gyro": 24, "acc": 16, "rate": 24, "turn": 30, "min_time": 16, "tau": 24}
#: The EECF's defaults (imu_eecf.c) and the ESKF's (imu_rest.h), SI; the ESKF's turn is
#: 0.5 deg as IMU_REST_TURN writes it.
EECF = {"gyro": 3.0 * DEG, "acc": 0.5, "rate": 0.0, "turn": 0.5 * DEG, "min_time": 1.5, "tau": 0.5}
ESKF = {"gyro": 2.0 * DEG, "acc": 0.5, "rate": 2.0 * DEG, "turn": 0.008727, "min_time": 1.5, "tau": 0.5}
#: The rate test alone.
RATE_ONLY = {**ESKF, "turn": 0.0}


@pytest.fixture(scope="module", params=["fixed", "float"])
def lib(request, tmp_path_factory):
    arithmetic = request.param
    module = build(f"_imulink_rest_{arithmetic}", TYPEDEFS[arithmetic] + CDEF, '#include "imu_rest.h"\n',
                   [CORE / "imu_rest.c", CORE / "imu_math.c"], [CORE], tmp_path_factory.mktemp("rest"),
                   define_macros=[("IMU_FIXED" if arithmetic == "fixed" else "IMU_FLOAT", "1")])
    return arithmetic, module


class Detector:
    """imu_rest in one build, fed SI values."""

    def __init__(self, lib, config: dict, period: float):
        self.arithmetic, module = lib
        self.ffi, self.lib = module.ffi, module.lib
        self.fixed = self.arithmetic == "fixed"
        self.sat = self.ffi.new("uint32_t *")
        self.state = self.ffi.new("imu_rest_t *")
        c = self.ffi.new("imu_rest_config_t *")
        for name, value in config.items():
            setattr(c, name, self.q(value, CONFIG_Q[name]))
        self.lib.imu_rest_init(self.state, c, self.q(period, 30), self.sat)

    def q(self, value: float, frac_bits: int):
        return int(round(value * 2**frac_bits)) if self.fixed else float(value)

    def vec(self, v, frac_bits: int):
        return self.ffi.new("imu_rate_t[3]" if frac_bits == 24 else "imu_q16_t[3]", [self.q(x, frac_bits) for x in v])

    def update(self, gyr, acc=GRAVITY, mag=FIELD, bias=None) -> int:
        b = self.vec(bias, 24) if bias is not None else self.ffi.NULL
        return self.lib.imu_rest_update(self.state, self.vec(gyr, 24), b, self.vec(acc, 16), self.vec(mag, 16),
                                        self.sat)

    def run(self, gyr, acc=None, mag=None, bias=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Decisions (at rest, quiet, calm) per update over rows of readings."""
        n = len(gyr)
        acc = np.tile(GRAVITY, (n, 1)) if acc is None else acc
        mag = np.tile(FIELD, (n, 1)) if mag is None else mag
        rest, quiet, calm = (np.zeros(n, dtype=int) for _ in range(3))
        for i in range(n):
            rest[i] = self.update(gyr[i], acc[i], mag[i], bias)
            quiet[i] = self.lib.imu_rest_quiet(self.state)
            calm[i] = self.lib.imu_rest_calm(self.state)
        assert self.sat[0] == 0
        return rest, quiet, calm


def first(flags: np.ndarray) -> int:
    """Index of the first set flag (-1: none)."""
    hits = np.nonzero(flags)[0]
    return int(hits[0]) if len(hits) else -1


def turning(rate_dps: float, axis: int, n: int, period: float, offset=(0.0, 0.0, 0.0)):
    """Readings of a board turning at a constant rate about a sensor axis (flat: z is the
    vertical, x a horizontal axis), with a gyro offset (rad/s)."""
    w = rate_dps * DEG
    angle = w * period * np.arange(n)
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]

    def turned(v):
        # v seen from the sensor frame after turning by +angle about `axis`: rotated by -angle.
        out = np.tile(v, (n, 1)).astype(float)
        out[:, i] = c * v[i] + s * v[j]
        out[:, j] = -s * v[i] + c * v[j]
        return out

    gyr = np.tile(np.asarray(offset, dtype=float), (n, 1))
    gyr[:, axis] += w
    return gyr, turned(GRAVITY), turned(FIELD)


# --------------------------------------------------------------------------- (a) the ESKF's configuration


def test_default_configuration_is_the_eskfs_constants(lib):
    d = Detector(lib, ESKF, 0.03)
    c = d.lib.imu_rest_default_config
    for name, value in ESKF.items():
        assert getattr(c, name) == pytest.approx(d.q(value, CONFIG_Q[name]), rel=1e-8), name


@pytest.mark.parametrize("period", [0.01, 0.03, 0.0002])
def test_rest_after_min_time_at_any_period(lib, period):
    """Per sample (EECF, 100 Hz; 5 kHz) or per three-sample group (ESKF, 100 Hz): rest after
    min_time / period steady updates with the rate test alone; with the turn tests after the
    settling (tau / period) and min_time more."""
    n = int(round(4.0 / period))
    gyr = np.zeros((n, 3))
    rest, _, _ = Detector(lib, RATE_ONLY, period).run(gyr, bias=(0.0, 0.0, 0.0))
    assert first(rest) == round(1.5 / period) - 1 and rest[first(rest):].all()
    for config in (EECF, ESKF):
        rest, _, _ = Detector(lib, config, period).run(gyr, bias=(0.0, 0.0, 0.0))
        assert first(rest) == round(0.5 / period) + round(1.5 / period) and rest[first(rest):].all()


# --------------------------------------------------------------------------- (b) the rate test


def test_rate_test_rejects_an_offset_not_yet_estimated(lib):
    gyr = np.tile([10.0 * DEG, 0.0, 0.0], (300, 1))
    assert not Detector(lib, ESKF, 0.03).run(gyr, bias=(0.0, 0.0, 0.0))[0].any()
    assert Detector(lib, ESKF, 0.03).run(gyr, bias=(10.0 * DEG, 0.0, 0.0))[0][-1]


@pytest.mark.parametrize("axis", [0, 2], ids=["horizontal", "vertical"])
def test_rate_test_takes_a_slower_turn_for_rest(lib, axis):
    """Its limit: a steady turn below `rate` (after the bias estimate) passes it. The ESKF's
    turn tests see gravity or the field turn."""
    gyr, acc, mag = turning(1.0, axis, 300, 0.03)
    assert Detector(lib, RATE_ONLY, 0.03).run(gyr, acc, mag, bias=(0.0, 0.0, 0.0))[0][-1]
    assert not Detector(lib, ESKF, 0.03).run(gyr, acc, mag, bias=(0.0, 0.0, 0.0))[0].any()


# --------------------------------------------------------------------------- (c) the turn tests


def test_turn_tests_take_a_20_dps_offset_for_what_it_is(lib):
    n = 400
    gyr = np.tile([20.0 * DEG, -20.0 * DEG, 20.0 * DEG], (n, 1))
    rest, quiet, calm = Detector(lib, EECF, 0.01).run(gyr)
    assert first(rest) == 50 + 150 and rest[200:].all() and quiet[200:].all()
    assert (calm == np.arange(1, n + 1)).all()


@pytest.mark.parametrize("rate_dps", [3.0, -3.0, 1.5])
def test_a_turn_about_the_vertical_turns_the_field(lib, rate_dps):
    """Gravity stays (quiet: no linear acceleration), the field turns (never at rest), and the
    turn tests' restarts break the calm count."""
    gyr, acc, mag = turning(rate_dps, 2, 3000, 0.01)
    d = Detector(lib, EECF, 0.01)
    rest, quiet, calm = d.run(gyr, acc, mag)
    assert not rest.any()
    assert quiet[300:].all()
    assert (calm[300:] == 0).any() and calm.max() < 50 + 1 + 150  # settling, then less than min_time
    assert d.lib.imu_rest_gravity(d.state) == pytest.approx(d.q(9.81, 16), rel=1e-6)


def test_a_turn_about_a_horizontal_axis_turns_gravity(lib):
    gyr, acc, mag = turning(3.0, 0, 3000, 0.01)
    rest, quiet, _ = Detector(lib, EECF, 0.01).run(gyr, acc, mag)
    assert not rest.any() and not quiet.any()


def test_turn_tests_limit(lib):
    """Slower than turn / (min_time sin(angle between axis and field)), about 0.85 deg/s about
    the vertical at 67 deg dip, a turn passes for rest (docs/filters.md)."""
    gyr, acc, mag = turning(0.5, 2, 3000, 0.01)
    rest = Detector(lib, EECF, 0.01).run(gyr, acc, mag)[0]
    # The field turns 0.5 deg in about 2.6 s: at rest from 1.5 s after each new reference until then.
    assert 0.2 < rest.mean() < 0.6


# --------------------------------------------------------------------------- (d) motion restarts the counts


@pytest.mark.parametrize("config", [EECF, ESKF], ids=["eecf", "eskf"])
def test_a_bump_restarts_the_counts(lib, config):
    n = 600
    gyr = np.zeros((n, 3))
    gyr[300] = [0.0, 0.5, 0.0]  # one sample at 29 deg/s
    rest, quiet, calm = Detector(lib, config, 0.01).run(gyr, bias=(0.0, 0.0, 0.0))
    assert rest[299] and not rest[300] and quiet[299] and not quiet[300]
    assert calm[300] == 0 and calm[299] == 300
    # The counts start again: rest no sooner than min_time after the bump.
    again = first(rest[301:]) + 301
    assert again >= 300 + int(1.5 / 0.01) and rest[again:].all()


def test_unturned_holds_from_the_references_until_a_test_fails(lib):
    """The references are taken settle + 1 updates into a steady stretch (tau / period = 50
    here); unturned holds from the next update until a bump or a turn breaks the stretch."""
    d = Detector(lib, EECF, 0.01)
    n = 600
    gyr = np.zeros((n, 3))
    gyr[300] = [0.0, 0.5, 0.0]  # one sample at 29 deg/s
    unturned = np.zeros(n, dtype=int)
    for i in range(n):
        d.update(gyr[i])
        unturned[i] = d.lib.imu_rest_unturned(d.state)
    assert first(unturned) == 51 and unturned[51:300].all() and not unturned[300]
    assert first(unturned[301:]) + 301 == 301 + 51 and unturned[352:].all()
    turn_gyr, acc, mag = turning(3.0, 2, 600, 0.01)
    for i in range(600):
        d.update(turn_gyr[i], acc[i], mag[i])
        unturned[i] = d.lib.imu_rest_unturned(d.state)
    assert not unturned.all() and unturned.any()  # each new reference of the field restarts it


# --------------------------------------------------------------------------- (e) fixed and float alike


def test_both_builds_decide_alike_on_noisy_readings(tmp_path_factory):
    """Noise that reaches the limits now and then (gyro 0.4 deg/s rms, 0.05 m/s^2, 0.3 uT) and
    bumps: the same decisions in both builds."""
    modules = {a: build(f"_imulink_rest_{a}_2", TYPEDEFS[a] + CDEF, '#include "imu_rest.h"\n',
                        [CORE / "imu_rest.c", CORE / "imu_math.c"], [CORE], tmp_path_factory.mktemp(a),
                        define_macros=[("IMU_FIXED" if a == "fixed" else "IMU_FLOAT", "1")])
               for a in ("fixed", "float")}
    rng = np.random.default_rng(7)
    n = 3000
    gyr = rng.normal(0.0, 0.4 * DEG, (n, 3)) + [5.0 * DEG, 0.0, 0.0]
    acc = GRAVITY + rng.normal(0.0, 0.05, (n, 3))
    mag = FIELD + rng.normal(0.0, 0.3, (n, 3))
    gyr[1000:1050] += [0.0, 0.3, 0.0]
    acc[2000:2020] += [1.0, 0.0, 0.0]
    for config in (EECF, ESKF):
        results = {a: Detector((a, m), config, 0.01).run(gyr, acc, mag, bias=(5.0 * DEG, 0.0, 0.0))
                   for a, m in modules.items()}
        for fixed, twin in zip(results["fixed"], results["float"]):
            assert (fixed == twin).all()
        assert 0.2 < results["fixed"][0].mean() < 0.95
