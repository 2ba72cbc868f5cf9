"""Sample rates of timestamped rows (pure functions over numpy arrays): what the readers, the
stillness detector and the gyro's rotation windows count as samples per second."""
from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["effective_rate", "PAUSE_FACTOR"]

#: an interval longer than this many mean intervals is a pause (nothing sampled in it)
PAUSE_FACTOR = 20.0


def effective_rate(t: np.ndarray, keep: Optional[np.ndarray] = None) -> float:
    """Samples per second (of the rows ``keep`` marks, default all), pauses excluded: an
    interval longer than PAUSE_FACTOR x the mean interval is a pause, neither its time nor
    its sample counted.  Rows sharing a timestamp (a coarse clock) count as samples.
    0 when the timestamps do not advance."""
    t = np.asarray(t, float)
    if keep is not None:
        t = t[keep]
    d = np.diff(t)
    if not len(d) or not (d > 0).any():
        return 0.0
    # pauses are judged among the steps between distinct timestamps, each counting the rows
    # stamped at its end: a logger that stamps a FIFO's burst of 40 samples with one read
    # time has 39 zero steps a burst, and against their mean every burst's step was a pause
    # (none counted: 0 Hz, so 1 / the burst period, 10 Hz for 400 Hz of samples, was used)
    adv = np.flatnonzero(d > 0)
    dd = d[adv]
    rows = np.diff(np.concatenate([adv, [len(d)]]))     # rows stamped at each step's end
    ok = np.ones(len(dd), bool)
    for _ in range(5):
        m = float(dd[ok].sum()) / int(rows[ok].sum())
        ok2 = dd <= PAUSE_FACTOR * m * rows
        if (ok2 == ok).all():
            break
        ok = ok2
    span = float(dd[ok].sum())
    return int(rows[ok].sum()) / span if span > 0 else 0.0
