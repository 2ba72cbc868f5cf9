"""imucald command line (the ``imucald`` console script is :func:`main`).

Layout: ``parser`` (arguments and choices), one module per command family --
``offline`` (simulate, calibrate, demo), ``hardware`` (probe, record),
``service`` (run, replay, status, recalibrate, watch), ``gap`` -- with
``boards`` (the one board factory, real or emulated) and ``faults`` (``--fault``).

User errors (bad files, bad options) print one line, ``imucald: error: ...``,
and exit 2 (78 for a bad configuration file) with no traceback.
"""
from __future__ import annotations

from typing import List, Optional

from ..errors import UserError
from ._common import eprint
from .parser import build_parser

__all__ = ["main", "build_parser"]


def main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as e:
        eprint(f"imucald: error: {e}")
        return e.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
