"""The gyro's own still stretch inside each accelerometer-led pose.

The calibration's stillness detector is led by the accelerometer (hand tremor must not
break a pose) and lets the gyro veto only a window's turn above a limit that adapts to the
session (0.5 deg on a bench, up to ``max_turn_deg`` = 3 deg under a hand's sway; see
fitting/stillness/detector.py).  The slow start and end of a smooth turn therefore stay inside a pose: the
accelerometer's variance has not risen yet, but the gyro already reads the turn.
For the accelerometer's norm this is harmless (a tilt does not change |a|); a gyro
pose mean, whose noise is a few mdeg/s, carries the turn's rate (0.4 deg over 0.5 s in
a 15 s pose moves the mean by ~30 mdeg/s), and the gap diagnosis would report it as
an effect.

:func:`trim_turns` cuts each pose's ends while the gyro, smoothed over ``smooth_s``
(a few tremor cycles at 6-12 Hz), lies more than ``k`` robust standard deviations from
the pose's central level (median and MAD of the smoothed rate over the middle half,
so tremor raises the threshold with the scatter it causes).  Only the ends are cut:
a pose is one contiguous stretch.  Derivation of the defaults: a raised-cosine turn's
rate grows as u^2 from its start, so the part below the threshold (k = 5 x ~7 mdeg/s
for an MPU-6050 at 50 Hz and 0.5 s smoothing) turns < 0.001 deg; the smoothed
rate of a still gyro exceeds 5 robust sd in ~1e-6 of its values.
"""
from __future__ import annotations

from typing import Dict, List, Sequence, Tuple

import numpy as np

__all__ = ["trim_turns", "split_at_time_gaps"]


def trim_turns(gyro_dps: np.ndarray, slices: Sequence[slice], rate_hz: float, k: float = 5.0,
               smooth_s: float = 0.5, min_keep: float = 0.5) -> Tuple[List[slice], Dict[str, object]]:
    """Slices with the turning ends cut (per pose; a pose keeps at least ``min_keep`` of its
    samples, else it is left as it was) and {"trimmed_s": per-pose seconds cut}."""
    m = max(3, int(round(smooth_s * rate_hz)))
    ker = np.ones(m) / m
    out: List[slice] = []
    cut = []
    for s in slices:
        g = gyro_dps[s]
        n = len(g)
        if n < 4 * m:
            out.append(s)
            cut.append(0.0)
            continue
        sm = np.stack([np.convolve(g[:, j], ker, mode="valid") for j in range(3)], axis=1)   # (n-m+1, 3)
        core = sm[len(sm) // 4: 3 * len(sm) // 4]
        c = np.median(core, axis=0)
        sd = 1.4826 * np.median(np.abs(core - c), axis=0)
        sd = np.maximum(sd, 1e-12)
        quiet = np.all(np.abs(sm - c) <= k * sd, axis=1)       # window i covers samples i..i+m-1
        idx = np.flatnonzero(quiet)
        if len(idx) == 0:
            out.append(s)
            cut.append(0.0)
            continue
        a, b = int(idx[0]), int(idx[-1]) + m                    # samples a..b-1 in quiet windows only
        if b - a < min_keep * n:
            out.append(s)
            cut.append(0.0)
            continue
        out.append(slice(s.start + a, s.start + b))
        cut.append((n - (b - a)) / rate_hz)
    return out, {"trimmed_s": np.round(cut, 2).tolist()}


def split_at_time_gaps(t_s: np.ndarray, acc: np.ndarray, slices: Sequence[slice], rate_hz: float,
                       max_gap_s: float = 0.5, k: float = 6.0) -> List[slice]:
    """Cut still slices where the time stamps jump by more than ``max_gap_s`` (and 10 sample
    periods) and the accelerometer's mean over the half second before differs from the
    half second after by more than ``k`` standard errors on some axis: the board moved
    while nothing was recorded (recordings appended, samples lost during a turn).  The
    stillness detector's windows on either side of such a jump are each quiet, so it keeps
    one pose across it.  A logger's pauses with the board unmoved (bursty sampling) stay
    inside the pose."""
    lim = max(max_gap_s, 10.0 / rate_hz)
    m = max(5, int(round(0.5 * rate_hz)))
    out: List[slice] = []
    for s in slices:
        gaps = np.flatnonzero(np.diff(t_s[s]) > lim) + 1 + s.start
        cuts = []
        for g in gaps:
            a, b = acc[max(s.start, g - m):g], acc[g:min(s.stop, g + m)]
            if len(a) < 3 or len(b) < 3:
                continue
            se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b)) + 1e-12
            if np.any(np.abs(a.mean(0) - b.mean(0)) > k * se):
                cuts.append(int(g - s.start))
        edges = [0, *cuts, s.stop - s.start]
        out += [slice(s.start + x, s.start + y) for x, y in zip(edges[:-1], edges[1:]) if y > x]
    return out
