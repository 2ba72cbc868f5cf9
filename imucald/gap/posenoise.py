"""The variance of a pose mean from the recording's own within-pose statistics, tremor
included (the twin's noise; issue 25 item 1), and the disturbed poses.

The structure-function estimate lives in :mod:`imucald.fitting.noise.posecov` (the calibration's
pose covariance uses it too); the gap twin calls it one-sided per axis: it replaces the white
figure only when clearly below it (its colour inflation is handled elsewhere), and for the
accelerometer two-sided on the radial series, whose colour clearly above the white figure
it takes when larger (gap/diagnose.py ``_accel_pose_noise``).
"""
from __future__ import annotations

import numpy as np

from ..fitting.noise.posecov import FRACTIONS, MIN_SAMPLES, pose_mean_variance

__all__ = ["pose_mean_variance", "flag_disturbed", "flicker_level", "flicker_between_poses",
           "FRACTIONS", "MIN_SAMPLES"]


def flag_disturbed(s2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Poses whose within-pose variance ``s2`` (n samples each) is far above the robust
    level (hand moved)."""
    med = np.median(s2)
    # chi-square(n-1)/(n-1) upper 99.9 % point ~ 1 + 3.1 sqrt(2/(n-1)); times 1.5 for colour
    lim = med * 1.5 * (1 + 3.1 * np.sqrt(2.0 / np.maximum(n - 1, 1)))
    return s2 > lim


#: the Hadamard variance of flicker noise of one-sided PSD h / f, over h: (8/3) times the
#: integral of sin^6 x / x^3 over x > 0 (IEEE Std 952-1997 annex C's transfer-function
#: method applied to the three-sample variance; white noise reads the Allan figure)
FLICKER_HVAR_PER_H = 1.1247
#: the pose means' variance about their common mean under flicker noise is h (ln(S/T) + c0)
#: for poses of T seconds over a span of S; c0 from 300 simulated 1/f records for each of
#: six layouts (S 200-1200 s, T 3-30 s): -0.10..0.34, the middle taken
FLICKER_SPAN_C0 = 0.1
#: the pooled flicker level must stand this many (jackknife) standard errors above zero to
#: enter the twin.  Measured (tests/test_gap_flicker.py's generator, 15-40 holds of 3-12 s,
#: 0.005 dps/rtHz): white noise passes in 4 of 200 recordings (2 %), a flicker floor of
#: 0.002 dps (B ~ 11 deg/h) in 45 of 60 (at 2.0: 1 of 200 and 34 of 60)
FLICKER_GATE_Z = 1.5


def _hadamard_rows(x: np.ndarray, slices, rate_hz: float):
    """(tau_s (m,), hvar (m, C), dof (m,), pose (m,)): each pose's three-sample (Hadamard)
    variance of the means of its 16ths, 8ths and quarters (second differences: blind to a
    linear drift through the hold, e.g. a warm-up's), and which pose each row is from."""
    taus, hv, dof, pose = [], [], [], []
    for i, s in enumerate(slices):
        n = s.stop - s.start
        if n < 32:
            continue
        xb = x[s]
        for parts in (16, 8, 4):
            b = np.linspace(0, n, parts + 1).astype(int)
            q = np.add.reduceat(xb, b[:-1], axis=0) / np.diff(b)[:, None]
            d = q[2:] - 2 * q[1:-1] + q[:-2]
            taus.append(n / parts / rate_hz)
            hv.append(np.mean(d * d, axis=0) / 6.0)
            dof.append(parts - 2)
            pose.append(i)
    return (np.array(taus), np.array(hv).reshape(len(taus), x.shape[1]), np.array(dof, float),
            np.array(pose, dtype=int))


def _fit_h(taus: np.ndarray, hv: np.ndarray, dof: np.ndarray) -> float:
    """h of hv = a / tau + H h (one axis), weighted least squares (weights: degrees of
    freedom over the model squared, the model never below half the white-only one: a fit
    at or below zero at some tau would weigh those rows without bound; iterated)."""
    A = np.column_stack([1.0 / taus, np.full(len(taus), FLICKER_HVAR_PER_H)])
    white = np.sum(dof * hv * taus) / np.sum(dof) / taus
    w = dof / white ** 2
    for _ in range(3):
        sw = np.sqrt(w)
        sol = np.linalg.lstsq(A * sw[:, None], hv * sw, rcond=None)[0]
        w = dof / np.maximum(A @ sol, 0.5 * white) ** 2
    return float(sol[1])


def flicker_level(x: np.ndarray, slices, rate_hz: float):
    """(h (C,), its standard error (C,)) per axis: the flicker (1/f, bias instability) level of
    ``x`` read inside the still poses, h of the one-sided PSD h / f (units^2), from the
    poses' Hadamard variances at T/16, T/8 and T/4 pooled and fitted as a / tau + H h
    (:func:`_fit_h`); the standard error by the jackknife over poses (the rows of one pose
    share its samples, and a flicker's variance estimates scatter beyond their degrees of
    freedom: the formula's error read 1.7x too small on simulated 1/f).  None when fewer
    than 3 poses have 32 samples; an axis held at one value reads 0 +- 0."""
    x = np.asarray(x, float).reshape(len(x), -1)
    taus, hv, dof, pose = _hadamard_rows(x, slices, rate_hz)
    ids = np.unique(pose)
    if len(ids) < 3:
        return None
    C = hv.shape[1]
    h, se = np.zeros(C), np.zeros(C)
    for c in range(C):
        # an axis held at one value (or not finite) reads 0 +- 0: its variances are rounding
        white = np.sum(dof * hv[:, c] * taus) / np.sum(dof)
        scale = float(np.max(np.abs(x[:, c]))) if np.all(np.isfinite(x[:, c])) else 0.0
        if not white > (1e-12 * scale) ** 2 * np.max(taus):
            continue
        h[c] = _fit_h(taus, hv[:, c], dof)
        jk = np.array([_fit_h(taus[pose != i], hv[pose != i, c], dof[pose != i]) for i in ids])
        se[c] = np.sqrt((len(ids) - 1) / len(ids) * np.sum((jk - jk.mean()) ** 2))
    return h, se


def flicker_between_poses(x: np.ndarray, slices, rate_hz: float, axes=None):
    """(variance (N, C) to add to each pose mean's, info): the part of flicker noise slower
    than a pose, which no within-pose statistic sees, as it scatters the pose means about
    their common mean: h (ln(S / T_i) + c0) less the H h the pose's own colour already
    counts (poses of T_i s over a span of S s; :func:`flicker_level`'s h).  Zero unless the
    pooled level stands FLICKER_GATE_Z standard errors above zero (white noise: 2 % of
    recordings add a little).  Only the ``axes`` (C,) bool given are read (default all):
    where a hand's tremor or sway fills the holds, their variances follow the hand, not
    a / tau + H h, and the fit reads flicker where there is none (a simulated swaying
    hand-held session's gyro twin read 15x its held-out residual)."""
    N = len(slices)
    C = x.shape[1] if x.ndim > 1 else 1
    x = x.reshape(len(x), C)
    on = np.ones(C, bool) if axes is None else np.asarray(axes, bool)
    lv = flicker_level(x[:, on], slices, rate_hz) if on.any() else None
    if lv is None:
        why = ("no axis free of a hand's tremor or sway" if not on.any()
               else "fewer than 3 poses of 32 samples")
        return np.zeros((N, C)), {"note": f"{why}: no flicker read"}
    h, se = np.zeros(C), np.zeros(C)
    h[on], se[on] = lv
    z = float(np.sum(h[on]) / max(np.sqrt(np.sum(se[on] ** 2)), 1e-300))
    info = {"h_per_axis": h.tolist(), "h_stderr": se.tolist(), "axes_read": on.tolist(), "z": round(z, 2)}
    if not z > FLICKER_GATE_Z:
        return np.zeros((N, C)), dict(info, added=False)
    T = np.array([max(s.stop - s.start, 1) / rate_hz for s in slices])    # an empty slice: one sample
    S = (max(s.stop for s in slices) - min(s.start for s in slices)) / rate_hz
    k = np.maximum(np.log(S / T) + FLICKER_SPAN_C0 - FLICKER_HVAR_PER_H, 0.0)
    info.update(added=True, span_s=round(S, 1), factor_median=round(float(np.median(k)), 3))
    return k[:, None] * np.maximum(h, 0.0)[None, :], info
