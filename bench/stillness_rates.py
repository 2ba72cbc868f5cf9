"""Error rates of the still-pose judgements (issue 20), measured over seeds on simulated sessions.

* false-still: slow hand tumbles (15-60 deg/s, never stopping, 120 s, accelerometer only as
  the real 3-5 Hz tumbles) at 3, 5 and 10 Hz: the fraction of tumbles with any pose, and poses
  per tumble; for the board's own chip and for an unknown chip (generic bounds);
* missed-pose: holds of 1.5-3 s with 1.5 deg/s hand tremor (10 poses), bench holds of 10 s
  read with sample-and-hold 2-4x, and 10 bench then 10 hand-held poses: poses missed / poses;
* hold detection: sessions without hold called held (ADXL345's quantised noise), and held
  2-4x sessions not called held.
Usage: python bench/stillness_rates.py [SEEDS]   (default 10)
"""
import sys

from _common import np

from imucald.fitting.stillness.poses import detect
from imucald.fitting.stillness.repeats import find_repeats
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import hold_samples, simulate_session, simulate_tumble


def found(rec, holds, chip):
    ivs, _, det = detect(rec.t, rec.acc, rec.gyro, rec.rate_hz, mag=rec.mag, chip=chip)
    mids = np.array([(rec.t[min(iv.i0, len(rec.t) - 1)] + rec.t[iv.i1 - 1]) / 2 for iv in ivs])
    return sum(bool(np.any((mids > h0) & (mids < h1))) for h0, h1 in holds)


def main():
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    print(f"seeds per case: {seeds}")
    for board, chip in (("mpu6050", "mpu6050"), ("9dof", "adxl345"), ("mpu6050", None)):
        for rate in (3.0, 5.0, 10.0):
            any_pose, poses = 0, 0
            for s in range(seeds):
                rec = simulate_tumble(board, np.random.default_rng(1000 + s), rate_hz=rate,
                                      duration_s=120).recording
                ivs, _, _ = detect(rec.t, rec.acc, None, rec.rate_hz, chip=chip)
                any_pose += bool(ivs)
                poses += len(ivs)
            print(f"tumble {board} (chip {chip or 'unknown: generic bounds'}) at {rate:g} Hz: "
                  f"false-still {any_pose}/{seeds} tumbles, {poses} poses in all")
    # quasi-static turns: 2-10 deg/s, no linear acceleration, no gyro; the magnetometer is
    # the only witness of a turn about gravity.  What the poses found are worth: their
    # corrected |mean| against 1 g (truth calibration applied)
    from imucald.fitting.models.accel import Triangular9
    t9 = Triangular9()
    for board in ("9dof", "mpu9250"):
        for rate in (3.0, 10.0):
            any_pose, err = 0, []
            for s in range(seeds):
                ss = simulate_tumble(board, np.random.default_rng(1500 + s), rate_hz=rate, duration_s=120,
                                     speed_dps=(2.0, 10.0), move_accel_g=0.0)
                rec = ss.recording
                ivs, _, _ = detect(rec.t, rec.acc, None, rec.rate_hz, mag=rec.mag, chip=None)
                any_pose += bool(ivs)
                err += [abs(np.linalg.norm(t9.forward(ss.truth.accel, iv.acc[None])[0]) - 1) for iv in ivs]
            print(f"quasi-static turn 2-10 deg/s {board} (accelerometer + magnetometer, generic bounds) at "
                  f"{rate:g} Hz: {any_pose}/{seeds} with a pose, {len(err)} poses; their corrected |mean| - 1 g: "
                  + (f"median {np.median(err) * 1e3:.2f} mg, max {np.max(err) * 1e3:.2f} mg" if err else "-"))
    for board, chip in (("mpu6050", "mpu6050"), ("9dof", "adxl345")):
        miss = tot = 0
        for s in range(seeds):
            rng = np.random.default_rng(2000 + s)
            ss = simulate_session(board, random_pose_set(10, rng), rng, hold_s=(1.5, 3.0), move_s=(1.5, 3.0),
                                  lead_s=0.0, tremor_dps=1.5)
            f = found(ss.recording, ss.hold, chip)
            miss += len(ss.hold) - f
            tot += len(ss.hold)
        print(f"hand-held 1.5-3 s holds with tremor, {board}: missed {miss}/{tot} poses")
    miss = tot = 0
    for s in range(seeds):
        rng = np.random.default_rng(3000 + s)
        ss = simulate_session("mpu6050", random_pose_set(20, rng), rng, hold_s=(2.0, 4.0), move_s=(1.5, 3.0),
                              lead_s=0.0, tremor_dps=[0.0] * 10 + [1.5] * 10)
        f = found(ss.recording, ss.hold, "mpu6050")
        miss += len(ss.hold) - f
        tot += len(ss.hold)
    print(f"10 bench then 10 hand-held poses: missed {miss}/{tot} poses")
    miss = tot = short = false_hold = not_held = 0
    for s in range(seeds):
        for board, chip in (("mpu6050", "mpu6050"), ("9dof", "adxl345")):
            rng = np.random.default_rng(4000 + s)
            ss = simulate_session(board, random_pose_set(8, rng), rng, hold_s=10.0, move_s=2.0)
            rec = ss.recording
            false_hold += find_repeats(rec.t, rec.acc, rec.rate_hz).held
            factor = 2.0 + 2.0 * (s % 5) / 4                     # 2, 2.5, 3, 3.5, 4
            h = hold_samples(rec, factor * rec.rate_hz, phase=0.37)
            not_held += not find_repeats(h.t, h.acc, h.rate_hz).held
            ivs, _, det = detect(h.t, h.acc, h.gyro, h.rate_hz, chip=chip)
            from imucald.fitting.stillness.poses import merge_cut
            sl = merge_cut(ivs)
            for h0, h1 in ss.hold:
                tot += 1
                got = [x for x in sl if h.t[x.start] < h1 and h.t[x.stop - 1] > h0]
                if not got:
                    miss += 1
                elif max(h.t[x.stop - 1] - h.t[x.start] for x in got) < 0.9 * (h1 - h0):
                    short += 1
    print(f"sample-and-hold 2-4x, 10 s holds (mpu6050 and 9dof): missed {miss}/{tot} poses, "
          f"{short}/{tot} kept < 90 % of the hold")
    print(f"hold detection: {false_hold}/{2 * seeds} sessions without hold called held, "
          f"{not_held}/{2 * seeds} held 2-4x not called held")
    return 0


if __name__ == "__main__":
    sys.exit(main())
