"""Start-up and end-to-end command times, as a user runs them (fresh processes).

* ``imucald --help``, ``status`` and ``watch`` (no daemon running: they stop at the
  missing socket, after loading all they need): wall time (median of 5) and
  ``python -X importtime`` -- total import time and whether numpy was imported.
* ``imucald calibrate`` on the IMU-TK Xsens file (raw counts, README's command): wall time
  (median of 5) and the result's digest, to compare before/after a change.
Usage: python bench/startup.py [--repeats N]
"""
import argparse
import hashlib
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
XSENS = os.environ.get("IMUCALD_XSENS") or os.path.join(ROOT, "..", "shared", "data", "real",
                                                         "imutk_xsens_mti", "xsens_acc.mat")


def run(argv, extra=()):
    t = time.perf_counter()
    p = subprocess.run([sys.executable, *extra, "-m", "imucald.cli", *argv], capture_output=True)
    return time.perf_counter() - t, p


def importtime(argv):
    """(total import s, numpy imported?, slowest top-level packages) from -X importtime."""
    _, p = run(argv, ("-X", "importtime"))
    rows = [re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", l)
            for l in p.stderr.decode().splitlines()]
    rows = [(int(m[1]), int(m[2]), len(m[3]), m[4]) for m in rows if m]
    top = [r for r in rows if r[2] == 1]
    total = sum(r[1] for r in top) / 1e6
    worst = sorted(top, key=lambda r: -r[1])[:3]
    return total, any(r[3] == "numpy" for r in rows), ", ".join(f"{r[3]} {r[1] / 1e3:.0f} ms" for r in worst)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    run(["--version"])                                  # warm the file cache
    with tempfile.TemporaryDirectory() as d:
        print(f"{'command':<22} {'median ms':>9} {'imports ms':>10} {'numpy':>6}  slowest imports")
        for argv in (["--help"], ["status", "--runtime-dir", d], ["watch", "--runtime-dir", d]):
            ts = [run(argv)[0] for _ in range(a.repeats)]
            imp, np_, worst = importtime(argv)
            print(f"{' '.join(argv[:1]):<22} {statistics.median(ts) * 1e3:>9.0f} {imp * 1e3:>10.0f} "
                  f"{'yes' if np_ else 'no':>6}  {worst}")
    if not os.path.exists(XSENS):
        print(f"calibrate: skipped, {XSENS} is absent (../shared is not beside the checkout)")
        return 0
    sys.path.insert(0, ROOT)
    from imucald.calib.inputs import read_table
    ts = []
    for _ in range(a.repeats):
        t = time.perf_counter()
        read_table(XSENS, ["t", "ax", "ay", "az"], 4069.76, 32768.0)
        ts.append(time.perf_counter() - t)
    print(f"read Xsens table (51175 rows, in process): median {statistics.median(ts) * 1e3:.0f} ms")
    argv = ["calibrate", XSENS, "--columns", "t,ax,ay,az", "--nominal-offset", "32768",
            "--nominal-scale", "4069.76", "--json"]
    ts, outs = [], set()
    for _ in range(a.repeats):
        t, p = run(argv)
        ts.append(t)
        doc = json.loads(p.stdout or b"{}")
        doc.pop("wall_s", None)                        # the run's own duration
        outs.add(hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16])
        if p.returncode:
            print(p.stderr.decode().strip())
            return 1
    imp, _, worst = importtime(argv)
    print(f"calibrate Xsens (ga)   {statistics.median(ts) * 1e3:>9.0f} {imp * 1e3:>10.0f}    yes  {worst}")
    print(f"calibrate result digest: {', '.join(sorted(outs))} (the same over the {a.repeats} runs: "
          f"{len(outs) == 1}; wall_s left out)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
