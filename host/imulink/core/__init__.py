"""Bindings to the C attitude core: the fixed-point build and its float twin.

`run()` feeds whole (N,3) arrays to C in one call per batch: the per-sample loop
never runs in Python. Settings travel as SI values (dicts keyed by the C field
names); they are converted to each field's Q format for the fixed build from the
descriptor table the C core exports, so the C header is the single definition.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import imulink.core._fixed as _core_fixed
import imulink.core._float as _core_float
from imulink import protocol
from imulink.core.calibration import MATRIX_FRAC_BITS, OFFSET_FRAC_BITS, SENSORS, CalibrationError
from imulink.core.calibration import to_fixed as calibration_to_fixed
from imulink.core.counts import (
    DEFAULT_PROFILE,
    SCALE_FRAC_BITS,
    SensorProfile,
    check_counts,
    fixed_scales,
    si_to_counts,
)
from imulink.errors import ImulinkError

ARITHMETICS = ("fixed", "float")

#: attitude filter name -> (id in imu_filter_id_t: the schema's filter code, C prefix of its settings symbols)
FILTERS = {name: (protocol.FILTER_IDS[name.upper()], f"imu_{name}") for name in ("eecf", "kf1d", "eskf")}
#: every filter the board runs: the attitude filters and the navigation filter (imu_navfilter.h:
#: position and velocity besides the attitude; Filter.run_nav_counts feeds it what it measures)
BOARD_FILTERS = {**FILTERS, "nav": (protocol.FILTER_IDS["NAV"], "imu_navfilter")}
#: filter id -> name, of every filter the board runs
FILTER_NAMES = {filter_id: name for name, (filter_id, _) in BOARD_FILTERS.items()}


def filter_name_of(filter_id: int) -> str:
    """The name of a filter id a board reports (the number itself for one this host does not know)."""
    return FILTER_NAMES.get(filter_id, str(filter_id))

#: Q formats of the fixed-build outputs: those of the ESTIMATE fields that carry them (shared/protocol.toml).
QUAT_FRAC_BITS = protocol.frac_bits("ESTIMATE", "quat")
EULER_FRAC_BITS = protocol.frac_bits("ESTIMATE", "euler")
RATE_FRAC_BITS = protocol.frac_bits("ESTIMATE", "gyro_bias")
#: Q formats of the ESKF's measurement weights and of the mantissas of its block-floating
#: covariance (P = mant * 2^(exp - COV_FRAC_BITS)), as ESTIMATE carries them.
WEIGHT_FRAC_BITS = protocol.frac_bits("ESTIMATE", "weights")
COV_FRAC_BITS = protocol.frac_bits("ESTIMATE", "cov_mantissa")
#: Scales of the fixed-build navigation outputs: latitude and longitude (rad) and velocity
#: (m/s) per raw count, those of NAV_STATE's lat, lon and vel.
NAV_ANGLE_SCALE = protocol.field_format("NAV_STATE", "lat").scale
NAV_VEL_SCALE = protocol.field_format("NAV_STATE", "vel").scale


class SettingsError(ImulinkError, ValueError):
    """An unknown setting name or a value outside its documented range."""


def _module(arithmetic: str):
    if arithmetic == "fixed":
        return _core_fixed
    if arithmetic == "float":
        return _core_float
    raise ValueError(f"arithmetic must be one of {ARITHMETICS}, not {arithmetic!r}")


def _check_filter(name: str) -> tuple[int, str]:
    try:
        return BOARD_FILTERS[name]
    except KeyError:
        raise ValueError(f"unknown filter {name!r}; choose one of {sorted(BOARD_FILTERS)}") from None


@dataclass(frozen=True)
class SettingField:
    name: str
    unit: str
    frac_bits: int  # Q format in the fixed build
    offset: int
    minimum: float  # the accepted range in the unit, as this build checks it (fixed: raw / 2^frac_bits)
    maximum: float


def settings_fields(filter_name: str, arithmetic: str = "fixed") -> list[SettingField]:
    """The settings of a filter as the C core declares them (name, unit, Q format,
    offset in that build's struct, accepted range)."""
    _, prefix = _check_filter(filter_name)
    mod = _module(arithmetic)
    descs = getattr(mod.lib, f"{prefix}_setting_descs")
    count = getattr(mod.lib, f"{prefix}_setting_count")
    scale = (lambda d: 2.0 ** -d.frac_bits) if arithmetic == "fixed" else (lambda d: 1.0)
    return [
        SettingField(
            mod.ffi.string(descs[i].name).decode(),
            mod.ffi.string(descs[i].unit).decode(),
            descs[i].frac_bits,
            descs[i].offset,
            descs[i].min * scale(descs[i]),
            descs[i].max * scale(descs[i]),
        )
        for i in range(count)
    ]


def default_settings(filter_name: str) -> dict[str, float]:
    """Default settings of a filter in SI units (read from the float build's defaults)."""
    _, prefix = _check_filter(filter_name)
    mod = _core_float
    struct = getattr(mod.lib, f"{prefix}_default_settings")
    base = mod.ffi.cast("char *", mod.ffi.addressof(struct))
    out = {}
    for f in settings_fields(filter_name, "float"):
        out[f.name] = float(mod.ffi.cast("double *", base + f.offset)[0])
    return out


def to_fixed(value: float, frac_bits: int, what: str = "value") -> int:
    """Round a real to Q`frac_bits` int32; SettingsError when it does not fit."""
    raw = int(np.rint(value * 2.0**frac_bits))
    if not -(2**31) <= raw < 2**31:
        raise SettingsError(f"{what}={value!r} does not fit the fixed-point format Q{frac_bits}")
    return raw


def _settings_struct(mod, arithmetic: str, filter_name: str, values: dict[str, float]):
    _, prefix = _check_filter(filter_name)
    ctype = f"{prefix}_settings_t"
    buf = mod.ffi.new("char[]", mod.ffi.sizeof(ctype))
    mod.ffi.memmove(buf, mod.ffi.addressof(getattr(mod.lib, f"{prefix}_default_settings")), mod.ffi.sizeof(ctype))
    fields = {f.name: f for f in settings_fields(filter_name, arithmetic)}
    for name, value in values.items():
        f = fields[name]
        if arithmetic == "fixed":
            mod.ffi.cast("int32_t *", buf + f.offset)[0] = to_fixed(value, f.frac_bits, name)
        else:
            mod.ffi.cast("double *", buf + f.offset)[0] = float(value)
    return buf


def plain_settings(settings, filter_name: str) -> dict | None:
    """A settings argument as a mapping for `filter_name`: a mapping or None as it is, named
    settings (`filter_name`, `values`) their values (SettingsError when they are another
    filter's)."""
    owner = getattr(settings, "filter_name", None)
    if owner is None:
        return settings
    if owner != filter_name:
        raise SettingsError(f"the settings are {owner}'s, the filter is {filter_name}")
    return settings.values


def resolve_settings(filter_name: str, rate_hz: float, settings) -> dict[str, float]:
    """Defaults overlaid with `settings` (a mapping by name, or named settings such as
    imulink.io.settings_file.FilterSettings: `filter_name` and `values`, which must be this
    filter's) and the sample rate; unknown names raise SettingsError."""
    settings = plain_settings(settings, filter_name)
    values = default_settings(filter_name)
    for name, value in (settings or {}).items():
        if name not in values:
            raise SettingsError(
                f"unknown setting {name!r} for filter {filter_name!r}; valid: {', '.join(sorted(values))}"
            )
        values[name] = float(value)
    if settings and "sample_rate" in settings and float(settings["sample_rate"]) != float(rate_hz):
        raise SettingsError("sample_rate in settings contradicts rate_hz")
    values["sample_rate"] = float(rate_hz)
    return values


def sensor_struct(mod, arithmetic: str, profile: SensorProfile):
    s = mod.ffi.new("imu_sensor_settings_t *")
    if arithmetic == "fixed":
        for name, value, q in zip(("gyro_scale", "acc_scale", "mag_scale"), fixed_scales(profile), SCALE_FRAC_BITS):
            setattr(s, name, to_fixed(value * 2.0**-q, q, name))  # the same integer; to_fixed checks it fits
    else:
        s.gyro_scale, s.acc_scale, s.mag_scale = profile.gyro_scale, profile.acc_scale, profile.mag_scale
    s.gyro_limits, s.acc_limits, s.mag_limits = profile.gyro_limits, profile.acc_limits, profile.mag_limits
    return s


def calibration_struct(mod, arithmetic: str, calibration, profile: SensorProfile):
    """The C imu_calibration_t of an imulink.analysis.calibration.Calibration (None: identity), from
    the integers the board takes (Q8 offsets, Q24 matrices), so that the fixed build and
    the float twin get identical parameters. SettingsError when it was made for another
    sensor profile than `profile` (its counts would mean something else) or lies beyond
    what the board accepts."""
    s = mod.ffi.new("imu_calibration_t *", mod.lib.imu_calibration_identity)
    if calibration is None:
        return s
    if calibration.profile != profile:
        raise SettingsError(f"the calibration was made for sensor profile {calibration.profile.name}, the filter runs "
                            f"on {profile.name}")
    for name in SENSORS:
        try:
            offset, matrix = calibration_to_fixed(calibration.sensor(name))
        except CalibrationError as exc:
            raise SettingsError(str(exc)) from None
        target = getattr(s, name)
        if arithmetic == "fixed":
            target.offset, target.matrix = offset, matrix
        else:
            target.offset = [v / 2.0**OFFSET_FRAC_BITS for v in offset]
            target.matrix = [v / 2.0**MATRIX_FRAC_BITS for v in matrix]
    return s


@dataclass
class RunResult:
    """Filter outputs for every sample.

    quat: (N,4) sensor-to-earth ENU quaternion, w first. euler: (N,3) [roll, pitch,
    heading] in rad (heading clockwise from north). gyro_bias: (N,3) rad/s.
    raw: the integer outputs of the fixed build (Q30 / Q29 / Q24), None for float.
    """

    filter_name: str
    arithmetic: str
    quat: np.ndarray
    euler: np.ndarray
    gyro_bias: np.ndarray
    saturations: int
    settings: dict = field(default_factory=dict)
    raw: dict | None = None


@dataclass
class NavBoardRun:
    """The nav filter's outputs for every sample as the board runs it (Filter.run_nav_counts):
    the ESTIMATE's attitude (quaternion, Euler angles, gyro bias: SI; raw: the fixed build's
    integers, None for float) and saturation count after each sample, the position (deg, m)
    and ENU velocity (m/s; zero before the first fix), and in the fixed build the NAV_STATE
    and ESTIMATE fields (name -> array, one row per sample)."""

    quat: np.ndarray
    euler: np.ndarray
    gyro_bias: np.ndarray
    raw: dict | None
    saturations: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    vel_enu: np.ndarray
    nav_states: dict | None
    estimates: dict | None = None  # the fixed build's ESTIMATE fields (name -> array), as the board sends them


_NUMPY_INTEGERS = {("int", 1): "i1", ("int", 2): "i2", ("int", 4): "i4", ("int", 8): "i8",
                   ("uint", 1): "u1", ("uint", 2): "u2", ("uint", 4): "u4", ("uint", 8): "u8"}


def _struct_columns(ffi, rows, ctype: str, n: int) -> dict[str, np.ndarray]:
    """The fields of n C structs of integers (a cffi array) as int64 columns (name -> (n,) or
    (n, length)), read through a NumPy view of the structs' own layout."""
    names, formats, offsets = [], [], []
    for name, member in ffi.typeof(ctype).fields:
        item = member.type.item if member.type.kind == "array" else member.type
        kind = "uint" if item.cname.startswith("uint") else "int"
        code = _NUMPY_INTEGERS[kind, ffi.sizeof(item)]
        names.append(name)
        formats.append(f"({member.type.length},){code}" if member.type.kind == "array" else code)
        offsets.append(member.offset)
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": ffi.sizeof(ctype)})
    view = np.frombuffer(ffi.buffer(rows, n * ffi.sizeof(ctype)), dtype, count=n)
    return {name: view[name].astype(np.int64) for name in names}


class Filter:
    """A filter instance of the C core: feed count arrays batch after batch."""

    def __init__(self, filter_name: str, rate_hz: float, arithmetic: str = "fixed", settings: dict | None = None,
                 profile: SensorProfile = DEFAULT_PROFILE, calibration=None):
        self.mod = _module(arithmetic)
        self.arithmetic = arithmetic
        self.filter_name = filter_name
        filter_id, _ = _check_filter(filter_name)
        self.settings = resolve_settings(filter_name, rate_hz, settings)
        self._handle = self.mod.ffi.new("imu_filter_t *")
        if self.mod.lib.imu_filter_init(self._handle, filter_id) != 0:
            raise ValueError(f"the core does not know filter {filter_name!r}")
        self.mod.lib.imu_filter_set_sensor(self._handle, sensor_struct(self.mod, arithmetic, profile))
        if self.mod.lib.imu_filter_set_calibration(self._handle, calibration_struct(self.mod, arithmetic, calibration,
                                                                                    profile)) != 0:
            raise SettingsError("the core refuses the calibration (an offset beyond 65536 counts)")
        if not self._apply(self.settings):
            defaults = default_settings(filter_name)
            bad = [k for k, v in self.settings.items() if not self._apply({**defaults, k: v})]
            fields = {f.name: f for f in settings_fields(filter_name, "float")}
            detail = ", ".join(f"{k}={self.settings[k]!r} {fields[k].unit} (range [{fields[k].minimum:g}, "
                               f"{fields[k].maximum:g}])" for k in bad) or str(self.settings)
            raise SettingsError(f"setting out of range for {filter_name!r}: {detail}")

    def _apply(self, values: dict[str, float]) -> bool:
        struct = _settings_struct(self.mod, self.arithmetic, self.filter_name, values)
        return self.mod.lib.imu_filter_set_settings(self._handle, struct) == 0

    def run_counts(self, gyr_counts, acc_counts, mag_counts) -> RunResult:
        """Run on register counts: (N,3) integers in the int16 range (SensorDataError otherwise)."""
        ffi, lib = self.mod.ffi, self.mod.lib
        arrays = [check_counts(name, a) for name, a in (("gyr", gyr_counts), ("acc", acc_counts),
                                                         ("mag", mag_counts))]
        n = arrays[0].shape[0]
        for a in arrays:
            if a.ndim != 2 or a.shape != (n, 3):
                raise ValueError(f"sensor arrays must all be (N,3); got {[x.shape for x in arrays]}")
        out_type = np.int32 if self.arithmetic == "fixed" else np.float64
        c_type = "int32_t *" if self.arithmetic == "fixed" else "double *"
        quat = np.empty((n, 4), out_type)
        euler = np.empty((n, 3), out_type)
        bias = np.empty((n, 3), out_type)
        lib.imu_filter_run(
            self._handle,
            *(ffi.cast("int16_t *", ffi.from_buffer(a)) for a in arrays),
            n,
            ffi.cast(c_type, ffi.from_buffer(quat)),
            ffi.cast(c_type, ffi.from_buffer(euler)),
            ffi.cast(c_type, ffi.from_buffer(bias)),
        )
        if self.arithmetic == "fixed":
            raw = {"quat": quat, "euler": euler, "gyro_bias": bias}
            quat_f = quat / 2.0**QUAT_FRAC_BITS
            euler_f = euler / 2.0**EULER_FRAC_BITS
            bias_f = bias / 2.0**RATE_FRAC_BITS
        else:
            raw, quat_f, euler_f, bias_f = None, quat, euler, bias
        return RunResult(self.filter_name, self.arithmetic, quat_f, euler_f, bias_f,
                         int(lib.imu_filter_saturations(self._handle)), dict(self.settings), raw)


    def run_nav_counts(self, gyr_counts, acc_counts, mag_counts, baro_after=(), baro_pa=(), gnss_after=(),
                       gnss=(), marker_after=(), markers=()) -> NavBoardRun:
        """Run the nav filter as the board runs it: after sample k its barometer readings
        (compensated Pa), its receiver's fixes (GNSS frame fields) and its markers (MARKER
        frame fields) whose *_after is k (each list ascending). Only for filter "nav"."""
        if self.filter_name != "nav":
            raise ValueError(f"run_nav_counts runs the nav filter, not {self.filter_name!r}")
        ffi, lib = self.mod.ffi, self.mod.lib
        arrays = [check_counts(name, a) for name, a in (("gyr", gyr_counts), ("acc", acc_counts),
                                                         ("mag", mag_counts))]
        n = arrays[0].shape[0]
        fixed = self.arithmetic == "fixed"

        def structs(ctype: str, rows):
            out = ffi.new(f"{ctype}[]", max(1, len(rows)))
            for k, row in enumerate(rows):
                for name, value in row.items():
                    if hasattr(out[k], name) and name not in ("timestamp_us", "index"):
                        setattr(out[k], name, value)
            return out

        def indices(values):
            return np.ascontiguousarray(np.asarray(values, dtype=np.int32).reshape(-1))

        baro_at, gnss_at, marker_at = indices(baro_after), indices(gnss_after), indices(marker_after)
        pressures = indices(baro_pa)
        outputs = ffi.new("imu_output_t[]", max(1, n))
        saturations = np.zeros(n, np.uint32)
        position = np.zeros((n, 6), np.int32 if fixed else np.float64)
        states = ffi.new("imu_proto_nav_state_t[]", max(1, n)) if fixed else ffi.NULL
        estimates = ffi.new("imu_proto_estimate_t[]", max(1, n)) if fixed else ffi.NULL
        lib.navfilter_run(self._handle, n, *(ffi.cast("int16_t *", ffi.from_buffer(a)) for a in arrays),
                          ffi.cast("int32_t *", ffi.from_buffer(baro_at)), len(baro_at),
                          ffi.cast("int32_t *", ffi.from_buffer(pressures)),
                          ffi.cast("int32_t *", ffi.from_buffer(gnss_at)), len(gnss_at),
                          structs("imu_proto_gnss_t", list(gnss)),
                          ffi.cast("int32_t *", ffi.from_buffer(marker_at)), len(marker_at),
                          structs("imu_proto_marker_t", list(markers)), outputs,
                          ffi.cast("uint32_t *", ffi.from_buffer(saturations)),
                          ffi.cast("int32_t *" if fixed else "double *", ffi.from_buffer(position)),
                          states, estimates)
        raw_out = {name: np.array([list(getattr(outputs[k], name)) for k in range(n)]).reshape(n, width)
                   for name, width in (("quat", 4), ("euler", 3), ("gyro_bias", 3))}
        scale = {"quat": QUAT_FRAC_BITS, "euler": EULER_FRAC_BITS, "gyro_bias": RATE_FRAC_BITS}
        si = {name: values / 2.0**scale[name] if fixed else values.astype(np.float64)
              for name, values in raw_out.items()}
        nav_states = _struct_columns(ffi, states, "imu_proto_nav_state_t", n) if fixed else None
        estimate_fields = _struct_columns(ffi, estimates, "imu_proto_estimate_t", n) if fixed else None
        lat_lon_scale, vel_scale = (NAV_ANGLE_SCALE, NAV_VEL_SCALE) if fixed else (1.0, 1.0)
        return NavBoardRun(si["quat"], si["euler"], si["gyro_bias"], raw_out if fixed else None,
                           saturations.astype(np.int64), np.degrees(position[:, 0] * lat_lon_scale),
                           np.degrees(position[:, 1] * lat_lon_scale), position[:, 2] / 1000.0,
                           position[:, 3:] * vel_scale, nav_states, estimate_fields)

    def run_estimates(self, gyr_counts, acc_counts, mag_counts) -> dict[str, np.ndarray]:
        """Run on register counts and return the ESTIMATE the board sends after each sample
        (name -> array, one row per sample, numbered from 0), assembled by the core's
        imu_wire_estimate, the board's own function. Fixed build only."""
        if self.arithmetic != "fixed":
            raise ValueError("ESTIMATE carries the fixed build's integers")
        ffi, lib = self.mod.ffi, self.mod.lib
        arrays = [check_counts(name, a) for name, a in (("gyr", gyr_counts), ("acc", acc_counts),
                                                         ("mag", mag_counts))]
        n = arrays[0].shape[0]
        estimates = ffi.new("imu_proto_estimate_t[]", max(1, n))
        lib.estimates_run(self._handle, n, *(ffi.cast("int16_t *", ffi.from_buffer(a)) for a in arrays), estimates)
        return _struct_columns(ffi, estimates, "imu_proto_estimate_t", n)

    def estimate(self, index: int) -> dict:
        """The ESTIMATE fields (name -> int, or list for arrays) the board sends after the last
        sample, numbered `index`: assembled by the core's imu_wire_estimate, the board's own
        function. Fixed build only (the message carries its integers)."""
        if self.arithmetic != "fixed":
            raise ValueError("ESTIMATE carries the fixed build's integers")
        ffi, lib = self.mod.ffi, self.mod.lib
        out, msg = ffi.new("imu_output_t *"), ffi.new("imu_proto_estimate_t *")
        lib.imu_filter_get(self._handle, out)
        lib.imu_wire_estimate(self._handle, out, index, msg)
        return {name: list(getattr(msg, name)) if length else getattr(msg, name)
                for name, _, length in protocol.message_fields("ESTIMATE")}

    def state(self) -> bytes:
        """The filter's complete state as the board's CHECKPOINT carries it (imu_filter_state
        in firmware/core/imu_filter.h): fixed build only, whose bytes lie as on the board."""
        if self.arithmetic != "fixed":
            raise ValueError("a checkpoint is the fixed build's state")
        lib = self.mod.lib
        return bytes(self.mod.ffi.buffer(lib.imu_filter_state(self._handle), lib.imu_filter_state_size(self._handle)))

    def restore(self, state: bytes) -> None:
        """Put back a state :meth:`state` or a board's CHECKPOINT gave (of the same filter,
        with the same settings); ValueError for bytes of another size."""
        if self.arithmetic != "fixed":
            raise ValueError("a checkpoint is the fixed build's state")
        if self.mod.lib.imu_filter_restore(self._handle, state, len(state)) != 0:
            raise ValueError(f"a checkpoint of {len(state)} bytes is not a state of {self.filter_name!r} "
                             f"({self.mod.lib.imu_filter_state_size(self._handle)} bytes)")

    def _eskf(self):
        state = self.mod.lib.imu_filter_eskf(self._handle)
        if state == self.mod.ffi.NULL:
            raise ValueError(f"filter {self.filter_name!r} has no error-state covariance (only 'eskf' has)")
        return state

    def covariance(self) -> np.ndarray:
        """ESKF error-state covariance (n x n, n = 9 or 6) in the state units: rad, rad/s, g.

        Reconstructed from the block-floating storage: P_ij = mant * 2^(exp - 30) in
        the fixed build, the double itself in the float build.
        """
        state = self._eskf()
        ffi, lib = self.mod.ffi, self.mod.lib
        n = lib.imu_eskf_state_count(state)
        mant = ffi.new("int32_t *" if self.arithmetic == "fixed" else "double *")
        exp = ffi.new("int32_t *")
        out = np.empty((n, n))
        for i in range(n):
            for j in range(n):
                lib.imu_eskf_covariance(state, i, j, mant, exp)
                out[i, j] = mant[0] * 2.0 ** (exp[0] - COV_FRAC_BITS) if self.arithmetic == "fixed" else mant[0]
        return out

    def covariance_diagonal_raw(self) -> tuple[list[int], list[int]]:
        """ESKF covariance diagonal exactly as the fixed build stores it (what the board
        sends in ESTIMATE): 9 mantissas and exponents, P_ii = mant * 2^(exp - 30), zeros
        past the state count. Fixed build only."""
        if self.arithmetic != "fixed":
            raise ValueError("the raw covariance exists in the fixed build only")
        state = self._eskf()
        ffi, lib = self.mod.ffi, self.mod.lib
        mant, exp = ffi.new("int32_t *"), ffi.new("int32_t *")
        mantissas, exponents = [0] * 9, [0] * 9
        for i in range(lib.imu_eskf_state_count(state)):
            lib.imu_eskf_covariance(state, i, i, mant, exp)
            mantissas[i], exponents[i] = mant[0], exp[0]
        return mantissas, exponents

    def measurement_weights(self) -> tuple[float, float]:
        """ESKF weights of the last gravity and heading updates, in [0, 1] (0: rejected)."""
        state = self._eskf()
        ctype = "int32_t *" if self.arithmetic == "fixed" else "double *"
        gravity, heading = self.mod.ffi.new(ctype), self.mod.ffi.new(ctype)
        self.mod.lib.imu_eskf_get_weights(state, gravity, heading)
        scale = 2.0**-WEIGHT_FRAC_BITS if self.arithmetic == "fixed" else 1.0
        return gravity[0] * scale, heading[0] * scale

    def measurement_weights_raw(self) -> list[int]:
        """The same weights as the fixed build stores them (what the board sends in
        ESTIMATE): Q30 integers. Fixed build only."""
        if self.arithmetic != "fixed":
            raise ValueError("the raw weights exist in the fixed build only")
        return [round(w * 2**WEIGHT_FRAC_BITS) for w in self.measurement_weights()]

    def acc_bias(self) -> np.ndarray:
        """ESKF accelerometer bias estimate, m/s^2 (3,)."""
        state = self._eskf()
        out = self.mod.ffi.new("int32_t[3]" if self.arithmetic == "fixed" else "double[3]")
        self.mod.lib.imu_eskf_get_acc_bias(state, out)
        scale = 2.0**-24 if self.arithmetic == "fixed" else 1.0
        return np.array([out[k] * scale for k in range(3)])


def run_counts(filter_name: str, gyr_counts, acc_counts, mag_counts, rate_hz: float, arithmetic: str = "fixed",
               settings: dict | None = None, profile: SensorProfile = DEFAULT_PROFILE, calibration=None) -> RunResult:
    """Run a filter on raw register counts ((N,3) integers in the int16 range; anything
    else raises counts.SensorDataError). calibration: an imulink.analysis.calibration.Calibration
    applied to the counts first, as the board applies it (None: none)."""
    return Filter(filter_name, rate_hz, arithmetic, settings, profile, calibration).run_counts(
        gyr_counts, acc_counts, mag_counts)


def run(filter_name: str, gyr, acc, mag, rate_hz: float, arithmetic: str = "fixed", settings=None,
        profile: SensorProfile = DEFAULT_PROFILE, calibration=None) -> RunResult:
    """Run a filter on SI arrays: gyr (N,3) rad/s, acc (N,3) m/s^2, mag (N,3) uT.

    settings: by name in SI (a dict, or a settings file: imulink.io.settings_file.load(path));
    the others keep their defaults. calibration: see :func:`run_counts`.

    The arrays are first converted to counts with :func:`imulink.core.counts.si_to_counts`
    and `profile`, so fixed and float runs see identical inputs: values beyond a
    sensor's range are clipped to it as the sensor saturates, NaN or infinite values
    raise SensorDataError.
    """
    g, a, m = si_to_counts(gyr, acc, mag, profile)
    return run_counts(filter_name, g, a, m, rate_hz, arithmetic, settings, profile, calibration)
