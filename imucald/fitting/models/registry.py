"""Error models for norm-based (orientation-free) calibration.

Every model here is *affine in the measurement*: the corrected vector is

    h = A(theta) @ x + c(theta)

where ``x`` is the raw (nominally scaled) measurement in the sensor body frame
and ``theta`` the model's parameter vector.  The norm fitness compares ``|h|``
with a known magnitude (1 g for the accelerometer, 1 for the normalised
magnetometer).  Writing every model this way gives, once and for all:

* the forward map (measured -> corrected) and its inverse (true -> measured),
* the residual ``r = target - |h|`` and its analytic Jacobian
  ``dr/dtheta = -u^T (dA/dtheta x + dc/dtheta)`` with ``u = h/|h|``,
* all of it vectorised over a population of parameter vectors: ``theta`` may
  have any leading shape ``(..., k)``; poses are ``(N, 3)``.

Models
------
``triangular9``  Marinov & Petrov 2019 (paper 000) eq. 1:
    a = T K (a_m - b), T = [[1, a_yz, a_zy], [0, 1, a_zx], [0, 0, 1]], K = diag(S).
``full12``  Kim et al. 2023 (paper 001): the same with a unit-diagonal T holding all
    six misalignment terms.  A norm fitness cannot see a rotation of the corrected
    frame, so three directions of its parameter space are unobservable; see
    :meth:`Full12.unobservable_directions`.
``cosine``  Sarcevic, Pletl & Kincses (paper 002) eqs. 1-5:
    X = (X' + o1) s1;  Y = (Y' cos a_ZY + o2) s2;  Z = (Z' cos a_XZ cos a_YZ + o3) s3.
    Offsets are added before scaling, as in the paper.  Parameter subsets
    (offsets / scales / misalignment and their combinations) reproduce its Table I.
``mag_sym`` / ``mag_diag`` / ``mag_sphere``  magnetometer hard iron v plus soft
    iron W (symmetric, diagonal or scalar): h = W (m - v).  The field magnitude F is
    an unknown (paper 002): the fit is done on the unit sphere, |W~ (m - v)| = 1,
    and F = det(W~)^(-1/3) is recovered in the gauge det(W) = 1, so that the
    corrected field keeps the sensor's nominal gauss scale.  See :func:`mag_report`.

Units: accelerometer inputs and biases are in g; magnetometer in gauss; scales,
misalignment terms (small angles, rad) and soft-iron entries are dimensionless.

``diag6``  offsets and scales only (triangular9 with its three terms held at 0): the
    low-order end of model-order selection (:func:`imucald.fitting.fit.select_model`).

The base class lives in :mod:`.base`, the accelerometer models in
:mod:`.accel`, the magnetometer models in :mod:`.mag`.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .accel import COSINE_SUBSETS, Cosine, Diag6, Full12, Triangular9
from .mag import MagModel, mag_report
from .base import NormModel

__all__ = [
    "NormModel", "Triangular9", "Diag6", "Full12", "Cosine", "COSINE_SUBSETS", "MagModel",
    "get_model", "MODEL_NAMES", "gyro_bias_mean", "gyro_bias_scatter_se", "gyro_bias_eq6_fitness", "mag_report",
]

MODEL_NAMES = ["triangular9", "diag6", "full12", "cosine", "cosine-o", "cosine-s", "cosine-os",
               "cosine-om", "cosine-sm", "mag_sym", "mag_diag", "mag_sphere"]


def get_model(name: str) -> NormModel:
    """Model by name; raises ValueError naming the allowed values."""
    if name == "triangular9":
        return Triangular9()
    if name == "diag6":
        return Diag6()
    if name == "full12":
        return Full12()
    if name == "cosine":
        return Cosine("osm")
    if name.startswith("cosine-"):
        return Cosine(name.split("-", 1)[1])
    if name.startswith("mag_"):
        return MagModel(name[4:])
    raise ValueError(f"unknown model {name!r}: allowed {', '.join(MODEL_NAMES)}")


# --- gyroscope bias from stationary data ------------------------------------------------

def gyro_bias_mean(pose_means_dps: np.ndarray, counts: Optional[np.ndarray] = None
                   ) -> np.ndarray:
    """Plain (sample-count weighted) mean of the stationary gyro pose means, deg/s."""
    m = np.asarray(pose_means_dps, float)
    w = np.ones(len(m)) if counts is None else np.asarray(counts, float)
    return (m * w[:, None]).sum(0) / w.sum()


def gyro_bias_scatter_se(pose_means_dps: np.ndarray, counts: np.ndarray,
                         bias_dps: np.ndarray) -> np.ndarray:
    """Standard error (3,) of :func:`gyro_bias_mean` from the between-pose scatter, deg/s.

    The scatter includes g-sensitivity and drift as well as noise, so the error bar is
    honest when those are present; NaN with fewer than 2 poses."""
    m = np.asarray(pose_means_dps, float)
    w = np.asarray(counts, float)
    n = len(m)
    if n < 2:
        return np.full(3, np.nan)
    return np.sqrt(((m - bias_dps) ** 2 * w[:, None]).sum(0) / w.sum() / (n - 1))


def gyro_bias_eq6_fitness(bias_dps: np.ndarray, samples_dps: np.ndarray) -> np.ndarray:
    """Paper 002 eq. 6, averaged over samples: mean of (|X'-b1| + |Y'-b2| + |Z'-b3|)^2.

    bias_dps (..., 3), samples_dps (N, 3) -> (...,).
    """
    b = np.asarray(bias_dps, float)
    s = np.asarray(samples_dps, float)
    e = np.abs(s[None, :, :] - b.reshape(-1, 1, 3)).sum(-1)
    return (e ** 2).mean(-1).reshape(b.shape[:-1])
