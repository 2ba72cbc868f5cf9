"""Simulator: truth within datasheet tolerances, noise at the datasheet density, ADC effects."""
import numpy as np
import pytest

from imucald.sim.poses import euler_pose_set, random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, pose_sigma, simulate_session, temperature_profile
from imucald.specs import ACCEL, BOARDS, GYRO, MAG


@pytest.mark.parametrize("board", list(BOARDS))
def test_truth_within_datasheet_tolerances(board):
    an, gn, mn = BOARDS[board]
    for seed in range(20):
        tr = draw_truth(board, seed)
        assert np.all(np.abs(tr.accel[6:9]) <= np.array(ACCEL[an].bias_tol_g) + 1e-15)
        assert np.all(np.abs(1 / tr.accel[3:6] - 1) <= ACCEL[an].scale_tol + 1e-12)
        assert np.all(np.abs(tr.accel[0:3]) <= ACCEL[an].cross_axis_tol + 1e-15)
        assert np.all(np.abs(tr.gyro_bias_dps) <= GYRO[gn].bias_tol_dps)
        assert (tr.mag_soft_iron is not None) == (mn is not None)


def test_pose_sets_are_unit_up_vectors_and_planar_for_euler():
    R = euler_pose_set(12, 12, 0, 1, jitter_deg=0.0)
    ups = up_vectors(R)
    assert ups.shape == (24, 3)
    assert np.allclose(np.linalg.norm(ups, axis=1), 1)
    assert np.allclose(ups[:12, 0], 0, atol=1e-12)    # rotation about x: gravity in y-z
    assert np.allclose(ups[12:, 1], 0, atol=1e-12)    # rotation about y: gravity in x-z
    for r in R:
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
    ups = up_vectors(random_pose_set(30, 2))
    # well spread: every direction is within 50 deg of some pose
    probe = np.random.default_rng(0).normal(size=(500, 3))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip((probe @ ups.T).max(1), -1, 1))).max() < 50


def test_stream_noise_quantisation_and_still_truth():
    rng = np.random.default_rng(5)
    R = random_pose_set(6, rng)
    s = simulate_session("mpu6050", R, rng, rate_hz=100, hold_s=20, move_s=2)
    rec = s.recording
    spec = ACCEL["mpu6050"]
    # ADC: every accelerometer value is a whole number of counts
    counts = rec.acc / spec.lsb_g
    assert np.allclose(counts, np.round(counts), atol=1e-6)
    # within a hold the noise sd is the datasheet density over the Nyquist band
    sig, _ = pose_sigma(spec.noise_density_g_rthz, 100, 1)
    t0, t1 = s.hold[1]
    m = (rec.t >= t0) & (rec.t <= t1)
    sd = rec.acc[m].std(0, ddof=1)
    n = m.sum()
    # sd of n ~ 2000 samples: relative s.e. 1/sqrt(2n) ~ 1.6 %; 4 s.e. plus quantisation (q^2/12)
    q = np.sqrt(sig ** 2 + spec.lsb_g ** 2 / 12)
    assert np.all(np.abs(sd / q - 1) < 4 / np.sqrt(2 * n))
    # the hold's mean equals the inverse model of the true up vector within 5 sigma_pose
    from imucald.calib.models import Triangular9
    expect = Triangular9().inverse(s.truth.accel, up_vectors(R[1:2]))[0]
    assert np.all(np.abs(rec.acc[m].mean(0) - expect) < 5 * q / np.sqrt(n))
    assert np.allclose(s.specific_force_g[m], up_vectors(R[1:2]), atol=1e-12)


def test_range_clipping():
    rng = np.random.default_rng(6)
    R = random_pose_set(4, rng)
    s = simulate_session("mpu6050", R, rng, move_accel_g=3.0)   # violent moves
    assert s.recording.acc.max() <= 2.0 and s.recording.acc.min() >= -2.0
    assert np.any(np.isclose(np.abs(s.recording.acc), 2.0, atol=1e-4))


def test_nine_dof_board_has_magnetometer_with_true_field():
    rng = np.random.default_rng(7)
    s = simulate_session("9dof", random_pose_set(5, rng), rng, hold_s=5)
    tr = s.truth
    h = (s.recording.mag - tr.mag_hard_iron_gauss) @ tr.mag_soft_iron.T
    # |h| = F up to noise and quantisation (sigma ~ 2 mG)
    assert np.allclose(np.linalg.norm(h, axis=1), tr.field_gauss, atol=6 * MAG["hmc5883l"].noise_gauss)


@pytest.mark.parametrize("kind", ["warmup", "ramp", "heatcool", "constant"])
def test_temperature_profiles(kind):
    t = np.linspace(0, 600, 601)
    T = temperature_profile(t, kind, 20.0, 8.0)
    assert T[0] == pytest.approx(20.0)
    if kind == "constant":
        assert np.all(T == 20.0)
    elif kind == "heatcool":
        assert T.max() == pytest.approx(28.0) and T[-1] == pytest.approx(20.0)
    else:
        assert T[-1] == pytest.approx(28.0) and np.all(np.diff(T) >= 0)
