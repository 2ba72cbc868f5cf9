"""The magnetometer's gap diagnosis against the deployed model, from rotation as well as
still poses.

The daemon and ``calibrate --sensor mag`` fit hard + soft iron (``mag_sym``, no prior)
to a rotation cloud thinned over the sphere (:class:`imucald.fitting.magcal.SphereReservoir`,
per-sample noise from second differences).  The gap takes the same points: every
magnetometer reading outside the still poses (each held reading once), thinned by the
same reservoir, plus the still poses' means (precise points), each with its own noise
variance.  Every kept point carries its time, temperature and orientation (the
calibrated accelerometer's specific force at that sample; during a turn it also holds
the motion's acceleration, a noisier regressor but not a biased one for the norm), so
the candidates (thermal hard iron, thermal gain, drift, orientation interference) are
tested on all of them.
"""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..fitting.magcal import SphereReservoir, flat_axis, readings, sample_noise
from ..fitting.models.mag import MagModel
from ..fitting.models.accel import Triangular9
from ..fitting.solvers.lsq import sphere_fit
from .candidates import hat_columns

__all__ = ["mag_points", "MIN_MAG_POINTS", "quiet_noise", "mag_still_slices"]

MIN_MAG_POINTS = 30
LSB_GAUSS = 1 / 1090            #: HMC5883L at its default gain (datasheet p.13): the quantisation floor


def _windows(m: np.ndarray, w: int):
    """Per window of ``w`` readings: the mean square second difference / 6 (C,) (white noise:
    its variance; a turn adds its curvature) and the window's slice."""
    d2 = np.diff(m, 2, axis=0)
    k = len(d2) // w
    if k == 0:
        return np.zeros((0, m.shape[1])), []
    v = np.mean(d2[:k * w].reshape(k, w, -1) ** 2, axis=1) / 6.0
    return v, [slice(i * w, i * w + w + 2) for i in range(k)]


def quiet_noise(m: np.ndarray, rate_hz: float, chip_noise: Optional[float] = None) -> Dict[str, object]:
    """Per-sample noise (C,) of a magnetometer stream free of the motion.

    Second differences see white noise and a turn's curvature (at 50 Hz a slow turn adds
    little; at 3 Hz the curvature dominates, and a noise figure over every sample then
    holds the motion).  The stream is cut into windows of about 1 s (at least 8 readings);
    a window is quiet when its mean square second difference lies within the chi-square
    99.9 % point of the lowest decile's level; the noise is the pooled figure over the
    quiet windows.  When even that exceeds 2.5x the chip's datasheet noise (``chip_noise``,
    gauss) the datasheet figure is used, said in ``source``."""
    m = np.asarray(m, float)
    w = max(8, int(round(rate_hz)))
    v, sls = _windows(m, w)
    if len(v) < 3:
        sd = sample_noise(m)
        return {"sigma": sd, "source": "every sample (too short for quiet windows)", "quiet_windows": 0}
    tot = v.sum(1)
    floor = float(np.quantile(tot, 0.1))
    dof = w * m.shape[1] / 3.0                 # second differences overlap: ~w/3 independent per axis
    lim = floor * (1 + 3.1 * np.sqrt(2.0 / dof))
    quiet = tot <= lim
    sigma = np.sqrt(np.mean(v[quiet], axis=0))
    out = {"sigma": sigma, "source": f"second differences over {int(quiet.sum())} quiet windows of {w} readings",
           "quiet_windows": int(quiet.sum()), "windows": int(len(v)),
           "quiet_slices": [s for s, q in zip(sls, quiet) if q]}
    if chip_noise is not None and float(np.sqrt(np.mean(sigma ** 2))) > 2.5 * chip_noise:
        out["measured_sigma"] = sigma
        out["sigma"] = np.full(m.shape[1], float(chip_noise))
        out["source"] = (f"datasheet ({chip_noise * 1e3:.1f} mG): the quietest windows' figure "
                         f"({np.sqrt(np.mean(sigma ** 2)) * 1e3:.1f} mG) holds the motion (no still moment)")
    return out


def mag_still_slices(t_s: np.ndarray, m: np.ndarray, rate_hz: float, sigma: np.ndarray,
                     min_s: float = 1.0, k: float = 4.0) -> List[slice]:
    """Still stretches of a magnetometer stream (no accelerometer to find them): runs of
    windows (about 0.5 s) whose readings stay within ``k`` noise sd of the window mean
    on every axis and whose means stay within ``k`` standard errors of the run's first
    window (a slow turn creeps out of it), at least ``min_s`` long."""
    w = max(5, int(round(0.5 * rate_hz)))
    n = len(m) // w
    ok = np.zeros(n, bool)
    for i in range(n):
        x = m[i * w:(i + 1) * w]
        ok[i] = bool(np.all(np.abs(x - x.mean(0)) <= k * np.maximum(sigma, 1e-12)))
    out: List[slice] = []
    i = 0
    while i < n:
        if not ok[i]:
            i += 1
            continue
        j = i
        ref = m[i * w:(i + 1) * w].mean(0)
        tol = k * np.maximum(sigma, 1e-12) * np.sqrt(2.0 / w)      # two window means apart
        while j + 1 < n and ok[j + 1] and np.all(np.abs(m[(j + 1) * w:(j + 2) * w].mean(0) - ref) <= tol):
            j += 1
        a, b = i * w, (j + 1) * w
        if t_s[b - 1] - t_s[a] >= min_s:
            out.append(slice(a, b))
        i = j + 1
    return out


def mag_points(rec, slices: Sequence[slice], pose_mag: Optional[np.ndarray], pose_var: Optional[np.ndarray],
               pose_idx: Sequence[int], acc_theta: Optional[np.ndarray], use_temp: bool,
               chip_noise: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray, Dict[str, np.ndarray], Dict[str, object]]:
    """Points (M, 3) gauss, their isotropic noise variances (M,), the candidates' context and
    a summary.  ``pose_idx``: the still slices kept (their means ``pose_mag`` with variances
    ``pose_var``); ``acc_theta``: a triangular9 accelerometer calibration for the orientation
    regressor (None: raw accelerometer directions)."""
    n = len(rec.t)
    still = np.zeros(n, bool)
    for s in slices:
        still[s] = True
    m = rec.mag
    # each reading once, off the rails (clipping, an overflow code): the calibration's rule
    _, idx, rl = readings(m, say=False)
    fresh = np.zeros(n, bool)
    fresh[idx] = True
    # per-sample noise: second differences inside the still poses (plain mean of squares:
    # the robust MAD of the calibration's sample_noise is lumpy on quantised readings and
    # overstates the noise by ~10 % there); no still stretch: the calibration's estimate
    d2 = [np.diff(m[s][fresh[s]], 2, axis=0) for s in slices if fresh[s].sum() > 10]
    d2 = np.vstack(d2) if d2 else np.zeros((0, 3))
    if len(d2) >= 100:
        sigma, source = np.sqrt(np.mean(d2 ** 2, axis=0) / 6.0), "second differences inside the still poses"
    else:       # no still pose: the quiet windows (a noise figure free of the motion)
        qn = quiet_noise(m[fresh], rate_hz=rec.rate_hz * fresh.mean(), chip_noise=chip_noise)
        sigma, source = qn["sigma"], qn["source"]
    moving = np.flatnonzero(fresh & ~still)
    if use_temp:            # a reading without a temperature cannot carry the thermal regressors
        moving = moving[np.isfinite(rec.temp[moving])]
    res = SphereReservoir()
    res.add(m[moving], tags=moving)
    rp, ri = res.points(), res.tags()
    floor = LSB_GAUSS ** 2 / 12
    var_r = np.full(len(rp), max(float(np.mean(sigma ** 2)), floor)) if len(rp) else np.zeros(0)
    t9 = Triangular9()

    have_acc = rec.acc is not None

    def acc_dir(a):
        if not have_acc:
            return np.zeros((len(a), 3))
        return t9.forward(acc_theta, a) if acc_theta is not None else a / np.linalg.norm(a, axis=1, keepdims=True)
    parts_x, parts_v, parts_t, parts_T, parts_a = [], [], [], [], []
    if pose_mag is not None and len(pose_idx):
        ps_sl = [slices[i] for i in pose_idx]
        parts_x.append(pose_mag)
        parts_v.append(np.maximum(pose_var, floor / np.array([s.stop - s.start for s in ps_sl])))
        parts_t.append(np.array([0.5 * (rec.t[s.start] + rec.t[s.stop - 1]) for s in ps_sl]))
        parts_T.append(np.array([np.nanmean(rec.temp[s]) for s in ps_sl]) if use_temp else None)
        parts_a.append(acc_dir(np.array([rec.acc[s].mean(0) for s in ps_sl]) if have_acc else ps_sl))
    if len(rp):
        parts_x.append(rp)
        parts_v.append(var_r)
        parts_t.append(rec.t[ri])
        parts_T.append(rec.temp[ri] if use_temp else None)
        parts_a.append(acc_dir(rec.acc[ri] if have_acc else ri))
    if not parts_x:             # no still pose means and no rotation: nothing to fit (diagnosable says)
        return np.zeros((0, 3)), np.zeros(0), {}, {"still_pose_means": 0, "rotation_points": 0,
                                                   "rotation_samples": int(len(moving))}
    x = np.vstack(parts_x)
    var = np.concatenate(parts_v)
    t = np.concatenate(parts_t)
    ctx: Dict[str, np.ndarray] = {"t": t - t.min(), "dt": t - t.mean(), **hat_columns(t)}
    if have_acc:
        ctx["acc_dir"] = np.vstack(parts_a)
    if use_temp:
        T = np.concatenate(parts_T)
        ctx["temp"], ctx["dT"] = T, T - T.mean()
    _, rad = sphere_fit(x)
    info = {"still_pose_means": int(len(pose_idx)) if pose_mag is not None else 0,
            "rotation_points": int(len(rp)), "rotation_samples": int(len(moving)),
            "sample_noise_gauss": np.round(sigma, 6).tolist(), "noise_source": source,
            "rotation_flat": flat_axis(rp, sigma) is not None if len(rp) > 10 else None,
            "field_gauss": float(rad)}
    if rl:
        info["rails_left_out"] = [{"axis": "xyz"[j], "value": v, "samples": k} for j, v, k in rl]
    return x, var, ctx, info


def diagnosable(x: np.ndarray, var: np.ndarray) -> Optional[str]:
    """Why the points cannot determine hard + soft iron (None when they can)."""
    if len(x) < MIN_MAG_POINTS:
        return f"{len(x)} magnetometer points (still poses and thinned rotation); {MIN_MAG_POINTS} needed"
    if flat_axis(x, np.full(3, np.sqrt(np.median(var)))) is not None:
        return "the magnetometer points lie in one plane: turn the sensor through every orientation"
    return None


def mag_model() -> MagModel:
    """The deployed magnetometer model (daemon and calibrate): hard + soft iron, no prior."""
    return MagModel("sym")
