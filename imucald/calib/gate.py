"""The acceptance gate: cross-validated, paired, with a stated false-accept rate.

A candidate calibration replaces the one in force only if it predicts the poses
*significantly* better.  Both are scored on the same poses:

* the incumbent as it is (it was fitted on other, older data, so its residuals on
  these poses are already out of sample; the raw sensor is the incumbent before the
  first calibration);
* the candidate by cross-validation: pose i's residual comes from a refit without
  pose i (leave-one-pose-out; k-fold over poses for large sets), so a fit that
  merely absorbs the noise of its own poses earns nothing.

The per-pose squared residuals are paired, d_i = r_inc,i^2 - r_cv,i^2 (the pose's
own noise, common to both, cancels in the pairing), and a one-sided Wilcoxon
signed-rank test asks whether the d_i lean positive.  The candidate is accepted
when p <= alpha, so a candidate that is no better is accepted at most a fraction
alpha of the time: alpha is the stated false-accept rate.  The parameters then
applied are the fit on *all* poses (the refits only score it).

Pure functions over numpy arrays; the daemon's worker, replay and the
benchmark (bench/gate.py) call them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional

import numpy as np

__all__ = ["Decision", "fold_groups", "poses_needed", "signed_rank_p", "paired_gate",
           "cv_residuals", "loo_weighted_mean_residuals", "ALPHA", "LOO_MAX_POSES", "KFOLDS"]

#: default false-accept rate (config calibration.false_accept_rate)
ALPHA = 0.05
# leave-one-pose-out up to LOO_MAX_POSES poses, KFOLDS folds beyond; poses_needed: the
# fewest poses a fit plus its cross-validation need (numpy-free, in imucald/cv.py)
from ..cv import KFOLDS, LOO_MAX_POSES, poses_needed  # noqa: E402
from .models import gyro_bias_mean  # noqa: E402
#: exact signed-rank distribution up to this many pairs, normal approximation beyond
_EXACT_MAX = 200


def fold_groups(n: int, folds: Optional[int] = None) -> List[np.ndarray]:
    """The cross-validation scheme over n poses: each group is held out once.

    folds None: leave-one-pose-out for n <= LOO_MAX_POSES, else KFOLDS contiguous
    folds (the scheme calib.fit.heldout_residuals uses)."""
    if folds is None:
        folds = n if n <= LOO_MAX_POSES else KFOLDS
    return [g for g in np.array_split(np.arange(n), min(folds, n)) if len(g)]


def _exact_upper_tail(ranks2: np.ndarray, w2: int) -> float:
    """P(W+ >= w) under H0 (each sign +/- with probability 1/2), exact by counting
    the sign patterns; ranks2 are doubled (integer) ranks, so ties are exact too."""
    top = int(ranks2.sum())
    c = np.zeros(top + 1)
    c[0] = 1.0
    for r in ranks2.astype(int):
        nxt = c.copy()
        nxt[r:] += c[:top + 1 - r]
        c = nxt * 0.5
    return float(min(1.0, c[w2:].sum()))


def signed_rank_p(d: np.ndarray) -> float:
    """One-sided Wilcoxon signed-rank p-value for 'd leans positive'.

    Zero differences are dropped (Wilcoxon's convention); tied magnitudes get their
    mean rank.  Exact permutation distribution up to 200 pairs, the normal
    approximation (tie-corrected, continuity-corrected) beyond.  1.0 when no pair
    differs."""
    d = np.asarray(d, float)
    d = d[np.isfinite(d) & (d != 0)]
    n = len(d)
    if n == 0:
        return 1.0
    a = np.abs(d)
    order = np.argsort(a, kind="mergesort")
    ranks = np.empty(n)
    ranks[order] = np.arange(1, n + 1)
    # mean ranks for ties
    vals, inv, counts = np.unique(a, return_inverse=True, return_counts=True)
    if len(vals) < n:
        sums = np.bincount(inv, weights=ranks)
        ranks = (sums / counts)[inv]
    ranks2 = np.rint(2 * ranks).astype(int)
    w2 = int(ranks2[d > 0].sum())
    if n <= _EXACT_MAX:
        return _exact_upper_tail(ranks2, w2)
    mean = n * (n + 1) / 4.0
    var = n * (n + 1) * (2 * n + 1) / 24.0 - float(((counts ** 3) - counts).sum()) / 48.0
    z = (w2 / 2.0 - mean - 0.5) / math.sqrt(var)
    return 0.5 * math.erfc(z / math.sqrt(2.0))


@dataclass(frozen=True)
class Decision:
    """What the gate decided and the figures behind it (sensor units)."""

    accept: bool
    p_value: float          #: one-sided signed-rank p: 'the candidate predicts better'
    alpha: float            #: the false-accept rate the decision was taken at
    n: int                  #: paired poses (or points)
    rms_cv: float           #: candidate, cross-validated RMS over the n
    rms_incumbent: float    #: incumbent as it is, RMS over the same n
    against: str            #: 'raw' (no calibration in force) or 'current'

    def to_dict(self) -> Dict[str, object]:
        return {"accept": self.accept, "p_value": self.p_value, "alpha": self.alpha, "n": self.n,
                "rms_cv": self.rms_cv, "rms_incumbent": self.rms_incumbent, "against": self.against}

    def text(self, scale: float = 1.0, unit: str = "", what: str = "poses") -> str:
        """'0.912 mg cross-validated vs 58.3 mg raw on 10 poses, p = 0.001 <= 0.05'."""
        rel = "<=" if self.p_value <= self.alpha else ">"
        who = "raw" if self.against == "raw" else "current"
        return (f"{self.rms_cv * scale:.3f} {unit} cross-validated vs {self.rms_incumbent * scale:.3f} "
                f"{unit} {who} on {self.n} {what}, p = {self.p_value:.2g} {rel} {self.alpha:g}")


def paired_gate(sq_incumbent: np.ndarray, sq_cv: np.ndarray, alpha: float = ALPHA,
                against: str = "current") -> Decision:
    """Decide on paired per-pose squared residuals (incumbent as is, candidate
    cross-validated).  Pairs with a non-finite value are an error, not skipped: a
    NaN there means a refit failed."""
    a = np.asarray(sq_incumbent, float).ravel()
    b = np.asarray(sq_cv, float).ravel()
    if a.shape != b.shape or a.size == 0:
        raise ValueError(f"the gate needs equal, non-empty residual sets (got {a.size} and {b.size})")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("the gate got a non-finite residual (a cross-validation refit failed)")
    if not 0 < alpha < 1:
        raise ValueError(f"false-accept rate {alpha!r} must lie in (0, 1)")
    p = signed_rank_p(a - b)
    return Decision(bool(p <= alpha), float(p), float(alpha), int(a.size),
                    float(np.sqrt(b.mean())), float(np.sqrt(a.mean())), against)


def cv_residuals(n: int, refit: Callable[[np.ndarray], object],
                 residual: Callable[[object, np.ndarray], np.ndarray],
                 folds: Optional[int] = None) -> np.ndarray:
    """Cross-validated residuals of any fit: for each fold, ``refit(keep_mask)``
    without it, then ``residual(fit, held_out_indices)`` on it.  Returns (n, ...)."""
    out = None
    for g in fold_groups(n, folds):
        keep = np.ones(n, bool)
        keep[g] = False
        r = np.asarray(residual(refit(keep), g), float)
        if out is None:
            out = np.zeros((n,) + r.shape[1:])
        out[g] = r
    return out


def loo_weighted_mean_residuals(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Leave-one-out residuals of a weighted mean (e.g. the gyro bias from pose
    means weighted by their sample counts): x_i minus the mean of the others. (n, d)"""
    x = np.asarray(x, float)
    w = np.asarray(w, float)
    if len(x) < 2:
        raise ValueError("a leave-one-out mean needs at least 2 poses")
    tot = (x * w[:, None]).sum(0)
    others = (tot[None, :] - x * w[:, None]) / (w.sum() - w)[:, None]
    return x - others


def gate_accel(raw_g: np.ndarray, pose_cov: Optional[np.ndarray], incumbent_g: np.ndarray,
               method: str = "lm", alpha: float = ALPHA, against: str = "current", rng=None,
               chip: Optional[str] = None, model: str = "triangular9"):
    """Fit the accelerometer on all poses and gate it against the incumbent.

    raw_g: pose means (N, 3); incumbent_g: the same pose means corrected by the
    calibration in force (the raw means themselves when there is none).
    Returns (the all-pose fit, its cross-validated residuals (N,), Decision)."""
    from .fit import fit_norm
    raw_g = np.asarray(raw_g, float)
    cal = fit_norm(raw_g, model, method, pose_cov=pose_cov, rng=rng, heldout=True, chip=chip)
    r_cv = np.asarray(cal.info["heldout_residuals"], float)
    r_inc = 1.0 - np.linalg.norm(np.asarray(incumbent_g, float), axis=1)
    return cal, r_cv, paired_gate(r_inc ** 2, r_cv ** 2, alpha, against)


def gate_gyro_bias(means_dps: np.ndarray, counts: np.ndarray, incumbent_dps: np.ndarray,
                   alpha: float = ALPHA, against: str = "current"):
    """Gyro bias = the count-weighted mean of the still poses' mean rates, gated
    against the incumbent's corrected pose means (raw when none): a still pose
    should read zero.  Returns (bias_dps (3,), Decision)."""
    m = np.asarray(means_dps, float)
    w = np.asarray(counts, float)
    bias = gyro_bias_mean(m, w)
    e_cv = loo_weighted_mean_residuals(m, w)
    e_inc = np.asarray(incumbent_dps, float)
    return bias, paired_gate((e_inc ** 2).sum(1), (e_cv ** 2).sum(1), alpha, against)
