"""The digital twin and the noise model of the gap diagnosis.

The fitting kernels (numerical Jacobian, weighted Levenberg-Marquardt, hat matrix and
leave-one-out residuals) and the twin (the held-out residual the noise model predicts
for this design, by linearised re-simulation) are :mod:`imucald.calib.heldout`'s,
re-exported; here the noise model itself (disturbed-pose flags; the coloured-noise
inflation is the calibration's own, calib.noise.colour_inflation).
"""
from __future__ import annotations

import numpy as np

__all__ = ["numjac", "lm_weighted", "hat_diag", "heldout", "twin_rms", "flag_disturbed"]


# the fitting kernels and the twin live in calib/heldout.py (the thermal order choice uses them)
from ..calib.heldout import hat_diag, heldout, lm_weighted, numjac, twin_rms  # noqa: F401


# --- noise -----------------------------------------------------------------------------------

def flag_disturbed(s2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Poses whose within-pose variance is far above the robust level (hand moved)."""
    med = np.median(s2)
    # chi-square(n-1)/(n-1) upper 99.9 % point ~ 1 + 3.1 sqrt(2/(n-1)); times 1.5 for colour
    lim = med * 1.5 * (1 + 3.1 * np.sqrt(2.0 / np.maximum(n - 1, 1)))
    return s2 > lim
