"""The affine norm-model base class (see :mod:`imucald.fitting.models.registry` for the models).

A model is affine in the measurement, h = A(theta) x + c(theta); this class gives
the forward and inverse maps, residuals, analytic Jacobians and the population
fitness once for every model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

__all__ = ["NormModel", "bias_form_jac", "unit_upper_from_off"]


def unit_upper_from_off(off: np.ndarray, idx: Sequence[Tuple[int, int]]) -> np.ndarray:
    shape = off.shape[:-1]
    T = np.zeros(shape + (3, 3))
    T[..., 0, 0] = T[..., 1, 1] = T[..., 2, 2] = 1.0
    for k, (i, j) in enumerate(idx):
        T[..., i, j] = off[..., k]
    return T


@dataclass
class NormModel:
    """Base class: an affine correction ``h = A x + c`` fitted to a known norm."""

    name: str = ""
    sensor: str = "accel"
    param_names: List[str] = field(default_factory=list)
    #: reporting groups: name (unit in the name) -> indices into theta
    groups: Dict[str, List[int]] = field(default_factory=dict)
    #: parameter mask for subset fits: True = free, False = held at ``nominal``
    free: Optional[np.ndarray] = None

    # -- to be provided by subclasses -------------------------------------------------
    def affine(self, theta: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Return A (..., 3, 3) and c (..., 3) for parameters theta (..., k)."""
        raise NotImplementedError

    def affine_jac(self, theta: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Return dA/dtheta (..., k, 3, 3) and dc/dtheta (..., k, 3)."""
        raise NotImplementedError

    @property
    def nominal(self) -> np.ndarray:
        """The parameter vector of an ideal sensor (identity correction)."""
        raise NotImplementedError

    # -- generic machinery -------------------------------------------------------------
    @property
    def k(self) -> int:
        return len(self.param_names)

    @property
    def free_mask(self) -> np.ndarray:
        return np.ones(self.k, bool) if self.free is None else np.asarray(self.free, bool)

    def forward(self, theta: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """Measured -> corrected.  theta (..., k), raw (N, 3) -> (..., N, 3)."""
        A, c = self.affine(np.asarray(theta, float))
        raw = np.asarray(raw, float)
        return np.einsum("...ij,nj->...ni", A, raw) + c[..., None, :]

    def inverse(self, theta: np.ndarray, true: np.ndarray) -> np.ndarray:
        """True (corrected-frame) -> measured.  theta (..., k), true (N, 3) -> (..., N, 3)."""
        A, c = self.affine(np.asarray(theta, float))
        Ainv = np.linalg.inv(A)
        d = np.asarray(true, float) - c[..., None, :]
        return np.einsum("...ij,...nj->...ni", Ainv, d)

    def norms(self, theta: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """|h| for every pose and every parameter vector: (..., N).

        Uses one BLAS matrix product over the whole population, which is what
        makes the GA's fitness cheap.
        """
        theta = np.asarray(theta, float)
        lead = theta.shape[:-1]
        raw = np.asarray(raw, float)
        # [A | c] rows grouped by output axis, (3*P, 4) @ [x, 1]^T (4, N): one BLAS call
        # for the whole population, giving h as three contiguous (P, N) blocks
        P = math.prod(lead) if lead else 1
        Ac = self.affine_rows(theta.reshape(P, -1)).reshape(3 * P, 4)
        xh = np.concatenate([raw, np.ones((len(raw), 1))], axis=1)
        h = (Ac @ xh.T).reshape(3, P, len(raw))
        np.multiply(h, h, out=h)
        n = h[0]
        n += h[1]
        n += h[2]
        np.sqrt(n, out=n)
        return n.reshape(lead + (len(raw),))

    def affine_rows(self, theta: np.ndarray) -> np.ndarray:
        """[A | c] for a population theta (P, k), laid out by output row: (3, P, 4)."""
        A, c = self.affine(theta)
        return np.concatenate([A, c[..., None]], axis=-1).transpose(1, 0, 2)

    def residual(self, theta: np.ndarray, raw: np.ndarray, target: float = 1.0) -> np.ndarray:
        """r = target - |h|, shape (..., N)."""
        return target - self.norms(theta, raw)

    def fitness(self, theta: np.ndarray, raw: np.ndarray, target: float = 1.0,
                weights: Optional[np.ndarray] = None) -> np.ndarray:
        """Paper 000 eq. 5: sum over poses of (target - |h_i|)^2, optionally weighted."""
        r = self.residual(theta, raw, target)
        if weights is None:
            return np.einsum("...n,...n->...", r, r)
        return np.einsum("...n,...n,n->...", r, r, weights)

    def jacobian(self, theta: np.ndarray, raw: np.ndarray, target: float = 1.0
                 ) -> Tuple[np.ndarray, np.ndarray]:
        """Residual and its analytic Jacobian.

        theta (..., k), raw (N, 3) -> r (..., N), J (..., N, k) with J = dr/dtheta.
        """
        theta = np.asarray(theta, float)
        raw = np.asarray(raw, float)
        A, c = self.affine(theta)
        h = np.einsum("...ij,nj->...ni", A, raw) + c[..., None, :]
        nh = np.linalg.norm(h, axis=-1)
        u = h / np.maximum(nh, 1e-300)[..., None]
        dA, dc = self.affine_jac(theta)
        # dh/dtheta_k = dA_k x + dc_k  -> (..., N, k, 3)
        dh = np.einsum("...kij,nj->...nki", dA, raw) + dc[..., None, :, :]
        J = -np.einsum("...ni,...nki->...nk", u, dh)
        return target - nh, J

    def unobservable_directions(self, theta: np.ndarray) -> np.ndarray:
        """Analytic directions of parameter space that no norm data can observe.

        Returns an (m, k) array of unit vectors (m = 0 for identifiable models).
        """
        return np.zeros((0, self.k))

    def canonical(self, theta: np.ndarray) -> np.ndarray:
        """The representative of theta's equivalence class under unobservable moves.

        Identity for identifiable models.  Averaging solutions (paper 000's 20 runs)
        is only meaningful after mapping them to one gauge.
        """
        return np.asarray(theta, float)

    def from_ellipsoid(self, center: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """An initial guess from an algebraic ellipsoid fit (x-c)^T Q (x-c) = 1.

        Q = A^T A for the correction matrix A.  Models that cannot use it return
        :attr:`nominal`.
        """
        return self.nominal.copy()

    def unpack(self, theta: np.ndarray) -> Dict[str, object]:
        """Split a flat parameter vector into the named, unit-carrying groups."""
        theta = np.asarray(theta, float)
        return {g: theta[idx].tolist() for g, idx in self.groups.items()}

    def default_bounds(self, spec_bias: float = 0.25, spec_scale: float = 0.15,
                       spec_alpha: float = 0.08) -> Tuple[np.ndarray, np.ndarray]:
        """Search bounds, centred on the nominal parameters."""
        raise NotImplementedError


def bias_form_jac(dM: np.ndarray, M: np.ndarray, b: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """For h = M (x - b) with theta = [m-params..., b]: assemble dA, dc.

    dM: (..., km, 3, 3) derivative of M w.r.t. its own parameters.
    Returns dA (..., km+3, 3, 3), dc (..., km+3, 3).
    """
    lead = M.shape[:-2]
    km = dM.shape[-3]
    dA = np.zeros(lead + (km + 3, 3, 3))
    dA[..., :km, :, :] = dM
    dc = np.zeros(lead + (km + 3, 3))
    dc[..., :km, :] = -np.einsum("...kij,...j->...ki", dM, b)
    dc[..., km:, :] = -np.swapaxes(M, -1, -2)  # dc/db_j = -M[:, j]
    return dA, dc
