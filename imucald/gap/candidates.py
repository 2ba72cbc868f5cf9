"""The unmodelled effects the gap diagnosis tests, and what separates look-alikes.

A norm-model candidate (accelerometer, magnetometer) is a raw-frame perturbation
``delta(eta, x, theta, ctx)`` removed from the readings, x' = x - delta; a gyro
candidate is a block of design columns added to the linear bias model.  ``ctx``
holds per-pose regressors: ``t`` and ``dt`` (s), ``temp`` and ``dT`` (degC),
``acc_dir`` (g, calibrated specific force), ``hat2``..``hat4`` (time hat functions).
Several candidates may share a name (variants of one class, e.g. the knot count of
``wandering_bias``): the variant with the lower held-out error is kept.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from ..fitting.models import effect_forms as ef

__all__ = ["Candidate", "ACCEL_CANDIDATES", "MAG_CANDIDATES", "GYRO_CANDIDATES", "SEPARATE", "TRACELESS",
           "hat_columns", "kron_cols"]


@dataclass
class Candidate:
    name: str
    q: int
    #: raw-frame perturbation delta (N, 3) for norm models: x' = x - delta(eta, x, theta, ctx)
    delta: Optional[Callable] = None
    #: design columns (3N, q) for the linear gyro model
    columns: Optional[Callable] = None
    units: str = ""
    #: the coefficients reported under several keys: [(units, count), ...] (None: one key)
    parts: Optional[list] = None


def _vec(eta):
    return np.asarray(eta, float)[:3]


def _radial_cubic(e, f):
    """delta = u * C(u), u = f / |f|, C the cubic form with coefficients ``e`` (10,)."""
    u = f / np.linalg.norm(f, axis=1, keepdims=True)
    x, y, z = u.T
    mon = np.stack([x ** 3, y ** 3, z ** 3, x * x * y, x * x * z, y * y * x, y * y * z, z * z * x, z * z * y,
                    x * y * z], 1)
    return u * (mon @ e)[:, None]


def _thermal2(e, dT):
    """A bias linear plus quadratic in temperature (a warm-up's curvature), (N, 3)."""
    e = np.asarray(e, float)
    q = dT ** 2 - np.mean(dT ** 2)
    return ef.thermal_bias(e[:3], dT) + ef.thermal_bias(e[3:6], q)


ACCEL_CANDIDATES = [
    Candidate("thermal_bias", 3, lambda e, x, th, c: ef.thermal_bias(_vec(e), c["dT"]), units="g/degC"),
    # with curvature: a variant of the same class, chosen by held-out error (issue 25: a bias
    # that follows temperature along a curve left a linear fit "partially" explaining it)
    Candidate("thermal_bias", 6, lambda e, x, th, c: _thermal2(e, c["dT"]), units="g/degC",
              parts=[("g/degC", 3), ("curvature_g/degC^2", 3)]),
    Candidate("thermal_scale", 3, lambda e, x, th, c: ef.thermal_scale(_vec(e), x - th[6:9], c["dT"]),
              units="1/degC"),
    Candidate("nonlinearity", 3, lambda e, x, th, c: ef.nonlinearity(_vec(e), x - th[6:9]), units="g/g^2"),
    # second order with cross-axis terms (reference E3 + E4): each axis also sees the
    # product of the other two; a variant of the same class, chosen by held-out error
    Candidate("nonlinearity", 6,
              lambda e, x, th, c: _vec(e) * (x - th[6:9]) ** 2 + np.asarray(e, float)[3:]
              * (x - th[6:9])[:, [1, 2, 0]] * (x - th[6:9])[:, [2, 0, 1]],
              units="g/g^2 (x^2, y^2, z^2 on their own axes; then yz on x, zx on y, xy on z)"),
    # the general second-order form (each axis any quadratic form of the input): norm-only
    # data see only its radial part u . delta, a cubic form in the unit direction u (10
    # monomials, 3 of them degree-1 on the sphere and absorbed by the bias); a variant of
    # the same class, chosen by held-out error (issue 25: a full quadratic with nine cross
    # terms per axis was "unexplained" against the 3- and 6-term forms)
    Candidate("nonlinearity", 10, lambda e, x, th, c: _radial_cubic(np.asarray(e, float), x - th[6:9]),
              units="g (radial cubic form in the unit input: xxx, yyy, zzz, xxy, xxz, yyx, yyz, zzx, zzy, xyz)"),
    Candidate("bias_drift", 3, lambda e, x, th, c: ef.bias_drift(_vec(e), c["dt"]), units="g/s"),
    # a wandering bias: piecewise linear in time with m + 1 equally spaced knots (m = 2, 3, 4,
    # the count chosen by held-out error), beyond the straight line of bias_drift
    *[Candidate("wandering_bias", 3 * m, lambda e, x, th, c, m=m: c[f"hat{m}"] @ np.asarray(e).reshape(m, 3),
                units=f"g (bias at knots 1..{m} of {m + 1} equally spaced in time, relative to the first)")
      for m in (2, 3, 4)],
]


#: traceless 3x3 matrices (row-major), 8 basis vectors: the isotropic part of a
#: g-sensitivity G reads k u, the same as Earth's vertical rate, which the baseline holds
TRACELESS = np.linalg.svd(np.eye(9) - np.outer(np.eye(3).ravel(), np.eye(3).ravel()) / 3)[0][:, :8]


def hat_columns(t_s: np.ndarray) -> dict:
    """ctx entries ``hat2``..``hat4``: hat functions of time at knots 1..m of m + 1."""
    sc = (t_s - t_s.min()) / max(float(np.ptp(t_s)), 1e-9)
    return {f"hat{m}": np.clip(1 - np.abs(sc[:, None] * m - np.arange(1, m + 1)[None, :]), 0, None)
            for m in (2, 3, 4)}


#: the magnetometer's baseline is the deployed hard + soft iron model (mag_sym), so soft
#: iron is not an effect; what it misses: hard iron and gain changing with temperature,
#: a drifting hard iron, and interference that follows the orientation (``acc_dir``)
MAG_CANDIDATES = [
    Candidate("thermal_bias", 3, lambda e, x, th, c: ef.thermal_bias(_vec(e), c["dT"]), units="gauss/degC"),
    Candidate("thermal_bias", 6, lambda e, x, th, c: _thermal2(e, c["dT"]), units="gauss/degC",
              parts=[("gauss/degC", 3), ("curvature_gauss/degC^2", 3)]),
    Candidate("thermal_scale", 3, lambda e, x, th, c: ef.thermal_scale(_vec(e), x - th[-3:], c["dT"]),
              units="1/degC"),
    Candidate("bias_drift", 3, lambda e, x, th, c: ef.bias_drift(_vec(e), c["dt"]), units="gauss/s"),
    # traceless: an offset c f (D = c I) only moves the sphere's centre in the world frame
    # (|R'(h + c g)| is the same for every orientation R), so it leaves no trace; a fit
    # would slide along it to soak up anything (e.g. a magnetometer that lags the turns)
    Candidate("orientation_interference", 8,
              lambda e, x, th, c: c["acc_dir"] @ (TRACELESS @ np.asarray(e, float)).reshape(3, 3).T,
              units="gauss/g (8 coefficients of a traceless D on the TRACELESS basis: offset D f "
                    "with f the specific force; D = c I is not identifiable)"),
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
    return X @ TRACELESS


GYRO_CANDIDATES = [
    Candidate("thermal_bias", 3, columns=lambda c: kron_cols(c["dT"]), units="dps/degC"),
    Candidate("g_sensitivity", 8, columns=_gsens_cols,
              units="dps/g (row-major G, traceless: its trace is not separable from Earth's vertical rate)"),
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
    frozenset({"wandering_bias", "bias_drift"}): "a longer recording, or a repeated reference pose at the end",
    frozenset({"wandering_bias", "thermal_bias"}): "a temperature profile that rises and falls, more than once",
}
