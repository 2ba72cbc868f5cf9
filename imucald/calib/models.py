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
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

__all__ = [
    "NormModel", "Triangular9", "Full12", "Cosine", "MagModel",
    "get_model", "MODEL_NAMES", "gyro_bias_mean", "gyro_bias_eq6_fitness",
    "mag_report",
]


def _unit_upper_from_off(off: np.ndarray, idx: Sequence[Tuple[int, int]]) -> np.ndarray:
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
        P = int(np.prod(lead)) if lead else 1
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


def _bias_form_jac(dM: np.ndarray, M: np.ndarray, b: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
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


class Triangular9(NormModel):
    """Paper 000: a = T K (a_m - b) with upper-triangular unit T (3 terms)."""

    def __init__(self):
        super().__init__(
            name="triangular9", sensor="accel",
            param_names=["alpha_yz", "alpha_zy", "alpha_zx", "scale_x", "scale_y", "scale_z",
                         "bias_x_g", "bias_y_g", "bias_z_g"],
            groups={"alpha": [0, 1, 2], "scale": [3, 4, 5], "bias_g": [6, 7, 8]})

    @property
    def nominal(self):
        return np.array([0, 0, 0, 1, 1, 1, 0, 0, 0], float)

    @staticmethod
    def matrix(theta):
        theta = np.asarray(theta, float)
        a_yz, a_zy, a_zx = theta[..., 0], theta[..., 1], theta[..., 2]
        S = theta[..., 3:6]
        M = np.zeros(theta.shape[:-1] + (3, 3))
        M[..., 0, 0] = S[..., 0]
        M[..., 0, 1] = a_yz * S[..., 1]
        M[..., 0, 2] = a_zy * S[..., 2]
        M[..., 1, 1] = S[..., 1]
        M[..., 1, 2] = a_zx * S[..., 2]
        M[..., 2, 2] = S[..., 2]
        return M

    def affine(self, theta):
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        b = theta[..., 6:9]
        return M, -np.einsum("...ij,...j->...i", M, b)

    def affine_rows(self, theta):
        # the GA's hot path: [T K | -T K b] built row by row, no (P, 3, 3) temporaries
        a_yz, a_zy, a_zx, s0, s1, s2, b0, b1, b2 = theta.T
        out = np.empty((3, theta.shape[0], 4))
        m01, m02, m12 = a_yz * s1, a_zy * s2, a_zx * s2
        out[0, :, 0] = s0
        out[0, :, 1] = m01
        out[0, :, 2] = m02
        out[0, :, 3] = -(s0 * b0 + m01 * b1 + m02 * b2)
        out[1, :, 0] = 0.0
        out[1, :, 1] = s1
        out[1, :, 2] = m12
        out[1, :, 3] = -(s1 * b1 + m12 * b2)
        out[2, :, 0:2] = 0.0
        out[2, :, 2] = s2
        out[2, :, 3] = -s2 * b2
        return out

    def affine_jac(self, theta):
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        a_yz, a_zy, a_zx = theta[..., 0], theta[..., 1], theta[..., 2]
        S = theta[..., 3:6]
        dM = np.zeros(theta.shape[:-1] + (6, 3, 3))
        dM[..., 0, 0, 1] = S[..., 1]
        dM[..., 1, 0, 2] = S[..., 2]
        dM[..., 2, 1, 2] = S[..., 2]
        dM[..., 3, 0, 0] = 1.0
        dM[..., 4, 0, 1] = a_yz
        dM[..., 4, 1, 1] = 1.0
        dM[..., 5, 0, 2] = a_zy
        dM[..., 5, 1, 2] = a_zx
        dM[..., 5, 2, 2] = 1.0
        return _bias_form_jac(dM, M, theta[..., 6:9])

    def from_ellipsoid(self, center, Q):
        # Q = (TK)^T (TK); the upper Cholesky factor R (R^T R = Q) is exactly T K.
        R = np.linalg.cholesky(Q).T
        S = np.diag(R).copy()
        return np.array([R[0, 1] / S[1], R[0, 2] / S[2], R[1, 2] / S[2], *S, *center], float)

    def default_bounds(self, spec_bias=0.25, spec_scale=0.15, spec_alpha=0.08):
        lo = np.array([-spec_alpha] * 3 + [1 - spec_scale] * 3 + [-spec_bias] * 3)
        hi = np.array([spec_alpha] * 3 + [1 + spec_scale] * 3 + [spec_bias] * 3)
        return lo, hi


_FULL_IDX = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]


class Full12(NormModel):
    """Paper 001: a = T K (a_m - b) with a unit-diagonal T holding 6 misalignment terms.

    Only M^T M (6 numbers) and b are visible to a norm fitness; the three
    directions that rotate the corrected frame are unobservable.
    """

    def __init__(self):
        super().__init__(
            name="full12", sensor="accel",
            param_names=["m_xy", "m_xz", "m_yx", "m_yz", "m_zx", "m_zy",
                         "scale_x", "scale_y", "scale_z", "bias_x_g", "bias_y_g", "bias_z_g"],
            groups={"misalignment": list(range(6)), "scale": [6, 7, 8], "bias_g": [9, 10, 11]})

    @property
    def nominal(self):
        return np.array([0] * 6 + [1, 1, 1] + [0, 0, 0], float)

    @staticmethod
    def matrix(theta):
        theta = np.asarray(theta, float)
        T = _unit_upper_from_off(theta[..., 0:6], _FULL_IDX)
        return T * theta[..., None, 6:9]

    def affine(self, theta):
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        return M, -np.einsum("...ij,...j->...i", M, theta[..., 9:12])

    def affine_jac(self, theta):
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        T = _unit_upper_from_off(theta[..., 0:6], _FULL_IDX)
        S = theta[..., 6:9]
        dM = np.zeros(theta.shape[:-1] + (9, 3, 3))
        for k, (i, j) in enumerate(_FULL_IDX):
            dM[..., k, i, j] = S[..., j]
        for j in range(3):
            dM[..., 6 + j, :, j] = T[..., :, j]
        return _bias_form_jac(dM, M, theta[..., 9:12])

    def unobservable_directions(self, theta):
        """The 3 tangent directions of M -> (I + [w]x) M, expressed in theta.

        With M = T K: dS_j = dM_jj and dT_ij = (dM_ij - T_ij dS_j) / S_j.
        """
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        T = _unit_upper_from_off(theta[0:6], _FULL_IDX)
        S = theta[6:9]
        out = []
        for axis in range(3):
            w = np.zeros(3)
            w[axis] = 1.0
            W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
            dM = W @ M
            d = np.zeros(12)
            dS = np.diag(dM).copy()
            d[6:9] = dS
            for k, (i, j) in enumerate(_FULL_IDX):
                d[k] = (dM[i, j] - T[i, j] * dS[j]) / S[j]
            out.append(d / np.linalg.norm(d))
        return np.array(out)

    def canonical(self, theta):
        """Gauge-fix to the triangular representative: the rotation R with R M upper
        triangular (QR of M), so that m_yx = m_zx = m_zy = 0.  Same M^T M, same b."""
        theta = np.asarray(theta, float)
        flat = theta.reshape(-1, 12)
        out = flat.copy()
        for i, th in enumerate(flat):
            M = self.matrix(th)
            _, Rm = np.linalg.qr(M)
            Rm = Rm * np.sign(np.diag(Rm))[:, None]     # positive diagonal
            S = np.diag(Rm).copy()
            out[i, 0:6] = [Rm[0, 1] / S[1], Rm[0, 2] / S[2], 0.0, Rm[1, 2] / S[2], 0.0, 0.0]
            out[i, 6:9] = S
        return out.reshape(theta.shape)

    def from_ellipsoid(self, center, Q):
        t9 = Triangular9().from_ellipsoid(center, Q)
        th = self.nominal.copy()
        th[0], th[1], th[3] = t9[0], t9[1], t9[2]
        th[6:9] = t9[3:6]
        th[9:12] = t9[6:9]
        return th

    def default_bounds(self, spec_bias=0.25, spec_scale=0.15, spec_alpha=0.08):
        lo = np.array([-spec_alpha] * 6 + [1 - spec_scale] * 3 + [-spec_bias] * 3)
        hi = np.array([spec_alpha] * 6 + [1 + spec_scale] * 3 + [spec_bias] * 3)
        return lo, hi


#: Cosine-model parameter subsets (paper 002, Table I): name -> groups that are free.
COSINE_SUBSETS = {
    "o": ("offsets",), "s": ("scales",), "os": ("offsets", "scales"),
    "om": ("offsets", "misalignment"), "sm": ("scales", "misalignment"),
    "osm": ("offsets", "scales", "misalignment"),
}


class Cosine(NormModel):
    """Paper 002 eqs. 1-5 (offsets added before scaling, misalignment as cosines).

    theta = [o1, o2, o3, s1, s2, s3, a_ZY, a_XZ, a_YZ].

    Note what the model implies: with the scales free, each cos(angle) factor is
    a pure rescaling of one axis and cannot be told apart from the scale, and at
    angle 0 its derivative vanishes.  This is why the paper's Table I finds that
    "misalignment ... almost do not have any effect".  The subset fits report
    such parameters as unobservable.
    """

    def __init__(self, subset: str = "osm"):
        if subset not in COSINE_SUBSETS:
            raise ValueError(f"cosine subset {subset!r}: allowed {sorted(COSINE_SUBSETS)}")
        idx = {"offsets": [0, 1, 2], "scales": [3, 4, 5], "misalignment": [6, 7, 8]}
        free = np.zeros(9, bool)
        for g in COSINE_SUBSETS[subset]:
            free[idx[g]] = True
        super().__init__(
            name="cosine" if subset == "osm" else f"cosine-{subset}", sensor="accel",
            param_names=["offset_x_g", "offset_y_g", "offset_z_g", "scale_x", "scale_y", "scale_z",
                         "angle_zy_rad", "angle_xz_rad", "angle_yz_rad"],
            groups={"offset_g": [0, 1, 2], "scale": [3, 4, 5], "angle_rad": [6, 7, 8]},
            free=free)
        self.subset = subset

    @property
    def nominal(self):
        return np.array([0, 0, 0, 1, 1, 1, 0, 0, 0], float)

    def affine(self, theta):
        theta = np.asarray(theta, float)
        o, s, a = theta[..., 0:3], theta[..., 3:6], theta[..., 6:9]
        C = np.stack([np.ones_like(a[..., 0]), np.cos(a[..., 0]),
                      np.cos(a[..., 1]) * np.cos(a[..., 2])], axis=-1)
        A = np.zeros(theta.shape[:-1] + (3, 3))
        for i in range(3):
            A[..., i, i] = s[..., i] * C[..., i]
        return A, s * o

    def affine_jac(self, theta):
        theta = np.asarray(theta, float)
        o, s, a = theta[..., 0:3], theta[..., 3:6], theta[..., 6:9]
        c0, c1, c2 = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
        C = np.stack([np.ones_like(c0), c0, c1 * c2], axis=-1)
        dA = np.zeros(theta.shape[:-1] + (9, 3, 3))
        dc = np.zeros(theta.shape[:-1] + (9, 3))
        for i in range(3):
            dc[..., i, i] = s[..., i]           # d(s o)/do
            dc[..., 3 + i, i] = o[..., i]       # d(s o)/ds
            dA[..., 3 + i, i, i] = C[..., i]    # d(s C)/ds
        dA[..., 6, 1, 1] = -s[..., 1] * np.sin(a[..., 0])
        dA[..., 7, 2, 2] = -s[..., 2] * np.sin(a[..., 1]) * c2
        dA[..., 8, 2, 2] = -s[..., 2] * c1 * np.sin(a[..., 2])
        return dA, dc

    def from_ellipsoid(self, center, Q):
        # Diagonal approximation: s_i = sqrt(Q_ii), o = -center (offset before scaling).
        th = self.nominal.copy()
        if self.free_mask[3]:
            th[3:6] = np.sqrt(np.clip(np.diag(Q), 1e-12, None))
        if self.free_mask[0]:
            th[0:3] = -np.asarray(center)
        return th

    def default_bounds(self, spec_bias=0.25, spec_scale=0.15, spec_alpha=0.08):
        lo = np.array([-spec_bias] * 3 + [1 - spec_scale] * 3 + [-spec_alpha] * 3)
        hi = np.array([spec_bias] * 3 + [1 + spec_scale] * 3 + [spec_alpha] * 3)
        return lo, hi


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
        return _bias_form_jac(dM, W, theta[..., self.kw:])

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


MODEL_NAMES = ["triangular9", "full12", "cosine", "cosine-o", "cosine-s", "cosine-os",
               "cosine-om", "cosine-sm", "mag_sym", "mag_diag", "mag_sphere"]


def get_model(name: str) -> NormModel:
    """Model by name; raises ValueError naming the allowed values."""
    if name == "triangular9":
        return Triangular9()
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


def gyro_bias_eq6_fitness(bias_dps: np.ndarray, samples_dps: np.ndarray) -> np.ndarray:
    """Paper 002 eq. 6, averaged over samples: mean of (|X'-b1| + |Y'-b2| + |Z'-b3|)^2.

    bias_dps (..., 3), samples_dps (N, 3) -> (...,).
    """
    b = np.asarray(bias_dps, float)
    s = np.asarray(samples_dps, float)
    e = np.abs(s[None, :, :] - b.reshape(-1, 1, 3)).sum(-1)
    return (e ** 2).mean(-1).reshape(b.shape[:-1])
