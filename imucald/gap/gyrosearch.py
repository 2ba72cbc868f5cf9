"""The combination search of the gyro's linear gap diagnosis (issue 25 items 3-4): the
discipline of the norm path's search (gap/search.py) on the gyro's weighted least squares
of pose means (gap/linear.py), where every figure is exact and cheap.

A model M is a set of gyro candidates (``thermal_bias``, ``g_sensitivity``, ``bias_drift``:
one form per class) added as design columns to the baseline (a bias per axis and Earth's
vertical rate).  Its fit is weighted least squares; its held-out residuals are the exact
leave-one-out ones r_i / (1 - h_i) from the normal equations; its twin the held-out RMS of
the same design on HELDOUT_SIMS noise draws (the pose-mean variances, Earth's horizontal
rate included), the same draws for every model (common random numbers).

Each member m of M is tested twice and is named only when it passes both:

* **coefficients**: a Wald test, beta_m' Cov_m^+ beta_m against chi-square with the visible
  rank (F(rank, dof) below MIN_DOF residual dof, where the scale is a rough estimate), the
  covariance scaled by the excess scatter M leaves (chi2 / residual dof, at least 1), at
  GAP_ATTRIBUTION_LEVEL split over the search's member tests (:func:`coef_level`);
* **held-out shrink**: the fall in the held-out ratio (held-out RMS over the model's own
  twin median, floored at 1) from M without m to M, against the same fall on the noise
  draws (on which m is absent: signals in the smaller model's span leave both models'
  leave-one-out residuals unchanged, so the null is exact, not linearised); one-sided, at
  GAP_HELDOUT_LEVEL, the Monte Carlo p-value (1 + #{draws >= observed}) / (1 + draws).

Forward: from the baseline, the moves that pass (a class not in the model, in any variant;
or another variant of a member, every member still passing; the first effect must also lower
the held-out RMS below the baseline's and leave MIN_DOF residual degrees of freedom, a second
member down to SEARCH_MIN_DOF); of those the simplest (fewest coefficients, then fewest
effects) that closes the gap (ratio within its own twin's 99th percentile), else the one with
the lowest floored ratio.  Backward, after every forward step: the member that fails a test
by most is dropped, until every member passes.  Stop when no move passes (or a model
repeats).  At most MAX_MEMBERS effects together, as on the norm path.

Pure functions over numpy arrays (the GyroSearch object only caches fits).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..fitting.judging.levels import GAP_ATTRIBUTION_LEVEL
from .candidates import TRACELESS, Candidate, kron_cols
from .search import MAX_MEMBERS, MIN_DOF, SEARCH_MIN_DOF, MemberTests, take_move
from .signif import scaled_wald_p

__all__ = ["gyro_stepwise", "coef_level", "GyroFit", "HELDOUT_SIMS", "THERMAL_CURVED"]

#: noise draws for the twins and the held-out shrink tests (one set per diagnosis, shared by
#: every model): a p-value at 1 % is then resolved to about +-0.2 % (binomial); each model's
#: fit on the data and the draws together costs ~2 products of (3N x p) with (3N x 2001)
HELDOUT_SIMS = 2000
MAX_STEPS = 8


def _dT2(c):
    q = np.asarray(c["dT"], float) ** 2
    return kron_cols(q - q.mean())


#: a variant of the gyro's thermal bias with curvature (a warm-up's ZRO curve is not a
#: straight line in temperature: the linear form left its curvature to a drift on warm-ups
#: and to a g-sensitivity on heat-then-cool, dev seeds 500-539); chosen by the search like
#: the norm path's variants, the single candidates' report keeps the linear form
THERMAL_CURVED = Candidate("thermal_bias", 6, columns=lambda c: np.hstack([kron_cols(c["dT"]), _dT2(c)]),
                           units="dps/degC", parts=[("dps/degC", 3), ("curvature_dps/degC^2", 3)])


def coef_level(variants: Dict[str, int]) -> float:
    """The Wald tests' level, with ``variants`` {class: variant count}: GAP_ATTRIBUTION_LEVEL
    over the (model, member) tests the search can make (each variant alone, and each member
    of each two-class model: 2 n_a n_b per pair of classes), so that a false member is named
    in the final model with probability at most GAP_ATTRIBUTION_LEVEL whatever path the steps
    take (a union bound over (model, member); the held-out test, required as well, only
    lowers it).  Three classes, the thermal bias in two variants: 4 + 2 (4 + 4 + 2) = 14."""
    n = list(variants.values())
    tests = sum(n) + sum(2 * n[i] * n[j] for i in range(len(n)) for j in range(i + 1, len(n)))
    return GAP_ATTRIBUTION_LEVEL / max(tests, 1)


def _key(cands) -> frozenset:
    """A model's identity: its candidates (the search's cache key and its visited set)."""
    return frozenset(id(c) for c in cands)


@dataclass
class GyroFit:
    """One model's weighted least-squares fit and its twin."""
    cands: Tuple                   #: members (Candidate objects)
    beta: np.ndarray               #: baseline coefficients, then each member's
    cov: np.ndarray                #: their covariance, scaled by the excess scatter left
    r: np.ndarray                  #: residuals, dps
    e: np.ndarray                  #: exact leave-one-out residuals, dps
    chi2: float
    dof: float                     #: residual degrees of freedom (3N - rank)
    rms: float                     #: held-out RMS, dps
    sim_rms: np.ndarray            #: held-out RMS on each noise draw
    twin: float = 0.0              #: their median
    q99: float = 0.0               #: the 99th percentile of their ratio to it
    member_p: Dict[str, float] = field(default_factory=dict)

    @property
    def classes(self) -> Tuple[str, ...]:
        """The members' names (what gap/search.py's backward step counts)."""
        return tuple(c.name for c in self.cands)

    def __post_init__(self):
        self.twin = float(np.median(self.sim_rms))
        self.q99 = float(np.quantile(self.sim_rms / self.twin, 0.99))

    @property
    def ratio(self) -> float:
        return self.rms / self.twin

    @property
    def excess(self) -> float:
        return max(self.ratio, 1.0)

    @property
    def closed(self) -> bool:
        return self.ratio <= self.q99

    @property
    def names(self) -> List[str]:
        return [c.name for c in self.cands]

    @property
    def key(self) -> frozenset:
        return _key(self.cands)

    @property
    def n_coef(self) -> int:
        return sum(c.q for c in self.cands)


def _loo(X: np.ndarray, w: np.ndarray, Y: np.ndarray):
    """Weighted least squares of the columns of Y (3N, k) on X: (coefficients, inverse normal
    matrix, residuals, leave-one-out residuals, rank)."""
    Xw = X * w[:, None]
    Ai = np.linalg.pinv(X.T @ Xw, rcond=1e-12, hermitian=True)
    # the products with the draws by einsum, not BLAS: on a busy 2-core machine a threaded
    # BLAS took 17 ms for one (90 x 15)' (90 x 2001) product, einsum 0.9 ms
    beta = np.einsum("kl,lm->km", Ai, np.einsum("nk,nm->km", Xw, Y))
    r = Y - np.einsum("nk,km->nm", X, beta)
    h = np.einsum("nk,kl,nl->n", X, Ai, Xw)
    rank = int(np.linalg.matrix_rank(X * np.sqrt(w)[:, None]))
    return beta, Ai, r, r / np.maximum(1 - h, 1e-3)[:, None], rank


class GyroSearch(MemberTests):
    """The models of one gyro diagnosis, fitted on demand and cached."""

    def __init__(self, b, cols: Dict[int, np.ndarray], rng, level: float):
        self.b, self.cols, self.level = b, cols, level
        # the data, then the noise draws (3N, 1 + sims)
        self.Y = np.column_stack([b.y, (rng.normal(size=(HELDOUT_SIMS, len(b.y))) * np.sqrt(b.var)).T])
        self.cache: Dict[frozenset, Optional[GyroFit]] = {}

    def fit(self, cands: Sequence) -> Optional[GyroFit]:
        key = _key(cands)
        if key not in self.cache:
            self.cache[key] = self._fit(tuple(cands))
        return self.cache[key]

    def _fit(self, cands) -> Optional[GyroFit]:
        b = self.b
        X = np.hstack([b.X0] + [self.cols[id(c)] for c in cands])
        beta, Ai, r, e, rank = _loo(X, b.w, self.Y)
        dof = len(b.y) - rank
        if cands and dof < (MIN_DOF if len(cands) == 1 else SEARCH_MIN_DOF):
            return None
        r0, e0 = r[:, 0], e[:, 0]
        chi2 = float(np.sum(b.w * r0 * r0))
        cov = Ai * max(1.0, chi2 / max(dof, 1))
        m = GyroFit(tuple(cands), beta[:, 0], cov, r0, e0, chi2, float(dof),
                    float(np.sqrt(np.mean(e0 ** 2))), np.sqrt(np.mean(e[:, 1:] ** 2, axis=0)))
        o = b.X0.shape[1]
        # below MIN_DOF the excess scale (chi2 / dof) is a rough estimate: each member's Wald
        # statistic against F(rank, dof), as on the norm path (gap/search.py Search._fit)
        short = dof < MIN_DOF and chi2 > dof
        for c in cands:
            Ca, za = cov[o:o + c.q, o:o + c.q], m.beta[o:o + c.q]
            m.member_p[c.name] = scaled_wald_p(za, Ca, int(dof) if short else None)
            o += c.q
        return m

    def without(self, m: GyroFit, name: str) -> Optional[GyroFit]:
        return self.fit([c for c in m.cands if c.name != name])

    def heldout_p(self, small: GyroFit, big: GyroFit) -> float:
        """One-sided Monte Carlo p-value of the floored held-out ratio falling from ``small``
        to ``big`` by as much as it does when what ``big`` adds is absent."""
        obs = small.excess - big.excess
        g = np.maximum(small.sim_rms / small.twin, 1.0) - np.maximum(big.sim_rms / big.twin, 1.0)
        return float((1 + np.sum(g >= obs)) / (1 + len(g)))


def _add_moves(s: GyroSearch, cur: GyroFit, base: GyroFit, variants: Dict[str, list], visited) -> list:
    """Forward: a class not in the model, in any of its variants, with every variant of the
    members already in (a member's best variant alone can be the wrong one beside a second)."""
    moves = []
    if len(cur.cands) >= MAX_MEMBERS:
        return moves
    kept = [()]
    for c in cur.cands:
        kept = [k + (v,) for k in kept for v in variants[c.name]]
    for cls in variants:
        if cls in cur.names:
            continue
        for cands in (k + (c,) for k in kept for c in variants[cls]):
            m = s.fit(cands)
            if m is None or m.key in visited or not m.excess < cur.excess:
                continue
            if not cur.cands and not m.rms < base.rms:
                continue            # the first effect must predict the held-out poses better
            pc = m.member_p[cls]
            if pc >= s.level:
                continue
            pho = s.heldout_p(s.without(m, cls), m)
            if s.passes(pc, pho):
                moves.append((m, f"add {cls} ({cands[-1].q} coefficients)"
                              + "".join(f"; {c.name} {c.q}" for c in cands[:-1] if c not in cur.cands), pc, pho))
    return moves


def _variant_moves(s: GyroSearch, cur: GyroFit, variants: Dict[str, list], visited) -> list:
    """Another variant of a member, every member still passing."""
    moves = []
    for c in cur.cands:
        for v in variants[c.name]:
            if v is c:
                continue
            m = s.fit(tuple(v if x is c else x for x in cur.cands))
            if m is None or m.key in visited or not m.excess < cur.excess:
                continue
            if all(s.passes(*t) for t in s.tests(m).values()):
                moves.append((m, f"{c.name}: {c.q} -> {v.q} coefficients", m.member_p[c.name], None))
    return moves


def _path(s: GyroSearch, base: GyroFit, variants: Dict[str, list]) -> Tuple[GyroFit, list]:
    """Forward and backward steps from the baseline until no move passes."""
    cur, steps, visited = base, [], {base.key}
    for _ in range(MAX_STEPS):
        moves = _add_moves(s, cur, base, variants, visited) + _variant_moves(s, cur, variants, visited)
        if not moves:
            break
        # the simplest move that closes the gap (fewest coefficients, then fewest effects: on a
        # warm-up a curved thermal bias and a linear one plus a drift both close with 6), else
        # the one leaving least to explain
        cur = take_move(s, min(moves, key=lambda t: (not t[0].closed, t[0].n_coef if t[0].closed else 0,
                                                     len(t[0].cands) if t[0].closed else 0,
                                                     t[0].excess, t[0].n_coef)), steps, visited)
    return cur, steps


def _members(s: GyroSearch, m: GyroFit) -> List[dict]:
    """Each named member's coefficients (g-sensitivity as its 9 matrix elements; a curved
    thermal bias under two keys), standard errors and both tests' p-values."""
    out = []
    t = s.tests(m) if m.cands else {}
    o = s.b.X0.shape[1]
    for c in m.cands:
        B = TRACELESS if c.name == "g_sensitivity" else np.eye(c.q)
        z, C = B @ m.beta[o:o + c.q], B @ m.cov[o:o + c.q, o:o + c.q] @ B.T
        sd = np.sqrt(np.clip(np.diag(C), 0, None))
        ent = {"name": c.name, "coefficients": c.q, "coefficient_p_value": t[c.name][0],
               "heldout_p_value": t[c.name][1], "params": {}, "stderr": {}}
        oo = 0
        for u, k in (c.parts or [(c.units, len(z))]):
            ent["params"][f"{c.name}_{u}"] = z[oo:oo + k].tolist()
            ent["stderr"][f"{c.name}_{u}"] = sd[oo:oo + k].tolist()
            oo += k
        out.append(ent)
        o += c.q
    return out


def gyro_stepwise(b, cands: Sequence, ctx, rng) -> Dict[str, object]:
    """Forward and backward over the gyro candidates ``cands`` (the visible ones, not skipped;
    a thermal bias brings its curved variant THERMAL_CURVED along) from the baseline ``b``
    (linear.GyroBaseline): {"model", "base", "members", "steps", "models_fitted",
    "coefficient_level"}."""
    variants: Dict[str, list] = {}
    for c in cands:
        variants.setdefault(c.name, []).append(c)
    if "thermal_bias" in variants and np.ptp(np.asarray(ctx["dT"], float)) > 0:
        variants["thermal_bias"].append(THERMAL_CURVED)
    cols = {id(c): c.columns(ctx) for v in variants.values() for c in v}
    s = GyroSearch(b, cols, rng, coef_level({k: len(v) for k, v in variants.items()}))
    base = s.fit(())
    cur, steps = _path(s, base, variants)
    return {"model": cur, "base": base, "members": _members(s, cur), "steps": steps,
            "models_fitted": len(s.cache), "coefficient_level": s.level}
