"""The board's calibration format: one correction per sensor, in counts,

    corrected = matrix @ (counts - offset)

as the firmware applies it to the raw counts before the filter (firmware/core/imu_sensor.h,
imu_sample_calibrate), and the integers the board takes (:func:`to_fixed`: offsets in Q8
counts, matrices in Q24). Fitting one is :mod:`imulink.analysis.calibration`; its file is
:mod:`imulink.io.calibration_file`; :func:`calibration_from_frames` reads it from a board's
CALIBRATION frames.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imulink import protocol
from imulink.core.counts import SensorProfile
from imulink.errors import ImulinkError

SENSORS = ("gyr", "acc", "mag")
SENSOR_NAMES = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer"}
#: Fixed-point formats of the board's calibration (imu_sensor.h): offsets in counts with
#: 8 fraction bits, matrices with 24 (range +-128, resolution 6e-8), as SET_CALIBRATION carries them.
OFFSET_FRAC_BITS = protocol.arg_frac_bits("SET_CALIBRATION", "offset")
MATRIX_FRAC_BITS = protocol.arg_frac_bits("SET_CALIBRATION", "row")
#: Largest offset the board accepts, counts: it keeps the corrected sums within int64
#: (imu_sensor.h) and is twice the range of a 16-bit register.
MAX_OFFSET_COUNTS = 65536.0
#: Largest matrix element the Q24 format holds.
MAX_MATRIX = 128.0 - 2.0**-MATRIX_FRAC_BITS


class CalibrationError(ImulinkError):
    """Data that cannot give the calibration asked for (no rest, a missing position, too
    few directions, ...), or a calibration file that cannot be used."""


@dataclass
class SensorCalibration:
    """One sensor's correction, in counts: corrected = matrix @ (counts - offset).

    report: what the calibration was made from and how good it is (JSON-ready)."""

    sensor: str
    offset: np.ndarray  # (3,) counts
    matrix: np.ndarray  # (3,3), dimensionless
    report: dict = field(default_factory=dict)

    def apply(self, counts) -> np.ndarray:
        """Corrected counts (float) of (N,3) counts."""
        return (np.asarray(counts, np.float64) - self.offset) @ self.matrix.T

    @classmethod
    def identity(cls, sensor: str) -> "SensorCalibration":
        return cls(sensor, np.zeros(3), np.eye(3))


FORMAT = "imulink-calibration"
FORMAT_VERSION = 1


@dataclass
class Calibration:
    """A calibration file: the profile its counts belong to and a correction per sensor
    calibrated (the others: identity)."""

    profile: SensorProfile
    sensors: dict[str, SensorCalibration] = field(default_factory=dict)

    def sensor(self, name: str) -> SensorCalibration:
        return self.sensors.get(name) or SensorCalibration.identity(name)


def to_fixed(calibration: SensorCalibration) -> tuple[list[int], list[int]]:
    """The board's integers: offsets in Q8 counts (3), the matrix in Q24, row by row (9).
    CalibrationError when a value lies beyond what the board accepts."""
    if not np.all(np.abs(calibration.offset) <= MAX_OFFSET_COUNTS):
        raise CalibrationError(f"{SENSOR_NAMES[calibration.sensor]} offset {calibration.offset.tolist()} counts lies "
                               f"beyond +-{MAX_OFFSET_COUNTS:g} counts")
    if not np.all(np.abs(calibration.matrix) <= MAX_MATRIX):
        raise CalibrationError(f"{SENSOR_NAMES[calibration.sensor]} matrix has an element beyond +-128")
    offset = [int(v) for v in np.rint(calibration.offset * 2.0**OFFSET_FRAC_BITS)]
    matrix = [int(v) for v in np.rint(calibration.matrix.ravel() * 2.0**MATRIX_FRAC_BITS)]
    return offset, matrix


def from_fixed(sensor: str, offset: list[int], matrix: list[int]) -> SensorCalibration:
    """The real values of the board's integers (as :func:`to_fixed` gives them)."""
    return SensorCalibration(sensor, np.asarray(offset, np.float64) / 2.0**OFFSET_FRAC_BITS,
                             np.asarray(matrix, np.float64).reshape(3, 3) / 2.0**MATRIX_FRAC_BITS)


def calibration_from_frames(frames) -> dict[str, SensorCalibration]:
    """Per sensor, the calibration of the board's CALIBRATION frames (fields dicts), the
    last frame of each sensor and axis counting; a sensor with all three axes reported
    only. CalibrationError when a frame's Q formats are not this host's."""
    names = {code: name for name, code in zip(SENSORS, (protocol.SENSORS[k] for k in
                                                         ("GYROSCOPE", "ACCELEROMETER", "MAGNETOMETER")))}
    rows: dict[str, dict[int, dict]] = {}
    for f in frames:
        if (f["offset_frac_bits"], f["matrix_frac_bits"]) != (OFFSET_FRAC_BITS, MATRIX_FRAC_BITS):
            raise CalibrationError(f"the board reports its calibration in Q{f['offset_frac_bits']} offsets and "
                                   f"Q{f['matrix_frac_bits']} matrices; this host uses Q{OFFSET_FRAC_BITS} and "
                                   f"Q{MATRIX_FRAC_BITS}")
        if f["sensor"] in names and 0 <= f["axis"] < 3:
            rows.setdefault(names[f["sensor"]], {})[f["axis"]] = f
    out = {}
    for name, axes in rows.items():
        if len(axes) == 3:
            out[name] = from_fixed(name, [axes[a]["offset"] for a in range(3)],
                                   [v for a in range(3) for v in axes[a]["row"]])
    return out
