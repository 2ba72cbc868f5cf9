"""Shared by the command modules: messages go to stderr, data to stdout."""
from __future__ import annotations

import math
import numbers
import sys


def eprint(*a) -> None:
    print(*a, file=sys.stderr, flush=True)


def window_rows(t, start_s=None, end_s=None, where: str = "") -> "tuple":
    """(lo, hi): the rows of ``t`` within [start_s, end_s] (s after the first sample), at
    least two, else a one-line UserError (``where``: the file, heading it)."""
    import numpy as np
    t = np.asarray(t, float)
    lo = 0 if start_s is None else int(np.searchsorted(t, t[0] + start_s))
    hi = len(t) if end_s is None else int(np.searchsorted(t, t[0] + end_s, side="right"))
    if hi - lo < 2:
        head = f"{where}: " if where else ""
        from ..errors import UserError
        raise UserError(f"{head}--start-s/--end-s select {max(hi - lo, 0)} samples of "
                        f"{t[-1] - t[0]:.4g} s: widen the window")
    return lo, hi


def print_json(doc) -> None:
    """A command's ``--json`` answer, one object on stdout, as the stream's objects are
    (docs/reference/stream.md): a field whose value is unknown (None, or a number that is
    not finite) is omitted, never null or NaN; in a list, where places count (one per axis
    or parameter), such a value is null."""
    import json
    print(json.dumps(_present(doc), default=float, allow_nan=False))


def _present(v):
    """``v`` with unknown values dropped from objects and null in lists (print_json)."""
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            x = _present(x)
            if x is not None:
                out[k] = x
        return out
    if isinstance(v, (list, tuple)):
        return [_present(x) for x in v]
    if isinstance(v, numbers.Real) and not isinstance(v, numbers.Integral):
        v = float(v)
        return v if math.isfinite(v) else None
    if hasattr(v, "tolist"):            # a numpy array or integer
        return _present(v.tolist())
    return v


class TableReader:
    """A raw numeric table (a logger's file, read whole by ``imucald.fitting.inputs.read_table``)
    served as ``open_recording``'s reader is: ``header``, ``meta`` and ``chunks()``."""

    def __init__(self, rec, rows: int = 1 << 16):
        self.rec, self.rows = rec, rows
        self.header, self.meta = rec.columns(), rec.meta

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> bool:
        return False

    def chunks(self):
        for i in range(0, len(self.rec), self.rows):
            yield self.rec.slice(i, i + self.rows)


def read_input(args, path: str, applied=()):
    """(kind, obj) of the file a command reads (fitting.inputs.load_input), with the raw-table
    options it was given: --columns, --nominal-scale, --nominal-offset, --rate-hz, --join
    with --join-columns, and --board.  ``applied``: the options the command applies to an
    imucald file too (not warned of as ignored there)."""
    from ..fitting.inputs import load_input
    columns = args.columns.split(",") if getattr(args, "columns", None) else None
    join = (args.join, args.join_columns.split(",")) if getattr(args, "join", None) else None
    return load_input(path, columns, args.nominal_scale, args.nominal_offset, args.rate_hz, join,
                      getattr(args, "board", None), applied)


def input_recording(args, path: str, whole: bool = True):
    """The recording a command reads: an imucald recording (whatever ``--columns`` says: its
    header names its board, which apply checks, and ``--board`` must agree with), or with
    ``--columns`` a raw table (``--nominal-scale``, ``--nominal-offset``, ``--rate-hz``,
    ``--board``; ``--join``: a second one joined).
    ``whole``: the Recording; else a reader (a recording streamed block by block, a table read
    whole)."""
    if getattr(args, "columns", None):
        from ..errors import UserError
        from ..fitting.inputs import input_kind
        kind = input_kind(path)
        if kind == "poses":
            raise UserError(f"{path}: a pose file (still-pose averages): this command needs the "
                            f"samples, a recording or a raw table")
        if kind == "table" or getattr(args, "join", None):
            _, rec = read_input(args, path)       # (load_input refuses --join on a recording)
            return rec if whole else TableReader(rec)
    from ..files.recording import open_recording
    from ..fitting.inputs import warn_table_options
    reader = open_recording(path)         # (not a recording: its own error, no warning)
    columns = args.columns.split(",") if getattr(args, "columns", None) else None
    warn_table_options(path, "recording", columns, getattr(args, "nominal_scale", 1.0),
                       getattr(args, "nominal_offset", 0.0), getattr(args, "rate_hz", None))
    if getattr(args, "board", None):              # it must agree with the header's board
        from ..fitting.inputs import check_board
        try:
            check_board(path, "recording", args.board, reader.meta)
        except BaseException:
            reader.close()
            raise
    if not whole:
        return reader
    with reader:
        return reader.read()
