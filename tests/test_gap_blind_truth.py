"""Truth within 3 standard errors for named coefficients, on the model-space blind generator
(tests/blindgen2.py), whose forms are not the library's: the truth a named coefficient is
judged against is the injected effect projected onto the named form (the library's form
fitted, with the diagnosis's weighting, to the noise-free signal over the recording's own
poses and temperatures: bench/gap_blind.py ``truth_check``, where the weighting is stated).

Noise model: the coefficient minus its projected truth is the noise's part of the fit,
Gaussian with the reported standard error (scaled up by any remaining misfit, so |z| is if
anything smaller), so |z| > 3 has probability 0.27 % per coefficient.  Four thermal-bias
recordings (seeds 0-3, 18 coefficients: two fits chose the curved variant): at most one
beyond 3 SE (two or more by chance with probability 0.11 %), and the sum of z^2 below the
99.9 % point of chi-square with as many degrees of freedom.  Measured: max |z| 2.52."""
import os
import sys

import numpy as np
from scipy.stats import chi2

from imucald.gap.diagnose import diagnose

from .blindgen2 import make_case

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench"))
from gap_blind import truth_check  # noqa: E402


def test_thermal_bias_coefficients_lie_within_3_se_of_the_projected_truth():
    """Seen to fail with the standard errors of the candidate refit scaled by 0.2 (gap/norm.py
    refit_with): 11 of 18 coefficients beyond 3 SE."""
    z, named = [], 0
    for seed in range(4):
        rec, lab = make_case("thermal_bias", seed)
        res = diagnose(rec, sims=50, seed=seed)
        if res["sensors"]["accel"]["verdict"] != "thermal_bias":
            continue
        named += 1
        tc = truth_check(res, lab, rec.t)
        assert "z" in tc, tc
        z.extend(tc["z"].tolist())
    z = np.abs(np.array(z))
    assert named >= 3, f"thermal bias named on {named} of 4 recordings"
    assert np.sum(z > 3) <= 1, f"|z| = {np.round(z, 2)}"
    assert np.sum(z ** 2) < chi2.ppf(0.999, len(z)), f"sum z^2 = {np.sum(z ** 2):.1f} over {len(z)}"


def test_a_pair_reports_the_fit_its_tests_judged():
    """pair_nl_thermal development seeds 2001 and 2004 (22 and 24 poses): the general
    nonlinearity (10 terms, 7 visible in norm-only data) is fitted and tested in its visible
    combinations (gap/search.py VisiblePart) and reported as that fit mapped back: its
    coefficients lie in the span of the reported ``visible_basis``, and against the truth
    projected onto the same combinations every coefficient of the pair lies within 3 SE.
    Seen to fail with the first version's report, a refit of the full form (it interpolated
    the poses, N minus the hat's trace 0.8-2.5; coefficients off the span by up to 0.03 g,
    standard errors 20-140x the tested fit's)."""
    z = []
    for seed in (2001, 2004):
        rec, lab = make_case("pair_nl_thermal", seed)
        res = diagnose(rec, sims=100, seed=seed)
        a = res["sensors"]["accel"]
        assert set(a["verdict"].split("+")) == {"nonlinearity", "thermal_bias"}, a["verdict"]
        nl = next(m for m in a["search"]["members"] if m["name"] == "nonlinearity")
        V = np.asarray(nl["visible_basis"], float)
        eta = np.concatenate([np.asarray(v, float) for v in nl["params"].values()])
        assert V.shape == (10, nl["visible_coefficients"]) and V.shape[1] < 10
        assert np.linalg.norm(eta - V @ (V.T @ eta)) <= 1e-9 * max(np.linalg.norm(eta), 1e-12), seed
        tc = truth_check(res, lab, rec.t)
        assert "z" in tc, tc
        z.extend(tc["z"].tolist())
    z = np.abs(np.array(z))
    assert len(z) == 26 and np.sum(z > 3) <= 1, f"|z| = {np.round(z, 2)}"
