"""Leave-one-pose-out (and k-fold) refits of a norm fit, all folds at once.

calib/fit.py's held-out figures refit the model without each pose (38 LM runs on the
Xsens file, each warm-started at the full fit).  Here every fold is one row of a batch:
the fold's objective is the full problem's with the held-out poses' residual rows
zeroed, and Gauss-Newton steps are taken on all folds together (one residual and
Jacobian evaluation of the batch per step, calib.lsq.Problem.rj).  It converges to the
same minimiser as the LM refit (a small-residual problem, started within ~1e-4 of it:
quadratic convergence in 2-4 steps), so the held-out residuals are the same numbers to
~1e-12 g (tests/test_calibrate_all.py compares them).  A fold that leaves the search box
or does not converge is returned as None and refitted by LM as before.
"""
from __future__ import annotations

from typing import List, Optional, Sequence

import numpy as np

from .lsq import Problem

__all__ = ["fold_thetas"]

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
