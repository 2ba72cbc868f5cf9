"""Plots for `imucald gap --report DIR` (matplotlib, the optional 'plots' extra):
normalised residuals against temperature, time and orientation, before and after
the chosen effects are modelled."""
from __future__ import annotations

import os
from typing import Dict

import numpy as np

from ..errors import UserError

__all__ = ["write_report"]


def write_report(res: Dict[str, object], outdir: str) -> list:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise UserError("--report needs matplotlib: pip install 'imucald[plots]'") from None
    os.makedirs(outdir, exist_ok=True)
    written = []
    for sensor, r in res["sensors"].items():
        p = r.get("_plot")
        if p is None:
            continue
        sd = np.sqrt(np.asarray(p["var"]))
        series = [("baseline", np.asarray(p["e"]) / sd, "o", "0.6")]
        if p.get("e_after") is not None:
            series.append((f"with {p['after_label']}", np.asarray(p["e_after"]) / sd, "o", "C0"))
        fig, ax = plt.subplots(1, 3, figsize=(13, 4))
        u = np.asarray(p["u"])
        j = np.argmax(np.abs(u), axis=1)
        region = j * 2 + (np.take_along_axis(u, j[:, None], 1)[:, 0] < 0)
        for label, z, m, c in series:
            if p.get("temp") is not None:
                ax[0].plot(p["temp"], z, m, color=c, label=label)
            ax[1].plot(p["t"], z, m, color=c, label=label)
            ax[2].plot(region, z, m, color=c, label=label)
        if p.get("temp") is not None:
            ax[0].set_xlabel("temperature, degC")
        else:
            ax[0].text(0.5, 0.5, "no temperature column", ha="center", transform=ax[0].transAxes)
        ax[1].set_xlabel("time, s")
        ax[1].legend(fontsize=8)
        ax[2].set_xticks(range(6), ["+X", "-X", "+Y", "-Y", "+Z", "-Z"])
        ax[2].set_xlabel("axis up")
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
