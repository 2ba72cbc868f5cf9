"""Loading calibration inputs: a recording, a pose file, or a raw numeric table.

A raw table (no imucald magic line) is whitespace- or comma-separated numbers
whose columns are named by ``columns`` (e.g. ``t,ax,ay,az``); sensor columns
in raw counts are converted with ``(value - nominal_offset) / nominal_scale``.
This is how the IMU-TK Xsens files (ASCII, unsigned 16-bit counts) are read.
"""
from __future__ import annotations

import os
from typing import Optional, Sequence

import numpy as np

from ..errors import UserError
from ..recording import COLUMNS, MAGIC, Recording, read_recording
from .poses import POSES_MAGIC, read_poses

__all__ = ["load_input", "read_table"]


def _first_line(path: str) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            return fh.readline().rstrip("\r\n")
    except OSError as e:
        raise UserError(f"{path}: cannot open: {e.strerror}") from None


def read_table(path: str, columns: Sequence[str], nominal_scale: float = 1.0,
               nominal_offset: float = 0.0, rate_hz: Optional[float] = None) -> Recording:
    """A headerless numeric table as a Recording (units after nominal scaling)."""
    cols = list(columns)
    bad = [c for c in cols if c not in COLUMNS and c != "-"]
    if bad:
        raise UserError(f"--columns: unknown column {bad[0]!r}; allowed {', '.join(COLUMNS)} "
                        f"(or - to skip one)")
    if nominal_scale == 0:
        raise UserError("--nominal-scale: 0 is not allowed (counts per unit, e.g. 16384)")
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            s = line.strip()
            if not s or s[0] in "#%":
                continue
            parts = s.replace(",", " ").split()
            if not rows and not _numeric(parts):
                continue  # header lines before the first row of numbers
            if len(parts) != len(cols):
                raise UserError(f"{path}:{lineno}: expected {len(cols)} values "
                                f"({','.join(cols)}), found {len(parts)}")
            try:
                rows.append([float(p) for p in parts])
            except ValueError:
                raise UserError(f"{path}:{lineno}: a value is not a number") from None
    if not rows:
        raise UserError(f"{path}: no numeric rows")
    d = np.array(rows)
    c = {name: d[:, i] for i, name in enumerate(cols) if name != "-"}
    rate = rate_hz
    if "t" in c:
        t = c["t"]
    else:
        if not rate:
            raise UserError(f"{path}: no t column: give --rate-hz")
        t = np.arange(len(d)) / rate
    grp = lambda ks: (np.column_stack([c[k] for k in ks]) - nominal_offset) / nominal_scale \
        if all(k in c for k in ks) else None
    meta = {"board": "unknown", "rate_hz": f"{rate or 1.0 / np.median(np.diff(t)):g}",
            "source": os.path.basename(path)}
    return Recording(t=t, acc=grp(["ax", "ay", "az"]), gyro=grp(["gx", "gy", "gz"]),
                     mag=grp(["mx", "my", "mz"]), temp=c.get("temp"), meta=meta)


def _numeric(parts) -> bool:
    try:
        [float(p) for p in parts]
        return True
    except ValueError:
        return False


def load_input(path: str, columns: Optional[Sequence[str]] = None, nominal_scale: float = 1.0,
               nominal_offset: float = 0.0, rate_hz: Optional[float] = None):
    """Return (kind, obj): ('recording', Recording) or ('poses', PoseSet)."""
    first = _first_line(path)
    if first == MAGIC:
        return "recording", read_recording(path)
    if first.strip() == POSES_MAGIC:
        return "poses", read_poses(path)
    if first.startswith("# imucald"):
        raise UserError(f"{path}:1: unsupported imucald file {first!r} "
                        f"(this version reads {MAGIC!r} and {POSES_MAGIC!r})")
    if columns is None:
        raise UserError(f"{path}: not an imucald recording or pose file; for a raw numeric "
                        f"table name its columns, e.g. --columns t,ax,ay,az")
    return "recording", read_table(path, columns, nominal_scale, nominal_offset, rate_hz)
