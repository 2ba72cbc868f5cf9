"""Paper metrics: equivalent-path error and roll/pitch."""
import numpy as np
import pytest

from imucald.fitting.fit import fit_norm
from imucald.fitting.judging.metrics import G0_M_S2, path_error, roll_pitch_deg
from imucald.fitting.models.accel import Triangular9
from imucald.sim.orientations import random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, simulate_pose_means


def test_path_error_of_constant_norm_error_is_half_g_t_squared():
    # a pose whose norm is 1 + e for 20 s: ds(20) = e * g0 * 20^2 / 2 (exact for constant a)
    e = 1e-3
    t, mean, std = path_error([np.array([[0, 0, 1 + e]]), np.array([[0.6 * (1 + e), 0.8 * (1 + e), 0]])], 50.0)
    assert mean[-1] == pytest.approx(e * G0_M_S2 * 400 / 2, rel=1e-9)
    assert std[-1] == pytest.approx(0, abs=1e-9)


def test_calibration_shrinks_path_error():
    rng = np.random.default_rng(9)
    tr = draw_truth("mpu6050", rng).accel
    ups = up_vectors(random_pose_set(25, rng))
    raw, cov = simulate_pose_means(tr, ups, 63e-6, rng)
    cal = fit_norm(raw, "triangular9", "lm", pose_cov=cov, heldout=False)
    corr = Triangular9().forward(cal.theta, raw)
    _, _, sd_raw = path_error([r[None] for r in raw], 50.0)
    _, _, sd_cal = path_error([c[None] for c in corr], 50.0)
    assert sd_cal[-1] < sd_raw[-1] / 50


def test_roll_pitch():
    r, p = roll_pitch_deg(np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0], [0, np.sin(0.3), np.cos(0.3)]]))
    assert np.allclose(r, [0, 90, 0, np.degrees(0.3)])
    assert np.allclose(p, [0, 0, 90, 0])
