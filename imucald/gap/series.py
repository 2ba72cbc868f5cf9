"""Gap diagnosis from still stretches split in time: one orientation or a few.

A bench warm-up, a thermal-chamber log or a board left on a desk has one (or a
few) orientations, so the pose-set norm model cannot be fitted; yet a gyro's
bias needs no orientation, and an accelerometer's reading in a fixed
orientation shows its bias (and, along gravity, its scale) changing with
temperature and time.  Pure functions over arrays:

1. **Blocks.**  Each still stretch is cut into blocks of ``block_s`` seconds;
   a block's mean, temperature and mid time are one observation per axis.
2. **Twin noise (coloured).**  The variance of a block mean under the noise
   model is the Allan variance at the block length, extrapolated from inside the
   blocks (Hadamard variance at tau = T/8, T/4 from sub-block means) with the measured
   log-log slope, which is clamped to [-1/2, 0]: white (-1/2) and flicker /
   bias instability (0) are noise; anything steeper, i.e. variation that
   grows with the time scale beyond the block, is left for the effects.
3. **Baseline.**  One constant per group (gap/single.py ``run_groups``: each still
   run its own) and axis (the deployed calibration's bias; per run because a fixed
   orientation's gravity share and g-sensitivity are constants too, and a board set
   down again is never in quite the same orientation).
4. **Candidates** (shared by all groups, per axis): ``thermal_bias`` (linear in
   temperature), ``bias_drift`` (linear in time), ``wandering_bias`` (a smooth
   function of time: cubic spline with interior knots chosen by held-out error).
   Held-out = leave-one-block-out; the twin re-simulates the blocks with the
   noise of step 2 and refits the same model.  Effects are added greedily; a
   second one only if it passes the same test against the twin of the model
   that already contains the first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence

import numpy as np

from ..numerics.tails import chi2_logsf
from ..fitting.judging.levels import GAP_ATTRIBUTION_LEVEL, GAP_REMAINING_LEVEL, GAP_TEST_LEVEL
from .verdict import verdict

__all__ = ["make_blocks", "block_noise_var", "series_diagnose",
           "within_pose_inflation"]



def make_blocks(t_s: np.ndarray, x: np.ndarray, temp_c: Optional[np.ndarray], slices: Sequence[slice],
                group: Sequence[int], block_s: float, min_fill: float = 0.5) -> Dict[str, np.ndarray]:
    """Cut each still slice into blocks of ``block_s`` seconds (by time: gaps in the
    sampling are allowed; a block needs ``min_fill`` of the median sample count).
    Returns means (K, C), quarter means (K, 4, C), counts, mid times, temperatures, groups."""
    rows = []
    stretch = []
    for si, (s, gk) in enumerate(zip(slices, group)):
        ts = t_s[s]
        if len(ts) < 8:
            continue
        edges = np.arange(ts[0], ts[-1] + 1e-9, block_s)
        idx = np.searchsorted(ts, edges)
        for a, b in zip(idx[:-1], idx[1:]):
            if b - a >= 8:
                rows.append((s.start + a, s.start + b, gk))
                stretch.append(si)
    if not rows:
        return {"n": np.zeros(0)}
    n = np.array([b - a for a, b, _ in rows])
    keep = n >= min_fill * np.median(n)
    rows = [r for r, k in zip(rows, keep) if k]
    stretch = [r for r, k in zip(stretch, keep) if k]
    C = x.shape[1]
    K = len(rows)
    m = np.zeros((K, C))
    q = np.zeros((K, 8, C))
    nq = np.zeros((K, 8))
    tm = np.zeros(K)
    tc = np.full(K, np.nan)
    for k, (a, b, _) in enumerate(rows):
        xb = x[a:b]
        m[k] = xb.mean(0)
        for j, part in enumerate(np.array_split(np.arange(b - a), 8)):
            q[k, j] = xb[part].mean(0)
            nq[k, j] = len(part)
        tm[k] = 0.5 * (t_s[a] + t_s[b - 1])
        if temp_c is not None:
            tc[k] = float(np.mean(temp_c[a:b]))
    return {"mean": m, "parts": q, "nparts": nq, "n": np.array([b - a for a, b, _ in rows]),
            "t": tm, "temp": tc, "group": np.array([g for _, _, g in rows]), "stretch": np.array(stretch)}


def block_noise_var(blk: Dict[str, np.ndarray]) -> Dict[str, object]:
    """Variance of each block mean (K, C) under the noise model, from inside the blocks:
    the Hadamard variance (second differences of consecutive sub-block means, blind to a
    linear trend such as a warm-up's within a block; equal to the Allan variance for white
    and close to it for flicker noise) at tau = T/8 and T/4, extrapolated to the block
    length T with the log-log slope clamped to [-1/2, 0] (white .. flicker).  Each
    block's variance is scaled by its count relative to the median."""
    q, nq = blk["parts"], blk["nparts"]
    hv = []
    for L in (8, 4):
        g = 8 // L
        qq = np.stack([np.sum(q[:, j * g:(j + 1) * g] * nq[:, j * g:(j + 1) * g, None], 1)
                       / np.sum(nq[:, j * g:(j + 1) * g], 1)[:, None] for j in range(L)], 1)
        d = (qq[:, 2:] - 2 * qq[:, 1:-1] + qq[:, :-2]).reshape(-1, q.shape[2])
        hv.append(np.mean(d ** 2, axis=0) / 6.0)
    hv = np.array(hv)                                  # (2, C): tau = T/8, T/4
    slope = np.clip(0.5 * np.log2(np.maximum(hv[1], 1e-300) / np.maximum(hv[0], 1e-300)), -0.5, 0.0)
    av_T = hv[1] * 16.0 ** slope                       # two doublings: avar ratio (2^slope)^4
    rel = np.median(blk["n"]) / blk["n"]
    var = av_T[None, :] * rel[:, None]
    return {"var": var, "adev_eighth": np.sqrt(hv[0]), "adev_quarter": np.sqrt(hv[1]),
            "adev_block": np.sqrt(av_T), "loglog_slope": slope}


def between_block_var(blk: Dict[str, np.ndarray], min_diffs: int = 12) -> Optional[np.ndarray]:
    """Variance of a block mean (C,) from the block means themselves: the Hadamard variance at
    tau = the block length (second differences of consecutive blocks of one still stretch),
    taken robustly (median of the squared differences / 0.455, the chi-square(1) median), so
    that a warm-up's curvature in a few early blocks does not count as noise.  This sees the
    colour at time scales beyond a block (flicker / bias instability with time constants of
    minutes) that the sub-block estimate cannot; a trend (linear or the smooth part of a
    warm-up) cancels in second differences.  None with fewer than ``min_diffs`` differences."""
    m, st = blk["mean"], blk.get("stretch")
    if st is None or len(m) < 3:
        return None
    ok = (st[2:] == st[1:-1]) & (st[1:-1] == st[:-2])
    if ok.sum() < min_diffs:
        return None
    d = (m[2:] - 2 * m[1:-1] + m[:-2])[ok]
    # white noise of per-block variance v: Var(d) = 6 v (blocks of equal counts)
    return np.median(d * d, axis=0) / 0.455 / 6.0


def within_pose_inflation(x: np.ndarray, slices: Sequence[slice]) -> Dict[str, object]:
    """Variance inflation of a pose mean over white noise, measured inside the poses:
    each pose is cut in eighths and :func:`block_noise_var` extrapolates the Hadamard
    variance at T/8 and T/4 to the pose length T.  Inflation per axis = the variance at T
    over the white prediction (the T/8 value divided by 8), in [1, 8]."""
    parts, nparts, n = [], [], []
    for s in slices:
        if s.stop - s.start < 16:
            continue
        xb = x[s]
        idx = np.array_split(np.arange(len(xb)), 8)
        parts.append([xb[i].mean(0) for i in idx])
        nparts.append([len(i) for i in idx])
        n.append(len(xb))
    if len(parts) < 3:
        return {"inflation": 1.0, "note": "fewer than 3 poses of 16 samples: white noise assumed"}
    blk = {"parts": np.array(parts), "nparts": np.array(nparts, float), "n": np.array(n)}
    nv = block_noise_var(blk)
    # only colour that is clear of the slope's sampling error inflates the twin's noise:
    # a log variance from m squared differences scatters by about sqrt(2 / m)
    m8, m4 = 6 * len(parts), 2 * len(parts)
    se = 0.5 * math.sqrt(2.0 / m8 + 2.0 / m4) / math.log(2.0)
    slope = np.clip(nv["loglog_slope"] - 2 * se, -0.5, 0.0)
    k = np.clip(16.0 ** slope * nv["adev_quarter"] ** 2 / (nv["adev_eighth"] ** 2 / 8.0), 1.0, 8.0)
    return {"inflation": float(np.mean(k)), "per_axis": np.round(k, 3).tolist(),
            "loglog_slope": np.round(nv["loglog_slope"], 3).tolist(), "slope_stderr": round(se, 3)}


# --- linear machinery -----------------------------------------------------------------------

def _group_cols(group: np.ndarray) -> np.ndarray:
    gs = np.unique(group)
    return (group[:, None] == gs[None, :]).astype(float)


def _spline_cols(s: np.ndarray, knots: Sequence[float]) -> np.ndarray:
    """Cubic spline in s in [0, 1] without its constant: s, s^2, s^3, (s - k)_+^3."""
    cols = [s - 0.5, (s - 0.5) ** 2, (s - 0.5) ** 3] + [np.clip(s - k, 0, None) ** 3 for k in knots]
    X = np.stack(cols, 1)
    return X - X.mean(0)


def _fit(X: np.ndarray, Y: np.ndarray, V: np.ndarray):
    """Per-channel WLS of Y (K, C) on X (K, p) with variances V (K, C).
    Returns beta (p, C), residuals, held-out (LOO) residuals, chi2 per channel, cov (C, p, p)."""
    K, C = Y.shape
    p = X.shape[1]
    beta = np.zeros((p, C))
    R = np.zeros_like(Y)
    E = np.zeros_like(Y)
    cov = np.zeros((C, p, p))
    for c in range(C):
        w = 1.0 / V[:, c]
        A = X.T @ (X * w[:, None])
        Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
        b = Ai @ (X.T @ (w * Y[:, c]))
        r = Y[:, c] - X @ b
        hdiag = np.einsum("kp,pq,kq->k", X, Ai, X) * w
        beta[:, c], R[:, c], cov[c] = b, r, Ai
        E[:, c] = r / np.maximum(1 - hdiag, 1e-3)
    chi2 = np.sum(R ** 2 / V, axis=0)
    return beta, R, E, chi2, cov


def _twin(X: np.ndarray, V: np.ndarray, sims: int, rng) -> np.ndarray:
    """Normalised held-out RMS of the model X on pure noise V: (sims,) re-simulations."""
    K, C = V.shape
    out = np.zeros(sims)
    acc = np.zeros(sims)
    for c in range(C):
        w = 1.0 / V[:, c]
        A = X.T @ (X * w[:, None])
        Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
        H = X @ Ai @ (X * w[:, None]).T
        hd = np.diag(H)
        n = rng.normal(size=(sims, K)) * np.sqrt(V[:, c])
        e = (n - n @ H.T) / np.maximum(1 - hd, 1e-3)
        acc += np.sum(e * e / V[None, :, c], axis=1)
    out[:] = np.sqrt(acc / (K * C))
    return out


def _norm_heldout(E: np.ndarray, V: np.ndarray) -> float:
    return float(np.sqrt(np.mean(E * E / V)))


def _log10p(stat: float, dof: int) -> float:
    return chi2_logsf(stat, dof) / math.log(10) if dof > 0 else 0.0


# --- the diagnosis --------------------------------------------------------------------------------

@dataclass
class SeriesProblem:
    """Block means of one sensor, their noise and the candidates' design columns."""
    Y: np.ndarray                  #: block means (K, C), unit
    V: np.ndarray                  #: their noise variance (K, C), unit^2
    G: np.ndarray                  #: the baseline: a constant per group (still run)
    t: np.ndarray                  #: block mid times, s
    s: np.ndarray                  #: time scaled to [0, 1]
    cands: Dict[str, np.ndarray]   #: parametric candidates' columns, by name
    units: Dict[str, str]          #: their coefficients' units
    unit: str

    @property
    def K(self) -> int:
        return self.Y.shape[0]

    @property
    def C(self) -> int:
        return self.Y.shape[1]

    def dof(self, X: np.ndarray) -> int:
        return self.K * self.C - X.shape[1] * self.C


def series_problem(blk: Dict[str, np.ndarray], noise: Dict[str, object], unit: str,
                   use_temp: bool) -> SeriesProblem:
    t = blk["t"]
    s = (t - t.min()) / max(np.ptp(t), 1e-9)
    cands: Dict[str, np.ndarray] = {}
    if use_temp:
        cands["thermal_bias"] = (blk["temp"] - blk["temp"].mean())[:, None]
    cands["bias_drift"] = (t - t.mean())[:, None]
    units = {"thermal_bias": f"{unit}/degC", "bias_drift": f"{unit}/s"}
    return SeriesProblem(blk["mean"], noise["var"], _group_cols(blk["group"]), t, s, cands, units, unit)


def _wander_cols(p: SeriesProblem, base: np.ndarray):
    """Spline knots chosen by held-out error on top of ``base``: (columns, knots)."""
    best = None
    for m in range(0, max(0, min(6, p.K // 8 - 1)) + 1):
        knots = [(i + 1) / (m + 1) for i in range(m)]
        S = _spline_cols(p.s, knots)
        _, _, E, _, _ = _fit(np.hstack([base, S]), p.Y, p.V)
        ho = _norm_heldout(E, p.V)
        if best is None or ho < best[0]:
            best = (ho, S, m)
    return best[1], best[2]


@dataclass
class SeriesBaseline:
    """The baseline fit (a constant per group and axis), its held-out residuals and its twin."""
    R0: np.ndarray                 #: residuals (K, C)
    E0: np.ndarray                 #: held-out residuals (K, C)
    chi0: np.ndarray               #: chi-square per channel
    ratio0: float                  #: normalised held-out RMS over the twin's median
    lp0: float                     #: log10 p-value of the chi-square test
    gap: bool                      #: chi-square rejects and the ratio is above the twin's q99
    report: Dict[str, object]      #: the baseline figures of the output


def series_baseline(p: SeriesProblem, noise: Dict[str, object], sims: int, rng) -> SeriesBaseline:
    X0, V = p.G, p.V
    _, R0, E0, chi0, _ = _fit(X0, p.Y, V)
    tw0 = _twin(X0, V, sims, rng)
    twin0 = max(float(np.median(tw0)), 1e-300)      # no freedom left: single.py refuses first
    ratio0 = _norm_heldout(E0, V) / twin0
    dof0 = p.dof(X0)
    lp0 = _log10p(float(chi0.sum()), dof0)
    q99 = float(np.quantile(tw0 / twin0, 0.99))
    gap = lp0 < math.log10(GAP_TEST_LEVEL) and ratio0 > q99
    out: Dict[str, object] = {"mode": "time_series", "blocks": p.K, "groups": int(p.G.shape[1]),
                              "block_s": None, "ratio_before": ratio0, "twin_ratio_q99": q99,
                              "chi2": float(chi0.sum()), "dof": dof0, "log10_p_value": round(lp0, 2),
                              "p_value": 10 ** lp0, "unit": p.unit,
                              "noise_colour": {"adev_block": noise["adev_block"].tolist(),
                                               "loglog_slope": noise["loglog_slope"].tolist()}}
    return SeriesBaseline(R0, E0, chi0, ratio0, lp0, gap, out)


def _try_candidate(p: SeriesProblem, X: np.ndarray, chi_cur: np.ndarray, E_cur: np.ndarray, name: str,
                   cols: Optional[np.ndarray], sims: int, rng, bonf: float, gap: bool, step: int):
    """The model ``X`` with candidate ``name`` added: (report entry, design, chi2, held-out)."""
    Y, V, C = p.Y, p.V, p.C
    knots = None
    if name == "wandering_bias":
        cols, knots = _wander_cols(p, X)
    Xa = np.hstack([X, cols])
    beta, R, E, chi, cov = _fit(Xa, Y, V)
    qa = cols.shape[1] * C
    dchi = float(chi_cur.sum() - chi.sum())
    lpn = _log10p(max(dchi, 0.0), qa)
    twa = _twin(Xa, V, sims, rng)
    ra = _norm_heldout(E, V) / float(np.median(twa))
    ok = lpn < math.log10(bonf) and np.mean(E * E / V) < np.mean(E_cur * E_cur / V)
    ent = {"name": name, "nested_log10_p": round(lpn, 2), "ratio_after": ra,
           "closed": bool(ra <= float(np.quantile(twa / np.median(twa), 0.99))),
           "significant": bool(gap and ok), "step": step + 1}
    # coefficients with standard errors scaled by the remaining excess (chi2/dof > 1)
    red = max(1.0, float(chi.sum()) / max(p.dof(Xa), 1))
    if name != "wandering_bias":
        co = beta[X.shape[1]:, :][0]
        se = np.sqrt(np.array([cov[c][X.shape[1], X.shape[1]] for c in range(C)]) * red)
        ent["params"] = {f"{name}_{p.units[name]}": co.tolist()}
        ent["stderr"] = {f"{name}_{p.units[name]}": se.tolist()}
    else:
        curve = cols @ beta[X.shape[1]:, :]
        ent["params"] = {"interior_knots": knots, f"curve_rms_{p.unit}": np.sqrt(np.mean(curve ** 2, 0)).tolist()}
    return ent, Xa, chi, E


def _gap_remains(p: SeriesProblem, X: np.ndarray, chi_cur: np.ndarray, E_cur: np.ndarray,
                 tw_cur: np.ndarray) -> bool:
    """The model ``X`` is still rejected (chi-square) and out of its own twin's range."""
    return (_log10p(float(chi_cur.sum()), p.dof(X)) < math.log10(GAP_REMAINING_LEVEL)
            and _norm_heldout(E_cur, p.V) / np.median(tw_cur) > np.quantile(tw_cur / np.median(tw_cur), 0.99))


@dataclass
class SeriesChoice:
    """The greedy forward steps: every trial's entry and the model they end with."""
    chosen: List[str]
    effects: List[Dict[str, object]]
    steps: List[tuple]
    E_cur: np.ndarray
    ratio_cur: float


def series_candidates(p: SeriesProblem, b: SeriesBaseline, sims: int, rng) -> SeriesChoice:
    """Greedy, at most two steps: each addition judged on held-out blocks against its twin."""
    V = p.V
    chosen: List[str] = []
    X, chi_cur, E_cur, ratio_cur = p.G, b.chi0, b.E0, b.ratio0
    effects: List[Dict[str, object]] = []
    pending = dict(p.cands)
    pending["wandering_bias"] = None
    steps = []
    bonf = GAP_ATTRIBUTION_LEVEL / max(len(pending), 1)
    for _step in range(2):
        if not (b.lp0 < math.log10(GAP_TEST_LEVEL)):
            break
        # the model so far must itself leave a gap against its own twin
        tw_cur = _twin(X, V, sims, rng)
        if _step and not _gap_remains(p, X, chi_cur, E_cur, tw_cur):
            break
        trial = [_try_candidate(p, X, chi_cur, E_cur, name, cols, sims, rng, bonf, b.gap, _step)
                 for name, cols in pending.items()]
        # the simplest significant candidate that closes the gap; else the one closing most
        trial.sort(key=lambda d: (not d[0]["significant"], not d[0]["closed"],
                                  d[1].shape[1] if d[0]["closed"] else 0, d[0]["ratio_after"]))
        effects.extend(d[0] for d in trial)
        best = trial[0]
        if not best[0]["significant"]:
            break
        chosen.append(best[0]["name"])
        steps.append(best)
        X, chi_cur, E_cur, ratio_cur = best[1], best[2], best[3], best[0]["ratio_after"]
        pending.pop(best[0]["name"])
        if best[0]["closed"]:
            break
    return SeriesChoice(chosen, effects, steps, E_cur, ratio_cur)


def series_diagnose(blk: Dict[str, np.ndarray], noise: Dict[str, object], sims: int, rng,
                    unit: str, use_temp: bool, axis_names: str = "xyz") -> Dict[str, object]:
    """Baseline (constant per group and axis) against thermal bias, linear drift and a
    wandering (spline) bias; greedy, each addition judged on held-out blocks against its twin.

    Steps: :func:`series_baseline` -> :func:`series_candidates` -> verdict (gap/verdict.py)."""
    p = series_problem(blk, noise, unit, use_temp)
    K, C, V, t = p.K, p.C, p.V, p.t
    b = series_baseline(p, noise, sims, rng)
    ch = series_candidates(p, b, sims, rng)
    chosen = ch.chosen
    out = b.report
    out["effects"] = ch.effects
    out["chosen"] = chosen
    out["gap"] = bool(b.gap)
    out["ratio_after"] = float(ch.ratio_cur)
    out["closed"] = bool(ch.steps[-1][0]["closed"]) if ch.steps else None
    out["confusable"] = _confusable(blk, chosen, ch.effects, use_temp)
    out.update(verdict(b.gap, chosen, b.ratio0, float(ch.ratio_cur), out["closed"]))
    # for --report: one point per block and axis
    out["_plot"] = {"e": b.E0.ravel(), "var": V.ravel(), "t": np.repeat(t - t.min(), C),
                    "temp": np.repeat(blk["temp"], C) if use_temp else None, "u": None,
                    "axis": np.tile(np.arange(C), K), "e_after": ch.E_cur.ravel() if chosen else None,
                    "after_label": "+".join(chosen) if chosen else None}
    rz = (b.R0 / np.sqrt(V))
    tot = float(np.sum(np.maximum(rz ** 2 - 1, 0))) or 1.0
    out["where"] = {"axis_share": {axis_names[c]: round(float(np.sum(np.maximum(rz[:, c] ** 2 - 1, 0))) / tot, 3)
                                   for c in range(C)}}
    return out


def _confusable(blk, chosen, effects, use_temp) -> List[Dict[str, object]]:
    """Effects that this recording cannot tell apart."""
    out = []
    if not chosen or not use_temp:
        return out
    T, t = blk["temp"] - blk["temp"].mean(), blk["t"] - blk["t"].mean()
    cc = abs(float(np.corrcoef(T, t)[0, 1])) if np.std(T) > 0 and np.std(t) > 0 else 0.0
    closed = {e["name"] for e in effects if e["step"] == 1 and e.get("closed")}
    if "thermal_bias" in chosen or "bias_drift" in chosen:
        if cc > 0.98:
            out.append({"effects": ["bias_drift", "thermal_bias"], "correlation": round(cc, 4),
                        "to_separate": "a temperature profile that rises and falls (heat then cool), "
                                       "so temperature is not a function of time"})
    if "thermal_bias" in chosen and "wandering_bias" in closed | {"wandering_bias"} and \
            _monotonic(blk["temp"], blk["t"]):
        out.append({"effects": ["thermal_bias", "wandering_bias"],
                    "why": "on a monotonic warm-up a smooth function of time can follow the temperature "
                           "curve; the one-coefficient thermal model is preferred when it closes the gap",
                    "to_separate": "heat then cool, or a second warm-up from a different start temperature"})
    return out


def _monotonic(temp, t) -> bool:
    o = np.argsort(t)
    d = np.diff(temp[o])
    return bool(np.all(d >= -0.5) or np.all(d <= 0.5))
