"""The variance of a pose mean from the recording's own within-pose statistics, tremor
included (the twin's noise; issue 25 item 1).

A pose mean over n samples is Theta(n) / n, with Theta the running sum of the readings.
Its variance is D(n) / n^2, where D(tau) = E[(Theta(t + tau) - Theta(t))^2] is the
structure function of the running sum.  White noise of variance s^2 gives D = s^2 tau
(the familiar s^2 / n); hand tremor (a band-limited oscillation at 4-12 Hz, no power near
0 Hz) gives a D that stops growing after a fraction of a second: its running sum is
bounded, and the pose mean holds only the end effect 2 var(int tremor) / n^2.  Taking the
per-sample variance over n (s^2 / n) instead overstates a tremor-filled gyro pose mean by
~30x (the twin was "pessimistic under tremor": ratio 0.17 on hand-held sessions).

Model, per axis, for lags beyond the tremor's correlation time:
D(tau) = a + b tau (a: bounded part, b: white part).  Inside a pose only the running sum
of the readings minus the pose's own mean is seen (a bridge); for the model above its
increments have E = a (1 + tau^2 / n^2) + b tau (1 - tau / n) (derivation: the covariance
of an inner increment with Theta(n) is b tau).  a, b >= 0 are fitted by least squares to
the pooled increments at tau = n/8 .. n/2 of every pose, and each pose mean's variance
is (a + b n) / n^2.

The white part b is kept only where it is clear of twice its jackknife error or where
the bounded part does not dominate (the estimate at least a quarter of the white figure):
b >= 0 clipped from noise is biased upwards and b n dominates the extrapolation; there
the unconstrained least-squares split (unbiased, either sign) is used instead.

Decision (stated error rate): the estimate replaces the white one (s^2 / n) only when it
is below it beyond twice its jackknife standard error over poses (one-sided ~2 %);
otherwise the white figure stands (its colour inflation is handled elsewhere).
"""
from __future__ import annotations

from typing import Dict, Sequence, Tuple

import numpy as np

__all__ = ["pose_mean_variance", "flag_disturbed", "FRACTIONS"]

FRACTIONS = (0.125, 0.1875, 0.25, 0.375, 0.5)    #: lags as fractions of the pose length
MIN_SAMPLES = 16


def _pose_rows(x: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Design rows (len(FRACTIONS), 2) and observed mean squared increments (len, C) of one pose."""
    n = len(x)
    c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x - x.mean(0), axis=0)])
    rows, obs = [], []
    for f in FRACTIONS:
        tau = max(1, int(round(f * n)))
        d = c[tau:] - c[:-tau]
        rows.append([1 + (tau / n) ** 2, tau * (1 - tau / n)])
        obs.append(np.mean(d * d, axis=0))
    return np.array(rows), np.array(obs)


def _nnls2(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """min |A z - y| with z >= 0 for two columns (closed form over the active sets)."""
    best, bz = np.inf, np.zeros(2)
    cands = []
    z = np.linalg.lstsq(A, y, rcond=None)[0]
    cands.append(z)
    for j in (0, 1):
        zz = np.zeros(2)
        a = A[:, j]
        zz[j] = max(float(a @ y) / max(float(a @ a), 1e-300), 0.0)
        cands.append(zz)
    for z in cands:
        if np.all(z >= 0):
            r = float(np.sum((A @ z - y) ** 2))
            if r < best:
                best, bz = r, z
    return bz


def _fit(rows, obs, ns, idx, white=True):
    """a, b per axis from poses ``idx`` (``white`` False: b = 0); each pose's rows scaled by
    1/n (its increments' scale grows with n)."""
    C = obs[idx[0]].shape[1]
    A = np.vstack([rows[i] / ns[i] for i in idx])
    out = np.zeros((2, C))
    for j in range(C):
        y = np.concatenate([obs[i][:, j] / ns[i] for i in idx])
        if white == "ls":
            out[:, j] = np.linalg.lstsq(A, y, rcond=None)[0]
        elif white:
            out[:, j] = _nnls2(A, y)
        else:
            a = A[:, 0]
            out[0, j] = max(float(a @ y) / float(a @ a), 0.0)
    return out


def pose_mean_variance(x: np.ndarray, slices: Sequence[slice]) -> Tuple[np.ndarray, Dict[str, object]]:
    """Variance (N, C) of each pose mean of ``x`` (samples, C) over ``slices`` (sensor
    units squared), and a summary.  Poses shorter than 16 samples get the white figure."""
    ns = np.array([s.stop - s.start for s in slices], float)
    C = x.shape[1]
    s2 = np.array([x[s].var(0, ddof=1) if s.stop - s.start > 1 else np.full(C, np.nan) for s in slices])
    s2_pool = np.nanmedian(s2, axis=0)
    white = s2_pool[None, :] / ns[:, None]
    use = [i for i, s in enumerate(slices) if s.stop - s.start >= MIN_SAMPLES]
    info: Dict[str, object] = {"method": "white", "poses_used": len(use)}
    if len(use) < 5:
        info["note"] = "fewer than 5 poses of 16 samples: per-sample variance over n"
        return white, info
    rows, obs = {}, {}
    for i in use:
        rows[i], obs[i] = _pose_rows(np.asarray(x[slices[i]], float))
    ab = _fit(rows, obs, ns, use)
    ref = np.median(ns[use])
    m = len(use)
    jk_ab = np.array([_fit(rows, obs, ns, [k for k in use if k != i]) for i in use])     # (m, 2, C)
    jse = lambda v: np.sqrt((m - 1) / m * np.sum((v - v.mean(0)) ** 2, axis=0))
    # the white part only where it is clear of its jackknife error: a b >= 0 clipped from
    # noise is biased upwards, and b n dominates the extrapolation to the pose length
    # (only where the bounded part dominates: the pose mean's variance below a quarter of
    # the white figure, a tremor-filled gyro; an accelerometer keeps its white part)
    ratio_ab = (ab[0] + ab[1] * ref) / ref ** 2 / (s2_pool / ref)
    drop_b = (ab[1] < 2 * jse(jk_ab[:, 1])) & (ratio_ab < 0.25)
    if drop_b.any():
        # there the unconstrained least-squares split (unbiased, either sign) replaces it
        ab0 = _fit(rows, obs, ns, use, white="ls")
        jk0 = np.array([_fit(rows, obs, ns, [k for k in use if k != i], white="ls") for i in use])
        ab[:, drop_b] = ab0[:, drop_b]
        jk_ab[:, :, drop_b] = jk0[:, :, drop_b]
    est = lambda ab_: (ab_[0] + ab_[1] * ref) / ref ** 2          # (C,) at the median length
    # jackknife over poses: the standard error of the ratio to the white figure
    full = est(ab) / (s2_pool / ref)
    jk = np.array([est(a_) / (s2_pool / ref) for a_ in jk_ab])
    se = jse(jk)
    lower = full + 2 * se < 1.0                              # clearly below white, per axis
    var = white.copy()
    for j in range(C):
        if lower[j]:
            var[:, j] = np.maximum((ab[0, j] + ab[1, j] * ns) / ns ** 2, 1e-3 * white[:, j])
    info.update({"method": "structure function" if lower.any() else "white",
                 "ratio_to_white": np.round(full, 4).tolist(), "ratio_stderr": np.round(se, 4).tolist(),
                 "bounded_part": ab[0].tolist(), "white_part": ab[1].tolist(),
                 "axes_below_white": lower.tolist()})
    return var, info


def flag_disturbed(s2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Poses whose within-pose variance ``s2`` (n samples each) is far above the robust
    level (hand moved)."""
    med = np.median(s2)
    # chi-square(n-1)/(n-1) upper 99.9 % point ~ 1 + 3.1 sqrt(2/(n-1)); times 1.5 for colour
    lim = med * 1.5 * (1 + 3.1 * np.sqrt(2.0 / np.maximum(n - 1, 1)))
    return s2 > lim
