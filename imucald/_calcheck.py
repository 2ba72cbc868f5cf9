"""Validation of calibration documents: every check raises one line naming the key
path, the problem and the fix (used by :mod:`imucald.calibration`)."""
from __future__ import annotations

import math
import re
from typing import Any, Dict, Mapping, Tuple

import numpy as np

from .errors import UserError

#: per-parameter flags a fit may report
FLAGS = ("determined", "undetermined", "at_bound", "at_bound+undetermined")


class CalibrationError(UserError):
    """A calibration document that fails validation (one line: key path, problem, fix)."""


def _fail(path: str, problem: str, fix: str):
    raise CalibrationError(f"{path}: {problem}; {fix}")


def _keys(d: Mapping, path: str, required: set, optional: set) -> None:
    pre = f"{path}." if path else ""
    for k in d:
        if k not in required and k not in optional:
            _fail(f"{pre}{k}", "unknown key", "allowed: " + ", ".join(sorted(required | optional)))
    for k in sorted(required):
        if k not in d:
            _fail(f"{pre}{k}", "missing", "see README: calibration file")


def _array(v: Any, path: str, shape, nullable: bool = False, nonneg: bool = False) -> np.ndarray:
    """A finite float array of the given length (0 scalar, -3 rows of 3, tuple exact)."""
    def num(x):
        if x is None and nullable:
            return math.nan
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            _fail(path, f"{x!r} is not a number", "write plain numbers")
        if not math.isfinite(x):
            _fail(path, f"{x!r} is not finite", "write a finite number" + (" or null" if nullable else ""))
        if nonneg and x < 0:
            _fail(path, f"{x!r} is negative", "a standard error is >= 0")
        return float(x)
    if isinstance(shape, tuple):
        want = shape
    else:
        want = () if shape == 0 else ((-1, 3) if shape == -3 else (shape,))
    if want == ():
        if isinstance(v, (list, tuple)):
            _fail(path, f"expected one number, got a list of {len(v)}", "write a single number")
        return np.array(num(v))
    if not isinstance(v, (list, tuple)):
        _fail(path, f"expected a list of {_describe(want)}, got {type(v).__name__}", "write [x, y, z]")
    if len(want) == 2:
        if not v or not all(isinstance(r, (list, tuple)) and len(r) == want[1] for r in v):
            _fail(path, f"expected rows of {want[1]} numbers", "write [[x, y, z], ...]")
        return np.array([[num(x) for x in r] for r in v])
    if len(v) != want[0] or any(isinstance(x, (list, tuple)) for x in v):
        _fail(path, f"expected {_describe(want)}, got {len(v)} items", f"give {want[0]} numbers")
    return np.array([num(x) for x in v])


def _describe(shape) -> str:
    return f"{shape[0]} numbers" if len(shape) == 1 and shape[0] > 0 else f"rows of {shape[-1]} numbers"


def _flags(v: Any, path: str, n: int) -> Tuple[str, ...]:
    if not isinstance(v, (list, tuple)) or len(v) != n or not all(x in FLAGS for x in v):
        _fail(path, f"{v!r} is not a list of {n} flags", "each one of " + ", ".join(FLAGS))
    return tuple(v)


def _table(v: Any, path: str) -> Dict[str, Any]:
    if not isinstance(v, Mapping) or set(v) != {"columns", "rows"}:
        _fail(path, "expected {columns: [...], rows: [[...], ...]}", "or leave it out")
    cols = v["columns"]
    if not isinstance(cols, list) or not all(isinstance(c, str) for c in cols):
        _fail(f"{path}.columns", "expected a list of column names", "or leave poses_used out")
    rows = v["rows"]
    if not isinstance(rows, list):
        _fail(f"{path}.rows", f"expected a list of rows, got {type(rows).__name__}", "or leave it out")
    lens = {len(r) for r in rows if isinstance(r, list)}
    if len(lens) == 1 and len(rows) > 1 and lens != {len(cols)}:
        _fail(f"{path}.columns", f"names {len(cols)} columns, the rows have {lens.pop()}",
              "one name per column")
    out = [_array(r, f"{path}.rows[{i}]", len(cols), nullable=True).tolist() for i, r in enumerate(rows)]
    return {"columns": list(cols), "rows": out}




def _provisional(v: Any, path: str) -> Dict[str, Any]:
    """{poses, poses_for_final, missing_orientations}: a calibration applied before the
    pose set met the readiness targets (README: provisional calibrations)."""
    if not isinstance(v, Mapping):
        _fail(path, f"expected a mapping, got {type(v).__name__}", "or leave it out (not provisional)")
    _keys(v, path, {"poses", "poses_for_final", "missing_orientations"}, set())
    for k in ("poses", "poses_for_final"):
        if isinstance(v[k], bool) or not isinstance(v[k], int) or v[k] < 1:
            _fail(f"{path}.{k}", f"{v[k]!r} is not a positive integer", "e.g. 10")
    m = v["missing_orientations"]
    if not isinstance(m, list) or not all(isinstance(x, str) and re.fullmatch(r"([+-][XYZ]){1,3} up", x)
                                          for x in m):
        _fail(f"{path}.missing_orientations", f"{m!r} is not a list of orientation names",
              "e.g. ['-Z up', '+X+Y up']")
    return {"poses": v["poses"], "poses_for_final": v["poses_for_final"], "missing_orientations": list(m)}
