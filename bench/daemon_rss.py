"""Resident memory of the running daemon and its calibration worker (issue 15's budget:
<= 45 MB idle, <= 60 MB while calibrating, the daemon and worker processes summed).

Each repeat starts ``imucald run --emulate --speed S`` (the emulated board's tour at S times
real time, fresh state and sockets in a temporary directory) and reads /proc:

* idle, before any calibration: the daemon's VmRSS (and PSS, from smaps_rollup, which
  counts a shared page once per sharer), median of 10 reads over 1 s, once the daemon has
  streamed for a few seconds;
* calibrating: the daemon's automatic first calibration (at calibration.min_poses poses)
  and then one asked for on the control socket (``recalibrate``): every 5 ms, the daemon's
  VmRSS plus each worker's VmHWM (its peak so far: a worker lives ~0.3 s, so a poll
  between two reads cannot miss its peak); the largest sum over the job;
* idle, after the calibrations (no worker left: none runs between jobs).

Prints the medians over the repeats.  Usage: python bench/daemon_rss.py [--repeats N]
[--board B] [--speed S]
"""
import argparse
import os
import statistics
import sys
import tempfile
import time

from _common import control, start_daemon, status_kb, stop_daemon


def pss_kb(pid):
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Pss:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def frames(pid):
    """Physical page frames the process has resident (its /proc pagemap; needs root to see
    frame numbers): pages shared by the daemon and the worker (libpython, numpy's libraries)
    are then counted once, as the machine holds them.  None without the rights."""
    import numpy as np
    out = []
    try:
        with open(f"/proc/{pid}/maps") as m, open(f"/proc/{pid}/pagemap", "rb") as pm:
            for line in m:
                a, b = (int(x, 16) for x in line.split()[0].split("-"))
                if a >= 1 << 47:                      # [vsyscall]
                    continue
                pm.seek(a // 4096 * 8)
                e = np.frombuffer(pm.read((b - a) // 4096 * 8), "<u8")
                out.append(e[(e >> np.uint64(63)) == 1] & np.uint64((1 << 55) - 1))
    except OSError:
        return None
    f = np.concatenate(out) if out else np.zeros(0, np.uint64)
    return None if len(f) and not f.any() else f       # all zero: frame numbers hidden


def union_mb(pids):
    """MB of distinct physical pages resident in the processes together (None if hidden)."""
    import numpy as np
    fs = [frames(p) for p in pids]
    fs = [f for f in fs if f is not None] if all(f is not None for f in fs) else None
    return None if not fs else len(np.unique(np.concatenate(fs))) * 4096 / 2 ** 20


def children(pid):
    """Process ids whose parent is pid (the calibration workers)."""
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                st = f.read()
        except OSError:
            continue
        if int(st[st.rindex(")") + 2:].split()[1]) == pid:
            out.append(int(d))
    return out


def idle_mb(pid):
    """(median VmRSS MB, median PSS MB) of the daemon and any worker, 10 reads over 1 s."""
    rss, pss = [], []
    for _ in range(10):
        ps = [pid] + children(pid)
        rss.append(sum(status_kb(p, "VmRSS") for p in ps) / 1024)
        pss.append(sum(pss_kb(p) for p in ps) / 1024)
        time.sleep(0.1)
    return statistics.median(rss), statistics.median(pss)


def _nan(x):
    return float("nan") if x is None else x


def _nanmax(*xs):
    xs = [x for x in xs if x == x]
    return max(xs) if xs else float("nan")


def watch_job(pid, start, timeout_s=120.0):
    """Over one job, from ``start()`` (it asks for the job, or does nothing to wait for the
    daemon's own) until a worker has come and gone: peak (daemon VmRSS + workers' VmHWM) MB,
    peak (daemon + workers) PSS MB and peak distinct physical MB."""
    seen, peak, ppss, puni = set(), 0.0, 0.0, None
    t_end = time.monotonic() + timeout_s
    start()
    while time.monotonic() < t_end:
        ws = children(pid)
        if ws:
            seen.update(ws)
            peak = max(peak, (status_kb(pid, "VmRSS") + sum(status_kb(w, "VmHWM") for w in ws)) / 1024)
            ppss = max(ppss, sum(pss_kb(q) for q in [pid] + ws) / 1024)
            u = union_mb([pid] + ws)              # None when a worker ended mid-read
            if u is not None:
                puni = u if puni is None else max(puni, u)
        elif seen:
            return peak, ppss, _nan(puni)
        time.sleep(0.005)
    return float("nan"), float("nan"), float("nan")


def one_run(board, speed):
    with tempfile.TemporaryDirectory(prefix="imucald-rss-") as d:
        sock = os.path.join(d, "control.sock")
        p = start_daemon(d, os.path.join(d, "state"), "--board", board, "--speed", speed)
        try:
            time.sleep(3.0)                               # streaming, poses accumulating
            idle0 = idle_mb(p.pid)
            first = watch_job(p.pid, lambda: None)        # the automatic first calibration
            t_end = time.monotonic() + 60
            while not control(sock, "status", 5.0).get("calibration_id") and time.monotonic() < t_end:
                time.sleep(0.2)
            again = watch_job(p.pid, lambda: control(sock, "recalibrate", 5.0))
            time.sleep(1.0)
            idle1 = idle_mb(p.pid)
            hwm = status_kb(p.pid, "VmHWM") / 1024
            return idle0, first, again, idle1, hwm
        finally:
            stop_daemon(p, 10)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--board", default="mpu6050")
    ap.add_argument("--speed", type=float, default=10.0, help="emulated time per wall second")
    a = ap.parse_args()
    runs = []
    for i in range(a.repeats):
        r = one_run(a.board, a.speed)
        runs.append(r)
        (i0, p0), (c1, w1, u1), (c2, w2, u2), (i1, p1), hwm = r
        print(f"run {i + 1}: idle {i0:.1f} MB RSS (PSS {p0:.1f}); calibrating, first / recalibrate: "
              f"RSS {c1:.1f} / {c2:.1f}, PSS {w1:.1f} / {w2:.1f}, distinct {u1:.1f} / {u2:.1f} MB; "
              f"idle after {i1:.1f} MB (PSS {p1:.1f}); daemon peak {hwm:.1f} MB", flush=True)
    med = lambda f: statistics.median(f(r) for r in runs)
    print(f"\n{a.board} emulated at {a.speed:g}x, median of {len(runs)} daemons (daemon + worker processes):")
    print(f"  idle before any calibration  {med(lambda r: r[0][0]):5.1f} MB RSS  {med(lambda r: r[0][1]):5.1f} MB PSS")
    print(f"  while calibrating (peak)     {med(lambda r: max(r[1][0], r[2][0])):5.1f} MB RSS  "
          f"{med(lambda r: max(r[1][1], r[2][1])):5.1f} MB PSS  "
          f"{med(lambda r: _nanmax(r[1][2], r[2][2])):5.1f} MB distinct physical pages")
    print(f"  idle after calibrating       {med(lambda r: r[3][0]):5.1f} MB RSS  {med(lambda r: r[3][1]):5.1f} MB PSS")
    print(f"  daemon's own peak (VmHWM)    {med(lambda r: r[4]):5.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
