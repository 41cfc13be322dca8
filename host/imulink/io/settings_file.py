"""Settings files: a filter's settings by name, in SI units, as JSON.

    {"format": "imulink-settings", "format_version": 1, "filter": "eskf",
     "settings": {"gyro_arw": 0.000967, "gyro_rrw": 4.6e-05, "acc_noise": 0.0116}}

`imulink allan ... --settings eskf --write FILE` writes one from a still board's noise
terms; `imulink record`, `inject` and `emulate` take one with `--settings FILE` (the
board gets the settings over the protocol, SET_SETTING), and so does `core.run`
(`settings=imulink.io.settings_file.load(FILE)`). Settings the file does not name keep the
filter's defaults. The sample rate is not a setting of the file: it belongs to the board
or the input.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from imulink import core
from imulink.io.files import FileError, read_regular_file, write_replacing

FORMAT = "imulink-settings"
FORMAT_VERSION = 1
MAX_BYTES = 1 << 20


class SettingsFileError(core.SettingsError):
    """A file that is not a usable settings file; the message names it and why."""


@dataclass(frozen=True)
class FilterSettings:
    """Settings of one filter in SI units, by the names of its C settings struct."""

    filter_name: str
    values: dict

    def raw(self) -> dict[str, int]:
        """The values as the board takes them (SET_SETTING): raw integers in each field's Q format."""
        fields = {f.name: f for f in core.settings_fields(self.filter_name)}
        return {name: core.to_fixed(value, fields[name].frac_bits, name) for name, value in self.values.items()}


def check(settings: FilterSettings, what: str = "the settings") -> FilterSettings:
    """`settings` if the filter knows every name and accepts every value (both builds'
    range checks); SettingsFileError naming `what` otherwise."""
    if settings.filter_name not in core.BOARD_FILTERS:
        raise SettingsFileError(f"{what}: unknown filter {settings.filter_name!r}; choose one of "
                                f"{', '.join(core.BOARD_FILTERS)}")
    if "sample_rate" in settings.values:
        raise SettingsFileError(f"{what}: sample_rate is not a setting of a settings file (the board's or the "
                                "input's rate is used)")
    for name, value in settings.values.items():
        if type(value) not in (int, float) or not math.isfinite(value):
            raise SettingsFileError(f"{what}: {name} is {value!r}, not a finite number")
    try:
        for arithmetic in core.ARITHMETICS:
            core.Filter(settings.filter_name, 100.0, arithmetic, settings.values)
    except core.SettingsError as exc:
        raise SettingsFileError(f"{what}: {exc}") from None
    return settings


def load(path) -> FilterSettings:
    """Read and check a settings file (SettingsFileError, one line, for anything wrong)."""
    try:
        data = json.loads(read_regular_file(path, MAX_BYTES))
    except FileError as exc:
        raise SettingsFileError(str(exc)) from None
    except (ValueError, RecursionError):
        raise SettingsFileError(f"{path} is not JSON (a settings file is)") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise SettingsFileError(f"{path} is not an imulink settings file (no \"format\": \"{FORMAT}\")")
    if data.get("format_version") != FORMAT_VERSION:
        raise SettingsFileError(f"{path}: settings format {data.get('format_version')!r} is not supported "
                                f"(this imulink reads format {FORMAT_VERSION})")
    if not isinstance(data.get("filter"), str) or not isinstance(data.get("settings"), dict):
        raise SettingsFileError(f"{path}: a settings file names its \"filter\" and holds \"settings\" by name")
    return check(FilterSettings(data["filter"], dict(data["settings"])), str(path))


def save(settings: FilterSettings, path, inputs=()) -> None:
    """Check and write the file atomically (a temporary file renamed)."""
    check(settings)
    units = {f.name: f.unit for f in core.settings_fields(settings.filter_name)}
    text = json.dumps({"format": FORMAT, "format_version": FORMAT_VERSION, "filter": settings.filter_name,
                       "settings": settings.values, "units": {name: units[name] for name in settings.values}},
                      indent=1) + "\n"
    write_replacing(path, lambda temporary: Path(temporary).write_text(text, encoding="utf-8"), inputs=inputs)
