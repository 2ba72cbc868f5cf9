"""Genetic optimisers: paper 000's GA core and protocol (``ga-paper``), the daemon's
light ``ga`` and paper 001's hybrid ``hga`` (see :mod:`imucald.fitting.solvers.optim`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Tuple

import numpy as np

from ...numerics.rng import as_rng

from .lsq import (OptimResult, Problem, optim_result, closed_form_starts, lm_converge,
                  lm_converge_rows, lm_steps)
from ...numerics.rng import RngLike
from ..models.base import NormModel

__all__ = ["ga_paper", "ga", "hga", "ga_core"]


# --- MATLAB-style GA (paper 000), vectorised over independent runs ----------------------

@dataclass(eq=False)
class _GaShape:
    """Sizes and index helpers of a vectorised GA: ``runs`` independent runs, each of
    ``nsub`` subpopulations of ``Ps`` individuals over ``kf`` parameters."""
    runs: int
    nsub: int
    Ps: int
    kf: int
    elite: int
    n_x: int                    #: crossover children per subpopulation
    n_par: int                  #: parents drawn per subpopulation
    n_mig: int                  #: migrants per subpopulation
    cw: np.ndarray              #: cumulative rank-scaled weights (1/sqrt(rank))
    base: np.ndarray            #: (rows, 1) flat offset of each (run, subpop) row
    ar: np.ndarray              #: arange(runs)
    ri: np.ndarray              #: (rows, 1) arange(rows): each row's index, for fancy indexing
    par_ar: np.ndarray          #: arange(n_par)

    @property
    def rows(self) -> int:
        return self.runs * self.nsub


def _ga_shape(runs: int, kf: int, pop: int, nsub: int, elite: int, xfrac: float,
              mig_frac: float) -> _GaShape:
    Ps = pop // nsub
    n_x = int(round(xfrac * (Ps - elite)))
    n_m = Ps - elite - n_x
    w = 1.0 / np.sqrt(np.arange(1, Ps + 1))
    return _GaShape(runs, nsub, Ps, kf, elite, n_x, 2 * n_x + n_m,
                    max(1, int(round(mig_frac * Ps))), np.cumsum(w) / w.sum(),
                    (np.arange(runs * nsub) * Ps)[:, None], np.arange(runs),
                    np.arange(runs * nsub)[:, None], np.arange(2 * n_x + n_m))


def _generation_best(sh: _GaShape, Xf: np.ndarray, Ff: np.ndarray):
    """(order, best f per run, best z per run): ``order`` ranks each row, best first."""
    order = np.argsort(Ff, axis=1)
    top = Ff[sh.ri[:, 0], order[:, 0]].reshape(sh.runs, sh.nsub)
    sb = top.argmin(1)
    fb = top[sh.ar, sb]
    zb = Xf[(sh.base[:, 0].reshape(sh.runs, sh.nsub)[sh.ar, sb]
             + order.reshape(sh.runs, sh.nsub, sh.Ps)[sh.ar, sb, 0])]
    return order, fb, zb


def _offspring(sh: _GaShape, Xf: np.ndarray, order: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               sig: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stochastic-uniform selection on rank-scaled fitness, scattered crossover and the
    feasible Gaussian mutation: (rows, Ps - elite, kf) children."""
    n_x = sh.n_x
    pos = (rng.random((sh.rows, 1)) + sh.par_ar) / sh.n_par
    rk = np.minimum(np.searchsorted(sh.cw, pos), sh.Ps - 1)
    rk = rng.permuted(rk, axis=-1)
    pidx = order[sh.ri, rk] + sh.base                  # np.take_along_axis(order, rk, 1)
    par = Xf[pidx]                                      # (rows, n_par, kf)
    p1, p2, pm = par[:, :n_x], par[:, n_x:2 * n_x], par[:, 2 * n_x:]
    xo = np.where(rng.integers(0, 2, p1.shape, dtype=bool), p1, p2)  # scattered crossover
    mu = pm + rng.standard_normal(pm.shape) * sig
    bad = (mu < lo) | (mu > hi)
    if bad.any():  # redraw between the parent and the violated bound: stays feasible
        bound = np.where(mu < lo, lo, hi)
        mu = np.where(bad, pm + rng.random(mu.shape) * (bound - pm), mu)
    return np.concatenate([xo, mu], axis=1)


def _migrate(sh: _GaShape, X: np.ndarray, F: np.ndarray) -> None:
    """Forward migration, in place: each subpopulation's best replace the next one's worst."""
    o2 = np.argsort(F, axis=1)
    bi = o2[:, :sh.n_mig].reshape(sh.runs, sh.nsub, sh.n_mig)
    wi = o2[:, sh.Ps - sh.n_mig:].reshape(sh.runs, sh.nsub, sh.n_mig)
    X4 = X.reshape(sh.runs, sh.nsub, sh.Ps, sh.kf)
    F3 = F.reshape(sh.runs, sh.nsub, sh.Ps)
    # subpopulation s takes the best of s - 1 (cyclically): gathered, then written over its
    # worst (plain fancy indexing: what take_along_axis, roll and put_along_axis did, in ~1/3
    # of their time)
    r = sh.ar[:, None, None]
    s = np.arange(sh.nsub)[None, :, None]
    src = (s - 1) % sh.nsub
    rows = bi[r, src, np.arange(sh.n_mig)]          # (runs, nsub, n_mig): the migrants' places in s - 1
    mX, mF = X4[r, src, rows], F3[r, src, rows]
    X4[r, s, wi] = mX
    F3[r, s, wi] = mF


def ga_core(prob: Problem, lo: np.ndarray, hi: np.ndarray, runs: int, rng: np.random.Generator,
            pop: int = 200, nsub: int = 2, elite: int = 2, xfrac: float = 0.8,
            mig_frac: float = 0.2, mig_interval: int = 20, max_gen: int = 150,
            stall_gen: int = 50, tol: float = 1e-10, mut_scale: float = 1.0,
            mut_shrink: float = 1.0, progress: Optional[Callable[[int, np.ndarray], None]] = None
            ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run ``runs`` independent GAs at once (paper 000's operators, MATLAB defaults) on
    anything with a vectorised ``fitness(Z)``.  Returns best z (R, kf), best f (R,),
    generations (R,)."""
    kf = lo.size
    sh = _ga_shape(runs, kf, pop, nsub, elite, xfrac, mig_frac)
    Ps, rows, ar = sh.Ps, sh.rows, sh.ar
    span = hi - lo
    X = lo + rng.random((runs, nsub, Ps, kf)) * span
    F = prob.fitness(X)
    hist = np.full((max_gen + 1, runs), np.inf)
    stopped = np.zeros(runs, bool)
    stop_gen = np.full(runs, max_gen)
    best_z = np.zeros((runs, kf))
    best_f = np.full(runs, np.inf)
    gen = 0
    for gen in range(max_gen):
        Xf = X.reshape(rows * Ps, kf)
        Ff = F.reshape(rows, Ps)
        order, fb, zb = _generation_best(sh, Xf, Ff)
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
        sig = mut_scale * max(0.0, 1.0 - mut_shrink * gen / max_gen) * span
        children = _offspring(sh, Xf, order, lo, hi, sig, rng)
        eidx = order[:, :elite] + sh.base
        Fc = prob.fitness(children)
        X = np.concatenate([Xf[eidx], children], axis=1)
        F = np.concatenate([Ff[sh.ri, order[:, :elite]], Fc], axis=1)
        if nsub > 1 and (gen + 1) % mig_interval == 0:
            _migrate(sh, X, F)
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
    """Paper 000's full protocol: 20 averaged runs, 3 iterations with narrowed bounds.

    As the paper wrote it: the fitness is its eq. 5 alone, so a prior on ``prob`` is
    not used (``info['prior']`` says so); a parameter the poses do not determine can
    then end anywhere in the box, including on a bound (reported by ``at_bound``)."""
    rng = as_rng(rng)
    had_prior = prob.has_prior
    if had_prior:
        prob = prob.without_prior()
    prob.nfev = 0
    lo, hi = prob.lo.copy(), prob.hi.copy()
    per_iter = []
    gens = 0
    mean = None
    for it in range(iterations):
        z, f, g = ga_core(prob, lo, hi, runs, rng, **ga_kw)
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
    info = {"iterations": per_iter, "runs": runs}
    if had_prior:
        info["prior"] = "not used: ga-paper is paper 000's protocol as written"
    return optim_result(prob, mean, fit, gens, "ga-paper", info)


def ga(prob: Problem, rng: RngLike = None, pop: int = 100, max_gen: int = 60,
       stall_gen: int = 20, progress: Optional[Callable[[int, np.ndarray], None]] = None
       ) -> OptimResult:
    """The daemon's light GA (paper 000 operators, one run) polished by LM."""
    rng = as_rng(rng)
    prob.nfev = 0
    z, f, g = ga_core(prob, prob.lo, prob.hi, 1, rng, pop=pop, max_gen=max_gen,
                       stall_gen=stall_gen, mig_interval=10, progress=progress)
    # the closed-form starts are polished too, so the GA can only add to what lm finds (all
    # the starts at once, each as lm_converge alone polishes it)
    Zp, Fp, its = lm_converge_rows(prob, np.array([z[0]] + closed_form_starts(prob)))
    zp, fp, it, ga_won = Zp[0], float(Fp[0]), int(its[0]), True
    for zs, fs, n in zip(Zp[1:], Fp[1:].tolist(), its[1:].tolist()):
        it += n
        if fs < fp:
            zp, fp, ga_won = zs, fs, False
    return optim_result(prob, zp, fp, int(g[0]) + it, "ga",
                       {"ga_fitness": float(f[0]), "ga_generations": int(g[0]), "lm_iterations": it,
                        "ga_start_won": ga_won})


def hga(prob: Problem, rng: RngLike = None, pop: int = 300, max_gen: int = 200,
        stall_gen: int = 70, tol: float = 1e-15, pc: float = 0.8, pm: float = 0.1,
        refine_frac: float = 0.1, refine_steps: int = 2, polish: bool = True) -> OptimResult:
    """Paper 001's hybrid GA with a bounded-LM local step (see module doc).

    ``polish=False`` returns the population's best as the GA left it (tests check the
    GA on its own with it)."""
    rng = as_rng(rng)
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
        Zr, Fr, _, _ = lm_steps(prob, C[top], FC[top], np.full(n_ref, 1e-3), refine_steps)
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
    zp, fp, it = lm_converge(prob, X[0]) if polish else (X[0], float(F[0]), 0)
    return optim_result(prob, zp, fp, gen + 1 + it, "hga", {"generations": gen + 1, "lm_iterations": it})
