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

The choice is the combination search's (gap/search.py for the accelerometer and
magnetometer, gap/gyrosearch.py for the gyro; gap/series.py for the time-series path).
Candidates whose projected signatures coincide with
a chosen one (canonical correlation > 0.98) are reported as confusable, with the
recording that would separate them.
"""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence

import numpy as np

from .candidates import SEPARATE
from .signif import canon

__all__ = ["verdict", "no_gap", "confusable"]

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
