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
"""
from __future__ import annotations

import json
import socket
from typing import Any, BinaryIO, Dict, Iterator, Optional

from .errors import UserError

__all__ = ["StreamClient", "connect", "iter_records", "DEFAULT_SOCKET"]

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
        self._records = iter_records(self._fh, path)
        self.version: Dict[str, Any] = next(self._records, {})
        if self.version.get("class") != "VERSION":
            self.close()
            raise UserError(f"{path}: no VERSION banner: not an imucald stream socket")
        if self.version.get("format") != "ndjson":
            self.close()
            raise UserError(f"{path}: the daemon streams {self.version.get('format')}; this client "
                            f"reads ndjson (set output.format: ndjson)")

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
