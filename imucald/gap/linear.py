"""The gap diagnosis of the gyro: a linear model (bias per axis) fitted to the pose
means by weighted least squares; candidates add design columns."""
from __future__ import annotations

from typing import Dict

import numpy as np

from .candidates import GYRO_CANDIDATES, kron_cols
from .signif import p_and_log10, proj_sig, score
from .twin import heldout, twin_rms
from .verdict import ALPHA, decide
from .where import linear_where

__all__ = ["gyro_diag"]


def gyro_diag(g: np.ndarray, gvar: np.ndarray, ctx, sims, rng, names_skip) -> Dict[str, object]:
    """Diagnose gyro pose means ``g`` (N, 3) in dps with noise variance ``gvar`` (N, 3)."""
    N = len(g)
    y = g.reshape(-1)
    var = gvar.reshape(-1)
    w = 1 / var
    X0 = kron_cols(np.ones(N))

    def wls(X):
        A = X.T @ (X * w[:, None])
        Ai = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
        beta = Ai @ (X.T @ (w * y))
        r = y - X @ beta
        return beta, r, Ai
    b0, r0, _ = wls(X0)
    chi2 = float(np.sum(w * r0 * r0))
    p_gap, lp = p_and_log10(chi2, 3 * N - 3)
    J0 = -X0
    e0 = heldout(r0, J0, w)
    tw = twin_rms(J0, var, w, sims, rng)
    twin = float(np.median(tw))
    ratio = float(np.sqrt(np.mean(e0 ** 2)) / twin)
    ratio_q99 = float(np.quantile(tw / twin, 0.99))
    out = {"poses": N, "ratio_before": ratio, "p_value": p_gap, "log10_p_value": round(lp, 2),
           "chi2": chi2, "dof": 3 * N - 3, "unit": "dps", "bias_dps": b0.tolist(),
           "heldout_rms": float(np.sqrt(np.mean(e0 ** 2))), "twin_heldout_rms": twin,
           "twin_ratio_q99": ratio_q99}
    significant = p_gap < ALPHA and ratio > ratio_q99
    effects = []
    bonf = ALPHA / max(len(GYRO_CANDIDATES), 1)
    tested = []
    for c in GYRO_CANDIDATES:
        if c.name in names_skip:
            continue
        C = c.columns(ctx)
        Ct, Cw = proj_sig(J0, -C, w)
        stat, qv, vis = score(r0 * np.sqrt(w), Ct, Cw)
        p, lpc = p_and_log10(stat, qv) if qv else (1.0, 0.0)
        tested.append((c, Ct, stat, qv, p, lpc, vis))
    tested.sort(key=lambda d: d[5])
    for c, Ct, stat, qv, p, lpc, vis in tested:
        ent = {"name": c.name, "score_chi2": round(stat, 3), "score_p_value": p,
               "visibility": round(vis, 3), "significant": False, "ratio_after": ratio, "params": {}}
        if qv:
            X = np.hstack([X0, c.columns(ctx)])
            beta, r1, Ai = wls(X)
            chi2a = float(np.sum(w * r1 * r1))
            e1 = heldout(r1, -X, w)
            pn, _ = p_and_log10(max(chi2 - chi2a, 0.0), c.q)
            twa = float(np.median(twin_rms(-X, var, w, sims, rng)))
            ra = float(np.sqrt(np.mean(e1 ** 2)) / twa)
            ent.update({"ratio_after": ra, "nested_p_value": pn,
                        "significant": bool(significant and p < bonf and pn < bonf
                                            and np.mean(e1 ** 2) < np.mean(e0 ** 2)),
                        "params": {f"{c.name}_{c.units}": beta[3:].tolist()},
                        "stderr": {f"{c.name}_{c.units}": np.sqrt(np.diag(Ai))[3:].tolist()}})
        effects.append(ent)
    out["effects"] = effects
    chosen = decide(out, ratio, significant, effects, {d[0].name: d[1] for d in tested if d[3]})
    if chosen and chosen[0] == "g_sensitivity":
        out["note"] = ("Earth's rate (15 deg/h) projects on the vertical like an isotropic "
                       "g-sensitivity of about 0.003 dps/g: below that, the two cannot be told apart")
    rz = (r0 * np.sqrt(w)).reshape(N, 3)
    out["where"] = linear_where(rz, ctx)
    return out
