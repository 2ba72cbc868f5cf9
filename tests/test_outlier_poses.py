"""Still poses taken while the board accelerated (a lift, a vehicle) or was knocked: left out
of calibrate's fit and the daemon's, and said (fitting/judging/outliers.py).

A cold review's hand-held sessions with 2 of their first 10 holds in an accelerating lift
(|f| = 1 g +- 20-50 mg, otherwise still): calibrate kept all 25 poses with exit 0 and no word,
its bias 4.9 mg off (median of the worst axis over 20 sessions; 0.13 mg with them left out)
and its standard errors scaled by the scatter; the daemon ended 6.6-18.4 mg off.

Noise model: the simulated MPU-6050's pose means, 0.1-0.3 mg; a lift's 20-50 mg is 50-300 of
their standard deviations, far beyond OUTLIER_POSE_Z (8), which no clean session of 270
reached (max 6.2: the module's docstring)."""
import json

import numpy as np
import pytest

from imucald.cli import main
from imucald.files.recording import write_recording
from imucald.fitting.judging.outliers import outlier_poses
from imucald.fitting.models.registry import get_model
from imucald.fitting.stillness.poses import poses_and_pieces
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import simulate_session


def _session(seed, lift=(), hold=(1.5, 3)):
    """A hand-held MPU-6050 session; the holds in ``lift`` taken in a lift accelerating along
    gravity (|f| 1 g +- 20-50 mg, the sign and size drawn), applied to the raw readings."""
    g = np.random.default_rng(seed)
    s = simulate_session("mpu6050", random_pose_set(25, g), g, hold_s=hold, move_s=(1.5, 3), tremor_dps=1.0)
    rec = s.recording
    for i in lift:
        a, b = s.hold[i]
        m = (rec.t >= a) & (rec.t <= b)
        f = s.specific_force_g[m]
        extra = f / np.linalg.norm(f, axis=1, keepdims=True) * g.choice([-1, 1]) * g.uniform(0.02, 0.05)
        rec.acc[m] = s.truth.accel_raw(f + extra) + (rec.acc[m] - s.truth.accel_raw(f))
    return s


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_lifts_poses_and_only_they_are_outliers(seed):
    """Broken once (outlier_poses flagging nothing): fails; with the Tukey reweighting off
    (the least-squares fit's residuals, dragged toward the lift's poses) all three seeds fail."""
    m = get_model("triangular9")
    for lift in ((), (1, 6)):
        s = _session(seed, lift)
        ps, _ = poses_and_pieces(s.recording)
        bad, z, r = outlier_poses(m, ps.acc, ps.acc_cov)
        want = [int(np.argmin(np.abs(ps.t0 - s.hold[i][0]))) for i in lift]
        assert np.flatnonzero(bad).tolist() == sorted(want), (lift, np.round(z, 1))
        assert np.all(np.abs(z[~bad]) < 6)


def test_calibrate_leaves_the_lifts_poses_out_says_so_and_lands_on_the_truth(tmp_path, capsys):
    """Broken once (drop_outlier_poses returning the poses as they are): no warning, and the
    bias 3-50 standard errors off."""
    s = _session(3, (2, 7))
    p = tmp_path / "lift.csv"
    write_recording(s.recording, str(p))
    assert main(["calibrate", str(p), "--json"]) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert "imucald: warning: " + str(p) + ": 2 still pose(s) read |a| far from what the others' calibration " \
        "predicts" in cap.err and "left out" in cap.err, cap.err
    assert d["stillness"]["rejected"].get("outlier") == 2 and d["poses"] == 23
    b, sb = np.array(d["params"]["bias_g"]), np.array(d["stderr"]["bias_g"])
    assert np.all(np.abs(b - s.truth.accel[6:9]) < 3.5 * sb), ((b - s.truth.accel[6:9]) / sb)


def test_the_daemon_leaves_them_out_of_its_fits(tmp_path):
    """The fit job (daemon/fitjob.py) drops them as calibrate does and says so; the candidate
    on the remaining poses is within 3.5 of its standard errors of the truth.  Broken once
    (_without_outliers returning the job): no note, and the bias mg off."""
    from imucald.daemon.fitjob import calibration_job
    s = _session(4, (1, 5), hold=(3, 4))
    ps, _ = poses_and_pieces(s.recording)
    job = {"acc": ps.acc, "acc_cov": ps.acc_cov, "acc_sample_cov": None, "t0": ps.t0, "t1": ps.t1,
           "n": ps.n, "temp": None, "gyro": ps.gyro, "method": "lm", "alpha": 0.05, "seed": 0}
    res = calibration_job(job)
    out = res.notes.get("outlier_poses")
    assert out and [round(o["t0_s"], 2) for o in out] == [round(float(ps.t0[i]), 2) for i in
                                                          (int(np.argmin(np.abs(ps.t0 - s.hold[k][0]))) for k in (1, 5))]
    a = res.candidate.accel
    b, sb = np.asarray(a.params["bias_g"]), np.asarray(a.stderr["bias_g"])
    assert np.all(np.abs(b - s.truth.accel[6:9]) < 3.5 * sb), ((b - s.truth.accel[6:9]) / sb)


@pytest.mark.parametrize("seed", [1, 4, 7])
def test_a_warm_ups_cold_poses_are_not_a_lift_and_a_lift_in_it_still_is(seed):
    """A 12 degC warm-up with the datasheet's thermal bias (0.5 mg/degC): the constant model
    left its cold first poses 7-20 sd off, and 1-3 of them were left out as "a lift" in 5 of 8
    seeds (a cold review), taking the thermal fit's span with them.  The robust model holds a
    bias linear in temperature where the poses' temperatures vary: none is left out (max |z|
    1.4-2.2 on seeds 1-8), while two lift poses in the same warm-up still are.  Broken once
    (temp_c not used): seeds 1, 4 and 7 fail (clean poses at |z| up to 19.5); with a quadratic
    term too, seed 4 kept the lift's second pose and left two clean ones out."""
    from imucald.sim.effects import DEFAULT_MAGNITUDE, effect_session
    m = get_model("triangular9")
    for lift in ((), (3, 9)):
        g = np.random.default_rng(seed)
        s, _ = effect_session("mpu6050", random_pose_set(25, g), g,
                              [("accel.thermal_bias", DEFAULT_MAGNITUDE["accel.thermal_bias"])],
                              hold_s=(3.0, 5.0), temp_kind="warmup", temp_rise_c=12.0)
        rec = s.recording
        for i in lift:
            a, b = s.hold[i]
            k = (rec.t >= a) & (rec.t <= b)
            u = rec.acc[k] / np.linalg.norm(rec.acc[k], axis=1, keepdims=True)
            rec.acc[k] += u * 0.03                      # 30 mg along gravity: a lift starting
        ps, _ = poses_and_pieces(rec)
        bad, z, _ = outlier_poses(m, ps.acc, ps.acc_cov, temp_c=ps.temp)
        want = sorted(int(np.argmin(np.abs(ps.t0 - s.hold[i][0]))) for i in lift)
        assert np.flatnonzero(bad).tolist() == want, (lift, np.round(z, 1))


def test_every_calibrate_path_leaves_them_out_with_the_poses_state_kept(tmp_path, capsys):
    """The pieces of a dropped pose leave the thermal fit too; --sensor all drops them and keeps
    its stillness object; --model eq6 keeps each pose's sample slice (it crashed: the subset
    lost them; a cold review).  Broken once (PoseSet.subset without detector, noise, slices):
    eq6 raises TypeError and --sensor all has no stillness; the pieces left as they were: the
    pieces check fails; calall without drop_outlier_poses: no outlier count."""
    from imucald.cli.offline import drop_outlier_poses
    s = _session(3, (2, 7))
    ps, pieces = poses_and_pieces(s.recording)
    kept, kp = drop_outlier_poses("x.csv", ps, pieces, s.recording.acc)
    capsys.readouterr()
    gone = [(a, b) for a, b in zip(ps.t0, ps.t1) if a not in kept.t0]
    assert len(gone) == 2 and len(kp) < len(pieces)
    assert not any(a >= g0 - 1e-9 and b <= g1 + 1e-9 for a, b in zip(kp.t0, kp.t1) for g0, g1 in gone)
    assert kept.detector is ps.detector and len(kept.slices) == len(kept)
    p = tmp_path / "lift.csv"
    write_recording(s.recording, str(p))
    assert main(["calibrate", str(p), "--sensor", "all", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["stillness"]["rejected"].get("outlier") == 2
    assert main(["calibrate", str(p), "--sensor", "gyro", "--model", "eq6", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["poses"] == 23


def test_the_daemons_calibration_does_not_list_them_as_fitted_on(tmp_path):
    """poses_used (the poses the accelerometer part in force was fitted on, which the gate
    never scores it on) listed the poses its fit left out (a cold review).  A replay of the
    lift session: the saved calibration's poses_used holds neither lift pose, and every other
    pose.  Broken once (the job's pose set kept whole in _apply): the lift poses are listed."""
    import subprocess
    import sys
    import yaml
    s = _session(3, (2, 7))
    p = tmp_path / "lift.csv"
    write_recording(s.recording, str(p))
    r = subprocess.run([sys.executable, "-m", "imucald.cli", "replay", str(p), "--state-dir", str(tmp_path / "st"),
                        "--orientation", "no"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    doc = yaml.safe_load(open(tmp_path / "st" / "calibration.yaml"))
    t0 = [row[doc["poses_used"]["columns"].index("t0_s")] for row in doc["poses_used"]["rows"]]
    lift = [s.hold[i][0] for i in (2, 7)]
    assert not any(abs(a - b) < 0.5 for a in t0 for b in lift), (t0, lift)
    assert "2 pose(s) left out" in r.stderr


def test_a_coarse_converters_rounding_is_not_an_outlier(capsys):
    """An accelerometer at 15.6 mg/LSB (a LIS3DH in low-power mode) with noise under a count:
    a hold's samples are often one value, its own variance ~0, and the rounding of its mean
    took clean poses 12 sd off (a cold review).  The rounding's variance (fitting/noise/
    posefloor.py pose_quantisation_floor, read off the samples) is added: none left out on 4
    seeds (without it 14 poses of 12 sessions stood out).  Broken once (the floor not read):
    poses left out on these seeds."""
    from imucald.cli.offline import drop_outlier_poses
    lsb = 0.0156
    for seed in range(700, 704):
        g = np.random.default_rng(seed)
        rec = simulate_session("mpu6050", random_pose_set(25, g), g, hold_s=(2, 4), move_s=(1.5, 3)).recording
        rec.acc = np.round(rec.acc / lsb) * lsb
        ps, pc = poses_and_pieces(rec)
        kept, _ = drop_outlier_poses("x.csv", ps, pc, rec.acc)
        assert len(kept) == len(ps), (seed, capsys.readouterr().err)
