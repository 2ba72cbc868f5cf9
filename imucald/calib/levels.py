"""Significance levels: one home, each named for the decision it bounds.

Each is the rate at which its test says "yes" when the truth is "no", under the noise
model the test assumes (the measured rates are in the tests named beside each).
"""
from __future__ import annotations

__all__ = ["GATE_FALSE_ACCEPT_RATE", "GAP_EFFECT_LEVEL", "THERMAL_TREND_LEVEL"]

#: the calibration gate: how often a new calibration that is no better than the incumbent
#: is applied (default of config calibration.false_accept_rate; tests/test_gate.py)
GATE_FALSE_ACCEPT_RATE = 0.05

#: the gap diagnosis (imucald gap): how often a gap, or an effect within it, is named when
#: the simulation explains the data (tests/test_gap*.py)
GAP_EFFECT_LEVEL = 0.01

#: the thermal fit: how often a temperature trend (and each order beyond a constant) is
#: kept when there is none.  The fit applies the gap diagnosis's rule to temperature terms,
#: so it takes the gap diagnosis's level.
THERMAL_TREND_LEVEL = GAP_EFFECT_LEVEL
