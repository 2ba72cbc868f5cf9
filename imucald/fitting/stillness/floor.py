"""Helpers of the stillness detector (:mod:`imucald.fitting.stillness.detector`): the noise floor of
the window variances, and where motion starts at the end of a still run.  Pure numpy."""
from __future__ import annotations

import numpy as np

from ...numerics.npstats import row_max, row_sum

__all__ = ["FLOOR_PCT", "FLOOR_WINDOWS", "floors", "floor", "onset"]

FLOOR_PCT = 5.0         #: percentile of the window variances taken as the noise floor
FLOOR_WINDOWS = 300     #: over the last this many non-overlapping windows


def onset(acc: np.ndarray, short: int = 10, allow: float = 0.0) -> int:
    """Index where motion starts at the end of a still run (len(acc) if none): where a
    ``short``-sample moving mean first leaves the first half's mean by 5 of its standard
    errors, on some axis (plus ``allow`` x |mean|: the sine of the angle a hand's sway may
    turn the board from its mean) or in magnitude (a turn leaves the magnitude alone, a
    hand's push does not: no allowance there)."""
    n = len(acc)
    if n < 4 * short:
        return n
    half = n // 2
    x = np.concatenate([acc, np.sqrt(row_sum(acc * acc))[:, None]], 1)
    # the first half's mean and standard deviation: numpy's mean(0) and std(0, ddof=1) of
    # x[:half] written out (the same sum / half; the deviations squared, summed, / (half - 1),
    # square-rooted; x in the layout concatenate gives it, as there), without their wrappers
    m0 = x[:half].sum(0) / half
    dev = x[:half] - m0
    np.multiply(dev, dev, out=dev)
    sd = np.sqrt(dev.sum(0) / (half - 1)) + 1e-12
    c = np.empty((n + 1, 4))                         # running sums of x from 0 (no vstack copy)
    c[0] = 0.0
    c[1:] = x
    np.cumsum(c, 0, out=c)
    ma = (c[half + short:] - c[half:-short]) / short  # ma[i] = mean of x[half + i:half + i + short]
    lim = 5.0 * sd / np.sqrt(short)
    lim[:3] += allow * float(np.sqrt(m0[:3] @ m0[:3]))
    bad = np.flatnonzero(row_max(np.abs(ma - m0) - lim) > 0.0)
    return n if not len(bad) else half + int(bad[0])


def floors(hist: np.ndarray, m: int) -> np.ndarray:
    """The noise floor after each of the last m windows of hist: the FLOOR_PCT percentile of
    the variances of the FLOOR_WINDOWS windows up to it, as ``numpy.percentile`` (method
    'linear') computes it, value for value, for all m at once (np.percentile per window cost
    ~60 us, most of a file's stillness detection); a floor of 0 (quantised, noiseless data)
    becomes the smallest positive variance, or 1e-12."""
    if not np.isfinite(hist).all():           # not from finite samples: numpy's own rules
        return np.array([floor(hist[max(0, len(hist) - m + j + 1 - FLOOR_WINDOWS):len(hist) - m + j + 1])
                         for j in range(m)])
    L = FLOOR_WINDOWS
    pad = np.concatenate([np.full(L - 1, np.inf), hist])     # +inf sorts after every variance
    rows = np.sort(np.lib.stride_tricks.sliding_window_view(pad, L)[-m:], axis=1)
    n = np.minimum(np.arange(len(hist) - m + 1, len(hist) + 1), L)    # real values per row
    vi = (n - 1) * (FLOOR_PCT / 100.0)                       # numpy's virtual index, 'linear'
    prev = np.floor(vi)
    top = vi >= n - 1
    i0 = np.where(top, n - 1, prev).astype(np.intp)
    i1 = np.where(top, n - 1, prev + 1).astype(np.intp)
    a = rows[np.arange(m), i0]
    b = rows[np.arange(m), i1]
    g = vi - prev
    d = b - a
    f = np.where(g >= 0.5, b - d * (1 - g), a + d * g)       # numpy's _lerp
    for j in np.flatnonzero(f <= 0):
        pos = rows[j, :n[j]][rows[j, :n[j]] > 0]
        f[j] = float(pos.min()) if pos.size else 1e-12
    return f


def floor(v: np.ndarray) -> float:
    f = float(np.percentile(v, FLOOR_PCT))
    if f <= 0:  # quantised, noiseless data: the smallest positive variance
        pos = v[v > 0]
        f = float(pos.min()) if pos.size else 1e-12
    return f
