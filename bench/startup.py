"""Start-up and end-to-end command times, as a user runs them (fresh processes).

* ``imucald --help``, ``status`` and ``watch`` with no daemon running (they stop at the
  missing socket, after loading all they need), and ``status`` against a running daemon
  (``imucald run --emulate`` started here): wall time and CPU time (user + system of the
  child) as medians over the repeats, and ``python -X importtime`` -- total import time and
  whether numpy was imported.  CPU time is the figure to compare on a shared machine: other
  processes stretch the wall time, hardly the CPU time.
* ``imucald calibrate`` on the IMU-TK Xsens file (raw counts, README's command): the same
  medians and the result's digest, to compare before/after a change.

The package's byte code is compiled first (``compileall``; an installed package has it, and
with PYTHONDONTWRITEBYTECODE set every run would otherwise compile imucald's sources anew).
Usage: python bench/startup.py [--repeats N]
"""
import argparse
import compileall
import hashlib
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from _common import ROOT, start_daemon, stop_daemon

XSENS = os.environ.get("IMUCALD_XSENS") or os.path.join(ROOT, "..", "shared", "data", "real",
                                                         "imutk_xsens_mti", "xsens_acc.mat")


def run(argv, extra=()):
    """(wall s, CPU s of the child, CompletedProcess) of one ``imucald argv``."""
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run([sys.executable, *extra, "-m", "imucald.cli", *argv], capture_output=True,
                       cwd=ROOT)
    wall = time.perf_counter() - t
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime), p


def medians(argv, repeats):
    """(median wall ms, median CPU ms, last CompletedProcess) over the repeats."""
    rs = [run(argv) for _ in range(repeats)]
    return (statistics.median(r[0] for r in rs) * 1e3, statistics.median(r[1] for r in rs) * 1e3,
            rs[-1][2])


def importtime(argv):
    """(total import s, numpy imported?, slowest top-level packages) from -X importtime."""
    _, _, p = run(argv, ("-X", "importtime"))
    rows = [re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", l)
            for l in p.stderr.decode().splitlines()]
    rows = [(int(m[1]), int(m[2]), len(m[3]), m[4]) for m in rows if m]
    top = [r for r in rows if r[2] == 1]
    total = sum(r[1] for r in top) / 1e6
    worst = sorted(top, key=lambda r: -r[1])[:3]
    return total, any(r[3] == "numpy" for r in rows), ", ".join(f"{r[3]} {r[1] / 1e3:.0f} ms" for r in worst)


def row(name, wall_ms, cpu_ms, argv):
    imp, np_, worst = importtime(argv)
    print(f"{name:<24} {wall_ms:>8.0f} {cpu_ms:>7.0f} {imp * 1e3:>10.0f} {'yes' if np_ else 'no':>6}  {worst}",
          flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    compileall.compile_dir(os.path.join(ROOT, "imucald"), quiet=1)
    run(["--version"])                                  # warm the file cache
    print(f"{'command':<24} {'wall ms':>8} {'CPU ms':>7} {'imports ms':>10} {'numpy':>6}  slowest imports")
    with tempfile.TemporaryDirectory() as d:
        for argv in (["--help"], ["status", "--runtime-dir", d], ["watch", "--runtime-dir", d]):
            w, c, _ = medians(argv, a.repeats)
            row(f"{argv[0]} (no daemon)" if argv[0] != "--help" else argv[0], w, c, argv)
        try:
            p = start_daemon(d, os.path.join(d, "state"), timeout_s=20)
        except RuntimeError as e:
            print(f"status (daemon running): the emulated daemon did not come up ({e})")
        else:
            try:
                argv = ["status", "--runtime-dir", d]
                w, c, _ = medians(argv, a.repeats)
                row("status (daemon running)", w, c, argv)
            finally:
                stop_daemon(p, 10)
    if not os.path.exists(XSENS):
        print(f"calibrate: skipped, {XSENS} is absent (../shared is not beside the checkout)")
        return 0
    sys.path.insert(0, ROOT)
    from imucald.fitting.inputs import read_table
    ts = []
    for _ in range(a.repeats):
        t = time.perf_counter()
        read_table(XSENS, ["t", "ax", "ay", "az"], 4069.76, 32768.0)
        ts.append(time.perf_counter() - t)
    print(f"read Xsens table (51175 rows, in process): median {statistics.median(ts) * 1e3:.0f} ms")
    argv = ["calibrate", XSENS, "--columns", "t,ax,ay,az", "--nominal-offset", "32768",
            "--nominal-scale", "4069.76", "--json"]
    rs, outs = [], set()
    for _ in range(a.repeats):
        w, c, p = run(argv)
        rs.append((w, c))
        if p.returncode:
            print(p.stderr.decode().strip())
            return 1
        doc = json.loads(p.stdout or b"{}")
        doc.pop("wall_s", None)                        # the run's own duration
        outs.add(hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16])
    row("calibrate Xsens (ga)", statistics.median(r[0] for r in rs) * 1e3,
        statistics.median(r[1] for r in rs) * 1e3, argv)
    print(f"calibrate result digest: {', '.join(sorted(outs))} (the same over the {a.repeats} runs: "
          f"{len(outs) == 1}; wall_s left out)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
