"""Significance levels: one home, each named for the decision it bounds.

Each is the rate at which its test says "yes" when the truth is "no", under the noise
model the test assumes (the measured rates are in the tests named beside each).
"""
from __future__ import annotations

__all__ = ["GATE_FALSE_ACCEPT_RATE", "IN_FORCE_CHALLENGE_LEVEL", "GAP_EFFECT_LEVEL", "GAP_TEST_LEVEL", "GAP_ATTRIBUTION_LEVEL",
           "GAP_REMAINING_LEVEL", "GAP_HELDOUT_LEVEL", "THERMAL_TREND_LEVEL"]

#: the calibration gate: how often a new calibration that is no better than the incumbent
#: is applied (default of config calibration.false_accept_rate; tests/test_gate.py)
GATE_FALSE_ACCEPT_RATE = 0.05

#: the daemon's check of a final calibration in force (one loaded at start, or applied in an
#: earlier session) on the poses it was not fitted on, before the pose set is ready: how often
#: a right calibration is challenged by an early fit (which the gate then judges, so a false
#: challenge costs one background fit; tests/test_daemon_challenge.py)
IN_FORCE_CHALLENGE_LEVEL = 1e-3

#: the gap diagnosis (imucald gap): how often a gap, or an effect within it, is named when
#: the simulation explains the data (tests/test_gap*.py)
GAP_EFFECT_LEVEL = 0.01
#: its three decisions (imucald/gap/norm.py, linear.py, series.py, verdict.py):
#: - the chi-square test of the noise model: a gap needs its p-value below this (and the
#:   held-out ratio above the twin's 99th percentile)
GAP_TEST_LEVEL = GAP_EFFECT_LEVEL
#: - naming an effect: family-wise, split (Bonferroni) over the candidates tested; each
#:   candidate's score, nested and Wald tests must pass at GAP_ATTRIBUTION_LEVEL / count
#:   (a single candidate's report: every candidate scored; the combination search: the
#:   variants it can take as members, gap/search.py family_level)
GAP_ATTRIBUTION_LEVEL = GAP_EFFECT_LEVEL
#: - with the first effect modelled, a second is sought only while the chi-square test of
#:   that model still rejects at this level
GAP_REMAINING_LEVEL = GAP_EFFECT_LEVEL
#: - the combination search (imucald/gap/search.py; the gyro's, gap/gyrosearch.py): a member's
#:   held-out shrink (the fall in the held-out RMS it brings) must be significant at this level
#:   against its twin, one-sided, beside its coefficient test at GAP_ATTRIBUTION_LEVEL / count
#:   (the gyro: count = the (model, member) tests its search can make)
GAP_HELDOUT_LEVEL = GAP_EFFECT_LEVEL

#: the thermal fit: how often a temperature trend (and each order beyond a constant) is
#: kept when there is none.  The fit applies the gap diagnosis's rule to temperature terms,
#: so it takes the gap diagnosis's level.
THERMAL_TREND_LEVEL = GAP_EFFECT_LEVEL
