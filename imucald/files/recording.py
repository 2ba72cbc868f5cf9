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

* The file is UTF-8 (the body is ASCII numbers); ``rate_hz`` is a number > 0.
* Every value is finite, sensor values lie within +-PLAUSIBLE_LIMIT (1e6), and t
  never decreases.  Lines starting with ``#`` in the body and blank lines are skipped.

Reader errors are :class:`RecordingError`, one line naming the file and line
(and the column or byte offset).  The body is parsed in bulk, block by block
(:mod:`imucald.files.tables`): ``open_recording(path).chunks()`` streams it in bounded
memory, ``read_recording(path)`` returns it whole.
"""
from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from typing import Dict, Iterator, List, Optional, TextIO, Union

import numpy as np

from ..errors import UserError, snippet
from . import tables
from .tables import TableSpec, collect, decode_line, iter_blocks
from ..numerics.npstats import median
from ..numerics.rates import effective_rate

__all__ = ["Recording", "RecordingError", "RecordingReader", "open_recording", "iter_recording",
           "read_recording", "write_recording", "RecordingWriter", "read_small", "BOM", "MAGIC", "COLUMNS", "PLAUSIBLE_LIMIT"]

MAGIC = "# imucald recording v1"
COLUMNS = ["t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz", "temp"]
_GROUPS = {"acc": ["ax", "ay", "az"], "gyro": ["gx", "gy", "gz"], "mag": ["mx", "my", "mz"]}


class RecordingError(UserError):
    """A recording file that cannot be read; the message names file and line."""


@dataclass(eq=False)
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
        return float(1.0 / median(dt)) if len(dt) else 0.0

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


def _head(meta: Dict[str, str], columns: List[str]) -> str:
    out = [MAGIC]
    out += [f"# {k}: {v}" for k, v in meta.items()]
    out.append(",".join(columns))
    return "\n".join(out) + "\n"


def _rows_text(rec: Recording) -> str:
    parts, fmts = [rec.t[:, None]], [_FMT["t"]]
    for g in ("acc", "gyro", "mag"):
        a = getattr(rec, g)
        if a is not None:
            parts.append(np.asarray(a, float))
            fmts += [_FMT[g]] * 3
    if rec.temp is not None:
        parts.append(np.asarray(rec.temp, float)[:, None])
        fmts.append(_FMT["temp"])
    buf = io.StringIO()
    np.savetxt(buf, np.hstack(parts), fmt=",".join(fmts))
    return buf.getvalue()


def write_recording(rec: Recording, path: Union[str, os.PathLike, TextIO], flag: str = "") -> None:
    """Write a recording; to a path it is written atomically (temp file, fsync, rename), to
    ``-`` on standard output; a path that is not a regular file is refused (atomic.NotAFile)."""
    meta = dict(rec.meta)
    meta.setdefault("board", "unknown")
    meta.setdefault("rate_hz", f"{rec.rate_hz:g}")
    text = _head(meta, rec.columns()) + _rows_text(rec)
    if hasattr(path, "write"):
        path.write(text)
        return
    from .atomic import atomic_write_text
    atomic_write_text(os.fspath(path), text, flag=flag)


class RecordingWriter:
    """A recording written as it is sampled (``imucald record``): the header first, then
    each block of rows appended as it comes, fsynced at most every ``fsync_s`` s
    (atomic.GrowingFile).  Whatever ends the process (Ctrl-C, SIGTERM, SIGKILL, a power
    cut), the file holds a valid recording of what was sampled, but for the last
    ``fsync_s`` s after a power cut and a last line the readers drop with a warning."""

    def __init__(self, path: str, meta: Dict[str, str], columns: List[str], flag: str = "-o",
                 fsync_s: float = 1.0):
        from .atomic import GrowingFile
        self.columns = list(columns)
        self.rows = 0
        self._file = GrowingFile(path, _head(meta, self.columns).encode(), flag, fsync_s)

    def write(self, rec: Recording) -> None:
        """Append the rows; ``rows`` counts those written whole, also when a write fails part
        way (a full disk: the whole lines the kernel took before the error are counted)."""
        if len(rec):
            data = _rows_text(rec).encode()
            self._file.partial_bytes = 0
            try:
                self._file.write(data)
            except OSError:
                self.rows += data.count(b"\n", 0, getattr(self._file, "partial_bytes", 0))
                raise
            self.rows += len(rec)

    def close(self) -> None:
        self._file.close()


#: No MEMS sensor reads anywhere near this in g, deg/s, gauss or degC (the widest full-scale
#: ranges are +-4000 deg/s, +-400 g and +-50 gauss): a larger value is a corrupt line, which
#: would otherwise swamp every variance and mean it enters.
PLAUSIBLE_LIMIT = 1e6
_LIMIT_NOTE = " (|value| > 1e6 g, deg/s, gauss or degC)"
_MAX_HEADER_LINE = 1 << 16
_MAX_HEADER_LINES = 1000


#: a recording, raw table or pose file given as a stream (``-``, a pipe or FIFO) is read once
#: into a temporary file, at most this many bytes, and waits at most STREAM_IDLE_S for data
MAX_STREAM_BYTES = 512 << 20
STREAM_IDLE_S = 10.0
_SPOOLED: Dict[str, str] = {}
BOM = b"\xef\xbb\xbf"


def _idle_s() -> float:
    try:
        v = float(os.environ.get("IMUCALD_STREAM_IDLE_S", STREAM_IDLE_S))
        return v if 0 < v < 1e6 else STREAM_IDLE_S
    except ValueError:
        return STREAM_IDLE_S


def _spool(path: str, error) -> str:
    """Read the stream ``path`` (``-`` = stdin) once into a temporary file (removed at exit)
    and return its name, so every later open (the kind sniffed, then the file parsed) reads
    the same bytes.  A FIFO with no writer, or a stream idle for STREAM_IDLE_S, is an error."""
    import atexit
    import select
    import tempfile
    if path in _SPOOLED:
        return _SPOOLED[path]
    idle = _idle_s()
    if path == "-":
        if os.isatty(0):
            raise error("-: standard input is a terminal: pipe or redirect a file into it "
                        "(imucald calibrate - < session.csv)")
        fd, own = os.dup(0), True
    else:
        try:
            fd, own = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC), True
        except OSError as e:
            raise error(f"{path}: cannot open: {e.strerror}") from None
    tmp = tempfile.NamedTemporaryFile(prefix="imucald-stream-", suffix=".tmp", delete=False)
    _SPOOLED[path] = tmp.name
    atexit.register(lambda n=tmp.name: os.path.exists(n) and os.unlink(n))
    poll = select.poll()
    poll.register(fd, select.POLLIN | select.POLLHUP)
    total = 0
    try:
        with tmp:
            while True:
                if not poll.poll(idle * 1000):
                    what = "no writer opened it" if total == 0 else "its writer stopped writing"
                    raise error(f"{path}: nothing to read for {idle:g} s ({what}; a stream is read "
                                f"once, to its end): start the writer first, or give a file")
                try:
                    data = os.read(fd, 1 << 20)
                except BlockingIOError:
                    continue
                if not data:
                    break
                total += len(data)
                if total > MAX_STREAM_BYTES:
                    raise error(f"{path}: a stream of more than {MAX_STREAM_BYTES >> 20} MiB: save "
                                f"it to a file and give the file")
                tmp.write(data)
    except BaseException:
        del _SPOOLED[path]
        os.unlink(tmp.name)
        raise
    finally:
        if own:
            os.close(fd)
    return tmp.name


def open_binary(path: str, error=None):
    """Open ``path`` for reading bytes, or raise the one-line error saying why not.  A
    stream (``-`` for stdin, a pipe, a FIFO, a character device) is read once, whole, into
    a temporary file (_spool): the opens after the first see the same bytes."""
    import stat
    error = error or RecordingError
    if path == "-":
        return open(_spool(path, error), "rb")
    try:
        st = os.stat(path)
    except OSError as e:
        raise error(f"{path}: cannot open: {e.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a directory; give the file inside it")
    if not stat.S_ISREG(st.st_mode):
        if stat.S_ISFIFO(st.st_mode) or stat.S_ISCHR(st.st_mode):
            return open(_spool(path, error), "rb")
        raise error(f"{path}: is not a regular file, pipe or FIFO (a socket or device): give a file")
    try:
        return open(path, "rb")
    except OSError as e:
        raise error(f"{path}: cannot open: {e.strerror}") from None


#: the header's rate_hz and the t column's median step over the first RATE_CHECK_ROWS rows
#: must agree within this factor (clock error and jitter are a few %; a wrong header is 2x+)
RATE_TOLERANCE = 1.25
RATE_CHECK_ROWS = 1000

#: the largest small text file read whole (pose files, calibration and configuration files)
MAX_SMALL_BYTES = 16 << 20


def read_small(path: str, error=None, what: str = "this file", limit: int = MAX_SMALL_BYTES) -> bytes:
    """The bytes of a file read whole (at most ``limit``; a UTF-8 BOM dropped), or the one-line
    error naming it."""
    error = error or RecordingError
    with open_binary(path, error) as fh:
        try:
            raw = fh.read(limit + 1)
        except OSError as e:
            raise error(f"{path}: cannot read: {e.strerror}") from None
    if len(raw) > limit:
        raise error(f"{path}: larger than {limit >> 20} MiB, far beyond {what}: is it the right file?")
    return raw[len(BOM):] if raw.startswith(BOM) else raw


class RecordingReader:
    """An open v1 recording: header parsed and checked at once, samples read on demand.

    ``chunks()`` yields the samples as consecutive Recordings of a few thousand rows (bounded
    memory: replay and streaming detectors); ``read()`` returns the whole file as one
    Recording with contiguous float64 arrays.  Use as a context manager, or call close().
    """

    def __init__(self, path: Union[str, os.PathLike]):
        self.path = os.fspath(path)
        self._fh = open_binary(self.path)
        try:
            self._read_header()
        except BaseException:
            self._fh.close()
            raise

    def _line(self, lineno: int) -> Optional[str]:
        raw = self._fh.readline(_MAX_HEADER_LINE)
        if not raw:
            return None
        if len(raw) >= _MAX_HEADER_LINE and not raw.endswith(b"\n"):
            raise RecordingError(f"{self.path}:{lineno}: header line longer than "
                                 f"{_MAX_HEADER_LINE} bytes: not an imucald recording")
        s = decode_line(self.path, raw, lineno, self._offset, RecordingError)
        self._offset += len(raw)
        return s.rstrip("\r\n")

    def _read_header(self) -> None:
        path = self.path
        self._offset = 0
        raw = self._fh.readline(len(MAGIC) + 3 + len(BOM))
        if raw.startswith(BOM):         # a UTF-8 byte-order mark (Windows editors): skipped
            raw = raw[len(BOM):]
            self._offset = len(BOM)
        first = raw.rstrip(b"\r\n")
        if first != MAGIC.encode():
            raise RecordingError(f"{path}:1: not an imucald recording (expected {MAGIC!r}, "
                                 f"found {snippet(first)})")
        self._offset += len(raw)
        meta: Dict[str, str] = {}
        where: Dict[str, int] = {}
        lineno, header = 1, None
        while True:
            s = self._line(lineno + 1)
            if s is None:
                break
            lineno += 1
            if lineno > _MAX_HEADER_LINES:
                raise RecordingError(f"{path}:{lineno}: more than {_MAX_HEADER_LINES} header lines "
                                     f"before the column header: not an imucald recording")
            if s.startswith("#"):
                body = s[1:].strip()
                if ":" not in body:
                    raise RecordingError(f"{path}:{lineno}: header line must be '# key: value'")
                k, v = body.split(":", 1)
                meta[k.strip()] = v.strip()
                where[k.strip()] = lineno
                continue
            header = [c.strip() for c in s.split(",")]
            break
        if header is None:
            raise RecordingError(f"{path}:{lineno}: no column header (expected e.g. t,ax,ay,az)")
        hl = lineno
        for key in ("board", "rate_hz"):
            if key not in meta:
                raise RecordingError(f"{path}: header lacks required key '{key}' "
                                     f"(add a line '# {key}: ...' before the column header)")
        try:
            rate = float(meta["rate_hz"])
        except ValueError:
            rate = None
        if rate is None or not (0 < rate < np.inf):
            raise RecordingError(f"{path}:{where['rate_hz']}: header rate_hz={snippet(meta['rate_hz'])} is "
                                 f"not a number of samples per second > 0 (e.g. '# rate_hz: 100')")
        bad = [c for c in header if c not in COLUMNS]
        if bad:
            raise RecordingError(f"{path}:{hl}: unknown column {snippet(bad[0])}; allowed: "
                                 f"{', '.join(COLUMNS)}")
        if header[0] != "t":
            raise RecordingError(f"{path}:{hl}: the first column must be t")
        if len(set(header)) != len(header):
            raise RecordingError(f"{path}:{hl}: a column is repeated")
        for g, cols in _GROUPS.items():
            n = sum(c in header for c in cols)
            if n not in (0, 3):
                raise RecordingError(f"{path}:{hl}: columns {','.join(cols)} must come together")
        self.meta, self.header, self._hl, self._where = meta, header, hl, where
        half = [np.inf] + [PLAUSIBLE_LIMIT] * (len(header) - 1)
        self._spec = TableSpec(path, header, RecordingError, comma_only=True, skip="#",
                               halfwidth=half, tcol=0, limit_note=_LIMIT_NOTE)
        col = {c: i for i, c in enumerate(header)}
        self._groups = [(g, [col[c] for c in cs]) for g, cs in _GROUPS.items() if cs[0] in col]
        self._groups.insert(0, ("t", [0]))
        if "temp" in col:
            self._groups.append(("temp", [col["temp"]]))
        self._started = False

    def _blocks(self, chunk_bytes: int) -> Iterator[np.ndarray]:
        if self._started:
            raise ValueError("a RecordingReader reads its samples once")
        self._started = True
        return self._rate_checked(iter_blocks(self._fh, self._spec, self._hl + 1, self._offset,
                                              chunk_bytes=chunk_bytes or tables.CHUNK_BYTES))

    def _rate_checked(self, blocks: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
        """The blocks, the first RATE_CHECK_ROWS rows' median time step checked against the
        header's rate_hz (a header contradicting the t column made every window the
        stillness detector sized from it wrong: 'only 0 still poses found')."""
        head: List[np.ndarray] = []
        n = 0
        checked = False
        for b in blocks:
            if checked:
                yield b
                continue
            head.append(b)
            n += len(b)
            if n >= RATE_CHECK_ROWS:
                self._check_rate(np.concatenate([h[:, 0] for h in head])[:RATE_CHECK_ROWS])
                checked = True
                yield from head
                head = []
        if not checked:
            if n >= 3:
                self._check_rate(np.concatenate([h[:, 0] for h in head]))
            yield from head

    def _check_rate(self, t: np.ndarray) -> None:
        """The header's rate_hz against the first rows: their median step between distinct
        stamps, or their rows a second (a logger stamping each FIFO burst with its read time
        writes 40 rows under one stamp every 0.1 s at 400 Hz: its steps say 10 Hz)."""
        dt = np.diff(t)
        dt = dt[dt > 0]
        if len(dt) < 2:
            return
        step = float(median(dt))
        rate = float(self.meta["rate_hz"])
        rows = effective_rate(t)            # rows a second between stamps, pauses out
        if not (1 / RATE_TOLERANCE <= rate * step <= RATE_TOLERANCE
                or 1 / RATE_TOLERANCE <= rate / rows <= RATE_TOLERANCE):
            raise RecordingError(
                f"{self.path}:{self._where['rate_hz']}: header rate_hz={self.meta['rate_hz']} but the t "
                f"column steps by {step:.6g} s (median of the first rows: {1 / step:.4g} Hz) and holds "
                f"{rows:.4g} rows a second: correct the header ('# rate_hz: {rows:.4g}') or the t column")

    def _empty(self):
        return RecordingError(f"{self.path}:{self._hl}: no samples after the column header")

    def chunks(self, chunk_bytes: Optional[int] = None) -> Iterator[Recording]:
        """Consecutive Recordings (views of one block each); raises on the first bad line."""
        any_rows = False
        for b in self._blocks(chunk_bytes):
            any_rows = True
            g = {name: (b[:, ix] if len(ix) > 1 else b[:, ix[0]]) for name, ix in self._groups}
            yield Recording(t=g["t"], acc=g.get("acc"), gyro=g.get("gyro"), mag=g.get("mag"),
                            temp=g.get("temp"), meta=self.meta)
        if not any_rows:
            raise self._empty()

    def read(self, chunk_bytes: Optional[int] = None) -> Recording:
        """The whole recording; peak memory is the result plus one block."""
        n, g = collect(self._blocks(chunk_bytes), self._groups, self._fh, self._offset)
        if not n:
            raise self._empty()
        return Recording(t=g["t"], acc=g.get("acc"), gyro=g.get("gyro"), mag=g.get("mag"),
                         temp=g.get("temp"), meta=self.meta)

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> "RecordingReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_recording(path: Union[str, os.PathLike]) -> RecordingReader:
    """Open a v1 recording and check its header; raises RecordingError naming file:line."""
    return RecordingReader(path)


def iter_recording(path: Union[str, os.PathLike], chunk_bytes: Optional[int] = None) -> Iterator[Recording]:
    """The samples of a recording as consecutive chunks (see RecordingReader.chunks)."""
    with RecordingReader(path) as r:
        yield from r.chunks(chunk_bytes)


def read_recording(path: Union[str, os.PathLike]) -> Recording:
    """Read a whole v1 recording.  Raises RecordingError naming file:line on any defect."""
    with RecordingReader(path) as r:
        return r.read()
