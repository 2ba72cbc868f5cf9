"""Continuous-time motion: a board carried through a sequence of still poses.

:class:`PoseTour` can be evaluated at any times (vectorised), which is what the
emulated chips need: each fills its FIFO at its own output rate from the same
trajectory.  Between poses the board turns smoothly (smoothstep profile) about a
fixed body axis, with a hand-like linear-acceleration bump; with ``loop`` the
tour repeats forever (the daemon demo).

Units: specific force in g (body frame), angular rate in deg/s (body frame),
magnetic field in gauss (body frame), temperature in degC, time in s.
"""
from __future__ import annotations

from typing import Dict

import numpy as np

from ..rng import RngLike, as_rng


__all__ = ["PoseTour", "log_so3"]

#: cosines per axis in PoseTour's tremor (enough for a band-like, non-periodic look)
_TREMOR_K = 12



def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix."""
    c = np.clip((np.trace(R) - 1) / 2, -1, 1)
    ang = np.arccos(c)
    if ang < 1e-12:
        return np.zeros(3)
    if np.pi - ang < 1e-6:
        w, V = np.linalg.eigh((R + R.T) / 2)
        return V[:, np.argmax(w)] * ang
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2 * np.sin(ang))
    return v * ang


def _rodrigues_batch(axis: np.ndarray, ang: np.ndarray) -> np.ndarray:
    """Rotation matrices for unit axes (n, 3) and angles (n,)."""
    K = np.zeros((len(ang), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -axis[:, 2], axis[:, 1]
    K[:, 1, 0], K[:, 1, 2] = axis[:, 2], -axis[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -axis[:, 1], axis[:, 0]
    s, c = np.sin(ang)[:, None, None], np.cos(ang)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


class PoseTour:
    """Hold each pose, then move to the next; evaluate with :meth:`sample`."""

    def __init__(self, rotations: np.ndarray, rng: RngLike = None,
                 hold_s=(6.0, 10.0), move_s=(2.0, 4.0), lead_s: float = 2.0,
                 move_accel_g: float = 0.2, field_gauss: float = 0.5, dip_deg: float = 60.0,
                 temp0_c: float = 22.0, temp_rise_c: float = 6.0, temp_tau_s: float = 600.0,
                 loop: bool = False, tremor_dps: float = 0.0, tremor_lever_m: float = 0.025):
        rng = as_rng(rng)
        draw = lambda v: float(rng.uniform(*v)) if isinstance(v, tuple) else float(v)
        self.R = np.asarray(rotations, float)
        n = len(self.R)
        self.loop = loop
        self.move_accel_g = move_accel_g
        t = 0.0
        holds, moves, ends = [], [], []
        self.axis = np.zeros((n, 3))
        self.angle = np.zeros(n)
        self.bump_dir = np.zeros((n, 3))
        self.bump_amp = np.zeros(n)
        for i in range(n):
            holds.append(t)
            t += draw(hold_s) + (lead_s if i == 0 else 0.0)
            moves.append(t)
            if i + 1 < n or loop:
                nxt = self.R[(i + 1) % n]
                rv = log_so3(self.R[i].T @ nxt)
                ang = np.linalg.norm(rv)
                self.axis[i] = rv / ang if ang > 0 else np.array([1.0, 0, 0])
                self.angle[i] = ang
                d = rng.normal(size=3)
                self.bump_dir[i] = d / np.linalg.norm(d)
                self.bump_amp[i] = rng.uniform(0.3, 1.0) * move_accel_g
                t += draw(move_s)
            ends.append(t)
        self.t_hold0 = np.array(holds)
        self.t_move0 = np.array(moves)
        self.t_end = np.array(ends)
        self.period = t
        dip = np.radians(dip_deg)
        self.B_world = field_gauss * np.array([np.cos(dip), 0.0, -np.sin(dip)])
        self.temp0_c, self.temp_rise_c, self.temp_tau_s = temp0_c, temp_rise_c, temp_tau_s
        self.tremor_dps, self.tremor_lever_m = float(tremor_dps), float(tremor_lever_m)
        if self.tremor_dps > 0:
            # a deterministic function of time (every chip samples the same hand at its own
            # rate): per axis, _TREMOR_K cosines at frequencies drawn in 6-12 Hz with random
            # phases and weights, scaled so that the rate has RMS tremor_dps per axis
            k = _TREMOR_K
            self._tf_hz = rng.uniform(6.0, 12.0, (3, k))
            self._tph = rng.uniform(0.0, 2 * np.pi, (3, k))
            c = rng.normal(size=(3, k))
            self._tc_dps = c * (self.tremor_dps / np.sqrt((c ** 2).sum(1) / 2))[:, None]

    @property
    def duration_s(self) -> float:
        return self.period

    def tremor(self, t: np.ndarray):
        """Hand tremor at times t (n,): (angle rad (n, 3), rate deg/s (n, 3), angular
        acceleration rad/s^2 (n, 3)), body frame; zeros without tremor."""
        n = len(t)
        if self.tremor_dps <= 0:
            z = np.zeros((n, 3))
            return z, z, z
        w2 = 2 * np.pi * self._tf_hz                               # rad/s, (3, k)
        ph = w2[None] * t[:, None, None] + self._tph[None]         # (n, 3, k)
        cos, sin = np.cos(ph), np.sin(ph)
        rate = (self._tc_dps[None] * cos).sum(2)
        ang = np.radians((self._tc_dps / w2)[None] * sin).sum(2)
        acc = -np.radians((self._tc_dps * w2)[None] * sin).sum(2)
        return ang, rate, acc

    def holds(self):
        """(start, end) of every still interval in the first pass, s."""
        return list(zip(self.t_hold0, self.t_move0))

    def sample(self, t: np.ndarray) -> Dict[str, np.ndarray]:
        """Motion at times t (n,): keys f (g), w (deg/s), h (gauss), temp (degC), R, still."""
        t = np.atleast_1d(np.asarray(t, float))
        tt = np.mod(t, self.period) if self.loop else np.clip(t, 0, self.period)
        i = np.clip(np.searchsorted(self.t_end, tt, side="right"), 0, len(self.R) - 1)
        moving = tt >= self.t_move0[i]
        dur = np.maximum(self.t_end[i] - self.t_move0[i], 1e-9)
        tau = np.where(moving, np.clip((tt - self.t_move0[i]) / dur, 0, 1), 0.0)
        s = 3 * tau ** 2 - 2 * tau ** 3
        sdot = np.where(moving, 6 * tau * (1 - tau) / dur, 0.0)
        R = self.R[i] @ _rodrigues_batch(self.axis[i], self.angle[i] * s)
        w = np.degrees(self.axis[i] * (self.angle[i] * sdot)[:, None])
        a_world = (self.bump_amp[i] * np.sin(2 * np.pi * tau) * moving)[:, None] * self.bump_dir[i]
        if self.tremor_dps > 0:
            # physical tremor: the wobble rotates the board (the accelerometer sees gravity
            # tilt), the gyro sees its rate, and a point tremor_lever_m from the wrist pivot
            # sees the tangential acceleration alpha x r (2.5 cm: 1.3-3x the accelerometer's
            # noise variance at 1.5 deg/s, as real hand-held poses show)
            ang, rate, alpha = self.tremor(t)
            a_n = np.linalg.norm(ang, axis=1)
            R = R @ _rodrigues_batch(ang / np.maximum(a_n, 1e-300)[:, None], a_n)
            w = w + rate
            lever = np.cross(alpha, np.array([self.tremor_lever_m, 0.0, 0.0])) / 9.80665
            a_world = a_world + np.einsum("nij,nj->ni", R, lever)
        up = np.array([0.0, 0.0, 1.0])
        f = np.einsum("nji,nj->ni", R, a_world + up)
        h = np.einsum("nji,j->ni", R, self.B_world)
        temp = self.temp0_c + self.temp_rise_c * (1 - np.exp(-t / self.temp_tau_s))
        return {"f": f, "w": w, "h": h, "temp": temp, "R": R, "still": ~moving}
