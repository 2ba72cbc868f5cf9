"""Fisher information, Cramér-Rao bound, rank and condition of a norm fit.

The norm-linearised bound (reference/error-models.md section 4.1 (b)): for pose i
with pose-mean covariance Sigma_i, the residual r_i = target - |A x_i + c| has
variance  v_i = u_i^T A Sigma_i A^T u_i  (u_i the corrected unit vector), so

    I(theta) = sum_i J_i^T J_i / v_i,        CRLB = I^-1.

When no per-pose covariance is known the residual variance is estimated from
the fit itself, s^2 = SSR / (N - k).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from .models import NormModel

__all__ = ["Uncertainty", "residual_variance", "fisher", "crlb"]


@dataclass
class Uncertainty:
    """What a pose set can and cannot determine, for one model at one theta."""

    cov: np.ndarray                 #: (k, k) CRLB covariance (pseudo-inverse on the observable part)
    std: np.ndarray                 #: (k,) CRLB standard deviations; inf = not determined at all
    rank: int                       #: numerical rank of the whitened Jacobian
    condition: float                #: its condition number on the observable subspace
    singular_values: np.ndarray     #: of the whitened Jacobian, descending
    null_directions: np.ndarray     #: (m, k) parameter directions the data cannot see
    unobservable: List[str] = field(default_factory=list)  #: parameters with no information at all


def residual_variance(model: NormModel, theta: np.ndarray, raw: np.ndarray,
                      pose_cov: Optional[np.ndarray]) -> np.ndarray:
    """Per-pose residual variance v_i (N,) from pose-mean covariances.

    pose_cov: (N, 3, 3) covariance of each pose *mean*, (N,) isotropic variances,
    or a scalar variance.
    """
    A, c = model.affine(theta)
    raw = np.asarray(raw, float)
    h = raw @ A.T + c
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    w = u @ A                                   # A^T u, (N, 3)
    pc = np.asarray(pose_cov, float)
    if pc.ndim == 3:
        return np.einsum("ni,nij,nj->n", w, pc, w)
    return np.broadcast_to(pc, (len(raw),)) * np.einsum("ni,ni->n", w, w)


def fisher(model: NormModel, theta: np.ndarray, raw: np.ndarray,
           var: np.ndarray, free: Optional[np.ndarray] = None) -> np.ndarray:
    """Fisher information of the free parameters given per-pose residual variances."""
    _, J = model.jacobian(theta, raw)
    if free is not None:
        J = J[:, free]
    Jw = J / np.sqrt(var)[:, None]
    return Jw.T @ Jw


def crlb(model: NormModel, theta: np.ndarray, raw: np.ndarray, var: np.ndarray,
         free: Optional[np.ndarray] = None, rtol: float = 1e-10) -> Uncertainty:
    """Cramér-Rao bound with an honest account of unobservable directions.

    Directions with singular value below ``rtol`` times the largest are the
    null space; the covariance is the pseudo-inverse (i.e. expressed in the
    gauge orthogonal to the null space).  A parameter whose Jacobian column
    carries no information at all gets std = inf.
    """
    theta = np.asarray(theta, float)
    free = model.free_mask if free is None else np.asarray(free, bool)
    _, J = model.jacobian(theta, raw)
    J = J[:, free]
    Jw = J / np.sqrt(np.asarray(var, float))[:, None]
    # column scaling so that rank decisions do not depend on parameter units
    colnorm = np.linalg.norm(Jw, axis=0)
    scale = np.where(colnorm > 0, colnorm, 1.0)
    U, s, Vt = np.linalg.svd(Jw / scale, full_matrices=True)
    smax = s.max() if s.size else 0.0
    keep = s > rtol * smax if smax > 0 else np.zeros_like(s, bool)
    rank = int(keep.sum())
    kf = Jw.shape[1]
    V = Vt.T
    inv_s2 = np.zeros(kf)
    inv_s2[:len(s)][keep] = 1.0 / s[keep] ** 2
    cov_scaled = (V * inv_s2) @ V.T
    cov_f = cov_scaled / np.outer(scale, scale)
    null = V[:, rank:].T / scale[None, :] if rank < kf else np.zeros((0, kf))
    if null.size:
        null = null / np.linalg.norm(null, axis=1, keepdims=True)
    k = model.k
    cov = np.zeros((k, k))
    idx = np.flatnonzero(free)
    cov[np.ix_(idx, idx)] = cov_f
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    dead = colnorm <= 1e-12 * max(colnorm.max(), 1e-300)
    unobs = []
    for j, d in zip(idx, dead):
        if d:
            std[j] = np.inf
            unobs.append(model.param_names[j])
    null_full = np.zeros((null.shape[0], k))
    null_full[:, idx] = null
    cond = float(s[keep].max() / s[keep].min()) if rank else float("inf")
    return Uncertainty(cov=cov, std=std, rank=rank, condition=cond, singular_values=s,
                       null_directions=null_full, unobservable=unobs)
