"""The variance of a pose mean from the recording's own within-pose statistics, tremor
included (the twin's noise; issue 25 item 1), and the disturbed poses.

The structure-function estimate lives in :mod:`imucald.fitting.noise.posecov` (the calibration's
pose covariance uses it too); the gap twin calls it one-sided per axis: it replaces the white
figure only when clearly below it (its colour inflation is handled elsewhere), and for the
accelerometer two-sided on the radial series, whose colour clearly above the white figure
it takes when larger (gap/diagnose.py ``_accel_pose_noise``).
"""
from __future__ import annotations

import numpy as np

from ..fitting.noise.posecov import FRACTIONS, MIN_SAMPLES, pose_mean_variance

__all__ = ["pose_mean_variance", "flag_disturbed", "FRACTIONS", "MIN_SAMPLES"]


def flag_disturbed(s2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Poses whose within-pose variance ``s2`` (n samples each) is far above the robust
    level (hand moved)."""
    med = np.median(s2)
    # chi-square(n-1)/(n-1) upper 99.9 % point ~ 1 + 3.1 sqrt(2/(n-1)); times 1.5 for colour
    lim = med * 1.5 * (1 + 3.1 * np.sqrt(2.0 / np.maximum(n - 1, 1)))
    return s2 > lim
