"""``calibrate --sensor gyro`` on a recording: scale, misalignment and g-sensitivity from
the rotations between the still poses (fitting/gyro/rotations.py), printed, as JSON, and in the
calibration file."""
from __future__ import annotations

from typing import Dict, List, Optional

import numpy as np

_AX = "xyz"


#: the held-out gravity direction after a rotation, deg (the mean over rotations, with the
#: correction the file keeps): a gyro within its datasheet scale (+-3 %) and misalignment
#: (+-2 %) misses by at most ~6 deg after a half turn (a 7 %-wrong --nominal-scale: 6.0 deg
#: before K, 0.8 after); beyond this, the gyro's units, axes or a sign disagree with the
#: accelerometer's (a 2x scale: 86 deg).  Measured on simulated sessions (25 poses, 4-s holds):
#: no warning on 72 read right (MPU-6050, 9DOF, MPU-9250; 12 seeds, with and without 1.5 deg/s
#: of tremor), a warning on 30 of 30 read 2x or with X's sign flipped; none on the Xsens file
ROTATION_DISAGREE_DEG = 15.0


def disagreement(fit) -> Optional[str]:
    """A warning when the gyro's rotations between poses miss the accelerometer's gravity
    directions by more than ROTATION_DISAGREE_DEG on average (held out), else None."""
    h = {} if fit is None else fit.heldout
    if "cal_mean_deg" not in h:
        return None
    miss = h["cal_mean_deg"] if h.get("better") else h["raw_mean_deg"]
    if miss <= ROTATION_DISAGREE_DEG:
        return None
    return (f"the gyro's rotations between poses miss the accelerometer's gravity directions by "
            f"{miss:.0f} deg on average (held out; a gyro within its datasheet misses by a few): its "
            f"scale (--nominal-scale gyro=N, counts per deg/s), its axes or a sign disagree with the "
            f"accelerometer's (a wrong scale makes the bias written wrong too), or it saturated in "
            f"the turns (a raw table gives no range to leave those out)")


def fit_rotations(rec, poses, args, pieces=None, acc_cal=None, mag_cal=None, slices=None):
    """(GyroRotFit or None, why none): the accelerometer calibrated on ``poses`` (triangular9,
    MAP with the datasheet prior; or ``acc_cal``, a FitResult already fitted on them, as
    ``calibrate --sensor all`` shares its accelerometer part) with its thermal terms fitted
    on ``pieces`` (the detector's still pieces, each at its own temperature), then the
    rotations between the recording's still intervals (found with the same detector
    settings).  mag_cal: the magnetometer's rotation-cloud FitResult when already fitted
    (None: fitted here, mag_sym; False: tried, none: gravity alone is the reference); slices:
    the poses' sample ranges (None: read back from ``poses``, :func:`pose_slices`, else the
    detector is run again with the same settings)."""
    from ..fitting.fit import fit_norm
    from ..fitting.gyro.rotations import fit_gyro_rotations
    from ..fitting.stillness.poses import detect_static
    from ..specs import BOARDS, GYRO
    if rec is None or rec.acc is None or rec.gyro is None:
        return None, "needs a recording with accelerometer and gyro columns"
    if len(poses) < 10:
        return None, f"{len(poses)} still poses: the accelerometer needs 10 to give gravity directions"
    from ..fitting.inputs import stuck_columns, stuck_message
    stuck = stuck_columns(rec.acc, "accel")
    if stuck:      # gravity, the rotations' reference, cannot be read along that axis
        return None, f"the accelerometer's {stuck_message(stuck)}: no gravity direction to refer the rotations to"
    chips = BOARDS.get(rec.meta.get("board", ""), (None, None, None))
    if acc_cal is None:
        acc_cal = fit_norm(poses.acc, "triangular9", "lm", pose_cov=poses.acc_cov, chip=chips[0],
                           heldout=False)      # only its theta and covariance are used
    acc, theta, tnote = _gravity_reference(rec, poses, pieces, acc_cal, chips[0], args.seed)
    if slices is None:
        slices = pose_slices(rec, poses)
    if slices is None:
        slices = detect_static(rec.t, rec.acc, rec.gyro, rec.rate_hz, window_s=args.window_s,
                               k=args.threshold_k, min_still_s=args.min_still_s)
    rng = rec.meta.get("gyro_range_dps")
    try:
        rng = float(rng) if rng is not None else (GYRO[chips[1]].range_dps if chips[1] in GYRO else None)
    except ValueError:
        rng = None
    frame = (acc_cal.model, theta, acc_cal.info["covariance"])
    fit = fit_gyro_rotations(rec.t, rec.gyro, acc, slices, chip=chips[1], range_dps=rng, acc_frame=frame)
    if fit is None:
        return None, _too_few_rotations(rec, slices, rng)
    fit.reference += tnote
    mag = _calibrated_mag(rec, args.seed, mag_cal)
    if mag is not None:     # the field direction too, when it agrees with its noise model
        fm = fit_gyro_rotations(rec.t, rec.gyro, acc, slices, mag=mag, chip=chips[1], range_dps=rng,
                                acc_frame=frame)
        if fm is not None and fm.excess_scatter == 1.0:
            fm.reference += tnote
            return _warned(fm, args), ""
        fit.reference += " (field directions left out: they scatter beyond their noise)"
    return _warned(fit, args), ""


def _too_few_rotations(rec, slices, range_dps) -> str:
    """Why no rotation fit: how many rotations were clean of how many, and what left the
    others out (it said "fewer than 3 clean rotations" only: a logger losing samples in
    every turn could not tell why)."""
    from ..fitting.gyro.rotations import rotation_windows
    slices = [s for s in slices if s.stop - s.start >= 2]
    wins, left = rotation_windows(rec.t, rec.gyro, slices, range_dps)
    why = [f"{v} {k}" for k, v in (("with samples lost in the motion (time steps longer than the "
                                     "rate's)", left["gap"]),
                                    ("with a gyro sample at its range's rail", left["saturated"])) if v]
    return (f"{len(wins)} clean rotations between consecutive still poses, 3 needed"
            + (f" (of {max(len(slices) - 1, 0)}; left out: {', '.join(why)})" if why else ""))


def _warned(fit, args):
    """``fit``, after a warning on stderr when it disagrees with gravity (:func:`disagreement`):
    judged on the fit whose correction the file keeps."""
    warn = disagreement(fit)
    if warn:
        from ._common import eprint
        eprint(f"imucald: warning: {getattr(args, 'input', 'the recording')}: {warn}")
    return fit


def pose_slices(rec, poses) -> Optional[List[slice]]:
    """The sample ranges of ``poses`` (found in ``rec``): each pose starts at its t0 and holds
    n samples; None when that does not give back every pose's t0 and t1 (repeated time
    stamps), and the detector is then run again."""
    i0 = np.searchsorted(rec.t, poses.t0, "left")
    i1 = i0 + np.asarray(poses.n, int)
    if len(i0) and (i1[-1] > len(rec.t) or np.any(rec.t[i0] != poses.t0) or np.any(rec.t[i1 - 1] != poses.t1)):
        return None
    return [slice(int(a), int(b)) for a, b in zip(i0, i1)]


def _gravity_reference(rec, poses, pieces, acc_cal, chip, seed):
    """(calibrated accelerometer (n, 3), the theta of the frame, a note for the reference):
    the constant fit ``acc_cal`` plus the thermal terms the held-out test supports on the
    still pieces, each sample corrected at its own temperature.  Any span is tried here (the
    order test guards against fitting noise): a bias drifting 0.7 mg/degC over 6 degC turns
    the gravity directions by ~0.2 deg, far beyond a gyro rotation's noise."""
    from ..fitting.models.registry import get_model
    from .thermal import fit_thermal, pieces_colour_inflation, thermal_part
    tf = None
    if pieces is not None and rec.temp is not None and len(pieces) >= 10:
        tf = fit_thermal("accel", pieces, acc_cal, chip, pieces_colour_inflation(rec, poses, pieces), 0.0, seed)
    if tf is None or not (tf.order or tf.scale_poly is not None):
        A, c = get_model(acc_cal.model).affine(acc_cal.theta)
        return rec.acc @ np.asarray(A, float).T + np.asarray(c, float), acc_cal.theta, ""
    part = thermal_part("accel", acc_cal, tf)
    return (part.apply(rec.acc, rec.temp), np.asarray(tf.base, float),
            f" (accelerometer with its thermal terms, {tf.name}, at each sample's temperature)")


def _calibrated_mag(rec, seed, cal=None):
    """The recording's magnetometer corrected by its own rotation-cloud calibration
    (``cal``, else mag_sym fitted here), or None (no magnetometer, ``cal`` False: tried by
    the caller and not determined, or the cloud does not determine one)."""
    if rec.mag is None or cal is False:
        return None
    from ..calibration import SensorCal
    if cal is None:
        from ..fitting.magcal import calibrate_rotation
        res = calibrate_rotation(rec.mag, "mag_sym", "lm", rng=seed)
        if not res["determined"]:
            return None
        cal = res["calibration"]
    return SensorCal.from_fit(cal).apply(rec.mag)


def _row(v, fmt):
    return "[" + ", ".join(fmt.format(x) for x in v) + "]"


def rotation_lines(fit, why: str = "") -> List[str]:
    if fit is None:
        return [f"gyro scale/misalignment: not fitted ({why})"]
    K, se = fit.matrix, fit.matrix_se
    out = [f"gyro scale/misalignment from {fit.rotations} rotations between still poses "
           f"(reference: {fit.reference}; left out: {fit.left_out['saturated']} saturated, "
           f"{fit.left_out['gap']} with lost samples)",
           "  matrix K, corrected = K (raw - bias - G a), row by row:"]
    out += [f"    {_row(K[i], '{:+.6f}')}  +- {_row(se[i], '{:.1e}')}" for i in range(3)]
    out.append("  scale error %: " + ", ".join(
        f"{a} {(K[i, i] - 1) * 100:+.3f} +- {se[i, i] * 100:.3f}" for i, a in enumerate(_AX)))
    und = [f"K{_AX[k // 3]}{_AX[k % 3]}" for k, f in enumerate(fit.matrix_flags) if f != "determined"]
    if und:
        out.append(f"  not determined by these rotations (prior kept): {', '.join(und)}")
    if fit.g_sens_used:
        out.append("  g-sensitivity G, deg/s per g (from the still poses), row by row:")
        out += [f"    {_row(fit.g_sens[i], '{:+.4f}')}  +- {_row(fit.g_sens_se[i], '{:.1e}')}" for i in range(3)]
    else:
        out.append("  g-sensitivity: not determined by these poses (left out)")
    h = fit.heldout
    out.append(f"  noise model: chi2/dof {fit.chi2_dof:.2f}, excess scatter x{fit.excess_scatter:.2f}; "
               f"in-sample gravity-direction RMS {fit.rms_deg:.3f} deg")
    om = f"; {h['omitted']} omitted: {h['omitted_reason']}" if h.get("omitted") else ""
    if "cal_mean_deg" in h:
        out.append(f"  gravity direction at the next pose, held-out rotations ({h['folds']}-fold, "
                   f"{h['evaluated']} evaluated{om}): bias only mean {h['raw_mean_deg']:.3f} max "
                   f"{h['raw_max_deg']:.3f} deg; calibrated mean {h['cal_mean_deg']:.3f} max "
                   f"{h['cal_max_deg']:.3f} deg (p = {h['p_value']:.2g})")
    else:
        out.append(f"  gravity direction at the next pose, held-out rotations: none evaluated{om}")
    if not h.get("better"):
        out.append(f"  K and G not used: {h.get('why', 'not better than bias only')}; "
                   f"the calibration file keeps the gyro bias only")
    return out


def file_line(part) -> str:
    """The gyro bias the calibration file holds (the rotation fit's intercept when G is
    used: the pose mean above includes G a), so that text, JSON and file agree."""
    with_ = [w for k, w in (("matrix", "K"), ("g_sens_dps_per_g", "G")) if k in part.params]
    th = part.thermal or {}
    if "g_sens_dps_per_g" in part.params:
        src = "intercept of the rotation fit, G a removed"
    elif len(np.asarray(th.get("bias_poly_dps", []))):
        src = f"the thermal fit's, at its reference {th['t_ref_c']:.2f} degC"
    elif th:
        src = "the still pieces' mean of the thermal fit, constant only"
    else:
        src = "the still-pose mean above"
    return (f"  in the calibration file (-o): bias_dps {_row(part.params['bias_dps'], '{:+.6f}')} deg/s ({src})"
            + (f", with {' and '.join(with_)}" if with_ else ", bias only"))


def rotation_json(fit, why: str = "") -> Dict[str, object]:
    if fit is None:
        return {"fitted": False, "reason": why}
    return {"fitted": True, "rotations": fit.rotations, "left_out": dict(fit.left_out),
            "reference": fit.reference, "matrix": fit.matrix.tolist(), "matrix_stderr": fit.matrix_se.tolist(),
            "matrix_flags": list(fit.matrix_flags), "g_sens_dps_per_g": fit.g_sens.tolist() if fit.g_sens_used
            else None, "g_sens_stderr": fit.g_sens_se.tolist() if fit.g_sens_used else None,
            "g_sens_flags": list(fit.g_sens_flags), "bias_dps": fit.bias_dps.tolist(),
            "chi2_dof": fit.chi2_dof, "excess_scatter": fit.excess_scatter, "rms_deg": fit.rms_deg,
            "heldout": dict(fit.heldout), "used": bool(fit.heldout.get("better")),
            **({} if fit.heldout.get("better") else
               {"not_used_reason": fit.heldout.get("why", "not better than bias only") +
                "; the calibration file keeps the gyro bias only"})}


def with_rotations(part, fit):
    """The gyro part with K (and G, with the bias intercept that goes with it) added, when
    they beat bias only on held-out rotations (else the part as is).  G is left out when
    the part carries a thermal bias polynomial (fitted without G)."""
    from dataclasses import replace
    if fit is None or not fit.heldout.get("better"):
        return part             # K (and G) only when they beat bias only on held-out rotations
    p, se, fl = dict(part.params), dict(part.stderr), dict(part.flags)
    p["matrix"], se["matrix"], fl["matrix"] = fit.matrix.ravel(), fit.matrix_se.ravel(), tuple(fit.matrix_flags)
    th = part.thermal
    poly = None if not th else th.get("bias_poly_dps")
    if fit.g_sens_used and (poly is None or not len(np.asarray(poly))):
        p["g_sens_dps_per_g"], se["g_sens_dps_per_g"] = fit.g_sens.ravel(), fit.g_sens_se.ravel()
        fl["g_sens_dps_per_g"] = tuple(fit.g_sens_flags)
        p["bias_dps"], se["bias_dps"] = fit.bias_dps.copy(), fit.bias_se_dps.copy()
    q = {**part.quality, "rotations": int(fit.rotations),
         "heldout_gravity_mean_deg": fit.heldout["cal_mean_deg"],
         "heldout_gravity_max_deg": fit.heldout["cal_max_deg"]}
    return replace(part, params=p, stderr=se, flags=fl, quality=q)
