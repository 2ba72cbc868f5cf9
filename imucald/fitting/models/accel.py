"""Accelerometer norm models: paper 000's triangular 9, paper 001's full 12, paper 002's
cosine model, and the 6-parameter offset + scale model (model-order selection).

Units: inputs and biases in g; scales, misalignment terms (small angles, rad) dimensionless.
"""
from __future__ import annotations

import numpy as np

from .base import NormModel, bias_form_jac, unit_upper_from_off

__all__ = ["Triangular9", "Diag6", "Full12", "Cosine", "COSINE_SUBSETS"]


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
        return bias_form_jac(dM, M, theta[..., 6:9])

    def from_ellipsoid(self, center, Q):
        # Q = (TK)^T (TK); the upper Cholesky factor R (R^T R = Q) is exactly T K.
        R = np.linalg.cholesky(Q).T
        S = np.diag(R).copy()
        return np.array([R[0, 1] / S[1], R[0, 2] / S[2], R[1, 2] / S[2], *S, *center], float)

    def default_bounds(self, spec_bias=0.25, spec_scale=0.15, spec_alpha=0.08):
        lo = np.array([-spec_alpha] * 3 + [1 - spec_scale] * 3 + [-spec_bias] * 3)
        hi = np.array([spec_alpha] * 3 + [1 + spec_scale] * 3 + [spec_bias] * 3)
        return lo, hi


class Diag6(Triangular9):
    """Offset + scale only (6 parameters): triangular9 with the three non-orthogonality
    terms held at 0.  The lowest order offered by model-order selection."""

    def __init__(self):
        super().__init__()
        self.name = "diag6"
        self.free = np.array([False] * 3 + [True] * 6)


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
        T = unit_upper_from_off(theta[..., 0:6], _FULL_IDX)
        return T * theta[..., None, 6:9]

    def affine(self, theta):
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        return M, -np.einsum("...ij,...j->...i", M, theta[..., 9:12])

    def affine_jac(self, theta):
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        T = unit_upper_from_off(theta[..., 0:6], _FULL_IDX)
        S = theta[..., 6:9]
        dM = np.zeros(theta.shape[:-1] + (9, 3, 3))
        for k, (i, j) in enumerate(_FULL_IDX):
            dM[..., k, i, j] = S[..., j]
        for j in range(3):
            dM[..., 6 + j, :, j] = T[..., :, j]
        return bias_form_jac(dM, M, theta[..., 9:12])

    def unobservable_directions(self, theta):
        """The 3 tangent directions of M -> (I + [w]x) M, expressed in theta.

        With M = T K: dS_j = dM_jj and dT_ij = (dM_ij - T_ij dS_j) / S_j.
        """
        theta = np.asarray(theta, float)
        M = self.matrix(theta)
        T = unit_upper_from_off(theta[0:6], _FULL_IDX)
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
