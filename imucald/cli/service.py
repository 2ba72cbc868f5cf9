"""``imucald run``, ``replay``, ``status``, ``recalibrate`` and ``watch``: the daemon's commands."""
from __future__ import annotations

import json
import os
import sys

from ..errors import UserError

DEFAULT_CONFIG = "/etc/imucald/imucald.yaml"


def _setup_logging(level: str) -> None:
    import logging
    logging.basicConfig(level=getattr(logging, level.upper()), stream=sys.stderr,
                        format="imucald: %(message)s")


def _daemon_config(args):
    from ..daemon.config import load_config, set_override
    path = args.config
    if path is None and os.path.exists(DEFAULT_CONFIG):
        path = DEFAULT_CONFIG
    cfg = load_config(path)
    for attr, key, flag in (("board", "sensor.board", "--board"), ("rate", "sensor.rate_hz", "--rate"),
                            ("bus", "sensor.bus", "--bus"), ("state_dir", "state.directory", "--state-dir"),
                            ("runtime_dir", "runtime.directory", "--runtime-dir"),
                            ("format", "output.format", "--format"), ("fifo", "output.fifo", "--fifo"),
                            ("method", "calibration.method", "--method"),
                            ("min_poses", "calibration.min_poses", "--min-poses"),
                            ("log_level", "log.level", "--log-level")):
        v = getattr(args, attr, None)
        if v is not None:
            set_override(cfg, key, v, flag)
    return cfg, path


def cmd_run(args) -> int:
    from ..daemon.run import Daemon
    from .boards import open_board
    from .faults import faults_from_options
    cfg, path = _daemon_config(args)
    _setup_logging(cfg["log"]["level"])
    s = cfg["sensor"]
    emulate = "yes" if args.emulate else ("no" if args.no_emulate else s["emulate"])
    kw = {}
    if s["address"] is not None:
        kw = {"addr": s["address"]} if s["board"] != "9dof" else {"gyro_addr": s["address"]}
    if s["board"] not in ("9dof", "gy273"):
        kw.update(accel_range_g=s["accel_range_g"], gyro_range_dps=s["gyro_range_dps"])
    board, bus, desc = open_board(s["board"], s["rate_hz"], emulate, s["bus"], speed=args.speed,
                                  mag=s["magnetometer"],
                                  seed=args.seed, faults=faults_from_options(args.fault),
                                  tour=dict(hold_s=(3.0, 4.0), move_s=(1.2, 1.8), lead_s=1.0), **kw)
    d = Daemon(cfg, board, bus, desc, duration_s=args.duration, echo=args.echo, config_path=path)
    return d.run()


def cmd_replay(args) -> int:
    import logging

    import numpy as np

    from ..daemon.pipeline import Pipeline
    from ..daemon.state import save_calibration
    from ..drivers.board import SampleBatch
    from ..recording import read_recording
    cfg, _ = _daemon_config(args)
    _setup_logging(cfg["log"]["level"])
    rec = read_recording(args.recording)
    if rec.acc is None:
        raise UserError(f"{args.recording}: no accelerometer columns (ax, ay, az)")
    n = len(rec)
    gyro, temp = rec.gyro, rec.temp          # None (omitted from the stream) when absent
    fresh = None
    if rec.mag is not None:
        fresh = np.ones(n, bool)
        fresh[1:] = np.any(np.diff(rec.mag, axis=0) != 0, axis=1)
    pipe = Pipeline(cfg, rec.meta.get("board", "unknown"), rec.rate_hz, rec.mag is not None)
    out = sys.stdout.buffer
    from ..daemon.outputs import banner
    out.write(banner(cfg["output"]["format"], pipe.board))
    step = max(1, int(round(cfg["sensor"]["batch_s"] * rec.rate_hz)))
    seq = np.arange(n, dtype=np.int64)
    for i in range(0, n, step):
        sl = slice(i, min(n, i + step))
        b = SampleBatch(rec.t[sl], seq[sl], rec.acc[sl], None if gyro is None else gyro[sl],
                        None if temp is None else temp[sl],
                        None if rec.mag is None else rec.mag[sl], None if fresh is None else fresh[sl])
        out.write(pipe.process(b))
    out.flush()
    if args.state_dir and pipe.applied.id:
        os.makedirs(args.state_dir, exist_ok=True)
        p = save_calibration(args.state_dir, pipe.applied, history=0)
        logging.getLogger("imucald").info("calibration #%d saved to %s", pipe.applied.id, p)
    elif args.state_dir:
        logging.getLogger("imucald").info("no calibration was reached (%d poses; %s)",
                                          len(pipe.acc), pipe.ready_to_calibrate())
    return 0


def _control_path(args) -> str:
    cfg, _ = _daemon_config(args)
    p = cfg["control"]["socket"]
    return p if os.path.isabs(p) else os.path.join(cfg["runtime"]["directory"], p)


def cmd_status(args) -> int:
    from ..daemon.control import request
    r = request(_control_path(args), "status")
    if args.json:
        print(json.dumps(r))
        return 0
    if r.get("class") == "ERROR":
        raise UserError(r.get("message", "error"))
    cal = f"#{r['calibration_id']} ({r.get('calibration_created')})" if r.get("calibration_id") else "none yet"
    print(f"board {r['board']} at {r['rate_hz']:g} Hz on {r['bus']}")
    print(f"poses {r['poses']}/{r['poses_needed']}, coverage {r['coverage']:.0%}"
          + (f", next: {r['next_orientation']}" if r.get("next_orientation") else ""))
    print(f"calibration {cal}{', calibrating now' if r.get('calibrating') else ''}")
    bs = r["board_stats"]
    print(f"samples {bs['samples']}, gaps {bs['gaps']} ({bs['missing']} lost), bus faults {bs['bus_faults']}, "
          f"clients {r['clients']} (dropped {r['clients_dropped']})")
    if r.get("last_event"):
        print(f"last: {r['last_event']}")
    return 0


def cmd_recalibrate(args) -> int:
    from ..daemon.control import request
    r = request(_control_path(args), "recalibrate")
    if r.get("class") == "ERROR":
        raise UserError(r["message"])
    print("recalibration started" if r.get("started") else "a calibration is already running")
    return 0


def cmd_watch(args) -> int:
    import socket as _socket
    cfg, _ = _daemon_config(args)
    p = cfg["output"]["socket"]
    p = p if os.path.isabs(p) else os.path.join(cfg["runtime"]["directory"], p)
    s = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    try:
        s.connect(p)
    except OSError as e:
        raise UserError(f"{p}: cannot connect: {e.strerror}: is imucald running?") from None
    f = s.makefile("rb")
    count = 0
    for line in f:
        sys.stdout.write(line.decode(errors="replace"))
        count += 1
        if args.count and count >= args.count:
            break
    return 0

