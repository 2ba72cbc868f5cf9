"""The one verdict of the gap diagnosis, for every sensor and path (the norm path of
the accelerometer and magnetometer, the gyro's linear path, the time-series path).

Wording from ../shared/reference/error-models.md section 5 (shrink S on held-out
data, S = (ratio before - ratio after) / (ratio before - 1); "the tool must flag
S < 0.5 as partially explained"):

* ``none``: no gap (the chi-square test does not reject the noise model, or the
  held-out ratio lies within the twin's 99th percentile);
* the effect name(s), joined by ``+``: a gap, and the chosen effect(s) close it
  (held-out ratio within the augmented model's own twin: ``explained: "closed"``)
  or close at least half of it (S >= 0.5, ``explained: "mostly"``);
* ``partially_explained``: a gap, and the best effect(s) close less than half of
  it (S < 0.5); ``partially_explained_by`` names them;
* ``unexplained``: a gap, and no candidate passes its tests (coefficients significant by a
  Wald test as well as the score and nested tests), or the best closes less than
  ``PARTIAL_MIN`` (0.2) of it (``closest_form`` then names it, for the record).

The choice (:func:`decide`): among the significant parametric candidates, the simplest
(fewest parameters) that closes the gap; when none closes it, the one that closes most,
and then a second effect (forward step from each of the three best singles) only if it
passes the same tests against the twin of the model that already holds the first.  A
stochastic form (the random-walk wandering bias, gap/wander.py) is chosen only when the
parametric choice leaves a gap and the walk's likelihood gain less Akaike's penalty beats
the parametric choice's.  Candidates whose projected signatures coincide with
a chosen one (canonical correlation > 0.98) are reported as confusable, with the
recording that would separate them.
"""
from __future__ import annotations

from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from .candidates import SEPARATE
from ..fitting.judging.levels import GAP_ATTRIBUTION_LEVEL
from .signif import canon

__all__ = ["decide", "verdict", "confusable"]

#: below this held-out shrink nothing is named, not even partially (issue 25 item 4)
PARTIAL_MIN = 0.2
CONFUSABLE_CC = 0.98    # canonical correlation above which two signatures look alike


def verdict(gap: bool, chosen: Sequence[str], ratio_before: float, ratio_after: float,
            closed: Optional[bool]) -> Dict[str, object]:
    """The rule of the module doc: {"verdict", "shrink"?, "explained"?, "partially_explained_by"?}."""
    if not gap:
        return {"verdict": "none"}
    if not chosen:
        return {"verdict": "unexplained"}
    shrink = (ratio_before - ratio_after) / max(ratio_before - 1.0, 1e-9)
    name = "+".join(chosen)
    if closed:
        return {"verdict": name, "shrink": float(shrink), "explained": "closed"}
    if shrink >= 0.5:
        return {"verdict": name, "shrink": float(shrink), "explained": "mostly"}
    if shrink < PARTIAL_MIN:
        # attribution discipline: a shrink this small names nothing (the bench's out-of-library
        # forms land here); the closest form is kept for the record
        return {"verdict": "unexplained", "shrink": float(shrink), "closest_form": name}
    return {"verdict": "partially_explained", "shrink": float(shrink), "explained": "partially",
            "partially_explained_by": name}


def no_gap(out: Dict[str, object], ratio: float) -> None:
    """The verdict when the baseline's chi-square finds no gap, written into ``out`` (with a
    note when the held-out ratio alone is above the twin's 99th percentile)."""
    out.update(verdict(False, [], ratio, ratio, None))
    out["ratio_after"] = float(ratio)
    if ratio > float(out["twin_ratio_q99"]) * 1.05:
        out["note"] = "held-out ratio above the twin's 99th percentile but chi-square not significant"


def confusable(chosen: Sequence[str], signatures: Dict[str, np.ndarray]) -> List[dict]:
    """Candidates whose projected signatures coincide with a chosen one (canonical
    correlation above CONFUSABLE_CC), with the recording that would separate them."""
    confused = []
    for n in chosen:
        for o, Ct in signatures.items():
            if o == n or o in chosen or n not in signatures:
                continue
            cc = canon(signatures[n], Ct)
            if cc > CONFUSABLE_CC:
                confused.append({"effects": sorted([n, o]), "canonical_correlation": round(cc, 4),
                                 "to_separate": SEPARATE.get(frozenset({n, o}), "a more varied recording")})
    return confused


def decide(out: Dict[str, object], ratio: float, significant: bool, effects: List[dict],
           signatures: Dict[str, np.ndarray],
           second: Optional[Callable[[str], Optional[dict]]] = None) -> List[str]:
    """Write ``verdict``, ``ratio_after`` (and ``shrink``, ``explained``, ``joint``,
    ``confusable``, ``note``) into ``out``; return the chosen effects.

    ``effects``: the tested candidates' entries (``name``, ``significant``, ``q``,
    ``closed``, ``ratio_after``); ``signatures``: projected signature by name;
    ``second(best)``: the joint fit of ``best`` with the best second effect (a dict
    with ``effects``, ``ratio_after``, ``closed``), or None when none passes."""
    allsig = [ef for ef in effects if ef.get("significant")]
    # a stochastic form (the random-walk wandering bias) can follow anything smooth in time;
    # it is chosen only when no parametric effect or pair does as well (below)
    sig = [ef for ef in allsig if not ef.get("stochastic")]
    stoch = [ef for ef in allsig if ef.get("stochastic")]
    ratio_after, chosen, closed = ratio, [], None
    if significant and sig:
        closing = [ef for ef in sig if ef.get("closed")]
        best = (min(closing, key=lambda ef: (ef["q"], ef["ratio_after"])) if closing
                else min(sig, key=lambda ef: ef["ratio_after"]))
        chosen, ratio_after, closed = [best["name"]], best["ratio_after"], bool(best.get("closed"))
        joint = None
        if second is not None and not closed:
            # forward step from each of the three best single effects (a pair's members can
            # each lose to a third form alone, e.g. a wandering bias soaking up part of a
            # nonlinearity + thermal pair): the pair with the lowest held-out ratio is kept
            firsts = sorted(sig, key=lambda ef: ef["ratio_after"])[:3]
            if best not in firsts:
                firsts.insert(0, best)
            for f in firsts:
                j = second(f["name"])
                if j is not None and (joint is None or j["ratio_after"] < joint["ratio_after"]):
                    joint = j
            if joint is not None and joint["ratio_after"] >= ratio_after:
                joint = None
        if joint is not None:
            out["joint"] = joint
            chosen, ratio_after, closed = list(joint["effects"]), joint["ratio_after"], joint["closed"]
    if significant and stoch and not closed:
        # the parametric choice leaves a gap: the random walk when its likelihood gain, less
        # Akaike's penalty (one variance parameter), beats the parametric choice's (its
        # held-out "closure" alone is too easy: a strong walk predicts any misfit)
        s_ = min(stoch, key=lambda ef: ef["ratio_after"])
        par = out.get("joint") or (best if chosen else None)
        aic_par = (par["lr"] - 2 * par["q"]) if par is not None and "lr" in par else 0.0
        if s_["lr"] - 2.0 > aic_par:
            out["parametric_choice"] = {"effects": list(chosen), "ratio_after": float(ratio_after),
                                        "aic_gain": float(aic_par), "random_walk_aic_gain": float(s_["lr"] - 2.0)}
            out.pop("joint", None)
            chosen, ratio_after, closed = [s_["name"]], s_["ratio_after"], bool(s_.get("closed"))
    elif not significant and ratio > float(out["twin_ratio_q99"]) * 1.05:
        # not significant by chi-square, yet the held-out ratio is out of the twin's range
        out["note"] = "held-out ratio above the twin's 99th percentile but chi-square not significant"
    res = verdict(significant, chosen, ratio, ratio_after, closed)
    if res.get("explained") == "partially":
        # attribution discipline: a partial explanation is named only when the chosen
        # coefficients are significant by a Wald test too (covariance scaled by the excess
        # that remains), at the Bonferroni level of the candidate tests
        bonf = GAP_ATTRIBUTION_LEVEL / max(len(effects), 1)
        src = out.get("joint") or next((ef for ef in allsig if ef["name"] == chosen[0]), {})
        if src.get("wald_p_value", 0.0) >= bonf:
            res = {"verdict": "unexplained", "shrink": res["shrink"], "closest_form": "+".join(chosen),
                   "closest_form_wald_p_value": src.get("wald_p_value")}
    out.update(res)
    out["ratio_after"] = float(ratio_after)
    confused = confusable(chosen, signatures)
    if confused:
        out["confusable"] = confused
    return chosen
