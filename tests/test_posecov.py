"""The variance of a pose mean from the within-pose structure function
(imucald/fitting/noise/posecov.py): what calibrate's pose covariance and the gap twin use."""
import numpy as np

from imucald.fitting.noise.posecov import pose_mean_variance, pose_mean_variance_parts
from imucald.fitting.stillness.poses import poses_and_pieces
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import pose_sigma, simulate_session
from imucald.specs import ACCEL


def _ar1(n, phi, sd, rng):
    e = rng.normal(scale=sd * np.sqrt(1 - phi * phi), size=n)
    x = np.empty(n)
    x[0] = rng.normal(scale=sd)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


def test_hand_held_pose_covariance_is_the_sensor_noise_not_the_tremor():
    """A simulated MPU-6050 held by hand (tremor 3 deg/s, 6-12 Hz, 10 s holds): the tremor
    is in each pose's samples (the per-sample variance over n is 6.6-7.2x the sensor's white
    noise over n) but averages out of the mean; the pose covariance calibrate fits with is
    within 0.7-1.4x the sensor's white figure (seen 0.91-1.09 over 6 seeds).  Seen to fail
    with poses_and_pieces keeping the sample covariance over n (ratio ~6.8)."""
    sa, _ = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 100.0, 1.0)
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        s = simulate_session("mpu6050", random_pose_set(12, rng), rng, hold_s=10.0, move_s=(1.5, 3.0),
                             lead_s=0.0, tremor_dps=3.0)
        ps, _ = poses_and_pieces(s.recording)
        assert len(ps) == 12
        white = np.median(np.einsum("nii->ni", ps.acc_sample_cov) / sa ** 2)
        new = np.median(np.einsum("nii->ni", ps.acc_cov) * ps.n[:, None] / sa ** 2)
        assert white > 3.0, white                         # the tremor is really there
        assert 0.7 < new < 1.4, (new, ps.noise)


def test_short_correlated_colour_is_counted_above_white():
    """White noise plus an AR(1) drift of 0.2 s correlation (20 samples) and the same size:
    a 1000-sample pose mean's variance is ~20x the per-sample variance over n.  calibrate's
    two-sided estimate lands within 0.6-1.5x of the exact figure; the gap twin's one-sided
    one keeps the white figure.  Seen to fail with two_sided ignored (ratio ~0.05)."""
    rng = np.random.default_rng(5)
    n, phi, N = 1000, np.exp(-1 / 20), 12
    parts = [np.column_stack([rng.normal(size=n) + _ar1(n, phi, 1.0, rng) for _ in range(2)])
             for _ in range(N)]
    k = np.arange(1, n)
    exact = (1.0 * n + n + 2 * np.sum((n - k) * phi ** k)) / n ** 2          # white + AR(1) mean
    var, info = pose_mean_variance_parts(parts, two_sided=True)
    ratio = np.median(var) / exact
    assert 0.6 < ratio < 1.5, (ratio, info)
    one, _ = pose_mean_variance(np.vstack(parts), [slice(i * n, (i + 1) * n) for i in range(N)])
    assert np.median(one) / exact < 0.2                  # the twin's one-sided figure: white


def test_the_daemons_poses_keep_what_the_estimate_needs():
    """The daemon's poses are formed incrementally (stillness detector -> accumulator,
    the samples then dropped): each keeps its holds' structure functions (25 numbers a
    hold), the job carries them and the worker forms the covariances as calibrate does
    (the sensor's white noise under 3 deg/s tremor, 0.7-1.4x), also for a pose refined
    by a second hold.  Seen to fail with the pipeline's job leaving them out (ratio ~6.8)."""
    from concurrent.futures import Executor, Future

    from imucald.fitting.stillness.detector import StillnessDetector
    from imucald.daemon.fitjob import _pose_cov
    from imucald.daemon.config import validate
    from imucald.daemon.pipeline import Pipeline

    class Capture(Executor):
        jobs = []

        def submit(self, fn, *a, **kw):
            self.jobs.append(a[0])
            return Future()

    sa, _ = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 100.0, 1.0)
    rng = np.random.default_rng(0)
    rots = random_pose_set(12, rng)
    s = simulate_session("mpu6050", np.concatenate([rots, rots[:1]]), rng, hold_s=10.0,
                         move_s=(1.5, 3.0), lead_s=0.0, tremor_dps=3.0)
    rec = s.recording
    det = StillnessDetector(100.0, chip="mpu6050", keep_structure=True)   # as the daemon
    ivs = det.update(rec.t, rec.acc, rec.gyro, rec.temp)[1] + det.flush()
    ex = Capture()
    p = Pipeline(validate({}), "mpu6050", 100.0, False, executor=ex, chips={"accel": "mpu6050"})
    kinds = [p.acc.add(iv) for iv in ivs]
    assert "refined" in kinds and len(p.acc) == 12          # the 13th hold refines the first
    assert max(len(q.acc_sf) for q in p.acc.poses) == 2
    assert p.request_calibration()
    job = ex.jobs[-1]
    notes = {}
    cov = _pose_cov(job, notes)["acc_cov"]
    n = np.asarray(job["n"])
    assert np.median(np.einsum("nii->ni", np.asarray(job["acc_cov"])) * n[:, None] / sa ** 2) > 3.0
    new = np.median(np.einsum("nii->ni", cov) * n[:, None] / sa ** 2)
    assert 0.7 < new < 1.4, (new, notes)


def test_swaying_hand_keeps_the_norm_residuals_at_their_noise(tmp_path, capsys):
    """A hand sways the board's direction (0.05-0.4 deg at 0.2-2 Hz, tests/test_posefloor.py's
    session): the per-axis structure function counts that wander in each pose mean, but the
    norm model does not see directions, so calibrate's norm residuals must still scatter as
    their predicted noise: chi-square over the three sessions' degrees of freedom (~52)
    within 0.5-1.6 (chi-square tails ~1e-3 and ~4e-3).  Seen to fail with the radial
    override off (poses.py _structure): 5.4 / 52 = 0.10, the standard errors ~3x too large."""
    import json
    from imucald.cli import main
    from imucald.files.recording import write_recording
    from .test_posefloor import _hand_held
    chi2 = dof = 0.0
    for seed in (0, 1, 2):
        p = tmp_path / f"h{seed}.csv"
        write_recording(_hand_held(seed, sway=True), str(p))
        assert main(["calibrate", str(p), "--json"]) == 0
        nm = json.loads(capsys.readouterr().out)["noise_model"]
        chi2, dof = chi2 + nm["chi2"], dof + nm["dof"]
    assert 0.5 < chi2 / dof < 1.6, (chi2, dof)


def _tremor_ratio(tremor_dps, noise_dps, seeds, rate_hz=100, band_hz=(6.0, 12.0), hold_s=(1.5, 3.0)):
    """Pooled over ``seeds``: the estimated pose-mean variance (gap's one-sided estimate)
    over the pose means' own scatter about their average, 30 holds (of ``hold_s``, moves as
    long) of a hand's tremor (imucald.sim.motion.HandTremor over ``band_hz``) plus white
    noise (``noise_dps`` per sample)."""
    from imucald.sim.motion import HandTremor
    est, emp = [], []
    for seed in seeds:
        g = np.random.default_rng(seed)
        t = np.arange(0, 140, 1.0 / rate_hz)
        w = tremor_dps * HandTremor(g, 140.0, band_hz).unit(t)[1] + g.normal(0, noise_dps, (len(t), 3))
        stops = np.cumsum(g.uniform(*hold_s, 60) * rate_hz).astype(int)
        # hold, move, hold..: 60 segments (~135 s at 1.5-3 s), those past the record left out
        parts = [w[a:b] for a, b in zip(stops[0::2], stops[1::2]) if b <= len(w)]
        var, _ = pose_mean_variance_parts(parts)
        m = np.array([p.mean(0) for p in parts])
        est.append(var.mean())
        emp.append(np.sum((m - m.mean(0)) ** 2) / (3 * (len(m) - 1)))
    return float(np.mean(est) / np.mean(emp))


def test_tremor_pose_mean_variance_is_neither_pessimistic_nor_optimistic():
    """A tremor-filled gyro (bounded part dominating): the estimate over the pose means' own
    scatter, pooled over 30 records of 30 holds, is within 1 +- 0.1.  The tolerance: each
    record's scatter is a mean of 87 squared deviations (relative SE sqrt(2/87) = 0.15),
    pooled over 30 records 0.028 (the estimate's own scatter adds little): +-0.1 is 3.5 SE.
    Two cases, because the white part matters in the weak one (its share of the pose mean's
    variance ~45 %) and not in the strong one.  Seen to fail with the white part read from
    the structure function's non-negative split (strong tremor 1.15: a clipped b >= 0 is
    biased up; the gap twin's ratio median 0.84 on hand-held sessions) and with the bounded
    part alone (weak tremor 0.63: the white part dropped); a cold review saw it fail with
    rectangular halves and with the white part doubled or halved.  Not pinned: a taken from
    the non-negative split instead of refitted given b (weak tremor 0.95)."""
    strong = _tremor_ratio(1.5, 0.05, range(30))
    weak = _tremor_ratio(0.3, 0.05, range(30))
    assert 0.9 < strong < 1.1 and 0.9 < weak < 1.1, (strong, weak)


def test_tremor_axes_the_split_misreads_take_the_halves_too():
    """Where the structure function's split scatters above a quarter of the white figure on
    a tremor-filled axis (at 400 Hz; a 4-12 Hz tremor over 1-1.5 s holds), the halves' white
    part, far below the per-sample variance, still marks the axis as tremor-filled.  The
    same +-0.1 as above (3.5 SE over 30 records).  Seen to fail with the split's quarter as
    the only reading (400 Hz 1.17, short holds 1.14: axes kept the split, some at 2.7-3.4x
    their scatter) and with the white-only fit's test deciding "below white" there (400 Hz
    1.71: axes kept the white figure)."""
    fast = _tremor_ratio(1.5, 0.05, range(30), rate_hz=400)
    short = _tremor_ratio(1.5, 0.05, range(30), band_hz=(4.0, 12.0), hold_s=(1.0, 1.5))
    assert 0.9 < fast < 1.1 and 0.9 < short < 1.1, (fast, short)
