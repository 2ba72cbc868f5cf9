"""Still poses that no calibration of the others explains: a board held still while it
accelerated (a lift starting, a vehicle speeding up, an arm swinging the board gently), or
knocked during a hold.  Such a pose passes the stillness test (its variance is low, its
|a| is 20-50 mg off 1 g) and, kept, drags the whole fit: a cold review's two such poses in 25
made calibrate's result 9 mg off (median over 2000 directions; clean sessions 0.2-0.3 mg) with
exit 0 and no word, and the standard errors scaled by the scatter (x260-4700).

The test: a robust fit (Tukey's biweight, iteratively reweighted Gauss-Newton from the least-
squares solution, itself Gauss-Newton from the ideal sensor) whose residuals are each divided by the pose's own radial noise and by the
robust scale of those ratios when above 1 (real noise above the model: the Xsens file's
1.3); a pose beyond OUTLIER_POSE_Z of that is an outlier.  The robust fit is needed: a
least-squares fit drags toward the outliers, so that every pose's residual grows and none
stands out (the review's poses: 3.0 and 1.7 held-out standard errors; robust: 124 and 53).

Error rate (measured, max |z| of a session): 270 clean simulated sessions of 25 poses (bench,
hand-held tremor, a sway of 0.2 deg, 3 deg/s tremor with a 5 cm lever arm, a 20 degC warm-up,
20 Hz; MPU-6050, 9DOF, MPU-9250; 30 seeds each) reach 6.2 at most, none over 8; the real Xsens
file 2.3.  So a session loses a good pose to this test well under 1 time in 270."""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from ...numerics.npstats import median
from .uncertainty import residual_variance

__all__ = ["OUTLIER_POSE_Z", "OUTLIER_CAUSE", "outlier_poses", "poses_to_leave_out"]

#: a pose whose robust residual is this many of its standard deviations off is an outlier
OUTLIER_POSE_Z = 8.0
#: Tukey's biweight constant (95 % efficiency on normal residuals)
_TUKEY_C = 4.685
#: what such a pose was, in the CLI's warning and the daemon's calibration line
OUTLIER_CAUSE = "the board accelerated while still (a lift, a vehicle) or was knocked"
#: the model the test fits (the deployed one) and the fewest poses its fit keeps
_MODEL = "triangular9"


def _temperature_basis(temp_c, n_poses: int, n_params: int) -> Optional[np.ndarray]:
    """(N, 1): the poses' temperatures scaled to [-1, 1] (a bias linear in temperature, 3 terms),
    with 5 poses to spare beyond the model's parameters and those; else None (or when the
    temperatures are unknown or span under 0.5 degC).  Not quadratic: with 6 temperature terms
    beside the 9 on 25 poses the robust fit interpolated a lift's pose and threw out two clean
    ones (a simulated warm-up, seed 4); linear, the warm-ups' max |z| is 1.4-2.2 (seeds 1-8)."""
    if temp_c is None:
        return None
    T = np.asarray(temp_c, float)
    if len(T) != n_poses or not np.all(np.isfinite(T)) or T.max() - T.min() < 0.5:
        return None
    if n_poses < n_params + 3 + 5:
        return None
    u = (T - (T.max() + T.min()) / 2) / ((T.max() - T.min()) / 2)
    return u[:, None]


def poses_to_leave_out(raw: np.ndarray, pose_cov: Optional[np.ndarray], temp_c: Optional[np.ndarray] = None,
                       floor_var: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(indices of the outlier poses, z (N,), residual (N,), whether to leave them out) under
    the deployed model (calibrate's and the daemon's one rule): none with fewer poses than
    its fit needs plus one; found but kept when fewer than it needs would be left."""
    from ...numerics.folds import poses_needed
    from ..models.registry import get_model
    m = get_model(_MODEL)
    need = poses_needed(int(np.sum(m.free_mask)))
    N = len(raw)
    if pose_cov is None or N < need + 1:
        return np.zeros(0, int), np.zeros(N), np.zeros(N), False
    try:
        bad, z, r = outlier_poses(m, raw, pose_cov, temp_c=temp_c, floor_var=floor_var)
    except (ValueError, np.linalg.LinAlgError):
        return np.zeros(0, int), np.zeros(N), np.zeros(N), False
    idx = np.flatnonzero(bad)
    return idx, z, r, len(idx) > 0 and N - len(idx) >= need


def outlier_poses(model, raw: np.ndarray, pose_cov: Optional[np.ndarray], theta: Optional[np.ndarray] = None,
                  temp_c: Optional[np.ndarray] = None, floor_var: Optional[np.ndarray] = None,
                  iters: int = 40, tol: float = 1e-8) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(outlier mask (N,), z (N,), residual (N,), 1 - |a| under the robust fit, the raw
    unit): the robust residual of each pose in its standard deviations (module doc).  From
    ``theta`` (else the ideal sensor) Gauss-Newton least squares until its step falls under
    ``tol``, then Tukey-reweighted steps (``iters`` at most each).

    ``temp_c`` (N,): the poses' temperatures; where they vary, the robust model also holds a
    bias linear in temperature, so that a warm-up's
    cold first poses are not taken for a lift (a cold review: 1-3 of them left out at 9-20
    sd in 5 of 8 simulated warm-ups at the datasheet's 0.5 mg/degC, and the thermal fit lost
    with its span).  ``floor_var`` (3,): per axis, the variance of a pose mean's rounding
    (fitting/noise/posefloor.py pose_quantisation_floor), added along each pose's direction:
    at 15.6 mg/LSB the samples of a hold are often one value, the pose's own variance ~0,
    and the rounding of its mean took a clean pose 12 sd off.
    With no covariances nothing is flagged."""
    raw = np.asarray(raw, float)
    N = len(raw)
    none = np.zeros(N, bool), np.zeros(N), np.zeros(N)
    if pose_cov is None or N == 0:
        return none
    th = np.asarray(model.nominal if theta is None else theta, float).copy()
    P = _temperature_basis(temp_c, N, int(np.sum(model.free_mask)))
    c = np.zeros((0 if P is None else P.shape[1], 3))     # bias per temperature power, raw unit
    floor = (0.0 if floor_var is None else
             (raw / np.linalg.norm(raw, axis=1, keepdims=True)) ** 2 @ np.asarray(floor_var, float))

    def state(th, c):
        x = raw if P is None else raw - P @ c
        sig = np.sqrt(np.maximum(residual_variance(model, th, x, pose_cov) + floor, 1e-300))
        return x, sig

    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # poses that do not determine the model (all in one orientation: a board turned on a
        # table) send Gauss-Newton off to infinity; that ends the test with nothing flagged
        # (below), not with numpy's warnings on the user's terminal (an independent probe)
        fitted = _robust_fit(model, th, c, P, state, iters, tol)
        if fitted is None:
            return none
        x, sig = state(*fitted)
        r = model.residual(fitted[0], x)
        u = r / sig
    if not np.all(np.isfinite(u)):
        return none
    s = 1.4826 * float(median(np.abs(u)))
    z = u / max(s, 1.0)
    return np.abs(z) > OUTLIER_POSE_Z, z, r


def _robust_fit(model, th: np.ndarray, c: np.ndarray, P: Optional[np.ndarray], state,
                iters: int, tol: float) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """Gauss-Newton least squares, then Tukey-reweighted steps (outlier_poses), from the
    model's parameters ``th`` and the temperature terms ``c`` (basis ``P``; ``state(th, c)``:
    the corrected poses and their noise sd); (theta, c), or None when a step leaves the finite
    numbers."""
    free = np.asarray(model.free_mask, bool)
    k = int(free.sum())
    for robust in (False, True):
        for _ in range(iters):
            x, sig = state(th, c)
            r, J = model.jacobian(th, x)
            J = J[:, free]
            if P is not None:       # dr/dc_k = p_k(T) A^T u, u the corrected direction
                A, b = model.affine(th)
                h = x @ A.T + b
                g = (h / np.linalg.norm(h, axis=1, keepdims=True)) @ A
                J = np.concatenate([J, (P[:, :, None] * g[:, None, :]).reshape(len(x), -1)], 1)
            u = r / sig
            w = np.ones(len(x))
            if robust:
                # the scale never below the noise model's: with as many terms as a warm-up
                # needs, a scale read off the residuals alone collapsed onto a subset the model
                # interpolates (a lift in a simulated warm-up: half the poses at 0 residual)
                s = max(1.4826 * float(median(np.abs(u))), 1.0)
                w = np.clip(1.0 - (u / (_TUKEY_C * s)) ** 2, 0.0, None) ** 2
            Jf = J / sig[:, None]
            H, g = Jf.T @ (w[:, None] * Jf), -(Jf.T @ (w * u))
            try:
                step = np.linalg.solve(H, g)
            except np.linalg.LinAlgError:       # a direction the poses do not determine
                step = np.linalg.lstsq(H, g, rcond=None)[0]
            th[free] += step[:k]
            c = c + step[k:].reshape(c.shape)
            if not (np.all(np.isfinite(th)) and np.all(np.isfinite(c))):
                return None
            if float(np.max(np.abs(step))) < tol:
                break
    return th, c
