"""The gap diagnosis of a norm model (accelerometer |a| = 1 g, magnetometer |m| = const):
baseline weighted fit, twin, score tests of the candidates, refits, verdict."""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..calib.fit import _mag_bounds
from ..calib.models import MagModel, NormModel
from ..calib.optim import sphere_fit
from ..calib.optim import Problem, lm
from ..calib.uncertainty import residual_variance
from .candidates import Candidate
from .signif import p_and_log10, proj_sig, score
from ..calib.heldout import hat_diag, heldout, lm_weighted, numjac, twin_rms
from ..calib.stats import chi2_sf
from .levels import ATTRIBUTION_LEVEL, GAP_TEST_LEVEL, REMAINING_GAP_LEVEL
from .verdict import decide
from .wander import random_walk_fit
from .where import norm_where
from ..calib.metrics import rms

__all__ = ["norm_diag", "MIN_DOF"]

MIN_DOF = 10           #: residual degrees of freedom a candidate fit must leave


def norm_diag(x: np.ndarray, ctx: Dict[str, np.ndarray], pose_var: np.ndarray, model: NormModel,
              cands: List[Candidate], sims: int, rng, names_skip: Dict[str, str],
              unit: str, scale: float = 1.0,
              prior: Optional[Tuple[np.ndarray, np.ndarray]] = None) -> Dict[str, object]:
    """Diagnose pose means ``x`` (N, 3) against ``model`` with per-pose noise variance
    ``pose_var`` (squared units of x); ``scale`` converts residuals to ``unit``.

    ``prior``: (mean, std) over the model's parameters, the Gaussian prior the deployed
    calibration uses (calib.fit.accel_prior, MAP): the baseline is then the same MAP fit
    (weights 1/variance, so the prior term is sum ((theta - mean) / std)^2), and the
    leverages, the twin and the projection of each candidate's signature hold the prior
    precision, so what the gap sees is what the deployed fit leaves."""
    N = len(x)
    p0 = model.k
    if isinstance(model, MagModel):
        # started from a sphere fit inside the calibration's search box: a hard iron several
        # field radii off (the QMC5883L recording: 6x) is out of the default start's reach
        c, rad = sphere_fit(x)
        lo, hi = _mag_bounds(model, x, 1.0)
        prob = Problem(model, x, lo=lo, hi=hi)
        kd = min(model.kw, 3)
        th0 = np.concatenate([[1.0 / rad] * kd, np.zeros(model.kw - kd), c])
        th = lm(prob, z0=prob.reduce(th0)).theta
    else:
        prob = Problem(model, x)
        th = lm(prob).theta
    var = residual_variance(model, th, x, pose_var)
    w = 1.0 / var
    pm = ps = lam = None
    if prior is not None:
        pm, ps = (np.asarray(a, float) for a in prior)
        lam = np.where(np.isfinite(ps), 1.0 / np.where(np.isfinite(ps), ps, 1.0) ** 2, 0.0)
    th = lm(Problem(model, x, weights=w, prior_mean=pm, prior_std=ps, noise_var=1.0),
            z0=prob.reduce(th)).theta
    r, J = model.jacobian(th, x)
    chi2 = float(np.sum(w * r * r))
    p_gap, lp_gap = p_and_log10(chi2, N - p0)
    e = heldout(r, J, w, lam)
    # the ratio compares noise-normalised held-out residuals (the points' noise differs:
    # pose means against single rotation samples of the magnetometer)
    nrms = lambda ee: float(np.sqrt(np.mean(ee * ee * w)))
    tw = twin_rms(J, var, w, sims, rng, lam, normalised=True)
    twin = float(np.median(tw))
    ratio = nrms(e) / twin
    twin_raw = float(np.median(twin_rms(J, var, w, max(sims // 4, 20), rng, lam)))
    ratio_q99 = float(np.quantile(tw / twin, 0.99))
    out: Dict[str, object] = {
        "poses": N, "ratio_before": ratio, "p_value": p_gap, "log10_p_value": round(lp_gap, 2),
        "chi2": chi2, "dof": N - p0, "heldout_rms": rms(e) * scale,
        "twin_heldout_rms": twin_raw * scale, "twin_ratio_q99": ratio_q99, "unit": unit,
        # what the ratio compares: held-out residual / noise sd, its RMS in the data and the twin
        "heldout_rms_normalised": nrms(e), "twin_heldout_rms_normalised": twin,
        "baseline_params": {n: float(v) for n, v in zip(model.param_names, th)},
    }
    # a gap: the chi-square test rejects the noise model, and the held-out ratio lies
    # above what the twin produces in 99 % of its re-simulations
    significant = p_gap < GAP_TEST_LEVEL and ratio > ratio_q99
    # --- which effect: score tests from the baseline fit
    sw = np.sqrt(w)
    rw = r * sw
    tested = []
    for c in cands:
        if c.name in names_skip:
            continue
        f = lambda eta, c=c: 1.0 - model.norms(th, x - c.delta(eta, x, th, ctx))
        _, C = numjac(f, np.zeros(c.q), eps=np.full(c.q, 1e-5))
        Ct, Cw = proj_sig(J, C, w, lam)
        stat, q_vis, vis = score(rw, Ct, Cw)
        p, lp = p_and_log10(stat, q_vis) if q_vis else (1.0, 0.0)
        tested.append({"cand": c, "Ct": Ct, "stat": stat, "q": q_vis, "p": p, "lp": lp, "vis": vis})
    tested.sort(key=lambda d: d["lp"])
    bonf = ATTRIBUTION_LEVEL / max(len(tested), 1)

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
            r_ = 1.0 - model.norms(t, xx)
            # the baseline's prior as pseudo-observations (weight 1: std-normalised)
            return r_ if lam is None else np.concatenate([r_, (z[:p0] - pm) * np.sqrt(lam)])
        z, ra, Ja = lm_weighted(fun, z0, w if lam is None else np.concatenate([w, np.ones(p0)]))
        ra, Ja = ra[:N], Ja[:N]
        lam_a = None if lam is None else np.concatenate([lam, np.zeros(len(z) - p0)])
        chi2a = float(np.sum(w * ra * ra))
        ea = heldout(ra, Ja, w, lam_a)
        twl = twin_rms(Ja, var, w, sims, rng, lam_a, normalised=True)
        twa = float(np.median(twl))
        _, Ai = hat_diag(Ja, w, lam_a)
        # standard errors scaled by the excess scatter that remains (chi2/dof above 1)
        red = max(1.0, chi2a / max(N - len(z), 1))
        sd = np.sqrt(np.clip(np.diag(Ai), 0, None) * red)
        q99 = float(np.quantile(twl / twa, 0.99))
        # Wald test of the added coefficients with the same scaled covariance (attribution
        # discipline: an effect is named only when its coefficients are significant too)
        # (of the last candidate's coefficients: in a pair, the one added)
        o = len(z) - qs[-1]
        Ca = Ai[o:, o:] * red
        za = z[o:]
        wald = float(za @ np.linalg.pinv(Ca, rcond=1e-10, hermitian=True) @ za)
        rank = int(np.linalg.matrix_rank(Ca, tol=1e-10 * max(np.abs(Ca).max(), 1e-300)))
        refit.wald = p_and_log10(wald, max(rank, 1))[0]
        return z, chi2a, ea, twa, sd, q99

    effects = []
    fits = {}
    cand_of: Dict[str, Candidate] = {}           # the kept variant of each name
    fits_all: Dict[int, tuple] = {}               # every variant's single fit, by id
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
        if p0 + d["q"] > N - MIN_DOF:
            continue                              # too many visible parameters for this pose set
        z, chi2a, ea, twa, sd, q99 = refit([c])
        p_wald = refit.wald
        dchi = chi2 - chi2a
        pn, lpn = p_and_log10(max(dchi, 0.0), c.q)
        ra_after = nrms(ea) / twa      # against the augmented model's twin
        key = c.name + (f"_{c.units}" if c.units else "")
        entry.update({"ratio_after": ra_after, "nested_p_value": pn, "chi2_after": chi2a, "q": c.q,
                      "lr": float(chi2 - chi2a),
                      "closed": bool(ra_after <= q99),
                      "wald_p_value": p_wald,
                      "significant": bool(significant and d["p"] < bonf and pn < bonf
                                          and nrms(ea) < nrms(e)),
                      "params": {key: z[p0:].tolist()}, "stderr": {key: sd[p0:].tolist()}})
        if c.parts:                                # several keys (e.g. slope and curvature)
            o = p0
            entry["params"], entry["stderr"] = {}, {}
            for u, k in c.parts:
                entry["params"][f"{c.name}_{u}"] = z[o:o + k].tolist()
                entry["stderr"][f"{c.name}_{u}"] = sd[o:o + k].tolist()
                o += k
        fits_all[id(c)] = (chi2a, ea, ra_after)
        if c.name in fits:                         # a second variant of the same class
            if fits[c.name][2] <= ra_after:
                continue
            effects = [ef for ef in effects if ef["name"] != c.name]
        fits[c.name] = (chi2a, ea, ra_after)
        cand_of[c.name] = c
        effects.append(entry)
    # the wandering bias as a random walk (gap/wander.py): a variant of its class, kept when
    # its held-out ratio is the lower
    if "wandering_bias" not in names_skip and any(c.name == "wandering_bias" for c in cands):
        _, B = numjac(lambda eta: 1.0 - model.norms(th, x - eta[None, :]), np.zeros(3), eps=np.full(3, 1e-5))
        gp = random_walk_fit(r, J, var, B, ctx["t"], sims, rng, lam)
        if gp is not None and gp["q"] > 0:
            ra_gp = gp["nrms"] / gp["twin"]
            old_w = next((ef for ef in effects if ef["name"] == "wandering_bias"), None)
            if old_w is None or ra_gp < old_w["ratio_after"]:
                edf = gp["edf"]
                entry = {"name": "wandering_bias", "form": "random walk (REML strength, gap/wander.py)",
                         "stochastic": True,
                         "score_p_value": gp["p_value"], "nested_p_value": gp["p_value"],
                         "visibility": 1.0, "ratio_after": ra_gp, "q": max(1, int(round(edf))),
                         "lr": gp["lr"],
                         "closed": bool(ra_gp <= gp["twin_q99"]),
                         "significant": bool(significant and gp["p_value"] < bonf and gp["nrms"] < nrms(e)),
                         "params": {f"random_walk_intensity_{unit}^2/s": [gp["q"] * scale ** 2] * 3},
                         "stderr": {},
                         "random_walk": {"intensity_ci95": [None if v is None else v * scale ** 2
                                                            for v in gp["q_ci95"]],
                                         "likelihood_ratio": gp["lr"], "effective_parameters": round(edf, 2),
                                         "allan_variance_slope_term": "q tau / 3 (IEEE 952 rate random walk)"}}
                effects = [ef for ef in effects if ef["name"] != "wandering_bias"] + [entry]
                fits.pop("wandering_bias", None)
                cand_of.pop("wandering_bias", None)
    out["effects"] = effects

    def second(first: str):
        """With ``first`` modelled (any of its fitted variants), the second effect that still
        explains a significant part (nested test) and lowers the held-out residual most;
        None when none does."""
        if first not in fits:
            return None                           # the random-walk form: no parametric pair
        best_pair = None
        firsts = [d["cand"] for d in tested if d["cand"].name == first and id(d["cand"]) in fits_all]
        for cf in firsts:
            chi2_best, e_best, _ = fits_all[id(cf)]
            q_best = cf.q
            if chi2_sf(chi2_best, N - p0 - q_best) >= REMAINING_GAP_LEVEL:
                continue
            for d in tested:
                other = d["cand"]
                # every variant of a kept class (a smaller one may fit where the kept one has
                # too many parameters for the pair)
                if other.name == first or d["q"] == 0 or other.name not in cand_of:
                    continue
                if {first, other.name} == {"bias_drift", "wandering_bias"}:
                    continue                      # nested: the drift's line is in the wandering span
                if p0 + q_best + other.q > N - MIN_DOF:
                    continue
                z, chi2a, ea, twa, sd, q99 = refit([cf, other])
                rr = nrms(ea) / twa
                pn, _ = p_and_log10(max(chi2_best - chi2a, 0.0), other.q)
                if pn < bonf and nrms(ea) < nrms(e_best) and \
                        (best_pair is None or rr < best_pair[1]):
                    best_pair = (other.name, rr, z, sd, pn, rr <= q99, float(chi2 - chi2a), q_best + other.q,
                                 refit.wald)
        if best_pair is None:
            return None
        return {"effects": [first, best_pair[0]], "ratio_after": best_pair[1],
                "nested_p_value": best_pair[4], "closed": bool(best_pair[5]), "lr": best_pair[6],
                "wald_p_value": best_pair[8],
                "q": best_pair[7], "params": best_pair[2][p0:].tolist(),
                "stderr": best_pair[3][p0:].tolist()}

    chosen = decide(out, ratio, significant, effects,
                    {d["cand"].name: d["Ct"] for d in tested if d["q"] and cand_of.get(d["cand"].name) is d["cand"]},
                    second)
    out["where"], ud = norm_where(x, r * sw, model, th, ctx)
    out["_plot"] = {"r": r, "e": e, "t": ctx["t"], "temp": ctx.get("temp"), "u": ud, "var": var,
                    "e_after": fits[chosen[0]][1] if chosen and chosen[0] in fits else None,
                    "after_label": chosen[0] if chosen else None}
    return out
