"""Timing of the gap diagnosis: a 30-pose, 100 Hz, 10-minute recording (target < 30 s),
median over repeats.  Usage: python bench/gap.py [--repeats N]"""
import argparse
import time

from _common import np

from imucald.gap.diagnose import diagnose
from imucald.sim.effects import effect_session
from imucald.sim.orientations import random_pose_set


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    ts = []
    for k in range(args.repeats):
        g = np.random.default_rng(k)
        # 30 poses x (17 s hold + 3 s move) = 10 minutes at 100 Hz, 9DOF (all three sensors)
        s, _ = effect_session("9dof", random_pose_set(30, g), g, [("accel.thermal_bias", None)],
                              rate_hz=100.0, hold_s=(15.0, 19.0), move_s=(2.5, 3.5), temp_kind="heatcool")
        import os
        import tempfile
        from imucald.files.recording import read_recording, write_recording
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "r.csv")
            write_recording(s.recording, path)
            t = time.perf_counter()
            rec = read_recording(path)                  # what `imucald gap FILE` does
            res = diagnose(rec, sims=200)
            ts.append(time.perf_counter() - t)
        v = {k2: r["verdict"] for k2, r in res["sensors"].items()}
    print(f"recording: {len(rec)} samples, {rec.t[-1] / 60:.1f} min at 100 Hz, {res['poses_found']} poses, "
          f"sensors {sorted(res['sensors'])}; verdicts {v}")
    print(f"read + diagnosis wall time: median {np.median(ts):.2f} s (min {min(ts):.2f}, max {max(ts):.2f}) "
          f"over {args.repeats} recordings")


if __name__ == "__main__":
    main()
