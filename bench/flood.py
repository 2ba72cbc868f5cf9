"""Control-socket flood against a daemon sampling at 1 kHz in real time (issue 12: one 63 KB
write lost 83 samples, and unread replies grew the daemon from 46 to 187 MB).

Each repeat starts ``imucald run --emulate --rate 1000 --speed 1`` (MPU-6050 emulator, whose
1024-byte FIFO holds 73 ms of samples: a sampling loop held up longer than that loses
samples, counted in board_stats ``missing``), fresh state and sockets in a temporary
directory, lets it run a quiet window, then a flood window in which C clients each send
``status\\n`` x 9000 (63 KB) writes as fast as the socket takes them and never read a
reply.  Per window: samples read, samples lost (``missing``), gaps, the daemon's CPU (% of
one core, user + system, over the window), its VmRSS at
the window's end and its VmHWM (peak so far), bytes the flooders got into the socket,
connections refused (beyond control's client limit) and the polls in which the daemon
throttled a client (control stats).

Prints the medians over the repeats.  Usage: python bench/flood.py [--repeats N]
[--seconds S] [--clients C ...]
"""
import argparse
import os
import socket
import statistics
import tempfile
import threading
import time

from _common import control, start_daemon, status_kb, stop_daemon


def _control(sock_path, cmd="status"):
    """The reply to ``cmd``; retried while the daemon refuses (all client slots taken, or
    still held by flooders that have just hung up)."""
    t0 = time.time()
    while True:
        r = control(sock_path, cmd)
        if r.get("class") != "ERROR" or time.time() - t0 > 30:
            return r
        time.sleep(0.2)


def _flood(sock_path, stop, sent):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.connect(sock_path)
    except OSError:
        return                                  # refused beyond the client limit: fine
    s.settimeout(0.5)
    chunk = b"status\n" * 9000                  # 63 KB; the replies are never read
    while not stop.is_set():
        try:
            sent.append(s.send(chunk))
        except socket.timeout:
            pass
        except OSError:
            break
    s.close()


def _cpu_s(pid):
    """User + system CPU seconds of ``pid`` so far."""
    with open(f"/proc/{pid}/stat") as f:
        st = f.read().rsplit(")", 1)[1].split()
    return (int(st[11]) + int(st[12])) / os.sysconf("SC_CLK_TCK")


def _window(pid, sock_path, seconds, clients):
    s0 = _control(sock_path)
    cpu0, w0 = _cpu_s(pid), time.time()
    stop, sent, ths = threading.Event(), [], []
    for _ in range(clients):
        th = threading.Thread(target=_flood, args=(sock_path, stop, sent), daemon=True)
        th.start()
        ths.append(th)
    time.sleep(seconds)
    rss = status_kb(pid, "VmRSS") / 1024
    cpu = 100 * (_cpu_s(pid) - cpu0) / (time.time() - w0)
    stop.set()
    for th in ths:
        th.join(5)
    s1 = _control(sock_path)
    b0, b1 = s0["board_stats"], s1["board_stats"]
    c0, c1 = s0["control"], s1["control"]
    return {"samples": b1["samples"] - b0["samples"], "lost": b1["missing"] - b0["missing"],
            "gaps": b1["gaps"] - b0["gaps"], "cpu_pct": cpu, "rss_mb": rss, "hwm_mb": status_kb(pid, "VmHWM") / 1024,
            "sent_mb": sum(sent) / 1e6,
            "refused": c1["refused"] - c0["refused"],
            "throttled": c1["throttled"] - c0["throttled"]}


def run_once(seconds, clients):
    with tempfile.TemporaryDirectory(prefix="imucald-flood-") as d:
        rt = os.path.join(d, "run")
        sock = os.path.join(rt, "control.sock")
        p = start_daemon(rt, os.path.join(d, "state"), "--rate", "1000", "--speed", "1", timeout_s=60)
        try:
            time.sleep(2.0)                             # past start-up
            out = []
            for c in clients:           # each flood window after a quiet one: same machine load
                out.append((0, _window(p.pid, sock, seconds, 0)))
                out.append((c, _window(p.pid, sock, seconds, c)))
        finally:
            stop_daemon(p, 30)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--clients", type=int, nargs="+", default=[1, 8])
    a = ap.parse_args()
    wins = [w for _ in range(a.repeats) for w in run_once(a.seconds, a.clients)]
    keys = ["samples", "lost", "gaps", "cpu_pct", "rss_mb", "hwm_mb", "sent_mb", "refused", "throttled"]
    print(f"imucald run --emulate --rate 1000 --speed 1: {a.seconds:g} s windows, a quiet one before "
          f"each flood; medians over {a.repeats} runs (max lost: the worst window)")
    print(f"{'flooders':>9}{'windows':>8}" + "".join(f"{k:>10}" for k in keys) + f"{'max lost':>10}")
    for c in sorted({c for c, _ in wins}):
        rs = [r for cc, r in wins if cc == c]
        med = {k: statistics.median(r[k] for r in rs) for k in keys}
        print(f"{c:>9}{len(rs):>8}" + "".join(f"{med[k]:>10.1f}" if k[-2:] in ("mb", "ct")
                                            else f"{med[k]:>10g}" for k in keys)
              + f"{max(r['lost'] for r in rs):>10}")


if __name__ == "__main__":
    main()
