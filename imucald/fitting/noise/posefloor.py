"""What a still pose's mean carries beyond the sample noise over n: the net rotation of a
swaying hand, the quantisation floor of an un-dithered converter, and the samples a held
column repeats.  Pure numpy; used by the gap twin (gap/diagnose.py) and open to calibrate.

Sway (hand-held board, slow angular wander within a "still" pose).
    A gyro pose mean over T seconds is bias + (theta(T) - theta(0)) / T: the hand's net
    rotation over the hold.  A wander of 0.5 deg over 5 s is 0.1 dps, far above the white
    noise of the mean; the within-pose structure function does not see it (inside a pose
    only the running sum minus the pose's own mean is observed: the net rotation is exactly
    what that removes).  The accelerometer sees the tilt change between the start and the
    end of the hold: a fixed gravity vector seen from a rotating body obeys du/dt = -w x u,
    so du = u x dtheta and the tilt across u (mean direction) is theta_perp = u(t) x u.
    Inside the pose the gyro's own bridge (running sum of its readings minus their mean)
    is theta(t) - theta(0) - (t / T) dtheta; the accelerometer's tilt minus the gyro's
    bridge (across u) is therefore a straight line whose slope is dtheta_perp / T, the
    sway's share of the pose mean (tremor and every within-pose wobble cancel; window means
    at the ends were tried first and smooth away a 1-2 Hz sway the pose mean holds).  Per
    pose that slope r_i is noisy (on a bench ~3x noisier than the gyro mean itself), so it
    is not subtracted; its *covariance* with the gyro pose mean's deviation
    from the common bias, mean_i (g_i - b) . r_i, is unbiased for the sway's rotation
    variance whatever the noise (the two sensors' noises are independent; Earth's rate and
    a g-sensitivity do not correlate with a random sway).  Rotation variance per axis =
    that over the two observed components / 2 (the component about gravity, unobserved
    without a heading reference, is taken as large as the mean of the other two).  Its
    angle variance S (deg^2) is pooled over poses (T_i^2 c_i: a stationary sway's net
    rotation does not grow with the hold); S / T_i^2 per axis of pose i is the pose mean's
    motion variance (tremor's end effect included: the accelerometer sees that net rotation
    too).  It is used only when it is clear of its standard error over poses (one-sided
    ~16 %) (S + SE was tried: gyro twin ratios 0.82-0.91 on simulated hand-held nulls
    against 0.85-0.99 with S, no false alarm either way in 60).  The caller takes
    the larger of it and the within-pose figure per pose and axis: the within-pose figure
    holds the sensor noise and, on a bench or under tremor alone, the motion as well (a
    sum would count the motion twice: measured on simulated hand-held sessions, the sum
    overstated the pose-mean variance 1.4-2.1x, the larger of the two 1.0-1.24x).

Accelerometer under sway: the norm model |a| = 1 g is insensitive to direction (to first
order), so the noise that matters is the radial component, a . u (u the pose's mean
direction): :func:`radial_series`.

Quantisation (Widrow & Kollar, "Quantization Noise", Cambridge UP 2008, ch. 4-5;
Gray & Stockham, IEEE Trans. IT 39(3) 1993).
    Q(x) = LSB round(x / LSB); the error e(x) = Q(x) - x is a sawtooth,
    e(x) = (LSB / pi) sum_k (-1)^k / k sin(2 pi k x / LSB).  With x = mu + n, n ~ N(0, s^2),
    the expectation over the noise (what a long pose mean tends to) is
    E_n e = (LSB / pi) sum_k (-1)^k / k sin(2 pi k mu / LSB) exp(-2 pi^2 k^2 s^2 / LSB^2):
    a deterministic offset that does not average down.  Over poses, mu is uniform within
    the LSB, each sin^2 averages 1/2, so the offset's variance is
        V_q(s) = sum_k LSB^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 s^2 / LSB^2)
    (LSB^2 / 12 at s = 0; below 1e-7 LSB^2 from s = LSB / 2 up: :func:`quantisation_floor`).
    The quantised samples' own variance, averaged over mu, is s^2 + LSB^2 / 12 - V_q(s)
    (by Stein's lemma the noise-error covariance averages to 0 over mu), increasing in s:
    :func:`noise_before_quantisation` inverts it.  The LSB, when the chip's is not given,
    is the spacing of the distinct values inside the poses (:func:`estimate_lsb`).

Held columns (a magnetometer read at its own 75 or 100 Hz inside a 400 Hz log).
    Rows that repeat the previous reading of a sensor group are not new samples; a pose mean
    over n rows made of runs of lengths L_r has the variance s^2 sum_r L_r^2 / n^2, so its
    effective sample count is n^2 / sum_r L_r^2 (:func:`run_effective_counts`).
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from ...numerics.npstats import median

__all__ = ["quantisation_floor", "noise_before_quantisation", "estimate_lsb", "run_effective_counts",
           "radial_series", "sway_rotation_variance", "tilt_wander_test", "tilt_wander_test_parts",
           "tilt_wander_test_stats", "pose_quantisation_floor"]

_K = np.arange(1, 401, dtype=float)     #: the tail beyond is below 0.2 % of LSB^2 / 12


def quantisation_floor(lsb: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Variance (units^2) over poses of a pose mean's quantisation offset, for a quantiser of
    step ``lsb`` and Gaussian noise ``sigma`` before it (same units; broadcast).  0 where
    lsb is 0 (not quantised)."""
    lsb = np.asarray(lsb, float)
    sigma = np.asarray(sigma, float)
    L = np.where(lsb > 0, lsb, 1.0)
    r2 = (sigma / L)[..., None] ** 2
    s = np.sum(np.exp(-4 * math.pi ** 2 * _K ** 2 * r2) / (2 * math.pi ** 2 * _K ** 2), axis=-1)
    return np.where(lsb > 0, s * L ** 2, 0.0)


def noise_before_quantisation(var_quantised: np.ndarray, lsb: np.ndarray) -> np.ndarray:
    """The noise sd before the quantiser from the quantised samples' variance (averaged over
    the position within the LSB): solves s^2 + LSB^2/12 - V_q(s) = var_quantised (monotone
    in s).  Where lsb is 0: sqrt(var)."""
    v = np.atleast_1d(np.asarray(var_quantised, float))
    lsb = np.broadcast_to(np.asarray(lsb, float), v.shape)
    out = np.sqrt(np.maximum(v, 0.0))
    q = lsb > 0
    if not np.any(q):
        return out
    grid = np.linspace(0.0, 4.0, 401)                                   # s / LSB
    f = grid ** 2 + 1 / 12 - quantisation_floor(np.ones_like(grid), grid)   # var / LSB^2, increasing
    y = v[q] / lsb[q] ** 2
    # beyond the grid Sheppard's correction is exact to 1e-100
    s = np.where(y > f[-1], np.sqrt(np.maximum(y - 1 / 12, 0.0)), np.interp(y, f, grid))
    out[q] = s * lsb[q]
    return out


def estimate_lsb(x: np.ndarray, slices: Sequence[slice], max_values: int = 4000) -> np.ndarray:
    """Quantisation step (C,) of each column of ``x`` (samples, C) from the spacing of the
    distinct values inside the still stretches ``slices``: the smallest spacing seen, kept
    only when at least 95 % of the spacings are whole multiples of it (within 1 %) and the
    values fill fewer distinct levels than samples (0: the column is not on a grid)."""
    x = np.asarray(x, float)
    C = x.shape[1]
    out = np.zeros(C)
    for j in range(C):
        d, nval, nsamp = [], 0, 0
        for s in slices:
            v = x[s, j]
            v = v[np.isfinite(v)]
            if len(v) < 4:
                continue
            u = np.unique(v)
            nval += len(u)
            nsamp += len(v)
            if len(u) > 1:
                d.append(np.diff(u))
            if nsamp > max_values * 20:
                break
        if not d or nval >= 0.9 * nsamp:
            continue
        d = np.concatenate(d)
        scale = max(float(np.max(np.abs(x[np.isfinite(x[:, j]), j]))), 1e-300)
        d = d[d > 1e-9 * scale]
        if len(d) < 10:
            continue
        step = float(np.quantile(d, 0.02))
        m = d / step
        if np.mean(np.abs(m - np.round(m)) < 0.01) >= 0.95:
            # refine: the mean of the spacings that are one step
            one = np.abs(m - 1) < 0.01
            out[j] = float(np.mean(d[one])) if one.any() else step
    return out


def run_effective_counts(x: np.ndarray, slices: Sequence[slice]) -> np.ndarray:
    """Effective sample count (N,) of each slice of ``x`` (rows, C: one sensor group) whose
    rows may repeat the previous reading: n^2 / sum_r L_r^2 over the runs of identical rows."""
    x = np.asarray(x)
    out = np.zeros(len(slices))
    for i, s in enumerate(slices):
        v = x[s]
        n = len(v)
        if n < 2:
            out[i] = n
            continue
        new = np.r_[True, np.any(v[1:] != v[:-1], axis=1)]
        L = np.diff(np.r_[np.flatnonzero(new), n])
        out[i] = n * n / float(np.sum(L.astype(float) ** 2))
    return out


def radial_series(acc_g: np.ndarray, slices: Sequence[slice]) -> np.ndarray:
    """(samples, 1): each still stretch's samples projected on its mean direction (the
    component the norm model |a| = 1 g sees; 0 outside the stretches)."""
    a = np.asarray(acc_g, float)
    out = np.zeros((len(a), 1))
    for s in slices:
        m = a[s].mean(0)
        out[s, 0] = a[s] @ (m / max(float(np.linalg.norm(m)), 1e-300))
    return out


def tilt_wander_test(acc_g: np.ndarray, slices: Sequence[slice], min_samples: int = 16) -> Dict[str, object]:
    """:func:`tilt_wander_test_parts` on the still stretches ``slices`` of ``acc_g``."""
    a = np.asarray(acc_g, float)
    return tilt_wander_test_parts([a[s] for s in slices], min_samples)


def tilt_wander_test_parts(parts: Sequence[np.ndarray], min_samples: int = 16,
                           means: Optional[Sequence[np.ndarray]] = None) -> Dict[str, object]:
    """Whether the accelerometer's direction wanders within the still stretches (each pose's
    samples, (n_i, 3) g): the mean over poses of log(tangential / radial per-sample variance)
    (tangential: the mean of the two components across the pose's mean direction) above 2 of
    its standard errors over poses (one-sided ~2 %; isotropic sensor noise gives 0).
    ``means``: each part's ``x.sum(0) / n`` when the caller has it already (the same numbers)."""
    lr = []
    for i, x in enumerate(parts):
        x = np.asarray(x, float)
        n = len(x)
        if n < min_samples:
            continue
        # numpy's mean, var and cov steps without their wrappers (called for every pose of
        # every calibrate): the same operations on the same arrays, so the same numbers
        m = x.sum(0) / n if means is None else means[i]      # x.mean(0)
        u = m / max(math.sqrt(float(m.dot(m))), 1e-300)      # np.linalg.norm(m)
        y = x @ u
        dy = y - y.sum() / n
        vr = float(np.square(dy).sum() / (n - 1))            # np.var(y, ddof=1)
        X = np.array(x.T, ndmin=2, dtype=np.float64)         # np.cov(x.T), as numpy forms it
        X -= (X.sum(1) / n)[:, None]
        c = np.dot(X, X.T.conj())
        c *= np.true_divide(1, n - 1)
        vt = (float(np.trace(c)) - vr) / 2.0
        if vr > 0 and vt > 0:
            lr.append(math.log(vt / vr))
    return _wander_decision(lr)


def tilt_wander_test_stats(ns: np.ndarray, means: np.ndarray, sample_covs: np.ndarray,
                           min_samples: int = 16) -> Dict[str, object]:
    """:func:`tilt_wander_test_parts` from each pose's count (N,), mean (N, 3) g and
    within-pose sample covariance (N, 3, 3) g^2, for poses whose samples are gone (the
    daemon's): the radial variance is u^T S u, the tangential (trace S - u^T S u) / 2."""
    lr = []
    for n, m, S in zip(np.asarray(ns), np.asarray(means, float), np.asarray(sample_covs, float)):
        if n < min_samples:
            continue
        u = m / max(float(np.linalg.norm(m)), 1e-300)
        vr = float(u @ S @ u)
        vt = (float(np.trace(S)) - vr) / 2.0
        if vr > 0 and vt > 0:
            lr.append(math.log(vt / vr))
    return _wander_decision(lr)


def _wander_decision(lr) -> Dict[str, object]:
    """The tilt-wander decision from each pose's log(tangential / radial) variance."""
    if len(lr) < 5:
        return {"wander": False, "note": "fewer than 5 poses of 16 samples"}
    lr = np.array(lr)
    mean, se = float(lr.mean()), float(lr.std(ddof=1) / math.sqrt(len(lr)))
    return {"wander": bool(mean > 2 * se), "log_tangential_over_radial": round(mean, 4), "stderr": round(se, 4)}


#: poses longer than this many times the median pose are rests, left out of the sway estimate
HOLD_SPAN = 3.0


def sway_rotation_variance(acc_g: np.ndarray, gyro_dps: np.ndarray, slices: Sequence[slice],
                           rate_hz: float, min_samples: int = 16) -> Tuple[np.ndarray, Dict[str, object]]:
    """Extra variance (N,) dps^2, per axis, of each gyro pose mean over ``slices`` from the
    net rotation of a swaying hold, and a summary (see the module text: the accelerometer's
    tilt change across the pose, its covariance with the gyro pose mean's deviation from
    the common bias).  Zeros when the sway is not clear of its standard error."""
    a = np.asarray(acc_g, float)
    g = np.asarray(gyro_dps, float)
    N = len(slices)
    T = np.array([(s.stop - s.start) / rate_hz for s in slices], float)
    use = np.array([s.stop - s.start >= min_samples for s in slices])
    # holds, not rests: a stretch over HOLD_SPAN x the median pose's length (a warm-up on the
    # table, 10 minutes among 6-s holds) tilts and drifts with the temperature, and its T^2
    # weighs it 10^4 times a hold's: alone it made a "sway" of 5.9 deg RMS, and every hold's
    # gyro variance ~20x (an independent probe's warm-up tours: gap named no gyro thermal
    # drift in 6 of 8, ratio 0.09-0.16)
    if use.any():
        use &= T <= HOLD_SPAN * float(np.median(T[use]))
    info: Dict[str, object] = {"method": "accelerometer tilt change x gyro pose mean"}
    if use.sum() < 5:
        info["note"] = "fewer than 5 poses of 16 samples: sway not estimated"
        return np.zeros(N), info
    r = np.zeros((N, 3))
    gm = np.zeros((N, 3))
    for i, s in enumerate(slices):
        n = s.stop - s.start
        gm[i] = g[s].mean(0)
        if not use[i]:
            continue
        m = a[s].mean(0)
        u = m / np.linalg.norm(m)
        th_a = np.cross(a[s] / np.linalg.norm(m), u)                 # tilt, rad (across u)
        th_g = np.radians(np.cumsum(g[s] - gm[i], axis=0) / rate_hz)  # the gyro's bridge, rad
        th_g -= np.outer(th_g @ u, u)
        tt = np.arange(n) / rate_hz
        tc = tt - tt.mean()
        d = th_a - th_g
        # the line left is theta(0) + t dtheta / T: its slope is the hold's net rotation rate
        r[i] = np.degrees(tc @ (d - d.mean(0)) / float(tc @ tc))
    b = median(gm[use], axis=0)
    c = np.sum((gm - b) * r, axis=1) * T ** 2                      # deg^2 per pose
    cu = c[use]
    S = float(np.mean(cu))
    se = float(np.std(cu, ddof=1) / math.sqrt(len(cu)))
    on = S > se
    per_axis = S / 2.0 if on else 0.0
    info.update({"net_rotation_variance_deg2": S, "stderr_deg2": se, "used": bool(on),
                 "net_rotation_rms_deg": math.sqrt(max(S, 0.0) * 1.5)})
    return np.where(use, per_axis / T ** 2, 0.0), info


def pose_quantisation_floor(x: np.ndarray, slices) -> Tuple[np.ndarray, dict]:
    """Per axis (C,): the variance of a pose mean's quantisation offset, from the LSB seen in
    the samples ``x`` inside the still ``slices`` and the noise before the quantiser; and a
    summary (the gap twin's, gap/diagnose.py, and calibrate's outlier test,
    cli/offline.py drop_outlier_poses)."""
    # float64 first: a float32 column's held values show a variance at float32's rounding,
    # far above the "held" threshold below (a float32 held column crashed as a float64 one did)
    x = np.asarray(x, float)
    lsb = estimate_lsb(x, slices)
    many = [x[s] for s in slices if s.stop - s.start > 1]
    if not many:
        return np.zeros(x.shape[1]), {"lsb": lsb.tolist()}
    # the median over the poses whose variance is defined (a NaN in a pose is not a variance)
    v = np.nanmedian([p.var(0, ddof=1) for p in many], axis=0)
    # "held": a variance at the float rounding of the values (a grid of 1/14.375 is not exact)
    flat = (lsb == 0) & ~(v > (1e-9 * np.nanmax(np.abs(x), axis=0)) ** 2)
    if np.any(flat):
        # a column held at one value inside (nearly) every pose (noise far below the LSB: an
        # un-dithered gyro at 14.375 LSB/dps read at 25 Hz) shows no spacing inside the poses;
        # its grid is read from the whole column (the turns sweep it), and its pose means are
        # then off by up to half an LSB (variance LSB^2 / 12 at zero noise): with no floor a
        # zero pose-mean variance divided the fit's weights by zero (LinAlgError)
        lsb = np.where(flat, estimate_lsb(x, [slice(0, len(x))]), lsb)
    if not np.any(lsb > 0):
        return np.zeros(x.shape[1]), {"lsb": lsb.tolist()}
    sig = noise_before_quantisation(v, lsb)
    qf = quantisation_floor(lsb, sig)
    return qf, {"lsb": lsb.tolist(), "noise_before_quantisation": sig.tolist(), "floor_variance": qf.tolist()}
