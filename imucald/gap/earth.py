"""Earth's rotation in a still gyro's reading, as part of the twin (not an effect).

A gyro at rest reads its bias plus Earth's rate in the body frame,
Omega_E = 7.2921e-5 rad/s = 0.004178 deg/s (IERS value; WGS-84 uses the same).
Split along the local vertical u (from the accelerometer: the unit specific force,
body frame) and the horizontal:

* vertical: Omega_E sin(latitude) u, one unknown coefficient (the latitude is not
  known), a column of the baseline;
* horizontal: Omega_E cos(latitude) along north, whose body-frame direction
  depends on the heading, unknown without a magnetometer reference.  Over poses of
  random heading it acts as extra pose-to-pose scatter of variance
  Omega_h^2 (1 - u_j^2) / 2 on axis j (a horizontal vector of fixed length and
  uniform azimuth), added to the twin's noise.

With a 0.005 deg/s/sqrt(Hz) gyro and 10 s poses (1.6 mdeg/s per pose mean) the
horizontal part (2.8 mdeg/s at 48 deg latitude) is well above the noise: without
it every consumer-gyro pose set would show a "gap".
"""
from __future__ import annotations

import numpy as np

__all__ = ["EARTH_RATE_DPS", "vertical_column", "horizontal_variance", "earth_rate_report"]

EARTH_RATE_DPS = float(np.degrees(7.2921e-5))
#: the fitted vertical rate also holds any isotropic g-sensitivity, so it is capped at
#: the rate below 60 deg latitude (sin 60 = 0.866): the twin assumes a user below 60 deg
MAX_VERTICAL_DPS = EARTH_RATE_DPS * float(np.sin(np.radians(60.0)))


def vertical_column(u_body: np.ndarray) -> np.ndarray:
    """(3N, 1) design column: the vertical Earth rate's coefficient times u (stacked x, y, z per pose)."""
    u = u_body / np.linalg.norm(u_body, axis=1, keepdims=True)
    return u.reshape(-1, 1)


def horizontal_variance(u_body: np.ndarray, vertical_dps: float) -> np.ndarray:
    """(N, 3) extra variance per pose and axis, (deg/s)^2, from the horizontal Earth rate
    of unknown heading; ``vertical_dps`` is the fitted vertical component (capped)."""
    u = u_body / np.linalg.norm(u_body, axis=1, keepdims=True)
    v = min(abs(float(vertical_dps)), MAX_VERTICAL_DPS)
    h2 = EARTH_RATE_DPS ** 2 - v ** 2
    return h2 * (1.0 - u ** 2) / 2.0


def earth_rate_report(vertical_dps: float, stderr_dps: float) -> dict:
    """The fitted vertical rate with its standard error (scaled by the excess scatter) and
    what it says: not determined when its SE exceeds Earth's rate; beyond Earth's rate by
    more than 3 SE: it holds something else (an isotropic g-sensitivity, a residual net
    rotation of the hand)."""
    out = {"earth_rate_vertical_dps_stderr": float(stderr_dps)}
    if stderr_dps > EARTH_RATE_DPS:
        out["earth_rate_vertical_note"] = (f"not determined: its standard error {stderr_dps:.2g} dps exceeds "
                                           f"Earth's rate ({EARTH_RATE_DPS:.4f} dps)")
    elif abs(vertical_dps) - 3 * stderr_dps > EARTH_RATE_DPS:
        out["earth_rate_vertical_note"] = ("beyond Earth's rate by more than 3 standard errors: the term also "
                                           "holds an isotropic g-sensitivity (or a net rotation of the hand)")
    return out
