"""Leave-one-pose-out (and k-fold) refits of a norm fit, all folds at once.

fitting/fit.py's held-out figures refit the model without each pose (38 LM runs on the
Xsens file, each warm-started at the full fit).  Here every fold is one row of a batch:
the fold's objective is the full problem's with the held-out poses' residual rows
zeroed, and Gauss-Newton steps are taken on all folds together (one residual and
Jacobian evaluation of the batch per step, fitting.solvers.lsq.Problem.rj).  It converges to the
same minimiser as the LM refit (a small-residual problem, started within ~1e-4 of it:
quadratic convergence in 2-4 steps), so the held-out residuals are the same numbers to
~1e-12 g (tests/test_calibrate_all.py compares them).  A fold that leaves the search box
or does not converge is returned as None, and fitting/fit.py then refits every fold by LM
as before.  The predicted std of each held-out residual (the fold's covariance,
fitting.judging.uncertainty.map_covariance) is formed for all folds at once too.
"""
from __future__ import annotations

from typing import List, Optional, Sequence

import numpy as np

from .lsq import Problem

__all__ = ["fold_thetas", "heldout_by_update"]

#: a fold has converged when its largest step is below this (free-parameter units: g, 1)
STEP_TOL = 1e-12
MAX_STEPS = 12


def fold_thetas(prob: Problem, z0: np.ndarray, groups: Sequence[np.ndarray]) -> List[Optional[np.ndarray]]:
    """The fold solutions (full theta each, or None where LM must refit it): ``prob`` the
    problem over all poses (no weights), ``z0`` the full fit's free parameters, ``groups``
    the held-out pose indices of each fold."""
    N = len(prob.raw)
    G = len(groups)
    keep = np.ones((G, N))
    for i, g in enumerate(groups):
        keep[i, g] = 0.0
    if prob.has_prior:                       # the prior's pseudo-rows stay in every fold
        keep = np.concatenate([keep, np.ones((G, prob.kf))], 1)
    Z = np.repeat(np.asarray(z0, float)[None, :], G, 0)
    done = np.zeros(G, bool)
    for _ in range(MAX_STEPS):
        r, J = prob.rj(Z)                     # (G, rows), (G, rows, kf)
        Jk = J * keep[:, :, None]
        H = np.einsum("gnk,gnl->gkl", Jk, J)
        g = np.einsum("gnk,gn->gk", Jk, r)
        try:
            step = -np.linalg.solve(H, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return [None] * G
        Z = Z + step
        done = np.max(np.abs(step), axis=1) < STEP_TOL * np.maximum(1.0, np.max(np.abs(Z), axis=1))
        if done.all():
            break
    inside = np.all((Z > prob.lo) & (Z < prob.hi), axis=1) & ~prob.at_bound(Z).any(axis=1)
    th = prob.expand(Z)
    return [th[i] if done[i] and inside[i] else None for i in range(G)]


def heldout_by_update(model, theta, raw, target, groups, lo=None, hi=None, prior=None, var=None):
    """fitting.fit.heldout_residuals' result ((residuals, predicted std) with ``var``, else
    residuals), every fold solved by :func:`fold_thetas`; None when a fold needs the LM."""
    raw = np.asarray(raw, float)
    N = len(raw)
    pm, psd, nv = prior if prior is not None else (None, None, 1.0)
    prob = Problem(model, raw, target, lo=lo, hi=hi, prior_mean=pm, prior_std=psd, noise_var=nv)
    th = fold_thetas(prob, prob.reduce(theta), groups)
    if any(t is None for t in th):
        return None
    TH = np.array(th)                                    # (G, k)
    r, J = model.jacobian(TH, raw, target)               # (G, N), (G, N, k)
    out = np.zeros(N)
    for i, g in enumerate(groups):
        out[g] = r[i, g]
    if var is None:
        return out
    var = np.asarray(var, float)
    J = J[..., prob.free]
    keep = np.ones((len(groups), N))
    for i, g in enumerate(groups):
        keep[i, g] = 0.0
    P = np.diag(prob.prior_precision())
    Jk = J * keep[:, :, None]
    H = np.einsum("gnk,gnl->gkl", Jk, J) / nv + P        # map_covariance, every fold at once
    Hp = np.linalg.pinv(H, rcond=1e-12, hermitian=True)
    M = np.einsum("gnk,gnl->gkl", Jk * var[None, :, None], J) / nv ** 2 + P
    C = Hp @ M @ Hp
    pred = np.zeros(N)
    for i, g in enumerate(groups):
        Gi = J[i, g]
        pred[g] = np.sqrt(var[g] + np.einsum("nk,kl,nl->n", Gi, C[i], Gi))
    return out, pred
