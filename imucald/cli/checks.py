"""Arguments checked before anything is opened: number ranges (argparse types), output
paths (a file that can be created, not a directory), rates the chosen board can run at.

numpy-free: the parser uses the types, :func:`check_args` runs before every command.
"""
from __future__ import annotations

import argparse
import math
import os

from ..errors import CannotCreate, UserError

__all__ = ["positive_float", "non_negative_float", "at_least", "check_args", "output_file", "output_dir"]


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"{text} is not a number > 0")
    return v


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"{text} is not a number >= 0")
    return v


def at_least(n: int, why: str = ""):
    """argparse type: an integer >= n (``why`` says what needs that many)."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if v < n:
            raise argparse.ArgumentTypeError(f"{v} is too few: at least {n}{why}")
        return v
    parse.__name__ = f"integer >= {n}"
    return parse


def _existing_ancestor(path: str) -> str:
    p = os.path.abspath(path)
    while not os.path.exists(p):
        parent = os.path.dirname(p)
        if parent == p:
            break
        p = parent
    return p


def output_file(path: str, flag: str) -> None:
    """``path`` can be written as a file: ``-`` (standard output), or a regular file or a
    name not yet taken (never a device node, FIFO, socket or directory: atomic.check_output),
    in a directory that exists and is writable."""
    if path == "-":
        return
    from ..atomic import check_output
    if os.path.isdir(path):
        raise CannotCreate(f"{flag} {path}: is a directory; give a file name, e.g. "
                           f"{os.path.join(path, 'out' + _ext(flag))}")
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        what = "is not a directory" if os.path.exists(d) else "does not exist"
        raise CannotCreate(f"{flag} {path}: directory {d} {what} (create it first: mkdir -p {d})")
    if not os.access(d, os.W_OK | os.X_OK):
        raise CannotCreate(f"{flag} {path}: directory {d} is not writable by this user")
    check_output(path, flag)


def _ext(flag: str) -> str:
    return ".yaml" if flag == "--output" else ".csv"


def output_dir(path: str, flag: str) -> None:
    """``path`` is, or can be created as, a writable directory."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise CannotCreate(f"{flag} {path}: exists and is not a directory")
    top = _existing_ancestor(path)
    if not os.path.isdir(top):
        raise CannotCreate(f"{flag} {path}: {top} is not a directory")
    if not os.access(top, os.W_OK | os.X_OK):
        raise CannotCreate(f"{flag} {path}: {top} is not writable by this user")


def check_args(args) -> None:
    """Per command: output paths, and the rate against the board (record; run checks it
    with its configuration)."""
    cmd = getattr(args, "cmd", None)
    if cmd in ("simulate", "record", "apply"):
        output_file(args.output, "-o")
    if cmd == "simulate" and args.truth:
        output_file(args.truth, "--truth")
    if cmd == "calibrate" and args.output:
        output_file(args.output, "--output")
    if cmd == "noise":
        for p, f in ((args.output, "-o"), (args.kalibr, "--kalibr")):
            if p:
                output_file(p, f)
        if args.output == "-" and args.kalibr == "-":
            raise UserError("-o - and --kalibr -: only one of them can go to standard output")
    if cmd == "gap" and args.report:
        output_dir(args.report, "--report")
    if cmd == "replay" and args.state_dir:
        output_dir(args.state_dir, "--state-dir")
    if cmd == "record":
        from ..drivers.rates import rate_problem
        why = rate_problem(args.board, args.rate)
        if why:
            raise UserError(f"--rate {args.rate:g}: {why}")
