"""Where the excess residual lies: orientation regions, temperature and time bins,
and trends (against temperature, time, each axis squared, the previous pose)."""
from __future__ import annotations

from typing import Dict, Tuple

import numpy as np

from ..fitting.models.mag import MagModel
from ..fitting.models.base import NormModel
from .signif import corr_p

__all__ = ["norm_where", "linear_where", "region"]


def region(u: np.ndarray, along: str = "up") -> str:
    """'+Z up', '-X up' ...: the axis nearest the vector ``u`` (the up vector; for the
    magnetometer the field's direction, ``along`` 'along the field')."""
    j = int(np.argmax(np.abs(u)))
    return f"{'+' if u[j] > 0 else '-'}{'XYZ'[j]} {along}"


def norm_where(x: np.ndarray, z_n: np.ndarray, model: NormModel, th: np.ndarray,
               ctx: Dict[str, np.ndarray]) -> Tuple[Dict[str, object], np.ndarray]:
    """Shares of the excess of the normalised residuals ``z_n`` by region and bin, and
    trends; also the poses' unit directions about the fitted centre (for the plots)."""
    N = len(x)
    excess = z_n ** 2 - 1.0
    mag = isinstance(model, MagModel)
    u = (x - (th[6:9] if model.k == 9 else th[model.kw:] if mag else 0))
    # the magnetometer's u is the field's direction in the body frame, not the up vector: its
    # regions are named so ("+X up" read as an orientation, without an accelerometer too)
    along = "along the field" if mag else "up"
    regions = {}
    for i in range(N):
        regions.setdefault(region(u[i], along), []).append(i)
    tot = float(np.sum(np.maximum(excess, 0))) or 1.0
    where = {"region_share": {k: round(float(np.sum(np.maximum(excess[v], 0))) / tot, 3)
                              for k, v in sorted(regions.items())}}
    if "temp" in ctx and np.isfinite(ctx["temp"]).all():
        qs = np.quantile(ctx["temp"], [0, 0.25, 0.5, 0.75, 1])
        b = np.clip(np.searchsorted(qs[1:-1], ctx["temp"], side="right"), 0, 3)
        where["temperature_bin_share"] = {f"{qs[k]:.1f}..{qs[k + 1]:.1f} C":
                                          round(float(np.sum(np.maximum(excess[b == k], 0))) / tot, 3)
                                          for k in range(4)}
    tq = np.quantile(ctx["t"], [0, 0.25, 0.5, 0.75, 1])
    bt = np.clip(np.searchsorted(tq[1:-1], ctx["t"], side="right"), 0, 3)
    where["time_bin_share"] = {f"{tq[k]:.0f}..{tq[k + 1]:.0f} s":
                               round(float(np.sum(np.maximum(excess[bt == k], 0))) / tot, 3) for k in range(4)}
    ud = u / np.linalg.norm(u, axis=1, keepdims=True)
    order = np.argsort(ctx["t"])
    prev = np.full(N, np.nan)
    prev[order[1:]] = z_n[order[:-1]]
    trends = {"temperature": corr_p(ctx.get("temp", np.full(N, np.nan)), z_n),
              "time": corr_p(ctx["t"], z_n), "previous_pose": corr_p(prev, z_n)}
    for j, ax in enumerate("xyz"):
        trends[f"{ax}_squared"] = corr_p(ud[:, j] ** 2, z_n)
    where["trends"] = {k: v for k, v in trends.items() if v is not None}
    return where, ud


def linear_where(rz: np.ndarray, ctx: Dict[str, np.ndarray]) -> Dict[str, object]:
    """Shares of the excess of the normalised gyro residuals ``rz`` (N, 3) by axis, and trends."""
    N = len(rz)
    ex = np.maximum(rz ** 2 - 1, 0)
    tot = max(float(np.sum(ex)), 1e-300)
    size = np.linalg.norm(rz, axis=1)
    trends = {"temperature": corr_p(ctx.get("temp", np.full(N, np.nan)), size),
              "time": corr_p(ctx["t"], size)}
    return {"axis_share": {ax: round(float(np.sum(ex[:, j])) / tot, 3) for j, ax in enumerate("xyz")},
            "trends": {k: v for k, v in trends.items() if v is not None}}
