"""Issue 21's bounded-resource figures: wall time and peak RSS of imucald commands on hostile
inputs, each the median over --repeats runs, beside a baseline (``python -c "import numpy"``)
run in the same command.

* ``nul``: a 7,353-row recording followed by --nul-gb GB of NUL bytes (a sparse file made
  with truncate, as a power cut or ``truncate -s +2G`` leaves it): calibrate, replay, noise.
* ``bomb``: a YAML billion-laughs configuration (10^8 leaves through aliases): ``run`` at
  start-up, and a running daemon sent it by SIGHUP (peak RSS of the daemon, time to the log
  line, whether status still answers and SIGTERM ends it with 0).
* ``record``: ``record --emulate --realtime`` stopped after --after-s by SIGINT, SIGTERM and
  SIGKILL: the seconds of recording each leaves.

    nice -n 10 python bench/hostile_inputs.py [--nul-gb 2] [--repeats 3]
"""
import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time

from _common import ROOT, control, status_kb

PY = sys.executable
ENV = dict(os.environ, PYTHONPATH=ROOT)


def timed(argv, **kw):
    """(wall s, peak RSS MB, returncode, stderr) of one child process (wait4's ru_maxrss)."""
    t = time.perf_counter()
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=ENV, **kw)
    err = p.stderr.read()
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    return time.perf_counter() - t, ru.ru_maxrss / 1024, p.returncode, err.decode(errors="replace")


def median_of(argv, repeats):
    runs = [timed(argv) for _ in range(repeats)]
    ws, ms = sorted(r[0] for r in runs), sorted(r[1] for r in runs)
    return ws[len(ws) // 2], ms[len(ms) // 2], runs[-1][2], runs[-1][3]


def bench_nul(d, gb, repeats, base):
    rec = os.path.join(d, "rec.csv")
    subprocess.run([PY, "-m", "imucald.cli", "simulate", "-o", rec, "--poses", "12", "--hold", "3"],
                   env=ENV, check=True, stderr=subprocess.DEVNULL)
    with open(rec, "r+b") as fh:
        fh.truncate(os.path.getsize(rec) + int(gb * (1 << 30)))
    print(f"nul: {os.path.getsize(rec) / 2**30:.2f} GB file ({gb:g} GB of NUL after 7,353 rows)")
    for cmd in (["calibrate", rec], ["replay", rec], ["noise", rec]):
        w, m, rc, err = median_of([PY, "-m", "imucald.cli", *cmd], repeats)
        warn = next((ln for ln in err.splitlines() if "warning" in ln), "")
        print(f"  {cmd[0]:9s} wall {w:6.2f} s ({w / base[0]:5.1f}x baseline)  peak {m:6.1f} MB "
              f"({m / base[1]:4.1f}x)  exit {rc}  warned: {'yes' if warn else 'NO'}")


def _bomb():
    lines = ["sensor:", '  board: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    lines += [f"  x{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 8)]
    return "\n".join(lines) + "\n"


def bench_bomb(d, repeats, base):
    bomb = os.path.join(d, "bomb.yaml")
    with open(bomb, "w") as fh:
        fh.write(_bomb())
    w, m, rc, err = median_of([PY, "-m", "imucald.cli", "run", "--emulate", "--config", bomb,
                               "--runtime-dir", os.path.join(d, "r0"), "--state-dir", os.path.join(d, "s0")],
                              repeats)
    print(f"bomb at start-up: wall {w:.2f} s ({w / base[0]:.1f}x baseline), peak {m:.1f} MB, exit {rc}: "
          f"{err.strip()[:90]}")
    cfg, rt = os.path.join(d, "c.yaml"), os.path.join(d, "run")
    with open(cfg, "w") as fh:
        fh.write("log:\n  level: info\n")
    log = open(os.path.join(d, "log.txt"), "w+")
    p = subprocess.Popen([PY, "-m", "imucald.cli", "run", "--emulate", "--config", cfg, "--runtime-dir", rt,
                          "--state-dir", os.path.join(d, "state")], env=ENV, stderr=log)
    sock = os.path.join(rt, "control.sock")
    t_end = time.monotonic() + 60
    while time.monotonic() < t_end:
        try:
            n0 = control(sock, "status")["board_stats"]["samples"]
            break
        except OSError:
            time.sleep(0.1)
    with open(cfg, "w") as fh:
        fh.write(_bomb())
    t0 = time.perf_counter()
    p.send_signal(signal.SIGHUP)
    said = None
    while time.perf_counter() - t0 < 30 and said is None:
        log.seek(0)
        said = next((ln for ln in log.read().splitlines() if "reload failed" in ln), None)
        time.sleep(0.02)
    t_line = time.perf_counter() - t0
    time.sleep(2)
    n1 = control(sock, "status")["board_stats"]["samples"]
    peak = status_kb(p.pid, "VmHWM") / 1024
    p.send_signal(signal.SIGTERM)
    rc = p.wait(30)
    print(f"bomb by SIGHUP: log line after {t_line:.2f} s, status answers, {n1 - n0} samples streamed "
          f"since, daemon peak RSS {peak:.1f} MB, SIGTERM -> exit {rc}")


def bench_record(d, after_s):
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        out = os.path.join(d, f"r{int(sig)}.csv")
        p = subprocess.Popen([PY, "-m", "imucald.cli", "record", "--emulate", "--realtime", "--seconds",
                              "120", "-o", out], env=ENV, stderr=subprocess.DEVNULL)
        time.sleep(after_s)
        p.send_signal(sig)
        rc = p.wait(30)
        sys.path.insert(0, ROOT)
        from imucald.files.recording import read_recording
        rec = read_recording(out)
        print(f"record stopped by {signal.Signals(sig).name} after {after_s:g} s: exit {rc}, "
              f"{len(rec)} samples, {rec.t[-1]:.2f} s readable")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nul-gb", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--after-s", type=float, default=4.0)
    ap.add_argument("--only", choices=["nul", "bomb", "record"])
    a = ap.parse_args()
    base = median_of([PY, "-c", "import numpy"], a.repeats)[:2]
    print(f"baseline python -c 'import numpy': wall {base[0]:.2f} s, peak {base[1]:.1f} MB "
          f"(median of {a.repeats})")
    with tempfile.TemporaryDirectory() as d:
        if a.only in (None, "nul"):
            bench_nul(d, a.nul_gb, a.repeats, base)
        if a.only in (None, "bomb"):
            bench_bomb(d, a.repeats, base)
        if a.only in (None, "record"):
            bench_record(d, a.after_s)


if __name__ == "__main__":
    main()
