"""`gap` on accelerometer nulls whose noise is coloured on a time scale of the holds (an
AR(1) of 0.1 s beside the white noise, short holds, no long still stretch for an Allan
figure): nothing is injected, so the verdict should be "none" and the twin ratio near 1."""
import math

import numpy as np
from scipy.signal import lfilter

from imucald.files.recording import Recording
from imucald.gap.diagnose import diagnose


def _coloured_null(seed, tau_s=0.1, ar_g=1.5e-3, white_g=3e-3, rate=100.0, n_poses=30):
    """30 random orientations held 1.5-3 s, eased turns between them, a fixed affine sensor
    error, white noise (3 mg a sample) and an AR(1) noise of ``tau_s`` (1.5 mg) on each axis:
    its share of a pose mean's variance is ~5x the white noise's, of a sample's 1/4."""
    rng = np.random.default_rng(seed)
    U = rng.normal(size=(n_poses, 3))
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    rows = []
    for i, u in enumerate(U):
        rows.append(np.repeat(u[None], int(rng.uniform(1.5, 3.0) * rate), 0))
        if i + 1 < n_poses:
            m, v = int(rng.uniform(1.5, 3.0) * rate), U[i + 1]
            ang = math.acos(float(np.clip(u @ v, -1, 1)))
            s = 0.5 - 0.5 * np.cos(np.pi * np.arange(m) / m)
            w = (np.sin((1 - s) * ang)[:, None] * u + np.sin(s * ang)[:, None] * v) / max(math.sin(ang), 1e-9)
            rows.append(w / np.linalg.norm(w, axis=1, keepdims=True))
    f = np.concatenate(rows)
    n = len(f)
    A = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    phi = math.exp(-1.0 / (rate * tau_s))
    ar = lfilter([1.0], [1.0, -phi], rng.normal(size=(n, 3)) * ar_g * math.sqrt(1 - phi * phi), axis=0)
    acc = f @ A.T + rng.normal(0, 0.03, 3) + ar + rng.normal(size=(n, 3)) * white_g
    return Recording(t=np.arange(n) / rate, acc=acc, meta={"rate_hz": f"{rate:g}"})


def test_colour_on_the_holds_time_scale_is_in_the_twin():
    """8 seeds: at most 1 false alarm, and the median twin ratio within 0.25 of 1 (one
    session's ratio scatters by ~1 / sqrt(2 x 21 dof) = 0.15, a median of 8 by ~0.07).  The
    colour is read by the radial series' structure function, two-sided (it reads 3.4-4.5x
    the white figure here; seen: no false alarm, median 1.08).  Seen to fail with the
    radial reading's larger figure not taken (gap/diagnose.py ``_accel_pose_noise``), the
    colour left to the within-pose inflation alone: 7 false alarms of 8, median ratio ~1.8
    (5 of 8, median 1.65, with that inflation read per axis, as before this round)."""
    ratios, alarms = [], 0
    for seed in range(8):
        a = diagnose(_coloured_null(seed), sensors=["accel"], sims=100, seed=seed)["sensors"]["accel"]
        ratios.append(a["ratio_before"])
        alarms += a["verdict"] != "none"
    assert alarms <= 1, (alarms, ratios)
    assert abs(np.median(ratios) - 1) < 0.25, ratios
