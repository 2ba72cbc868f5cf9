"""Residuals before and after a calibration: for each still pose, |a| - 1 g of the pose
mean as read (nominal scaling only) and as corrected, against the pose number, with the
RMS of each in the legend.  The same picture for a magnetometer uses |h| / F - 1."""
from __future__ import annotations

import numpy as np

from ._mpl import pyplot, save

__all__ = ["residual_figure", "write_residuals"]


def residual_figure(before: np.ndarray, after: np.ndarray, unit: str = "mg", scale: float = 1e3,
                    title: str = ""):
    """``before``, ``after``: (N,) residuals (|a| - 1 g in g, or relative) of the same poses."""
    plt = pyplot("--plot")
    b = np.asarray(before, float) * scale
    a = np.asarray(after, float) * scale
    i = np.arange(1, len(b) + 1)
    rms = lambda x: float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan")
    fig, ax = plt.subplots(figsize=(8.0, 3.6))
    ax.axhline(0, color="0.6", lw=0.8)
    ax.plot(i, b, "o", ms=5, color="0.55", label=f"before (raw): RMS {rms(b):.3g} {unit}")
    ax.plot(i, a, "o", ms=5, color="C0", label=f"after (calibrated, fitted on these poses): RMS {rms(a):.3g} {unit}")
    ax.set_xlabel("still pose")
    ax.set_ylabel(f"|a| - 1 g, {unit}" if unit == "mg" else f"residual, {unit}")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def write_residuals(path: str, before, after, unit: str = "mg", scale: float = 1e3, title: str = "",
                    flag: str = "--plot") -> str:
    return save(residual_figure(before, after, unit, scale, title), path, flag)
