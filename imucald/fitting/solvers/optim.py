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

from typing import Callable, Dict

from .ga import ga, ga_paper, hga
from .lsq import OptimResult, Problem, ellipsoid_fit, lm, sphere_fit
from ...numerics.rng import RngLike

__all__ = ["Problem", "OptimResult", "lm", "ga_paper", "hga", "ga", "METHODS", "run_method",
           "sphere_fit", "ellipsoid_fit"]


METHODS: Dict[str, Callable[..., OptimResult]] = {
    "ga": ga, "ga-paper": ga_paper, "hga": hga, "lm": lm,
}


def run_method(method: str, prob: Problem, rng: RngLike = None, **kw) -> OptimResult:
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: allowed {', '.join(METHODS)}")
    return METHODS[method](prob, rng=rng, **kw)
