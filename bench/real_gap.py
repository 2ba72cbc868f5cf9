"""`imucald gap` on the real recordings in ../shared/data/real (read in place, never copied).

* imutk_xsens_mti: accelerometer and gyro files merged on their common timestamps
  (raw counts: offset 32768; 415 counts per m/s^2; 4778 counts per rad/s, IMU-TK's
  "datasheet" values); no temperature.
* freeimu_mpu6050_tempsweep: one orientation for 36 minutes while warming 10 -> 29 C
  (accel 16384 counts/g, gyro 16.4 counts/dps as FreeIMU configures it, T = raw/340 + 36.53).
* sunsided_mpu6050_hmc5883l: the 10-minute unmoved recording alone (one orientation), and
  every recording of set 2 appended in time (placements differ between recordings),
  magnetometer held at the MPU timestamps.
Usage: python bench/real_gap.py
"""
import json
import os
import sys

from _common import np

from imucald.errors import UserError
from imucald.gap.diagnose import diagnose
from imucald.files.recording import Recording

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REAL = os.path.join(ROOT, "..", "shared", "data", "real")


def xsens():
    a = np.loadtxt(os.path.join(REAL, "imutk_xsens_mti", "xsens_acc.mat"))
    g = np.loadtxt(os.path.join(REAL, "imutk_xsens_mti", "xsens_gyro.mat"))
    return Recording(t=a[:, 0] - a[0, 0], acc=(a[:, 1:4] - 32768) / (415 * 9.80665),
                     gyro=(g[:, 1:4] - 32768) / (4778 * np.pi / 180),
                     meta={"board": "xsens-mti", "rate_hz": "100"})


def tempsweep():
    d = np.genfromtxt(os.path.join(REAL, "freeimu_mpu6050_tempsweep", "Tempdata01-02-14.csv"),
                      delimiter=",", skip_header=1)
    t = (d[:, 12] - d[0, 12]) / 1000.0
    return Recording(t=t, acc=d[:, 0:3] / 16384.0, gyro=d[:, 3:6] / 16.4, temp=d[:, 9] / 340 + 36.53,
                     meta={"board": "mpu6050", "rate_hz": f"{1 / np.median(np.diff(t)):.1f}"})


def sunsided(only=None):
    base = os.path.join(REAL, "sunsided_mpu6050_hmc5883l")
    parts, off = [], 0.0
    for name in sorted(os.listdir(base)) if only is None else [only]:
        f = os.path.join(base, name, "mpu6050.csv")
        if not os.path.exists(f):
            continue
        m = np.loadtxt(f, delimiter=",", skiprows=1)
        h = np.loadtxt(os.path.join(base, name, "hmc5883l.csv"), delimiter=",", skiprows=1)
        i = np.clip(np.searchsorted(h[:, 0], m[:, 0], side="right") - 1, 0, len(h) - 1)
        # resample to a uniform 100 Hz grid (the logged times are reception times, in bursts)
        tg = np.arange(m[0, 0], m[-1, 0], 0.01)
        j = np.clip(np.searchsorted(m[:, 0], tg, side="right") - 1, 0, len(m) - 1)
        parts.append((tg - tg[0] + off, m[j, 1:4], m[j, 4:7], h[i[j], 1:4], m[j, 7]))
        off += tg[-1] - tg[0] + 5.0
    cat = lambda k: np.concatenate([p[k] for p in parts])
    return Recording(t=cat(0), acc=cat(1), gyro=cat(2), mag=cat(3), temp=cat(4),
                     meta={"board": "mpu6050+hmc5883l", "rate_hz": "100"})


def main():
    if not os.path.isdir(REAL):
        print(f"skipped: {REAL} is absent")
        return 0
    from imucald.cli.gap import gap_summary
    ten = "unmoved-with-x-pointing-forward-10min"
    for name, load in (("imutk_xsens_mti", xsens), ("freeimu_mpu6050_tempsweep", tempsweep),
                       (f"sunsided_mpu6050_hmc5883l {ten} (one orientation, 10 min)", lambda: sunsided(ten)),
                       ("sunsided_mpu6050_hmc5883l (all set-2 recordings appended)", sunsided)):
        print(f"=== {name}")
        rec = load()
        try:
            res = diagnose(rec, name=name)
        except UserError as e:
            print(f"no verdict: {e}")
            continue
        print(gap_summary(res))
        for s, r in res["sensors"].items():
            for k in ("noise_colour",):
                if k in r:
                    print(f"  {s} {k}: {json.dumps(r[k], default=float)[:300]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
