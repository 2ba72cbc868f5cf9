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

from typing import Dict, Optional

import numpy as np

from ..numerics.tails import chi2_sf

__all__ = ["random_walk_fit"]


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


def random_walk_fit(r: np.ndarray, J: np.ndarray, var: np.ndarray, B: np.ndarray, t_s: np.ndarray,
                    sims: int, rng, lam: Optional[np.ndarray] = None) -> Optional[Dict[str, object]]:
    """Residuals ``r`` (N,) of the baseline with Jacobian ``J`` (N, p), noise variances ``var``,
    bias sensitivities ``B`` (N, 3) and times ``t_s`` (N,).  Returns q (units^2/s), its
    likelihood-ratio p-value, the held-out residuals, the twin's ratio quantities; None
    when the record is too short in time."""
    N = len(r)
    t = np.asarray(t_s, float) - float(np.min(t_s))
    T = float(t.max())
    if N < 8 or T <= 0:
        return None
    K = (B @ B.T) * np.minimum(t[:, None], t[None, :])
    D = np.diag(var)
    # grid: the walk's variance over the record from 1e-2 to 1e4 times the median noise variance
    v0 = float(np.median(var))
    grid = v0 / T * np.logspace(-2, 4, 25)

    def reml(q):
        P, ld = _P(D + q * K, J, lam)
        return -0.5 * (ld + float(r @ P @ r)), P
    l0, P0 = reml(0.0)
    best = (l0, 0.0, P0)
    ls = []                                   # (q, restricted log-likelihood) over the grid
    for q in grid:
        try:
            l, P = reml(q)
        except np.linalg.LinAlgError:
            continue
        ls.append((q, l))
        if l > best[0]:
            best = (l, q, P)
    lq, q, P = best
    LR = max(2 * (lq - l0), 0.0)
    p = 0.5 * chi2_sf(LR, 1) if LR > 0 else 1.0
    # profile-likelihood 95 % interval of q (LR drop of 3.84) over the grid
    ci = [None, None]
    if q > 0:
        inside = [g for g, l in ls if 2 * (lq - l) <= 3.84]
        ci = [min(inside), max(inside)] if inside else [q, q]
        if 2 * (lq - l0) <= 3.84:
            ci[0] = 0.0
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
