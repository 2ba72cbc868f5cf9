"""Validation of calibration documents: every check raises one line naming the key
path, the problem and the fix (used by :mod:`imucald.calibration`)."""
from __future__ import annotations

import math
import re
from typing import Any, Dict, Mapping, Tuple

import numpy as np

from ..errors import UserError, snippet

#: per-parameter flags a fit may report
FLAGS = ("determined", "undetermined", "at_bound", "at_bound+undetermined")


class CalibrationError(UserError):
    """A calibration document that fails validation (one line: key path, problem, fix)."""


def fail_check(path: str, problem: str, fix: str):
    """The one-line error: the key path and the problem quoted bounded and escaped (a file
    that is not a calibration, e.g. a symlink to /etc/shadow, must not be echoed)."""
    raise CalibrationError(f"{snippet(path, 60, quote=False)}: {snippet(problem, 120, quote=False)}; {fix}")


def check_keys(d: Mapping, path: str, required: set, optional: set) -> None:
    pre = f"{path}." if path else ""
    for k in d:
        if k not in required and k not in optional:
            fail_check(f"{pre}{k}", "unknown key", "allowed: " + ", ".join(sorted(required | optional)))
    for k in sorted(required):
        if k not in d:
            fail_check(f"{pre}{k}", "missing", "see docs/reference/calibration-file.md")


#: largest magnitude of a correction parameter: no sensor's scale, bias, hard iron or
#: thermal coefficient comes near it, and products of such values stay finite (1e308 loaded
#: before, and the correction gave inf and NaN)
PARAM_LIMIT = 1e6


def check_array(v: Any, path: str, shape, nullable: bool = False, nonneg: bool = False,
           limit: float = math.inf) -> np.ndarray:
    """A finite float array of the given length (0 scalar, -3 rows of 3, tuple exact),
    each |value| <= ``limit``."""
    def num(x):
        if x is None and nullable:
            return math.nan
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            fail_check(path, f"{x!r} is not a number", "write plain numbers")
        if not math.isfinite(x):
            fail_check(path, f"{x!r} is not finite", "write a finite number" + (" or null" if nullable else ""))
        if abs(x) > limit:
            fail_check(path, f"{x!r} is beyond {limit:g}", "no calibration holds such a value: recalibrate")
        if nonneg and x < 0:
            fail_check(path, f"{x!r} is negative", "a standard error is >= 0")
        return float(x)
    if isinstance(shape, tuple):
        want = shape
    else:
        want = () if shape == 0 else ((-1, 3) if shape == -3 else (shape,))
    if want == ():
        if isinstance(v, (list, tuple)):
            fail_check(path, f"expected one number, got a list of {len(v)}", "write a single number")
        return np.array(num(v))
    if not isinstance(v, (list, tuple)):
        fail_check(path, f"expected a list of {_describe(want)}, got {type(v).__name__}", "write [x, y, z]")
    if len(want) == 2:
        if not v or not all(isinstance(r, (list, tuple)) and len(r) == want[1] for r in v):
            fail_check(path, f"expected rows of {want[1]} numbers", "write [[x, y, z], ...]")
        return np.array([[num(x) for x in r] for r in v])
    if len(v) != want[0] or any(isinstance(x, (list, tuple)) for x in v):
        fail_check(path, f"expected {_describe(want)}, got {len(v)} items", f"give {want[0]} numbers")
    return np.array([num(x) for x in v])


def _describe(shape) -> str:
    return f"{shape[0]} numbers" if len(shape) == 1 and shape[0] > 0 else f"rows of {shape[-1]} numbers"


def check_flags(v: Any, path: str, n: int) -> Tuple[str, ...]:
    if not isinstance(v, (list, tuple)) or len(v) != n or not all(x in FLAGS for x in v):
        fail_check(path, f"{v!r} is not a list of {n} flags", "each one of " + ", ".join(FLAGS))
    return tuple(v)


def check_table(v: Any, path: str) -> Dict[str, Any]:
    if not isinstance(v, Mapping) or set(v) != {"columns", "rows"}:
        fail_check(path, "expected {columns: [...], rows: [[...], ...]}", "or leave it out")
    cols = v["columns"]
    if not isinstance(cols, list) or not all(isinstance(c, str) for c in cols):
        fail_check(f"{path}.columns", "expected a list of column names", "or leave poses_used out")
    rows = v["rows"]
    if not isinstance(rows, list):
        fail_check(f"{path}.rows", f"expected a list of rows, got {type(rows).__name__}", "or leave it out")
    lens = {len(r) for r in rows if isinstance(r, list)}
    if len(lens) == 1 and len(rows) > 1 and lens != {len(cols)}:
        fail_check(f"{path}.columns", f"names {len(cols)} columns, the rows have {lens.pop()}",
              "one name per column")
    out = [check_array(r, f"{path}.rows[{i}]", len(cols), nullable=True).tolist() for i, r in enumerate(rows)]
    return {"columns": list(cols), "rows": out}




def check_provisional(v: Any, path: str) -> Dict[str, Any]:
    """{poses, poses_for_final, missing_orientations}: a calibration applied before the
    pose set met the readiness targets (README: provisional calibrations)."""
    if not isinstance(v, Mapping):
        fail_check(path, f"expected a mapping, got {type(v).__name__}", "or leave it out (not provisional)")
    check_keys(v, path, {"poses", "poses_for_final", "missing_orientations"}, set())
    for k in ("poses", "poses_for_final"):
        if isinstance(v[k], bool) or not isinstance(v[k], int) or v[k] < 1:
            fail_check(f"{path}.{k}", f"{v[k]!r} is not a positive integer", "e.g. 10")
    m = v["missing_orientations"]
    if not isinstance(m, list) or not all(isinstance(x, str) and re.fullmatch(r"([+-][XYZ]){1,3} up", x)
                                          for x in m):
        fail_check(f"{path}.missing_orientations", f"{m!r} is not a list of orientation names",
              "e.g. ['-Z up', '+X+Y up']")
    return {"poses": v["poses"], "poses_for_final": v["poses_for_final"], "missing_orientations": list(m)}


#: the unit of a sensor's thermal bias polynomial (its key names carry it)
THERMAL_UNIT = {"accel": "g", "gyro": "dps", "mag": "gauss"}


def check_thermal(v: Any, path: str, sensor: str) -> Dict[str, Any]:
    """A part's ``thermal`` block: {order 0..3, t_ref_c, t_min_c <= t_ref_c <= t_max_c,
    bias_poly_<unit> (order rows of 3) with bias_poly_stderr_<unit>, accel: scale_poly
    (1 row) with scale_poly_stderr, note} (README: calibration file)."""
    unit = THERMAL_UNIT[sensor]
    bp, bs = f"bias_poly_{unit}", f"bias_poly_stderr_{unit}"
    if not isinstance(v, Mapping):
        fail_check(path, f"expected a mapping, got {type(v).__name__}", "or leave it out (no thermal terms)")
    opt = {bp, bs, "note"} | ({"scale_poly", "scale_poly_stderr"} if sensor == "accel" else set())
    check_keys(v, path, {"order", "t_ref_c", "t_min_c", "t_max_c"}, opt)
    order = v["order"]
    if isinstance(order, bool) or not isinstance(order, int) or not 0 <= order <= 3:
        fail_check(f"{path}.order", f"{order!r} is not an order 0..3", "e.g. order: 1")
    out: Dict[str, Any] = {"order": order}
    for k in ("t_min_c", "t_ref_c", "t_max_c"):
        out[k] = float(check_array(v[k], f"{path}.{k}", 0, limit=PARAM_LIMIT))
    if not out["t_min_c"] <= out["t_ref_c"] <= out["t_max_c"]:
        fail_check(f"{path}.t_ref_c", f"{out['t_ref_c']} is not within [t_min_c, t_max_c] = "
              f"[{out['t_min_c']}, {out['t_max_c']}]", "t_min_c <= t_ref_c <= t_max_c")
    for key, se, rows in ((bp, bs, order), ("scale_poly", "scale_poly_stderr", 1)):
        if key not in v and key == bp and order:
            fail_check(f"{path}.{bp}", "missing", f"order {order} needs {order} rows of 3 coefficients")
        if key in v:
            a = check_array(v[key], f"{path}.{key}", (rows, 3), limit=PARAM_LIMIT)
            if a.shape[0] != rows:
                fail_check(f"{path}.{key}", f"{a.shape[0]} rows for order {rows}", f"give {rows} rows of 3")
            out[key] = a
            if se in v:
                out[se] = check_array(v[se], f"{path}.{se}", (rows, 3), nullable=True, nonneg=True)
                if out[se].shape[0] != rows:
                    fail_check(f"{path}.{se}", f"{out[se].shape[0]} rows", f"give {rows} rows of 3")
        elif se in v:
            fail_check(f"{path}.{se}", f"without {key}", f"give {key} too, or neither")
    note = v.get("note", "")
    if not isinstance(note, str):
        fail_check(f"{path}.note", f"expected text, got {type(note).__name__}", "quote it")
    out["note"] = note
    return out
