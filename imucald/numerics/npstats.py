"""Small numeric helpers shared by the calibration, the daemon and the readers (a leaf:
it imports nothing from imucald).

:func:`median` is ``numpy.median`` without its first-call cost: numpy 2's median checks
its result for NaN through ``numpy.ma``, whose import took 14-28 ms (and a few MB) here,
paid by every command and by the daemon at its first pose.  Same algorithm (partition,
mean of the middle one or two), so the same values bit for bit.  :func:`nanmedian` is
``numpy.nanmedian`` over the rows of a 2-D array likewise: numpy takes a slice of fewer
than 600 values through ``numpy.ma`` too (its masked median sums the middle one or two and
halves: the same values as the mean of the non-NaN slice's middle one or two).

:func:`row_sum`, :func:`row_all`, :func:`row_max`: ``x.sum(1)``, ``x.all(1)``, ``x.max(1)``
of a tall array of a few columns (samples x axes), column by column: numpy reduces a row of
3 values with a loop set up per row (0.6-1.5 ms for 51 k rows, 15-25x the column-wise
form).  The same values bit for bit: below 8 columns numpy adds a row left to right (its
pairwise summation starts at 8), as the column-wise sum does; ``&`` and ``maximum`` are
exact and ``maximum`` propagates NaN as ``max`` does.

:func:`window_var`: ``b.var(1, ddof=ddof)`` of m windows of w rows of a few columns, (m, w, C),
the same steps on a (w, m, C) copy: numpy sums a middle axis C values at a time (~5x slower).
The same values bit for bit: where the columns lie closer in memory than the rows, numpy adds
each window's rows in order, one after the other (pairwise summation is for the innermost
axis only), and so does the sum down the copy's rows; elsewhere it is numpy's own var.
"""
from __future__ import annotations

import numpy as np

__all__ = ["median", "nanmedian", "row_sum", "row_all", "row_max", "row_prod", "window_var"]


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
    mid = part[tuple(idx)]
    if mid.dtype == np.float64:     # np.mean's own steps (the sum over the axis, / the count) without its wrapper
        out = np.add.reduce(mid, axis=axis) / mid.shape[axis]
    else:                           # integers and other floats: np.mean's accumulator types
        out = np.mean(mid, axis=axis)
    if nan_possible:
        last = part.take(-1, axis=axis)
        bad = np.isnan(last)
        if bad.any():
            if isinstance(out, np.generic):
                return last
            np.copyto(out, last, where=bad)
    return out


def nanmedian(a, axis=0):
    """``numpy.nanmedian(a, axis)`` of a 2-D array along axis 0 or 1: each slice's median
    of its non-NaN values; NaN (with numpy's RuntimeWarning) for a slice of NaN only."""
    a = np.asarray(a)
    # float32/float64 only (float16's mean adds in float32, numpy's masked median does not)
    if (a.ndim != 2 or axis not in (0, 1, -1, -2) or a.dtype not in (np.float32, np.float64)
            or a.shape[axis] == 0):
        return np.nanmedian(a, axis=axis)
    lines = a.T if axis in (0, -2) else a
    out = np.empty(len(lines), a.dtype)
    for j, v in enumerate(lines):
        v = v[~np.isnan(v)]
        if len(v):
            out[j] = median(v)
        else:
            import warnings
            warnings.warn("All-NaN slice encountered", RuntimeWarning, stacklevel=2)
            out[j] = np.nan
    return out


def row_sum(x: np.ndarray) -> np.ndarray:
    """``x.sum(1)`` of a 2-D float array, the same values (left to right under 8 columns)."""
    x = np.asarray(x)
    if x.ndim != 2 or x.shape[1] == 0 or x.shape[1] >= 8 or x.dtype.kind != "f":
        return x.sum(1)
    out = x[:, 0].copy()
    for j in range(1, x.shape[1]):
        out += x[:, j]
    return out


def row_all(b: np.ndarray) -> np.ndarray:
    """``b.all(1)`` of a 2-D array."""
    b = np.asarray(b)
    if b.ndim != 2 or b.shape[1] == 0:
        return b.all(1)
    out = b[:, 0].astype(bool)
    for j in range(1, b.shape[1]):
        out &= b[:, j]
    return out


def row_max(x: np.ndarray) -> np.ndarray:
    """``x.max(1)`` of a 2-D float array (NaN where a row holds one)."""
    x = np.asarray(x)
    if x.ndim != 2 or x.shape[1] == 0 or x.dtype.kind != "f":
        return x.max(1)
    out = x[:, 0].copy()
    for j in range(1, x.shape[1]):
        np.maximum(out, x[:, j], out=out)
    return out


def row_prod(x: np.ndarray) -> np.ndarray:
    """``np.prod(x, axis=1)`` of a 2-D array column by column: the same products in the same
    order, without numpy's reduction over a narrow axis (most of the repeat-chance fixed point's time)."""
    out = np.array(x[:, 0], dtype=float)
    for j in range(1, x.shape[1]):
        out *= x[:, j]
    return out


def window_var(b: np.ndarray, ddof: int = 1) -> np.ndarray:
    """``b.var(1, ddof=ddof)`` of a float64 (m, w, C) array: numpy's steps (each window's sum /
    w, the deviations squared, summed, / (w - ddof)) with the windows' rows outermost.  Only
    where numpy adds the window's rows in order: C >= 2 columns lying closer in memory than
    the rows (a C-order array or its column slice); else (one column, or a column-major
    array: numpy sums the window pairwise there) numpy's own var."""
    b = np.asarray(b)
    if (b.ndim != 3 or b.dtype != np.float64 or b.shape[1] - ddof <= 0 or b.shape[2] < 2
            or not 0 < b.strides[2] < b.strides[1]):
        return b.var(1, ddof=ddof)
    w = b.shape[1]
    x = np.array(b.transpose(1, 0, 2), order="C")     # (w, m, C), a copy (centred in place)
    x -= x.sum(0, keepdims=True) / w
    np.multiply(x, x, out=x)
    return x.sum(0) / (w - ddof)
