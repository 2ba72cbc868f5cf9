"""Issue 25's tremor-robust gyro twin, end to end: on simulated hand-held sessions with
nothing injected (MPU-6050, 30 poses of 1.5-3 s, tremor 1.5 deg/s RMS, 100 Hz), `gap`'s
gyro ratio (held-out RMS over its twin's median) lies within 0.8-1.25 and the gyro's
verdict is "none"."""
import numpy as np

from imucald.gap.diagnose import diagnose
from imucald.sim.effects import effect_session
from imucald.sim.orientations import random_pose_set


def test_hand_held_gyro_twin_ratio_is_near_one():
    """20 sessions (seeds 0-19, ``diagnose(sims=100)``).  Each ratio's own sampling error is
    about 1 / sqrt(2 x 87 residuals) = 0.076, so an honest twin leaves a session outside
    0.8-1.25 about 1 time in 100; the median of 20 has an error of ~0.021, and the bound
    0.9-1.1 on it is 5 of those.  Seen to fail with the tremor's white part read from the
    structure function's own split (fitting/noise/posecov.py before the holds' halves:
    median 0.84, 6 of 20 below 0.8).  The white part itself is not tested here (at 1.5 deg/s
    of tremor it is a few per cent of a pose mean's variance; a cold review found this test
    passing with it doubled, halved or dropped): tests/test_posecov.py tests it.  No sway:
    with one the twin stays pessimistic (docs/methods/gap.md)."""
    ratios, verdicts = [], []
    for seed in range(20):
        g = np.random.default_rng(seed)
        s, _ = effect_session("mpu6050", random_pose_set(30, g), g, [], rate_hz=100,
                              hold_s=(1.5, 3), move_s=(1.5, 3), tremor_dps=1.5)
        gy = diagnose(s.recording, sims=100, seed=seed)["sensors"]["gyro"]
        ratios.append(round(gy["ratio_before"], 3))
        verdicts.append(gy["verdict"])
    assert 0.9 < np.median(ratios) < 1.1, ratios
    assert all(0.8 <= r <= 1.25 for r in ratios), ratios
    assert set(verdicts) == {"none"}, verdicts


def test_hand_held_sway_the_tilt_test_misses_is_not_read_as_colour():
    """A swaying hand (0.1 deg at 0.2-2 Hz) over the tremor, on three of the five sessions
    of seeds 0-9 whose sway the tilt test misses (0, 3, 5; also 8, 9): the accelerometer's
    colour inside the poses is read on the radial component, where the norm model sees the
    noise, so the slow tangential sway is not colour.  The sensor noise is white: the
    inflation stays below 2 (a white column reads 2 or more by chance about 2 % of the
    time, measured by a cold review; fixed seeds, so the outcome is fixed).  Its twin ratio
    then lies above 1 - 4 sampling standard deviations (1 / sqrt(2 dof)).  Seen to fail
    with the colour read per axis: inflation 3.9, 3.7 and 3.4, ratios 0.34, 0.28 and 0.30.
    The ratios are still below 1 (0.68, 0.53, 0.55): the per-axis pose-mean variance holds
    the sway's tangential part, and the radial one's white figure the lever arm's tremor
    (0.70, 0.54, 0.57); the structure function on the radial column read 1.09, 0.74, 0.93
    here but called some replicas of an independent probe's null a gap.  So they are not
    asserted near 1."""
    for seed in (0, 3, 5):
        g = np.random.default_rng(seed)
        s, _ = effect_session("mpu6050", random_pose_set(30, g), g, [], rate_hz=100,
                              hold_s=(1.5, 3), move_s=(1.5, 3), tremor_dps=1.5, sway_deg=0.1)
        a = diagnose(s.recording, sensors=["accel"], sims=100, seed=seed)["sensors"]["accel"]
        colour = a["noise_colour"]
        assert not colour["pose_mean_variance"]["tilt_wander"]["wander"], seed   # the case tested
        assert colour["within_pose"]["inflation"] < 2.0, (seed, colour["within_pose"])
        assert a["ratio_before"] > 1 - 4 / np.sqrt(2 * a["dof"]), (seed, a["ratio_before"])
        assert a["verdict"] == "none", (seed, a["verdict"])
