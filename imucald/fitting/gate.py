"""The acceptance gate: out of sample on the same poses, paired, with stated error rates.

A candidate calibration (fitted on all the poses there are) replaces the one in force
only after both are scored *out of sample on the same poses*:

* the incumbent on the poses it was not fitted on (its ``poses_used`` table says which
  of the current poses it saw; the raw sensor, before the first calibration, saw none).
  Its residuals on its own poses are in-sample and are never scored: comparing them
  with the candidate's cross-validated ones favoured the calibration in force and froze
  the first provisional fit;
* the candidate by cross-validation on those same poses: pose i's residual comes from
  a refit without pose i (leave-one-pose-out; k-fold over poses for large sets), so a
  fit that merely absorbs the noise of its own poses earns nothing.

Two rules, either applies the candidate:

1. **more data, same sensor** (the candidate's poses contain every pose the incumbent
   was fitted on, and some new ones): when the new poses are *consistent* with the
   incumbent -- its squared residuals there, each divided by what the pose's noise plus
   the incumbent's own estimation uncertainty predict, sum to a chi-square with p >
   alpha -- and the candidate does not predict them significantly *worse*
   (signed-rank, p_worse > alpha), the candidate is the same estimate on more data, so
   the more precise one: it is applied.  New poses that disagree with the incumbent (a
   moved, bumped or heated sensor; a pose taken in motion) fall through to rule 2.
2. **significantly better**: the paired per-pose squared residuals d_i = r_inc,i^2 -
   r_cv,i^2 over the new poses lean positive by a one-sided Wilcoxon signed-rank test at
   p <= alpha (the pose's own noise, common to both, cancels in the pairing).  Against
   an incumbent fitted on other data (or the raw sensor) this is the only rule, so a
   candidate that is no better is applied at most a fraction alpha of the time.

The parameters then applied are the fit on *all* poses (the refits only score it).
bench/gate.py measures both error rates against the simulated truth.

Pure functions over numpy arrays; the daemon's worker, replay and the
benchmark (bench/gate.py) call them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional

import numpy as np

# leave-one-pose-out up to LOO_MAX_POSES poses, KFOLDS folds beyond; poses_needed: the
# fewest poses a fit plus its cross-validation need (numpy-free, in imucald/numerics/folds.py)
from ..numerics.folds import KFOLDS, LOO_MAX_POSES, default_folds, poses_needed
from .judging.levels import GATE_FALSE_ACCEPT_RATE
from .models.registry import gyro_bias_mean
from ..numerics.tails import chi2_sf

__all__ = ["Decision", "fold_groups", "poses_needed", "signed_rank_p", "paired_gate", "gate_rule",
           "fitted_poses", "incumbent_predicted_var", "cv_residuals", "loo_weighted_mean_residuals",
           "LOO_MAX_POSES", "KFOLDS", "MATCH_ANGLE_DEG"]

#: exact signed-rank distribution up to this many pairs, normal approximation beyond
_EXACT_MAX = 200


def fold_groups(n: int, folds: Optional[int] = None) -> List[np.ndarray]:
    """The cross-validation scheme over n poses: each group is held out once.

    folds None: leave-one-pose-out for n <= LOO_MAX_POSES, else KFOLDS contiguous
    folds (the scheme fitting.fit.heldout_residuals uses)."""
    if folds is None:
        folds = default_folds(n)
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
    """What the gate decided and the figures behind it (sensor units).

    rms_cv and rms_incumbent are both out of sample on the same n poses (the
    candidate cross-validated, the incumbent on poses it was not fitted on)."""

    accept: bool
    p_value: float          #: one-sided signed-rank p: 'the candidate predicts better'
    alpha: float            #: the false-accept rate the decision was taken at
    n: int                  #: paired poses (or points) scored
    rms_cv: float           #: candidate, cross-validated RMS over the n
    rms_incumbent: float    #: incumbent as it is, RMS over the same n
    against: str            #: 'raw' (no calibration in force) or 'current'
    #: which rule decided: 'better' (significantly better), 'consistent' (rule 1: same
    #: sensor, more data), 'not_better', 'worse', 'no_new_poses'
    rule: str = ""
    n_fitted: int = 0       #: poses of the candidate's set the incumbent was fitted on (not scored)
    nested: bool = False    #: the candidate's poses contain every pose the incumbent was fitted on
    consistency_chi2: Optional[float] = None   #: sum of r_inc^2 / predicted variance over the n
    consistency_max: Optional[float] = None    #: the largest single pose's term of that sum
    #: the new poses agree with the incumbent when this exceeds alpha: twice the smaller of
    #: P(chi2_dof >= the sum) and P(the largest of n terms >= consistency_max) (Bonferroni)
    consistency_p: Optional[float] = None
    consistency_dof: Optional[int] = None      #: its degrees of freedom (n, or 3n for the gyro's axes)
    p_worse: Optional[float] = None            #: one-sided signed-rank p: 'the candidate predicts worse'

    @property
    def consistent(self) -> bool:
        """The new poses agree with the incumbent (rule 1's test passed)."""
        return self.consistency_p is not None and self.consistency_p > self.alpha

    def to_dict(self) -> Dict[str, object]:
        d = {"accept": self.accept, "p_value": self.p_value, "alpha": self.alpha, "n": self.n,
             "rms_cv": self.rms_cv, "rms_incumbent": self.rms_incumbent, "against": self.against}
        if self.rule:
            d.update(rule=self.rule, n_fitted=self.n_fitted, nested=self.nested)
        for k in ("consistency_chi2", "consistency_max", "consistency_p", "consistency_dof", "p_worse"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        # JSON has no NaN, and the stream omits a field rather than send null (gpsd's habit):
        # a figure that does not exist (no pose to score) is left out
        return {k: v for k, v in d.items() if not (isinstance(v, float) and not math.isfinite(v))}

    def text(self, scale: float = 1.0, unit: str = "", what: str = "poses") -> str:
        """The figures and, in numbers, why: '0.912 mg cross-validated vs 58.3 mg raw on 10
        poses, p = 0.001 <= 0.05'; against a calibration fitted on some of these poses, first
        the poses both figures are on, then what each figure is: 'on the 10 poses the
        current one was not fitted on (out of sample for both): 0.276 mg for the new fit
        (each pose left out of it in turn) vs 0.209 mg for the current one; higher, but not
        significantly (p_worse = ...), and these poses agree with the current one (...): the
        fit on all 30 poses (...) replaces it'.  (It read '0.276 mg cross-validated vs 0.209
        mg current, both out of sample on the 10 poses it was not fitted on; ...', which
        looked like a worse calibration applied: rule 1 applies the fit on more data when
        the new poses agree with the current one and it predicts them not significantly
        worse; a higher figure on a few poses is within their noise.)"""
        rel = lambda p: "<=" if p <= self.alpha else ">"
        who = "raw" if self.against == "raw" else "current"
        one = what[:-1] if what.endswith("s") else what
        some = f"{self.n} {what if self.n != 1 else one}"
        if self.n_fitted:
            k = default_folds(self.n + self.n_fitted)
            how = (f"each {one} left out of it in turn" if k == self.n + self.n_fitted
                   else f"in {k} folds, each left out in turn")
            head = (f"on the {some} the current one was not fitted on (out of sample for both): "
                    f"{self.rms_cv * scale:.3f} {unit} for the new fit ({how}) vs "
                    f"{self.rms_incumbent * scale:.3f} {unit} for the current one")
        else:
            head = (f"{self.rms_cv * scale:.3f} {unit} cross-validated vs {self.rms_incumbent * scale:.3f} "
                    f"{unit} {who} on {some}")
        if self.rule == "no_new_poses":
            return (f"no {one} that the current one was not "
                    f"fitted on ({self.n_fitted} of {self.n_fitted}): nothing to score it on out of sample")
        sig = f"p = {self.p_value:.2g} {rel(self.p_value)} {self.alpha:g}"
        cons = ("" if self.consistency_p is None else
                f"chi2 = {self.consistency_chi2:.1f} on {self.consistency_dof}, largest {one} "
                f"{self.consistency_max:.1f}: p = {self.consistency_p:.2g} (the smaller of the two "
                f"tests' p, doubled, at most 1) {rel(self.consistency_p)} {self.alpha:g}")
        if self.rule == "consistent":
            how = "higher, but not significantly" if self.rms_cv > self.rms_incumbent else "no worse"
            return (f"{head}; {how} (p_worse = {self.p_worse:.2g} > {self.alpha:g}), and these {what} "
                    f"agree with the current one ({cons}): the fit on all {self.n + self.n_fitted} "
                    f"{what} (the same sensor, more data: smaller standard errors) replaces it")
        if self.rule == "worse":
            return (f"{head}; the new fit predicts them significantly worse (p_worse = {self.p_worse:.2g} "
                    f"<= {self.alpha:g})" + (f"; {sig}" if self.accept else ""))
        tail = (f" (lower, but noise alone gives such a difference with probability {self.p_value:.2g})"
                if not self.accept and self.rms_cv < self.rms_incumbent else "")
        if self.rule in ("better", "not_better") and self.consistency_p is not None:
            return (f"{head}; these {what} disagree with the current one ({cons}), so the new fit "
                    f"must be significantly better: {sig}{tail}")
        return f"{head}, {sig}{tail}"


def _paired(sq_incumbent, sq_cv, alpha: float):
    """The paired per-pose squared residuals as flat arrays, checked: equal, non-empty sizes,
    all finite (a NaN means a refit failed: an error, not a skipped pair), alpha in (0, 1)."""
    a = np.asarray(sq_incumbent, float).ravel()
    b = np.asarray(sq_cv, float).ravel()
    if a.shape != b.shape or a.size == 0:
        raise ValueError(f"the gate needs equal, non-empty residual sets (got {a.size} and {b.size})")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("the gate got a non-finite residual (a cross-validation refit failed)")
    if not 0 < alpha < 1:
        raise ValueError(f"false-accept rate {alpha!r} must lie in (0, 1)")
    return a, b


def paired_gate(sq_incumbent: np.ndarray, sq_cv: np.ndarray, alpha: float = GATE_FALSE_ACCEPT_RATE,
                against: str = "current") -> Decision:
    """Decide on paired per-pose squared residuals (incumbent as is, candidate
    cross-validated).  Pairs with a non-finite value are an error, not skipped: a
    NaN there means a refit failed."""
    a, b = _paired(sq_incumbent, sq_cv, alpha)
    p = signed_rank_p(a - b)
    return Decision(bool(p <= alpha), float(p), float(alpha), int(a.size),
                    float(np.sqrt(b.mean())), float(np.sqrt(a.mean())), against)


def gate_rule(sq_incumbent: np.ndarray, sq_cv: np.ndarray, alpha: float = GATE_FALSE_ACCEPT_RATE,
              against: str = "current", fitted: Optional[np.ndarray] = None, nested: bool = False,
              var_incumbent: Optional[np.ndarray] = None, dof_per_pose: int = 1) -> Decision:
    """The gate's two rules (module docstring) on per-pose squared residuals.

    sq_incumbent, sq_cv (N,): the incumbent as is and the candidate cross-validated;
    fitted (N,) bool: the poses the incumbent was fitted on (never scored: in-sample for
    it), None for none; nested: the candidate's poses contain every pose the incumbent
    was fitted on; var_incumbent (N,): the incumbent's predicted squared residual on each
    pose if it describes the sensor (:func:`incumbent_predicted_var`), for rule 1, over
    dof_per_pose squared components (the gyro's 3 axes: var_incumbent per axis)."""
    a, b = _paired(sq_incumbent, sq_cv, alpha)
    old = np.zeros(a.size, bool) if fitted is None else np.asarray(fitted, bool).ravel()
    new = ~old
    m, k_old = int(new.sum()), int(old.sum())
    if m == 0:
        return Decision(False, 1.0, float(alpha), 0, float("nan"), float("nan"), against,
                        "no_new_poses", k_old, bool(nested))
    an, bn = a[new], b[new]
    p = signed_rank_p(an - bn)
    pw = signed_rank_p(bn - an)
    chi2 = pc = zmax = None
    if nested and k_old and var_incumbent is not None:
        v = np.asarray(var_incumbent, float).ravel()[new]
        if np.all(np.isfinite(v)) and np.all(v > 0):
            z = an / v
            chi2, zmax = float(z.sum()), float(z.max())
            # the sum catches a shift of them all, the largest term one pose taken in
            # motion (diluted in the sum); each at alpha/2, so that poses of the sensor
            # the incumbent describes are called inconsistent at most a fraction alpha
            p_sum = chi2_sf(chi2, m * dof_per_pose)
            p_max = -math.expm1(m * math.log1p(-min(chi2_sf(zmax, dof_per_pose), 1.0 - 1e-16)))
            pc = float(min(1.0, 2 * min(p_sum, p_max)))
    fig = dict(alpha=float(alpha), n=m, rms_cv=float(np.sqrt(bn.mean())),
               rms_incumbent=float(np.sqrt(an.mean())), against=against, n_fitted=k_old,
               nested=bool(nested), consistency_chi2=chi2, consistency_max=zmax, consistency_p=pc,
               consistency_dof=None if pc is None else m * dof_per_pose, p_worse=float(pw))
    if pc is not None and pc > alpha:                      # rule 1: same sensor, more data
        if pw > alpha:
            return Decision(True, float(p), rule="consistent", **fig)
        return Decision(False, float(p), rule="worse", **fig)
    return Decision(bool(p <= alpha), float(p), rule="better" if p <= alpha else "not_better", **fig)


#: a current pose is one the incumbent was fitted on when their still intervals overlap in
#: time and their directions agree within this angle (a pose refined since keeps its start)
MATCH_ANGLE_DEG = 15.0


def fitted_poses(acc: np.ndarray, t0_s: np.ndarray, t1_s: np.ndarray,
                 poses_used: Optional[Dict[str, object]]):
    """Which current poses the incumbent was fitted on, from its ``poses_used`` table.

    Returns (mask (N,), nested): nested when every pose of the table is among the
    current ones.  A pose matches a row when their still intervals overlap in time and
    their directions agree within MATCH_ANGLE_DEG (a pose the accumulator has refined
    since spans its old interval).  No table: (all False, False)."""
    acc = np.asarray(acc, float).reshape(-1, 3)
    N = len(acc)
    none = (np.zeros(N, bool), False)
    if not poses_used or not poses_used.get("rows"):
        return none
    cols = list(poses_used["columns"])
    try:
        rows = np.asarray(poses_used["rows"], float)
        ix = [cols.index(c) for c in ("ax_g", "ay_g", "az_g", "t0_s", "t1_s")]
    except (ValueError, TypeError):
        return none
    if rows.ndim != 2 or t0_s is None or t1_s is None:
        return none
    ra, r0, r1 = rows[:, ix[:3]], rows[:, ix[3]], rows[:, ix[4]]
    t0 = np.asarray(t0_s, float)
    t1 = np.asarray(t1_s, float)
    unit = lambda x: x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-300)
    same_dir = unit(acc) @ unit(ra).T >= np.cos(np.radians(MATCH_ANGLE_DEG))
    overlap = (t0[:, None] <= r1[None, :] + 1e-6) & (r0[None, :] <= t1[:, None] + 1e-6)
    hit = same_dir & overlap                    # (N current, M rows)
    return hit.any(1), bool(hit.any(0).all())


def in_force_check(cal, raw_g: np.ndarray, pose_cov: Optional[np.ndarray], temp_c=None):
    """(p-value, |a| - 1 g RMS, expected RMS) of a calibration in force on poses it was not
    fitted on (raw means (n, 3), g; their covariances (n, 3, 3) or None; temperatures or None):
    the chi-square of each pose's |corrected| - 1 g over its variance, the pose mean's along its
    direction plus the calibration's own held-out RMS squared (``quality['loo_rms_g']``, else
    its ``heldout_rms_g``, else its noise figure: the error it makes on a pose it never saw,
    noise included, so the test is conservative), on n degrees of freedom.  A right
    calibration gives p uniform or larger; a calibration of another board, p ~ 0.  Without
    any of those figures there is no test (p 1)."""
    raw = np.asarray(raw_g, float).reshape(-1, 3)
    corr = np.asarray(cal.apply_accel(raw, temp_c), float)
    nrm = np.linalg.norm(corr, axis=1)
    u = corr / np.maximum(nrm, 1e-300)[:, None]
    var = (np.einsum("ni,nij,nj->n", u, np.asarray(pose_cov, float), u) if pose_cov is not None
           else np.zeros(len(raw)))
    q = cal.accel.quality if cal.accel is not None else {}
    own = next((float(q[k]) for k in ("loo_rms_g", "heldout_rms_g", "noise_g")
                if k in q and np.isfinite(q[k]) and q[k] > 0), 0.0)
    rms = float(np.sqrt(np.mean((nrm - 1) ** 2)))
    var = var + own ** 2
    # no figure of its own error (a file written by hand): no test, for the poses' noise alone
    # would challenge a right calibration (a cold review: p 8e-4 on a same-board session)
    if own == 0.0 or not np.all(var > 0):
        return 1.0, rms, 0.0
    return chi2_sf(float(np.sum((nrm - 1) ** 2 / var)), len(raw)), rms, float(np.sqrt(np.mean(var)))


def incumbent_predicted_var(model, theta: np.ndarray, raw: np.ndarray,
                            pose_cov: Optional[np.ndarray], fitted: np.ndarray,
                            chip: Optional[str] = None) -> Optional[np.ndarray]:
    """Each pose's expected squared residual under the incumbent if the pose comes from
    the sensor it describes: the pose's noise along its measured direction plus the
    incumbent's own estimation uncertainty there, g_i' C g_i, with C the covariance of
    the fit on the poses it was fitted on (MAP with the datasheet prior, as the fit; its
    excess-scatter factor scales the noise).  None when those poses cannot determine
    the model (fewer than its parameters + 1, or the fit fails)."""
    from .fit import fit_norm
    from .models.registry import get_model
    from .judging.uncertainty import residual_variance
    m = get_model(model) if isinstance(model, str) else model
    raw = np.asarray(raw, float)
    old = np.asarray(fitted, bool)
    if int(old.sum()) < int(m.free_mask.sum()) + 1:
        return None
    pc = None if pose_cov is None else np.asarray(pose_cov, float)
    from ..errors import UserError
    try:
        f = fit_norm(raw[old], m, "lm", pose_cov=None if pc is None else pc[old], chip=chip, heldout=False)
    except (UserError, ValueError, np.linalg.LinAlgError):
        return None                 # no rule 1 then: the candidate must be significantly better
    phi = float(f.info["noise_model"]["excess_scatter"])
    var = (residual_variance(m, theta, raw, pc) * phi if pc is not None
           else np.full(len(raw), float(f.noise) ** 2))
    G = m.jacobian(np.asarray(theta, float), raw)[1]
    C = np.asarray(f.info["covariance"], float)
    return var + np.einsum("nk,kl,nl->n", G, C, G)


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
               method: str = "lm", alpha: float = GATE_FALSE_ACCEPT_RATE, against: str = "current",
               rng=None, chip: Optional[str] = None, model: str = "triangular9",
               fitted: Optional[np.ndarray] = None, nested: bool = False, incumbent=None,
               temp_c: Optional[np.ndarray] = None):
    """Fit the accelerometer on all poses and gate it against the incumbent.

    raw_g: pose means (N, 3); incumbent_g: the same pose means corrected by the
    calibration in force (the raw means themselves when there is none).  fitted (N,)
    bool and nested: which poses it was fitted on (:func:`fitted_poses`); incumbent:
    its (model, theta) over raw_g, for rule 1's consistency test.  temp_c (N,): the poses'
    temperatures, for the stated covariance (fit_norm: the bias's temperature slope a constant
    leaves out; None where thermal terms are in force).
    Returns (the all-pose fit, its cross-validated residuals (N,), Decision)."""
    from .fit import fit_norm
    raw_g = np.asarray(raw_g, float)
    cal = fit_norm(raw_g, model, method, pose_cov=pose_cov, rng=rng, heldout=True, chip=chip,
                   temp_c=temp_c)
    r_cv = np.asarray(cal.info["heldout_residuals"], float)
    r_inc = 1.0 - np.linalg.norm(np.asarray(incumbent_g, float), axis=1)
    var = None
    if nested and fitted is not None and incumbent is not None and np.any(fitted) and not np.all(fitted):
        var = incumbent_predicted_var(incumbent[0], incumbent[1], raw_g, pose_cov, fitted, chip)
    return cal, r_cv, gate_rule(r_inc ** 2, r_cv ** 2, alpha, against, fitted, nested, var)


def gate_gyro_bias(means_dps: np.ndarray, counts: np.ndarray, incumbent_dps: np.ndarray,
                   alpha: float = GATE_FALSE_ACCEPT_RATE, against: str = "current",
                   fitted: Optional[np.ndarray] = None, nested: bool = False):
    """Gyro bias = the count-weighted mean of the still poses' mean rates, gated
    against the incumbent's corrected pose means (raw when none): a still pose
    should read zero.  Scored on the poses the incumbent was not fitted on; rule 1's
    predicted variance of a pose's residual is s^2 (1/n_i + 1/n_fitted) per axis (chi-square
    over 3 per pose), s^2
    the per-sample scatter of the fitted poses about their weighted mean.
    Returns (bias_dps (3,), Decision)."""
    m = np.asarray(means_dps, float)
    w = np.asarray(counts, float)
    bias = gyro_bias_mean(m, w)
    e_cv = loo_weighted_mean_residuals(m, w)
    e_inc = np.asarray(incumbent_dps, float)
    var = None
    old = None if fitted is None else np.asarray(fitted, bool)
    if nested and old is not None and old.sum() >= 2 and not old.all():
        mo, wo = m[old], w[old]
        mu = (mo * wo[:, None]).sum(0) / wo.sum()
        s2 = float((wo[:, None] * (mo - mu) ** 2).sum() / (3 * (len(mo) - 1)))
        var = s2 * (1 / w + 1 / wo.sum())
    return bias, gate_rule((e_inc ** 2).sum(1), (e_cv ** 2).sum(1), alpha, against, old, nested, var, 3)
