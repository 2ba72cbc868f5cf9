"""Significance tests of the gap diagnosis: score (Lagrange-multiplier) tests of a
candidate's signature from the baseline fit, canonical correlation between two
signatures, chi-square p-values with their log10, and trend correlations."""
from __future__ import annotations

import math
from typing import Optional, Tuple

import numpy as np

from ..numerics.tails import chi2_logsf, f_sf, norm_sf2

__all__ = ["proj_sig", "score", "visible_svd", "canon", "p_and_log10", "corr_p", "wald_p", "wald_f_p", "scaled_wald_p"]


def proj_sig(J, C, w, lam=None):
    """Candidate columns whitened and projected off the baseline Jacobian (with a prior
    of precision ``lam``, off what the MAP fit absorbs: C - J (J'WJ + diag(lam))^-1 J'W C)."""
    sw = np.sqrt(w)[:, None]
    Jw, Cw = J * sw, C * sw
    if lam is None or not np.any(lam):
        Q, _ = np.linalg.qr(Jw)
        return Cw - Q @ (Q.T @ Cw), Cw
    A = Jw.T @ Jw + np.diag(np.asarray(lam, float))
    return Cw - Jw @ np.linalg.pinv(A, rcond=1e-12, hermitian=True) @ (Jw.T @ Cw), Cw


#: a direction of a candidate's coefficients is visible when its projected signature's
#: singular value is above this share of the largest whitened column's norm (visible_svd)
VISIBLE_SHARE = 0.01


def _kept(s, Cw):
    full = np.linalg.norm(Cw, axis=0).max() if Cw.size else 0
    return s > VISIBLE_SHARE * max(full, 1e-300)


def visible_svd(Ct, Cw):
    """(U_k (N, k), V_k (q, k)): the singular vectors of a candidate's projected signature
    ``Ct`` that its score test sees (singular value above VISIBLE_SHARE of the largest
    whitened column's norm).  V_k spans the directions of the candidate's coefficients the
    baseline leaves visible; the rest it absorbs (e.g. the degree-1 part of a radial cubic,
    which the bias holds)."""
    U, s, Vt = np.linalg.svd(Ct, full_matrices=False)
    keep = _kept(s, Cw)
    return U[:, keep], Vt[keep].T


def score(rw, Ct, Cw, svd=None):
    """Lagrange-multiplier (score) statistic and its visible rank (``svd``: visible_svd's
    result when the caller already has it)."""
    Uk = (visible_svd(Ct, Cw) if svd is None else svd)[0]
    if Uk.shape[1] == 0:
        return 0.0, 0, 0.0
    stat = float(np.sum((Uk.T @ rw) ** 2))
    vis = float(np.linalg.norm(Ct) / max(np.linalg.norm(Cw), 1e-300))
    return stat, int(Uk.shape[1]), vis


def canon(Ct1, Ct2):
    """Largest canonical correlation between two projected signature subspaces."""
    def basis(C):
        U, s, _ = np.linalg.svd(C, full_matrices=False)
        return U[:, s > 1e-9 * max(s.max(), 1e-300)] if s.size else U[:, :0]
    A, B = basis(Ct1), basis(Ct2)
    if not A.shape[1] or not B.shape[1]:
        return 0.0
    return float(np.linalg.svd(A.T @ B, compute_uv=False).max())


def p_and_log10(stat, dof):
    lp = chi2_logsf(stat, dof) if dof > 0 else 0.0
    return math.exp(lp), lp / math.log(10)


def _wald_stat(z: np.ndarray, C: np.ndarray) -> Tuple[float, int]:
    """z' C^+ z and C's numerical rank (at least 1)."""
    wald = float(z @ np.linalg.pinv(C, rcond=1e-10, hermitian=True) @ z)
    rank = int(np.linalg.matrix_rank(C, tol=1e-10 * max(np.abs(C).max(), 1e-300)))
    return wald, max(rank, 1)


def wald_p(z: np.ndarray, C: np.ndarray) -> float:
    """p-value of the Wald test that coefficients ``z`` with covariance ``C`` are zero:
    z' C^+ z against chi-square on C's numerical rank (at least 1)."""
    return p_and_log10(*_wald_stat(z, C))[0]


def wald_f_p(z: np.ndarray, C: np.ndarray, dof: int) -> float:
    """p-value of the Wald test of ``z`` = 0 when its covariance ``C`` was scaled by the
    residual chi-square over ``dof`` (the excess scatter a misfit leaves, estimated from the
    same residuals): the statistic over C's rank follows F(rank, dof), not chi-square over
    rank (the scale is itself an estimate on ``dof`` degrees of freedom; with the few that a
    pair on 22 poses leaves, the chi-square reference understates p by orders of magnitude)."""
    wald, rank = _wald_stat(z, C)
    return f_sf(wald / rank, rank, max(dof, 1))


def scaled_wald_p(z: np.ndarray, C: np.ndarray, dof: Optional[int]) -> float:
    """A member's Wald p-value in the gap searches (gap/search.py, gap/gyrosearch.py): against
    chi-square when its covariance is the noise's or its excess scale was estimated on MIN_DOF
    or more residual degrees of freedom (``dof`` None); against F(rank, dof) when the
    covariance was scaled by a residual chi-square over ``dof`` < MIN_DOF (wald_f_p); 1 when
    the fit leaves no residual degree of freedom to estimate that scale on (nothing about its
    members can be tested)."""
    if dof is None:
        return wald_p(z, C)
    return wald_f_p(z, C, dof) if dof > 0 else 1.0


def corr_p(x, y):
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) < 5 or x.std() == 0 or y.std() == 0:
        return None
    r = float(np.corrcoef(x, y)[0, 1])
    r = max(min(r, 0.999999), -0.999999)
    z = math.atanh(r) * math.sqrt(len(x) - 3)
    return {"r": round(r, 3), "p_value": norm_sf2(z)}
