"""Pose accumulator: keeps the still poses well spread on the sphere.

A new pose within ``merge_angle_deg`` of an existing one and within the pose noise of
it is the same pose: the two are averaged (refined).  So is a piece that continues the
interval before it (one still run cut at the detector's ``max_pose_s``: the same placement,
its mean drifting with the temperature through a warm-up), which refines the pose that
interval went to, as calibrate joins such pieces into one pose.  Any other pose is kept,
even a few degrees of tilt away (it carries its own information); past ``max_poses`` the
oldest pose in the most crowded region gives way.  Coverage
is measured against the 26 directions of a cube's faces, edges and corners
(fitting/judging/coverage.py); the accumulator says which ones still lack a pose, and what
CRLB the current pose set predicts for the calibration.
"""
from __future__ import annotations

from typing import Dict, List, Optional

import numpy as np

from ..fitting.judging.coverage import cube_coverage
from ..fitting.models.accel import Triangular9
from ..fitting.noise.posecov import MAX_HOLDS
from ..fitting.stillness.poses import PoseSet
from ..fitting.stillness.detector import StaticInterval
from ..fitting.judging.uncertainty import crlb, residual_variance
from ..numerics.npstats import median

__all__ = ["PoseAccumulator"]

_T9 = Triangular9()


class PoseAccumulator:
    def __init__(self, merge_angle_deg: float = 12.0, max_poses: int = 60,
                 cover_angle_deg: float = 25.0):
        self.merge_cos = np.cos(np.radians(merge_angle_deg))
        self.cover_angle_deg = cover_angle_deg
        self.cover_cos = np.cos(np.radians(cover_angle_deg))
        self.max_poses = max_poses
        self.poses: List[StaticInterval] = []
        self.added = 0            #: poses accepted since start (incl. replacements)
        self.rejected = 0
        self._last: Optional[int] = None    #: the pose the last interval went to

    def __len__(self):
        return len(self.poses)

    def clear(self) -> None:
        """Forget every pose (the control socket's reset)."""
        self.poses, self.added, self._last = [], 0, None

    def add(self, iv: StaticInterval) -> str:
        """Add an interval; returns 'new', 'refined', 'replaced' or 'rejected'."""
        what, self._last = self._add(iv)
        return what

    def _add(self, iv: StaticInterval):
        """('new' | 'refined' | 'replaced' | 'rejected', index of the pose it went to)."""
        norm = float(np.linalg.norm(iv.acc))
        if not 0.5 < norm < 1.5:            # not a still pose under 1 g (raw, uncalibrated)
            self.rejected += 1
            return "rejected", None
        u = iv.acc / norm
        if self.poses:
            U = self.directions()
            c = U @ u
            j = int(np.argmax(c))
            # the same still run as the interval before (cut at max_pose_s): the same
            # placement, however far its mean drifted with the temperature
            same_run = iv.continues and self._last is not None and c[self._last] >= self.merge_cos
            if same_run:
                j = self._last
            if same_run or c[j] >= self.merge_cos:
                old = self.poses[j]
                sep = np.linalg.norm(iv.acc - old.acc)
                noise = np.sqrt(np.trace(iv.acc_cov) + np.trace(old.acc_cov))
                if same_run or sep < 4 * noise:     # the same run, or the same pose within its noise
                    self.poses[j] = _merge(old, iv)
                    self.added += 1
                    return "refined", j
                # a nearby but distinct pose (a few degrees of tilt away) carries its own
                # information, as calibrate uses it: kept, up to max_poses
        if len(self.poses) >= self.max_poses:
            # full: replace the oldest pose in the most crowded region
            U = self.directions()
            crowd = (U @ U.T > self.cover_cos).sum(1)
            j = int(np.argmax(crowd))
            self.poses[j] = iv
            self.added += 1
            return "replaced", j
        self.poses.append(iv)
        self.added += 1
        return "new", len(self.poses) - 1

    def directions(self) -> np.ndarray:
        a = np.array([p.acc for p in self.poses]) if self.poses else np.zeros((0, 3))
        return a / np.linalg.norm(a, axis=1, keepdims=True) if len(a) else a

    def coverage(self) -> Dict[str, object]:
        """Fraction of the 26 cube directions within 25 deg of a pose, and the missing ones."""
        return cube_coverage(self.directions(), self.cover_angle_deg)

    def pose_set(self) -> PoseSet:
        """The poses as a PoseSet (the covariances of the means: each pose's sample
        covariance over n; the worker rescales them from the holds' structure functions
        each pose keeps, ``acc_sf`` and ``acc_radial_sf``: daemon/fitjob.py)."""
        P = self.poses
        N = len(P)
        g = lambda f: np.array([getattr(p, f) for p in P]) if N and all(
            getattr(p, f) is not None for p in P) else None
        return PoseSet(acc=np.array([p.acc for p in P]).reshape(N, 3),
                       acc_cov=np.array([p.acc_cov for p in P]).reshape(N, 3, 3),
                       n=np.array([p.n for p in P], int), t0=np.array([p.t0 for p in P]),
                       t1=np.array([p.t1 for p in P]),
                       acc_sample_cov=np.array([p.acc_sample_cov for p in P]).reshape(N, 3, 3),
                       gyro=g("gyro"), gyro_cov=g("gyro_cov"), mag=g("mag"),
                       temp=np.array([p.temp for p in P]))

    def load(self, ps: PoseSet) -> None:
        self.poses, self._last = [], None
        for i in range(len(ps)):
            sc = ps.acc_sample_cov[i] if ps.acc_sample_cov is not None else ps.acc_cov[i] * ps.n[i]
            self.poses.append(StaticInterval(
                ps.acc[i], ps.acc_cov[i], sc, int(ps.n[i]), float(ps.t0[i]), float(ps.t1[i]),
                float(ps.temp[i]) if ps.temp is not None else float("nan"),
                None if ps.gyro is None else ps.gyro[i], None,
                None if ps.mag is None else ps.mag[i]))

    def predicted_std(self, theta: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        """CRLB standard deviations of the triangular9 parameters this pose set predicts."""
        if len(self.poses) < 10:
            return None
        ps = self.pose_set()
        th = _T9.nominal if theta is None else theta
        v = median(np.einsum("nii->n", ps.acc_cov) / 3)
        var = residual_variance(_T9, th, ps.acc, np.full(len(ps), v))
        return crlb(_T9, th, ps.acc, var).std


def _merge(a: StaticInterval, b: StaticInterval) -> StaticInterval:
    n = a.n + b.n
    wa, wb = a.n / n, b.n / n
    m = wa * a.acc + wb * b.acc
    # the pooled sample covariance of both holds' rows, the spread between their means included
    # (pieces of one rest through a warm-up drift apart: calibrate's joined pose has it)
    d = a.acc - b.acc
    sc = wa * a.acc_sample_cov + wb * b.acc_sample_cov + wa * wb * np.outer(d, d)
    mix = lambda x, y: None if x is None or y is None else wa * x + wb * y
    return StaticInterval(m, sc / n, sc, n, min(a.t0, b.t0), max(a.t1, b.t1),
                          _mean_temp(a.temp, b.temp, wa, wb),
                          mix(a.gyro, b.gyro),
                          None if a.gyro_cov is None or b.gyro_cov is None else
                          (a.gyro_cov * a.n ** 2 + b.gyro_cov * b.n ** 2) / n ** 2,
                          mix(a.mag, b.mag) if a.mag is not None and b.mag is not None else (b.mag if b.mag is not None else a.mag),
                          # both holds' structure functions (each ~28 numbers), when both known;
                          # the longest MAX_HOLDS kept (a board resting for hours refines one pose)
                          acc_sf=_holds(a.acc_sf, b.acc_sf),
                          acc_radial_sf=_holds(a.acc_radial_sf, b.acc_radial_sf))


def _holds(x, y):
    """Two poses' per-hold structure functions joined (None unless both are known), the
    MAX_HOLDS longest kept."""
    return None if x is None or y is None else sorted(x + y, key=lambda e: -e[0])[:MAX_HOLDS]


def _mean_temp(ta: float, tb: float, wa: float, wb: float) -> float:
    """Weighted mean temperature, degC; NaN (unknown) stays unknown, and a known one
    is not pulled towards 0 by an unknown one."""
    if np.isfinite(ta) and np.isfinite(tb):
        return float(wa * ta + wb * tb)
    return float(ta) if np.isfinite(ta) else float(tb)
