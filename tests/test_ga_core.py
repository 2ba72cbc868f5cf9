"""The genetic cores on their own (no LM polish of the closed-form starts), and the case
where the GA earns its place: lm from the closed-form starts stops in a worse minimum.

Tolerances come from the problem: a point inside the 99 % confidence region of the
optimum has fitness f* + sigma^2 chi2_k(0.99) at most (quadratic approximation), and
the global minimum has a fitness no larger than the true parameters' own.
"""
import numpy as np
import pytest

from imucald.fitting.models.accel import Full12, Triangular9
from imucald.fitting.solvers.ga import ga, ga_core, hga
from imucald.fitting.solvers.lsq import Problem, closed_form_starts, lm, lm_converge
from imucald.sim.orientations import random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, pose_sigma, simulate_pose_means
from imucald.specs import ACCEL

T9 = Triangular9()
SIGMA = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 50.0, 20.0)[1]
CHI2_9_99 = 21.666          # chi-square 99 % point, 9 degrees of freedom


def _case(seed):
    rng = np.random.default_rng(seed)
    truth = draw_truth("mpu6050", rng).accel
    raw, _ = simulate_pose_means(truth, up_vectors(random_pose_set(25, rng)), SIGMA, rng)
    return raw


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_hga_without_polish_lands_in_the_optimums_confidence_region(seed):
    raw = _case(seed)
    best = lm(Problem(T9, raw))
    res = hga(Problem(T9, raw), rng=seed, polish=False)
    assert res.fitness <= best.fitness + SIGMA ** 2 * CHI2_9_99, \
        f"hga alone: fitness excess {(res.fitness - best.fitness) / SIGMA ** 2:.3g} sigma^2"


@pytest.mark.parametrize("seed", [1, 2])
def test_ga_core_alone_with_paper_budget_beats_the_sphere_fit(seed):
    # the core with paper 000's settings, one run, no polish, against the optimum:
    # it does not reach the noise floor on its own (fitness excess ~1e4 sigma^2 here,
    # which is why ga polishes and ga-paper averages and narrows), but it must beat the
    # sphere fit (bias and one common scale in closed form).
    raw = _case(seed)
    best = lm(Problem(T9, raw))
    p = Problem(T9, raw)
    z, f, _ = ga_core(p, p.lo, p.hi, 1, np.random.default_rng(seed))
    sphere_start = closed_form_starts(p)[1]
    assert f[0] - best.fitness < p.fitness(sphere_start) - best.fitness


def _full12_cap_case():
    """12 poses within 40 deg of vertical, full12 misalignment near the box edge: the
    closed-form starts lead lm into a local minimum (found by a search over seeds: one
    of 80 full12 cases, none for triangular9 or cosine; README 'Which optimiser')."""
    m = Full12()
    lo, hi = m.default_bounds()
    rng = np.random.default_rng(1)
    th = m.nominal + (rng.random(m.k) * 0.5 + 0.45) * np.sign(rng.normal(size=m.k)) * (hi - lo) / 2
    u = rng.normal(size=(600, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    ups = u[u[:, 2] > np.cos(np.radians(40))][:12]
    raw = m.inverse(th, ups) + rng.normal(scale=1e-4, size=ups.shape)
    return m, th, raw


def test_ga_finds_the_global_minimum_where_lm_from_closed_form_starts_does_not():
    m, th, raw = _full12_cap_case()
    f_truth = float(Problem(m, raw).fitness(th))   # the global minimum is at most this
    f_lm = lm(Problem(m, raw)).fitness
    res = ga(Problem(m, raw), rng=1)
    assert f_lm > 10 * f_truth                     # lm: a local minimum
    assert res.fitness <= f_truth                  # ga: the global basin
    assert res.info["ga_start_won"]                # ... reached from the GA's own point


def test_ga_core_point_alone_reaches_the_global_basin():
    # the GA core's best, polished by LM on its own (no closed-form starts)
    m, th, raw = _full12_cap_case()
    p = Problem(m, raw)
    f_truth = float(p.fitness(th))
    z, _, _ = ga_core(p, p.lo, p.hi, 1, np.random.default_rng(1), pop=100, max_gen=60,
                       stall_gen=20, mig_interval=10)
    _, f, _ = lm_converge(p, z[0])
    assert f <= f_truth
