"""Bulk, chunked parsing of numeric text tables with one-line errors that name the place.

Both readers use it: the recording body (comma-separated) and the raw numeric
tables of ``calibrate``/``gap`` (whitespace- or comma-separated).  The file is
read in blocks of whole lines (``CHUNK_BYTES``); each block is parsed by numpy's
C tokenizer in one call, or, when its lines are all of one fixed-width layout (MATLAB's
``save -ascii``, ``printf("%16.7e")``), by numpy arithmetic on its columns of bytes
(``_parse_fixed``: the same bits, ~3x faster).  A block that does not parse cleanly (a bad line, a
blank or comment line, a non-finite or implausible value, time going
backwards) is parsed again line by line by the reference parser below, which
defines what is accepted and raises the one-line error with file:line and the
column; so both paths accept exactly the same text and give the same numbers.

Values are checked per column: finite, and ``|x - centre| <= halfwidth`` (the
caller derives these from what the column can physically hold), and the time
column must not decrease.
"""
from __future__ import annotations

import io
import os
import re
import warnings
from typing import BinaryIO, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from ..errors import UserError, snippet
from ..numerics import blas

__all__ = ["CHUNK_BYTES", "MAX_LINE_BYTES", "TableSpec", "iter_blocks", "decode_line", "collect",
           "warn"]

CHUNK_BYTES = 1 << 20     #: bytes per block: ~15-25 k rows, ~2 MB of float64 at 11 columns
#: the longest line a table may hold: a row of 11 numbers is ~100 bytes; a longer line is
#: binary or damaged, and is refused at once instead of being gathered in memory (a 50 MB
#: line cost 674 MB before this bound)
MAX_LINE_BYTES = 1 << 16


def warn(msg: str) -> None:
    """One warning line on stderr (readers: a cut last line, a NUL tail ignored)."""
    import sys
    print(f"imucald: warning: {msg}", file=sys.stderr, flush=True)


#: a raw table's time column by name: its unit, and seconds per unit (loggers often write an
#: Arduino's millis() or micros(); Android stamps sensor events in ns)
TIME_UNITS = {"t": ("s", 1.0), "t_ms": ("ms", 1e-3), "t_us": ("us", 1e-6), "t_ns": ("ns", 1e-9)}


def _quoted(path: str) -> str:
    """``path`` quoted for a shell command in a message; shlex is imported only when a message
    needs it (its import compiles a regular expression: ~0.3 ms of every command that reads
    a table)."""
    import shlex
    return shlex.quote(path)


def _backwards(name: str, t: float, prev_t: float, lineno: int = 0, path: str = "") -> str:
    """The message for a time column ``name`` (t in s; a raw table's t_ms, t_us, t_ns) that steps
    back from ``prev_t`` to ``t``, in its unit: an Arduino's 32-bit micros() wraps every
    2**32 us (71.6 min), which a long recording in t_us meets.  A step back of more than a
    second is a logger that restarted (or a narrow counter that wrapped): sorting would mix
    two recordings, so the advice is to split the file at that line (the command that does it
    when the line is known); a small one is rows out of order."""
    unit, s_per_unit = TIME_UNITS.get(name, ("s", 1.0))
    split = (f"split the file there (head -n {lineno - 1} {_quoted(path)} > part1.csv, and the rest from line "
             f"{lineno}, below the header lines if the file has them: each part is a recording)"
             if lineno > 1 and path else "split the file there")
    if name == "t_us" and prev_t - t > 2 ** 31:
        return (f"time goes backwards ({t:.12g} us after {prev_t:.12g} us): a 32-bit micros() "
                f"counter wraps every 71.6 min; {split}, or log a wider counter")
    if (prev_t - t) * s_per_unit > 1.0:
        return (f"time goes backwards ({t:.12g} {unit} after {prev_t:.12g} {unit}): the logger "
                f"restarted or its time counter wrapped; {split}")
    return (f"time goes backwards ({t:.12g} {unit} after {prev_t:.12g} {unit}); sort the rows by "
            f"time or cut the file there")


_NAME = re.compile(r"[A-Za-z_][\w .:/()\[\]^*-]*")


#: column names that mark a row of names as a header (beside the file's own --columns names)
_HEADER_WORDS = {"t", "time", "timestamp", "t_s", "t_ms", "t_us", "ax", "ay", "az", "gx", "gy", "gz"}


def header_key(line: str) -> str:
    """A header line as :func:`_header_again` compares it: its words, whatever stood between
    them (',', ';', quotes, white space: a table read through a translation keeps its words)."""
    return " ".join(re.split(r'[\s,;"]+', line)).strip()


def _header_again(parts, names, line: str = "", header: str = "") -> bool:
    """A row of column names where numbers were expected: the file's own header line again
    (``header``: the line above its first row, :func:`header_key`), or no field a number,
    every field a name, one of them a known column's (a logger that restarted and appended wrote its header again;
    a logger's error line, "I2C,timeout", is not one)."""
    if header and header_key(line) == header:
        return True
    known = _HEADER_WORDS | {n.lower() for n in names}
    if not any(p.strip().lower() in known for p in parts):
        return False
    return all(_NAME.fullmatch(p.strip() or "-") is not None and not _is_number(p) for p in parts)


def _is_number(p: str) -> bool:
    try:
        float(p)
    except ValueError:
        return False
    return True


def _header_message(line: str, path: str, lineno: int, start: int) -> str:
    """``start``: the first of the comment lines right above the header (a recording's own
    header lines, which the second part needs: a cold review), else ``lineno``."""
    q = _quoted(path) if path else "FILE"
    return (f"a column header again ({snippet(line)}): a logger that restarted and appended? "
            f"If the time carries on below it, delete this line (sed -i '{lineno}d' {q}); if it "
            f"starts again, split the file there (head -n {start - 1} {q} > part1.csv; "
            f"tail -n +{start} {q} > part2.csv: each part is a recording)")


class TableSpec:
    """How the body of one file is laid out and checked."""

    def __init__(self, path: str, names: Sequence[str], error=UserError, comma_only: bool = True,
                 skip: str = "#", centre=None, halfwidth=None, tcol: Optional[int] = None,
                 limit_note: str = "", checked=None):
        self.path, self.names, self.error = path, list(names), error
        self.accepted = 0       #: rows read so far (the layout message needs none before it)
        self.ncol = len(self.names)
        self.comma_only, self.skip, self.tcol = comma_only, skip, tcol
        self.centre = np.zeros(self.ncol) if centre is None else np.asarray(centre, float)
        self.halfwidth = np.full(self.ncol, np.inf) if halfwidth is None else np.asarray(halfwidth, float)
        self.limit_note = limit_note
        #: columns whose values are checked (finite, within bounds); others need only be numbers
        self.checked = np.ones(self.ncol, bool) if checked is None else np.asarray(checked, bool)
        #: line number -> that line as the file writes it, or None, for a table read through a
        #: translation (a decimal-comma export: ``1,5;2`` is parsed as ``1.5 2``): an error then
        #: quotes the file's own text, not the translated one
        self.source_line = None
        #: the non-comment line right above the first row (a table's column names, as its
        #: logger wrote them; :func:`header_key`): the same line again mid-file is that header
        self.header_line = ""

    def quoted(self, lineno: int, j: int, text: str) -> str:
        """The value of column ``j`` on line ``lineno``, parsed as ``text``, as the file has it
        (a translated table's values are separated by ';' or whitespace)."""
        line = self.source_line(lineno) if self.source_line is not None else None
        toks = line.replace(";", " ").split() if line else []
        return (toks[j] if j < len(toks) else text).strip()

    def fail(self, lineno: int, msg: str):
        raise self.error(f"{self.path}:{lineno}: {msg}")


def decode_line(spec_path: str, raw: bytes, lineno: int, offset: int, error=UserError) -> str:
    """One line of UTF-8, or the one-line error naming line and byte offset."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(_not_utf8(spec_path, raw, e, lineno, offset)) from None


def _not_utf8(path, raw: bytes, e: UnicodeDecodeError, lineno: int, offset: int) -> str:
    line = lineno + raw.count(b"\n", 0, e.start)
    return (f"{path}:{line}: byte 0x{raw[e.start]:02x} at offset {offset + e.start} is not UTF-8 "
            f"text; the file is binary or damaged (re-export it as plain text, or cut the damaged "
            f"part)")


def iter_blocks(fh: BinaryIO, spec: TableSpec, lineno: int, offset: int, prev_t: float = -np.inf,
                chunk_bytes: int = CHUNK_BYTES) -> Iterator[np.ndarray]:
    """Yield (k, ncol) float64 arrays of the rows of ``fh`` from line ``lineno`` (1-based) on.

    ``offset`` is the byte offset of that line in the file (for error messages).  Bounded:
    a line longer than MAX_LINE_BYTES is an error; a tail of NUL bytes (what a power cut
    leaves on many file systems, or ``truncate -s +2G``) is skipped with one warning after
    checking, block by block, that nothing but NUL follows; a last line cut short (no
    newline at the end, not a valid row: an interrupted recording) is dropped with one
    warning.
    """
    rest = b""
    while True:
        data = fh.read(chunk_bytes)
        buf = rest + data if rest else data
        if not buf:
            return
        nul = buf.find(b"\0")
        if nul >= 0:
            start = buf.rfind(b"\n", 0, nul) + 1       # the line the NULs start in
            before = buf[:start]
            if before:
                yield from _rows(before, spec, lineno, offset, prev_t)
                lineno += before.count(b"\n")
                offset += len(before)
            _nul_tail(fh, spec, buf[start:], lineno, offset, chunk_bytes)
            return
        if data:
            cut = buf.rfind(b"\n") + 1
            if cut == 0:            # no newline within the block: keep reading
                if len(buf) > MAX_LINE_BYTES:
                    _long_line(spec, lineno, offset)
                rest = buf
                continue
            rows = _fixed_lines(buf, cut, spec, prev_t)
            if rows is not None:        # one fixed-width layout, read in place (no copy, no count)
                rest = buf[cut:]
                if len(rest) > MAX_LINE_BYTES:      # refused before the block's rows are handed out
                    _long_line(spec, lineno + len(rows), offset + cut)
                if spec.tcol is not None:
                    prev_t = rows[-1, spec.tcol]
                spec.accepted += len(rows)
                yield rows
                lineno += len(rows)
                offset += cut
                if rest and fh.seekable():      # read again with the next block: no joining copy
                    fh.seek(-len(rest), 1)
                    rest = b""
                continue
            block, rest = buf[:cut], buf[cut:]
            if len(rest) > MAX_LINE_BYTES:
                _long_line(spec, lineno + block.count(b"\n"), offset + cut)
        else:
            block, rest = buf, b""
            if not block.endswith(b"\n"):
                head = block[:block.rfind(b"\n") + 1]
                if head:
                    for rows in _rows(head, spec, lineno, offset, prev_t):
                        if spec.tcol is not None and len(rows):
                            prev_t = rows[-1, spec.tcol]
                        yield rows
                    lineno += head.count(b"\n")
                    offset += len(head)
                yield from _last_line(block[len(head):], spec, lineno, offset, prev_t)
                return
        nl = block.count(b"\n")
        for rows in _rows(block, spec, lineno, offset, prev_t, nl, at_end=not rest and _at_eof(fh)):
            if spec.tcol is not None and len(rows):
                prev_t = rows[-1, spec.tcol]
            yield rows
        lineno += nl
        offset += len(block)
        if not data:
            return



def _long_line(spec: TableSpec, lineno: int, offset: int) -> None:
    """Refuse a line longer than MAX_LINE_BYTES (no text table has one) at ``lineno``."""
    spec.fail(lineno, f"line longer than {MAX_LINE_BYTES} bytes (from byte offset {offset}): not "
                      f"a text table; the file is binary or damaged (cut the damaged part)")

def _fixed_lines(buf: bytes, cut: int, spec: TableSpec, prev_t: float) -> Optional[np.ndarray]:
    """The rows of ``buf[:cut]`` (whole lines) when they are all of one fixed-width layout and
    pass the checks, read in place; None otherwise (the caller then reads the block as any
    other).  The layout's validation covers what the general path checks first: every byte
    is one the layout allows (so ASCII, no CR, no comma but the layout's), and the line count
    is the size over the line length."""
    L = buf.find(b"\n", 0, cut) + 1
    if L < 2 or cut % L:
        return None
    comma = spec.comma_only or b"," in buf[:L]
    rows = _parse_fixed(buf, spec, cut // L, comma, cut)
    return rows if rows is not None and _ok(rows, spec, prev_t) else None


def _at_eof(fh: BinaryIO) -> bool:
    """Whether ``fh`` has been read to its end (a regular file; False when unknown: a pipe)."""
    try:
        return fh.tell() >= os.fstat(fh.fileno()).st_size
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):
        return False


def _rows(block: bytes, spec: TableSpec, lineno: int, offset: int, prev_t: float,
          nl: Optional[int] = None, at_end: bool = False):
    """The rows of one block of whole lines (a generator of at most one array); ``nl``: its
    count of newlines when the caller has it.

    An ASCII block (every numeric table in practice) goes to numpy's tokenizer as bytes: no
    decoded copy (an ``io.StringIO`` of the text holds 4 bytes a character, page-faulted afresh
    each block: that was half the reader's time).  Its lines and their characters are those of
    the text, so the fast path accepts the same and gives the same numbers; any other block is
    decoded (the one-line error when it is not UTF-8) and parsed as text."""
    if block.isascii():
        rows = _parse_fast(block, spec, prev_t, nl)
        if rows is None:
            rows = _parse_slow(block.decode("ascii"), spec, lineno, prev_t, at_end)
    else:
        try:
            text = block.decode("utf-8")
        except UnicodeDecodeError as e:
            raise spec.error(_not_utf8(spec.path, block, e, lineno, offset)) from None
        rows = _parse_fast(text, spec, prev_t, nl)
        if rows is None:
            rows = _parse_slow(text, spec, lineno, prev_t, at_end)
    if len(rows):
        spec.accepted += len(rows)
        yield rows


def _last_line(raw: bytes, spec: TableSpec, lineno: int, offset: int, prev_t: float):
    """The file's last line, which has no newline: kept when it is a valid row, else (an
    interrupted write) dropped with one warning."""
    try:
        rows = list(_rows(raw, spec, lineno, offset, prev_t))
    except UserError as e:
        warn(f"{spec.path}:{lineno}: the last line is cut short (no newline at the end of the "
             f"file: an interrupted recording?) and is ignored: {str(e).split(': ', 2)[-1]}")
        return
    yield from rows


def _nul_tail(fh: BinaryIO, spec: TableSpec, head: bytes, lineno: int, offset: int,
              chunk_bytes: int) -> None:
    """From ``head`` (the start of the line the first NUL byte is in) on, the rest of the
    file must be NUL bytes, perhaps after a cut line: then it is skipped with one warning;
    anything else after the NULs is an error naming its offset.  Read block by block:
    bounded memory, and time at the speed of reading."""
    nul = head.find(b"\0")
    cut = head[:nul]
    total = len(head) - nul
    pos = offset + len(head)
    tail = head[nul:]
    while True:
        junk = tail.strip(b"\0")
        if junk:
            at = pos - len(tail) + tail.find(junk[:1])
            # the data after may be most of the file (one stray NUL byte in a serial log): cutting
            # there threw it away; taking the NULs out keeps it, and names a line they broke
            spec.fail(lineno, f"{at - offset - nul} NUL byte(s) from byte offset {offset + nul}, then other "
                              f"data at offset {at}: the file is damaged; take the NUL bytes out "
                              f"(tr -d '\\000' < {_quoted(spec.path)} > fixed.csv; a line they broke is "
                              f"then named, unless it still reads as numbers: check the line) or cut "
                              f"the file at offset {offset + nul}")
        tail = fh.read(chunk_bytes)
        if not tail:
            break
        total += len(tail)
        pos += len(tail)
    what = f"a cut line ({snippet(cut)}) and " if cut.strip() else ""
    warn(f"{spec.path}:{lineno}: {what}{total} NUL bytes from byte offset {offset + len(cut)} to the "
         f"end (an interrupted write, e.g. a power cut) are ignored; the rows before are used")


def _parse_fast(text, spec: TableSpec, prev_t: float, count: Optional[int] = None
                ) -> Optional[np.ndarray]:
    """The block (``str``, or ``bytes`` of ASCII text) through numpy's tokenizer, or None when
    the reference parser must look.  ``count``: its newlines, when known (a UTF-8 newline is
    one byte, never part of another character: the count of the bytes is the text's)."""
    nl, cr, comma = ("\n", "\r", ",") if isinstance(text, str) else (b"\n", b"\r", b",")
    nlines = (text.count(nl) if count is None else count) + (0 if text.endswith(nl) else 1)
    if cr in text:
        text = text.replace(cr + nl, nl)
        if cr in text:
            return None
    delim = "," if spec.comma_only or comma in text else None
    if isinstance(text, bytes):
        rows = _parse_fixed(text, spec, nlines, delim is not None)
        if rows is not None:
            return rows if _ok(rows, spec, prev_t) else None
    src = io.StringIO(text) if isinstance(text, str) else io.BytesIO(text)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows = np.loadtxt(src, delimiter=delim, comments=None, ndmin=2, dtype=np.float64)
    except (ValueError, TypeError, OverflowError):
        return None
    if rows.shape != (nlines, spec.ncol) or not _ok(rows, spec, prev_t):
        return None         # blank or comment lines, wrong counts, bad values: look line by line
    return rows


# --- fixed-width tables: every line the same length, each number in the same columns ---------
# (MATLAB's ``save -ascii``, C's ``printf("%15.7e ...")``, the IMU-TK Xsens files).  Their
# numbers are read with numpy arithmetic on the columns of bytes instead of numpy's tokenizer,
# ~3x faster, and to the same bits: a number of at most 15 significant digits m and a decimal
# exponent k with |k| <= 22 is m * 10**k or m / 10**-k with both operands exact doubles
# (m < 2**53; 10**22 = 2**22 * 5**22, 5**22 < 2**53), and one IEEE multiplication or division
# of exact operands is the correctly rounded value, which is what numpy's parser (CPython's
# correctly rounded strtod) gives (Clinger 1990, "How to read floating point numbers
# accurately", the fast path).  Anything else (more digits, a larger exponent, nan, a line
# of another layout) goes to numpy's tokenizer as before.

_FIXED_NUM = re.compile(rb"([+-]?)(\d*)(?:(\.)(\d*))?(?:([eE])([+-]?)(\d{1,3}))?")
#: 10**(i - 22) for i >= 22 and 1 below; 10**(22 - i) for i <= 22 and 1 above: a value is
#: m * _P_MUL[k + 22] / _P_DIV[k + 22] (one of the two operations is exact: by 1)
_P_MUL = np.array([1.0] * 22 + [float(10 ** i) for i in range(23)])
_P_DIV = np.array([float(10 ** (22 - i)) for i in range(23)] + [1.0] * 22)
#: bytes of float64 per slice of rows in ``_parse_fixed``: 1 MB was the fastest of 0.25-2 MB
#: and the whole block (whose temporaries, ~8 MB, were mapped and page-faulted afresh)
_FIXED_SLICE_BYTES = 1 << 20
#: a sign byte's factor: ' ' and '+' +1, '-' -1, any other NaN (not a sign)
_SIGN = np.full(256, np.nan)
_SIGN[[32, 43, 45]] = 1.0, 1.0, -1.0


def _fixed_layout(row: bytes, ncol: int, comma: bool):
    """How to read a fixed-width table whose first line (without its newline) is ``row``:
    None when that line is not ``ncol`` plain decimal numbers (sign, at most 15 digits, a
    point, an exponent of at most 3 digits) between separators; else a tuple: the lowest
    byte each position may hold and the range above it (a digit 0-9, a sign slot space..'-',
    an exponent sign '+'..'-', any other byte itself); the first and last digit position;
    the weights turning the digit bytes between them into each field's digits as an integer
    and each exponent's magnitude; the sign slots and their fields; the exponent signs and,
    per exponent, its field and whether it has a sign; the fraction digits per field."""
    sep = b" \t"
    if comma:
        spans, start = [], 0
        for part in row.split(b","):
            s, e = start, start + len(part)
            while s < e and row[s] in sep:
                s += 1
            while e > s and row[e - 1] in sep:
                e -= 1
            spans.append((s, e))
            start += len(part) + 1
    else:
        spans = [m.span() for m in re.finditer(rb"[^ \t]+", row)]
    if len(spans) != ncol:
        return None
    L = len(row) + 1
    lo = np.frombuffer(row + b"\n", np.uint8).copy()
    width = np.zeros(L, np.uint8)
    inside = bytearray(L)                   # 1 on the numbers' own bytes
    wcol = []                               # (position, column of the weights, weight)
    slots, sfield, esigns, efields, frac = [], [], [], [], []
    for j, (s, e) in enumerate(spans):
        m = _FIXED_NUM.fullmatch(row, s, e) if s < e else None
        if m is None:
            return None
        sg, ip, _, fp, ech, es, ed = m.groups()
        fp = fp or b""
        nd = len(ip) + len(fp)
        if not nd or nd > 15:
            return None
        inside[s:e] = b"\1" * (e - s)
        p = s + len(sg)
        mpos = [p + i for i in range(len(ip))] + [p + len(ip) + 1 + i for i in range(len(fp))]
        wcol += [(q, j, float(10 ** (nd - 1 - i))) for i, q in enumerate(mpos)]
        if sg:
            slots.append(s)
        elif s >= 1 and row[s - 1] == 32 and (comma or s == 1 or row[s - 2] in sep):
            slots.append(s - 1)             # a space before the number: room for a '-'
        if len(slots) > len(sfield):
            sfield.append(j)
        if ech:
            c = ncol + len(efields)
            wcol += [(q, c, float(10 ** (e - 1 - q))) for q in range(e - len(ed), e)]
            if es:
                esigns.append(e - len(ed) - 1)
            efields.append((j, bool(es)))
        frac.append(len(fp))
    between = b" \t," if comma else sep
    if any(not inside[q] and row[q] not in between for q in range(L - 1)):
        return None
    pos = [q for q, _, _ in wcol]
    lo[pos], width[pos] = 48, 9
    lo[slots], width[slots] = 32, 13
    lo[esigns], width[esigns] = 43, 2
    a, b = min(pos), max(pos) + 1
    W = np.zeros((b - a, ncol + len(efields)))
    for q, c, w in wcol:
        W[q - a, c] = w
    return lo, width, a, b, W, slots, sfield, esigns, efields, np.array(frac, float)


def _digit_sums(F: np.ndarray, W: np.ndarray, runs) -> np.ndarray:
    """The digits' bytes ``F`` (48 + digit, as floats) times their powers of ten ``W``, summed
    per output: every product and partial sum an integer below 2**53 (at most 15 digits), so
    exact in any order (FMA or not).  By one matrix product when the BLAS runs one thread (the
    CLI), else by numpy's einsum, one run of bytes at a time (numerics/blas.py: a BLAS thread
    pool would spin)."""
    if blas.ONE_THREAD:
        return F @ W
    MX = np.empty((len(F), len(runs)))
    for c, (r0, r1, w) in enumerate(runs):
        np.einsum("ij,j->i", F[:, r0:r1], w, out=MX[:, c])
    return MX


def _parse_fixed(block: bytes, spec: TableSpec, nlines: int, comma: bool,
                 size: Optional[int] = None) -> Optional[np.ndarray]:
    """The rows of a block of whole lines of one fixed-width layout (see above), to the bits
    numpy's tokenizer gives; None when the block is not such a layout (the caller then uses
    the tokenizer).  ``size``: the block is ``block[:size]`` (read in place, not copied)."""
    size = len(block) if size is None else size
    L = block.find(b"\n", 0, size) + 1
    if L < 2 or size != nlines * L:
        return None
    A = np.frombuffer(block, np.uint8, count=size).reshape(nlines, L)
    if not (A[:, -1] == 10).all():
        return None
    lay = _fixed_layout(block[:L - 1], spec.ncol, comma)
    if lay is None:
        return None
    lo, width, a, b, W, slots, sfield, esigns, efields, frac = lay
    ncol = spec.ncol
    offset = 48.0 * W.sum(0)
    # each output (a field's digits, an exponent's) is the weighted sum of one run of bytes
    runs = [(nz[0], nz[-1] + 1, W[nz[0]:nz[-1] + 1, c].copy())
            for c, nz in enumerate(np.flatnonzero(W[:, c]) for c in range(W.shape[1]))]
    # dense where the layout allows (every field signed, every one with a signed exponent:
    # the usual %e table), else by the fields' indices
    all_slots = sfield == list(range(ncol))
    all_exps = [j for j, _ in efields] == list(range(ncol)) and len(esigns) == ncol
    rows = np.empty((nlines, ncol))
    # in slices of rows: every temporary (the float copy of a slice's bytes, ~1 MB, the
    # largest) stays in the heap and in cache (numerics/allocator.py)
    step = max(1, _FIXED_SLICE_BYTES // (8 * (b - a)))
    for r in range(0, nlines, step):
        B = A[r:r + step]
        if not ((B - lo) <= width).all():      # uint8: a byte below lo wraps above any width
            return None
        # signs: +1 or -1 for ' ', '+' or '-', NaN for any other byte (refused)
        sg = _SIGN[B[:, slots]]
        es = _SIGN[B[:, esigns]]
        if np.isnan(sg).any():
            return None
        MX = _digit_sums(B[:, a:b].astype(np.float64), W, runs)
        MX -= offset
        out = rows[r:r + step]
        if all_exps:
            k = MX[:, ncol:] * es
            k -= frac
        else:
            k = np.broadcast_to(-frac, out.shape).copy()
            ei = 0
            for c, (j, signed) in enumerate(efields):
                ex = MX[:, ncol + c]
                if signed:
                    ex = ex * es[:, ei]
                    ei += 1
                k[:, j] += ex
        lo_k, hi_k = k.min(), k.max()
        if not (lo_k >= -22 and hi_k <= 22):    # also NaN: an exponent sign not + or -
            return None
        i = (k + 22).astype(np.intp)
        # m * 10**k, or m / 10**-k: one rounding of exact operands (a sign, +-1, is exact)
        M = MX[:, :ncol]
        if all_slots:
            np.multiply(M, sg, out=out)
        else:
            out[:] = M
            if slots:
                out[:, sfield] *= sg
        if hi_k > 0:
            out *= _P_MUL[i]
        out /= _P_DIV[i]
    return rows


def _ok(rows: np.ndarray, spec: TableSpec, prev_t: float) -> bool:
    """Every checked value within ``|x - centre| <= halfwidth`` (so not NaN), the time column
    finite and not decreasing.  Checked on each column's least and greatest value: rounding
    ``x - centre`` is monotonic in ``x``, so that is the test of every value, without the
    temporaries of the whole block; NaN propagates through min/max and fails it.  Column by
    column: numpy reduces one strided column ~50x faster than ``min(axis=0)`` of a few columns."""
    centre, half = spec.centre, spec.halfwidth
    with np.errstate(invalid="ignore", over="ignore"):
        for j in np.flatnonzero(spec.checked):
            col = rows[:, j]
            if not (col.max() - centre[j] <= half[j] and centre[j] - col.min() <= half[j]):
                return False
    if spec.tcol is not None:
        t = rows[:, spec.tcol]
        if not (np.isfinite(t.min()) and np.isfinite(t.max())) or t[0] < prev_t \
                or (t[1:] < t[:-1]).any():
            return False
    return True


def _count_message(s: str, parts: List[str], spec: TableSpec, lineno: int) -> str:
    """A row that does not hold one value per column: an empty field named by its column
    (``1,2,,4``; ``1;2;;4`` in a decimal-comma table), else the count and the line itself as
    the file writes it (a serial logger's banner, a header written again, a line cut short),
    and what to do."""
    orig = spec.source_line(lineno) if spec.source_line is not None else None
    if orig:
        s = orig.strip()
        fields = s.split(";") if ";" in s else None
    else:
        fields = s.split(",") if "," in s else None
    if fields is not None and len(fields) == spec.ncol and any(not f.strip() for f in fields):
        j = next(j for j, f in enumerate(fields) if not f.strip())
        return f"column {spec.names[j]} is empty (repair or delete this line)"
    return (f"expected {spec.ncol} values ({','.join(spec.names)}), found {len(parts)}: {snippet(s)} "
            f"(repair or delete this line)")


def _layout_message(spec: TableSpec, lineno: int, found: int, lines: int, last: int,
                    at_end: bool = True) -> str:
    """Every garbled line holds ``found`` values where the columns name ``spec.ncol``: the
    layout differs from the columns (a logger's 7 values read as 8 columns, a ';'-separated
    file), so the fix is the column names or the separator, not the line (a helper: "repair or
    delete this line" was said of line 8 of a file whose every row had 7 values)."""
    sep = " (one value a line: the values are not separated by ',' or white space)" if found == 1 else ""
    return (f"{spec.path}:{lineno}: {lines} lines from here to line {last} hold {found} "
            f"value{'s' if found != 1 else ''} "
            f"each, the columns name {spec.ncol} ({','.join(spec.names)}){sep}: the file's layout is not "
            f"these columns; name its columns as the file writes them (its header line or --columns)"
            + ("" if at_end else "; later lines not checked"))


#: the problems _parse_slow stops at (a structure, not one garbled line: what follows depends on it)
_STRUCTURAL = ("time goes backwards", "a column header again", "line longer than")
#: garbled lines after the first that the error lists by number
_MORE_LISTED = 5


def _parse_slow(text: str, spec: TableSpec, lineno: int, prev_t: float, at_end: bool = False) -> np.ndarray:
    """The reference parser: defines what is accepted; raises naming file:line and column.
    After a first garbled line (a wrong count, not a number, not finite, beyond a sensor) it
    reads on to the end of the block and, when most lines there are good, the error lists the
    other garbled lines, so one run shows what to repair (earlier notes: "only the first
    garbled line reported"); when most are bad the layout is wrong, and the first line says how.
    ``at_end``: the block ends the file (the list then says so, not "later lines not checked")."""
    out: List[List[float]] = []
    first: Optional[Exception] = None
    more: List[int] = []
    counts = set()              # the garbled lines' value counts
    first_ln = last = lineno
    run = 0                     # the first of the '#' lines right above this one (0: none)
    for i, line in enumerate(text.split("\n")):
        s = line.strip()
        if not s or s[0] in spec.skip:
            run = run or (lineno + i if s.startswith("#") else 0)
            continue
        ln = last = lineno + i
        start, run = run, 0
        try:
            row = _slow_row(s, line, spec, ln, prev_t if first is None else -np.inf, start)
        except spec.error as e:
            counts.add(len(_fields(s, spec)))
            if first is not None:
                more.append(ln)
                continue
            if any(f"{ln}: {k}" in str(e) for k in _STRUCTURAL):
                raise
            first, first_ln = e, ln
            continue
        if spec.tcol is not None:
            prev_t = row[spec.tcol]
        out.append(row)
    if first is not None:
        if not more or len(more) >= len(out):     # most lines: a wrong layout, which the first names
            # every line of the block garbled the same way, and nothing read before it: the
            # layout (a file whose first rows were read has a layout that changes, or a fault)
            if more and not out and not spec.accepted and len(counts) == 1 and spec.ncol not in counts:
                raise spec.error(_layout_message(spec, first_ln, counts.pop(), len(more) + 1, more[-1],
                                                 at_end)) from None
            raise first
        listed = ", ".join(map(str, more[:_MORE_LISTED]))
        extra = f" and {len(more) - _MORE_LISTED} more" if len(more) > _MORE_LISTED else ""
        rest = "the file's end" if at_end else f"line {last}; later lines not checked"
        raise spec.error(f"{first} (also garbled: line{'s' if len(more) > 1 else ''} {listed}{extra}, "
                         f"up to {rest})") from None
    return np.array(out, dtype=np.float64).reshape(len(out), spec.ncol)


def _fields(s: str, spec: TableSpec) -> List[str]:
    """A line's fields as the reference parser splits them (',' only, or ',' and white space)."""
    return s.split(",") if spec.comma_only else s.replace(",", " ").split()


def _slow_row(s: str, line: str, spec: TableSpec, ln: int, prev_t: float, start: int = 0) -> List[float]:
    """One line's values, checked (spec.fail naming the line and column); ``start``: the first
    line of the comment lines right above it (its own number when none)."""
    n = spec.ncol
    parts = _fields(s, spec)
    if len(parts) != n:
        if len(line) > MAX_LINE_BYTES:      # within a block (one longer than a block: _long_line)
            spec.fail(ln, f"line longer than {MAX_LINE_BYTES} bytes: not a line of a text table; "
                          f"the file is binary or damaged (cut the damaged part)")
        spec.fail(ln, _count_message(s, parts, spec, ln))
    row = []
    for j, p in enumerate(parts):
        try:
            v = float(p)
        except ValueError:
            if spec.names[j] == "-":        # a skipped column may hold text (a frame id)
                v = float("nan")
            elif _header_again(parts, spec.names, s, spec.header_line):
                own = spec.source_line(ln) if spec.source_line is not None else None
                spec.fail(ln, _header_message((own or s).strip(), spec.path, ln, start or ln))
            else:
                spec.fail(ln, f"column {spec.names[j]}: {snippet(spec.quoted(ln, j, p))} is not a number")
        row.append(v)
    for j, v in enumerate(row):
        if not spec.checked[j]:
            continue
        if v != v or v in (np.inf, -np.inf):
            spec.fail(ln, f"column {spec.names[j]}: {v} is not a finite number (repair or "
                          f"delete this line)")
        if not abs(v - spec.centre[j]) <= spec.halfwidth[j]:
            spec.fail(ln, f"column {spec.names[j]}: {snippet(spec.quoted(ln, j, parts[j]), quote=False)} is beyond what "
                          f"a sensor reads{spec.limit_note} (repair or delete this line)")
    if spec.tcol is not None and row[spec.tcol] < prev_t:
        spec.fail(ln, _backwards(spec.names[spec.tcol], row[spec.tcol], prev_t, ln, spec.path))
    return row


def collect(blocks: Iterator[np.ndarray], groups: Sequence[Tuple[str, List[int]]], fh: BinaryIO,
            start: int) -> Tuple[int, dict]:
    """(rows, {group: array}): the blocks of ``fh`` (body from byte ``start``) copied into one
    contiguous array per group as they are parsed, each block dropped once copied.

    Peak memory is the result plus one block: the arrays are sized from the first block's
    bytes per row over the file's remaining bytes, with a margin whose pages are never
    touched (so never resident), and grown by half again in the rare case that is short.
    The arrays returned are views of the first ``rows`` rows.
    """
    out: dict = {}
    n = cap = 0
    for b in blocks:
        k = len(b)
        if n + k > cap:
            if not cap:
                try:
                    size = os.fstat(fh.fileno()).st_size
                    here = max(fh.tell() - start, 1)
                    est = int(k * max(size - start, here) / here * 1.25) + 64
                except (OSError, ValueError, AttributeError):
                    est = 0
                cap = max(est, n + k)
            else:
                cap = max(int(cap * 1.5), n + k)
            new = {name: np.empty((cap, len(ix)) if len(ix) > 1 else cap) for name, ix in groups}
            for name in out:
                new[name][:n] = out[name][:n]
            out = new
        for name, ix in groups:
            out[name][n:n + k] = b[:, ix] if len(ix) > 1 else b[:, ix[0]]
        n += k
        del b
    return n, {name: a[:n] for name, a in out.items()}
