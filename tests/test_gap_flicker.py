"""Flicker (1/f, bias instability) in the gap twin: the part slower than a hold scatters the
pose means about their common mean, and no within-pose figure sees it (gap/posenoise.py
``flicker_between_poses``).  A cold helper's gyro nulls with an Allan floor near a real
MPU-6050's (0.002 dps, B ~ 11 deg/h; this project's real 10-min MPU-6050 recording reads
0.001-0.003 dps at 30-100 s) were called a gap in 18 of 20 before it."""
import numpy as np

from imucald.gap.diagnose import diagnose
from imucald.gap.posenoise import flicker_between_poses, flicker_level
from imucald.sim.effects import effect_session
from imucald.sim.orientations import random_pose_set


def _pink(rng, n, rate_hz, h, dims=3):
    """(n, dims) noise of one-sided PSD h / f above 1 / (8 n / rate) (this file's own FFT
    generator, not the project's simulator), units^2 / Hz * Hz = units^2."""
    m = 1
    while m < 8 * n:
        m *= 2
    f = np.fft.rfftfreq(m, 1.0 / rate_hz)
    amp = np.zeros_like(f)
    amp[1:] = np.sqrt(h / f[1:])
    out = np.empty((n, dims))
    for d in range(dims):
        z = rng.standard_normal(len(f)) + 1j * rng.standard_normal(len(f))
        out[:, d] = np.fft.irfft(z * amp * np.sqrt(rate_hz * m / 4.0), m)[:n]
    return out


def _holds(rng, n_poses=30, rate_hz=100.0, gap_s=3.0):
    """Slices of n_poses holds of 3-12 s with gap_s between them, and the sample count."""
    sl, i = [], 0
    for _ in range(n_poses):
        k = int(rng.uniform(3, 12) * rate_hz)
        sl.append(slice(i, i + k))
        i += k + int(gap_s * rate_hz)
    return sl, i


def test_flicker_level_is_read_inside_the_holds():
    """White noise of 0.005 dps/rtHz at 100 Hz (0.035 dps a sample: the density over the
    50-Hz Nyquist band) plus flicker of h = 3e-6 dps^2 (an Allan floor of 0.002 dps) in 30
    holds of 3-12 s, 12 seeds: the mean of the 36 axis estimates over h lies within
    0.6-1.4 (one estimate scatters by ~0.83 h, measured on 30 seeds; a mean of 36,
    correlated within a seed, by ~0.14: the band is 3 of those), and the gate passes in at
    least 6 of 12 (75 % each, measured on 60: fewer than 6 about 1 time in 70).  White
    noise alone passes it in at most 1 of 10 seeds (2 % each, measured on 200: 2 or more
    in 10 about 1 time in 60).  Seen to fail with the jackknife's (m - 1) factor dropped
    from flicker_level (standard errors sqrt(m) too small): white noise passed in 7 of 10.
    Not caught here: the flicker factor FLICKER_HVAR_PER_H taken as the Allan one's
    (2 ln 2, estimates 19 % low); the test below catches that (5 of 8 "none")."""
    h, ratios, passed = 3e-6, [], 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        sl, n = _holds(rng)
        x = rng.normal(size=(n, 3)) * 0.005 * np.sqrt(50.0) + _pink(rng, n, 100.0, h)
        est, se = flicker_level(x, sl, 100.0)
        ratios += (est / h).tolist()
        passed += flicker_between_poses(x, sl, 100.0)[1]["added"]
    assert 0.6 < np.mean(ratios) < 1.4, np.round(ratios, 2)
    assert passed >= 6, passed
    passed = 0
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        sl, n = _holds(rng)
        x = rng.normal(size=(n, 3)) * 0.005 * np.sqrt(50.0)
        add, info = flicker_between_poses(x, sl, 100.0)
        passed += info["added"]
        assert info["added"] or not add.any()
    assert passed <= 1, passed


def test_gyro_flicker_null_is_not_a_gap():
    """Simulated MPU-6050 sessions (30 poses held 3-12 s, nothing injected) with gyro flicker
    of an Allan floor of 0.002 dps added: the gyro's verdict is "none" in at least 7 of 8
    seeds and the median twin ratio lies within 0.2 of 1 (one session's ratio scatters by
    ~1 / sqrt(2 x 87) = 0.076; the median of 8 by ~0.03; seen: 7 of 8, median 1.00, the
    gate passed in 6 of 8).  Seen to fail with the flicker between poses left out of the
    twin (gap/diagnose.py ``_gyro_step``): 8 of 8 called a gap, ratios 1.38-1.68."""
    ratios, verdicts = [], []
    for seed in range(8):
        g = np.random.default_rng(seed)
        s, _ = effect_session("mpu6050", random_pose_set(30, g), g, [], rate_hz=100,
                              hold_s=(3, 12), move_s=(1.5, 3))
        rec = s.recording
        rec.gyro = rec.gyro + _pink(np.random.default_rng(1000 + seed), len(rec.t), 100.0,
                                    0.002 ** 2 / (2 * np.log(2)))
        gy = diagnose(rec, sensors=["gyro"], sims=100, seed=seed)["sensors"]["gyro"]
        ratios.append(round(gy["ratio_before"], 3))
        verdicts.append(gy["verdict"])
    assert sum(v == "none" for v in verdicts) >= 7, (verdicts, ratios)
    assert abs(np.median(ratios) - 1) < 0.2, ratios


def test_no_hold_of_32_samples_reads_no_flicker():
    """Holds of 31 samples (10 Hz, 3.1 s) give no Hadamard rows: nothing is added and the
    note says why.  Seen to fail (ValueError from reshaping no rows: the whole `gap` run
    ended in a traceback, a cold review's 10-Hz recordings with 2-s holds) before
    _hadamard_rows shaped its empty result by the columns."""
    rng = np.random.default_rng(0)
    sl = [slice(i * 40, i * 40 + 31) for i in range(20)]
    add, info = flicker_between_poses(rng.normal(size=(800, 3)), sl, 10.0)
    assert add.shape == (20, 3) and not add.any()
    assert "fewer than 3 poses of 32 samples" in info["note"]


def test_a_swaying_hand_is_not_read_as_flicker():
    """Hand-held sessions (tremor 1.5 deg/s, sway 0.3 deg, 25 poses of 3-6 s, seeds 0-3):
    the hand's slow turning inside the holds fills their long-tau Hadamard variances, and
    the sway test (4.0-6.2 of its standard errors here) stops the flicker reading, so the
    gyro twin stays near its held-out residual: each ratio above 0.5 (seen 0.73-1.07; the
    twin under a sway is pessimistic anyway, docs/methods/gap.md).  Seen to fail with the
    sway left out of gap/diagnose.py's ``read`` mask: the gate passed in 4 of 4 and the
    ratios fell to 0.10-0.14."""
    for seed in range(4):
        g = np.random.default_rng(seed)
        s, _ = effect_session("mpu6050", random_pose_set(25, g), g, [], rate_hz=100, hold_s=(3, 6),
                              move_s=(1.5, 3), tremor_dps=1.5, sway_deg=0.3)
        gy = diagnose(s.recording, sensors=["gyro"], sims=100, seed=seed)["sensors"]["gyro"]
        assert "no flicker read" in gy["noise_colour"]["flicker_between_poses"].get("note", ""), seed
        assert gy["ratio_before"] > 0.5, (seed, gy["ratio_before"])
