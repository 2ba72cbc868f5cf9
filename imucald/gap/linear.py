"""The gap diagnosis of the gyro: a linear model (bias per axis) fitted to the pose
means by weighted least squares; candidates add design columns."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Sequence, Tuple

import numpy as np

from .candidates import GYRO_CANDIDATES, TRACELESS, kron_cols
from .earth import earth_rate_report, horizontal_variance, vertical_column
from .gyrosearch import gyro_stepwise
from .signif import corr_p, p_and_log10, proj_sig, score
from ..fitting.judging.heldout import heldout, twin_rms
from ..fitting.judging.levels import GAP_ATTRIBUTION_LEVEL, GAP_HELDOUT_LEVEL, GAP_TEST_LEVEL
from .verdict import confusable, no_gap, verdict
from .where import linear_where, region
from ..fitting.judging.metrics import rms

__all__ = ["gyro_diag", "gyro_baseline", "gyro_where", "GyroBaseline"]


def _wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted least squares: (coefficients, residuals y - X beta, inverse normal matrix)."""
    A = X.T @ (X * w[:, None])
    Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
    beta = Ai @ (X.T @ (w * y))
    r = y - X @ beta
    return beta, r, Ai


@dataclass
class GyroBaseline:
    """The gyro baseline (a bias per axis and Earth's vertical rate) fitted to the pose means."""
    n: int                         #: poses
    y: np.ndarray                  #: pose means stacked x, y, z per pose, dps
    var: np.ndarray                #: their noise variance, Earth's horizontal rate included, dps^2
    w: np.ndarray                  #: weights 1 / var
    X0: np.ndarray                 #: the baseline design
    r0: np.ndarray                 #: baseline residuals, dps
    e0: np.ndarray                 #: held-out residuals, dps
    chi2: float
    ratio: float                   #: held-out RMS over the twin's median
    significant: bool              #: a gap: chi-square rejects and the ratio is above the twin's q99
    report: Dict[str, object]      #: the baseline figures of the output


def gyro_baseline(g: np.ndarray, gvar: np.ndarray, ctx, sims, rng) -> GyroBaseline:
    """The baseline fit of gyro pose means ``g`` (N, 3) in dps with noise variance ``gvar``
    (N, 3), its held-out residuals and its twin."""
    N = len(g)
    y = g.reshape(-1)
    var = gvar.reshape(-1)
    # baseline: a bias per axis and Earth's vertical rate along the accelerometer's up
    X0 = np.hstack([kron_cols(np.ones(N)), vertical_column(ctx["acc_dir"])])
    b0, r0, A0 = _wls(X0, y, 1 / var)
    # Earth's horizontal rate (unknown heading) as pose-to-pose scatter in the twin; its
    # size from the fitted vertical rate taken 2 standard errors towards zero (a larger
    # horizontal share): an overestimated vertical rate would call Earth's rate a gap.  The
    # standard error is scaled by the excess scatter of this fit: an effect the baseline
    # misses pulls the vertical rate (a g-sensitivity of 0.05 dps/g moved it from -0.0030 to
    # -0.0075 dps, past the cap), and the horizontal share left too small kept the true
    # model from closing (tests/test_gap_gyro_search.py)
    exc0 = max(1.0, float(np.sum(r0 * r0 / var)) / max(3 * N - 4, 1))
    v_low = max(abs(float(b0[3])) - 2 * math.sqrt(max(float(A0[3, 3]), 0.0) * exc0), 0.0)
    var = var + horizontal_variance(ctx["acc_dir"], v_low).reshape(-1)
    w = 1 / var
    b0, r0, A1 = _wls(X0, y, w)
    chi2 = float(np.sum(w * r0 * r0))
    p_gap, lp = p_and_log10(chi2, 3 * N - 4)
    e0 = heldout(r0, -X0, w)
    tw = twin_rms(-X0, var, w, sims, rng)
    twin = float(np.median(tw))
    ratio = rms(e0) / twin
    ratio_q99 = float(np.quantile(tw / twin, 0.99))
    report = {"poses": N, "ratio_before": ratio, "p_value": p_gap, "log10_p_value": round(lp, 2),
              "chi2": chi2, "dof": 3 * N - 4, "unit": "dps", "bias_dps": b0[:3].tolist(),
              "earth_rate_vertical_dps": float(b0[3]),
              **earth_rate_report(float(b0[3]), math.sqrt(max(float(A1[3, 3]), 0.0)
                                                           * max(1.0, chi2 / max(3 * N - 4, 1)))),
              "heldout_rms": rms(e0), "twin_heldout_rms": twin,
              "twin_ratio_q99": ratio_q99}
    significant = p_gap < GAP_TEST_LEVEL and ratio > ratio_q99
    return GyroBaseline(N, y, var, w, X0, r0, e0, chi2, ratio, significant, report)


def _score_gyro(b: GyroBaseline, ctx, names_skip) -> List[tuple]:
    """Score test of each gyro candidate, most significant first: (cand, Ct, stat, q, p, lp, vis)."""
    tested = []
    for c in GYRO_CANDIDATES:
        if c.name in names_skip:
            continue
        C = c.columns(ctx)
        Ct, Cw = proj_sig(-b.X0, -C, b.w)
        stat, qv, vis = score(b.r0 * np.sqrt(b.w), Ct, Cw)
        p, lpc = p_and_log10(stat, qv) if qv else (1.0, 0.0)
        tested.append((c, Ct, stat, qv, p, lpc, vis))
    tested.sort(key=lambda d: d[5])
    return tested


def _fit_gyro(b: GyroBaseline, tested: List[tuple], ctx, sims, rng) -> List[Dict[str, object]]:
    """Refit every visible candidate: the report's entries."""
    bonf = GAP_ATTRIBUTION_LEVEL / max(len(GYRO_CANDIDATES), 1)
    w, var = b.w, b.var
    effects = []
    for c, Ct, stat, qv, p, lpc, vis in tested:
        ent = {"name": c.name, "score_chi2": round(stat, 3), "score_p_value": p,
               "visibility": round(vis, 3), "significant": False, "ratio_after": b.ratio, "params": {}}
        if qv:
            X = np.hstack([b.X0, c.columns(ctx)])
            B = TRACELESS if c.name == "g_sensitivity" else np.eye(c.q)
            beta, r1, Ai = _wls(X, b.y, w)
            chi2a = float(np.sum(w * r1 * r1))
            e1 = heldout(r1, -X, w)
            pn, _ = p_and_log10(max(b.chi2 - chi2a, 0.0), c.q)
            twl = twin_rms(-X, var, w, sims, rng)
            twa = float(np.median(twl))
            ra = rms(e1) / twa
            Ai = Ai * max(1.0, chi2a / max(3 * b.n - X.shape[1], 1))   # remaining excess scatter
            ent.update({"ratio_after": ra, "nested_p_value": pn, "q": c.q,
                        "closed": bool(ra <= float(np.quantile(twl / twa, 0.99))),
                        "significant": bool(b.significant and p < bonf and pn < bonf
                                            and np.mean(e1 ** 2) < np.mean(b.e0 ** 2)),
                        "params": {f"{c.name}_{c.units}": (B @ beta[4:]).tolist()},
                        "stderr": {f"{c.name}_{c.units}": np.sqrt(np.diag(B @ Ai[4:, 4:] @ B.T)).tolist()}})
        effects.append(ent)
    return effects


def _spawn(rng):
    """A child generator for the search's draws that leaves ``rng``'s own stream as it was
    (the magnetometer, diagnosed next, draws the same twins as before the search).  The
    child comes from the bit generator's seed sequence, as ``Generator.spawn`` (numpy >=
    1.25) makes it, so numpy 1.21-1.24 (Raspberry Pi OS bookworm ships 1.24) draw the same."""
    bg = rng.bit_generator
    ss = getattr(bg, "seed_seq", None) or getattr(bg, "_seed_seq", None)
    if ss is None or not hasattr(ss, "spawn"):     # a generator made without a seed sequence
        return np.random.default_rng(int(rng.integers(2 ** 62)))
    return np.random.Generator(type(bg)(ss.spawn(1)[0]))


def _decide_gyro(out: Dict[str, object], b: GyroBaseline, tested: List[tuple], ctx, rng) -> Tuple[List[str], object]:
    """The verdict from the combination search (gap/gyrosearch.py), written into ``out``:
    with a gap, the members of the model the forward and backward steps end with (each
    passed its Wald and held-out tests); returns (chosen, held-out residuals after)."""
    if not b.significant:
        no_gap(out, b.ratio)
        return [], None
    sr = gyro_stepwise(b, [d[0] for d in tested if d[3]], ctx, _spawn(rng))
    m = sr["model"]
    chosen = m.names
    ratio_after = m.ratio if chosen else b.ratio
    closed = m.closed if chosen else None
    out["search"] = {"steps": sr["steps"], "members": sr["members"], "models_fitted": sr["models_fitted"],
                     "coefficient_level": sr["coefficient_level"], "heldout_level": GAP_HELDOUT_LEVEL,
                     "rule": "forward and backward steps; every member's coefficients (Wald, at the "
                             "attribution level over the search's member tests) and held-out shrink "
                             "(against noise draws without it) significant"}
    if len(chosen) > 1:
        # the members' coefficients flat in the verdict's order (g-sensitivity as its 9 elements)
        out["joint"] = {"effects": list(chosen), "ratio_after": float(ratio_after), "closed": closed,
                        "params": [v for e in sr["members"] for p in e["params"].values() for v in p],
                        "stderr": [v for e in sr["members"] for p in e["stderr"].values() for v in p]}
    out.update(verdict(True, chosen, b.ratio, float(ratio_after), closed))
    out["ratio_after"] = float(ratio_after)
    conf = confusable(chosen, {d[0].name: d[1] for d in tested if d[3]})
    if conf:
        out["confusable"] = conf
    if "g_sensitivity" in chosen:
        out["note"] = ("Earth's vertical rate (up to 15 deg/h) is in the baseline; it takes up an "
                       "isotropic g-sensitivity of the same size")
    return chosen, (m.e if chosen else None)


def gyro_diag(g: np.ndarray, gvar: np.ndarray, ctx, sims, rng, names_skip) -> Dict[str, object]:
    """Diagnose gyro pose means ``g`` (N, 3) in dps with noise variance ``gvar`` (N, 3):
    baseline -> candidates (score tests, single refits: the report) -> the combination
    search's verdict (gap/gyrosearch.py)."""
    b = gyro_baseline(g, gvar, ctx, sims, rng)
    out = b.report
    tested = _score_gyro(b, ctx, names_skip)
    effects = _fit_gyro(b, tested, ctx, sims, rng)
    out["effects"] = effects
    chosen, e_after = _decide_gyro(out, b, tested, ctx, rng)
    N = b.n
    rz = (b.r0 * np.sqrt(b.w)).reshape(N, 3)
    out["where"] = gyro_where(rz, ctx)
    # for --report: one point per pose and axis (stacked x, y, z per pose)
    rep = lambda v: None if v is None else np.repeat(np.asarray(v), 3, axis=0)
    out["_plot"] = {"e": b.e0, "var": b.var, "t": rep(ctx["t"]), "temp": rep(ctx.get("temp")),
                    "u": rep(ctx["acc_dir"]), "axis": np.tile(np.arange(3), N),
                    "e_after": e_after, "after_label": "+".join(chosen) if chosen else None}
    return out


def _shares(ex: np.ndarray, labels: np.ndarray, names: Sequence[str]) -> Dict[str, float]:
    tot = max(float(np.sum(ex)), 1e-300)
    return {nm: round(float(np.sum(ex[labels == k])) / tot, 3) for k, nm in enumerate(names)}


def gyro_where(rz: np.ndarray, ctx) -> Dict[str, object]:
    """Where the excess of the normalised baseline residuals ``rz`` (N, 3) lies: by axis
    (gap/where.py linear_where, with its trends), by orientation (the axis up), by
    temperature and time quartile, and the trend against each axis's squared up component
    (what a g-sensitivity or an out-of-library orientation effect leaves)."""
    out = linear_where(rz, ctx)
    ex = np.sum(np.maximum(rz ** 2 - 1, 0), axis=1)
    u = np.asarray(ctx["acc_dir"], float)
    reg = np.array([region(v) for v in u])
    names = sorted(set(reg.tolist()))
    out["region_share"] = _shares(ex, np.array([names.index(x) for x in reg]), names)
    for key, v, fmt in (("temperature_bin_share", ctx.get("temp"), "{:.1f}..{:.1f} C"),
                        ("time_bin_share", ctx["t"], "{:.0f}..{:.0f} s")):
        if v is None or not np.all(np.isfinite(v)):
            continue
        qs = np.quantile(v, [0, 0.25, 0.5, 0.75, 1])
        k = np.clip(np.searchsorted(qs[1:-1], v, side="right"), 0, 3)
        out[key] = _shares(ex, k, [fmt.format(qs[i], qs[i + 1]) for i in range(4)])
    ud = u / np.linalg.norm(u, axis=1, keepdims=True)
    size = np.linalg.norm(rz, axis=1)
    for j, ax in enumerate("xyz"):
        c = corr_p(ud[:, j] ** 2, size)
        if c is not None:
            out["trends"][f"{ax}_squared"] = c
    return out
