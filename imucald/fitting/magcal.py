"""Magnetometer calibration from rotation alone (no still poses, no accelerometer).

Hard and soft iron come from turning the sensor: the raw readings of a fixed
field lie on an ellipsoid, m = W^-1 h + v with |h| = F.  This module takes the
raw cloud (a recording's mx, my, mz, or the daemon's reservoir), thins it over
the sphere with the daemon's own :class:`SphereReservoir` (so the still start of
a recording or a slow sweep does not dominate), and fits the same hard + soft iron
model, with the same CRLB and held-out machinery, as the accelerometer-paired
path (:func:`imucald.fitting.fit.fit_norm`).

What the cloud can determine is said, not assumed:

* coverage: the fraction of direction cells (Fibonacci lattice) the corrected
  cloud reaches, and the eigenvalues of the scatter (covariance) of its unit
  directions (1/3 each for the whole sphere; one near 0 for a swing in one plane);
* a swing in one plane (the out-of-plane spread of the raw cloud is within
  ``FLAT_K`` noise standard deviations) leaves the axis normal to the plane
  undetermined: then no 3-D calibration is returned, only the plane, its normal
  and the ring's centre in the plane;
* a cloud that spans three dimensions can still leave terms undetermined: a cap of
  the sphere (the sensor tilted a little, never rolled over), a planar turn with a
  wobble, or a sensor carried about without turning (the field's spatial changes then
  make a small blob that an ellipsoid fits as a tiny sphere).  Each hard-iron
  component and soft-iron term counts as determined only when its standard error
  (the fit's covariance: the Cramer-Rao bound at the per-point noise, scaled up by
  the excess scatter when the residuals reject that noise) is within
  ``HARD_IRON_SE_MAX`` of the fitted field (hard iron) or ``SOFT_IRON_SE_MAX``
  (soft-iron terms, W normalised to det 1), and not on a search bound.  2 % is about
  a degree of heading error at one standard error.  That bound is a linearisation: it
  holds only when the field directions spread in every plane, so first the corrected
  cloud's direction scatter must have its smallest eigenvalue at least
  ``MIN_DIRECTION_EIG`` (1/3 for the whole sphere; 0.02 is a cap of about 60 degrees
  about the mean direction, a quarter of the sphere), else every term is undetermined:
  on simulated caps of 45-60 degrees and planar turns with a 10 degree wobble, terms
  whose standard error passed had errors 40-50x the limit.  Otherwise no calibration
  is returned either: what is undetermined, how much of the sphere the field
  directions reached and which sensor axes never pointed along the field.  The
  rule's error rates on simulated partial rotations and its decisions on the real
  BROAD trials: bench/mag_determination.py, docs/guide/magnetometer.md.

Before that rule, two checks for a recording whose field is not one field, which its
standard errors do not see (an independent probe: clipped tumbles, a board carried to another
room, a passing magnet, all calibrated before with the hard iron off by up to 31 % of the field):
samples on a rail (:func:`rails`: clipping, an overflow code) are left out of the fit, and a
cloud whose corrected magnitude varies beyond the noise by more than ``FIELD_EXCESS_MAX`` of
the field (and over ``FIELD_RATIO_MIN`` times the noise's spread) determines nothing
(:func:`field_consistency`).  Error rates: docs/guide/magnetometer.md.

Noise per sample comes from second differences of the time series (robust scale), per axis.
A brisk turn logged slowly (a figure-8 at 10-12.5 Hz) inflates those 6-116x, so the corrected
field magnitude's second differences under a first fit, which the turning leaves, replace
them when they give under ``MOTION_NOISE_RATIO`` of it (:func:`rotation_noise`; its figures:
docs/guide/magnetometer.md).
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from .judging.coverage import sphere_lattice
from .fit import FitResult, fit_norm
from .models.mag import MagModel
from .models.registry import get_model
from .solvers.lsq import sphere_fit
from .judging.uncertainty import residual_variance
from ..numerics.npstats import median

__all__ = ["SphereReservoir", "sample_noise", "flat_axis", "coverage", "undetermined_terms",
           "missing_axes", "fit_cloud", "fit_points", "calibrate_rotation", "rel_std", "FLAT_K", "HARD_IRON_SE_MAX",
           "SOFT_IRON_SE_MAX", "MIN_DIRECTION_EIG", "rails", "on_rails", "field_consistency",
           "FIELD_EXCESS_MAX", "FIELD_RATIO_MIN", "unit_problem", "readings", "motion_free_noise",
           "rotation_noise"]

#: a cloud whose out-of-plane standard deviation is below FLAT_K times the noise's
#: along the plane normal is flat: the normal axis is not determined (3 sigma)
FLAT_K = 3.0
#: rows a SphereReservoir queues before binning them
QUEUE_ROWS = 64
#: a hard-iron component is determined when its standard error is at most this fraction
#: of the fitted field (module doc)
HARD_IRON_SE_MAX = 0.02
#: a soft-iron term (W normalised to det 1, dimensionless) is determined when its
#: standard error is at most this
SOFT_IRON_SE_MAX = 0.02
#: smallest eigenvalue of the corrected unit directions' scatter for the standard errors
#: to be trusted at all (module doc)
MIN_DIRECTION_EIG = 0.02
#: the corrected field's magnitude may vary beyond the noise by at most this fraction of
#: the field (RMS): the determination limit (2 %, about a degree of heading), since a
#: field that changes during the recording (the board carried to another room, a magnet
#: passing, the sensor clipping) bends the fitted ellipsoid by about as much, however small
#: the standard errors the fit's own scatter gives (module doc)
FIELD_EXCESS_MAX = 0.02
#: ... and only when the corrected magnitude's spread is over this multiple of what the
#: noise gives: the noise estimate (second differences) is itself uncertain, e.g. 1.25x short
#: on the real filtered GY-273 log (a smoothing filter hides noise from second differences)
FIELD_RATIO_MIN = 1.5
#: the corrected magnitude's second differences replace the per-axis noise figure when they
#: give under this fraction of it: motion, not noise (:func:`motion_free_noise`)
MOTION_NOISE_RATIO = 2.0 / 3.0
MOTION_FREE_SOURCE = "second differences of the field magnitude"
#: a rail (clipping, an overflow code) is an axis's extreme value met in at least this
#: many distinct samples and this fraction of them, and in more than lie near it inside
#: (within 1 % of the axis's span or 3 counts): :func:`rails`
RAIL_MIN_COUNT = 5
RAIL_MIN_FRACTION = 0.005
SOFT_NAMES = ("soft_iron_xx", "soft_iron_yy", "soft_iron_zz", "soft_iron_xy", "soft_iron_xz",
              "soft_iron_yz")
HARD_NAMES = ("hard_iron_x", "hard_iron_y", "hard_iron_z")


class SphereReservoir:
    """Magnetometer samples thinned over the sphere: at most ``per_cell`` in each of
    ``cells`` direction cells (about a running centre), so no region dominates.
    Newer samples replace older ones in a full cell.  Used by the daemon (fed as
    samples arrive), by the offline rotation calibration (fed a whole recording) and by
    the gap diagnosis, which passes ``tags`` (e.g. sample indices) to find each kept
    point's time, temperature and orientation (:meth:`tags`)."""

    def __init__(self, cells: int = 200, per_cell: int = 5):
        self.P = sphere_lattice(cells)
        self.per_cell = per_cell
        self.buf = np.full((cells, per_cell, 3), np.nan)
        self.tag = np.full((cells, per_cell), -1, np.int64)
        self.count = np.zeros(cells, int)
        self.centre: Optional[np.ndarray] = None
        self._seen = 0
        self._pending: List[np.ndarray] = []
        self._pending_tags: List[np.ndarray] = []
        # add() only queues (a daemon adds one or two readings a batch); the queue is worked
        # off in bulk, with the same result as adding each batch at once (see _flush)
        self._queue: List[Tuple[np.ndarray, Optional[np.ndarray]]] = []
        self._queued = 0

    @property
    def seen(self) -> int:
        """Finite samples added so far."""
        self._flush()
        return self._seen

    def add(self, m: np.ndarray, tags: Optional[np.ndarray] = None) -> None:
        m = np.asarray(m, float).reshape(-1, 3)
        if len(m):
            self._queue.append((m, None if tags is None else np.asarray(tags, np.int64).reshape(-1)))
            self._queued += len(m)
            if self._queued >= QUEUE_ROWS:
                self._flush()

    def _flush(self) -> None:
        """Work off the queue as if each queued batch had been added on its own: the first
        centre is fitted at the first batch that brings 50 spread samples, and the points are
        re-binned after the batch that doubles the samples seen; between those events the
        centre is fixed, so binning the batches together gives the same reservoir."""
        if not self._queue:
            return
        q, self._queue, self._queued = self._queue, [], 0
        ms = [m for m, _ in q]
        M = ms[0] if len(q) == 1 else np.concatenate(ms)
        T = np.concatenate([np.full(len(m), -1, np.int64) if t is None else t for m, t in q])
        ok = np.all(np.isfinite(M), axis=1)
        ends = np.cumsum([len(m) for m in ms])
        kept = np.cumsum(ok)[ends - 1]                      # finite rows up to each batch's end
        i = 0
        while i < len(q):
            lo = ends[i - 1] if i else 0
            if self.centre is None:                          # rare: the first samples
                ok_i = ok[lo:ends[i]]
                self._add_one(M[lo:ends[i]][ok_i], T[lo:ends[i]][ok_i])
                i += 1
                continue
            base = self._seen - (int(kept[i - 1]) if i else 0)
            hit = np.flatnonzero(base + kept[i:] >= self._next_recentre)
            j = int(hit[0]) + i if len(hit) else len(q) - 1
            hi = ends[j]
            self._bin(M[lo:hi][ok[lo:hi]], T[lo:hi][ok[lo:hi]])
            self._seen = int(base + kept[j])
            if self._seen >= self._next_recentre:    # 2x, 4x, 8x ... the first centre's samples
                self._next_recentre = 2 * self._seen
                self.recentre()
            i = j + 1

    def _add_one(self, m: np.ndarray, tg: np.ndarray) -> None:
        """One batch of finite samples (m, their tags), binned at once."""
        if not len(m):
            return
        self._seen += len(m)
        if self.centre is None:
            self._pending.append(m)
            self._pending_tags.append(tg)
            pts = np.vstack(self._pending)
            if len(pts) < 50 or np.ptp(pts, axis=0).min() < 1e-3:
                return
            self.centre, _ = sphere_fit(pts)
            tg = np.concatenate(self._pending_tags)
            self._pending, self._pending_tags = [], []
            m = pts
            self._next_recentre = 2 * len(pts)
        self._bin(m, tg)
        if self._seen >= self._next_recentre:      # 2x, 4x, 8x ... the first centre's samples
            self._next_recentre = 2 * self._seen
            self.recentre()

    def _bin(self, m: np.ndarray, tags: Optional[np.ndarray] = None) -> None:
        d = m - self.centre
        cell = np.argmax(d @ self.P.T, axis=1)
        tags = np.full(len(m), -1, np.int64) if tags is None else tags
        for c, x, tg in zip(cell, m, tags):
            k = self.count[c] % self.per_cell
            self.buf[c, k] = x
            self.tag[c, k] = tg
            self.count[c] += 1

    def points(self) -> np.ndarray:
        self._flush()
        return self.buf[~np.isnan(self.buf[..., 0])]

    def tags(self) -> np.ndarray:
        """The tag of each point of :meth:`points`, in the same order (-1: none given)."""
        self._flush()
        return self.tag[~np.isnan(self.buf[..., 0])]

    def coverage(self) -> float:
        """Fraction of direction cells the kept points reach about *their* sphere fit (the
        running centre, fixed early from a small arc, can be far off)."""
        pts = self.points()
        if len(pts) < 20:
            return float((self.count > 0).mean())
        c, _ = sphere_fit(pts)
        d = pts - c
        return float(len(np.unique(np.argmax(d @ self.P.T, axis=1))) / len(self.P))

    def recentre(self) -> None:
        """Refit the centre to the kept points and re-bin them about it."""
        pts, tg = self.points(), self.tags()
        if len(pts) >= 20:
            self.centre, _ = sphere_fit(pts)
            self.buf[:] = np.nan
            self.tag[:] = -1
            self.count[:] = 0
            self._bin(pts, tg)


def sample_noise(m: np.ndarray) -> np.ndarray:
    """Per-axis white-noise standard deviation (sensor units) of a time series
    (N, 3): robust scale (1.4826 MAD) of second differences / sqrt(6)."""
    m = np.asarray(m, float)
    d2 = np.diff(m, 2, axis=0)
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if len(d2) < 10:
        return np.full(3, np.nan)
    mad = median(np.abs(d2 - median(d2, axis=0)), axis=0)
    sd = 1.4826 * mad / np.sqrt(6.0)
    # noise below one count: most second differences are 0 and the MAD with them; the
    # plain standard deviation still sees the quantisation
    return np.where(sd > 0, sd, d2.std(axis=0) / np.sqrt(6.0))


def _noise_cov(noise: np.ndarray, n: int) -> np.ndarray:
    """Each of ``n`` points' covariance (n, 3, 3) from the per-sample noise (3,), per axis."""
    return np.broadcast_to(np.diag(np.asarray(noise, float) ** 2), (n, 3, 3))


def motion_free_noise(model: MagModel, theta: np.ndarray, mag: np.ndarray,
                      noise: np.ndarray) -> Optional[np.ndarray]:
    """Per-axis noise (sensor units, the same on each axis) from the second differences of the
    corrected magnitude's time series under a first fit ``theta`` of the readings ``mag`` (N, 3)
    in time order, when it is below MOTION_NOISE_RATIO of what the per-axis figure ``noise``
    (3,) (:func:`sample_noise`) gives; else None.  The magnitude does not change as the
    board turns, so the motion that inflates the per-axis second differences at low rates
    (a figure-8 at 10 Hz: 6-116x) leaves it; a step or a bump of the field is a few
    outlying differences, which the robust scale ignores (so is a slow change of the field:
    the one-field rule, :func:`field_consistency`, judges those).  Rows that are not finite
    are left out."""
    mag = np.asarray(mag, float).reshape(-1, 3)
    mag = mag[np.all(np.isfinite(mag), axis=1)]
    h = np.linalg.norm(model.forward(theta, mag), axis=1)
    sd = float(sample_noise(h[:, None])[0])         # the same robust scale, of one column
    if not np.isfinite(sd):
        return None
    pred = float(np.sqrt(np.mean(residual_variance(model, theta, mag, _noise_cov(noise, len(mag))))))
    if not sd < MOTION_NOISE_RATIO * pred:
        return None
    unit = float(np.sqrt(np.mean(residual_variance(model, theta, mag, 1.0))))
    return np.full(3, sd / unit)


def rotation_noise(model: MagModel, points: np.ndarray, mag: np.ndarray, noise: np.ndarray,
                   rng=None) -> Tuple[np.ndarray, str]:
    """(per-sample noise (3,), where it came from) for the fit of the thinned cloud ``points``
    of the readings ``mag`` (N, 3) in time order: ``noise`` (:func:`sample_noise` of ``mag``),
    or, when the turning inflated it, :func:`motion_free_noise` under a first fit of the cloud
    (``calibrate --sensor mag`` and the daemon alike)."""
    if len(points) > int(model.free_mask.sum()) and np.all(np.isfinite(noise)):
        pilot = fit_points(model, points, noise, "lm", rng, heldout=False)
        quiet = motion_free_noise(model, pilot.theta, mag, noise)
        if quiet is not None:
            return quiet, MOTION_FREE_SOURCE
    return np.asarray(noise, float), "second differences"


def flat_axis(points: np.ndarray, noise: np.ndarray, k: float = FLAT_K) -> Optional[Dict[str, Any]]:
    """The plane of a one-plane swing, or None when the cloud spans three dimensions.

    Flat when the raw cloud's standard deviation along its least-spread principal
    axis is below ``k`` times the noise's along that axis; ``rank`` counts the axes
    along which it does spread (2: one plane; 0 or 1: the sensor was hardly turned)."""
    x = np.asarray(points, float)
    c = x.mean(0)
    ev, V = np.linalg.eigh(np.cov((x - c).T))
    S = np.diag(np.asarray(noise, float) ** 2)
    sd_axes = np.sqrt(np.clip(ev, 0, None))
    sd_noise_axes = np.sqrt(np.einsum("ij,ik,kj->j", V, S, V))
    # principal axes along which the cloud spreads beyond the noise: 3 = turned in 3-D,
    # 2 = one plane, 0-1 = hardly turned at all
    rank = int(np.sum(sd_axes >= k * sd_noise_axes))
    n = V[:, 0]
    sd_out, sd_noise = float(sd_axes[0]), float(sd_noise_axes[0])
    if rank == 3 or not np.all(np.isfinite(sd_noise_axes)):
        return None
    # the ring in the plane: algebraic conic fit A u^2 + B uv + C v^2 + D u + E v = 1
    e1, e2 = V[:, 2], V[:, 1]
    u, v = (x - c) @ e1, (x - c) @ e2
    s = max(np.std(u), np.std(v), 1e-300)
    u, v = u / s, v / s
    D = np.column_stack([u * u, u * v, v * v, u, v])
    sol, *_ = np.linalg.lstsq(D, np.ones(len(u)), rcond=None)
    M = np.array([[2 * sol[0], sol[1]], [sol[1], 2 * sol[2]]])
    try:
        u0, v0 = np.linalg.solve(M, -sol[3:5]) * s
    except np.linalg.LinAlgError:
        u0 = v0 = 0.0
    return {"normal": (n * np.sign(n[np.argmax(np.abs(n))])).tolist(), "rank": rank,
            "out_of_plane_std": sd_out, "noise_std_along_normal": sd_noise,
            "ring_centre": (c + u0 * e1 + v0 * e2).tolist()}


def coverage(model: MagModel, theta: np.ndarray, points: np.ndarray, cells: int = 200
             ) -> Dict[str, Any]:
    """How much of the sphere the corrected cloud spans: fraction of direction cells
    reached, and the eigenvalues (descending) and axes of the covariance of the
    corrected unit directions (1/3 each for a full sphere)."""
    h = model.forward(theta, np.asarray(points, float))
    d = h / np.linalg.norm(h, axis=1, keepdims=True)
    P = sphere_lattice(cells)
    reached = np.unique(np.argmax(d @ P.T, axis=1))
    ev, V = np.linalg.eigh(np.cov(d.T))
    order = np.argsort(ev)[::-1]
    return {"fraction": float(len(reached) / cells), "cells": cells,
            "direction_eigenvalues": [float(x) for x in ev[order]],
            "least_spread_axis": V[:, order[-1]].tolist()}


def undetermined_terms(cal: FitResult, min_direction_eig: float = np.inf) -> List[Dict[str, Any]]:
    """The hard-iron components and soft-iron terms a rotation fit does not determine
    (module doc: every term when the direction scatter's smallest eigenvalue
    ``min_direction_eig`` is below ``MIN_DIRECTION_EIG``, reason "coverage"; else each
    whose standard error is above ``HARD_IRON_SE_MAX`` of the field or above
    ``SOFT_IRON_SE_MAX``, reason "stderr", or whose fitted parameter is on a search
    bound, reason "at_bound": a soft-iron term is on one when any of the model's W
    entries it is formed from is, W being normalised to det 1): one dict each (name,
    stderr, limit, unit, reason).  The terms a model holds fixed (mag_diag's
    off-diagonal, mag_sphere's shape) have standard error 0 and are listed only for
    coverage."""
    F = float(cal.params["field_gauss"])
    hi = np.asarray(cal.stderr.get("hard_iron_gauss", [np.inf] * 3), float)
    si = np.asarray(cal.stderr.get("soft_iron", [np.inf] * 6), float)
    terms = ([(n, float(hi[k]), HARD_IRON_SE_MAX * abs(F), "gauss") for k, n in enumerate(HARD_NAMES)]
             + [(n, float(si[k]), SOFT_IRON_SE_MAX, "") for k, n in enumerate(SOFT_NAMES)])
    if not min_direction_eig >= MIN_DIRECTION_EIG:
        return [{"name": n, "stderr": se, "limit": lim, "unit": u, "reason": "coverage"}
                for n, se, lim, u in terms]
    bound = {f["name"] for f in cal.uncertainty.flags if "at_bound" in f["reason"]}
    # every soft-iron term depends on all of W (the det-1 normalisation): any W entry on a
    # bound pins them all (the terms the model holds fixed, standard error 0, excepted)
    w_bound = any(b == "w" or b.startswith("w_") for b in bound)
    on_bound = lambda n: f"{n}_gauss" in bound if n in HARD_NAMES else w_bound
    return [{"name": n, "stderr": se, "limit": lim, "unit": u,
             "reason": "stderr" if not se <= lim else "at_bound"}
            for n, se, lim, u in terms if not se <= lim or (se > 0 and on_bound(n))]


def missing_axes(model: MagModel, theta: np.ndarray, points: np.ndarray,
                 cover_angle_deg: float = 30.0) -> List[str]:
    """The sensor axes (+X, -X, ... faces of a cube, then edges) the field direction never
    came within ``cover_angle_deg`` of, in the corrected cloud: where to turn the sensor."""
    from .judging.coverage import cube_coverage
    h = model.forward(theta, np.asarray(points, float))
    d = h / np.linalg.norm(h, axis=1, keepdims=True)
    miss = cube_coverage(d, cover_angle_deg)["missing"]
    return [m.replace(" up", "") for m in miss]


def rel_std(norms: np.ndarray) -> float:
    """Relative standard deviation of a field norm: std / mean."""
    n = np.asarray(norms, float)
    return float(np.std(n) / np.mean(n))


def fit_points(model, points, noise, method, rng, heldout=True) -> FitResult:
    """The norm fit of rotation points (M, 3) with ``noise`` (3,) per-sample as each point's
    covariance (None: the fit uses its residuals)."""
    cov = None if noise is None else _noise_cov(noise, len(points))
    return fit_norm(points, model, method, pose_cov=cov, rng=rng, heldout=heldout)


def rails(mag: np.ndarray) -> List[Tuple[int, float, int]]:
    """(axis, value, count) of each rail in ``mag`` (N, 3): an axis's largest or smallest
    reading when it recurs in at least RAIL_MIN_COUNT samples and RAIL_MIN_FRACTION of
    them, and in more than lie near it inside (within 1 % of the axis's span, or 3 counts
    of its quantisation step).  A sensor that clips (its range) or writes an overflow code
    (an HMC5883L's -4096, datasheet data output registers 0x03-0x08) piles its readings on
    one value; a rotation through an axis's extreme spreads them over the counts next to
    it (noise, and the turn's dwell): the independent probe's clipped tumbles had 10-42 % of
    their samples on the rail, its clean ones none, the simulator's quantised caps and
    translations up to 7 samples (0.15 %) at an extreme."""
    out: List[Tuple[int, float, int]] = []
    m = np.asarray(mag, float)
    need = max(RAIL_MIN_COUNT, RAIL_MIN_FRACTION * len(m))
    for j in range(m.shape[1]):
        x = m[:, j]
        span = float(x.max() - x.min())
        if not span > 0:
            continue
        steps = np.diff(np.unique(x))
        band = max(0.01 * span, 3.0 * float(np.min(steps))) if len(steps) else 0.01 * span
        for v in (float(x.max()), float(x.min())):
            at = int(np.count_nonzero(x == v))
            near = int(np.count_nonzero((x != v) & (np.abs(x - v) <= band)))
            if at >= need and at > near:
                out.append((j, v, at))
    return out


def on_rails(mag: np.ndarray) -> Tuple[np.ndarray, List[Tuple[int, float, int]]]:
    """(mask of the rows with any axis on a rail, the rails) of ``mag`` (N, 3) (:func:`rails`);
    the CLI, the daemon's reservoir and the gap diagnosis leave those rows out alike."""
    m = np.asarray(mag, float)
    rl = rails(m) if len(m) else []
    off = np.zeros(len(m), bool)
    for j, v, _ in rl:
        off |= m[:, j] == v
    return off, rl


def field_consistency(model: MagModel, theta: np.ndarray, points: np.ndarray,
                      noise: Optional[np.ndarray]) -> Optional[Dict[str, Any]]:
    """The corrected field magnitude's relative spread over ``points`` against what the
    per-sample ``noise`` (3,) gives: {"rel_std", "predicted_rel_std", "excess_rel_std"
    (the spread beyond the noise, as a fraction of the field), "consistent"} (module doc:
    FIELD_EXCESS_MAX, FIELD_RATIO_MIN).  None without a noise figure."""
    if noise is None:
        return None
    pts = np.asarray(points, float)
    rel = rel_std(np.linalg.norm(model.forward(theta, pts), axis=1))
    var = residual_variance(model, theta, pts, _noise_cov(noise, len(pts)))
    pred = float(np.sqrt(np.mean(var)))
    excess = float(np.sqrt(max(rel * rel - pred * pred, 0.0)))
    return {"rel_std": rel, "predicted_rel_std": pred, "excess_rel_std": excess,
            "consistent": not (excess > FIELD_EXCESS_MAX and rel > FIELD_RATIO_MIN * pred)}


def fit_cloud(model: MagModel, points: np.ndarray, noise: Optional[np.ndarray], method: str = "lm",
              rng=None, cells: int = 200, heldout: bool = True) -> Dict[str, Any]:
    """What a thinned rotation cloud ``points`` (M, 3) determines (module doc), for
    ``calibrate --sensor mag`` (:func:`calibrate_rotation`) and the daemon's worker alike:
    the one-plane test (with ``noise`` (3,) per-sample, else skipped: the fit then uses
    its residuals), the fit, the coverage, and the determination rule.  Returns a dict:
    ``determined``; ``flat`` (a one-plane swing, nothing fitted); else ``coverage`` and
    either ``calibration`` (the :class:`FitResult`) or ``undetermined`` (the terms), with
    ``rejected_fit``, ``field_gauss`` and ``missing_axes``."""
    if noise is not None:
        flat = flat_axis(points, noise)
        if flat is not None:
            return {"determined": False, "flat": flat}
    cal = fit_points(model, points, noise, method, rng, heldout)
    cv = coverage(model, cal.theta, points, cells)
    und = undetermined_terms(cal, cv["direction_eigenvalues"][-1])
    # a field that is not one field comes before the standard errors, which its scatter
    # inflates (their message would ask for more orientations, not for another place);
    # a cloud that does not spread, or a fit pinned on a search bound, comes first (an
    # ellipsoid fits a cap or a blob closely; a pinned fit cannot fit the field it has)
    first = und and any(u["reason"] in ("coverage", "at_bound") for u in und)
    fc = None if first else field_consistency(model, cal.theta, points, noise)
    if fc is not None and not fc["consistent"]:
        return {"determined": False, "coverage": cv, "inconsistent": fc, "rejected_fit": cal,
                "field_gauss": float(cal.params["field_gauss"])}
    if und:
        # the fit is kept for the report only ("rejected_fit"): a file from it would be wrong
        return {"determined": False, "coverage": cv, "undetermined": und, "rejected_fit": cal,
                "field_gauss": float(cal.params["field_gauss"]),
                "missing_axes": missing_axes(model, cal.theta, points)}
    return {"determined": True, "coverage": cv, "calibration": cal, "consistency": fc}


def readings(mag: np.ndarray, name: str = "", say: bool = True):
    """(readings, the rows they came from, rails) of a magnetometer series (N, 3): finite rows,
    each reading once (a board that samples faster than its magnetometer holds the last
    reading: repeats would fake a zero noise and weigh one direction more; imucald's own
    9-DoF recordings repeat the slower magnetometer's reading by design, so the report says
    how many readings the rows held, without a warning), the samples on a rail
    (:func:`rails`) left out with a warning line (``say``; gap notes them in its output)."""
    from ..files.tables import warn
    mag = np.asarray(mag, float)
    keep = np.all(np.isfinite(mag), axis=1)
    if keep.sum() > 1:
        ix = np.flatnonzero(keep)
        keep[ix[1:]] &= np.any(np.diff(mag[ix], axis=0) != 0, axis=1)
    idx = np.flatnonzero(keep)
    off, rl = on_rails(mag[idx])
    if rl and say:
        where = ", ".join(f"{'xyz'[j]} at {v:+.6g} ({n})" for j, v, n in rl)
        head = f"{name}: " if name else ""
        warn(f"{head}{int(off.sum())} magnetometer samples sit on a rail ({where}): the sensor "
             f"clipped at its range or wrote an overflow code; they are left out of the fit")
    if rl:
        idx = idx[~off]
    return mag[idx], idx, rl


def field_step(model: MagModel, theta: np.ndarray, mag: np.ndarray,
               t_s: Optional[np.ndarray]) -> Optional[Dict[str, float]]:
    """Where a field that is not one field changed, when one step explains most of it: the
    split of the corrected magnitude (readings ``mag`` in time order, at ``t_s``) into a
    before and an after that takes away the most variance; None unless it takes at least
    half (a passing magnet is a bump, not a step).  {"t_s" (or "row" without times), "change"
    (after / before - 1: the rejected fit's own scale is a compromise between the two fields,
    so only their ratio is told)}."""
    h = np.linalg.norm(model.forward(theta, np.asarray(mag, float)), axis=1)
    n = len(h)
    if n < 20:
        return None
    c = np.cumsum(h)
    k = np.arange(1, n)
    m1, m2 = c[:-1] / k, (c[-1] - c[:-1]) / (n - k)
    gain = k * (n - k) / n * (m1 - m2) ** 2          # variance taken away by the split, x n
    lo, hi = max(1, n // 20), n - max(1, n // 20)
    b = lo + int(np.argmax(gain[lo - 1:hi - 1]))
    if gain[b - 1] < 0.5 * float(np.sum((h - h.mean()) ** 2)):
        return None
    where = {"row": int(b)} if t_s is None else {"t_s": float(np.asarray(t_s, float)[b])}
    return {**where, "change": float(m2[b - 1] / m1[b - 1] - 1.0)}


def calibrate_rotation(mag: np.ndarray, model: str = "mag_sym", method: str = "lm",
                       holdout_fraction: float = 0.3, rng=None, noise: Optional[np.ndarray] = None,
                       cells: int = 200, per_cell: int = 5, temp_c: Optional[np.ndarray] = None,
                       thermal_min_span_c: float = 10.0, name: str = "",
                       t_s: Optional[np.ndarray] = None) -> Dict[str, Any]:
    """Hard + soft iron from a rotation time series ``mag`` (N, 3), in time order (``name``:
    the file, heading the warning for samples on a rail; ``t_s``: the rows' times, for when
    a field that is not one field changed, else the row numbers).

    Returns a dict: ``determined`` (False for a one-plane swing, with ``flat``
    describing the plane), ``calibration`` (a :class:`FitResult` fitted on the
    whole thinned cloud), ``coverage``, ``noise`` (per-axis, sensor units),
    ``norm_rel_std`` (corrected norm over every sample), ``predicted_rel_std``
    (what the noise alone would give), and ``heldout``: the calibration fitted on
    the first ``1 - holdout_fraction`` of the samples in time and tested on the
    rest (relative std of the corrected norm there).  With ``temp_c`` (N,) degC: also
    ``thermal``, the hard iron's temperature polynomial (fitting/thermal/terms.py) on the thinned
    cloud, each point at its own temperature (order 0 below ``thermal_min_span_c``).
    """
    mag_rows = mag
    mag, idx, rl = readings(mag, name)
    temp = None if temp_c is None else np.asarray(temp_c, float)[idx]
    mdl = get_model(model)
    if not isinstance(mdl, MagModel):
        raise ValueError(f"model {model!r} is not a magnetometer model (mag_sym, mag_diag, mag_sphere)")
    sigma = sample_noise(mag) if noise is None else np.asarray(noise, float)
    source = "second differences" if noise is None else "the caller's figure"
    res = SphereReservoir(cells, per_cell)
    res.add(mag, np.arange(len(mag)))
    pts = res.points()
    out: Dict[str, Any] = {"samples": int(len(mag)), "rows": int(len(np.asarray(mag_rows))),
                           "points": int(len(pts)), "noise": sigma.tolist()}
    if rl:
        out["rails"] = [{"axis": "xyz"[j], "value": v, "samples": n} for j, v, n in rl]
    if len(pts) <= int(mdl.free_mask.sum()):
        from ..errors import UserError
        raise UserError(f"{len(mag)} magnetometer samples reach only {len(pts)} direction cells: "
                        f"rotate the sensor through many orientations")
    if noise is None:       # estimated: the turning may have inflated it
        sigma, source = rotation_noise(mdl, pts, mag, sigma, rng)
        out["noise"] = sigma.tolist()
    out["noise_source"] = source
    out.update(fit_cloud(mdl, pts, sigma, method, rng, cells))
    if "inconsistent" in out:
        step = field_step(mdl, out["rejected_fit"].theta, mag,
                          None if t_s is None else np.asarray(t_s, float)[idx])
        if step is not None:
            out["inconsistent"]["step"] = step
    if not out["determined"]:
        return out
    cal = out["calibration"]
    cal.noise_source = source
    hn = np.linalg.norm(mdl.forward(cal.theta, mag), axis=1)
    out["norm_rel_std"] = rel_std(hn)
    var = residual_variance(mdl, cal.theta, pts, _noise_cov(sigma, len(pts)))
    out["predicted_rel_std"] = float(np.sqrt(np.mean(var)))
    if temp is not None and np.all(np.isfinite(temp[res.tags()])):
        from .thermal.terms import fit_norm_thermal
        out["thermal"] = fit_norm_thermal(mdl, pts, var, temp[res.tags()], cal.theta, None,
                                          thermal_min_span_c, scale=False, rng=rng)
    k = int(round(len(mag) * (1 - holdout_fraction)))
    if 0 < k < len(mag):
        r_tr = SphereReservoir(cells, per_cell)
        r_tr.add(mag[:k])
        p_tr = r_tr.points()
        if len(p_tr) > int(mdl.free_mask.sum()) and flat_axis(p_tr, sigma) is None:
            c_tr = fit_points(mdl, p_tr, sigma, "lm", rng, heldout=False)
            out["heldout"] = {
                "train_samples": k, "test_samples": int(len(mag) - k),
                "norm_rel_std": rel_std(np.linalg.norm(mdl.forward(c_tr.theta, mag[k:]), axis=1)),
                "train_coverage": coverage(mdl, c_tr.theta, p_tr, cells)["fraction"]}
        else:
            out["heldout"] = {"train_samples": k, "note": "the first part of the rotation alone "
                              "does not span three dimensions: no held-out figure"}
    return out


#: a fitted field at or above this (gauss) is no field a board meets (the Earth's is 0.25-0.65
#: G; the chips' ranges end at 8-16 G): the file is in counts, mG or uT, not gauss
FIELD_UNIT_MAX_GAUSS = 10.0


def unit_problem(res: Dict[str, Any]) -> Optional[str]:
    """Why a rotation fit (``calibrate_rotation``'s result) is in the wrong unit, or None: a
    newcomer's HMC5883L counts without --nominal-scale were fitted and reported as a 545-gauss
    field (a calibration file would carry counts as gauss)."""
    cal = res.get("calibration") or res.get("rejected_fit")
    if cal is None:
        return None
    F = abs(float(cal.params["field_gauss"]))
    if F < FIELD_UNIT_MAX_GAUSS:
        return None
    return (f"the fitted field is {F:.4g} gauss, no field a board meets (the Earth's is 0.25-0.65 G): "
            f"the file is not in gauss; give --nominal-scale mag=N, its counts per gauss (1090 for an "
            f"HMC5883L at its default gain, 1000 for mG, 100 for uT); nothing is written")


def rotation_json(res: Dict[str, Any]) -> Dict[str, Any]:
    """The JSON object ``imucald calibrate --sensor mag`` prints for a rotation fit."""
    d: Dict[str, Any] = {"sensor": "mag", "input": "rotation", "determined": bool(res["determined"]),
                         "samples": res["samples"], "rows": res.get("rows", res["samples"]),
                         "points": res["points"], "noise_gauss": res["noise"],
                         "noise_source": res.get("noise_source", "second differences")}
    if "rails" in res:
        d["rails"] = res["rails"]
    if not res["determined"] and "inconsistent" in res:
        cal = res["rejected_fit"]
        d["inconsistent"] = res["inconsistent"]
        d["coverage"] = res["coverage"]
        d["rejected_fit"] = {"params": cal.params, "stderr": cal.stderr, "model": cal.model}
        return d
    if not res["determined"] and "undetermined" in res:
        cal = res["rejected_fit"]
        d["undetermined"] = res["undetermined"]
        d["missing_axes"] = res["missing_axes"]
        d["coverage"] = res["coverage"]
        d["rejected_fit"] = {"params": cal.params, "stderr": cal.stderr, "model": cal.model}
        return d
    if not res["determined"]:
        f = res["flat"]
        d["undetermined_axis"] = f["normal"]
        d["flat"] = {"out_of_plane_std_gauss": f["out_of_plane_std"],
                     "noise_std_along_normal_gauss": f["noise_std_along_normal"],
                     "ring_centre_gauss": f["ring_centre"]}
        return d
    d.update(res["calibration"].to_json())
    d["input"] = "rotation"
    d["coverage"] = res["coverage"]
    d["norm_rel_std"] = res["norm_rel_std"]
    d["predicted_rel_std"] = res["predicted_rel_std"]
    if res.get("consistency") is not None:
        d["field_excess_rel_std"] = res["consistency"]["excess_rel_std"]
    if "heldout" in res:
        d["heldout_time_split"] = res["heldout"]
    return d


def flat_message(res: Dict[str, Any]) -> str:
    """One line: why the rotation determines no calibration and what to record."""
    if "undetermined" in res:
        return undetermined_message(res)
    if "inconsistent" in res:
        c = res["inconsistent"]
        st = c.get("step")
        at = (f"{st['t_s']:.4g} s" if "t_s" in st else f"row {st['row']}") if st else ""
        when = f"; it changes by {st['change']:+.0%} at {at}" if st else ""
        return (f"the corrected field's magnitude varies by {c['excess_rel_std']:.1%} of the field beyond "
                f"the noise (spread {c['rel_std']:.2%}, the noise alone {c['predicted_rel_std']:.2%}{when}); a "
                f"calibration is determined to {FIELD_EXCESS_MAX:.0%}: the field changed during the "
                f"recording (the board carried elsewhere, a magnet, a motor or iron nearby) or the sensor "
                f"clipped; no calibration is given: record again away from iron and magnets, in one place "
                f"(or calibrate the part before or after the change: --start-s, --end-s)")
    f = res["flat"]
    if f.get("rank", 2) < 2:
        return ("the magnetometer was hardly turned (its readings spread no more than its noise "
                "in at least two directions): nothing is determined; turn the sensor through every "
                "orientation and record again")
    n = ", ".join(f"{x:+.3f}" for x in f["normal"])
    return (f"the rotation stayed in one plane (normal [{n}] in sensor axes: spread across it "
            f"{f['out_of_plane_std']:.4g} vs noise {f['noise_std_along_normal']:.4g}): hard and soft "
            f"iron along that axis are not determined, so no calibration is given; tilt the sensor "
            f"onto another face and keep turning it (in-plane ring centre: "
            f"[{', '.join(f'{x:.6g}' for x in f['ring_centre'])}])")


def undetermined_message(res: Dict[str, Any]) -> str:
    """One line for a cloud that leaves terms undetermined (module doc): what, why, and
    which sensor axes never pointed along the field."""
    und = res["undetermined"]
    c = res["coverage"]
    if und[0]["reason"] == "coverage":
        ax = ", ".join(f"{x:+.2f}" for x in c["least_spread_axis"])
        what = (f"hard and soft iron: the field directions hardly spread along [{ax}] (direction "
                f"scatter eigenvalue {c['direction_eigenvalues'][-1]:.3f}; the rule needs "
                f"{MIN_DIRECTION_EIG:g}, the whole sphere gives 1/3)")
    else:
        F = abs(float(res["field_gauss"]))
        hard = [u for u in und if u["name"].startswith("hard")]
        soft = [u for u in und if u["name"].startswith("soft")]
        parts = []
        if hard:
            worst = max(u["stderr"] for u in hard)
            parts.append(f"hard iron {','.join(u['name'][-1] for u in hard)} (standard error up to "
                         f"{worst / F:.0%} of the field, the rule needs {HARD_IRON_SE_MAX:.0%})")
        if soft:
            worst = max(u["stderr"] for u in soft)
            parts.append(f"soft iron {','.join(u['name'].split('_')[-1] for u in soft)} (standard "
                         f"error up to {worst:.2g}, the rule needs {SOFT_IRON_SE_MAX:g})")
        what = " and ".join(parts)
    miss = res.get("missing_axes") or []
    faces = [m for m in miss if len(m) == 2] or miss[:4]
    toward = (f"; the field never came near the sensor's {', '.join(faces)} axes: turn the sensor "
              f"so that each of those in turn points along the field (north, dipping down)") if faces else ""
    return (f"the rotation does not determine {what}; the field directions reached "
            f"{c['fraction']:.0%} of the sphere{toward}; no calibration is given: turn the sensor "
            f"through every orientation (roll it over each face, not only round in one plane) "
            f"and record again")


def rotation_lines(res: Dict[str, Any]) -> List[str]:
    """Text lines for coverage, corrected-norm spread and the held-out figure."""
    c = res["coverage"]
    ev = ", ".join(f"{x:.3f}" for x in c["direction_eigenvalues"])
    out = [f"  coverage: {c['fraction']:.0%} of {c['cells']} direction cells; direction scatter "
           f"eigenvalues [{ev}] (1/3 each for the whole sphere)",
           f"  corrected |h| relative std {res['norm_rel_std']:.4f} over {res['samples']} readings"
           + (f" ({res['rows']} rows; a reading repeated on the next rows counted once)"
              if res.get("rows") != res["samples"] else "")
           + f" (noise alone would give {res['predicted_rel_std']:.4f})"]
    c = res.get("consistency")
    if c is not None:
        out.append(f"  field magnitude beyond the noise: {c['excess_rel_std']:.2%} of the field over the "
                   f"thinned cloud (a calibration is given up to {FIELD_EXCESS_MAX:.0%})")
    h = res.get("heldout")
    if h and "norm_rel_std" in h:
        out.append(f"  held out in time: fitted on the first {h['train_samples']} samples, "
                   f"relative std {h['norm_rel_std']:.4f} on the last {h['test_samples']}")
    elif h:
        out.append(f"  held out in time: {h['note']}")
    return out
