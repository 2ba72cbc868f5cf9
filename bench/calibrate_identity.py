"""calibrate's answers in this tree against another tree's, byte for byte (issue 24 item 4:
"with identical results"): the JSON (without the fit's own ``wall_s``), the text report
(stdout and stderr of ``-o``), and the calibration file (without its ``created`` time),
compared by sha256 on 24 inputs, real and simulated:

* the real recordings calibrate takes (../shared/data/real, each SOURCE.md): the IMU-TK
  Xsens raw files (the accelerometer's; the gyro's alone is refused: the error line
  compared), the Xsens accelerometer and gyro merged (as bench/real_gap.py builds it:
  accel, gyro, all), the QMC5883L raw tables, the sunsided MPU-6050/HMC5883L raw CSVs and
  all 13 merged, the FreeIMU temperature sweep raw and converted;
* simulated with the BEFORE tree's ``imucald simulate`` (so both read the same bytes):
  mpu6050 at 100 Hz, mpu9250 at 25 Hz (all), 9dof-qmc at 400 Hz, hand-held (sway and
  tremor), 9dof (mag; all), duplicated rows, sample-and-hold (--logger-rate);
* two fixed-width tables made from a simulated one: MATLAB ``save -ascii`` style
  (``%16.7e``) and a signed comma form (``%+.6e``).

Errors count as answers: the same one-line error and exit code in both trees is "same".
Usage: python bench/calibrate_identity.py --before DIR   (DIR: e.g. ``git archive 4cf3bcb |
tar -x -C /tmp/base``).  Prints one line per case and exits 1 if any differs.
"""
import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile


from _common import ROOT

REAL = os.path.join(ROOT, "..", "shared", "data", "real")
X = ["--columns", "t,ax,ay,az", "--nominal-offset", "32768", "--nominal-scale", "4069.76"]
SIM = [("sim_mpu6050_100.csv", ["--board", "mpu6050", "--rate", "100", "--seed", "1"]),
       ("sim_mpu9250_25.csv", ["--board", "mpu9250", "--rate", "25", "--seed", "2"]),
       ("sim_9dofqmc_400.csv", ["--board", "9dof-qmc", "--rate", "400", "--seed", "3", "--poses", "20"]),
       ("sim_hand.csv", ["--board", "mpu6050", "--seed", "4", "--sway-deg", "0.2", "--tremor-dps", "1.0"]),
       ("sim_9dof.csv", ["--board", "9dof", "--seed", "5"]),
       ("sim_dup.csv", ["--board", "mpu6050", "--seed", "6", "--duplicate-rows"]),
       ("sim_sah.csv", ["--board", "mpu6050", "--seed", "7", "--logger-rate", "385"])]


def cases(d):
    r = lambda *p: os.path.join(REAL, *p)
    s = lambda n: os.path.join(d, n)
    sun = lambda n, f: r("sunsided_mpu6050_hmc5883l", n, f)
    return [
        ("xsens_acc raw", [r("imutk_xsens_mti", "xsens_acc.mat"), *X]),
        ("xsens_gyro raw (error path)", [r("imutk_xsens_mti", "xsens_gyro.mat"), "--columns", "t,gx,gy,gz",
                                         "--nominal-offset", "32768", "--nominal-scale", "83.4", "--sensor", "gyro"]),
        ("xsens merged accel", [s("xsens_merged.csv"), "--sensor", "accel"]),
        ("xsens merged gyro", [s("xsens_merged.csv"), "--sensor", "gyro"]),
        ("xsens merged all", [s("xsens_merged.csv"), "--sensor", "all"]),
        ("qmc noisy raw mag", [r("tomisuarez_qmc5883l", "noisy_raw_data.csv"), "--columns", "mx,my,mz",
                               "--rate-hz", "50", "--nominal-scale", "12000"]),
        ("qmc filtered raw mag", [r("tomisuarez_qmc5883l", "filtered_raw_data.csv"), "--columns", "mx,my,mz",
                                  "--rate-hz", "50", "--nominal-scale", "12000"]),
        ("sunsided full-sphere raw all", [sun("full-sphere", "mpu6050.csv"), "--columns",
                                          "t,ax,ay,az,gx,gy,gz,temp", "--sensor", "all"]),
        ("sunsided unmoved-10min raw gyro", [sun("unmoved-with-x-pointing-forward-10min", "mpu6050.csv"),
                                             "--columns", "t,ax,ay,az,gx,gy,gz,temp", "--sensor", "gyro"]),
        ("sunsided full-sphere hmc raw mag", [sun("full-sphere", "hmc5883l.csv"), "--columns", "t,mx,my,mz",
                                              "--sensor", "mag"]),
        ("freeimu tempsweep raw accel", [r("freeimu_mpu6050_tempsweep", "Tempdata01-02-14.csv"), "--columns",
                                         "ax,ay,az,gx,gy,gz,-,-,-,-,temp,-,-", "--rate-hz", "59",
                                         "--nominal-scale", "16384"]),
        ("tempsweep gyro", [s("tempsweep.csv"), "--sensor", "gyro"]),
        ("tempsweep all", [s("tempsweep.csv"), "--sensor", "all"]),
        ("sunsided all", [s("sunsided.csv"), "--sensor", "all"]),
        ("sim mpu6050 100Hz", [s("sim_mpu6050_100.csv")]),
        ("sim mpu9250 25Hz all", [s("sim_mpu9250_25.csv"), "--sensor", "all"]),
        ("sim 9dof-qmc 400Hz", [s("sim_9dofqmc_400.csv")]),
        ("sim hand-held all", [s("sim_hand.csv"), "--sensor", "all"]),
        ("sim 9dof mag", [s("sim_9dof.csv"), "--sensor", "mag"]),
        ("sim 9dof all", [s("sim_9dof.csv"), "--sensor", "all"]),
        ("sim duplicated rows", [s("sim_dup.csv")]),
        ("sim sample-and-hold all", [s("sim_sah.csv"), "--sensor", "all"]),
        ("matlab-style fixed width", [s("matlab_sim.txt"), "--columns", "t,ax,ay,az,gx,gy,gz",
                                      "--nominal-scale", "16384", "--sensor", "all"]),
        ("signed %+.6e csv", [s("signed_sim.csv"), "--columns", "t,ax,ay,az,gx,gy,gz", "--sensor", "all"]),
    ]


def build(d, before):
    """The inputs, written with the BEFORE tree's code (both trees read the same bytes)."""
    env = dict(os.environ, PYTHONPATH=before)
    for name, argv in SIM:
        subprocess.run([sys.executable, "-m", "imucald.cli", "simulate", "-o", os.path.join(d, name), *argv],
                       check=True, capture_output=True, env=env, cwd=d)
    code = (f"import sys; sys.path.insert(0, {os.path.join(ROOT, 'bench')!r})\n"
            "import numpy as np\n"
            "from real_gap import xsens, tempsweep, sunsided\n"
            "from imucald.files.recording import write_recording, read_recording\n"
            "write_recording(xsens(), 'xsens_merged.csv'); write_recording(tempsweep(), 'tempsweep.csv')\n"
            "write_recording(sunsided(), 'sunsided.csv')\n"
            "r = read_recording('sim_mpu6050_100.csv')\n"
            "np.savetxt('matlab_sim.txt', np.column_stack([r.t, r.acc * 16384, r.gyro]), fmt='%16.7e', delimiter='')\n"
            "np.savetxt('signed_sim.csv', np.column_stack([r.t, r.acc, r.gyro]), fmt='%+.6e', delimiter=', ')\n")
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, env=env, cwd=d)


def _strip(o):
    if isinstance(o, dict):
        return {k: _strip(v) for k, v in o.items() if k != "wall_s"}
    return [_strip(v) for v in o] if isinstance(o, list) else o


def answers(tree, argv, d):
    env = dict(os.environ, PYTHONPATH=tree)
    cal = [sys.executable, "-m", "imucald.cli", "calibrate", *argv]
    p = subprocess.run(cal + ["--json"], capture_output=True, env=env, cwd=d)
    j = json.loads(p.stdout) if p.stdout.strip() else {}
    out = {"json": json.dumps(_strip(j), sort_keys=True).encode() + p.stderr + bytes([p.returncode])}
    f = os.path.join(d, "out.yaml")
    p = subprocess.run(cal + ["-o", f], capture_output=True, env=env, cwd=d)
    out["text"] = p.stdout + p.stderr + bytes([p.returncode])
    body = open(f, "rb").read() if os.path.exists(f) else b""
    out["file"] = re.sub(rb"created: .*", b"created: X", body)
    if os.path.exists(f):
        os.remove(f)
    return {k: hashlib.sha256(v).hexdigest()[:16] for k, v in out.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="the other tree (a checkout of an older commit)")
    a = ap.parse_args()
    before = os.path.abspath(a.before)
    bad = 0
    with tempfile.TemporaryDirectory(prefix="imucald-identity-") as d:
        build(d, before)
        for name, argv in cases(d):
            ha, hb = answers(ROOT, argv, d), answers(before, argv, d)
            bad += ha != hb
            print(f"{'same' if ha == hb else 'DIFF'}  {name:34s} json {ha['json']}  text {ha['text']}  "
                  f"file {ha['file']}" + ("" if ha == hb else f"   before {hb}"), flush=True)
    print(f"{len(cases('')) - bad} of {len(cases(''))} cases identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
