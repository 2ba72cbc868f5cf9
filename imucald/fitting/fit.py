"""High-level calibration: pose means in, a reported :class:`FitResult` out.

Everything the daemon and the command line report comes from here: the
parameters under unit-carrying names, their standard errors and CRLB, rank and
condition of the problem, in-sample and held-out residuals.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Dict, Optional, Tuple

import numpy as np

from ..numerics.rng import as_rng

from .judging.metrics import path_error, rms
from .models.mag import MagModel, mag_report
from .models.base import NormModel
from .models.registry import get_model, gyro_bias_eq6_fitness, gyro_bias_mean, gyro_bias_scatter_se
from .solvers.lsq import lm_converge
from .solvers.lsq import OptimResult, Problem, lm, sphere_fit
from .solvers.optim import run_method
from .judging.uncertainty import (
    Uncertainty, crlb, determination, map_covariance, omitted_covariance, residual_variance
)
from ..numerics.npstats import median

__all__ = ["FitResult", "fit_norm", "mag_bounds", "heldout_residuals", "fit_gyro_bias",
           "select_model", "accel_prior", "AUTO_MODELS"]


@dataclass(eq=False)
class FitResult:
    """One norm fit (accelerometer or magnetometer) or gyro-bias fit: what the daemon and the
    command line report (:func:`fit_norm`, :func:`fit_gyro_bias`)."""
    sensor: str
    model: str
    method: str
    poses: int
    theta: np.ndarray
    params: Dict[str, object]
    stderr: Dict[str, object]
    fitness: float
    rms: float                      #: in-sample RMS of target - |h| (sensor unit)
    heldout_rms: float              #: leave-one-pose-out (or k-fold) RMS
    crlb_std: np.ndarray            #: per parameter (flat, model order)
    uncertainty: Optional[Uncertainty]
    noise: float                    #: robust per-pose residual sigma used for the bound
    noise_source: str               #: 'poses' (within-pose scatter), 'residuals', or a rotation fit's (fitting/magcal.py)
    iterations: int
    nfev: int
    wall_s: float
    info: Dict[str, object] = field(default_factory=dict)

    def to_json(self) -> Dict[str, object]:
        unit = {"accel": "g", "mag": "gauss", "gyro": "dps"}[self.sensor]
        d: Dict[str, object] = {
            "sensor": self.sensor, "model": self.model, "method": self.method,
            "poses": int(self.poses), "params": self.params, "stderr": self.stderr,
            "fitness": float(self.fitness),
            f"heldout_rms_{unit}": float(self.heldout_rms) if np.isfinite(self.heldout_rms) else None,
            f"rms_{unit}": float(self.rms),
        }
        if self.uncertainty is not None:
            names = get_model(self.model).param_names if self.sensor != "gyro" else []
            d["crlb_std"] = {n: (None if not np.isfinite(s) else float(s))
                             for n, s in zip(names, self.crlb_std)}
            d["rank"] = int(self.uncertainty.rank)
            d["condition"] = float(self.uncertainty.condition)
            if self.uncertainty.unobservable:
                d["unobservable"] = list(self.uncertainty.unobservable)
            if len(self.uncertainty.null_directions):
                d["null_directions"] = np.round(self.uncertainty.null_directions, 6).tolist()
            u = self.uncertainty
            if u.posterior_std is not None and self.sensor != "gyro":
                names = get_model(self.model).param_names
                fin = lambda a, i: None if a is None or not np.isfinite(a[i]) else float(a[i])
                d["determination"] = {n: {"std": fin(u.posterior_std, i), "prior_std": fin(u.prior_std, i),
                                          "data_only_std": fin(u.std, i)} for i, n in enumerate(names)}
                if u.left_out_std is not None:      # the share of "std" from terms left out
                    for i, n in enumerate(names):
                        d["determination"][n]["left_out_std"] = fin(u.left_out_std, i)
                d["flags"] = list(u.flags)
        for key in ("noise_model", "heldout_normalised_rms", "model_selection"):
            if key in self.info:
                v = self.info[key]
                d[key] = None if isinstance(v, float) and not np.isfinite(v) else v
        d[f"noise_{unit}"] = float(self.noise)
        d["noise_source"] = self.noise_source
        if "path_error_20s_std_m" in self.info:
            d["path_error_20s_std_m"] = self.info["path_error_20s_std_m"]
        d["iterations"] = int(self.iterations)
        d["wall_s"] = round(float(self.wall_s), 4)
        return d


def _pose_cov(pose_cov: Optional[np.ndarray], N: int,
              noise_inflation) -> Optional[np.ndarray]:
    """Each pose's own mean covariance (N, 3, 3) times its colour inflation, or None
    when any pose lacks a finite positive one (the fit's residuals are used then)."""
    if pose_cov is None:
        return None
    pc = np.asarray(pose_cov, float)
    if pc.ndim == 1:
        pc = pc[:, None, None] * np.eye(3)
    if pc.shape != (N, 3, 3) or not np.all(np.isfinite(pc)):
        return None
    if not np.all(np.einsum("nii->n", pc) > 0):
        return None
    k = np.ones(N) if noise_inflation is None else np.broadcast_to(
        np.asarray(noise_inflation, float), (N,))
    return pc * k[:, None, None]


def heldout_residuals(model: NormModel, theta: np.ndarray, raw: np.ndarray, target: float = 1.0,
                      folds: Optional[int] = None, lo=None, hi=None, prior=None,
                      var: Optional[np.ndarray] = None):
    """Held-out residual of every pose: refit (LM, warm-started at theta) without it.

    Leave-one-pose-out when ``folds`` is None and N <= 60, otherwise k-fold over
    poses (10 folds by default).  ``prior``: (mean, std, noise_var) over the free
    parameters, as in the fit.  With ``var`` (N,) each pose's residual variance, also
    returns each held-out residual's predicted std, sqrt(var_i + g_i' C_-i g_i), with
    C_-i the covariance of the fold's estimate: returns (residuals, predicted std).
    """
    raw = np.asarray(raw, float)
    N = len(raw)
    if folds is None:
        folds = N if N <= 60 else 10
    groups = np.array_split(np.arange(N), folds)
    from .solvers.loo import heldout_by_update      # all folds at once (fitting/solvers/loo.py); None: refit each
    quick = heldout_by_update(model, theta, raw, target, groups, lo, hi, prior, var)
    if quick is not None:
        return quick
    out = np.zeros(N)
    pred = np.zeros(N)
    z0 = None
    pm, psd, nv = prior if prior is not None else (None, None, 1.0)
    for g in groups:
        keep = np.ones(N, bool)
        keep[g] = False
        prob = Problem(model, raw[keep], target, lo=lo, hi=hi, prior_mean=pm, prior_std=psd,
                       noise_var=nv)
        if z0 is None:
            z0 = prob.reduce(theta)
        z, _, _ = lm_converge(prob, z0, max_iter=60, ftol=1e-12)
        th = prob.expand(z)
        out[g] = model.residual(th, raw[g], target)
        if var is not None:
            J = model.jacobian(th, raw[keep], target)[1][:, prob.free]
            C = map_covariance(J, var[keep], nv, prob.prior_precision())
            Gi = model.jacobian(th, raw[g], target)[1][:, prob.free]
            pred[g] = np.sqrt(var[g] + np.einsum("nk,kl,nl->n", Gi, C, Gi))
    return (out, pred) if var is not None else out


def accel_bounds(model: NormModel, chip: Optional[str]) -> Tuple[np.ndarray, np.ndarray]:
    """Initial search box from the chip's datasheet tolerances, made wide enough for
    real parts: bias +-max(3 tol, 0.1 g), scale +-max(3 tol, 5 %), non-orthogonality
    +-max(3 cross-axis, 0.05).  Unknown chips get the generic wide box
    (+-0.25 g, +-15 %, +-0.08)."""
    from ..specs import ACCEL
    spec = ACCEL.get(chip or "")
    if spec is None:
        return model.default_bounds()
    return model.default_bounds(spec_bias=max(3 * max(spec.bias_tol_g), 0.1),
                                spec_scale=max(3 * spec.scale_tol, 0.05),
                                spec_alpha=max(3 * spec.cross_axis_tol, 0.05))


def accel_prior(model: NormModel, chip: Optional[str]) -> Tuple[np.ndarray, np.ndarray]:
    """Gaussian prior (mean, std) over the full parameter vector from the datasheet:
    an ideal sensor, std = the tolerance (bias: the largest axis's zero-g tolerance,
    scale: sensitivity tolerance, non-orthogonality: cross-axis sensitivity).  Unknown
    chips: a third of the generic box (0.083 g, 5 %, 0.027).  The search box is 3x
    (or more) wider, so the box edge is >= 3 prior std away."""
    from ..specs import ACCEL
    spec = ACCEL.get(chip or "")
    if spec is None:
        lo, hi = model.default_bounds(spec_bias=0.25 / 3, spec_scale=0.15 / 3, spec_alpha=0.08 / 3)
    else:
        lo, hi = model.default_bounds(spec_bias=max(spec.bias_tol_g), spec_scale=spec.scale_tol,
                                      spec_alpha=spec.cross_axis_tol)
    return (lo + hi) / 2, (hi - lo) / 2


#: candidate orders for ``model='auto'``: offset + scale, + 3 non-orthogonality, + 6 misalignment
AUTO_MODELS = ("diag6", "triangular9", "full12")


def select_model(raw: np.ndarray, pose_cov: Optional[np.ndarray] = None, target: float = 1.0,
                 chip: Optional[str] = None, candidates=AUTO_MODELS, noise_inflation=None
                 ) -> Tuple[str, Dict[str, float]]:
    """Model order by leave-one-pose-out error (MAP fits with the datasheet prior, lm from
    the closed-form starts), with the one-standard-error rule: the simplest model whose
    held-out RMS is within one standard error of the lowest (the s.e. of an RMS over N
    poses from the spread of the squared residuals, std(r^2) / (2 RMS sqrt(N))).
    Returns (name, {model: held-out RMS, g}) and, under '_se', that standard error."""
    scores: Dict[str, float] = {}
    se: Dict[str, float] = {}
    held = {}
    for name in candidates:
        m = get_model(name)
        kf = int(m.free_mask.sum())
        if len(raw) < kf + 1:
            # fewer poses than free parameters + 1: with the datasheet prior (MAP) the terms
            # the poses cannot determine are held at the prior; tried when the poses determine
            # at least the smallest candidate (skipped otherwise)
            if m.sensor != "accel" or len(raw) < min(int(get_model(c).free_mask.sum()) for c in candidates) + 1:
                continue
            held[name] = kf + 1
        cal = fit_norm(raw, m, "lm", pose_cov=pose_cov, target=target, chip=chip,
                       noise_inflation=noise_inflation, _min_poses=1 if name in held else None)
        r2 = np.asarray(cal.info["heldout_residuals"]) ** 2
        scores[name] = float(cal.heldout_rms)
        se[name] = float(np.std(r2, ddof=1) / (2 * max(cal.heldout_rms, 1e-300) * np.sqrt(len(r2))))
    low = min(scores, key=scores.get)
    best = next(n for n in candidates if n in scores and scores[n] <= scores[low] + se[low])
    return best, {**scores, "_se": se[low], "_held_at_prior": held}


@dataclass(eq=False)
class FitSetup:
    """What the solver is given: the model chosen, its search box and prior, the noise level
    the prior is weighed against (``noise_var``) and each pose's own covariance (or None)."""
    model: NormModel
    raw: np.ndarray
    target: float
    lo: np.ndarray
    hi: np.ndarray
    pose_cov: Optional[np.ndarray]      #: (N, 3, 3) times colour inflation, or None
    use_prior: bool                     #: an accelerometer fit with the datasheet prior asked for
    prior_mean: Optional[np.ndarray]    #: over the free parameters
    prior_std: Optional[np.ndarray]     #: over the free parameters
    prior_std_full: np.ndarray          #: over all parameters (inf: no prior)
    noise_var: float
    chip: Optional[str]
    selection: Optional[Dict[str, object]]
    temp_c: Optional[np.ndarray] = None  #: each pose's temperature (degC) when they differ, else None

    def problem(self, noise_var: float) -> Problem:
        return Problem(self.model, self.raw, self.target, lo=self.lo, hi=self.hi,
                       prior_mean=self.prior_mean, prior_std=self.prior_std, noise_var=noise_var)


@dataclass(eq=False)
class NoiseFit:
    """The solution with its noise model: per-pose residual variance (scaled up by the
    excess scatter when the noise model is rejected) and the MAP estimate re-polished at
    the noise actually seen."""
    prob: Problem
    res: OptimResult
    theta: np.ndarray
    residuals: np.ndarray
    var: np.ndarray                     #: per-pose residual variance (sensor unit^2, on target)
    source: str                         #: 'poses' or 'residuals'
    jacobian: np.ndarray                #: (N, kf) over the free parameters
    prior_precision: np.ndarray         #: (kf,) 0: no prior
    noise_var: float
    excess_scatter: float
    chi2: float
    dof: float


@dataclass(eq=False)
class Determination:
    """The covariance of the estimate (all parameters), its standard errors and the
    uncertainty with its determination flags."""
    cov: np.ndarray
    stderr: np.ndarray
    uncertainty: Uncertainty


@dataclass(eq=False)
class Heldout:
    """The held-out step's result: each pose's residual from the fit without it."""
    residuals: np.ndarray               #: per pose, held out of the fit
    predicted_std: np.ndarray           #: per pose, what the uncertainty predicts
    normalised_rms: float               #: RMS of residuals / predicted_std (1: it holds)


@dataclass
class Report:
    """The figures in the sensor's unit: parameters, standard errors, RMS in-sample and
    held out, noise, and the report extras (``info``)."""
    params: Dict[str, object]
    stderr: Dict[str, object]
    rms: float
    heldout_rms: float
    noise: float
    info: Dict[str, object]


def _choose_model(model, raw, pose_cov, target, chip, noise_inflation, min_poses):
    """(model, selection or None, min_poses): 'auto' resolved by :func:`select_model`."""
    selection = None
    if isinstance(model, str) and model == "auto":
        name, scores = select_model(raw, pose_cov, target, chip, noise_inflation=noise_inflation)
        se = scores.pop("_se")
        held = scores.pop("_held_at_prior")
        selection = {"chosen": name, "heldout_rms_g": scores, "standard_error_g": se,
                     "rule": "simplest model within one standard error of the lowest "
                             "leave-one-pose-out RMS"}
        if held:
            # candidates fitted with fewer poses than they need: their undetermined terms
            # are held at the datasheet prior (named in the fit's flags)
            selection["held_at_prior"] = sorted(held)
        if name in held:
            min_poses = 1
        model = name
    model = get_model(model) if isinstance(model, str) else model
    return model, selection, min_poses


def _setup(raw, model, pose_cov, target, bounds, chip, noise_inflation, prior, min_poses,
           temp_c=None) -> FitSetup:
    """Model, search box, datasheet prior and the noise level the prior is weighed against."""
    N = len(raw)
    model, selection, min_poses = _choose_model(model, raw, pose_cov, target, chip,
                                                noise_inflation, min_poses)
    free = model.free_mask
    kf = int(free.sum())
    if N < (kf + 1 if min_poses is None else min_poses):
        from ..errors import UserError
        raise UserError(f"{N} poses cannot determine the {kf} parameters of "
                        f"{model.name}: collect at least {kf + 1} (about 25 recommended)")
    if bounds is not None:
        lo, hi = bounds
    elif isinstance(model, MagModel):
        lo, hi = mag_bounds(model, raw, target)
    else:
        lo, hi = (b[free] for b in accel_bounds(model, chip))
    pc = _pose_cov(pose_cov, N, noise_inflation)
    use_prior = prior and model.sensor == "accel"
    pmean = pstd = None
    pstd_full = np.full(model.k, np.inf)
    if use_prior:
        pm_full, pstd_full = accel_prior(model, chip)
        pstd_full = np.where(free, pstd_full, np.inf)
        pmean, pstd = pm_full[free], pstd_full[free]
    if pc is not None:
        nv = float(np.mean(residual_variance(model, model.nominal, raw, pc)))
    else:   # the prior's weight needs a noise level: from a prior-less fit's residuals
        r0 = lm(Problem(model, raw, target, lo=lo, hi=hi)).data_fitness if use_prior else 0.0
        nv = max(r0 / max(N - kf, 1), 1e-30)
    T = None if temp_c is None else np.asarray(temp_c, float)
    if T is not None and (T.shape != (N,) or np.sum(np.isfinite(T)) < 2 or np.ptp(T[np.isfinite(T)]) == 0):
        T = None            # (a pose without a temperature: no slope share of its own, _fixed_terms_cov)
    return FitSetup(model, raw, target, lo, hi, pc, use_prior, pmean, pstd, pstd_full, nv,
                    chip, selection, T)


def _solve(st: FitSetup, method: str, rng, method_kw) -> NoiseFit:
    """Run the method, then the noise model: per-pose variance, excess scatter, and the
    MAP estimate re-polished when the noise seen differs from the prior's weight."""
    model, raw, target = st.model, st.raw, st.target
    N, free, kf = len(raw), model.free_mask, int(model.free_mask.sum())
    nv = st.noise_var
    prob = st.problem(nv)
    res: OptimResult = run_method(method, prob, rng=rng, **method_kw)
    theta = res.theta
    # per-pose residual variance: each pose's own noise, else the residuals
    r = model.residual(theta, raw, target)
    if st.pose_cov is not None:
        var = residual_variance(model, theta, raw, st.pose_cov)
        source = "poses"
    else:
        var = np.full(N, float(r @ r) / max(N - kf, 1))
        source = "residuals"
    J = model.jacobian(theta, raw, target)[1][:, free]
    lam = prob.prior_precision() if prob.has_prior and res.method != "ga-paper" else np.zeros(kf)
    # excess scatter: chi-square of the residuals against the noise model, per dof
    # (dof = N minus the effective number of parameters, the trace of the hat matrix)
    H = J.T @ J / nv + np.diag(lam)
    k_eff = float(np.trace(np.linalg.pinv(H, hermitian=True) @ (J.T @ J) / nv))
    dof = max(N - k_eff, 1.0)
    chi2 = float(np.sum(r * r / var))
    # scale up only when the noise model is rejected (chi-square above its 99 % point,
    # Wilson-Hilferty): with 10 poses and 9 parameters one degree of freedom is too
    # noisy to rescale by on every fit
    q99 = dof * (1 - 2 / (9 * dof) + 2.326 * np.sqrt(2 / (9 * dof))) ** 3
    phi = chi2 / dof if (source == "poses" and chi2 > q99) else 1.0
    var = var * phi
    if prob.has_prior and res.method != "ga-paper" and abs(np.log(np.mean(var) / nv)) > 0.1:
        # the prior's weight follows the noise actually seen: re-polish the MAP estimate
        nv = float(np.mean(var))
        prob = st.problem(nv)
        z, _, _ = lm_converge(prob, prob.reduce(theta))
        theta = prob.expand(z)
        r = model.residual(theta, raw, target)
        J = model.jacobian(theta, raw, target)[1][:, free]
    return NoiseFit(prob, res, theta, r, var, source, J, lam, nv, phi, chi2, dof)


def _determination(st: FitSetup, nf: NoiseFit) -> Determination:
    """Covariance (MAP), standard errors, CRLB and the determination flags."""
    model, raw, theta, free = st.model, st.raw, nf.theta, st.model.free_mask
    at_bound = np.zeros(model.k, bool)
    at_bound[free] = nf.prob.at_bound(nf.prob.reduce(theta))
    unc = crlb(model, theta, raw, nf.var)
    idx = np.flatnonzero(free)
    cov = _embedded(map_covariance(nf.jacobian, nf.var, nf.noise_var, nf.prior_precision), idx, model.k)
    cov_poses = cov       # what the flags judge: how far the poses determined each parameter
    if st.use_prior and (not free.all() or st.temp_c is not None) and nf.res.method != "ga-paper":
        left = _embedded(_fixed_terms_cov(st, nf), idx, model.k)
        unc.left_out_std = np.sqrt(np.clip(np.diag(left), 0, None))
        # the flags leave the temperature slope's share out: another pose does not narrow it
        # below the thermal fit's 18; they keep the terms the poses can pin (diag6's)
        if st.temp_c is None:
            cov_poses = cov + left
        elif not free.all():
            cov_poses = cov + _embedded(_fixed_terms_cov(replace(st, temp_c=None), nf), idx, model.k)
        cov = cov + left
    stderr_flat = np.sqrt(np.clip(np.diag(cov), 0, None))
    stderr_flat[~np.isfinite(unc.std) & ~np.isfinite(st.prior_std_full)] = np.inf
    if st.use_prior:       # ga-paper too: its data-only std is compared with the tolerance
        unc.prior_std = st.prior_std_full
    unc.posterior_std = stderr_flat
    unc.flags = determination(model, theta, raw, cov_poses, st.prior_std_full, at_bound,
                              float(median(nf.var)), st.target)
    return Determination(cov, stderr_flat, unc)


def _fixed_terms_cov(st: FitSetup, nf: NoiseFit) -> np.ndarray:
    """What the terms the model leaves out add to the free ones' covariance
    (judging/uncertainty.py omitted_covariance): diag6's non-orthogonality, held at 0, and,
    when the poses' temperatures differ, the bias's temperature slope (the constant model's
    bias is b(T) = b + k (T - t_ref) with k held at 0; t_ref the poses' weighted mean
    temperature, where the thermal block's order-0 constant stands: thermal/terms.py
    _constant_ref).  Those terms are where the poses and the datasheet prior (std = the
    tolerance, as the fit's; the slope's std the datasheet's zero-g change per degC,
    :func:`bias_tempco_prior`) put them, as the full model (every term free, one Gauss-Newton
    step from this fit) sees them: their second moment about the 0 they are held at, a a' + C
    (a the step's values, C their MAP covariance).  A black-box helper's 9-pose sessions, for
    which --model auto chose diag6 (its held-out error lowest where the pose set hides what
    alpha does), stated bias standard errors of 0.1-1.5 mg against errors of up to 23 mg from
    a +-1 % cross-axis (|z| up to 53); there the poses say little and C is near the prior.
    Where they pin the terms (25 poses on a part without cross-axis, which auto also fits with
    diag6) the term is small: the prior alone in its place stated 4.3 mg for errors of 0.02 (a
    cold review's find, in effect).  Its 8-degC warm-ups on 9-11 poses, below the thermal
    terms' 10-degC span (a constant only), kept parameters 9-25 sd from the truth: the slope
    moved each pose's bias by up to 4 mg, which the 9 parameters absorbed with 1-2 residual
    degrees of freedom left to show it."""
    model, free = st.model, st.model.free_mask
    pm, sd = accel_prior(model, st.chip)
    J = model.jacobian(nf.theta, st.raw, st.target)[1]
    lam = 1.0 / sd ** 2
    lam[free] = nf.prior_precision
    theta, fixed = nf.theta, ~free
    if st.temp_c is not None:           # the slope's columns: d r / d b_j times (T - t_ref)
        ok = np.isfinite(st.temp_c)
        w = 1.0 / np.asarray(nf.var, float)[ok]
        dT = np.where(ok, st.temp_c - np.sum(w * st.temp_c[ok]) / np.sum(w), 0.0)
        bias = model.groups.get("bias_g", model.groups.get("offset_g"))
        J = np.hstack([J, J[:, bias] * dT[:, None]])
        lam = np.concatenate([lam, 1.0 / bias_tempco_prior(st.chip) ** 2])
        pm, theta = np.concatenate([pm, np.zeros(3)]), np.concatenate([theta, np.zeros(3)])
        fixed = np.concatenate([fixed, np.ones(3, bool)])
    H = J.T @ J / nf.noise_var + np.diag(lam)
    g = J.T @ nf.residuals / nf.noise_var + lam * (theta - pm)
    a = -(np.linalg.pinv(H, rcond=1e-12, hermitian=True) @ g)[fixed]
    C = map_covariance(J, nf.var, nf.noise_var, lam)[np.ix_(fixed, fixed)]
    return omitted_covariance(J[:, ~fixed], J[:, fixed], nf.noise_var, nf.prior_precision,
                              np.outer(a, a) + C)


def _embedded(c: np.ndarray, idx: np.ndarray, k: int) -> np.ndarray:
    """The free parameters' (kf, kf) matrix ``c`` in the (k, k) matrix of all of them."""
    out = np.zeros((k, k))
    out[np.ix_(idx, idx)] = c
    return out


def bias_tempco_prior(chip: Optional[str]) -> np.ndarray:
    """The std (g/degC, per axis) of an accelerometer bias's temperature slope: the datasheet's
    zero-g change per degC (specs.AccelSpec.bias_tempco_g_per_c); unknown chips the largest
    of the known ones on each axis (the MPU-9250's 1.5 mg/degC)."""
    from ..specs import ACCEL
    spec = ACCEL.get(chip or "")
    if spec is not None:
        return np.asarray(spec.bias_tempco_g_per_c, float)
    return np.max([s.bias_tempco_g_per_c for s in ACCEL.values()], axis=0).astype(float)


def _heldout(st: FitSetup, nf: NoiseFit, heldout: bool) -> Heldout:
    """Each pose's residual from a fit without it, and the std the uncertainty predicts."""
    N = len(st.raw)
    if not heldout:
        return Heldout(np.full(N, np.nan), np.full(N, np.nan), float("nan"))
    hprior = (st.prior_mean, st.prior_std, nf.noise_var) if nf.prior_precision.any() else None
    ho, ho_sd = heldout_residuals(st.model, nf.theta, st.raw, st.target, lo=nf.prob.lo,
                                  hi=nf.prob.hi, prior=hprior, var=nf.var)
    return Heldout(ho, ho_sd, rms(ho / ho_sd))


def _noise_info(st: FitSetup, nf: NoiseFit, ho: Heldout, det: Determination,
                noise_inflation) -> Dict[str, object]:
    """The report extras every norm fit carries: the noise model, held-out figures,
    covariance and the model selection."""
    if nf.prior_precision.any():
        prior = "datasheet tolerances" + (f" ({st.chip})" if st.chip else " (generic)")
    else:
        prior = "none: ga-paper is paper 000 as written" if st.use_prior else "none"
    extra: Dict[str, object] = {
        "noise_model": {"per_pose": nf.source == "poses", "excess_scatter": round(nf.excess_scatter, 4),
                        "chi2": round(nf.chi2, 3), "dof": round(nf.dof, 2), "prior": prior},
        "heldout_normalised_rms": ho.normalised_rms, "heldout_residuals": ho.residuals,
        "covariance": det.cov, "heldout_predicted_std": ho.predicted_std}
    if noise_inflation is not None:
        k = np.broadcast_to(np.asarray(noise_inflation, float), (len(st.raw),))
        extra["noise_model"]["colour_inflation_median"] = round(float(median(k)), 3)
    if st.selection is not None:
        extra["model_selection"] = st.selection
    return extra


def _mag_figures(model: MagModel, nf: NoiseFit, ho: Heldout, det: Determination, extra) -> Report:
    """Magnetometer: hard/soft iron under their names; residuals (on the unit sphere)
    scaled to gauss by the fitted field."""
    params, stderr = mag_report(model, nf.theta, det.cov)
    scale = params["field_gauss"]
    return Report(params, stderr, rms(nf.residuals) * scale, rms(ho.residuals) * scale,
                  float(np.sqrt(median(nf.var))) * scale, extra)


def _accel_figures(model: NormModel, raw: np.ndarray, nf: NoiseFit, ho: Heldout,
                   det: Determination, extra) -> Report:
    """Accelerometer: parameters by group, in g, and paper 000's equivalent-path error."""
    params = model.unpack(nf.theta)
    se = det.stderr
    stderr = {g: [None if not np.isfinite(se[i]) else float(se[i]) for i in idx_g]
              for g, idx_g in model.groups.items()}
    # paper 000's equivalent-path error after 20 s, STD over poses (pose means held)
    _, _, sd_raw = path_error([x[None] for x in raw], 10.0, 20.0)
    _, _, sd_cal = path_error([x[None] for x in model.forward(nf.theta, raw)], 10.0, 20.0)
    extra["path_error_20s_std_m"] = {"raw": float(sd_raw[-1]), "calibrated": float(sd_cal[-1])}
    return Report(params, stderr, rms(nf.residuals), rms(ho.residuals),
                  float(np.sqrt(median(nf.var))), extra)


def _report(st: FitSetup, nf: NoiseFit, det: Determination, ho: Heldout,
            noise_inflation) -> Report:
    extra = _noise_info(st, nf, ho, det, noise_inflation)
    if isinstance(st.model, MagModel):
        return _mag_figures(st.model, nf, ho, det, extra)
    return _accel_figures(st.model, st.raw, nf, ho, det, extra)


def fit_norm(raw: np.ndarray, model="triangular9", method: str = "ga",
             pose_cov: Optional[np.ndarray] = None, target: float = 1.0, rng=None,
             bounds: Optional[Tuple[np.ndarray, np.ndarray]] = None, heldout: bool = True,
             chip: Optional[str] = None, noise_inflation=None, prior: bool = True,
             _min_poses: Optional[int] = None, temp_c: Optional[np.ndarray] = None,
             **method_kw) -> FitResult:
    """Fit a norm model (accelerometer or magnetometer) to pose means raw (N, 3) and report it.

    pose_cov: covariance of each pose mean (N, 3, 3) from within-pose scatter; each
    pose keeps its own (times ``noise_inflation``, scalar or (N,), the coloured-noise
    factor of :mod:`imucald.fitting.noise.colour`).  Without it (or with NaNs) the residual
    variance is used.  If the residuals scatter more than that noise explains
    (chi-square / dof > 1: model error, drift), the variances are scaled up by that
    ratio (``info['noise_model']['excess_scatter']``).
    chip: accelerometer chip name (mpu6050, mpu9250, adxl345) for bounds and prior.
    prior: the datasheet prior (MAP) for accelerometer models (not ga-paper, which
    is the paper's protocol as written; magnetometer models have none).
    model: a name, a model, or 'auto' (:func:`select_model`, reported in
    ``info['model_selection']``).
    temp_c: each pose's temperature (degC, (N,)); where they differ, the bias's temperature
    slope, which this constant model leaves out, is part of the stated covariance
    (:func:`_fixed_terms_cov`; accelerometer with the prior).

    The steps: setup (model, box, prior) -> solve (with the noise model) ->
    determination (covariance, flags) -> held-out -> report.
    """
    t_start = time.perf_counter()
    raw = np.asarray(raw, float)
    st = _setup(raw, model, pose_cov, target, bounds, chip, noise_inflation, prior, _min_poses, temp_c)
    nf = _solve(st, method, rng, method_kw)
    det = _determination(st, nf)
    ho = _heldout(st, nf, heldout)
    rep = _report(st, nf, det, ho, noise_inflation)
    res = nf.res
    fitness = float(st.model.fitness(nf.theta, raw, target))
    return FitResult(st.model.sensor, st.model.name, res.method, len(raw), nf.theta, rep.params,
                     rep.stderr, fitness, rep.rms, rep.heldout_rms, det.uncertainty.std,
                     det.uncertainty, rep.noise, nf.source, res.iterations, res.nfev,
                     time.perf_counter() - t_start,
                     {"optim": {k: v for k, v in res.info.items() if k != "iterations"}, **rep.info})


def mag_bounds(model: MagModel, raw: np.ndarray, target: float):
    """Search box for the magnetometer around a sphere fit (hard iron +- radius,
    soft iron within a factor 3 of 1/radius)."""
    c, r = sphere_fit(raw)
    inv = target / r
    kd = min(model.kw, 3)
    lo = np.array([inv / 3] * kd + [-inv] * (model.kw - kd) + list(c - r))
    hi = np.array([inv * 3] * kd + [inv] * (model.kw - kd) + list(c + r))
    return lo, hi


def fit_gyro_bias(pose_means_dps: np.ndarray, counts: np.ndarray,
                  pose_cov: Optional[np.ndarray] = None, method: str = "mean",
                  samples_dps: Optional[np.ndarray] = None, rng=None) -> FitResult:
    """Gyro bias from stationary poses: the sample-weighted mean (default), or paper
    002's eq. 6 fitness minimised by the GA ('eq6', needs the raw still samples)."""
    t0 = time.perf_counter()
    m = np.asarray(pose_means_dps, float)
    w = np.asarray(counts, float)
    N = len(m)
    b = gyro_bias_mean(m, w)
    if N > 1:
        sd = gyro_bias_scatter_se(m, w, b)
    elif pose_cov is not None:
        sd = np.sqrt(np.diag(pose_cov[0]))
    else:
        sd = np.full(3, np.nan)
    fitness = float(gyro_bias_eq6_fitness(b, samples_dps)) if samples_dps is not None else float(
        ((m - b) ** 2).sum())
    it = 0
    if method == "eq6":
        if samples_dps is None:
            from ..errors import UserError
            raise UserError("gyro method eq6 needs the still samples: give a recording, not pose means")
        from .solvers.ga import ga_core
        s = np.asarray(samples_dps, float)

        class _P:   # minimal problem adaptor for the GA core
            nfev = 0

            def fitness(self, z):
                return gyro_bias_eq6_fitness(z, s)
        lo, hi = b - 5 * s.std(0) - 1e-3, b + 5 * s.std(0) + 1e-3
        rng = as_rng(rng)
        z, f, g = ga_core(_P(), lo, hi, 1, rng, pop=60, max_gen=80, stall_gen=20)
        b, fitness, it = z[0], float(f[0]), int(g[0])
    mk = lambda v: [float(x) for x in v]
    return FitResult("gyro", "bias", method, N, b.copy(), {"bias_dps": mk(b)},
                       {"bias_dps": mk(sd)}, fitness, rms(m - b), float("nan"), sd, None,
                       float(np.sqrt(median(np.einsum("nii->n", pose_cov) / 3)))
                       if pose_cov is not None else float("nan"),
                       "poses", it, 0, time.perf_counter() - t0)
