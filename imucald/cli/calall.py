"""``imucald calibrate REC --sensor all``: every part the recording supports, fitted once,
into one calibration file (the daemon's calibration.yaml).

The parts share what they share: the recording is read once and its still poses found
once; the accelerometer part (the same fit as ``--sensor accel``) gives the gyro's gravity
directions; the magnetometer part (the same rotation-cloud fit as ``--sensor mag``) gives
its field directions.  Each part is what the single-sensor command would print and write
(cli/offline.py), so the results agree with ``--sensor accel``, ``--sensor gyro`` and
``--sensor mag`` within their reported standard errors (the gyro's K and G to the extent
that the shared accelerometer and magnetometer fits differ from the lighter ones
``--sensor gyro`` makes for itself: far inside K's standard error, tests/test_calibrate_all.py).
A part the recording cannot give is skipped with the reason (the others are still written).
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional

from ..errors import UserError, write_failure
from ._common import eprint as _eprint, print_json

#: the order parts are fitted in: the gyro uses the other two
ORDER = ("accel", "mag", "gyro")


def cmd_calibrate_all(args, kind: str, rec) -> int:
    """Fit, present, write.  Exit 0 with at least one part; 2 (UserError) without any."""
    if kind != "recording":
        raise UserError(f"{args.input}: --sensor all needs a recording (samples), not a pose file; "
                        f"calibrate a pose file one sensor at a time (--sensor accel, gyro or mag)")
    if args.model:
        raise UserError(f"--model {args.model}: --sensor all fits each part with its default model "
                        f"(accel triangular9, gyro mean bias with K and G from the rotations, mag mag_sym); "
                        f"for another model run --sensor accel, gyro or mag")
    progress = None if args.json else _eprint
    res = fit_all(args, rec, progress)
    still = res.pop("stillness", None)
    parts = {s: r["part"] for s, r in res.items() if r.get("part") is not None}
    if not parts:
        raise UserError(f"{args.input}: no part could be calibrated: "
                        + "; ".join(f"{s}: {r['skipped']}" for s, r in res.items()))
    if args.output:
        _write(args.output, rec.meta, res, parts)
    if args.json:
        d: Dict[str, Any] = {"sensor": "all", "parts": [s for s in ORDER if s in parts],
                             "skipped": {s: r["skipped"] for s, r in res.items() if "skipped" in r},
                             "output": args.output, "stillness": still}
        d.update({s: r["json"] for s, r in res.items() if "json" in r})
        print_json(d)
        return 0
    for s in ("accel", "gyro", "mag"):
        r = res[s]
        print("\n".join(r["lines"]) if "lines" in r else f"{s}: not calibrated ({r['skipped']})")
    if args.output:
        print(f"wrote {args.output}: " + ", ".join(_part_name(s, parts[s]) for s in ORDER if s in parts))
    return 0


def _part_name(sensor: str, part) -> str:
    th = part.thermal or {}
    tw = ", thermal terms" if th.get("order") or th.get("scale_poly") is not None else ""
    if sensor != "gyro":
        return f"{sensor} ({part.model}{tw})"
    extra = [w for k, w in (("matrix", "K"), ("g_sens_dps_per_g", "G")) if k in part.params]
    return "gyro (bias" + "".join(f", {w}" for w in extra) + tw + ")"


def fit_all(args, rec, progress=None) -> Dict[str, Dict[str, Any]]:
    """sensor -> {part (SensorCal for the file), json, lines, thermal} or {skipped: why}; and
    under "stillness" the still-pose detection the parts share (calibrate --json's object)."""
    out: Dict[str, Dict[str, Any]] = {}
    poses = pieces = None
    if rec.acc is not None:
        from .offline import still_poses
        poses, pieces = still_poses(args, rec)
        if progress:
            progress(f"imucald: {len(poses)} still poses")
    out["accel"], acc_fit = _accel(args, rec, poses, pieces, progress)
    out["mag"], mag_fit = _mag(args, rec, progress)
    out["gyro"] = _gyro(args, rec, poses, pieces, acc_fit, mag_fit, progress)
    if poses is not None and poses.detector is not None:
        # the still-pose detection the parts share, once (said too when no part could use it)
        from .offline import stillness_json
        out["stillness"] = stillness_json(poses.detector)
    return out


def _unusable(x, sensor: str, absent: str):
    """Why ``sensor``'s columns ``x`` cannot be calibrated (``absent`` when there are none, a
    dead or stuck axis: fitting/inputs.stuck_columns), or None."""
    from ..fitting.inputs import stuck_columns, stuck_message
    if x is None:
        return absent
    stuck = stuck_columns(x, sensor)
    return stuck_message(stuck) if stuck else None


def _accel(args, rec, poses, pieces, progress):
    from ..fitting.fit import fit_norm
    from ..fitting.noise.colour import pose_colour_inflation
    from ..specs import BOARDS
    from .offline import DEFAULT_MODEL, check_rest_norms, file_part, one_orientation
    from .thermal import fit_thermal, pieces_colour_inflation, thermal_json, thermal_lines
    why = _unusable(rec.acc, "accel", "no accelerometer columns (ax, ay, az)")
    if why:
        return {"skipped": why}, None
    if not len(poses):
        # why none (the quiet windows' scatter, the quiet stretches rejected), as --sensor accel says
        from ..fitting.stillness.poses import no_still_message
        return {"skipped": no_still_message("", poses.detector, 0, rec.acc)}, None   # the file: in the error
    why = one_orientation(poses)
    if why:
        return {"skipped": why}, None
    if len(poses) < 10:
        return {"skipped": f"only {len(poses)} still poses found; the 9-parameter model needs at least "
                           f"10 (about 25 recommended), well spread over the sphere"}, None
    check_rest_norms(args.input, poses)
    model = DEFAULT_MODEL["accel"]
    if progress:
        progress(f"imucald: accel: fitting {model} with {args.method}")
    kw = {"progress": progress} if args.method == "ga-paper" and progress else {}
    chip = BOARDS.get(poses.meta.get("board", ""), (None,))[0]
    from ..fitting.noise.posecov import allan_still_needed
    infl = None
    if allan_still_needed((poses.noise or {}).get("accel")):    # not counted twice (fitting/noise/posecov.py)
        infl, _ = pose_colour_inflation(rec.t, rec.acc, rec.rate_hz, poses.t0, poses.t1, poses.n)
    cal = fit_norm(poses.acc, model, args.method, pose_cov=poses.acc_cov, rng=args.seed, chip=chip,
                   noise_inflation=infl, temp_c=poses.temp, **kw)
    tf = None
    if args.method != "ga-paper":
        tf = fit_thermal("accel", pieces, cal, chip, pieces_colour_inflation(rec, poses, pieces),
                         args.thermal_min_span, args.seed)
    d = cal.to_json()
    lines = _print_lines("accel", cal)
    part = file_part(cal, tf)
    if tf is not None:
        d["thermal"] = thermal_json("accel", tf, part)
        lines += thermal_lines("accel", tf, part)
    return {"part": part, "json": d, "lines": lines, "thermal": tf}, cal


def _mag(args, rec, progress):
    from ..fitting.magcal import calibrate_rotation, flat_message, rotation_json, rotation_lines, unit_problem
    from .offline import DEFAULT_MODEL, file_part
    from .thermal import thermal_json, thermal_lines
    why = _unusable(rec.mag, "mag", "no magnetometer columns (mx, my, mz)")
    if why:
        return {"skipped": why}, None
    model = DEFAULT_MODEL["mag"]
    if progress:
        progress(f"imucald: mag: {len(rec)} rows; thinning over the sphere and fitting {model} "
                 f"with {args.method}")
    res = calibrate_rotation(rec.mag, model, args.method, rng=args.seed, temp_c=rec.temp,
                             thermal_min_span_c=args.thermal_min_span, name=args.input, t_s=rec.t)
    why = unit_problem(res)
    if why:
        return {"skipped": why}, None
    d = rotation_json(res)
    if not res["determined"]:
        return {"skipped": flat_message(res), "json": d}, None
    tf = res.get("thermal")
    lines = _print_lines("mag", res["calibration"]) + rotation_lines(res)
    part = file_part(res["calibration"], tf)
    if tf is not None:
        d["thermal"] = thermal_json("mag", tf, part)
        lines += thermal_lines("mag", tf, part)
    return {"part": part, "json": d, "lines": lines, "thermal": tf}, res["calibration"]


def _gyro(args, rec, poses, pieces, acc_fit, mag_fit, progress) -> Dict[str, Any]:
    from ..fitting.fit import fit_gyro_bias
    from .gyrorot import file_line, fit_rotations, rotation_json, rotation_lines
    from .offline import DEFAULT_MODEL, file_part
    from .thermal import fit_thermal, thermal_json, thermal_lines
    why = _unusable(rec.gyro, "gyro", "no gyro columns (gx, gy, gz)")
    if why:
        return {"skipped": why}
    if poses is None or len(poses) == 0:
        return {"skipped": "no still poses found (the gyro bias needs at least one, found by the "
                           "accelerometer's stillness)"}
    model = DEFAULT_MODEL["gyro"]
    cal = fit_gyro_bias(poses.gyro, poses.n, poses.gyro_cov, model, None, rng=args.seed)
    if progress:
        progress("imucald: gyro: bias from the still poses; scale, misalignment and g-sensitivity "
                 "from the rotations between them")
    # a magnetometer part not determined above is not fitted again (nor warned about twice)
    rot, why = fit_rotations(rec, poses, args, pieces, acc_cal=acc_fit,
                             mag_cal=mag_fit if mag_fit is not None else False)
    tf = None
    if args.method != "ga-paper":
        tf = fit_thermal("gyro", pieces, cal, None, None, args.thermal_min_span, args.seed)
    part = file_part(cal, tf, rot)
    d = cal.to_json()
    d["rotations"] = rotation_json(rot, why)
    d["file"] = {"bias_dps": part.params["bias_dps"].tolist(), "matrix": "matrix" in part.params,
                 "g_sens_dps_per_g": "g_sens_dps_per_g" in part.params}
    lines = _print_lines("gyro", cal) + rotation_lines(rot, why) + [file_line(part)]
    if tf is not None:
        d["thermal"] = thermal_json("gyro", tf)
        lines += thermal_lines("gyro", tf)
    return {"part": part, "json": d, "lines": lines, "thermal": tf}


def _print_lines(sensor: str, cal) -> List[str]:
    """The lines ``calibrate --sensor SENSOR`` prints for a fit (offline.print_cal)."""
    import contextlib
    import io
    from .offline import print_cal
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        print_cal(sensor, cal)
    return buf.getvalue().splitlines()


def _temperature_range(res) -> Optional[tuple]:
    """The span of temperatures the parts' thermal terms were fitted over (their union)."""
    tfs = [r["thermal"] for r in res.values() if r.get("thermal") is not None and "part" in r]
    if not tfs:
        return None
    return (round(min(t.t_min_c for t in tfs), 2), round(max(t.t_max_c for t in tfs), 2))


def _write(path: str, meta, res, parts) -> None:
    from ..calibration import build_calibration, save
    try:
        save(build_calibration(parts, meta=meta, temperature_range_c=_temperature_range(res)), path)
    except OSError as e:            # disk full 74, cannot create 73 (errors.write_failure)
        raise write_failure(e, "--output", path) from None


__all__: List[str] = ["cmd_calibrate_all", "fit_all"]
