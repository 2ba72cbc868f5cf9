"""Pose sets: orientations of the board, as rotation matrices and gravity directions.

Frames: the world frame is z up.  ``R`` maps body vectors to world vectors; a
static accelerometer measures the specific force  f_body = R^T (0, 0, 1) g,
i.e. +1 g along whichever body axis points up.
"""
from __future__ import annotations


import numpy as np

from ..numerics.rng import RngLike, as_rng

from ..fitting.judging.coverage import sphere_lattice

__all__ = ["euler_pose_set", "random_pose_set", "up_vectors", "rotation_from_up",
           "axis_angle", "small_rotation"]




def axis_angle(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix from a unit axis and an angle (Rodrigues)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * (K @ K)


def small_rotation(rng: np.random.Generator, sigma_rad: float) -> np.ndarray:
    """A random rotation whose rotation vector is N(0, sigma^2 I)."""
    v = rng.normal(scale=sigma_rad, size=3)
    ang = np.linalg.norm(v)
    return np.eye(3) if ang == 0 else axis_angle(v / ang, ang)


def rotation_from_up(up_body: np.ndarray, yaw_rad: float = 0.0) -> np.ndarray:
    """A body->world rotation R with R @ up_body = world z, then yawed about world z."""
    u = np.asarray(up_body, float)
    u = u / np.linalg.norm(u)
    z = np.array([0.0, 0.0, 1.0])
    c = float(u @ z)
    if c > 1 - 1e-12:
        R = np.eye(3)
    elif c < -1 + 1e-12:
        R = axis_angle(np.array([1.0, 0, 0]), np.pi)
    else:
        ax = np.cross(u, z)
        R = axis_angle(ax / np.linalg.norm(ax), np.arccos(c))
    return axis_angle(z, yaw_rad) @ R


def up_vectors(R: np.ndarray) -> np.ndarray:
    """Gravity reaction (specific force, g) in the body frame for rotations R (..., 3, 3)."""
    return np.asarray(R)[..., 2, :]          # R^T e_z = third row of R


def euler_pose_set(nx: int, ny: int, nz: int, rng: RngLike = None,
                   jitter_deg: float = 3.0) -> np.ndarray:
    """Paper 000's pose set: N_k orientations by rotation about body axis k.

    For axis k the up vector sweeps the body plane perpendicular to k at angles
    2 pi j / N_k plus a random phase; every pose then gets a random hand-placement
    tilt of ``jitter_deg`` (rms per axis) and a random yaw.  Without rotation
    about z (nz = 0) no pose has gravity in the x-y plane, which leaves alpha_yz
    poorly determined, as the paper finds.  Returns R (nx+ny+nz, 3, 3).
    """
    rng = as_rng(rng)
    out = []
    for axis, n in enumerate((nx, ny, nz)):
        if n <= 0:
            continue
        a, b = [i for i in range(3) if i != axis]
        phase = rng.uniform(0, 2 * np.pi)
        for j in range(n):
            phi = phase + 2 * np.pi * j / n
            up = np.zeros(3)
            up[a], up[b] = np.cos(phi), np.sin(phi)
            R = rotation_from_up(up, rng.uniform(0, 2 * np.pi))
            out.append(R @ small_rotation(rng, np.deg2rad(jitter_deg)))
    return np.array(out).reshape(-1, 3, 3)


def random_pose_set(n: int, rng: RngLike = None, jitter_deg: float = 3.0) -> np.ndarray:
    """n well-spread orientations: a randomly rotated spherical Fibonacci lattice of
    up vectors, each with hand jitter and a random yaw.  Returns R (n, 3, 3)."""
    rng = as_rng(rng)
    ups = sphere_lattice(n)
    Q = small_rotation(rng, 10.0)  # large sigma: effectively a random rotation
    ups = ups @ Q.T
    rng.shuffle(ups)
    return np.array([rotation_from_up(u, rng.uniform(0, 2 * np.pi))
                     @ small_rotation(rng, np.deg2rad(jitter_deg)) for u in ups])
