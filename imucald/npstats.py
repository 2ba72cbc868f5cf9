"""Small numeric helpers shared by the calibration, the daemon and the readers (a leaf:
it imports nothing from imucald).

:func:`median` is ``numpy.median`` without its first-call cost: numpy 2's median checks
its result for NaN through ``numpy.ma``, whose import took 14-28 ms (and a few MB) here,
paid by every command and by the daemon at its first pose.  Same algorithm (partition,
mean of the middle one or two), so the same values bit for bit.
"""
from __future__ import annotations

import numpy as np

__all__ = ["median"]


def median(a, axis=None):
    """``numpy.median(a, axis)`` (axis None or an int): NaN where a slice holds a NaN."""
    a = np.asarray(a)
    if axis is None:
        a, axis = a.ravel(), 0
    n = a.shape[axis]
    if n == 0 or a.dtype.kind not in "fiub":
        return np.median(a, axis=axis)          # empty or unusual: numpy's own warnings/types
    h = n // 2
    kth = [h - 1, h] if n % 2 == 0 else [h]
    nan_possible = a.dtype.kind == "f"
    part = np.partition(a, kth + [-1] if nan_possible else kth, axis=axis)
    idx = [slice(None)] * a.ndim
    idx[axis] = slice(h - 1, h + 1) if n % 2 == 0 else slice(h, h + 1)
    out = np.mean(part[tuple(idx)], axis=axis)
    if nan_possible:
        last = part.take(-1, axis=axis)
        bad = np.isnan(last)
        if bad.any():
            if isinstance(out, np.generic):
                return last
            np.copyto(out, last, where=bad)
    return out
