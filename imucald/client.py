"""A small client for the daemon's stream socket (the way gpsd ships one for its
protocol): connect, then iterate over the decoded NDJSON records.

    from imucald.client import connect
    with connect("/run/imucald/imucald.sock") as stream:
        print(stream.version)                  # the VERSION banner
        for rec in stream:                     # dicts: class IMU, GAP, CAL
            if rec["class"] == "IMU":
                print(rec["seq"], rec["acc_g"])

Fields that are not known are absent (``temp_c`` without a temperature sensor,
``gyro_dps`` on a board without one), never ``null`` or NaN: use ``rec.get(...)``.

With orientation on (``stream.version["orientation"] == "on"``) each IMU record has ``q``
[w, x, y, z] (body -> ENU, REP-103), ``lin_acc_g``, ``heading`` ("magnetic" or "arbitrary"),
``incl_std_deg``, ``heading_std_deg`` and ``q_cov_rad2``; :func:`attitude_deg` turns ``q``
into roll, pitch and compass heading.  A binary stream (``output.format: binary``, record
version 2) is decoded into the same dicts.
"""
from __future__ import annotations

import itertools
import json
import math
import socket
import struct
from typing import Any, BinaryIO, Dict, Iterator, Optional, Sequence, Tuple

from .errors import UserError

__all__ = ["StreamClient", "connect", "iter_records", "iter_binary", "decode_record", "attitude_deg",
           "refusal_message", "DEFAULT_SOCKET"]

DEFAULT_SOCKET = "/run/imucald/imucald.sock"


def iter_records(fh: BinaryIO, source: str = "stream") -> Iterator[Dict[str, Any]]:
    """Decode NDJSON lines from a binary file object; a line that is not JSON raises a
    one-line UserError naming the source and the line number."""
    for i, line in enumerate(fh, 1):
        if not line.strip():
            continue
        try:
            yield json.loads(line)
        except ValueError:
            raise UserError(f"{source}:{i}: not a JSON line ({line[:60]!r}): is output.format "
                            f"ndjson?") from None


def refusal_message(first: bytes) -> Optional[str]:
    """The daemon's message when the stream's first line ``first`` refuses this client (an
    ERROR object where the VERSION banner would be: too many clients; '# ' before it in CSV),
    else None."""
    text = first.decode("utf-8", "replace").strip()
    if text.startswith("# "):
        text = text[2:]
    if not text.startswith('{"class":"ERROR"'):
        return None
    try:
        return str(json.loads(text).get("message", ""))
    except ValueError:
        return None


#: the binary record this client reads (daemon/outputs.py BINARY_FORMAT, record version 2)
_RECORD = struct.Struct("<QdIB3x3f3ff3f4f3fff")
_RECORD_VERSION = 2


def _vec(v) -> Optional[list]:
    return None if any(x != x for x in v) else [round(x, 7) for x in v]


def decode_record(buf: bytes) -> Dict[str, Any]:
    """One binary record (version 2, 100 bytes) as the NDJSON IMU object: NaN fields omitted."""
    f = _RECORD.unpack(buf)
    seq, t, cal, flags = f[0], f[1], f[2], f[3]
    d: Dict[str, Any] = {"class": "IMU", "seq": seq, "t": t}
    for name, v in (("acc_g", f[4:7]), ("gyro_dps", f[7:10]), ("mag_gauss", f[11:14])):
        v = _vec(v)
        if v is not None and (name != "mag_gauss" or flags & 2):
            d[name] = v
    if f[10] == f[10]:
        d["temp_c"] = f[10]
    if flags & 4:
        d["q"] = _vec(f[14:18])
        d["lin_acc_g"] = _vec(f[18:21])
        d["heading"] = "magnetic" if flags & 8 else "arbitrary"
        if flags & 2:
            d["mag_disturbed"] = bool(flags & 16)
        if f[21] == f[21]:
            d["incl_std_deg"] = f[21]
        if f[22] == f[22]:
            d["heading_std_deg"] = f[22]
    d["still"] = bool(flags & 1)
    d["cal"] = cal
    return d


def iter_binary(fh: BinaryIO, source: str = "stream") -> Iterator[Dict[str, Any]]:
    """Decode binary records (after the banner line) from a binary file object."""
    while True:
        buf = fh.read(_RECORD.size)
        if len(buf) < _RECORD.size:
            return
        yield decode_record(buf)


def attitude_deg(q: Sequence[float]) -> Tuple[float, float, float]:
    """(roll, pitch, heading) in degrees from ``q`` [w, x, y, z] (body -> ENU): roll and pitch
    are REP-103's fixed-axis angles (about x, then y); heading is the compass heading of the
    body x axis, degrees clockwise from north (magnetic north; arbitrary on a 6D board),
    in [0, 360)."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), (90.0 - math.degrees(yaw)) % 360.0


class StreamClient:
    """A connection to the data socket.  ``version`` is the banner; iterating yields the
    records that follow it, until the daemon closes the connection."""

    def __init__(self, path: str = DEFAULT_SOCKET, timeout_s: Optional[float] = None):
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(timeout_s)
        try:
            self.sock.connect(path)
        except OSError as e:
            self.sock.close()
            raise UserError(f"{path}: cannot connect ({e.strerror or e}): is imucald running, and "
                            f"may this user read its socket (group of output.socket_group)?") from None
        self._fh = self.sock.makefile("rb")
        first = self._fh.readline()
        why = refusal_message(first)
        if why is not None:                                  # refused (too many clients)
            self.close()
            raise UserError(f"{path}: the daemon refused this client: {why}")
        self._records = iter_records(itertools.chain([first], self._fh), path)
        self.version: Dict[str, Any] = next(self._records, {})
        if self.version.get("class") != "VERSION":
            self.close()
            raise UserError(f"{path}: no VERSION banner: not an imucald stream socket")
        fmt = self.version.get("format")
        rv = (self.version.get("record") or {}).get("version")
        if fmt == "binary" and rv == _RECORD_VERSION:
            self._records = iter_binary(self._fh, path)
        elif fmt != "ndjson":
            self.close()
            raise UserError(f"{path}: the daemon streams {fmt}" + (f" (record version {rv})" if rv else "")
                            + f"; this client reads ndjson and binary record version {_RECORD_VERSION} "
                            f"(set output.format: ndjson, or update the client)")

    def __iter__(self) -> Iterator[Dict[str, Any]]:
        return self._records

    def __enter__(self) -> "StreamClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._fh.close()
        self.sock.close()


def connect(path: str = DEFAULT_SOCKET, timeout_s: Optional[float] = None) -> StreamClient:
    """Connect to the daemon's data socket (see :class:`StreamClient`)."""
    return StreamClient(path, timeout_s)
