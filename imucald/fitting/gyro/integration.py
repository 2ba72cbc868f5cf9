"""The integration half of fitting/gyro/rotations.py: the windows between consecutive still poses
(clean of saturation and lost samples), their ramp-weighted, bias-corrected increments and
the quaternion composition at the sample rate (a two-level prefix scan over complex-pair
quaternions, vectorised over samples and rotations: the same products as composing sample
by sample, to rounding).  See gyrorot's docstring for the method."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ...numerics.rates import PAUSE_FACTOR, effective_rate

#: a sample within 4 LSB of a 16-bit converter's full scale is at the rail
RAIL_FRACTION = 1.0 - 4.0 / 32768.0
#: samples were lost in a rotation's motion (between the two holds; the holds' own losses do
#: not count) when a time step is longer than the hole limit, max(HOLE_FACTOR, 1 + 5 x the
#: steps' relative scatter) periods, or when the motion's span holds MISSING_MIN more
#: periods than it has steps.  The period is the mean step between distinct timestamps, pauses out (numerics/rates.py effective_rate): the median step was
#: 0 in a file of duplicated rows, where every step read as a loss.  A step over 1.5 periods
#: was the only test: stamps jittering by 15 % of the period, or a whole-ms clock at 416 Hz
#: (steps of 1-4 ms for 2.4), make such steps in every rotation with nothing lost (an
#: independent probe: 27 of 31 rotations left out, K and G unfitted).  The count sees a lost
#: sample however the stamps jitter (the span's error is two stamps').  Measured on 200
#: seeds of tests/test_gyrorot.py's jittered 9-window session, at jitter 0, 5, 15 and 25 %
#: of the period: windows wrongly left out 0, 0, 0.17 and 2.0 %; one lost sample seen
#: 100, 100, 83 and 62 %
HOLE_FACTOR, MISSING_MIN = 1.5, 0.75
D2R = np.pi / 180.0


def rotation_windows(t_s, gyro_dps, slices: Sequence[slice], range_dps: Optional[float] = None):
    """(windows, left_out): for each consecutive pair of still intervals p, p+1 whose samples
    and the motion between are clean, (p, s, a, b, e): pose p's first and last sample, pose
    p+1's first and last; left_out counts the pairs dropped as ``saturated`` or ``gap``."""
    t = np.asarray(t_s, float)
    g = np.asarray(gyro_dps, float)
    new_stamp = np.concatenate([[True], np.diff(t) > 0])
    steps = np.cumsum(new_stamp)                  # distinct stamps up to each row
    rate = effective_rate(t[new_stamp]) if len(t) > 1 else 0.0
    step = 1.0 / rate if rate > 0 else 0.0
    hole = HOLE_FACTOR * step
    if step > 0:
        d = np.diff(t[new_stamp])
        d = d[d <= PAUSE_FACTOR * step]
        if len(d) > 1:
            hole = max(hole, step + 5.0 * float(np.std(d)))
    rail = None if not range_dps else RAIL_FRACTION * float(range_dps)
    out, left = [], {"saturated": 0, "gap": 0}
    for p in range(len(slices) - 1):
        s, a = slices[p].start, slices[p].stop - 1
        b, e = slices[p + 1].start, slices[p + 1].stop - 1
        if b <= a:
            continue
        # lost samples count in the motion only (last sample of pose p .. first of p+1):
        # inside the holds the rates are the bias and noise, integrated over the stamps' own
        # steps, so a lost still sample moves the angle by ~bias error x one period; checked
        # over the whole window, 0.2 % of a serial logger's rows lost inside the holds left
        # out every rotation (a cold review: K and G "not fitted" on 4 such files)
        missing = (t[b] - t[a]) / step - (steps[b] - steps[a]) if step > 0 else 0.0
        if missing >= MISSING_MIN or np.any(np.diff(t[a:b + 1]) > hole):
            left["gap"] += 1
            continue
        if rail is not None and np.any(np.abs(g[s:e + 1]) >= rail):
            left["saturated"] += 1
            continue
        out.append((p, s, a, b, e))
    return out, left


def _cmul(a, b, c, d):
    """The quaternion product (a + b j)(c + d j) = (ac - b conj(d)) + (ad + b conj(c)) j,
    a quaternion w + x i + y j + z k held as the complex pair (w + x i, y + z i)."""
    return a * c - b * d.conj(), a * d + b * c.conj()


def _prefix_products(a, b):
    """Prefix products along axis 1 of unit quaternions held as complex pairs a, b (R, L):
    out[:, k] = q_0 ... q_k.  A two-level scan: sequential products inside blocks of
    m ~ sqrt(L) samples (each step over all rotations and blocks at once), then over the
    blocks' totals, then one product joins them: 2 sqrt(L) small array steps instead of
    log2(L) passes over everything.  The same products as a sample-by-sample composition,
    grouped differently (rounding only: ~1e-15 rad over a thousand samples)."""
    R, L = a.shape
    m = max(1, int(np.ceil(np.sqrt(L))))
    nb = -(-L // m)
    if nb * m > L:                              # pad with identities
        a = np.concatenate([a, np.ones((R, nb * m - L), complex)], 1)
        b = np.concatenate([b, np.zeros((R, nb * m - L), complex)], 1)
    # sample-in-block first, so that each step reads and writes contiguous (R, nb) slices;
    # the conjugates each step needs are taken once
    a = np.ascontiguousarray(a.reshape(R, nb, m).transpose(2, 0, 1))
    b = np.ascontiguousarray(b.reshape(R, nb, m).transpose(2, 0, 1))
    ac, bc = a.conj(), b.conj()
    oa, ob = np.empty_like(a), np.empty_like(b)
    pa, pb = oa[0], ob[0] = a[0], b[0]
    for j in range(1, m):
        pa, pb = oa[j], ob[j] = pa * a[j] - pb * bc[j], pa * b[j] + pb * ac[j]
    if nb > 1:
        ta, tb = oa[-1], ob[-1]                     # (R, nb): each block's total
        qa, qb = np.empty_like(ta), np.empty_like(tb)
        pa, pb = qa[:, 0], qb[:, 0] = ta[:, 0], tb[:, 0]
        for k in range(1, nb - 1):
            pa, pb = qa[:, k], qb[:, k] = _cmul(pa, pb, ta[:, k], tb[:, k])
        oa[:, :, 1:], ob[:, :, 1:] = _cmul(qa[None, :, :-1], qb[None, :, :-1], oa[:, :, 1:], ob[:, :, 1:])
    oa, ob = oa.transpose(1, 2, 0), ob.transpose(1, 2, 0)
    return oa.reshape(R, -1)[:, :L], ob.reshape(R, -1)[:, :L]


def _prefix_rotations(theta_rad):
    """theta (R, L, 3) body-frame increments -> prefix rotation matrices (R, L, 3, 3):
    P_k = exp(theta_1) ... exp(theta_k) (quaternion products, :func:`_prefix_products`)."""
    ang = np.sqrt(np.einsum("rli,rli->rl", theta_rad, theta_rad))
    half = 0.5 * ang
    small = ang <= 1e-12
    sinc = np.sin(half) / np.where(small, 1.0, ang)
    sinc[small] = 0.5
    v = theta_rad * sinc[..., None]
    a, b = _prefix_products(np.cos(half) + 1j * v[..., 0], v[..., 1] + 1j * v[..., 2])
    n2 = a.real ** 2 + a.imag ** 2 + b.real ** 2 + b.imag ** 2
    w, x, y, z = (u / np.sqrt(n2) for u in (a.real, a.imag, b.real, b.imag))
    P = np.empty(a.shape + (3, 3))
    P[..., 0, 0] = 1 - 2 * (y * y + z * z)
    P[..., 0, 1] = 2 * (x * y - w * z)
    P[..., 0, 2] = 2 * (x * z + w * y)
    P[..., 1, 0] = 2 * (x * y + w * z)
    P[..., 1, 1] = 1 - 2 * (x * x + z * z)
    P[..., 1, 2] = 2 * (y * z - w * x)
    P[..., 2, 0] = 2 * (x * z - w * y)
    P[..., 2, 1] = 2 * (y * z + w * x)
    P[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return P


class RotationWindows:
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
        K = np.asarray(K, float)
        if idx is None and getattr(self, "_last", None) is not None and np.array_equal(self._last[0], K):
            return self._last[1]            # the fit asks again at its solution (frame, RMS)
        vd = (self.vd if idx is None else self.vd[idx]) * D2R
        R, L = vd.shape[:2]
        P = _prefix_rotations(vd @ K.T)
        S = np.matmul(P.reshape(R, L, 9).transpose(0, 2, 1), vd).reshape(R, 3, 3, 3)
        if idx is None:
            self._last = (K.copy(), (P[:, -1], S))
        return P[:, -1], S


def tangent_basis(u):
    """Two unit vectors perpendicular to each row of u (R, 3): (R, 3, 2)."""
    ref = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(u, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(u, e1)], -1)


def predict_directions(Delta, start):
    """The start directions (R, 3) carried through the rotations: Delta^T u."""
    return np.einsum("rji,rj->ri", Delta, start)


def angle_deg(x, y):
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(x, y), axis=1), np.einsum("ri,ri->r", x, y)))
