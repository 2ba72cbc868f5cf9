"""Sim-to-real gap diagnosis: where real data leaves the sensor model, which
unmodelled effect causes it, and how far the gap shrinks once it is modelled.

Method (../shared/reference/error-models.md sections 3-5):

1. **Twin.**  Still poses are segmented with the calibration's detector; the
   baseline model is fitted by weighted least squares; the noise is measured in
   the data: per-pose within-pose variance, combined robustly (median over
   poses; a pose whose own variance is far above it is flagged as disturbed and
   left out), inflated by the Allan deviation at the pose length when a long
   still stretch shows coloured noise.  The twin re-simulates the same poses
   ``sims`` times with that noise and refits (linearised), giving the held-out
   residual the model predicts.
2. **Gap.**  Held-out residuals (leave-one-pose-out, by leverage) of the real
   data over the twin's median: ``ratio`` is about 1 when the model is adequate;
   a chi-square test on the normalised residuals gives the p-value.
3. **Where.**  Excess residual by orientation region, temperature and time bins;
   trend tests against temperature, time, each axis squared, and the previous pose.
4. **Which effect.**  Every candidate's signature (its Jacobian columns,
   projected off what the baseline absorbs) is score-tested from the single
   baseline fit; significant candidates are refitted (nested test), judged by
   the held-out ratio; a second effect is added when one is not enough;
   candidates whose projected signatures coincide are reported as one class,
   with the recording that would separate them.
5. **Shrink**: ratio before and after, the effect's parameters and uncertainty.
6. **Verdict** per sensor: the effect, ``none``, or ``unexplained``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..calib.models import MagModel, NormModel, Triangular9
from ..calib.optim import Problem, lm
from ..calib.poses import detect_static, poses_from_slices
from ..calib.uncertainty import residual_variance
from ..errors import UserError
from ..recording import Recording
from ..calib.noise import colour_inflation
from .stats import chi2_logsf, chi2_sf, norm_sf2

__all__ = ["diagnose", "GapError", "ACCEL_CANDIDATES", "GYRO_CANDIDATES", "MAG_CANDIDATES"]

ALPHA = 0.01
RATIO_OK = 1.3          # a ratio after modelling above this is not "closed"
MIN_POSES = 15


class GapError(UserError):
    pass


# --- candidate effects --------------------------------------------------------------------

@dataclass
class Candidate:
    name: str
    q: int
    needs_temp: bool
    #: raw-frame perturbation delta (N, 3) for norm models: x' = x - delta(eta, x, theta, ctx)
    delta: Optional[Callable] = None
    #: design columns (3N, q) for the linear gyro model
    columns: Optional[Callable] = None
    units: str = ""


def _vec(eta):
    return np.asarray(eta, float)[:3]


ACCEL_CANDIDATES = [
    Candidate("thermal_bias", 3, True, lambda e, x, th, c: np.outer(c["dT"], _vec(e)), units="g/degC"),
    Candidate("thermal_scale", 3, True, lambda e, x, th, c: (x - th[6:9]) * np.outer(c["dT"], _vec(e)),
              units="1/degC"),
    Candidate("nonlinearity", 3, False, lambda e, x, th, c: _vec(e) * (x - th[6:9]) ** 2, units="g/g^2"),
    Candidate("bias_drift", 3, False, lambda e, x, th, c: np.outer(c["dt"], _vec(e)), units="g/s"),
]


def _sym_traceless(e):
    a, b, c, d, f = e
    return np.array([[a, c, d], [c, b, f], [d, f, -a - b]])


MAG_CANDIDATES = [
    Candidate("soft_iron", 5, False, lambda e, x, th, c: (x - th[1:4]) @ _sym_traceless(e).T,
              units="(symmetric traceless xx, yy, xy, xz, yz)"),
    Candidate("thermal_bias", 3, True, lambda e, x, th, c: np.outer(c["dT"], _vec(e)), units="gauss/degC"),
]


def _kron_cols(v):                      # (N,) -> (3N, 3): v_i * I3
    N = len(v)
    X = np.zeros((3 * N, 3))
    for j in range(3):
        X[j::3, j] = v
    return X


def _gsens_cols(c):
    a = c["acc_dir"]
    N = len(a)
    X = np.zeros((3 * N, 9))
    for j in range(3):
        X[j::3, 3 * j:3 * j + 3] = a
    return X


GYRO_CANDIDATES = [
    Candidate("thermal_bias", 3, True, columns=lambda c: _kron_cols(c["dT"]), units="dps/degC"),
    Candidate("g_sensitivity", 9, False, columns=_gsens_cols, units="dps/g (row-major G)"),
    Candidate("bias_drift", 3, False, columns=lambda c: _kron_cols(c["dt"]), units="dps/s"),
]

#: what separates candidates that look alike on a given pose set
SEPARATE = {
    frozenset({"thermal_bias", "bias_drift"}):
        "a temperature profile that rises and falls (heat then cool), so temperature is not a function of time",
    frozenset({"nonlinearity", "thermal_bias"}):
        "edge and corner poses (not only the six +-1 g faces) and a wider temperature range",
    frozenset({"nonlinearity", "bias_drift"}): "edge and corner poses, and a repeated reference pose",
    frozenset({"thermal_scale", "nonlinearity"}): "edge and corner poses and a wider temperature range",
    frozenset({"thermal_scale", "thermal_bias"}): "more poses per axis sign at each temperature",
    frozenset({"thermal_scale", "bias_drift"}): "a temperature profile that rises and falls",
    frozenset({"g_sensitivity", "thermal_bias"}): "poses in every orientation at each temperature",
    frozenset({"g_sensitivity", "bias_drift"}): "poses in every orientation at the start and the end",
    frozenset({"soft_iron", "thermal_bias"}): "rotation data over the whole sphere at a steady temperature",
}


# --- helpers ---------------------------------------------------------------------------------

def _numjac(fun, z, eps=None):
    z = np.asarray(z, float)
    r0 = fun(z)
    J = np.zeros((len(r0), len(z)))
    for k in range(len(z)):
        h = (eps[k] if eps is not None else 1e-6 * max(1.0, abs(z[k])))
        d = np.zeros_like(z)
        d[k] = h
        J[:, k] = (fun(z + d) - fun(z - d)) / (2 * h)
    return r0, J


def _lm_weighted(fun, z0, w, iters=60):
    """Weighted least squares min sum w r^2 with numerical Jacobians (small problems)."""
    z = np.asarray(z0, float).copy()
    r = fun(z)
    f = float(np.sum(w * r * r))
    mu = 1e-3
    for _ in range(iters):
        r, J = _numjac(fun, z)
        A = J.T @ (J * w[:, None])
        g = J.T @ (w * r)
        dA = np.diag(A).copy()
        dA[dA <= 0] = 1e-12
        improved = False
        for _ in range(12):
            try:
                step = -np.linalg.solve(A + mu * np.diag(dA), g)
            except np.linalg.LinAlgError:
                step = -np.linalg.lstsq(A + mu * np.diag(dA), g, rcond=None)[0]
            zn = z + step
            rn = fun(zn)
            fn = float(np.sum(w * rn * rn))
            if fn < f:
                rel = (f - fn) / max(f, 1e-300)
                z, r, f = zn, rn, fn
                mu = max(mu / 3, 1e-12)
                improved = True
                break
            mu *= 4
        if not improved or rel < 1e-12:
            break
    r, J = _numjac(fun, z)
    return z, r, J


def _hat_diag(J, w):
    A = J.T @ (J * w[:, None])
    Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
    return np.einsum("nk,kl,nl->n", J, Ai, J) * w, Ai


def _heldout(r, J, w):
    h, _ = _hat_diag(J, w)
    return r / np.maximum(1 - h, 1e-3)


def _twin(J, var, w, sims, rng):
    """Held-out RMS under the noise model for this design: M linearised re-simulations."""
    A = J.T @ (J * w[:, None])
    Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
    H = J @ Ai @ (J * w[:, None]).T
    h = np.diag(H)
    n = rng.normal(size=(sims, len(var))) * np.sqrt(var)
    r = n - n @ H.T
    e = r / np.maximum(1 - h, 1e-3)
    return np.sqrt(np.mean(e * e, axis=1))


def _proj_sig(J, C, w):
    """Candidate columns whitened and projected off the baseline Jacobian."""
    sw = np.sqrt(w)[:, None]
    Jw, Cw = J * sw, C * sw
    Q, _ = np.linalg.qr(Jw)
    Ct = Cw - Q @ (Q.T @ Cw)
    return Ct, Cw


def _score(rw, Ct, Cw):
    """Lagrange-multiplier (score) statistic and its visible rank."""
    U, s, _ = np.linalg.svd(Ct, full_matrices=False)
    full = np.linalg.norm(Cw, axis=0).max() if Cw.size else 0
    keep = s > 0.01 * max(full, 1e-300)
    if not keep.any():
        return 0.0, 0, 0.0
    Uk = U[:, keep]
    stat = float(np.sum((Uk.T @ rw) ** 2))
    vis = float(np.linalg.norm(Ct) / max(np.linalg.norm(Cw), 1e-300))
    return stat, int(keep.sum()), vis


def _canon(Ct1, Ct2):
    """Largest canonical correlation between two projected signature subspaces."""
    def basis(C):
        U, s, _ = np.linalg.svd(C, full_matrices=False)
        return U[:, s > 1e-9 * max(s.max(), 1e-300)] if s.size else U[:, :0]
    A, B = basis(Ct1), basis(Ct2)
    if not A.shape[1] or not B.shape[1]:
        return 0.0
    return float(np.linalg.svd(A.T @ B, compute_uv=False).max())


def _p_and_log10(stat, dof):
    lp = chi2_logsf(stat, dof) if dof > 0 else 0.0
    return math.exp(lp), lp / math.log(10)


def _region(u):
    j = int(np.argmax(np.abs(u)))
    return f"{'+' if u[j] > 0 else '-'}{'XYZ'[j]} up"


def _corr_p(x, y):
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) < 5 or x.std() == 0 or y.std() == 0:
        return None
    r = float(np.corrcoef(x, y)[0, 1])
    r = max(min(r, 0.999999), -0.999999)
    z = math.atanh(r) * math.sqrt(len(x) - 3)
    return {"r": round(r, 3), "p_value": norm_sf2(z)}


# --- noise -----------------------------------------------------------------------------------

def _flag_disturbed(s2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Poses whose within-pose variance is far above the robust level (hand moved)."""
    med = np.median(s2)
    # chi-square(n-1)/(n-1) upper 99.9 % point ~ 1 + 3.1 sqrt(2/(n-1)); times 1.5 for colour
    lim = med * 1.5 * (1 + 3.1 * np.sqrt(2.0 / np.maximum(n - 1, 1)))
    return s2 > lim


def _colour(rec_x: np.ndarray, still: Optional[slice], rate: float, T: float) -> Tuple[float, Optional[dict]]:
    """Inflation of the pose-mean variance at averaging time T over white noise, from
    the longest still stretch: the calibration's own estimate (calib.noise)."""
    return colour_inflation(None if still is None else rec_x[still], rate, T)


# --- the norm-model diagnosis (accelerometer, magnetometer) --------------------------------

def _norm_diag(x: np.ndarray, ctx: Dict[str, np.ndarray], pose_var: np.ndarray, model: NormModel,
               cands: List[Candidate], sims: int, rng, names_skip: Dict[str, str],
               unit: str, scale: float = 1.0) -> Dict[str, object]:
    N = len(x)
    p0 = model.k
    prob = Problem(model, x)
    th = lm(prob).theta
    var = residual_variance(model, th, x, pose_var)
    w = 1.0 / var
    th = lm(Problem(model, x, weights=w), z0=prob.reduce(th)).theta
    r, J = model.jacobian(th, x)
    chi2 = float(np.sum(w * r * r))
    p_gap, lp_gap = _p_and_log10(chi2, N - p0)
    e = _heldout(r, J, w)
    tw = _twin(J, var, w, sims, rng)
    twin = float(np.median(tw))
    ratio = float(np.sqrt(np.mean(e * e)) / twin)
    ratio_q99 = float(np.quantile(tw / twin, 0.99))
    out: Dict[str, object] = {
        "poses": N, "ratio_before": ratio, "p_value": p_gap, "log10_p_value": round(lp_gap, 2),
        "chi2": chi2, "dof": N - p0, "heldout_rms": float(np.sqrt(np.mean(e * e))) * scale,
        "twin_heldout_rms": twin * scale, "twin_ratio_q99": ratio_q99, "unit": unit,
    }
    # a gap: the chi-square test rejects the noise model, and the held-out ratio lies
    # above what the twin produces in 99 % of its re-simulations
    significant = p_gap < ALPHA and ratio > ratio_q99
    # --- which effect: score tests from the baseline fit
    sw = np.sqrt(w)
    rw = r * sw
    tested = []
    for c in cands:
        if c.name in names_skip:
            continue
        f = lambda eta, c=c: 1.0 - model.norms(th, x - c.delta(eta, x, th, ctx))
        _, C = _numjac(f, np.zeros(c.q), eps=np.full(c.q, 1e-5))
        Ct, Cw = _proj_sig(J, C, w)
        stat, q_vis, vis = _score(rw, Ct, Cw)
        p, lp = _p_and_log10(stat, q_vis) if q_vis else (1.0, 0.0)
        tested.append({"cand": c, "Ct": Ct, "stat": stat, "q": q_vis, "p": p, "lp": lp, "vis": vis})
    tested.sort(key=lambda d: d["lp"])
    bonf = ALPHA / max(len(tested), 1)

    def refit(cs: Sequence[Candidate]):
        qs = [c.q for c in cs]
        z0 = np.concatenate([prob.reduce(th)] + [np.zeros(q) for q in qs])

        def fun(z):
            t = prob.expand(z[:p0])
            xx = x.copy()
            o = p0
            for c, q in zip(cs, qs):
                xx = xx - c.delta(z[o:o + q], x, t, ctx)
                o += q
            return 1.0 - model.norms(t, xx)
        z, ra, Ja = _lm_weighted(fun, z0, w)
        chi2a = float(np.sum(w * ra * ra))
        ea = _heldout(ra, Ja, w)
        twa = float(np.median(_twin(Ja, var, w, sims, rng)))
        _, Ai = _hat_diag(Ja, w)
        sd = np.sqrt(np.clip(np.diag(Ai), 0, None))
        return z, chi2a, ea, twa, sd

    effects = []
    fits = {}
    for d in tested:
        c = d["cand"]
        entry = {"name": c.name, "score_chi2": round(d["stat"], 3), "score_p_value": d["p"],
                 "visibility": round(d["vis"], 3)}
        if d["q"] == 0:
            entry.update({"note": "leaves no trace in this pose set (absorbed by the baseline model)",
                          "significant": False, "ratio_after": ratio, "params": {}})
            effects.append(entry)
            continue
        # every visible candidate is refitted (cheap), so each reports its shrink and
        # parameters; it is significant only when the gap is, its score test passes
        # (Bonferroni), the nested test passes and the held-out residual falls
        z, chi2a, ea, twa, sd = refit([c])
        dchi = chi2 - chi2a
        pn, lpn = _p_and_log10(max(dchi, 0.0), c.q)
        ra_after = float(np.sqrt(np.mean(ea * ea)) / twa)      # against the augmented model's twin
        key = c.name + (f"_{c.units}" if c.units else "")
        entry.update({"ratio_after": ra_after, "nested_p_value": pn, "chi2_after": chi2a,
                      "significant": bool(significant and d["p"] < bonf and pn < bonf
                                          and np.mean(ea * ea) < np.mean(e * e)),
                      "params": {key: z[p0:].tolist()}, "stderr": {key: sd[p0:].tolist()}})
        fits[c.name] = (chi2a, ea, ra_after)
        effects.append(entry)
    out["effects"] = effects
    # --- choose
    sig = [ef for ef in effects if ef.get("significant")]
    verdict, ratio_after, chosen = "none", ratio, []
    if significant:
        if sig:
            best = min(sig, key=lambda ef: ef["ratio_after"])
            chosen = [best["name"]]
            ratio_after = best["ratio_after"]
            chi2_best = fits[best["name"]][0]
            q_best = next(c.q for c in cands if c.name == best["name"])
            p_rest = chi2_sf(chi2_best, N - p0 - q_best)
            if p_rest < ALPHA:
                # greedy forward selection: with the first effect modelled, does a second
                # one still explain a significant part (nested test) and improve held-out?
                best_pair = None
                e_best = fits[best["name"]][1]
                for d in tested:
                    other = d["cand"]
                    if other.name == best["name"] or d["q"] == 0:
                        continue
                    cs = [next(c for c in cands if c.name == best["name"]), other]
                    z, chi2a, ea, twa, sd = refit(cs)
                    rr = float(np.sqrt(np.mean(ea * ea)) / twa)
                    pn, _ = _p_and_log10(max(chi2_best - chi2a, 0.0), other.q)
                    if pn < bonf and np.mean(ea * ea) < np.mean(e_best * e_best) and \
                            (best_pair is None or rr < best_pair[1]):
                        best_pair = (other.name, rr, z, sd, pn)
                if best_pair is not None:
                    chosen = [best["name"], best_pair[0]]
                    ratio_after = best_pair[1]
                    out["joint"] = {"effects": chosen, "ratio_after": ratio_after,
                                    "nested_p_value": best_pair[4],
                                    "params": best_pair[2][p0:].tolist(),
                                    "stderr": best_pair[3][p0:].tolist()}
            shrink = (ratio - ratio_after) / max(ratio - 1.0, 1e-9)
            out["shrink"] = float(shrink)
            if ratio_after <= RATIO_OK:
                verdict = "+".join(chosen)
            elif shrink >= 0.5:
                verdict = "+".join(chosen)
                out["partially_explained"] = True
            else:
                verdict = "unexplained"
        else:
            verdict = "unexplained"
    elif ratio > ratio_q99 * 1.05:
        # not significant by chi-square, yet the held-out ratio is out of the twin's range
        out["note"] = "held-out ratio above the twin's 99th percentile but chi-square not significant"
    out["verdict"] = verdict
    out["ratio_after"] = float(ratio_after)
    # --- confusable candidates
    if chosen:
        confused = []
        byname = {d["cand"].name: d for d in tested}
        for n in chosen:
            for d in tested:
                o = d["cand"].name
                if o == n or o in chosen or d["q"] == 0:
                    continue
                cc = _canon(byname[n]["Ct"], d["Ct"])
                if cc > 0.98:
                    confused.append({"effects": sorted([n, o]), "canonical_correlation": round(cc, 4),
                                     "to_separate": SEPARATE.get(frozenset({n, o}), "a more varied recording")})
        if confused:
            out["confusable"] = confused
    # --- where: regions, temperature and time bins, trends
    z_n = r * sw
    excess = z_n ** 2 - 1.0
    u = (x - (th[6:9] if model.k == 9 else th[model.kw:] if isinstance(model, MagModel) else 0))
    regions = {}
    for i in range(N):
        regions.setdefault(_region(u[i]), []).append(i)
    tot = float(np.sum(np.maximum(excess, 0))) or 1.0
    where = {"region_share": {k: round(float(np.sum(np.maximum(excess[v], 0))) / tot, 3)
                              for k, v in sorted(regions.items())}}
    if "temp" in ctx and np.isfinite(ctx["temp"]).all():
        qs = np.quantile(ctx["temp"], [0, 0.25, 0.5, 0.75, 1])
        b = np.clip(np.searchsorted(qs[1:-1], ctx["temp"], side="right"), 0, 3)
        where["temperature_bin_share"] = {f"{qs[k]:.1f}..{qs[k + 1]:.1f} C":
                                          round(float(np.sum(np.maximum(excess[b == k], 0))) / tot, 3)
                                          for k in range(4)}
    tq = np.quantile(ctx["t"], [0, 0.25, 0.5, 0.75, 1])
    bt = np.clip(np.searchsorted(tq[1:-1], ctx["t"], side="right"), 0, 3)
    where["time_bin_share"] = {f"{tq[k]:.0f}..{tq[k + 1]:.0f} s":
                               round(float(np.sum(np.maximum(excess[bt == k], 0))) / tot, 3) for k in range(4)}
    ud = u / np.linalg.norm(u, axis=1, keepdims=True)
    order = np.argsort(ctx["t"])
    prev = np.full(N, np.nan)
    prev[order[1:]] = z_n[order[:-1]]
    trends = {"temperature": _corr_p(ctx.get("temp", np.full(N, np.nan)), z_n),
              "time": _corr_p(ctx["t"], z_n), "previous_pose": _corr_p(prev, z_n)}
    for j, ax in enumerate("xyz"):
        trends[f"{ax}_squared"] = _corr_p(ud[:, j] ** 2, z_n)
    where["trends"] = {k: v for k, v in trends.items() if v is not None}
    out["where"] = where
    out["_plot"] = {"r": r, "e": e, "t": ctx["t"], "temp": ctx.get("temp"), "u": ud, "var": var,
                    "e_after": fits[chosen[0]][1] if chosen and chosen[0] in fits else None,
                    "after_label": chosen[0] if chosen else None}
    return out


# --- the gyro diagnosis (linear) -----------------------------------------------------------

def _gyro_diag(g: np.ndarray, gvar: np.ndarray, ctx, sims, rng, names_skip) -> Dict[str, object]:
    N = len(g)
    y = g.reshape(-1)
    var = gvar.reshape(-1)
    w = 1 / var
    X0 = _kron_cols(np.ones(N))

    def wls(X):
        A = X.T @ (X * w[:, None])
        Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
        beta = Ai @ (X.T @ (w * y))
        r = y - X @ beta
        return beta, r, Ai
    b0, r0, _ = wls(X0)
    chi2 = float(np.sum(w * r0 * r0))
    p_gap, lp = _p_and_log10(chi2, 3 * N - 3)
    J0 = -X0
    e0 = _heldout(r0, J0, w)
    tw = _twin(J0, var, w, sims, rng)
    twin = float(np.median(tw))
    ratio = float(np.sqrt(np.mean(e0 ** 2)) / twin)
    ratio_q99 = float(np.quantile(tw / twin, 0.99))
    out = {"poses": N, "ratio_before": ratio, "p_value": p_gap, "log10_p_value": round(lp, 2),
           "chi2": chi2, "dof": 3 * N - 3, "unit": "dps", "bias_dps": b0.tolist(),
           "heldout_rms": float(np.sqrt(np.mean(e0 ** 2))), "twin_heldout_rms": twin,
           "twin_ratio_q99": ratio_q99}
    significant = p_gap < ALPHA and ratio > ratio_q99
    effects, fits = [], {}
    bonf = ALPHA / max(len(GYRO_CANDIDATES), 1)
    tested = []
    for c in GYRO_CANDIDATES:
        if c.name in names_skip:
            continue
        C = c.columns(ctx)
        Ct, Cw = _proj_sig(J0, -C, w)
        stat, qv, vis = _score(r0 * np.sqrt(w), Ct, Cw)
        p, lpc = _p_and_log10(stat, qv) if qv else (1.0, 0.0)
        tested.append((c, Ct, stat, qv, p, lpc, vis))
    tested.sort(key=lambda d: d[5])
    for c, Ct, stat, qv, p, lpc, vis in tested:
        ent = {"name": c.name, "score_chi2": round(stat, 3), "score_p_value": p, "visibility": round(vis, 3),
               "significant": False, "ratio_after": ratio, "params": {}}
        if qv:
            X = np.hstack([X0, c.columns(ctx)])
            beta, r1, Ai = wls(X)
            chi2a = float(np.sum(w * r1 * r1))
            e1 = _heldout(r1, -X, w)
            pn, _ = _p_and_log10(max(chi2 - chi2a, 0.0), c.q)
            twa = float(np.median(_twin(-X, var, w, sims, rng)))
            ra = float(np.sqrt(np.mean(e1 ** 2)) / twa)
            ent.update({"ratio_after": ra, "nested_p_value": pn,
                        "significant": bool(significant and p < bonf and pn < bonf
                                            and np.mean(e1 ** 2) < np.mean(e0 ** 2)),
                        "params": {f"{c.name}_{c.units}": beta[3:].tolist()},
                        "stderr": {f"{c.name}_{c.units}": np.sqrt(np.diag(Ai))[3:].tolist()}})
            fits[c.name] = (chi2a, ra)
        effects.append(ent)
    out["effects"] = effects
    sig = [ef for ef in effects if ef["significant"]]
    verdict, ratio_after = "none", ratio
    if significant:
        if sig:
            best = min(sig, key=lambda ef: ef["ratio_after"])
            ratio_after = best["ratio_after"]
            shrink = (ratio - ratio_after) / max(ratio - 1, 1e-9)
            out["shrink"] = float(shrink)
            verdict = best["name"] if (ratio_after <= RATIO_OK or shrink >= 0.5) else "unexplained"
            if ratio_after > RATIO_OK and shrink >= 0.5:
                out["partially_explained"] = True
            byname = {d[0].name: d for d in tested}
            conf = []
            for d in tested:
                if d[0].name != best["name"] and d[3]:
                    cc = _canon(byname[best["name"]][1], d[1])
                    if cc > 0.98:
                        conf.append({"effects": sorted([best["name"], d[0].name]), "canonical_correlation": round(cc, 4),
                                     "to_separate": SEPARATE.get(frozenset({best["name"], d[0].name}),
                                                                 "a more varied recording")})
            if conf:
                out["confusable"] = conf
            if best["name"] == "g_sensitivity":
                out["note"] = ("Earth's rate (15 deg/h) projects on the vertical like an isotropic "
                               "g-sensitivity of about 0.003 dps/g: below that, the two cannot be told apart")
        else:
            verdict = "unexplained"
    out["verdict"] = verdict
    out["ratio_after"] = float(ratio_after)
    rz = (r0 * np.sqrt(w)).reshape(N, 3)
    out["where"] = {"axis_share": {ax: round(float(np.sum(np.maximum(rz[:, j] ** 2 - 1, 0)))
                                             / max(float(np.sum(np.maximum(rz ** 2 - 1, 0))), 1e-300), 3)
                                   for j, ax in enumerate("xyz")},
                    "trends": {k: v for k, v in {
                        "temperature": _corr_p(ctx.get("temp", np.full(N, np.nan)), np.linalg.norm(rz, axis=1)),
                        "time": _corr_p(ctx["t"], np.linalg.norm(rz, axis=1))}.items() if v is not None}}
    return out


def _saturated(rec: Recording, slices) -> np.ndarray:
    """Poses with accelerometer samples at the range limit.  The limit is the
    recording's accel_range_g when given, else an extreme value that recurs (a rail)."""
    a = rec.acc
    rail = None
    try:
        rail = float(rec.meta.get("accel_range_g", "nan"))
    except ValueError:
        rail = None
    out = np.zeros(len(slices), bool)
    if rail is not None and np.isfinite(rail):
        hit = np.abs(a) >= rail * (1 - 1e-4)
    else:
        hit = np.zeros_like(a, bool)
        for j in range(3):
            for v in (a[:, j].max(), a[:, j].min()):
                at = a[:, j] == v
                if at.sum() >= 5 and abs(v) > 1.2:       # a recurring extreme beyond 1.2 g
                    hit[:, j] |= at
    h = hit.any(axis=1)
    for i, s in enumerate(slices):
        out[i] = h[s].any()
    return out


# --- entry point --------------------------------------------------------------------------------

def diagnose(rec: Recording, sensors: Optional[Sequence[str]] = None, sims: int = 200,
             seed: int = 0, name: str = "recording") -> Dict[str, object]:
    """Diagnose every sensor present (or the ones asked for); returns the JSON object."""
    rng = np.random.default_rng(seed)
    if rec.acc is None:
        raise GapError(f"{name}: no accelerometer columns: still poses are found from the accelerometer")
    avail = [s for s, a in (("accel", rec.acc), ("gyro", rec.gyro), ("mag", rec.mag)) if a is not None]
    sensors = list(sensors or avail)
    for s in sensors:
        if s not in avail:
            raise GapError(f"{name}: --sensor {s}: the recording has no {s} columns")
    rate = rec.rate_hz
    sl = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rate)
    ps = poses_from_slices(rec, sl)
    N = len(ps)
    notes: List[str] = []
    if N < MIN_POSES:
        from ..daemon.accumulator import PoseAccumulator
        from ..daemon.stillness import StaticInterval
        acc = PoseAccumulator()
        for i in range(N):
            acc.add(StaticInterval(ps.acc[i], ps.acc_cov[i], ps.acc_sample_cov[i], int(ps.n[i]),
                                   ps.t0[i], ps.t1[i], float("nan")))
        miss = acc.coverage()["missing"][:6]
        raise GapError(f"{name}: {N} still poses found; the diagnosis needs at least {MIN_POSES} "
                       f"(25-30 recommended): {MIN_POSES - N} more, e.g. {', '.join(miss)}")
    # saturation (E10: not a model term): samples at the range limit bias a pose mean
    sat = _saturated(rec, sl)
    # robust noise and disturbed poses (accelerometer)
    s2 = np.einsum("nii->n", ps.acc_sample_cov) / 3
    bad = _flag_disturbed(s2, ps.n) | sat
    keep = ~bad
    if keep.sum() < MIN_POSES:
        keep = np.ones(N, bool)
        notes.append("many poses look disturbed; none were left out")
    temp = ps.temp
    skip: Dict[str, str] = {}
    if temp is None or not np.all(np.isfinite(temp)):
        skip = {"thermal_bias": "no temperature", "thermal_scale": "no temperature"}
        notes.append("no temperature column: temperature effects were skipped")
    elif np.ptp(temp) < 0.5:
        skip = {"thermal_bias": "flat temperature", "thermal_scale": "flat temperature"}
        notes.append(f"temperature varied by only {np.ptp(temp):.2f} C: temperature effects were skipped")
    tmid = 0.5 * (ps.t0 + ps.t1)
    ctx_all = {"t": tmid - tmid.min(), "dt": tmid - tmid.mean()}
    if not skip:
        ctx_all["temp"] = temp
        ctx_all["dT"] = temp - temp.mean()
    sub = lambda c, m: {k: v[m] for k, v in c.items()}
    T_pose = float(np.median(ps.n[keep]) / rate)
    longest = max(sl, key=lambda s: s.stop - s.start) if sl else None
    result: Dict[str, object] = {"sensors": {}, "poses_found": N,
                                 "poses_left_out": np.flatnonzero(bad).tolist() if keep.sum() < N else []}
    if "accel" in sensors:
        kap, colour = _colour(rec.acc, longest, rate, T_pose)
        pv = np.median(s2[keep]) / ps.n[keep] * kap
        r = _norm_diag(ps.acc[keep], sub(ctx_all, keep), pv, Triangular9(), ACCEL_CANDIDATES, sims, rng,
                       skip, "g")
        if colour:
            r["noise_colour"] = colour
        r["not_detectable"] = ("a local |g| different from 1 g and a rotation of the sensor frame leave no "
                               "trace in norm-only data: not detectable without an external reference")
        if bad.any():
            r["where"]["disturbed_poses"] = {"indices": np.flatnonzero(bad).tolist(),
                                             "t0_s": np.round(ps.t0[bad], 2).tolist()}
        if sat.any():
            idx = np.flatnonzero(sat).tolist()
            r["effects"].insert(0, {"name": "saturation", "significant": True, "poses": idx,
                                    "ratio_after": r["ratio_after"], "params": {},
                                    "note": "samples at the range limit (clipping, e.g. vibration peaks) "
                                            "bias these poses' means; they were left out of the fit: "
                                            "reduce vibration or raise the range"})
            r["verdict"] = "saturation" if r["verdict"] in ("none",) else f"saturation+{r['verdict']}"
        result["sensors"]["accel"] = r
    if "gyro" in sensors:
        gv = np.einsum("nii->ni", ps.gyro_cov) if ps.gyro_cov is not None else None
        gs2 = gv * ps.n[:, None]
        med = np.median(gs2[keep], axis=0)
        kap_g, colour_g = _colour(rec.gyro, longest, rate, T_pose)
        gvar = med[None, :] / ps.n[keep, None] * kap_g
        ctx = sub(ctx_all, keep)
        # specific force in g from the calibrated accelerometer (raw directions carry the
        # accelerometer's own scale and bias errors into the g-sensitivity regressor)
        t9 = Triangular9()
        th_a = lm(Problem(t9, ps.acc[keep])).theta
        ctx["acc_dir"] = t9.forward(th_a, ps.acc[keep])
        r = _gyro_diag(ps.gyro[keep], gvar, ctx, sims, rng, skip)
        if colour_g:
            r["noise_colour"] = colour_g
        result["sensors"]["gyro"] = r
    if "mag" in sensors:
        mv = np.einsum("nii->n", ps.mag_cov) / 3 if ps.mag_cov is not None else None
        mvar = np.median(mv[keep] * ps.n[keep]) / ps.n[keep]
        mvar = np.maximum(mvar, (1 / 1090) ** 2 / 12 / ps.n[keep])     # quantisation floor
        x = ps.mag[keep]
        from ..calib.optim import sphere_fit
        _, rad = sphere_fit(x)
        model = MagModel("sphere")
        r = _norm_diag(x, sub(ctx_all, keep), mvar, model, MAG_CANDIDATES, sims, rng,
                       {k: v for k, v in skip.items() if k == "thermal_bias"}, "gauss", scale=rad)
        r["note"] = "still-pose means only; the baseline is hard iron with a single gain"
        result["sensors"]["mag"] = r
    result["notes"] = notes
    return result
