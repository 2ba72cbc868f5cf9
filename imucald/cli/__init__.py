"""imucald command line (the ``imucald`` console script is :func:`main`).

Layout: ``parser`` (arguments and choices), one module per command family --
``offline`` (simulate, calibrate, demo), ``hardware`` (probe, record),
``service`` (run, replay, status, recalibrate, watch), ``gap`` -- with
``boards`` (the one board factory, real or emulated) and ``faults`` (``--fault``).

One error boundary (:func:`main`): every user-facing failure prints one line,
``imucald: error: ...``, naming the place and the fix, and exits with a code
from :mod:`imucald.errors` (2 usage/input, 69 unavailable device, 73 cannot
create, 74 I/O, 75 another instance running, 78 configuration), no traceback.
Arguments are checked (:mod:`.checks`) before anything is opened.
"""
from __future__ import annotations

import os
import sys
from typing import List, Optional

# One BLAS thread, unless the user says otherwise: imucald's linear algebra is on matrices of
# at most a few thousand rows by 12 columns, which a BLAS thread pool does not speed up; the
# pool's start (a thread per core, spinning while it waits) cost ~35 ms of CPU at numpy's
# import here and doubled a command's wall time on a busy 2-core machine (bench/startup.py).
# Set before numpy is imported by any command (the daemon's calibration worker inherits it).
for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
if "numpy" not in sys.modules and all(os.environ[_v] == "1" for _v in ("OPENBLAS_NUM_THREADS",
                                                                      "MKL_NUM_THREADS")):
    from ..numerics import blas as _blas
    _blas.ONE_THREAD = True         # the fixed-width reader's matrix products (numerics/blas.py)

from ..errors import EX_IOERR, EX_UNAVAILABLE, UserError, os_error_line
from ._common import eprint
from .parser import COMMANDS, build_parser

COMMAND_NAMES = frozenset(c[0] for c in COMMANDS)

__all__ = ["main", "entry", "build_parser"]


def _unrecognized(parser, cmd: Optional[str], extra: List[str], positional: List[str]) -> None:
    """argparse's 'unrecognized arguments' from the command's own parser (its --help named),
    with the nearest of its options when one is close: '--colums' -> 'did you mean --columns?'
    (not for a word given after '--', a positional: ``positional``)."""
    import argparse
    import difflib
    sub = next((a.choices.get(cmd) for a in parser._actions
                if isinstance(a, argparse._SubParsersAction) and cmd), None) or parser
    options = [o for a in sub._actions for o in a.option_strings]
    near = [m for w in extra if w.startswith("-") and w not in positional and w.split("=", 1)[0] not in options
            for m in difflib.get_close_matches(w.split("=", 1)[0], options, n=1, cutoff=0.7)]
    hint = f" (did you mean {', '.join(dict.fromkeys(near))}?)" if near else ""
    sub.error(f"unrecognized arguments: {' '.join(extra)}{hint}")


#: options whose value is a column list, which may start with "-" (a skipped column)
_COLUMN_LISTS = ("--columns", "--join-columns")


def _glue_column_lists(words: List[str]) -> List[str]:
    """``--columns -,t,ax,ay,az`` as ``--columns=-,t,ax,ay,az``: argparse takes a value that
    starts with "-" for an option and said only "expected one argument" (a logger's first
    column skipped is common: an index, a date).  Only a comma list is glued, and nothing
    after ``--``."""
    out: List[str] = []
    i = 0
    while i < len(words):
        w = words[i]
        if w == "--":
            return out + words[i:]
        nxt = words[i + 1] if i + 1 < len(words) else ""
        if (len(w) > 2 and any(o.startswith(w) for o in _COLUMN_LISTS)   # argparse's abbreviations too
                and nxt.startswith("-") and "," in nxt):
            out.append(f"{w}={nxt}")
            i += 2
            continue
        out.append(w)
        i += 1
    return out


def main(argv: Optional[List[str]] = None) -> int:
    words = _glue_column_lists(sys.argv[1:] if argv is None else list(argv))
    # only the subcommand given gets its arguments built (--help and a typo: none)
    cmd = next((w for w in words if not w.startswith("-")), "")
    parser = build_parser(cmd if cmd in COMMAND_NAMES else "")
    type(parser).json_errors = "--json" in words
    args, extra = parser.parse_known_args(words)
    if extra:
        after = words[words.index("--") + 1:] if "--" in words else []      # positionals there
        _unrecognized(parser, getattr(args, "cmd", None), extra, after)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    stdout = sys.stdout             # check_args may point it at stderr (-o -): put back after
    try:
        from .checks import check_args
        check_args(args)
        return int(args.func(args) or 0)
    except UserError as e:
        return _fail(args, _one_line(e), e.exit_code)
    except OSError as e:            # disk full, read-only, EIO: said in one line
        if isinstance(e, BrokenPipeError):      # the reader of our stdout went away (| head)
            try:                                 # nothing more to say, and no "Exception
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # ignored" at exit
            except (OSError, ValueError):
                pass
            return 0
        return _fail(args, _one_line(os_error_line(e)), EX_IOERR)
    except KeyboardInterrupt:
        return 130
    except Exception as e:
        # the chip stopped answering (or never did); drivers.bus is loaded only by the
        # commands that open a bus (--help and status do not), and only then can this be one
        bus = sys.modules.get(f"{__package__.rsplit('.', 1)[0]}.drivers.bus")
        if bus is None or not isinstance(e, bus.BusError):
            raise
        return _fail(args, _one_line(e), EX_UNAVAILABLE)
    finally:
        sys.stdout = stdout
        # only a command that loaded files.atomic can have pointed it at stdout (check_args
        # for -o -); one that did not (calibrate --json) is not made to import it here
        atomic = sys.modules.get(f"{__package__.rsplit('.', 1)[0]}.files.atomic")
        if atomic is not None:
            atomic.STDOUT = None


def entry() -> None:
    """The ``imucald`` console script and ``python -m imucald.cli``: :func:`main`, then exit
    with its code.  The objects alive at exit are first moved out of the cyclic garbage
    collector's reach (``gc.freeze``), so the interpreter's last full collection does not walk
    the ~10^5 objects numpy's import made: 15-20 ms of a 0.19-s ``calibrate`` here
    (bench/imutk.py).  They are still freed by reference counting as the modules are torn
    down; only reference cycles left at exit go uncollected (the OS takes the memory back),
    so nothing may rely on a finalizer run by that collection: imucald closes its files with
    ``with`` (the daemon's log appender is unbuffered) and the interpreter flushes stdout and
    stderr as before.  Not in :func:`main`, which tests and scripts call in-process."""
    code = main()
    import gc
    gc.freeze()
    sys.exit(code)


def _fail(args, line: str, code: int) -> int:
    """A user error: one line on stderr; under ``--json`` (whose answer is one JSON object)
    also that object, ``{"error": LINE, "exit_code": CODE}``, on stdout."""
    eprint(f"imucald: error: {line}")
    if getattr(args, "json", False):
        import json
        print(json.dumps({"error": line, "exit_code": code}))
    return code


def _one_line(e) -> str:
    return " ".join(str(e).split())
