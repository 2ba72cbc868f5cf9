"""Held-out residuals and the digital twin: the test the gap diagnosis uses, shared with
model-order choices elsewhere (the thermal terms, fitting/thermal/terms.py).

A fit's leave-one-out residuals from its hat matrix (exact for a linear least-squares
fit, linearised for a norm fit), and the held-out residual the noise model predicts for
the same design (the twin: linearised re-simulations).  A model "closes" a gap when its
held-out RMS lies within the twin's 99th percentile (gap/verdict.py).
"""
from __future__ import annotations

import numpy as np

__all__ = ["numjac", "lm_weighted", "hat_diag", "heldout", "twin_rms"]


def numjac(fun, z, eps=None):
    z = np.asarray(z, float)
    r0 = fun(z)
    J = np.zeros((len(r0), len(z)))
    for k in range(len(z)):
        h = (eps[k] if eps is not None else 1e-6 * max(1.0, abs(z[k])))
        d = np.zeros_like(z)
        d[k] = h
        J[:, k] = (fun(z + d) - fun(z - d)) / (2 * h)
    return r0, J


def lm_weighted(fun, z0, w, iters=60):
    """Weighted least squares min sum w r^2 with numerical Jacobians (small problems)."""
    z = np.asarray(z0, float).copy()
    r = fun(z)
    f = float(np.sum(w * r * r))
    mu = 1e-3
    for _ in range(iters):
        r, J = numjac(fun, z)
        A = J.T @ (J * w[:, None])
        g = J.T @ (w * r)
        dA = np.diag(A).copy()
        dA[dA <= 0] = 1e-12
        improved = False
        for _ in range(12):
            try:
                step = -np.linalg.solve(A + mu * np.diag(dA), g)
            except np.linalg.LinAlgError:
                step = -np.linalg.lstsq(A + mu * np.diag(dA), g, rcond=None)[0]
            zn = z + step
            rn = fun(zn)
            fn = float(np.sum(w * rn * rn))
            if fn < f:
                rel = (f - fn) / max(f, 1e-300)
                z, r, f = zn, rn, fn
                mu = max(mu / 3, 1e-12)
                improved = True
                break
            mu *= 4
        if not improved or rel < 1e-12:
            break
    r, J = numjac(fun, z)
    return z, r, J


def _normal(J, w, lam=None):
    """J' W J plus the prior precision ``lam`` (per column; the calibration's MAP prior)."""
    A = J.T @ (J * w[:, None])
    if lam is not None:
        A = A + np.diag(np.asarray(lam, float))
    return A


def hat_diag(J, w, lam=None):
    """Leverages and the (posterior) covariance (J'WJ + diag(lam))^+ ."""
    Ai = np.linalg.pinv(_normal(J, w, lam), rcond=1e-12, hermitian=True)
    return np.einsum("nk,kl,nl->n", J, Ai, J) * w, Ai


def heldout(r, J, w, lam=None):
    h, _ = hat_diag(J, w, lam)
    return r / np.maximum(1 - h, 1e-3)


def twin_rms(J, var, w, sims, rng, lam=None, normalised=False):
    """Held-out RMS under the noise model for this design: M linearised re-simulations
    (with a prior of precision ``lam`` the fit is the MAP one, the prior mean held fixed).
    ``normalised``: the RMS of held-out residual / noise sd (points of unequal noise)."""
    Jw = J * w[:, None]
    Ai = np.linalg.pinv(_normal(J, w, lam), rcond=1e-12, hermitian=True)
    # the hat matrix H = J Ai Jw^T is applied in factored form (never N x N: 50 MB at 2,500
    # poses); its diagonal as in hat_diag
    h = np.einsum("nk,kl,nl->n", J, Ai, Jw)
    n = rng.normal(size=(sims, len(var))) * np.sqrt(var)
    r = n - ((n @ Jw) @ Ai.T) @ J.T
    e = r / np.maximum(1 - h, 1e-3)
    if normalised:
        return np.sqrt(np.mean(e * e / var, axis=1))
    return np.sqrt(np.mean(e * e, axis=1))
