"""Streaming stillness detector: moving variance over a trailing window.

Per batch, numpy only: the windowed variance of each accelerometer axis (and
gyro axis) is summed over axes; the noise floor is learnt from the quietest
windows seen recently (a low percentile of the variances of consecutive,
non-overlapping windows), so no dedicated still period is needed at start-up;
a sample is still when its variance is below ``k`` x floor.  A still run at
least ``min_still_s`` long, trimmed by ``trim_s`` at its end (the trailing
window already trims the start), becomes a :class:`StaticInterval`; a run
longer than ``max_pose_s`` is cut into several.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Deque, List, Optional

import numpy as np

__all__ = ["StaticInterval", "StillnessDetector"]


@dataclass
class StaticInterval:
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


class StillnessDetector:
    def __init__(self, rate_hz: float, window_s: float = 1.0, k: float = 6.0,
                 min_still_s: float = 1.5, max_pose_s: float = 20.0, trim_s: float = 0.25,
                 floor_windows: int = 300, floor_pct: float = 10.0):
        self.rate = float(rate_hz)
        self.w = max(3, int(round(window_s * rate_hz)))
        self.k, self.min_n = k, int(round(min_still_s * rate_hz))
        self.max_n = int(round(max_pose_s * rate_hz))
        self.trim_n = int(round(trim_s * rate_hz))
        self.floor_pct = floor_pct
        self._hist = {"a": deque(maxlen=floor_windows), "g": deque(maxlen=floor_windows)}
        self._tail = None            # last w-1 samples of [acc | gyro]
        self._blk = None             # partial non-overlapping window for the floor
        self._run: List[dict] = []   # batches of the current still run
        self._run_n = 0
        self.floor_a: Optional[float] = None
        self.floor_g: Optional[float] = None

    # -- noise floor ----------------------------------------------------------------
    def _learn(self, x: np.ndarray, na: int) -> None:
        buf = x if self._blk is None else np.vstack([self._blk, x])
        m = len(buf) // self.w
        if m:
            blocks = buf[:m * self.w].reshape(m, self.w, -1)
            v = blocks.var(axis=1, ddof=1)
            self._hist["a"].extend(v[:, :na].sum(1))
            if x.shape[1] > na:
                self._hist["g"].extend(v[:, na:].sum(1))
        self._blk = buf[m * self.w:]
        if m:                                   # new windows: update the floor (once a window)
            self.floor_a = _floor(self._hist["a"], self.floor_pct)
            if self._hist["g"]:
                self.floor_g = _floor(self._hist["g"], self.floor_pct)

    def still_mask(self, acc: np.ndarray, gyro: Optional[np.ndarray]) -> np.ndarray:
        """Still flag per sample of this batch (False until a floor is known)."""
        x = acc if gyro is None else np.hstack([acc, gyro])
        na = 3
        self._learn(x, na)
        full = x if self._tail is None else np.vstack([self._tail, x])
        n = len(x)
        self._tail = full[-(self.w - 1):] if self.w > 1 else None
        if self.floor_a is None or len(full) < self.w:
            return np.zeros(n, bool)
        c1 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), full - full[0]]), 0)
        c2 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), (full - full[0]) ** 2]), 0)
        hi = np.arange(len(full) - n, len(full)) + 1
        lo = np.maximum(hi - self.w, 0)
        cnt = (hi - lo)[:, None]
        s1 = c1[hi] - c1[lo]
        s2 = c2[hi] - c2[lo]
        var = np.maximum(s2 - s1 * s1 / cnt, 0) / np.maximum(cnt - 1, 1)
        still = (var[:, :na].sum(1) <= self.k * self.floor_a) & (cnt[:, 0] >= self.w)
        if gyro is not None and self.floor_g is not None:
            still &= var[:, na:].sum(1) <= self.k * self.floor_g
        return still

    # -- intervals ------------------------------------------------------------------
    def update(self, t, acc, gyro=None, temp=None, mag=None, mag_fresh=None) -> (np.ndarray, List[StaticInterval]):
        """Feed one batch; returns (still flags, intervals completed in this batch)."""
        still = self.still_mask(acc, gyro)
        out: List[StaticInterval] = []
        n = len(t)
        i = 0
        while i < n:
            if still[i]:
                j = i
                while j < n and still[j]:
                    j += 1
                self._append(t, acc, gyro, temp, mag, mag_fresh, i, j)
                if self._run_n >= self.max_n:
                    iv = self._close(trim=False)
                    if iv is not None:
                        out.append(iv)
                i = j
            else:
                if self._run:
                    iv = self._close(trim=True)
                    if iv is not None:
                        out.append(iv)
                j = i
                while j < n and not still[j]:
                    j += 1
                i = j
        return still, out

    def _append(self, t, acc, gyro, temp, mag, mag_fresh, i, j):
        sl = slice(i, j)
        self._run.append({"t": t[sl], "acc": acc[sl],
                          "gyro": None if gyro is None else gyro[sl],
                          "temp": None if temp is None else temp[sl],
                          "mag": None if mag is None else mag[sl],
                          "fresh": None if mag_fresh is None else mag_fresh[sl]})
        self._run_n += j - i

    def _close(self, trim: bool) -> Optional[StaticInterval]:
        run, self._run, self._run_n = self._run, [], 0
        cat = lambda k: None if run[0][k] is None else np.concatenate([r[k] for r in run])
        t, acc = cat("t"), cat("acc")
        if trim:
            # a slow motion onset raises the trailing variance only after the board has
            # started to turn: cut where a short moving average first leaves the
            # first half's mean by more than 5 sigma, then trim a further trim_s
            end = _onset(acc)
            end = max(0, end - self.trim_n)
            t, acc = t[:end], acc[:end]
        cut = len(t)
        if len(t) < max(self.min_n, 3):
            return None
        gyro, temp, mag, fresh = cat("gyro"), cat("temp"), cat("mag"), cat("fresh")
        m = acc.mean(0)
        d = acc - m
        sc = d.T @ d / (len(acc) - 1)
        iv = StaticInterval(m, sc / len(acc), sc, len(acc), float(t[0]), float(t[-1]),
                            float(np.nanmean(temp[:cut])) if temp is not None else float("nan"))
        if gyro is not None:
            g = gyro[:cut]
            iv.gyro = g.mean(0)
            dg = g - iv.gyro
            iv.gyro_cov = dg.T @ dg / (len(g) - 1) / len(g)
        if mag is not None:
            mm = mag[:cut]
            f = fresh[:cut] if fresh is not None else np.ones(len(mm), bool)
            f &= np.all(np.isfinite(mm), axis=1)
            if f.any():
                iv.mag = mm[f].mean(0)
        return iv


def _onset(acc: np.ndarray, short: int = 10) -> int:
    """Index where motion starts at the end of a still run (len(acc) if none)."""
    n = len(acc)
    if n < 4 * short:
        return n
    half = n // 2
    m0 = acc[:half].mean(0)
    sd = acc[:half].std(0, ddof=1) + 1e-12
    c = np.cumsum(np.vstack([np.zeros((1, 3)), acc]), 0)
    ma = (c[short:] - c[:-short]) / short            # ma[i] = mean of acc[i:i+short]
    dev = np.abs(ma - m0) / (sd / np.sqrt(short))
    bad = np.flatnonzero(dev[half:].max(1) > 5.0)
    return n if not len(bad) else half + int(bad[0])


def _floor(h: Deque[float], pct: float) -> float:
    v = np.fromiter(h, float)
    f = float(np.percentile(v, pct))
    if f <= 0:
        pos = v[v > 0]
        f = float(pos.min()) if pos.size else 1e-12
    return f
