"""Helpers shared by the CLI and daemon fault tests (test_errors, test_reliability,
test_survival): running the CLI in-process, the one-line error checks, waiting for a
condition with a deadline instead of sleeping a fixed time."""
import os
import sys
import time

from imucald.cli import main

PY = sys.executable
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: the environment of a CLI subprocess: this checkout first on the import path
ENV = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))


def run_main(capsys, *argv):
    """The CLI in this process: (exit code, stdout, stderr); argparse's own exit (usage
    errors) counts as the exit code."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:
        rc = e.code
    out, err = capsys.readouterr()
    return rc, out, err


def one_line(err):
    """The only non-blank line of ``err``, no traceback."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def one_error_line(err):
    """The one error line of ``err`` (progress lines before it are fine), no traceback."""
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert len(lines) == 1 and "Traceback" not in err and lines[0].startswith("imucald"), err
    return lines[0]


def wait_until(pred, timeout=30, step=0.05):
    """``pred()``'s first true value, polled every ``step`` s; AssertionError after
    ``timeout`` s.  A deadline for a hung process, not a measure of a slow one: give
    what a loaded two-core machine needs."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        v = pred()
        if v:
            return v
        time.sleep(step)
    raise AssertionError(f"timed out waiting ({timeout} s)")


def or_none(fn):
    """``fn()``, or None when it raises OSError (a socket not yet listening)."""
    try:
        return fn()
    except OSError:
        return None
