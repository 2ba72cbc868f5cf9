"""Quaternion arithmetic over numpy arrays, in the stream's convention.

A quaternion is ``[w, x, y, z]`` (scalar first), a unit quaternion ``q`` rotates body-frame
vectors into the earth frame ENU (x east, y north, z up; ROS REP-103):
``v_enu = q * v_body * conj(q)``.  Arrays are (4,) or (n, 4); vectors (3,) or (n, 3).
Pure functions, no state.
"""
from __future__ import annotations

import numpy as np

__all__ = ["qmul", "qconj", "qnormalize", "rotate", "rotate_inv", "up_in_body", "euler_deg", "compass_heading_deg",
           "gravity_free_g", "error_angles_rad", "rmse_deg"]


def qmul(a, b) -> np.ndarray:
    """Hamilton product a * b (row by row)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def qconj(q) -> np.ndarray:
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


def qnormalize(q) -> np.ndarray:
    q = np.asarray(q, float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _matrix_rows(q):
    """The rotation matrix of q (body -> ENU), as nine arrays r00..r22 (row-major)."""
    q = np.asarray(q, float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    return (1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy))


def rotate(q, v) -> np.ndarray:
    """q * v * conj(q): a body-frame vector v in ENU (row by row)."""
    r = _matrix_rows(q)
    v = np.asarray(v, float)
    a, b, c = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([r[0] * a + r[1] * b + r[2] * c, r[3] * a + r[4] * b + r[5] * c,
                     r[6] * a + r[7] * b + r[8] * c], -1)


def rotate_inv(q, v) -> np.ndarray:
    """conj(q) * v * q: an ENU vector v in the body frame."""
    r = _matrix_rows(q)
    v = np.asarray(v, float)
    a, b, c = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([r[0] * a + r[3] * b + r[6] * c, r[1] * a + r[4] * b + r[7] * c,
                     r[2] * a + r[5] * b + r[8] * c], -1)


def up_in_body(q) -> np.ndarray:
    """The ENU up axis (0, 0, 1) in the body frame: the third row of the rotation matrix."""
    q = np.asarray(q, float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)


def euler_deg(q) -> np.ndarray:
    """(roll, pitch, yaw) in degrees, REP-103's fixed-axis x-y-z angles (R = Rz(yaw) Ry(pitch)
    Rx(roll)); yaw is counter-clockwise from east (ENU)."""
    q = qnormalize(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.degrees(np.stack([roll, pitch, yaw], -1))


def compass_heading_deg(q) -> np.ndarray:
    """Heading of the body x axis as a compass reads it: degrees clockwise from north
    (the ENU frame's y axis), in [0, 360)."""
    return np.mod(90.0 - euler_deg(q)[..., 2], 360.0)


def gravity_free_g(q, acc_g) -> np.ndarray:
    """Specific force minus gravity's share, body frame, g: acc_g - conj(q) * (0, 0, 1) * q.
    An accelerometer at rest reads +1 g up (specific force), so this is ~0 at rest."""
    return np.asarray(acc_g, float) - up_in_body(q)


def error_angles_rad(q_est, q_ref):
    """BROAD's error metric (Laidig et al., Data 2021, ``calculateRMSE``): the error quaternion
    in the earth frame e = q_est * conj(q_ref); returns (total, heading, inclination) angles,
    rad, per row: 2 acos|e_w|, 2 atan|e_z / e_w|, 2 acos sqrt(e_w^2 + e_z^2)."""
    e = qmul(qnormalize(q_est), qconj(qnormalize(q_ref)))
    ew, ez = np.abs(e[..., 0]), e[..., 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        total = 2 * np.arccos(np.clip(ew, -1.0, 1.0))
        heading = 2 * np.arctan(np.abs(ez / ew))
        incl = 2 * np.arccos(np.clip(np.sqrt(ew ** 2 + ez ** 2), -1.0, 1.0))
    return total, heading, incl


def rmse_deg(x_rad, mask=None) -> float:
    """RMS in degrees over ``mask`` (NaN rows skipped, as the metric's nanmean)."""
    x = np.asarray(x_rad, float)
    if mask is not None:
        x = x[mask]
    return float(np.degrees(np.sqrt(np.nanmean(x ** 2))))
