"""Saturation (not a model term): samples at the range limit bias a pose's mean."""
from __future__ import annotations

import numpy as np

from ..recording import Recording

__all__ = ["saturated"]


def saturated(rec: Recording, slices) -> np.ndarray:
    """Poses with accelerometer samples at the range limit.  The limit is the
    recording's accel_range_g when given, else an extreme value that recurs (a rail)."""
    a = rec.acc
    rail = None
    try:
        rail = float(rec.meta.get("accel_range_g", "nan"))
    except ValueError:
        rail = None
    out = np.zeros(len(slices), bool)
    if rail is not None and np.isfinite(rail):
        hit = np.abs(a) >= rail * (1 - 1e-4)
    else:
        hit = np.zeros_like(a, bool)
        for j in range(3):
            for v in (a[:, j].max(), a[:, j].min()):
                at = a[:, j] == v
                if at.sum() >= 5 and abs(v) > 1.2:       # a recurring extreme beyond 1.2 g
                    hit[:, j] |= at
    h = hit.any(axis=1)
    for i, s in enumerate(slices):
        out[i] = h[s].any()
    return out
