"""Repeated samples: sample-and-hold, duplicated rows and duplicated timestamps.  Pure numpy.

Real loggers often read a sensor faster than it updates (an FXOS8700 at ~100 Hz read at
400 Hz: 74 % of the rows repeat the previous one), or write every row twice.  Repeated
rows are not new measurements: counted as samples they shrink every standard error by
sqrt(hold), make the noise look smaller than it is, and a detector that expects ``rate``
independent samples a second cuts poses short.  Every user of still samples
(:class:`imucald.fitting.stillness.detector.StillnessDetector`, hence ``calibrate``, ``replay``,
``gap`` and the daemon; ``noise``) therefore works on the *distinct* samples at their
*effective rate*.

Which rows are repeats (:func:`find_repeats`):

* a row whose timestamp and sensor values both equal the previous row's is a duplicated
  row, always dropped;
* a row whose sensor values (the three axes of the group tested: the accelerometer, or the
  magnetometer of a magnetometer-only file) equal the previous row's is a *held* sample
  when such rows are more frequent than chance says.  Quantised low-noise data repeat by
  chance (an ADXL345 at 3.9 mg/LSB with ~2 mg noise repeats one axis in two): under
  independence of the axes the chance of a whole-row repeat is the product of the per-axis
  repeat rates, estimated from the rows that are not whole-row repeats and solved for the
  unconditional rates (:func:`chance_repeats`).  The rows are held when the count exceeds
  ``HOLD_RATIO`` (2) x that expectation plus 5 of its Poisson standard deviations plus 3
  (measured: 0 of 40 seeded simulated ADXL345/MPU-6050 sessions without hold are called
  held; 40 of 40 held 2-4x are, bench/stillness_rates.py).
* duplicated timestamps are counted (a one-line warning names the count); a row with a
  repeated timestamp but new values is kept.

Effective rate (imucald.numerics.rates ``effective_rate``): the distinct samples per second of recording,
pauses excluded (an interval longer than 20 x the mean interval is a pause: the logger
stopped, nothing was sampled); 74 % held rows at 400 Hz give ~104 Hz.  It replaces the
nominal rate when rows are dropped, or when the nominal rate (a file's ``rate_hz`` or
1 / median interval, which burst timestamps fool: a logger writing ~99 rows a second in
bursts 2 ms apart) differs from it by more than ``RATE_MISMATCH`` (25 %).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ...numerics.npstats import median, row_all, row_prod
from ...numerics.rates import effective_rate

__all__ = ["Repeats", "find_repeats", "chance_repeats", "repeat_flags", "duplicated_rows",
           "HOLD_RATIO", "RATE_MISMATCH"]

HOLD_RATIO = 2.0
RATE_MISMATCH = 0.25
#: rows over which the axes' chance repeat rates are measured (chance_repeats)
CHANCE_WINDOW = 64


@dataclass(eq=False)
class Repeats:
    """What :func:`find_repeats` found in n rows."""

    keep: np.ndarray            #: (n,) bool: the distinct samples
    held: bool                  #: whole-row repeats beyond chance: dropped as held samples
    repeated: int               #: rows dropped (held samples and duplicated rows)
    duplicated_t: int           #: rows whose timestamp equals the previous row's
    duplicated_rows: int        #: of those, rows whose values are the previous row's too
    chance: float               #: whole-row repeats expected by chance (independent axes)
    rate_hz: float              #: effective rate of the distinct samples, Hz
    nominal_hz: float           #: the rate given (or 1 / median interval)

    @property
    def hold_factor(self) -> float:
        """Rows per distinct sample (1: none repeated)."""
        n = len(self.keep)
        return n / max(int(self.keep.sum()), 1)

    @property
    def rate_changed(self) -> bool:
        if not (self.rate_hz > 0 and self.nominal_hz > 0):
            return False                    # timestamps that do not advance: the rate given stays
        return self.repeated > 0 or abs(self.rate_hz / self.nominal_hz - 1) > RATE_MISMATCH

    def summary(self) -> str:
        """One line for the user ('' when nothing is repeated and the rate is as given)."""
        parts = []
        if self.duplicated_t:
            parts.append(f"{self.duplicated_t} rows repeat the previous row's timestamp"
                         + (f" ({self.duplicated_rows} of them its values too: duplicated rows, dropped)"
                            if self.duplicated_rows else " with new values (a FIFO's bursts stamped with "
                                                         "their read time?): kept"))
        if self.held:
            parts.append(f"{self.repeated - self.duplicated_rows} rows repeat the previous sample "
                         f"(sample-and-hold, {self.hold_factor:.2f} rows per distinct sample; "
                         f"{self.chance:.0f} expected by chance): dropped")
        if self.rate_changed:
            parts.append(f"effective rate {self.rate_hz:.4g} Hz of distinct samples "
                         f"(nominal {self.nominal_hz:.4g} Hz)")
        return "; ".join(parts)


def repeat_flags(t: np.ndarray, x: np.ndarray):
    """(whole-row repeat of the previous row (n,), timestamp repeat (n,), per-axis repeat (n, c)),
    row 0 never a repeat."""
    x = np.asarray(x)
    n = len(x)
    eq = np.zeros((n,) + x.shape[1:], bool)
    if n > 1:
        eq[1:] = x[1:] == x[:-1]
    full = row_all(eq.reshape(n, -1)) if n else np.zeros(0, bool)
    tt = np.zeros(n, bool)
    if n > 1 and t is not None:
        t = np.asarray(t, float)
        tt[1:] = t[1:] == t[:-1]
    return full, tt, eq.reshape(n, -1)


def duplicated_rows(t: np.ndarray, groups, prev=None) -> np.ndarray:
    """(n,) bool: rows whose timestamp and every value of ``groups`` (arrays (n, k) or None)
    equal the previous row's: a logger that wrote a row twice.  ``prev``: a dict that carries
    the last row from batch to batch (keys 't' and 'x', set here; start with {}), or None, when
    row 0 is never a repeat.  A repeated timestamp with new values (a FIFO's burst stamped with
    its read time) is not one."""
    cols = [np.asarray(g, float) for g in groups if g is not None]
    if not cols:
        return np.zeros(len(t), bool)
    x = np.column_stack(cols)
    full, tt, _ = repeat_flags(t, x)
    dup = full & tt
    if isinstance(prev, dict):
        if len(t) and prev.get("t") is not None:
            dup[0] = bool(t[0] == prev["t"] and np.array_equal(x[0], prev["x"]))
        if len(t):
            prev["t"], prev["x"] = t[-1], x[-1].copy()
    return dup


def chance_repeats(full: np.ndarray, eq: np.ndarray, window: int = CHANCE_WINDOW) -> float:
    """Whole-row repeats expected among the rows if the axes repeated independently at
    their own rates (the rates estimated from the rows that are not whole-row repeats,
    then solved for the unconditional ones: p = p'(1 - P) + P, P = prod p).

    The rates are local (over ``window`` rows around each row): a recording alternates
    still poses (a quantised low-noise axis repeats often) and turns (it never repeats), and
    the product of whole-recording rates understates the chance of a whole-row repeat (the
    axes repeat *together* when still).  Measured: an un-dithered ADXL345 (3.9 mg LSB,
    noise 0.1-0.45 LSB) at 25-50 Hz was called held in 4 of 10 sessions with whole-recording
    rates, and its dropped rows biased every pose mean (a pose near the middle of an LSB
    loses the samples at that level)."""
    m = len(full) - 1
    if m <= 0:
        return 0.0
    rest = ~full[1:]
    if not rest.any():
        return float(m)
    w = int(min(max(window, 1), m))
    a, b = (w - 1) // 2 + 1, w // 2       # row i sums rows max(0, i - b) .. min(m, i + a) - 1

    def msum(v):            # centred moving sum over w rows (np.convolve 'same', in O(m))
        c = np.zeros(m + 1, np.int64)
        np.cumsum(v, out=c[1:])
        out = np.empty(m, np.int64)
        out[:m - a + 1] = c[a:]           # c[min(m, i + a)]
        out[m - a + 1:] = c[m]
        out[b:] -= c[:m - b]              # - c[max(0, i - b)] (c[0] = 0)
        return out
    # local counts; rows with no non-repeated neighbour in the window fall back to the
    # whole-recording rates
    cnt = msum(rest)
    C = eq.shape[1]
    glob = np.array([np.count_nonzero(eq[1:, j] & rest) for j in range(C)]) / int(rest.sum())
    num = [msum(eq[1:, j] & rest) for j in range(C)]
    # a row's rates are a function of its counts (cnt, num), which take few distinct values
    # (3851 of 51174 rows on the Xsens file): the fixed point runs once per distinct row
    # (each row's iteration is its own; the stopping test, the largest step over the rows,
    # is the same over the distinct ones), and the sum is over every row as before
    first, inv = _distinct_rows(cnt, num, w)
    cnt_u = cnt[first].astype(float)
    pc = np.empty((len(first), C))
    for j in range(C):
        pc[:, j] = np.where(cnt_u > 0, num[j][first].astype(float) / np.maximum(cnt_u, 1.0), glob[j])
    return float(np.sum(row_prod(unconditional_rates(pc))[inv]))


def unconditional_rates(pc: np.ndarray) -> np.ndarray:
    """Per-row, per-axis chance that a sample repeats its predecessor, from the rates ``pc``
    seen among rows that are not full repeats: the fixed point of p = pc (1 - P) + P, P the
    row's product of p (a full repeat repeats every axis), iterated on each row until the
    largest step is under 1e-12 (at most 50 times)."""
    p = pc.copy()
    for _ in range(50):
        P = row_prod(p)[:, None]
        p_new = pc * (1 - P) + P
        done = np.max(np.abs(p_new - p)) < 1e-12
        p = p_new
        if done:
            break
    return p


def _distinct_rows(cnt: np.ndarray, num, w: int):
    """(index of one occurrence of each distinct row, each row's distinct-row number) of the
    integer rows (cnt, num[0], num[1], ...), entries in 0..w: equal neighbours first (runs:
    cheap, and most repeats are neighbours), then the distinct run values, grouped by an
    unstable sort (which occurrence stands for a row does not matter: equal rows have equal
    counts, so equal rates; ~5x faster than the stable sort np.unique(return_index) needs)."""
    base = w + 1
    if base ** (len(num) + 1) >= 2 ** 62:
        _, first, inv = np.unique(np.column_stack([cnt, *num]), axis=0, return_index=True,
                                  return_inverse=True)
        return first, inv.ravel()
    key = cnt.astype(np.int64)
    for v in num:
        key = key * base + v
    starts = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
    ks = key[starts]
    perm = ks.argsort()
    srt = ks[perm]
    new = np.empty(len(srt), bool)
    new[:1] = True
    np.not_equal(srt[1:], srt[:-1], out=new[1:])
    inv_run = np.empty(len(ks), np.intp)
    inv_run[perm] = np.cumsum(new) - 1
    return starts[perm[new]], np.repeat(inv_run, np.diff(np.append(starts, len(key))))


def find_repeats(t: np.ndarray, x: np.ndarray, rate_hz: Optional[float] = None) -> Repeats:
    """Repeated rows of x (n, c) with timestamps t (see the module docstring)."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    full, tt, eq = repeat_flags(t, x)
    dup_rows = full & tt
    # the hold test on the rows that are not duplicated rows (those are dropped anyway)
    rows = ~dup_rows
    chance = chance_repeats(full[rows], eq[rows])
    R = int((full & ~tt).sum())
    held = R > HOLD_RATIO * chance + 5.0 * np.sqrt(chance) + 3.0
    drop = full if held else dup_rows
    keep = ~drop
    d = np.diff(t)
    nominal = float(rate_hz) if rate_hz else (1.0 / float(median(d[d > 0])) if (d > 0).any() else 0.0)
    eff = effective_rate(t, keep)
    dropped = int(drop.sum())
    rate = nominal
    if eff > 0 and (dropped or (nominal > 0 and abs(eff / nominal - 1) > RATE_MISMATCH) or nominal <= 0):
        rate = eff
    if not rate > 0:            # timestamps that never advance: no rate to be had (as before: 1e9)
        rate = 1e9
    return Repeats(keep, bool(held), dropped, int(tt.sum()), int(dup_rows.sum()), chance,
                   float(rate), float(nominal if nominal > 0 else rate))
