"""The calibration a board reports in its CALIBRATION frames."""
from __future__ import annotations

from imulink import protocol
from imulink.core.calibration import (
    MATRIX_FRAC_BITS,
    OFFSET_FRAC_BITS,
    SENSORS,
    CalibrationError,
    SensorCalibration,
    from_fixed,
)


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
