"""The variance of a pose mean from the recording's own within-pose statistics: hand
tremor and short-correlated coloured noise included (issue 25 item 1 for the gap twin;
the calibration's pose covariance since issue 20's check).

A pose mean over n samples is Theta(n) / n, with Theta the running sum of the readings.
Its variance is D(n) / n^2, where D(tau) = E[(Theta(t + tau) - Theta(t))^2] is the
structure function of the running sum.  White noise of variance s^2 gives D = s^2 tau
(the familiar s^2 / n); hand tremor (a band-limited oscillation at 4-12 Hz, no power near
0 Hz) gives a D that stops growing after a fraction of a second: its running sum is
bounded, and the pose mean holds only the end effect 2 var(int tremor) / n^2.  Taking the
per-sample variance over n (s^2 / n) instead overstates a tremor-filled pose mean (the
gap twin was "pessimistic under tremor": ratio 0.17 on hand-held sessions; calibrate's
standard errors were 2x too wide: z-score RMS 0.47 on simulated hand-held sessions at
3 deg/s).  Noise correlated over a short time (e.g. a low-pass filtered drift, an AR(1)
process of 0.2 s) gives D = a + b tau with b above s^2: the pose mean is noisier than
s^2 / n (z-score RMS 1.8 before).

Model, per axis, for lags beyond the tremor's (or the colour's) correlation time:
D(tau) = a + b tau (a: bounded part, b: white part).  Inside a pose only the running sum
of the readings minus the pose's own mean is seen (a bridge); for the model above its
increments have E = a (1 + tau^2 / n^2) + b tau (1 - tau / n) (derivation: the covariance
of an inner increment with Theta(n) is b tau).  a, b >= 0 are fitted by least squares to
the pooled increments at tau = n/8 .. n/2 of every pose, and each pose mean's variance
is (a + b n) / n^2.  Noise whose structure keeps growing faster than tau over the pose
(flicker, random walk) is beyond this model: fitting/noise/colour.py's Allan inflation is for it.

Where the bounded part dominates (the estimate below a quarter of the white figure: a
tremor-filled gyro) the split into a and b is not read from the structure function: over
lags n/8 .. n/2 a band-pass tremor's D still approaches its bound from above (its angle
has no power at 0 Hz, so its autocorrelation's tail is negative), and b n extrapolates that
slope to the pose length.  On pure tremor (6-12 Hz) the non-negative split overstated the
pose mean's variance 1.2x (its clipped b >= 0 is biased upwards) and the unconstrained one
understated it 0.76x; the bounded part alone is right there (1.01x) but drops the white
part (0.63-0.69x with a weak tremor over the noise).  There b comes from each hold's two
halves instead (:func:`_half_white`): their Hann-weighted means differ by the white noise
only (a Hann window's leakage falls as f^-3; at worst a 4-6 Hz tremor enters a half's
mean at -31.5 dB of its amplitude over 0.5 s, -41.5 dB over 0.75 s), and a is fitted given
that b.  Measured (30-80 simulated tremor records of 30 holds, the estimate over the pose
means' own scatter, pooled): 1.01-1.02 with a 6-12 Hz tremor of 1.5-3 deg/s over white
noise 0.05 deg/s, 0.95-0.98 with tremor 0.15-0.5 deg/s; 0.95-1.04 for a 4-12, 4-6 or 3-8 Hz
tremor over 1-3 s holds (before: 1.4-1.7; with the split's quarter as the only reading of
which axes are tremor-filled, below, 1.0-1.3).  Noise correlated over 0.3-1 s under the
tremor reads 0.62-0.83 (beyond the model, as before).  A
hand's slow sway (0.2-2 Hz) or a drifting bias inside the holds raises the halves'
difference too: pessimistic, never below the truth (the sway's own term: posefloor.py).

Decision (stated error rate): the estimate replaces the white one (s^2 / n) only when it
differs from it beyond twice its jackknife standard error over poses: below it
(``two_sided`` False, the gap twin: one-sided ~2 %), or either way (the calibration:
~5 % of white-noise axes take the estimate, which is then near the white figure
anyway); otherwise the white figure stands.  Measured by bench/calib_se.py (z-scores of
calibrate's parameters against the simulator's truth, docs/guide/hand-held.md).

Which axes are tremor-filled is read twice: the split's estimate below a quarter of the
white figure, or (from 20 holds) the halves' white part below a quarter of the per-sample
variance; the split alone scattered past its quarter on some tremor axes at 400 Hz and on
short holds.  There "below white" is also judged on the halves (their white part clear of
the per-sample variance), not on the white-only fit, which reads a tremor's bound as a
slope.  At 400 Hz (tremor 1.5 deg/s) the estimate over the pose means' scatter went 1.71 ->
1.04, a 4-12 Hz tremor over 1-1.5 s holds 1.14 -> 1.03 (tests/test_posecov.py).
"""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ...numerics.npstats import median, nanmedian

__all__ = ["pose_mean_variance", "pose_mean_variance_parts", "pose_mean_variance_stats", "pose_sf_rows",
           "scale_pose_cov", "scale_pose_cov_stats", "radial_pose_cov",
           "radial_pose_cov_stats", "allan_still_needed", "FRACTIONS", "MIN_SAMPLES",
           "MIN_POSES"]

FRACTIONS = (0.125, 0.1875, 0.25, 0.375, 0.5)    #: lags as fractions of the pose length
MIN_SAMPLES = 16                                 #: shortest pose whose increments count
MIN_POSES = 5                                    #: fewest such poses for an estimate
MAX_HOLDS = 8                                    #: holds a refined daemon pose keeps


def pose_sf_rows(x: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Design rows (len(FRACTIONS), 2) and observed mean squared increments (len, C) of one
    pose's samples x (n, C): the structure function of its bridge (module doc); and the
    white part measured from the pose's halves (C,) (:func:`_half_white`)."""
    x = np.asarray(x, float)
    # means as sum / count: numpy's mean(axis=0) bit for bit, without its wrapper (called
    # for every pose twice, and 5 lags each)
    return _sf_rows(x - x.sum(0) / len(x))


def _pose_stats(parts: List[np.ndarray], centred: Optional[Sequence[np.ndarray]] = None):
    """(ns, s2, sf) of each pose's samples: counts, per-sample variances (ddof 1; NaN for
    one sample) and :func:`pose_sf_rows` (for poses of MIN_SAMPLES or more), from one
    centring of each pose (numpy's ``var(0, ddof=1)``: sum / n, the deviations squared,
    summed, / (n - 1); the same numbers as ``p.var(0, ddof=1)``, without its wrapper).
    ``centred``: each part's ``x - x.sum(0) / n`` when the caller has it already."""
    C = np.asarray(parts[0]).shape[1]
    ns = np.array([len(p) for p in parts], float)
    s2 = np.full((len(parts), C), np.nan)
    sf = []
    for i, p in enumerate(parts):
        x = np.asarray(p, float)
        n = len(x)
        if centred is not None:
            d = centred[i]
        else:
            d = x - x.sum(0) / n if n else x
        if n > 1:
            s2[i] = np.square(d).sum(0) / (n - 1)
        sf.append([(n,) + _sf_rows(d)] if n >= MIN_SAMPLES else [])
    return ns, s2, sf


def _half_white(d: np.ndarray) -> np.ndarray:
    """The white part b (C,) (the per-sample variance of a flat noise spectrum) from one
    pose's samples or deviations ``d`` (n, C): the Hann-weighted means of its two halves
    differ by white noise of variance 2 k b (k = sum w^2 / (sum w)^2), while a hand's
    tremor (above ~4 Hz, several Hann bins over a half of 0.5 s or more) barely leaks into
    either mean.  One degree of freedom per axis: pooled over the holds by the caller."""
    h = len(d) // 2
    w = np.hanning(h + 2)[1:-1]
    sw = float(w.sum())
    return np.square((w @ d[:h] - w @ d[h:2 * h]) / sw) / (2.0 * float(w @ w) / sw ** 2)


def _sf_rows(d: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`pose_sf_rows` from the pose's deviations from its mean."""
    n = len(d)
    hw = _half_white(d)
    if d.flags.c_contiguous:                   # [0; cumsum(d)] without a vstack copy (a C-
        c = np.empty((n + 1, d.shape[1]))      # order array, as vstack makes it from C-order d)
        c[0] = 0.0
        np.cumsum(d, axis=0, out=c[1:])
    else:                                      # vstack's own layout: the sums below follow it
        c = np.vstack([np.zeros((1, d.shape[1])), np.cumsum(d, axis=0)])
    rows, obs = [], []
    for f in FRACTIONS:
        tau = max(1, int(round(f * n)))
        d = c[tau:] - c[:-tau]
        rows.append([1 + (tau / n) ** 2, tau * (1 - tau / n)])
        # (d * d).sum(0) (squared in place: the same products), not einsum: einsum adds with
        # a fused multiply-add where the CPU has one (aarch64: a Raspberry Pi), and the last
        # bits would differ between a Pi and a PC
        np.multiply(d, d, out=d)
        obs.append(d.sum(0) / len(d))
    return np.array(rows), np.array(obs), hw


def _jack_stats(rows, obs, ns):
    """Each pose's 2x2 normal-equation statistics (A_e^T A_e, A_e^T y_e, y_e^T y_e; each
    pose's rows scaled by 1/n: its increments' scale grows with n), totalled over all poses
    (first) and over each leave-one-pose-out fold (a fold's are the totals less its pose's,
    so the m folds cost O(m), not m refits).  Returns (G (m+1, 2, 2), h (m+1, 2, C),
    yy (m+1, C))."""
    A = rows / ns[:, None, None]                      # (E, L, 2)
    Y = obs / ns[:, None, None]                       # (E, L, C)
    G_e = np.einsum("eli,elj->eij", A, A)             # (E, 2, 2)
    h_e = np.einsum("eli,elc->eic", A, Y)             # (E, 2, C)
    yy_e = np.einsum("elc,elc->ec", Y, Y)             # (E, C)
    G = np.concatenate([G_e.sum(0)[None], G_e.sum(0)[None] - G_e])
    h = np.concatenate([h_e.sum(0)[None], h_e.sum(0)[None] - h_e])
    yy = np.concatenate([yy_e.sum(0)[None], yy_e.sum(0)[None] - yy_e])
    return G, h, yy


def _fit_jack(stats, white=True):
    """a, b per axis on all poses (2, C) and on each leave-one-pose-out fold (m, 2, C) from
    :func:`_jack_stats`; ``white`` True: both non-negative, "b": the white part alone
    (a = 0), or an array (m + 1, C): b as given for all poses and each fold, a >= 0 fitted
    given it."""
    out = _solve_stats(*stats, white)
    return out[0], out[1:]


def _solve_stats(G, h, yy, white):
    """(F, 2, C) fits from (F, 2, 2), (F, 2, C), (F, C) statistics (see :func:`_fit_jack`)."""
    F, _, C = h.shape
    out = np.zeros((F, 2, C))
    if isinstance(white, np.ndarray):
        out[:, 1] = white
        out[:, 0] = np.maximum((h[:, 0] - G[:, 0, 1][:, None] * white) / G[:, 0, 0][:, None], 0.0)
        return out
    if white == "b":
        out[:, 1] = np.maximum(h[:, 1] / G[:, 1, 1][:, None], 0.0)
        return out
    ls = np.linalg.solve(G, h)                       # (F, 2, C)
    # non-negative: the least-squares split when feasible, else the better one-column fit
    # (the candidates in this order, the first of equal residuals kept)
    cands = [ls, np.zeros_like(ls), np.zeros_like(ls)]
    cands[1][:, 0] = np.maximum(h[:, 0] / G[:, 0, 0][:, None], 0.0)
    cands[2][:, 1] = np.maximum(h[:, 1] / G[:, 1, 1][:, None], 0.0)
    best = np.full((F, C), np.inf)
    for z in cands:
        r = yy - 2 * np.einsum("fic,fic->fc", z, h) + np.einsum("fic,fij,fjc->fc", z, G, z)
        take = np.all(z >= 0, axis=1) & (r < best)
        best = np.where(take, r, best)
        out = np.where(take[:, None, :], z, out)
    return out


def pose_mean_variance(x: np.ndarray, slices: Sequence[slice], two_sided: bool = False
                       ) -> Tuple[np.ndarray, Dict[str, object]]:
    """Variance (N, C) of each pose mean of ``x`` (samples, C) over ``slices`` (sensor
    units squared), and a summary.  Poses shorter than 16 samples get the white figure."""
    return pose_mean_variance_parts([x[s] for s in slices], two_sided)


def pose_mean_variance_parts(parts: List[np.ndarray], two_sided: bool = False
                             ) -> Tuple[np.ndarray, Dict[str, object]]:
    """:func:`pose_mean_variance` from each pose's samples (a list of (n_i, C) arrays)."""
    if not parts:
        return pose_mean_variance_stats(np.zeros(0), np.zeros((0, 1)), [], two_sided)
    return pose_mean_variance_stats(*_pose_stats(parts), two_sided)


def _pose_vars(white, ab, lower, higher, sf, ns) -> np.ndarray:
    """Each pose mean's variance (N, C): the structure function's (a K + b n) / n^2 on the
    axes it decided, the white figure elsewhere."""
    # each pose's number of holds (one, unless a daemon refined it; a daemon keeps the
    # longest MAX_HOLDS: the others are counted at the kept ones' mean length)
    K = np.array([n / np.mean([e[0] for e in holds]) if len(holds) else 1.0 for holds, n in zip(sf, ns)])
    var = white.copy()
    for j in range(white.shape[1]):
        if lower[j] or higher[j]:
            sf_var = (ab[0, j] * K + ab[1, j] * ns) / ns ** 2
            var[:, j] = np.maximum(sf_var, (1.0 if higher[j] else 1e-3) * white[:, j])
    return var


def _ratio_to_white(ab: np.ndarray, ref: float, s2_pool: np.ndarray) -> np.ndarray:
    """The variance of a mean over the median pose length ``ref`` from a, b (..., 2, C), over
    the white figure s2 / ref: (C,) for one fit, (m, C) for the folds."""
    return (ab[..., 0, :] + ab[..., 1, :] * ref) / ref ** 2 / (s2_pool / ref)


def _tremor_axes(stats, ab: np.ndarray, jk_ab: np.ndarray, hw: np.ndarray, s2_pool: np.ndarray,
                 ref: float) -> Tuple[np.ndarray, np.ndarray]:
    """The axes where the bounded part dominates (a tremor-filled gyro, or an accelerometer
    a lever arm's tremor fills), and whether the halves' white part is clearly below the
    per-sample variance there; on those axes ``ab`` (2, C) and ``jk_ab`` (m, 2, C) are
    replaced in place by the white part from the holds' halves ``hw`` (m, C), pooled (and
    per leave-one-out fold), and a fitted given it (module doc).

    An axis is tremor-filled when the split's pose-mean variance is below a quarter of the
    white figure, or the halves' white part below a quarter of the per-sample variance
    (the split itself scatters: at 400 Hz some tremor axes read 0.26-0.36 and kept it,
    2.7-3.4x the pose means' scatter).  On white noise the halves' part is the per-sample
    variance times a mean of m one-degree chi-squares over m: below a quarter of it by
    chance with probability 3e-4 at m = 20 holds (1e-5 at 30; 0.9 % at 10), so the second
    reading needs 20 holds.

    "Below white" on those axes: the white-only fit reads the tremor's bound as a slope
    (its ratio ~5x the estimate's: at 400 Hz 0.12-0.15 -> 0.6-0.8, not clear of 1, and the
    white figure stood: twin ratio 0.48-0.64), so the test there is the halves' own: their
    white part (the noise that averages down) below the per-sample variance by twice its
    standard error over the holds (white noise: ratio 1)."""
    m = len(hw)
    white_hw = hw.mean(0) / s2_pool
    bounded = (_ratio_to_white(ab, ref, s2_pool) < 0.25) | ((white_hw < 0.25) & (m >= 20))
    if bounded.any():
        b = np.concatenate([hw.mean(0)[None], (hw.sum(0) - hw) / (m - 1)])   # all, each fold
        abw, jkw = _fit_jack(stats, white=b)
        ab[:, bounded] = abw[:, bounded]
        jk_ab[:, :, bounded] = jkw[:, :, bounded]
    hw_below = white_hw + 2 * hw.std(0, ddof=1) / np.sqrt(m) / s2_pool < 1.0
    return bounded, hw_below


def pose_mean_variance_stats(ns: np.ndarray, s2: np.ndarray, sf: Sequence[Sequence[tuple]],
                             two_sided: bool = False) -> Tuple[np.ndarray, Dict[str, object]]:
    """:func:`pose_mean_variance` from per-pose statistics, for poses whose samples are
    gone (the daemon keeps these, a few hundred bytes a pose): ``ns`` (N,) samples per
    pose, ``s2`` (N, C) per-sample variances, ``sf[i]`` the holds averaged into pose i,
    each (n_k, rows, obs, the halves' white part) of :func:`pose_sf_rows` (one for a pose
    from one hold, several for a pose refined by later holds, none when unknown, e.g. read
    back from a file).
    A pose of K holds has variance (K a + b n) / n^2 (independent holds)."""
    ns = np.asarray(ns, float)
    s2 = np.asarray(s2, float).reshape(len(ns), -1)
    C = s2.shape[1]
    if len(ns) == 0 or not np.isfinite(s2).any():
        return np.full((len(ns), C), np.nan), {"method": "white", "poses_used": 0}
    s2_pool = nanmedian(s2, axis=0)
    white = s2_pool[None, :] / ns[:, None]
    ent = [e for holds in sf for e in holds if e[0] >= MIN_SAMPLES]
    info: Dict[str, object] = {"method": "white", "poses_used": len(ent)}
    if len(ent) < MIN_POSES or not np.all(s2_pool > 0):
        info["note"] = (f"fewer than {MIN_POSES} poses of {MIN_SAMPLES} samples (or a constant "
                        f"axis): per-sample variance over n")
        return white, info
    rows = np.array([e[1] for e in ent], float)         # (E, len(FRACTIONS), 2)
    obs = np.array([e[2] for e in ent], float)          # (E, len(FRACTIONS), C)
    hn = np.array([e[0] for e in ent], float)
    stats = _jack_stats(rows, obs, hn)
    ab, jk_ab = _fit_jack(stats)
    ref = median(hn)
    m = len(ent)
    jse = lambda v: np.sqrt((m - 1) / m * np.sum((v - v.mean(0)) ** 2, axis=0))
    bounded, hw_below = _tremor_axes(stats, ab, jk_ab, np.array([e[3] for e in ent], float),
                                     s2_pool, ref)
    # jackknife over poses: the standard error of the ratio to the white figure
    full = _ratio_to_white(ab, ref, s2_pool)
    jk = _ratio_to_white(jk_ab, ref, s2_pool)
    se = jse(jk)
    # the white part alone (a = 0), one parameter per axis: unbiased on white noise (1.00 of
    # white) where the constrained split is not (its clipping picks the bounded part alone
    # on some white axes: 0.89 of white on average)
    ab_ls, jk_ls = _fit_jack(stats, white="b")
    full_ls = _ratio_to_white(ab_ls, ref, s2_pool)
    se_ls = jse(_ratio_to_white(jk_ls, ref, s2_pool))
    # clearly below white, per axis: by twice the estimate's jackknife error AND by twice
    # the white-only fit's error, which is what the estimate scatters by when the noise
    # is white (a variance's error shrinks with the estimate, so a falsely low estimate
    # came with a falsely small error: `full + 2 se < 1` alone fired on 8.4 % of white
    # axes against the rule's 2.3 %, tests/test_gap_blind_calibration.py)
    lower = (full + 2 * se < 1.0) & (full_ls < 1.0 - 2 * se_ls / np.maximum(full_ls, 1e-12))
    # on tremor-filled axes the second test is the halves' (_tremor_axes)
    lower = np.where(bounded, (full + 2 * se < 1.0) & hw_below, lower)
    higher = np.zeros(C, bool)
    if two_sided:
        # above white: the white part alone, one parameter per axis: the split into a and b
        # is ill-conditioned over lags n/8..n/2 (its jackknife error came out as large as
        # the estimate on AR(1) noise, and most coloured axes stayed white); a
        # short-correlated colour's negative a biases b low by a few per cent
        higher = (full_ls - 2 * se_ls > 1.0) & ~lower
        ab[:, higher] = ab_ls[:, higher]
        full[higher], se[higher] = full_ls[higher], se_ls[higher]
    var = _pose_vars(white, ab, lower, higher, sf, ns)
    info.update({"method": "structure function" if (lower | higher).any() else "white",
                 "ratio_to_white": np.round(full, 4).tolist(), "ratio_stderr": np.round(se, 4).tolist(),
                 "bounded_part": ab[0].tolist(), "white_part": ab[1].tolist(),
                 "axes_below_white": lower.tolist(), "axes_above_white": higher.tolist()})
    return var, info


def scale_pose_cov(parts: List[np.ndarray], cov_mean: np.ndarray,
                   centred: Optional[Sequence[np.ndarray]] = None
                   ) -> Tuple[np.ndarray, Dict[str, object]]:
    """Each pose's covariance of the mean (N, C, C), formed as its own sample covariance
    over n, rescaled per axis by the structure-function estimate's ratio to the white
    figure (:func:`pose_mean_variance_parts`, two-sided): S_i cov_i S_i with
    S_i = diag(sqrt(ratio_i)).  Each pose keeps its own scatter (a disturbed pose stays
    noisier); the averaging is what changes.  Returns (covariances, summary)."""
    if len(parts) == 0:
        return np.asarray(cov_mean, float), {"method": "white", "poses_used": 0}
    return scale_pose_cov_stats(*_pose_stats(parts, centred), cov_mean)


def scale_pose_cov_stats(ns: np.ndarray, s2: np.ndarray, sf: Sequence[Sequence[tuple]],
                         cov_mean: np.ndarray) -> Tuple[np.ndarray, Dict[str, object]]:
    """:func:`scale_pose_cov` from per-pose statistics (:func:`pose_mean_variance_stats`)."""
    cov_mean = np.asarray(cov_mean, float)
    if len(ns) == 0:
        return cov_mean, {"method": "white", "poses_used": 0}
    var, info = pose_mean_variance_stats(ns, s2, sf, two_sided=True)
    if info["method"] == "white":
        return cov_mean, info
    ns = np.asarray(ns, float)
    s2_pool = nanmedian(np.asarray(s2, float).reshape(len(ns), -1), axis=0)
    ratio = var / (s2_pool[None, :] / ns[:, None])
    s = np.sqrt(np.where(np.isfinite(ratio) & (ratio > 0), ratio, 1.0))
    return cov_mean * s[:, :, None] * s[:, None, :], info


def radial_pose_cov(parts: List[np.ndarray], means: np.ndarray, cov_mean: np.ndarray
                    ) -> Tuple[np.ndarray, Dict[str, object]]:
    """The accelerometer's pose covariances (N, 3, 3) with the variance along each pose's
    mean direction set from the structure function of the RADIAL series (the samples
    projected on that direction), by a congruence S cov S with S = I + (f - 1) u u^T (the
    tangential block is left as it is).  A hand sways the board's direction by tenths of a
    degree at 0.2-2 Hz: the per-axis structure function rightly counts that wander in the
    pose mean's direction, but the norm model (|a| = 1 g) does not see a direction, and the
    sway inflated the norm residuals' variance ~10x (chi-square 0.7-2.9 on 16 degrees of
    freedom on simulated swaying sessions).  Returns (covariances, summary)."""
    cov_mean = np.asarray(cov_mean, float)
    if len(parts) == 0:
        return cov_mean, {"method": "white", "poses_used": 0}
    u = np.asarray(means, float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    ns, s2, sf = _pose_stats([(np.asarray(p, float) @ ui)[:, None] for p, ui in zip(parts, u)])
    return radial_pose_cov_stats(ns, s2[:, 0], sf, means, cov_mean)


def radial_pose_cov_stats(ns: np.ndarray, s2: np.ndarray, sf: Sequence[Sequence[tuple]],
                          means: np.ndarray, cov_mean: np.ndarray) -> Tuple[np.ndarray, Dict[str, object]]:
    """:func:`radial_pose_cov` from per-pose statistics of the radial series, for poses whose
    samples are gone (the daemon's): ``ns`` (N,) samples, ``s2`` (N,) the radial per-sample
    variances, ``sf[i]`` the structure functions of the radial series of the holds averaged
    into pose i (:func:`pose_mean_variance_stats`), ``means`` (N, 3) the pose means."""
    cov_mean = np.asarray(cov_mean, float)
    if len(ns) == 0:
        return cov_mean, {"method": "white", "poses_used": 0}
    u = np.asarray(means, float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    ns = np.asarray(ns, float)
    s2 = np.asarray(s2, float).reshape(len(ns), 1)
    target, info = scale_pose_cov_stats(ns, s2, sf, (s2[:, 0] / ns)[:, None, None])
    cur = np.einsum("ni,nij,nj->n", u, cov_mean, u)
    f = np.sqrt(target[:, 0, 0] / cur)
    f = np.where(np.isfinite(f) & (f > 0), f, 1.0)
    S = np.eye(3)[None] + (f - 1.0)[:, None, None] * np.einsum("ni,nj->nij", u, u)
    return S @ cov_mean @ S, info


def allan_still_needed(noise_info) -> bool:
    """Whether the Allan colour inflation (fitting/noise/colour.py, read from the longest still
    stretch) should still multiply covariances formed by :func:`scale_pose_cov`: only
    when the structure function left every axis at the white figure.  Where it decided,
    it measured the pose mean's variance at the poses' own length, which is what the
    Allan inflation estimates too: applied both, the colour would be counted twice (on
    the IMU-TK Xsens file the product came out at chi-square / dof 1.6 and held-out
    residuals 1.27x their predicted std; the structure function alone, with the fit's
    excess-scatter test, 0.95x)."""
    return not (isinstance(noise_info, dict) and noise_info.get("method") == "structure function")
