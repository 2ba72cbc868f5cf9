"""The daemon's pipeline: CPU cost per sample, highest sustained rate, lateness while a
calibration runs in the background, and resident memory.

Targets (issue 4): <= 50 us per sample on one core here (20x the MPU6050's 1 kHz),
calibration never delaying a sample by more than one batch, resident memory < 60 MB.
Usage: python bench/pipeline.py [--seconds S]
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

from _common import np

from imucald.calibration import Calibration, SensorCal
from imucald.daemon.config import DEFAULTS
from imucald.daemon.outputs import SocketSink
from imucald.daemon.pipeline import Pipeline, batch_period_s
from imucald.drivers.board import make_board
from imucald.drivers.bus import Bus, RealClock, VirtualClock
from imucald.sim.emulators import emulated_board
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import random_pose_set
import copy


def batches(board, rate, seconds):
    clk = VirtualClock()
    eb = emulated_board(board, PoseTour(random_pose_set(30, 1), rng=1, hold_s=(3, 4), move_s=(1.2, 1.8),
                                        loop=True), rng=1, clock=clk)
    b = make_board(board, Bus(eb, board, clock=clk), clk, rate_hz=rate)
    b.start()
    out = []
    period = batch_period_s(DEFAULTS["sensor"]["batch_s"], rate)     # as the daemon drains it
    while clk.now() < seconds:
        bt = b.read_batch(batch_s=period)
        if len(bt):
            out.append(bt)
    return out


#: the stream's reader, in its own process: process_time() of the bench then counts the
#: daemon's side only (a reader thread here would add its recv calls and GIL hand-overs)
_DRAIN = ("import socket, sys\n"
          "s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)\n"
          "s.connect(sys.argv[1])\n"
          "while s.recv(1 << 20):\n"
          "    pass\n")


#: the heaviest thermal terms a calibration holds (order 3, accelerometer scale term too)
THERMAL = {"order": 3, "t_min_c": 15.0, "t_ref_c": 30.0, "t_max_c": 45.0, "note": "bench"}


#: a gyro scale/misalignment matrix and g-sensitivity (fitting/gyro/rotations.py's terms)
GYRO_ROT = {"matrix": np.array([1.01, 0.004, -0.003, 0.002, 0.995, 0.006, -0.005, 0.001, 1.003]),
            "g_sens_dps_per_g": np.array([0.05, -0.02, 0.01, 0.03, -0.06, 0.02, -0.01, 0.04, 0.05])}


def cost(board, rate, seconds, fmt, tmp, thermal=False, gyro_rot=False, orientation=False):
    """CPU per sample (us) and samples; ``orientation``: the orientation filter on (issue 26,
    the orientation extra), else off as without the extra."""
    cfg = copy.deepcopy(DEFAULTS)
    cfg["output"]["format"] = fmt
    bs = batches(board, rate, seconds)
    pipe = Pipeline(cfg, board, rate, board in ("9dof", "mpu9250"))
    pipe.use_orientation("yes" if orientation else "no")
    poly = np.array([[5e-4, -4e-4, 3e-4], [1e-5, 2e-6, -3e-6], [1e-7, -1e-7, 2e-7]])
    ta = dict(THERMAL, bias_poly_g=poly, scale_poly=np.array([[1e-4, -1e-4, 5e-5]])) if thermal else None
    tg = dict(THERMAL, bias_poly_dps=poly * 40) if thermal else None
    acc = SensorCal.accel("triangular9", [0.01, 0, 0, 1.01, 0.99, 1, 0.02, -0.01, 0.03])
    pipe.applied = Calibration(board, id=1, accel=SensorCal("accel", acc.model, acc.params, thermal=ta),
                               gyro=SensorCal("gyro", "bias", {"bias_dps": np.array([1.0, -2, 0.5]),
                                                               **(GYRO_ROT if gyro_rot else {})}, thermal=tg))
    path = os.path.join(tmp, f"b-{board}-{fmt}.sock")
    sink = SocketSink(path, fmt, board, max_buffer=1 << 30)
    reader = subprocess.Popen([sys.executable, "-c", _DRAIN, path])
    while not sink.clients:
        time.sleep(0.01)
        sink.accept()
    n = sum(len(b) for b in bs)
    c0 = time.process_time()
    for b in bs:
        sink.write(pipe.process(b))
    c = time.process_time() - c0
    while sink.clients and sink.clients[0].buf:      # what the reader has not taken yet
        time.sleep(0.01)
        sink.write(b"")
    sink.close()
    reader.wait()
    return c / n * 1e6, n


def lateness(seconds):
    """Real-time 1 kHz MPU6050 emulation; a ga-paper calibration (about 1 s of CPU) is
    started in a worker process (the daemon's: one per job); the delay of each batch behind its
    schedule is recorded."""
    from imucald.daemon.worker import WorkerRunner
    cfg = copy.deepcopy(DEFAULTS)
    cfg["calibration"]["method"] = "ga-paper"
    cfg["calibration"]["min_poses"] = 10
    clk = RealClock()
    eb = emulated_board("mpu6050", PoseTour(random_pose_set(30, 2), rng=2, hold_s=(3, 4), move_s=(1, 1.5),
                                            loop=True), rng=2, clock=clk)
    b = make_board("mpu6050", Bus(eb, "emu", clock=clk), clk, rate_hz=1000)
    b.start()
    ex = WorkerRunner()
    pipe = Pipeline(cfg, "mpu6050", 1000.0, False, executor=ex)
    # preload poses so a calibration can start at once, and keep forcing new ones
    from imucald.sim.sensor import draw_truth, simulate_pose_means
    from imucald.sim.orientations import up_vectors
    from imucald.fitting.stillness.detector import StaticInterval
    rng = np.random.default_rng(3)
    raw, cov = simulate_pose_means(draw_truth("mpu6050", rng).accel, up_vectors(random_pose_set(30, rng)), 1e-4, rng)
    for i, r in enumerate(raw):
        pipe.acc.add(StaticInterval(r, cov[i], cov[i] * 500, 500, i, i + 1, 25.0))
    late_idle, late_cal = [], []
    t_start = clk.now()
    cal_runs = 0
    idle_since = clk.now()
    while clk.now() - t_start < seconds:
        bt = b.read_batch(batch_s=0.02)
        busy = pipe.pending is not None
        if not busy and clk.now() - idle_since > 2.0:      # alternate 2 s idle / one calibration
            pipe.request_calibration()
        pipe.process(bt)
        if busy and pipe.pending is None:
            idle_since = clk.now()
        if pipe.pending is not None and not busy:
            cal_runs += 1
        if len(bt):
            # the newest sample was produced at about (its seq) / rate after the board's t0;
            # how long after that has it been processed?
            due = b.t0 + (bt.seq[-1] + 1) / b.rate_hz
            lag = clk.now() - due
            (late_cal if busy else late_idle).append(lag)
    ex.shutdown()
    li, lc = np.array(late_idle), np.array(late_cal)
    base = np.median(li)
    return (np.percentile(li - base, 99) * 1e3, (lc - base).max() * 1e3 if len(lc) else float("nan"),
            np.percentile(lc - base, 99) * 1e3 if len(lc) else float("nan"), cal_runs)


def rss(seconds):
    with tempfile.TemporaryDirectory() as d:
        p = subprocess.Popen([sys.executable, "-m", "imucald.cli", "run", "--emulate", "--speed", "20",
                              "--min-poses", "10", "--state-dir", d, "--runtime-dir", d,
                              "--duration", str(20 * seconds)], stderr=subprocess.DEVNULL)
        idle, busy = [], []         # daemon alone / daemon + its worker, kB, every 20 ms
        while p.poll() is None:
            try:
                d = _rss_kb(p.pid)
                w = sum(_rss_kb(c) for c in _children(p.pid))
                (busy if w else idle).append((d + w, d, w))
            except OSError:
                pass
            time.sleep(0.02)        # a ga job's worker lives ~0.1 s: poll often enough to see it
    mb = lambda xs, k: max((x[k] for x in xs), default=0) / 1024
    return mb(idle, 0), mb(busy, 0), mb(busy, 2), len(busy)


def _rss_kb(pid):
    with open(f"/proc/{pid}/status") as f:
        for l in f:
            if l.startswith("VmRSS:"):
                return int(l.split()[1])
    return 0


def _children(pid):
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(x) for x in f.read().split()]
    except OSError:
        return []


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cost-only", action="store_true", help="only the per-sample cost rows")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        print("pipeline CPU per sample (stillness + poses + correction + encoding + socket write),"
              f" median of {args.repeats} runs of {args.seconds:g} s of data")
        for board, rate in (("mpu6050", 1000), ("mpu9250", 1000), ("9dof", 100)):
            for fmt in ("ndjson", "binary"):
                cs = [cost(board, rate, args.seconds if rate == 1000 else args.seconds * 4, fmt, tmp)
                      for _ in range(args.repeats)]
                us = float(np.median([c for c, _ in cs]))
                print(f"  {board:<8} {rate:5d} Hz {fmt:<7} {us:6.1f} us/sample -> highest sustained "
                      f"rate {1e6 / us:8.0f} Hz ({cs[0][1]} samples)")
        # with the orientation filter (issue 26, the orientation extra): q, gravity-free
        # acceleration and their uncertainty in every sample
        try:
            import vqf  # noqa: F401
            have_vqf = True
        except ImportError:
            have_vqf = False
            print("  (orientation rows left out: the orientation extra (vqf) is not installed)")
        for board in ("mpu6050", "mpu9250") if have_vqf else ():
            for fmt in ("ndjson", "binary"):
                us = float(np.median([cost(board, 1000, args.seconds, fmt, tmp, orientation=True)[0]
                                      for _ in range(args.repeats)]))
                print(f"  {board:<8}  1000 Hz {fmt:<7} {us:6.1f} us/sample with orientation (issue 26: <= 20)")
        # with thermal terms applied (order 3 accelerometer bias + scale, order 3 gyro bias)
        for fmt in ("ndjson", "binary"):
            us = float(np.median([cost("mpu6050", 1000, args.seconds, fmt, tmp, thermal=True)[0]
                                  for _ in range(args.repeats)]))
            print(f"  mpu6050   1000 Hz {fmt:<7} {us:6.1f} us/sample with thermal terms (order 3 + scale)")
        # and the gyro's scale/misalignment matrix and g-sensitivity on top
        for fmt in ("ndjson", "binary"):
            us = float(np.median([cost("mpu6050", 1000, args.seconds, fmt, tmp, thermal=True, gyro_rot=True)[0]
                                  for _ in range(args.repeats)]))
            print(f"  mpu6050   1000 Hz {fmt:<7} {us:6.1f} us/sample with thermal terms and the gyro matrix + "
                  f"g-sensitivity")
    if args.cost_only:
        return
    idle99, cal_max, cal99, runs = lateness(20.0)
    print(f"lateness behind schedule at 1 kHz, 20 ms batches (one batch = 20 ms): idle p99 {idle99:.1f} ms; "
          f"while {runs} ga-paper calibrations ran in the worker: p99 {cal99:.1f} ms, max {cal_max:.1f} ms")
    idle_mb, busy_mb, worker_mb, n = rss(8.0)
    busy = (f"while calibrating daemon + worker {busy_mb:.1f} MB (worker {worker_mb:.1f} MB, {n} samples)"
            if n else "no calibration worker was seen running (see bench/daemon_rss.py)")
    print(f"resident memory (ps RSS, peak): idle daemon {idle_mb:.1f} MB (no worker process between "
          f"calibrations); {busy}")


if __name__ == "__main__":
    main()
