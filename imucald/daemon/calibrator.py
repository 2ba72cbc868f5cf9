"""Background calibration: a pure job function and the acceptance gate.

:func:`calibration_job` is pure (arrays and the calibration in force in, a
candidate :class:`~imucald.calibration.Calibration` and a decision per sensor
out), so the daemon runs it in a worker process and replay runs it inline.
Every candidate part is validated on held-out poses (every k-th pose in time
order is withheld from the fit) against the calibration currently applied, and
:func:`gate` decides; a part that validates worse is never applied.
"""
from __future__ import annotations

import time
from typing import Any, Dict, NamedTuple

import numpy as np

from ..calib.fit import fit_norm
from ..calib.magcal import SphereReservoir as MagReservoir
from ..calib.magcal import coverage, flat_axis
from ..calib.models import MagModel, Triangular9
from ..calib.uncertainty import residual_variance
from ..calibration import Calibration, SensorCal

__all__ = ["calibration_job", "gate", "JobResult", "MagReservoir"]

_T9 = Triangular9()
_MAG = MagModel("sym")


class JobResult(NamedTuple):
    candidate: Calibration          #: the parts fitted (quality: held-out before/after)
    accept: Dict[str, bool]         #: sensor -> the gate's decision
    wall_s: float
    #: mag_flat: the plane of a one-plane swing (no magnetometer part then)
    notes: Dict[str, Any]


def gate(sensor: str, heldout_new: float, heldout_current: float) -> bool:
    """The acceptance gate: a candidate part replaces the current one only if its
    held-out residual RMS is smaller."""
    return bool(heldout_new < heldout_current)


def _holdout(n: int, frac: float) -> np.ndarray:
    k = max(2, int(round(1 / frac)))
    mask = np.zeros(n, bool)
    mask[k - 1::k] = True
    return mask


def _rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def calibration_job(job: Dict[str, Any]) -> JobResult:
    """Fit, validate and decide.  Pure: no I/O, no globals.

    job keys: acc (N,3) or None (a board without an accelerometer), acc_cov (N,3,3), t0 (N,),
    n (N,), gyro (N,3) or None, mag_points (M,3) or None, mag_noise (3,) per-sample noise or
    None, current (the Calibration in force), method, holdout_fraction, seed.
    """
    t_start = time.perf_counter()
    cur: Calibration = job.get("current") or Calibration()
    parts: Dict[str, SensorCal] = {}
    accept: Dict[str, bool] = {}
    notes: Dict[str, Any] = {}
    if job.get("acc") is not None:
        _accel_gyro(job, cur, parts, accept)
    mp = job.get("mag_points")
    if mp is not None and len(mp) >= 30:
        _mag(np.asarray(mp, float), job, cur, parts, accept, notes)
    candidate = Calibration(cur.board, dict(cur.chips), **parts)
    return JobResult(candidate, accept, time.perf_counter() - t_start, notes)


def _accel_gyro(job, cur: Calibration, parts: Dict[str, SensorCal], accept: Dict[str, bool]) -> None:
    acc = np.asarray(job["acc"], float)
    order = np.argsort(job["t0"])
    ho = np.zeros(len(acc), bool)
    ho[order[_holdout(len(acc), job["holdout_fraction"])]] = True
    tr = ~ho
    # --- accelerometer ---
    cal = fit_norm(acc[tr], "triangular9", job["method"], pose_cov=job["acc_cov"][tr],
                   rng=job.get("seed"), heldout=True)
    e_new = _rms(1 - np.linalg.norm(_T9.forward(cal.theta, acc[ho]), axis=1))
    e_cur = _rms(1 - np.linalg.norm(cur.apply_accel(acc[ho]), axis=1))
    # CRLB-predicted held-out residual: pose noise plus the parameters' uncertainty
    v = np.median(np.einsum("nii->n", job["acc_cov"]) / 3)
    var = residual_variance(_T9, cal.theta, acc[ho], np.full(ho.sum(), v))
    _, J = _T9.jacobian(cal.theta, acc[ho])
    pred = float(np.sqrt(np.mean(var + np.einsum("nk,kl,nl->n", J, cal.uncertainty.cov, J))))
    parts["accel"] = SensorCal.from_fit(cal, {
        "fitness": float(cal.fitness), "heldout_rms_g": e_new, "heldout_rms_before_g": e_cur,
        "predicted_heldout_rms_g": pred, "poses": int(len(acc)), "heldout_poses": int(ho.sum())})
    accept["accel"] = gate("accel", e_new, e_cur)
    # --- gyro bias: weighted mean of the still poses, validated the same way ---
    g = job.get("gyro")
    if g is not None:
        g = np.asarray(g, float)
        w = np.asarray(job["n"], float)
        b = (g[tr] * w[tr, None]).sum(0) / w[tr].sum()
        e_new = _rms(g[ho] - b)
        e_cur = _rms(cur.apply_gyro(g[ho]))
        bfull = (g * w[:, None]).sum(0) / w.sum()
        sd = np.sqrt(((g - bfull) ** 2 * w[:, None]).sum(0) / w.sum() / max(len(g) - 1, 1))
        parts["gyro"] = SensorCal("gyro", "bias", {"bias_dps": b}, {"bias_dps": sd}, method="mean",
                                  quality={"heldout_rms_dps": e_new, "heldout_rms_before_dps": e_cur,
                                           "poses": int(len(g))})
        accept["gyro"] = gate("gyro", e_new, e_cur)


def _mag(mp: np.ndarray, job, cur: Calibration, parts, accept, notes) -> None:
    """The rotation-cloud calibration (calib.magcal), validated on every k-th point.

    A cloud from a one-plane swing is reported (notes["mag_flat"]: the undetermined
    axis) and never applied."""
    noise = job.get("mag_noise")
    cov = None
    if noise is not None and np.all(np.isfinite(noise)) and np.all(np.asarray(noise) > 0):
        flat = flat_axis(mp, np.asarray(noise, float))
        if flat is not None:
            notes["mag_flat"] = flat
            return
        cov = np.diag(np.asarray(noise, float) ** 2)
    mho = _holdout(len(mp), job["holdout_fraction"])
    mc = fit_norm(mp[~mho], "mag_sym", "lm", rng=job.get("seed"), heldout=False,
                  pose_cov=None if cov is None else np.broadcast_to(cov, (int((~mho).sum()), 3, 3)))
    e_new = _rms(np.linalg.norm(_MAG.forward(mc.theta, mp[mho]), axis=1) - 1)
    if cur.mag is None:
        hc = np.linalg.norm(mp[mho], axis=1)
        e_cur = _rms(hc / np.median(np.linalg.norm(mp, axis=1)) - 1)
    else:
        hc = np.linalg.norm(cur.apply_mag(mp[mho]), axis=1)
        e_cur = _rms(hc / float(cur.mag.params["field_gauss"]) - 1)
    cv = coverage(_MAG, mc.theta, mp)
    parts["mag"] = SensorCal.from_fit(mc, {
        "points": int(len(mp)), "heldout_rel_rms": e_new, "heldout_rel_rms_before": e_cur,
        "coverage_fraction": cv["fraction"], "coverage_min_eigenvalue": cv["direction_eigenvalues"][-1]})
    accept["mag"] = gate("mag", e_new, e_cur)
