"""The significance levels of the gap diagnosis, one place, each named for the decision it
sets (every path reads them from here: the norm path gap/norm.py, the gyro's linear path
gap/linear.py, the time-series path gap/series.py and the verdict gap/verdict.py).

Each is the false-alarm rate of its decision under the noise model (the twin's
re-simulations check the calibration of the tests: tests/test_gap*.py).
"""
from __future__ import annotations

__all__ = ["GAP_TEST_LEVEL", "ATTRIBUTION_LEVEL", "REMAINING_GAP_LEVEL"]

#: the chi-square test of the noise model: a gap needs its p-value below this (and the
#: held-out ratio above the twin's 99th percentile)
GAP_TEST_LEVEL = 0.01
#: family-wise level for naming an effect: split (Bonferroni) over the candidates tested,
#: each candidate's score, nested and Wald tests must pass at ATTRIBUTION_LEVEL / count
ATTRIBUTION_LEVEL = 0.01
#: with the first effect modelled, a second is sought only while the chi-square test of
#: that model still rejects at this level
REMAINING_GAP_LEVEL = 0.01
