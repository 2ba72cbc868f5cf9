"""The gap diagnosis of a norm model (accelerometer |a| = 1 g, magnetometer |m| = const):
baseline weighted fit and its twin (:func:`norm_baseline`), score tests and refits of the
candidates (:func:`score_candidates`, :func:`fit_candidates`), verdict (:func:`norm_diag`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..fitting.fit import mag_bounds
from ..fitting.judging.heldout import hat_diag, heldout, lm_weighted, numjac, twin_rms
from ..fitting.judging.metrics import rms
from ..fitting.models.mag import MagModel
from ..fitting.models.base import NormModel
from ..fitting.solvers.lsq import Problem, lm, sphere_fit
from ..fitting.judging.uncertainty import residual_variance
from .candidates import Candidate
from ..fitting.judging.levels import GAP_ATTRIBUTION_LEVEL, GAP_HELDOUT_LEVEL, GAP_TEST_LEVEL
from .signif import p_and_log10, proj_sig, score, visible_svd, wald_p
from .search import single_floor, stepwise, walk_sensitivity
from .verdict import confusable, no_gap, verdict
from .wander import random_walk_fit
from .where import norm_where

__all__ = ["norm_diag", "norm_baseline", "score_candidates", "fit_candidates", "NormBaseline",
           "CandidateFit", "CandidateFits"]



@dataclass
class NormBaseline:
    """The baseline weighted (MAP) fit of pose means ``x`` and what its twin says of it."""
    x: np.ndarray                  #: pose means (N, 3), units of the sensor
    model: NormModel
    prob: Problem                  #: the unweighted problem (its reduce/expand map the parameters)
    th: np.ndarray                 #: baseline parameters
    var: np.ndarray                #: residual variance per point
    w: np.ndarray                  #: weights 1 / var
    pm: Optional[np.ndarray]       #: prior mean (None: no prior)
    lam: Optional[np.ndarray]      #: prior precision (None: no prior)
    r: np.ndarray                  #: residuals 1 - |model(x)|
    J: np.ndarray                  #: their Jacobian
    chi2: float
    e: np.ndarray                  #: held-out (leave-one-out) residuals
    ratio: float                   #: noise-normalised held-out RMS over the twin's median
    significant: bool              #: a gap: chi-square rejects and the ratio is above the twin's q99
    report: Dict[str, object]      #: the baseline figures of the output

    @property
    def n(self) -> int:
        return len(self.x)

    @property
    def p0(self) -> int:
        return self.model.k

    def nrms(self, ee: np.ndarray) -> float:
        """RMS of residuals ``ee`` in noise standard deviations."""
        return float(np.sqrt(np.mean(ee * ee * self.w)))


def _unweighted_fit(x: np.ndarray, model: NormModel) -> Tuple[Problem, np.ndarray]:
    if isinstance(model, MagModel):
        # started from a sphere fit inside the calibration's search box: a hard iron several
        # field radii off (the QMC5883L recording: 6x) is out of the default start's reach
        c, rad = sphere_fit(x)
        lo, hi = mag_bounds(model, x, 1.0)
        prob = Problem(model, x, lo=lo, hi=hi)
        kd = min(model.kw, 3)
        th0 = np.concatenate([[1.0 / rad] * kd, np.zeros(model.kw - kd), c])
        return prob, lm(prob, z0=prob.reduce(th0)).theta
    prob = Problem(model, x)
    return prob, lm(prob).theta


def norm_baseline(x: np.ndarray, pose_var: np.ndarray, model: NormModel, sims: int, rng,
                  unit: str, scale: float = 1.0,
                  prior: Optional[Tuple[np.ndarray, np.ndarray]] = None) -> NormBaseline:
    """The baseline MAP fit (weights 1/variance), its held-out residuals and its twin."""
    N, p0 = len(x), model.k
    prob, th = _unweighted_fit(x, model)
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
    nrms = float(np.sqrt(np.mean(e * e * w)))
    tw = twin_rms(J, var, w, sims, rng, lam, normalised=True)
    twin = float(np.median(tw))
    ratio = nrms / twin
    twin_raw = float(np.median(twin_rms(J, var, w, max(sims // 4, 20), rng, lam)))
    ratio_q99 = float(np.quantile(tw / twin, 0.99))
    report: Dict[str, object] = {
        "poses": N, "ratio_before": ratio, "p_value": p_gap, "log10_p_value": round(lp_gap, 2),
        "chi2": chi2, "dof": N - p0, "heldout_rms": rms(e) * scale,
        "twin_heldout_rms": twin_raw * scale, "twin_ratio_q99": ratio_q99, "unit": unit,
        # what the ratio compares: held-out residual / noise sd, its RMS in the data and the twin
        "heldout_rms_normalised": nrms, "twin_heldout_rms_normalised": twin,
        "baseline_params": {n: float(v) for n, v in zip(model.param_names, th)},
    }
    # a gap: the chi-square test rejects the noise model, and the held-out ratio lies
    # above what the twin produces in 99 % of its re-simulations
    significant = p_gap < GAP_TEST_LEVEL and ratio > ratio_q99
    return NormBaseline(x, model, prob, th, var, w, pm, lam, r, J, chi2, e, ratio, significant, report)


def score_candidates(b: NormBaseline, cands: Sequence[Candidate], ctx: Dict[str, np.ndarray],
                     names_skip: Dict[str, str]) -> List[Dict[str, object]]:
    """Score test of each candidate from the baseline fit, most significant first:
    {"cand", "Ct" (projected signature), "stat", "q" (visible dimensions), "p", "lp", "vis"}."""
    model, th, x = b.model, b.th, b.x
    rw = b.r * np.sqrt(b.w)
    tested = []
    for c in cands:
        if c.name in names_skip:
            continue
        f = lambda eta, c=c: 1.0 - model.norms(th, x - c.delta(eta, x, th, ctx))
        _, C = numjac(f, np.zeros(c.q), eps=np.full(c.q, 1e-5))
        Ct, Cw = proj_sig(b.J, C, b.w, b.lam)
        sv = visible_svd(Ct, Cw)
        stat, q_vis, vis = score(rw, Ct, Cw, sv)
        p, lp = p_and_log10(stat, q_vis) if q_vis else (1.0, 0.0)
        tested.append({"cand": c, "Ct": Ct, "stat": stat, "q": q_vis, "p": p, "lp": lp, "vis": vis,
                       "V": sv[1]})
    tested.sort(key=lambda d: d["lp"])
    return tested


@dataclass
class CandidateFit:
    """The baseline model augmented with candidate effects, refitted."""
    z: np.ndarray                  #: reduced baseline parameters then the effects' coefficients
    chi2: float
    e: np.ndarray                  #: held-out residuals
    twin: float                    #: the augmented model's twin median (noise-normalised)
    sd: np.ndarray                 #: standard errors scaled by the remaining excess scatter
    q99: float                     #: the augmented twin's 99th percentile of the ratio
    wald_p: float                  #: Wald test of the last candidate's coefficients
    r: Optional[np.ndarray] = None     #: residuals at the fit (N,)
    J: Optional[np.ndarray] = None     #: their Jacobian over z (N, len(z))
    lam: Optional[np.ndarray] = None   #: the prior precision over z (None: no prior)
    cov: Optional[np.ndarray] = None   #: covariance of z, scaled by the remaining excess


def refit_with(b: NormBaseline, cs: Sequence[Candidate], ctx: Dict[str, np.ndarray], sims: int,
               rng, z0: Optional[np.ndarray] = None) -> CandidateFit:
    """Refit the baseline model with candidates ``cs`` added (the baseline's prior kept as
    pseudo-observations), and the augmented model's twin; ``z0``: a start (default: the
    baseline with zero effects)."""
    x, N, p0, prob, model, lam, w = b.x, b.n, b.p0, b.prob, b.model, b.lam, b.w
    qs = [c.q for c in cs]
    if z0 is None:
        z0 = np.concatenate([prob.reduce(b.th)] + [np.zeros(q) for q in qs])

    def fun(z):
        t = prob.expand(z[:p0])
        xx = x.copy()
        o = p0
        for c, q in zip(cs, qs):
            xx = xx - c.delta(z[o:o + q], x, t, ctx)
            o += q
        r_ = 1.0 - model.norms(t, xx)
        # the baseline's prior as pseudo-observations (weight 1: std-normalised)
        return r_ if lam is None else np.concatenate([r_, (z[:p0] - b.pm) * np.sqrt(lam)])
    z, ra, Ja = lm_weighted(fun, z0, w if lam is None else np.concatenate([w, np.ones(p0)]))
    ra, Ja = ra[:N], Ja[:N]
    lam_a = None if lam is None else np.concatenate([lam, np.zeros(len(z) - p0)])
    chi2a = float(np.sum(w * ra * ra))
    ea = heldout(ra, Ja, w, lam_a)
    twl = twin_rms(Ja, b.var, w, sims, rng, lam_a, normalised=True)
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
    return CandidateFit(z, chi2a, ea, twa, sd, q99, wald_p(za, Ca), ra, Ja, lam_a, Ai * red)


@dataclass
class CandidateFits:
    """Every visible candidate refitted alone: the report entries and the kept variants."""
    effects: List[Dict[str, object]] = field(default_factory=list)
    fits: Dict[str, tuple] = field(default_factory=dict)        #: kept variant: (chi2, e, ratio)
    cand_of: Dict[str, Candidate] = field(default_factory=dict)  #: the kept variant of each name
    #: every refit made (each variant alone, by id of its Candidate; the random walk alone under
    #: "walk", its bias sensitivities under "walk_B"): the combination search takes them as
    #: they are instead of fitting them again
    prefit: Dict[object, object] = field(default_factory=dict)


def _single_entry(b: NormBaseline, c: Candidate, d: Dict[str, object], f: CandidateFit,
                  bonf: float) -> Dict[str, object]:
    pn, _ = p_and_log10(max(b.chi2 - f.chi2, 0.0), c.q)
    ra_after = b.nrms(f.e) / f.twin      # against the augmented model's twin
    key = c.name + (f"_{c.units}" if c.units else "")
    p0, z, sd = b.p0, f.z, f.sd
    entry = {"ratio_after": ra_after, "nested_p_value": pn, "chi2_after": f.chi2, "q": c.q,
             "lr": float(b.chi2 - f.chi2),
             "closed": bool(ra_after <= f.q99),
             "wald_p_value": f.wald_p,
             "significant": bool(b.significant and d["p"] < bonf and pn < bonf
                                 and b.nrms(f.e) < b.nrms(b.e)),
             "params": {key: z[p0:].tolist()}, "stderr": {key: sd[p0:].tolist()}}
    if c.parts:                                # several keys (e.g. slope and curvature)
        o = p0
        entry["params"], entry["stderr"] = {}, {}
        for u, k in c.parts:
            entry["params"][f"{c.name}_{u}"] = z[o:o + k].tolist()
            entry["stderr"][f"{c.name}_{u}"] = sd[o:o + k].tolist()
            o += k
    return entry


def fit_candidates(b: NormBaseline, tested: List[Dict[str, object]], ctx: Dict[str, np.ndarray],
                   sims: int, rng, bonf: float) -> CandidateFits:
    """Every visible candidate is refitted (cheap), so each reports its shrink and
    parameters; it is significant only when the gap is, its score test passes
    (Bonferroni level ``bonf``), the nested test passes and the held-out residual falls.
    Of two variants of one class the one with the lower held-out ratio is kept."""
    out = CandidateFits()
    for d in tested:
        c = d["cand"]
        entry = {"name": c.name, "score_chi2": round(d["stat"], 3), "score_p_value": d["p"],
                 "visibility": round(d["vis"], 3)}
        if d["q"] == 0:
            entry.update({"note": "leaves no trace in this pose set (absorbed by the baseline model)",
                          "significant": False, "ratio_after": b.ratio, "params": {}})
            out.effects.append(entry)
            continue
        if b.p0 + d["q"] > b.n - single_floor(d["cand"].q):
            continue                              # too many visible parameters for this pose set
        f = refit_with(b, [c], ctx, sims, rng)
        out.prefit[id(c)] = f
        entry.update(_single_entry(b, c, d, f, bonf))
        ra_after = entry["ratio_after"]
        if c.name in out.fits:                     # a second variant of the same class
            if out.fits[c.name][2] <= ra_after:
                continue
            out.effects = [ef for ef in out.effects if ef["name"] != c.name]
        out.fits[c.name] = (f.chi2, f.e, ra_after)
        out.cand_of[c.name] = c
        out.effects.append(entry)
    return out


def random_walk_variant(b: NormBaseline, cf: CandidateFits, ctx: Dict[str, np.ndarray], sims: int,
                        rng, bonf: float, unit: str, scale: float) -> None:
    """The wandering bias as a random walk (gap/wander.py): a variant of its class, kept in
    ``cf`` (in place) when its held-out ratio is the lower."""
    B = walk_sensitivity(b)
    gp = random_walk_fit(b.r, b.J, b.var, B, ctx["t"], sims, rng, b.lam, ctx.get("hold_s"))
    cf.prefit["walk"], cf.prefit["walk_B"] = gp, B
    if gp is None or not gp["q"] > 0:
        return
    ra_gp = gp["nrms"] / gp["twin"]
    old_w = next((ef for ef in cf.effects if ef["name"] == "wandering_bias"), None)
    if old_w is not None and not ra_gp < old_w["ratio_after"]:
        return
    edf = gp["edf"]
    entry = {"name": "wandering_bias", "form": "random walk (REML strength, gap/wander.py)",
             "stochastic": True,
             "score_p_value": gp["p_value"], "nested_p_value": gp["p_value"],
             "visibility": 1.0, "ratio_after": ra_gp, "q": max(1, int(round(edf))),
             "lr": gp["lr"],
             "closed": bool(ra_gp <= gp["twin_q99"]),
             "significant": bool(b.significant and gp["p_value"] < bonf and gp["nrms"] < b.nrms(b.e)),
             "params": {f"random_walk_intensity_{unit}^2/s": [gp["q"] * scale ** 2] * 3},
             "stderr": {},
             "random_walk": {"intensity_ci95": [None if v is None else v * scale ** 2
                                                for v in gp["q_ci95"]],
                             "likelihood_ratio": gp["lr"], "effective_parameters": round(edf, 2),
                             "allan_variance_slope_term": "q tau / 3 (IEEE 952 rate random walk)"}}
    cf.effects = [ef for ef in cf.effects if ef["name"] != "wandering_bias"] + [entry]
    cf.fits.pop("wandering_bias", None)
    cf.cand_of.pop("wandering_bias", None)


def decide_search(out: Dict[str, object], b: NormBaseline, tested: List[Dict[str, object]],
                  ctx: Dict[str, np.ndarray], sims: int, rng, walk_ok: bool,
                  signatures: Dict[str, np.ndarray], scale: float, unit: str,
                  prefit: Optional[dict] = None):
    """The verdict from the combination search (gap/search.py): with a gap, the model the
    forward and backward steps end with names its members (each passed its coefficient and
    held-out tests); written into ``out``; returns (chosen classes, held-out residuals after)."""
    if not b.significant:
        no_gap(out, b.ratio)
        return [], None
    sr = stepwise(b, tested, ctx, sims, rng, walk_ok, refit_with, prefit)
    m = sr["model"]
    chosen = m.classes
    for ent in sr["members"]:
        if "random_walk" in ent:                      # intensity in the sensor's units
            ent["params"] = {f"random_walk_intensity_{unit}^2/s": [v * scale ** 2 for v in
                                                                  ent["params"]["random_walk_intensity"]]}
            ent["stochastic"] = True
            ent["random_walk"]["q_ci95"] = [None if v is None else v * scale ** 2
                                            for v in ent["random_walk"]["q_ci95"]]
    ratio_after = m.nrms / m.twin if chosen else b.ratio
    closed = bool(ratio_after <= m.q99) if chosen else None
    out["search"] = {"steps": sr["steps"], "members": sr["members"], "models_fitted": sr["models_fitted"],
                     "coefficient_level": sr["coefficient_level"], "heldout_level": GAP_HELDOUT_LEVEL,
                     "rule": "forward and backward steps; every member's coefficients (Wald or "
                             "likelihood ratio, at the attribution level over the search's member "
                             "variants) and held-out shrink (against its twin) significant"}
    if len(chosen) > 1:
        # params / stderr: the fixed members' coefficients in the order of ``effects`` (flat,
        # as before the search; the walk's strength is in search.members)
        rm = sr["report_model"]              # the members in their full forms (search.VisiblePart)
        out["joint"] = {"effects": list(chosen), "ratio_after": float(ratio_after), "closed": closed,
                        "params": rm.z[b.p0:].tolist(), "stderr": rm.sd[b.p0:].tolist()}
        bases = [e.get("visible_basis") for e in sr["members"] if "random_walk" not in e]
        if any(v is not None for v in bases):   # each fixed member's tested combinations (or None: all)
            out["joint"]["visible_bases"] = bases
    out.update(verdict(True, chosen, b.ratio, float(ratio_after), closed))
    out["ratio_after"] = float(ratio_after)
    conf = confusable(chosen, signatures)
    if conf:
        out["confusable"] = conf
    return chosen, (m.e if chosen else None)


def norm_diag(x: np.ndarray, ctx: Dict[str, np.ndarray], pose_var: np.ndarray, model: NormModel,
              cands: List[Candidate], sims: int, rng, names_skip: Dict[str, str],
              unit: str, scale: float = 1.0,
              prior: Optional[Tuple[np.ndarray, np.ndarray]] = None) -> Dict[str, object]:
    """Diagnose pose means ``x`` (N, 3) against ``model`` with per-pose noise variance
    ``pose_var`` (squared units of x); ``scale`` converts residuals to ``unit``.

    ``prior``: (mean, std) over the model's parameters, the Gaussian prior the deployed
    calibration uses (fitting.fit.accel_prior, MAP): the baseline is then the same MAP fit
    (weights 1/variance, so the prior term is sum ((theta - mean) / std)^2), and the
    leverages, the twin and the projection of each candidate's signature hold the prior
    precision, so what the gap sees is what the deployed fit leaves.

    Steps: baseline -> candidates (score tests, single refits, the random-walk variant)
    -> verdict (the combination search, gap/search.py)."""
    b = norm_baseline(x, pose_var, model, sims, rng, unit, scale, prior)
    out = b.report
    tested = score_candidates(b, cands, ctx, names_skip)
    bonf = GAP_ATTRIBUTION_LEVEL / max(len(tested), 1)
    cf = fit_candidates(b, tested, ctx, sims, rng, bonf)
    if "wandering_bias" not in names_skip and any(c.name == "wandering_bias" for c in cands):
        random_walk_variant(b, cf, ctx, sims, rng, bonf, unit, scale)
    out["effects"] = cf.effects
    signatures = {d["cand"].name: d["Ct"] for d in tested
                  if d["q"] and cf.cand_of.get(d["cand"].name) is d["cand"]}
    walk_ok = "wandering_bias" not in names_skip and any(c.name == "wandering_bias" for c in cands)
    chosen, e_after = decide_search(out, b, tested, ctx, sims, rng, walk_ok, signatures, scale, unit,
                                    cf.prefit)
    out["where"], ud = norm_where(x, b.r * np.sqrt(b.w), model, b.th, ctx)
    out["_plot"] = {"r": b.r, "e": b.e, "t": ctx["t"], "temp": ctx.get("temp"), "u": ud, "var": b.var,
                    "e_after": e_after, "after_label": "+".join(chosen) if chosen else None}
    return out
