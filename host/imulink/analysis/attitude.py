"""Attitude error metrics (the BROAD dataset's definitions) on w-first quaternions.

For an estimate q_est and a reference q_ref (both sensor-to-earth, ENU), the error
quaternion in the earth frame is e = q_est (x) q_ref^-1; total error 2 acos|e_w|,
heading error 2 atan|e_z / e_w|, inclination error 2 acos sqrt(e_w^2 + e_z^2).
"""
from __future__ import annotations

import numpy as np

from imulink.sim import quat


def attitude_errors(q_est, q_ref) -> dict[str, np.ndarray]:
    """Per-sample total, heading and inclination errors in degrees ((N,) arrays, NaN where q_ref is NaN)."""
    q_est = np.asarray(q_est, dtype=np.float64)
    q_ref = np.asarray(q_ref, dtype=np.float64)
    ref_inv = q_ref * np.array([1.0, -1.0, -1.0, -1.0])
    e = quat.multiply(q_est, ref_inv)
    e = e / np.linalg.norm(e, axis=-1, keepdims=True)
    ew, ez = np.abs(e[..., 0]), np.abs(e[..., 3])
    return {
        "total": np.degrees(2.0 * np.arccos(np.clip(ew, 0.0, 1.0))),
        "heading": np.degrees(2.0 * np.arctan2(ez, ew)),
        "inclination": np.degrees(2.0 * np.arccos(np.clip(np.sqrt(ew**2 + ez**2), 0.0, 1.0))),
    }


def rmse(errors: dict[str, np.ndarray], mask=None) -> dict[str, float]:
    """Root mean square of each error series over `mask` (default all), skipping NaN."""
    out = {}
    for key, values in errors.items():
        v = values if mask is None else values[np.asarray(mask, dtype=bool)]
        v = v[~np.isnan(v)]
        out[key] = float(np.sqrt(np.mean(v**2))) if v.size else float("nan")
    return out


def angle_difference(q1, q2) -> np.ndarray:
    """Total rotation angle between two quaternion series, degrees (sign-invariant)."""
    return attitude_errors(q1, q2)["total"]


def quat_to_euler(q) -> np.ndarray:
    """[roll, pitch, heading] in rad of w-first sensor-to-earth quaternions, in imulink's
    convention R = Rz(-heading) Rx(pitch) Ry(roll) (heading clockwise from north)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = np.moveaxis(q, -1, 0)
    r01 = 2 * (x * y - w * z)
    r11 = 1 - 2 * (x * x + z * z)
    r20 = 2 * (x * z - w * y)
    r21 = 2 * (y * z + w * x)
    r22 = 1 - 2 * (x * x + y * y)
    return np.stack([np.arctan2(-r20, r22), np.arctan2(r21, np.hypot(r01, r11)), np.arctan2(r01, r11)], axis=-1)


def wrap_deg(a):
    """Wrap angles in degrees to (-180, 180]."""
    return -((-np.asarray(a) + 180.0) % 360.0 - 180.0)
