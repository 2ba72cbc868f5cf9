"""Pose coverage: the 26 directions of a cube's faces, edges and corners, and which
of them a set of poses reaches (the daemon's guidance and gap's advice use it)."""
from __future__ import annotations

from typing import Dict

import numpy as np

__all__ = ["TARGETS", "target_name", "cube_coverage", "sphere_lattice"]


def sphere_lattice(n: int) -> np.ndarray:
    """n near-uniform unit vectors (n, 3) over the sphere (spherical Fibonacci lattice):
    the one lattice for pose sets, direction cells and dense checks over all directions."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _targets() -> np.ndarray:
    out = []
    for x in (-1, 0, 1):
        for y in (-1, 0, 1):
            for z in (-1, 0, 1):
                if (x, y, z) != (0, 0, 0):
                    v = np.array([x, y, z], float)
                    out.append(v / np.linalg.norm(v))
    return np.array(out)


#: the 26 cube directions (faces, edges, corners), as up vectors in the sensor frame
TARGETS = _targets()


def target_name(v: np.ndarray) -> str:
    """'+Z up', '+X+Y up' ... for a cube direction."""
    parts = [f"{'+' if c > 0 else '-'}{ax}" for c, ax in zip(v, "XYZ") if abs(c) > 1e-9]
    return "".join(parts) + " up"


def cube_coverage(directions: np.ndarray, cover_angle_deg: float = 25.0) -> Dict[str, object]:
    """Fraction of the 26 cube directions within ``cover_angle_deg`` of one of the unit
    ``directions`` (N, 3), and the missing ones, faces first (easiest to place), then
    edges, corners."""
    U = np.asarray(directions, float).reshape(-1, 3)
    if len(U):
        covered = (TARGETS @ U.T).max(1) >= np.cos(np.radians(cover_angle_deg))
    else:
        covered = np.zeros(len(TARGETS), bool)
    missing = [target_name(TARGETS[i]) for i in np.flatnonzero(~covered)]
    missing.sort(key=lambda s: s.count("+") + s.count("-"))
    return {"fraction": float(covered.mean()), "covered": int(covered.sum()),
            "targets": len(TARGETS), "missing": missing}
