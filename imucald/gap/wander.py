"""A wandering bias as a random walk (issue 25 item 2): a first-class candidate whose
strength is estimated, tested and compared with the Allan figures.

The bias b(t) (sensor frame, 3 axes) wanders as a random walk of intensity q
(units^2 / s per axis; its Allan variance is q tau / 3, IEEE Std 952-1997 annex C
"rate random walk" term).  Linearised about the baseline fit, a pose's residual moves by
B_i . b(t_i) with B_i = d r_i / d b (the bias column of the model's Jacobian), so the
residuals have covariance

    Sigma(q) = D + q K,   K_ij = (B_i . B_j) min(t_i, t_j)   (t from the first point),

D the points' noise variances.  The constant part of b is the baseline's own bias, so
the fixed effects J (the baseline parameters, with the calibration prior's precision)
are profiled out (REML).  Then:

* q by restricted maximum likelihood over a log grid;
* significance: the likelihood-ratio statistic of q = 0 on the boundary, p = 1/2 P(chi2_1 > LR);
* held-out residuals: the mixed model's leave-one-out e_i = (P r)_i / P_ii with
  P = S^-1 - S^-1 J (J' S^-1 J + Lambda)^-1 J' S^-1 (exact for a Gaussian process with fixed
  effects; with q = 0 it is the hat-matrix formula of fitting/judging/heldout.py);
* the twin: the same leave-one-out on re-simulations of noise plus a walk of strength q
  (the model's own prediction of its held-out residual).

Pure functions over arrays; O(N^3) per grid point (N up to ~1000 magnetometer points).
"""
from __future__ import annotations

import math
from typing import Dict, Optional

import numpy as np

from ..numerics.tails import chi2_sf

__all__ = ["random_walk_fit", "walk_kernel"]


def _P(S, J, lam):
    L = np.linalg.cholesky(S)
    Si = np.linalg.inv(L).T @ np.linalg.inv(L)
    SiJ = Si @ J
    A = J.T @ SiJ + (np.diag(lam) if lam is not None else 0.0)
    Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
    P = Si - SiJ @ Ai @ SiJ.T
    logdet = 2 * float(np.sum(np.log(np.diag(L))))
    sgn, ld_a = np.linalg.slogdet(A)
    return P, logdet + (ld_a if sgn > 0 else 0.0)


def walk_kernel(B: np.ndarray, t_s: np.ndarray, hold_s: Optional[np.ndarray] = None) -> np.ndarray:
    """K (N, N): the covariance of the points' residuals per unit walk intensity.  A point that
    is the mean over a hold of h_i seconds (a still pose) averages the walk over it: with the
    walk zero at the first hold's start and the holds disjoint, Cov(mean_i, mean_j) = q t_i
    (t_i the hold's middle, i before j) and Var(mean_i) = q (t_i - h_i / 6).  Taking the
    points as instants (h = 0) overstates the variance of the increments between consecutive
    poses, q (dt - (h_i + h_j) / 6) against q dt: on the blind generator's holds (6-14 s,
    1.5-3 s moves) the REML strength read 0.72-0.75 of the injected one."""
    t = np.asarray(t_s, float) - float(np.min(t_s))
    h = np.zeros(len(t)) if hold_s is None else np.clip(np.asarray(hold_s, float), 0.0, None)
    i0 = int(np.argmin(t_s))
    t = t + 0.5 * h[i0]                      # the first hold's start is the walk's origin
    K = np.minimum(t[:, None], t[None, :]) - np.diag(h / 6.0)
    return (B @ B.T) * K


def _loglik(reml, q):
    try:
        return reml(q)[0]
    except np.linalg.LinAlgError:
        return -np.inf


def _refine(reml, ls, l0, P0):
    """The REML maximum: the best grid point (a factor 1.78 apart), then golden-section search
    in log q between its neighbours (the grid's step alone put the estimate up to 33 % off and
    the interval's ends on grid points, so a true value just beside an end fell outside).
    Returns (q, log-likelihood, P)."""
    if not ls or max(l for _, l in ls) <= l0:
        return 0.0, l0, P0
    k = int(np.argmax([l for _, l in ls]))
    a = math.log(ls[max(k - 1, 0)][0])
    b = math.log(ls[min(k + 1, len(ls) - 1)][0])
    g = (math.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = _loglik(reml, math.exp(c)), _loglik(reml, math.exp(d))
    for _ in range(16):                       # the bracket shrinks to 0.06 % of a grid step
        if fc > fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = _loglik(reml, math.exp(c))
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = _loglik(reml, math.exp(d))
    q = math.exp(0.5 * (a + b))
    if ls[k][1] >= max(fc, fd):
        q = ls[k][0]
    lq, P = reml(q)
    return q, lq, P


def _profile_ci(reml, ls, q, lq, l0):
    """Profile-likelihood 95 % interval of q (a drop of 3.84 in 2 log-likelihood), each end
    found by bisection in log q between the grid points that straddle it; the grid's ends
    when it does not drop that far (0 below when q = 0 is inside)."""
    if not q > 0:
        return [None, None]
    drop = lambda l: 2 * (lq - l) - 3.84

    def cross(inside, outside):       # drop(inside) <= 0 < drop(outside): log-bisection
        a, b = math.log(inside), math.log(outside)
        for _ in range(12):
            m = 0.5 * (a + b)
            if drop(_loglik(reml, math.exp(m))) > 0:
                b = m
            else:
                a = m
        return math.exp(0.5 * (a + b))
    below = [(g, l) for g, l in ls if g < q]
    above = [(g, l) for g, l in ls if g > q]
    lo_end = ls[0][0]
    if drop(l0) <= 0:
        lo_end = 0.0
    else:
        out = [g for g, l in below if drop(l) > 0]
        if out:
            lo_end = cross(q, out[-1])
    hi_end = ls[-1][0]
    out = [g for g, l in above if drop(l) > 0]
    if out:
        hi_end = cross(q, out[0])
    return [lo_end, hi_end]


def random_walk_fit(r: np.ndarray, J: np.ndarray, var: np.ndarray, B: np.ndarray, t_s: np.ndarray,
                    sims: int, rng, lam: Optional[np.ndarray] = None,
                    hold_s: Optional[np.ndarray] = None) -> Optional[Dict[str, object]]:
    """Residuals ``r`` (N,) of the baseline with Jacobian ``J`` (N, p), noise variances ``var``,
    bias sensitivities ``B`` (N, 3) and times ``t_s`` (N,).  Returns q (units^2/s), its
    likelihood-ratio p-value, the held-out residuals, the twin's ratio quantities; None
    when the record is too short in time."""
    N = len(r)
    t = np.asarray(t_s, float) - float(np.min(t_s))
    T = float(t.max())
    if N < 8 or T <= 0:
        return None
    K = walk_kernel(B, t_s, hold_s)
    D = np.diag(var)
    # grid: the walk's variance over the record from 1e-2 to 1e4 times the median noise variance
    v0 = float(np.median(var))
    grid = v0 / T * np.logspace(-2, 4, 25)

    def reml(q):
        P, ld = _P(D + q * K, J, lam)
        return -0.5 * (ld + float(r @ P @ r)), P
    l0, P0 = reml(0.0)
    ls = []                                   # (q, restricted log-likelihood) over the grid
    for g in grid:
        try:
            ls.append((float(g), reml(g)[0]))
        except np.linalg.LinAlgError:
            continue
    q, lq, P = _refine(reml, ls, l0, P0)
    LR = max(2 * (lq - l0), 0.0)
    p = 0.5 * chi2_sf(LR, 1) if LR > 0 else 1.0
    ci = _profile_ci(reml, ls, q, lq, l0)
    Pd = np.diag(P)
    e = (P @ r) / Pd
    # the augmented model's twin: noise plus a walk of the fitted strength (a random walk is
    # not predictable from the neighbouring poses, so its held-out residual keeps the walk's
    # increments; "closed" means the data's held-out residual is what this model predicts)
    Lq = np.linalg.cholesky(D + q * K)
    n = rng.normal(size=(sims, N)) @ Lq.T
    en = (n @ P) / Pd                         # P symmetric
    tw = np.sqrt(np.mean(en * en / var, axis=1))
    twin = float(np.median(tw))
    edf = float((N - J.shape[1]) - np.trace(P * var[None, :])) if q > 0 else 0.0
    return {"q": float(q), "edf": edf, "q_ci95": ci, "lr": float(LR), "p_value": float(p), "heldout": e,
            "twin": twin, "twin_q99": float(np.quantile(tw / twin, 0.99)),
            "nrms": float(np.sqrt(np.mean(e * e / var))), "record_s": T}
