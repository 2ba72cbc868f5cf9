"""A dead sensor under a watchdog (issue 22), without systemd: the daemon's side of the
protocol on a notify socket of our own.  tests/test_system.py checks the same under systemd."""
import os
import socket
import subprocess
import sys
import time

from imucald.daemon.run import STALL_S

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_a_stalled_sensor_is_logged_and_triggers_the_watchdog(tmp_path):
    """The emulated chip stops answering 1 s after the start (WatchdogSec=10s, so the ping
    period is 5 s): within STALL_S (3 s) + 1.5 s of the last fresh sample the daemon logs one
    line naming the stall and sends WATCHDOG=trigger, and sends no WATCHDOG=1 after it.
    Breakage caught: pings went on for 2 x 5 s after the last sample, nothing was logged and
    no trigger was sent (systemd restarted ~17 s after the outage)."""
    ns = str(tmp_path / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(ns)
    srv.settimeout(0.1)
    env = dict(os.environ, NOTIFY_SOCKET=ns, WATCHDOG_USEC="10000000")
    p = subprocess.Popen([sys.executable, "-m", "imucald.cli", "run", "--emulate", "--state-dir",
                          str(tmp_path / "s"), "--runtime-dir", str(tmp_path / "r"), "--fault",
                          "disconnect=0x68@1+1000"], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                         text=True, env=env, cwd=ROOT)
    msgs = []
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < 30 and not any("WATCHDOG=trigger" in m for _, m in msgs):
            try:
                msgs.append((time.monotonic(), srv.recv(4096).decode()))
            except socket.timeout:
                if p.poll() is not None:
                    break
        t_end = time.monotonic() + 0.5               # anything sent after the trigger
        while time.monotonic() < t_end:
            try:
                msgs.append((time.monotonic(), srv.recv(4096).decode()))
            except socket.timeout:
                pass
    finally:
        p.terminate()
        err = p.communicate(timeout=30)[1]
        srv.close()
    trig = [t for t, m in msgs if "WATCHDOG=trigger" in m]
    assert trig, (err[-2000:], [m[:40] for _, m in msgs][-10:])
    ready = [t for t, m in msgs if "READY=1" in m][0]
    # the last fresh sample is at most ~1 s (the outage) + one batch after READY; the trigger
    # comes STALL_S after it, plus the loop's retry time on a dead bus
    assert STALL_S <= trig[0] - ready <= 1.0 + STALL_S + 1.5, trig[0] - ready
    assert not [t for t, m in msgs if "WATCHDOG=1" in m and t > trig[0]]
    lines = [ln for ln in err.splitlines() if "no sample from the sensor for" in ln]
    assert len(lines) == 1 and "stopped feeding the watchdog" in lines[0] and "bus faults" in lines[0], err[-2000:]
