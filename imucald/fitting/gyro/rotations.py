"""Gyro scale, misalignment and g-sensitivity from the rotations between still poses.

Method (Tedaldi, Pretto & Menegatti, "A robust and easy to implement method for IMU
calibration without external equipments", ICRA 2014, sec. IV-C): the gyro is integrated
between two consecutive still poses and the rotation it gives must carry the first
pose's gravity direction (calibrated accelerometer, body frame) onto the second's.
Gravity fixes 2 of the 3 degrees of freedom of each rotation; a calibrated magnetometer's
field direction, when given, adds the rotation about gravity.

Model (body frame = the calibrated accelerometer's frame), rates in deg/s::

    w = K (raw - b(t) - G a),   K = I + E

* ``E`` (3x3, row-major): scale errors on the diagonal, the 6 misalignment terms off it
  (relative to the accelerometer frame, all 6 observable); stored as ``matrix`` = K.
* ``G`` (3x3, deg/s per g, raw frame): g-sensitivity.  It is fitted, with the bias
  intercept b, from the still poses' gyro means against their calibrated specific force
  (error-models.md E12: the static gyro mean moves linearly with a).  Earth rate's vertical
  part is parallel to g and lands in G's isotropic part (~0.003 deg/s/g at 45 deg).
* During each rotation the bias is the straight line between the two poses' offsets
  (gyro mean - G a), so slow drift (warm-up) between poses does not enter E.

Integration: trapezoid increments theta_k = (w_{k-1} + w_k)/2 dt_k from the last sample
of one pose to the first of the next, composed as quaternions at the sample rate (an
associative prefix scan, vectorised over samples and rotations).  The residual of a
rotation is the predicted end direction, Delta^T u_start, in a tangent basis of the
measured one (radians, 2 per reference vector).  Its covariance: both poses' direction
noise (covariance of the mean / |a|^2), the gyro angle random walk (per-sample gyro
variance x dt^2 x samples) and the two poses' gyro-mean noise x rotation time.  The
Jacobian in E is analytic: d phi = Delta^T sum_k R_k dK v_k dt_k (R_k the prefix
rotation).  MAP Gauss-Newton with the datasheet prior (scale_tol on the diagonal,
cross_axis_tol off it); the covariance is scaled by chi^2/dof when the residuals reject
the noise model (above its 99 % point), as the accelerometer fit does.  A parameter is
``undetermined`` when its posterior std exceeds half its prior std.

Rotations are left out when a gyro sample sits at the rail (|x| within 4 LSB of a 16-bit
converter's full scale) or when samples were lost in the motion between the two poses (integration.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np

from ...numerics.npstats import median
from ..judging.metrics import rms
from ...numerics.rates import effective_rate
from .integration import (D2R, HOLE_FACTOR, MISSING_MIN, RAIL_FRACTION, RotationWindows,
                          angle_deg, predict_directions, rotation_windows, tangent_basis)
from ..judging.uncertainty import UNDETERMINED_RATIO

__all__ = ["GyroRotFit", "fit_gyro_rotations", "rotation_windows", "predict_directions",
           "gyro_prior", "fit_g_sensitivity", "RAIL_FRACTION", "HOLE_FACTOR", "MISSING_MIN"]



@dataclass
class GyroRotFit:
    """What :func:`fit_gyro_rotations` found.  Matrices are (3, 3), rates deg/s."""

    matrix: np.ndarray                  #: K, w = K (raw - b - G a)
    matrix_se: np.ndarray
    matrix_flags: List[str]             #: 9, row-major: determined / undetermined
    bias_dps: np.ndarray                #: intercept b of the pose gyro means
    bias_se_dps: np.ndarray
    g_sens: np.ndarray                  #: G, deg/s per g (zeros when not fitted)
    g_sens_se: np.ndarray
    g_sens_flags: List[str]
    rotations: int                      #: rotations used
    left_out: Dict[str, int]            #: saturated, gap
    excess_scatter: float               #: chi^2/dof scaling applied (1 = noise model held)
    chi2_dof: float                     #: whitened residuals' chi^2 per degree of freedom (fit)
    rms_deg: float                      #: in-sample direction error RMS
    #: folds, evaluated, better (K beats bias only), p_value, {raw,cal}_{mean,max}_deg when any
    #: rotation was evaluated, omitted + omitted_reason, why (when not better)
    heldout: Dict[str, object] = field(default_factory=dict)
    reference: str = "gravity"          #: gravity, or gravity+field

    @property
    def g_sens_used(self) -> bool:
        return any(f == "determined" for f in self.g_sens_flags)


def gyro_prior(chip: Optional[str]):
    """(std of K's diagonal, off-diagonal, G entries): the datasheet's scale and cross-axis
    tolerances and g-sensitivity; unknown chips 5 %, 3 %, 0.2 deg/s/g."""
    from ...specs import GYRO
    s = GYRO.get(chip or "")
    if s is None:
        return 0.05, 0.03, 0.2
    return s.scale_tol, s.cross_axis_tol, s.g_sensitivity_dps_per_g


def _white_var(chip, rate_hz):
    """Per-sample white-noise variance, (deg/s)^2, of the chip's gyro: noise density^2 x
    rate/2 (datasheet); None for an unknown chip."""
    from ...specs import GYRO
    s = GYRO.get(chip or "")
    return None if s is None else s.noise_density_dps_rthz ** 2 * rate_hz / 2


def _wobble(t, gyro, slices, white_var):
    """Per pose, the variance (deg^2, mean over axes) of the in-pose angle about its mean
    beyond white noise: hand tremor.  The pose's mean rate, the bias used, carries its
    end-to-start angle / T, and the ramp-weighted in-pose part half of it; so each pose adds
    2 x this x (1/2 + T_motion / (2 T_pose))^2 to a rotation's angle noise.  White noise
    alone gives the Brownian bridge's white_var dt^2 n / 6, which is taken off."""
    dt = 1.0 / max(effective_rate(t), 1e-300)      # rows a second: FIFO bursts share stamps
    out = np.zeros(len(slices))
    for i, s in enumerate(slices):
        g = gyro[s]
        th = np.cumsum(g - g.mean(0), 0) * dt
        out[i] = max(float(th.var(0).mean()) - white_var * dt * dt * len(g) / 6, 0.0)
    return out


def fit_g_sensitivity(gyro_means, gyro_cov, acc_means, g_std, fit: bool = True):
    """Bias intercept and G from still-pose means: gyro_p = b + G a_p (per axis, weighted by
    the pose means' variances, flat prior on b, N(0, g_std^2) on G; variances scaled by
    chi^2/dof when it exceeds its 99 % point).  Returns (b, b_se, G, G_se, flags)."""
    m = np.asarray(gyro_means, float)
    a = np.asarray(acc_means, float)
    N = len(m)
    var = np.einsum("nii->ni", gyro_cov) if gyro_cov is not None else np.full((N, 3), np.nan)
    X = np.column_stack([np.ones(N), a]) if fit else np.ones((N, 1))
    lam = np.r_[0.0, np.full(3, 1.0 / g_std ** 2)] if fit else np.zeros(1)
    b, bse = np.zeros(3), np.zeros(3)
    G, Gse = np.zeros((3, 3)), np.full((3, 3), g_std)
    for i in range(3):
        v = var[:, i]
        if not np.all(np.isfinite(v) & (v > 0)):
            v = np.full(N, max(float(np.var(m[:, i], ddof=1)) if N > 1 else 1.0, 1e-12))
        for _ in range(2):
            Xw = X / v[:, None]
            H = X.T @ Xw + np.diag(lam)
            beta = np.linalg.solve(H, Xw.T @ m[:, i])
            r = m[:, i] - X @ beta
            dof = max(N - np.trace(np.linalg.solve(H, X.T @ Xw)), 1.0)
            chi2 = float(np.sum(r * r / v))
            q99 = dof * (1 - 2 / (9 * dof) + 2.326 * np.sqrt(2 / (9 * dof))) ** 3
            if chi2 <= q99:
                break
            v = v * chi2 / dof
        cov = np.linalg.inv(H)
        se = np.sqrt(np.diag(cov))
        b[i], bse[i] = beta[0], se[0]
        if fit:
            G[i], Gse[i] = beta[1:], se[1:]
    flags = ["determined" if fit and s <= UNDETERMINED_RATIO * g_std else "undetermined"
             for s in Gse.ravel()]
    return b, bse, G, Gse, flags


class _Problem:
    """Residuals and Jacobian in E of a set of rotations, whitened."""

    def __init__(self, W, refs, var_ang):
        self.W = W
        self.refs = refs        # list of (start (R,3), end (R,3), start cov, end cov): unit vectors
        self.var_ang = var_ang  # (R,) rad^2, isotropic angle noise from the gyro
        self.B = [tangent_basis(e) for _, e, _, _ in refs]

    def subset(self, idx) -> "_Problem":
        """The same problem over rotations ``idx`` only (their rows are unchanged)."""
        sub = _Problem.__new__(_Problem)
        sub.W = _SubWindows(self.W, idx)
        sub.refs = [tuple(a[idx] for a in ref) for ref in self.refs]
        sub.var_ang = self.var_ang[idx]
        sub.B = [B[idx] for B in self.B]
        return sub

    def cov(self, Delta):
        blocks = []
        for (s, e, Cs, Ce), B in zip(self.refs, self.B):
            Cs_r = np.einsum("rji,rjk,rkl->ril", Delta, Cs, Delta)
            C = Cs_r + Ce + self.var_ang[:, None, None] * (np.eye(3) - np.einsum("ri,rj->rij", e, e))
            blocks.append(np.einsum("ria,rij,rjb->rab", B, C, B))
        return blocks

    def residual_jacobian(self, K):
        Delta, S = self.W.integrate(K)
        dphi = np.einsum("rji,rjab->riab", Delta, S).reshape(len(Delta), 3, 9)
        rs, Js = [], []
        for ((s, e, _, _), B, C) in zip(self.refs, self.B, self.cov(Delta)):
            u = predict_directions(Delta, s)
            Lc = np.linalg.cholesky(C)
            r = np.einsum("ria,ri->ra", B, u)
            J = np.einsum("ria,rik->rak", B, np.cross(u[:, :, None], dphi, axis=1))
            rs.append(np.linalg.solve(Lc, r[..., None])[..., 0])
            Js.append(np.linalg.solve(Lc, J))
        return np.concatenate(rs, 1).reshape(-1), np.concatenate(Js, 1).reshape(-1, 9), Delta

    def frame_jacobian(self, K, du_start, du_end):
        """Whitened residuals' derivative (rows as residual_jacobian's, k columns) in the
        accelerometer calibration's parameters, from the gravity directions' derivatives
        du (R, 3, k) at the start and end poses (the field directions do not depend on them)."""
        Delta, _ = self.W.integrate(K)
        out = []
        for i, (B, C) in enumerate(zip(self.B, self.cov(Delta))):
            if i == 0:
                D = np.einsum("ria,rik->rak", B, np.einsum("rji,rjk->rik", Delta, du_start) - du_end)
                out.append(np.linalg.solve(np.linalg.cholesky(C), D))
            else:
                out.append(np.zeros((len(Delta), 2, du_start.shape[2])))
        return np.concatenate(out, 1).reshape(-1, du_start.shape[2])


class _SubWindows:
    """Some of a RotationWindows' rotations (integrated without copying the others)."""

    def __init__(self, W, idx):
        self.W, self.idx = W, np.asarray(idx)
        self.T = W.T[self.idx]

    def integrate(self, K, idx=None):
        return self.W.integrate(K, self.idx if idx is None else self.idx[idx])


def _solve(prob, lam, phi=1.0, E0=None, iters=20):
    """MAP Gauss-Newton on E (9), prior precision lam (9,), noise scale phi."""
    E = np.zeros(9) if E0 is None else E0.copy()
    for _ in range(iters):
        r, J, _ = prob.residual_jacobian(np.eye(3) + E.reshape(3, 3))
        H = J.T @ J / phi + np.diag(lam)
        step = -np.linalg.solve(H, J.T @ r / phi + lam * E)
        E = E + step
        if np.max(np.abs(step)) < 1e-9:
            break
    r, J, Delta = prob.residual_jacobian(np.eye(3) + E.reshape(3, 3))
    return E, r, J, H


def _build(t, gyro, acc, mag, slices, wins, offsets, G, acc_cov, mag_cov, sample_var, offset_var, wobble):
    """The problem over windows ``wins``."""
    W = RotationWindows(t, gyro, acc, wins, offsets, G)
    p0 = np.array([w[0] for w in wins])
    refs = []
    for means, covs in ((acc, acc_cov), (mag, mag_cov)):
        if means is None:
            continue
        mu = np.array([means[s].mean(0) for s in slices])
        nrm = np.linalg.norm(mu, axis=1)
        u = mu / nrm[:, None]
        P = np.eye(3) - np.einsum("ni,nj->nij", u, u)
        C = np.einsum("nij,njk,nkl->nil", P, covs, P) / nrm[:, None, None] ** 2
        refs.append((u[p0], u[p0 + 1], C[p0], C[p0 + 1]))
    var_ang = sample_var * W.wdt2
    for q in (p0, p0 + 1):      # the wobble's share: (end - start angle) x (1/2 + T_motion / 2 T_pose)
        Tq = np.array([t[slices[i].stop - 1] - t[slices[i].start] for i in q])
        var_ang = var_ang + 2 * wobble[q] * (0.5 + W.T / (2 * np.maximum(Tq, 1e-9))) ** 2
    var_ang = var_ang * D2R ** 2
    return _Problem(W, refs, var_ang)


def fit_gyro_rotations(t_s, gyro_dps, acc_g, slices: Sequence[slice], mag=None, chip: Optional[str] = None,
                       range_dps: Optional[float] = None, g_sens: bool = True, folds: int = 5,
                       acc_frame=None, heldout_refits: bool = False) -> Optional[GyroRotFit]:
    """Fit K (and G) from a recording: samples t_s (n,), gyro_dps (n, 3) raw, acc_g (n, 3)
    calibrated, optional mag (n, 3) calibrated (any unit; its direction is used), the still
    intervals ``slices`` (sample index ranges, e.g. fitting.stillness.poses.detect_static).  range_dps:
    the gyro's full scale (saturation check; None: no check).  Held-out figures from
    ``folds``-fold cross-validation over rotations.  acc_frame: (accelerometer model name,
    theta, covariance of theta) of the calibration that gave acc_g; its uncertainty (the
    frame K is relative to) is then added to K's covariance (sensitivity of the MAP
    estimate to the gravity directions).  None when fewer than 3 rotations are usable.
    heldout_refits: each fold's K by its own Gauss-Newton fit (the figures' definition)
    instead of the one-step update from the full fit (:func:`_heldout_update`; the same
    figures within 1e-4 deg, tests/test_calibrate_all.py)."""
    t = np.asarray(t_s, float)
    gyro = np.asarray(gyro_dps, float)
    acc = np.asarray(acc_g, float)
    mg = None if mag is None else np.asarray(mag, float)
    slices = [s for s in slices if s.stop - s.start >= 2]
    wins, left = rotation_windows(t, gyro, slices, range_dps)
    if len(wins) < 3:
        return None
    sd_k, sd_off, sd_g = gyro_prior(chip)
    n = np.array([s.stop - s.start for s in slices])
    gm = np.array([gyro[s].mean(0) for s in slices])
    gsc = np.array([np.cov(gyro[s].T) for s in slices])
    am = np.array([acc[s].mean(0) for s in slices])
    b, bse, G, Gse, gflags = fit_g_sensitivity(gm, gsc / n[:, None, None], am, sd_g, g_sens)
    if not any(f == "determined" for f in gflags):       # not supported by these poses: leave G out
        b, bse, G, Gse, gflags = fit_g_sensitivity(gm, gsc / n[:, None, None], am, sd_g, False)
    offsets = gm - am @ G.T
    # white gyro noise per sample: the still samples' variance, capped at the datasheet's
    # density over the Nyquist band when the chip is known (hand tremor is a real rotation:
    # it integrates exactly and the ramp weighting takes it out; it is not angle noise)
    var_n = np.einsum("nii->n", gsc) / 3
    spec = _white_var(chip, effective_rate(t))
    if spec is not None:
        var_n = np.minimum(var_n, spec)
    sample_var = float(median(var_n))
    offset_var = var_n / n
    wobble = _wobble(t, gyro, slices, sample_var)
    acc_cov = np.array([np.cov(acc[s].T) for s in slices]) / n[:, None, None]
    mag_cov = None if mg is None else np.array([np.cov(mg[s].T) for s in slices]) / n[:, None, None]
    build = lambda w: _build(t, gyro, acc, mg, slices, w, offsets, G, acc_cov, mag_cov, sample_var, offset_var,
                             wobble)
    lam = 1.0 / np.where(np.eye(3, dtype=bool), sd_k, sd_off).ravel() ** 2
    prob = build(wins)
    E, r, J, H = _solve(prob, lam)
    dof = max(len(r) - float(np.trace(np.linalg.solve(H, J.T @ J))), 1.0)
    chi2 = float(r @ r)
    q99 = dof * (1 - 2 / (9 * dof) + 2.326 * np.sqrt(2 / (9 * dof))) ** 3
    phi = chi2 / dof if chi2 > q99 else 1.0
    if phi != 1.0:
        E, r, J, H = _solve(prob, lam, phi, E)
    cov = np.linalg.inv(H)
    if acc_frame is not None:
        du = _frame_derivative(acc_frame, np.array([acc[s].mean(0) for s in slices]))
        p0 = np.array([w[0] for w in wins])
        Ja = prob.frame_jacobian(np.eye(3) + E.reshape(3, 3), du[p0], du[p0 + 1])
        Sens = -cov @ (J.T @ Ja) / phi
        cov = cov + Sens @ np.asarray(acc_frame[2], float) @ Sens.T
    se = np.sqrt(np.diag(cov))
    flags = ["determined" if s <= UNDETERMINED_RATIO / np.sqrt(l) else "undetermined"
             for s, l in zip(se, lam)]
    K = np.eye(3) + E.reshape(3, 3)
    ho = (_heldout(build, wins, lam, phi, folds, K) if heldout_refits
          else _heldout_update(prob, lam, phi, folds, E, r, J))
    Delta = prob.W.integrate(K)[0]
    rms_deg = rms([angle_deg(predict_directions(Delta, s), e) for s, e, _, _ in prob.refs])
    return GyroRotFit(K, se.reshape(3, 3), flags, b, bse, G, Gse, gflags, len(wins), left, float(phi),
                      chi2 / dof, rms_deg, ho, "gravity" if mg is None else "gravity+field")


def _frame_derivative(acc_frame, cal_means):
    """d(unit gravity direction)/d theta (N, 3, k) at the calibrated pose means, by central
    differences of the model's affine correction."""
    from ..models.registry import get_model
    name, theta, _ = acc_frame
    m = get_model(name)
    th = np.asarray(theta, float)
    A, c = (np.asarray(x, float) for x in m.affine(th))
    raw = np.linalg.solve(A, (cal_means - c).T).T
    unit = lambda x: x / np.linalg.norm(x, axis=1, keepdims=True)
    out = np.zeros((len(raw), 3, len(th)))
    for i in range(len(th)):
        h = 1e-6 * max(1.0, abs(th[i]))
        d = np.zeros(len(th))
        d[i] = h
        Ap, cp = (np.asarray(x, float) for x in m.affine(th + d))
        Am, cm = (np.asarray(x, float) for x in m.affine(th - d))
        out[:, :, i] = (unit(raw @ Ap.T + cp) - unit(raw @ Am.T + cm)) / (2 * h)
    return out


def _folds(R: int, folds: int):
    """(k, [(test, train)]): the k-fold split of R rotations (every k-th to the test set)."""
    k = max(2, min(folds, R))
    out = []
    idx = np.arange(R)
    for f in range(k):          # (a mask, not setdiff1d: that imports numpy.ma, 7 ms)
        out.append((idx[f::k], idx[idx % k != f]))
    return k, out


#: a fold's Gauss-Newton steps stop after one below this change of E: that step moves a
#: direction carried through pi rad by < 3.2e-6 rad (1.8e-4 deg), and what it leaves is far
#: smaller (quadratic convergence; measured <= 1.3e-6 deg from _heldout's fits, which stop
#: at 1e-9)
FOLD_STEP_TOL = 1e-6


def _heldout_update(prob, lam, phi, folds, E_all, r, J):
    """:func:`_heldout`'s figures without a Gauss-Newton fit per fold from scratch.  Each
    rotation's whitened residual rows do not depend on the other rotations, so a fold's
    normal equations at the full fit's E are the full fit's less the held-out rows: the
    fold's first Gauss-Newton step (the step _heldout's fit starts with) costs no
    integration.  Steps on the fold's own rotations follow until one is below
    FOLD_STEP_TOL (usually one: Gauss-Newton converges quadratically, the first step
    leaving an error second order in the fold's change of E), and the held-out rotations
    are then integrated exactly at the fold's K.  About five integrations of the rotations
    in all instead of ~35 on the Xsens; the figures agree with _heldout's to ~1e-6 deg
    (tests/test_calibrate_all.py)."""
    from ..gate import paired_gate
    from ..judging.levels import GATE_FALSE_ACCEPT_RATE
    R = len(prob.W.T)
    rows = len(r) // R
    Jr = J.reshape(R, rows, 9)
    rr = r.reshape(R, rows)
    Hw = np.einsum("rak,ral->rkl", Jr, Jr)          # each rotation's share of J'J and J'r
    gw = np.einsum("rak,ra->rk", Jr, rr)
    H_all, g_all = Hw.sum(0), gw.sum(0)
    k, split = _folds(R, folds)
    s, e = prob.refs[0][:2]
    raw = angle_deg(predict_directions(prob.W.integrate(np.eye(3))[0], s), e)
    cal, ok = np.zeros(R), np.zeros(R, bool)
    for test, train in split:
        if len(train) < 3:
            continue
        H = (H_all - Hw[test].sum(0)) / phi + np.diag(lam)
        Ef = E_all - np.linalg.solve(H, (g_all - gw[test].sum(0)) / phi + lam * E_all)
        sub = prob.subset(train)
        for _ in range(20):
            rf, Jf, _ = sub.residual_jacobian(np.eye(3) + Ef.reshape(3, 3))
            step = -np.linalg.solve(Jf.T @ Jf / phi + np.diag(lam), Jf.T @ rf / phi + lam * Ef)
            Ef = Ef + step
            if np.max(np.abs(step)) < FOLD_STEP_TOL:
                break
        D = prob.W.integrate(np.eye(3) + Ef.reshape(3, 3), test)[0]
        cal[test] = angle_deg(predict_directions(D, s[test]), e[test])
        ok[test] = True
    return _heldout_figures(raw, cal, ok, k, GATE_FALSE_ACCEPT_RATE, paired_gate)


def _heldout_figures(raw, cal, ok, k, alpha, paired_gate):
    R = len(raw)
    out: Dict[str, object] = {"folds": k, "evaluated": int(ok.sum())}
    if not ok.all():
        out["omitted"] = int(R - ok.sum())
        out["omitted_reason"] = "held-out folds with fewer than 3 training rotations"
    if not ok.any():
        out.update(better=False, why="no held-out rotation could be evaluated")
        return out
    dec = paired_gate(raw[ok] ** 2, cal[ok] ** 2, alpha, "raw")
    out.update(raw_mean_deg=float(raw[ok].mean()), raw_max_deg=float(raw[ok].max()),
               cal_mean_deg=float(cal[ok].mean()), cal_max_deg=float(cal[ok].max()),
               p_value=dec.p_value, better=dec.accept)
    if not dec.accept:
        out["why"] = (f"not better than bias only on {int(ok.sum())} held-out rotations "
                      f"(one-sided signed-rank p = {dec.p_value:.2g} > {alpha:g})")
    return out


def _heldout(build, wins, lam, phi, folds, K_all):
    """Gravity-direction prediction error (deg) on held-out rotations: bias only (K = I)
    and calibrated (K fitted on the other folds), and whether the calibrated errors are
    smaller (one-sided signed-rank test on the paired squared errors, fitting.gate).  A fold
    with fewer than 3 training rotations is not evaluated: its rotations are counted as
    omitted (the figures and the test use the evaluated ones; none evaluated: no figures)."""
    from ..gate import paired_gate
    from ..judging.levels import GATE_FALSE_ACCEPT_RATE
    R = len(wins)
    k, split = _folds(R, folds)
    raw, cal, ok = np.zeros(R), np.zeros(R), np.zeros(R, bool)
    for test, train in split:
        if len(train) < 3:
            continue
        Ef, _, _, _ = _solve(build([wins[i] for i in train]), lam, phi, (K_all - np.eye(3)).ravel())
        pt = build([wins[i] for i in test])
        s, e = pt.refs[0][:2]
        raw[test] = angle_deg(predict_directions(pt.W.integrate(np.eye(3))[0], s), e)
        cal[test] = angle_deg(predict_directions(pt.W.integrate(np.eye(3) + Ef.reshape(3, 3))[0], s), e)
        ok[test] = True
    return _heldout_figures(raw, cal, ok, k, GATE_FALSE_ACCEPT_RATE, paired_gate)
