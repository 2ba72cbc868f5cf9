"""``imucald simulate``, ``calibrate`` and ``demo``: the offline commands.

Heavy modules (the simulator, the fitters) are imported inside each command so
that ``imucald --help`` stays light; json too, which only ``--json`` and ``--truth`` need.
"""
from __future__ import annotations

import math
import os
from typing import Optional

from ..errors import EX_UNDETERMINED, UserError, write_failure
from ._common import eprint as _eprint, print_json

SENSORS = ("accel", "gyro", "mag")
DEFAULT_MODEL = {"accel": "triangular9", "mag": "mag_sym", "gyro": "mean"}


# --- simulate ----------------------------------------------------------------------------

def cmd_simulate(args) -> int:
    import numpy as np
    from ..files.recording import write_recording
    from ..sim.orientations import euler_pose_set, random_pose_set
    from ..sim.sensor import simulate_session
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
        from ..sim.effects import effect_session
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
            if spec[-1][1] is not None and not math.isfinite(spec[-1][1]):
                raise UserError(f"--effect {e!r}: the magnitude after '=' is not a finite number")
        try:
            s, effects = effect_session(args.board, R, rng, spec, args.rate, hold, move,
                                        args.temp_profile, args.temp_rise, args.tremor_dps,
                                        args.sway_deg)
        except ValueError as ex:
            raise UserError(f"--effect: {ex}") from None
    else:
        s = simulate_session(args.board, R, rng, rate_hz=args.rate, hold_s=hold, move_s=move,
                             temp_kind=args.temp_profile, temp_rise_c=args.temp_rise,
                             tremor_dps=args.tremor_dps, sway_deg=args.sway_deg)
    s.recording.meta["seed"] = str(args.seed)
    out = s.recording
    if getattr(args, "logger_rate", None):
        from ..sim.sensor import hold_samples
        if args.logger_rate <= args.rate:
            raise UserError(f"--logger-rate {args.logger_rate:g}: must exceed --rate {args.rate:g} "
                            f"(the logger reads faster than the chip updates)")
        out = hold_samples(out, args.logger_rate)
    if getattr(args, "duplicate_rows", False):
        from ..sim.sensor import duplicate_rows
        out = duplicate_rows(out)
    if getattr(args, "fifo_burst", None):
        from ..sim.sensor import burst_stamps
        out = burst_stamps(out, args.fifo_burst)
    try:
        write_recording(out, args.output, "-o")
    except OSError as e:
        raise write_failure(e, "-o", args.output) from None
    if args.truth:
        from ..files.atomic import atomic_write_text
        tr = s.truth
        d = {"board": tr.board, "accel_triangular9": tr.accel.tolist(),
             "gyro_bias_dps": tr.gyro_bias_dps.tolist(), "gyro_matrix": tr.gyro_matrix.tolist(),
             "hold_s": [list(h) for h in s.hold],
             "effects": effects}
        if tr.mag_soft_iron is not None:
            d.update(mag_hard_iron_gauss=tr.mag_hard_iron_gauss.tolist(),
                     mag_soft_iron=tr.mag_soft_iron.tolist(), field_gauss=tr.field_gauss,
                     dip_deg=tr.dip_deg)
        try:
            import json
            atomic_write_text(args.truth, json.dumps(d, indent=1) + "\n", flag="--truth")
        except OSError as e:
            raise write_failure(e, "--truth", args.truth) from None
    _eprint(f"imucald: wrote {args.output}: {args.board}, {len(R)} poses, "
            f"{len(s.recording)} samples at {args.rate:g} Hz ({s.recording.t[-1]:.0f} s)"
            + (f", {len(out)} rows as logged" if out is not s.recording else ""))
    return 0


# --- calibrate ---------------------------------------------------------------------------

def _fmt_vec(v, unit_scale=1.0, fmt="{:+.6f}"):
    return "[" + ", ".join("   n/a   " if x is None else fmt.format(x * unit_scale) for x in v) + "]"


#: |mean specific force| a still accelerometer pose may read, g: gravity (1 g) through an
#: uncalibrated MEMS accelerometer's scale (a few %) and offset (<= ~0.15 g) errors, with a
#: wide margin; outside it the pose is not at rest under gravity or not in g (a zero pose made
#: the fit's matrices singular, a pose in counts gave nonsense)
REST_NORM_G = (0.5, 2.0)


def check_rest_norms(path: str, poses) -> None:
    import numpy as np
    norm = np.linalg.norm(poses.acc, axis=1)
    bad = np.flatnonzero(~((norm >= REST_NORM_G[0]) & (norm <= REST_NORM_G[1])))
    if len(bad):
        i = int(bad[0])
        raise UserError(f"{path}: pose {i + 1} (t0 {poses.t0[i]:g} s) reads |a| = {norm[i]:.3g} g, not ~1 g "
                        f"({REST_NORM_G[0]:g}..{REST_NORM_G[1]:g}): a still pose reads gravity in g; "
                        f"remove that pose or convert the file to g")


def one_orientation(poses) -> Optional[str]:
    """Why the accelerometer's still poses determine no calibration when they all hold the
    board in one orientation (the gap diagnosis's grouping, 20 deg: None otherwise): a norm
    fit then sees one direction of gravity, and 7 of the 9 parameters rest on the prior alone
    (an independent probe's board turned flat on a table: calibrate accepted it with exit 0,
    where replay and gap refuse it)."""
    import numpy as np
    from ..fitting.judging.coverage import orientation_groups
    if len(poses) < 2 or not np.all(np.linalg.norm(poses.acc, axis=1) > 0) \
            or orientation_groups(poses.acc).max() > 0:
        return None         # (a zero pose has no direction: check_rest_norms says so)
    return (f"all {len(poses)} still poses hold the board in one orientation (gravity directions within "
            f"20 deg of the first's), which determines no calibration: turn it over between holds, "
            f"about 25 orientations spread over the sphere (turning it flat on a table keeps one)")


#: smallest ratio of the magnetometer pose means' least to greatest spread (principal axes)
#: for a 3-D fit; below it they lie in a plane, on a line or at one point, where the
#: ellipsoid is not determined (and the solvers raised LinAlgError)
MAG_MIN_SPAN_RATIO = 1e-3


def _check_mag_span(path: str, mag) -> None:
    import numpy as np
    x = np.asarray(mag, float)
    sv = np.linalg.svd(x - x.mean(0), compute_uv=False) if len(x) >= 3 else np.zeros(3)
    if len(sv) < 3 or not sv[0] > 0 or sv[-1] < MAG_MIN_SPAN_RATIO * sv[0]:
        raise UserError(f"{path}: the magnetometer pose means do not span three dimensions (they lie in a "
                        f"plane, on a line or at one point), so no 3-D calibration is determined: turn the "
                        f"board through many orientations, or calibrate from a rotation recording "
                        f"(docs/guide/magnetometer.md)")


def _accel_model_order(path, model, n_poses, default, det, progress, acc_g=None):
    """(poses needed, model to fit): each model needs one pose more than its free parameters
    (diag6 7, triangular9 10, full12 13; ``auto`` the smallest candidate's).  An explicit
    model is judged by its own count; the default (triangular9, no --model) with fewer poses
    than it needs but enough for a smaller model becomes ``auto`` (said on stderr); fewer
    poses than any model needs: one line, exit 2 (no still moment at all: why)."""
    from ..fitting.fit import AUTO_MODELS
    from ..fitting.models.registry import get_model
    from ..fitting.stillness.poses import no_still_message
    k = lambda m: int(get_model(m).free_mask.sum())
    need = min(k(m) for m in AUTO_MODELS) + 1 if model == "auto" else k(model) + 1
    smallest = min(k(m) for m in AUTO_MODELS) + 1
    if n_poses == 0:
        raise UserError(no_still_message(path, det, 0, acc_g))
    if n_poses >= need:
        return need, model
    if default and n_poses >= smallest:
        _eprint(f"imucald: {n_poses} still poses: fewer than the {need} the default {model} needs; "
                f"choosing the model by held-out error among those the poses determine (--model auto)")
        return smallest, "auto"
    hint = (f"; with {n_poses} poses use --model auto or diag6 (offset + scale, needs {smallest})"
            if n_poses >= smallest else "")
    raise UserError(f"{path}: only {n_poses} still poses found; the {k(model) if model != 'auto' else smallest - 1}"
                    f"-parameter model {model} needs at least {need} (about 25 recommended), well spread "
                    f"over the sphere{hint}")


def cmd_calibrate(args) -> int:
    """:func:`_calibrate` with the cyclic garbage collector paused (and put back as it was):
    one command that makes little cyclic garbage and ends in a fraction of a second, while
    numpy's import and the fit's small objects made it run ~47 collections on the Xsens file
    (1.3 % of its instructions under valgrind, more of its time on a loaded machine, where
    the scans miss the cache).  The results do not depend on it."""
    import gc
    was = gc.isenabled()
    gc.disable()
    try:
        return _calibrate(args)
    finally:
        if was:
            gc.enable()


def _calibrate(args) -> int:
    """parse (input, sensor, model) -> poses -> fit -> rotations and thermal terms -> write
    and present; each step a function below."""
    from ..numerics import allocator
    # the fit tunes the allocator anyway (fitting/solvers/lsq.py); tuned before reading, the reader's
    # and the detector's MB-sized temporaries are reused from the heap, not page-faulted
    # afresh each time (measured: 3.5 ms of reading, 1.5 ms of detection on the Xsens file)
    allocator.tune()
    from ._common import read_input
    kind, obj = read_input(args, args.input)
    obj = _time_window(args, kind, obj)
    if args.sensor == "all":    # every part the recording supports, into one file (cli/calall.py)
        from .calall import cmd_calibrate_all
        return cmd_calibrate_all(args, kind, obj)
    sensor, model = _sensor_and_model(args, kind, obj)
    rec = obj if kind == "recording" else None
    from ..fitting.inputs import stuck_columns, stuck_message
    x = {"accel": obj.acc, "gyro": obj.gyro, "mag": obj.mag}[sensor]
    # a pose file's means: at least 3 poses; the magnetometer's have their own check, that
    # they span three dimensions (fitting/magcal.py), which names what is wrong with them
    stuck = (stuck_columns(x, sensor) if rec is not None else
             stuck_columns(x, sensor, min_rows=3) if sensor != "mag" else [])
    if stuck:
        row = "sample" if rec is not None else "pose"
        raise UserError(f"{args.input}: {sensor}: {stuck_message(stuck, row)}; not calibrated")
    progress = None if args.json else _eprint
    if sensor == "mag" and rec is not None:
        if rec.mag is None:
            raise UserError(f"{args.input}: no magnetometer columns (mx, my, mz)")
        return _calibrate_mag_rotation(args, rec, model, progress)
    # poses: one per placement (the constant fit); pieces: the detector's pieces of them, each
    # at its own temperature (the thermal fit: a one-placement warm-up is one pose but many pieces)
    poses, pieces = still_poses(args, rec) if rec is not None else (obj, obj)
    det = poses.detector
    chip = infl_pieces = None
    if sensor == "accel":
        cal, chip, infl_pieces = _fit_accel(args, rec, poses, pieces, det, model, progress)
    elif sensor == "mag":
        cal = _fit_mag_poses(args, poses, model)
    else:
        cal = _fit_gyro_poses(args, rec, poses, det, model)
    rot = why = None
    if sensor == "gyro" and rec is not None:    # scale/misalignment from the rotations between poses
        from .gyrorot import fit_rotations
        rot, why = fit_rotations(rec, poses, args, pieces)
    tf = None
    if sensor in ("accel", "gyro") and args.method != "ga-paper":
        # the thermal terms: the order the held-out test supports (docs: thermal terms)
        from .thermal import fit_thermal
        tf = fit_thermal(sensor, pieces, cal, chip, infl_pieces, args.thermal_min_span, args.seed)
    # what -o writes (and the file's bias for the gyro, the accelerometer's plots, the
    # parameters thermal terms moved: the report shows them); nothing else reads it, so an
    # accelerometer answer without -o or thermal terms skips it (and the calibration
    # module's import: ~2 ms)
    plot = getattr(args, "plot", None) and sensor == "accel"
    if args.output or sensor == "gyro" or plot or (tf is not None and _thermal_moves(tf)):
        part = file_part(cal, tf, rot)
    else:
        part = None
    if args.output:
        _write_calibration(args.output, poses.meta, part, tf)
    if plot:                                   # coverage sphere, residuals (plots extra)
        from .plotcmd import calibrate_plots
        calibrate_plots(args.plot, poses, part, os.path.basename(args.input))
    if args.json:
        print_json(_calibrate_json(sensor, cal, det, rec, rot, why, part, tf))
    else:
        _print_report(sensor, cal, rec, rot, why, part, tf)
    return 0


def still_poses(args, rec):
    """(poses, pieces) of a recording, as every accelerometer and gyro calibration takes them:
    found (poses: one per placement, for the constant fit; pieces: the detector's pieces of
    them, each at its own temperature, for the thermal fit: a one-placement warm-up is one
    pose but many pieces), the repeated rows said once (sample-and-hold, duplicated rows: not
    measurements), and the poses no calibration of the others explains left out."""
    from ..fitting.stillness.poses import poses_and_pieces
    poses, pieces = poses_and_pieces(rec, window_s=args.window_s, k=args.threshold_k,
                                     min_still_s=args.min_still_s)
    det = poses.detector
    if det is not None and det.repeats.summary():
        _eprint(f"imucald: warning: {args.input}: {det.repeats.summary()}")
    return drop_outlier_poses(args.input, poses, pieces, rec.acc)


def drop_outlier_poses(path: str, poses, pieces, acc_g=None):
    """(poses, pieces) without the still poses that no calibration of the others explains (a
    board held still while it accelerated, or knocked: fitting/judging/outliers.py, with the
    poses' temperatures and, from the samples ``acc_g``, the rounding of their means), said
    in one warning and counted among the detector's rejected stretches (``outlier``)."""
    import numpy as np
    from ..fitting.judging.outliers import OUTLIER_CAUSE, OUTLIER_POSE_Z, poses_to_leave_out
    from ..fitting.noise.posefloor import pose_quantisation_floor
    if poses.acc is None:
        return poses, pieces
    idx, z, r, drop = poses_to_leave_out(poses.acc, poses.acc_cov, poses.temp)
    if len(idx) and acc_g is not None and poses.slices:
        # the rounding of the pose means (a coarse converter) only adds variance: read off the
        # samples (~15 ms on the Xsens file) only when a pose stands out without it
        floor = pose_quantisation_floor(acc_g, poses.slices)[0]
        idx, z, r, drop = poses_to_leave_out(poses.acc, poses.acc_cov, poses.temp, floor)
    if not len(idx):
        return poses, pieces
    what = "; ".join(f"{poses.t0[i]:.1f}-{poses.t1[i]:.1f} s: |a| {-r[i] * 1e3:+.3g} mg, {abs(z[i]):.0f} sd"
                     for i in idx[:4]) + ("; ..." if len(idx) > 4 else "")
    _eprint(f"imucald: warning: {path}: {len(idx)} still pose(s) read |a| far from what the others' "
            f"calibration predicts (over {OUTLIER_POSE_Z:g} sd: {what}): {OUTLIER_CAUSE}; "
            + ("left out" if drop else "kept: too few poses would be left"))
    if not drop:
        return poses, pieces
    det = poses.detector
    if det is not None:
        det.rejected_counts["outlier"] = det.rejected_counts.get("outlier", 0) + len(idx)
        det.rejected.extend({"kind": "outlier", "t0_s": float(poses.t0[i]), "t1_s": float(poses.t1[i]),
                             "reason": f"|a| {-r[i] * 1e3:+.3g} mg off the others' calibration "
                                       f"({abs(z[i]):.0f} sd)"} for i in idx)
    bad = np.isin(np.arange(len(poses)), idx)
    inside = lambda ps: np.any((ps.t0[:, None] >= poses.t0[idx][None, :] - 1e-9) &
                               (ps.t1[:, None] <= poses.t1[idx][None, :] + 1e-9), axis=1)
    return poses.subset(~bad), (pieces.subset(~inside(pieces)) if pieces is not poses else poses.subset(~bad))


def _time_window(args, kind: str, obj):
    """The recording within --start-s/--end-s (s after its first sample), or as it is."""
    start, end = getattr(args, "start_s", None), getattr(args, "end_s", None)
    if start is None and end is None:
        return obj
    if kind != "recording":
        raise UserError(f"{args.input}: --start-s/--end-s select samples: give a recording or a raw "
                        f"table, not a pose file")
    from ._common import window_rows
    return obj.slice(*window_rows(obj.t, start, end, args.input))


def _sensor_and_model(args, kind: str, obj):
    """The sensor to calibrate (a magnetometer-only recording: the magnetometer) and the
    model asked for (else the sensor's default), refused in one line when it does not fit."""
    from ..fitting.models.registry import MODEL_NAMES
    sensor = args.sensor
    if sensor is None:
        sensor = "mag" if kind == "recording" and obj.acc is None and obj.mag is not None else "accel"
    model = args.model or DEFAULT_MODEL[sensor]
    accel_models = ["auto"] + [m for m in MODEL_NAMES if not m.startswith("mag_")]
    if sensor == "accel" and model not in accel_models:
        raise UserError(f"--model {model!r} does not fit --sensor accel: allowed " + ", ".join(accel_models))
    if sensor == "mag" and not model.startswith("mag_"):
        raise UserError(f"--model {model!r} does not fit --sensor mag: allowed mag_sym, mag_diag, mag_sphere")
    if sensor == "gyro" and model not in ("mean", "eq6"):
        raise UserError(f"--model {model!r} does not fit --sensor gyro: allowed mean, eq6")
    return sensor, model


def _fit_accel(args, rec, poses, pieces, det, model, progress):
    """The accelerometer on the still poses: the model the pose count supports, the chip's
    datasheet prior, the coloured-noise inflation from the recording; returns (FitResult,
    chip, the pieces' inflation for the thermal fit)."""
    from ..fitting.fit import fit_norm
    from ..specs import BOARDS
    if len(poses):
        check_rest_norms(args.input, poses)     # each pose reads ~1 g (a zero pose: no direction)
    why = one_orientation(poses)
    if why:
        raise UserError(f"{args.input}: {why}")
    need, model = _accel_model_order(args.input, model, len(poses), args.model is None, det, progress,
                                     rec.acc if rec is not None else None)
    if progress:
        from ..fitting.stillness.poses import still_report
        for line in still_report(det)[1:]:
            progress(f"imucald: {line}")
        progress(f"imucald: {len(poses)} still poses; fitting {model} with {args.method}")
    kw = {"progress": progress} if args.method == "ga-paper" and progress else {}
    chip = BOARDS.get(poses.meta.get("board", ""), (None,))[0]
    infl = infl_pieces = None
    if rec is not None:     # coloured noise: the Allan model of the longest still pose
        from ..fitting.noise.colour import pose_colour_inflation
        from .thermal import pieces_colour_inflation
        from ..fitting.noise.posecov import allan_still_needed
        if allan_still_needed((poses.noise or {}).get("accel")):
            infl, _ = pose_colour_inflation(rec.t, rec.acc, rec.rate_hz, poses.t0, poses.t1, poses.n)
        infl_pieces = pieces_colour_inflation(rec, poses, pieces)
    cal = fit_norm(poses.acc, model, args.method, pose_cov=poses.acc_cov, rng=args.seed,
                   chip=chip, noise_inflation=infl, temp_c=poses.temp, **kw)
    return cal, chip, infl_pieces


def _fit_mag_poses(args, poses, model):
    """The magnetometer from a pose file: the pose means are the points."""
    from ..fitting.fit import fit_norm
    if poses.mag is None:
        raise UserError(f"{args.input}: no magnetometer columns (mx, my, mz)")
    _check_mag_span(args.input, poses.mag)
    return fit_norm(poses.mag, model, args.method, pose_cov=poses.mag_cov, rng=args.seed)


def _fit_gyro_poses(args, rec, poses, det, model):
    """The gyro bias from the still poses (``eq6``: from their distinct still samples)."""
    import numpy as np
    from ..fitting.fit import fit_gyro_bias
    if poses.gyro is None:
        raise UserError(f"{args.input}: no gyro columns (gx, gy, gz)")
    if len(poses) == 0:
        raise UserError(f"{args.input}: no still poses found; the gyro bias needs at least one: hold "
                        f"the board still for a few seconds, or check the units (--nominal-scale)")
    samples = None
    if model == "eq6":
        if rec is None:
            raise UserError("--model eq6 needs the still samples: give a recording")
        # the poses' own stretches (the detector ran once, with the user's options)
        keep = det.repeats.keep if det is not None else np.ones(len(rec.t), bool)
        samples = np.concatenate([rec.gyro[s][keep[s]] for s in poses.slices])     # distinct samples
    return fit_gyro_bias(poses.gyro, poses.n, poses.gyro_cov, model, samples, rng=args.seed)


def _thermal_moves(tf) -> bool:
    from .thermal import moves_params
    return moves_params(tf)


def _calibrate_json(sensor, cal, det, rec, rot, why, part, tf) -> dict:
    """calibrate --json: the fit, the still-pose detection behind it, the rotations, what the
    file holds and the thermal terms."""
    d = cal.to_json()
    if det is not None:     # the still-pose detection behind the fit (issue 20)
        d["stillness"] = stillness_json(det)
    if rec is not None and sensor == "gyro":
        from .gyrorot import rotation_json
        d["rotations"] = rotation_json(rot, why)
    if sensor == "gyro":
        d["file"] = {"bias_dps": part.params["bias_dps"].tolist(),
                     "matrix": "matrix" in part.params, "g_sens_dps_per_g": "g_sens_dps_per_g" in part.params}
    if tf is not None:
        from .thermal import thermal_json
        d["thermal"] = thermal_json(sensor, tf, part)
    return d


def stillness_json(det) -> dict:
    """calibrate --json's ``stillness``: the still-pose detection behind a fit (issue 20)."""
    rp = det.repeats
    return {"effective_rate_hz": round(float(det.rate), 4), "repeated_rows": int(rp.repeated),
            "held": bool(rp.held), "duplicated_timestamps": int(rp.duplicated_t),
            "rejected": dict(det.rejected_counts)}


def _print_report(sensor, cal, rec, rot, why, part, tf) -> None:
    """calibrate's text report: the fit, then the rotations, the file's gyro line, the thermal terms."""
    print_cal(sensor, cal)
    if rec is not None and sensor == "gyro":
        from .gyrorot import rotation_lines
        print("\n".join(rotation_lines(rot, why)))
    if sensor == "gyro":
        from .gyrorot import file_line
        print(file_line(part))
    if tf is not None:
        from .thermal import thermal_lines
        print("\n".join(thermal_lines(sensor, tf, part)))


def print_cal(sensor: str, cal) -> None:
    unit = {"accel": ("mg", 1e3), "mag": ("mG", 1e3), "gyro": ("deg/s", 1.0)}[sensor]
    what = "poses" if cal.noise_source in ("poses", "residuals") else "points (thinned rotation samples)"
    print(f"{sensor} {cal.model} by {cal.method}: {cal.poses} {what}, fitness {cal.fitness:.6g}")
    for g, v in cal.params.items():
        se = cal.stderr.get(g)
        vv = v if isinstance(v, list) else [v]
        ss = se if isinstance(se, list) else [se]
        name = "bias_dps (pose mean)" if sensor == "gyro" and g == "bias_dps" else g
        print(f"  {name:<18} {_fmt_vec(vv)}  +- {_fmt_vec(ss, fmt='{:.2e}')}")
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
        for f in cal.uncertainty.flags:
            ratio = f["std_over_prior_std"]
            print(f"  {f['name']}: {f['reason'].replace('+', ' and ')}"
                  + ("" if ratio is None else f" (std {ratio:.2f} x its prior std)") + f"; {f['hint']}")
        nm = cal.info.get("noise_model")
        if nm is not None:
            z = cal.info.get("heldout_normalised_rms", float("nan"))
            print(f"  noise model: {'each pose its own' if nm['per_pose'] else 'fit residuals'}"
                  + (f", coloured-noise inflation x{nm['colour_inflation_median']:.2f} (median)"
                     if "colour_inflation_median" in nm else "")
                  + f", excess scatter x{nm['excess_scatter']:.2f}; prior: {nm['prior']}; "
                  f"held-out residual / predicted std RMS {z:.2f}")
        ms = cal.info.get("model_selection")
        if ms is not None:
            print(f"  model {ms['chosen']} chosen by leave-one-pose-out RMS ("
                  + ", ".join(f"{m} {v * unit[1]:.4f} {unit[0]}" for m, v in ms["heldout_rms_g"].items())
                  + f"; one standard error {ms['standard_error_g'] * unit[1]:.4f} {unit[0]})"
                  + (f"; {', '.join(ms['held_at_prior'])} fitted with fewer poses than their parameters "
                     f"+ 1: the terms the poses do not determine held at the datasheet prior"
                     if ms.get("held_at_prior") else ""))
        if "path_error_20s_std_m" in cal.info:
            pe = cal.info["path_error_20s_std_m"]
            print(f"  paper 000 path error after 20 s (STD over poses): raw {pe['raw']:.3g} m, "
                  f"calibrated {pe['calibrated']:.3g} m")
    else:
        print(f"  between-pose scatter RMS {cal.rms:.4f} deg/s")


def _calibrate_mag_rotation(args, rec, model, progress) -> int:
    """Magnetometer from the rotation cloud (any recording with mx, my, mz).
    Exit 3 when the cloud does not determine a calibration (a one-plane swing)."""
    from ..fitting.magcal import calibrate_rotation, flat_message, rotation_json, rotation_lines, unit_problem
    if progress:
        progress(f"imucald: {len(rec)} magnetometer rows; thinning over the sphere and fitting "
                 f"{model} with {args.method}")
    res = calibrate_rotation(rec.mag, model, args.method, rng=args.seed, temp_c=rec.temp,
                             thermal_min_span_c=args.thermal_min_span, name=args.input, t_s=rec.t)
    why = unit_problem(res)
    if why:
        raise UserError(f"{args.input}: {why}")
    tf = res.get("thermal")
    part = file_part(res["calibration"], tf) if res["determined"] else None
    if args.output and res["determined"]:
        _write_calibration(args.output, rec.meta, part, tf)
    if args.json:
        d = rotation_json(res)
        if tf is not None:
            from .thermal import thermal_json
            d["thermal"] = thermal_json("mag", tf, part)
        print_json(d)
        return 0 if res["determined"] else EX_UNDETERMINED
    if not res["determined"]:
        _eprint(f"imucald: {args.input}: {flat_message(res)}")
        return EX_UNDETERMINED
    print_cal("mag", res["calibration"])
    print("\n".join(rotation_lines(res)))
    if tf is not None:
        from .thermal import thermal_lines
        print("\n".join(thermal_lines("mag", tf, part)))
    return 0


def file_part(fit, thermal=None, rotations=None):
    """The part --output writes: the fitted one with its thermal terms and, for the gyro,
    the scale/misalignment (and g-sensitivity) from the rotations when they beat bias only."""
    from ..calibration import SensorCal
    from .thermal import thermal_part
    part = SensorCal.from_fit(fit) if thermal is None else thermal_part(fit.sensor, fit, thermal)
    if rotations is not None:
        from .gyrorot import with_rotations
        part = with_rotations(part, rotations)
    return part


def _write_calibration(path: str, meta, part, thermal=None) -> None:
    """--output: ``part`` (a fit: its part, see file_part) as a calibration file (the
    daemon's and imucald.load_calibration's format), written atomically; board and chips
    from the input's meta (chips: the recorded ones, else the board's usual), created now."""
    from ..calibration import SensorCal, build_calibration, save
    if not isinstance(part, SensorCal):
        part = file_part(part, thermal)
    tr = None if thermal is None else (round(thermal.t_min_c, 2), round(thermal.t_max_c, 2))
    try:
        save(build_calibration({part.sensor: part}, meta=meta, temperature_range_c=tr), path)
    except OSError as e:
        raise write_failure(e, "--output", path) from None


def get_free(cal) -> int:
    from ..fitting.models.registry import get_model
    return int(get_model(cal.model).free_mask.sum())


# --- demo (make run) ---------------------------------------------------------------------

def cmd_demo(args) -> int:
    """Simulate a handled MPU6050, find its poses, and show the GA converging."""
    import numpy as np

    from .. import __version__
    from ..fitting.fit import fit_norm
    from ..fitting.judging.metrics import rms
    from ..fitting.models.accel import Triangular9
    from ..fitting.solvers.lsq import Problem
    from ..fitting.solvers.ga import ga
    from ..fitting.stillness.poses import poses_from_recording
    from ..sim.orientations import random_pose_set
    from ..sim.sensor import simulate_session
    rng = np.random.default_rng(args.seed)
    print(f"imucald {__version__} demo: a calibration on a simulated MPU6050 (seed {args.seed}); "
          f"'imucald run --emulate' runs the daemon on an emulated board")
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
    from ..fitting.judging.metrics import roll_pitch_deg
    from ..sim.orientations import up_vectors
    true_up = up_vectors(R)[:len(raw)] if len(raw) == len(R) else None
    if true_up is not None:
        r0, p0 = roll_pitch_deg(true_up)
        rr, pr = roll_pitch_deg(raw)
        rc, pc = roll_pitch_deg(Triangular9().forward(cal.theta, raw))
        wrap = lambda d: (d + 180) % 360 - 180
        e_raw = rms(np.concatenate([wrap(rr - r0), pr - p0]))
        e_cal = rms(np.concatenate([wrap(rc - r0), pc - p0]))
        print(f"roll/pitch RMS error over the poses (paper 001's measure): raw {e_raw:.3f} deg -> "
              f"calibrated {e_cal:.4f} deg")
    un = np.linalg.norm(raw, axis=1) - 1
    print(f"\n| |a| - 1 g | RMS over poses: raw {rms(un) * 1e3:.2f} mg -> calibrated "
          f"{cal.rms * 1e3:.3f} mg in-sample, {cal.heldout_rms * 1e3:.3f} mg held-out "
          f"(pose noise {cal.noise * 1e3:.3f} mg)")
    return 0

