"""Magnetometer hard + soft iron norm models and their physical report (paper 002:
the field magnitude is an unknown).  Units: gauss; soft-iron entries per gauss."""
from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from .base import NormModel, bias_form_jac

__all__ = ["MagModel", "mag_report"]

_SYM_IDX = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]


class MagModel(NormModel):
    """Magnetometer hard + soft iron on the unit sphere: |W~ (m - v)| = 1.

    ``kind``: 'sym' (symmetric W~, 6 + 3 parameters), 'diag' (3 + 3) or 'sphere' (1 + 3).
    The physical report (field magnitude F, W normalised to det 1) comes from
    :func:`mag_report`.
    """

    def __init__(self, kind: str = "sym"):
        if kind not in ("sym", "diag", "sphere"):
            raise ValueError(f"magnetometer model kind {kind!r}: allowed sym, diag, sphere")
        self.kind = kind
        if kind == "sym":
            wn = ["w_xx", "w_yy", "w_zz", "w_xy", "w_xz", "w_yz"]
        elif kind == "diag":
            wn = ["w_xx", "w_yy", "w_zz"]
        else:
            wn = ["w"]
        kw = len(wn)
        super().__init__(
            name=f"mag_{kind}", sensor="mag",
            param_names=wn + ["hard_iron_x_gauss", "hard_iron_y_gauss", "hard_iron_z_gauss"],
            groups={"soft_iron_per_gauss": list(range(kw)),
                    "hard_iron_gauss": list(range(kw, kw + 3))})
        self.kw = kw

    @property
    def nominal(self):
        return np.array([1.0] * min(self.kw, 3) + [0.0] * (self.kw - min(self.kw, 3)) + [0, 0, 0], float)

    def matrix(self, theta):
        theta = np.asarray(theta, float)
        W = np.zeros(theta.shape[:-1] + (3, 3))
        if self.kind == "sphere":
            for i in range(3):
                W[..., i, i] = theta[..., 0]
        else:
            for k in range(self.kw):
                i, j = _SYM_IDX[k]
                W[..., i, j] = theta[..., k]
                W[..., j, i] = theta[..., k]
        return W

    def affine(self, theta):
        theta = np.asarray(theta, float)
        W = self.matrix(theta)
        return W, -np.einsum("...ij,...j->...i", W, theta[..., self.kw:])

    def affine_jac(self, theta):
        theta = np.asarray(theta, float)
        W = self.matrix(theta)
        dM = np.zeros(theta.shape[:-1] + (self.kw, 3, 3))
        if self.kind == "sphere":
            for i in range(3):
                dM[..., 0, i, i] = 1.0
        else:
            for k in range(self.kw):
                i, j = _SYM_IDX[k]
                dM[..., k, i, j] = 1.0
                dM[..., k, j, i] = 1.0
        return bias_form_jac(dM, W, theta[..., self.kw:])

    def from_ellipsoid(self, center, Q):
        # symmetric square root of Q = W^T W = W^2
        ev, V = np.linalg.eigh(Q)
        W = (V * np.sqrt(np.clip(ev, 1e-300, None))) @ V.T
        if self.kind == "sym":
            w = [W[i, j] for i, j in _SYM_IDX]
        elif self.kind == "diag":
            w = list(np.sqrt(np.clip(np.diag(Q), 1e-300, None)))
        else:
            w = [float(np.cbrt(np.prod(np.sqrt(np.clip(ev, 1e-300, None)))))]
        return np.array(w + list(center), float)

    def default_bounds(self, spec_bias=10.0, spec_scale=0.9, spec_alpha=0.5, w_hi=20.0):
        """Wide bounds: hard iron up to spec_bias gauss; W~ up to w_hi per gauss."""
        kd = min(self.kw, 3)
        lo = np.array([1.0 / w_hi] * kd + [-w_hi] * (self.kw - kd) + [-spec_bias] * 3)
        hi = np.array([w_hi] * kd + [w_hi] * (self.kw - kd) + [spec_bias] * 3)
        return lo, hi


def mag_report(model: MagModel, theta: np.ndarray, cov: Optional[np.ndarray] = None
               ) -> Tuple[Dict[str, object], Dict[str, object]]:
    """Physical magnetometer parameters from a unit-sphere fit.

    Returns (params, stderr) with keys ``hard_iron_gauss`` (3), ``soft_iron``
    (W normalised to det 1, upper triangle xx, yy, zz, xy, xz, yz) and
    ``field_gauss`` (F = det(W~)^(-1/3)); corrected readings h = W (m - v) have
    |h| = F.  Standard errors by the delta method (numerical Jacobian of this
    map) when ``cov`` is given.
    """
    def phys(th):
        W = model.matrix(th)
        F = float(np.linalg.det(W)) ** (-1.0 / 3.0)
        Wn = W * F
        return np.array([*th[model.kw:], *[Wn[i, j] for i, j in _SYM_IDX], F])

    theta = np.asarray(theta, float)
    p = phys(theta)
    params = {"hard_iron_gauss": p[0:3].tolist(), "soft_iron": p[3:9].tolist(),
              "field_gauss": float(p[9])}
    stderr: Dict[str, object] = {}
    if cov is not None:
        eps = 1e-7 * np.maximum(1.0, np.abs(theta))
        G = np.zeros((10, theta.size))
        for k in range(theta.size):
            d = np.zeros_like(theta)
            d[k] = eps[k]
            G[:, k] = (phys(theta + d) - phys(theta - d)) / (2 * eps[k])
        C = G @ cov @ G.T
        sd = np.sqrt(np.clip(np.diag(C), 0, None))
        stderr = {"hard_iron_gauss": sd[0:3].tolist(), "soft_iron": sd[3:9].tolist(),
                  "field_gauss": float(sd[9])}
    return params, stderr
