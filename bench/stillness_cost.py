"""CPU cost of the stillness detector per sample, as the daemon feeds it (batches of 10 rows at
100 Hz: the 0.1-s batch of imucald.daemon) and as calibrate feeds it (one batch): a simulated
hand-held session of 20 poses (accelerometer and gyro, tremor and sway), median over repeats,
microseconds per sample, and the ratio to numpy's own cost for a reference operation of the
same size (np.cumsum over the session's accelerometer rows, timed in the same run); and a
bench session of 20 poses (no tremor or sway: the same poses found before and after sway was
allowed for, so the mechanism's own cost compares).
Usage: python bench/stillness_cost.py [REPEATS]   (default 7)
"""
import sys
import time

from _common import np

from imucald.fitting.stillness.detector import StillnessDetector
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import simulate_session


def _run(rec, batch):
    det = StillnessDetector(rec.rate_hz, chip="mpu6050")
    t0 = time.process_time()
    n = 0
    for i in range(0, len(rec.t), batch):
        sl = slice(i, i + batch)
        n += len(det.update(rec.t[sl], rec.acc[sl], rec.gyro[sl], rec.temp[sl])[1])
    n += len(det.flush())
    return time.process_time() - t0, n


def _case(name, rec, reps):
    n = len(rec.t)
    ref = []
    for _ in range(reps):
        t0 = time.process_time()
        for _ in range(100):
            np.cumsum(rec.acc, 0)
        ref.append((time.process_time() - t0) / 100)
    r = float(np.median(ref))
    for batch in (10, n):
        ts, poses = zip(*(_run(rec, batch) for _ in range(reps)))
        m = float(np.median(ts))
        print(f"{name}, batches of {batch:6d} rows: {m / n * 1e6:6.2f} us/sample ({poses[0]} poses, {n} samples), "
              f"{m / r:6.0f}x one np.cumsum over the rows ({r * 1e6:.0f} us)")


def main():
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 7
    rng = np.random.default_rng(1)
    kw = {"sway_deg": 0.3} if "sway_deg" in simulate_session.__code__.co_varnames else {}
    rec = simulate_session("mpu6050", random_pose_set(20, rng), rng, hold_s=(1.5, 3.0), move_s=(1.5, 3.0),
                           lead_s=0.0, tremor_dps=1.5, **kw).recording
    _case("hand-held (tremor 1.5 deg/s, sway 0.3 deg)", rec, reps)
    rec = simulate_session("mpu6050", random_pose_set(20, rng), rng, hold_s=4.0, move_s=2.0,
                           lead_s=0.0).recording
    _case("bench (4-s holds)", rec, reps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
