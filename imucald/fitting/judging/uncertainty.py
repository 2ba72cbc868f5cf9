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
from typing import Dict, List, Optional

import numpy as np

from ..models.base import NormModel

__all__ = ["Uncertainty", "residual_variance", "fisher", "crlb", "map_covariance",
           "omitted_covariance", "determination", "UNDETERMINED_RATIO"]

#: a parameter whose posterior std is above this fraction of its prior std is
#: ``undetermined``: the poses cut the prior's variance by less than 75 %
UNDETERMINED_RATIO = 0.5


@dataclass(eq=False)
class Uncertainty:
    """What a pose set can and cannot determine, for one model at one theta."""

    cov: np.ndarray                 #: (k, k) CRLB covariance (pseudo-inverse on the observable part)
    std: np.ndarray                 #: (k,) CRLB standard deviations; inf = not determined at all
    rank: int                       #: numerical rank of the whitened Jacobian
    condition: float                #: its condition number on the observable subspace
    singular_values: np.ndarray     #: of the whitened Jacobian, descending
    null_directions: np.ndarray     #: (m, k) parameter directions the data cannot see
    unobservable: List[str] = field(default_factory=list)  #: parameters with no information at all
    #: (k,) prior std of each parameter (inf: no prior); None when the fit had no prior
    prior_std: Optional[np.ndarray] = None
    #: (k,) std of the estimate with the prior and the per-pose noise (what to believe)
    posterior_std: Optional[np.ndarray] = None
    #: (k,) the part of posterior_std from the terms the model leaves out (diag6's
    #: non-orthogonality, the bias's temperature slope: fit._fixed_terms_cov), as a std
    #: (posterior_std^2 = the fit's own variance + left_out_std^2); None when none is left out
    left_out_std: Optional[np.ndarray] = None
    #: parameters the data did not determine or that ended on a search bound: one dict
    #: each (name, reason, ratio posterior/prior std, the orientation that would help)
    flags: List[Dict[str, object]] = field(default_factory=list)


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
    # V only (U is N x N with full matrices: 48 MB at 2,500 poses); with N >= k the reduced
    # decomposition has the same V, and with fewer poses the full one carries the null space
    _, s, Vt = np.linalg.svd(Jw / scale, full_matrices=Jw.shape[0] < Jw.shape[1])
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


def map_covariance(J: np.ndarray, var: np.ndarray, noise_var: float,
                   prior_precision: np.ndarray) -> np.ndarray:
    """Covariance of the MAP estimate of an unweighted norm fit with a Gaussian prior.

    J (N, kf) residual Jacobian, var (N,) each pose's residual variance, noise_var the
    variance that weighs the data against the prior, prior_precision (kf,) (0 = none).
    With H = J'J / noise_var + P:  C = H^+ (J' V J / noise_var^2 + P) H^+  (the sandwich:
    right when the per-pose variances differ from noise_var; H^+ when they do not).
    Without a prior it is the plain least-squares sandwich (J'J)^+ J'VJ (J'J)^+.
    """
    P = np.diag(np.asarray(prior_precision, float))
    H = J.T @ J / noise_var + P
    Hp = np.linalg.pinv(H, rcond=1e-12, hermitian=True)
    return Hp @ ((J.T * np.asarray(var, float)) @ J / noise_var ** 2 + P) @ Hp


def omitted_covariance(J_free: np.ndarray, J_fixed: np.ndarray, noise_var: float,
                       prior_precision: np.ndarray, fixed_second_moment: np.ndarray) -> np.ndarray:
    """Covariance (kf, kf) the terms a model holds fixed add to its free estimates.

    A fixed term (diag6's non-orthogonality, held at 0) is not 0 on a real part, and the free
    terms absorb what it does to the poses (least squares' omitted-variable bias, linearised):
    the MAP estimate moves by -A d, with A = H^+ J_free' J_fixed / noise_var and H as in
    :func:`map_covariance`, for the fixed terms' offset d from where they are held, of second
    moment ``fixed_second_moment`` = E[d d'] (kf_fixed, kf_fixed); its covariance A E[d d'] A'.
    This is the error of the estimate the model makes (not the full model's posterior, which
    is centred elsewhere)."""
    H = J_free.T @ J_free / noise_var + np.diag(np.asarray(prior_precision, float))
    A = np.linalg.pinv(H, rcond=1e-12, hermitian=True) @ (J_free.T @ J_fixed) / noise_var
    return A @ np.asarray(fixed_second_moment, float) @ A.T


def _describe_up(u: np.ndarray) -> str:
    ang = np.degrees(np.arccos(np.clip(u, -1, 1)))
    axes = ", ".join(f"{a} {d:.0f}" for a, d in zip("xyz", ang))
    return (f"hold a pose with the sensor axes at {axes} degrees from straight up "
            f"(up-vector {u[0]:+.2f} {u[1]:+.2f} {u[2]:+.2f} in the sensor frame)")


def determination(model: NormModel, theta: np.ndarray, raw: np.ndarray, cov: np.ndarray,
                  prior_std: np.ndarray, at_bound: np.ndarray, pose_var: float,
                  target: float = 1.0, free: Optional[np.ndarray] = None,
                  ratio: float = UNDETERMINED_RATIO) -> List[Dict[str, object]]:
    """Flag parameters the data did not determine, and every one on a search bound.

    cov (k, k) the estimate's covariance (:func:`map_covariance`, expanded); prior_std
    (k,) (inf: none); at_bound (k,) bool; pose_var a typical pose's residual variance.
    A parameter is ``undetermined`` when std / prior std > ``ratio``, or when it has no
    prior and infinite std.  For each flagged one, the up-vector (sensor frame) of the
    single extra pose that would cut its std most is searched on a 400-point lattice.
    """
    free = model.free_mask if free is None else np.asarray(free, bool)
    idx = np.flatnonzero(free)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    C = cov[np.ix_(idx, idx)]
    flags: List[Dict[str, object]] = []
    U = None
    for jj, j in enumerate(idx):
        ps = float(prior_std[j])
        rho = sd[j] / ps if np.isfinite(ps) else (np.inf if not np.isfinite(sd[j]) else 0.0)
        und = rho > ratio
        if not (und or at_bound[j]):
            continue
        if U is None:          # the lattice's gains, formed once and only when a parameter is flagged
            from .coverage import sphere_lattice      # (not imported by a fit that flags none)
            U = sphere_lattice(400)
            G = model.jacobian(theta, model.inverse(theta, U * target), target)[1][:, free]   # (400, kf)
            CG = G @ C
            denom = pose_var + np.einsum("nk,nk->n", G, CG)
        gain = CG[:, jj] ** 2 / denom
        b = int(np.argmax(gain))
        after = float(np.sqrt(max(C[jj, jj] - gain[b], 0.0)))
        reason = "at_bound+undetermined" if (und and at_bound[j]) else ("undetermined" if und else "at_bound")
        flags.append({"name": model.param_names[j], "reason": reason,
                      "std_over_prior_std": None if not np.isfinite(rho) else round(float(rho), 3),
                      "hint": _describe_up(U[b]), "up_vector": np.round(U[b], 3).tolist(),
                      "std_after_one_such_pose": after})
    return flags
