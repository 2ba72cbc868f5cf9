"""Peak resident memory (ru_maxrss of the child process) of calibrate, gap and replay
on recordings of 10 k and 100 k rows (and 1 M with --big).

The recordings are a simulated MPU-6050 session (``imucald simulate``, 30 poses held ~3 s) tiled in
time to the wanted length (t shifted so it keeps increasing), written once to a temporary
directory; so the still poses and moves are those of the simulator, repeated.
``gap`` runs with --sims 20 (memory does not grow with the number of twin simulations;
time does).  Usage: python bench/memory.py [--big] [--rows N ...]
"""
import argparse
import os
import subprocess
import sys
import tempfile

from _common import np

from imucald.files.recording import read_recording, write_recording

COMMANDS = {
    "calibrate": ["calibrate", "{f}", "--json"],
    "gap": ["gap", "{f}", "--sims", "20", "--json", "--sensor", "accel"],
    "replay": ["replay", "{f}"],
}


def tiled(base, n):
    reps = -(-n // len(base))
    span = base.t[-1] - base.t[0] + 1.0 / base.rate_hz
    t = (base.t[None, :] + span * np.arange(reps)[:, None]).ravel()[:n]
    tile = lambda a: None if a is None else np.concatenate([a] * reps)[:n]
    from imucald.files.recording import Recording
    return Recording(t=t, acc=tile(base.acc), gyro=tile(base.gyro), temp=tile(base.temp),
                     meta=dict(base.meta))


#: A bare Python that forks and execs the command and reports its ru_maxrss: Linux carries a
#: process's peak RSS across fork and exec, so spawning from this (numpy-laden) script would
#: report at least this script's own size.
_LAUNCH = ("import os, sys\n"
           "pid = os.fork()\n"
           "if pid == 0:\n"
           "    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)\n"
           "    os.execv(sys.executable, [sys.executable, '-m', 'imucald.cli'] + sys.argv[1:])\n"
           "_, st, ru = os.wait4(pid, 0)\n"
           "print(ru.ru_maxrss, os.waitstatus_to_exitcode(st))\n")


def peak_rss_mb(argv):
    """Run ``imucald argv`` as a child of a bare Python; (peak RSS in MB, exit code)."""
    p = subprocess.run([sys.executable, "-c", _LAUNCH, *argv], stdout=subprocess.PIPE,
                       stderr=subprocess.PIPE)
    kb, rc = p.stdout.split()[-2:]
    if int(rc):
        print(f"  ({argv[0]} exit {int(rc)}: {p.stderr.decode(errors='replace').strip()[-200:]})")
    return int(kb) / 1024.0, int(rc)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--big", action="store_true", help="also 1,000,000 rows (a few minutes)")
    ap.add_argument("--rows", type=int, nargs="*", help="row counts (default 10000 100000)")
    ap.add_argument("--commands", nargs="*", default=list(COMMANDS), choices=list(COMMANDS))
    a = ap.parse_args()
    rows = a.rows or ([10_000, 100_000] + ([1_000_000] if a.big else []))
    with tempfile.TemporaryDirectory(prefix="imucald-mem-") as d:
        base_path = os.path.join(d, "base.csv")
        subprocess.run([sys.executable, "-m", "imucald.cli", "simulate", "-o", base_path, "--poses",
                        "30", "--hold", "3", "--move", "1", "--seed", "1"], check=True, stderr=subprocess.DEVNULL)
        base = read_recording(base_path)
        print(f"base: simulated mpu6050, {len(base)} rows at {base.rate_hz:g} Hz, tiled")
        baseline, _ = peak_rss_mb(["--version"])
        print(f"python + imucald --version: {baseline:.0f} MB")
        print(f"{'rows':>9} {'file MB':>8} " + " ".join(f"{c + ' MB':>13}" for c in a.commands))
        for n in rows:
            f = os.path.join(d, f"r{n}.csv")
            write_recording(tiled(base, n), f)
            mb = os.path.getsize(f) / 1e6
            peaks = [peak_rss_mb([x.format(f=f) for x in COMMANDS[c]])[0] for c in a.commands]
            print(f"{n:>9} {mb:>8.1f} " + " ".join(f"{p:>13.0f}" for p in peaks), flush=True)
            os.remove(f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
