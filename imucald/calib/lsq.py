"""The norm-fit problem, its closed-form starting points and bounded Levenberg-Marquardt.

A :class:`Problem` may carry a Gaussian prior on the free parameters (the datasheet
tolerances, MAP): the objective is then

    sum_i w_i r_i^2  +  noise_var * sum_j ((z_j - prior_mean_j) / prior_std_j)^2,

i.e. the negative log posterior times ``noise_var`` (the data residual variance), so
that it stays in the units of the plain sum of squares (paper 000 eq. 5) and the
two terms are weighted as Bayes' rule says.  A parameter the poses carry no
information on then stays near its prior instead of running to a search bound.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Union

import numpy as np

from .. import _malloc
from .models import NormModel

__all__ = ["Problem", "OptimResult", "lm", "sphere_fit", "ellipsoid_fit"]

RngLike = Union[int, None, np.random.Generator]


def _rng(rng: RngLike) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


@dataclass
class Problem:
    """A norm-fit problem: model, pose means (N, 3), target norm, weights, bounds."""

    model: NormModel
    raw: np.ndarray
    target: float = 1.0
    weights: Optional[np.ndarray] = None
    lo: Optional[np.ndarray] = None        #: bounds on the free parameters
    hi: Optional[np.ndarray] = None

    def __post_init__(self):
        _malloc.tune()
        self.raw = np.asarray(self.raw, float)
        self.free = self.model.free_mask
        self.base = self.model.nominal.copy()
        if self.lo is None or self.hi is None:
            lo, hi = self.model.default_bounds()
            self.lo = lo[self.free] if self.lo is None else np.asarray(self.lo, float)
            self.hi = hi[self.free] if self.hi is None else np.asarray(self.hi, float)
        self.lo = np.asarray(self.lo, float)
        self.hi = np.asarray(self.hi, float)
        self._sw = None if self.weights is None else np.sqrt(np.asarray(self.weights, float))
        self.nfev = 0
        self._all_free = bool(self.free.all())

    @property
    def kf(self) -> int:
        return int(self.free.sum())

    def expand(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, float)
        if self._all_free:
            return z
        th = np.broadcast_to(self.base, z.shape[:-1] + (self.model.k,)).copy()
        th[..., self.free] = z
        return th

    def reduce(self, theta: np.ndarray) -> np.ndarray:
        return np.asarray(theta, float)[..., self.free]

    def fitness(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, float)
        self.nfev += int(np.prod(z.shape[:-1])) if z.ndim > 1 else 1
        return self.model.fitness(self.expand(z), self.raw, self.target, self.weights)

    def rj(self, z: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Weighted residual and Jacobian over the free parameters."""
        r, J = self.model.jacobian(self.expand(z), self.raw, self.target)
        J = J[..., self.free]
        if self._sw is not None:
            r = r * self._sw
            J = J * self._sw[:, None]
        return r, J

    def clip(self, z: np.ndarray) -> np.ndarray:
        return np.clip(z, self.lo, self.hi)


@dataclass
class OptimResult:
    """What every optimiser returns (free parameters expanded to the full vector).

    """

    theta: np.ndarray
    fitness: float
    iterations: int
    method: str
    nfev: int = 0
    info: Dict[str, object] = field(default_factory=dict)
    #: per-parameter standard error from the fit's own residuals,
    #: sqrt(diag(s^2 (J'J)^+)) with s^2 = fitness / (N - k_free); 0 for fixed
    #: parameters, inf for parameters the poses carry no information on
    stderr: Optional[np.ndarray] = None

    def __post_init__(self):
        self.theta = np.asarray(self.theta, float)


def _result(prob: "Problem", z: np.ndarray, fitness: float, iterations: int, method: str,
            info: Dict[str, object]) -> "OptimResult":
    return OptimResult(prob.expand(z), float(fitness), int(iterations), method, prob.nfev, info,
                       _stderr(prob, z, fitness))


def _stderr(prob: "Problem", z: np.ndarray, fitness: float) -> np.ndarray:
    _, J = prob.rj(z)
    N, kf = J.shape
    s2 = fitness / max(N - kf, 1)
    JtJ = J.T @ J
    sd = np.zeros(prob.model.k)
    sd[prob.free] = np.sqrt(np.clip(np.diag(np.linalg.pinv(JtJ, rcond=1e-12, hermitian=True)), 0, None) * s2)
    dead = np.linalg.norm(J, axis=0) <= 1e-12 * max(np.linalg.norm(J, axis=0).max(), 1e-300)
    sd[np.flatnonzero(prob.free)[dead]] = np.inf
    return sd


# --- closed-form starting points --------------------------------------------------------

def sphere_fit(x: np.ndarray) -> Tuple[np.ndarray, float]:
    """Linear least-squares sphere: |x|^2 = 2 c.x + d.  Returns centre and radius."""
    x = np.asarray(x, float)
    A = np.column_stack([2 * x, np.ones(len(x))])
    y = (x ** 2).sum(1)
    sol, *_ = np.linalg.lstsq(A, y, rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    return c, float(np.sqrt(max(r2, 1e-300)))


def ellipsoid_fit(x: np.ndarray) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """Algebraic ellipsoid fit (x - c)^T Q (x - c) = 1, or None when degenerate.

    Fits the 9 coefficients of x^T P x + q.x = 1 by linear least squares; returns
    None unless P is positive definite (too few or coplanar poses give a
    degenerate quadric).
    """
    x = np.asarray(x, float)
    if len(x) < 9:
        return None
    X, Y, Z = x.T
    D = np.column_stack([X * X, Y * Y, Z * Z, 2 * X * Y, 2 * X * Z, 2 * Y * Z, X, Y, Z])
    sol, _, rank, _ = np.linalg.lstsq(D, np.ones(len(x)), rcond=None)
    if rank < 9:
        return None
    P = np.array([[sol[0], sol[3], sol[4]], [sol[3], sol[1], sol[5]], [sol[4], sol[5], sol[2]]])
    q = sol[6:9]
    try:
        c = -0.5 * np.linalg.solve(P, q)
    except np.linalg.LinAlgError:
        return None
    k = 1.0 + c @ P @ c
    if k <= 0:
        return None
    Q = P / k
    if np.any(np.linalg.eigvalsh(Q) <= 0):
        return None
    return c, Q


def _starts(prob: Problem) -> List[np.ndarray]:
    """Candidate starting points: nominal, sphere fit, ellipsoid fit (when valid)."""
    m = prob.model
    starts = [prob.clip(prob.reduce(m.nominal))]
    try:
        c, r = sphere_fit(prob.raw)
        Q = np.eye(3) / (r * r) * prob.target ** 2
        starts.append(prob.clip(prob.reduce(m.from_ellipsoid(c, Q))))
    except (np.linalg.LinAlgError, ValueError):
        pass
    e = ellipsoid_fit(prob.raw)
    if e is not None:
        c, Q = e
        try:
            starts.append(prob.clip(prob.reduce(m.from_ellipsoid(c, Q * prob.target ** 2))))
        except (np.linalg.LinAlgError, ValueError):
            pass
    return starts


# --- Levenberg-Marquardt ----------------------------------------------------------------

def _lm_steps(prob: Problem, Z: np.ndarray, f: np.ndarray, mu: np.ndarray, n: int
              ) -> Tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """n projected LM iterations on a batch Z (B, kf).  Returns Z, f, mu, iterations."""
    kf = Z.shape[-1]
    eye = np.eye(kf)
    it = 0
    for it in range(1, n + 1):
        r, J = prob.rj(Z)                                   # (B, N), (B, N, kf)
        g = np.einsum("bnk,bn->bk", J, r)
        H = np.einsum("bnk,bnl->bkl", J, J)
        d = np.einsum("bkk->bk", H)
        Hd = H + mu[:, None, None] * (d[:, :, None] * eye + 1e-12 * eye * d.max(1)[:, None, None])
        try:
            step = -np.linalg.solve(Hd, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -np.einsum("bkl,bl->bk", np.linalg.pinv(Hd), g)
        Zc = prob.clip(Z + step)
        fc = prob.fitness(Zc)
        ok = fc < f
        Z = np.where(ok[:, None], Zc, Z)
        f = np.where(ok, fc, f)
        mu = np.where(ok, np.maximum(mu / 3.0, 1e-12), mu * 4.0)
    return Z, f, mu, it


def _lm_converge(prob: Problem, z0: np.ndarray, max_iter: int = 200, ftol: float = 1e-15
                 ) -> Tuple[np.ndarray, float, int]:
    Z = np.asarray(z0, float)[None, :]
    f = prob.fitness(Z)
    mu = np.array([1e-3])
    it_total = 0
    stall = 0
    while it_total < max_iter:
        f_old = f[0]
        Z, f, mu, it = _lm_steps(prob, Z, f, mu, 1)
        it_total += it
        rel = (f_old - f[0]) / max(f_old, 1e-300)
        if rel <= ftol:
            stall += 1
            if mu[0] > 1e10 or stall >= 6 or f[0] == 0.0:
                break
        else:
            stall = 0
    return Z[0], float(f[0]), it_total


def lm(prob: Problem, z0: Optional[np.ndarray] = None, max_iter: int = 200,
       rng: RngLike = None) -> OptimResult:
    """Bounded Levenberg-Marquardt from z0, or from the best of the closed-form starts."""
    prob.nfev = 0
    starts = [np.asarray(z0, float)] if z0 is not None else _starts(prob)
    best = None
    iters = 0
    for s in starts:
        z, f, it = _lm_converge(prob, prob.clip(s), max_iter)
        iters += it
        if best is None or f < best[1]:
            best = (z, f)
    return _result(prob, best[0], best[1], iters, "lm", {"starts": len(starts)})
