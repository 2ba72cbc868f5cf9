"""Optimisers for the norm fitness: ga-paper, hga, lm and the daemon's light ga.

All are seedable (``rng``: a seed or a numpy Generator), keep every candidate
inside the box bounds, and return :class:`OptimResult`.  They work on the free
parameters of a :class:`Problem`; fixed parameters stay at the model's nominal.

``ga-paper``  Marinov & Petrov 2019 as written: population 200 in 2 subpopulations
    (20 % forward migration every 20 generations, MATLAB's default interval), elite 2,
    crossover fraction 0.8, rank fitness scaling (1/sqrt(rank)), stochastic-uniform
    selection, scattered crossover, and a Gaussian mutation whose scale shrinks
    linearly to zero over the generation limit (MATLAB's mutationgaussian, scale 1,
    shrink 1) made feasible by redrawing an out-of-bounds coordinate uniformly
    between the parent and the violated bound.  Stop at 150 generations or when the
    mean relative change of the best fitness over 50 generations is <= 1e-10.
    20 independent runs (vectorised: one population array holds them all) are
    averaged; 3 iterations, bounds narrowed to mean +- 5 sigma, then +- 15 sigma.
``hga``  Kim et al. 2023: population 300, tournament selection (size 2), arithmetic
    crossover, real-valued Gaussian mutation, (mu + lambda) reproduction, stop at 200
    generations or 70 generations whose best improved by < 1e-15 (relative).  The
    paper refines individuals with SQP; here each generation's best 10 % are refined
    by two steps of the bounded Levenberg-Marquardt below (analytic Jacobian) and
    written back (Lamarckian), and the final best is polished to convergence.
``lm``  projected Levenberg-Marquardt with the analytic Jacobian, numpy only,
    started from the nominal parameters, a sphere fit and an algebraic ellipsoid
    fit; the best end point wins.
``ga``  the daemon's default: one run of the ga-paper operators with a smaller
    budget (population 100, 60 generations), polished by ``lm``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple, Union

import numpy as np

from .. import _malloc
from .models import NormModel

__all__ = ["Problem", "OptimResult", "lm", "ga_paper", "hga", "ga", "METHODS", "run_method",
           "sphere_fit", "ellipsoid_fit"]

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


# --- MATLAB-style GA (paper 000), vectorised over independent runs ----------------------

def _ga_core(prob: Problem, lo: np.ndarray, hi: np.ndarray, runs: int, rng: np.random.Generator,
             pop: int = 200, nsub: int = 2, elite: int = 2, xfrac: float = 0.8,
             mig_frac: float = 0.2, mig_interval: int = 20, max_gen: int = 150,
             stall_gen: int = 50, tol: float = 1e-10, mut_scale: float = 1.0,
             mut_shrink: float = 1.0, progress: Optional[Callable[[int, np.ndarray], None]] = None
             ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run ``runs`` independent GAs at once.  Returns best z (R, kf), best f (R,), generations (R,)."""
    kf = lo.size
    Ps = pop // nsub
    span = hi - lo
    X = lo + rng.random((runs, nsub, Ps, kf)) * span
    F = prob.fitness(X)
    n_x = int(round(xfrac * (Ps - elite)))
    n_m = Ps - elite - n_x
    n_par = 2 * n_x + n_m
    w = 1.0 / np.sqrt(np.arange(1, Ps + 1))
    cw = np.cumsum(w) / w.sum()
    n_mig = max(1, int(round(mig_frac * Ps)))
    hist = np.full((max_gen + 1, runs), np.inf)
    stopped = np.zeros(runs, bool)
    stop_gen = np.full(runs, max_gen)
    best_z = np.zeros((runs, kf))
    best_f = np.full(runs, np.inf)
    # flat views: row (run, subpop) offsets turn per-row indices into flat ones
    rows = runs * nsub
    base = (np.arange(rows) * Ps)[:, None]
    ar = np.arange(runs)
    gen = 0
    for gen in range(max_gen):
        Xf = X.reshape(rows * Ps, kf)
        Ff = F.reshape(rows, Ps)
        order = np.argsort(Ff, axis=1)                      # ranks, best first
        # record the best of each run
        top = Ff[np.arange(rows), order[:, 0]].reshape(runs, nsub)
        sb = top.argmin(1)
        fb = top[ar, sb]
        zb = Xf[(base[:, 0].reshape(runs, nsub)[ar, sb] + order.reshape(runs, nsub, Ps)[ar, sb, 0])]
        upd = ~stopped
        best_f = np.where(upd, fb, best_f)
        best_z = np.where(upd[:, None], zb, best_z)
        hist[gen] = best_f
        if progress is not None:
            progress(gen, best_f)
        if gen >= stall_gen:
            old = hist[gen - stall_gen]
            rel = (old - best_f) / np.maximum(np.abs(best_f), 1e-300) / stall_gen
            newly = (~stopped) & (rel <= tol)
            stop_gen[newly] = gen
            stopped |= newly
            if stopped.all():
                break
        # stochastic-uniform selection on rank-scaled fitness
        pos = (rng.random((rows, 1)) + np.arange(n_par)) / n_par
        rk = np.minimum(np.searchsorted(cw, pos), Ps - 1)
        rk = rng.permuted(rk, axis=-1)
        pidx = np.take_along_axis(order, rk, axis=1) + base
        par = Xf[pidx]                                      # (rows, n_par, kf)
        p1, p2, pm = par[:, :n_x], par[:, n_x:2 * n_x], par[:, 2 * n_x:]
        xo = np.where(rng.integers(0, 2, p1.shape, dtype=bool), p1, p2)  # scattered crossover
        sig = mut_scale * max(0.0, 1.0 - mut_shrink * gen / max_gen) * span
        mu = pm + rng.standard_normal(pm.shape) * sig
        bad = (mu < lo) | (mu > hi)
        if bad.any():  # redraw between the parent and the violated bound: stays feasible
            bound = np.where(mu < lo, lo, hi)
            mu = np.where(bad, pm + rng.random(mu.shape) * (bound - pm), mu)
        eidx = order[:, :elite] + base
        children = np.concatenate([xo, mu], axis=1)
        Fc = prob.fitness(children)
        X = np.concatenate([Xf[eidx], children], axis=1)
        F = np.concatenate([Ff[np.arange(rows)[:, None], order[:, :elite]], Fc], axis=1)
        if nsub > 1 and (gen + 1) % mig_interval == 0:   # forward migration: best replace worst
            o2 = np.argsort(F, axis=1)
            bi = o2[:, :n_mig].reshape(runs, nsub, n_mig)
            wi = o2[:, Ps - n_mig:].reshape(runs, nsub, n_mig)
            X4 = X.reshape(runs, nsub, Ps, kf)
            F3 = F.reshape(runs, nsub, Ps)
            mX = np.roll(np.take_along_axis(X4, bi[..., None], axis=2), 1, axis=1)
            mF = np.roll(np.take_along_axis(F3, bi, axis=2), 1, axis=1)
            np.put_along_axis(X4, wi[..., None], mX, axis=2)
            np.put_along_axis(F3, wi, mF, axis=2)
        X = X.reshape(runs, nsub, Ps, kf)
        F = F.reshape(runs, nsub, Ps)
    flat = F.reshape(runs, -1)
    ib = flat.argmin(1)
    fb = flat[ar, ib]
    zb = X.reshape(runs, -1, kf)[ar, ib]
    upd = (~stopped) & (fb < best_f)
    best_f = np.where(upd, fb, best_f)
    best_z = np.where(upd[:, None], zb, best_z)
    stop_gen = np.where(stopped, stop_gen, gen + 1)
    return best_z, best_f, stop_gen


def ga_paper(prob: Problem, rng: RngLike = None, runs: int = 20, iterations: int = 3,
             narrow=(5.0, 15.0), progress: Optional[Callable[[str], None]] = None,
             **ga_kw) -> OptimResult:
    """Paper 000's full protocol: 20 averaged runs, 3 iterations with narrowed bounds."""
    rng = _rng(rng)
    prob.nfev = 0
    lo, hi = prob.lo.copy(), prob.hi.copy()
    per_iter = []
    gens = 0
    mean = None
    for it in range(iterations):
        z, f, g = _ga_core(prob, lo, hi, runs, rng, **ga_kw)
        gens += int(g.sum())
        if type(prob.model).canonical is not NormModel.canonical:
            # average in one gauge (full12's rotation freedom), inside the bounds
            z = prob.clip(prob.reduce(prob.model.canonical(prob.expand(z))))
        mean = z.mean(0)
        sd = z.std(0, ddof=1) if runs > 1 else np.zeros_like(mean)
        per_iter.append({"theta": prob.expand(mean), "run_std": sd.copy(),
                         "fitness": float(prob.fitness(mean)), "generations": g.tolist()})
        if progress is not None:
            progress(f"ga-paper iteration {it + 1}/{iterations}: {runs} runs, "
                     f"fitness of the mean {per_iter[-1]['fitness']:.4g}")
        if it + 1 < iterations:
            k = narrow[min(it, len(narrow) - 1)]
            half = np.maximum(k * sd, 1e-12 * np.maximum(1.0, np.abs(mean)))
            lo = np.maximum(prob.lo, mean - half)
            hi = np.minimum(prob.hi, mean + half)
    fit = float(prob.fitness(mean))
    return _result(prob, mean, fit, gens, "ga-paper", {"iterations": per_iter, "runs": runs})


def ga(prob: Problem, rng: RngLike = None, pop: int = 100, max_gen: int = 60,
       stall_gen: int = 20, progress: Optional[Callable[[int, np.ndarray], None]] = None
       ) -> OptimResult:
    """The daemon's light GA (paper 000 operators, one run) polished by LM."""
    rng = _rng(rng)
    prob.nfev = 0
    z, f, g = _ga_core(prob, prob.lo, prob.hi, 1, rng, pop=pop, max_gen=max_gen,
                       stall_gen=stall_gen, mig_interval=10, progress=progress)
    zp, fp, it = _lm_converge(prob, z[0])
    # the closed-form starts are polished too, so the GA can only add to what lm finds
    ga_won = True
    for s in _starts(prob):
        zs, fs, its = _lm_converge(prob, s)
        it += its
        if fs < fp:
            zp, fp, ga_won = zs, fs, False
    return _result(prob, zp, fp, int(g[0]) + it, "ga",
                       {"ga_fitness": float(f[0]), "ga_generations": int(g[0]), "lm_iterations": it,
                        "ga_start_won": ga_won})


def hga(prob: Problem, rng: RngLike = None, pop: int = 300, max_gen: int = 200,
        stall_gen: int = 70, tol: float = 1e-15, pc: float = 0.8, pm: float = 0.1,
        refine_frac: float = 0.1, refine_steps: int = 2) -> OptimResult:
    """Paper 001's hybrid GA with a bounded-LM local step (see module doc)."""
    rng = _rng(rng)
    prob.nfev = 0
    lo, hi = prob.lo, prob.hi
    span = hi - lo
    kf = lo.size
    X = lo + rng.random((pop, kf)) * span
    F = prob.fitness(X)
    n_ref = max(1, int(round(refine_frac * pop)))
    hist = []
    gen = 0
    for gen in range(max_gen):
        # tournament selection (size 2)
        a = rng.integers(0, pop, (2, pop))
        win = np.where(F[a[0]] <= F[a[1]], a[0], a[1])
        P = X[win]
        # arithmetic crossover on consecutive pairs
        half = pop // 2
        p1, p2 = P[:half], P[half:2 * half]
        lam = rng.random((half, 1))
        do = rng.random((half, 1)) < pc
        c1 = np.where(do, lam * p1 + (1 - lam) * p2, p1)
        c2 = np.where(do, (1 - lam) * p1 + lam * p2, p2)
        C = np.concatenate([c1, c2, P[2 * half:]], axis=0)
        # real-valued mutation, shrinking scale
        m = rng.random(C.shape) < pm
        sig = 0.1 * span * (1.0 - gen / max_gen)
        C = np.where(m, C + rng.standard_normal(C.shape) * sig, C)
        C = np.clip(C, lo, hi)
        FC = prob.fitness(C)
        # local refinement of the best children (Lamarckian)
        top = np.argsort(FC)[:n_ref]
        Zr, Fr, _, _ = _lm_steps(prob, C[top], FC[top], np.full(n_ref, 1e-3), refine_steps)
        C[top], FC[top] = Zr, Fr
        # (mu + lambda) reproduction
        allX = np.concatenate([X, C])
        allF = np.concatenate([F, FC])
        keep = np.argsort(allF)[:pop]
        X, F = allX[keep], allF[keep]
        hist.append(F[0])
        if len(hist) > stall_gen:
            old = hist[-stall_gen - 1]
            if (old - F[0]) / max(abs(F[0]), 1e-300) < tol:
                break
    zp, fp, it = _lm_converge(prob, X[0])
    return _result(prob, zp, fp, gen + 1 + it, "hga", {"generations": gen + 1, "lm_iterations": it})


METHODS: Dict[str, Callable[..., OptimResult]] = {
    "ga": ga, "ga-paper": ga_paper, "hga": hga, "lm": lm,
}


def run_method(method: str, prob: Problem, rng: RngLike = None, **kw) -> OptimResult:
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: allowed {', '.join(METHODS)}")
    return METHODS[method](prob, rng=rng, **kw)
