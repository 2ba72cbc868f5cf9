"""The daemon survives its own parts: the calibration worker (killed, hung, orphaned), a flooding
control client, a state directory that stops taking writes, bad state files."""
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from imucald.daemon import control as ctl
from imucald.daemon.worker import WorkerDied, WorkerRunner, WorkerTimeout

from .test_daemon import control as _control
from .test_daemon import start_daemon, wait_for
from ._helpers import PY, ROOT, or_none, wait_until


def alive(pid):
    """True while ``pid`` runs (a zombie waiting for its reaper counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def children(pid):
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as fh:
                    st = fh.read().rsplit(")", 1)[1].split()
                if int(st[1]) == pid and st[0] != "Z":
                    with open(f"/proc/{d}/cmdline", "rb") as fh:
                        out.append((int(d), fh.read().replace(b"\0", b" ").decode()))
            except OSError:
                pass
    return out


# --- the worker -------------------------------------------------------------------------------

def test_worker_runs_a_job_in_its_own_process_and_none_stays():
    r = WorkerRunner(timeout_s=60)
    f = r.submit(os.getpid)
    pid = f.result(timeout=60)
    assert pid != os.getpid() and not alive(pid)
    assert r.running() == 0 and r.started == 1 and r.died == 0


def test_without_openssl_keeps_libcrypto_out_and_hashes_the_same():
    """The daemon and its worker leave OpenSSL unloaded (numpy.random would load it through
    hashlib: ~3.5 MB resident each); SHA-256 (the sensor fingerprint) gives the same digest."""
    import hashlib
    code = ("import sys\n"
            "from imucald.daemon.worker import without_openssl\n"
            "ok = without_openssl()\n"
            "import numpy.random, hashlib\n"
            "numpy.random.default_rng(1).random()\n"
            "maps = open('/proc/self/maps').read()\n"
            "print(ok, 'libcrypto' in maps, hashlib.sha256(b'imucald').hexdigest())\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["True", "False", hashlib.sha256(b"imucald").hexdigest()]


def test_a_worker_that_dies_fails_its_job_in_one_line_and_the_next_job_runs():
    r = WorkerRunner(timeout_s=60)
    with pytest.raises(WorkerDied, match=r"the calibration worker was killed \(SIGABRT; the OOM killer "
                                         r"sends SIGKILL\) without a result; the next calibration starts"):
        r.submit(os.abort).result(timeout=60)
    assert r.submit(sum, [1, 2, 3]).result(timeout=60) == 6
    assert r.died == 1 and r.started == 2


def test_a_job_that_raises_is_reported_not_fatal():
    r = WorkerRunner(timeout_s=60)
    with pytest.raises(RuntimeError, match=r"^ValueError: invalid literal for int\(\) with base 10: 'x'$"):
        r.submit(int, "x").result(timeout=60)


def test_a_hung_worker_is_killed_at_the_timeout():
    r = WorkerRunner(timeout_s=1.0)
    f = r.submit(time.sleep, 3600)
    pid = wait_until(lambda: r.pids() and r.pids()[0])
    with pytest.raises(WorkerTimeout, match=r"calibration took longer than 1 s \(calibration.timeout_s\)"):
        f.result(timeout=60)
    assert not alive(pid) and r.timeouts == 1


def test_the_worker_goes_with_its_daemon_killed_by_sigkill():
    code = ("import time, sys; from imucald.daemon.worker import WorkerRunner; r = WorkerRunner(600); "
            "r.submit(time.sleep, 600); t0 = time.time()\n"
            "while not r.pids(): time.sleep(0.02)\n"
            "print(r.pids()[0], flush=True); time.sleep(600)")
    parent = subprocess.Popen([PY, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        wpid = int(parent.stdout.readline())
        time.sleep(0.3)                       # the worker is running its job
        assert alive(wpid)
        parent.kill()
        parent.wait(timeout=10)
        wait_until(lambda: not alive(wpid), timeout=10)
    finally:
        if parent.poll() is None:
            parent.kill()


# --- the control socket -----------------------------------------------------------------------

def test_control_flood_is_bounded_per_poll_per_client_and_in_memory(tmp_path):
    now = [0.0]
    calls = []

    def handler(cmd):
        calls.append(cmd)
        return {"class": "STATUS", "pad": "x" * 2000}          # a large reply, never read
    srv = ctl.ControlServer(str(tmp_path / "c.sock"), handler, clock=lambda: now[0])
    flood = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    flood.connect(str(tmp_path / "c.sock"))
    flood.setblocking(False)
    sent = 0
    try:
        for i in range(400):
            try:
                sent += flood.send(b"status\n" * 9000)          # 63 KB writes, replies unread
            except BlockingIOError:
                pass
            before = len(calls)
            srv.poll()
            assert len(calls) - before <= ctl.PER_POLL
            for c in srv.conns:
                assert len(c.inbuf) <= ctl.MAX_LINE + 256
                assert len(c.outbuf) <= ctl.MAX_OUT + 2100
            now[0] += 0.02                                       # a batch every 20 ms
        # the rate limit: a burst, then RATE_PER_S over the 8 s of batches
        assert len(calls) <= ctl.BURST + ctl.RATE_PER_S * now[0] + 1
        assert sent > 1_000_000 or len(calls) < 400
        # a second, polite client is still served while the flood goes on
        c2 = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c2.connect(str(tmp_path / "c.sock"))
        c2.sendall(b'{"cmd": "status"}\n')
        c2.settimeout(0.01)
        got = b""
        for _ in range(200):
            srv.poll()
            now[0] += 0.02
            try:
                got += c2.recv(65536)
            except socket.timeout:
                pass
            if got.endswith(b"\n"):
                break
        assert json.loads(got)["class"] == "STATUS"
        c2.close()
    finally:
        flood.close()
        srv.close()
    assert not os.path.exists(tmp_path / "c.sock")


def test_control_refuses_connections_beyond_the_limit_and_overlong_lines(tmp_path):
    srv = ctl.ControlServer(str(tmp_path / "c.sock"), lambda c: {"class": "OK"})
    socks = []
    try:
        for _ in range(ctl.MAX_CLIENTS + 2):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.connect(str(tmp_path / "c.sock"))
            socks.append(s)
            srv.poll()                  # accepts (the listen backlog is short)
        assert len(srv.conns) == ctl.MAX_CLIENTS and srv.refused == 2
        socks[-1].settimeout(5)
        assert json.loads(socks[-1].recv(4096))["message"].startswith("too many control clients")
        socks[0].sendall(b"x" * (ctl.MAX_LINE + 10))
        socks[0].settimeout(5)
        for _ in range(5):
            srv.poll()
        assert json.loads(socks[0].recv(4096))["message"] == f"request longer than {ctl.MAX_LINE} bytes"
        assert srv.dropped == 1 and len(srv.conns) == ctl.MAX_CLIENTS - 1
    finally:
        for s in socks:
            s.close()
        srv.close()


# --- the daemon end to end --------------------------------------------------------------------

def start(tmp_path, *extra):
    """The emulated daemon, once its control socket is there (stdout unread: not piped).
    Its stderr is read as it comes by a thread (stop() returns it): left in the pipe, a
    long test's log filled it and the daemon blocked writing a log line, so the control
    socket stopped answering (seen under load, where the tests run longer)."""
    p, rt, st = start_daemon(tmp_path, *extra, stdout=subprocess.DEVNULL)
    p.err_lines = []
    p.err_thread = threading.Thread(target=lambda: p.err_lines.extend(iter(p.stderr.readline, "")),
                                    daemon=True)
    p.err_thread.start()
    wait_for(rt / "control.sock", p, timeout=120)
    # the socket file exists a moment before it listens (bind, chmod, then listen): the
    # first request could be refused; wait until one is answered
    wait_until(lambda: or_none(lambda: control(rt, "status")), timeout=120, step=0.1)
    return p, rt, st


def control(rt, cmd):
    """One control request.  The bound is for a hung daemon, not a slow one: at --speed 20 on
    a machine whose cores are busy (two CPU hogs beside other load) the sampling loop, which
    serves the socket between batches, was seen to take over 20 s to answer."""
    return _control(rt, cmd, timeout=90)


def stop(p):
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
    try:
        if hasattr(p, "err_thread"):
            p.wait(timeout=60)
            p.err_thread.join(10)
            return "".join(p.err_lines)
        return p.communicate(timeout=60)[1]
    finally:
        if p.poll() is None:
            p.kill()


def test_control_flood_loses_no_sample_at_1khz_real_time(tmp_path):
    """A flooding client never holds up sampling.  The flood is continuous, so a stall it
    caused would lose samples in every window; a loaded machine's scheduler now and then
    holds the daemon past the FIFO's ~70 ms, in quiet windows too (bench/flood.py), so up
    to 3 windows of 6 s are watched and one must lose nothing."""
    p, rt, st = start(tmp_path, "--rate", "1000", "--speed", "1")
    stop_flag = threading.Event()
    sent = [0]

    def flood():
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(str(rt / "control.sock"))
        s.settimeout(0.5)
        chunk = b"status\n" * 9000                  # 63 KB, replies never read
        while not stop_flag.is_set():
            try:
                sent[0] += s.send(chunk)
            except socket.timeout:
                pass
            except OSError:
                break
        s.close()
    windows = []
    try:
        th = threading.Thread(target=flood, daemon=True)
        th.start()
        time.sleep(0.5)                              # the flood under way
        for _ in range(3):
            s0 = control(rt, "status")["board_stats"]
            time.sleep(6.0)                          # 6000 samples at 1 kHz
            s1 = control(rt, "status")
            b1 = s1["board_stats"]
            windows.append({k: b1[k] - s0[k] for k in ("samples", "missing", "gaps")})
            if windows[-1]["missing"] == 0 and windows[-1]["gaps"] == 0:
                break
        stop_flag.set()
        th.join(5)
    finally:
        stop_flag.set()
        err = stop(p)
    assert p.returncode == 0, err
    assert all(w["samples"] > 4000 for w in windows), windows
    assert windows[-1]["missing"] == 0 and windows[-1]["gaps"] == 0, windows
    assert sent[0] >= 63_000 and s1["control"]["throttled"] > 0


def _settled(rt, n0):
    """The status once a worker started after ``n0`` workers has finished: the daemon idle,
    or a later one started (jobs run one at a time).  On a loaded machine the emulated tour
    at 20x brings new poses faster than the niced worker fits, so the daemon may never be
    idle: waiting for idle alone timed out there."""
    s = control(rt, "status")
    w = s["worker"]["started"]
    return s if w > n0 and (not s["calibrating"] or w >= n0 + 2) else None


def test_worker_killed_mid_calibration_and_the_daemon_carries_on(tmp_path):
    p, rt, st = start(tmp_path, "--speed", "20", "--seed", "2")
    try:
        wait_until(lambda: control(rt, "status")["poses"] >= 10, timeout=300, step=0.2)
        # one whole job, timed: its wall time sets the later waits.  The worker runs niced,
        # so on a machine whose cores are busy (two `yes` hogs) a job takes minutes where it
        # takes seconds on a quiet one (a fixed 120 s timed out under load)
        t0 = time.monotonic()
        n = control(rt, "status")["worker"]["started"]
        control(rt, "recalibrate")
        wait_until(lambda: _settled(rt, n), timeout=900, step=0.2)
        job_s = max(120.0, 10 * (time.monotonic() - t0))
        # idle: no worker process, no multiprocessing resource tracker (checked when the daemon
        # is idle; under load it may calibrate without a pause)
        t_end = time.monotonic() + job_s
        while time.monotonic() < t_end and control(rt, "status")["calibrating"]:
            time.sleep(0.2)
        assert all("imucald.daemon.worker" not in c and "resource_tracker" not in c
                   for _, c in children(p.pid)) or control(rt, "status")["calibrating"]
        killed = 0
        for _ in range(3):                           # kill every worker seen, as the OOM killer would
            control(rt, "recalibrate")
            w = []
            t_end = time.monotonic() + job_s         # the worker starts a moment after the reply
            while time.monotonic() < t_end:          # (a condition, not a count: under load)
                w = [pid for pid, c in children(p.pid) if "imucald.daemon.worker" in c]
                if w or not control(rt, "status")["calibrating"]:
                    break
                time.sleep(0.01)
            if w:
                os.kill(w[0], signal.SIGKILL)
                killed += 1
                k = killed
                wait_until(lambda: control(rt, "status")["worker"]["died"] >= k, timeout=job_s, step=0.2)
        assert killed >= 1
        s = control(rt, "status")
        assert s["worker"]["died"] == killed and p.poll() is None
        # a later calibration runs in a new worker and is applied or judged as usual
        n0 = s["worker"]["started"]
        control(rt, "recalibrate")
        s = wait_until(lambda: _settled(rt, n0), timeout=job_s, step=0.2)
        assert s["worker"]["started"] >= n0 + 1 and s["worker"]["died"] == killed
        assert "calibration failed" not in s["last_event"]
    finally:
        err = stop(p)
    assert p.returncode == 0 and "Traceback" not in err, err
    assert "the calibration worker was killed (SIGKILL" in err


def test_state_dir_that_stops_taking_writes_keeps_the_calibration_and_writes_it_later(tmp_path):
    p, rt, st = start(tmp_path, "--speed", "20", "--seed", "2")
    moved = tmp_path / "state.real"
    try:
        wait_until(lambda: control(rt, "status")["calibration_id"] >= 1, timeout=180, step=0.2)
        # the state directory stops taking writes (a file where it was: ENOTDIR even for root)
        os.rename(st, moved)
        st.write_text("not a directory")
        n0 = control(rt, "status")["calibration_id"]
        wait_until(lambda: control(rt, "recalibrate").get("started") is not None, timeout=60)
        s = wait_until(lambda: (lambda s: s if not s["state"]["ok"] else None)(control(rt, "status")),
                       timeout=120, step=0.2)
        assert "could not save the" in s["state"]["error"] and s["state"]["unsaved"]
        # writable again: the newest state is written without a restart
        os.unlink(st)
        os.rename(moved, st)
        s = wait_until(lambda: (lambda s: s if s["state"]["ok"] and not s["state"]["unsaved"] else None)(
            control(rt, "status")), timeout=60, step=0.2)
        from imucald.calibration import load
        assert load(st / "calibration.yaml").id == s["calibration_id"] >= n0
        # unwritable again at SIGTERM: one line, sockets removed, the process ends cleanly
        os.rename(st, moved)
        st.write_text("not a directory")
    finally:
        err = stop(p)
    assert "Traceback" not in err, err
    assert "could not be saved" in err and p.returncode == 0
    assert sorted(os.listdir(rt)) == ["imucald.lock"]


GOOD_CAL = """# imucald calibration (see README: calibration file)
format_version: 2
id: 3
created: ''
board: mpu6050
chips: {}
units: {accel: g, gyro: deg/s, mag: gauss, temperature: degC, time: s}
accel:
  model: triangular9
  params:
    alpha: [0.0, 0.0, 0.0]
    scale: [1.0, 1.0, 1.0]
    bias_g: [0.0, 0.0, 0.0]
gyro:
  model: bias
  method: mean
  params:
    bias_dps: [0.0, 0.0, 0.0]
"""


def test_the_unaltered_calibration_file_loads(tmp_path):
    from imucald.daemon.state import load_calibration
    (tmp_path / "calibration.yaml").write_text(GOOD_CAL)
    assert load_calibration(str(tmp_path), "mpu6050").id == 3


@pytest.mark.parametrize("body,why", [
    (GOOD_CAL.replace("id: 3", "id: abc"), "id"),
    (GOOD_CAL.replace("bias_g: [0.0, 0.0, 0.0]", "bias_g: [0.0, 0.0, .nan]"), "bias_g"),
    (GOOD_CAL.replace("bias_g: [0.0, 0.0, 0.0]", "bias_g: [0.0, 0.0, x]"), "bias_g"),
    (GOOD_CAL.replace("scale: [1.0, 1.0, 1.0]", "scale: [1.0, 1.0]"), "scale"),
    (GOOD_CAL.replace("    bias_dps: [0.0, 0.0, 0.0]\n", "    scale: [1.0, 1.0, 1.0]\n"), "bias_dps"),
    (GOOD_CAL.encode().replace(b"board: mpu6050", b"board: mpu6050  # \xb0C"), "UTF-8"),
])
def test_bad_calibration_file_is_set_aside_in_one_line(tmp_path, caplog, body, why):
    from imucald.daemon.state import load_calibration
    p = tmp_path / "calibration.yaml"
    p.write_bytes(body if isinstance(body, bytes) else body.encode())
    with caplog.at_level("WARNING", logger="imucald"):
        assert load_calibration(str(tmp_path), "mpu6050") is None
    assert not p.exists() and any(f.startswith("calibration.yaml.corrupt-") for f in os.listdir(tmp_path))
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and "\n" not in msgs[0] and why in msgs[0] and "set aside as" in msgs[0]


@pytest.mark.parametrize("name", ["poses.csv", "thermal.csv"])
@pytest.mark.parametrize("value,what", [("nan", "is not a finite number"), ("1e300", "is beyond")])
def test_nan_in_poses_csv_is_set_aside_in_one_line(tmp_path, caplog, name, value, what):
    """A NaN, or a value no sensor reads (1e300 in ax: the fit overflowed for minutes), in the
    saved poses or thermal log: set aside naming line and column, the daemon starts afresh."""
    from imucald.fitting.stillness.poses import PoseSet, write_poses
    from imucald.daemon.state import load_poses
    rng = np.random.default_rng(0)
    acc = rng.normal(size=(12, 3))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    cov = np.broadcast_to(np.eye(3) * 1e-8, (12, 3, 3)).copy()
    ps = PoseSet(acc=acc, acc_cov=cov / 200, n=np.full(12, 200), t0=np.arange(12.0), t1=np.arange(12.0) + 2,
                 acc_sample_cov=cov)
    write_poses(ps, str(tmp_path / name))
    assert len(load_poses(str(tmp_path), name)) == 12
    lines = (tmp_path / name).read_text().splitlines()
    i = next(k for k, l in enumerate(lines) if l[:1].isdigit() or l[:1] == "-")
    row = lines[i + 3].split(",")
    row[lines[i - 1].split(",").index("ax")] = value
    lines[i + 3] = ",".join(row)
    (tmp_path / name).write_text("\n".join(lines) + "\n")
    with caplog.at_level("WARNING", logger="imucald"):
        assert load_poses(str(tmp_path), name) is None
    msgs = [r.getMessage() for r in caplog.records]
    what = "still intervals" if name == "thermal.csv" else "poses"      # (session 20: thermal.csv's own word)
    assert len(msgs) == 1 and f"unreadable {what}" in msgs[0] and "set aside as" in msgs[0], msgs
    assert f"{name}:{i + 4}: column ax: " in msgs[0] and what in msgs[0], msgs
    assert not (tmp_path / name).exists() and any(f.startswith(name + ".corrupt-") for f in os.listdir(tmp_path))


def test_a_state_write_in_progress_is_still_unsaved():
    """``status``'s ``state.unsaved`` names the kind being written until it is on disk: it
    was popped from the pending ones first, so a status read during the write said nothing
    was unsaved while the file still held the calibration before (seen once under load:
    this file's state-directory test read id 2 from a file that status called saved at 3).
    Broken once (unsaved from the pending kinds alone): the first assertion fails."""
    import threading
    from imucald.daemon.persist import StateWriter
    entered, release, saved = threading.Event(), threading.Event(), []

    def save(kind, obj):
        entered.set()
        release.wait(10)
        saved.append((kind, obj))

    w = StateWriter(save, "the test's state")
    try:
        w.submit("calibration", 3)
        assert entered.wait(10)
        assert w.status()["unsaved"] == ["calibration"]
        release.set()
        for _ in range(1000):
            if not w.status()["unsaved"]:
                break
            threading.Event().wait(0.01)
        assert saved == [("calibration", 3)] and w.status()["unsaved"] == []
    finally:
        release.set()
        w.close()


@pytest.mark.parametrize("name", ["poses.csv", "thermal.csv"])
@pytest.mark.parametrize("case", ["other_board", "m_s2", "own", "no_header", "other_board_Key",
                                  "own_upper", "units_mg", "one_m_s2"])
def test_saved_poses_of_another_board_or_unit_are_set_aside(tmp_path, caplog, name, case):
    """Saved poses the running daemon did not make -- another board's header (a toaster's, a
    daemon helper put one there) or another tool's poses in m/s^2 -- are set aside in one line
    with the reason, not resumed; its own (header with its board) and files saved before the
    header carried the board are resumed.  Broken once: with ``_foreign`` returning None the
    two foreign cases were resumed (12 poses, this test failed).  Session 19 (a black-box
    helper): '# Board: 9dof' was read as no board line and resumed, '# board: MPU6050' set
    aside as another board's, and '# units:' not checked; broken once with the header's key and
    value compared as written (other_board_Key resumed, own_upper set aside: both fail).
    Session 20 (the same helper): one pose in m/s^2 among 11 good ones passed the median check
    and was resumed, then blocked the fit; now that row is left out with one warning naming it,
    the others resumed, the file as it was kept beside; and thermal.csv's messages speak of
    still intervals, not poses.  Broken once: _drop_foreign_rows returning ps (12 resumed:
    fails)."""
    from imucald.fitting.stillness.poses import PoseSet
    from imucald.daemon.state import load_poses, save_poses
    rng = np.random.default_rng(1)
    acc = rng.normal(size=(12, 3))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    cov = np.broadcast_to(np.eye(3) * 1e-8, (12, 3, 3)).copy()
    if case == "m_s2":
        acc, cov = acc * 9.80665, cov * 9.80665 ** 2
    if case == "one_m_s2":
        acc[4] *= 9.80665
    ps = PoseSet(acc=acc, acc_cov=cov / 200, n=np.full(12, 200), t0=np.arange(12.0),
                 t1=np.arange(12.0) + 2, acc_sample_cov=cov)
    board = {"other_board": "toaster", "no_header": ""}.get(case, "mpu6050")
    save_poses(str(tmp_path), ps, name, board=board)
    edit = {"other_board_Key": ("# board: mpu6050", "# Board: 9dof"),
            "own_upper": ("# board: mpu6050", "# board: MPU6050"),
            "units_mg": ("# units: g", "# units: mg")}.get(case)
    if edit:
        f = tmp_path / name
        f.write_text(f.read_text().replace(*edit, 1))
    with caplog.at_level("WARNING", logger="imucald"):
        back = load_poses(str(tmp_path), name, board="mpu6050")
    msgs = [r.getMessage() for r in caplog.records]
    what = "still intervals" if name == "thermal.csv" else "poses"
    if case == "one_m_s2":
        assert back is not None and len(back) == 11 and len(msgs) == 1, msgs
        assert f"{what} (data rows) 5 (|a| 9.807) not about 1 g (another unit?): left out, the others resumed" in msgs[0]
        assert np.allclose(back.acc, np.delete(acc, 4, 0), atol=1e-6)
        assert (tmp_path / name).exists() and any(f.startswith(name + ".corrupt-") for f in os.listdir(tmp_path))
        caplog.clear()                          # rewritten: the next start finds it clean
        with caplog.at_level("WARNING", logger="imucald"):
            again = load_poses(str(tmp_path), name, board="mpu6050")
        assert len(again) == 11 and caplog.records == []
        return
    if case in ("own", "no_header", "own_upper"):
        assert back is not None and len(back) == 12 and msgs == []
        assert (back.meta.get("board") or "").lower() == board
        return
    assert back is None and len(msgs) == 1 and "set aside as" in msgs[0], msgs
    assert {"other_board": "'toaster', this daemon runs 'mpu6050'", "m_s2": "m/s^2?",
            "other_board_Key": "'9dof', this daemon runs 'mpu6050'",
            "units_mg": f"{what} in 'mg'"}[case] in msgs[0]
    assert not (tmp_path / name).exists() and any(f.startswith(name + ".corrupt-") for f in os.listdir(tmp_path))


def test_a_full_disk_while_leaving_out_a_foreign_pose_resumes_the_others_and_keeps_the_file(tmp_path, caplog, monkeypatch):
    """One pose in m/s^2 among good ones on a full state disk: the copy (or the rewrite) fails,
    and the daemon exited 74 at start (a cold review).  Now the good poses are resumed from
    memory and the file is left as it was, said in the one warning.  Broken once: the OSError
    not caught (raises: fails)."""
    import errno
    from imucald.daemon import state
    from imucald.fitting.stillness.poses import PoseSet
    rng = np.random.default_rng(2)
    acc = rng.normal(size=(12, 3))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    acc[4] *= 9.80665
    cov = np.broadcast_to(np.eye(3) * 1e-8, (12, 3, 3)).copy()
    ps = PoseSet(acc=acc, acc_cov=cov / 200, n=np.full(12, 200), t0=np.arange(12.0),
                 t1=np.arange(12.0) + 2, acc_sample_cov=cov)
    state.save_poses(str(tmp_path), ps, board="mpu6050")
    before = (tmp_path / "poses.csv").read_bytes()

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(state.shutil, "copy2", full)
    with caplog.at_level("WARNING", logger="imucald"):
        back = state.load_poses(str(tmp_path), board="mpu6050")
    assert len(back) == 11 and (tmp_path / "poses.csv").read_bytes() == before
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and "the file is left as it was (No space left on device" in msgs[0], msgs
    assert not any(f.startswith("poses.csv.corrupt-") for f in os.listdir(tmp_path))
