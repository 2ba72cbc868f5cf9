"""The corrected stream: encoders (NDJSON, CSV, binary) and sinks (Unix socket, FIFO).

NDJSON follows gpsd's habits: one object per line with a ``class`` field, a
``VERSION`` banner when a client connects, fields omitted rather than null.

``class: "IMU"`` (one per sample):
  seq (int), t (s since start), acc_g [x, y, z], gyro_dps [x, y, z] (omitted for
  an accelerometer-only recording), mag_gauss [x, y, z] (boards with a
  magnetometer), temp_c (omitted when unknown), still (bool), cal (calibration
  id; 0 = uncalibrated, nominally scaled data).  A value that is not known is
  left out, never written as NaN or null.
  With ``output.covariance: true`` (and a ``noise.file``) also acc_var_g2 and
  gyro_var_dps2 [x, y, z]: the variance of one sample on each axis (module
  :mod:`imucald.daemon.pipeline`, README "Noise figures in the daemon").
``class: "GAP"``: seq (first missing), missing (count).
``class: "CAL"``: id, accel/gyro/mag held-out residuals before and after.

With orientation on (``output.orientation``, the ``orientation`` extra; issue 26) every IMU
object also carries ``q`` [w, x, y, z] (unit quaternion, body -> ENU, REP-103) and
``lin_acc_g`` [x, y, z] (gravity-free specific force, body frame, g), and per batch the
same ``heading`` ("magnetic": north is magnetic north; "arbitrary": a 6D board, the heading
is where the filter started), ``mag_disturbed`` (boards with a magnetometer: the filter
rejected the magnetometer as disturbed at some sample of the batch),
``incl_std_deg``, ``heading_std_deg`` (omitted when arbitrary) and ``q_cov_rad2`` (9 numbers,
sensor_msgs/Imu ``orientation_covariance``).  The VERSION banner says ``"orientation":"on"``
or ``"off"`` (with ``orientation_off``: why).

Binary record version 2, little-endian, 100 bytes (struct ``<QdIB3x3f3ff3f4f3fff``, see
:data:`BINARY_FORMAT`; the banner names it as ``record``): seq u64, t f64, cal u32, flags u8
(bit 0 still, bit 1 magnetometer present, bit 2 orientation present, bit 3 heading magnetic,
bit 4 magnetometer disturbed), 3 pad bytes, acc_g 3 x f32, gyro_dps 3 x f32, temp_c f32,
mag_gauss 3 x f32, q 4 x f32 [w, x, y, z], lin_acc_g 3 x f32, incl_std_deg f32,
heading_std_deg f32 (NaN when absent).  Version 1 (64 bytes) ended after mag_gauss.

Sinks never block the sampler: sockets and the FIFO are non-blocking, every
client has a bounded buffer, and a client that falls behind it is dropped and
counted.
"""
from __future__ import annotations

import errno
import json
import os
import stat
import struct
from typing import List, Optional

import numpy as np

from .. import __version__
from .unixsock import UnixServer, set_mode_group

__all__ = ["encode_samples", "banner", "event", "SocketSink", "FifoSink", "MAX_STREAM_CLIENTS",
           "BINARY_FORMAT", "BINARY_DTYPE", "BINARY_VERSION", "PROTO_MAJOR", "PROTO_MINOR", "CSV_HEADER",
           "CSV_ORIENTATION", "orientation_extra"]

#: 2.0: the binary record's layout changed (version 2, 100 bytes: a client of the 64-byte
#: records must not read it as one, so a major step, docs/reference/stream.md); the
#: orientation fields are additive in NDJSON and CSV
PROTO_MAJOR, PROTO_MINOR = 2, 0
BINARY_FORMAT = struct.Struct("<QdIB3x3f3ff3f4f3fff")
BINARY_VERSION = 2
#: the record as a numpy dtype (the same layout as BINARY_FORMAT)
BINARY_DTYPE = np.dtype([("seq", "<u8"), ("t", "<f8"), ("cal", "<u4"), ("flags", "u1"), ("pad", "u1", 3),
                         ("acc", "<f4", 3), ("gyro", "<f4", 3), ("temp", "<f4"), ("mag", "<f4", 3),
                         ("q", "<f4", 4), ("lin_acc", "<f4", 3), ("incl_std", "<f4"),
                         ("heading_std", "<f4")])
FLAG_STILL, FLAG_MAG, FLAG_ORIENT, FLAG_HEADING_MAGNETIC, FLAG_MAG_DISTURBED = 1, 2, 4, 8, 16
CSV_HEADER = "seq,t,ax,ay,az,gx,gy,gz,mx,my,mz,temp,still,cal\n"
#: columns CSV adds with orientation on
CSV_ORIENTATION = ",qw,qx,qy,qz,lax,lay,laz,incl_std_deg,heading_std_deg"


def banner(fmt: str, board: str, chips: Optional[dict] = None,
           orientation: Optional[str] = None) -> bytes:
    """The VERSION line: release, protocol, format, board and (when known) its chips by
    role, e.g. {"accel": "adxl345", "gyro": "itg3200", "mag": "qmc5883l"}; ``orientation``
    None: on, else why it is off (``"orientation":"off","orientation_off":why``); binary
    streams name their record (version, bytes, struct)."""
    d = {"class": "VERSION", "release": __version__, "proto_major": PROTO_MAJOR,
         "proto_minor": PROTO_MINOR, "format": fmt, "board": board}
    if chips:
        d["chips"] = chips
    d["orientation"] = "on" if orientation is None else "off"
    if orientation is not None:
        d["orientation_off"] = orientation
    if fmt == "binary":
        d["record"] = {"version": BINARY_VERSION, "bytes": BINARY_FORMAT.size,
                       "struct": BINARY_FORMAT.format}
    line = json.dumps(d, separators=(",", ":")) + "\n"
    if fmt == "csv":
        return ("# " + line + CSV_HEADER[:-1] + (CSV_ORIENTATION if orientation is None else "")
                + "\n").encode()
    if fmt == "binary":
        # the banner is a JSON line, then fixed-size records
        return line.encode()
    return line.encode()


def event(cls: str, fmt: str, **fields) -> bytes:
    """A non-sample object (GAP, CAL): a JSON line in ndjson; a '# ' comment in CSV;
    nothing in binary (records carry seq, so gaps are visible there)."""
    if fmt == "binary":
        return b""
    d = {"class": cls}
    d.update({k: v for k, v in fields.items() if v is not None})
    line = json.dumps(d, separators=(",", ":")) + "\n"
    return (("# " + line) if fmt == "csv" else line).encode()


def _vecs(name: str, V, ok, n: int):
    """',"name":[x,y,z]' per row, '' where the row is absent or not finite (fields are
    omitted, never NaN)."""
    if V is None:
        return [""] * n
    return [f',"{name}":[{v[0]},{v[1]},{v[2]}]' if k else "" for v, k in zip(V, ok)]


def orientation_extra(o) -> str:
    """The batch-level orientation fields as ',"key":value...' (NDJSON): heading reference,
    inclination and heading standard deviations (omitted when not known), the ROS covariance."""
    if o is None:
        return ""
    h = o.get("heading_std_deg")
    cov = ",".join(f"{v:.4g}" for v in o["cov"])
    md = o.get("mag_disturbed")
    return (f',"heading":"{o["heading"]}","incl_std_deg":{o["incl_std_deg"]:.3g}'
            + (f',"heading_std_deg":{h:.3g}' if h is not None and np.isfinite(h) else "")
            + f',"q_cov_rad2":[{cov}]'
            + ("" if md is None else f',"mag_disturbed":{"true" if md.any() else "false"}'))


def encode_samples(fmt: str, seq, t, acc, gyro, temp, mag, still, cal_id: int, extra: str = "",
                   orient=None) -> bytes:
    """Encode a batch of corrected samples (arrays with n rows; gyro, temp and mag may
    be None when the board or recording has none).  NDJSON omits a field whose value is
    unknown (no gyro, NaN temperature, no fresh magnetometer reading, a non-finite
    value); CSV leaves its cells empty; binary carries NaN.  ``extra``: fields the same
    for every sample of the batch (',"key":value...'), NDJSON only (the covariances).
    ``orient``: the orientation filter's output for these rows (q, lin_acc_g, mag_disturbed,
    heading, incl_std_deg, heading_std_deg, cov; orientation/filter.py), or None when off."""
    if len(seq) == 0:
        return b""
    if fmt == "binary":
        return _binary(seq, t, acc, gyro, temp, mag, still, cal_id, orient)
    if fmt == "ndjson" and orient is not None:
        extra = extra + orientation_extra(orient)
    if fmt == "ndjson" and gyro is not None and temp is not None:
        # the usual case, every value known (_ndjson_known); else one comprehension per field
        fast = _ndjson_known(seq, t, acc, gyro, temp, mag, still, cal_id, extra, orient)
        if fast is not None:
            return fast
    c = _Columns(seq, t, acc, gyro, temp, mag, still, orient)
    out = _csv_rows(c, cal_id, orient) if fmt == "csv" else _ndjson_rows(c, cal_id, extra)
    return "".join(out).encode()


def _binary(seq, t, acc, gyro, temp, mag, still, cal_id: int, orient) -> bytes:
    """Binary records (BINARY_DTYPE): NaN where a value is not known."""
    n = len(seq)
    nan3 = np.full((n, 3), np.nan)
    m = mag if mag is not None else nan3
    flags = still.astype(np.uint8) | (np.uint8(FLAG_MAG) if mag is not None else np.uint8(0))
    rec = np.zeros(n, dtype=BINARY_DTYPE)
    rec["seq"], rec["t"], rec["cal"] = seq, t, cal_id
    rec["acc"], rec["gyro"] = acc, gyro if gyro is not None else nan3
    rec["temp"], rec["mag"] = temp if temp is not None else np.nan, m
    if orient is None:
        rec["q"], rec["lin_acc"], rec["incl_std"], rec["heading_std"] = np.nan, np.nan, np.nan, np.nan
    else:
        okq = np.all(np.isfinite(orient["q"]), 1)
        flags = flags | np.where(okq, np.uint8(FLAG_ORIENT), np.uint8(0))
        if orient["heading"] == "magnetic":
            flags = flags | np.uint8(FLAG_HEADING_MAGNETIC)
        if orient.get("mag_disturbed") is not None:
            flags = flags | np.where(orient["mag_disturbed"], np.uint8(FLAG_MAG_DISTURBED), np.uint8(0))
        h = orient.get("heading_std_deg")
        rec["q"], rec["lin_acc"] = orient["q"], orient["lin_acc_g"]
        rec["incl_std"], rec["heading_std"] = orient["incl_std_deg"], np.nan if h is None else h
    rec["flags"] = flags
    return rec.tobytes()


def _finite_rows(x):
    """Per row: every value finite (None when the array is absent)."""
    return None if x is None else np.all(np.isfinite(x), axis=1)


class _Columns:
    """A batch as rounded Python lists (the decimals the stream writes) with, per row,
    whether each vector is known: the general path's input (CSV, and NDJSON with a value
    that is not known)."""

    def __init__(self, seq, t, acc, gyro, temp, mag, still, orient):
        self.n = len(seq)
        self.okA, self.okG, self.okM = _finite_rows(acc), _finite_rows(gyro), _finite_rows(mag)
        self.okT = None if temp is None else np.isfinite(temp)
        self.A = np.round(acc, 6).tolist()
        self.G = None if gyro is None else np.round(gyro, 5).tolist()
        self.T = None if temp is None else np.round(temp, 3).tolist()
        self.M = None if mag is None else np.round(mag, 6).tolist()
        self.S = still.tolist()
        self.Q = seq.tolist()
        self.TT = np.round(t, 6).tolist()
        self.okO = self.OQ = self.OL = None
        if orient is not None:
            self.okO = _finite_rows(orient["q"]) & _finite_rows(orient["lin_acc_g"])
            self.OQ = np.round(orient["q"], 6).tolist()
            self.OL = np.round(orient["lin_acc_g"], 5).tolist()


def _csv_rows(c: _Columns, cal_id: int, orient) -> List[str]:
    """CSV lines; a value that is not known leaves its cells empty."""
    cell = lambda V, ok, i: V[i] if V is not None and ok[i] else ("", "", "")
    if orient is not None:
        h = orient.get("heading_std_deg")
        sd = f"{orient['incl_std_deg']:.3g},{'' if h is None else format(h, '.3g')}"
    out = []
    for i in range(c.n):
        a, g, m = cell(c.A, c.okA, i), cell(c.G, c.okG, i), cell(c.M, c.okM, i)
        tc = c.T[i] if c.T is not None and c.okT[i] else ""
        o = ""
        if orient is not None:
            OQ, OL = c.OQ, c.OL
            o = (f",{OQ[i][0]},{OQ[i][1]},{OQ[i][2]},{OQ[i][3]},{OL[i][0]},{OL[i][1]},{OL[i][2]},{sd}"
                 if c.okO[i] else ",,,,,,,,,")
        out.append(f"{c.Q[i]},{c.TT[i]},{a[0]},{a[1]},{a[2]},{g[0]},{g[1]},{g[2]},"
                   f"{m[0]},{m[1]},{m[2]},{tc},{int(c.S[i])},{cal_id}{o}\n")
    return out


def _ndjson_rows(c: _Columns, cal_id: int, extra: str) -> List[str]:
    """NDJSON lines, one comprehension per field (a value that is not known contributes "")."""
    n = c.n
    aa = _vecs("acc_g", c.A, c.okA, n)
    gg = _vecs("gyro_dps", c.G, c.okG, n)
    mm = _vecs("mag_gauss", c.M, c.okM, n)
    tt = [""] * n if c.T is None else [f',"temp_c":{x}' if ok else "" for x, ok in zip(c.T, c.okT)]
    if c.OQ is None:
        oo = [""] * n
    else:
        oo = [f',"q":[{q[0]},{q[1]},{q[2]},{q[3]}],"lin_acc_g":[{la[0]},{la[1]},{la[2]}]' if ok else ""
              for q, la, ok in zip(c.OQ, c.OL, c.okO)]
    tail = f',"cal":{cal_id}}}\n'
    return [f'{{"class":"IMU","seq":{q},"t":{ts}{a}{g}{m}{tc}{o}{extra},"still":{"true" if st else "false"}{tail}'
            for q, ts, a, g, m, tc, o, st in zip(c.Q, c.TT, aa, gg, mm, tt, oo, c.S)]


#: decimals written per column of [t, acc, gyro, temp, mag]: as np.round(x, d), which is
#: rint(x * 10**d) / 10**d
_DEC = np.array([6, 6, 6, 6, 5, 5, 5, 3, 6, 6, 6])
_POW = 10.0 ** _DEC
#: and of the orientation columns [q (4), lin_acc_g (3)]
_POW_O = 10.0 ** np.array([6, 6, 6, 6, 5, 5, 5])
#: [t, acc, gyro, temp, q, lin_acc_g, mag] with orientation on
_POW_Q = np.concatenate([_POW[:8], _POW_O, _POW[8:]])


def _ndjson_known(seq, t, acc, gyro, temp, mag, still, cal_id: int, extra: str = "",
                  orient=None) -> Optional[bytes]:
    """NDJSON of a batch whose t, acc, gyro and temp (and orientation) are all finite (the
    usual case; a magnetometer row that is not fresh or not finite is left out), with a
    handful of numpy calls per batch rather than per field; None when the general path
    must look."""
    # one array for everything: [t, acc, gyro, temp] (+ [q, lin_acc] with orientation), mag
    cols = [t[:, None], acc, gyro, temp[:, None]]
    if orient is not None:
        cols += [orient["q"], orient["lin_acc_g"]]
    k = 8 if orient is None else 15                  # the columns that must be finite
    X = np.concatenate(cols + ([mag] if mag is not None else []), 1)
    fin = np.isfinite(X)
    if not fin[:, :k].all():
        return None
    P = (_POW if orient is None else _POW_Q)[:X.shape[1]]
    R = (np.rint(X * P) / P).tolist()
    okM = fin[:, k:].all(1).tolist() if mag is not None else None
    tail = f',"cal":{cal_id}}}\n'
    out = []
    for i, (q, r, st) in enumerate(zip(seq.tolist(), R, still.tolist())):
        m = f',"mag_gauss":[{r[k]},{r[k + 1]},{r[k + 2]}]' if okM is not None and okM[i] else ""
        o = ("" if orient is None else
             f',"q":[{r[8]},{r[9]},{r[10]},{r[11]}],"lin_acc_g":[{r[12]},{r[13]},{r[14]}]')
        out.append(f'{{"class":"IMU","seq":{q},"t":{r[0]},"acc_g":[{r[1]},{r[2]},{r[3]}],'
                   f'"gyro_dps":[{r[4]},{r[5]},{r[6]}]{m},"temp_c":{r[7]}{o}{extra},'
                   f'"still":{"true" if st else "false"}{tail}')
    return "".join(out).encode()


class _Client:
    __slots__ = ("sock", "buf", "peer")

    def __init__(self, sock, peer):
        self.sock, self.buf, self.peer = sock, bytearray(), peer


#: data clients at once, each buffer up to max_buffer (1 MiB): the stream's memory is bounded
#: by their product (a cold review's 3000 clients that never read took 1.4 GB and lost samples);
#: more are refused with one ERROR line (gpsd's limit is 64, on larger machines)
MAX_STREAM_CLIENTS = 32


#: the refusal's message (client.py and `imucald watch` show it as it is)
REFUSED_MESSAGE = (f"too many stream clients ({MAX_STREAM_CLIENTS}): close idle readers "
                   f"(`imucald status --json` counts clients) and try again")


def refusal(fmt: str) -> bytes:
    """The one line a client beyond MAX_STREAM_CLIENTS reads before the socket closes: an
    ERROR object where the VERSION banner would be ('# ' before it in CSV, as the banner)."""
    line = json.dumps({"class": "ERROR", "message": REFUSED_MESSAGE}, separators=(",", ":")) + "\n"
    return (("# " + line) if fmt == "csv" else line).encode()


class SocketSink(UnixServer):
    """A listening Unix stream socket; up to MAX_STREAM_CLIENTS clients, each with a bounded
    buffer."""

    def __init__(self, path: str, fmt: str, board: str, mode: str = "0660",
                 group: Optional[str] = None, max_buffer: int = 1 << 20):
        self.fmt, self.board, self.max_buffer = fmt, board, max_buffer
        self.chips: Optional[dict] = None     #: set by the daemon once the chips are identified
        #: None: orientation on; else why it is off (the banner says so); set by the daemon
        self.orientation_off: Optional[str] = "not started"
        super().__init__(path, mode, group, 16, "output.socket")
        self.clients: List[_Client] = []
        self.dropped = 0          #: clients dropped for falling behind
        self.disconnected = 0     #: clients that went away
        self.refused = 0          #: clients refused (MAX_STREAM_CLIENTS)
        self.accepted = 0

    def accept(self) -> None:
        while True:
            try:
                s, _ = self.lsock.accept()
            except (BlockingIOError, InterruptedError):
                return
            s.setblocking(False)
            if len(self.clients) >= MAX_STREAM_CLIENTS:
                self.refused += 1
                try:
                    s.send(refusal(self.fmt))
                except OSError:
                    pass
                s.close()
                continue
            c = _Client(s, self.accepted)
            c.buf += banner(self.fmt, self.board, self.chips, self.orientation_off)
            self.clients.append(c)
            self.accepted += 1

    def write(self, data: bytes) -> None:
        self.accept()
        if not self.clients:
            return
        keep = []
        for c in self.clients:
            if data:
                c.buf += data
            ok = self._flush(c)
            if ok and len(c.buf) > self.max_buffer:
                c.sock.close()
                self.dropped += 1
                continue
            if ok:
                keep.append(c)
        self.clients = keep

    def _flush(self, c: _Client) -> bool:
        while c.buf:
            try:
                n = c.sock.send(c.buf)
            except (BlockingIOError, InterruptedError):
                return True
            except OSError:
                c.sock.close()
                self.disconnected += 1
                return False
            del c.buf[:n]
        return True

    def connections(self) -> List[_Client]:
        return self.clients


class FifoSink:
    """A named pipe opened non-blocking.  No reader: nothing is written and nothing
    stalls; a reader that comes back gets the stream again from a record boundary."""

    def __init__(self, path: str, fmt: str, board: str, mode: str = "0660",
                 group: Optional[str] = None, max_buffer: int = 1 << 20):
        self.path, self.fmt, self.board, self.max_buffer = path, fmt, board, max_buffer
        self.chips: Optional[dict] = None     #: set by the daemon once the chips are identified
        self.orientation_off: Optional[str] = "not started"    #: as SocketSink's
        if not os.path.exists(path):
            try:
                os.mkfifo(path)
            except OSError as e:        # a missing directory, a read-only one (a helper: bare errno)
                from ..errors import CannotCreate
                raise CannotCreate(f"output.fifo: cannot create {path}: {e.strerror} (a relative "
                                   f"path is taken from the runtime directory; create its directory "
                                   f"or choose another output.fifo)") from None
            try:
                set_mode_group(path, mode, group, "output.fifo")
            except Exception:
                os.unlink(path)
                raise
        elif not stat.S_ISFIFO(os.stat(path).st_mode):
            from ..errors import CannotCreate
            raise CannotCreate(f"output.fifo: {path} exists and is not a FIFO: move it away or "
                               f"choose another output.fifo")
        self.fd: Optional[int] = None
        self.buf = bytearray()
        self.dropped_bytes = 0
        self.connects = 0

    def _open(self) -> bool:
        try:
            self.fd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as e:
            if e.errno in (errno.ENXIO, errno.ENOENT):
                return False          # no reader yet
            raise
        self.connects += 1
        self.buf = bytearray(banner(self.fmt, self.board, self.chips, self.orientation_off))
        self._banner_left = len(self.buf)
        self._written = 0           # record bytes delivered since the banner
        self._last = b"\n"
        return True

    def write(self, data: bytes) -> None:
        if self.fd is None and not self._open():
            return
        self.buf += data
        while self.buf:
            try:
                n = os.write(self.fd, self.buf)
            except BlockingIOError:
                break
            except BrokenPipeError:
                os.close(self.fd)
                self.fd = None
                self.buf = bytearray()
                return
            self._account(bytes(self.buf[:n]))
            del self.buf[:n]
        if len(self.buf) > self.max_buffer:        # slow reader: drop the backlog, but
            keep = self._partial()                 # finish the record it is inside
            self.dropped_bytes += len(self.buf) - keep
            self.buf = self.buf[:keep]

    def _account(self, chunk: bytes) -> None:
        b = min(self._banner_left, len(chunk))
        self._banner_left -= b
        self._written += len(chunk) - b
        if chunk:
            self._last = chunk[-1:]

    def _partial(self) -> int:
        """Bytes of the buffer needed to complete the record being written."""
        if self._banner_left:
            return self._banner_left
        if self.fmt == "binary":
            return (BINARY_FORMAT.size - self._written % BINARY_FORMAT.size) % BINARY_FORMAT.size
        if self._last == b"\n":
            return 0
        i = self.buf.find(b"\n")
        return i + 1 if i >= 0 else len(self.buf)

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
