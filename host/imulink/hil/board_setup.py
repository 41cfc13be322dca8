"""Configure a board over its link: settings, sensor profile, calibration."""
from __future__ import annotations

from imulink import core, protocol
from imulink.board.link import Link
from imulink.core.calibration import SENSORS, Calibration, calibration_from_frames, to_fixed
from imulink.core.counts import SensorProfile, describe_profile, fixed_scales, profile_from_scales
from imulink.hil.common import HilError


def read_settings(link: Link) -> tuple[int, dict[int, dict]]:
    """The active filter's id and its settings (index -> SETTING fields), read with GET_SETTING."""
    first = link.query("GET_SETTING", index=0)
    settings = {0: first}
    for index in range(1, first["setting_count"]):
        settings[index] = link.query("GET_SETTING", index=index)
    return first["filter_id"], settings


def setting_range(setting: dict) -> tuple[float, float]:
    """The range [min, max] a SETTING states, in the setting's unit."""
    return setting["min"] / 2.0 ** setting["frac_bits"], setting["max"] / 2.0 ** setting["frac_bits"]


def setting_range_text(setting: dict) -> str:
    """"[0.001, 32767]": a SETTING's range, four significant digits (the ends are the Q
    format's nearest values: 0.001 in Q24 is 0.000999987)."""
    def short(value: float) -> str:
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"

    low, high = setting_range(setting)
    return f"[{short(low)}, {short(high)}]"


def apply_settings(link: Link, settings) -> None:
    """Make the settings file's filter (an imulink.io.settings_file.FilterSettings) active and
    give it the file's settings (SET_SETTING, raw); the others keep the board's values.
    HilError naming the setting the board refuses."""
    fields = core.settings_fields(settings.filter_name)
    link.command("SELECT_FILTER", filter_id=core.BOARD_FILTERS[settings.filter_name][0])
    raw = settings.raw()
    for index, f in enumerate(fields):
        if f.name in raw:
            try:
                link.command("SET_SETTING", index=index, value=raw[f.name])
            except protocol.CommandError as exc:
                raise HilError(f"the board refuses {f.name} = {settings.values[f.name]:g} {f.unit} "
                               f"({exc.reason})") from None


#: The protocol's sensor codes in the order of imulink.analysis.calibration.SENSORS.
_SENSOR_CODES = dict(zip(("gyr", "acc", "mag"), ("GYROSCOPE", "ACCELEROMETER", "MAGNETOMETER")))


def board_profile(hello: dict) -> SensorProfile:
    """The sensor profile a board states in its HELLO (its sensitivities; see
    counts.profile_from_scales). HilError when they are not usable."""
    try:
        return profile_from_scales(hello["gyro_scale"], hello["acc_scale"], hello["mag_scale"])
    except ValueError as exc:
        raise HilError(f"board {hello['board']!r} states no usable sensor sensitivities: {exc}") from None


def check_profile(declared: SensorProfile | None, hello: dict, what: str = "--profile") -> SensorProfile:
    """The board's profile (HELLO); HilError when `declared` (None: nothing declared) has
    other sensitivities, as every estimate would then differ."""
    board = board_profile(hello)
    if declared is not None and fixed_scales(declared) != fixed_scales(board):
        raise HilError(f"the board ({hello['board']}) states sensor profile {describe_profile(board)}; "
                       f"{what} says {describe_profile(declared)}")
    return board


def read_calibration(link: Link):
    """The board's calibration (GET_CALIBRATION of every sensor and axis), as an
    imulink.analysis.calibration.Calibration of the profile the board states (link.connect() first)."""
    frames = [link.query("GET_CALIBRATION", sensor=protocol.SENSORS[code], axis=axis)
              for code in _SENSOR_CODES.values() for axis in range(3)]
    assert link.hello is not None  # set by link.connect() (or listen()), which callers do first
    return Calibration(board_profile(link.hello), calibration_from_frames(frames))


def set_calibration(link: Link, calibration) -> None:
    """Give the board `calibration` (every sensor and axis: SET_CALIBRATION; a sensor the
    calibration lacks gets the identity). The board restarts its filter with each."""
    for name in SENSORS:
        offset, matrix = to_fixed(calibration.sensor(name))
        for axis in range(3):
            link.command("SET_CALIBRATION", sensor=protocol.SENSORS[_SENSOR_CODES[name]], axis=axis,
                         offset=offset[axis], row=tuple(matrix[3 * axis:3 * axis + 3]))


def leave_injection_mode(link: Link) -> None:
    if link.query("GET_STATUS")["injection_mode"]:
        link.command("SET_INJECTION_MODE", enabled=0)
