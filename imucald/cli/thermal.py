"""The thermal terms offline: ``imucald calibrate`` fits them when the recording spans
enough temperature (fitting/thermal/terms.py chooses the order and says why), and
``imucald apply`` writes a recording corrected by a calibration file (so that ``gap``
can be run on the corrected data: the loop of README "Closing the loop")."""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from ..errors import UserError, write_failure
from ._common import eprint

UNIT = {"accel": ("g", "mg", 1e3), "gyro": ("dps", "deg/s", 1.0), "mag": ("gauss", "mG", 1e3)}


def fit_thermal(sensor: str, poses, fit, chip: Optional[str], infl, min_span_c: float, seed):
    """The thermal fit of ``sensor`` on the still poses (None: no temperatures), started
    from the constant fit ``fit`` (fitting.fit.FitResult).  From a recording the poses are the
    detector's pieces (fitting.stillness.poses.poses_and_pieces), not the joined placements.
    Below ``min_span_c`` a constant only, as before; when the terms would be chosen there had
    the span been enough (the same held-out test), the note says so and how to fit them (a
    cold review's 9.5 degC warm-up: "constant only" while the constant missed the truth by
    3 standard errors and a term closed the scatter)."""
    tf = _fit_thermal(sensor, poses, fit, chip, infl, min_span_c, seed)
    if tf is None or tf.order > 0 or tf.scale_poly is not None or tf.t_max_c - tf.t_min_c >= min_span_c:
        return tf
    alt = _fit_thermal(sensor, poses, fit, chip, infl, 0.0, seed)
    if alt is not None and (alt.order > 0 or alt.scale_poly is not None):
        span = tf.t_max_c - tf.t_min_c
        tf.note += (f"; over these {span:.1f} degC the held-out test would choose {alt.note.split(':')[0]}"
                    f"{' with a scale term' if alt.scale_poly is not None else ''} "
                    f"({alt.note.split(': ', 1)[-1]}): --thermal-min-span {np.floor(span * 10) / 10:g} fits it")
    return tf


def _fit_thermal(sensor: str, poses, fit, chip: Optional[str], infl, min_span_c: float, seed):
    if poses.temp is None or not np.any(np.isfinite(poses.temp)):
        return None
    from ..fitting.thermal.terms import fit_bias_series, fit_norm_thermal
    if sensor == "gyro":
        var = np.einsum("nii->ni", poses.gyro_cov) if poses.gyro_cov is not None else np.full((len(poses), 3), 1e-4)
        return fit_bias_series(poses.temp, poses.gyro, np.maximum(var, 1e-12), min_span_c, rng=seed)
    if sensor == "mag":             # a pose file's magnetometer means (recordings: fitting/magcal.py)
        return None
    from ..fitting.fit import accel_prior
    from ..fitting.models.registry import get_model
    from ..fitting.judging.uncertainty import residual_variance
    m = get_model(fit.model)
    cov = poses.acc_cov if sensor == "accel" else poses.mag_cov
    if cov is None:
        var = np.full(len(poses), fit.noise ** 2)
    else:
        k = np.ones(len(poses)) if infl is None else np.broadcast_to(np.asarray(infl, float), (len(poses),))
        var = residual_variance(m, fit.theta, poses.acc if sensor == "accel" else poses.mag,
                                cov * k[:, None, None])
    prior = accel_prior(m, chip) if sensor == "accel" else None
    x = poses.acc if sensor == "accel" else poses.mag
    if not np.any(np.isfinite(poses.temp) & (np.asarray(var) > 0)):
        return None     # no within-pose deviations (a pose file of bare means): nothing to weight by
    return fit_norm_thermal(m, x, var, poses.temp, fit.theta, prior, min_span_c, scale=sensor == "accel",
                            rng=seed)


def pieces_colour_inflation(rec, poses, pieces):
    """The accelerometer's coloured-noise inflation of each piece (fitting/noise/colour.py), read from
    the Allan model of the longest pose, as the constant fit's is."""
    from ..fitting.noise.colour import colour_inflation_per_pose
    if len(poses) == 0 or len(pieces) == 0 or rec.temp is None:
        return None         # (no temperatures: no thermal fit to weigh)
    i = int(np.argmax(poses.t1 - poses.t0))
    i0, i1 = np.searchsorted(rec.t, [poses.t0[i], poses.t1[i]])
    return colour_inflation_per_pose(rec.acc[i0:i1], rec.rate_hz, pieces.n / rec.rate_hz)[0]


def moves_params(tf) -> bool:
    """Whether the thermal terms change the parameters the file holds (:func:`thermal_part`:
    refitted with the terms, at ``t_ref_c``) from the constant fit's, which averages over the
    temperatures the poses were held at."""
    return tf is not None and (tf.order > 0 or tf.scale_poly is not None)


def thermal_lines(sensor: str, tf, part=None) -> List[str]:
    """What was chosen and why, for ``calibrate``'s text output; with ``part`` (the file's,
    :func:`thermal_part`) of an accelerometer or magnetometer whose parameters the terms
    moved, those parameters too (the gyro's file line says its bias: gyrorot.file_line)."""
    u, shown, k = UNIT[sensor]
    out = [f"  thermal ({tf.t_min_c:.1f}..{tf.t_max_c:.1f} degC, about {tf.t_ref_c:.1f} degC): {tf.note}"]
    for j in range(tf.order):
        row = ", ".join(f"{v * k:+.4g}+-{s * k:.2g}" for v, s in zip(tf.bias_poly[j], tf.bias_poly_stderr[j]))
        out.append(f"    bias (T - {tf.t_ref_c:.1f})^{j + 1}: [{row}] {shown}/degC^{j + 1}")
    if tf.scale_poly is not None:
        row = ", ".join(f"{v * 1e6:+.1f}+-{s * 1e6:.1f}" for v, s in zip(tf.scale_poly[0], tf.scale_poly_stderr[0]))
        out.append(f"    scale (T - {tf.t_ref_c:.1f}): [{row}] ppm/degC")
    if tf.inflation > 1.05:
        out.append(f"    (variances inflated x{tf.inflation:.2f}: scatter the smoothest curve leaves)")
    if part is not None and sensor != "gyro" and moves_params(tf):
        out.append(f"  in the calibration file (-o), fitted with these terms, at {tf.t_ref_c:.1f} degC "
                   f"(the fit above is constant over the temperatures):")
        row = lambda a, f: "[" + ", ".join(f.format(float(x)) for x in np.ravel(a)) + "]"
        for g, v in part.params.items():
            out.append(f"    {g:<16} {row(v, '{:+.6f}')}  +- {row(part.stderr[g], '{:.2e}')}")
    return out


def thermal_json(sensor: str, tf, part=None):
    """calibrate --json's ``thermal``; with ``part`` as in :func:`thermal_lines`, the file's
    parameters and standard errors under ``file_params`` and ``file_stderr``."""
    d = tf.to_thermal(UNIT[sensor][0])
    d = {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}
    d["variants"] = tf.variants
    d["inflation"] = tf.inflation
    if part is not None and sensor != "gyro" and moves_params(tf):
        d["file_params"] = {g: np.asarray(v, float).tolist() for g, v in part.params.items()}
        d["file_stderr"] = {g: np.asarray(v, float).tolist() for g, v in part.stderr.items()}
    return d


def thermal_part(sensor: str, fit, tf):
    """The calibration part of ``fit`` with the thermal terms (its parameters then the
    ones at t_ref_c)."""
    from dataclasses import replace             # with calibration's: only where a part is made
    from ..calibration import SensorCal
    sc = SensorCal.from_fit(fit)
    if tf is None:
        return sc
    th = tf.to_thermal(UNIT[sensor][0])
    if tf.order == 0 and tf.scale_poly is None:
        return replace(sc, thermal=th)
    if sensor == "gyro":
        return SensorCal("gyro", "bias", {"bias_dps": np.asarray(tf.base, float)},
                         {"bias_dps": np.asarray(tf.base_stderr, float)}, {}, sc.method, sc.quality, th)
    if sensor == "accel":
        a = SensorCal.accel(fit.model, tf.base, tf.base_stderr, sc.method, sc.quality, sc.flags)
        return replace(a, thermal=th)
    from ..fitting.models.registry import get_model
    from ..fitting.models.mag import mag_report
    m = get_model(fit.model)
    p, se = mag_report(m, tf.base, tf.cov[:m.k, :m.k])
    arr = lambda d: {k: np.asarray(v, float) for k, v in d.items()}
    return SensorCal("mag", fit.model, arr(p), arr(se), {}, sc.method, sc.quality, th)


# --- apply ---------------------------------------------------------------------------------

def _swapped(cal_path: str, rec_path: str) -> bool:
    """A calibration file given where the recording goes, and another file (a recording, a
    table) where the calibration goes: the loader's own message ("expected a mapping", "more
    than 1024 KiB") did not say that the two were the other way round."""
    def first(path):
        try:
            with open(path, "rb") as fh:
                return fh.readline(64)
        except OSError:
            return b""
    return (not first(cal_path).startswith(b"# imucald calibration")
            and first(rec_path).startswith(b"# imucald calibration"))


def cmd_apply(args) -> int:
    """Correct a recording with a calibration file: every sensor the file has a part for,
    each sample at its own temperature (thermal terms)."""
    from ..calibration import load
    from ..files.recording import Recording, write_recording
    from ._common import input_recording
    if getattr(args, "orientation", None):          # the extra missing: say so before writing
        from ..orientation import load_vqf
        load_vqf()
    try:
        cal = load(args.calibration)
    except UserError:
        if _swapped(args.calibration, args.recording):
            raise UserError(f"{args.calibration} is not a calibration and {args.recording} is one: "
                            f"the calibration comes first (imucald apply {args.recording} "
                            f"{args.calibration} -o ...)") from None
        raise
    rec = input_recording(args, args.recording)
    board = rec.meta.get("board", "unknown")
    why = None if "unknown" in (board, cal.board) else cal.mismatch(board)
    if why:
        raise UserError(f"{args.calibration}: {why} ({args.recording}); use a calibration made on this board")
    T = rec.temp
    if T is None and any(p is not None and p.thermal for p in (cal.accel, cal.gyro, cal.mag)):
        eprint(f"imucald: {args.recording}: no temp column: thermal terms applied at their reference "
               f"temperature")
    got = []
    acc, gyro, mag = rec.acc, rec.gyro, rec.mag
    if acc is not None and cal.accel is not None:
        acc, _ = cal.apply_accel(acc, T), got.append("accel")
    if gyro is not None and cal.gyro is not None:
        # the g-sensitivity term takes the calibrated specific force (acc, corrected above)
        has_g = "g_sens_dps_per_g" in cal.gyro.params
        if has_g and acc is None:
            raise UserError(f"{args.calibration}: the gyro part has a g-sensitivity term and "
                            f"{args.recording} has no accelerometer columns; record ax,ay,az too")
        if has_g and cal.accel is None:
            eprint(f"imucald: {args.calibration} has no accelerometer part: the gyro's g-sensitivity "
                   f"takes the recording's raw accelerometer")
        gyro, _ = cal.apply_gyro(gyro, np.full(len(rec), np.nan) if T is None else T,
                                 acc if has_g else None), got.append("gyro")
    if mag is not None and cal.mag is not None:
        mag, _ = cal.apply_mag(mag, T), got.append("mag")
    if not got:
        raise UserError(f"{args.calibration}: no part for a sensor of {args.recording}")
    meta = dict(rec.meta)
    meta["corrected"] = f"{','.join(got)} by calibration {cal.id} ({args.calibration})"
    out = Recording(rec.t, acc, gyro, mag, rec.temp, meta)
    try:
        write_recording(out, args.output, "-o")
    except OSError as e:
        raise write_failure(e, "-o", args.output) from None
    eprint(f"imucald: wrote {args.output}: {len(rec)} samples, {', '.join(got)} corrected")
    if getattr(args, "orientation", None):          # issue 26: cli/orientation.py
        from .orientation import write_orientation
        h = write_orientation(out, cal, args.orientation, args.recording)
        eprint(f"imucald: wrote {args.orientation}: orientation of every sample (heading {h})")
    return 0
