"""Plots for `imucald gap --report DIR` (matplotlib, the optional 'plots' extra): for
every sensor diagnosed (accelerometer, gyro, magnetometer; pose path and time-series
path), the held-out residuals over their noise standard deviation against temperature,
time and orientation (the axis pointing up), before and after the chosen effects are
modelled.  One PNG per sensor, ``<sensor>_residuals.png``."""
from __future__ import annotations

import os
from typing import Dict

import numpy as np

from ..errors import UserError, install_hint

__all__ = ["write_report"]

_REGIONS = ["+X", "-X", "+Y", "-Y", "+Z", "-Z"]


def write_report(res: Dict[str, object], outdir: str) -> list:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise UserError(f"--report needs matplotlib, the plots extra: {install_hint('plots')}") from None
    try:
        os.makedirs(outdir, exist_ok=True)
    except OSError as e:
        raise UserError(f"--report {outdir}: cannot create the directory ({e.strerror}): "
                        "give a writable path") from None
    written = []
    for sensor, r in res["sensors"].items():
        p = r.get("_plot")
        if p is None:
            continue
        sd = np.sqrt(np.asarray(p["var"], float))
        series = [("baseline", np.asarray(p["e"]) / sd, "0.6")]
        if p.get("e_after") is not None:
            series.append((f"with {p['after_label']}", np.asarray(p["e_after"]) / sd, "C0"))
        fig, ax = plt.subplots(1, 3, figsize=(13, 4))
        u = p.get("u")
        region = None
        if u is not None:
            u = np.asarray(u, float)
            j = np.argmax(np.abs(u), axis=1)
            region = j * 2 + (np.take_along_axis(u, j[:, None], 1)[:, 0] < 0)
        jitter = (np.asarray(p["axis"]) - 1) * 0.15 if p.get("axis") is not None else 0.0
        for label, z, c in series:
            if p.get("temp") is not None:
                ax[0].plot(p["temp"], z, "o", ms=3, color=c, label=label)
            ax[1].plot(p["t"], z, "o", ms=3, color=c, label=label)
            if region is not None:
                ax[2].plot(region + jitter, z, "o", ms=3, color=c, label=label)
        if p.get("temp") is not None:
            ax[0].set_xlabel("temperature, degC")
        else:
            ax[0].text(0.5, 0.5, "no temperature (or too flat)", ha="center", transform=ax[0].transAxes)
        ax[1].set_xlabel("time, s")
        ax[1].legend(fontsize=8)
        if region is not None:
            ax[2].set_xticks(range(6))
            ax[2].set_xticklabels(_REGIONS)
            ax[2].set_xlabel("axis up" + (" (x, y, z residuals side by side)" if p.get("axis") is not None
                                          else ""))
        else:
            ax[2].text(0.5, 0.5, "one orientation (time-series diagnosis)", ha="center",
                       transform=ax[2].transAxes)
        for a in ax:
            a.axhline(0, color="k", lw=0.5)
            a.set_ylabel("held-out residual / noise sd")
        fig.suptitle(f"{sensor}: verdict {r['verdict']}, ratio {r['ratio_before']:.2f} -> {r['ratio_after']:.2f}")
        fig.tight_layout()
        f = os.path.join(outdir, f"{sensor}_residuals.png")
        fig.savefig(f, dpi=90)
        plt.close(fig)
        written.append(f)
    return written
