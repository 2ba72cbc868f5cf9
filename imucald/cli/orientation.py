"""``imucald apply ... --orientation FILE``: the orientation of a corrected recording as a table.

The filter (imucald/orientation, the ``orientation`` extra) runs over the corrected samples at the
recording's rate, in the daemon's batch size, and is handed each still interval's gyro mean as
the interval ends, as the daemon does; the table gets one row per sample:
``t,qw,qx,qy,qz,lax,lay,laz,incl_std_deg,heading_std_deg`` (q body -> ENU, REP-103;
lin_acc gravity-free, body frame, g; heading_std_deg empty when the heading is arbitrary), after
``# `` lines naming the recording, the calibration and the heading reference.
"""
from __future__ import annotations

import io
import math
import os

import numpy as np

from ..errors import CannotCreate, UserError

__all__ = ["orientation_table", "write_orientation"]

COLUMNS = "t,qw,qx,qy,qz,lax,lay,laz,incl_std_deg,heading_std_deg"


def orientation_table(rec, cal, batch_s: float = 0.02):
    """(rows (n, 10) with NaN where unknown, heading reference) for a corrected recording."""
    from ..orientation import OrientationFilter
    from ..fitting.stillness.repeats import duplicated_rows
    from ..specs import ACCEL, GYRO, recording_chips
    if rec.acc is None or rec.gyro is None:
        raise UserError("--orientation needs accelerometer and gyro columns (ax..az, gx..gz)")
    rep = duplicated_rows(rec.t, [rec.acc, rec.gyro, rec.mag])  # a logger that wrote rows twice
    if rep.any() and "rate_hz" not in rec.meta:     # a headerless table: its distinct rows' rate
        from ..files.recording import Recording
        rate = Recording(rec.t[~rep]).rate_hz or rec.rate_hz
    else:
        rate = rec.rate_hz
    chips = recording_chips(rec.meta)
    spec, gspec = ACCEL.get(chips.get("accel", "")), GYRO.get(chips.get("gyro", ""))
    f = OrientationFilter(rate, rec.mag is not None,
                          None if spec is None else spec.noise_density_g_rthz * rate ** 0.5)
    f.use_gyro_range(gyro_range_dps(rec.meta, gspec), None if gspec is None else gspec.bias_tol_dps)
    f.use_calibration(cal, None if spec is None else spec.bias_tol_g,
                      None if gspec is None else gspec.bias_tol_dps,
                      None if gspec is None else (gspec.scale_tol, gspec.cross_axis_tol))
    n = len(rec)
    out = np.full((n, 10), np.nan)
    out[:, 0] = rec.t
    step = max(1, int(round(batch_s * rate)))
    heading = "arbitrary"
    ivs, k = _still_intervals(rec), 0
    for i in range(0, n, step):
        sl = slice(i, min(n, i + step))
        while k < len(ivs) and ivs[k][0] <= rec.t[sl.stop - 1]:    # closed by this batch's end
            f.still_interval(ivs[k][1], ivs[k][2])
            k += 1
        o = f.update(rec.acc[sl], rec.gyro[sl], None if rec.mag is None else rec.mag[sl], rep[sl])
        out[sl, 1:5], out[sl, 5:8] = o["q"], o["lin_acc_g"]
        out[sl, 8] = o["incl_std_deg"]
        if o["heading_std_deg"] is not None:
            out[sl, 9] = o["heading_std_deg"]
        heading = o["heading"]
    return out, heading


def gyro_range_dps(meta, gspec):
    """The gyro's full scale, deg/s: the recording's ``gyro_range_dps`` (a positive number),
    else its chip's datasheet default (imucald/specs.py), else None."""
    try:
        v = float(meta["gyro_range_dps"])
        if math.isfinite(v) and v > 0:
            return v
    except (KeyError, ValueError):
        pass
    return None if gspec is None else float(gspec.range_dps)


def _still_intervals(rec):
    """[(end s, mean gyro deg/s, its standard error deg/s)] of the recording's still intervals
    (the pieces imucald's detector cuts), in time order: what the daemon hands the filter as
    each one closes (orientation/filter.py still_interval); [] without a gyro or a still one."""
    if rec.gyro is None:
        return []
    import warnings
    from ..fitting.stillness.poses import poses_and_pieces
    try:
        with warnings.catch_warnings():         # the reader has said what the file holds
            warnings.simplefilter("ignore")
            pieces = poses_and_pieces(rec)[1]
    except UserError:
        return []
    if pieces.gyro is None or pieces.gyro_cov is None:
        return []
    se = np.sqrt(np.einsum("nii->ni", pieces.gyro_cov))
    return sorted(zip(pieces.t1.tolist(), pieces.gyro, se), key=lambda r: r[0])


def write_orientation(rec, cal, path: str, source: str) -> str:
    """Write the table atomically; returns the heading reference."""
    from ..files.atomic import atomic_write_text
    rows, heading = orientation_table(rec, cal)
    buf = io.StringIO()
    buf.write(f"# imucald orientation of {source} (calibration {cal.id}); q body -> ENU (REP-103); "
              f"heading {heading}{' (magnetic north)' if heading == 'magnetic' else ' (6D: no magnetometer)'}\n")
    buf.write(COLUMNS + "\n")
    fmt = ["%.6f"] + ["%.6f"] * 4 + ["%.5f"] * 3 + ["%.3g"] * 2
    for r in rows:
        buf.write(",".join("" if not np.isfinite(v) else (f % v) for f, v in zip(fmt, r)) + "\n")
    try:
        atomic_write_text(os.fspath(path), buf.getvalue())
    except OSError as e:
        raise CannotCreate(f"--orientation {path}: cannot write: {e.strerror}") from None
    return heading
