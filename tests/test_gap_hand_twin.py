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
