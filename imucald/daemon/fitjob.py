"""Background calibration: a pure job function and the acceptance gate.

:func:`calibration_job` is pure (arrays and the calibration in force in, a
candidate :class:`~imucald.calibration.Calibration` and a decision per sensor
out), so the daemon runs it in a worker process and replay runs it inline.
Every candidate part is fitted on all poses and scored by leave-one-pose-out
against the calibration in force (the raw sensor before the first), both out of
sample on the same poses: those the calibration in force was not fitted on (its
``poses_used`` table).  fitting/gate.py decides: the fit on more data replaces it when
the new poses agree with it, else the candidate must predict significantly better, at
the configured false-accept rate (job key ``alpha``).
The magnetometer cloud goes through the same test on its withheld points and is
then refitted on all of them.
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Dict, NamedTuple

import numpy as np

from ..fitting.models.registry import gyro_bias_scatter_se
from ..fitting.gate import Decision, fitted_poses, gate_accel, gate_gyro_bias, paired_gate
from ..fitting.inputs import stuck_columns
from ..fitting.judging.levels import GATE_FALSE_ACCEPT_RATE
from ..fitting.magcal import SphereReservoir as MagReservoir
from ..fitting.magcal import fit_cloud, fit_points, on_rails, rotation_noise
from ..fitting.models.mag import MagModel
from ..fitting.models.accel import Triangular9
from ..calibration import Calibration, SensorCal, build_calibration
from ..fitting.judging.metrics import rms
from ..numerics.npstats import median

__all__ = ["calibration_job", "JobResult", "MagReservoir"]

_T9 = Triangular9()
_MAG = MagModel("sym")


class JobResult(NamedTuple):
    candidate: Calibration          #: the parts fitted (quality: held-out before/after)
    accept: Dict[str, bool]         #: sensor -> the gate's decision
    #: notes: "gate": sensor -> fitting.gate.Decision (p-value, alpha, cross-validated RMS...)
    wall_s: float
    #: mag_flat: the plane of a one-plane swing; mag_undetermined: the terms a partial
    #: rotation leaves undetermined, or the field's inconsistency (fitting/magcal.py
    #: field_consistency) (no magnetometer part in either case)
    notes: Dict[str, Any]


def _holdout(n: int, frac: float) -> np.ndarray:
    k = max(2, int(round(1 / frac)))
    mask = np.zeros(n, bool)
    mask[k - 1::k] = True
    return mask


def calibration_job(job: Dict[str, Any]) -> JobResult:
    """Fit, validate and decide.  Pure: no I/O, no globals.

    job keys: acc (N,3) or None (a board without an accelerometer), acc_cov (N,3,3) (each
    pose's sample covariance over n), acc_sample_cov (N,3,3) (within-pose sample covariances)
    or None, acc_sf and acc_radial_sf (the holds' structure functions per axis and of the
    radial series, fitting/noise/posecov.py) or None, acc_colour_k (N,) (the noise file's
    Allan inflation, applied by :func:`_pose_cov` where the structure function decided
    nothing) or None, t0 (N,),
    t1 (N,) (the poses' still intervals, s: matched against the incumbent's poses_used), n (N,),
    gyro (N,3) or None, temp (N,) degC or None, mag_points (M,3) or None, mag_noise (3,)
    per-sample noise or None, mag_series (K,3) the latest readings in time order (for the
    noise: fitting/magcal.py rotation_noise), current (the Calibration in force), method, holdout_fraction
    (magnetometer points), alpha (the gate's false-accept rate), seed; thermal (the thermal
    log's arrays, daemon/thermallog.py) or None and thermal_min_span_c (daemon/thermaljob.py).
    """
    t_start = time.perf_counter()
    cur: Calibration = job.get("current") or Calibration()
    parts: Dict[str, SensorCal] = {}
    accept: Dict[str, bool] = {}
    notes: Dict[str, Any] = {"gate": {}}
    # a dead or stuck axis (its pose means all one value: fitting/inputs.stuck_columns) carries
    # no measurement: that sensor is not fitted, and the outcome says which column and why
    stuck = {s: c for s, c in (("accel", stuck_columns(job.get("acc"), "accel", min_rows=3)),
                               ("gyro", stuck_columns(job.get("gyro"), "gyro", min_rows=3))) if c}
    if stuck:
        notes["stuck"] = stuck
    if job.get("acc") is not None:
        job = _without_outliers(_pose_cov(job, notes), notes)
        _accel_gyro(job, cur, parts, accept, notes["gate"], notes, skip=set(stuck))
    mp = job.get("mag_points")
    if mp is not None and len(mp) >= 30:
        _mag(np.asarray(mp, float), job, cur, parts, accept, notes)
    candidate = build_calibration(parts, cur.board, cur.chips, id=0, created="")   # not in force yet
    return JobResult(candidate, accept, time.perf_counter() - t_start, notes)


#: the job's per-pose entries (each pose's row, in the poses' order)
_PER_POSE = ("acc", "acc_cov", "acc_sample_cov", "acc_sf", "acc_radial_sf", "acc_colour_k", "t0", "t1", "n",
             "temp", "gyro")


def _without_outliers(job: Dict[str, Any], notes: Dict[str, Any]) -> Dict[str, Any]:
    """The job without the poses no calibration of the others explains (a board held still in
    a lift or a vehicle that accelerated, or knocked: fitting/judging/outliers.py), as
    calibrate leaves them out (cli/offline.py drop_outlier_poses); noted under
    ``outlier_poses``.  Kept, two such poses in the first ten left a cold review's replays
    6.6-18.4 mg off at the end (20 of 20).  As it was when the rule leaves none out."""
    from ..fitting.judging.outliers import poses_to_leave_out
    from ..fitting.noise.posefloor import noise_before_quantisation, quantisation_floor
    from ..specs import ACCEL
    acc = np.asarray(job["acc"], float)
    chip = ACCEL.get((job.get("current") or Calibration()).chips.get("accel", ""))
    floor, sc = None, job.get("acc_sample_cov")
    if chip is not None and sc is not None and len(acc):
        # the rounding of a pose mean at the chip's LSB, given the noise before it (as calibrate,
        # which reads the LSB off the samples: fitting/noise/posefloor.py)
        v = np.median(np.einsum("nii->ni", np.asarray(sc, float)), axis=0)
        floor = quantisation_floor(chip.lsb_g, noise_before_quantisation(v, np.full(3, chip.lsb_g)))
    idx, z, r, drop = poses_to_leave_out(acc, job["acc_cov"], job.get("temp"), floor)
    if not drop:
        return job
    t0, t1 = job.get("t0"), job.get("t1")
    notes["outlier_poses"] = [{k: v for k, v in (("t0_s", None if t0 is None else float(t0[i])),
                                                 ("t1_s", None if t1 is None else float(t1[i])),
                                                 ("residual_g", float(-r[i])), ("z", float(z[i])))
                               if v is not None} for i in idx]
    keep = np.setdiff1d(np.arange(len(acc)), idx)
    out = dict(job)
    for k in _PER_POSE:
        v = job.get(k)
        if v is not None:
            out[k] = np.asarray(v)[keep] if isinstance(v, np.ndarray) else [v[i] for i in keep]
    return out


def _pose_cov(job: Dict[str, Any], notes: Dict[str, Any]) -> Dict[str, Any]:
    """The job with acc_cov formed as calibrate forms its poses' (fitting/stillness/poses.py
    _structure, cli/offline.py _fit_accel), from the statistics each pose keeps instead of
    its samples (here in the worker: ~80 ms at 60 poses):

    1. each pose's own covariance of the mean (job["acc_cov"]: sample covariance over n)
       rescaled per axis by the holds' structure functions (job["acc_sf"],
       fitting/noise/posecov.py scale_pose_cov_stats);
    2. where the direction wanders within the poses (a hand's sway: the tilt-wander test
       on each pose's mean and sample covariance, fitting/noise/posefloor.py), the variance
       along each pose's direction from the radial series' structure functions
       (job["acc_radial_sf"], radial_pose_cov_stats);
    3. the Allan colour inflation (job["acc_colour_k"], the noise file's) only where the
       structure function decided nothing (allan_still_needed).

    The inflation is applied here and nowhere else: the pipeline used to multiply it in
    and this function divided it out again where the structure function decided."""
    from ..fitting.noise.posecov import allan_still_needed, radial_pose_cov_stats, scale_pose_cov_stats
    from ..fitting.noise.posefloor import tilt_wander_test_stats
    cov = np.asarray(job["acc_cov"], float)
    sc, n, info = job.get("acc_sample_cov"), job["n"], None
    if job.get("acc_sf") is not None and sc is not None:
        sc = np.asarray(sc, float)
        cov, info = scale_pose_cov_stats(n, np.einsum("nii->ni", sc), job["acc_sf"], cov)
        notes["pose_noise"] = info
        rsf = job.get("acc_radial_sf")
        tilt = tilt_wander_test_stats(n, job["acc"], sc)
        if tilt["wander"] and rsf is not None:
            u = np.asarray(job["acc"], float)
            u = u / np.linalg.norm(u, axis=1, keepdims=True)
            cov, rinfo = radial_pose_cov_stats(n, np.einsum("ni,nij,nj->n", u, sc, u), rsf, job["acc"], cov)
            notes["pose_noise_radial"] = dict(rinfo, tilt_wander=tilt)
    k = job.get("acc_colour_k")
    if k is not None and allan_still_needed(info):
        cov = cov * np.asarray(k, float)[:, None, None]
    return dict(job, acc_cov=cov)


def _accel_gyro(job, cur: Calibration, parts: Dict[str, SensorCal], accept: Dict[str, bool],
                gates: Dict[str, Decision], notes: Dict[str, Any], skip=frozenset()) -> None:
    """The accelerometer (gated on its poses' cross-validated residuals), the gyro bias and
    the thermal terms; a sensor in ``skip`` (a stuck axis) is not fitted."""
    acc = np.asarray(job["acc"], float)
    alpha = job.get("alpha", GATE_FALSE_ACCEPT_RATE)
    temp = job.get("temp")
    # thermal terms in force: the constant part is refitted on the poses with them removed
    # (each at its own temperature) and the candidate keeps them
    ta = cur.accel.thermal if cur.accel is not None and temp is not None else None
    acc_fit = cur.accel.thermal_offset(acc, temp) if ta else acc
    # the poses the calibration in force was fitted on: in-sample for it, never scored
    fitted, nested = fitted_poses(acc, job.get("t0"), job.get("t1"), cur.poses_used)
    if "accel" not in skip:
        # --- accelerometer: fitted on all poses, gated on their cross-validated residuals ---
        cal, _, dec = gate_accel(acc_fit, job["acc_cov"], cur.apply_accel(acc, temp), job["method"], alpha,
                                 against="raw" if cur.accel is None else "current", rng=job.get("seed"),
                                 chip=cur.chips.get("accel"),      # the datasheet prior of this chip
                                 fitted=fitted if cur.accel is not None else None, nested=nested,
                                 incumbent=None if cur.accel is None else (cur.accel.model, cur.accel.theta),
                                 temp_c=None if ta else temp)    # the slope a constant leaves out
        # predicted cross-validated residual: each pose's noise plus the uncertainty of the
        # refit without it (fitting.fit.heldout_residuals)
        pred = rms(cal.info["heldout_predicted_std"])
        # heldout_rms_g and heldout_rms_before_g: both out of sample on the same gate_poses poses
        # (those the calibration in force was not fitted on); loo_rms_g: the candidate's over all
        q = {"fitness": float(cal.fitness), "heldout_rms_g": dec.rms_cv,
             "heldout_rms_before_g": dec.rms_incumbent, "predicted_heldout_rms_g": pred,
             "poses": int(len(acc)), "gate_poses": int(dec.n), "gate_p_value": dec.p_value,
             "false_accept_rate": dec.alpha}
        parts["accel"] = SensorCal.from_fit(cal, {k: v for k, v in q.items() if np.isfinite(v)})
        if ta:
            parts["accel"] = replace(parts["accel"], thermal=ta)
        accept["accel"], gates["accel"] = dec.accept, dec
    # --- gyro bias: count-weighted mean of the still poses, gated the same way ---
    g = job.get("gyro")
    if g is not None and "gyro" not in skip:
        g = np.asarray(g, float)
        w = np.asarray(job["n"], float)
        tg = cur.gyro.thermal if cur.gyro is not None and temp is not None else None
        # the incumbent is scored as the daemon applies it: with the calibrated specific
        # force for its g-sensitivity term (else G a counts against it)
        acc_cal = cur.apply_accel(acc, temp)
        g_inc = cur.apply_gyro(g, temp if temp is not None else np.full(len(g), np.nan), acc_cal)
        g = cur.gyro.thermal_offset(g, temp) if tg else g
        # the scale/misalignment matrix and g-sensitivity in force (calibrate --sensor gyro,
        # fitting/gyro/rotations.py) are kept; the bias is refitted on the means without G a
        kept = [k for k in ("matrix", "g_sens_dps_per_g") if cur.gyro is not None and k in cur.gyro.params]
        if kept:
            g = cur.gyro.g_offset(g, acc_cal)
        b, gdec = gate_gyro_bias(g, w, g_inc, alpha, against="raw" if cur.gyro is None else "current",
                                 fitted=fitted if cur.gyro is not None else None, nested=nested)
        sd = gyro_bias_scatter_se(g, w, b)
        carry = lambda d: {k: d[k] for k in kept if k in d}
        parts["gyro"] = SensorCal("gyro", "bias", {"bias_dps": b, **carry(cur.gyro.params if kept else {})},
                                  {"bias_dps": sd, **carry(cur.gyro.stderr if kept else {})},
                                  carry(cur.gyro.flags if kept else {}), method="mean",
                                  quality={k: v for k, v in {
                                      "heldout_rms_dps": gdec.rms_cv,
                                      "heldout_rms_before_dps": gdec.rms_incumbent, "poses": int(len(g)),
                                      "gate_poses": int(gdec.n), "gate_p_value": gdec.p_value}.items()
                                      if np.isfinite(v)},
                                  thermal=tg)
        accept["gyro"], gates["gyro"] = gdec.accept, gdec
    # --- thermal terms from the thermal log (daemon/thermaljob.py) ---
    if job.get("thermal"):
        from .thermaljob import thermal_parts
        thermal_parts(job, cur, parts, accept, gates, notes)


def _mag(mp: np.ndarray, job, cur: Calibration, parts, accept, notes) -> None:
    """The rotation-cloud calibration, determined as ``calibrate --sensor mag`` determines
    it (fitting/magcal.py fit_cloud, on every point), then gated on every k-th point.

    A cloud from a one-plane swing is reported (notes["mag_flat"]: the undetermined
    axis) and never applied; so is one whose terms the determination rule of
    fitting/magcal.py does not accept, or whose field is not one field (notes["mag_undetermined"])."""
    noise = job.get("mag_noise")
    if noise is None or not (np.all(np.isfinite(noise)) and np.all(np.asarray(noise) > 0)):
        noise = None            # unknown: the fits use their residuals, no one-plane test
    else:
        noise = np.asarray(noise, float)
    mt = job.get("mag_temp")
    off, rl = on_rails(mp)              # clipping or an overflow code: left out, as calibrate does
    if rl:
        mp, mt = mp[~off], (None if mt is None else np.asarray(mt)[~off])
        notes["mag_rails"] = [{"axis": "xyz"[j], "value": v, "points": n} for j, v, n in rl]
    if noise is not None and job.get("mag_series") is not None:   # the turning may have inflated it
        series = np.asarray(job["mag_series"], float).reshape(-1, 3)
        noise = rotation_noise(_MAG, mp, series[~on_rails(series)[0]], noise, job.get("seed"))[0]
    tm = cur.mag.thermal if cur.mag is not None and mt is not None else None
    raw = mp
    if tm:      # thermal terms in force: the constant part is refitted without them, and keeps them
        mp = cur.mag.thermal_offset(mp, mt)
    fc = fit_cloud(_MAG, mp, noise, "lm", rng=job.get("seed"), heldout=False)
    if "flat" in fc:
        notes["mag_flat"] = fc["flat"]
        return
    if "inconsistent" in fc:    # the field changed, a magnet, clipping: never applied
        notes["mag_undetermined"] = {k: fc[k] for k in ("inconsistent", "coverage", "field_gauss")}
        return
    if not fc["determined"]:    # a cap, a wobbly planar turn, no turning at all: never applied
        notes["mag_undetermined"] = {k: fc[k] for k in ("undetermined", "coverage", "field_gauss",
                                                         "missing_axes")}
        return
    mc, cv = fc["calibration"], fc["coverage"]
    mho = _holdout(len(mp), job["holdout_fraction"])
    mc_ho = fit_points(_MAG, mp[~mho], noise, "lm", job.get("seed"), heldout=False)
    r_new = np.linalg.norm(_MAG.forward(mc_ho.theta, mp[mho]), axis=1) - 1
    if cur.mag is None:
        hc = np.linalg.norm(mp[mho], axis=1)
        r_cur = hc / median(np.linalg.norm(mp, axis=1)) - 1
    else:
        hc = np.linalg.norm(cur.apply_mag(raw[mho], None if mt is None else mt[mho]), axis=1)
        r_cur = hc / float(cur.mag.params["field_gauss"]) - 1
    # the same paired test on the withheld points; the applied fit uses every point
    dec = paired_gate(r_cur ** 2, r_new ** 2, job.get("alpha", GATE_FALSE_ACCEPT_RATE),
                      "raw" if cur.mag is None else "current")
    parts["mag"] = SensorCal.from_fit(mc, {
        "points": int(len(mp)), "heldout_rel_rms": dec.rms_cv, "heldout_rel_rms_before": dec.rms_incumbent,
        "gate_p_value": dec.p_value,
        "coverage_fraction": cv["fraction"], "coverage_min_eigenvalue": cv["direction_eigenvalues"][-1]})
    if tm:
        parts["mag"] = replace(parts["mag"], thermal=tm)
    accept["mag"], notes["gate"]["mag"] = dec.accept, dec
    if job.get("thermal") and mt is not None:
        from .thermaljob import mag_thermal
        mag_thermal(job, cur, raw, mt, None if noise is None else np.diag(noise ** 2), mc.theta, parts,
                    accept, notes)
