"""The one verdict of the gap diagnosis, shared by the norm (accelerometer,
magnetometer) and the linear (gyro) paths.

A gap is *significant* when the chi-square test rejects the noise model and the
held-out ratio lies above what the twin produces in 99 % of its re-simulations.
Then the significant candidate with the lowest ratio after modelling is chosen
(plus a second one when the path offers it and it still explains a significant
part); the verdict is that effect when the ratio after falls to ``RATIO_OK``, or
when it removes at least half of the excess (then ``partially_explained``), else
``unexplained``.  Candidates whose projected signatures coincide with a chosen
one (canonical correlation > 0.98) are reported as confusable, with the
recording that would separate them.
"""
from __future__ import annotations

from typing import Callable, Dict, List, Optional

import numpy as np

from .candidates import SEPARATE
from .signif import canon

__all__ = ["ALPHA", "RATIO_OK", "decide"]

ALPHA = 0.01
RATIO_OK = 1.3          # a ratio after modelling above this is not "closed"
CONFUSABLE_CC = 0.98    # canonical correlation above which two signatures look alike


def decide(out: Dict[str, object], ratio: float, significant: bool, effects: List[dict],
           signatures: Dict[str, np.ndarray],
           second: Optional[Callable[[str], Optional[dict]]] = None) -> List[str]:
    """Write ``verdict``, ``ratio_after`` (and ``shrink``, ``partially_explained``,
    ``joint``, ``confusable``, ``note``) into ``out``; return the chosen effects.

    ``effects``: the tested candidates' entries (``name``, ``significant``,
    ``ratio_after``); ``signatures``: projected signature by name, for the visible
    candidates; ``second(best)``: the joint fit of ``best`` with the best second
    effect (a dict with ``effects`` and ``ratio_after``), or None when none helps."""
    sig = [ef for ef in effects if ef.get("significant")]
    verdict, ratio_after, chosen = "none", ratio, []
    if significant and sig:
        best = min(sig, key=lambda ef: ef["ratio_after"])
        chosen, ratio_after = [best["name"]], best["ratio_after"]
        joint = second(best["name"]) if second is not None else None
        if joint is not None:
            out["joint"] = joint
            chosen, ratio_after = list(joint["effects"]), joint["ratio_after"]
        shrink = (ratio - ratio_after) / max(ratio - 1.0, 1e-9)
        out["shrink"] = float(shrink)
        if ratio_after <= RATIO_OK:
            verdict = "+".join(chosen)
        elif shrink >= 0.5:
            verdict = "+".join(chosen)
            out["partially_explained"] = True
        else:
            verdict = "unexplained"
    elif significant:
        verdict = "unexplained"
    elif ratio > float(out["twin_ratio_q99"]) * 1.05:
        # not significant by chi-square, yet the held-out ratio is out of the twin's range
        out["note"] = "held-out ratio above the twin's 99th percentile but chi-square not significant"
    out["verdict"] = verdict
    out["ratio_after"] = float(ratio_after)
    confused = []
    for n in chosen:
        for o, Ct in signatures.items():
            if o == n or o in chosen:
                continue
            cc = canon(signatures[n], Ct)
            if cc > CONFUSABLE_CC:
                confused.append({"effects": sorted([n, o]), "canonical_correlation": round(cc, 4),
                                 "to_separate": SEPARATE.get(frozenset({n, o}), "a more varied recording")})
    if confused:
        out["confusable"] = confused
    return chosen
