"""Shared set-up for the benchmark scripts (run them from the repository root)."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from imucald.specs import ACCEL  # noqa: E402
from imucald.sim.sensor import pose_sigma  # noqa: E402

#: Paper 000 does not state its simulation noise.  We use the MPU-6050 datasheet
#: density (400 ug/rtHz) at the paper's real-experiment settings, 50 Hz for 20 s
#: per pose, samples independent over the 25 Hz Nyquist band: sigma_sample = 2.0 mg,
#: sigma_pose = 63 ug.  Paper 000's reported error STDs (2e-5 g bias, 2.5e-5 scale)
#: are of this order, which supports the choice.
SIGMA_POSE_G = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 50.0, 20.0)[1]


def median_time(fn, repeats):
    import time
    ts = []
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), out


# --- a daemon under test: start/stop, /proc figures, the control socket ----------------------

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def status_kb(pid, key):
    """One ``key:`` figure (kB) of /proc/pid/status, e.g. VmRSS or VmHWM; 0 once pid is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def control(sock_path, cmd, timeout_s=20.0):
    """The daemon's JSON reply to one control-socket command."""
    import json
    import socket
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout_s)
    s.connect(sock_path)
    with s:
        s.sendall((cmd + "\n").encode())
        buf = b""
        while not buf.endswith(b"\n"):
            d = s.recv(65536)
            if not d:
                break
            buf += d
    return json.loads(buf)


def start_daemon(runtime_dir, state_dir, *extra, timeout_s=30.0):
    """``imucald run --emulate *extra`` with its sockets in runtime_dir and its state in
    state_dir; returns the process once its control socket answers ``status``.  Raises
    RuntimeError (with the end of the daemon's stderr) if it does not within timeout_s."""
    import subprocess
    import tempfile
    import time
    err = tempfile.TemporaryFile()      # a file, not a pipe: a chatty daemon never blocks on it
    p = subprocess.Popen([sys.executable, "-m", "imucald.cli", "run", "--emulate", *map(str, extra),
                          "--runtime-dir", runtime_dir, "--state-dir", state_dir],
                         cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
    sock = os.path.join(runtime_dir, "control.sock")
    t_end = time.monotonic() + timeout_s
    while p.poll() is None and time.monotonic() < t_end:
        if os.path.exists(sock):
            try:
                control(sock, "status", timeout_s=5.0)
                return p
            except (OSError, ValueError):
                pass
        time.sleep(0.1)
    stop_daemon(p)
    err.seek(0)
    raise RuntimeError(f"the daemon did not start: {err.read().decode(errors='replace')[-300:]}")


def stop_daemon(p, timeout_s=30.0):
    """SIGTERM, then SIGKILL if the daemon has not exited within timeout_s."""
    import subprocess
    p.terminate()
    try:
        p.wait(timeout_s)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


# --- a validation page: the figures as the bench script measured them -------------------------

def provenance() -> dict:
    """What the figures were measured on: the commit (with '+changes' when the tree differs
    from it), the machine (CPU model, cores, load), Python and numpy, the UTC date."""
    import datetime
    import platform
    import subprocess
    def git(*a):
        try:
            return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True,
                                  timeout=10).stdout.strip()
        except OSError:
            return ""
    commit = git("rev-parse", "--short=12", "HEAD") or "unknown"
    if git("status", "--porcelain", "--untracked-files=no", "--", "imucald", "bench"):
        commit += "+changes"
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((l.split(":", 1)[1].strip() for l in f if l.startswith("model name")), cpu)
    except OSError:
        pass
    try:
        load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        load = "?"
    return {"commit": commit, "machine": f"{cpu}, {os.cpu_count()} cores, load {load} (1/5/15 min)",
            "python": platform.python_version(), "numpy": np.__version__,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}


class Markdown:
    """Collects a bench script's figures as a Markdown page (``--markdown FILE``): a title,
    the command that produced it, the provenance, then tables and text, written atomically.
    The documentation includes these pages as they are: no figure is copied by hand."""

    def __init__(self, path, title: str, command: str):
        self.path, self.parts = path, []
        p = provenance()
        self.parts.append(
            f"<!-- generated by {command.split()[1]}: rerun it (tools/gen_validation.py), do not edit -->\n\n"
            f"# {title}\n\n"
            f"Measured by `{command}` at commit `{p['commit']}` on {p['machine']}; "
            f"Python {p['python']}, numpy {p['numpy']}; {p['date']}.\n")

    def text(self, s: str):
        self.parts.append(s.rstrip() + "\n")

    def table(self, header, rows):
        out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
        self.parts.append("\n".join(out) + "\n")

    def write(self):
        if self.path:
            from imucald.files.atomic import atomic_write_text
            atomic_write_text(self.path, "\n".join(self.parts))
            print(f"wrote {self.path}")
