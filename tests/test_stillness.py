"""The one stillness detector: the batch call and the streaming daemon find the same
poses; hand tremor passes; non-finite and absurd samples do not wipe detection out."""
import numpy as np
import pytest

from imucald.fitting.stillness.poses import detect_static, merge_cut
from imucald.fitting.stillness.detector import StillnessDetector
from imucald.files.recording import Recording
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import simulate_session

from .conftest import real_path


def _streamed(rec, batch_n, rate):
    """What the daemon and replay do: the detector fed in batches, then flushed."""
    det = StillnessDetector(rate)
    ivs = []
    for i in range(0, len(rec.t), batch_n):
        sl = slice(i, i + batch_n)
        ivs += det.update(rec.t[sl], rec.acc[sl], None if rec.gyro is None else rec.gyro[sl])[1]
    return merge_cut(ivs + det.flush())


def _hand_session(seed, holds=(1.5, 3.0), n_poses=10):
    """Hand-held: 1.5-3 s holds, hand tremor 1.5 deg/s RMS per gyro axis."""
    rng = np.random.default_rng(seed)
    s = simulate_session("mpu6050", random_pose_set(n_poses, rng), rng, hold_s=holds,
                         move_s=(1.5, 3.0), lead_s=0.0, tremor_dps=1.5)
    return s, s.recording


def test_simulated_tremor_is_what_real_hands_show():
    """The simulator's tremor (1.5 deg/s RMS per gyro axis, 6-12 Hz) against its noise model,
    so that no seed decides (the former check, every one of 30 hold-axes within 1.2-1.8
    deg/s, passed 37 of seeds 0-79: a coin flip).  One hold-axis's std over 5 s of a
    Gaussian process 6 Hz wide has 2 x 6 x 5 = 60 degrees of freedom, a relative sd of
    1 / sqrt(2 x 60) = 0.091 (measured over seeds 0-79: 0.089); pooled over the 30
    hold-axes 0.091 / sqrt(30) = 0.017: the pooled RMS within 4 of those of 1.5 (seeds 0-79:
    0.965-1.026 x, 80/80 pass; a 4-sigma miss has chance ~6e-5), and the hold-axes' spread
    no wider than 4 of its own standard errors above 0.091 (0.091 x (1 + 4 / sqrt(58))).
    The accelerometer's summed variance 1.3-3.2x that of the same session without tremor in
    every hold (what real hand-held poses show; 80/80 seeds).  Seen to fail with the tremor's
    RMS taken over the rate vector's magnitude instead of per axis (x 1 / sqrt(3): pooled
    0.58 x)."""
    s, rec = _hand_session(8, holds=6.0)
    rng = np.random.default_rng(8)                 # the same session without tremor
    quiet = simulate_session("mpu6050", random_pose_set(10, rng), rng, hold_s=6.0,
                             move_s=(1.5, 3.0), lead_s=0.0).recording
    mid = lambda r, h0, h1: slice(int(h0 * r.rate_hz) + 50, int(h1 * r.rate_hz) - 50)
    g = np.array([rec.gyro[mid(rec, *h)].std(0) for h in s.hold]) / 1.5
    ratio = np.array([rec.acc[mid(rec, *h)].var(0).sum() / quiet.acc[mid(quiet, *h)].var(0).sum()
                      for h in s.hold])
    rel = 1 / np.sqrt(2 * 2 * 6.0 * 5.0)           # relative sd of one hold-axis's std
    assert abs(np.sqrt(np.mean(g ** 2)) - 1) < 4 * rel / np.sqrt(g.size), g
    assert g.std() < rel * (1 + 4 / np.sqrt(2 * (g.size - 1))), g
    assert np.all((ratio > 1.3) & (ratio < 3.2))   # real hand poses: 1.3-3.2x the floor


@pytest.mark.parametrize("batch_n", [1, 7, 100])
def test_batch_and_streaming_find_the_same_poses_simulated(batch_n):
    s, rec = _hand_session(3)
    a = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)
    assert a == _streamed(rec, batch_n, rec.rate_hz)


def test_whole_file_call_in_chunks_finds_what_one_update_finds(monkeypatch):
    """detect_intervals feeds the detector in chunks (bounded memory on long files): the
    intervals, means included, equal those of the whole file fed as one batch."""
    from imucald.fitting.stillness import poses
    s, rec = _hand_session(5)
    det = StillnessDetector(rec.rate_hz)
    one = det.update(rec.t, rec.acc, rec.gyro)[1] + det.flush()
    monkeypatch.setattr(poses, "DETECT_CHUNK", 333)
    ivs, dropped = poses.detect_intervals(rec.t, rec.acc, rec.gyro, rec.rate_hz)
    assert len(one) >= 8 and dropped == 0
    assert [(i.i0, i.i1) for i in ivs] == [(i.i0, i.i1) for i in one]
    assert all(np.array_equal(a.acc, b.acc) and np.array_equal(a.gyro, b.gyro) for a, b in zip(ivs, one))


def _xsens():
    """The real Xsens MTi file in physical units (IMU-TK's nominal scales; SOURCE.md)."""
    p = real_path("imutk_xsens_mti", "xsens_acc.mat")
    a = np.loadtxt(str(p))
    g = np.loadtxt(str(real_path("imutk_xsens_mti", "xsens_gyro.mat")))
    rec = Recording(t=a[:, 0] - a[0, 0], acc=(a[:, 1:4] - 32768) / (415 * 9.80665),
                    gyro=(g[:, 1:4] - 32768) / (4778 * np.pi / 180))
    return rec


def test_batch_and_streaming_find_the_same_poses_on_real_xsens():
    rec = _xsens()
    b = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=100.0)
    assert len(b) == 38              # SOURCE.md: 38 (k = 10) to 40 (k = 3) segments
    assert b == _streamed(rec, 20, 100.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_short_hand_held_holds_with_tremor_count(seed):
    """Every 1.5-3 s hold with 1.5 deg/s tremor is one pose, and what the samples of the
    moves either side add to a pose mean stays under one standard error of its white noise
    (noise-free truth: the mean true specific force of the pose's rows against that of its
    rows inside the hold; 0.08-0.2 here).  Seen to fail with trim_s 0.1 s (3-7.6 standard
    errors) and 0 (14-22)."""
    from imucald.sim.sensor import pose_sigma
    from imucald.specs import ACCEL
    s, rec = _hand_session(seed)
    gstd = np.array([rec.gyro[int(h0 * 100) + 50:int(h1 * 100) - 50].std(0) for h0, h1 in s.hold])
    assert np.median(gstd) > 0.8                   # the tremor the real hands show
    sl = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)
    mids = np.array([(rec.t[x.start] + rec.t[x.stop - 1]) / 2 for x in sl])
    found = [np.any((mids > h0) & (mids < h1)) for h0, h1 in s.hold]
    assert all(found), found
    assert len(sl) == len(s.hold)
    sa, _ = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, rec.rate_hz, 1.0)
    f = s.specific_force_g
    for x, (h0, h1) in zip(sl, s.hold):             # and no pose takes in a move
        r = np.arange(x.start, x.stop)
        r = r[(rec.t[r] >= h0) & (rec.t[r] <= h1)]
        assert np.abs(f[x].mean(0) - f[r].mean(0)).max() < sa / np.sqrt(x.stop - x.start)


def test_a_rotation_the_accelerometer_cannot_see_is_not_still():
    # a slow turn about gravity: the accelerometer is unchanged, the gyro reads 5 deg/s
    s, rec = _hand_session(4)
    base = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)
    h0, h1 = s.hold[5]
    gy = rec.gyro.copy()
    inside = (rec.t > h0) & (rec.t < h1)
    gy[inside] += 5.0 * rec.acc[inside] / np.linalg.norm(rec.acc[inside], axis=1)[:, None]
    turned = detect_static(rec.t, rec.acc, gy, rate_hz=rec.rate_hz)
    assert len(turned) == len(base) - 1


@pytest.mark.parametrize("bad", [np.nan, 1e308, np.inf])
def test_one_absurd_sample_does_not_wipe_out_detection(bad):
    s, rec = _hand_session(5)
    base = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)
    det = StillnessDetector(rec.rate_hz)
    acc = rec.acc.copy()
    i = base[2].start + 40                          # inside the third pose
    acc[i, 1] = bad
    ivs = det.update(rec.t, acc, rec.gyro)[1] + det.flush()
    assert det.dropped == 1
    sl = merge_cut(ivs)
    # the pose holding the bad sample ends before it or starts after it; the rest stand
    assert len(sl) >= len(base) - 1
    assert all(not (x.start <= i < x.stop) for x in sl)
    assert all(np.all(np.isfinite(acc[x])) for x in sl)


def _pipeline_poses(rec, board="mpu6050"):
    """The daemon's pipeline fed the way replay feeds it (batch_s from the config)."""
    from imucald.daemon.config import load_config
    from imucald.daemon.pipeline import Pipeline
    from imucald.drivers.board import SampleBatch
    cfg = load_config(None)
    pipe = Pipeline(cfg, board, rec.rate_hz, has_mag=False)
    got = []
    pipe._pose = got.append
    n = len(rec.t)
    step = max(1, int(round(cfg["sensor"]["batch_s"] * rec.rate_hz)))
    seq = np.arange(n, dtype=np.int64)
    temp = np.full(n, 25.0)
    for i in range(0, n, step):
        sl = slice(i, min(n, i + step))
        pipe.process(SampleBatch(rec.t[sl], seq[sl], rec.acc[sl], rec.gyro[sl], temp[sl], None, None))
    pipe.end_of_stream()
    return merge_cut(got)


def test_the_daemon_pipeline_and_calibrate_find_the_same_poses():
    s, rec = _hand_session(6)
    assert _pipeline_poses(rec) == detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)


def test_floors_are_numpy_percentiles_value_for_value():
    """The vectorised floors equal np.percentile over each window's history bit for bit
    (random, quantised with zeros, and a history shorter and longer than FLOOR_WINDOWS)."""
    from imucald.fitting.stillness.floor import FLOOR_WINDOWS, floor as _floor, floors as _floors
    rng = np.random.default_rng(3)
    for hist in (rng.gamma(2.0, 1e-6, 700), np.round(rng.gamma(1.0, 1.0, 450)) * 1e-8,
                 np.zeros(20), rng.gamma(2.0, 1.0, 1)):
        for m in sorted({1, min(len(hist), 7), min(len(hist), 333)}):
            got = _floors(hist, m)
            want = [_floor(hist[max(0, len(hist) - m + j + 1 - FLOOR_WINDOWS):len(hist) - m + j + 1])
                    for j in range(m)]
            assert np.array_equal(got, want), (len(hist), m)


@pytest.mark.parametrize("gap_s", [0.0, 5.0])
def test_an_instant_change_of_orientation_splits_the_pose(gap_s):
    """Two quiet stretches with nothing between them (samples lost while the board turned,
    or files appended), with or without a time gap: two poses, each with its own mean - not
    one pose with the mean of both.  A time gap with the board unmoved (a logger pausing)
    stays one pose."""
    rng = np.random.default_rng(0)
    n, sig = 3000, 0.004                          # 30 s at 100 Hz, MPU-6050-like noise
    t = np.arange(2 * n) / 100.0
    t[n:] += gap_s
    up = np.concatenate([np.tile([0, 0, 1.0], (n, 1)), np.tile([1.0, 0, 0], (n, 1))])
    acc = up + rng.normal(0, sig, (2 * n, 3))
    gyro = rng.normal(0, 0.05, (2 * n, 3))
    sl = detect_static(t, acc, gyro, rate_hz=100.0)
    assert len(sl) == 2 and sl[0].stop <= n <= sl[1].start
    for x, u in zip(sl, ([0, 0, 1.0], [1.0, 0, 0])):
        assert np.all(np.abs(acc[x].mean(0) - u) < 5 * sig / np.sqrt(x.stop - x.start))
    assert sl == _streamed(Recording(t=t, acc=acc, gyro=gyro), 37, 100.0)
    same = np.tile([0, 0, 1.0], (2 * n, 1)) + rng.normal(0, sig, (2 * n, 3))
    assert len(detect_static(t, same, gyro, rate_hz=100.0)) == 1


def test_a_small_step_between_two_quiet_stretches_splits_the_pose():
    """A 60 mg (3.4 deg) change between two quiet stretches (a board set down again a little
    differently, two sessions appended) on a noisy part (10 mg per axis): too small for the
    variance test (a window half on each side reads 9e-4 g^2, under k x floor), so the means
    of the quiet windows either side decide: two poses.  A 1-deg change, what a hand's sway
    moves adjacent 1-s means by (up to ~1.5 deg, bench/stillness_holds.py), stays one pose:
    the step must exceed half ``max_turn_deg`` (1.5 deg) besides the noise (it had to exceed
    the noise alone before sway was allowed for, and a 20 mg step split).  Seen to fail with
    the step test off (_Core._steps returning no break: poses 0-20 s and 40-60 s, the middle
    20-s piece refused for its scatter)."""
    rng = np.random.default_rng(1)
    n, sig = 3000, 0.01
    t = np.arange(2 * n) / 100.0
    for step, poses in ((0.06, 2), (np.sin(np.radians(1.0)), 1)):
        up = np.tile([0, 0, 1.0], (2 * n, 1))
        up[n:, 0] += step
        acc = up + rng.normal(0, sig, (2 * n, 3))
        gyro = rng.normal(0, 0.05, (2 * n, 3))
        sl = detect_static(t, acc, gyro, rate_hz=100.0)
        assert len(sl) == poses, (step, sl)
        assert sl == _streamed(Recording(t=t, acc=acc, gyro=gyro), 23, 100.0)
        if poses == 2:
            # each reaches to within a window of the step (not two pieces of 20 s either side
            # of a middle piece refused for its scatter)
            assert n - 100 < sl[0].stop <= n <= sl[1].start < n + 100, sl
            assert abs(acc[sl[1]].mean(0)[0] - acc[sl[0]].mean(0)[0] - step) < 5 * sig * np.sqrt(2 / 2000)


def test_the_daemon_keeps_nearby_but_distinct_poses():
    """A pose a few degrees of tilt from another is distinct information (calibrate uses
    it): the accumulator keeps it; a repeat of a pose within its noise refines that pose.
    (It used to replace the older pose within 12 deg, so replaying the real Xsens file left
    14 of its 38 poses.)"""
    from imucald.fitting.stillness.detector import StaticInterval
    from imucald.daemon.accumulator import PoseAccumulator
    cov = np.eye(3) * (1e-4) ** 2
    iv = lambda u, t: StaticInterval(np.asarray(u, float) / np.linalg.norm(u), cov, cov * 100, 100, t, t + 1, 25.0)
    acc = PoseAccumulator()
    assert acc.add(iv([0, 0, 1], 0)) == "new"
    assert acc.add(iv([np.sin(np.radians(5)), 0, np.cos(np.radians(5))], 2)) == "new"
    assert acc.add(iv([0, 0, 1], 4)) == "refined"
    assert len(acc) == 2


def test_pieces_of_one_rest_refine_one_pose_with_the_scatter_of_all_their_rows():
    """A rest cut into pieces (max_pose_s) whose means drift apart far beyond their noise (a
    warm-up): each piece that ``continues`` the one before refines the pose it went to, and
    the pose's sample covariance is that of all the pieces' rows, the spread between their
    means included (as calibrate's joined pose has it); a piece that does not continue, with
    the same drift, is a pose of its own.  Broken once each: the same-run rule removed (4
    poses: fails), the pooled covariance without the between-means term (z scatter 2.9x
    small: fails)."""
    from imucald.fitting.stillness.detector import StaticInterval
    from imucald.daemon.accumulator import PoseAccumulator
    rng = np.random.default_rng(3)
    rows = [np.array([0.0, 0.0, 1.0]) + [0, 0, 0.004 * k] + rng.normal(0, 1e-3, (1000, 3)) for k in range(4)]

    def piece(x, k, continues):
        m = x.mean(0)
        sc = np.cov(x.T)
        return StaticInterval(m, sc / len(x), sc, len(x), 20.0 * k, 20.0 * k + 19.9, 20 + k,
                              continues=continues)
    acc = PoseAccumulator()
    assert [acc.add(piece(x, k, k > 0)) for k, x in enumerate(rows)] == ["new"] + ["refined"] * 3
    np.testing.assert_allclose(acc.poses[0].acc_sample_cov, np.cov(np.concatenate(rows).T), rtol=0.01, atol=1e-8)
    np.testing.assert_allclose(acc.poses[0].acc, np.concatenate(rows).mean(0), rtol=0, atol=1e-12)
    assert acc.add(piece(rows[3] + [0, 0, 0.004], 4, False)) == "new"


def test_replaying_the_real_xsens_file_keeps_every_pose_calibrate_finds():
    rec = _xsens()
    from imucald.daemon.config import load_config
    from imucald.daemon.pipeline import Pipeline
    from imucald.drivers.board import SampleBatch
    pipe = Pipeline(load_config(None), "xsens", 100.0, has_mag=False)
    pipe.maybe_calibrate = lambda *a, **k: None            # poses only
    n = len(rec.t)
    seq = np.arange(n, dtype=np.int64)
    for i in range(0, n, 50):
        sl = slice(i, i + 50)
        pipe.process(SampleBatch(rec.t[sl], seq[sl], rec.acc[sl], rec.gyro[sl], np.full(len(seq[sl]), 25.0), None, None))
    pipe.end_of_stream()
    assert len(pipe.acc) == len(detect_static(rec.t, rec.acc, rec.gyro, rate_hz=100.0)) == 38


# --- issue 20: distinct samples, effective rate, stillness in absolute terms ------------------

def _bench_session(seed, n_poses=12, hold=10.0, rate=100.0, tremor=0.0):
    rng = np.random.default_rng(seed)
    return simulate_session("mpu6050", random_pose_set(n_poses, rng), rng, rate_hz=rate, hold_s=hold,
                            move_s=2.0, tremor_dps=tremor)


@pytest.mark.parametrize("factor", [2.0, 3.0, 3.85, 4.0])
def test_sample_and_hold_keeps_every_pose_and_its_standard_errors(factor):
    """Each value held 2-4x (a ~100 Hz chip read at 200-400 Hz; 3.85: the FXOS8700 log of
    issue 20): every pose keeps >= 90 % of its hold and the calibration's standard errors are
    within 20 % of the de-duplicated recording's.  Seen to catch: with the repeat detection
    off (find_repeats never calling rows held), poses kept 46-96 % of their 10 s holds (the
    onset cut, which assumes independent samples, fired halfway) and the standard errors
    were 0.71-0.77x (held 2x) to 1.43-1.71x (3-4x: shorter poses, excess scatter)."""
    from imucald.fitting.fit import fit_norm
    from imucald.fitting.stillness.poses import poses_and_pieces
    from imucald.sim.sensor import hold_samples
    s = _bench_session(11)
    base, _ = poses_and_pieces(s.recording)
    held = hold_samples(s.recording, factor * s.recording.rate_hz)
    ps, _ = poses_and_pieces(held)
    assert len(ps) == len(s.hold) == len(base)
    for (h0, h1), a, b in zip(s.hold, ps.t0, ps.t1):
        assert b - a >= 0.9 * (h1 - h0), (h0, h1, a, b)
    se = lambda p: np.array(fit_norm(p.acc, "triangular9", "lm", pose_cov=p.acc_cov, heldout=False)
                            .info["covariance"].diagonal()) ** 0.5
    r = se(ps) / se(base)
    assert np.all(np.abs(r - 1) < 0.2), r


def test_duplicated_rows_are_dropped_with_one_warning(tmp_path, capsys):
    """Every row written twice with its timestamp: one warning line with the count; the
    calibration's standard errors and `noise`'s rate are those of the distinct samples.
    Seen to catch: without the duplicate check the bias standard errors were 0.75x and
    noise reported 200 Hz for a 100 Hz recording."""
    import json
    from imucald.cli import main
    from imucald.files.recording import write_recording
    from imucald.sim.sensor import duplicate_rows
    s = _bench_session(12, hold=4.0)
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    write_recording(s.recording, str(a))
    write_recording(duplicate_rows(s.recording), str(b))
    out = {}
    for p in (a, b):
        assert main(["calibrate", str(p), "--json", "--method", "lm"]) == 0
        c = capsys.readouterr()
        out[p] = json.loads(c.out)
        warn = [l for l in c.err.splitlines() if "warning" in l]
        if p == b:
            assert len(warn) == 1 and f"{len(s.recording)} rows repeat the previous row's timestamp" in warn[0], c.err
        else:
            assert not warn, c.err
    se = lambda d: np.concatenate([d["stderr"][g] for g in ("scale", "bias_g")])
    assert np.allclose(se(out[b]), se(out[a]), rtol=0.02)
    st = out[b]["stillness"]
    assert st["repeated_rows"] == st["duplicated_timestamps"] == len(s.recording) and not st["held"]
    assert out[a]["stillness"]["repeated_rows"] == 0
    rates = []
    for p in (a, b):
        assert main(["noise", str(p), "--json", "--sensor", "accel"]) == 0
        rates.append(json.loads(capsys.readouterr().out)["rate_hz"])
    assert abs(rates[1] / rates[0] - 1) < 0.01, rates


def test_fifo_bursts_stamped_with_their_read_time_change_no_decision(tmp_path, capsys):
    """A logger that drains the FIFO every 0.1 s and stamps the burst's 40 rows with its read
    time (simulate --fifo-burst): the same poses and the same calibration as the rows at
    their own times.  The file was refused before ("header rate_hz=400 but the t column steps
    by 0.1 s": the header was checked against the stamps' steps, not the rows a second).
    Broken once: files/recording.py _check_rate without the rows-a-second test (exit 2); and
    fitting/gyro/rotations.py's rate as 1 / the median step (ZeroDivisionError)."""
    import json
    from imucald.cli import main
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    common = ["--rate", "400", "--poses", "12", "--hold", "4", "--seed", "6"]
    assert main(["simulate", "-o", str(a), *common]) == 0
    assert main(["simulate", "-o", str(b), *common, "--fifo-burst", "0.1"]) == 0
    capsys.readouterr()
    t = np.loadtxt(b, delimiter=",", comments="#", skiprows=8, usecols=0)
    assert np.unique(t).size == pytest.approx(t.size / 40, abs=2)
    out = {}
    for p in (a, b):
        assert main(["calibrate", str(p), "--json", "--method", "lm"]) == 0
        out[p] = json.loads(capsys.readouterr().out)
    assert out[a]["poses"] == out[b]["poses"] == 12
    for g in ("alpha", "scale", "bias_g"):
        assert np.allclose(out[a]["params"][g], out[b]["params"][g], rtol=0, atol=1e-9), g
        assert np.allclose(out[a]["stderr"][g], out[b]["stderr"][g], rtol=1e-6), g
    # the gyro's scale and misalignment from the rotations: the burst file's white-noise rate
    # was 1 / its median step, 0 (a cold review: ZeroDivisionError in --sensor all); now
    # fitted, within the errors of the rows at their own times (its standard errors are
    # ~4x larger: the integration steps by the stamps)
    rot = {}
    for p in (a, b):
        assert main(["calibrate", str(p), "--json", "--sensor", "all"]) == 0
        rot[p] = json.loads(capsys.readouterr().out)["gyro"]["rotations"]
    K = {p: np.array(rot[p]["matrix"]) for p in (a, b)}
    se = np.hypot(np.array(rot[a]["matrix_stderr"]), np.array(rot[b]["matrix_stderr"]))
    assert rot[b]["rotations"] == rot[a]["rotations"] and np.all(np.abs(K[a] - K[b]) < 3 * se)


@pytest.mark.parametrize("rate,board", [(3.0, "mpu6050"), (5.0, "9dof"), (10.0, "mpu6050")])
def test_a_slow_tumble_without_a_still_moment_is_refused_in_one_line(tmp_path, capsys, rate, board):
    """A board turned by hand without stopping, logged at 3-10 Hz: `calibrate` exits 2 with
    one line saying there is no still moment (and how far from still the quietest windows
    are).  Seen to catch: with the floor not capped by the chip's noise (still_limits' cap =
    inf) the detector learnt its floor from the motion, found 'still poses' and calibrate
    exited 0 on all three (issue 20: '11 still poses', exit 0); the main code of issue 20
    found 6-22 per 120 s tumble."""
    from imucald.cli import main
    from imucald.files.recording import write_recording
    from imucald.sim.sensor import simulate_tumble
    p = tmp_path / "tumble.csv"
    rec = simulate_tumble(board, np.random.default_rng(int(rate) + 40), rate_hz=rate, duration_s=150).recording
    # accelerometer (+ magnetometer) only, as the real 3-5 Hz tumbles of issue 20: no gyro to
    # see the turning
    rec.gyro = None
    write_recording(rec, str(p))
    assert main(["calibrate", str(p), "--method", "lm"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "no still moment" in err, err


def test_bench_then_hand_held_session_finds_all_20_poses():
    """10 bench poses (no tremor) then 10 hand-held ones (1.5 deg/s tremor): 20 of 20.  The
    bench poses teach the detector a floor without tremor, so a rule that lets the gyro vote
    on stillness rejects the hand-held poses.  Seen to catch: making the gyro vote (its window
    variance summed into the one the floor is learnt from and judged on, _blocks and
    _window_stats over all six columns) found 0 + 0 poses."""
    rng = np.random.default_rng(20)
    s = simulate_session("mpu6050", random_pose_set(20, rng), rng, hold_s=(2.0, 4.0), move_s=(1.5, 3.0),
                         lead_s=0.0, tremor_dps=[0.0] * 10 + [1.5] * 10)
    rec = s.recording
    hand = [h for i, h in enumerate(s.hold) if i >= 10]
    g = np.median([rec.gyro[int(h0 * 100) + 30:int(h1 * 100) - 30].std(0).mean() for h0, h1 in hand])
    assert g > 1.0                                  # the tremor is there, only in the second half
    sl = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)
    mids = np.array([(rec.t[x.start] + rec.t[x.stop - 1]) / 2 for x in sl])
    found = [bool(np.any((mids > h0) & (mids < h1))) for h0, h1 in s.hold]
    assert sum(found[:10]) == 10 and sum(found[10:]) == 10, (sum(found[:10]), sum(found[10:]))
    assert len(sl) == 20


def test_rejected_stretches_name_their_reason():
    """A hold whose mean is not ~1 g (here scaled to 0.55 g, as issue 20's tumble pose) is
    not a pose and is reported with that reason; the others count.  Seen to catch: without
    the |mean| check the 0.55 g stretch was a pose (12 found, not 11)."""
    from imucald.fitting.stillness.poses import detect
    s = _bench_session(13, hold=4.0)
    rec = s.recording
    acc = rec.acc.copy()
    h0, h1 = s.hold[4]
    inside = (rec.t >= h0 - 1) & (rec.t <= h1 + 1)
    acc[inside] *= 0.55
    ivs, _, det = detect(rec.t, acc, rec.gyro, rec.rate_hz, chip="mpu6050")
    sl = merge_cut(ivs)
    assert len(sl) == len(s.hold) - 1
    norm = [r for r in det.rejected if r["kind"] == "norm"]
    assert norm and "|mean| 0.5" in norm[0]["reason"] and h0 - 1 <= norm[0]["t0_s"] <= h1 + 1


def test_repeat_detection_does_not_fire_on_quantised_noise():
    """An ADXL345 (3.9 mg/LSB, ~3 mg noise: one axis in two repeats by chance) without hold
    is not called held; the same held 2x is.  Seen to catch: a rule dropping every whole-row
    repeat dropped 3 % (169 of 5600) of the ADXL345's genuine samples."""
    from imucald.fitting.stillness.repeats import find_repeats
    from imucald.sim.sensor import hold_samples
    rng = np.random.default_rng(14)
    s = simulate_session("9dof", random_pose_set(8, rng), rng, hold_s=5.0, move_s=2.0)
    rec = s.recording
    r = find_repeats(rec.t, rec.acc, rec.rate_hz)
    assert not r.held and r.repeated == 0 and r.chance > 50
    h = hold_samples(rec, 2 * rec.rate_hz)
    r2 = find_repeats(h.t, h.acc, h.rate_hz)
    assert r2.held and abs(r2.rate_hz / rec.rate_hz - 1) < 0.05


def test_a_run_ending_exactly_at_a_cut_is_not_continued_by_the_next_placement():
    """Pieces of one still run cut at max_pose_s are joined into one pose (``continues``);
    a run that ends exactly at a cut left nothing to close, and the mark stayed set: the next
    placement, after a 3-s turn from z-up to x-up, was taken for its continuation, joined
    into one pose across the turn (|mean| 0.72 g) and its start left untrimmed (a cold
    review).  Now two poses, each on its own face, and the second trimmed at its start.
    Broken once: the reset on a run's end without rows removed (one pose: fails)."""
    from imucald.files.recording import Recording
    from imucald.fitting.stillness.poses import detect, poses_and_pieces
    rng = np.random.default_rng(1)
    rate = 100.0

    def seg(v, s):
        return np.tile(v, (int(s * rate), 1)) + rng.normal(0, 0.002, (int(s * rate), 3))
    ang = np.linspace(0, np.pi / 2, int(3 * rate))
    turn = np.c_[np.sin(ang), np.zeros_like(ang), np.cos(ang)] + rng.normal(0, 0.002, (len(ang), 3))
    acc = np.r_[seg([0, 0, 1], 30), turn, seg([1, 0, 0], 30)]
    gyro = rng.normal(0, 0.05, acc.shape)
    gyro[3000:3300, 1] += 30
    t = np.arange(len(acc)) / rate
    ivs, _, _ = detect(t, acc, gyro, rate, max_pose_s=1e5)
    trim = round(0.25 * rate)                          # trim_s at each end of an uncut run
    first = ivs[0].i1 - ivs[0].i0 + 2 * trim           # the first still run's length
    ivs, _, _ = detect(t, acc, gyro, rate, max_pose_s=first / rate)
    assert ivs[0].i1 == first                          # cut (not trimmed) where the run ends
    ps, _ = poses_and_pieces(Recording(t=t, acc=acc, gyro=gyro), max_pose_s=first / rate)
    assert len(ps) == 2
    np.testing.assert_allclose(ps.acc, [[0, 0, 1], [1, 0, 0]], atol=0.01)
    assert ps.slices[1].start > 3300


@pytest.mark.parametrize("batch_n", [9, 50])
def test_streaming_finds_the_poses_of_the_whole_file_in_a_held_stream(batch_n):
    """The daemon and replay feed the detector in batches: it decides from the first 10 s
    that the stream is held (3x) and then finds the poses the whole-file call finds, at the
    effective rate.  Seen to catch: a streaming decision that ignored the hold (_decide
    starting the core with held=False) ran at 300 Hz on the held rows."""
    from imucald.fitting.stillness.poses import detect
    from imucald.sim.sensor import hold_samples
    s = _bench_session(15, n_poses=5, hold=6.0)
    h = hold_samples(s.recording, 3 * s.recording.rate_hz)
    ivs, _, det = detect(h.t, h.acc, h.gyro, h.rate_hz)
    whole = merge_cut(ivs)
    det2 = StillnessDetector(h.rate_hz)
    got = []
    for i in range(0, len(h.t), batch_n):
        sl = slice(i, i + batch_n)
        q, iv = det2.update(h.t[sl], h.acc[sl], h.gyro[sl])
        assert len(q) == len(h.t[sl])
        got += iv
    got += det2.flush()
    assert merge_cut(got) == whole and len(whole) == 5
    assert det2.repeats.held and abs(det2.rate - 100.0) < 1.0


def test_a_turn_about_gravity_without_a_gyro_is_seen_by_the_magnetometer():
    """A hold during which the board turns 10 deg about gravity (the accelerometer reads the
    same; no gyro, as issue 20's accelerometer + magnetometer tumbles) is not a pose: the
    magnetometer's field direction turns; the reason is reported.  Seen to catch: without
    the magnetometer check (_mag_turn) the turning stretch was a pose (8 of 8)."""
    from imucald.fitting.stillness.poses import detect
    from imucald.sim.orientations import axis_angle
    rng = np.random.default_rng(16)
    s = simulate_session("9dof", random_pose_set(8, rng), rng, hold_s=5.0, move_s=2.0)
    rec = s.recording
    h0, h1 = s.hold[3]
    mag = rec.mag.copy()
    inside = np.flatnonzero((rec.t >= h0) & (rec.t <= h1))
    up = rec.acc[inside].mean(0)
    centre = mag[inside].mean(0) - s.truth.mag_hard_iron_gauss
    for j, i in enumerate(inside):          # the field turns about the gravity direction
        R = axis_angle(up, np.radians(10.0) * (j / len(inside) - 0.5))
        mag[i] = s.truth.mag_hard_iron_gauss + R @ (mag[i] - s.truth.mag_hard_iron_gauss - centre) + R @ centre
    base = merge_cut(detect(rec.t, rec.acc, None, rec.rate_hz, mag=rec.mag, chip="adxl345")[0])
    ivs, _, det = detect(rec.t, rec.acc, None, rec.rate_hz, mag=mag, chip="adxl345")
    assert len(base) == 8 and len(merge_cut(ivs)) == 7
    turn = [r for r in det.rejected if r["kind"] == "turn"]
    assert turn and h0 - 1 <= turn[0]["t0_s"] <= h1 and "magnetometer turned" in turn[0]["reason"]


def test_simulate_writes_what_real_loggers_do(tmp_path):
    """`simulate --logger-rate` (sample-and-hold) and `--duplicate-rows`: the rows as a
    logger writes them, the distinct samples those of the chip."""
    from imucald.fitting.stillness.repeats import find_repeats
    from imucald.cli import main
    from imucald.files.recording import read_recording
    p, q = tmp_path / "held.csv", tmp_path / "dup.csv"
    assert main(["simulate", "-o", str(p), "--poses", "3", "--hold", "3", "--logger-rate", "300"]) == 0
    assert main(["simulate", "-o", str(q), "--poses", "3", "--hold", "3", "--duplicate-rows"]) == 0
    h, d = read_recording(str(p)), read_recording(str(q))
    rh, rd = find_repeats(h.t, h.acc, h.rate_hz), find_repeats(d.t, d.acc, d.rate_hz)
    assert h.rate_hz == 300 and rh.held and abs(rh.hold_factor - 3) < 0.01 and abs(rh.rate_hz - 100) < 0.5
    assert rd.duplicated_rows == len(d.t) // 2 and abs(rd.rate_hz - 100) < 0.5


def test_swaying_hand_held_holds_stay_whole_and_a_slow_turn_is_no_pose():
    """Hand-held sessions of 20 holds of 1.5-3 s that sway as real hands do (0.25 deg RMS per
    axis at 0.2-2 Hz, mid-range, with 2 deg/s of tremor): no hold split, and of two sessions at
    least one loses no hold.  Rates over 80 such sessions (seeds 100-179): 0 of 1600 holds
    split; 74 sessions lost none, the others 1-4, all among their first holds (until the gyro
    bias is trusted a window may turn only 0.5 deg; one more session seen lost 7): this test
    fails by chance with (6/80)^2 ~ 0.6 %.  Over 600 holds bench/stillness_holds.py finds
    98.3 % whole (36.8 % before sway was allowed for); at 0.4 deg, the top of the range,
    75 % (9.3 % before).  A slow turn (2-10 deg/s, never stopping, the gyro on) gives no pose
    (30 of 30 sessions at 100 Hz).  Seen to fail with the former turn limit (max_turn_deg
    0.5 deg in stillness_defaults: 0 of 40 holds found)."""
    from imucald.sim.sensor import simulate_tumble
    lost = []
    for seed in (23, 24):
        rng = np.random.default_rng(seed)
        s = simulate_session("mpu6050", random_pose_set(20, rng), rng, hold_s=(1.5, 3.0),
                             move_s=(1.5, 3.0), lead_s=0.0, tremor_dps=2.0, sway_deg=0.25)
        rec = s.recording
        sl = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)
        ks = [sum(rec.t[x.start] < h1 and rec.t[x.stop - 1] > h0 for x in sl) for h0, h1 in s.hold]
        assert max(ks) <= 1, (seed, ks)                 # never split
        lost.append(ks.count(0))
    assert min(lost) == 0, lost
    rec = simulate_tumble("mpu6050", np.random.default_rng(7003), rate_hz=100.0, duration_s=60,
                          speed_dps=(2.0, 10.0), move_accel_g=0.0).recording
    assert detect_static(rec.t, rec.acc, rec.gyro, rate_hz=100.0) == []


def test_warming_gyro_under_sway_keeps_long_holds():
    """A hand-held session (4-8 s holds, 0.3 deg of sway, 2 deg/s of tremor) whose gyro warms
    17 C at 0.1 deg/s/C: the tracked bias follows the drift, so the run-level gyro check does
    not take the lag for a turn.  Measured over seeds 0-7: 116 of 128 holds whole (90.6 %);
    rule: at least 22 of the 32 holds of seeds 0-1 (26 now; binomial at 0.906: fails with
    probability < 0.1 %, holds treated as independent).  Seen to fail with either half of the
    mend undone: the bias gate centred on the bias in force (16 of 32), no constant-rate
    allowance in the run-level gyro check (17 of 32); both undone, as merged before (24 of 128
    over seeds 0-7, 8 of 32 here)."""
    from imucald.fitting.stillness.poses import detect
    from imucald.sim.effects import make_effect
    from imucald.sim.orientations import random_pose_set
    from imucald.sim.sensor import simulate_session
    whole = total = 0
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        e = make_effect("gyro.thermal_bias", 0.1, rng)
        ss = simulate_session("mpu6050", random_pose_set(16, rng), rng, rate_hz=100.0, lead_s=0.0,
                              effects=[e["apply"]], hold_s=(4.0, 8.0), move_s=(1.5, 3.0),
                              tremor_dps=2.0, sway_deg=0.3, temp_kind="warmup", temp_rise_c=17.0)
        rec = ss.recording
        ivs, _, _ = detect(rec.t, rec.acc, rec.gyro, rec.rate_hz, chip="mpu6050")
        spans = [(rec.t[iv.i0], rec.t[iv.i1 - 1]) for iv in ivs]
        whole += sum(sum(a < h1 and b > h0 for a, b in spans) == 1 for h0, h1 in ss.hold)
        total += len(ss.hold)
    assert total == 32 and whole >= 22, f"{whole} of {total} holds whole"


@pytest.mark.parametrize("rate_dps,turn_s", [(10.0, 10.0), (2.0, 20.0)])
def test_a_turn_about_gravity_does_not_become_the_gyro_bias(rate_dps, turn_s):
    """A board flat on a table, still 60 s, spun about the vertical (which the accelerometer
    does not see), then still 30 s: the stillness after the turn is a pose at once, and no
    pose takes in the turn.  Seen to fail (the next 19-28 s of stillness lost as "turn")
    with the gyro-bias gate centred on the median of every accelerometer-quiet window, which
    a turn about gravity fills with its own rate (review of this round)."""
    from imucald.fitting.stillness.poses import detect
    rng = np.random.default_rng(3)
    rate = 100.0
    n0, n1, n2 = 6000, int(turn_s * rate), 3000
    n = n0 + n1 + n2
    t = np.arange(n) / rate
    acc = np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.003, (n, 3))        # MPU-6050-like, g
    gyro = np.array([0.5, -0.3, 0.2]) + rng.normal(0, 0.05, (n, 3))       # bias + noise, dps
    gyro[n0:n0 + n1, 2] += rate_dps
    ivs, _, _ = detect(t, acc, gyro, rate, chip="mpu6050")
    t_end = (n0 + n1) / rate
    inside = [iv for iv in ivs if t[iv.i0] < t_end - 0.5 and t[iv.i1 - 1] > n0 / rate + 0.5]
    assert not inside, [(t[iv.i0], t[iv.i1 - 1]) for iv in inside]
    after = [iv for iv in ivs if t[iv.i0] >= t_end - 0.5]
    assert after and t[after[0].i0] <= t_end + 2.5, [(t[iv.i0], t[iv.i1 - 1]) for iv in ivs]
