"""The unmodelled effects the gap diagnosis tests, and what separates look-alikes.

A norm-model candidate (accelerometer, magnetometer) is a raw-frame perturbation
``delta(eta, x, theta, ctx)`` removed from the readings, x' = x - delta; a gyro
candidate is a block of design columns added to the linear bias model.  ``ctx``
holds per-pose regressors: ``t`` and ``dt`` (s), ``temp`` and ``dT`` (degC),
``acc_dir`` (g, calibrated specific force).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

__all__ = ["Candidate", "ACCEL_CANDIDATES", "MAG_CANDIDATES", "GYRO_CANDIDATES", "SEPARATE"]


@dataclass
class Candidate:
    name: str
    q: int
    #: raw-frame perturbation delta (N, 3) for norm models: x' = x - delta(eta, x, theta, ctx)
    delta: Optional[Callable] = None
    #: design columns (3N, q) for the linear gyro model
    columns: Optional[Callable] = None
    units: str = ""


def _vec(eta):
    return np.asarray(eta, float)[:3]


ACCEL_CANDIDATES = [
    Candidate("thermal_bias", 3, lambda e, x, th, c: np.outer(c["dT"], _vec(e)), units="g/degC"),
    Candidate("thermal_scale", 3, lambda e, x, th, c: (x - th[6:9]) * np.outer(c["dT"], _vec(e)),
              units="1/degC"),
    Candidate("nonlinearity", 3, lambda e, x, th, c: _vec(e) * (x - th[6:9]) ** 2, units="g/g^2"),
    Candidate("bias_drift", 3, lambda e, x, th, c: np.outer(c["dt"], _vec(e)), units="g/s"),
]


def _sym_traceless(e):
    a, b, c, d, f = e
    return np.array([[a, c, d], [c, b, f], [d, f, -a - b]])


MAG_CANDIDATES = [
    Candidate("soft_iron", 5, lambda e, x, th, c: (x - th[1:4]) @ _sym_traceless(e).T,
              units="(symmetric traceless xx, yy, xy, xz, yz)"),
    Candidate("thermal_bias", 3, lambda e, x, th, c: np.outer(c["dT"], _vec(e)), units="gauss/degC"),
]


def kron_cols(v):                      # (N,) -> (3N, 3): v_i * I3
    N = len(v)
    X = np.zeros((3 * N, 3))
    for j in range(3):
        X[j::3, j] = v
    return X


def _gsens_cols(c):
    a = c["acc_dir"]
    N = len(a)
    X = np.zeros((3 * N, 9))
    for j in range(3):
        X[j::3, 3 * j:3 * j + 3] = a
    return X


GYRO_CANDIDATES = [
    Candidate("thermal_bias", 3, columns=lambda c: kron_cols(c["dT"]), units="dps/degC"),
    Candidate("g_sensitivity", 9, columns=_gsens_cols, units="dps/g (row-major G)"),
    Candidate("bias_drift", 3, columns=lambda c: kron_cols(c["dt"]), units="dps/s"),
]

#: what separates candidates that look alike on a given pose set
SEPARATE = {
    frozenset({"thermal_bias", "bias_drift"}):
        "a temperature profile that rises and falls (heat then cool), so temperature is not a function of time",
    frozenset({"nonlinearity", "thermal_bias"}):
        "edge and corner poses (not only the six +-1 g faces) and a wider temperature range",
    frozenset({"nonlinearity", "bias_drift"}): "edge and corner poses, and a repeated reference pose",
    frozenset({"thermal_scale", "nonlinearity"}): "edge and corner poses and a wider temperature range",
    frozenset({"thermal_scale", "thermal_bias"}): "more poses per axis sign at each temperature",
    frozenset({"thermal_scale", "bias_drift"}): "a temperature profile that rises and falls",
    frozenset({"g_sensitivity", "thermal_bias"}): "poses in every orientation at each temperature",
    frozenset({"g_sensitivity", "bias_drift"}): "poses in every orientation at the start and the end",
    frozenset({"soft_iron", "thermal_bias"}): "rotation data over the whole sphere at a steady temperature",
}
