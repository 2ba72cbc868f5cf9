"""Background calibration: a pure job function, the applied calibration, and the
magnetometer's sample reservoir.

:func:`calibration_job` is pure (arrays in, a result dict out), so the daemon
runs it in a worker process and replay runs it inline.  Every candidate is
validated on held-out poses (every k-th pose in time order is withheld from the
fit) against the calibration currently applied; it is accepted only if its
held-out residual is smaller.  A worse calibration is never applied.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

import numpy as np

from ..calib.fit import fit_norm
from ..calib.magcal import SphereReservoir as MagReservoir
from ..calib.magcal import coverage, flat_axis
from ..calib.models import MagModel, Triangular9, mag_report
from ..calib.uncertainty import residual_variance

__all__ = ["Applied", "calibration_job", "MagReservoir", "correct_accel"]

_T9 = Triangular9()
_MAG = MagModel("sym")


@dataclass
class Applied:
    """The calibration in force.  id 0 = none (raw, nominally scaled data)."""

    id: int = 0
    accel_theta: Optional[np.ndarray] = None        #: triangular9 parameters
    gyro_bias_dps: Optional[np.ndarray] = None
    mag_theta: Optional[np.ndarray] = None          #: mag_sym unit-sphere parameters
    mag_field_gauss: Optional[float] = None
    info: Dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        self._acc_M = self._acc_b = self._mag_W = self._mag_v = None
        self.refresh()

    def refresh(self) -> None:
        if self.accel_theta is not None:
            self._acc_M = _T9.matrix(self.accel_theta)
            self._acc_b = self.accel_theta[6:9]
        if self.mag_theta is not None:
            p, _ = mag_report(_MAG, self.mag_theta)
            W = np.zeros((3, 3))
            for k, (i, j) in enumerate([(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]):
                W[i, j] = W[j, i] = p["soft_iron"][k]
            self._mag_W, self._mag_v = W, np.array(p["hard_iron_gauss"])
            self.mag_field_gauss = p["field_gauss"]

    def accel(self, raw: np.ndarray) -> np.ndarray:
        return raw if self._acc_M is None else (raw - self._acc_b) @ self._acc_M.T

    def gyro(self, raw: np.ndarray) -> np.ndarray:
        return raw if self.gyro_bias_dps is None else raw - self.gyro_bias_dps

    def mag(self, raw: np.ndarray) -> np.ndarray:
        return raw if self._mag_W is None else (raw - self._mag_v) @ self._mag_W.T


def correct_accel(theta: Optional[np.ndarray], raw: np.ndarray) -> np.ndarray:
    return raw if theta is None else _T9.forward(theta, raw)


def _holdout(n: int, frac: float) -> np.ndarray:
    k = max(2, int(round(1 / frac)))
    mask = np.zeros(n, bool)
    mask[k - 1::k] = True
    return mask


def _rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def calibration_job(job: Dict[str, Any]) -> Dict[str, Any]:
    """Fit, validate and decide.  Pure: no I/O, no globals.

    job keys: acc (N,3) or None (a board without an accelerometer), acc_cov (N,3,3), t0 (N,),
    n (N,), temp (N,), gyro (N,3) or None, mag_points (M,3) or None, mag_noise (3,) per-sample
    noise or None, current: {accel_theta, gyro_bias_dps, mag_theta} (None = raw), method,
    holdout_fraction, seed.
    """
    t_start = time.perf_counter()
    out: Dict[str, Any] = {"accel": None, "gyro": None, "mag": None}
    cur = job.get("current") or {}
    if job.get("acc") is not None:
        _accel_gyro(job, cur, out)
    mp = job.get("mag_points")
    if mp is not None and len(mp) >= 30:
        out["mag"] = _mag(np.asarray(mp, float), job, cur)
    out["wall_s"] = time.perf_counter() - t_start
    return out


def _accel_gyro(job: Dict[str, Any], cur: Dict[str, Any], out: Dict[str, Any]) -> None:
    acc = np.asarray(job["acc"], float)
    order = np.argsort(job["t0"])
    ho = np.zeros(len(acc), bool)
    ho[order[_holdout(len(acc), job["holdout_fraction"])]] = True
    tr = ~ho
    # --- accelerometer ---
    cal = fit_norm(acc[tr], "triangular9", job["method"], pose_cov=job["acc_cov"][tr],
                   rng=job.get("seed"), heldout=True)
    r_new = 1 - np.linalg.norm(_T9.forward(cal.theta, acc[ho]), axis=1)
    cth = cur.get("accel_theta")
    r_cur = 1 - np.linalg.norm(correct_accel(cth, acc[ho]), axis=1)
    # CRLB-predicted held-out residual: pose noise plus the parameters' uncertainty
    v = np.median(np.einsum("nii->n", job["acc_cov"]) / 3)
    var = residual_variance(_T9, cal.theta, acc[ho], np.full(ho.sum(), v))
    _, J = _T9.jacobian(cal.theta, acc[ho])
    pred = float(np.sqrt(np.mean(var + np.einsum("nk,kl,nl->n", J, cal.uncertainty.cov, J))))
    out["accel"] = {
        "theta": cal.theta.tolist(), "params": cal.params, "stderr": cal.stderr,
        "crlb_std": [None if not np.isfinite(s) else float(s) for s in cal.crlb_std],
        "fitness": float(cal.fitness), "rms_g": float(cal.rms), "loo_rms_g": float(cal.heldout_rms),
        "heldout_rms_g": _rms(r_new), "heldout_rms_before_g": _rms(r_cur),
        "predicted_heldout_rms_g": pred, "train_poses": int(tr.sum()), "heldout_poses": int(ho.sum()),
        "noise_g": float(cal.noise), "rank": int(cal.uncertainty.rank),
        "accept": bool(_rms(r_new) < _rms(r_cur)),
    }
    # --- gyro bias: weighted mean of the still poses, validated the same way ---
    g = job.get("gyro")
    if g is not None:
        g = np.asarray(g, float)
        w = np.asarray(job["n"], float)
        b = (g[tr] * w[tr, None]).sum(0) / w[tr].sum()
        bc = cur.get("gyro_bias_dps")
        e_new = _rms(g[ho] - b)
        e_cur = _rms(g[ho] - (0 if bc is None else np.asarray(bc)))
        bfull = (g * w[:, None]).sum(0) / w.sum()
        sd = np.sqrt(((g - bfull) ** 2 * w[:, None]).sum(0) / w.sum() / max(len(g) - 1, 1))
        out["gyro"] = {"bias_dps": b.tolist(), "stderr_dps": sd.tolist(),
                       "heldout_rms_dps": e_new, "heldout_rms_before_dps": e_cur,
                       "accept": bool(e_new < e_cur)}


def _mag(mp: np.ndarray, job: Dict[str, Any], cur: Dict[str, Any]) -> Dict[str, Any]:
    """The rotation-cloud calibration (calib.magcal), validated on every k-th point.

    A cloud from a one-plane swing is reported (the undetermined axis) and never
    applied."""
    noise = job.get("mag_noise")
    cov = None
    if noise is not None and np.all(np.isfinite(noise)) and np.all(np.asarray(noise) > 0):
        flat = flat_axis(mp, np.asarray(noise, float))
        if flat is not None:
            return {"determined": False, "flat": flat, "points": int(len(mp)), "accept": False}
        cov = np.diag(np.asarray(noise, float) ** 2)
    mho = _holdout(len(mp), job["holdout_fraction"])
    mc = fit_norm(mp[~mho], "mag_sym", "lm", rng=job.get("seed"), heldout=False,
                  pose_cov=None if cov is None else np.broadcast_to(cov, (int((~mho).sum()), 3, 3)))
    hn = np.linalg.norm(_MAG.forward(mc.theta, mp[mho]), axis=1)
    e_new = _rms(hn - 1)
    mth = cur.get("mag_theta")
    if mth is None:
        hc = np.linalg.norm(mp[mho], axis=1)
        e_cur = _rms(hc / np.median(np.linalg.norm(mp, axis=1)) - 1)
    else:
        e_cur = _rms(np.linalg.norm(_MAG.forward(np.asarray(mth), mp[mho]), axis=1) - 1)
    return {"determined": True, "theta": mc.theta.tolist(), "params": mc.params, "stderr": mc.stderr,
            "points": int(len(mp)), "coverage": coverage(_MAG, mc.theta, mp),
            "heldout_rel_rms": e_new, "heldout_rel_rms_before": e_cur, "accept": bool(e_new < e_cur)}
