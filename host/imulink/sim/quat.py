"""Small numpy quaternion helpers (scalar first: ``q = [w, x, y, z]``).

Every function broadcasts over leading dimensions: quaternions are ``(..., 4)``
arrays and vectors ``(..., 3)`` arrays.  Attitude quaternions in imulink rotate
sensor (body) vectors into the earth frame (ENU): ``v_earth = q ⊗ v_body ⊗ q*``.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "multiply",
    "conjugate",
    "normalize",
    "rotate",
    "rotate_inverse",
    "from_rotvec",
    "from_axis_angle",
    "from_zyx",
    "to_rotmat",
    "from_rotmat",
    "angle_between",
    "cumulative_product",
    "IDENTITY",
]

#: The identity rotation.
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def multiply(p, q) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` of (..., 4) quaternions."""
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q) -> np.ndarray:
    """Conjugate ``q*`` (the inverse of a unit quaternion)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q) -> np.ndarray:
    """Scale (..., 4) quaternions to unit norm."""
    q = np.asarray(q, dtype=np.float64)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rotate(q, v) -> np.ndarray:
    """Rotate vectors by unit quaternions: ``q ⊗ v ⊗ q*`` (body -> earth, i.e. ``R v``)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def rotate_inverse(q, v) -> np.ndarray:
    """Rotate vectors by the inverse of unit quaternions: ``q* ⊗ v ⊗ q`` (earth -> body, ``R^T v``)."""
    return rotate(conjugate(q), v)


def from_rotvec(rv) -> np.ndarray:
    """Quaternion exponential of a rotation vector (radians): ``exp([0, rv/2])``.

    ``rv = angle * unit_axis``; the result is ``[cos(angle/2), sin(angle/2) * axis]``.
    Exact (no small-angle approximation) and well behaved at ``rv = 0``.
    """
    rv = np.asarray(rv, dtype=np.float64)
    angle = np.linalg.norm(rv, axis=-1, keepdims=True)
    # sin(angle/2)/angle == 0.5 * sinc(angle / (2 pi)) with numpy's normalised sinc.
    k = 0.5 * np.sinc(angle / (2.0 * np.pi))
    return np.concatenate([np.cos(0.5 * angle), k * rv], axis=-1)


def from_axis_angle(axis, angle_rad) -> np.ndarray:
    """Quaternion of a rotation by ``angle_rad`` (radians) about ``axis`` (normalised here)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    return from_rotvec(axis * np.asarray(angle_rad, dtype=np.float64)[..., None])


def from_zyx(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """Quaternion from Z-Y-X (yaw, pitch, roll) angles in radians.

    ``q = qz(yaw) ⊗ qy(pitch) ⊗ qx(roll)``: roll about body x, pitch about body y,
    yaw about the earth up axis (counter-clockwise from east seen from above, ENU).
    This is the simulator's way to build an orientation, not the inverse of the angles
    the filters report (imulink.analysis.attitude.quat_to_euler: R = Rz(-heading)
    Rx(pitch) Ry(roll), heading clockwise from north).
    """
    ex = np.array([1.0, 0.0, 0.0])
    ey = np.array([0.0, 1.0, 0.0])
    ez = np.array([0.0, 0.0, 1.0])
    qx = from_axis_angle(ex, roll_rad)
    qy = from_axis_angle(ey, pitch_rad)
    qz = from_axis_angle(ez, yaw_rad)
    return multiply(qz, multiply(qy, qx))


def to_rotmat(q) -> np.ndarray:
    """(..., 3, 3) rotation matrix R of unit quaternions (``R v == rotate(q, v)``)."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def from_rotmat(m) -> np.ndarray:
    """Unit quaternions (w >= 0) of (..., 3, 3) rotation matrices (the inverse of
    :func:`to_rotmat`): Shepperd's method, from the largest of w, x, y, z, well-conditioned
    for any rotation."""
    m = np.asarray(m, dtype=np.float64)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # 4 w^2 = 1 + trace, 4 x^2 = 1 + m00 - m11 - m22, ...: take the largest
    squares = np.stack([1.0 + trace, 1.0 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                        1.0 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                        1.0 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]], axis=-1)
    big = np.argmax(squares, axis=-1)
    s = 2.0 * np.sqrt(np.take_along_axis(squares, big[..., None], axis=-1)[..., 0])  # 4 |largest|
    diff = np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)
    summ = np.stack([m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2]], -1)
    # rows: the quaternion from w, from x, from y, from z (each times 4 |largest| / s)
    cand = np.stack([
        np.stack([s / 4, diff[..., 0] / s, diff[..., 1] / s, diff[..., 2] / s], -1),
        np.stack([diff[..., 0] / s, s / 4, summ[..., 0] / s, summ[..., 1] / s], -1),
        np.stack([diff[..., 1] / s, summ[..., 0] / s, s / 4, summ[..., 2] / s], -1),
        np.stack([diff[..., 2] / s, summ[..., 1] / s, summ[..., 2] / s, s / 4], -1),
    ], axis=-2)
    q = np.take_along_axis(cand, big[..., None, None], axis=-2)[..., 0, :]
    return normalize(np.where(q[..., :1] < 0, -q, q))


def angle_between(q1, q2) -> np.ndarray:
    """Rotation angle (radians, in [0, pi]) of ``q1* ⊗ q2``; sign-invariant (q ≡ -q).

    Uses ``atan2`` so that small angles are accurate (unlike ``2 acos(|q1·q2|)``).
    """
    d = multiply(conjugate(q1), q2)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def cumulative_product(q) -> np.ndarray:
    """Running products ``out[k] = q[0] ⊗ q[1] ⊗ ... ⊗ q[k]`` of a (N, 4) array.

    Vectorised as a log2(N)-step parallel prefix scan (Hillis-Steele), so one hour at
    100 Hz takes a fraction of a second.  The result is renormalised to unit norm
    (the inputs are expected to be unit quaternions).
    """
    out = np.array(q, dtype=np.float64, copy=True)
    n = out.shape[0]
    d = 1
    while d < n:
        # The right-hand side is evaluated into a temporary before the assignment,
        # so every element combines the values of the previous step.
        out[d:] = multiply(out[:-d], out[d:])
        d *= 2
    return normalize(out)
