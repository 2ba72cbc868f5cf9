"""The imucald recording format (v1): CSV with a versioned, self-describing header.

::

    # imucald recording v1
    # board: mpu6050
    # rate_hz: 100
    # accel_range_g: 2
    # gyro_range_dps: 250
    t,ax,ay,az,gx,gy,gz,temp
    0.000000,0.0123,-0.0040,1.0021,0.51,-0.22,1.02,25.31
    ...

* Line 1 is exactly ``# imucald recording v1``.
* Header lines ``# key: value`` follow; required keys: board, rate_hz.  Known
  optional keys: accel_range_g, gyro_range_dps, mag_range_gauss, source,
  seed, note.  Unknown keys are kept.
* Then one column header, from t, ax, ay, az, gx, gy, gz, mx, my, mz, temp
  (present sensors only, in this order; t first and required; a sensor's three
  axes come together).
* Units: t in s, accelerometer in g, gyro in deg/s, magnetometer in gauss,
  temp in degC, after the datasheet's nominal scaling and before calibration.

Reader errors are :class:`RecordingError` and name the file and line.
"""
from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, TextIO, Union

import numpy as np

from .errors import UserError

__all__ = ["Recording", "RecordingError", "read_recording", "write_recording", "MAGIC",
           "COLUMNS"]

MAGIC = "# imucald recording v1"
COLUMNS = ["t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz", "temp"]
_GROUPS = {"acc": ["ax", "ay", "az"], "gyro": ["gx", "gy", "gz"], "mag": ["mx", "my", "mz"]}


class RecordingError(UserError):
    """A recording file that cannot be read; the message names file and line."""


@dataclass
class Recording:
    """Samples in physical units.  Arrays are (n,) or (n, 3); absent sensors are None."""

    t: np.ndarray                              #: time, s
    acc: Optional[np.ndarray] = None           #: accelerometer, g (body frame)
    gyro: Optional[np.ndarray] = None          #: gyro, deg/s (body frame)
    mag: Optional[np.ndarray] = None           #: magnetometer, gauss (body frame)
    temp: Optional[np.ndarray] = None          #: die temperature, degC
    meta: Dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def rate_hz(self) -> float:
        if "rate_hz" in self.meta:
            return float(self.meta["rate_hz"])
        dt = np.diff(self.t)
        return float(1.0 / np.median(dt)) if len(dt) else 0.0

    def columns(self) -> List[str]:
        cols = ["t"]
        for g in ("acc", "gyro", "mag"):
            if getattr(self, g) is not None:
                cols += _GROUPS[g]
        if self.temp is not None:
            cols.append("temp")
        return cols

    def slice(self, i0: int, i1: int) -> "Recording":
        f = lambda a: None if a is None else a[i0:i1]
        return Recording(self.t[i0:i1], f(self.acc), f(self.gyro), f(self.mag), f(self.temp),
                         dict(self.meta))


_FMT = {"t": "%.6f", "acc": "%.7f", "gyro": "%.5f", "mag": "%.6f", "temp": "%.3f"}


def write_recording(rec: Recording, path: Union[str, os.PathLike, TextIO]) -> None:
    """Write a recording; to a path it is written atomically (temp file, fsync, rename)."""
    meta = dict(rec.meta)
    meta.setdefault("board", "unknown")
    meta.setdefault("rate_hz", f"{rec.rate_hz:g}")
    parts, fmts = [rec.t[:, None]], [_FMT["t"]]
    for g in ("acc", "gyro", "mag"):
        a = getattr(rec, g)
        if a is not None:
            parts.append(np.asarray(a, float))
            fmts += [_FMT[g]] * 3
    if rec.temp is not None:
        parts.append(np.asarray(rec.temp, float)[:, None])
        fmts.append(_FMT["temp"])
    data = np.hstack(parts)
    buf = io.StringIO()
    buf.write(MAGIC + "\n")
    for k, v in meta.items():
        buf.write(f"# {k}: {v}\n")
    buf.write(",".join(rec.columns()) + "\n")
    np.savetxt(buf, data, fmt=",".join(fmts))
    text = buf.getvalue()
    if hasattr(path, "write"):
        path.write(text)
        return
    from .atomic import atomic_write_text
    atomic_write_text(os.fspath(path), text)


def read_recording(path: Union[str, os.PathLike]) -> Recording:
    """Read a v1 recording.  Raises RecordingError naming file:line on any defect."""
    path = os.fspath(path)
    try:
        fh = open(path, "r", encoding="utf-8")
    except OSError as e:
        raise RecordingError(f"{path}: cannot open: {e.strerror}") from None
    with fh:
        first = fh.readline().rstrip("\r\n")
        if first != MAGIC:
            raise RecordingError(f"{path}:1: not an imucald recording (expected {MAGIC!r}, "
                                 f"found {first[:40]!r})")
        meta: Dict[str, str] = {}
        lineno = 1
        header = None
        for line in fh:
            lineno += 1
            s = line.rstrip("\r\n")
            if s.startswith("#"):
                body = s[1:].strip()
                if ":" not in body:
                    raise RecordingError(f"{path}:{lineno}: header line must be '# key: value'")
                k, v = body.split(":", 1)
                meta[k.strip()] = v.strip()
                continue
            header = [c.strip() for c in s.split(",")]
            break
        if header is None:
            raise RecordingError(f"{path}:{lineno}: no column header (expected e.g. t,ax,ay,az)")
        hl = lineno
        for key in ("board", "rate_hz"):
            if key not in meta:
                raise RecordingError(f"{path}: header lacks required key '{key}'")
        try:
            float(meta["rate_hz"])
        except ValueError:
            raise RecordingError(f"{path}: header rate_hz={meta['rate_hz']!r} is not a number") from None
        bad = [c for c in header if c not in COLUMNS]
        if bad:
            raise RecordingError(f"{path}:{hl}: unknown column {bad[0]!r}; allowed: {', '.join(COLUMNS)}")
        if header[0] != "t":
            raise RecordingError(f"{path}:{hl}: the first column must be t")
        if len(set(header)) != len(header):
            raise RecordingError(f"{path}:{hl}: a column is repeated")
        for g, cols in _GROUPS.items():
            n = sum(c in header for c in cols)
            if n not in (0, 3):
                raise RecordingError(f"{path}:{hl}: columns {','.join(cols)} must come together")
        rows = []
        ncol = len(header)
        for line in fh:
            lineno += 1
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = s.split(",")
            if len(parts) != ncol:
                raise RecordingError(f"{path}:{lineno}: expected {ncol} values, found {len(parts)}")
            try:
                rows.append([float(p) for p in parts])
            except ValueError:
                bad = next(p for p in parts if not _isfloat(p))
                raise RecordingError(f"{path}:{lineno}: {bad.strip()!r} is not a number") from None
        if not rows:
            raise RecordingError(f"{path}:{lineno}: no samples after the column header")
    data = np.array(rows)
    if not np.all(np.isfinite(data)):
        r = int(np.argwhere(~np.isfinite(data))[0, 0])
        raise RecordingError(f"{path}: sample {r + 1} holds a non-finite value")
    if np.any(np.diff(data[:, 0]) < 0):
        r = int(np.argmax(np.diff(data[:, 0]) < 0))
        raise RecordingError(f"{path}: time goes backwards at sample {r + 2}")
    col = {c: i for i, c in enumerate(header)}
    get = lambda cs: data[:, [col[c] for c in cs]] if cs[0] in col else None
    return Recording(t=data[:, 0], acc=get(_GROUPS["acc"]), gyro=get(_GROUPS["gyro"]),
                     mag=get(_GROUPS["mag"]), temp=data[:, col["temp"]] if "temp" in col else None,
                     meta=meta)


def _isfloat(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False
