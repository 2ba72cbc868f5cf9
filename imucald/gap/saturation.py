"""Saturation (not a model term): samples at the range limit bias a pose's mean."""
from __future__ import annotations

import numpy as np

from ..files.recording import Recording

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
    # only the samples inside the poses are looked at (no temporary the size of the recording)
    if rail is not None and np.isfinite(rail):
        lim = rail * (1 - 1e-4)
        for i, s in enumerate(slices):
            out[i] = bool((np.abs(a[s]) >= lim).any())
        return out
    rails = []                              # (axis, value) of a recurring extreme beyond 1.2 g
    for j in range(3):
        for v in (a[:, j].max(), a[:, j].min()):
            if abs(v) > 1.2 and np.count_nonzero(a[:, j] == v) >= 5:
                rails.append((j, v))
    for i, s in enumerate(slices):
        out[i] = any(bool((a[s, j] == v).any()) for j, v in rails)
    return out
