"""The Cramer-Rao bound: checked against Monte Carlo, and paper 000's alpha_yz finding."""
import numpy as np
import pytest

from imucald.fitting.models.accel import Triangular9
from imucald.fitting.solvers.lsq import Problem, lm_converge
from imucald.fitting.judging.uncertainty import crlb, residual_variance
from imucald.sim.orientations import euler_pose_set, random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth

T9 = Triangular9()
SIGMA = 63e-6


def _bound(theta, raw, sigma=SIGMA):
    return crlb(T9, theta, raw, residual_variance(T9, theta, raw, np.full(len(raw), sigma ** 2)))


def test_crlb_matches_monte_carlo_spread_of_the_ml_estimate():
    rng = np.random.default_rng(100)
    truth = draw_truth("mpu6050", rng).accel
    ups = up_vectors(random_pose_set(27, rng))
    raw0 = T9.inverse(truth, ups)
    n = 300
    est = np.zeros((n, 9))
    for i in range(n):
        raw = raw0 + rng.normal(scale=SIGMA, size=raw0.shape)
        prob = Problem(T9, raw)
        z, _, _ = lm_converge(prob, truth.copy())
        est[i] = z
    bound = _bound(truth, raw0).std
    ratio = est.std(0, ddof=1) / bound
    # the sample std of n=300 draws has relative s.e. 1/sqrt(2n) = 4.1 %: +-15 % is ~3.6 s.e.
    assert np.all(np.abs(ratio - 1) < 0.15), np.round(ratio, 3)
    # and the estimator is unbiased at this noise level (mean error < 4 s.e. of the mean)
    assert np.all(np.abs(est.mean(0) - truth) < 4 * bound / np.sqrt(n))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_no_rotation_about_z_leaves_alpha_yz_worst(seed):
    rng = np.random.default_rng(seed)
    truth = draw_truth("mpu6050", rng).accel
    sd = {}
    for ps in [(12, 12, 0), (8, 8, 8)]:
        ups = up_vectors(euler_pose_set(*ps, rng))
        sd[ps] = _bound(truth, T9.inverse(truth, ups)).std
    a = sd[(12, 12, 0)]
    # alpha_yz couples x and y; without rotation about z no pose has gravity in the x-y plane
    assert a[0] > 2 * max(a[1], a[2])
    assert a[0] > 2 * sd[(8, 8, 8)][0]


def test_rank_and_condition_flag_a_degenerate_pose_set():
    # six face poses cannot fit 9 parameters (reference: "rank 6")
    ups = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
    unc = _bound(T9.nominal, ups)
    assert unc.rank < 9
    assert len(unc.null_directions) == 9 - unc.rank
