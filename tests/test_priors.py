"""Datasheet prior (MAP), determination flags, search-bound flags, model-order choice.

The hand-placed pose set: 10 poses, the six faces plus four 45-degree tilts in the
x-z and y-z planes, 1 degree of placement jitter (faces put down on a table); no pose has large x and y at once,
so alpha_yz (it couples x and y) is left to the prior, as in the real MPU-6050 log of
issue 9.  Noise: MPU-6050 density, 3 s holds at 100 Hz.
"""
import json

import numpy as np
import pytest

from imucald.fitting.fit import accel_prior, fit_norm
from imucald.fitting.models.accel import Triangular9
from imucald.fitting.solvers.lsq import Problem, lm
from imucald.fitting.solvers.ga import ga, hga
from imucald.sim.orientations import random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, pose_sigma, simulate_pose_means
from imucald.specs import ACCEL

T9 = Triangular9()
SIGMA = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 100.0, 3.0)[1]
_C = np.cos(np.radians(45))
HAND = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
                 [_C, 0, _C], [-_C, 0, _C], [0, _C, _C], [0, -_C, -_C]], float)


def _hand10(seed):
    rng = np.random.default_rng(seed)
    truth = draw_truth("mpu6050", rng).accel
    ups = HAND + rng.normal(scale=np.radians(1), size=HAND.shape)
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    raw, cov = simulate_pose_means(truth, ups, SIGMA, rng)
    return truth, raw, cov


@pytest.mark.parametrize("method", ["lm", "ga", "hga"])
@pytest.mark.parametrize("seed", [0, 1, 9])
def test_hand_placed_poses_flag_alpha_yz_and_keep_it_within_its_prior(method, seed):
    # seeds whose jitter leaves alpha_yz a data-only std of 0.05-0.19 (the real log: 0.075)
    truth, raw, cov = _hand10(seed)
    cal = fit_norm(raw, "triangular9", method, pose_cov=cov, chip="mpu6050", rng=seed)
    u = cal.uncertainty
    _, prior_sd = accel_prior(T9, "mpu6050")
    assert u.std[0] > 2 * prior_sd[0]           # the scenario: the data alone cannot fix it
    flags = {f["name"]: f for f in u.flags}
    assert "alpha_yz" in flags and "undetermined" in flags["alpha_yz"]["reason"]
    # the orientation named is one with x and y both well away from vertical and horizontal
    up = np.abs(flags["alpha_yz"]["up_vector"])
    assert up[0] > 0.5 and up[1] > 0.5, flags["alpha_yz"]["hint"]
    assert flags["alpha_yz"]["std_after_one_such_pose"] < u.posterior_std[0] / 2
    # stays within its prior, off the search bound (the bound is at 3 prior std)
    assert abs(cal.theta[0]) < 3 * prior_sd[0]
    assert "at_bound" not in flags["alpha_yz"]["reason"]
    # every parameter, flagged or not, within 3 reported standard errors of the truth
    z = (cal.theta - truth) / u.posterior_std
    assert np.all(np.abs(z) < 3), np.round(z, 2)
    # and the well-determined ones are not flagged
    assert set(flags) == {"alpha_yz"}


@pytest.mark.parametrize("seed", [2, 3])
def test_when_the_jitter_happens_to_determine_alpha_yz_nothing_is_flagged(seed):
    truth, raw, cov = _hand10(seed)
    cal = fit_norm(raw, "triangular9", "lm", pose_cov=cov, chip="mpu6050", heldout=False)
    u = cal.uncertainty
    assert u.posterior_std[0] < 0.5 * u.prior_std[0]
    assert u.flags == []
    assert np.all(np.abs((cal.theta - truth) / u.posterior_std) < 3)


def test_ga_paper_is_the_papers_fitness_and_says_so():
    truth, raw, cov = _hand10(0)
    cal = fit_norm(raw, "triangular9", "ga-paper", pose_cov=cov, chip="mpu6050", rng=0,
                   heldout=False)
    assert "not used" in cal.info["optim"]["prior"]
    assert cal.info["noise_model"]["prior"].startswith("none")
    # its data-only std is still compared with the datasheet tolerance: alpha_yz flagged
    assert "alpha_yz" in [f["name"] for f in cal.uncertainty.flags]


@pytest.mark.parametrize("method", ["lm", "ga", "hga", "ga-paper"])
def test_a_parameter_on_a_search_bound_is_always_flagged(method):
    rng = np.random.default_rng(41)
    truth = draw_truth("mpu6050", rng).accel
    raw, cov = simulate_pose_means(truth, up_vectors(random_pose_set(25, rng)), SIGMA, rng)
    lo, hi = T9.default_bounds(spec_bias=0.005)       # the truth's biases lie outside
    cal = fit_norm(raw, "triangular9", method, pose_cov=cov, chip="mpu6050", rng=1,
                   bounds=(lo, hi), heldout=False)
    on = np.isclose(cal.theta, lo) | np.isclose(cal.theta, hi)
    assert on[6:9].any()
    flagged = {f["name"]: f["reason"] for f in cal.uncertainty.flags}
    for j in np.flatnonzero(on):
        assert "at_bound" in flagged[T9.param_names[j]]


def test_json_and_text_fields_are_plain_json():
    truth, raw, cov = _hand10(1)
    d = fit_norm(raw, "triangular9", "lm", pose_cov=cov, chip="mpu6050").to_json()
    s = json.dumps(d, allow_nan=False)
    back = json.loads(s)
    assert back["flags"][0]["name"] == "alpha_yz"
    det = back["determination"]["alpha_yz"]
    assert det["std"] / det["prior_std"] > 0.5 > back["determination"]["bias_x_g"]["std"] / \
        back["determination"]["bias_x_g"]["prior_std"]


@pytest.mark.parametrize("seed", [5, 6])
def test_lm_ga_hga_reach_the_same_map_optimum(seed):
    _, raw, cov = _hand10(seed)
    pm, ps = accel_prior(T9, "mpu6050")
    mk = lambda: Problem(T9, raw, prior_mean=pm, prior_std=ps, noise_var=SIGMA ** 2)
    f = {name: fn(mk(), rng=seed).fitness for name, fn in (("lm", lm), ("ga", ga), ("hga", hga))}
    assert f["ga"] == pytest.approx(f["lm"], rel=1e-9)
    assert f["hga"] == pytest.approx(f["lm"], rel=1e-9)


def test_model_auto_picks_a_model_with_non_orthogonality_when_the_sensor_has_it():
    rng = np.random.default_rng(7)
    truth = T9.nominal.copy()
    truth[0:3] = [0.03, -0.025, 0.02]           # 1.5 deg-scale non-orthogonality
    truth[6:9] = [0.02, -0.03, 0.05]
    raw, cov = simulate_pose_means(truth, up_vectors(random_pose_set(25, rng)), SIGMA, rng)
    cal = fit_norm(raw, "auto", "lm", pose_cov=cov, chip="mpu6050")
    sel = cal.info["model_selection"]
    assert set(sel["heldout_rms_g"]) == {"diag6", "triangular9", "full12"}
    assert sel["chosen"] == cal.model != "diag6"
    assert sel["heldout_rms_g"]["diag6"] > sel["heldout_rms_g"][cal.model]


def test_a_model_that_leaves_terms_out_states_what_they_can_do_to_the_others():
    """9 poses, 6 distinct directions and 3 repeated within ~3 deg (a hand putting the board
    down again), an MPU-6050 whose non-orthogonality is drawn from the datasheet prior itself
    (N(0, 2 %)): --model auto picks diag6 (alpha held at 0) where its held-out error is lowest,
    i.e. where the pose set hides what alpha does.  The terms left out are not 0 but within the
    tolerance, and the free terms absorb them: their prior is propagated into the stated
    covariance (fit._fixed_terms_cov).  Over 80 seeds, the bias and scale estimates of the 24
    sessions that chose diag6: none beyond 3 stated sd (a Gaussian's 0.3 %; up to 1 % allowed)
    and a median |z| of 0.91 (a Gaussian's 0.67; 0.4-1.0 allowed), the stated bias sd 6.1 mg,
    under a third of the 80-mg zero-g tolerance.  Broken once each: the term at a third of its
    sd, 39 % beyond 3 sd, median |z| 2.6 (fails); the term left out, 76 % beyond, median 6.1,
    sd 0.8 mg (fails).  A black-box helper saw the same with its own generator: bias errors of
    8-23 mg against stated 0.1-1.5 mg."""
    z, sd = [], []
    for seed in range(80):
        rng = np.random.default_rng(seed)
        truth = draw_truth("mpu6050", rng).accel
        truth[0:3] = rng.normal(0, ACCEL["mpu6050"].cross_axis_tol, 3)    # the prior's own spread
        u = up_vectors(random_pose_set(6, rng))
        d = u[rng.integers(0, 6, 3)] + rng.normal(0, 0.05, (3, 3))
        u = np.vstack([u, d / np.linalg.norm(d, axis=1, keepdims=True)])
        raw, cov = simulate_pose_means(truth, u, pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 100.0, 6.5)[1],
                                       rng)
        cal = fit_norm(raw, "auto", "lm", pose_cov=cov, chip="mpu6050")
        if cal.model != "diag6":
            continue
        for g, sl in (("scale", slice(3, 6)), ("bias_g", slice(6, 9))):
            se = np.array(cal.stderr[g], float)
            z += list((np.array(cal.params[g]) - truth[sl]) / se)
        sd += cal.stderr["bias_g"]
    assert len(z) >= 6 * 15                          # diag6 was chosen in 15 sessions or more
    assert np.mean(np.abs(z) > 3) <= 0.01, np.mean(np.abs(z) > 3)
    # the term's size: a Gaussian's median |z| is 0.67; under 0.4 the sd would be too wide, over
    # 1.0 too narrow (with the term at a third of its sd: fails)
    assert 0.4 < np.median(np.abs(z)) < 1.0, np.median(np.abs(z))
    assert np.median(sd) < max(ACCEL["mpu6050"].bias_tol_g) / 3


def test_where_the_poses_pin_the_left_out_terms_their_share_is_small():
    """The other side of the test above: 25 well-spread poses of a part without
    non-orthogonality, where --model auto also chooses diag6.  The poses pin the terms it
    leaves out near 0, so their share of the covariance (their second moment under the full
    model, poses and prior) is small and the stated sd stays the data's: median |z| within
    0.4-1.0 (a Gaussian's 0.67), none beyond 3 sd.  Measured: median |z| 0.63, the bias sd
    0.057 mg.  Broken once: the prior alone in the poses' place (the first version), bias sd
    0.44 mg and median |z| 0.07 (fails); a black-box helper's 25-pose sessions showed the same
    with it (4.3 mg stated for errors of 0.02)."""
    z, sd = [], []
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        truth = draw_truth("mpu6050", rng).accel
        truth[0:3] = 0.0
        raw, cov = simulate_pose_means(truth, up_vectors(random_pose_set(25, rng)), SIGMA, rng)
        cal = fit_norm(raw, "auto", "lm", pose_cov=cov, chip="mpu6050")
        if cal.model != "diag6":
            continue
        for g, sl in (("scale", slice(3, 6)), ("bias_g", slice(6, 9))):
            z += list((np.array(cal.params[g]) - truth[sl]) / np.array(cal.stderr[g], float))
        sd += cal.stderr["bias_g"]
    assert len(z) >= 6 * 10
    assert np.mean(np.abs(z) > 3) <= 0.01 and 0.4 < np.median(np.abs(z)) < 1.0, (np.median(np.abs(z)), np.median(sd))


def test_a_warm_up_below_the_thermal_span_states_what_the_slope_does():
    """10 poses, 20 s apart, through a warm-up of 7.6 degC (towards 8; below
    calibration.thermal_min_span_c, 10 degC: a constant only), an MPU-6050 whose bias slope is drawn from the datasheet's
    zero-g change per degC itself.  The 9 parameters absorb what the slope does to each pose
    (up to 4 mg) with 1 residual degree of freedom left to show it; the slope the constant
    leaves out is propagated into the stated covariance (fit._fixed_terms_cov, the poses'
    temperatures given).  Over 40 seeds, alpha, scale and bias: none beyond 3 stated sd (a
    Gaussian's 0.3 %; up to 1 % allowed), median |z| 0.4-1.0 (a Gaussian's 0.67).  Measured:
    0 of 360, median 0.60.  Broken once each: without the temperatures, 19 % beyond 3 sd
    (|z| up to 36; fails); the slope's prior at a third of the datasheet's, 8 % beyond (fails).
    (On a part whose slope is near 0 the same sd is far wider than the error: a cold review
    measured median |z| 0.11 there; docs/methods/models.md.)
    A black-box helper's 8-degC warm-ups on 9-11 poses kept parameters 9-25 sd off."""
    z = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        truth = draw_truth("mpu6050", rng).accel
        k = rng.normal(0, 1, 3) * np.asarray(ACCEL["mpu6050"].bias_tempco_g_per_c)     # g/degC
        t = np.arange(10) * 20.0
        temp = 25.0 + 8.0 * (1 - np.exp(-t / 60.0))
        raw, cov = simulate_pose_means(truth, up_vectors(random_pose_set(10, rng)), SIGMA, rng)
        raw = raw + np.outer(temp - temp.mean(), k)       # the bias at the poses' mean temperature: truth's
        cal = fit_norm(raw, "triangular9", "lm", pose_cov=cov, chip="mpu6050", temp_c=temp)
        for g, sl in (("alpha", slice(0, 3)), ("scale", slice(3, 6)), ("bias_g", slice(6, 9))):
            z += list((np.array(cal.params[g]) - truth[sl]) / np.array(cal.stderr[g], float))
    assert np.mean(np.abs(z) > 3) <= 0.01, (np.mean(np.abs(z) > 3), np.max(np.abs(z)))
    assert 0.4 < np.median(np.abs(z)) < 1.0, np.median(np.abs(z))


def test_the_flags_say_what_the_poses_did_not_pin_not_the_slope():
    """The hand-placed 10-pose set of this file's first tests through a warm-up of 7.6 degC:
    the slope's share widens the stated sd, but the undetermined flags are what the poses did
    not pin, the same as without the temperatures (another pose would not narrow the slope's
    share: the thermal fit needs 18).  Seen to fail with the flags judged on the widened
    covariance (alpha_yz flagged where the poses pinned it)."""
    t = np.arange(10) * 20.0
    temp = 25.0 + 8.0 * (1 - np.exp(-t / 60.0))
    flags = lambda c: sorted(f["name"] for f in c.uncertainty.flags)
    widened = 0
    for seed in range(20):
        truth, raw, cov = _hand10(seed)
        a = fit_norm(raw, "triangular9", "lm", pose_cov=cov, chip="mpu6050", temp_c=temp)
        b = fit_norm(raw, "triangular9", "lm", pose_cov=cov, chip="mpu6050")
        assert flags(a) == flags(b), (seed, flags(a), flags(b))
        widened += a.stderr["alpha"][0] > 1.2 * b.stderr["alpha"][0]
    assert widened >= 10, widened          # the slope's share is there (alpha_yz)
