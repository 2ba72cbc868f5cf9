"""The still intervals the thermal terms are learnt from.

The pose accumulator keeps one pose per direction (a newer one replaces an older one
nearby, so its temperatures are the latest); the thermal terms need the same
orientations at *different* temperatures.  This log keeps every still interval the
detector closes (accelerometer mean and covariance, gyro mean and its variance,
temperature), bounded: when full, the oldest interval of the most crowded cell of
(1 degC of temperature) x (the 26 cube directions, fitting/judging/coverage.py) goes, so a board
that sits still for hours at one temperature does not push out the rest of the range.
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional

import numpy as np

from ..fitting.stillness.poses import PoseSet
from ..fitting.stillness.detector import StaticInterval

__all__ = ["ThermalLog", "MAX_INTERVALS", "thermal_status"]

MAX_INTERVALS = 300
_CUBE = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                  if (x, y, z) != (0, 0, 0)], float)
_CUBE /= np.linalg.norm(_CUBE, axis=1, keepdims=True)


class ThermalLog:
    def __init__(self, max_intervals: int = MAX_INTERVALS):
        self.max = int(max_intervals)
        self.items: List[StaticInterval] = []
        self.seen = 0               #: intervals offered since start
        self._span_c = 0.0          #: max - min temperature of items, kept by add/load

    def __len__(self) -> int:
        return len(self.items)

    def add(self, iv: StaticInterval) -> bool:
        """Keep ``iv`` if it is a still pose under 1 g with a known temperature."""
        self.seen += 1
        norm = float(np.linalg.norm(iv.acc))
        if not np.isfinite(iv.temp) or not 0.5 < norm < 1.5:
            return False
        if len(self.items) >= self.max:
            keys = [self._key(p) for p in self.items]
            uniq, inv, counts = np.unique(np.array(keys), axis=0, return_inverse=True, return_counts=True)
            crowded = int(np.argmax(counts))
            j = int(np.flatnonzero(np.asarray(inv).ravel() == crowded)[0])    # the oldest there
            del self.items[j]
        self.items.append(iv)
        self._respan()
        return True

    def _respan(self) -> None:
        t = [p.temp for p in self.items]
        self._span_c = float(max(t) - min(t)) if t else 0.0

    @staticmethod
    def _key(p: StaticInterval):
        return (int(np.floor(p.temp)), int(np.argmax(_CUBE @ (p.acc / np.linalg.norm(p.acc)))))

    def span_c(self) -> float:
        """Temperature span of the log, degC (the pipeline asks once per batch: kept, not
        recomputed over up to MAX_INTERVALS items each time)."""
        return self._span_c

    def pose_set(self) -> PoseSet:
        """The log as a pose set (the state directory's thermal.csv)."""
        P = self.items
        N = len(P)
        has_g = N > 0 and all(p.gyro is not None and p.gyro_cov is not None for p in P)
        return PoseSet(acc=np.array([p.acc for p in P]).reshape(N, 3),
                       acc_cov=np.array([p.acc_cov for p in P]).reshape(N, 3, 3),
                       n=np.array([p.n for p in P], int), t0=np.array([p.t0 for p in P], float),
                       t1=np.array([p.t1 for p in P], float),
                       acc_sample_cov=np.array([p.acc_sample_cov for p in P]).reshape(N, 3, 3),
                       gyro=np.array([p.gyro for p in P]) if has_g else None,
                       gyro_cov=np.array([p.gyro_cov for p in P]) if has_g else None,
                       temp=np.array([p.temp for p in P], float))

    def load(self, ps: PoseSet) -> None:
        """Resume from a saved log (the poses whose temperature is known)."""
        self.items = []
        for i in range(len(ps)):
            if ps.temp is None or not np.isfinite(ps.temp[i]):
                continue
            self.items.append(StaticInterval(
                ps.acc[i], ps.acc_cov[i], ps.acc_sample_cov[i], int(ps.n[i]), float(ps.t0[i]),
                float(ps.t1[i]), float(ps.temp[i]), None if ps.gyro is None else ps.gyro[i],
                None if ps.gyro_cov is None else ps.gyro_cov[i]))
        self.items = self.items[-self.max:]
        self._respan()

    def arrays(self) -> Optional[Dict[str, np.ndarray]]:
        """The job's ``thermal`` data: acc (N, 3) g, acc_cov (N, 3, 3), gyro (N, 3) deg/s or
        None, gyro_var (N, 3), n (N,), temp (N,) degC, t0 (N,) s."""
        P = self.items
        if not P:
            return None
        has_g = all(p.gyro is not None and p.gyro_cov is not None for p in P)
        return {"acc": np.array([p.acc for p in P]), "acc_cov": np.array([p.acc_cov for p in P]),
                "gyro": np.array([p.gyro for p in P]) if has_g else None,
                "gyro_var": np.array([np.diag(p.gyro_cov) for p in P]) if has_g else None,
                "n": np.array([p.n for p in P], int), "temp": np.array([p.temp for p in P]),
                "t0": np.array([p.t0 for p in P])}


def thermal_status(log: "ThermalLog", applied, notes: Dict[str, Dict[str, Any]],
                   need: float) -> Dict[str, Any]:
    """The thermal terms: the log's span against the minimum, and per sensor the terms in
    force (order, range, why) or why there are none."""
    span = log.span_c()
    d: Dict[str, Any] = {"intervals": len(log), "span_c": round(span, 2),
                         "min_span_c": need}
    if span < need:
        d["why"] = (f"temperature span {span:.1f} degC < {need:g} degC "
                    f"(calibration.thermal_min_span_c): constant only")
    for s in ("accel", "gyro", "mag"):
        p = applied.part(s)
        th = p.thermal if p is not None else None
        if th:
            d[s] = {"order": th["order"], "t_min_c": th["t_min_c"], "t_max_c": th["t_max_c"],
                    "note": th.get("note", "")}
        elif s in notes:
            e = notes[s]
            d[s] = {"order": 0, "note": e["note"] + ("" if e.get("accepted", True) or "p_value" not in e
                                                      else f"; not applied (gate p = {e['p_value']:.2g})")}
    return d
