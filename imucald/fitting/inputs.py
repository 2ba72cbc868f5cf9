"""Loading calibration inputs: a recording, a pose file, or a raw numeric table.

A raw table (no imucald magic line) is whitespace- or comma-separated numbers
whose columns are named by ``columns`` (e.g. ``t,ax,ay,az``); sensor columns
in raw counts are converted with ``(value - nominal_offset) / nominal_scale``, one
number for every sensor or one per sensor (``{"accel": 16384, "gyro": 131}``: an
MPU-6050's counts per g and per deg/s).
The time column is ``t`` in seconds, or ``t_ms`` / ``t_us`` / ``t_ns`` in milli-, micro- or
nanoseconds (a logger's millis() or micros(), a phone's sensor timestamps).
This is how the IMU-TK Xsens files (ASCII, unsigned 16-bit counts) are read.

Lines that are blank or start with ``#`` or ``%`` are skipped, and so are
non-numeric lines before the first row of numbers (a column header).  Every
named column must hold finite numbers, sensor values within
:data:`imucald.files.recording.PLAUSIBLE_LIMIT` after scaling, and t must not
decrease; otherwise the one-line error names file:line and the column.  Columns
named ``-`` are skipped (any number).  The body is parsed in bulk by
:mod:`imucald.files.tables`.
"""
from __future__ import annotations

import math
import os
import re
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from ..errors import UserError
from ..files.recording import (BOM, COLUMNS, MAGIC, PLAUSIBLE_LIMIT, Recording, open_binary,
                                read_recording)
from ..numerics.npstats import median
from ..files.tables import TIME_UNITS, TableSpec, collect, decode_line, header_key, iter_blocks, warn
from .stillness.poses import POSES_MAGIC, read_poses
from ..numerics.rates import effective_rate

__all__ = ["input_kind", "check_board", "load_input", "read_table", "join_tables", "stuck_columns", "stuck_message"]

_GROUP_COLUMNS = {"acc": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz"), "mag": ("mx", "my", "mz")}
_NAMES = {"acc": "accel", "gyro": "gyro", "mag": "mag"}        # as --nominal-scale names them
#: a nominal scale or offset: one number for every sensor, or one per sensor by name
PerSensor = Union[float, Dict[str, float]]
#: seconds per unit of a raw table's time column, by name (files/tables.TIME_UNITS)
TIME_COLUMNS_S_PER_UNIT = {k: s for k, (_, s) in TIME_UNITS.items()}
_UNIT = {k: u for k, (u, _) in TIME_UNITS.items()}
#: the step of a raw table's time column, s: an IMU read at 1 Hz to 10 kHz (the supported chips'
#: rates, LIMITS["rate"] of the CLI).  Outside, the column is refused (:func:`_table_rate`): a
#: column in ms read as s steps 1000x too far (the freeimu warm-up: 17 "s")
STEP_RANGE_S = (1e-4, 1.0)


_AXES = {_NAMES[g]: cols for g, cols in _GROUP_COLUMNS.items()}      # by sensor name
#: fewer samples than this: no claim that an axis is stuck (see :func:`stuck_columns`)
STUCK_MIN_SAMPLES = 50


def stuck_columns(x: Optional[np.ndarray], sensor: str, min_rows: int = STUCK_MIN_SAMPLES) -> List[str]:
    """The columns of ``x``, the (N, 3) samples of ``sensor`` ('accel', 'gyro' or 'mag': it
    names the columns) or its pose means (with ``min_rows`` 3: a pose file, the daemon's
    poses), that hold one value in every row, each as
    e.g. ``'gz (always 0)'``: a dead or stuck axis, or a column mapped to nothing.  Such a
    column carries no measurement: no noise, no pose-to-pose change, so no fit or diagnosis
    can use it (gap's twin divided by its zero variance; calibrate fitted the other axes and
    wrote a file).  Empty when the sensor is absent, every column moves, or there are fewer
    than ``min_rows`` rows (:data:`STUCK_MIN_SAMPLES` samples: too few to tell a dead axis
    from a live one, whose noise of a few LSB moves it every few samples)."""
    if x is None or len(x) < min_rows:
        return []
    x = np.asarray(x, float)
    out = []
    for k in range(x.shape[1]):
        col = x[:, k][np.isfinite(x[:, k])]
        if col.size == 0 or np.all(col == col[0]):
            out.append(f"{_AXES[sensor][k]} ({'no finite value' if col.size == 0 else f'always {col[0]:g}'})")
    return out


def stuck_message(stuck: Sequence[str], row: str = "sample") -> str:
    """One line for :func:`stuck_columns`' answer: what is wrong and what to check (``row``:
    'sample', or 'pose' for a pose file's means)."""
    many = len(stuck) > 1
    return (f"column{'s' if many else ''} {', '.join(stuck)} hold{'' if many else 's'} one value in "
            f"every {row}: a dead or stuck axis or a column mapped to nothing (check the sensor's "
            f"wiring, and for a raw table the columns given to --columns)")


def _first_line(path: str) -> str:
    with open_binary(path, UserError) as fh:
        raw = fh.readline(4096)
    return raw[len(BOM):].decode("utf-8", errors="replace").rstrip("\r\n") if raw.startswith(BOM) \
        else raw.decode("utf-8", errors="replace").rstrip("\r\n")


def _alias_table() -> Dict[str, str]:
    """A logger's column names as imucald's (lower case, '_', ' ', '.', '-' and units in
    brackets left out): Arduino sketches' AcX/GyX/Tmp, phone apps' accX, ROS's
    linear_acceleration.x."""
    out = {"t": "t", "time": "t", "timestamp": "t", "ts": "t", "seconds": "t", "times": "t",
           "tms": "t_ms", "timems": "t_ms", "millis": "t_ms", "ms": "t_ms",
           "tus": "t_us", "timeus": "t_us", "micros": "t_us", "us": "t_us",
           "tns": "t_ns", "timens": "t_ns", "ns": "t_ns",
           "temp": "temp", "tmp": "temp", "temperature": "temp", "tempc": "temp", "die": "temp"}
    stems = {"a": ("a", "ac", "acc", "accel", "accelerometer", "acceleration", "linearacceleration"),
             "g": ("g", "gy", "gyr", "gyro", "gyroscope", "angularvelocity", "rot", "rate"),
             "m": ("m", "mag", "magn", "magnet", "magnetometer", "magneticfield", "compass")}
    out.update({s + ax: k + ax for ax in "xyz" for k, ss in stems.items() for s in ss})
    return out


_ALIASES = _alias_table()


def _columns_from_header(line: str) -> str:
    """--columns for a header line of names, every name read as one of imucald's columns by
    :data:`_ALIASES` (a name it cannot place: '-', skipped), or '' when it is not a header of
    names (a number in it) or places no sensor column."""
    names = [n.strip().strip('"') for n in re.split(r"[,;\t]" if re.search(r"[,;\t]", line) else r"\s+", line.strip())]
    if not names or any(_numeric([n]) for n in names if n):
        return ""
    keys = [re.sub(r"[\s_.\-]|\(.*?\)|\[.*?\]", "", n.lower()) for n in names]
    # a ROS `rostopic echo -p` export: %time in ns, field.linear_acceleration.x, ...
    keys = ["tns" if k == "%time" else k[5:] if k.startswith("field") else k for k in keys]
    cols = [_ALIASES.get(k, "-") for k in keys]
    # a time named with its unit in brackets: "Time (ms)", "timestamp [us]"
    units = {"s": "t", "ms": "t_ms", "us": "t_us", "\u00b5s": "t_us", "ns": "t_ns"}
    for j, n in enumerate(names):
        u = re.search(r"[(\[]\s*([^)\]]*?)\s*[)\]]", n)
        if cols[j].startswith("t") and cols[j] != "temp" and u and u.group(1).lower() in units:
            cols[j] = units[u.group(1).lower()]
    real = [c for c in cols if c != "-"]
    if not any(c[0] in "agm" and len(c) == 2 for c in real) or len(real) != len(set(real)):
        return ""
    return ",".join(cols)


def _numeric(parts) -> bool:
    try:
        [float(p) for p in parts]
        return True
    except ValueError:
        return False


def read_table(path: str, columns: Sequence[str], nominal_scale: PerSensor = 1.0,
               nominal_offset: PerSensor = 0.0, rate_hz: Optional[float] = None,
               flag: str = "--columns", board: Optional[str] = None) -> Recording:
    """A headerless numeric table as a Recording (units after nominal scaling).  ``flag``:
    the option that named its columns, in messages (``--join-columns`` for a table joined to
    another: it takes no --rate-hz, so its time stamps must place its rows).  ``board``: the
    board it was logged from (--board), else 'unknown'."""
    cols = list(columns)
    allowed = COLUMNS + [k for k in TIME_COLUMNS_S_PER_UNIT if k not in COLUMNS]
    bad = [c for c in cols if c not in allowed and c != "-"]
    if bad:
        raise UserError(f"{flag}: unknown column {bad[0]!r}; allowed {', '.join(allowed)} "
                        f"(or - to skip one)")
    named = [c for c in cols if c != "-"]
    if len(set(named)) != len(named):
        raise UserError(f"{flag}: a column is repeated in {','.join(cols)}")
    times = [c for c in cols if c in TIME_COLUMNS_S_PER_UNIT]
    if len(times) > 1:
        raise UserError(f"{flag}: two time columns ({', '.join(times)}): name one, and - for the other")
    t_name = times[0] if times else None
    present = [g for g, ks in _GROUP_COLUMNS.items() if any(k in cols for k in ks)]
    scales = _per_sensor(nominal_scale, "--nominal-scale", present, cols)
    offsets = _per_sensor(nominal_offset, "--nominal-offset", present, cols, 0.0)
    t_scale, t_offset = _temp_conversion(nominal_scale, nominal_offset, cols)
    for g in present:
        if not math.isfinite(scales[g]) or scales[g] == 0:
            raise UserError(f"--nominal-scale {scales[g]:g} ({_NAMES[g]}): must be a finite, non-zero "
                            f"number (counts per unit, e.g. 16384)")
        if not math.isfinite(offsets[g]):
            raise UserError(f"--nominal-offset {offsets[g]:g} ({_NAMES[g]}): must be a finite number "
                            f"(counts at zero input, e.g. 32768)")
    if rate_hz is not None and not (0 < rate_hz < math.inf):
        raise UserError(f"--rate-hz {rate_hz}: must be a number of samples per second > 0")
    group = {k: g for g, ks in _GROUP_COLUMNS.items() for k in ks}
    centre = [offsets[group[c]] if c in group else (t_offset if c == "temp" else 0.0) for c in cols]
    half = [PLAUSIBLE_LIMIT * abs(scales[group[c]]) if c in group else
            (PLAUSIBLE_LIMIT * t_scale if c == "temp" else np.inf) for c in cols]
    spec = TableSpec(path, cols, UserError, comma_only=False, skip="#%", centre=centre,
                     halfwidth=half, tcol=cols.index(t_name) if t_name else None,
                     checked=[c != "-" for c in cols],
                     limit_note=" (|value| > 1e6 g, deg/s, gauss or degC after --nominal-scale)")
    with open_binary(path, UserError) as fh:
        lineno, offset, comma, quoted, spec.header_line = _first_row(fh, path, cols)
        if comma:
            warn(f"{path}:{lineno}: read as a spreadsheet's export: ';' or whitespace between "
                 f"values, ',' (if any) as the decimal mark")
        if comma or quoted:
            fh = _Translated(fh, _translation(comma, quoted))
            spec.source_line = lambda ln: _file_line(path, ln)
        idx = {name: i for i, name in enumerate(cols) if name != "-"}
        groups = [(k, [idx[k]]) for k in (t_name, "temp") if k in idx]
        for g, ks in _GROUP_COLUMNS.items():
            if all(k in idx for k in ks):
                groups.append((g, [idx[k] for k in ks]))
        n, c = collect(iter_blocks(fh, spec, lineno, offset), groups, fh, offset)
    if not n:
        raise UserError(f"{path}: no whole numeric rows (expected {len(cols)} numbers per line: "
                        f"{','.join(cols)})")
    rows = _drop_failed_reads(path, c, n)     # the rows kept (their numbers: the time without a t column)
    for g in ("acc", "gyro", "mag"):
        if g in c:
            c[g] -= offsets[g]
            c[g] /= scales[g]
    if "temp" in c and (t_scale, t_offset) != (1.0, 0.0):   # counts, converted when named (temp=N)
        c["temp"] = (c["temp"] - t_offset) / t_scale
    for msg in _unit_warnings(path, c, nominal_scale):
        warn(msg)
    if t_name:
        t = c.pop(t_name) * TIME_COLUMNS_S_PER_UNIT[t_name] if t_name != "t" else c.pop("t")
        rate = _table_rate(path, t, t_name, rate_hz, joined=flag != "--columns")
        if not rate_hz:
            rate = _burst_rate(t, c) or rate
    else:
        if not rate_hz:
            raise UserError(f"{path}: no time column (t, t_ms, t_us or t_ns): give --rate-hz")
        rate = rate_hz
        t = rows / rate                 # a failed read left out is a sample lost, not closed up
    meta = {"board": board or "unknown", "rate_hz": f"{rate:g}", "source": os.path.basename(path)}
    return Recording(t=t, acc=c.get("acc"), gyro=c.get("gyro"), mag=c.get("mag"),
                     temp=c.get("temp"), meta=meta)


def _drop_failed_reads(path: str, c: Dict[str, np.ndarray], n: int) -> np.ndarray:
    """Rows whose every accelerometer and gyro value (and magnetometer's, when logged) is the
    same number as written, before --nominal-scale: a read that failed and was logged anyway
    (an MPU-6050 on a disturbed I2C bus returns 0x0000 or 0xFFFF in every register: rows of
    0 or -1 counts).  No sensor reads one value on six axes at once, so they are taken out,
    with one warning, as lost samples.
    Kept, they made poses of their own and split real ones (a cold review: 20 rows of zeros
    in 22,627 gave 36 poses for 28 holds and the gyro's scale 0.1-0.3 % off, z up to 4).
    Returns the numbers of the rows kept."""
    groups = [g for g in ("acc", "gyro", "mag") if g in c]
    every = np.arange(n)
    if "acc" not in groups or "gyro" not in groups or n == 0:
        return every
    x = np.concatenate([c[g] for g in groups], axis=1)
    bad = np.all(x == x[:, :1], axis=1)
    k = int(bad.sum())
    if k == 0 or k == n:        # every row alike: not a few failed reads (stuck columns say it)
        return every
    vals = ", ".join(f"{v:g}" for v in np.unique(x[bad, 0])[:3])
    warn(f"{path}: {k} rows read one value ({vals}) on every axis: reads that failed (an I2C "
         f"error logged as data); left out as lost samples")
    keep = ~bad
    for key in list(c):
        c[key] = c[key][keep]
    return every[keep]


#: a decimal-comma table read as an ordinary one: ',' -> '.', ';' -> ' ' (byte for byte, so
#: every line number and byte offset of an error stays the file's own)
_DECIMAL_COMMA = bytes.maketrans(b",;", b". ")


#: a table of quoted numbers ("0.01","9.81") read as an ordinary one: '"' -> ' '
_QUOTES = (b'"', b" ")


def _translation(comma: bool, quoted: bool) -> bytes:
    """The byte table a decimal-comma and/or quoted table is read through."""
    src, dst = (b",;", b". ") if comma else (b"", b"")
    if quoted:
        src, dst = src + _QUOTES[0], dst + _QUOTES[1]
    return bytes.maketrans(src, dst)


def _quoted(s: str):
    """(the quoted fields, whether a ',' stands between them) of a row, or None when it has
    no (balanced) double quotes."""
    if '"' not in s or s.count('"') % 2:
        return None
    inside = re.findall(r'"([^"]*)"', s)
    return (inside, "," in re.sub(r'"[^"]*"', "", s)) if inside else None


def _quoted_numbers(s: str) -> bool:
    """Whether a row's values are written in double quotes, none with a ',' inside unless no
    ',' stands between them (``"0,61";"0,30"``: a decimal comma, ';' between).  A quoted
    "0,61" with ',' between the values is a decimal comma in a ','-separated file: read
    without its quotes it would be two numbers (:func:`_quoted_comma_message`)."""
    q = _quoted(s)
    # "" or "a b" (a skipped text column) would lose or split a field as spaces: read as before
    if q is None or any(not f or re.search(r"\s", f) for f in q[0]):
        return False
    return not (any("," in f for f in q[0]) and q[1])


def _quoted_comma_message(s: str, path: str, lineno: int) -> Optional[str]:
    """The error for a row of quoted decimal-comma values with ',' between them, or None."""
    qs = _quoted(s)
    if qs is None or not qs[1]:
        return None
    q = next((q for q in qs[0] if _COMMA_NUMBER.match(q.strip())), None)
    if q is None:
        return None
    return (f'{path}:{lineno}: values in quotes with "," as their decimal mark ("{q}") and "," '
            f'between them: export the table with ";" between values or "." as the decimal mark')


class _Translated:
    """A binary file whose bytes are read through ``bytes.translate(table)``; seeking, the
    position and the descriptor are the file's own (the translation keeps every length)."""

    def __init__(self, fh, table: bytes):
        self._fh, self._table = fh, table

    def read(self, n: int = -1) -> bytes:
        return self._fh.read(n).translate(self._table)

    def readline(self, n: int = -1) -> bytes:
        return self._fh.readline(n).translate(self._table)

    def __getattr__(self, name):
        return getattr(self._fh, name)


def _file_line(path: str, lineno: int) -> Optional[str]:
    """Line ``lineno`` of the file as written (for an error's quote), or None."""
    try:
        with open(path, "rb") as fh:
            for i, raw in enumerate(fh, 1):
                if i == lineno:
                    return raw.decode("utf-8", "replace").lstrip("\ufeff")
    except OSError:
        return None
    return None


#: a number written with the comma as its decimal mark: digits on both sides of it, as
#: 0,01 or -1,5E-3 (a CSV's "10," has none after it)
_COMMA_NUMBER = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")


def _decimal_comma(s: str, ncols: int, cols: Optional[Sequence[str]] = None) -> bool:
    """Whether a row is a spreadsheet's or phyphox's export in a locale whose decimal mark is
    the comma: ';' or whitespace between values (``0,01;0;9,81``, ``0,01<TAB>9,81``,
    ``12;-40;16384``).  Its format decides, not the count (a wrong --columns then gets the
    count's own message, "expected 4 values, found 5"), except that a row which reads as
    ``ncols`` comma-separated numbers stays a CSV (``0,5`` for two columns).  ``cols``: the
    columns, whose skipped ones ('-') may hold text (a date and time skipped)."""
    if ";" not in s and not any(_COMMA_NUMBER.match(t) for t in s.split()):
        return False
    toks = s.replace(";", " ").split()
    if cols is not None and len(toks) == len(cols):
        toks = [t for t, c in zip(toks, cols) if c != "-"]
    if not toks or not all(_COMMA_NUMBER.match(t) or _numeric([t]) for t in toks):
        return False
    plain = s.replace(",", " ").split()
    return not (len(plain) == ncols and _numeric(plain))


#: a date and time as loggers write them (ISO 8601, with 'T' or a space; a time of day alone,
#: as a serial terminal's timestamps): a time column imucald cannot read as a number
_DATETIME = re.compile(r"^(\d{4}-\d{2}-\d{2}([T ]\d{1,2}:\d{2}(:\d{2}([.,]\d+)?)?)?"
                       r"(Z|[+-]\d{2}:?\d{2})?|\d{1,2}:\d{2}:\d{2}([.,]\d+)?)$")


def _datetime_column(s: str, cols: Sequence[str]) -> Optional[tuple]:
    """(index, field, fields it is read as) of the named column of row ``s`` that holds a date or a time of day
    while the other named columns hold numbers, or None.  The fields are split at the row's
    ';' (a decimal-comma table), else tab, else ',', else whitespace (a date and its time
    there are one field).  Only a time column (t, t_ms, ...) or the first column is taken for
    one: a date where a sensor is named means the columns are not the file's."""
    sep = next((c for c in ";\t," if c in s), None)
    if sep is None:          # "2026-01-01 12:00:00.0 0.01 ...": the date and time are one field
        joined = re.sub(r"(\d{4}-\d{2}-\d{2}) +(\d{1,2}:\d{2})", "\\1\x00\\2", s)
        fields = [f.replace("\x00", " ") for f in joined.split()]
    else:
        fields = [f.strip() for f in s.split(sep)]
    if len(fields) != len(cols):
        return None
    named = [i for i, c in enumerate(cols) if c != "-"]
    hits = [i for i in named if _DATETIME.match(fields[i]) and (i == 0 or cols[i] in TIME_COLUMNS_S_PER_UNIT)]
    dec = (lambda f: f.replace(",", ".")) if sep == ";" else (lambda f: f)     # a decimal comma
    if len(hits) != 1 or not _numeric([dec(fields[i]) for i in named if i != hits[0]]):
        return None
    # the fields the readers will split it into: at ',' and white space, or (a decimal-comma
    # table, its ',' read as '.') at white space
    f = fields[hits[0]]
    return hits[0], f, len((f if sep == ";" else f.replace(",", " ")).split())


def _datetime_message(path: str, lineno: int, cols: Sequence[str], i: int, field: str, ntok: int) -> str:
    """The one-line error for a time column written as a date and time (:func:`_datetime_column`:
    ``ntok`` fields as the readers split it, one '-' each)."""
    skip = ",".join(",".join(["-"] * ntok) if j == i else c for j, c in enumerate(cols))
    return (f"{path}:{lineno}: column {i + 1} ({cols[i]}) reads {field!r}, a date and time, not a "
            f"number: skip it (--columns {skip}) and give the sample rate (--rate-hz), or write the "
            f"time as a number (t: s, t_ms: ms, t_us: us, t_ns: ns)")


def _first_row(fh, path: str, cols: Sequence[str]):
    """(line number, byte offset, decimal comma, quoted, header) of a raw table's first row of
    numbers, ``fh`` left there: blank, comment (#, %) and header lines before it skipped, and
    a UTF-8 byte-order mark.  Decimal comma: the row is written with ';' or whitespace between
    values and ',' as the decimal mark (:func:`_decimal_comma`; a row of whole numbers leaves
    it to the next row holding a ',' or ';').  Quoted: its values are in double quotes
    (:func:`_quoted_numbers`), read as if the quotes were spaces.  Last, the non-comment
    line skipped right above it (its header, as :class:`TableSpec` keeps it; header_key).  A row whose time is a date and time, or of quoted decimal commas between
    commas, is said (in place of "no row of numbers") only when no row of numbers follows: a
    logger's metadata line above its table may look like one."""
    lineno, offset = 1, 0
    if fh.read(len(BOM)) == BOM:
        offset = len(BOM)
    fh.seek(offset)
    header, pending = "", None
    while True:
        raw = fh.readline(1 << 16)
        if lineno > 1000 or (len(raw) >= 1 << 16 and not raw.endswith(b"\n")):
            raise UserError(pending or f"{path}:{lineno}: no row of {len(cols)} numbers in the first "
                                       f"{lineno} lines: not a numeric table ({','.join(cols)})")
        if not raw:
            raise UserError(pending or f"{path}: no numeric rows (expected {len(cols)} numbers per line: "
                                       f"{','.join(cols)})")
        s = decode_line(path, raw, lineno, offset).strip()
        quoted = _quoted_numbers(s)
        if quoted:
            s = s.replace('"', " ").strip()
        if s and s[0] not in "#%":
            comma = _decimal_comma(s, len(cols), cols)
            toks = s.replace(",", " ").split()
            # a row of numbers; or of numbers where the columns are named and text where they are
            # skipped ('-': a ROS export's frame_id "imu_link" was "not a numeric table")
            if comma or _numeric(toks) or (len(toks) == len(cols) and "-" in cols and
                                           _numeric([t for t, c in zip(toks, cols) if c != "-"])):
                if not comma and "," not in s and ";" not in s:
                    # a row of whole numbers (t = 0, counts) says nothing of the decimal mark
                    comma = _decimal_comma_ahead(fh, path, lineno + 1, offset + len(raw), len(cols))
                fh.seek(offset)
                return lineno, offset, comma, quoted, header
            if pending is None:
                dt = _datetime_column(s, cols)
                pending = _datetime_message(path, lineno, cols, *dt) if dt else _quoted_comma_message(s, path, lineno)
            header = header_key(decode_line(path, raw, lineno, offset))
        lineno, offset = lineno + 1, offset + len(raw)


def _decimal_comma_ahead(fh, path: str, lineno: int, offset: int, ncols: int, rows: int = 50) -> bool:
    """:func:`_decimal_comma` on the first of the next ``rows`` lines that holds a ',' or a
    ';' (False when none does)."""
    for _ in range(rows):
        raw = fh.readline(1 << 16)
        if not raw:
            return False
        s = decode_line(path, raw, lineno, offset).strip()
        if "," in s or ";" in s:
            return _decimal_comma(s, ncols)
        lineno, offset = lineno + 1, offset + len(raw)
    return False


def _temp_conversion(nominal_scale: PerSensor, nominal_offset: PerSensor, cols: Sequence[str]):
    """(counts per degC, counts at 0 degC) of a temperature column: (1, 0), degC as it is,
    unless --nominal-scale and --nominal-offset both name ``temp`` (one number is for the
    sensors' columns).  An MPU-6050's TEMP_OUT is temp=340 and temp=-12420.2 (its datasheet's
    T = counts / 340 + 36.53).  One without the other is refused: a scale without its offset
    reads a warm-up as -23..-8 degC, inside any die's range, so nothing would say so, and the
    file's thermal terms would never act on a board reading degC."""
    named = [o for o, v in (("--nominal-scale", nominal_scale), ("--nominal-offset", nominal_offset))
             if isinstance(v, dict) and "temp" in v]
    if not named:
        return 1.0, 0.0
    if len(named) == 1:
        v = (nominal_scale if named[0] == "--nominal-scale" else nominal_offset)["temp"]
        plain = (named[0] == "--nominal-scale" and float(v) == 1.0) or (named[0] == "--nominal-offset" and float(v) == 0.0)
        raise UserError(f"{named[0]} temp=N without {'--nominal-offset' if named[0] == '--nominal-scale' else '--nominal-scale'} "
                        f"temp=N: a temperature in counts needs both (an MPU-6050: --nominal-scale temp=340 "
                        f"and --nominal-offset temp=-12420.2, from T = counts / 340 + 36.53)"
                        + (f"; a column already in degC needs neither: leave temp= out of {named[0]}" if plain else ""))
    if "temp" not in cols:
        raise UserError("--nominal-scale temp=N: no temp column in --columns to convert")
    scale, offset = float(nominal_scale["temp"]), float(nominal_offset["temp"])
    if not scale > 0:
        raise UserError(f"--nominal-scale temp={scale:g}: must be the counts per degC, a number > 0 "
                        f"(an MPU-6050: 340)")
    return scale, offset


def _per_sensor(value, option: str, present: Sequence[str], cols: Sequence[str],
                temp_only: Optional[float] = None) -> dict:
    """``value`` of ``option`` (one number for every sensor, or a mapping accel/gyro/mag/temp ->
    number) for each sensor group in ``present``: a mapping must name every sensor whose
    columns the table has (one accelerometer scale left on a gyro's counts reads 131 counts
    per deg/s as 1 deg/s a count, a plausible but wrong number); an offset naming temp alone
    (``temp_only``: the sensors' value then, 0) is the one exception."""
    if not isinstance(value, dict):
        return {g: float(value) for g in present}
    if temp_only is not None and not any(k in value for k in _NAMES.values()):
        return {g: temp_only for g in present}
    for g in present:
        if _NAMES[g] not in value:
            have = ",".join(k for k in _GROUP_COLUMNS[g] if k in cols)
            raise UserError(f"{option}: no value for the {_NAMES[g]} columns ({have}): add "
                            f"{_NAMES[g]}=N to it ({_NAMES[g]}=1 when they are in its units already)")
    return {g: float(value[_NAMES[g]]) for g in present}


#: a raw table's median |accelerometer|, g, after --nominal-scale: about 1 at rest and in a
#: hand's motion; at or above the first, counts (or mg) read as g; between the next two, m/s^2;
#: below the last, with a scale given, a file already in g divided by it
ACC_MEDIAN_COUNTS_G, ACC_MEDIAN_SI_G, ACC_MEDIAN_TINY_G = 20.0, (8.8, 10.8), 0.1
#: a die temperature's plausible median, degC (every supported chip's operating range, -40..85,
#: with margin): outside it, counts (an MPU-6050's TEMP_OUT) read as degC
TEMP_MEDIAN_RANGE_C = (-60.0, 150.0)
#: the same of the magnetometer, gauss (Earth's field 0.25-0.65): at or above the first, counts
#: or milligauss; from the second, microtesla or counts at a low gain (230-390 per gauss);
#: below the last, with a scale given, a file already in gauss divided by it
MAG_MEDIAN_COUNTS_GAUSS, MAG_MEDIAN_UT_GAUSS, MAG_MEDIAN_TINY_GAUSS = 200.0, 10.0, 0.05


def _median_norm(x: np.ndarray) -> float:
    return float(median(np.sqrt(np.einsum("ij,ij->i", x, x))))


def _unit_warnings(path: str, c: dict, nominal_scale) -> List[str]:
    """Warnings for a raw table's accelerometer and magnetometer in units other than those the
    fit takes (g, gauss), by the median magnitude of their rows: counts without
    --nominal-scale, m/s^2, microtesla, a scale given to a file already in g or gauss; and a
    temperature column in counts (its median outside any die's range).  Each reads as
    plausible numbers that a fit then fails on ('no still moment: hold the board still') or
    that apply writes out; a warning, not a refusal, since a centrifuge, free fall or a table
    whose other sensors the command does not use is no error (a cold review)."""
    given = "" if (isinstance(nominal_scale, dict) or nominal_scale != 1.0) else " (none given)"
    out = []
    acc, mag = c.get("acc"), c.get("mag")
    if acc is not None and len(acc):
        a = _median_norm(acc)
        s = float(nominal_scale.get("accel", 1.0) if isinstance(nominal_scale, dict) else nominal_scale)
        say = f"{path}: the accelerometer reads a median |a| of {a:.4g} g after --nominal-scale{given}"
        if a >= ACC_MEDIAN_COUNTS_G:
            # with a scale given (a gyro's, or per m/s^2 read as per g), the median's counts
            at = f"; the scale that reads this median as 1 g is {s * a:.4g}" if s != 1.0 else ""
            out.append(f"{say}: raw counts (or mg)? give --nominal-scale, its counts per g, e.g. 16384 "
                       f"for an MPU-6050 at +-2 g, 256 for an ADXL345 at full resolution "
                       f"(accel=N,gyro=N when the gyro's differ; - in --columns leaves a sensor out){at}")
        elif ACC_MEDIAN_SI_G[0] <= a <= ACC_MEDIAN_SI_G[1] and s != 1.0:
            # counts per m/s^2 (a SOURCE's or datasheet's figure) given as counts per g
            out.append(f"{say}: is {s:g} counts per m/s^2? counts per g are {s * 9.80665:.6g}: give "
                       f"--nominal-scale accel={s * 9.80665:.6g}")
        elif ACC_MEDIAN_SI_G[0] <= a <= ACC_MEDIAN_SI_G[1]:
            out.append(f"{say}: m/s^2? give --nominal-scale accel=9.80665 (and gyro=0.0174533 for rad/s)")
        elif a < ACC_MEDIAN_TINY_G and not given:
            out.append(f"{say}: already in g? then leave --nominal-scale out")
    if mag is not None and len(mag):
        m = _median_norm(mag)
        say = f"{path}: the magnetometer reads a median |m| of {m:.4g} gauss after --nominal-scale{given}"
        if m >= MAG_MEDIAN_COUNTS_GAUSS:
            out.append(f"{say}: raw counts or milligauss? give --nominal-scale mag=N, its counts per "
                       f"gauss (1090 for an HMC5883L at its default gain; 1000 for mG)")
        elif m >= MAG_MEDIAN_UT_GAUSS:
            out.append(f"{say}: microtesla (--nominal-scale mag=100) or counts at a low gain (mag=N, "
                       f"its counts per gauss: 230-390 for an HMC5883L's lower gains)?")
        elif m < MAG_MEDIAN_TINY_GAUSS and not given:
            out.append(f"{say}: already in gauss? then leave its --nominal-scale out (mag=1)")
    temp = c.get("temp")          # finite: the reader refuses a NaN with its file:line
    if temp is not None and len(temp):
        m = float(median(temp))
        lo, hi = TEMP_MEDIAN_RANGE_C
        if not lo <= m <= hi:
            out.append(f"{path}: the temperature reads a median of {m:.5g} degC, outside any die's: "
                       f"raw counts? give --nominal-scale temp=N and --nominal-offset temp=N (an "
                       f"MPU-6050: temp=340 and temp=-12420.2, from T = counts / 340 + 36.53)")
        elif not lo <= float(temp.min()) <= float(temp.max()) <= hi:
            # a plausible median but a span no die reaches (a conversion off in its slope, a
            # logger's glitches): thermal terms fitted over it would be extrapolated far
            k = int(np.count_nonzero((temp < lo) | (temp > hi)))
            out.append(f"{path}: the temperature spans {float(temp.min()):.4g}..{float(temp.max()):.4g} "
                       f"degC, {k} row(s) outside any die's {lo:g}..{hi:g}: check its conversion "
                       f"(--nominal-scale temp=N, --nominal-offset temp=N) or the rows")
    return out


def _burst_rate(t: np.ndarray, c: Dict[str, np.ndarray]) -> Optional[float]:
    """Rows a second (pauses out: numerics/rates.py effective_rate) when most rows share
    their stamp with the row before and differ from it: a logger that stamps each FIFO burst
    with its read time (40 rows at 400 Hz under one stamp every 0.1 s), whose steps alone
    gave 10 Hz, and the gap diagnosis, noise and the gyro's windows then took each pose as
    40 times longer than it was.  None otherwise: a row repeated with its stamp and values
    (a logger writing a sample twice) is one sample, and the distinct stamps give the rate."""
    same = np.diff(t) == 0
    x = [v for k, v in c.items() if k in ("acc", "gyro", "mag")]
    if not len(same) or same.mean() <= 0.5 or not x:
        return None
    x = np.column_stack(x)
    differ = np.any(x[1:] != x[:-1], axis=1)
    if differ[same].mean() <= 0.5:
        return None
    rate = effective_rate(t)
    return rate if rate > 0 else None


def _table_rate(path: str, t: np.ndarray, t_name: str, rate_hz: Optional[float], joined: bool = False) -> float:
    """The sample rate of a raw table (``rate_hz`` when given) from its time column ``t`` (s;
    named ``t_name``): one over the median interval between rows that advance; for a column in
    whole ms, us or ns (t_ms, t_us, t_ns) the mean of the intervals within a factor 2 of the median (a
    2.5-ms period logged in whole ms steps by 2 and 3: either median is 20 % off).
    A column far likelier in another unit is refused, naming the time columns by unit.  Judged
    on the rows a second over the column's span (a logger that stamps a FIFO's burst as it
    prints it, or a coarse clock, has steps far from its rate but rows at it): more than 1/
    STEP_RANGE_S[0], or a ``rate_hz`` more than 100x away; and on a median step of
    STEP_RANGE_S[1] or more while the rows come no faster (a pause does not move either).
    ``joined``: a table joined to another by time (no --rate-hz to fall back on: its stamps
    must place its rows)."""
    dt = np.diff(t)
    dt = dt[dt > 0]
    if not len(dt):
        if rate_hz:
            return rate_hz
        raise UserError(f"{path}: {t_name} never advances, so " + (
            "its rows cannot be placed beside the first table's" if joined else "the sample rate is unknown: give --rate-hz"))
    step = float(median(dt))
    how = "a median"
    if t_name != "t":
        step, how = float(dt[(dt >= step / 2) & (dt <= 2 * step)].mean()), "on average"
    unit = TIME_COLUMNS_S_PER_UNIT[t_name]
    rows_per_s = (len(t) - 1) / float(t[-1] - t[0])
    said = (f"{t_name} spans {(t[-1] - t[0]) / unit:.4g} {_UNIT[t_name]} over {len(t)} rows "
            f"({rows_per_s:.4g} rows a second)")
    names = "name the time column by its unit (t: s, t_ms: ms, t_us: us, t_ns: ns)"
    if rate_hz:
        if not 1e-2 <= rate_hz / rows_per_s <= 1e2:
            raise UserError(f"{path}: --rate-hz {rate_hz:g} but {said}: {names}, or leave --rate-hz out")
        return rate_hz
    lo, hi = STEP_RANGE_S
    if rows_per_s > 1 / lo:
        raise UserError(f"{path}: {said}, faster than an IMU is read at: {names}")
    if step >= hi:
        if rows_per_s * step >= 2:      # many rows a tick: a coarse clock, not a slow one
            fix = ("cannot place them beside the first table's rows" if joined else
                   f"; give --rate-hz, the rate it was logged at (about {rows_per_s:.4g} by its span)")
            raise UserError(f"{path}: {t_name} advances by {how} {step / unit:.4g} {_UNIT[t_name]} a "
                            f"row but {said}: a clock coarser than the samples{' ' if joined else ''}{fix}, "
                            f"or {names}")
        raise UserError(f"{path}: {t_name} advances by {how} {step / unit:.4g} {_UNIT[t_name]} a "
                        f"row ({1 / step:.4g} Hz), slower than an IMU is read at: {names}" +
                        ("" if joined else f"; for so low a rate give --rate-hz {1 / step:.4g}"))
    return 1.0 / step


def input_kind(path: str) -> str:
    """What a file is by its first line: 'recording', 'poses' or 'table' (anything else: a
    raw numeric table, read only with named columns); an imucald file of another version is
    refused here."""
    first = _first_line(path)
    if first == MAGIC:
        return "recording"
    if first.strip() == POSES_MAGIC:
        return "poses"
    if first.startswith("# imucald"):
        raise UserError(f"{path}:1: unsupported imucald file {first!r} "
                        f"(this version reads {MAGIC!r} and {POSES_MAGIC!r})")
    return "table"


def check_board(path: str, kind: str, board: Optional[str], meta: Dict[str, str]) -> None:
    """``--board`` on an imucald file (whose header names its board) must agree with the header:
    the same name is taken (a habit from raw tables, and scripts that pass it to every file), another
    is refused naming both (the header decides: --board names a raw table's board).  A header
    that names none, or ``unknown``, decides nothing: ``--board`` is taken into ``meta`` then
    (a cold review: it was refused, and the calibration said ``unknown``)."""
    saved = meta.get("board")
    if board is None or board == saved:
        return
    if saved in (None, "", "unknown"):
        meta["board"] = board
        return
    what = "an imucald recording" if kind == "recording" else "an imucald pose file"
    raise UserError(f"--board {board}: {path} is {what} whose header names board {saved!r}: "
                    f"drop --board (the header decides; --board names a raw table's board)")


def load_input(path: str, columns: Optional[Sequence[str]] = None, nominal_scale: PerSensor = 1.0,
               nominal_offset: PerSensor = 0.0, rate_hz: Optional[float] = None,
               join: Optional[tuple] = None, board: Optional[str] = None, applied: Sequence[str] = ()):
    """Return (kind, obj): ('recording', Recording) or ('poses', PoseSet).  An imucald file is
    read as what it is, whatever ``columns`` say.  ``join``: (path, columns) of a second raw
    table of the same session whose sensors are joined to the first's (:func:`join_tables`;
    the same nominal scale and offset, per sensor).  ``board``: a raw table's board.
    ``applied``: options the command applies to any input (not warned of as ignored)."""
    kind = input_kind(path)
    if join is not None:
        _check_join(path, kind, columns, join)
    warn_table_options(path, kind, columns, nominal_scale, nominal_offset, rate_hz, applied)
    if kind == "recording":
        rec = read_recording(path)
        check_board(path, kind, board, rec.meta)
        return "recording", rec
    if kind == "poses":
        ps = read_poses(path)
        check_board(path, kind, board, ps.meta)
        return "poses", ps
    if board is not None and columns is None:
        raise UserError(f"--board {board}: names the board of a raw table: give its --columns too")
    if columns is None:
        guess = _columns_from_header(_first_line(path))
        rate = "" if any(c.startswith("t") and c != "temp" for c in guess.split(",")) else " and --rate-hz"
        raise UserError(f"{path}: not an imucald recording or pose file; for a raw numeric "
                        + (f"table name its columns: its header reads as --columns {guess} (check each "
                           f"unit: --nominal-scale{rate})" if guess else "table name its columns, e.g. --columns t,ax,ay,az"))
    rec = read_table(path, columns, nominal_scale, nominal_offset, rate_hz, board=board)
    if join is not None:
        other = read_table(join[0], join[1], nominal_scale, nominal_offset, flag="--join-columns")
        rec = join_tables(rec, path, other, join[0])
    return "recording", rec


def warn_table_options(path: str, kind: str, columns=None, nominal_scale: PerSensor = 1.0,
                       nominal_offset: PerSensor = 0.0, rate_hz: Optional[float] = None,
                       applied: Sequence[str] = ()) -> None:
    """One warning when a raw table's options were given for an imucald file, which is read as
    it is (its header names its columns, in g, deg/s and gauss): a user who took the file for
    counts learnt nothing from a fit that came out the same (a newcomer's walk).  ``applied``:
    the options the command applies to any input itself (noise's --rate-hz)."""
    if kind not in ("recording", "poses"):
        return
    given = [o for o, v, dflt in (("--columns", columns, None), ("--nominal-scale", nominal_scale, 1.0),
                                  ("--nominal-offset", nominal_offset, 0.0), ("--rate-hz", rate_hz, None))
             if v is not None and (isinstance(v, dict) or v != dflt) and o not in applied]
    if given:
        warn(f"{path}: an imucald {kind} (its header names its columns, in g, deg/s and gauss): "
             f"{', '.join(given)} {'apply' if len(given) > 1 else 'applies'} to raw tables only and "
             f"{'are' if len(given) > 1 else 'is'} ignored")


def _check_join(path: str, kind: str, columns, join) -> None:
    """What --join needs, said before either table is read: two raw tables, each with a time
    column on the same clock, the second naming a sensor."""
    if kind != "table":
        raise UserError(f"{path}: an imucald {kind}: --join joins two raw tables (a recording holds "
                        f"its sensors together already)")
    if input_kind(join[0]) != "table":
        raise UserError(f"--join {join[0]}: an imucald file; --join takes a raw table (its columns "
                        f"named by --join-columns)")
    for option, cols in (("--columns", columns or ()), ("--join-columns", join[1])):
        if not any(c in TIME_COLUMNS_S_PER_UNIT for c in cols):
            raise UserError(f"{option}: no time column: the two tables are joined by their time "
                            f"stamps (t, t_ms, t_us or t_ns in --columns and --join-columns)")
    if not any(c in COLUMNS and c != "t" for c in join[1]):
        raise UserError(f"--join-columns {','.join(join[1])}: names no sensor column to join "
                        f"(ax,ay,az, gx,gy,gz, mx,my,mz or temp)")


#: a joined table's row is held for the first table's rows up to this many times its file's
#: usual longest step after it (the 99th percentile of its steps: a regular file's period, and
#: a logger's reception bursts are usual, 0.07 s in the sunsided files at 77 rows a second,
#: where 1.5 mean periods dropped 13 % of the rows); past its last row or across a hole in it,
#: those rows are dropped
JOIN_HOLD_STEPS = 1.5


def join_tables(rec: Recording, path: str, other: Recording, other_path: str) -> Recording:
    """``rec`` (the table at ``path``) with the sensors of ``other`` (the table at
    ``other_path``) added: row for row when the two have the same time stamps (IMU-TK's
    xsens_acc.mat and xsens_gyro.mat); otherwise each row takes ``other``'s latest row at or
    before its time, held for at most JOIN_HOLD_STEPS times ``other``'s usual longest step (a
    slower chip logged to its own file).  Rows with no such row (outside ``other``'s times, or
    in a gap in them) are dropped, with a warning.  Both tables have time columns on the same
    clock (load_input checks); a sensor (or the temperature) in both is refused."""
    both = [g for g in ("acc", "gyro", "mag", "temp") if getattr(rec, g) is not None and getattr(other, g) is not None]
    if both:
        raise UserError(f"--join {other_path}: {_JOIN_NAMES[both[0]]} columns in both tables: "
                        f"- in --columns or --join-columns leaves one out")
    if np.array_equal(rec.t, other.t):
        keep, j = np.ones(len(rec.t), bool), np.arange(len(rec.t))
    else:
        hold_s = JOIN_HOLD_STEPS * _usual_longest_step(other.t)
        j = np.searchsorted(other.t, rec.t, side="right") - 1
        keep = j >= 0
        keep[keep] = rec.t[keep] - other.t[j[keep]] <= hold_s
    if not keep.any():
        raise UserError(f"--join {other_path}: its times ({other.t[0]:.6g}..{other.t[-1]:.6g} s) "
                        f"do not overlap {path}'s ({rec.t[0]:.6g}..{rec.t[-1]:.6g} s): the two "
                        f"tables must share a clock")
    if not keep.all():
        warn(f"{path}: {int((~keep).sum())} of {len(keep)} rows dropped: no row of --join {other_path} "
             f"at their time or up to {JOIN_HOLD_STEPS:g}x its usual longest step before (outside its "
             f"times, or in a hole in them)")
    j = j[keep]
    pick = lambda a, b: a[keep] if a is not None else (b[j] if b is not None else None)
    meta = dict(rec.meta, source=f"{rec.meta.get('source', '')}+{other.meta.get('source', '')}")
    return Recording(t=rec.t[keep], acc=pick(rec.acc, other.acc), gyro=pick(rec.gyro, other.gyro),
                     mag=pick(rec.mag, other.mag), temp=pick(rec.temp, other.temp), meta=meta)


#: steps a joined table needs for its 99th percentile to be a usual step (with fewer, one hole
#: is the percentile itself)
JOIN_PERCENTILE_MIN_STEPS = 100


def _usual_longest_step(t: np.ndarray) -> float:
    """A joined table's usual longest step, s: the 99th percentile of its steps (a logger's
    bursts are usual steps); with fewer than JOIN_PERCENTILE_MIN_STEPS, the longest step
    within 5x the median (a hole of a short table is not taken for a usual step)."""
    steps = np.diff(t)
    steps = steps[steps > 0]
    if not len(steps):
        return 0.0
    if len(steps) >= JOIN_PERCENTILE_MIN_STEPS:
        return float(np.percentile(steps, 99))
    return float(steps[steps <= 5 * median(steps)].max())


_JOIN_NAMES = {"acc": "accelerometer", "gyro": "gyro", "mag": "magnetometer", "temp": "temperature"}
