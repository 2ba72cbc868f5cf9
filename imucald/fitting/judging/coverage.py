"""Pose coverage: the 26 directions of a cube's faces, edges and corners, and which
of them a set of poses reaches (the daemon's guidance and gap's advice use it)."""
from __future__ import annotations

from typing import Dict

import numpy as np

__all__ = ["TARGETS", "target_name", "target_vector", "cube_coverage", "sphere_lattice", "next_orientation"]


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


def target_vector(name: str) -> np.ndarray:
    """The unit up vector (sensor frame) of a cube direction named as by :func:`target_name`."""
    v = np.zeros(3)
    body = name.replace(" up", "")
    for i in range(0, len(body), 2):
        v["XYZ".index(body[i + 1])] = 1.0 if body[i] == "+" else -1.0
    return v / np.linalg.norm(v)


def next_orientation(missing, hinted: Dict[str, int], up=None):
    """The missing cube direction to ask for next, so that the hint moves through the
    missing ones instead of repeating one the user does not (or cannot) reach: the one
    asked for fewest times so far (``hinted``: name -> times asked), then faces before
    edges before corners (easiest to place), then the nearest to the current up vector
    ``up`` (sensor frame; the smallest turn), then the order of ``missing``.  None when
    nothing is missing.  Pure: the caller counts what it asked for."""
    if not missing:
        return None
    u = None
    if up is not None:
        u = np.asarray(up, float)
        n = np.linalg.norm(u)
        u = u / n if n > 0 and np.all(np.isfinite(u)) else None

    def key(item):
        i, name = item
        turn = 0.0 if u is None else -float(target_vector(name) @ u)
        return (hinted.get(name, 0), name.count("+") + name.count("-"), turn, i)

    return min(enumerate(missing), key=key)[1]


def orientation_groups(acc_mean_g: np.ndarray, tol_deg: float = 20.0) -> np.ndarray:
    """Label poses whose gravity directions lie within ``tol_deg`` of a group's first pose
    (the gap diagnosis's orientations; calibrate refuses poses all in one)."""
    u = acc_mean_g / np.linalg.norm(acc_mean_g, axis=1, keepdims=True)
    lab = -np.ones(len(u), int)
    heads = []
    c = np.cos(np.radians(tol_deg))
    for i, v in enumerate(u):
        for k, h in enumerate(heads):
            if v @ h >= c:
                lab[i] = k
                break
        else:
            heads.append(v)
            lab[i] = len(heads) - 1
    return lab
