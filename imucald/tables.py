"""Bulk, chunked parsing of numeric text tables with one-line errors that name the place.

Both readers use it: the recording body (comma-separated) and the raw numeric
tables of ``calibrate``/``gap`` (whitespace- or comma-separated).  The file is
read in blocks of whole lines (``CHUNK_BYTES``); each block is parsed by numpy's
C tokenizer in one call.  A block that does not parse cleanly (a bad line, a
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
import warnings
from typing import BinaryIO, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from .errors import UserError

__all__ = ["CHUNK_BYTES", "TableSpec", "iter_blocks", "decode_line", "collect"]

CHUNK_BYTES = 1 << 20     #: bytes per block: ~15-25 k rows, ~2 MB of float64 at 11 columns


class TableSpec:
    """How the body of one file is laid out and checked."""

    def __init__(self, path: str, names: Sequence[str], error=UserError, comma_only: bool = True,
                 skip: str = "#", centre=None, halfwidth=None, tcol: Optional[int] = None,
                 limit_note: str = "", checked=None):
        self.path, self.names, self.error = path, list(names), error
        self.ncol = len(self.names)
        self.comma_only, self.skip, self.tcol = comma_only, skip, tcol
        self.centre = np.zeros(self.ncol) if centre is None else np.asarray(centre, float)
        self.halfwidth = np.full(self.ncol, np.inf) if halfwidth is None else np.asarray(halfwidth, float)
        self.limit_note = limit_note
        #: columns whose values are checked (finite, within bounds); others need only be numbers
        self.checked = np.ones(self.ncol, bool) if checked is None else np.asarray(checked, bool)

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

    ``offset`` is the byte offset of that line in the file (for error messages).
    """
    rest = b""
    while True:
        data = fh.read(chunk_bytes)
        buf = rest + data
        if not buf:
            return
        if data:
            cut = buf.rfind(b"\n") + 1
            if cut == 0:            # no newline within the block: keep reading
                rest = buf
                continue
            block, rest = buf[:cut], buf[cut:]
        else:
            block, rest = buf, b""
        try:
            text = block.decode("utf-8")
        except UnicodeDecodeError as e:
            raise spec.error(_not_utf8(spec.path, block, e, lineno, offset)) from None
        rows = _parse_fast(text, spec, prev_t)
        if rows is None:
            rows = _parse_slow(text, spec, lineno, prev_t)
        if len(rows):
            if spec.tcol is not None:
                prev_t = rows[-1, spec.tcol]
            yield rows
        lineno += block.count(b"\n")
        offset += len(block)
        if not data:
            return


def _parse_fast(text: str, spec: TableSpec, prev_t: float) -> Optional[np.ndarray]:
    """The block through numpy's tokenizer, or None when the reference parser must look."""
    nlines = text.count("\n") + (0 if text.endswith("\n") else 1)
    if "\r" in text:
        text = text.replace("\r\n", "\n")
        if "\r" in text:
            return None
    delim = "," if spec.comma_only or "," in text else None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows = np.loadtxt(io.StringIO(text), delimiter=delim, comments=None, ndmin=2,
                              dtype=np.float64)
    except (ValueError, TypeError, OverflowError):
        return None
    if rows.shape != (nlines, spec.ncol) or not _ok(rows, spec, prev_t):
        return None         # blank or comment lines, wrong counts, bad values: look line by line
    return rows


def _ok(rows: np.ndarray, spec: TableSpec, prev_t: float) -> bool:
    with np.errstate(invalid="ignore", over="ignore"):
        ok = np.abs(rows - spec.centre) <= spec.halfwidth              # False for nan
        if not ok[:, spec.checked].all():
            return False
    if spec.tcol is not None:
        t = rows[:, spec.tcol]
        if not np.isfinite(t).all() or t[0] < prev_t or (np.diff(t) < 0).any():
            return False
    return True


def _parse_slow(text: str, spec: TableSpec, lineno: int, prev_t: float) -> np.ndarray:
    """The reference parser: defines what is accepted; raises naming file:line and column."""
    out: List[List[float]] = []
    n = spec.ncol
    for i, line in enumerate(text.split("\n")):
        s = line.strip()
        if not s or s[0] in spec.skip:
            continue
        ln = lineno + i
        parts = s.split(",") if spec.comma_only else s.replace(",", " ").split()
        if len(parts) != n:
            spec.fail(ln, f"expected {n} values ({','.join(spec.names)}), found {len(parts)}")
        row = []
        for j, p in enumerate(parts):
            try:
                v = float(p)
            except ValueError:
                spec.fail(ln, f"column {spec.names[j]}: {p.strip()[:40]!r} is not a number")
            row.append(v)
        for j, v in enumerate(row):
            if not spec.checked[j]:
                continue
            if v != v or v in (np.inf, -np.inf):
                spec.fail(ln, f"column {spec.names[j]}: {v} is not a finite number (repair or "
                              f"delete this line)")
            if not abs(v - spec.centre[j]) <= spec.halfwidth[j]:
                spec.fail(ln, f"column {spec.names[j]}: {parts[j].strip()[:40]} is beyond what "
                              f"a sensor reads{spec.limit_note} (repair or delete this line)")
        if spec.tcol is not None:
            t = row[spec.tcol]
            if t < prev_t:
                spec.fail(ln, f"time goes backwards ({t:.9g} s after {prev_t:.9g} s); sort the "
                              f"rows by time or cut the file there")
            prev_t = t
        out.append(row)
    return np.array(out, dtype=np.float64).reshape(len(out), n)


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
