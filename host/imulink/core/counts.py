"""Sensor profiles and the one conversion between SI arrays and raw sensor counts.

The firmware core consumes integer register counts (what the MPU6050 and HMC5883L
deliver); the host converts SI data to counts with :func:`si_to_counts` so that a
fixed-point run and its float twin see identical inputs.

Conventions (shared by every module of imulink):

* sensor frame = body frame; the earth frame is ENU (x east, y north, z up);
* gyroscope in rad/s, accelerometer **specific force** in m/s^2 (a board lying
  flat reads +9.81 on z), magnetometer in microtesla (uT).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imulink import protocol
from imulink.errors import ImulinkError

#: Standard gravity in m/s^2 (the MPU6050 data sheet's "g").
STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class SensorProfile:
    """Full-scale settings of the sensors, as register sensitivities.

    Attributes:
        gyro_lsb_per_dps: gyroscope sensitivity, LSB per deg/s (MPU6050 FS_SEL=3: 16.4).
        acc_lsb_per_g: accelerometer sensitivity, LSB per g (MPU6050 AFS_SEL=2: 4096).
        mag_lsb_per_gauss: magnetometer gain, LSB per gauss (HMC5883L GN=1, its
            power-on default: 1090).
        gyro_limits, acc_limits, mag_limits: (min, max) count of each output register.
    """

    name: str = "gy86-default"
    gyro_lsb_per_dps: float = 16.4
    acc_lsb_per_g: float = 4096.0
    mag_lsb_per_gauss: float = 1090.0
    gyro_limits: tuple[int, int] = (-32768, 32767)
    acc_limits: tuple[int, int] = (-32768, 32767)
    mag_limits: tuple[int, int] = (-2048, 2047)

    @property
    def gyro_scale(self) -> float:
        """rad/s per LSB."""
        return np.deg2rad(1.0) / self.gyro_lsb_per_dps

    @property
    def acc_scale(self) -> float:
        """m/s^2 per LSB."""
        return STANDARD_GRAVITY / self.acc_lsb_per_g

    @property
    def mag_scale(self) -> float:
        """uT per LSB (1 gauss = 100 uT)."""
        return 100.0 / self.mag_lsb_per_gauss

    def ranges_si(self) -> dict[str, float]:
        """Largest representable magnitude of each sensor, in SI units."""
        return {
            "gyro_rad_s": self.gyro_limits[1] * self.gyro_scale,
            "acc_m_s2": self.acc_limits[1] * self.acc_scale,
            "mag_uT": self.mag_limits[1] * self.mag_scale,
        }


#: MPU6050 at +-2000 deg/s and +-8 g, HMC5883L at its default gain (+-1.3 Ga).
DEFAULT_PROFILE = SensorProfile()

#: The BROAD recordings reach 155 m/s^2 (tapping trial) and 1446 deg/s: +-16 g and
#: +-2000 deg/s keep every trial unsaturated (see docs/numerics.md).
BROAD_PROFILE = SensorProfile(name="gy86-broad", acc_lsb_per_g=2048.0)

#: The profiles imulink knows by name (the emulated boards run either).
PROFILES = {p.name: p for p in (DEFAULT_PROFILE, BROAD_PROFILE)}

#: Q formats of the firmware's sensitivities (imu_sensor_settings_t: gyroscope rad/s per LSB
#: Q40, accelerometer m/s^2 per LSB Q32, magnetometer uT per LSB Q24), which a board states in
#: HELLO: those of HELLO's fields (shared/protocol.toml).
SCALE_FRAC_BITS = tuple(protocol.frac_bits("HELLO", name) for name in ("gyro_scale", "acc_scale", "mag_scale"))


def fixed_scales(profile: SensorProfile) -> tuple[int, int, int]:
    """The profile's gyroscope, accelerometer and magnetometer sensitivities as the fixed-point
    core holds them (and HELLO carries them): rounded to SCALE_FRAC_BITS."""
    scales = (profile.gyro_scale, profile.acc_scale, profile.mag_scale)
    gyro, acc, mag = (int(np.rint(scale * 2.0**q)) for scale, q in zip(scales, SCALE_FRAC_BITS))
    return gyro, acc, mag


def profile_from_scales(gyro_scale: int, acc_scale: int, mag_scale: int) -> SensorProfile:
    """The profile of a board that states these fixed-point sensitivities (HELLO): the known
    profile with exactly these, else one named "board" with the sensitivities they give.
    ValueError unless all three are positive."""
    raw = (gyro_scale, acc_scale, mag_scale)
    if min(raw) <= 0:
        raise ValueError(f"sensitivities {raw} are not all positive")
    for profile in PROFILES.values():
        if fixed_scales(profile) == raw:
            return profile
    gyro, acc, mag = (value * 2.0**-q for value, q in zip(raw, SCALE_FRAC_BITS))
    return SensorProfile(name="board", gyro_lsb_per_dps=float(np.deg2rad(1.0) / gyro),
                         acc_lsb_per_g=STANDARD_GRAVITY / acc, mag_lsb_per_gauss=100.0 / mag)


def describe_profile(profile: SensorProfile) -> str:
    """"gy86-default (16.4 LSB per deg/s, 4096 LSB/g, 1090 LSB/gauss)": name and sensitivities."""
    return (f"{profile.name} ({profile.gyro_lsb_per_dps:.6g} LSB per deg/s, {profile.acc_lsb_per_g:.6g} LSB/g, "
            f"{profile.mag_lsb_per_gauss:.6g} LSB/gauss)")


class SensorDataError(ImulinkError, ValueError):
    """Sensor data no sensor delivers: NaN or infinite values, counts that are not
    integers or lie outside the 16-bit registers."""


def _reject(name: str, bad: np.ndarray, what: str) -> None:
    """SensorDataError if any value is `bad`, saying how many and where the first is."""
    if bad.any():
        raise SensorDataError(f"{name}: {int(bad.sum())} value(s) {what} (the first in sample "
                              f"{int(np.argwhere(bad)[0][0])})")


def _to_counts(name: str, x, scale: float, limits: tuple[int, int]) -> tuple[np.ndarray, int]:
    given = np.asarray(x)
    if given.dtype.kind not in "iuf":  # complex, bool, text, objects: a cast would drop or invent a value
        raise SensorDataError(f"{name}: values must be real numbers, not {given.dtype}")
    x = given.astype(np.float64)
    # a NaN has no count, and an infinite reading is a broken input rather than a saturated sensor
    _reject(name, ~np.isfinite(x), "are NaN or infinite")
    counts = np.rint(x / scale)
    saturated = int(np.count_nonzero((counts < limits[0]) | (counts > limits[1])))
    return np.clip(counts, limits[0], limits[1]).astype(np.int16), saturated


def si_to_counts(gyr, acc, mag, profile: SensorProfile = DEFAULT_PROFILE, return_saturation=False):
    """Convert SI sensor arrays to raw register counts.

    Args:
        gyr: (N,3) angular rate in rad/s.
        acc: (N,3) specific force in m/s^2.
        mag: (N,3) magnetic field in uT.
        profile: full-scale settings; values are rounded to the nearest count and
            clipped to each register's range, like the real sensor saturates. NaN or
            infinite values, and arrays that are not of real numbers (complex ones
            included), raise SensorDataError.
        return_saturation: also return the number of clipped values per sensor.

    Returns:
        (gyr_counts, acc_counts, mag_counts) as (N,3) int16 arrays, plus a dict
        {"gyr": n, "acc": n, "mag": n} of clipped values when requested.
    """
    g, sg = _to_counts("gyr", gyr, profile.gyro_scale, profile.gyro_limits)
    a, sa = _to_counts("acc", acc, profile.acc_scale, profile.acc_limits)
    m, sm = _to_counts("mag", mag, profile.mag_scale, profile.mag_limits)
    if return_saturation:
        return g, a, m, {"gyr": sg, "acc": sa, "mag": sm}
    return g, a, m


def check_counts(name: str, counts) -> np.ndarray:
    """`counts` as a C-contiguous int16 array; SensorDataError unless every value is an
    integer in the int16 range (a cast would wrap or truncate them silently)."""
    array = np.asarray(counts)
    if array.dtype == np.int16:
        return np.ascontiguousarray(array)
    if array.dtype.kind not in "iuf":
        raise SensorDataError(f"{name}: counts must be integers, not {array.dtype}")
    if array.dtype.kind == "f":
        _reject(name, ~np.isfinite(array), "are NaN or infinite")
        _reject(name, array != np.rint(array), "are not whole counts")
    _reject(name, (array < -32768) | (array > 32767), "lie outside the int16 range of a sensor register")
    return np.ascontiguousarray(array, dtype=np.int16)


def counts_to_si(gyr_counts, acc_counts, mag_counts, profile: SensorProfile = DEFAULT_PROFILE):
    """Inverse of :func:`si_to_counts` (without the clipping): counts to rad/s, m/s^2, uT."""
    return (
        np.asarray(gyr_counts, dtype=np.float64) * profile.gyro_scale,
        np.asarray(acc_counts, dtype=np.float64) * profile.acc_scale,
        np.asarray(mag_counts, dtype=np.float64) * profile.mag_scale,
    )


def profile_to_json(profile: SensorProfile | None) -> dict | None:
    if profile is None:
        return None
    return {"name": profile.name, "gyro_lsb_per_dps": profile.gyro_lsb_per_dps,
            "acc_lsb_per_g": profile.acc_lsb_per_g, "mag_lsb_per_gauss": profile.mag_lsb_per_gauss}


def profile_from_json(data: dict) -> SensorProfile:
    """The profile a header names; ValueError unless its sensitivities are positive numbers."""
    sensitivities = {key: data[key] for key in ("gyro_lsb_per_dps", "acc_lsb_per_g", "mag_lsb_per_gauss")}
    for key, value in sensitivities.items():
        if type(value) not in (int, float) or not 0 < value < math.inf:
            raise ValueError(f"{key} is {value!r}, not a positive number")
    if not isinstance(data["name"], str):
        raise ValueError(f"name is {data['name']!r}, not a string")
    return SensorProfile(name=data["name"], **sensitivities)
