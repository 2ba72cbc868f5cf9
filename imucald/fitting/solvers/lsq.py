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
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from ...numerics.rng import RngLike

from ...numerics import allocator
from ..models.base import NormModel

__all__ = ["Problem", "OptimResult", "lm", "lm_converge", "lm_converge_rows", "lm_steps",
           "closed_form_starts", "sphere_fit", "ellipsoid_fit", "optim_result"]




@dataclass(eq=False)
class Problem:
    """A norm-fit problem: model, pose means (N, 3), target norm, weights, bounds and an
    optional Gaussian prior on the free parameters (module doc)."""

    model: NormModel
    raw: np.ndarray
    target: float = 1.0
    weights: Optional[np.ndarray] = None
    lo: Optional[np.ndarray] = None        #: bounds on the free parameters
    hi: Optional[np.ndarray] = None
    prior_mean: Optional[np.ndarray] = None  #: (kf,) prior mean of the free parameters
    prior_std: Optional[np.ndarray] = None   #: (kf,) prior std; inf = no prior on that one
    noise_var: float = 1.0                   #: data residual variance (sensor unit^2)

    def __post_init__(self):
        allocator.tune()
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
        self._pw = None                      # sqrt(noise_var) / prior_std, 0 where no prior
        if self.prior_std is not None:
            ps = np.asarray(self.prior_std, float)
            if ps.shape != self.lo.shape or np.any(ps <= 0):
                raise ValueError("prior_std: one positive value per free parameter (inf = none)")
            self.prior_mean = np.asarray(self.prior_mean, float)
            pw = np.where(np.isfinite(ps), np.sqrt(self.noise_var) / np.where(np.isfinite(ps), ps, 1.0), 0.0)
            self._pw = pw if np.any(pw > 0) else None

    @property
    def has_prior(self) -> bool:
        return self._pw is not None

    def without_prior(self) -> "Problem":
        """The same problem with the prior removed (ga-paper: the paper's own fitness)."""
        return dataclasses.replace(self, prior_mean=None, prior_std=None)

    def prior_precision(self) -> np.ndarray:
        """(kf,) prior precision 1/prior_std^2 (0 where there is no prior)."""
        if self.prior_std is None:
            return np.zeros(self.kf)
        ps = np.asarray(self.prior_std, float)
        return np.where(np.isfinite(ps), 1.0 / ps ** 2, 0.0)

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

    def data_fitness(self, z: np.ndarray) -> np.ndarray:
        """The (weighted) sum of squared norm residuals alone, paper 000 eq. 5."""
        return self.model.fitness(self.expand(np.asarray(z, float)), self.raw, self.target,
                                  self.weights)

    def fitness(self, z: np.ndarray) -> np.ndarray:
        """The objective: data sum of squares plus the prior term (module doc)."""
        z = np.asarray(z, float)
        self.nfev += math.prod(z.shape[:-1]) if z.ndim > 1 else 1
        f = self.model.fitness(self.expand(z), self.raw, self.target, self.weights)
        if self._pw is not None:
            p = (z - self.prior_mean) * self._pw
            f = f + np.einsum("...k,...k->...", p, p)
        return f

    def rj(self, z: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Weighted residual and Jacobian over the free parameters; with a prior, its
        pseudo-observations are appended (kf extra rows)."""
        z = np.asarray(z, float)
        r, J = self.model.jacobian(self.expand(z), self.raw, self.target)
        J = J[..., self.free]
        if self._sw is not None:
            r = r * self._sw
            J = J * self._sw[:, None]
        if self._pw is not None:
            rp = (z - self.prior_mean) * self._pw
            Jp = np.broadcast_to(np.diag(self._pw), z.shape[:-1] + (self.kf, self.kf))
            r = np.concatenate([r, rp], axis=-1)
            J = np.concatenate([J, Jp], axis=-2)
        return r, J

    def at_bound(self, z: np.ndarray) -> np.ndarray:
        """(kf,) True where z sits on a search bound (within 1e-9 of the box width)."""
        z = np.asarray(z, float)
        tol = 1e-9 * np.maximum(self.hi - self.lo, 1e-300)
        return (z <= self.lo + tol) | (z >= self.hi - tol)

    def clip(self, z: np.ndarray) -> np.ndarray:
        return np.clip(z, self.lo, self.hi)


@dataclass(eq=False)
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
    #: sqrt(diag((J'J / s^2 + prior precision)^+)) with s^2 = data SSR / (N - k_free);
    #: 0 for fixed parameters, inf for parameters neither poses nor prior inform
    stderr: Optional[np.ndarray] = None
    #: the data sum of squares alone (``fitness`` includes the prior term when there is one)
    data_fitness: float = float("nan")
    #: (k,) True for a parameter that ended on a search bound (always reported)
    at_bound: Optional[np.ndarray] = None

    def __post_init__(self):
        self.theta = np.asarray(self.theta, float)


def optim_result(prob: "Problem", z: np.ndarray, fitness: float, iterations: int, method: str,
            info: Dict[str, object]) -> "OptimResult":
    nfev = prob.nfev
    dfit = float(prob.data_fitness(z))
    ab = np.zeros(prob.model.k, bool)
    ab[prob.free] = prob.at_bound(z)
    return OptimResult(prob.expand(z), float(fitness), int(iterations), method, nfev, info,
                       _stderr(prob, z, dfit), dfit, ab)


def _stderr(prob: "Problem", z: np.ndarray, data_fitness: float) -> np.ndarray:
    r, J = prob.model.jacobian(prob.expand(np.asarray(z, float)), prob.raw, prob.target)
    J = J[:, prob.free]
    if prob._sw is not None:
        J = J * prob._sw[:, None]
    N, kf = J.shape
    s2 = max(data_fitness / max(N - kf, 1), 1e-300)
    lam = prob.prior_precision()
    H = J.T @ J / s2 + np.diag(lam)
    sd = np.zeros(prob.model.k)
    sd[prob.free] = np.sqrt(np.clip(np.diag(np.linalg.pinv(H, rcond=1e-12, hermitian=True)), 0, None))
    dead = (np.linalg.norm(J, axis=0) <= 1e-12 * max(np.linalg.norm(J, axis=0).max(), 1e-300)) & (lam == 0)
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


def closed_form_starts(prob: Problem) -> List[np.ndarray]:
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

def lm_steps(prob: Problem, Z: np.ndarray, f: np.ndarray, mu: np.ndarray, n: int,
             cache: Optional[dict] = None) -> Tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """n projected LM iterations on a batch Z (B, kf).  Returns Z, f, mu, iterations.

    A rejected step leaves Z as it was (the same array), and the gradient and Gauss-Newton
    matrix at Z are then reused rather than computed again (the same numbers: over half of
    the steps of a leave-one-pose-out refit are rejected ones); ``cache`` carries them from
    one call to the next."""
    kf = Z.shape[-1]
    eye = np.eye(kf)
    it = 0
    cache = {} if cache is None else cache
    for it in range(1, n + 1):
        if cache.get("Z") is Z:
            g, H, d = cache["gHd"]
        else:
            g, H, d = _gauss_newton(prob, Z)
            cache["Z"], cache["gHd"] = Z, (g, H, d)
        Hd = _damped(H, d, mu, eye)
        try:
            step = -np.linalg.solve(Hd, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -np.einsum("bkl,bl->bk", np.linalg.pinv(Hd), g)
        Zc = prob.clip(Z + step)
        fc = prob.fitness(Zc)
        ok = fc < f
        if ok.any():                      # else Z and f stay (the same arrays, the same values)
            Z = np.where(ok[:, None], Zc, Z)
            f = np.where(ok, fc, f)
        mu = _next_damping(mu, ok)
    return Z, f, mu, it


def _gauss_newton(prob: Problem, Z: np.ndarray):
    """(gradient J'r (B, kf), Gauss-Newton matrix J'J (B, kf, kf), its diagonal (B, kf)) at each
    row of Z: the one place an LM step forms them (lm_steps, lm_converge_rows)."""
    r, J = prob.rj(Z)                                           # (B, N), (B, N, kf)
    H = np.einsum("bnk,bnl->bkl", J, J)
    return np.einsum("bnk,bn->bk", J, r), H, np.einsum("bkk->bk", H)


def _damped(H: np.ndarray, d: np.ndarray, mu: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """The damped matrix H + mu (diag(d) + 1e-12 max(d) I) of each row."""
    return H + mu[:, None, None] * (d[:, :, None] * eye + 1e-12 * eye * d.max(1)[:, None, None])


def _next_damping(mu: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """mu / 3 after an accepted step (not below 1e-12), x 4 after a rejected one."""
    return np.where(ok, np.maximum(mu / 3.0, 1e-12), mu * 4.0)


def lm_converge(prob: Problem, z0: np.ndarray, max_iter: int = 200, ftol: float = 1e-15
                ) -> Tuple[np.ndarray, float, int]:
    """Projected LM from z0 until a step improves the fitness by <= ftol (relative) with
    the damping above 1e10 or six such steps in a row, or max_iter: (z, fitness, iterations)."""
    Z, f, it = lm_converge_rows(prob, np.asarray(z0, float)[None, :], max_iter, ftol)
    return Z[0], float(f[0]), int(it[0])


def lm_converge_rows(prob: Problem, Z0: np.ndarray, max_iter: int = 200, ftol: float = 1e-15
                     ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`lm_converge` from each row of Z0 (B, kf), the rows run side by side: one
    residual-and-Jacobian and one fitness evaluation per step for the rows still going, where
    one start after the other cost one of each per row and step (the GA's polish runs its
    result and the closed-form starts so: ~50 single-row steps, most of their time numpy's
    per-call overhead).  Each row takes the steps it takes alone, to the bit: every
    operation is row by row (the batched products and solves give each row's own numbers),
    a row whose step was rejected reuses its gradient and Gauss-Newton matrix, and a row
    stops on its own test.  Returns (Z (B, kf), fitness (B,), iterations (B,))."""
    Z = np.array(Z0, float)
    B, kf = Z.shape
    f = prob.fitness(Z)
    mu = np.full(B, 1e-3)
    its = np.zeros(B, int)
    stall = np.zeros(B, int)
    g, H, d = np.empty((B, kf)), np.empty((B, kf, kf)), np.empty((B, kf))
    moved = np.ones(B, bool)                 # g, H, d to be formed at the row's Z
    eye = np.eye(kf)
    go = np.arange(B) if max_iter > 0 else np.zeros(0, int)
    while len(go):
        new = go[moved[go]]
        if len(new):
            g[new], H[new], d[new] = _gauss_newton(prob, Z[new])
            moved[new] = False
        mg, f_old = mu[go], f[go]
        Zc = prob.clip(Z[go] + _lm_step(_damped(H[go], d[go], mg, eye), g[go]))
        fc = prob.fitness(Zc)
        ok = fc < f_old
        Z[go[ok]], f[go[ok]], moved[go[ok]] = Zc[ok], fc[ok], True
        mu[go] = _next_damping(mg, ok)
        its[go] += 1
        flat = (f_old - f[go]) / np.maximum(f_old, 1e-300) <= ftol
        stall[go] = np.where(flat, stall[go] + 1, 0)
        done = flat & ((mu[go] > 1e10) | (stall[go] >= 6) | (f[go] == 0.0))
        go = go[~done & (its[go] < max_iter)]
    return Z, f, its


def _lm_step(Hd: np.ndarray, g: np.ndarray) -> np.ndarray:
    """-Hd^-1 g of each row (B, kf); a row whose damped matrix is singular takes the
    pseudo-inverse's step (row by row then, as each row alone did)."""
    try:
        return -np.linalg.solve(Hd, g[..., None])[..., 0]
    except np.linalg.LinAlgError:
        if len(Hd) > 1:
            return np.concatenate([_lm_step(Hd[i:i + 1], g[i:i + 1]) for i in range(len(Hd))])
        return -np.einsum("bkl,bl->bk", np.linalg.pinv(Hd), g)


def lm(prob: Problem, z0: Optional[np.ndarray] = None, max_iter: int = 200,
       rng: RngLike = None) -> OptimResult:
    """Bounded Levenberg-Marquardt from z0, or from the best of the closed-form starts."""
    prob.nfev = 0
    starts = [np.asarray(z0, float)] if z0 is not None else closed_form_starts(prob)
    best = None
    iters = 0
    for s in starts:
        z, f, it = lm_converge(prob, prob.clip(s), max_iter)
        iters += it
        if best is None or f < best[1]:
            best = (z, f)
    return optim_result(prob, best[0], best[1], iters, "lm", {"starts": len(starts)})
