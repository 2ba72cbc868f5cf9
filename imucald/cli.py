"""imucald command line.

User errors (bad files, bad options) print one line, ``imucald: error: ...``,
and exit 2 with no traceback.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import List, Optional

import numpy as np

from . import __version__
from .errors import UserError

SENSORS = ("accel", "gyro", "mag")
METHODS = ("ga", "ga-paper", "hga", "lm")
DEFAULT_MODEL = {"accel": "triangular9", "mag": "mag_sym", "gyro": "mean"}


def _eprint(*a):
    print(*a, file=sys.stderr, flush=True)


# --- simulate ----------------------------------------------------------------------------

def cmd_simulate(args) -> int:
    from .recording import write_recording
    from .sim.poses import euler_pose_set, random_pose_set
    from .sim.sensor import simulate_session
    rng = np.random.default_rng(args.seed)
    if args.euler:
        try:
            nx, ny, nz = (int(v) for v in args.euler.split(","))
        except ValueError:
            raise UserError(f"--euler {args.euler!r}: expected three integers NX,NY,NZ") from None
        R = euler_pose_set(nx, ny, nz, rng)
    else:
        if args.poses < 1:
            raise UserError(f"--poses {args.poses}: at least 1")
        R = random_pose_set(args.poses, rng)
    hold, move = (args.hold * 0.8, args.hold * 1.2), (args.move * 0.7, args.move * 1.3)
    effects = []
    if args.effect:
        from .sim.effects import effect_session
        named = [e for e in args.effect if e != "none"]
        if args.magnitude is not None and len(named) != 1:
            raise UserError("--magnitude applies to exactly one --effect (use NAME=X for several)")
        spec = []
        for e in named:
            name, _, m = e.partition("=")
            try:
                spec.append((name, float(m) if m else args.magnitude))
            except ValueError:
                raise UserError(f"--effect {e!r}: the magnitude after '=' is not a number") from None
        try:
            s, effects = effect_session(args.board, R, rng, spec, args.rate, hold, move,
                                        args.temp_profile, args.temp_rise)
        except ValueError as ex:
            raise UserError(f"--effect: {ex}") from None
    else:
        s = simulate_session(args.board, R, rng, rate_hz=args.rate, hold_s=hold, move_s=move,
                             temp_kind=args.temp_profile, temp_rise_c=args.temp_rise)
    s.recording.meta["seed"] = str(args.seed)
    write_recording(s.recording, args.output)
    if args.truth:
        from .atomic import atomic_write_text
        tr = s.truth
        d = {"board": tr.board, "accel_triangular9": tr.accel.tolist(),
             "gyro_bias_dps": tr.gyro_bias_dps.tolist(), "gyro_matrix": tr.gyro_matrix.tolist(),
             "hold_s": [list(h) for h in s.hold],
             "effects": effects}
        if tr.mag_soft_iron is not None:
            d.update(mag_hard_iron_gauss=tr.mag_hard_iron_gauss.tolist(),
                     mag_soft_iron=tr.mag_soft_iron.tolist(), field_gauss=tr.field_gauss,
                     dip_deg=tr.dip_deg)
        atomic_write_text(args.truth, json.dumps(d, indent=1) + "\n")
    _eprint(f"imucald: wrote {args.output}: {args.board}, {len(R)} poses, "
            f"{len(s.recording)} samples at {args.rate:g} Hz ({s.recording.t[-1]:.0f} s)")
    return 0


# --- calibrate ---------------------------------------------------------------------------

def _fmt_vec(v, unit_scale=1.0, fmt="{:+.6f}"):
    return "[" + ", ".join("   n/a   " if x is None else fmt.format(x * unit_scale) for x in v) + "]"


def cmd_calibrate(args) -> int:
    from .calib.fit import fit_gyro_bias, fit_norm
    from .calib.inputs import load_input
    from .calib.models import MODEL_NAMES
    from .calib.poses import poses_from_recording
    columns = args.columns.split(",") if args.columns else None
    kind, obj = load_input(args.input, columns, args.nominal_scale, args.nominal_offset, args.rate_hz)
    sensor = args.sensor
    if sensor is None:      # a magnetometer-only recording: calibrate the magnetometer
        sensor = "mag" if kind == "recording" and obj.acc is None and obj.mag is not None else "accel"
    model = args.model or DEFAULT_MODEL[sensor]
    if sensor == "accel" and not (model in MODEL_NAMES and not model.startswith("mag_")):
        raise UserError(f"--model {model!r} does not fit --sensor accel: allowed "
                        + ", ".join(m for m in MODEL_NAMES if not m.startswith("mag_")))
    if sensor == "mag" and not model.startswith("mag_"):
        raise UserError(f"--model {model!r} does not fit --sensor mag: allowed mag_sym, mag_diag, mag_sphere")
    if sensor == "gyro" and model not in ("mean", "eq6"):
        raise UserError(f"--model {model!r} does not fit --sensor gyro: allowed mean, eq6")
    rec = obj if kind == "recording" else None
    progress = None if args.json else _eprint
    if sensor == "mag" and rec is not None:
        if rec.mag is None:
            raise UserError(f"{args.input}: no magnetometer columns (mx, my, mz)")
        return _calibrate_mag_rotation(args, rec, model, progress)
    poses = poses_from_recording(rec, window_s=args.window_s, k=args.threshold_k,
                                 min_still_s=args.min_still_s) if rec is not None else obj
    if sensor == "accel":
        if len(poses) < 10:
            raise UserError(f"{args.input}: only {len(poses)} still poses found; the 9-parameter "
                            f"model needs at least 10 (about 25 recommended), well spread over the sphere")
        if progress:
            progress(f"imucald: {len(poses)} still poses; fitting {model} with {args.method}")
        kw = {"progress": progress} if args.method == "ga-paper" and progress else {}
        from .sim.specs import BOARDS
        chip = BOARDS.get(poses.meta.get("board", ""), (None,))[0]
        cal = fit_norm(poses.acc, model, args.method, pose_cov=poses.acc_cov, rng=args.seed,
                       chip=chip, **kw)
    elif sensor == "mag":           # a pose file: the pose means are the points
        if poses.mag is None:
            raise UserError(f"{args.input}: no magnetometer columns (mx, my, mz)")
        cal = fit_norm(poses.mag, model, args.method, pose_cov=poses.mag_cov, rng=args.seed)
    else:
        if poses.gyro is None:
            raise UserError(f"{args.input}: no gyro columns (gx, gy, gz)")
        samples = None
        if model == "eq6":
            if rec is None:
                raise UserError("--model eq6 needs the still samples: give a recording")
            from .calib.poses import detect_static
            sl = detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rec.rate_hz)
            samples = np.concatenate([rec.gyro[s] for s in sl])
        cal = fit_gyro_bias(poses.gyro, poses.n, poses.gyro_cov, model, samples, rng=args.seed)
    if args.json:
        print(json.dumps(cal.to_json()))
        return 0
    _print_cal(sensor, cal)
    return 0


def _print_cal(sensor: str, cal) -> None:
    unit = {"accel": ("mg", 1e3), "mag": ("mG", 1e3), "gyro": ("deg/s", 1.0)}[sensor]
    what = "points (thinned rotation samples)" if cal.noise_source == "second differences" else "poses"
    print(f"{sensor} {cal.model} by {cal.method}: {cal.poses} {what}, fitness {cal.fitness:.6g}")
    for g, v in cal.params.items():
        se = cal.stderr.get(g)
        vv = v if isinstance(v, list) else [v]
        ss = se if isinstance(se, list) else [se]
        print(f"  {g:<18} {_fmt_vec(vv)}  +- {_fmt_vec(ss, fmt='{:.2e}')}")
    if sensor != "gyro":
        print(f"  residual |x|-target RMS: in-sample {cal.rms * unit[1]:.4f} {unit[0]}, "
              f"held-out {cal.heldout_rms * unit[1]:.4f} {unit[0]}")
        print(f"  noise per {what.split()[0][:-1]} {cal.noise * unit[1]:.4f} {unit[0]} (from {cal.noise_source}); "
              f"rank {cal.uncertainty.rank}/{int(get_free(cal))}, condition {cal.uncertainty.condition:.3g}")
        if cal.uncertainty.unobservable:
            print(f"  not determined by these poses: {', '.join(cal.uncertainty.unobservable)}")
        elif len(cal.uncertainty.null_directions):
            print(f"  {len(cal.uncertainty.null_directions)} parameter direction(s) not observable "
                  f"by a norm fit (a rotation of the frame); errors are given in the minimum-norm gauge")
        if "path_error_20s_std_m" in cal.info:
            pe = cal.info["path_error_20s_std_m"]
            print(f"  paper 000 path error after 20 s (STD over poses): raw {pe['raw']:.3g} m, "
                  f"calibrated {pe['calibrated']:.3g} m")
    else:
        print(f"  between-pose scatter RMS {cal.rms:.4f} deg/s")


def _calibrate_mag_rotation(args, rec, model, progress) -> int:
    """Magnetometer from the rotation cloud (any recording with mx, my, mz).
    Exit 3 when the cloud does not determine a calibration (a one-plane swing)."""
    from .calib.magcal import calibrate_rotation, flat_message, rotation_json, rotation_lines
    if progress:
        progress(f"imucald: {len(rec)} magnetometer samples; thinning over the sphere and fitting "
                 f"{model} with {args.method}")
    res = calibrate_rotation(rec.mag, model, args.method, rng=args.seed)
    if args.json:
        print(json.dumps(rotation_json(res)))
        return 0 if res["determined"] else 3
    if not res["determined"]:
        _eprint(f"imucald: {args.input}: {flat_message(res)}")
        return 3
    _print_cal("mag", res["calibration"])
    print("\n".join(rotation_lines(res)))
    return 0


def get_free(cal) -> int:
    from .calib.models import get_model
    return int(get_model(cal.model).free_mask.sum())


# --- demo (make run) ---------------------------------------------------------------------

def cmd_demo(args) -> int:
    """Simulate a handled MPU6050, find its poses, and show the GA converging."""
    from .calib.fit import fit_norm
    from .calib.models import Triangular9
    from .calib.optim import Problem, ga
    from .calib.poses import poses_from_recording
    from .sim.poses import random_pose_set
    from .sim.sensor import simulate_session
    rng = np.random.default_rng(args.seed)
    print(f"imucald {__version__} demo: no daemon yet, so this is a calibration on a simulated "
          f"MPU6050 (seed {args.seed})")
    R = random_pose_set(args.poses, rng)
    s = simulate_session("mpu6050", R, rng, rate_hz=100, hold_s=(6, 10), move_s=(2, 4))
    rec = s.recording
    print(f"simulated {rec.t[-1]:.0f} s at 100 Hz: the board is placed in {args.poses} orientations "
          f"with hand motion between them")
    ps = poses_from_recording(rec)
    print(f"still-pose detector found {len(ps)} poses (true: {args.poses})")
    raw = ps.acc
    print("genetic algorithm (population 100, paper 000's operators): best fitness by generation")
    prob = Problem(Triangular9(), raw)

    def show(gen, best):
        if gen % 5 == 0:
            f = float(best[0])
            bar = "#" * max(1, min(60, int(round(-np.log10(max(f, 1e-30)) * 4))))
            print(f"  gen {gen:3d}  fitness {f:10.3e}  {bar}", flush=True)
    res = ga(prob, rng=rng, progress=show)
    print(f"  LM polish -> fitness {res.fitness:.4e} "
          f"({res.info['ga_generations']} GA generations, {res.info['lm_iterations']} LM iterations)")
    cal = fit_norm(raw, "triangular9", "lm", pose_cov=ps.acc_cov)
    tr = s.truth.accel
    names = Triangular9().param_names
    print(f"\n{'parameter':<10} {'true':>12} {'estimate':>12} {'error':>10} {'CRLB sd':>10} {'err/sd':>7}")
    for i, n in enumerate(names):
        e = cal.theta[i] - tr[i]
        print(f"{n:<10} {tr[i]:12.6f} {cal.theta[i]:12.6f} {e:10.2e} {cal.crlb_std[i]:10.2e} "
              f"{e / cal.crlb_std[i]:7.2f}")
    # paper 001's measure: roll and pitch from the accelerometer against the true attitude
    from .calib.metrics import roll_pitch_deg
    from .sim.poses import up_vectors
    true_up = up_vectors(R)[:len(raw)] if len(raw) == len(R) else None
    if true_up is not None:
        r0, p0 = roll_pitch_deg(true_up)
        rr, pr = roll_pitch_deg(raw)
        rc, pc = roll_pitch_deg(Triangular9().forward(cal.theta, raw))
        wrap = lambda d: (d + 180) % 360 - 180
        e_raw = np.sqrt(np.mean(np.concatenate([wrap(rr - r0), pr - p0]) ** 2))
        e_cal = np.sqrt(np.mean(np.concatenate([wrap(rc - r0), pc - p0]) ** 2))
        print(f"roll/pitch RMS error over the poses (paper 001's measure): raw {e_raw:.3f} deg -> "
              f"calibrated {e_cal:.4f} deg")
    un = np.linalg.norm(raw, axis=1) - 1
    print(f"\n| |a| - 1 g | RMS over poses: raw {np.sqrt(np.mean(un ** 2)) * 1e3:.2f} mg -> calibrated "
          f"{cal.rms * 1e3:.3f} mg in-sample, {cal.heldout_rms * 1e3:.3f} mg held-out "
          f"(pose noise {cal.noise * 1e3:.3f} mg)")
    return 0


# --- probe -------------------------------------------------------------------------------

def cmd_probe(args) -> int:
    from .drivers.bus import Bus, VirtualClock, open_bus, real_bus_numbers
    from .drivers.probe import detect_board, probe
    if args.emulate:
        from .drivers.emulator import emulated_board
        from .sim.motion import PoseTour
        from .sim.poses import random_pose_set
        clock = VirtualClock()
        eb = emulated_board(args.emulate, PoseTour(random_pose_set(4, 0), rng=0), rng=0, clock=clock)
        bus, num = Bus(eb, name=f"emulated {args.emulate}", clock=clock), None
        print(f"bus: emulated {args.emulate} board (no hardware)")
    else:
        nums = real_bus_numbers()
        num = args.bus if args.bus is not None else (1 if 1 in nums else (nums[0] if nums else None))
        if num is None:
            raise UserError("no I2C bus on this machine (/dev/i2c-* absent): enable I2C "
                            "(raspi-config, or dtparam=i2c_arm=on), or try --emulate 9dof")
        bus = open_bus(num)
        print(f"bus: /dev/i2c-{num}")
    found = probe(bus, num)
    if not found:
        print("nothing answered at 0x0C, 0x0D, 0x1D, 0x1E, 0x53, 0x68, 0x69: check wiring, power "
              "and pull-ups ('i2cdetect -y N' lists every address)")
        return 1
    for f in found:
        print("  " + f.line())
    b = detect_board(found)
    print(f"board: {b}" if b else "board: none of the supported boards (mpu6050, mpu6500, mpu9250, 9dof)")
    return 0


# --- record ------------------------------------------------------------------------------

def parse_fault(spec: str, faults) -> None:
    """--fault forms: nack=P, stuck=T+D, busy=ADDR, wrong-id=ADDR:ID, reset=ADDR@T,
    disconnect=ADDR@T+D (times and durations in s, addresses in hex)."""
    try:
        kind, val = spec.split("=", 1)
        if kind == "nack":
            faults.nack_prob = float(val)
        elif kind == "stuck":
            t, d = val.split("+")
            faults.stuck.append((float(t), float(t) + float(d)))
        elif kind == "busy":
            faults.busy.add(int(val, 16))
        elif kind == "wrong-id":
            a, i = val.split(":")
            faults.wrong_id[int(a, 16)] = int(i, 16)
        elif kind == "reset":
            a, t = val.split("@")
            faults.resets.setdefault(int(a, 16), []).append(float(t))
        elif kind == "disconnect":
            a, w = val.split("@")
            t, d = w.split("+")
            faults.disconnected[int(a, 16)] = (float(t), float(t) + float(d))
        else:
            raise ValueError
    except ValueError:
        raise UserError(f"--fault {spec!r}: allowed nack=P, stuck=T+D, busy=0xAA, wrong-id=0xAA:0xII, "
                        f"reset=0xAA@T, disconnect=0xAA@T+D") from None


def open_board(args, motion_seed: int = 0):
    """(board, bus, description): real I2C when a bus exists and --emulate is not given."""
    from .drivers.board import make_board
    from .drivers.bus import Bus, ScaledClock, VirtualClock, open_bus, real_bus_numbers
    nums = real_bus_numbers()
    if args.emulate or (args.bus is None and not nums):
        from .drivers.emulator import Faults, emulated_board
        from .sim.motion import PoseTour
        from .sim.poses import random_pose_set
        faults = Faults()
        for f in args.fault or []:
            parse_fault(f, faults)
        clock = ScaledClock(1.0) if getattr(args, "realtime", False) else VirtualClock()
        rng = np.random.default_rng(args.seed)
        tour = PoseTour(random_pose_set(args.poses, rng), rng=rng, loop=True)
        eb = emulated_board(args.board, tour, rng=rng, clock=clock, faults=faults)
        bus = Bus(eb, name=f"emulated {args.board}", clock=clock)
        desc = f"emulated {args.board} (no I2C bus here), moved through {args.poses} orientations"
    else:
        if args.fault:
            raise UserError("--fault applies only to the emulated board (--emulate)")
        num = args.bus if args.bus is not None else (1 if 1 in nums else nums[0])
        bus = open_bus(num)
        desc = f"{args.board} on /dev/i2c-{num}"
    return make_board(args.board, bus, rate_hz=args.rate), bus, desc


def cmd_record(args) -> int:
    from .recording import Recording, write_recording
    board, bus, desc = open_board(args)
    board.start()
    _eprint(f"imucald: recording {args.seconds:g} s from {desc} at {board.rate_hz:g} Hz")
    parts = []
    while not parts or parts[-1].t.size == 0 or parts[-1].t[-1] < args.seconds - 1e-9 \
            or board.stats.samples == 0:
        b = board.read_batch()
        if len(b):
            parts.append(b)
        elif board.clock.now() - board.t0 > args.seconds + 5:
            raise UserError(f"no samples from {desc} for {args.seconds + 5:.0f} s "
                            f"(last fault: {getattr(board, 'last_fault', 'none')})")
    cat = lambda k: np.concatenate([getattr(p, k) for p in parts])
    keep = cat("t") < args.seconds
    meta = {"board": board.name, "rate_hz": f"{board.rate_hz:g}", "source": f"imucald record: {desc}"}
    mag = cat("mag")[keep] if board.has_mag else None
    if mag is not None and np.isnan(mag).any():      # before the first magnetometer reading
        first = int(np.argmax(~np.isnan(mag[:, 0])))
        mag[:first] = mag[first]
    rec = Recording(t=cat("t")[keep], acc=cat("acc")[keep], gyro=cat("gyro")[keep], mag=mag,
                    temp=cat("temp")[keep], meta=meta)
    write_recording(rec, args.output)
    st = board.stats
    _eprint(f"imucald: wrote {args.output}: {len(rec)} samples; gaps {st.gaps} ({st.missing} samples "
            f"lost), re-initialisations {st.reinits}, bus faults {st.bus_faults}, retries "
            f"{bus.stats.retries}")
    return 0


# --- daemon: run, replay, status, recalibrate, watch ----------------------------------

DEFAULT_CONFIG = "/etc/imucald/imucald.yaml"


def _setup_logging(level: str) -> None:
    import logging
    logging.basicConfig(level=getattr(logging, level.upper()), stream=sys.stderr,
                        format="imucald: %(message)s")


def _daemon_config(args):
    from .daemon.config import load_config, set_override
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
    from .daemon.run import Daemon
    from .drivers.emulator import Faults
    cfg, path = _daemon_config(args)
    _setup_logging(cfg["log"]["level"])
    faults = None
    if args.fault:
        faults = Faults()
        for f in args.fault:
            parse_fault(f, faults)
    emulate = True if args.emulate else (False if args.no_emulate else None)
    d = Daemon(cfg, emulate=emulate, speed=args.speed, seed=args.seed, faults=faults,
               duration_s=args.duration, echo=args.echo, config_path=path)
    return d.run()


def cmd_replay(args) -> int:
    import logging
    from .daemon.pipeline import Pipeline
    from .daemon.state import save_calibration
    from .drivers.board import SampleBatch
    from .recording import read_recording
    cfg, _ = _daemon_config(args)
    _setup_logging(cfg["log"]["level"])
    rec = read_recording(args.recording)
    if rec.acc is None:
        raise UserError(f"{args.recording}: no accelerometer columns (ax, ay, az)")
    n = len(rec)
    gyro = rec.gyro if rec.gyro is not None else np.zeros((n, 3))
    temp = rec.temp if rec.temp is not None else np.full(n, np.nan)
    fresh = None
    if rec.mag is not None:
        fresh = np.ones(n, bool)
        fresh[1:] = np.any(np.diff(rec.mag, axis=0) != 0, axis=1)
    pipe = Pipeline(cfg, rec.meta.get("board", "unknown"), rec.rate_hz, rec.mag is not None,
                    chips={"board": rec.meta.get("board", "unknown"), "source": args.recording})
    out = sys.stdout.buffer
    from .daemon.outputs import banner
    out.write(banner(cfg["output"]["format"], pipe.board))
    step = max(1, int(round(cfg["sensor"]["batch_s"] * rec.rate_hz)))
    seq = np.arange(n, dtype=np.int64)
    for i in range(0, n, step):
        sl = slice(i, min(n, i + step))
        b = SampleBatch(rec.t[sl], seq[sl], rec.acc[sl], gyro[sl], temp[sl],
                        None if rec.mag is None else rec.mag[sl], None if fresh is None else fresh[sl])
        out.write(pipe.process(b))
    out.flush()
    if args.state_dir and pipe.cal_doc is not None:
        os.makedirs(args.state_dir, exist_ok=True)
        p = save_calibration(args.state_dir, pipe.cal_doc, history=0)
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
    from .daemon.control import request
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
    from .daemon.control import request
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


# --- gap -------------------------------------------------------------------------------

def _gap_summary(res) -> str:
    lines = [f"{res['poses_found']} still poses"
             + (f"; left out as disturbed: {res['poses_left_out']}" if res.get("poses_left_out") else "")]
    for s, r in res["sensors"].items():
        u = r.get("unit", "")
        k = 1e3 if u == "g" else 1.0
        uu = "mg" if u == "g" else u
        lines.append(f"{s}: verdict {r['verdict']!s}"
                     + (" (partially explained)" if r.get("partially_explained") else "")
                     + f"; held-out residual {r['heldout_rms'] * k:.4g} {uu} vs the twin's "
                     f"{r['twin_heldout_rms'] * k:.4g} {uu}: ratio {r['ratio_before']:.2f} -> "
                     f"{r['ratio_after']:.2f}; chi-square p = {r['p_value']:.3g}"
                     + (f" (log10 p = {r['log10_p_value']})" if r['p_value'] == 0 else ""))
        for ef in r["effects"]:
            if ef.get("significant"):
                (pk, pv), = ef["params"].items()
                se = list(ef["stderr"].values())[0]
                vals = ", ".join(f"{a:.3g}+-{b:.2g}" for a, b in zip(pv, se))
                lines.append(f"  {ef['name']}: ratio after {ef['ratio_after']:.2f}, {pk} = [{vals}]")
        for c in r.get("confusable", []):
            lines.append(f"  cannot tell {' from '.join(c['effects'])} apart here "
                         f"(correlation {c['canonical_correlation']}); to separate them: {c['to_separate']}")
        w = r.get("where", {})
        if w.get("region_share"):
            top = sorted(w["region_share"].items(), key=lambda kv: -kv[1])[:3]
            lines.append("  excess by orientation: " + ", ".join(f"{a} {b:.0%}" for a, b in top))
        if r.get("note"):
            lines.append(f"  note: {r['note']}")
    for n in res.get("notes", []):
        lines.append(f"note: {n}")
    return "\n".join(lines)


def cmd_gap(args) -> int:
    from .gap.diagnose import diagnose
    from .calib.inputs import load_input
    columns = args.columns.split(",") if args.columns else None
    kind, rec = load_input(args.recording, columns, args.nominal_scale, args.nominal_offset, args.rate_hz)
    if kind != "recording":
        raise UserError(f"{args.recording}: gap needs samples (a recording), not pose averages")
    res = diagnose(rec, args.sensor, sims=args.sims, seed=args.seed, name=args.recording)
    if args.report:
        from .gap.report import write_report
        write_report(res, args.report)
    for r in res["sensors"].values():
        r.pop("_plot", None)
    if args.json:
        print(json.dumps(res, default=float))
    else:
        print(_gap_summary(res))
    return 0


# --- main ------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="imucald", description="Field calibration of MEMS IMUs.")
    p.add_argument("--version", action="version", version=f"imucald {__version__}")
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND")

    s = sub.add_parser("simulate", help="write a simulated recording")
    s.add_argument("-o", "--output", required=True, help="recording file to write")
    s.add_argument("--board", default="mpu6050", choices=["mpu6050", "9dof", "mpu9250"])
    s.add_argument("--poses", type=int, default=30, help="number of well-spread orientations")
    s.add_argument("--euler", help="paper 000 pose set NX,NY,NZ instead of --poses")
    s.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    s.add_argument("--hold", type=float, default=10.0, help="mean still time per pose, s")
    s.add_argument("--move", type=float, default=3.0, help="mean move time between poses, s")
    s.add_argument("--temp-profile", default="warmup", choices=["warmup", "ramp", "heatcool", "constant"])
    s.add_argument("--temp-rise", type=float, default=6.0, help="temperature change, degC")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--truth", help="also write the true parameters as JSON here")
    s.add_argument("--effect", action="append", help="inject an unmodelled effect: NAME or NAME=MAGNITUDE, "
                   "e.g. thermal_bias, accel.nonlinearity=0.002, gyro.g_sensitivity, mag.soft_iron; "
                   "'none' for a baseline-only recording (repeatable)")
    s.add_argument("--magnitude", type=float, help="magnitude of the single --effect (default: datasheet)")
    s.set_defaults(func=cmd_simulate)

    c = sub.add_parser("calibrate", help="calibrate from a recording or pose file")
    c.add_argument("input", help="recording, pose file, or raw table (with --columns)")
    c.add_argument("--sensor", choices=SENSORS, help="default accel; mag for a recording with "
                   "magnetometer columns only")
    c.add_argument("--method", default="ga", choices=METHODS)
    c.add_argument("--model", help="accel: triangular9 (default), full12, cosine[-o|-s|-os|-om|-sm]; "
                                   "mag: mag_sym (default), mag_diag, mag_sphere; gyro: mean, eq6")
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.add_argument("--seed", type=int, default=0, help="seed for the GA")
    c.add_argument("--columns", help="raw table columns, e.g. t,ax,ay,az (- skips one)")
    c.add_argument("--nominal-scale", type=float, default=1.0,
                   help="raw table: counts per unit (g, deg/s, gauss), e.g. 16384")
    c.add_argument("--nominal-offset", type=float, default=0.0,
                   help="raw table: counts at zero input, e.g. 32768 for unsigned 16-bit")
    c.add_argument("--rate-hz", type=float, help="raw table without a t column: sample rate")
    c.add_argument("--window-s", type=float, default=1.0, help="still detector window, s")
    c.add_argument("--threshold-k", type=float, default=6.0,
                   help="still when moving variance < k x noise floor")
    c.add_argument("--min-still-s", type=float, default=1.0, help="shortest still interval, s")
    c.set_defaults(func=cmd_calibrate)

    pr = sub.add_parser("probe", help="list what answers on the I2C bus and what each device is")
    pr.add_argument("--bus", type=int, help="bus number N of /dev/i2c-N (default 1, or the first present)")
    pr.add_argument("--emulate", choices=["mpu6050", "mpu6500", "mpu9250", "9dof", "9dof-qmc"],
                    help="probe an emulated board instead of hardware")
    pr.set_defaults(func=cmd_probe)

    r = sub.add_parser("record", help="record samples to a recording file")
    r.add_argument("-o", "--output", required=True)
    r.add_argument("--board", default="mpu6050", choices=["mpu6050", "mpu6500", "mpu9250", "9dof"])
    r.add_argument("--seconds", type=float, default=10.0)
    r.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    r.add_argument("--bus", type=int, help="bus number N of /dev/i2c-N (default 1)")
    r.add_argument("--emulate", action="store_true", help="use the emulated board even if a bus exists")
    r.add_argument("--realtime", action="store_true", help="emulator runs in wall-clock time")
    r.add_argument("--poses", type=int, default=30, help="emulator: orientations to move through")
    r.add_argument("--seed", type=int, default=0, help="emulator: seed")
    r.add_argument("--fault", action="append", help="emulator fault, e.g. nack=0.01, reset=0x68@3 "
                                                    "(repeatable; see the README)")
    r.set_defaults(func=cmd_record)

    def daemon_opts(q, state=True):
        q.add_argument("--config", help=f"configuration file (default {DEFAULT_CONFIG} if present)")
        q.add_argument("--runtime-dir", help="directory of the sockets (overrides runtime.directory)")
        if state:
            q.add_argument("--state-dir", help="overrides state.directory")
        q.add_argument("--log-level", choices=["debug", "info", "warning", "error"])

    rn = sub.add_parser("run", help="run the daemon (real I2C when a bus exists, else emulated)")
    daemon_opts(rn)
    rn.add_argument("--board", choices=["mpu6050", "mpu6500", "mpu9250", "9dof"])
    rn.add_argument("--rate", type=float, help="sample rate, Hz")
    rn.add_argument("--bus", type=int, help="bus number N of /dev/i2c-N")
    rn.add_argument("--format", choices=["ndjson", "csv", "binary"])
    rn.add_argument("--fifo", help="also stream to this FIFO")
    rn.add_argument("--method", choices=["ga", "hga", "lm", "ga-paper"])
    rn.add_argument("--min-poses", type=int)
    g = rn.add_mutually_exclusive_group()
    g.add_argument("--emulate", action="store_true", help="use the emulated board")
    g.add_argument("--no-emulate", action="store_true", help="never fall back to the emulator")
    rn.add_argument("--speed", type=float, default=1.0, help="emulator: time runs this much faster")
    rn.add_argument("--seed", type=int, default=0, help="emulator: seed")
    rn.add_argument("--fault", action="append", help="emulator fault (as for record)")
    rn.add_argument("--duration", type=float, help="stop after this many (sensor-clock) seconds")
    rn.add_argument("--echo", action="store_true", help="print one stream line per second")
    rn.set_defaults(func=cmd_run)

    rp = sub.add_parser("replay", help="feed a recording through the pipeline; NDJSON to stdout")
    rp.add_argument("recording")
    rp.add_argument("--state-dir", help="save the calibration reached as DIR/calibration.yaml")
    rp.add_argument("--config")
    rp.add_argument("--format", choices=["ndjson", "csv", "binary"])
    rp.add_argument("--method", choices=["ga", "hga", "lm", "ga-paper"])
    rp.add_argument("--min-poses", type=int)
    rp.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    rp.set_defaults(func=cmd_replay)

    for name, fn, hlp in (("status", cmd_status, "the running daemon's state"),
                          ("recalibrate", cmd_recalibrate, "ask the daemon to calibrate now")):
        q = sub.add_parser(name, help=hlp)
        daemon_opts(q, state=False)
        if name == "status":
            q.add_argument("--json", action="store_true")
        q.set_defaults(func=fn)
    w = sub.add_parser("watch", help="print the daemon's stream")
    daemon_opts(w, state=False)
    w.add_argument("-n", "--count", type=int, help="stop after N lines")
    w.set_defaults(func=cmd_watch)

    gp = sub.add_parser("gap", help="diagnose the sim-to-real gap of a recording")
    gp.add_argument("recording")
    gp.add_argument("--sensor", action="append", choices=["accel", "gyro", "mag"],
                    help="sensor(s) to diagnose (default: all present)")
    gp.add_argument("--json", action="store_true", help="print one JSON object")
    gp.add_argument("--report", help="write plots to this directory (needs the plots extra)")
    gp.add_argument("--sims", type=int, default=200, help="twin re-simulations")
    gp.add_argument("--seed", type=int, default=0)
    gp.add_argument("--columns", help="raw table columns, e.g. t,ax,ay,az,temp")
    gp.add_argument("--nominal-scale", type=float, default=1.0)
    gp.add_argument("--nominal-offset", type=float, default=0.0)
    gp.add_argument("--rate-hz", type=float)
    gp.set_defaults(func=cmd_gap)

    d = sub.add_parser("demo", help="the calibration demo that `make run` shows")
    d.add_argument("--seed", type=int, default=1)
    d.add_argument("--poses", type=int, default=25)
    d.set_defaults(func=cmd_demo)
    return p


def main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as e:
        _eprint(f"imucald: error: {e}")
        return e.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
