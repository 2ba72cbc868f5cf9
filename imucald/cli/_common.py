"""Shared by the command modules: messages go to stderr, data to stdout."""
from __future__ import annotations

import sys


def eprint(*a) -> None:
    print(*a, file=sys.stderr, flush=True)
