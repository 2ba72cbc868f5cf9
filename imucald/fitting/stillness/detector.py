"""The one stillness detector (streaming; the batch call in fitting.stillness.poses runs it over a whole file).

Defaults (``DEFAULTS``) and what they mean, documented once here and in the README:

* ``window_s`` = 1.0 s: trailing window of the moving statistics.
* ``k`` = 6: a window is quiet when the summed variance of the three accelerometer
  axes is at most ``k`` x the learnt floor.  Hand-held poses sit at 1.3-3.2x the floor
  (tremor) of a noisy chip (an MPU-6050's), and the floor itself is a low percentile of
  window variances (for 100 samples per window it is ~0.85x the mean still variance), so
  6 leaves margin.  A quiet chip's hand-held windows read 5-13x a floor learnt on a table:
  with a gyro a second track allows a hand's tremor on top (HAND_VAR_G2, :class:`_Track`,
  :meth:`_Core._resolve`).
* ``max_turn_deg`` = 3 deg: the most the board may turn within a pose (about gravity, see
  below).  A hand sways the
  board by 0.05-0.4 deg RMS per axis at 0.2-2 Hz as well as trembling (6-12 Hz, 1-3 deg/s
  RMS); such a hold turns by up to ~2.6 deg net within a 1-s window and its 1/4-window
  moving-mean orientation strays up to ~1.5 deg from its mean (bench/stillness_holds.py,
  800 holds).  So the gyro votes only on real rotation: a window's net turn,
  |mean rate - bias| x window_s, must stay within what the session's own quiet windows
  turn (TURN_SIGMAS x their rates' scatter, at least 0.5 deg, STRICT_TURN_DEG, at most
  ``max_turn_deg``; 0.5 deg while the bias is not trusted, below): a bench keeps the strict
  limit, a swaying hand gets its sway's; a whole still run is refused
  (kind "turn", :func:`_turned`) when its orientation (the moving means over a quarter
  window of the accelerometer's direction and of the bias-free gyro's integrated angle)
  leaves its mean by more than half ``max_turn_deg``: a slow turn grows without bound, a
  sway does not.  The gyro bias is tracked (BIAS_WINDOWS, BIAS_GATE_DPS): the mean of the mean
  rates of the last 8 still windows (accelerometer-quiet and within the turn limit of the
  bias in force) that read within 0.5 deg/s of the median of the latest 16 still ones (not
  of the bias in force, which a warming gyro leaves behind), so a drifting bias is followed
  and a turn, even one about gravity that the accelerometer cannot see, never becomes it;
  until 8 windows passed, the median of the quiet windows of the last minute, trusted only
  when they scatter (MAD) by at most 1 deg/s per axis (a sway scatters them ~0.6; a slow
  tumble, no still moment to learn a bias from, by several).  A turn slower than ~2.5
  deg/s lasting 1.5-2 s is what a sway makes too: it passes as a pose holding at most
  ``max_turn_deg`` of rotation (bench/stillness_holds.py: slow turns of 0.5-3 deg/s).
  The run-level gyro angle is taken less the run's mean residual rate up to 0.5 deg/s (the
  lag a warming gyro's tracked bias still has), so about gravity, where only the gyro sees a
  turn, a steady turn slower than 0.5 deg/s is not told from a bias and passes however far
  it goes within a pose (up to ~10 deg over ``max_pose_s``), as the per-window 0.5-deg test
  let it before this round; it moves the gyro's pose mean, not the accelerometer's.
* ``min_still_s`` = 1.0 s, ``trim_s`` = 0.25 s: a sample is still when some quiet
  window contains it, and two neighbouring still samples belong to one run only when some
  quiet window contains both and the quiet windows just before and just from the second
  agree in mean (within 5 sigma of two still means: 25 x 2 x k x floor / w summed over the
  axes), so an instant change of orientation between two quiet stretches (samples lost
  while the board turned, sessions appended, a board set down again a little differently)
  splits them (the step must exceed the noise plus half ``max_turn_deg``, what a hand's sway
  moves two 1-s means apart: :meth:`_Core._steps`); a run of still samples, cut ``trim_s`` at
  its start and (after the motion-onset cut: a 10-sample mean leaving the first half's mean
  by 5 sigma in magnitude, or on an axis by 5 sigma plus half ``max_turn_deg`` of tilt) at its
  end, is a pose when it lasts ``min_still_s``.  A 1.5 s
  hold therefore counts.  Runs longer than ``max_pose_s`` (20 s) are cut in several.

Noise floor: the ``FLOOR_PCT`` (5th) percentile of the accelerometer variances of the
last ``FLOOR_WINDOWS`` (300) non-overlapping windows.  No decision is taken before
``WARMUP_WINDOWS`` (8) windows are seen: the first samples wait and are judged with
the floor at that point, so a pose at the very start of a file counts.  A floor is
fixed once per window; every sample is judged by the floor of the windows before it,
so the result does not depend on how the stream is cut in batches.

Non-finite samples, and samples with any value beyond ``ABSURD`` (1e6: no IMU range
comes near), are never still and never averaged; they are counted in ``dropped``.

Distinct samples (issue 20): repeated rows (sample-and-hold, duplicated rows;
:mod:`imucald.fitting.stillness.repeats`) are dropped before anything above is computed, and ``rate``
is the effective rate of the distinct samples, so windows, the onset cut (which compares
a moving mean with sd / sqrt(10), i.e. assumes independent samples) and every pose's
covariance see independent samples.

Still in absolute terms (issue 20), :func:`still_limits`: the learnt floor is capped by
what the chip can show at rest (datasheet density, or a generic one, over the noise
bandwidth), so a recording without a still moment cannot learn its floor from motion; and
a run makes a pose only when it lasts ``min_still_s`` by its timestamps, holds
``MIN_EFFECTIVE`` (5) distinct samples, scatters no more than k x the cap and reads
|mean| within the chip's band around 1 g.  Runs that fail are kept in ``rejected`` with
the reason (``rejected_counts`` by kind: short, few, noise, norm, and turn: a slow turn,
:func:`_turned`, or with a magnetometer a field direction that turns within the stretch,
:func:`_mag_turn`).  Rates: bench/stillness_rates.py (docs/changes/issue-20a.md),
bench/stillness_holds.py (hand sway, warming gyros, low rates: docs/methods/stillness.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Optional

import numpy as np

from ...numerics.npstats import median, row_all, row_sum, window_var
from .floor import FLOOR_WINDOWS, floors as _floors, onset as _onset
from ..noise.posecov import MIN_SAMPLES as SF_MIN_SAMPLES, pose_sf_rows

__all__ = ["StaticInterval", "StillnessDetector", "DEFAULTS", "still_limits"]

from ...stillness_defaults import STILLNESS_DEFAULTS as DEFAULTS
WARMUP_WINDOWS = 8
#: fewest distinct samples a pose holds (its covariance has n - 1 degrees of freedom)
MIN_EFFECTIVE = 5
#: rejected stretches kept for the report (their count by reason is kept whole)
MAX_REJECTED = 1000
ABSURD = 1e6
_CH = ("t", "acc", "gyro", "temp", "mag", "fresh", "oi", "bz")
#: the gyro bias is the mean of the mean rates of the last BIAS_WINDOWS windows that were quiet
#: to the accelerometer and read within BIAS_GATE_DPS of the median of the latest
#: 2 x BIAS_WINDOWS quiet ones (a zero-rate output the die's warming moves: the MPU-6050's
#: +-20 deg/s over -40..85 C is ~0.16 deg/s/C; a gate centred on the bias in force let in
#: only the windows nearest the old value, and the bias stayed ~1 deg/s behind).  A turn
#: slower than the gate could join the bias, but at under 0.5 deg/s it turns a 3-s pose by
#: under 1.5 deg; a brief faster one stays out of it
BIAS_WINDOWS, BIAS_GATE_DPS = 8, 0.5
#: what a steady hand adds to a still window's summed accelerometer variance, g^2: a window is
#: quiet when its variance is at most k x floor + HAND_VAR_G2.  Physiological tremor (6-12 Hz,
#: 0.5-2 deg/s RMS) seen 2.5 cm from the wrist's pivot is up to ~5 mg RMS on the two axes
#: across the lever (2 deg/s x 2 pi x ~9 Hz x 2.5 cm), 2 x (5 mg)^2.  Without it the
#: threshold was the floor's alone, and a floor learnt while the board lay on a table (the
#: noise alone) made a hand's holds motion on a quiet chip: at 50 Hz an LSM6DSO's or BMI160's
#: noise is ~1 mg and its hand-held windows read 5-13x the floor (an independent probe: after
#: a 60-s rest, 96 of ~300 hand-held holds lost).  On an MPU-6050 at 100 Hz (floor ~3.5e-5 g^2)
#: it raises the threshold by a quarter
HAND_VAR_G2 = 5e-5
#: a bias is trusted (the turn test allows a hand's sway: TURN_SIGMAS) when the
#: windows it is the median of scatter by at most this per axis: a hand's sway (0.4 deg RMS
#: at 0.2-2 Hz) scatters the 1-s mean rates by ~0.6 deg/s; a session that never stops
#: (a slow tumble: no still window to learn the bias from) by several.  Until then a
#: window may turn STRICT_TURN_DEG (the limit before sway was allowed for)
BIAS_TRUST_DPS, STRICT_TURN_DEG = 1.0, 0.5
#: a trusted window may turn this many times the scatter of the quiet windows' mean rates
#: (x window_s), within STRICT_TURN_DEG..max_turn_deg: a bench's windows keep the strict
#: limit, a swaying hand's get what its sway turns (up to ~2.6 deg at 0.4 deg of sway)
TURN_SIGMAS = 5.0
#: ... and until then the bias is the median of the accelerometer-quiet windows among the
#: last BIAS_SPAN_WINDOWS (a warming gyro's bias a few minutes old is not its bias)
BIAS_SPAN_WINDOWS = 60


@dataclass(eq=False)
class StaticInterval:
    """One still interval the detector found: its rows' averages and scatter, time and place."""
    acc: np.ndarray               #: mean specific force, g (3,)
    acc_cov: np.ndarray           #: covariance of the mean, g^2 (3, 3)
    acc_sample_cov: np.ndarray    #: within-interval sample covariance, g^2
    n: int
    t0: float                     #: s
    t1: float
    temp: float                   #: mean, degC (nan when unknown)
    gyro: Optional[np.ndarray] = None       #: mean, deg/s
    gyro_cov: Optional[np.ndarray] = None   #: covariance of the mean
    mag: Optional[np.ndarray] = None        #: mean of fresh readings, gauss
    i0: int = -1                  #: first sample, index in the stream since start
    i1: int = -1                  #: one past the last sample
    #: the structure function of each hold averaged into this pose, [(n, rows, obs, hw)] of
    #: fitting/noise/posecov.py (a daemon's pose covariance under tremor); None: unknown
    acc_sf: Optional[list] = None
    #: the same of the radial series (the samples projected on the hold's mean direction)
    acc_radial_sf: Optional[list] = None
    #: this interval continues the one before it without a break: the same still run, cut at
    #: ``max_pose_s`` (so the same placement: calibrate joins them into one pose, the daemon's
    #: accumulator refines the pose the piece before went to)
    continues: bool = False


class _Span:
    """A hand piece over stream rows i0..i1 whose floor-track poses stand (_Core._resolve)."""
    __slots__ = ("i0", "i1", "continues")

    def __init__(self, i0: int, i1: int):
        self.i0, self.i1, self.continues = i0, i1, False


class _Track:
    """One pass that builds runs from the decided samples: its run so far and what its step
    test remembers.  The core keeps two (HAND_VAR_G2): the noise floor's, which makes every
    pose it always made, and with a gyro the hand's, whose poses replace the floor's within
    them unless one floor stretch covers half of the hand's run (:meth:`_Core._resolve`)."""
    __slots__ = ("hand", "run", "run_n", "run_start", "run_cut", "cut_emitted", "prev_am", "prev_q")

    def __init__(self, hand: bool):
        self.hand = hand
        self.run: List[dict] = []
        self.run_n = 0
        self.run_start = 0                  # stream row of the run's first sample, across cuts
        self.run_cut = False                # the run continues a piece cut at max_pose_s
        self.cut_emitted = False            # and that piece was emitted (not rejected)
        self.prev_am = None                 # trailing accelerometer mean at the last decided sample
        self.prev_q = False                 # and whether its window was quiet


class _Core:
    """The detector on distinct samples at their effective rate (:class:`StillnessDetector`
    feeds it)."""

    def __init__(self, rate_hz: float, window_s: float = DEFAULTS["window_s"],
                 k: float = DEFAULTS["k"], min_still_s: float = DEFAULTS["min_still_s"],
                 max_pose_s: float = DEFAULTS["max_pose_s"], trim_s: float = DEFAULTS["trim_s"],
                 max_turn_deg: float = DEFAULTS["max_turn_deg"], floor_cap: float = np.inf,
                 rest_norm_g=(0.0, np.inf), keep_structure: bool = False):
        self.rate = float(rate_hz)
        self.keep_structure = bool(keep_structure)
        self.floor_cap = float(floor_cap)
        self.rest_norm_g = tuple(rest_norm_g)
        self.min_still_s = float(min_still_s)
        #: stretches that were quiet but did not make a pose: dicts t0_s, t1_s, n, reason, kind
        #: (the last MAX_REJECTED), and the count of each kind since start
        self.rejected: List[dict] = []
        self.rejected_counts: Dict[str, int] = {}
        self.w = max(3, int(round(window_s * rate_hz)))
        self.window_s = self.w / self.rate
        self.k, self.max_turn_deg = float(k), float(max_turn_deg)
        self._turn2 = np.radians(self.max_turn_deg / 2) ** 2     # the step a hand's sway may make, rad^2
        self.min_n = max(3, int(round(min_still_s * rate_hz)))
        self.max_n = max(self.min_n, int(round(max_pose_s * rate_hz)))
        self.trim_n = int(round(trim_s * rate_hz))
        self.dropped = 0
        #: every piece a track has cut since the caller last took them (take_pieces), before
        #: the tracks are reconciled: _resolve holds a floor pose back until the hand's run
        #: ends, which on a long rest is when the board moves, but a piece's gyro mean is the
        #: bias whichever track's pose is kept (the orientation's still intervals)
        self.pieces: List[StaticInterval] = []
        self.floor_a: Optional[float] = None
        self.bias_g: Optional[np.ndarray] = None
        self._ring = np.zeros((BIAS_WINDOWS, 3))   # mean rates of the last windows that passed the bias gate
        self._ring_sum = np.zeros(3)         # and their sum
        self._n_passed = 0                   # windows that passed it
        self._still = np.zeros((2 * BIAS_WINDOWS, 3))   # mean rates of the latest still windows
        self._n_still = 0                    # (quiet and within the turn limit of the bias in force)
        self._lim = None                     # the turn limit in force, deg
        self._seen = 0                       # samples received
        self._last = None                    # last good row, fills bad ones for the statistics
        self._tail = None                    # last w-1 rows of [acc | gyro] (filled)
        self._blk: List[np.ndarray] = []      # rows of the partial non-overlapping window
        self._blk_n = 0
        self._hist_a = np.zeros(0)              # variances of the last FLOOR_WINDOWS windows
        self._hist_g = np.zeros((0, 3))         # and their mean rates (with a gyro)
        self._F: Dict[int, tuple] = {}       # windows completed -> (floor, bias, turn limit deg)
        self._nblk = 0
        self._buf: Optional[dict] = None     # samples whose still flag is not decided yet
        self._pend: List[dict] = []          # batches not yet joined (warm-up, or < w/4)
        self._pend_n = 0
        self._pend_i0 = 0                    # stream index of the first pending row
        self._q_done = 0                     # quiet flags known for stream index < this
        self._tracks = [_Track(False)]        # the floor's; the hand's joins with a gyro
        self._strict: List[tuple] = []       # the floor track's still stretches: (first, end)
        self._strict_open = False            # stream rows; the last one open at the batch end
        self._held: List[StaticInterval] = []    # floor poses within the hand's open run
        self._real: List[tuple] = []         # (first, end) rows of the hand pieces emitted from it
        self._queue: List[StaticInterval] = []   # poses after a waiting floor pose, in order

    # -- statistics -------------------------------------------------------------------
    def _blocks(self, x: np.ndarray, gy: bool) -> None:
        # rows wait in a list until a window is complete (no copy per small batch)
        self._blk.append(x)
        self._blk_n += len(x)
        if self._blk_n < self.w:
            return
        buf = self._blk[0] if len(self._blk) == 1 else np.concatenate(self._blk)
        m = len(buf) // self.w
        b = buf[:m * self.w].reshape(m, self.w, buf.shape[1])
        # the m completed windows at once; each one's floor is a percentile of the variances
        # of the FLOOR_WINDOWS windows up to it (itself included), its bias the median mean
        # rate of the quiet ones among them
        hist_a = np.concatenate([self._hist_a, window_var(b[:, :, :3]).sum(1)])
        # the learnt floor, capped by the chip's noise bound (a recording without a still
        # moment learns its floor from motion)
        fas = np.minimum(_floors(hist_a, m), self.floor_cap)
        hist_g = np.concatenate([self._hist_g, b[:, :, 3:].mean(1)]) if gy else None
        n0 = len(hist_a) - m
        for j in range(m):
            fa, bias, lim = float(fas[j]), None, self.max_turn_deg
            if gy:
                bias, lim = self._track_bias(hist_a, hist_g, n0 + j, fa)
            self._nblk += 1
            self._F[self._nblk] = (fa, bias, lim)
            self.floor_a, self.bias_g = fa, bias
        self._hist_a = hist_a[-FLOOR_WINDOWS:]
        if gy:
            self._hist_g = hist_g[-FLOOR_WINDOWS:]
        rest = buf[m * self.w:]
        self._blk = [rest] if len(rest) else []
        self._blk_n = len(rest)

    def _track_bias(self, hist_a, hist_g, i, fa):
        """(gyro bias after window i, the turn a window may make, deg) (BIAS_WINDOWS): until
        that many windows have passed the gate, the median mean rate of the accelerometer-
        quiet windows of the last BIAS_SPAN_WINDOWS, trusted when their rates scatter about
        it (s: 1.4826 x median absolute deviation, the largest axis) by at most
        BIAS_TRUST_DPS; then the mean of the last ones that passed (the gate has taken the
        outliers out), trusted.  The turn limit: TURN_SIGMAS x s x window_s (what the
        session's own quiet windows turn: a bench's ~0.02 deg/s, a swaying hand's ~0.5),
        between STRICT_TURN_DEG and ``max_turn_deg``; STRICT_TURN_DEG while untrusted."""
        g = hist_g[i]
        lo = max(0, i + 1 - BIAS_SPAN_WINDOWS)
        ha, ga = hist_a[lo:i + 1], hist_g[lo:i + 1]
        qa = ha <= self.k * fa
        x = ga[qa] if qa.any() else ga
        prev, lim = self.bias_g, self._lim
        if qa[-1] and (prev is None or float(np.sqrt((g - prev) @ (g - prev))) * self.window_s <= lim):
            # a still window (quiet, and within the turn limit of the bias in force: a turn
            # about gravity, which the accelerometer does not see, stays out) joins the latest
            # still ones; the gate is centred on their median, not on the bias in force: centred
            # on a bias that lags a warming gyro, it let in only the windows nearest the old
            # value and the tracked bias stayed behind by ~1 deg/s (an independent hand-held
            # session warming 17 C: 4 of 36 holds found, 36 with this gate and the run-level
            # check's constant-rate allowance)
            self._still[self._n_still % len(self._still)] = g
            self._n_still += 1
            d = g - median(self._still[:min(self._n_still, len(self._still))], axis=0)
            if float(np.sqrt(d @ d)) <= BIAS_GATE_DPS:
                j = self._n_passed % BIAS_WINDOWS          # a ring of the last ones, and their sum
                self._ring_sum += g - self._ring[j]
                self._ring[j] = g
                self._n_passed += 1
        tracked = self._n_passed >= BIAS_WINDOWS
        b = self._ring_sum / BIAS_WINDOWS if tracked else median(x, axis=0)
        sc = float((1.4826 * median(np.abs(x - b), axis=0)).max()) if len(x) >= 3 else np.inf
        strict = min(self.max_turn_deg, STRICT_TURN_DEG)
        if not (tracked or sc <= BIAS_TRUST_DPS):
            self._lim = strict
        else:
            self._lim = min(self.max_turn_deg, max(strict, TURN_SIGMAS * sc * self.window_s))
        return b, self._lim

    def _window_stats(self, x: np.ndarray):
        """Trailing-window (w samples) accelerometer variance sum and mean of the other
        columns at each row of x, from running sums about the window's first row."""
        full = x if self._tail is None else np.concatenate([self._tail, x])
        n, L, k = len(x), len(full), x.shape[1]
        self._tail = full[-(self.w - 1):]
        ref = full[0]
        # cumulative sums of d = full - ref (k columns) and of the accelerometer's d**2 (3; the
        # gyro's squares are never used), written in place: each column's running sum is the
        # same whichever columns stand beside it.  Column-major, so that every operation below
        # runs down whole columns (row-major, numpy steps through the rows 3 values at a time)
        c = np.empty((k + 3, L + 1)).T
        c[0] = 0.0
        d = c[1:, :k]
        np.subtract(full, ref, out=d)
        np.multiply(d[:, :3], d[:, :3], out=c[1:, k:])
        np.cumsum(c, 0, out=c)
        if L - n + 1 >= self.w:            # every window full (after the first w-1 rows)
            cnt = self.w
            s = c[L - n + 1:] - c[L - n + 1 - self.w:L + 1 - self.w]
            full_w = np.ones(n, bool)
        else:
            hi = np.arange(L - n, L) + 1
            lo = np.maximum(hi - self.w, 0)
            cnt = (hi - lo)[:, None]
            s = c[L - n + 1:] - c[lo]          # c[hi]: hi is the range L - n + 1 .. L
            full_w = cnt[:, 0] >= self.w
        s1, s2 = s[:, :k], s[:, k:]
        # max(s2 - s1^2 / cnt, 0) / max(cnt - 1, 1), operation by operation in one buffer
        var = s1[:, :3] * s1[:, :3]
        np.divide(var, cnt, out=var)
        np.subtract(s2, var, out=var)
        np.maximum(var, 0, out=var)
        np.divide(var, np.maximum(cnt - 1, 1), out=var)
        return row_sum(var), s1[:, 3:] / cnt + ref[3:], s1[:, :3] / cnt + ref[:3], full_w

    # -- streaming --------------------------------------------------------------------
    def update(self, t, acc, gyro=None, temp=None, mag=None, mag_fresh=None, oi=None):
        """Feed one batch; returns (quiet flag per sample of the batch, intervals completed).

        The quiet flag is the trailing-window test (during the warm-up, with the floor
        known so far); poses are emitted up to a window after their end.  ``oi``: each
        row's index in the caller's stream (default: the rows counted here)."""
        acc = np.asarray(acc, float)
        n = len(acc)
        if oi is None:
            oi = np.arange(self._seen, self._seen + n)
        x = acc if gyro is None else np.concatenate([acc, np.asarray(gyro, float)], 1)
        good = row_all(np.abs(x) < ABSURD)             # False for NaN and inf too
        if not good.all():
            self.dropped += int((~good).sum())
            x = x.copy()
            idx = np.where(good, np.arange(n), -1)
            np.maximum.accumulate(idx, out=idx)
            fill = self._last if self._last is not None else np.zeros(x.shape[1])
            x = np.where((idx >= 0)[:, None], x[np.maximum(idx, 0)], fill)
        if n:
            self._last = x[-1]
        self._blocks(x, gyro is not None)
        va, gm, am, full = self._window_stats(x)
        # stream index, quiet flag and its known mark are made for the joined pending rows
        new = {"t": np.asarray(t, float), "acc": acc,
               "gyro": None if gyro is None else np.asarray(gyro, float),
               "temp": None if temp is None else np.asarray(temp, float), "mag": mag,
               "fresh": mag_fresh, "oi": np.asarray(oi), "good": good & full, "ok": good, "va": va, "gm": gm, "am": am}
        if gyro is not None and len(self._tracks) == 1:
            self._tracks.append(_Track(True))
        if not self._pend:
            self._pend_i0 = self._seen
        self._seen += n
        self._pend.append(new)
        self._pend_n += n
        # the live flag: this batch against the floor known now (it does not wait), the
        # hand's allowance included
        q_batch = self._quiet(new, *self._F[self._nblk], hand=True) if self._nblk else np.zeros(n, bool)
        if self._nblk < WARMUP_WINDOWS or self._pend_n < max(1, self.w // 4):
            # poses are decided in chunks of a quarter window (the decisions do not depend
            # on the chunking; the per-batch cost at 1-2 samples a batch does)
            return q_batch, []
        self._join()
        self._judge()
        return q_batch, self._advance(final=False)

    def _join(self) -> None:
        pend, m = self._pend, self._pend_n
        self._pend, self._pend_n = [], 0
        new = pend[0] if len(pend) == 1 else {
            k: (None if pend[0][k] is None else np.concatenate([p[k] for p in pend]))
            for k in pend[0]}
        new.update(i=np.arange(self._pend_i0, self._pend_i0 + m), q=np.zeros(m, bool), qh=np.zeros(m, bool),
                   known=np.zeros(m, bool), fa=np.zeros(m),
                   bz=None if new["gyro"] is None else np.zeros((m, 3)))
        b = self._buf
        self._buf = new if b is None else {
            k: (None if b[k] is None else np.concatenate([b[k], new[k]])) for k in b}

    def _quiet(self, b, fa, bias, lim, hand: bool = False) -> np.ndarray:
        """Quiet trailing windows: accelerometer variance <= k floor (``hand``: + HAND_VAR_G2,
        only where the gyro's turn test runs), turn <= lim (deg)."""
        allow = HAND_VAR_G2 if hand and bias is not None else 0.0
        q = b["good"] & (b["va"] <= self.k * fa + allow)
        if bias is not None:
            d = b["gm"] - bias
            q &= np.sqrt(row_sum(d * d)) * self.window_s <= lim
        return q

    def flush(self) -> List[StaticInterval]:
        """End of stream: judge what waits (with the floor known so far) and close the run."""
        if self._pend:
            self._join()
        if self._buf is None:
            return []
        self._judge(final=True)
        out = self._advance(final=True)
        last = [self._close(tr, trim=True) if tr.run else None for tr in self._tracks]
        for tr in self._tracks:
            tr.run_cut = False               # the stream has ended: no run goes on
        if len(self._tracks) == 1:
            return out + [iv for iv in last if iv is not None]
        return out + self._resolve([last[0]] if last[0] is not None else [],
                                   [last[1]] if last[1] is not None else [])

    def _judge(self, final: bool = False) -> None:
        b = self._buf
        todo = ~b["known"]
        if not todo.any() or not self._F:
            return
        j = np.maximum(b["i"] // self.w, WARMUP_WINDOWS)
        if final:
            j = np.minimum(j, self._nblk)
        idx = np.flatnonzero(todo & (j <= self._nblk))
        if len(idx):
            # each sample against the floor and bias of its window (j is non-decreasing)
            jv = j[idx]
            u = jv[np.concatenate([[True], jv[1:] != jv[:-1]])].tolist()
            pos = np.searchsorted(u, jv)
            F = [self._F[jj] for jj in u]         # (floor, bias, turn limit) of each window
            fa = np.array([f[0] for f in F])[pos]
            bias = None if F[0][1] is None else np.array([f[1] for f in F])[pos]
            lim = np.array([f[2] for f in F])[pos]
            sub = {k: b[k][idx] for k in ("good", "va", "gm")}
            b["q"][idx] = self._quiet(sub, fa, bias, lim)
            b["qh"][idx] = self._quiet(sub, fa, bias, lim, hand=True) if bias is not None else b["q"][idx]
            b["fa"][idx] = fa
            if bias is not None:
                b["bz"][idx] = bias
            b["known"][idx] = True
        lo = max(int(b["i"][0]) // self.w, WARMUP_WINDOWS) if len(b["i"]) else self._nblk
        for kk in [kk for kk in self._F if kk < min(lo, self._nblk)]:
            del self._F[kk]              # no waiting sample needs these floors any more

    def _advance(self, final: bool) -> List[StaticInterval]:
        """Decide 'still' (some quiet window holds the sample) where the look-ahead is known."""
        b = self._buf
        known = b["known"]
        nk = int(np.argmin(known)) if not known.all() else len(known)
        nd = nk if final else max(0, nk - (self.w - 1))
        if nd == 0:
            return []
        ch = {k: (None if b[k] is None else b[k][:nd]) for k in _CH + ("i",)}
        found = []
        for tr in self._tracks:
            still, brk = self._still_flags(tr, b, b["qh" if tr.hand else "q"][:nk], nk, nd)
            if not tr.hand and len(self._tracks) > 1:
                self._note_strict(still, ch["oi"])
            found.append(self._runs(tr, still, ch, brk))
        self.pieces += [iv for f in found for iv in f if isinstance(iv, StaticInterval)]
        self._buf = {k: (None if v is None else v[nd:]) for k, v in b.items()}
        return found[0] if len(found) == 1 else self._resolve(*found)

    def _still_flags(self, tr: _Track, b, q, nk, nd):
        """(still, brk) of the first ``nd`` buffered samples for one track's quiet flags ``q``."""
        # sample i is still if any window ending in [i, i+w-1] is quiet (and it is good)
        c = np.concatenate([[0], np.cumsum(q)])
        ar = np.arange(nd)
        hi = np.minimum(ar + self.w, nk)
        still = (c[hi] - c[ar] > 0) & b["ok"][:nd]
        # a run breaks before sample i when no quiet window holds both i - 1 and i (the
        # windows ending in [i, i + w - 2]): two quiet stretches either side of an instant
        # change of orientation (samples lost while the board turned, a spliced file) are
        # two poses, not one pose with the mean of both.  A time gap alone does not break a
        # run (loggers pause with the board unmoved); a turn during it shows as a step.
        brk = c[np.minimum(ar + self.w - 1, nk)] - c[ar] == 0
        brk |= self._steps(tr, b, q, nk, nd, ar)
        return still, brk

    def _floor_wins(self, i0: int, i1: int) -> bool:
        """Whether the floor track's poses stand over a hand run of stream rows i0..i1: its
        still stretches of a pose's length within the run are one, covering half of it."""
        over = [min(z, i1) - max(a, i0) for a, z in self._strict]
        over = [o for o in over if o >= self.min_n]
        return len(over) == 1 and over[0] >= (i1 - i0) / 2

    def _note_strict(self, still, oi) -> None:
        """Keep the floor track's still stretches (stream rows, first and end) for the hand's
        poses to be checked against (:meth:`_resolve`); a stretch open at the end of the batch
        is extended by the next."""
        if not len(still):
            return
        e = np.flatnonzero(np.diff(np.concatenate([[0], still.view(np.int8), [0]])))
        for a, z in zip(e[::2].tolist(), e[1::2].tolist()):
            lo, hi = int(oi[a]), int(oi[z - 1]) + 1
            if a == 0 and self._strict_open and self._strict:
                lo = self._strict.pop()[0]
            self._strict.append((lo, hi))
        self._strict_open = bool(still[-1])

    def _resolve(self, floor: List[StaticInterval], hand: List[StaticInterval]) -> List[StaticInterval]:
        """The poses to emit from the two tracks' (HAND_VAR_G2).  A hand piece is the pose
        unless the floor track's still stretches of a pose's length (``min_still_s``) within
        its run are one, covering at least half of it: then it is a :class:`_Span`, dropped
        (a board set down on a table: the hand's settling at its edges left out, as before
        the hand track).  A floor pose within the hand track's open run waits for the whole
        run (across its ``max_pose_s`` cuts); it is emitted unless it overlaps a hand piece
        emitted from that run (a hand's hold on a quiet chip: fragments of a floor pose where
        the tremor dipped), so no two emitted poses overlap, and poses are emitted in the
        stream's order, however the stream is cut."""
        out = [h for h in hand if not isinstance(h, _Span)]
        self._real += [(h.i0, h.i1) for h in out]
        tr = self._tracks[1]
        lo = tr.run_start if (tr.run or tr.run_cut) else None
        wait = lambda f: lo is not None and f.i1 > lo
        held = self._held + floor
        self._held = [f for f in held if wait(f)]
        out += [f for f in held if not wait(f) and not any(a < f.i1 and f.i0 < z for a, z in self._real)]
        # what a later piece or floor pose can still meet: from the open run's start (the
        # open floor stretch is extended by the next batch)
        if lo is None:
            self._real = []
            self._strict = self._strict[-1:] if self._strict_open else []
        else:
            self._real = [r for r in self._real if r[1] > lo]
            self._strict = [st for st in self._strict if st[1] > lo]
        # in the stream's order: what starts after a waiting floor pose waits with it
        out = sorted(self._queue + out, key=lambda iv: iv.i0)
        first = min((f.i0 for f in self._held), default=None)
        self._queue = [iv for iv in out if first is not None and iv.i0 > first]
        return [iv for iv in out if not (first is not None and iv.i0 > first)]

    def _steps(self, tr: _Track, b, q, nk, nd, ar) -> np.ndarray:
        """Where a run breaks because the mean of the window before i and of the window from i
        differ by more than a still board's can (a step too small for the variance test to
        see when a window holds only a few samples of the other side: two quiet stretches
        either side of samples lost while the board turned, files appended, a board set down
        again a little differently).  Per axis the difference of two w-sample means has
        variance 2 s^2 / w, s^2 <= k x floor on a quiet window: 25 x that (5 sigma) summed
        over the axes; plus the change a hand's sway makes, up to half ``max_turn_deg`` (a
        hand-held hold's adjacent 1-s means differ by up to ~1.5 deg: bench/stillness_holds.py).
        Only two quiet windows are compared."""
        am = b["am"][:nk]
        before = np.concatenate([[tr.prev_am if tr.prev_am is not None else am[0]], am[:nd - 1]])
        q_before = np.concatenate([[tr.prev_q], q[:nd - 1]])
        ia = np.minimum(ar + self.w - 1, nk - 1)
        after, q_after = am[ia], q[ia]
        tr.prev_am, tr.prev_q = am[nd - 1].copy(), bool(q[nd - 1])
        d = after - before
        lim2 = 25.0 * 2.0 * self.k * b["fa"][:nd] / self.w
        allow2 = self._turn2 * row_sum(before * before)
        return q_before & q_after & (row_sum(d * d) > lim2 + allow2)

    # -- intervals --------------------------------------------------------------------
    def _runs(self, tr: _Track, still, ch, brk) -> List[StaticInterval]:
        out: List[StaticInterval] = []
        n = len(still)
        if n == 0:
            return out
        # where the value changes, and where a still run breaks (brk[i]: before sample i)
        cut = np.flatnonzero((still[1:] != still[:-1]) | (still[1:] & brk[1:])) + 1
        cut = cut.tolist()
        for i, j in zip([0] + cut, cut + [n]):
            if not still[i] or brk[i]:
                # the still run so far ends (motion, or a step between quiet stretches); one
                # that ended exactly at a max_pose_s cut has nothing left to close, and the
                # next run neither continues it nor skips its start trim
                if tr.run:
                    iv = self._close(tr, trim=True)
                    if iv is not None:
                        out.append(iv)
                else:
                    tr.run_cut = tr.cut_emitted = False
            if still[i]:
                s = i
                while s < j:
                    take = min(j - s, self.max_n - tr.run_n)
                    if not tr.run and not tr.run_cut:
                        tr.run_start = int(ch["oi"][s])
                    tr.run.append({k: (None if ch[k] is None else ch[k][s:s + take]) for k in _CH})
                    tr.run_n += take
                    s += take
                    if tr.run_n >= self.max_n:
                        iv = self._close(tr, trim=False)
                        if iv is not None:
                            out.append(iv)
                        tr.run_cut = True
        return out

    def _close(self, tr: _Track, trim: bool) -> Optional[StaticInterval]:
        """The track's run so far as an interval (None: rejected), marked ``continues`` when
        it follows an emitted piece of the same run cut at ``max_pose_s``."""
        cont = tr.run_cut and tr.cut_emitted
        iv = self._piece(tr, trim)
        if iv is not None:
            iv.continues = cont
        tr.cut_emitted = not trim and isinstance(iv, StaticInterval)
        return iv

    def _piece(self, tr: _Track, trim: bool):
        """The run (or its ``max_pose_s`` piece) as a pose, or None (the floor track's why
        kept); a hand run (after its start trim) over which the floor track's poses stand
        (:meth:`_floor_wins`) as a :class:`_Span` only, not averaged."""
        run, tr.run, tr.run_n = tr.run, [], 0
        start = 0 if tr.run_cut else self.trim_n
        if trim:
            tr.run_cut = False
        reject = self._reject if not tr.hand else (lambda *a: None)
        # one piece (most runs): its rows as they are (C order, as a concatenation makes them)
        cat = lambda k: None if run[0][k] is None else np.ascontiguousarray(run[0][k]) \
            if len(run) == 1 else np.concatenate([r[k] for r in run])
        t, acc, oi = cat("t"), cat("acc"), cat("oi")
        end = len(t)
        if tr.hand and end > start and self._floor_wins(int(oi[start]), int(oi[-1]) + 1):
            return _Span(int(oi[start]), int(oi[-1]) + 1)
        if trim:
            # a slow motion onset shows in the means before the variance: cut where a
            # short moving average first leaves the first half's mean by 5 sigma (on an
            # axis, by the sway a pose may hold too)
            end = max(0, _onset(acc, allow=np.sin(np.radians(self.max_turn_deg / 2))) - self.trim_n)
        if end - start < self.min_n:
            if end > start:
                reject(t[start], t[end - 1], end - start, "short",
                       f"still {(t[end - 1] - t[start]) + 1 / self.rate:.2f} s, under the "
                       f"{self.min_still_s:g} s minimum")
            return None
        return self._pose(cat, slice(start, end), t[start:end], acc[start:end], oi, reject)

    def _pose(self, cat, sl, t, acc, oi, reject) -> Optional[StaticInterval]:
        """A run's rows ``sl`` (``t``, ``acc``: those rows) as a pose, or None with ``reject``
        told why: its length, distinct samples, scatter, |mean| and turn are checked."""
        gyro, temp, mag, fresh = cat("gyro"), cat("temp"), cat("mag"), cat("fresh")
        m = acc.mean(0)
        d = acc - m
        sc = d.T @ d / (len(acc) - 1)
        n = len(acc)
        dur = float(t[-1] - t[0]) + 1.0 / self.rate
        norm = float(np.sqrt(m @ m))
        if dur < self.min_still_s * (1 - 1e-9):
            reject(t[0], t[-1], n, "short", f"still {dur:.2f} s, under the {self.min_still_s:g} s minimum")
            return None
        if n < MIN_EFFECTIVE:
            reject(t[0], t[-1], n, "few", f"{n} distinct samples, under the {MIN_EFFECTIVE} a pose needs")
            return None
        if np.trace(sc) > self.k * self.floor_cap:
            reject(t[0], t[-1], n, "noise",
                   f"scatter {np.sqrt(np.trace(sc) / 3) * 1e3:.3g} mg per axis, above the chip's bound "
                   f"{np.sqrt(self.k * self.floor_cap / 3) * 1e3:.3g} mg")
            return None
        if not self.rest_norm_g[0] <= norm <= self.rest_norm_g[1]:
            reject(t[0], t[-1], n, "norm",
                   f"|mean| {norm:.3g} g, not {self.rest_norm_g[0]:.3g}..{self.rest_norm_g[1]:.3g} g "
                   f"(a sensor at rest reads ~1 g)")
            return None
        why = _turned(acc, None if gyro is None else gyro[sl] - cat("bz")[sl], self.rate, self.w,
                      self.max_turn_deg / 2)
        if why:
            reject(t[0], t[-1], n, "turn", why)
            return None
        if mag is not None:
            why = _mag_turn(np.asarray(mag, float)[sl], None if fresh is None else np.asarray(fresh, bool)[sl])
            if why:
                reject(t[0], t[-1], n, "turn", why)
                return None
        tmp = float("nan")
        if temp is not None and np.isfinite(temp[sl]).any():
            tmp = float(np.nanmean(temp[sl]))
        iv = StaticInterval(m, sc / len(acc), sc, len(acc), float(t[0]), float(t[-1]), tmp,
                            i0=int(oi[sl][0]), i1=int(oi[sl][-1]) + 1)
        if self.keep_structure and n >= SF_MIN_SAMPLES:     # 28 numbers a pose: what the
                                    # daemon's pose covariance needs (calibrate has the rows)
            iv.acc_sf = [(n,) + pose_sf_rows(acc)]
            # and the radial series' (6 more): the daemon's sway override (daemon/fitjob.py)
            iv.acc_radial_sf = [(n,) + pose_sf_rows((acc @ (m / norm))[:, None])]
        if gyro is not None:
            g = gyro[sl]
            iv.gyro = g.mean(0)
            dg = g - iv.gyro
            iv.gyro_cov = dg.T @ dg / (len(g) - 1) / len(g)
        if mag is not None:
            mm = np.asarray(mag, float)[sl]
            f = np.asarray(fresh, bool)[sl].copy() if fresh is not None else np.ones(len(mm), bool)
            f &= np.all(np.isfinite(mm), axis=1)
            if f.any():
                iv.mag = mm[f].mean(0)
        return iv

    def _reject(self, t0, t1, n, kind, reason) -> None:
        self.rejected_counts[kind] = self.rejected_counts.get(kind, 0) + 1
        self.rejected.append({"t0_s": float(t0), "t1_s": float(t1), "n": int(n), "kind": kind,
                              "reason": reason})
        del self.rejected[:-MAX_REJECTED]


def _turned(acc: np.ndarray, gyro_dps: Optional[np.ndarray], rate_hz: float, w: int,
            lim_deg: float) -> Optional[str]:
    """Why a still run is a slow turn (None when it is not): its orientation, as the moving
    means over a quarter window (a hand's 6-12 Hz tremor averages out, its 0.2-2 Hz sway does
    not) of the accelerometer's direction and of the bias-free gyro's integrated angle, leaves
    the run's mean by more than ``lim_deg`` (half the turn a pose may hold).

    The gyro's angle is taken less a constant rate of up to STRICT_TURN_DEG per window (the
    run's mean residual rate, clipped): the tracked bias lags a warming gyro by a few tenths of
    a deg/s, which over a 10-s hold integrates to more than ``lim_deg`` (bench/stillness_holds.py,
    4-8 s holds warming 17 C: 51 % of holds whole without it, 93 % with it); a steady rotation
    that slow was let through per window before hand sway was allowed for, and one about a
    tilted axis still moves the accelerometer's direction (about gravity it passes: see the
    module's docstring)."""
    n = len(acc)
    L = min(max(2, w // 4), n)
    if n - L < 1:
        return None
    if gyro_dps is not None:
        r = gyro_dps.mean(0)
        rn, r_max = float(np.sqrt(r @ r)), STRICT_TURN_DEG * rate_hz / w
        gyro_dps = gyro_dps - (r if rn <= r_max else r * (r_max / rn))
    # one pass of running sums over [acc | integrated gyro angle, deg]: L-sample moving sums
    x = acc if gyro_dps is None else np.concatenate([acc, np.cumsum(gyro_dps, 0) / rate_hz], 1)
    c = np.cumsum(x, 0)
    ms = c[L - 1:].copy()
    ms[1:] -= c[:n - L]
    ma, mu = ms[:, :3], c[-1, :3]
    cosang = (ma @ mu) / (np.sqrt(row_sum(ma * ma)) * float(np.sqrt(mu @ mu)))
    ang = float(np.degrees(np.arccos(np.clip(cosang.min(), -1.0, 1.0))))
    what = "accelerometer's direction"
    if gyro_dps is not None:
        mt = ms[:, 3:] / L
        mt -= mt.mean(0)
        ga = float(np.sqrt(row_sum(mt * mt).max()))
        if ga > ang:
            ang, what = ga, "gyro's integrated angle"
    if ang > lim_deg:
        return (f"turned: the {what} left its mean by {ang:.2g} deg within it (limit {lim_deg:.2g} deg, "
                f"half the {2 * lim_deg:g} deg a pose may turn): a slow turn, not a hold")
    return None


#: a stretch whose magnetometer field direction turns more than this (or 5 of its noise
#: standard deviations) between its first and last thirds is turning, not still: a rotation
#: about gravity is invisible to the accelerometer (issue 20's 3-5 Hz hand tumbles carry a
#: magnetometer and no gyro); tremor averages out over a third of a pose
MAG_TURN_DEG = 1.0


def _mag_turn(m: np.ndarray, fresh: Optional[np.ndarray]) -> Optional[str]:
    """Why the magnetometer says the stretch turned (None when it does not, or cannot tell).
    Only new readings count (fresh, finite, changed: a held magnetometer repeats)."""
    ok = np.all(np.isfinite(m), axis=1)
    if fresh is not None:
        ok &= fresh
    ch = np.r_[True, np.any(np.diff(m, axis=0) != 0, axis=1)]
    x = m[ok & ch]
    n3 = len(x) // 3
    if n3 < 2:
        return None
    a, b = x[:n3].mean(0), x[-n3:].mean(0)
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if not (na > 0 and nb > 0):
        return None
    ang = float(np.arccos(np.clip(a @ b / (na * nb), -1.0, 1.0)))
    d2 = np.diff(x, 2, axis=0)
    s2 = float(np.mean(d2 ** 2)) * 3 / 6.0 if len(d2) else 0.0     # summed per-sample variance
    noise = np.sqrt(2.0 * s2 / n3) / (0.5 * (na + nb))
    lim = max(np.radians(MAG_TURN_DEG), 5.0 * noise)
    if ang > lim:
        return (f"the magnetometer turned {np.degrees(ang):.2g} deg within it (limit "
                f"{np.degrees(lim):.2g} deg): turning about gravity, which the accelerometer cannot see")
    return None


# --- absolute limits: what a sensor at rest can read -----------------------------------------

#: a part's noise may exceed its datasheet's typical density: the floor is capped at this many
#: times the datasheet variance (measured: the real MPU-6050s of ../shared read 1.8x in summed
#: variance, z the noisiest; hand tremor adds 1.3-3.2x inside a window, which k covers)
CAP_FACTOR = 4.0
#: noise bandwidth a logger sees at least, Hz: a chip filters at its own output rate, not at
#: the logger's, so a logger reading a 100 Hz part at 3 Hz sees the part's full (aliased) noise;
#: consumer parts' default bandwidths are >= ~50 Hz (MPU-6050 DLPF 0: 260 Hz, ADXL345 at its
#: 100 Hz default ODR: 50 Hz)
MIN_NOISE_BW_HZ = 50.0
#: density assumed for an accelerometer not in imucald.specs: the MPU-6050's 400 ug/rtHz, near
#: the noisiest consumer parts (ADXL345 430, ICM-20948 230, LSM9DS1 ~?: datasheets); 2x it
#: (4x the variance, CAP_FACTOR) still rejects a hand tumble (bench/stillness_rates.py)
GENERIC_DENSITY_G_RTHZ = 400e-6
#: |mean| band of a pose for an unknown chip, g: 1 g +- 0.35 (a generic part's prior box:
#: +-0.25 g offset, 15 % scale, summed with margin)
GENERIC_REST_TOL_G = 0.35


def still_limits(chip: Optional[str], rate_hz: float):
    """(floor cap, |mean| band) for an accelerometer at rest sampled at ``rate_hz``
    (effective, distinct samples).  Floor cap: the summed per-sample variance of the three
    axes a still part can show, g^2: CAP_FACTOR x 3 x density^2 x max(rate / 2,
    MIN_NOISE_BW_HZ) with the datasheet density (imucald.specs), else GENERIC_DENSITY_G_RTHZ.
    Band: 1 g +- 1.5 x (scale tolerance + |zero-g tolerance|) (at least 0.1 g), else
    +- GENERIC_REST_TOL_G."""
    from ...specs import ACCEL
    spec = ACCEL.get(chip or "")
    nd = spec.noise_density_g_rthz if spec is not None else GENERIC_DENSITY_G_RTHZ
    cap = CAP_FACTOR * 3.0 * nd ** 2 * max(rate_hz / 2.0, MIN_NOISE_BW_HZ)
    if spec is not None:
        tol = max(0.1, 1.5 * (spec.scale_tol + float(np.linalg.norm(spec.bias_tol_g))))
    else:
        tol = GENERIC_REST_TOL_G
    return cap, (1.0 - tol, 1.0 + tol)


# --- the detector: repeated samples out, then the core ---------------------------------------

#: the streaming detector decides whether the stream holds repeated samples once it has
#: DECIDE_ROWS rows spanning DECIDE_S seconds (or DECIDE_MAX_ROWS rows): before the core's
#: warm-up ends (WARMUP_WINDOWS windows) at usual rates, so no pose waits for the decision;
#: a whole file is judged at once
DECIDE_ROWS, DECIDE_S, DECIDE_MAX_ROWS = 16, 7.0, 4096


class StillnessDetector:
    """The stillness detector (criterion and defaults: module docstring).

    Repeated samples (:mod:`imucald.fitting.stillness.repeats`) are dropped before anything is judged,
    and the detector runs at the effective rate of the distinct samples: a whole file's are
    found by the caller (``repeats``); a stream's from its first DECIDE_S seconds, which
    meanwhile run through a core at the nominal rate (its live flags are returned, its poses
    wait for the decision); when the stream turns out held (or its rate not the nominal one)
    those rows are judged again by a core at the effective rate.  ``chip``: the
    accelerometer (specs.ACCEL name, else the generic bounds of :func:`still_limits`).
    Intervals index the caller's rows (i0, i1).  ``keep_structure``: each interval keeps its
    accelerometer's within-pose structure function (``acc_sf``, fitting/noise/posecov.py), which
    the daemon needs because it keeps no samples; a caller holding the rows leaves it off."""

    def __init__(self, rate_hz: float, window_s: float = DEFAULTS["window_s"],
                 k: float = DEFAULTS["k"], min_still_s: float = DEFAULTS["min_still_s"],
                 max_pose_s: float = DEFAULTS["max_pose_s"], trim_s: float = DEFAULTS["trim_s"],
                 max_turn_deg: float = DEFAULTS["max_turn_deg"], chip: Optional[str] = None,
                 repeats=None, keep_structure: bool = False):
        self.nominal_rate = float(rate_hz)
        self._kw = dict(window_s=window_s, k=k, min_still_s=min_still_s, max_pose_s=max_pose_s,
                        trim_s=trim_s, max_turn_deg=max_turn_deg, keep_structure=keep_structure)
        self.chip = chip
        self.repeats = None          #: the repeats.Repeats the detector runs on, once decided
        self._core: Optional[_Core] = None
        self._wait: List[tuple] = []     # rows seen before the decision
        self._wait_n = 0
        self._waiting: List[StaticInterval] = []   # poses the provisional core found meanwhile
        self._seen = 0
        self._held = False
        self._prev = None            # (t, acc row) of the last row fed
        self._last_q = False
        if repeats is not None:
            self._start(repeats)
        else:
            self._start_core(self.nominal_rate, False)

    # what the core knows
    dropped = property(lambda self: self._core.dropped)
    floor_a = property(lambda self: self._core.floor_a)
    bias_g = property(lambda self: self._core.bias_g)
    rate = property(lambda self: self._core.rate)
    floor_cap = property(lambda self: self._core.floor_cap)
    rejected = property(lambda self: self._core.rejected)
    rejected_counts = property(lambda self: self._core.rejected_counts)

    @property
    def undecided(self) -> bool:
        return self.repeats is None

    def take_pieces(self) -> List[StaticInterval]:
        """The pieces the tracks have cut since the last call, as they are cut (_Core.pieces):
        still stretches whose gyro mean is the bias, before the poses are decided."""
        out, self._core.pieces = self._core.pieces, []
        return out

    def _start_core(self, rate: float, held: bool) -> None:
        self._held = bool(held)
        cap, band = still_limits(self.chip, rate)
        self._core = _Core(rate, floor_cap=cap, rest_norm_g=band, **self._kw)
        self._seen, self._prev, self._last_q = 0, None, False

    def _start(self, rep) -> None:
        self.repeats = rep
        self._start_core(rep.rate_hz if rep.rate_changed else self.nominal_rate, rep.held)

    def _decide(self, final: bool = False):
        """Judge the waiting rows; returns the intervals to emit now."""
        from .repeats import find_repeats
        wait, self._wait, self._wait_n = self._wait, [], 0
        waiting, self._waiting = self._waiting, []
        t = np.concatenate([w[0] for w in wait])
        acc = np.concatenate([w[1] for w in wait])
        rep = find_repeats(t, acc, self.nominal_rate)
        if not (rep.held or rep.rate_changed):
            self.repeats = rep              # the provisional core was right: keep it
            return waiting, None
        self._start(rep)                    # judged again, at the effective rate
        out, q = [], None
        for w in wait:
            q, got = self._feed(*w)
            out += got
        return out, q

    def update(self, t, acc, gyro=None, temp=None, mag=None, mag_fresh=None):
        """Feed one batch; returns (quiet flag per sample of the batch, intervals completed)."""
        if not self.undecided:
            return self._feed(t, acc, gyro, temp, mag, mag_fresh)
        t = np.asarray(t, float)
        acc = np.asarray(acc, float)
        self._wait.append((t, acc, gyro, temp, mag, mag_fresh))
        self._wait_n += len(t)
        q, got = self._feed(t, acc, gyro, temp, mag, mag_fresh)
        self._waiting += got
        t0 = next((w[0][0] for w in self._wait if len(w[0])), None)
        span = float(t[-1] - t0) if len(t) and t0 is not None else 0.0
        if (self._wait_n >= DECIDE_ROWS and span >= DECIDE_S) or self._wait_n >= DECIDE_MAX_ROWS:
            out, q2 = self._decide()
            return (q if q2 is None else q2), out
        return q, []

    def _feed(self, t, acc, gyro=None, temp=None, mag=None, mag_fresh=None):
        t = np.asarray(t, float)
        acc = np.asarray(acc, float)
        n = len(t)
        if not n:
            return np.zeros(0, bool), []
        same = np.zeros(n, bool)
        st = np.zeros(n, bool)
        if self._prev is not None:
            same[0] = bool(np.all(acc[0] == self._prev[1]))
            st[0] = t[0] == self._prev[0]
        same[1:] = row_all(acc[1:] == acc[:-1])
        st[1:] = t[1:] == t[:-1]
        self._prev = (t[-1], acc[-1].copy())
        drop = same & (st | self._held)
        oi = np.arange(self._seen, self._seen + n)
        self._seen += n
        if not drop.any():
            q, ivs = self._core.update(t, acc, gyro, temp, mag, mag_fresh, oi=oi)
            if len(q):
                self._last_q = bool(q[-1])
            return q, ivs
        keep = ~drop
        pick = lambda a: None if a is None else np.asarray(a)[keep]
        qk, ivs = self._core.update(t[keep], acc[keep], pick(gyro), pick(temp), pick(mag),
                                    pick(mag_fresh), oi=oi[keep])
        # a dropped row has the flag of the distinct sample it repeats
        pos = np.cumsum(keep) - 1
        q = np.where(pos >= 0, qk[np.maximum(pos, 0)] if len(qk) else False, self._last_q)
        if len(qk):
            self._last_q = bool(qk[-1])
        return q.astype(bool), ivs

    def flush(self) -> List[StaticInterval]:
        """End of stream: judge what waits (with the floor known so far) and close the run."""
        out: List[StaticInterval] = []
        if self.undecided and self._wait_n:
            out, _ = self._decide(final=True)
        return out + self._core.flush()
