"""The acceptance gate for thermal terms: the chosen variant cross-validated over the
still intervals (k-fold over intervals, each fold refitted with the same order and
reference temperature) against the calibration in force applied at each interval's own
temperature, with fitting/gate.py's paired signed-rank test at its false-accept rate.

Thermal terms already in force were fitted on a narrower range and are held at its edges
beyond it; a refit over a wider span is then judged on the intervals outside the range in
force, which it must predict significantly better.  Inside that range the terms in force
were fitted on the same intervals (their residuals there are in-sample, the candidate's
cross-validated), so a comparison there would favour them for nothing; and diluting the
new intervals among the many inside the old range would keep the old terms however wrong
their held edge value becomes."""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from ..gate import Decision, fold_groups, paired_gate
from ..judging.levels import GATE_FALSE_ACCEPT_RATE
from .terms import ThermalFit, thermal_design, norm_residuals, refit_norm

__all__ = ["gate_norm_thermal", "gate_bias_thermal", "FOLDS", "MIN_OUTSIDE"]

FOLDS = 10
MIN_OUTSIDE = 5     #: intervals beyond the range in force that a range extension is judged on


def _decide(sq_inc, sq_cv, T, current: Optional[dict], alpha: float, against: str) -> Decision:
    if current and current.get("order", 0) > 0:
        out = (T < current["t_min_c"]) | (T > current["t_max_c"])
        if out.sum() >= MIN_OUTSIDE:
            return paired_gate(sq_inc[out], sq_cv[out], alpha, against)
    return paired_gate(sq_inc, sq_cv, alpha, against)


def gate_norm_thermal(model, tf: ThermalFit, x, temp_c, incumbent,
                      alpha: float = GATE_FALSE_ACCEPT_RATE,
                      against: str = "current", target: float = 1.0,
                      current: Optional[dict] = None) -> Tuple[np.ndarray, Decision]:
    """Norm model (accelerometer): ``x`` raw pose means (N, 3) at ``temp_c``, ``incumbent``
    the same corrected by the calibration in force (each at its temperature), ``current``
    its thermal block (or None)."""
    x = np.asarray(x, float)
    T = np.asarray(temp_c, float)
    u = (T - tf.t_ref_c) / tf._scale_c
    st = tf.state
    k, sc = tf.order, bool(st["scale"])
    w = 1 / np.asarray(st["var"], float)
    r_cv = np.zeros(len(x))
    for g in fold_groups(len(x), FOLDS):
        keep = np.ones(len(x), bool)
        keep[g] = False
        z = refit_norm(model, x[keep], w[keep], u[keep], k, sc, st["z"], st["pm"], st["lam"], target)
        r_cv[g] = norm_residuals(model, z, x[g], u[g], k, sc, target)
    r_inc = target - np.linalg.norm(np.asarray(incumbent, float), axis=1)
    return r_cv, _decide(r_inc ** 2, r_cv ** 2, T, current, alpha, against)


def gate_bias_thermal(tf: ThermalFit, temp_c, y, incumbent, alpha: float = GATE_FALSE_ACCEPT_RATE,
                      against: str = "current", current: Optional[dict] = None
                      ) -> Tuple[np.ndarray, Decision]:
    """Direct bias observations (gyro still means, (N, 3)): a still interval should read
    zero; ``incumbent`` the same corrected by the calibration in force."""
    ok = tf.state["ok"]
    T = np.asarray(temp_c, float)[ok]
    y = np.asarray(y, float)[ok]
    u = (T - tf.t_ref_c) / tf._scale_c
    v = np.asarray(tf.state["var"], float)
    e = np.zeros_like(y)
    for g in fold_groups(len(y), FOLDS):
        keep = np.ones(len(y), bool)
        keep[g] = False
        X = thermal_design(u[keep], tf.order)
        wv = 1 / v[keep].reshape(-1)
        beta = np.linalg.lstsq(X * np.sqrt(wv)[:, None], y[keep].reshape(-1) * np.sqrt(wv), rcond=None)[0]
        e[g] = y[g] - (thermal_design(u[g], tf.order) @ beta).reshape(-1, 3)
    inc = np.asarray(incumbent, float)[ok]
    return e, _decide((inc ** 2).sum(1), (e ** 2).sum(1), T, current, alpha, against)
