"""fitting/noise/colour.py: the coloured-noise inflation of pose-mean variance (Allan model)."""
import numpy as np
import pytest

from imucald.fitting.noise.colour import allan_model, colour_inflation, colour_inflation_per_pose

RATE = 100.0
DUR = 600.0


def _signal(q, seed):
    """White noise (sigma 1 per sample) plus a random walk of rate q per sqrt(s), 3 axes.
    AVAR = 1/(rate tau) + q^2 tau / 3, so the inflation at T is 1 + q^2 rate T^2 / 3."""
    rng = np.random.default_rng(seed)
    n = int(DUR * RATE)
    w = rng.standard_normal((n, 3))
    rw = np.cumsum(rng.standard_normal((n, 3)) * q / np.sqrt(RATE), axis=0)
    return w + rw


@pytest.mark.parametrize("q,T", [(0.0, 10.0), (0.03, 10.0), (0.03, 5.0), (0.06, 3.0)])
def test_inflation_matches_the_noise_model(q, T):
    k_true = 1 + q * q * RATE * T * T / 3
    ks = []
    for seed in range(1, 9):
        k, info = colour_inflation(_signal(q, seed), RATE, T)
        assert info["variance_inflation"] == pytest.approx(k, abs=1e-3)
        ks.append(k)
    ks = np.array(ks)
    if q == 0:     # clamped at 1 from below: white noise must not look coloured
        assert np.mean(ks) - 1 < 3 * max(np.std(ks, ddof=1), 1e-3)
        return
    # the mean of 8 independent estimates within 3 of its standard errors of the truth
    assert abs(ks.mean() - k_true) < 3 * ks.std(ddof=1) / np.sqrt(len(ks)), (ks, k_true)


def test_white_noise_gives_no_random_walk_term_and_per_pose_follows_length():
    coef = allan_model(_signal(0.0, 2), RATE)
    # white: AVAR = 1/(rate tau); at 4 samples 15000 averages, relative s.e. 1.2 %: 10 % ~ 8 s.e.
    assert np.all(coef[:, 0] == pytest.approx(1 / RATE, rel=0.1))
    k, _ = colour_inflation_per_pose(_signal(0.03, 3), RATE, np.array([2.0, 5.0, 10.0, 400.0]))
    assert np.all(np.diff(k) > 0)                                   # longer poses, more colour
    assert k[-1] == pytest.approx(colour_inflation_per_pose(_signal(0.03, 3), RATE,
                                                            np.array([DUR / 3]))[0][0])


def test_short_stretch_means_white_noise_with_a_note():
    k, info = colour_inflation(_signal(0.03, 4)[:2000], RATE, 5.0)
    assert k == 1.0 and "too short" in info["note"]
    k, info = colour_inflation_per_pose(None, RATE, np.array([5.0, 6.0]))
    assert np.all(k == 1.0) and "white noise assumed" in info["note"]


def test_fit_uses_the_inflation_for_each_poses_noise():
    from imucald.fitting.fit import fit_norm
    from imucald.sim.orientations import random_pose_set, up_vectors
    from imucald.sim.sensor import draw_truth, simulate_pose_means
    rng = np.random.default_rng(5)
    truth = draw_truth("mpu6050", rng).accel
    raw, cov = simulate_pose_means(truth, up_vectors(random_pose_set(20, rng)), 1e-4, rng)
    k = np.linspace(1.0, 4.0, 20)
    a = fit_norm(raw, "triangular9", "lm", pose_cov=cov, heldout=False)
    b = fit_norm(raw, "triangular9", "lm", pose_cov=cov, heldout=False, noise_inflation=k)
    assert a.info["noise_model"]["excess_scatter"] == b.info["noise_model"]["excess_scatter"] == 1.0
    # each pose's noise grows with its own factor: the standard errors grow, and a
    # common factor 4 doubles the noise exactly
    assert np.all(b.uncertainty.posterior_std[6:9] > a.uncertainty.posterior_std[6:9])
    c = fit_norm(raw, "triangular9", "lm", pose_cov=cov, heldout=False, noise_inflation=4.0)
    assert c.noise / a.noise == pytest.approx(2.0, rel=1e-6)
