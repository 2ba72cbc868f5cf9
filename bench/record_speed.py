"""How long `imucald record --emulate` takes per board: 300 s of data at 100 Hz on
simulated time, median wall time over repeats, against `python -c "import numpy"` run in
the same command (the fixed cost of any imucald command) as the baseline.

The 9DOF board was the slow one (27.6 s for 300 s on a loaded machine, issue 23): its
ITG-3200 has no FIFO, so the driver polls once per sample period, and every emulated
I2C transaction evaluated the motion model for one or two samples.  The emulated chips
now read the motion in blocks on their own sample grid (imucald/sim/emulators/base.py,
GridMotion).

Usage: python bench/record_speed.py [--repeats N] [--seconds S] [--markdown FILE]
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

from _common import ROOT, Markdown, np


def wall(cmd, env):
    t = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--markdown", help="also write the figures as a Markdown page here")
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=ROOT)
    boards = ("mpu6050", "mpu9250", "9dof", "gy273")
    ts = {b: [] for b in boards}
    base = []
    with tempfile.TemporaryDirectory() as d:
        for _ in range(args.repeats):              # interleaved, so load hits all alike
            base.append(wall([sys.executable, "-c", "import numpy"], env))
            for b in boards:
                ts[b].append(wall([sys.executable, "-m", "imucald.cli", "record", "-o",
                                   os.path.join(d, "r.csv"), "--board", b, "--emulate",
                                   "--seconds", f"{args.seconds:g}"], env))
    b0 = float(np.median(base))
    print(f"record --emulate, {args.seconds:g} s at 100 Hz, median of {args.repeats}; "
          f"baseline python -c 'import numpy' {b0:.3f} s")
    rows = []
    for b in boards:
        m = float(np.median(ts[b]))
        print(f"{b:<8} {m:7.2f} s  (min {min(ts[b]):.2f}, max {max(ts[b]):.2f}; {m / b0:.1f} x baseline; "
              f"{args.seconds / m:.0f} x real time)")
        rows.append([f"`{b}`", f"{m:.2f}", f"{min(ts[b]):.2f}", f"{max(ts[b]):.2f}", f"{m / b0:.1f}",
                     f"{args.seconds / m:.0f}"])
    md = Markdown(args.markdown, "Recording on the emulated boards",
                  f"python bench/record_speed.py --repeats {args.repeats} --seconds {args.seconds:g}")
    md.text(f"`imucald record -o r.csv --board BOARD --emulate --seconds {args.seconds:g}` (100 Hz, "
            "simulated time): wall time per board, median over the repeats, run interleaved with "
            f"the baseline `python -c \"import numpy\"` (median {b0:.3f} s), the fixed cost of "
            "any command that loads numpy.")
    md.table(["board", "median s", "min s", "max s", "x baseline", "x real time"], rows)
    md.write()


if __name__ == "__main__":
    main()
