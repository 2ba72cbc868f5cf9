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
20 Hz; MPU-6050, 9DOF, MPU-9250; 30 seeds each) reach 5.3 at most, none over 8; the real Xsens
file 3.1.  So a session loses a good pose to this test well under 1 time in 270."""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from ...numerics.npstats import median
from .uncertainty import residual_variance

__all__ = ["OUTLIER_POSE_Z", "outlier_poses"]

#: a pose whose robust residual is this many of its standard deviations off is an outlier
OUTLIER_POSE_Z = 8.0
#: Tukey's biweight constant (95 % efficiency on normal residuals)
_TUKEY_C = 4.685


def outlier_poses(model, raw: np.ndarray, pose_cov: Optional[np.ndarray], theta: Optional[np.ndarray] = None,
                  iters: int = 40, tol: float = 1e-8) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(outlier mask (N,), z (N,), residual (N,), 1 - |a| under the robust fit, the raw
    unit): the robust residual of each pose in its standard deviations (module doc).  From
    ``theta`` (else the ideal sensor) Gauss-Newton least squares until its step falls under
    ``tol``, then Tukey-reweighted steps (``iters`` at most each).  With no covariances
    nothing is flagged."""
    raw = np.asarray(raw, float)
    N = len(raw)
    none = np.zeros(N, bool), np.zeros(N), np.zeros(N)
    if pose_cov is None or N == 0:
        return none
    th = np.asarray(model.nominal if theta is None else theta, float).copy()
    free = np.asarray(model.free_mask, bool)
    for robust in (False, True):
        for _ in range(iters):
            sig = np.sqrt(np.maximum(residual_variance(model, th, raw, pose_cov), 1e-300))
            r, J = model.jacobian(th, raw)
            u = r / sig
            w = np.ones(N)
            if robust:
                s = 1.4826 * float(median(np.abs(u)))
                if not s > 0:
                    break
                w = np.clip(1.0 - (u / (_TUKEY_C * s)) ** 2, 0.0, None) ** 2
            Jf = J[:, free] / sig[:, None]
            H, g = Jf.T @ (w[:, None] * Jf), -(Jf.T @ (w * u))
            try:
                step = np.linalg.solve(H, g)
            except np.linalg.LinAlgError:       # a direction the poses do not determine
                step = np.linalg.lstsq(H, g, rcond=None)[0]
            th[free] += step
            if not np.all(np.isfinite(th)):
                return none
            if float(np.max(np.abs(step))) < tol:
                break
    sig = np.sqrt(np.maximum(residual_variance(model, th, raw, pose_cov), 1e-300))
    r = model.residual(th, raw)
    u = r / sig
    s = 1.4826 * float(median(np.abs(u)))
    z = u / max(s, 1.0)
    return np.abs(z) > OUTLIER_POSE_Z, z, r
