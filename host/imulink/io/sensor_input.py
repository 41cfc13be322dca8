"""Sensor data from a file, for the commands that analyse recorded data (`imulink allan`,
`imulink calibrate`): a recording of `imulink record`, a CSV with the columns that
`imulink replay --csv` writes, or a BROAD trial (.mat).

:func:`read` gives every input the same shape, a :class:`SensorRecord` in SI units, and
checks what every use needs (a readable file, finite values, timestamps); what a use
needs beyond that (an unbroken record for an Allan analysis, rests for a calibration)
it checks itself.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imulink.core.counts import BROAD_PROFILE, SensorProfile
from imulink.errors import ImulinkError
from imulink.io.broad import BroadError, load_broad
from imulink.io.files import FileError, check_regular_file
from imulink.io.recording import load_recording
from imulink.progress import CountProgress

#: Largest CSV read (a replay CSV of two hours at 1 kHz is some 3 GB).
MAX_CSV_BYTES = 8 << 30
#: The SI columns of a CSV, per sensor (as `imulink replay --csv` names them).
CSV_COLUMNS = {"gyr": ("gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"), "acc": ("acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"),
               "mag": ("mag_x_uT", "mag_y_uT", "mag_z_uT")}
#: A spacing longer than this many median spacings is a gap (lost samples).
GAP_PERIODS = 1.5



class InputError(ImulinkError):
    """An input file that cannot be used; the message names it and why."""


@dataclass
class SensorRecord:
    """Sensor data in SI units: gyr (N,3) rad/s, acc (N,3) m/s^2, mag (N,3) uT, each None
    when the input lacks it.

    time_s: (N,) seconds from the first sample (a board's clock, a CSV's column, k / rate
    for a BROAD trial). profile: the sensor profile of the counts behind the values (a
    recording's header; gy86-broad for a BROAD trial, as `imulink inject` converts it),
    None for a CSV, which does not say. index: a recording's sample indices (the board
    counts every sensor read), else None. declared_rate_hz: the rate the board's STATUS or
    the trial's sampling_rate declares, else None. movement: a BROAD trial's movement
    mask (false at rest), else None.
    """

    description: str
    time_s: np.ndarray
    gyr: np.ndarray | None
    acc: np.ndarray | None
    mag: np.ndarray | None
    profile: SensorProfile | None = None
    index: np.ndarray | None = None
    declared_rate_hz: float | None = None
    movement: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time_s)


def read(path, progress: CountProgress | None = None) -> SensorRecord:
    """The sensor data of `path`: a BROAD trial (.mat), a CSV (.csv: `imulink replay --csv`
    or any with timestamp_us or time_s and the SI columns of CSV_COLUMNS), or a recording
    of `imulink record` (anything else). progress: see recording.load_recording.
    InputError (and recording.RecordingError) for what cannot be read."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".mat":
        return _from_broad(path)
    if suffix == ".csv":
        return _from_csv(path)
    return _from_recording(path, progress)


def rate_from_timestamps(time_s: np.ndarray, what: str) -> float:
    """The sample rate of an unbroken record with these timestamps (s), Hz.

    InputError when a timestamp does not increase or a spacing exceeds GAP_PERIODS times
    the median spacing (lost samples). The rate is then the mean spacing's inverse: a
    clock counting whole microseconds rounds each spacing, not their sum.
    """
    if len(time_s) < 2:
        raise InputError(f"{what} has {len(time_s)} sample(s): too few to have a sample rate")
    spacing = np.diff(time_s)
    backwards = np.flatnonzero(~(spacing > 0))
    if len(backwards):
        k = int(backwards[0])
        raise InputError(f"{what}: the timestamps do not increase at sample {k + 1} ({time_s[k]:.6f} s, then "
                         f"{time_s[k + 1]:.6f} s); give samples in the order they were taken")
    period = float(np.median(spacing))
    gaps = np.flatnonzero(spacing > GAP_PERIODS * period)
    if len(gaps):
        k = int(gaps[0])
        raise InputError(f"{what}: {len(gaps)} gap(s) in samples every {period * 1e3:.4g} ms, the first "
                         f"{spacing[k]:.4g} s long after sample {k} ({time_s[k] - time_s[0]:.1f} s in); the "
                         "analysis needs an unbroken record")
    return (len(time_s) - 1) / float(time_s[-1] - time_s[0])


def unwrap_us(timestamp_us: np.ndarray) -> np.ndarray:
    """Board timestamps (u32 microseconds, wrapping after 71.6 min) as seconds from the
    first: each step is taken modulo 2^32 as a signed number, so that a wrap counts as
    the short step it is and a step back stays negative."""
    steps: np.ndarray = np.diff(np.asarray(timestamp_us, dtype=np.int64))
    steps = (steps + 2**31) % 2**32 - 2**31
    return np.concatenate([[0.0], np.cumsum(steps) * 1e-6])


def _from_recording(path: Path, progress: CountProgress | None) -> SensorRecord:
    """The samples of a recording, in SI as the host's replay feeds them to its filters
    (counts times the recorded profile's scale)."""
    recording = load_recording(path, progress)
    s, profile = recording.samples, recording.profile
    declared = recording.status["sample_rate_mhz"] / 1000.0 if recording.status else None
    return SensorRecord(f"recording {path.name} (profile {profile.name})", unwrap_us(s.timestamp_us),
                        s.gyr * profile.gyro_scale, s.acc * profile.acc_scale, s.mag * profile.mag_scale, profile,
                        s.index, declared)


def open_csv(path: Path):
    """A CSV input opened as text (UTF-8, undecodable bytes replaced, newlines as csv wants
    them); InputError for a file that is missing, not a regular file, too large or
    unreadable."""
    try:
        check_regular_file(path, MAX_CSV_BYTES)
        return open(path, newline="", encoding="utf-8", errors="replace")
    except FileError as exc:
        raise InputError(str(exc)) from None
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None


def _from_csv(path: Path) -> SensorRecord:
    with open_csv(path) as f:
        header = [name.strip() for name in f.readline().strip().split(",")]
    time_column = next((c for c in ("timestamp_us", "time_s") if c in header), None)
    sensors = [k for k, names in CSV_COLUMNS.items() if all(c in header for c in names)]
    if time_column is None or not sensors:
        raise InputError(f"{path} is not a CSV with a timestamp_us or time_s column and the columns "
                         f"{', '.join(CSV_COLUMNS['gyr'])}, {', '.join(CSV_COLUMNS['acc'])} and/or "
                         f"{', '.join(CSV_COLUMNS['mag'])} (as `imulink replay --csv` writes)")
    names = [time_column] + [c for k in sensors for c in CSV_COLUMNS[k]]
    try:
        table = np.loadtxt(path, delimiter=",", skiprows=1, usecols=[header.index(c) for c in names], ndmin=2,
                           encoding="utf-8")
    except (ValueError, OSError) as exc:
        raise InputError(f"{path}: {str(exc).splitlines()[0]}") from None
    if not np.all(np.isfinite(table)):
        row, col = np.argwhere(~np.isfinite(table))[0]
        raise InputError(f"{path}: {names[col]} is empty, NaN or infinite in data row {row + 1}")
    times = unwrap_us(table[:, 0]) if time_column == "timestamp_us" else table[:, 0] - table[0, 0]
    columns = {k: table[:, 1 + 3 * i:4 + 3 * i] for i, k in enumerate(sensors)}
    return SensorRecord(f"CSV {path.name}", times, columns.get("gyr"), columns.get("acc"), columns.get("mag"))


def _from_broad(path: Path) -> SensorRecord:

    try:
        trial = load_broad(path)
    except BroadError as exc:
        raise InputError(str(exc)) from None
    for name, values in (("imu_gyr", trial.gyr), ("imu_acc", trial.acc), ("imu_mag", trial.mag)):
        if not np.all(np.isfinite(values)):
            raise InputError(f"{path}: {name} holds NaN or infinite values")
    return SensorRecord(f"BROAD trial {trial.name}", np.arange(len(trial)) / trial.rate_hz, trial.gyr, trial.acc,
                        trial.mag, BROAD_PROFILE, None, trial.rate_hz, trial.movement)


def still_segments(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of True in a boolean mask, in order."""
    padded = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def nominal_rate_hz(record: SensorRecord) -> float:
    """The record's sample rate for sizing windows, Hz: the declared one, else the median
    spacing's inverse (gaps do not change it)."""
    if record.declared_rate_hz:
        return record.declared_rate_hz
    spacing = np.diff(record.time_s)
    spacing = spacing[spacing > 0]
    if not len(spacing):
        raise InputError(f"{record.description}: its timestamps do not increase: no sample rate")
    return 1.0 / float(np.median(spacing))

