"""The navigation CSV (issue 16's `imulink nav` input): one row per IMU sample, with a GNSS
fix, a barometer sample or a marker's position only in the row of the sample where it was
measured.

Columns (a header names them; any order; other columns, such as ``truth_*``, are ignored):

- required: ``timestamp_us``, ``gyr_x_rad_s``, ``gyr_y_rad_s``, ``gyr_z_rad_s``,
  ``acc_x_m_s2``, ``acc_y_m_s2``, ``acc_z_m_s2``;
- optional, filled in every row when present: ``mag_x_uT``, ``mag_y_uT``, ``mag_z_uT``;
- optional, filled where a barometer sample was taken: ``baro_pa``, ``baro_temp_c``;
- optional, filled where a fix was measured: ``gnss_lat_deg``, ``gnss_lon_deg``,
  ``gnss_height_m``, ``gnss_h_acc_m``, ``gnss_v_acc_m`` (a position), and with it or not
  ``gnss_vel_e_m_s``, ``gnss_vel_n_m_s``, ``gnss_vel_u_m_s``, ``gnss_s_acc_m_s`` (a
  velocity; a marker's fix leaves them empty).

Units and axes as everywhere in imulink (sensor frame x right, y forward, z up; ENU; the
accelerometer reads specific force). :func:`read_nav_csv` refuses in one line, naming the
line, what a filter cannot use: a required column missing, a cell that is not a number
(NaN and infinities included), time that does not increase, a latitude or longitude that
is not one, an accuracy that is not positive, half a fix or half a barometer sample.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imulink.io.files import write_replacing
from imulink.io.sensor_input import CSV_COLUMNS, InputError, open_csv

REQUIRED = ("timestamp_us", *CSV_COLUMNS["gyr"], *CSV_COLUMNS["acc"])
MAG = CSV_COLUMNS["mag"]
BARO = ("baro_pa", "baro_temp_c")
GNSS_POSITION = ("gnss_lat_deg", "gnss_lon_deg", "gnss_height_m", "gnss_h_acc_m", "gnss_v_acc_m")
GNSS_VELOCITY = ("gnss_vel_e_m_s", "gnss_vel_n_m_s", "gnss_vel_u_m_s", "gnss_s_acc_m_s")
#: The unit of a column, by how its name ends (the first ending that matches).
UNITS = (("_rad_s", "rad/s"), ("_m_s2", "m/s^2"), ("_m_s", "m/s"), ("_uT", "uT"), ("_deg", "deg"), ("_m", "m"),
         ("_us", "us"), ("_pa", "Pa"), ("_temp_c", "deg C"))


def column_unit(name: str) -> str:
    """The unit of a column of the navigation CSV (UNITS); KeyError for a name without one."""
    for ending, unit in UNITS:
        if name.endswith(ending):
            return unit
    raise KeyError(name)


@dataclass
class NavInput:
    """What the CSV holds: per IMU sample `timestamp_us` (int64), `gyr`, `acc` (N,3) and
    `mag` (N,3, or None); the barometer samples (`baro_index` into the IMU samples,
    `baro_pa`, `baro_temp_c`); the fixes (`fix_index`, `fix_lat_deg`, `fix_lon_deg`,
    `fix_height_m`, `fix_h_acc_m`, `fix_v_acc_m`, and `fix_vel_enu` (M,3) and
    `fix_s_acc_m_s` NaN where a fix has no velocity; `fix_age_s`, when given, how long before
    the sample of its row each fix was valid: a CSV puts a fix in the row it was measured at,
    a recording in the row it arrived with; `fix_is_marker`, when given, which fixes are a
    marker's (else those without velocity: a CSV's convention; a receiver's fix without
    velocity, NMEA's GGA, is still a receiver's)."""
    timestamp_us: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray | None
    baro_index: np.ndarray
    baro_pa: np.ndarray
    baro_temp_c: np.ndarray
    fix_index: np.ndarray
    fix_lat_deg: np.ndarray
    fix_lon_deg: np.ndarray
    fix_height_m: np.ndarray
    fix_h_acc_m: np.ndarray
    fix_v_acc_m: np.ndarray
    fix_vel_enu: np.ndarray
    fix_s_acc_m_s: np.ndarray
    fix_age_s: np.ndarray | None = None  # how long before its row each fix was valid (a receiver's latency)
    fix_is_marker: np.ndarray | None = None  # per fix; None: the fixes without velocity are markers

    def __len__(self) -> int:
        return len(self.timestamp_us)


def _number(path: Path, line: int, name: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{path} line {line}: {name} is not a number ({text!r})") from None
    if not math.isfinite(value):
        raise InputError(f"{path} line {line}: {name} is {text!r}; give a finite number")
    return value


def _group(path: Path, line: int, row: list[str], columns: dict[str, int], names) -> list[float] | None:
    """The group's values, None when all its cells are empty; InputError when only some are."""
    cells = [row[columns[name]].strip() for name in names]
    if not any(cells):
        return None
    missing = [name for name, cell in zip(names, cells) if not cell]
    if missing:
        raise InputError(f"{path} line {line}: {', '.join(missing)} empty beside {names[0]}; a measurement "
                         f"fills all of {', '.join(names)}")
    return [_number(path, line, name, cell) for name, cell in zip(names, cells)]


def read_nav_csv(path) -> NavInput:
    """Read a navigation CSV (see the module's description); InputError names what is wrong."""
    path = Path(path)
    with open_csv(path) as f:
        rows = csv.reader(f)
        header = [name.strip() for name in next(rows, [])]
        columns = {name: k for k, name in enumerate(header)}
        missing = [name for name in REQUIRED if name not in columns]
        if missing:
            raise InputError(f"{path}: the column(s) {', '.join(missing)} are missing (a navigation CSV needs "
                             f"{', '.join(REQUIRED)})")
        partial = [names for names in (MAG, BARO, GNSS_POSITION, GNSS_VELOCITY)
                   if any(n in columns for n in names) and not all(n in columns for n in names)]
        if partial:
            names = partial[0]
            raise InputError(f"{path}: {', '.join(n for n in names if n not in columns)} missing beside "
                             f"{', '.join(n for n in names if n in columns)}")
        if all(n in columns for n in GNSS_VELOCITY) and not all(n in columns for n in GNSS_POSITION):
            raise InputError(f"{path}: GNSS velocity columns without the position ones ({', '.join(GNSS_POSITION)})")
        has_mag, has_baro = MAG[0] in columns, BARO[0] in columns
        has_fix, has_vel = GNSS_POSITION[0] in columns, GNSS_VELOCITY[0] in columns
        time: list[float] = []
        imu, mag, baro, fixes = [], [], [], []
        for line, row in enumerate(rows, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue  # a blank line
            if len(row) < len(header):
                raise InputError(f"{path} line {line}: {len(row)} cells, the header has {len(header)}")
            t = _number(path, line, "timestamp_us", row[columns["timestamp_us"]])
            if time and t <= time[-1]:
                raise InputError(f"{path} line {line}: timestamp_us {t:.0f} does not follow {time[-1]:.0f}; "
                                 "give the samples in the order they were taken")
            time.append(t)
            imu.append([_number(path, line, name, row[columns[name]]) for name in REQUIRED[1:]])
            if has_mag:
                values = _group(path, line, row, columns, MAG)
                if values is None:
                    raise InputError(f"{path} line {line}: the magnetometer cells are empty; a CSV with "
                                     f"{', '.join(MAG)} fills them in every row")
                mag.append(values)
            sample = len(time) - 1
            if has_baro:
                values = _group(path, line, row, columns, BARO)
                if values is not None:
                    if values[0] <= 0:
                        raise InputError(f"{path} line {line}: baro_pa {values[0]:g} is not a pressure")
                    baro.append([sample, *values])
            if has_fix:
                position = _group(path, line, row, columns, GNSS_POSITION)
                velocity = _group(path, line, row, columns, GNSS_VELOCITY) if has_vel else None
                if velocity is not None and position is None:
                    raise InputError(f"{path} line {line}: a GNSS velocity without a position")
                if position is not None:
                    lat, lon, _, h_acc, v_acc = position
                    if not -90.0 <= lat <= 90.0:
                        raise InputError(f"{path} line {line}: gnss_lat_deg {lat:g} is not a latitude")
                    if not -180.0 <= lon <= 180.0:
                        raise InputError(f"{path} line {line}: gnss_lon_deg {lon:g} is not a longitude")
                    if h_acc <= 0 or v_acc <= 0 or (velocity is not None and velocity[3] <= 0):
                        raise InputError(f"{path} line {line}: a fix's accuracies must be positive")
                    fixes.append([sample, *position, *(velocity if velocity is not None else [math.nan] * 4)])
    if len(time) < 2:
        raise InputError(f"{path}: {len(time)} sample(s); a navigation CSV needs at least 2")
    imu_array = np.asarray(imu)
    baro_array = np.asarray(baro).reshape(-1, 3)
    fix_array = np.asarray(fixes).reshape(-1, 10)
    return NavInput(timestamp_us=np.asarray(time, dtype=np.int64), gyr=imu_array[:, :3], acc=imu_array[:, 3:],
                    mag=np.asarray(mag) if has_mag else None, baro_index=baro_array[:, 0].astype(np.int64),
                    baro_pa=baro_array[:, 1], baro_temp_c=baro_array[:, 2],
                    fix_index=fix_array[:, 0].astype(np.int64), fix_lat_deg=fix_array[:, 1],
                    fix_lon_deg=fix_array[:, 2], fix_height_m=fix_array[:, 3], fix_h_acc_m=fix_array[:, 4],
                    fix_v_acc_m=fix_array[:, 5], fix_vel_enu=fix_array[:, 6:9], fix_s_acc_m_s=fix_array[:, 9])


def simulated_input(imu, fixes=None, at_arrival: bool = False, baro=None) -> NavInput:
    """A simulated run as a NavInput: `imu` an imulink.sim.SimResult, `fixes` a
    sim.navigation.GnssFixes or MarkerFixes (position only: accuracy each axis), `baro` a
    sim.navigation.BaroSamples. With
    `at_arrival`, each GNSS fix sits in the row of the sample it reaches the board with and
    says how late it is (a recording's order); else in the row it was measured at."""
    n = len(imu.t)
    index = np.zeros(0, dtype=np.int64) if fixes is None else np.asarray(fixes.index, dtype=np.int64)
    m = len(index)
    age = None
    if fixes is not None and hasattr(fixes, "vel_enu"):
        vel, s_acc = fixes.vel_enu, fixes.s_acc_m_s
        h_acc, v_acc = fixes.h_acc_m, fixes.v_acc_m
        if at_arrival:
            rate = 1.0 / float(imu.t[1] - imu.t[0])
            index = np.minimum(np.ceil(np.round(fixes.t_arrival * rate, 6)).astype(np.int64), n - 1)
            age = imu.t[index] - fixes.t_valid
    elif fixes is not None:
        vel, s_acc = np.full((m, 3), math.nan), np.full(m, math.nan)
        h_acc, v_acc = np.full(m, fixes.accuracy_m * math.sqrt(2.0)), np.full(m, fixes.accuracy_m)
    else:
        vel, s_acc, h_acc, v_acc = np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0)
    empty = np.zeros(0)
    return NavInput(timestamp_us=np.round(imu.t * 1e6).astype(np.int64), gyr=imu.gyr, acc=imu.acc, mag=imu.mag,
                    baro_index=np.zeros(0, dtype=np.int64) if baro is None else np.asarray(baro.index, dtype=np.int64),
                    baro_pa=empty if baro is None else np.asarray(baro.pressure_pa),
                    baro_temp_c=empty if baro is None else np.asarray(baro.temperature_c), fix_index=index,
                    fix_lat_deg=np.asarray(fixes.lat_deg) if m else empty,
                    fix_lon_deg=np.asarray(fixes.lon_deg) if m else empty,
                    fix_height_m=np.asarray(fixes.height_m) if m else empty, fix_h_acc_m=np.asarray(h_acc),
                    fix_v_acc_m=np.asarray(v_acc), fix_vel_enu=np.asarray(vel), fix_s_acc_m_s=np.asarray(s_acc),
                    fix_age_s=age)


def write_nav_csv(path, imu, fixes=None, baro=None, truth=None) -> None:
    """Write a simulated run as a navigation CSV: `imu` an imulink.sim.SimResult, `fixes` a
    sim.navigation.GnssFixes or MarkerFixes (position only), `baro` a BaroSamples, `truth`
    the NavTrajectory (adds truth_* columns, which readers ignore). Written beside `path`
    and renamed into place (files.write_replacing)."""
    n = len(imu.t)
    header = [*REQUIRED, *MAG]
    cells = [np.round(imu.t * 1e6).astype(np.int64).astype(str)]
    cells += [np.char.mod("%.9g", imu.gyr[:, k]) for k in range(3)]
    cells += [np.char.mod("%.9g", imu.acc[:, k]) for k in range(3)]
    cells += [np.char.mod("%.9g", imu.mag[:, k]) for k in range(3)]

    def sparse(index, values, fmt):
        column = np.full(n, "", dtype=object)
        column[index] = [fmt % v if math.isfinite(v) else "" for v in values]
        return column

    if baro is not None:
        header += BARO
        cells += [sparse(baro.index, baro.pressure_pa, "%.3f"), sparse(baro.index, baro.temperature_c, "%.3f")]
    if fixes is not None:
        header += GNSS_POSITION
        h_acc = getattr(fixes, "h_acc_m", None)
        accuracy = np.full(len(fixes), getattr(fixes, "accuracy_m", math.nan))
        cells += [sparse(fixes.index, fixes.lat_deg, "%.9f"), sparse(fixes.index, fixes.lon_deg, "%.9f"),
                  sparse(fixes.index, fixes.height_m, "%.4f"),
                  sparse(fixes.index, h_acc if h_acc is not None else accuracy * math.sqrt(2.0), "%.4f"),
                  sparse(fixes.index, getattr(fixes, "v_acc_m", accuracy), "%.4f")]
        if hasattr(fixes, "vel_enu"):
            header += GNSS_VELOCITY
            cells += [sparse(fixes.index, fixes.vel_enu[:, k], "%.5f") for k in range(3)]
            cells += [sparse(fixes.index, fixes.s_acc_m_s, "%.5f")]
    if truth is not None:
        header += ["truth_lat_deg", "truth_lon_deg", "truth_height_m", "truth_qw", "truth_qx", "truth_qy", "truth_qz"]
        cells += [np.char.mod("%.10f", truth.lat_deg), np.char.mod("%.10f", truth.lon_deg),
                  np.char.mod("%.4f", truth.height_m)]
        cells += [np.char.mod("%.9f", truth.quat[:, k]) for k in range(4)]

    def write(temporary: Path) -> None:
        with open(temporary, "w", newline="", encoding="utf-8") as f:
            out = csv.writer(f, lineterminator="\n")
            out.writerow(header)
            out.writerows(zip(*cells))

    write_replacing(path, write)
