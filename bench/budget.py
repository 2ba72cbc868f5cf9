"""A Pi-class CPU budget: per board and sample rate, the daemon's share of one core here and
that share scaled to a Raspberry Pi Zero 2 W and a Raspberry Pi 4 B core.

CPU per sample is bench/pipeline.py's ``cost``: the daemon's own work on each batch
(stillness, poses, correction, NDJSON encoding, socket write to one client), process time
over the emulated board's batches (median of the repeats).  CPU % of one core = us/sample x
rate / 10^4.  Not included: the I2C transfers themselves (the kernel driver's time on a
real bus; the emulator cannot stand for it) and a calibration job (its own process, at
lower priority, a few tenths of a second each time a pose set is complete).

The Pi factor (how many times longer a Pi core takes for the same work) is the ratio of
single-thread 7-Zip benchmark ratings (``7z b -mmt1``, the "Tot:" MIPS per unit of CPU use,
R/U, so that other load on this machine does not lower it):

* here: measured by this script (``7z b -mmt1 -md23``, the dictionaries the Pi runs used;
  median of 3), or --mips N;
* Raspberry Pi Zero 2 W (RP3A0, 4 x Cortex-A53 at 1000 MHz, Raspberry Pi OS Buster): 838;
* Raspberry Pi 4 B (BCM2711, 4 x Cortex-A72 at 1800 MHz, Raspberry Pi OS Bullseye arm64): 1769;

both the "7-zip single" column of Thomas Kaiser's sbc-bench results,
https://github.com/ThomasKaiser/sbc-bench/blob/master/Sorted-Results.md
(rows results/3E85.txt and results/3OBF.txt).  7-Zip is integer, branch and memory-latency
bound like an interpreter's loop, but it is a proxy: CPython on an in-order Cortex-A53 may
lose more than 7-Zip does, so treat the Zero 2 W column as a lower bound on its load.

Usage: python bench/budget.py [--seconds S] [--repeats N] [--mips M]
"""
import argparse
import re
import shutil
import subprocess
import sys
import tempfile

from _common import np

import pipeline

#: sbc-bench "7-zip single" (7z b -mmt1, Tot: rating, MIPS), see the module docstring
PI_MIPS = {"Pi Zero 2 W": 838.0, "Pi 4 B": 1769.0}
SBC_BENCH_URL = "https://github.com/ThomasKaiser/sbc-bench/blob/master/Sorted-Results.md"

#: (board, rate Hz): the MPU boards at their common and highest rates, the 9DOF board at
#: 100 Hz and 400 Hz (ADXL345 rates are 3200/2^k Hz)
RUNS = (("mpu6050", 100), ("mpu6050", 1000), ("mpu9250", 100), ("mpu9250", 1000),
        ("9dof", 100), ("9dof", 400))


def mips_here(runs=3):
    """Single-thread 7-Zip rating here (Tot: R/U MIPS, median of ``runs``), or None without 7z."""
    exe = next((e for e in ("7z", "7za", "7zz") if shutil.which(e)), None)
    if exe is None:
        return None
    out = []
    for _ in range(runs):
        p = subprocess.run([exe, "b", "-mmt1", "-md23"], capture_output=True, text=True)
        m = re.search(r"^Tot:\s+\d+\s+(\d+)\s+(\d+)", p.stdout, re.M)
        if m:
            out.append(float(m.group(1)))
    return float(np.median(out)) if out else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0, help="seconds of data per run (x4 at <= 100 Hz)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--mips", type=float, help="this machine's 7z b -mmt1 rating (skips measuring it)")
    a = ap.parse_args()
    here = a.mips or mips_here()
    if here is None:
        print("7z is not installed (apt install p7zip-full) and --mips was not given: "
              "the Pi columns are left out")
    factors = {k: here / v for k, v in PI_MIPS.items()} if here else {}
    if here:
        print(f"7-Zip single-thread rating here {here:.0f} MIPS; "
              + ", ".join(f"{k} {v:.0f} MIPS (factor {factors[k]:.1f})" for k, v in PI_MIPS.items())
              + f" [{SBC_BENCH_URL}]")
    cols = "".join(f" {k + ' %':>15}" for k in factors)
    print(f"{'board':<8} {'rate':>7} {'us/sample':>10} {'CPU % here':>11}{cols}")
    with tempfile.TemporaryDirectory() as tmp:
        for board, rate in RUNS:
            secs = a.seconds if rate > 100 else a.seconds * 4
            us = float(np.median([pipeline.cost(board, rate, secs, "ndjson", tmp)[0]
                                  for _ in range(a.repeats)]))
            pct = us * rate / 1e4
            print(f"{board:<8} {rate:>5} Hz {us:>10.1f} {pct:>11.2f}"
                  + "".join(f" {pct * f:>15.1f}" for f in factors.values()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
