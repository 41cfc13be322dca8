"""The Python API of the C core (imulink.core): shapes, errors, settings and conversions.

Nothing here depends on the values of the default settings (they are being tuned):
overrides are derived from whatever the defaults are.
"""
from __future__ import annotations

import numpy as np
import pytest

from imulink import core, sim
from imulink.core import _fixed as _core_fixed
from imulink.core.counts import BROAD_PROFILE, DEFAULT_PROFILE, SensorDataError

RATE = 100.0
FILTER_NAMES = sorted(core.FILTERS)
ARITHS = list(core.ARITHMETICS)


@pytest.fixture(scope="module")
def data():
    """4 s of random motion (the SI arrays are exactly counts * scale)."""
    return sim.simulate(sim.random_motion(4.0, RATE, seed=3), sim.SensorSuite.default(), seed=3)


def _run(data, filter_name="eecf", arithmetic="fixed", **kw):
    return core.run(filter_name, data.gyr, data.acc, data.mag, RATE, arithmetic, **kw)


# --------------------------------------------------------------------------- results


@pytest.mark.parametrize("arithmetic", ARITHS)
@pytest.mark.parametrize("filter_name", FILTER_NAMES)
def test_run_returns_arrays_per_sample(data, filter_name, arithmetic):
    n = len(data.t)
    r = _run(data, filter_name, arithmetic)
    assert (r.filter_name, r.arithmetic) == (filter_name, arithmetic)
    assert r.quat.shape == (n, 4) and r.euler.shape == (n, 3) and r.gyro_bias.shape == (n, 3)
    for a in (r.quat, r.euler, r.gyro_bias):
        assert a.dtype == np.float64 and np.all(np.isfinite(a))
    np.testing.assert_allclose(np.linalg.norm(r.quat, axis=1), 1.0, atol=1e-6)
    assert np.all(np.abs(r.euler) <= np.pi + 1e-8)
    assert isinstance(r.saturations, int) and r.saturations >= 0
    assert r.settings["sample_rate"] == RATE
    if arithmetic == "fixed":
        assert set(r.raw) == {"quat", "euler", "gyro_bias"}
        assert all(v.dtype == np.int32 for v in r.raw.values())
        np.testing.assert_array_equal(r.quat, r.raw["quat"] / 2.0**core.QUAT_FRAC_BITS)
        np.testing.assert_array_equal(r.euler, r.raw["euler"] / 2.0**core.EULER_FRAC_BITS)
        np.testing.assert_array_equal(r.gyro_bias, r.raw["gyro_bias"] / 2.0**core.RATE_FRAC_BITS)
    else:
        assert r.raw is None


@pytest.mark.parametrize("arithmetic", ARITHS)
@pytest.mark.parametrize("filter_name", FILTER_NAMES)
def test_run_on_counts_equals_run_on_si(data, filter_name, arithmetic):
    a = core.run(filter_name, data.gyr, data.acc, data.mag, RATE, arithmetic)
    b = core.run_counts(filter_name, data.gyr_counts, data.acc_counts, data.mag_counts, RATE, arithmetic)
    for name in ("quat", "euler", "gyro_bias"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.saturations == b.saturations


def test_run_on_si_uses_the_profile(data):
    """The same counts through another profile are different SI values: run() converts with it."""
    g, a, m = data.gyr_counts, data.acc_counts, data.mag_counts
    si = [c * s for c, s in zip((g, a, m), (BROAD_PROFILE.gyro_scale, BROAD_PROFILE.acc_scale,
                                            BROAD_PROFILE.mag_scale))]
    r_si = core.run("kf1d", *si, RATE, profile=BROAD_PROFILE)
    r_counts = core.run_counts("kf1d", g, a, m, RATE, profile=BROAD_PROFILE)
    np.testing.assert_array_equal(r_si.raw["quat"], r_counts.raw["quat"])
    r_default = core.run_counts("kf1d", g, a, m, RATE, profile=DEFAULT_PROFILE)
    assert not np.array_equal(r_default.raw["quat"], r_counts.raw["quat"])


@pytest.mark.parametrize("arithmetic", ARITHS)
def test_batches_continue_the_same_filter(data, arithmetic):
    whole = core.run_counts("eecf", data.gyr_counts, data.acc_counts, data.mag_counts, RATE, arithmetic)
    f = core.Filter("eecf", RATE, arithmetic)
    k = 123
    first = f.run_counts(data.gyr_counts[:k], data.acc_counts[:k], data.mag_counts[:k])
    rest = f.run_counts(data.gyr_counts[k:], data.acc_counts[k:], data.mag_counts[k:])
    np.testing.assert_array_equal(np.concatenate([first.quat, rest.quat]), whole.quat)
    np.testing.assert_array_equal(np.concatenate([first.gyro_bias, rest.gyro_bias]), whole.gyro_bias)


# --------------------------------------------------------------------------- errors


def test_unknown_filter(data):
    with pytest.raises(ValueError, match=r"unknown filter 'madgwick'.*eecf"):
        _run(data, "madgwick")
    with pytest.raises(ValueError, match="unknown filter 'nope'"):
        core.settings_fields("nope")
    with pytest.raises(ValueError, match="unknown filter"):
        core.default_settings("nope")


def test_unknown_setting(data):
    with pytest.raises(core.SettingsError, match=r"unknown setting 'kpp' for filter 'eecf'.*kp"):
        _run(data, "eecf", settings={"kpp": 1.0})
    with pytest.raises(core.SettingsError, match="unknown setting 'kp' for filter 'kf1d'"):
        _run(data, "kf1d", settings={"kp": 1.0})


@pytest.mark.parametrize("filter_name,name,value", [
    ("eecf", "kp", 150.0),          # documented range [0, 100]
    ("eecf", "ki", -0.1),           # [0, 1]
    ("eecf", "align_time", 61.0),   # [0, 60]
    ("kf1d", "r_angle", 0.05),      # [1e-6, 0.03]
    ("kf1d", "q_angle", 1.5e-3),    # [0, 1e-3] (still fits Q40)
])
def test_out_of_range_setting(data, filter_name, name, value):
    with pytest.raises(core.SettingsError, match=f"out of range for '{filter_name}'") as info:
        _run(data, filter_name, settings={name: value})
    assert f"{name}={value!r}" in str(info.value)  # the message names the offending setting and value


def test_setting_that_does_not_fit_its_q_format(data):
    with pytest.raises(core.SettingsError, match=r"kp=1000000\.0 does not fit the fixed-point format Q16"):
        _run(data, "eecf", settings={"kp": 1e6})
    # The float twin has no Q format but still checks the range.
    with pytest.raises(core.SettingsError, match="out of range"):
        _run(data, "eecf", "float", settings={"kp": 1e6})


def test_sample_rate_checks(data):
    with pytest.raises(core.SettingsError, match="sample_rate in settings contradicts rate_hz"):
        _run(data, "eecf", settings={"sample_rate": 50.0})
    with pytest.raises(core.SettingsError, match="out of range"):
        core.run("kf1d", data.gyr, data.acc, data.mag, 0.25)


def test_bad_arithmetic(data):
    with pytest.raises(ValueError, match=r"arithmetic must be one of \('fixed', 'float'\), not 'double'"):
        _run(data, "eecf", "double")


@pytest.mark.parametrize("shapes", [
    ((50, 3), (49, 3), (50, 3)),
    ((50, 3), (50, 3), (50, 4)),
    ((50,), (50,), (50,)),
    ((50, 3, 1), (50, 3, 1), (50, 3, 1)),
])
def test_mismatched_shapes(shapes):
    arrays = [np.zeros(s, dtype=np.int16) for s in shapes]
    with pytest.raises(ValueError, match=r"sensor arrays must all be \(N,3\)"):
        core.run_counts("eecf", *arrays, RATE)


@pytest.mark.parametrize("arithmetic", ARITHS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_or_infinite_si_input_is_refused(data, arithmetic, bad):
    """NaN has no sensor count and an infinite reading is a broken input: neither may
    become an arbitrary count (an all-NaN input would give an identity quaternion)."""
    acc = data.acc.copy()
    acc[17, 1] = bad
    with pytest.raises(SensorDataError, match=r"acc: 1 value\(s\) are NaN or infinite \(the first in sample 17\)"):
        core.run("eecf", data.gyr, acc, data.mag, RATE, arithmetic)
    with pytest.raises(SensorDataError, match="gyr: 150 value"):
        core.run("eecf", np.full((50, 3), np.nan), data.acc[:50], data.mag[:50], RATE, arithmetic)


@pytest.mark.parametrize("arithmetic", ARITHS)
def test_si_input_that_is_not_real_numbers_is_refused(data, arithmetic):
    """A complex array would lose its imaginary parts in the cast to float (with no more than
    a NumPy warning); booleans and text are not readings either: all refused, like NaN."""
    for gyr, kind in ((data.gyr.astype(complex), "complex128"), (data.gyr + 1e-3j, "complex128"),
                      (data.gyr > 0, "bool"), (data.gyr.astype(str), "<U")):
        with pytest.raises(SensorDataError, match=f"gyr: values must be real numbers, not {kind}"):
            core.run("eecf", gyr, data.acc, data.mag, RATE, arithmetic)
    with pytest.raises(SensorDataError, match="mag: values must be real numbers, not complex"):
        core.si_to_counts(data.gyr, data.acc, data.mag.astype(np.complex64))


@pytest.mark.parametrize("values, message", [
    (np.full((50, 3), 32768), r"gyr: 150 value\(s\) lie outside the int16 range"),
    (np.full((50, 3), -40000.0), r"gyr: 150 value\(s\) lie outside the int16 range"),
    (np.full((50, 3), 1.5), r"gyr: 150 value\(s\) are not whole counts"),
    (np.full((50, 3), np.nan), r"gyr: 150 value\(s\) are NaN or infinite"),
    (np.full((50, 3), "1"), "counts must be integers"),
])
def test_counts_that_a_register_cannot_hold_are_refused(values, message):
    """Counts beyond int16 must not wrap, nor fractions be cut, silently."""
    zeros = np.zeros((50, 3), np.int16)
    with pytest.raises(SensorDataError, match=message):
        core.run_counts("eecf", values, zeros, zeros, RATE)


def test_counts_of_any_integer_type_or_whole_floats_are_accepted(data):
    expected = core.run_counts("eecf", data.gyr_counts, data.acc_counts, data.mag_counts, RATE).raw["quat"]
    got = core.run_counts("eecf", data.gyr_counts.astype(np.int64), data.acc_counts.astype(np.float64),
                          data.mag_counts.tolist(), RATE).raw["quat"]
    np.testing.assert_array_equal(got, expected)


# --------------------------------------------------------------------------- settings


def _changed(filter_name: str, name: str) -> float:
    """A value of `name` different from its default and inside the documented range."""
    default = core.default_settings(filter_name)[name]
    alternatives = {"kp": (0.3, 5.0), "r_angle": (0.002, 0.02)}[name]
    return next(v for v in alternatives if abs(v - default) > 0.25 * max(default, 1e-12))


@pytest.mark.parametrize("arithmetic", ARITHS)
@pytest.mark.parametrize("filter_name,name", [("eecf", "kp"), ("kf1d", "r_angle")])
def test_settings_override_changes_output(data, filter_name, name, arithmetic):
    base = _run(data, filter_name, arithmetic)
    value = _changed(filter_name, name)
    other = _run(data, filter_name, arithmetic, settings={name: value})
    assert other.settings[name] == value and base.settings[name] == core.default_settings(filter_name)[name]
    assert np.abs(other.quat - base.quat).max() > 1e-6
    # Passing the default explicitly is the same as not passing it.
    same = _run(data, filter_name, arithmetic, settings={name: core.default_settings(filter_name)[name]})
    np.testing.assert_array_equal(same.quat, base.quat)


@pytest.mark.parametrize("filter_name", FILTER_NAMES)
def test_settings_fields_agree_between_builds(filter_name):
    fixed = core.settings_fields(filter_name, "fixed")
    flt = core.settings_fields(filter_name, "float")
    assert [(f.name, f.unit, f.frac_bits) for f in fixed] == [(f.name, f.unit, f.frac_bits) for f in flt]
    assert fixed[0].name == "sample_rate"
    assert [f.offset for f in fixed] == [4 * i for i in range(len(fixed))]
    assert [f.offset for f in flt] == [8 * i for i in range(len(flt))]
    assert all(0 <= f.frac_bits <= 62 and f.unit for f in fixed)


@pytest.mark.parametrize("filter_name", FILTER_NAMES)
def test_setting_ranges_are_what_the_filters_accept(filter_name):
    """Each descriptor's [minimum, maximum] (what SETTING reports to the host) is the range
    set_settings enforces in both builds: its ends are accepted, one step of the Q format
    beyond either end is refused (or does not fit the format at all)."""
    defaults = core.default_settings(filter_name)
    for arithmetic in ARITHS:
        for f in core.settings_fields(filter_name, arithmetic):
            if arithmetic == "float":  # the defaults as the exact reals (the fixed build rounds both)
                assert f.minimum <= defaults[f.name] <= f.maximum, f.name
            step = 2.0 ** -f.frac_bits
            for value, accepted in ((f.minimum, True), (f.maximum, True), (f.minimum - step, False),
                                    (f.maximum + step, False)):
                # the sample rate is a setting of its own and the rate the filter runs at
                rate, settings = (value, {}) if f.name == "sample_rate" else (100.0, {f.name: value})
                if accepted:
                    core.Filter(filter_name, rate, arithmetic, settings)
                else:
                    with pytest.raises(core.SettingsError):
                        core.Filter(filter_name, rate, arithmetic, settings)


@pytest.mark.parametrize("filter_name", FILTER_NAMES)
def test_default_settings_round_trip_through_fixed(filter_name):
    """The float defaults, converted with to_fixed, are the fixed build's default struct, and the
    raw integers converted back to SI convert to the same integers again."""
    _, prefix = core.FILTERS[filter_name]
    ffi, lib = _core_fixed.ffi, _core_fixed.lib
    base = ffi.cast("char *", ffi.addressof(getattr(lib, f"{prefix}_default_settings")))
    defaults = core.default_settings(filter_name)
    fields = core.settings_fields(filter_name, "fixed")
    assert set(defaults) == {f.name for f in fields}
    for f in fields:
        raw_c = ffi.cast("int32_t *", base + f.offset)[0]
        raw = core.to_fixed(defaults[f.name], f.frac_bits, f.name)
        assert raw == raw_c, f"{f.name}: to_fixed gives {raw}, the fixed build's default is {raw_c}"
        assert core.to_fixed(raw / 2.0**f.frac_bits, f.frac_bits) == raw
        assert abs(raw / 2.0**f.frac_bits - defaults[f.name]) <= 2.0 ** -(f.frac_bits + 1)
    # The defaults are accepted by both builds.
    for arithmetic in ARITHS:
        core.Filter(filter_name, defaults["sample_rate"], arithmetic)


def test_to_fixed():
    assert core.to_fixed(1.0, 16) == 65536
    assert core.to_fixed(-0.5, 30) == -(2**29)
    assert core.to_fixed(1.5 / 2**16, 16) == 2  # round half to even
    assert core.to_fixed(2.0**15 - 2.0**-16, 16) == 2**31 - 1
    with pytest.raises(core.SettingsError, match="does not fit"):
        core.to_fixed(2.0**15, 16, "x")
    with pytest.raises(core.SettingsError, match="does not fit"):
        core.to_fixed(-(2.0**15) - 1.0, 16, "x")
