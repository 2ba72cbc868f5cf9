"""``imucald run``, ``replay``, ``status``, ``recalibrate`` and ``watch``: the daemon's commands."""
from __future__ import annotations

import json
import os
import sys

from ..errors import UserError
from ._common import print_json

DEFAULT_CONFIG = "/etc/imucald/imucald.yaml"


def setup_logging(level: str) -> None:
    import logging
    logging.basicConfig(level=getattr(logging, level.upper()), stream=sys.stderr,
                        format="imucald: %(message)s")


def _overrides(args):
    """(key, value, flag) of every configuration key given on the command line."""
    out = []
    for attr, key, flag in (("board", "sensor.board", "--board"), ("rate", "sensor.rate_hz", "--rate"),
                            ("mag", "sensor.magnetometer", "--mag"),
                            ("bus", "sensor.bus", "--bus"), ("state_dir", "state.directory", "--state-dir"),
                            ("runtime_dir", "runtime.directory", "--runtime-dir"),
                            ("format", "output.format", "--format"), ("fifo", "output.fifo", "--fifo"),
                            ("orientation", "output.orientation", "--orientation"),
                            ("method", "calibration.method", "--method"),
                            ("min_poses", "calibration.min_poses", "--min-poses"),
                            ("log_level", "log.level", "--log-level")):
        v = getattr(args, attr, None)
        if v is not None:
            out.append((key, v, flag))
    return out


def daemon_config(args, with_overrides: bool = False):
    from ..daemon.config import apply_overrides, load_config
    path = args.config
    if path is None and os.path.exists(DEFAULT_CONFIG):
        path = DEFAULT_CONFIG
    cfg = load_config(path)
    ov = _overrides(args)
    apply_overrides(cfg, ov, path)      # an override may contradict a key of the file
    return (cfg, path, ov) if with_overrides else (cfg, path)


def cmd_run(args) -> int:
    import signal
    # a SIGHUP (reload) before the daemon installs its handler killed it (exit 129; a cold
    # review, within ~50 ms of the start): kept, and the daemon reloads once it runs
    early_hup: list = []
    signal.signal(signal.SIGHUP, lambda *_: early_hup.append(1))
    from ..daemon.worker import without_openssl
    without_openssl()                   # before numpy: the daemon's resident set (issue 15)
    from ..daemon.run import Daemon
    from .boards import RUN_TOUR, open_board
    from .faults import faults_from_options
    cfg, path, overrides = daemon_config(args, with_overrides=True)
    if args.echo and cfg["output"]["format"] == "binary":
        raise UserError("--echo prints the stream's lines, and output.format binary has none: "
                        "give --format ndjson (or csv) with --echo")
    setup_logging(cfg["log"]["level"])
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
                                  tour=dict(RUN_TOUR, tremor_dps=args.tremor_dps), **kw)
    d = Daemon(cfg, board, bus, desc, duration_s=args.duration, echo=args.echo, config_path=path,
               overrides=overrides)
    d.early_hup = early_hup
    return d.run()


def cmd_replay(args) -> int:
    import logging

    import numpy as np

    from ..daemon.pipeline import Pipeline
    from ..drivers.board import SampleBatch
    from ._common import input_recording
    cfg, _ = daemon_config(args)
    setup_logging(cfg["log"]["level"])
    # a recording is streamed (memory bounded by one block); a raw table is read whole
    with input_recording(args, args.recording, whole=False) as reader:
        cols = reader.header
        if "ax" not in cols and "mx" not in cols:
            raise UserError(f"{args.recording}: no accelerometer (ax, ay, az) or magnetometer "
                            f"(mx, my, mz) columns")
        meta, has_mag, has_acc = reader.meta, "mx" in cols, "ax" in cols
        rate_hz = float(meta["rate_hz"])
        from ..specs import recording_chips
        chips = recording_chips(meta)      # a simulated or converted recording: the board's usual
        pipe = Pipeline(cfg, meta.get("board", "unknown"), rate_hz, has_mag, chips=chips,
                        has_acc=has_acc)
        pipe.use_noise_file(cfg["noise"]["file"])
        from .orientation import gyro_range_dps
        pipe.use_orientation(cfg["output"]["orientation"], has_gyro="gx" in cols,
                             gyro_range_dps=gyro_range_dps(meta, None))
        start = _replay_start(args.state_dir, pipe.board, chips) if args.state_dir else None
        if start is not None:   # as the daemon at start: from the calibration saved there
            pipe.applied = start
            logging.getLogger("imucald").info("starting from calibration #%d (%s)", start.id, start.created)
        out = sys.stdout.buffer
        from ..daemon.outputs import banner
        out.write(banner(cfg["output"]["format"], pipe.board, chips or None, pipe.orientation_off))
        step = max(1, int(round(cfg["sensor"]["batch_s"] * rate_hz)))
        seq0, prev_mag, pending = 0, None, []
        for chunk in reader.chunks():
            n = len(chunk)
            if seq0 == 0:
                pipe.orientation_rate_from(chunk.t, [chunk.acc, chunk.gyro, chunk.mag])
            gyro, temp = chunk.gyro, chunk.temp      # None (omitted from the stream) when absent
            fresh = None
            if has_mag:         # a new magnetometer reading differs from the one before it
                before = np.vstack([chunk.mag[:1] + 1 if prev_mag is None else prev_mag, chunk.mag[:-1]])
                fresh = np.any(chunk.mag != before, axis=1)
                prev_mag = chunk.mag[-1:]
            seq = np.arange(seq0, seq0 + n, dtype=np.int64)
            seq0 += n
            acc = chunk.acc if has_acc else np.full((n, 3), np.nan)     # gy273: none
            pending.append((chunk.t, seq, acc, gyro, temp, chunk.mag, fresh))
            rows = _cat(pending)
            i = 0
            while len(rows[0]) - i >= step:
                out.write(pipe.process(SampleBatch(*(None if a is None else a[i:i + step] for a in rows))))
                i += step
            pending = [tuple(None if a is None else a[i:] for a in rows)]
        rows = _cat(pending)
        if len(rows[0]):
            out.write(pipe.process(SampleBatch(*rows)))
        out.write(pipe.end_of_stream())
    out.flush()
    _replay_unused(args.recording, pipe, cfg)
    if not pipe.applied.id:
        _none_reached(pipe, cfg)
    elif args.state_dir:
        _replay_save(args.state_dir, pipe, start)
    return 0


def _replay_unused(path: str, pipe, cfg) -> None:
    """At the end of a replay, the still poses the accelerometer calibration in force was not
    fitted on, said: the daemon refits every calibration.recalibrate_every_poses new poses and
    keeps a fit only when the gate takes it, so the last few of a file wait for more, or the
    fit on them was not taken (calibrate fits them all)."""
    import logging
    acc = pipe.applied.accel if pipe.applied.id else None
    if acc is None or not pipe.has_acc:
        return
    used, total = int(acc.quality.get("poses", 0)), len(pipe.acc)
    if 0 < used < total:
        logging.getLogger("imucald").info(
            "end of %s: calibration #%d is in force, its accelerometer part fitted on %d of the %d "
            "still poses (the daemon refits every %d new poses and keeps a fit only when the gate "
            "takes it; `imucald calibrate %s` fits them all)", path, pipe.applied.id, used, total,
            cfg["calibration"]["recalibrate_every_poses"], path)


def _replay_save(state_dir: str, pipe, start) -> None:
    """The end of a replay with --state-dir: the calibration reached saved there (the one it
    started from, if replaced, kept in DIR/history first: a calibrate -o copied in is not
    lost)."""
    import logging

    from ..daemon.state import save_calibration
    os.makedirs(state_dir, exist_ok=True)
    kept = ""
    if start is not None and pipe.applied is not start:
        kept = f" (the one it started from, #{start.id}, kept as {_keep_replaced(state_dir)})"
    p = save_calibration(state_dir, pipe.applied, history=0)
    logging.getLogger("imucald").info("calibration #%d saved to %s%s", pipe.applied.id, p, kept)


def _none_reached(pipe, cfg) -> None:
    """The end of a replay that reached no calibration: why (with or without --state-dir; a
    file of two long rests otherwise ended without a word)."""
    import logging
    log = logging.getLogger("imucald")
    if not pipe.has_acc:
        log.info("no calibration was reached (magnetometer rotation coverage %.0f%%, %.0f%% needed, "
                 "turned in all three dimensions)", 100 * pipe.reservoir.coverage(),
                 100 * cfg["calibration"]["mag_min_coverage"])
    else:
        from ..daemon.pipeline import MIN_FIT_POSES
        n = len(pipe.acc)
        why = (f"{n} still pose{'' if n == 1 else 's'}; a first calibration needs {MIN_FIT_POSES} in different orientations"
               if n < MIN_FIT_POSES else f"{n} still poses, none of the fits beat the raw readings "
               f"significantly")
        log.info("no calibration was reached (%s)", why)


def _keep_replaced(state_dir: str) -> str:
    """DIR/calibration.yaml copied, byte for byte, to DIR/history/replaced-<UTC time>.yaml
    before a replay replaces it (a name no calibration's history file has, so none of the
    daemon's trimming by id removes it); returns the copy's path."""
    import time

    from ..files.atomic import atomic_write_bytes
    hd = os.path.join(state_dir, "history")
    os.makedirs(hd, exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
    path, k = os.path.join(hd, f"replaced-{stamp}.yaml"), 1
    while os.path.exists(path):
        k += 1
        path = os.path.join(hd, f"replaced-{stamp}-{k}.yaml")
    with open(os.path.join(state_dir, "calibration.yaml"), "rb") as fh:
        atomic_write_bytes(path, fh.read(), flag="--state-dir")
    return path


def _replay_start(state_dir: str, board: str, chips):
    """The calibration in ``state_dir`` to start the replay from (None: no file there).
    One that does not load or belongs to another board is refused (the daemon would set it
    aside; a replay must not overwrite it with a calibration made from scratch)."""
    from ..calibration import CalibrationError, load
    path = os.path.join(state_dir, "calibration.yaml")
    if not os.path.exists(path):
        return None
    fix = "; replay starts from the calibration in --state-dir: move the file away or give another --state-dir"
    try:
        cal = load(path)
    except CalibrationError as e:
        raise type(e)(f"{str(e).splitlines()[0]}{fix}") from None
    why = cal.mismatch(board, chips)
    if why:
        raise UserError(f"{path}: {why}{fix}")
    return cal


def _cat(parts):
    """Concatenate tuples of arrays field by field (None stays None)."""
    import numpy as np
    if len(parts) == 1:
        return parts[0]
    return tuple(None if parts[0][k] is None else np.concatenate([p[k] for p in parts])
                 for k in range(len(parts[0])))


def _control_path(args) -> str:
    cfg, _ = daemon_config(args)
    p = cfg["control"]["socket"]
    return p if os.path.isabs(p) else os.path.join(cfg["runtime"]["directory"], p)


def cmd_status(args) -> int:
    from ..daemon.control import request
    r = request(_control_path(args), "status")
    if getattr(args, "plot", None) and r.get("class") != "ERROR":
        from .plotcmd import status_plot
        status_plot(args.plot, r, request(_control_path(args), "poses"))
    if args.json:
        print_json(r)
        return 0
    if r.get("class") == "ERROR":
        raise UserError(r.get("message", "error"))
    cal = f"#{r['calibration_id']} ({r.get('calibration_created')})" if r.get("calibration_id") else "none yet"
    chips = ", ".join(f"{k} {v.upper()}" for k, v in (r.get("chips") or {}).items())
    print(f"board {r['board']} at {r['rate_hz']:g} Hz on {r['bus']}" + (f" ({chips})" if chips else ""))
    if "mag_coverage" in r:
        print(f"magnetometer rotation coverage {r['mag_coverage']:.0%} of the sphere")
    print(f"poses {r['poses']}/{r['poses_needed']}, coverage {r['coverage']:.0%}"
          + (f", next: {r['next_orientation']}" if r.get("next_orientation") else ""))
    if r.get("calibration_provisional"):         # applied before the pose set was complete
        miss = r.get("missing_orientations") or []
        cal += ", provisional" + (f" (missing: {', '.join(miss[:6])}{', ...' if len(miss) > 6 else ''})"
                                  if miss else "")
    print(f"calibration {cal}{', calibrating now' if r.get('calibrating') else ''}")
    sn = r.get("sensor") or {}
    if sn:
        note = {"changed": f": a different sensor than last time (was {sn.get('previous')}); it started "
                           f"uncalibrated, the old calibration is kept in {sn.get('kept_in')}",
                "returned": f": swapped back in (was {sn.get('previous')}); its own calibration is back"
                }.get(sn.get("status"), "")
        print(f"sensor {sn.get('id')}{note}")
    bs = r["board_stats"]
    print(f"samples {bs['samples']}, gaps {bs['gaps']} ({bs['missing']} lost), bus faults {bs['bus_faults']}, "
          f"clients {r['clients']} (dropped {r['clients_dropped']}"
          + (f", refused {r['clients_refused']}" if r.get("clients_refused") else "") + ")")
    th = r.get("thermal")
    if th:
        print(f"thermal: {th['intervals']} still intervals over {th['span_c']:.1f} degC"
              + (f"; {th['why']}" if th.get("why") else ""))
        for s in ("accel", "gyro", "mag"):
            if s in th:
                e = th[s]
                rng = f" over {e['t_min_c']:.1f}..{e['t_max_c']:.1f} degC" if "t_min_c" in e else ""
                print(f"  {s}: order {e['order']}{rng}: {e['note']}")
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
    from ..client import refusal_message
    cfg, _ = daemon_config(args)
    p = cfg["output"]["socket"]
    p = p if os.path.isabs(p) else os.path.join(cfg["runtime"]["directory"], p)
    s = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    try:
        s.connect(p)
    except OSError as e:
        from ..errors import DeviceUnavailable
        from ..daemon.control import RUNTIME_DIR_HINT
        raise DeviceUnavailable(f"{p}: cannot connect: {e.strerror}: is imucald running? "
                                f"({RUNTIME_DIR_HINT})") from None
    f = s.makefile("rb")
    count = 0
    for line in f:
        why = refusal_message(line) if count == 0 else None
        if why is not None:                                     # refused: too many clients
            from ..errors import DeviceUnavailable
            raise DeviceUnavailable(f"{p}: the daemon refused this client: {why}")
        sys.stdout.write(_with_attitude(line.decode(errors="replace")))
        if is_sample_line(line):    # -n counts samples: not the VERSION banner, a CSV
            count += 1              # header, a GAP/CAL event
        if args.count and count >= args.count:
            return 0
    # The stream ends only when the daemon closes it (stopped, restarted or crashed): a
    # watcher must not mistake that for success (exit 0 silently was a reported bug).
    from ..errors import DeviceUnavailable
    raise DeviceUnavailable(f"{p}: the daemon closed the stream after {count} samples "
                            "(stopped or restarted?): see `imucald status` or journalctl -u imucald")


def _with_attitude(line: str) -> str:
    """An IMU line carrying ``q`` gets roll_deg, pitch_deg and heading_deg (compass degrees
    from magnetic north, or arbitrary as its ``heading`` says) appended; others unchanged."""
    if '"q":' not in line or not line.startswith('{"class":"IMU"'):
        return line
    try:
        q = json.loads(line)["q"]
    except (ValueError, KeyError):
        return line
    from ..client import attitude_deg
    r, p, h = attitude_deg(q)
    body = line.rstrip()
    return f'{body[:-1]},"roll_deg":{r:.2f},"pitch_deg":{p:.2f},"heading_deg":{h:.2f}}}\n'


def is_sample_line(line: bytes) -> bool:
    """One sample of the stream: an NDJSON ``IMU`` object or a CSV data row (not the
    ``VERSION`` banner, the CSV header, a ``# {...}`` event or another class)."""
    s = line.lstrip()
    if s.startswith(b"{"):
        return b'"class":"IMU"' in s[:40]
    return bool(s) and s[:1] != b"#" and s[:1].isdigit()

