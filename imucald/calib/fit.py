"""High-level calibration: pose means in, a reported :class:`Calibration` out.

Everything the daemon and the command line report comes from here: the
parameters under unit-carrying names, their standard errors and CRLB, rank and
condition of the problem, in-sample and held-out residuals.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np

from .metrics import path_error, rms
from .models import MagModel, NormModel, get_model, gyro_bias_eq6_fitness, mag_report
from .optim import OptimResult, Problem, _lm_converge, run_method, sphere_fit
from .uncertainty import Uncertainty, crlb, residual_variance

__all__ = ["Calibration", "fit_norm", "heldout_residuals", "fit_gyro_bias",
           "robust_pose_variance"]


@dataclass
class Calibration:
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
    noise_source: str               #: 'poses' (within-pose scatter) or 'residuals'
    iterations: int
    nfev: int
    wall_s: float
    info: Dict[str, object] = field(default_factory=dict)

    def to_json(self) -> Dict[str, object]:
        unit = {"accel": "g", "mag": "gauss", "gyro": "dps"}[self.sensor]
        d: Dict[str, object] = {
            "sensor": self.sensor, "model": self.model, "method": self.method,
            "poses": int(self.poses), "params": self.params, "stderr": self.stderr,
            "fitness": float(self.fitness), f"heldout_rms_{unit}": float(self.heldout_rms),
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
        d[f"noise_{unit}"] = float(self.noise)
        d["noise_source"] = self.noise_source
        if "path_error_20s_std_m" in self.info:
            d["path_error_20s_std_m"] = self.info["path_error_20s_std_m"]
        d["iterations"] = int(self.iterations)
        d["wall_s"] = round(float(self.wall_s), 4)
        return d


def robust_pose_variance(pose_cov: Optional[np.ndarray]) -> Optional[float]:
    """Median over poses of the isotropic pose-mean variance (trace/3): robust to a
    few disturbed poses (reference/error-models.md, key point 2)."""
    if pose_cov is None:
        return None
    pc = np.asarray(pose_cov, float)
    v = np.einsum("nii->n", pc) / 3.0 if pc.ndim == 3 else pc
    v = v[np.isfinite(v)]
    if v.size == 0 or not np.all(v > 0):
        return None
    return float(np.median(v))


def heldout_residuals(model: NormModel, theta: np.ndarray, raw: np.ndarray, target: float = 1.0,
                      folds: Optional[int] = None, lo=None, hi=None) -> np.ndarray:
    """Held-out residual of every pose: refit (LM, warm-started at theta) without it.

    Leave-one-pose-out when ``folds`` is None and N <= 60, otherwise k-fold over
    poses (10 folds by default).
    """
    raw = np.asarray(raw, float)
    N = len(raw)
    if folds is None:
        folds = N if N <= 60 else 10
    groups = np.array_split(np.arange(N), folds)
    out = np.zeros(N)
    z0 = None
    for g in groups:
        keep = np.ones(N, bool)
        keep[g] = False
        prob = Problem(model, raw[keep], target, lo=lo, hi=hi)
        if z0 is None:
            z0 = prob.reduce(theta)
        z, _, _ = _lm_converge(prob, z0, max_iter=60, ftol=1e-12)
        out[g] = model.residual(prob.expand(z), raw[g], target)
    return out


def _sandwich_std(model: NormModel, theta: np.ndarray, raw: np.ndarray, var: np.ndarray,
                  free: np.ndarray, unc: Uncertainty) -> np.ndarray:
    """Standard error of the (unweighted) least-squares estimate: (J'J)^+ J'VJ (J'J)^+."""
    _, J = model.jacobian(theta, raw)
    J = J[:, free]
    JtJ = J.T @ J
    Jp = np.linalg.pinv(JtJ, rcond=1e-12, hermitian=True)
    C = Jp @ (J.T * var) @ J @ Jp
    sd = np.zeros(model.k)
    sd[free] = np.sqrt(np.clip(np.diag(C), 0, None))
    sd[~np.isfinite(unc.std)] = np.inf
    return sd


def accel_bounds(model: NormModel, chip: Optional[str]) -> Tuple[np.ndarray, np.ndarray]:
    """Initial search box from the chip's datasheet tolerances, made wide enough for
    real parts: bias +-max(3 tol, 0.1 g), scale +-max(3 tol, 5 %), non-orthogonality
    +-max(3 cross-axis, 0.05).  Unknown chips get the generic wide box
    (+-0.25 g, +-15 %, +-0.08)."""
    from ..sim.specs import ACCEL
    spec = ACCEL.get(chip or "")
    if spec is None:
        return model.default_bounds()
    return model.default_bounds(spec_bias=max(3 * max(spec.bias_tol_g), 0.1),
                                spec_scale=max(3 * spec.scale_tol, 0.05),
                                spec_alpha=max(3 * spec.cross_axis_tol, 0.05))


def fit_norm(raw: np.ndarray, model="triangular9", method: str = "ga",
             pose_cov: Optional[np.ndarray] = None, target: float = 1.0, rng=None,
             bounds: Optional[Tuple[np.ndarray, np.ndarray]] = None, heldout: bool = True,
             chip: Optional[str] = None, **method_kw) -> Calibration:
    """Fit a norm model to pose means raw (N, 3) and report it.

    pose_cov: covariance of each pose mean (N, 3, 3) from within-pose scatter, used
    for the CRLB; without it (or with NaNs) the residual variance is used.
    chip: accelerometer chip name (mpu6050, mpu9250, adxl345) for the search bounds.
    """
    t_start = time.perf_counter()
    model = get_model(model) if isinstance(model, str) else model
    raw = np.asarray(raw, float)
    N = len(raw)
    free = model.free_mask
    if N < int(free.sum()) + 1:
        from ..errors import UserError
        raise UserError(f"{N} poses cannot determine the {int(free.sum())} parameters of "
                        f"{model.name}: collect at least {int(free.sum()) + 1} (about 25 recommended)")
    lo = hi = None
    if bounds is not None:
        lo, hi = bounds
    elif isinstance(model, MagModel):
        lo, hi = _mag_bounds(model, raw, target)
    else:
        lo, hi = (b[model.free_mask] for b in accel_bounds(model, chip))
    prob = Problem(model, raw, target, lo=lo, hi=hi)
    res: OptimResult = run_method(method, prob, rng=rng, **method_kw)
    theta = res.theta
    r = model.residual(theta, raw, target)
    # noise: robust within-pose estimate when available, else the fit's residuals
    pv = robust_pose_variance(pose_cov)
    if pv is not None:
        var = residual_variance(model, theta, raw, np.full(N, pv))
        source = "poses"
    else:
        dof = max(N - int(free.sum()), 1)
        var = np.full(N, float(r @ r) / dof)
        source = "residuals"
    unc = crlb(model, theta, raw, var)
    stderr_flat = _sandwich_std(model, theta, raw, var, free, unc)
    ho = heldout_residuals(model, theta, raw, target, lo=prob.lo, hi=prob.hi) if heldout \
        else np.full(N, np.nan)
    extra: Dict[str, object] = {}
    if isinstance(model, MagModel):
        params, stderr = mag_report(model, theta, unc.cov)
        scale = params["field_gauss"]           # residuals are on the unit sphere
        rr, hr, noise = rms(r) * scale, rms(ho) * scale, float(np.sqrt(np.median(var))) * scale
    else:
        params = model.unpack(theta)
        stderr = {g: [None if not np.isfinite(stderr_flat[i]) else float(stderr_flat[i])
                      for i in idx] for g, idx in model.groups.items()}
        rr, hr, noise = rms(r), rms(ho), float(np.sqrt(np.median(var)))
        # paper 000's equivalent-path error after 20 s, STD over poses (pose means held)
        _, _, sd_raw = path_error([x[None] for x in raw], 10.0, 20.0)
        _, _, sd_cal = path_error([x[None] for x in model.forward(theta, raw)], 10.0, 20.0)
        extra["path_error_20s_std_m"] = {"raw": float(sd_raw[-1]), "calibrated": float(sd_cal[-1])}
    return Calibration(model.sensor, model.name, res.method, N, theta, params, stderr,
                       res.fitness, rr, hr, unc.std, unc, noise, source, res.iterations,
                       res.nfev, time.perf_counter() - t_start,
                       {"optim": {k: v for k, v in res.info.items() if k != "iterations"}, **extra})


def _mag_bounds(model: MagModel, raw: np.ndarray, target: float):
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
                  samples_dps: Optional[np.ndarray] = None, rng=None) -> Calibration:
    """Gyro bias from stationary poses: the sample-weighted mean (default), or paper
    002's eq. 6 fitness minimised by the GA ('eq6', needs the raw still samples)."""
    t0 = time.perf_counter()
    m = np.asarray(pose_means_dps, float)
    w = np.asarray(counts, float)
    N = len(m)
    b = (m * w[:, None]).sum(0) / w.sum()
    # between-pose scatter includes g-sensitivity and drift: an honest error bar
    if N > 1:
        sd = np.sqrt(((m - b) ** 2 * w[:, None]).sum(0) / w.sum() / (N - 1))
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
        from .optim import _ga_core
        s = np.asarray(samples_dps, float)

        class _P:   # minimal problem adaptor for the GA core
            nfev = 0

            def fitness(self, z):
                return gyro_bias_eq6_fitness(z, s)
        lo, hi = b - 5 * s.std(0) - 1e-3, b + 5 * s.std(0) + 1e-3
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        z, f, g = _ga_core(_P(), lo, hi, 1, rng, pop=60, max_gen=80, stall_gen=20)
        b, fitness, it = z[0], float(f[0]), int(g[0])
    mk = lambda v: [float(x) for x in v]
    return Calibration("gyro", "bias", method, N, b.copy(), {"bias_dps": mk(b)},
                       {"bias_dps": mk(sd)}, fitness, rms(m - b), float("nan"), sd, None,
                       float(np.sqrt(np.median(np.einsum("nii->n", pose_cov) / 3)))
                       if pose_cov is not None else float("nan"),
                       "poses", it, 0, time.perf_counter() - t0)
