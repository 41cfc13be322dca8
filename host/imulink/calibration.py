"""Sensor calibration from recorded data, and the calibration file.

Every calibration has one form, the one the firmware applies to the raw counts before
the filter (firmware/core/imu_sensor.h, imu_sample_calibrate):

    corrected = matrix @ (counts - offset)          (counts in, counts out)

* gyroscope: offset = the bias at rest (:func:`gyro_bias`), matrix = identity;
* accelerometer: offset and scale per axis from six resting positions, each axis up and
  down (:func:`accel_six_position`); optionally a symmetric matrix (misalignment and
  cross-axis sensitivity) from more positions, fitted to |matrix (a - offset)| = g;
* magnetometer: hard iron (offset) and soft iron (a symmetric matrix) from an ellipsoid
  fit to a recording of the board turned in all directions (:func:`mag_ellipsoid`),
  with the coverage of the directions (:func:`coverage`) and the spread of the field
  norm before and after.

Matrices are symmetric: |matrix x| = constant fixes a matrix only up to a rotation, and
the symmetric one is the one that rotates least, so the calibrated axes stay the
sensor's own (the filter's body frame).

:class:`Calibration` is the file: a sensor profile (the counts mean something only
with it) and one :class:`SensorCalibration` per sensor calibrated; :func:`save` writes
it atomically, :func:`load` reads it. :func:`to_fixed` gives the integers the board
takes (offsets in Q8 counts, matrices in Q24).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import protocol
from .counts import STANDARD_GRAVITY, SensorProfile
from .sensor_input import InputError, SensorRecord, nominal_rate_hz, still_segments

SENSORS = ("gyr", "acc", "mag")
SENSOR_NAMES = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer"}
#: Fixed-point formats of the board's calibration (imu_sensor.h): offsets in counts with
#: 8 fraction bits, matrices with 24 (range +-128, resolution 6e-8), as SET_CALIBRATION carries them.
OFFSET_FRAC_BITS = protocol.arg_format("SET_CALIBRATION", "offset").frac_bits
MATRIX_FRAC_BITS = protocol.arg_format("SET_CALIBRATION", "row").frac_bits
#: Largest offset the board accepts, counts: it keeps the corrected sums within int64
#: (imu_sensor.h) and is twice the range of a 16-bit register.
MAX_OFFSET_COUNTS = 65536.0
#: Largest matrix element the Q24 format holds.
MAX_MATRIX = 128.0 - 2.0**-MATRIX_FRAC_BITS

#: A board is still where, over a window of STILL_WINDOW_S, every gyroscope axis varies
#: less than STILL_GYRO_RAD_S (standard deviation; an MPU6050's noise at 100 Hz is some
#: 0.001 rad/s, a hand holding a board moves it by 0.01 rad/s and more) and every
#: accelerometer axis less than STILL_ACC_M_S2 (its noise: some 0.03 m/s^2).
STILL_WINDOW_S = 0.25
STILL_GYRO_RAD_S = 0.02
STILL_ACC_M_S2 = 0.1
#: Shortest rest used for a calibration, s.
MIN_REST_S = 1.0
#: Least still time for a gyroscope bias, s.
MIN_GYRO_STILL_S = 5.0
#: A rest is a position "axis up" when gravity lies within this angle of the axis.
FACE_ANGLE_DEG = 30.0
#: Two rests are distinct positions when their gravity directions differ by more than this.
DISTINCT_ANGLE_DEG = 20.0
#: Fewest magnetometer samples for an ellipsoid fit.
MIN_MAG_SAMPLES = 100
#: Largest ratio of the fitted ellipsoid's longest to shortest axis. Soft iron near a
#: board changes the field by tens of percent at most; an ellipsoid far flatter than that
#: is the fit of readings that do not span the directions (the board turned about one
#: axis: a circle lies on countless ellipsoids), not a measurement.
MAX_AXIS_RATIO = 2.0
#: Smallest field a magnetometer calibration may find, uT. The earth's field is 25-65 uT;
#: a fitted sphere far smaller is the readings of a board that hardly turned (a still
#: board's noise about one point fits a tiny sphere and "covers" every direction).
MIN_FIELD_NORM_UT = 10.0
#: A direction of the coverage grid counts as covered with at least this many samples.
COVERAGE_MIN_SAMPLES = 3


class CalibrationError(InputError):
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


# ---------------------------------------------------------------------------- rests


def rests(record: SensorRecord, min_duration_s: float = MIN_REST_S) -> list[tuple[int, int]]:
    """(start, stop) sample ranges where the board lies still for at least min_duration_s.

    Windows of STILL_WINDOW_S are still when every gyroscope and accelerometer axis stays
    within its threshold (see the constants); a rest is a run of still windows, without
    its first and last window (the board may be settling or starting to move in them)."""
    if record.acc is None and record.gyr is None:
        raise CalibrationError(f"{record.description} has neither gyroscope nor accelerometer data to find rests in")
    rate = nominal_rate_hz(record)
    window = max(2, int(round(STILL_WINDOW_S * rate)))
    blocks = len(record) // window
    still = np.ones(blocks, bool)
    for data, limit in ((record.gyr, STILL_GYRO_RAD_S), (record.acc, STILL_ACC_M_S2)):
        if data is not None:
            spread = data[:blocks * window].reshape(blocks, window, 3).std(axis=1)
            still &= np.all(spread < limit, axis=1)
    found = []
    for start, stop in still_segments(still):
        start, stop = (start + 1) * window, (stop - 1) * window
        if stop - start >= min_duration_s * rate:
            found.append((start, stop))
    return found


def _counts(record: SensorRecord, sensor: str, profile: SensorProfile) -> np.ndarray:
    data = {"gyr": record.gyr, "acc": record.acc, "mag": record.mag}[sensor]
    if data is None:
        raise CalibrationError(f"{record.description} has no {SENSOR_NAMES[sensor]} data")
    scale = {"gyr": profile.gyro_scale, "acc": profile.acc_scale, "mag": profile.mag_scale}[sensor]
    return data / scale


# ---------------------------------------------------------------------------- gyroscope


def gyro_bias(record: SensorRecord, profile: SensorProfile) -> SensorCalibration:
    """The gyroscope's bias: the mean over every rest of the record (at least
    MIN_GYRO_STILL_S in all). The earth's rotation (at most 7.3e-5 rad/s, 0.07 count at
    +-2000 deg/s) is part of it: it is below what the counts resolve."""
    counts = _counts(record, "gyr", profile)
    found = rests(record)
    rate = nominal_rate_hz(record)
    still = np.concatenate([np.arange(a, b) for a, b in found]) if found else np.array([], int)
    if len(still) < MIN_GYRO_STILL_S * rate:
        raise CalibrationError(f"{record.description}: the board lies still for {len(still) / rate:.1f} s in all "
                               f"(rests of {MIN_REST_S:g} s or more); a gyroscope bias needs {MIN_GYRO_STILL_S:g} s: "
                               "record the board lying still on a steady surface")
    data = counts[still]
    bias = data.mean(axis=0)
    # per-rest means show a bias that drifts (warm-up), which the standard error alone would hide
    means = np.array([counts[a:b].mean(axis=0) for a, b in found])
    report = {"rests": len(found), "still_s": len(still) / rate,
              "bias_counts": bias.tolist(), "bias_rad_s": (bias * profile.gyro_scale).tolist(),
              "noise_rad_s": (data.std(axis=0) * profile.gyro_scale).tolist(),
              "rest_mean_spread_rad_s": ((means.max(axis=0) - means.min(axis=0)) * profile.gyro_scale).tolist()}
    return SensorCalibration("gyr", bias, np.eye(3), report)


# ---------------------------------------------------------------------------- accelerometer

FACES = ("+x", "-x", "+y", "-y", "+z", "-z")


def _face(direction: np.ndarray) -> str | None:
    """"+z" etc. when the unit vector lies within FACE_ANGLE_DEG of an axis, else None."""
    axis = int(np.argmax(np.abs(direction)))
    if abs(direction[axis]) < math.cos(math.radians(FACE_ANGLE_DEG)):
        return None
    return ("+" if direction[axis] > 0 else "-") + "xyz"[axis]


def _positions(record: SensorRecord, counts: np.ndarray) -> list[dict]:
    """The rests of the record as positions: mean counts, samples, and the face up."""
    found = rests(record)
    out = []
    for a, b in found:
        mean = counts[a:b].mean(axis=0)
        out.append({"start_s": float(record.time_s[a]), "duration_s": float(record.time_s[b - 1] - record.time_s[a]),
                    "samples": b - a, "mean": mean, "face": _face(mean / np.linalg.norm(mean))})
    return out


def _norm_fit(points: np.ndarray, weights: np.ndarray, target: float, offset0: np.ndarray, matrix0: np.ndarray,
              full: bool) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of |M (p - b)| - target over the points: M diagonal, or symmetric when
    `full`; starting from (offset0, matrix0)."""
    from scipy.optimize import least_squares

    upper = np.triu_indices(3) if full else (np.arange(3), np.arange(3))

    def unpack(x):
        m = np.zeros((3, 3))
        m[upper] = x[3:]
        return x[:3], m + np.triu(m, 1).T

    def residuals(x):
        b, m = unpack(x)
        return np.sqrt(weights) * (np.linalg.norm((points - b) @ m.T, axis=1) - target)

    solution = least_squares(residuals, np.concatenate([offset0, matrix0[upper]]), x_scale="jac")
    return unpack(solution.x)


def accel_six_position(record: SensorRecord, profile: SensorProfile, misalignment: bool = False) -> SensorCalibration:
    """Offset and scale of each accelerometer axis from rests with each axis up and down.

    The six-position method: with axis i up the axis reads b_i + g / s_i, down b_i - g / s_i,
    so b_i is the mean of the two and s_i = 2 g / (up - down) (g in counts). Every rest
    that is one of the six positions counts (several of one position are averaged,
    weighted by their samples); then a least-squares fit of |M (a - b)| = g over all of
    them refines it (M diagonal). With `misalignment`, M is a symmetric matrix: the
    cross-axis terms are not seen from six axis-aligned positions, so this needs at
    least nine distinct positions, some of them tilted between the axes.
    """
    counts = _counts(record, "acc", profile)
    g = STANDARD_GRAVITY / profile.acc_scale
    positions = _positions(record, counts)
    by_face = {face: [p for p in positions if p["face"] == face] for face in FACES}
    missing = [face for face, found in by_face.items() if not found]
    if missing:
        raise CalibrationError(
            f"{record.description}: {len(positions)} rest(s) of {MIN_REST_S:g} s or more, but no rest with "
            f"{', '.join(missing)} up (within {FACE_ANGLE_DEG:g} deg); the six-position method needs each axis up "
            "and down, the board still for a few seconds in each")
    face_mean = {face: np.average([p["mean"] for p in found], axis=0, weights=[p["samples"] for p in found])
                 for face, found in by_face.items()}
    offset, scale = np.zeros(3), np.zeros(3)
    for i, axis in enumerate("xyz"):
        up, down = face_mean["+" + axis][i], face_mean["-" + axis][i]
        offset[i] = (up + down) / 2.0
        scale[i] = 2.0 * g / (up - down)
    points = np.array([p["mean"] for p in positions])
    weights = np.array([p["samples"] for p in positions], np.float64)
    weights /= weights.mean()
    distinct = _distinct_directions(points)
    if misalignment and distinct < 9:
        raise CalibrationError(f"{record.description}: {distinct} distinct position(s); the misalignment (a "
                               "symmetric matrix, 9 unknowns with the offsets) needs at least 9: add rests tilted "
                               "between the axes (on an edge, on a corner)")
    offset, matrix = _norm_fit(points, weights, g, offset, np.diag(scale), misalignment)
    before = np.linalg.norm(points, axis=1) * profile.acc_scale
    after = np.linalg.norm((points - offset) @ matrix.T, axis=1) * profile.acc_scale
    report = {"positions": len(positions), "distinct_positions": distinct, "misalignment": misalignment,
              "faces": {face: len(found) for face, found in by_face.items()},
              "offset_m_s2": (offset * profile.acc_scale).tolist(), "scale": np.diag(matrix).tolist(),
              "norm_error_before_m_s2": _spread(before - STANDARD_GRAVITY),
              "norm_error_after_m_s2": _spread(after - STANDARD_GRAVITY)}
    return SensorCalibration("acc", offset, matrix, report)


def _distinct_directions(points: np.ndarray) -> int:
    """How many of the points' directions differ from each other by DISTINCT_ANGLE_DEG."""
    kept: list[np.ndarray] = []
    for p in points / np.linalg.norm(points, axis=1, keepdims=True):
        if all(np.dot(p, k) < math.cos(math.radians(DISTINCT_ANGLE_DEG)) for k in kept):
            kept.append(p)
    return len(kept)


def _spread(errors: np.ndarray) -> dict:
    """RMS and largest magnitude of a set of errors."""
    return {"rms": float(np.sqrt(np.mean(np.square(errors)))), "max": float(np.max(np.abs(errors)))}


# ---------------------------------------------------------------------------- magnetometer

#: The directions of the coverage grid: the 26 neighbours of a cube's centre (6 faces,
#: 12 edges, 8 corners), each the centre of a cell of some 0.48 sr.
_GRID = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)],
                 np.float64)
GRID_NAMES = ["".join(f"{'+' if c > 0 else '-'}{axis}" for c, axis in zip(d, "xyz") if c) for d in _GRID.astype(int)]
_GRID_UNIT = _GRID / np.linalg.norm(_GRID, axis=1, keepdims=True)


@dataclass
class Coverage:
    """How the field directions (in the sensor frame) fill the sphere: per direction of
    the 26-direction grid (GRID_NAMES: "+z", "+x-y", "+x+y-z", ...) the samples nearest to
    it; `missing` the directions with fewer than COVERAGE_MIN_SAMPLES."""

    counts: dict[str, int]
    missing: list[str]

    @property
    def covered(self) -> int:
        return len(self.counts) - len(self.missing)

    @property
    def missing_axes(self) -> list[str]:
        """The six axis directions (+x .. -z) among the missing."""
        return [name for name in self.missing if len(name) == 2]

    def describe(self) -> str:
        text = f"{self.covered} of {len(self.counts)} directions"
        if self.missing:
            text += f"; missing: {', '.join(self.missing)}"
        return text


def coverage(directions: np.ndarray) -> Coverage:
    """Coverage of (N,3) field vectors (any length; their directions count)."""
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    nearest = np.argmax(unit @ _GRID_UNIT.T, axis=1)
    counts = np.bincount(nearest, minlength=len(_GRID))
    return Coverage({name: int(n) for name, n in zip(GRID_NAMES, counts)},
                    [name for name, n in zip(GRID_NAMES, counts) if n < COVERAGE_MIN_SAMPLES])


def fit_ellipsoid(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre c and symmetric positive definite A with (p - c)^T A (p - c) = 1 for the
    points, by algebraic least squares: the quadric p^T M p + 2 n^T p + d = 0 whose
    coefficient vector (unit length) makes the residuals smallest, the smallest right
    singular vector of the design matrix. The points are centred and scaled first (the
    fit is then well conditioned whatever the units). CalibrationError when the best
    quadric is not an ellipsoid (too few directions: a plane, a cylinder)."""
    mean = points.mean(axis=0)
    unit = float(np.sqrt(np.mean(np.sum((points - mean) ** 2, axis=1))))
    if not unit > 0:
        raise CalibrationError("the magnetometer reads the same value throughout: no ellipsoid to fit")
    x, y, z = ((points - mean) / unit).T
    design = np.column_stack([x * x, y * y, z * z, 2 * y * z, 2 * x * z, 2 * x * y, 2 * x, 2 * y, 2 * z,
                              np.ones_like(x)])
    v = np.linalg.svd(design, full_matrices=False)[2][-1]
    m = np.array([[v[0], v[5], v[4]], [v[5], v[1], v[3]], [v[4], v[3], v[2]]])
    n = v[6:9]
    try:
        centre = -np.linalg.solve(m, n)
    except np.linalg.LinAlgError:
        raise CalibrationError("the magnetometer data fit no ellipsoid (a degenerate quadric): turn the board "
                               "through more directions") from None
    k = centre @ m @ centre - v[9]
    a = m / k
    if not np.all(np.linalg.eigvalsh(a) > 0):
        raise CalibrationError("the magnetometer data fit no ellipsoid (the best quadric is a hyperboloid): turn "
                               "the board through more directions")
    return mean + unit * centre, a / unit**2


def axis_ratio(a: np.ndarray) -> float:
    """Longest over shortest axis of the ellipsoid x^T a x = 1."""
    axes = 1.0 / np.sqrt(np.linalg.eigvalsh(a))
    return float(axes.max() / axes.min())


def symmetric_sqrt(a: np.ndarray) -> np.ndarray:
    """The symmetric square root of a symmetric positive definite matrix."""
    values, vectors = np.linalg.eigh(a)
    root = (vectors * np.sqrt(values)) @ vectors.T
    return (root + root.T) / 2.0  # symmetric to the last bit, not only to rounding


def mag_ellipsoid(record: SensorRecord, profile: SensorProfile) -> SensorCalibration:
    """Hard iron (the ellipsoid's centre) and soft iron (a symmetric matrix that maps the
    ellipsoid onto a sphere) of a magnetometer turned in all directions.

    With (m - c)^T A (m - c) = 1 the fitted ellipsoid, W = r sqrt(A) maps it onto the
    sphere of radius r; r is the mean distance of the readings from c, so the calibration
    keeps the mean field norm (the filters use the field's direction; a norm far from the
    true field's would only mislead a check of it). Samples at a register's limit (the
    HMC5883L saturates at +-2047) are left out.
    """
    counts = _counts(record, "mag", profile)
    low, high = profile.mag_limits
    unclipped = np.all((counts > low) & (counts < high), axis=1)
    points = counts[unclipped]
    if len(points) < MIN_MAG_SAMPLES:
        raise CalibrationError(f"{record.description}: {len(points)} magnetometer sample(s) within the register's "
                               f"range; an ellipsoid fit needs at least {MIN_MAG_SAMPLES}")
    try:
        centre, a = fit_ellipsoid(points)
        if axis_ratio(a) > MAX_AXIS_RATIO:
            raise CalibrationError(f"{record.description}: the fitted ellipsoid's axes differ by a factor of "
                                   f"{axis_ratio(a):.3g} (soft iron does not do that): the readings do not "
                                   "span the directions; turn the board through more directions")
    except CalibrationError as exc:
        # no fit: the directions the readings lack, seen from their mean (a turn about one axis
        # leaves that axis's two directions empty)
        lacking = coverage(points - points.mean(axis=0)).missing_axes
        raise CalibrationError(f"{exc}; {missing_advice(lacking)}" if lacking else str(exc)) from None
    radius = float(np.mean(np.linalg.norm(points - centre, axis=1)))
    if radius * profile.mag_scale < MIN_FIELD_NORM_UT:
        raise CalibrationError(f"{record.description}: the magnetometer readings lie within "
                               f"{radius * profile.mag_scale:.2g} uT of one point (the earth's field is 25-65 uT): "
                               "the board hardly turned; turn it slowly through every direction")
    matrix = radius * symmetric_sqrt(a)
    corrected = (points - centre) @ matrix.T
    before = np.linalg.norm(points, axis=1) * profile.mag_scale
    after = np.linalg.norm(corrected, axis=1) * profile.mag_scale
    found = coverage(corrected)
    report = {"samples": int(len(points)), "clipped_samples": int(np.count_nonzero(~unclipped)),
              "hard_iron_uT": (centre * profile.mag_scale).tolist(), "soft_iron": matrix.tolist(),
              "field_norm_uT": float(np.mean(after)),
              "norm_spread_before_uT": float(np.std(before)), "norm_spread_after_uT": float(np.std(after)),
              "coverage": {"covered": found.covered, "of": len(found.counts), "missing": found.missing,
                           "samples": found.counts}}
    return SensorCalibration("mag", centre, matrix, report)


# ---------------------------------------------------------------------------- the file

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
    from . import protocol

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


def to_json(calibration: Calibration) -> dict:
    from .recording import profile_to_json

    return {"format": FORMAT, "format_version": FORMAT_VERSION, "profile": profile_to_json(calibration.profile),
            "sensors": {name: {"offset_counts": c.offset.tolist(), "matrix": c.matrix.tolist(), "report": c.report}
                        for name, c in calibration.sensors.items()}}


def from_json(data, what: str) -> Calibration:
    """A Calibration from its JSON; CalibrationError naming `what` when it is not one."""
    from .recording import profile_from_json

    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CalibrationError(f"{what} is not an imulink calibration file (no \"format\": \"{FORMAT}\")")
    if data.get("format_version") != FORMAT_VERSION:
        raise CalibrationError(f"{what}: calibration format {data.get('format_version')!r} is not supported "
                               f"(this imulink reads format {FORMAT_VERSION})")
    try:
        profile = profile_from_json(data["profile"])
        sensors = {}
        for name, entry in data["sensors"].items():
            if name not in SENSORS:
                raise ValueError(f"unknown sensor {name!r} (known: {', '.join(SENSORS)})")
            offset = np.asarray(entry["offset_counts"], np.float64)
            matrix = np.asarray(entry["matrix"], np.float64)
            if offset.shape != (3,) or matrix.shape != (3, 3) or not (np.all(np.isfinite(offset))
                                                                         and np.all(np.isfinite(matrix))):
                raise ValueError(f"{name}: offset_counts must be 3 numbers and matrix 3 x 3")
            sensors[name] = SensorCalibration(name, offset, matrix, entry.get("report", {}))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CalibrationError(f"{what} is not a valid calibration file: {exc}") from None
    calibration = Calibration(profile, sensors)
    for c in sensors.values():
        to_fixed(c)  # values the board takes, or CalibrationError now
    return calibration


def load(path) -> Calibration:
    from .files import FileError, read_regular_file

    try:
        text = read_regular_file(path, 1 << 20)
    except FileError as exc:
        raise CalibrationError(str(exc)) from None
    try:
        data = json.loads(text)
    except (ValueError, RecursionError):
        raise CalibrationError(f"{path} is not JSON (an imulink calibration file is)") from None
    return from_json(data, str(path))


def save(calibration: Calibration, path, inputs=()) -> None:
    """Write the file atomically (a temporary file renamed: the old one stays whole until then)."""
    from .files import write_replacing

    text = json.dumps(to_json(calibration), indent=1) + "\n"
    write_replacing(path, lambda temporary: Path(temporary).write_text(text, encoding="utf-8"), inputs=inputs)


def merged(path, new: SensorCalibration, profile: SensorProfile) -> tuple[Calibration, bool]:
    """The calibration of the file at `path` (if it exists) with `new` in place of that
    sensor's entry; whether the file had an entry for the sensor. CalibrationError when the file's profile is
    another: its counts would mean something else."""
    path = Path(path)
    existing = load(path) if path.exists() else None
    if existing is not None and existing.profile != profile:
        raise CalibrationError(f"{path} holds a calibration for profile {existing.profile.name}, this one is for "
                               f"{profile.name}: write it to another file")
    calibration = existing or Calibration(profile)
    new.report = {"created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **new.report}
    replaced = new.sensor in calibration.sensors
    calibration.sensors[new.sensor] = new
    return calibration, replaced


# ---------------------------------------------------------------------------- the report


def _vector(values, fmt: str = "{:+.4g}") -> str:
    return "[" + ", ".join(fmt.format(v) for v in values) + "]"


def format_report(calibration: SensorCalibration, profile: SensorProfile) -> str:
    """A readable summary of one sensor's calibration."""
    c, r = calibration, calibration.report
    lines = [f"{SENSOR_NAMES[c.sensor]} calibration (profile {profile.name}): corrected = M (counts - offset)",
             f"  offset: {_vector(c.offset, '{:+.2f}')} counts"]
    if c.sensor == "gyr":
        lines += [f"  bias: {_vector(r['bias_rad_s'])} rad/s = "
                  f"{_vector(np.degrees(r['bias_rad_s']), '{:+.3f}')} deg/s",
                  f"  from {r['still_s']:.1f} s still in {r['rests']} rest(s); noise "
                  f"{_vector(r['noise_rad_s'], '{:.2g}')} rad/s a sample"
                  + (f"; the rests' means differ by up to {_vector(r['rest_mean_spread_rad_s'], '{:.2g}')} rad/s"
                     if r["rests"] > 1 else "")]
        return "\n".join(lines)
    lines += ["  M: " + "\n     ".join(_vector(row, "{:+.6f}") for row in c.matrix)]
    if c.sensor == "acc":
        before, after = r["norm_error_before_m_s2"], r["norm_error_after_m_s2"]
        faces = ", ".join(f"{face} {n}" for face, n in r["faces"].items())
        lines += [f"  offset {_vector(r['offset_m_s2'])} m/s^2, scale {_vector(r['scale'], '{:.5f}')}"
                  + (" (symmetric matrix: misalignment fitted)" if r["misalignment"] else ""),
                  f"  from {r['positions']} rest(s), {r['distinct_positions']} distinct position(s) (up: {faces})",
                  f"  |a| - g over the rests: RMS {before['rms']:.4f} m/s^2 before, {after['rms']:.4f} after "
                  f"(largest {before['max']:.4f}, {after['max']:.4f})"
                  + (": as many rests as unknowns fit exactly; rest in each position twice for a check"
                     if r["positions"] <= (9 if r["misalignment"] else 6) else "")]
    else:
        coverage_report = r["coverage"]
        missing = coverage_report["missing"]
        lines += [f"  hard iron {_vector(r['hard_iron_uT'], '{:+.2f}')} uT; field norm {r['field_norm_uT']:.2f} uT "
                  f"(kept)",
                  f"  field norm spread (std): {r['norm_spread_before_uT']:.3f} uT before, "
                  f"{r['norm_spread_after_uT']:.3f} uT after",
                  f"  from {r['samples']} samples" + (f" ({r['clipped_samples']} at the register's limit left out)"
                                                      if r["clipped_samples"] else ""),
                  f"  coverage: {coverage_report['covered']} of {coverage_report['of']} directions"
                  + (f"; missing: {', '.join(missing)}" if missing else " (all)")]
    return "\n".join(lines)


def format_calibration(calibration: Calibration) -> str:
    """Every sensor's offset and matrix, one line each."""
    return "\n".join(f"{SENSOR_NAMES[name]:<13} offset {_vector(c.offset, '{:+.2f}')} counts, M "
                     + " ".join(_vector(row, "{:+.6f}") for row in c.matrix)
                     for name, c in ((name, calibration.sensor(name)) for name in SENSORS))


def missing_advice(missing_axes: list[str]) -> str:
    """What to do when the field never lay along some of the board's axes."""
    return (f"the field never lay along {', '.join(missing_axes)} of the board: turn the board so that each of "
            "these axes points along the earth's field (north, and down in the northern hemisphere) for a moment")
