"""A quiet chip's hand-held holds after a table rest (the hand track of the stillness
detector, fitting/stillness/detector.py HAND_VAR_G2).

An independent probe (its own generator, chips other than imucald's) found that the floor
learnt while the board lay on a table made a hand's holds motion on a low-noise chip (an
LSM6DSO's or BMI160's ~1 mg of noise against a hand's 1-5 mg of tremor): after a 60-s rest,
96 of ~300 holds were lost.  The recordings here are made by this file, not the simulator:
accelerometer noise 0.7 mg and gyro noise 0.07 deg/s per axis at 104 Hz, tremor on both."""
import numpy as np
import pytest

from imucald.fitting.stillness import detector as det_mod
from imucald.fitting.stillness.poses import detect

RATE = 104.0


def _rot(axis, ang):
    """Rotation matrices (n, 3, 3) about a unit axis by angles ang (rad, n)."""
    x, y, z = axis
    c, s = np.cos(ang), np.sin(ang)
    C = 1 - c
    return np.stack([np.stack([c + x * x * C, x * y * C - z * s, x * z * C + y * s], -1),
                     np.stack([y * x * C + z * s, c + y * y * C, y * z * C - x * s], -1),
                     np.stack([z * x * C - y * s, z * y * C + x * s, c + z * z * C], -1)], -2)


def _session(rng, holds_s, move_s, tremor_mg, tremor_dps, rest_s=60.0, settle_mg=0.0):
    """(t, acc_g, gyro_dps, truth [(t0, t1)]): a rest on the table at +z, then holds in new
    orientations, each reached by a smooth turn about a random body axis (60-120 deg) with a
    hand's push (a sine bump of 0.2 g); holds carry tremor (6-12 Hz: ``tremor_mg`` per axis
    on the accelerometer, ``tremor_dps`` on the gyro; not on the rest) and, with
    ``settle_mg``, a settle after each turn (a 3-Hz ring decaying in 0.3 s on the
    accelerometer, a table's)."""
    segs, truth, R, t0 = [], [(0.0, rest_s)], np.eye(3), 0.0
    n = int(rest_s * RATE)
    segs.append((np.repeat(R[None], n, 0), np.zeros((n, 3)), np.zeros((n, 3)), False))
    t0 = rest_s
    for h in holds_s:
        m = int(move_s * RATE)
        ax = rng.normal(size=3)
        ax /= np.linalg.norm(ax)
        tot = np.radians(rng.uniform(60, 120))
        u = np.arange(m) / m
        ang = tot * (3 * u ** 2 - 2 * u ** 3)
        Rm = R @ _rot(ax, ang)
        w = np.outer(tot * (6 * u - 6 * u ** 2) / move_s, ax) * 180 / np.pi
        push = np.outer(0.2 * np.sin(2 * np.pi * u), rng.normal(size=3) / np.sqrt(3))
        segs.append((Rm, push, w, False))
        R = R @ _rot(ax, np.array([tot]))[0]
        t0 += move_s
        k = int(h * RATE)
        truth.append((t0, t0 + h))
        extra = np.zeros((k, 3))
        if settle_mg:
            tt = np.arange(k) / RATE
            extra += np.outer(settle_mg * 1e-3 * np.exp(-tt / 0.3) * np.sin(2 * np.pi * 3 * tt),
                              rng.normal(size=3) / np.sqrt(3))
        segs.append((np.repeat(R[None], k, 0), extra, np.zeros((k, 3)), not settle_mg))
        t0 += h
    Rs = np.concatenate([s[0] for s in segs])
    acc = np.einsum("nji,j->ni", Rs, [0.0, 0.0, 1.0]) + np.concatenate([s[1] for s in segs])
    gyro = np.concatenate([s[2] for s in segs])
    held = np.concatenate([np.full(len(s[0]), s[3]) for s in segs])
    t = np.arange(len(acc)) / RATE
    f = rng.uniform(6, 12, size=(8, 6))
    ph = rng.uniform(0, 2 * np.pi, size=(8, 6))
    tr = np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None]).sum(1) / 2.0     # (n, 6), RMS 1
    acc += held[:, None] * tr[:, :3] * tremor_mg * 1e-3
    gyro += held[:, None] * tr[:, 3:] * tremor_dps
    acc += rng.normal(0, 0.7e-3, acc.shape)
    gyro += rng.normal(0, 0.07, gyro.shape) + np.array([0.3, -0.2, 0.1])
    return t, acc, gyro, truth


def _covered(ivs, truth):
    """For each true still stretch, the poses within it; and the poses in no stretch."""
    ivs = [iv for iv in ivs if not iv.continues]      # a rest's later pieces (max_pose_s)
    per = [[iv for iv in ivs if iv.t0 >= a - 0.05 and iv.t1 <= b + 0.05] for a, b in truth]
    stray = [iv for iv in ivs if not any(iv.t0 >= a - 0.05 and iv.t1 <= b + 0.05 for a, b in truth)]
    return per, stray


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_quiet_chips_hand_holds_after_a_table_rest_are_poses(seed):
    """Every one of 14 hand-held holds (3-8 s, tremor 3 mg and 1.5 deg/s) after a 60-s rest
    on the table is found whole (one pose each, inside the hold), and no pose lies in a turn.
    Broken once (HAND_VAR_G2 = 0, the floor track alone): none of the 14 holds found."""
    rng = np.random.default_rng(seed)
    t, acc, gyro, truth = _session(rng, rng.uniform(3, 8, 14), 2.0, 3.0, 1.5)
    ivs, _, _ = detect(t, acc, gyro, RATE)
    per, stray = _covered(ivs, truth)
    assert not stray, [(iv.t0, iv.t1) for iv in stray]
    assert [len(p) for p in per] == [1] * len(truth), [len(p) for p in per]


@pytest.mark.parametrize("seed", [1, 2])
def test_table_poses_keep_the_floor_tracks_extent(seed, monkeypatch):
    """Table poses on a quiet chip, each ringing for a moment after it is set down (a settle
    the hand's allowance would take in): the poses are those of the floor track alone, to the
    sample (the real Xsens file's held-out residual rose from 0.140 to 0.153 mg when the
    allowance alone decided).  Broken once (the hand piece always preferred in _resolve):
    poses start and end up to 12 samples (0.12 s) off."""
    rng = np.random.default_rng(seed)
    t, acc, gyro, truth = _session(rng, rng.uniform(4, 10, 10), 2.0, 0.0, 0.0, settle_mg=15.0)
    got = [(iv.i0, iv.i1) for iv in detect(t, acc, gyro, RATE)[0]]
    monkeypatch.setattr(det_mod, "HAND_VAR_G2", 0.0)
    ivs = detect(t, acc, gyro, RATE)[0]
    per, stray = _covered(ivs, truth)
    assert [len(p) for p in per] == [1] * len(truth) and not stray
    assert got == [(iv.i0, iv.i1) for iv in ivs]


def test_a_fifo_logger_stamping_each_burst_with_its_read_time_keeps_its_rate_and_poses():
    """A logger that reads a FIFO every 40 samples and stamps the whole burst with the read
    time: the effective rate is the samples' (104 Hz), not one over the burst period (2.6 Hz,
    when every burst's step counted as a pause among the zero steps: an independent probe's
    400-Hz files were "no still moment" in 3 of 4), and the holds are found as with exact
    stamps; a regular stream's rate is what it was (samples / span, to the bit).
    Broken once (pauses judged among all steps, zero ones included): the rate assertions fail."""
    from imucald.fitting.stillness.repeats import find_repeats
    from imucald.numerics.rates import effective_rate
    rng = np.random.default_rng(5)
    t, acc, gyro, truth = _session(rng, rng.uniform(3, 8, 12), 2.0, 0.0, 0.0, rest_s=10.0)
    burst = (np.arange(len(t)) // 40 + 1) * 40 / RATE          # each row stamped at its burst's end
    assert effective_rate(t) == (len(t) - 1) / float(np.diff(t).sum())
    assert abs(effective_rate(burst) / RATE - 1) < 0.01
    rep = find_repeats(burst, acc)
    assert abs(rep.rate_hz / RATE - 1) < 0.01
    exact = detect(t, acc, gyro, RATE)[0]
    got = detect(burst, acc, gyro)[0]
    per, stray = _covered(got, [(a - 0.1, b + 0.1) for a, b in truth])
    assert len(exact) == len(got) and [len(p) for p in per] == [1] * len(truth) and not stray


@pytest.mark.parametrize("max_pose_s", [20.0, 5.0])
def test_two_tracks_give_the_same_poses_however_the_stream_is_cut_and_none_overlap(max_pose_s):
    """A quieter chip (the simulator's MPU-9250 with its noise x0.3) held on the bench and by
    hand, holds of 2-30 s: the same intervals in the same order from batches of 777 rows as
    from the whole file, and no two emitted intervals overlap.  A cold review found a floor
    pose crossing a hand run's max_pose_s cut decided piece by piece: emitted beside the hand
    piece it overlaps in a stream (and at the end of a file), dropped in one batch.
    Broken once (floor poses waiting only for the hand's current piece, as it found them):
    overlapping intervals and different lists."""
    from imucald.fitting.stillness.detector import StillnessDetector
    from imucald.sim.orientations import random_pose_set
    from imucald.sim.sensor import simulate_session
    rng = np.random.default_rng(3)
    s = simulate_session("mpu9250", random_pose_set(12, rng), rng, hold_s=(2.0, 30.0), move_s=(1.5, 3.0),
                         lead_s=2.0, tremor_dps=[0.0] * 4 + [1.5] * 4 + [0.0, 1.5] * 2, sway_deg=0.2)
    rec = s.recording
    acc = s.specific_force_g + (rec.acc - s.specific_force_g) * 0.3
    runs = []
    for step in (len(rec.t), 777):
        det = StillnessDetector(rec.rate_hz, max_pose_s=max_pose_s)
        got = []
        for i in range(0, len(rec.t), step):
            got += det.update(rec.t[i:i + step], acc[i:i + step], rec.gyro[i:i + step])[1]
        got += det.flush()
        runs.append([(iv.i0, iv.i1, iv.continues) for iv in got])
    assert runs[0] == runs[1]
    assert all(b <= a2 for (_, b, _), (a2, _, _) in zip(runs[0], runs[0][1:])), runs[0]
