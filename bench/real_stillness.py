"""Still poses on the real recordings (../shared/data/real, read in place): what a user sees.

For each recording (loaded as bench/real_gap.py does; the sunsided files also raw, as
logged, with their burst timestamps) it writes an imucald recording to a scratch directory
and runs ``imucald calibrate --json --method lm`` (and ``replay`` on the Xsens file) as a
user would, printing: rows, repeated samples found, effective rate, still poses found,
stretches rejected (with their reasons), the exit code and the calibration's held-out RMS.
Usage: python bench/real_stillness.py [--replay]
"""
import json
import os
import subprocess
import sys
import tempfile

from _common import np

from imucald.files.recording import Recording, write_recording

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from real_gap import REAL, sunsided, tempsweep, xsens  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def sunsided_raw(name):
    """One sunsided recording as logged: reception timestamps in bursts (median dt 2 ms,
    ~99 rows a second), no resampling."""
    m = np.loadtxt(os.path.join(REAL, "sunsided_mpu6050_hmc5883l", name, "mpu6050.csv"),
                   delimiter=",", skiprows=1)
    return Recording(t=m[:, 0] - m[0, 0], acc=m[:, 1:4], gyro=m[:, 4:7], temp=m[:, 7],
                     meta={"board": "mpu6050+hmc5883l", "rate_hz": f"{1 / np.median(np.diff(m[:, 0])):.1f}"})


def run(args):
    env = dict(os.environ, PYTHONPATH=ROOT)
    p = subprocess.run([sys.executable, "-m", "imucald.cli"] + args, capture_output=True, text=True,
                       env=env)
    return p.returncode, p.stdout, p.stderr


def main():
    if not os.path.isdir(REAL):
        print(f"skipped: {REAL} is absent")
        return 0
    cases = [("imutk_xsens_mti", xsens), ("freeimu_mpu6050_tempsweep", tempsweep),
             ("sunsided set 2 appended (100 Hz grid)", sunsided),
             ("sunsided full-sphere (raw bursts)", lambda: sunsided_raw("full-sphere")),
             ("sunsided roll-and-tilt-at-45-90 (raw bursts)", lambda: sunsided_raw("roll-and-tilt-at-45-90"))]
    tmp = tempfile.mkdtemp(prefix="imucald-real-")
    for name, load in cases:
        rec = load()
        path = os.path.join(tmp, name.split()[0] + ".csv")
        write_recording(rec, path)
        rc, out, err = run(["calibrate", path, "--json", "--method", "lm"])
        line = f"=== {name}: {len(rec)} rows, {rec.t[-1]:.0f} s; calibrate exit {rc}"
        if rc == 0:
            d = json.loads(out)
            line += (f"; {d['poses']} poses, held-out {d['heldout_rms_g'] * 1e3:.3f} mg, "
                     f"noise/pose {d['noise_g'] * 1e3:.4f} mg, excess scatter "
                     f"x{d['noise_model']['excess_scatter']:.2f}")
        print(line)
        for l in err.strip().splitlines():
            print("   " + l[:400])
        if name.startswith("imutk") and "--replay" in sys.argv:
            rc, out, err = run(["replay", path, "--method", "lm", "--log-level", "info"])
            cals = [json.loads(l) for l in out.splitlines() if '"CAL"' in l]
            poses = [l for l in err.splitlines() if "pose " in l and "/" in l]
            print(f"   replay exit {rc}: {len(poses)} pose lines, {len(cals)} CAL events, last: "
                  + (json.dumps({k: cals[-1].get(k) for k in ('poses', 'applied', 'provisional')}) if cals else "-"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
