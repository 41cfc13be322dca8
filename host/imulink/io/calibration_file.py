"""The calibration file: a sensor profile (the counts mean something only with it) and one
correction per sensor calibrated, as JSON; :func:`save` writes it atomically."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from imulink.core.calibration import (
    FORMAT,
    FORMAT_VERSION,
    SENSORS,
    Calibration,
    CalibrationError,
    SensorCalibration,
    to_fixed,
)
from imulink.core.counts import SensorProfile, profile_from_json, profile_to_json
from imulink.io.files import FileError, read_regular_file, write_replacing


def to_json(calibration: Calibration) -> dict:
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "profile": profile_to_json(calibration.profile),
            "sensors": {name: {"offset_counts": c.offset.tolist(), "matrix": c.matrix.tolist(), "report": c.report}
                        for name, c in calibration.sensors.items()}}


def from_json(data, what: str) -> Calibration:
    """A Calibration from its JSON; CalibrationError naming `what` when it is not one."""
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
