"""Pose-mean noise beyond the sample noise over n (imucald/fitting/noise/posefloor.py): the
quantisation floor, the net rotation of a swaying hand, held columns, and the chance
repeats of an un-dithered converter (fitting/stillness/repeats.py).  Each test names the breakage it
was seen to catch."""
import math

import numpy as np

from imucald.fitting.noise.posefloor import (
    estimate_lsb, noise_before_quantisation, quantisation_floor, run_effective_counts,
    sway_rotation_variance, tilt_wander_test
)
from imucald.fitting.stillness.repeats import find_repeats


def test_quantisation_floor_matches_monte_carlo():
    """The variance over poses of a pose mean's error (true value uniform within the LSB,
    Gaussian noise of 0.1, 0.25 and 0.4 LSB, 400 samples) equals the floor V_q(s) plus the
    quantised samples' variance over n, within 4 standard errors of the Monte Carlo mean.
    Breakage caught: the floor without its noise damping (LSB^2/12 at any noise: 4x too
    large at 0.25 LSB); a factor pi^2 k^2 in place of 2 pi^2 k^2 in the series."""
    rng = np.random.default_rng(5)
    lsb, n, M = 1.0, 400, 3000
    for s in (0.1, 0.25, 0.4):
        mu = rng.uniform(0, lsb, M)
        q = np.round((mu[:, None] + rng.normal(0, s, (M, n))) / lsb) * lsb
        err2 = (q.mean(1) - mu) ** 2
        vq = float(np.mean(q.var(1, ddof=1)))
        pred = float(quantisation_floor(lsb, s)) + vq / n
        se = float(np.std(err2) / math.sqrt(M))
        assert abs(err2.mean() - pred) < 4 * se, (s, err2.mean(), pred, se)
        # the noise before the quantiser from the quantised samples' variance (averaged over mu):
        # its sampling error over M poses is far below 2 %
        assert abs(float(noise_before_quantisation(vq, lsb)[0]) - s) < 0.02 * s + 0.005


def test_estimate_lsb_from_distinct_values():
    """The step of a quantised column from its distinct values, 0 for a continuous one.
    Breakage caught: the smallest spacing taken as the step without the distinct-level
    count and the grid check (a continuous column got a step)."""
    rng = np.random.default_rng(1)
    x = np.vstack([c + rng.normal(0, 0.002, (200, 3)) for c in rng.normal(0, 0.5, (10, 3))])
    sl = [slice(i * 200, i * 200 + 200) for i in range(10)]
    assert np.all(estimate_lsb(x, sl) == 0)
    q = np.round(x / 0.0039) * 0.0039
    np.testing.assert_allclose(estimate_lsb(q, sl), 0.0039, rtol=1e-6)


def _sway_poses(rng, N, n, rate, sway_deg, acc_sd_g, gyro_sd_dps):
    """Pose slices of accelerometer (g) and gyro (dps) samples with a band-limited angular
    wander (0.2-2 Hz, sway_deg RMS per axis) inside each hold; returns the true per-axis
    net rotation rate of each pose (dps) across its gravity direction."""
    t = np.arange(n) / rate
    acc, gyro, truth = [], [], []
    for _ in range(N):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        f = rng.uniform(0.2, 2.0, (6, 3))
        ph = rng.uniform(0, 2 * np.pi, (6, 3))
        ang = np.sum(np.sin(2 * np.pi * t[:, None, None] * f[None] + ph[None]), 1)
        rate_deg = np.sum(2 * np.pi * f[None] * np.cos(2 * np.pi * t[:, None, None] * f[None] + ph[None]), 1)
        k = sway_deg / 1.73
        ang, rate_deg = ang * k, rate_deg * k
        th = np.radians(ang)
        acc.append(u[None, :] - np.cross(th, u[None, :]) + rng.normal(0, acc_sd_g, (n, 3)))
        gyro.append(np.array([0.5, -0.3, 0.2]) + rate_deg + rng.normal(0, gyro_sd_dps, (n, 3)))
        d = rate_deg.mean(0)                        # the hold's net rotation over its length
        truth.append(d - (d @ u) * u)
    sl = [slice(i * n, (i + 1) * n) for i in range(N)]
    return np.vstack(acc), np.vstack(gyro), sl, np.array(truth)


def test_sway_net_rotation_variance():
    """The accelerometer-seen net rotation of a swaying hold: its angle variance (over the
    two components across gravity) within 3 of its standard errors of the true one, and on
    a still bench clear of zero by less than 3 standard errors.  Breakage caught: window
    means of the first and last eighth in place of the line through the tilt minus the
    gyro's bridge (a 1-2 Hz sway smoothed away: S = 0.042 deg^2 against 0.258); the gyro's
    bridge left out of that line (S = 0.022)."""
    rng = np.random.default_rng(11)
    rate, n, N = 200.0, 800, 30
    acc, gyro, sl, truth = _sway_poses(rng, N, n, rate, 0.25, 0.005, 0.07)
    _, info = sway_rotation_variance(acc, gyro, sl, rate)
    T = n / rate
    S_true = float(np.mean(np.sum(truth ** 2, 1))) * T ** 2
    assert info["used"]
    assert abs(info["net_rotation_variance_deg2"] - S_true) < 3 * info["stderr_deg2"], (info, S_true)
    acc0, gyro0, sl0, _ = _sway_poses(rng, N, n, rate, 0.0, 0.005, 0.07)
    v0, info0 = sway_rotation_variance(acc0, gyro0, sl0, rate)
    assert abs(info0["net_rotation_variance_deg2"]) < 3 * info0["stderr_deg2"]


def test_tilt_wander_seen_across_gravity_only():
    """The accelerometer's direction wander (0.25 deg sway against 5 mg noise: tangential
    variance 1.8x the radial) is seen; isotropic noise alone is not (the statistic within
    3 of its standard errors of 0).  Breakage caught: the radial variance not taken out of
    the trace (tangential = trace / 2: the statistic log 1.5 on isotropic noise)."""
    rng = np.random.default_rng(12)
    acc, gyro, sl, _ = _sway_poses(rng, 30, 800, 200.0, 0.25, 0.005, 0.07)
    assert tilt_wander_test(acc, sl)["wander"]
    acc0, _, sl0, _ = _sway_poses(rng, 30, 800, 200.0, 0.0, 0.005, 0.07)
    t0 = tilt_wander_test(acc0, sl0)
    assert abs(t0["log_tangential_over_radial"]) < 3 * t0["stderr"]


def test_held_runs_and_undithered_repeats():
    """A column held 5-6 rows (a 75 Hz magnetometer in a 400 Hz log) counts its distinct
    readings (n^2 / sum of run lengths^2); an un-dithered quantised accelerometer (noise
    0.15 LSB, still poses between turns) is not called held.  Breakage caught: the chance of
    a whole-row repeat from whole-recording axis rates (the still poses' repeats and the
    turns' none multiplied apart): the un-dithered recording was called held."""
    rows = np.floor(np.arange(4000) * 75 / 400).astype(int)
    x = np.random.default_rng(2).normal(size=(rows[-1] + 1, 3))[rows]
    sl = [slice(0, 2000), slice(2000, 4000)]
    neff = run_effective_counts(x, sl)
    # runs of 5 and 6 rows (mean 5.33): n / (E[L^2] / E[L]) = n / 5.375, 0.8 % below n 75 / 400
    assert np.all(np.abs(neff - 2000 * 75 / 400) < 2000 * 75 / 400 * 0.02)
    rng = np.random.default_rng(3)
    parts = []
    for _ in range(25):
        c = rng.normal(0, 0.6, 3)
        parts.append(c + rng.normal(0, 0.15 * 0.0039, (300, 3)))           # still: 6 s at 50 Hz
        parts.append(c + np.linspace(0, 1, 100)[:, None] * rng.normal(0, 0.5, 3))     # a turn
    a = np.round(np.vstack(parts) / 0.0039) * 0.0039
    t = np.arange(len(a)) / 50.0
    assert not find_repeats(t, a, 50.0).held


def test_summary_orientation_excess_only_with_a_gap():
    """`gap` text: no "excess by orientation" line when the verdict is "none" (it printed
    "+X up 0%, +Y up 0%, +Z up 0%" when the ratio was below 1), and no 0 % entries when
    there is a gap.  Breakage caught: the line printed whenever region shares exist."""
    from imucald.cli.gap import gap_summary
    base = {"unit": "g", "ratio_before": 0.8, "ratio_after": 0.8, "p_value": 0.5, "heldout_rms": 1e-4,
            "twin_heldout_rms": 1.2e-4, "effects": []}
    none = dict(base, verdict="none", where={"region_share": {"+X": 0.0, "+Y": 0.0, "+Z": 0.0}})
    txt = gap_summary({"poses_found": 20, "sensors": {"accel": none}})
    assert "excess by orientation" not in txt
    gap = dict(base, verdict="unexplained", ratio_before=3.0,
               where={"region_share": {"+X": 0.7, "+Y": 0.3, "+Z": 0.0}})
    txt = gap_summary({"poses_found": 20, "sensors": {"accel": gap}})
    assert "excess by orientation: +X 70%, +Y 30%" in txt and "0%" not in txt.split("+Y 30%")[1]


def _hand_held(seed, sway=True):
    """A hand-held session: 22-31 random poses of 3-6 s, eased turns, tremor (6-12 Hz,
    0.3-3 dps) and, with ``sway``, a slow angular wander (0.2-2 Hz, 0.05-0.4 deg RMS per
    axis); MPU-6050 noise (400 ug/rtHz, 0.005 dps/rtHz), Earth's rate, nothing injected."""
    from imucald.files.recording import Recording

    from .blindgen2 import _quat_rate_body, _rot as rot, _slerp_path as slerp   # its quaternion helpers

    def band(t, lo, hi):
        f, ph, a = rng.uniform(lo, hi, (10, 3)), rng.uniform(0, 2 * np.pi, (10, 3)), rng.uniform(0.5, 1, (10, 3))
        arg = 2 * np.pi * f[None] * t[:, None, None] + ph[None]
        return np.einsum("ka,nka->na", a, np.sin(arg)), np.einsum("ka,nka->na", a * 2 * np.pi * f, np.cos(arg))

    rng = np.random.default_rng(777000 + seed * 31 + 2)
    rate = float(rng.choice([100., 200., 400.]))
    npose = int(rng.integers(22, 32))
    qs = [(lambda q: q / np.linalg.norm(q))(rng.normal(size=4)) for _ in range(npose)]
    Q = []
    for k, q in enumerate(qs):
        Q.append(np.repeat(q[None], int(rng.uniform(3.0, 6.0) * rate), 0))
        if k + 1 < npose:
            mm = int(rng.uniform(1.5, 3) * rate)
            Q.append(slerp(q, qs[k + 1], 0.5 - 0.5 * np.cos(np.pi * np.arange(mm) / mm)))
    Q = np.concatenate(Q)
    for i in range(1, len(Q)):
        if np.dot(Q[i], Q[i - 1]) < 0:
            Q[i] = -Q[i]
    n = len(Q)
    t = np.arange(n) / rate
    R = np.stack([rot(q) for q in Q])
    w = _quat_rate_body(Q, 1 / rate)
    f = np.einsum("nji,j->ni", R, np.array([0, 0, 1.0]))
    _, r_t = band(t, 6, 12)
    r_t *= rng.uniform(0.3, 3.0) / r_t.std(0)
    a_t = np.cumsum(r_t, 0) / rate
    w, ang = w + r_t, np.radians(a_t - a_t.mean(0))
    a_s, r_s = band(t, 0.2, 2.0)
    k = rng.uniform(0.05, 0.4) / a_s.std(0) * (1.0 if sway else 0.0)
    w, ang = w + r_s * k, ang + np.radians(a_s * k)
    f = f - np.cross(ang, f)
    T = 22 + rng.uniform(2, 6) * (1 - np.exp(-t / (0.3 * t[-1])))
    lat, head = math.radians(rng.uniform(-60, 60)), rng.uniform(0, 2 * np.pi)
    om = math.degrees(7.2921e-5)
    ew = om * np.array([math.cos(lat) * math.cos(head), math.cos(lat) * math.sin(head), math.sin(lat)])
    Ga = np.diag(1 + rng.normal(0, .02, 3)) + rng.normal(0, .005, (3, 3)) * (1 - np.eye(3))
    acc = f @ Ga.T + rng.normal(0, .03, 3)
    acc += rng.normal(size=(n, 3)) * 400e-6 * rng.uniform(.5, 1.5) * math.sqrt(rate / 2)
    gyro = (w + np.einsum("nji,j->ni", R, ew)) @ (np.eye(3) + rng.normal(0, .01, (3, 3))).T + rng.normal(0, 1, 3)
    gyro += rng.normal(size=(n, 3)) * 0.005 * rng.uniform(.5, 1.5) * math.sqrt(rate / 2)
    return Recording(t=t, acc=np.round(acc * 16384) / 16384, gyro=np.round(gyro * 131) / 131,
                     temp=np.round(T * 340) / 340, meta={"board": "dev", "rate_hz": f"{rate:g}"})


def test_gap_gyro_twin_under_sway():
    """`gap` on a swaying hand-held null (400 Hz): the gyro's held-out residual over its
    twin within 4 of its sampling sd of 1 (sd ~ 1 / sqrt(2 dof), dof = 3 N - 4), and the
    vertical Earth rate within 3 of its reported standard errors of Earth's.  Breakage
    caught: the sway's net rotation left out of the gyro pose means' variance (ratio 2.5,
    "unexplained")."""
    from imucald.gap.diagnose import diagnose
    rec = _hand_held(501)
    g = diagnose(rec, sensors=["accel", "gyro"], sims=100, seed=1)["sensors"]["gyro"]
    sd = 1 / math.sqrt(2 * g["dof"])
    assert abs(g["ratio_before"] - 1) < 4 * sd, (g["ratio_before"], sd)
    assert g["verdict"] == "none"
    assert abs(g["earth_rate_vertical_dps"]) < 0.0042 + 3 * g["earth_rate_vertical_dps_stderr"]
