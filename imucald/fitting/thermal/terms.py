"""Temperature terms of a calibration, and how many of them the data support.

A sensor's bias is a polynomial in temperature about a reference t_ref_c,

    b(T) = b0 + sum_{k=1..K} p_k (T - t_ref_c)^k,      K = 0..3,

(ArduPilot's INS_TCAL and PX4's TC_* use a cubic; MPU-class parts have no common curve
from unit to unit, so it is fitted per unit) and, for the accelerometer, optionally a
scale change s(T) = s_1 (T - t_ref_c) per axis on the raw reading minus its bias.  Only
the temperature range the fit saw is trusted: outside it the terms are held at the edge
(calibration.py clamps).

The order is chosen with the gap diagnosis's own test (gap/verdict.py, fitting/judging/heldout.py):
each order's leave-one-out held-out residuals against the twin (what the noise model
predicts for the same design); the constant has a gap when the chi-square test rejects
the noise model *and* its held-out ratio lies above the twin's 99th percentile; then,
among the higher orders that improve significantly (nested chi-square, Bonferroni over
the variants) and lower the held-out error, the simplest whose held-out ratio lies within
its twin's 99th percentile ("closed"), else the one with the lowest ratio.  Scatter in
excess of the stated noise that even the richest variant (of the norm fit's variants, the
best-fitting one) leaves (steps, hysteresis, flicker between poses) inflates every
variance first (as gap/linear.py does), so the test is against what a smooth curve can
explain.  Below ``min_span_c`` of temperature
only the constant is fitted, and the note says why.

Two fitters, one rule: :func:`fit_bias_series` for direct bias observations (gyro still
means, deg/s; any vector bias) by weighted least squares, and :func:`fit_norm_thermal`
for a norm model (accelerometer |a| = 1 g, magnetometer hard iron), by weighted
Levenberg-Marquardt with the model's prior.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ...numerics.rng import as_rng
from ..models import effect_forms
from ..judging.heldout import heldout, lm_weighted, numjac, twin_rms
from ..judging.levels import THERMAL_TREND_LEVEL
from ...numerics.tails import chi2_logsf
from ...numerics.npstats import median

__all__ = ["ThermalFit", "fit_bias_series", "fit_norm_thermal", "thermal_design", "MIN_SPAN_C", "MAX_ORDER"]

MIN_SPAN_C = 10.0       #: default calibration.thermal_min_span_c: below it only a constant
MAX_ORDER = 3
SIMS = 200              #: twin re-simulations per variant
MIN_DOF = 6             #: residual degrees of freedom a variant must leave
#: observations fit_bias_series needs for a first-order term (3 N - 6 >= MIN_DOF); the
#: daemon's job asks the same of its thermal log
MIN_BIAS_OBS = (MIN_DOF + 6 + 2) // 3


@dataclass
class ThermalFit:
    """The chosen temperature terms.  Polynomial rows are coefficients of (T - t_ref_c)^k,
    k = 1..order, in the sensor's unit per degC^k; ``scale_poly`` (accelerometer) in 1/degC."""

    order: int
    t_ref_c: float
    t_min_c: float
    t_max_c: float
    bias_poly: np.ndarray                       #: (order, 3)
    bias_poly_stderr: np.ndarray                #: (order, 3)
    note: str
    base: np.ndarray                            #: constant part: bias (3,) or norm-model theta
    base_stderr: np.ndarray
    scale_poly: Optional[np.ndarray] = None     #: (1, 3) or None
    scale_poly_stderr: Optional[np.ndarray] = None
    variants: Dict[str, Dict[str, object]] = field(default_factory=dict)   #: the test, per variant
    inflation: float = 1.0                      #: excess-scatter factor applied to the variances
    cov: Optional[np.ndarray] = None            #: covariance of [base, terms] (scaled units)
    _scale_c: float = 1.0                       #: temperature scaling of the fit (degC)
    #: what a refit of the chosen variant needs (fitting/thermal/gate.py): z (norm fits), the
    #: inflated variances, the prior's precision and mean
    state: Dict[str, object] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"order {self.order}" + (" + scale" if self.scale_poly is not None else "")

    def to_thermal(self, unit: str) -> Dict[str, object]:
        """The ``thermal`` block of a calibration part (calibration.SensorCal.thermal)."""
        d: Dict[str, object] = {"order": int(self.order), "t_ref_c": round(float(self.t_ref_c), 3),
                                "t_min_c": round(float(self.t_min_c), 3),
                                "t_max_c": round(float(self.t_max_c), 3)}
        if self.order:
            d[f"bias_poly_{unit}"] = np.asarray(self.bias_poly, float)
            d[f"bias_poly_stderr_{unit}"] = np.asarray(self.bias_poly_stderr, float)
        if self.scale_poly is not None:
            d["scale_poly"] = np.asarray(self.scale_poly, float)
            d["scale_poly_stderr"] = np.asarray(self.scale_poly_stderr, float)
        d["note"] = self.note
        return d


# --- the rule ------------------------------------------------------------------------------

def _stats(r, J, w, var, lam, rng, sims):
    """chi2, held-out residuals, ratio to the twin and its 99th percentile (normalised, as
    gap/norm.py: points of unequal noise)."""
    e = heldout(r, J, w, lam)
    tw = twin_rms(J, var, w, sims, rng, lam, normalised=True)
    med = float(median(tw))
    num = float(np.sqrt(np.mean(e * e * w)))
    if not med > 0:     # the design leaves no residual freedom (one pose): nothing to compare
        return {"chi2": float(np.sum(w * r * r)), "mse": float(np.mean(e * e * w)),
                "ratio": float("nan"), "q99": float("nan")}
    return {"chi2": float(np.sum(w * r * r)), "mse": float(np.mean(e * e * w)), "ratio": num / med,
            "q99": float(np.quantile(tw / med, 0.99))}


def _choose(res: Dict[str, dict], n_obs: int, names: Sequence[str]) -> Tuple[str, str]:
    """The gap's rule over the variants (res[name]: q, chi2, mse, ratio, q99, dof); returns
    (chosen name, why)."""
    b = res["order 0"]
    p_gap = math.exp(chi2_logsf(b["chi2"], max(b["dof"], 1)))
    gap = p_gap < THERMAL_TREND_LEVEL and b["ratio"] > b["q99"]
    b.update(p_value=p_gap, gap=bool(gap))
    if not gap:
        return "order 0", (f"no temperature trend beyond the noise (held-out ratio {b['ratio']:.2f}, "
                           f"twin 99 % {b['q99']:.2f}, p = {p_gap:.2g})")
    bonf = THERMAL_TREND_LEVEL / max(len(names) - 1, 1)
    sig = []
    for n in names[1:]:
        v = res[n]
        lp = chi2_logsf(max(b["chi2"] - v["chi2"], 0.0), v["q"] - b["q"])
        v["nested_p_value"] = math.exp(lp)
        v["closed"] = bool(v["ratio"] <= v["q99"])
        v["significant"] = bool(v["nested_p_value"] < bonf and v["mse"] < b["mse"])
        if v["significant"]:
            sig.append(n)
    if not sig:
        return "order 0", "a gap at the constant, but no polynomial improves it significantly"
    closing = [n for n in sig if res[n]["closed"]]
    best = (min(closing, key=lambda n: (res[n]["q"], res[n]["ratio"])) if closing
            else min(sig, key=lambda n: res[n]["ratio"]))
    v = res[best]
    return best, (f"held-out ratio {b['ratio']:.2f} at the constant -> {v['ratio']:.2f} "
                  f"(twin 99 % {v['q99']:.2f}{', closed' if v['closed'] else ', the lowest; not closed'}; "
                  f"simplest that closes of {', '.join(names)})")


def _few_note(n: int, what: str, need: int) -> str:
    return f"{n} {what if n != 1 else what[:-1]}: a temperature term needs at least {need}: constant only, not tested"


def _span_note(span: float, min_span_c: float) -> str:
    return (f"temperature span {span:.1f} degC < {min_span_c:g} degC (calibration.thermal_min_span_c): "
            f"constant only")


# --- direct bias observations -----------------------------------------------------------------

def thermal_design(u: np.ndarray, order: int) -> np.ndarray:
    """(3N, 3 (order + 1)) design: per axis, powers u^0..u^order (rows x0 y0 z0 x1 ...)."""
    N = len(u)
    X = np.zeros((3 * N, 3 * (order + 1)))
    for p in range(order + 1):
        for j in range(3):
            X[j::3, 3 * p + j] = u ** p
    return X


def _temperature_axis(T):
    """(t_min_c, t_max_c, t_ref_c, scale_c, u) of temperatures T (N,): the range seen, its
    middle rounded to 0.01 degC yet within the range, half the span (at least 1e-6) and
    u = (T - t_ref_c) / scale_c in [-1, 1], the polynomials' variable."""
    lo, hi = float(T.min()), float(T.max())
    t_ref = min(max(round((lo + hi) / 2, 2), lo), hi)
    s = max((hi - lo) / 2, 1e-6)
    return lo, hi, t_ref, s, (T - t_ref) / s


def _constant_ref(T, w, lo: float, hi: float) -> float:
    """Where a constant (order 0) stands: the temperature its weighted mean of the poses is the
    bias at, rounded to 0.01 degC within the range (the weights ``w`` (N,), the fit's), not the
    range's middle: a black-box helper's 8-degC warm-up held its later poses longest, and its
    order-0 calibration named 31.9 degC where the poses' weighted mean was 35.5 (at 1 mg/degC,
    3.6 mg between the two)."""
    return min(max(round(float(np.sum(w * T) / np.sum(w)), 2), lo), hi)


def fit_bias_series(temp_c, y, var, min_span_c: float = MIN_SPAN_C, max_order: int = MAX_ORDER,
                    sims: int = SIMS, rng=None) -> ThermalFit:
    """Bias polynomial from direct observations: ``y`` (N, 3) bias readings (e.g. gyro still
    means, deg/s) at ``temp_c`` (N,) with variances ``var`` (N, 3) (or (N,))."""
    rng = as_rng(rng)
    T = np.asarray(temp_c, float)
    y = np.asarray(y, float)
    v = np.broadcast_to(np.asarray(var, float).reshape(len(y), -1), (len(y), 3)).astype(float)
    ok = np.isfinite(T) & np.all(np.isfinite(y), 1) & np.all(v > 0, 1)
    T, y, v = T[ok], y[ok], v[ok]
    if len(T) == 0:
        raise ValueError("no observation with a finite temperature")
    lo, hi, t_ref, s, u = _temperature_axis(T)
    span = hi - lo
    yy, vv = y.reshape(-1), v.reshape(-1)
    orders = [k for k in range(max_order + 1) if 3 * len(T) - 3 * (k + 1) >= MIN_DOF]
    few = len(orders) < 2       # too few observations for any temperature term: no test at all
    if span < min_span_c or few:
        orders = orders[:1] or [0]
    fits = {}
    for k in orders:
        X = thermal_design(u, k)
        fits[k] = X
    # excess scatter left by the richest order inflates every variance (steps, hysteresis)
    infl = 1.0
    kmax = orders[-1]
    if kmax > 0:
        X = fits[kmax]
        w = 1 / vv
        beta = np.linalg.lstsq(X * np.sqrt(w)[:, None], yy * np.sqrt(w), rcond=None)[0]
        r = yy - X @ beta
        infl = max(1.0, float(np.sum(w * r * r)) / (len(yy) - X.shape[1]))
    vv = vv * infl
    w = 1 / vv
    res, sol = {}, {}
    for k, X in fits.items():
        A = X.T @ (X * w[:, None])
        Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
        beta = Ai @ (X.T @ (w * yy))
        sol[k] = (beta, Ai)
        if not few:
            st = _stats(yy - X @ beta, -X, w, vv, None, rng, sims)
            st.update(q=X.shape[1], dof=len(yy) - X.shape[1])
            res[f"order {k}"] = st
    names = [f"order {k}" for k in orders]
    if few:
        chosen, why = "order 0", _few_note(len(T), "still intervals", MIN_BIAS_OBS)
    elif span < min_span_c:
        chosen, why = "order 0", _span_note(span, min_span_c)
    else:
        chosen, why = _choose(res, len(yy), names)
    k = int(chosen.split()[1])
    beta, Ai = sol[k]
    B = beta.reshape(k + 1, 3)
    S = np.sqrt(np.diag(Ai)).reshape(k + 1, 3)
    per = np.array([s ** p for p in range(1, k + 1)])[:, None]
    if k == 0:
        t_ref = _constant_ref(T, w.reshape(-1, 3).mean(1), lo, hi)
    return ThermalFit(k, t_ref, lo, hi, B[1:] / per, S[1:] / per, f"{chosen}: {why}", B[0], S[0],
                      variants=_public(res), inflation=infl, cov=Ai, _scale_c=s,
                      state={"var": vv.reshape(-1, 3), "ok": ok})


def _public(res):
    return {n: {k: (round(v, 4) if isinstance(v, float) else v) for k, v in d.items()} for n, d in res.items()}


# --- norm models (accelerometer, magnetometer hard iron) -----------------------------------------

def _norm_variants(max_order: int, scale: bool) -> List[Tuple[str, int, bool]]:
    out = [(f"order {k}", k, False) for k in range(max_order + 1)]
    if scale:
        out.insert(2, ("order 1 + scale", 1, True))
    return out


def _delta(model, z, x, u, k: int, sc: bool) -> np.ndarray:
    """The raw-frame thermal offset of parameters z = [theta, bias rows, scale row] at scaled
    temperatures u = (T - t_ref) / s: sum_j eta_j u^j (+ (x - b0) s u)."""
    p = model.k
    th, eta = z[:p], z[p:]
    d = np.zeros_like(x)
    for j in range(k):          # the declared effect forms (fitting/models/effect_forms.py), per power
        d += effect_forms.thermal_bias(eta[3 * j:3 * j + 3], u ** (j + 1))
    if sc:
        A, c = model.affine(th)
        d += effect_forms.thermal_scale(eta[3 * k:3 * k + 3], x - (-np.linalg.solve(A, c)), u)
    return d


def refit_norm(model, x, w, u, k: int, sc: bool, z0, pm, lam, target: float = 1.0) -> np.ndarray:
    """One variant's weighted LM fit (the MAP one with prior precision ``lam`` about ``pm``)
    on pose means x at scaled temperatures u; returns z = [theta, terms] (scaled units)."""
    p = model.k
    pri = lam > 0

    def fun(z):
        r = target - model.norms(z[:p], x - _delta(model, z, x, u, k, sc))
        return np.concatenate([r, (z[:p] - pm)[pri]])
    z, _, _ = lm_weighted(fun, z0, np.concatenate([w, lam[pri]]), iters=40)
    return z


def norm_residuals(model, z, x, u, k: int, sc: bool, target: float = 1.0) -> np.ndarray:
    """target - |corrected| of pose means x at scaled temperatures u."""
    return target - model.norms(z[:model.k], x - _delta(model, z, x, u, k, sc))


def fit_norm_thermal(model, x, pose_var, temp_c, theta0, prior: Optional[Tuple[np.ndarray, np.ndarray]] = None,
                     min_span_c: float = MIN_SPAN_C, max_order: int = MAX_ORDER, scale: bool = True,
                     sims: int = SIMS, rng=None, target: float = 1.0) -> ThermalFit:
    """Bias polynomial (and with ``scale`` a first-order scale term) of a norm model: raw pose
    means ``x`` (N, 3) at ``temp_c`` (N,), per-pose residual variances ``pose_var`` (N,) (of
    target - |h|), ``theta0`` a constant fit to start from, ``prior`` (mean, std) of the
    model's parameters (NaN/inf std: none).  The base part (``ThermalFit.base``) is the
    model's theta at t_ref_c."""
    rng = as_rng(rng)
    x = np.asarray(x, float)
    T = np.asarray(temp_c, float)
    vv0 = np.asarray(pose_var, float)
    ok = np.isfinite(T) & np.all(np.isfinite(x), 1) & (vv0 > 0)
    x, T, vv0 = x[ok], T[ok], vv0[ok]
    N, p = len(x), model.k
    if N == 0:
        raise ValueError("no pose with a finite temperature, a finite mean and a variance > 0")
    lo, hi, t_ref, s, u = _temperature_axis(T)
    span = hi - lo
    if prior is not None:
        pm, ps = (np.asarray(a, float) for a in prior)
        lam = np.where(np.isfinite(ps) & (ps > 0), 1.0 / np.where(np.isfinite(ps) & (ps > 0), ps, 1.0) ** 2, 0.0)
    else:
        pm, lam = np.zeros(p), np.zeros(p)
    variants = [v for v in _norm_variants(max_order, scale) if N - p - 3 * (v[1] + v[2]) >= MIN_DOF]
    few = len(variants) < 2     # too few poses for any temperature term: no test at all
    if span < min_span_c or few:
        variants = variants[:1] or [("order 0", 0, False)]

    def fit(k, sc, w, z0):
        z = refit_norm(model, x, w, u, k, sc, z0, pm, lam, target)
        r, J = numjac(lambda zz: target - model.norms(zz[:p], x - _delta(model, zz, x, u, k, sc)), z)
        return z, r, J, np.concatenate([lam, np.zeros(3 * (k + sc))])

    w0 = 1 / vv0
    fitted = {}
    for name, k, sc in variants:
        z0 = np.concatenate([np.asarray(theta0, float), np.zeros(3 * (k + sc))])
        fitted[name] = fit(k, sc, w0, z0)
    # the excess scatter the best of the temperature variants leaves (they are not nested:
    # a scale term is no part of the cubic bias)
    infl = 1.0
    if len(variants) > 1:
        infl = max(1.0, min(float(np.sum(w0 * fitted[v[0]][1] ** 2)) / max(N - fitted[v[0]][2].shape[1], 1)
                            for v in variants[1:]))
    vv = vv0 * infl
    w = 1 / vv
    res = {}
    for name, k, sc in variants:
        if few:
            break
        z, r, J, la = fitted[name]
        st = _stats(r, J, w, vv, la, rng, sims)
        st.update(q=3 * (k + sc), dof=N - p)
        res[name] = st
    names = [v[0] for v in variants]
    if few:
        chosen, why = "order 0", _few_note(N, "poses", p + 3 + MIN_DOF)
    elif span < min_span_c:
        chosen, why = "order 0", _span_note(span, min_span_c)
    else:
        chosen, why = _choose(res, N, names)
    name, k, sc = next(v for v in variants if v[0] == chosen)
    z, r, J, la = fitted[name]
    Ai = np.linalg.pinv(J.T @ (J * w[:, None]) + np.diag(la), rcond=1e-12, hermitian=True)
    sd = np.sqrt(np.diag(Ai))
    per = np.array([s ** j for j in range(1, k + 1)])[:, None]
    eta, seta = z[p:], sd[p:]
    bp = eta[:3 * k].reshape(k, 3) / per if k else np.zeros((0, 3))
    bs = seta[:3 * k].reshape(k, 3) / per if k else np.zeros((0, 3))
    sp = eta[3 * k:].reshape(1, 3) / s if sc else None
    ss = seta[3 * k:].reshape(1, 3) / s if sc else None
    if k == 0 and not sc:
        t_ref = _constant_ref(T, w, lo, hi)
    out = ThermalFit(k, t_ref, lo, hi, bp, bs, f"{chosen}: {why}", z[:p], sd[:p], sp, ss,
                     _public(res), infl, Ai, s)
    out.state = {"z": z, "var": vv, "lam": lam, "pm": pm, "scale": sc}
    return out
