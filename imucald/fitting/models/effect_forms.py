"""The functional forms of the unmodelled effects, declared once.

The simulator injects them (:mod:`imucald.sim.effects`) and the gap diagnosis fits them
(:mod:`imucald.gap.candidates`), so both speak of the same effect with the same
coefficient.  Every form returns the additive error (N, 3) in the sensor's unit.

Inputs: ``coef`` (3,) per-axis coefficients; ``dT_c`` (N,) temperature change from the
reference, degC; ``dt_s`` (N,) time from the start, s; ``f`` (N, 3) the true (or
calibrated) input in the sensor frame, in the sensor's unit (g, gauss); ``G`` (3, 3)
g-sensitivity matrix, deg/s per g.
"""
from __future__ import annotations

import numpy as np

__all__ = ["thermal_bias", "bias_drift", "thermal_scale", "nonlinearity", "g_sensitivity"]


def thermal_bias(coef, dT_c) -> np.ndarray:
    """Bias linear in temperature: coef * dT (unit/degC)."""
    return np.outer(np.asarray(dT_c, float), np.asarray(coef, float))


def bias_drift(coef, dt_s) -> np.ndarray:
    """Bias linear in time: coef * dt (unit/s)."""
    return np.outer(np.asarray(dt_s, float), np.asarray(coef, float))


def thermal_scale(coef, f, dT_c) -> np.ndarray:
    """Scale (1 + coef dT) on the input: coef * f * dT (1/degC)."""
    return np.asarray(coef, float) * np.asarray(f, float) * np.asarray(dT_c, float)[:, None]


def nonlinearity(coef, f) -> np.ndarray:
    """Per-axis quadratic in the input: coef * f^2 (unit per unit^2)."""
    return np.asarray(coef, float) * np.asarray(f, float) ** 2


def g_sensitivity(G, f_g) -> np.ndarray:
    """Gyro rate error from specific force: G f (deg/s per g)."""
    return np.asarray(f_g, float) @ np.asarray(G, float).T
