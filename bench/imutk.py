"""The whole calibration of the IMU-TK Xsens MTi recording, timed as a user runs it, as a
ratio to ``python -c "import numpy"`` measured in the same run (issue 27).

Commands (fresh processes, interleaved: one of each per round, the rounds repeated; medians
of wall time over the rounds, and of the child's CPU time):

* ``numpy``: ``python -c "import numpy"``, the baseline;
* ``accel (Xsens file)``: ``calibrate xsens_acc.mat --columns t,ax,ay,az --nominal-offset 32768
  --nominal-scale 4069.76 --json`` (the README's command on the raw IMU-TK file); ``accel
  (Xsens file, -o)``: the same with its text report and ``-o`` (the calibration file written);
* ``whole (2 files, -o)``: the whole calibration from IMU-TK's own two files, what its app
  does: ``calibrate xsens_acc.mat --columns t,ax,ay,az --join xsens_gyro.mat --join-columns
  t,gx,gy,gz --nominal-offset 32768 --nominal-scale accel=4069.76,gyro=83.39 --sensor all -o
  FILE`` (for a ``--before`` tree only when it has ``--join``);
* ``accel``, ``gyro``, ``all``: ``calibrate REC --sensor ...`` on the merged recording
  (accelerometer and gyro on their common timestamps, built as bench/real_gap.py builds it,
  written to a temporary imucald recording);
* with ``--before DIR`` (a checkout of an older commit, e.g. ``git archive bd2ec0f | tar -x
  -C /tmp/base``): the same commands with that tree's imucald, in the same rounds; its
  ``all`` is ``--sensor accel`` then ``--sensor gyro`` (two commands: ``--sensor all`` did
  not exist);
* with ``IMUTK_CALIB=/path/to/test_imu_calib`` set: IMU-TK's own app on the two files, and
  a line comparing it with ``whole``.  IMU-TK is never vendored and has no package.  Built
  here (2026-11-27) from the repository Kyle-ak/imu_tk at commit 1fd1e1ab (BSD), Release,
  against Debian's ``libeigen3-dev libceres-dev libboost-dev`` (Ceres 2.1, Eigen 3.4): that
  commit's visualisation needs PCL and gnuplot, so its CMakeLists was built without PCL and
  visualization.cpp, and the three lines of calibration.cpp that plot the static intervals
  and wait for a key (no terminal here) were removed; the calibration itself is unchanged.
  The app is ``bin/test_imu_calib ACC GYRO`` (it writes test_imu_acc.calib and
  test_imu_gyro.calib in its working directory: a temporary one here).

With ``--before``, the Xsens commands' answers are compared with that tree's byte for byte
(the JSON without the fit's own ``wall_s``, the text report, the calibration file without
its creation time).  Then the agreement of ``--sensor all`` with the separate commands: the largest difference of
each parameter over its reported standard error.  The byte code of each tree is compiled
first (``compileall``), as an installed package has it.

With ``--stages``: where the accelerometer command's time goes, stage by stage
(bench/_imutk_stages.py: the same steps in one fresh process, CPU time per stage, medians
over the rounds; with ``--before``, that tree's stages in the same rounds).
Usage: python bench/imutk.py [--rounds N] [--before DIR] [--stages]
"""
import argparse
import compileall
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from _common import ROOT

REAL = os.path.join(ROOT, "..", "shared", "data", "real", "imutk_xsens_mti")
ACC = os.path.join(REAL, "xsens_acc.mat")
GYRO = os.path.join(REAL, "xsens_gyro.mat")
RAW = ["--columns", "t,ax,ay,az", "--nominal-offset", "32768", "--nominal-scale", "4069.76"]
#: the whole calibration from IMU-TK's own two files, what its app does (docs/guide/calibrating.md)
WHOLE = ["--columns", "t,ax,ay,az", "--join", GYRO, "--join-columns", "t,gx,gy,gz",
         "--nominal-offset", "32768", "--nominal-scale", "accel=4069.76,gyro=83.39", "--sensor", "all"]


def run(argv, tree=None, cwd=None, env_extra=None):
    """(wall s, CPU s of the child, stdout) of one command; ``tree``: the checkout whose
    imucald it runs (PYTHONPATH and working directory); ``env_extra``: more variables."""
    env = dict(os.environ, **(env_extra or {}))
    if tree is not None:
        env["PYTHONPATH"] = tree
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run(argv, capture_output=True, cwd=cwd or tree or ROOT, env=env)
    wall = time.perf_counter() - t
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode:
        raise SystemExit(f"{' '.join(argv)}: exit {p.returncode}: {p.stderr.decode().strip()[-300:]}")
    return wall, (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime), p.stdout


def _has_join(tree) -> bool:
    """Whether that tree's calibrate reads a second table (``--join``, from 4ddb46d on)."""
    with open(os.path.join(tree, "imucald", "cli", "parser.py")) as f:
        return '"--join"' in f.read()


def commands(merged, before):
    py = sys.executable
    cal = [py, "-m", "imucald.cli", "calibrate"]
    out = [("numpy", [[py, "-c", "import numpy"]], None)]
    for label, tree in (("", ROOT),) + ((("before ", before),) if before else ()):
        out.append((f"{label}accel (Xsens file)", [cal + [ACC, *RAW, "--json"]], tree))
        out.append((f"{label}accel (Xsens file, -o)",
                    [cal + [ACC, *RAW, "-o", f"xsens_{'before' if label else 'after'}.yaml"]], tree))
        if _has_join(tree):
            out.append((f"{label}whole (2 files, -o)",
                        [cal + [ACC, *WHOLE, "-o", f"xsens_whole_{'before' if label else 'after'}.yaml"]], tree))
        for s in ("accel", "gyro"):
            out.append((f"{label}{s}", [cal + [merged, "--sensor", s, "--json"]], tree))
        if label:
            out.append((f"{label}all (accel + gyro)", [cal + [merged, "--sensor", s, "--json"]
                                                        for s in ("accel", "gyro")], tree))
        else:
            out.append(("all", [cal + [merged, "--sensor", "all", "--json"]], tree))
    imutk = os.environ.get("IMUTK_CALIB")
    if imutk:
        out.append(("IMU-TK test_imu_calib", [[imutk, ACC, GYRO]], None))
    return out


def agreement(docs):
    """Largest |all - separate| / reported standard error, per part."""
    import numpy as np
    a, sa, sg = docs["all"], docs["accel"], docs["gyro"]
    rows = []
    for g in sa["params"]:
        d = np.abs(np.subtract(a["accel"]["params"][g], sa["params"][g])) / np.asarray(sa["stderr"][g])
        rows.append((f"accel {g}", float(d.max())))
    ra, rg = a["gyro"]["rotations"], sg["rotations"]
    for k, se in (("matrix", "matrix_stderr"), ("g_sens_dps_per_g", "g_sens_stderr")):
        if ra.get(k) is not None and rg.get(k) is not None:
            d = np.abs(np.subtract(ra[k], rg[k])) / np.asarray(rg[se])
            rows.append((f"gyro {k}", float(d.max())))
    d = np.abs(np.subtract(a["gyro"]["file"]["bias_dps"], sg["file"]["bias_dps"])) / np.asarray(
        sg["stderr"]["bias_dps"])
    rows.append(("gyro file bias_dps", float(d.max())))
    for k in ("cal_mean_deg", "cal_max_deg"):
        rows.append((f"gyro held-out {k} (deg, absolute)", abs(ra["heldout"][k] - rg["heldout"][k])))
    return rows


def stages(rounds, before):
    """CPU ms per stage of the accelerometer calibrate (bench/_imutk_stages.py), medians over
    ``rounds`` fresh processes per tree, the trees interleaved."""
    child = [sys.executable, os.path.join(ROOT, "bench", "_imutk_stages.py"), ACC]
    trees = [("after" if before else "this tree", ROOT)] + ([("before", before)] if before else [])
    got = {label: [] for label, _ in trees}
    for _ in range(rounds):
        for label, tree in trees:
            # one BLAS thread, as the CLI sets before numpy's import (cli/__init__.py): with
            # a pool, its spinning threads' CPU lands in whichever stage first calls BLAS
            got[label].append(json.loads(run(child, tree, env_extra={"OPENBLAS_NUM_THREADS": "1"})[2]))
    print(f"where the accelerometer command's CPU goes (ms, medians of {rounds} fresh processes):")
    names = list(got[trees[0][0]][0])
    print(f"{'stage':<24}" + "".join(f"{label:>11}" for label, _ in trees))
    for n in names + ["total"]:
        row = [statistics.median(sum(r.values()) if n == "total" else r[n] for r in got[label])
               for label, _ in trees]
        print(f"{n:<24}" + "".join(f"{v:>11.1f}" for v in row))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--before", help="a checkout of an older commit, timed in the same rounds")
    ap.add_argument("--stages", action="store_true",
                    help="only the accelerometer command's CPU time stage by stage")
    a = ap.parse_args()
    if not os.path.exists(ACC):
        print(f"skipped: {ACC} is absent (../shared is not beside the checkout)")
        return 0
    if a.stages:
        for tree in (ROOT, a.before):
            if tree:
                compileall.compile_dir(os.path.join(tree, "imucald"), quiet=1)
        stages(a.rounds, a.before and os.path.abspath(a.before))
        return 0
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    from real_gap import xsens
    from imucald.files.recording import write_recording
    for tree in (ROOT, a.before):
        if tree:
            compileall.compile_dir(os.path.join(tree, "imucald"), quiet=1)
    with tempfile.TemporaryDirectory() as d:
        merged = os.path.join(d, "xsens_merged.csv")
        write_recording(xsens(), merged)
        cmds = commands(merged, a.before and os.path.abspath(a.before))
        for _, argvs, tree in cmds:               # warm the file cache
            run(argvs[0], tree, d)
        times = {name: [] for name, _, _ in cmds}
        docs, outs = {}, {}
        for _ in range(a.rounds):
            for name, argvs, tree in cmds:
                w = c = 0.0
                for argv in argvs:
                    dw, dc, out = run(argv, tree, d)
                    w, c = w + dw, c + dc
                    if name in ("accel", "gyro", "all") and out.strip():
                        docs[name] = json.loads(out)
                    if "Xsens" in name:
                        outs[name] = out
                times[name].append((w, c))
        for w in ("after", "before") if a.before else ():
            outs[f"{w} file"] = open(os.path.join(d, f"xsens_{w}.yaml"), "rb").read()
    base = statistics.median(t[0] for t in times["numpy"])
    base_cpu = statistics.median(t[1] for t in times["numpy"])
    print(f"IMU-TK Xsens MTi (51175 samples at 100 Hz): {a.rounds} interleaved rounds, medians; "
          f"baseline python -c 'import numpy' {base * 1e3:.0f} ms wall, {base_cpu * 1e3:.0f} ms CPU")
    print(f"{'command':<28} {'wall ms':>8} {'x numpy':>8} {'CPU ms':>7} {'x numpy':>8}")
    for name, _, _ in cmds:
        w = statistics.median(t[0] for t in times[name])
        c = statistics.median(t[1] for t in times[name])
        print(f"{name:<28} {w * 1e3:>8.0f} {w / base:>8.2f} {c * 1e3:>7.0f} {c / base_cpu:>8.2f}")
    med = {n: statistics.median(t[0] for t in times[n]) for n, _, _ in cmds}
    if "IMU-TK test_imu_calib" in med and "whole (2 files, -o)" in med:
        print(f"the whole calibration from IMU-TK's two files: imucald {med['whole (2 files, -o)'] * 1e3:.0f} ms, "
              f"IMU-TK's app {med['IMU-TK test_imu_calib'] * 1e3:.0f} ms wall "
              f"({med['IMU-TK test_imu_calib'] / med['whole (2 files, -o)']:.1f}x imucald's)")
    if a.before:
        same_as_before(outs)
    print("--sensor all against the separate commands (|difference| / reported standard error):")
    for k, v in agreement(docs):
        print(f"  {k:<44} {v:.2e}")
    return 0


def same_as_before(outs):
    """The Xsens commands' answers against the before tree's: stdout (the --json object
    without the fit's own wall_s; the text report) and the -o file without its creation
    time, compared byte for byte, with their sha256."""
    import hashlib
    import re
    strip_wall = lambda b: re.sub(rb'"wall_s": [0-9.e-]+', b'"wall_s": _', b)
    strip_created = lambda b: re.sub(rb"created: '[^']*'", b"created: _", b)
    pairs = [("--json stdout", strip_wall(outs["accel (Xsens file)"]), strip_wall(outs["before accel (Xsens file)"])),
             ("-o text stdout", outs["accel (Xsens file, -o)"], outs["before accel (Xsens file, -o)"])]
    pairs.append(("-o calibration file", strip_created(outs["after file"]), strip_created(outs["before file"])))
    print("the Xsens commands' answers against the before tree's (sha256, first 16 hex digits):")
    for what, x, y in pairs:
        h = lambda b: hashlib.sha256(b).hexdigest()[:16]
        print(f"  {what:<22} {'identical' if x == y else 'DIFFERENT'}  {h(x)} / {h(y)}")


if __name__ == "__main__":
    sys.exit(main())
