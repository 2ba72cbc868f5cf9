"""The thermal part of a calibration job (pure, run in the worker like the rest).

With the still intervals of the thermal log (daemon/thermallog.py) spanning at least
``calibration.thermal_min_span_c``: the accelerometer's bias polynomial (and scale term)
through the norm model, the gyro's from its still means, each order chosen by
fitting/thermal/terms.py's held-out test and then gated (fitting/thermal/gate.py) against the
calibration in force, applied at each interval's own temperature.  A candidate that
passes replaces the constant one of the same job.  Below the span nothing is fitted and
the note says why; with the terms in force, the constant refits of later jobs keep them
(fitjob.py fits on the thermally corrected poses).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Dict

import numpy as np

from ..fitting.fit import accel_prior
from ..fitting.judging.levels import GATE_FALSE_ACCEPT_RATE
from ..fitting.models.mag import MagModel, mag_report
from ..fitting.models.accel import Triangular9
from ..fitting.thermal.terms import fit_bias_series, fit_norm_thermal
from ..fitting.thermal.gate import gate_bias_thermal, gate_norm_thermal
from ..fitting.judging.uncertainty import residual_variance
from ..calibration import Calibration, SensorCal
from ..numerics.npstats import median

__all__ = ["thermal_parts", "mag_thermal"]

_T9 = Triangular9()


def thermal_parts(job: Dict[str, Any], cur: Calibration, parts: Dict[str, SensorCal],
                  accept: Dict[str, bool], gates: Dict[str, Any], notes: Dict[str, Any]) -> None:
    """Fit, choose and gate the thermal terms; write notes["thermal"][sensor] =
    {order, note, accepted, p_value?} and, when accepted, the part and its decision."""
    th = job.get("thermal")
    if not th:
        return
    min_span = float(job.get("thermal_min_span_c", 10.0))
    alpha = job.get("alpha", GATE_FALSE_ACCEPT_RATE)
    T = np.asarray(th["temp"], float)
    out = notes.setdefault("thermal", {})
    seed = job.get("seed")
    a = parts.get("accel")
    if a is not None and a.model == "triangular9" and len(T) >= 12:
        acc = np.asarray(th["acc"], float)
        var = residual_variance(_T9, a.theta, acc, np.asarray(th["acc_cov"], float))
        tf = fit_norm_thermal(_T9, acc, var, T, a.theta, accel_prior(_T9, cur.chips.get("accel")), min_span, rng=seed)
        ent = {"order": tf.order, "note": tf.note, "accepted": False, "span_c": round(tf.t_max_c - tf.t_min_c, 2)}
        if tf.order or tf.scale_poly is not None:
            _, dec = gate_norm_thermal(_T9, tf, acc, T, cur.apply_accel(acc, T), alpha,
                                       "raw" if cur.accel is None else "current",
                                       current=cur.accel.thermal if cur.accel is not None else None)
            ent.update(accepted=dec.accept, p_value=dec.p_value, rms_cv_g=dec.rms_cv,
                       rms_before_g=dec.rms_incumbent)
            if dec.accept:
                cand = SensorCal.accel("triangular9", tf.base, tf.base_stderr, a.method,
                                       {**a.quality, "thermal_heldout_rms_g": dec.rms_cv,
                                        "thermal_heldout_rms_before_g": dec.rms_incumbent,
                                        "thermal_gate_p_value": dec.p_value})
                parts["accel"], accept["accel"], gates["accel"] = replace(cand, thermal=tf.to_thermal("g")), True, dec
        out["accel"] = ent
    g = parts.get("gyro")
    if g is not None and th.get("gyro") is not None and len(T) >= 4:
        y = np.asarray(th["gyro"], float)
        var = np.maximum(np.asarray(th["gyro_var"], float), 1e-12)
        # a g-sensitivity in force (calibrate --sensor gyro): the bias series is fitted on the
        # means without G a, and the incumbent scored with it (as the daemon applies it)
        acc_cal = cur.apply_accel(np.asarray(th["acc"], float), T)
        y_fit = g.g_offset(y, acc_cal)
        tf = fit_bias_series(T, y_fit, var, min_span, rng=seed)
        ent = {"order": tf.order, "note": tf.note, "accepted": False, "span_c": round(tf.t_max_c - tf.t_min_c, 2)}
        if tf.order:
            _, dec = gate_bias_thermal(tf, T, y_fit, cur.apply_gyro(y, T, acc_cal), alpha,
                                       "raw" if cur.gyro is None else "current",
                                       current=cur.gyro.thermal if cur.gyro is not None else None)
            ent.update(accepted=dec.accept, p_value=dec.p_value, rms_cv_dps=dec.rms_cv,
                       rms_before_dps=dec.rms_incumbent)
            if dec.accept:
                # only the bias (and its thermal terms) is refitted: the matrix and
                # g-sensitivity of the part in force stay
                cand = SensorCal("gyro", g.model, {**g.params, "bias_dps": np.asarray(tf.base, float)},
                                 {**g.stderr, "bias_dps": np.asarray(tf.base_stderr, float)}, g.flags, "thermal",
                                 {**g.quality, "thermal_heldout_rms_dps": dec.rms_cv,
                                  "thermal_heldout_rms_before_dps": dec.rms_incumbent,
                                  "thermal_gate_p_value": dec.p_value}, tf.to_thermal("dps"))
                parts["gyro"], accept["gyro"], gates["gyro"] = cand, True, dec
        out["gyro"] = ent


def mag_thermal(job: Dict[str, Any], cur: Calibration, mp: np.ndarray, temp: np.ndarray, cov,
                theta0: np.ndarray, parts: Dict[str, SensorCal], accept: Dict[str, bool],
                notes: Dict[str, Any]) -> None:
    """The hard iron's thermal terms on the magnetometer cloud (raw points ``mp`` at
    ``temp``), started from the constant fit ``theta0`` (unit sphere), gated like the
    accelerometer's on the points (10 folds) against the calibration in force."""
    mdl = MagModel("sym")
    min_span = float(job.get("thermal_min_span_c", 10.0))
    c = np.eye(3) * median(np.var(np.diff(mp, axis=0), axis=0)) / 2 if cov is None else cov
    var = residual_variance(mdl, theta0, mp, np.broadcast_to(c, (len(mp), 3, 3)))
    tf = fit_norm_thermal(mdl, mp, var, temp, theta0, None, min_span, scale=False, rng=job.get("seed"))
    ent = {"order": tf.order, "note": tf.note, "accepted": False, "span_c": round(tf.t_max_c - tf.t_min_c, 2)}
    if tf.order:
        if cur.mag is None:
            inc = mp / median(np.linalg.norm(mp, axis=1))
        else:
            inc = cur.apply_mag(mp, temp) / float(cur.mag.params["field_gauss"])
        _, dec = gate_norm_thermal(mdl, tf, mp, temp, inc,
                                   job.get("alpha", GATE_FALSE_ACCEPT_RATE),
                                   "raw" if cur.mag is None else "current",
                                   current=cur.mag.thermal if cur.mag is not None else None)
        ent.update(accepted=dec.accept, p_value=dec.p_value)
        if dec.accept:
            p, se = mag_report(mdl, tf.base, tf.cov[:mdl.k, :mdl.k])
            arr = lambda d: {k: np.asarray(v, float) for k, v in d.items()}
            q = parts["mag"].quality if "mag" in parts else {}
            parts["mag"] = SensorCal("mag", "mag_sym", arr(p), arr(se), {}, "thermal",
                                     {**q, "thermal_heldout_rel_rms": dec.rms_cv,
                                      "thermal_heldout_rel_rms_before": dec.rms_incumbent,
                                      "thermal_gate_p_value": dec.p_value}, tf.to_thermal("gauss"))
            accept["mag"] = True
            notes["gate"]["mag"] = dec
    notes.setdefault("thermal", {})["mag"] = ent
