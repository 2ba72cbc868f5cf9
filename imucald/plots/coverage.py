"""The pose-coverage sphere: where the board's up vector (the direction of the measured
specific force, sensor frame) has been held still, against the 26 orientations of a cube's
faces, edges and corners that imucald asks for (fitting/judging/coverage.py).

Two discs, the +Z and -Z hemispheres seen from outside along Z (Lambert equal-area, so
equal areas of the sphere look equal), the X axis to the right and Y up: a dot per pose,
each cube orientation as a filled square when a pose lies within ``cover_angle_deg`` of it
and an open red square when it is missing, labelled ("+X+Y up")."""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..fitting.judging.coverage import TARGETS, target_name
from ._mpl import pyplot, save

__all__ = ["coverage_figure", "write_coverage", "lambert_disc"]


def lambert_disc(u: np.ndarray) -> np.ndarray:
    """Unit vectors (N, 3) -> (N, 2) on the disc of radius 1 (Lambert azimuthal equal-area
    about +Z for z >= 0 and about -Z for z < 0; the -Z disc is seen from below, x mirrored,
    so that it reads as the sphere's underside)."""
    u = np.asarray(u, float).reshape(-1, 3)
    z = np.abs(u[:, 2])
    rho = np.sqrt(np.clip(1 - z, 0, 1))                 # r / sqrt(2) on the hemisphere
    h = np.hypot(u[:, 0], u[:, 1])
    s = np.where(h > 0, rho / np.where(h > 0, h, 1), 0.0)
    x = u[:, 0] * s
    x = np.where(u[:, 2] < 0, -x, x)
    return np.column_stack([x, u[:, 1] * s])


def coverage_figure(acc_g: np.ndarray, cover_angle_deg: float = 25.0, title: str = "",
                    next_orientation: Optional[str] = None):
    plt = pyplot("--plot")
    A = np.asarray(acc_g, float).reshape(-1, 3)
    U = A / np.linalg.norm(A, axis=1, keepdims=True) if len(A) else A
    covered = (TARGETS @ U.T).max(1) >= np.cos(np.radians(cover_angle_deg)) if len(U) else \
        np.zeros(len(TARGETS), bool)
    fig, axes = plt.subplots(1, 2, figsize=(9.6, 5.0))
    for ax, sign, name in ((axes[0], 1, "+Z hemisphere (seen from +Z)"),
                           (axes[1], -1, "-Z hemisphere (seen from -Z)")):
        ax.add_patch(plt.Circle((0, 0), 1.0, fill=False, color="0.5"))
        ax.add_patch(plt.Circle((0, 0), np.sqrt(0.5), fill=False, color="0.85", ls=":"))
        pick = (U[:, 2] >= 0) if sign > 0 else (U[:, 2] < 0)
        if len(U) and pick.any():
            p = lambert_disc(U[pick])
            ax.plot(p[:, 0], p[:, 1], "o", ms=5, color="C0", alpha=0.7, label="pose collected")
        tp = (TARGETS[:, 2] > 1e-9) if sign > 0 else (TARGETS[:, 2] < -1e-9)
        eq = np.abs(TARGETS[:, 2]) < 1e-9            # the equator belongs to both discs
        for i in np.flatnonzero(tp | eq):
            v = TARGETS[i].copy()
            if sign < 0 and eq[i]:
                v[2] = -1e-12                           # on the equator: drawn on both discs
            q = lambert_disc(v)[0]
            nm = target_name(TARGETS[i])
            if covered[i]:
                ax.plot(*q, "s", ms=9, color="C2", alpha=0.8)
            else:
                ax.plot(*q, "s", ms=11, mfc="none", mec="C3", mew=2)
            bold = "bold" if nm == next_orientation else "normal"
            ax.annotate(nm.replace(" up", ""), q, textcoords="offset points", xytext=(0, 8),
                        ha="center", fontsize=7, weight=bold, color="C3" if not covered[i] else "0.3")
        ax.set_xlim(-1.15, 1.15)
        ax.set_ylim(-1.15, 1.15)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(name, fontsize=9)
    axes[0].plot([], [], "s", color="C2", label="orientation covered")
    axes[0].plot([], [], "s", mfc="none", mec="C3", mew=2, label="orientation missing")
    axes[0].legend(loc="lower left", fontsize=7, bbox_to_anchor=(0, -0.12))
    n_cov = int(covered.sum())
    fig.suptitle((title + ": " if title else "") + f"{len(U)} poses, {n_cov}/{len(TARGETS)} "
                 "orientations covered" + (f"; next: {next_orientation}" if next_orientation else ""),
                 fontsize=10)
    return fig


def write_coverage(path: str, acc_g: np.ndarray, cover_angle_deg: float = 25.0, title: str = "",
                   next_orientation: Optional[str] = None, flag: str = "--plot") -> str:
    """Draw the coverage sphere of the pose means ``acc_g`` (N, 3) into ``path`` (.png/.svg)."""
    return save(coverage_figure(acc_g, cover_angle_deg, title, next_orientation), path, flag)
