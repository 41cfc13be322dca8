"""The `nav` filter (firmware/core/imu_navkf.c) run offline over a navigation input, in
the firmware's fixed point or the float twin, through the same C core the board runs.

The filter starts at the first fix (a GNSS fix with velocity; a fix without one is a
marker's, at a known place) with the attitude from the accelerometer and magnetometer of
that sample, at rest; every later sample is propagated, and each fix is used right after
the sample of its row (with its age, when the input says how late it arrived: the filter
takes the estimate back that far). A marker's fix (in a CSV, one without velocity) is
trusted as its accuracy says, never gated; a receiver's is gated. `with_start` puts a
marker's fix at the first sample (`imulink nav --start`), for an input without a fix
there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from imulink import protocol
from imulink.core import SettingsError, _module, _settings_struct, resolve_settings, settings_fields, to_fixed
from imulink.io.files import write_replacing
from imulink.io.nav_input import NavInput
from imulink.io.recording import sample_rows, sample_times
from imulink.io.sensor_input import InputError
from imulink.sim import navigation as nv
from imulink.sim import quat as Q

#: The error states (imu_navkf.h): names and the unit each block's variance is kept in.
STATE_NAMES = ("pos_e", "pos_n", "pos_u", "vel_e", "vel_n", "vel_u", "att_x", "att_y", "att_z",
               "gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "acc_bias_x", "acc_bias_y", "acc_bias_z", "baro_bias")
STATE_UNITS = np.array([1024.0] * 3 + [64.0] * 3 + [1.0] * 9 + [1024.0])
STATES = len(STATE_NAMES)
#: Q formats of the fixed build's latitude and longitude (rad), velocity (m/s), quaternion and
#: variance mantissas: those of the NAV_STATE and ESTIMATE fields that carry them.
_ANGLE_Q = protocol.frac_bits("NAV_STATE", "lat")
_VEL_Q = protocol.frac_bits("NAV_STATE", "vel")
_QUAT_Q = protocol.frac_bits("ESTIMATE", "quat")
_VAR_Q = protocol.frac_bits("NAV_STATE", "var_mantissa")
#: Real value per count of a GNSS frame's fields: 1e-7 deg, mm and mm/s to m and m/s.
_GNSS_DEG = protocol.field_format("GNSS", "lat_1e7deg").scale
_GNSS_M = protocol.field_format("GNSS", "height_mm").scale
_GNSS_M_S = protocol.field_format("GNSS", "vel_ned_mm_s").scale
#: The sample rates the filter takes (imu_navkf_start).
MIN_RATE_HZ, MAX_RATE_HZ = 10.0, 1000.0


@dataclass
class NavResult:
    """The filter's output for each sample from the start (`start` is its index in the input):
    geodetic position (deg, m), ENU velocity (m/s), attitude quaternion (sensor to ENU, w
    first), the error state's standard deviations (STATE_NAMES, SI units: m, m/s, rad,
    rad/s, m/s^2, m); per fix of the input from the start on, whether the gate let it in;
    counts of rejected fixes (position or velocity gated), resets of position and velocity to
    the fixes (the estimate in doubt), fixes that scaled the covariance up, zero-velocity
    updates and saturations."""
    start: int
    timestamp_us: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    vel_enu: np.ndarray
    quat: np.ndarray
    sigma: np.ndarray
    fix_index: np.ndarray
    fix_accepted: np.ndarray
    rejected: int
    resets: int
    fades: int
    zero_velocity: int
    saturations: int

    def __len__(self) -> int:
        return len(self.timestamp_us)

    def since_fix_s(self) -> np.ndarray:
        """Seconds since the last fix the filter used, per sample (NaN before the first)."""
        used = self.fix_index[self.fix_accepted] - self.start
        last = np.full(len(self), -1, dtype=np.int64)
        last[used] = used
        last = np.maximum.accumulate(np.r_[0, last[1:]])  # the start is a fix too
        return (self.timestamp_us - self.timestamp_us[last]) / 1e6

    def gated(self) -> np.ndarray:
        """Fixes the gate rejected so far, per sample."""
        counts = np.zeros(len(self), dtype=np.int64)
        np.add.at(counts, self.fix_index[~self.fix_accepted] - self.start, 1)
        return np.cumsum(counts)


def input_from_recording(recording, latency_s: float = 0.0) -> NavInput:
    """A recording (imulink.io.recording.Recording) as a NavInput: its samples in SI, its
    barometer readings and its usable GNSS fixes (3-D, within the receiver's accuracy masks)
    in the rows of the samples they came with, each `latency_s` old there (the receiver's
    latency: a fix's time of week is on the receiver's clock, not the board's)."""
    s, p, g, b = recording.samples, recording.profile, recording.gnss, recording.baro
    if len(s) < 2:
        raise InputError("the recording has fewer than 2 samples")
    rows = sample_rows(recording, g.segment, g.index)
    usable = (rows >= 0) & (g.fix_ok != 0) & ((g.fix_type == 3) | (g.fix_type == 4))
    order = np.argsort(rows[usable], kind="stable")
    has_vel = (g.has_velocity[usable] != 0)[order]
    vel_ned = g.vel_ned_mm_s[usable][order] * _GNSS_M_S
    baro_rows = sample_rows(recording, b.segment, b.index)
    baro_ok = baro_rows >= 0
    nan = np.full(int(usable.sum()), math.nan)
    return NavInput(
        timestamp_us=np.round(sample_times(recording) * 1e6).astype(np.int64), gyr=s.gyr * p.gyro_scale,
        acc=s.acc * p.acc_scale, mag=s.mag * p.mag_scale, baro_index=baro_rows[baro_ok],
        baro_pa=b.pressure_pa[baro_ok].astype(np.float64), baro_temp_c=b.temperature_cdeg[baro_ok] / 100.0,
        fix_index=rows[usable][order], fix_lat_deg=g.lat_1e7deg[usable][order] * _GNSS_DEG,
        fix_lon_deg=g.lon_1e7deg[usable][order] * _GNSS_DEG, fix_height_m=g.height_mm[usable][order] * _GNSS_M,
        fix_h_acc_m=np.maximum(g.h_acc_mm[usable][order], 1) * _GNSS_M,
        fix_v_acc_m=np.maximum(g.v_acc_mm[usable][order], 1) * _GNSS_M,
        fix_vel_enu=np.where(has_vel[:, None], np.c_[vel_ned[:, 1], vel_ned[:, 0], -vel_ned[:, 2]], math.nan),
        fix_s_acc_m_s=np.where(has_vel, np.maximum(g.s_acc_mm_s[usable][order], 1) * _GNSS_M_S, nan),
        fix_age_s=np.full(int(usable.sum()), float(latency_s)), fix_is_marker=np.zeros(int(usable.sum()), bool))


#: Columns of the CSV `imulink nav` writes (write_csv), after timestamp_us.
OUTPUT_COLUMNS = ("lat_deg", "lon_deg", "height_m", "vel_e_m_s", "vel_n_m_s", "vel_u_m_s", "qw", "qx", "qy", "qz",
                  "sd_east_m", "sd_north_m", "sd_up_m", "sd_vel_e_m_s", "sd_vel_n_m_s", "sd_vel_u_m_s",
                  "sd_att_x_deg", "sd_att_y_deg", "sd_att_z_deg", "sd_gyro_bias_x_deg_s", "sd_gyro_bias_y_deg_s",
                  "sd_gyro_bias_z_deg_s", "sd_acc_bias_x_m_s2", "sd_acc_bias_y_m_s2", "sd_acc_bias_z_m_s2",
                  "sd_baro_bias_m", "fix_age_s", "gated")


def write_csv(result: NavResult, path, inputs=()) -> None:
    """The filter's output, one row per sample from the start: OUTPUT_COLUMNS (standard
    deviations of the error state; attitude and gyro bias in degrees), the time since the
    last fix used and the fixes gated so far. Written beside `path` and renamed into place."""
    sigma = result.sigma.copy()
    sigma[:, 6:12] = np.degrees(sigma[:, 6:12])
    cells = [result.timestamp_us.astype(str), np.char.mod("%.9f", result.lat_deg), np.char.mod("%.9f", result.lon_deg),
             np.char.mod("%.4f", result.height_m)]
    cells += [np.char.mod("%.5f", result.vel_enu[:, k]) for k in range(3)]
    cells += [np.char.mod("%.9f", result.quat[:, k]) for k in range(4)]
    cells += [np.char.mod("%.6g", sigma[:, k]) for k in range(STATES)]
    age = result.since_fix_s()
    cells += [np.char.mod("%.2f", age), result.gated().astype(str)]

    def write(temporary) -> None:
        with open(temporary, "w", encoding="utf-8") as out:
            out.write(",".join(("timestamp_us",) + OUTPUT_COLUMNS) + "\n")
            for row in zip(*cells):
                out.write(",".join(row) + "\n")

    write_replacing(path, write, inputs=inputs)


def errors(result: NavResult, traj) -> dict[str, np.ndarray]:
    """The estimate against a simulated truth (imulink.sim.navigation.NavTrajectory of the same
    samples), per sample from the start: horizontal and vertical position error (m), velocity
    error (m/s) and heading error (deg; the sensor's forward axis, y, in the horizontal)."""
    k = slice(result.start, None)
    e = nv.local_offsets(result.lat_deg, result.lon_deg, result.height_m, traj.lat_deg[k], traj.lon_deg[k],
                         traj.height_m[k])
    forward_true = Q.rotate(traj.quat[k], [0.0, 1.0, 0.0])
    forward = Q.rotate(result.quat, [0.0, 1.0, 0.0])
    heading = np.arctan2(forward[:, 0], forward[:, 1]) - np.arctan2(forward_true[:, 0], forward_true[:, 1])
    return {"horizontal": np.hypot(e[:, 0], e[:, 1]), "vertical": np.abs(e[:, 2]),
            "velocity": np.linalg.norm(result.vel_enu - traj.vel_enu[k], axis=1),
            "heading": np.degrees(np.abs(np.angle(np.exp(1j * heading))))}


def sample_rate_hz(timestamp_us: np.ndarray) -> float:
    """The rate of a sample stream from its timestamps (the median interval)."""
    intervals = np.diff(np.asarray(timestamp_us, dtype=np.float64))
    return 1e6 / float(np.median(intervals))


#: The largest lever arm the filter takes, each axis, m.
MAX_LEVER_ARM_M = 10.0

#: Where the filter can start (imu_nav.c's origin: +-85 deg latitude, +-180 deg longitude,
#: +-10 km above the ellipsoid) and the accuracy a start marker may say it has, m, each axis
#: (the filter takes accuracies from 1 mm to 2^30 mm; the horizontal one is sqrt(2) times it).
START_MAX_LAT_DEG, START_MAX_LON_DEG, START_MAX_HEIGHT_M = 85.0, 180.0, 10000.0
START_MAX_ACCURACY_M = 100000.0
DEFAULT_START_ACCURACY_M = 1.0


def start_error(lat_deg: float, lon_deg: float, height_m: float, accuracy_m: float) -> str | None:
    """Why the filter cannot start at this place with this accuracy (one line), None when it can."""
    for name, value in (("latitude", lat_deg), ("longitude", lon_deg), ("height", height_m),
                        ("accuracy", accuracy_m)):
        if not math.isfinite(value):
            return f"the {name} {value!r} is not a finite number"
    if abs(lat_deg) > START_MAX_LAT_DEG:
        return f"latitude {lat_deg:g} deg is beyond +-{START_MAX_LAT_DEG:g} deg, the nav filter's limit"
    if abs(lon_deg) > START_MAX_LON_DEG:
        return f"longitude {lon_deg:g} deg is beyond +-{START_MAX_LON_DEG:g} deg"
    if abs(height_m) > START_MAX_HEIGHT_M:
        return f"height {height_m:g} m is beyond +-{START_MAX_HEIGHT_M:g} m (10 km), the nav filter's limit"
    if not 0.0 < accuracy_m <= START_MAX_ACCURACY_M:
        return f"accuracy {accuracy_m:g} m is not above 0 and at most {START_MAX_ACCURACY_M:g} m"
    return None


def with_start(inp: NavInput, lat_deg: float, lon_deg: float, height_m: float,
               accuracy_m: float = DEFAULT_START_ACCURACY_M) -> NavInput:
    """`inp` with a marker's fix at its first sample (degrees, degrees, metres above the
    ellipsoid; `accuracy_m` one standard deviation on each axis, as a simulated marker's:
    a horizontal accuracy sqrt(2) times it), so that `run` starts there: position only,
    trusted as its accuracy says. The input's own fixes stay; one in the first row is used
    right after the second sample, its age one sample interval longer, so that it still
    counts for the instant it was valid (`run` refuses one that becomes over 1 s old).
    InputError for a place or an accuracy the filter does not take (start_error)."""
    problem = start_error(lat_deg, lon_deg, height_m, accuracy_m)
    if problem is not None:
        raise InputError(f"the start: {problem}")
    if len(inp) < 2:
        raise InputError(f"{len(inp)} sample(s); the nav filter needs at least 2")
    index = np.array(inp.fix_index, dtype=np.int64)
    age = np.zeros(len(index)) if inp.fix_age_s is None else np.array(inp.fix_age_s, dtype=np.float64)
    first_row = index == 0
    index[first_row] = 1
    age[first_row] += (int(inp.timestamp_us[1]) - int(inp.timestamp_us[0])) / 1e6
    s_acc = np.asarray(inp.fix_s_acc_m_s, dtype=np.float64)
    marker = np.isnan(s_acc) if inp.fix_is_marker is None else np.asarray(inp.fix_is_marker, dtype=bool)
    return replace(inp, fix_index=np.r_[0, index], fix_lat_deg=np.r_[float(lat_deg), inp.fix_lat_deg],
                   fix_lon_deg=np.r_[float(lon_deg), inp.fix_lon_deg],
                   fix_height_m=np.r_[float(height_m), inp.fix_height_m],
                   fix_h_acc_m=np.r_[float(accuracy_m) * math.sqrt(2.0), inp.fix_h_acc_m],
                   fix_v_acc_m=np.r_[float(accuracy_m), inp.fix_v_acc_m],
                   fix_vel_enu=np.vstack([np.full((1, 3), math.nan), np.reshape(inp.fix_vel_enu, (-1, 3))]),
                   fix_s_acc_m_s=np.r_[math.nan, s_acc], fix_age_s=np.r_[0.0, age], fix_is_marker=np.r_[True, marker])


#: The nav settings that tune the filter (imu_navkf_tuning_t, in this order).
TUNING_NAMES = ("gyro_noise", "acc_noise", "gyro_bias_walk", "acc_bias_walk", "gate", "reset_time", "rest_rate",
                "rest_force", "acc_range")


def tuning_settings(settings, rate_hz: float) -> dict[str, float]:
    """The board's nav settings (a dict by name in SI, or a settings file's FilterSettings)
    overlaid on the defaults, checked against the C core's ranges: SettingsError naming the
    setting and its range for an unknown name or a value outside it, and for `gnss_latency`
    (a recording's fixes take theirs from `--gnss-latency`, a CSV's from its rows)."""
    values = resolve_settings("nav", rate_hz, settings)
    for field in settings_fields("nav", "float"):
        value = values[field.name]
        if not (math.isfinite(value) and field.minimum <= value <= field.maximum):
            unit = "" if field.unit == "1" else f" {field.unit}"
            raise SettingsError(f"{field.name}={value:g} is outside {field.minimum:g} .. {field.maximum:g}{unit}")
    if values["gnss_latency"] != 0.0:
        raise SettingsError("gnss_latency is the board's; offline each fix's age comes from its row "
                            "(imulink nav --gnss-latency for a recording)")
    return values


def run(inp: NavInput, arithmetic: str = "fixed", lever_arm_m=None, settings=None) -> NavResult:
    """Run the filter over `inp` (a NavInput: imulink.io.nav_input); `lever_arm_m` is the GNSS
    antenna's position in the sensor frame (x right, y forward, z up), m, each axis within
    +-10 m (None: the settings' lever_arm_x, _y, _z, by default at the sensor); `settings`
    the board's nav settings by name (tuning_settings: the noise densities, the gate, the
    reset time, the rest bounds), None: the defaults. InputError when the input has no fix
    to start from or a rate the filter does not take; SettingsError for a bad setting."""
    if arithmetic not in ("fixed", "float"):
        raise ValueError(f"arithmetic must be 'fixed' or 'float', not {arithmetic!r}")
    if len(inp.fix_index) == 0:
        raise InputError("the input has no GNSS or position fix: the nav filter starts at the first one")
    rate = sample_rate_hz(inp.timestamp_us)
    if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        raise InputError(f"the samples come at {rate:g} Hz; the nav filter takes {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz")
    values = tuning_settings(settings, rate)
    arm = None
    if lever_arm_m is None and any(values[f"lever_arm_{axis}"] != 0.0 for axis in "xyz"):
        lever_arm_m = [values[f"lever_arm_{axis}"] for axis in "xyz"]
    if lever_arm_m is not None:
        arm = [float(v) for v in lever_arm_m]
        if len(arm) != 3 or not all(math.isfinite(v) and abs(v) <= MAX_LEVER_ARM_M for v in arm):
            raise InputError(f"a lever arm is three distances within +-{MAX_LEVER_ARM_M:g} m, not {lever_arm_m!r}")
    mod = _module(arithmetic)
    ffi, lib = mod.ffi, mod.lib
    fixed = arithmetic == "fixed"
    real = "int32_t" if fixed else "double"

    def convert(values, frac_bits: int, what: str):
        values = np.asarray(values, dtype=np.float64)
        if not fixed:
            return np.ascontiguousarray(values)
        scaled = np.round(values * 2.0 ** frac_bits)
        if np.any(np.abs(scaled) > 2 ** 31 - 1):
            raise InputError(f"{what} beyond the fixed-point range")
        return np.ascontiguousarray(scaled.astype(np.int32))

    start = int(inp.fix_index[0])
    mag = inp.mag if inp.mag is not None else np.zeros((len(inp), 3))
    gyr = convert(inp.gyr[start + 1:], 24, "an angular rate")
    acc = convert(inp.acc[start + 1:], 16, "a specific force")
    mags = convert(mag[start + 1:], 16, "a magnetic field")

    fixes = ffi.new("imu_navkf_fix_t[]", max(1, len(inp.fix_index)))
    for j in range(len(inp.fix_index)):
        f = fixes[j]
        has_vel = not math.isnan(float(inp.fix_s_acc_m_s[j]))
        marker = not has_vel if inp.fix_is_marker is None else bool(inp.fix_is_marker[j])
        f.source = lib.IMU_NAVKF_MARKER if marker else lib.IMU_NAVKF_GNSS
        f.has_vel = int(has_vel)
        lat, lon = math.radians(float(inp.fix_lat_deg[j])), math.radians(float(inp.fix_lon_deg[j]))
        if fixed:
            f.lat, f.lon = to_fixed(lat, _ANGLE_Q, "a latitude"), to_fixed(lon, _ANGLE_Q, "a longitude")
            f.height = to_fixed(float(inp.fix_height_m[j]) * 1000.0, 0, "a height")
            f.h_acc = max(1, to_fixed(float(inp.fix_h_acc_m[j]) * 1000.0, 0, "an accuracy"))
            f.v_acc = max(1, to_fixed(float(inp.fix_v_acc_m[j]) * 1000.0, 0, "an accuracy"))
            f.s_acc = max(1, to_fixed(float(inp.fix_s_acc_m_s[j]) * 1000.0, 0, "an accuracy")) if has_vel else 1000
            f.vel = [to_fixed(float(v), _VEL_Q, "a velocity") for v in inp.fix_vel_enu[j]] if has_vel else [0, 0, 0]
        else:
            f.lat, f.lon, f.height = lat, lon, float(inp.fix_height_m[j]) * 1000.0
            f.h_acc = float(inp.fix_h_acc_m[j]) * 1000.0
            f.v_acc = float(inp.fix_v_acc_m[j]) * 1000.0
            f.s_acc = float(inp.fix_s_acc_m_s[j]) * 1000.0 if has_vel else 1000.0
            f.vel = [float(v) for v in inp.fix_vel_enu[j]] if has_vel else [0.0, 0.0, 0.0]
        age = 0.0 if inp.fix_age_s is None else float(inp.fix_age_s[j])
        if not 0.0 <= age <= 1.0:
            raise InputError(f"a fix {age:g} s old at its row; the nav filter takes fixes up to 1 s late")
        f.age = to_fixed(age, 30, "a fix's age") if fixed else age

    state = ffi.new("imu_navkf_t *")
    start_acc = ffi.new(f"{real}[3]", [int(v) if fixed else float(v) for v in convert(inp.acc[start], 16, "a force")])
    start_mag = ffi.new(f"{real}[3]", [int(v) if fixed else float(v) for v in convert(mag[start], 16, "a field")])
    rate_value = to_fixed(rate, 16, "the sample rate") if fixed else rate
    arm_mm = ffi.NULL if arm is None else ffi.new(f"{real}[3]", [round(v * 1000.0) if fixed else v * 1000.0
                                                                  for v in arm])
    if lib.imu_navkf_start(state, rate_value, start_acc, start_mag, ffi.addressof(fixes[0]), arm_mm) != 0:
        raise InputError(f"the nav filter cannot start at line {start + 2}: a fix out of range (latitude beyond "
                         "85 deg, a height beyond 10 km) or an accelerometer that reads nothing")
    board_settings = _settings_struct(mod, arithmetic, "nav", values)
    tuning = next(field for field in settings_fields("nav", arithmetic) if field.name == TUNING_NAMES[0])
    # the settings' member `tuning` starts at its first field
    if lib.imu_navkf_tune(state, ffi.cast("imu_navkf_tuning_t *", board_settings + tuning.offset)) != 0:
        raise SettingsError("the nav filter's tuning takes positive values only")

    state0 = ffi.new("imu_navkf_t *", state[0])  # the start, kept for its row
    n = len(inp) - start - 1
    later = np.ascontiguousarray(inp.fix_index[1:] - (start + 1), dtype=np.int32)
    baro = inp.baro_index > start  # the samples after the start's
    baro_after = np.ascontiguousarray(inp.baro_index[baro] - (start + 1), dtype=np.int32)
    baro_pa = np.ascontiguousarray(np.rint(inp.baro_pa[baro]).astype(np.int32) if fixed
                                   else np.asarray(inp.baro_pa[baro], dtype=np.float64))
    accepted = np.zeros(len(later), dtype=np.uint8)
    lat_lon = np.zeros((n, 2), dtype=np.int32 if fixed else np.float64)
    height = np.zeros(n, dtype=lat_lon.dtype)
    vel = np.zeros((n, 3), dtype=lat_lon.dtype)
    quat = np.zeros((n, 4), dtype=lat_lon.dtype)
    var_mant = np.zeros((n, STATES), dtype=lat_lon.dtype)
    var_exp = np.zeros((n, STATES), dtype=np.int32)
    ptr = f"{real} *"
    lib.navkf_run(state, n, ffi.cast(ptr, ffi.from_buffer(gyr)), ffi.cast(ptr, ffi.from_buffer(acc)),
                  ffi.cast(ptr, ffi.from_buffer(mags)), ffi.cast("int32_t *", ffi.from_buffer(baro_after)),
                  len(baro_after), ffi.cast(ptr, ffi.from_buffer(baro_pa)),
                  ffi.cast("int32_t *", ffi.from_buffer(later)), len(later),
                  fixes + 1, ffi.cast("uint8_t *", ffi.from_buffer(accepted)), ffi.cast(ptr, ffi.from_buffer(lat_lon)),
                  ffi.cast(ptr, ffi.from_buffer(height)), ffi.cast(ptr, ffi.from_buffer(vel)),
                  ffi.cast(ptr, ffi.from_buffer(quat)), ffi.cast(ptr, ffi.from_buffer(var_mant)),
                  ffi.cast("int32_t *", ffi.from_buffer(var_exp)))

    scale = (lambda q: 2.0 ** -q) if fixed else (lambda q: 1.0)
    # the start's own row: the state imu_navkf_start left
    start_position = ffi.new(f"{real}[3]")
    lib.imu_navkf_position(state0, start_position, start_position + 1, start_position + 2)
    start_mant, start_exp = np.zeros((1, STATES), dtype=var_mant.dtype), np.zeros((1, STATES), dtype=np.int32)
    for i in range(STATES):
        m, e = ffi.new(ptr), ffi.new("int32_t *")
        lib.imu_navkf_variance(state0, i, m, e)
        start_mant[0, i], start_exp[0, i] = m[0], e[0]
    lat_lon = np.vstack([[start_position[0], start_position[1]], lat_lon])
    height = np.r_[start_position[2], height]
    vel = np.vstack([list(state0.nav.vel), vel])
    quat = np.vstack([list(state0.nav.q), quat])
    variance = np.vstack([start_mant, var_mant]) * np.exp2(np.vstack([start_exp, var_exp]) - (_VAR_Q if fixed else 0))
    return NavResult(
        start=start, timestamp_us=inp.timestamp_us[start:],
        lat_deg=np.degrees(lat_lon[:, 0] * scale(_ANGLE_Q)), lon_deg=np.degrees(lat_lon[:, 1] * scale(_ANGLE_Q)),
        height_m=height * scale(0) / 1000.0, vel_enu=vel * scale(_VEL_Q), quat=quat * scale(_QUAT_Q),
        sigma=np.sqrt(np.maximum(variance, 0.0)) * STATE_UNITS,
        fix_index=inp.fix_index[1:], fix_accepted=accepted.astype(bool),
        rejected=int(state.rejected), resets=int(state.resets), fades=int(state.fades),
        zero_velocity=int(state.zero_velocity), saturations=int(state.nav.saturations))
