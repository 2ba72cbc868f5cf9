"""Noise of pose means: per-pose variance and its inflation by coloured noise.

One place for the estimate that both the calibration's uncertainty and the gap
diagnosis use.  A pose mean over T seconds of white noise has variance
sigma^2 / n; flicker and random-walk noise make it larger.  The inflation over
white noise at averaging time T comes from the Allan variance of the longest
still stretch, fitted per axis with the three classic terms (IEEE Std 952-1997
annex C: white noise ~ 1/tau, flicker (bias instability) ~ const, random walk
~ tau), non-negative, by least squares weighted by each point's relative error
1/sqrt(K - 1) (K averages):

    AVAR(tau) = a / tau + b + c tau,    k(T) = mean over axes of 1 + (b T + c T^2) / a,

clamped to [1, 9].  A fitted curve rather than the Allan deviation read at T
alone: with a 50 s stretch and 7 s poses that single point rests on 7 averages and
scatters by a factor of 2 (IMU-TK Xsens recording).  It needs a still stretch of at
least max(30 s, 3 T); poses longer than a third of the stretch use k at that third.
"""
from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from ...numerics.npstats import median

__all__ = ["allan_deviation", "allan_model", "fit_avar_terms", "inflation_of", "colour_inflation", "colour_inflation_per_pose",
           "pose_colour_inflation",
           "MIN_STRETCH_S", "MAX_INFLATION"]

MIN_STRETCH_S = 30.0        #: shortest still stretch that gives an Allan deviation, s
MAX_INFLATION = 9.0         #: an inflation beyond this is a disturbance, not noise colour


def allan_deviation(x, rate_hz: float, taus, overlapping: bool = False) -> np.ndarray:
    """Allan deviation of a signal x (n, d) at averaging times taus (s), one implementation
    for the pose-noise model, the gap diagnosis and ``imucald noise``.

    sigma^2(tau) = 1/2 < (mean_{k+m} - mean_k)^2 >, over consecutive non-overlapping
    tau-averages (default) or, with ``overlapping``, over every start k (the overlapping
    estimator, IEEE Std 952-1997 annex C; NIST SP 1065 eq. 8: the same expectation, more
    degrees of freedom).  Cluster size m = round(tau rate_hz).  Returns (len(taus), d);
    NaN where fewer than 3 non-overlapping averages fit.
    """
    x = np.asarray(x, float).reshape(len(x), -1)
    out = np.full((len(taus), x.shape[1]), np.nan)
    c = None
    for i, tau in enumerate(taus):
        m = int(round(tau * rate_hz))
        k = len(x) // max(m, 1)
        if m < 1 or k < 3:
            continue
        if overlapping:
            if c is None:       # running sums: every m-average in O(n)
                c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x - x.mean(0), axis=0)])
            a = (c[m:] - c[:-m]) / m
            out[i] = np.sqrt(0.5 * np.mean((a[m:] - a[:-m]) ** 2, axis=0))
        else:
            a = x[:k * m].reshape(k, m, -1).mean(1)
            out[i] = np.sqrt(0.5 * np.mean(np.diff(a, axis=0) ** 2, axis=0))
    return out


def fit_avar_terms(taus, avar, weights, subsets=((0, 1, 2), (0, 1), (0, 2), (0,))
                   ) -> Tuple[np.ndarray, Tuple[int, ...]]:
    """Non-negative coefficients [a, b, c] of AVAR(tau) = a/tau + b + c tau for one axis:
    weighted least squares (residuals times ``weights``) over the term subsets that keep
    the white term, the smallest weighted residual winning.  Returns (coef (3,), terms)."""
    taus, y, w = (np.asarray(v, float) for v in (taus, avar, weights))
    ok = np.isfinite(y) & (y > 0) & np.isfinite(w)
    A = np.column_stack([1.0 / taus, np.ones_like(taus), taus])[ok]
    out = np.zeros(3)
    best = None
    for cols in subsets:
        Aw = A[:, cols] * w[ok][:, None]
        sol = np.linalg.lstsq(Aw, y[ok] * w[ok], rcond=None)[0]
        if np.all(sol >= 0):
            cost = float(np.sum((Aw @ sol - y[ok] * w[ok]) ** 2))
            if best is None or cost < best[0]:
                best = (cost, cols, sol)
    if best is None:
        return out, ()
    out[list(best[1])] = best[2]
    return out, best[1]


def allan_model(x_still: np.ndarray, rate_hz: float, points: int = 14) -> np.ndarray:
    """Per-axis coefficients [a, b, c] (d, 3) of AVAR(tau) = a/tau + b + c tau (module doc),
    fitted on ``points`` log-spaced averaging times from 4 samples to a quarter of the
    stretch; the non-negative fit with the smallest weighted residual among the term
    subsets that keep the white term."""
    x = np.asarray(x_still, float).reshape(len(x_still), -1)
    taus = np.geomspace(4.0 / rate_hz, len(x) / rate_hz / 4.0, points)
    av = allan_deviation(x - x.mean(0), rate_hz, taus) ** 2
    K = np.array([len(x) // max(int(round(t * rate_hz)), 1) for t in taus], float)
    out = np.zeros((x.shape[1], 3))
    for d in range(x.shape[1]):
        out[d] = fit_avar_terms(taus, av[:, d], np.sqrt(K - 1) / av[:, d])[0]
    return out


def inflation_of(coef: np.ndarray, T) -> np.ndarray:
    """k(T) of the module doc from per-axis coefficients [a, b, c] (d, 3): the pose-mean
    variance over T seconds relative to white noise, mean over axes, clamped to [1, 9]."""
    a, b, c = coef[:, 0:1], coef[:, 1:2], coef[:, 2:3]
    T = np.atleast_1d(np.asarray(T, float))[None, :]
    k = 1.0 + (b * T + c * T * T) / np.where(a > 0, a, np.inf)
    return np.clip(np.mean(k, axis=0), 1.0, MAX_INFLATION)


def colour_inflation(x_still: Optional[np.ndarray], rate_hz: float, pose_s: float
                     ) -> Tuple[float, Optional[Dict[str, object]]]:
    """Variance inflation of a pose mean over ``pose_s`` seconds relative to white noise,
    from a still stretch x_still (n, d) sampled at rate_hz.  Returns (k, info); k = 1
    with a note when the stretch is too short (info None when there is no stretch)."""
    if x_still is None:
        return 1.0, None
    x = np.asarray(x_still, float)
    dur = len(x) / rate_hz
    need = max(MIN_STRETCH_S, 3 * pose_s)
    if dur < need:
        return 1.0, {"note": f"longest still stretch {dur:.0f} s: too short for an Allan deviation "
                             f"at the {pose_s:.0f} s pose length (need {need:.0f} s)"}
    coef = allan_model(x, rate_hz)
    k = float(inflation_of(coef, pose_s)[0])
    ad = allan_deviation(x - x.mean(0), rate_hz, [4.0 / rate_hz, pose_s])
    white = np.sqrt(coef[:, 0] / pose_s)
    return k, {"still_stretch_s": round(dur, 1), "pose_length_s": round(pose_s, 1),
               "allan_at_pose_length": ad[1].tolist(), "white_prediction": white.tolist(),
               "variance_inflation": round(k, 3)}


def colour_inflation_per_pose(x_still: Optional[np.ndarray], rate_hz: float,
                              pose_s: np.ndarray) -> Tuple[np.ndarray, Dict[str, object]]:
    """:func:`colour_inflation` at each pose's own length (s), (N,).  Poses longer than a
    third of the stretch use the value at a third.  Returns (k (N,), summary)."""
    T = np.asarray(pose_s, float)
    if x_still is None or len(x_still) / rate_hz < MIN_STRETCH_S:
        dur = 0.0 if x_still is None else len(x_still) / rate_hz
        return np.ones(len(T)), {"note": f"no still stretch of {MIN_STRETCH_S:.0f} s or more "
                                         f"(longest {dur:.0f} s): white noise assumed"}
    dur = len(x_still) / rate_hz
    k = inflation_of(allan_model(x_still, rate_hz), np.minimum(T, dur / 3.0))
    return k, {"still_stretch_s": round(dur, 1), "variance_inflation_median": round(float(median(k)), 3),
               "variance_inflation_range": [round(float(k.min()), 3), round(float(k.max()), 3)]}


def pose_colour_inflation(t_s: np.ndarray, x: np.ndarray, rate_hz: float, t0_s: np.ndarray,
                          t1_s: np.ndarray, n: np.ndarray) -> Tuple[np.ndarray, Dict[str, object]]:
    """Per-pose inflation for poses [t0, t1] (s) of a recording (t_s, x): the longest pose
    is the still stretch the Allan model is read from; each pose's length is n / rate."""
    if len(t0_s) == 0:
        return np.ones(0), {"note": "no poses"}
    i = int(np.argmax(np.asarray(t1_s) - np.asarray(t0_s)))
    i0, i1 = np.searchsorted(t_s, [t0_s[i], t1_s[i]])
    return colour_inflation_per_pose(x[i0:i1], rate_hz, np.asarray(n, float) / rate_hz)
