"""The integration half of calib/gyrorot.py: the windows between consecutive still poses
(clean of saturation and lost samples), their ramp-weighted, bias-corrected increments and
the quaternion composition at the sample rate (an associative prefix scan, vectorised over
samples and rotations).  See gyrorot's docstring for the method."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ..npstats import median

#: a sample within 4 LSB of a 16-bit converter's full scale is at the rail
RAIL_FRACTION = 1.0 - 4.0 / 32768.0
#: a time step longer than this many median steps means samples were lost
GAP_FACTOR = 1.5
_D2R = np.pi / 180.0


def rotation_windows(t_s, gyro_dps, slices: Sequence[slice], range_dps: Optional[float] = None):
    """(windows, left_out): for each consecutive pair of still intervals p, p+1 whose samples
    and the motion between are clean, (p, s, a, b, e): pose p's first and last sample, pose
    p+1's first and last; left_out counts the pairs dropped as ``saturated`` or ``gap``."""
    t = np.asarray(t_s, float)
    g = np.asarray(gyro_dps, float)
    step = float(median(np.diff(t))) if len(t) > 1 else 0.0
    rail = None if not range_dps else RAIL_FRACTION * float(range_dps)
    out, left = [], {"saturated": 0, "gap": 0}
    for p in range(len(slices) - 1):
        s, a = slices[p].start, slices[p].stop - 1
        b, e = slices[p + 1].start, slices[p + 1].stop - 1
        if b <= a:
            continue
        if np.any(np.diff(t[s:e + 1]) > GAP_FACTOR * step):
            left["gap"] += 1
            continue
        if rail is not None and np.any(np.abs(g[s:e + 1]) >= rail):
            left["saturated"] += 1
            continue
        out.append((p, s, a, b, e))
    return out, left


def _qmul(p, q):
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw], -1)


def _qmat(q):
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def _prefix_rotations(theta_rad):
    """theta (R, L, 3) body-frame increments -> prefix rotation matrices (R, L, 3, 3):
    P_k = exp(theta_1) ... exp(theta_k) (Hillis-Steele scan of quaternion products)."""
    ang = np.linalg.norm(theta_rad, axis=-1, keepdims=True)
    half = 0.5 * ang
    sinc = np.where(ang > 1e-12, np.sin(half) / np.where(ang > 1e-12, ang, 1.0), 0.5)
    q = np.concatenate([np.cos(half), theta_rad * sinc], -1)
    L = q.shape[1]
    d = 1
    while d < L:
        q = np.concatenate([q[:, :d], _qmul(q[:, :-d], q[:, d:])], 1)
        d *= 2
    return _qmat(q)


class _Windows:
    """The rotations' increments, padded to one length (zeros): weight x (raw - b(t) - G a) x
    dt (deg, trapezoid).  A window runs from the
    first sample of pose p to the last of pose p+1; inside the poses the increments are
    ramp-weighted, so that the composed rotation runs from pose p's mean orientation to pose
    p+1's (the orientations their mean directions belong to, to first order in the small
    in-pose angles: tremor, a slow start of the motion).  b(t): each pose's offset inside it,
    the straight line between the two offsets during the motion."""

    def __init__(self, t, gyro, acc, wins, offsets, G):
        L = max(b - a for _, _, a, b, _ in wins) + 2
        R = len(wins)
        self.vd = np.zeros((R, L, 3))       # increments, deg (before K)
        self.wdt2 = np.zeros(R)             # s^2: the angle's white-noise variance / per-sample variance
        self.T = np.zeros(R)                # motion time, s
        for r, (p, s, a, b, e) in enumerate(wins):
            tt = t[s:e + 1]
            f = np.clip((tt - t[a]) / max(t[b] - t[a], 1e-12), 0.0, 1.0)
            bias = (1 - f)[:, None] * offsets[p] + f[:, None] * offsets[p + 1]
            w = gyro[s:e + 1] - bias - acc[s:e + 1] @ G.T
            k = np.arange(s + 1, e + 1)            # increment k: samples k-1 .. k
            wt = np.ones(len(k))
            pre, post = k <= a, k > b
            wt[pre] = (k[pre] - s) / (a - s + 1)
            wt[post] = (e - k[post] + 1) / (e - b + 1)
            d = 0.5 * (w[1:] + w[:-1]) * (wt * np.diff(tt))[:, None]
            # the in-pose parts (angles well under a degree) each compose as one increment
            n = b - a
            self.vd[r, 0] = d[pre].sum(0)
            self.vd[r, 1:n + 1] = d[~pre & ~post]
            self.vd[r, n + 1] = d[post].sum(0)
            # white noise: each sample's coefficient in the angle (s): its share of the weighted
            # increments less its share of the pose-mean bias subtracted over the window
            wd = wt * np.diff(tt)
            fm = 0.5 * (f[1:] + f[:-1])
            coef = np.zeros(len(tt))
            coef[:-1] += 0.5 * wd
            coef[1:] += 0.5 * wd
            coef[:a - s + 1] -= np.sum(wd * (1 - fm)) / (a - s + 1)
            coef[b - s:] -= np.sum(wd * fm) / (e - b + 1)
            self.wdt2[r] = float(coef @ coef)
            self.T[r] = t[b] - t[a]

    def integrate(self, K, idx=None):
        """(Delta (R, 3, 3), S (R, 3, 3, 3)): the rotation over each window (those ``idx``
        when given) and S[:, :, a, b] = sum_k P_k[:, a] vd_k[b] (rad)."""
        vd = (self.vd if idx is None else self.vd[idx]) * _D2R
        P = _prefix_rotations(np.einsum("ij,rlj->rli", K, vd))
        S = np.einsum("rlia,rlb->riab", P, vd)
        return P[:, -1], S


def _tangent(u):
    """Two unit vectors perpendicular to each row of u (R, 3): (R, 3, 2)."""
    ref = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(u, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(u, e1)], -1)


def predict_directions(Delta, start):
    """The start directions (R, 3) carried through the rotations: Delta^T u."""
    return np.einsum("rji,rj->ri", Delta, start)


def _angle_deg(x, y):
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(x, y), axis=1), np.einsum("ri,ri->r", x, y)))
