"""calibrate --sensor gyro --model eq6 (paper 002's eq. 6 over the still samples): the
samples are the poses' own (imucald/cli/offline.py _fit_gyro_poses)."""
import argparse

import numpy as np

from imucald.cli import offline
from imucald.fitting.stillness.poses import poses_and_pieces
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import simulate_session


def test_eq6_fits_the_samples_the_poses_were_averaged_from(monkeypatch):
    """With the user's detector options (--threshold-k 3 here) the eq6 fit takes exactly the
    distinct rows averaged into the still poses: as many as the poses count, with their
    count-weighted mean rate (within 1e-12 dps).  Seen to fail with the old second detection
    (detect_static at its defaults, without the chip, 37-66 ms more): 5497 samples against
    the poses' 5494, from stretches the detector cut otherwise."""
    rng = np.random.default_rng(4)
    rec = simulate_session("mpu6050", random_pose_set(12, rng), rng, hold_s=5.0, move_s=(1.5, 3.0),
                           lead_s=0.0).recording
    poses, _ = poses_and_pieces(rec, k=3.0, chip="mpu6050")
    seen = {}
    real = offline.__dict__.get("fit_gyro_bias")
    import imucald.fitting.fit as fit_mod
    orig = fit_mod.fit_gyro_bias

    def capture(means, counts, cov, model, samples, rng=None):
        seen["samples"] = samples
        return orig(means, counts, cov, model, samples, rng=rng)

    monkeypatch.setattr(fit_mod, "fit_gyro_bias", capture)
    args = argparse.Namespace(input="sim.csv", seed=1)
    offline._fit_gyro_poses(args, rec, poses, poses.detector, "eq6")
    assert real is None                 # offline imports it at the call (what the capture relies on)
    s = seen["samples"]
    assert len(s) == int(poses.n.sum()), (len(s), int(poses.n.sum()))
    np.testing.assert_allclose(s.mean(0), poses.n @ poses.gyro / poses.n.sum(), rtol=0, atol=1e-12)
