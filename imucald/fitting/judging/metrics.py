"""Quality metrics used by the papers.

* norm residual RMS (in-sample) and leave-one-pose-out held-out RMS
  (:func:`imucald.fitting.fit.heldout_residuals`);
* paper 000's equivalent-path error: double integration of calibrated static
  samples, ds_i(t) = |s_i(t)| - g t^2 / 2;
* paper 001's roll and pitch from the (calibrated) accelerometer.
"""
from __future__ import annotations

from typing import Sequence, Tuple

import numpy as np

__all__ = ["rms", "path_error", "roll_pitch_deg"]

G0_M_S2 = 9.80665   # standard gravity, m/s^2 (used only to express paths in metres)


def rms(x: np.ndarray) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def path_error(samples_g: Sequence[np.ndarray], rate_hz: float, duration_s: float = 20.0
               ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper 000's equivalent-path error of static poses.

    samples_g: per pose, calibrated static samples (n_i, 3) in g (a pose mean may be
    passed as a (1, 3) array: it is held constant).  Each pose is integrated twice
    (trapezoid) over ``duration_s``; ds_i(t) = |s_i(t)| - g0 t^2 / 2 in metres.
    Returns (t_s, mean_m, std_m) over poses at each time step.
    """
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    dt = 1.0 / rate_hz
    arrs = [np.asarray(s, float) for s in samples_g]
    if len(arrs) > 1 and all(s.shape == (1, 3) for s in arrs):
        # pose means held constant: every pose at once (the same sums, in the same order)
        a = np.repeat(np.concatenate(arrs)[:, None, :], n, 1) * G0_M_S2
        v = np.concatenate([np.zeros((len(a), 1, 3)), np.cumsum((a[:, 1:] + a[:, :-1]) * dt / 2, 1)], 1)
        p = np.concatenate([np.zeros((len(a), 1, 3)), np.cumsum((v[:, 1:] + v[:, :-1]) * dt / 2, 1)], 1)
        e = np.linalg.norm(p, axis=2) - 0.5 * G0_M_S2 * t ** 2
        return t, e.mean(0), e.std(0, ddof=1)
    errs = []
    for s in samples_g:
        s = np.asarray(s, float)
        a = np.resize(s, (n, 3)) if len(s) < n else s[:n]
        a = a * G0_M_S2
        v = np.vstack([np.zeros((1, 3)), np.cumsum((a[1:] + a[:-1]) * dt / 2, 0)])
        p = np.vstack([np.zeros((1, 3)), np.cumsum((v[1:] + v[:-1]) * dt / 2, 0)])
        errs.append(np.linalg.norm(p, axis=1) - 0.5 * G0_M_S2 * t ** 2)
    e = np.array(errs)
    return t, e.mean(0), e.std(0, ddof=1) if len(e) > 1 else np.zeros(n)


def roll_pitch_deg(acc_g: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (degrees) from specific force, x forward, z up at rest:
    roll = atan2(a_y, a_z), pitch = atan2(-a_x, sqrt(a_y^2 + a_z^2))."""
    a = np.asarray(acc_g, float)
    roll = np.degrees(np.arctan2(a[..., 1], a[..., 2]))
    pitch = np.degrees(np.arctan2(-a[..., 0], np.hypot(a[..., 1], a[..., 2])))
    return roll, pitch
