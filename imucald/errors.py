"""imucald's exception hierarchy and exit codes.

A :class:`UserError` is something the user can fix (bad input file, bad option,
wrong chip).  The command line prints its message on one line and exits with
the error's ``exit_code``, with no traceback.  The codes follow sysexits(3):

====  ==============  ==========================================================
code  name            meaning (a restart cannot fix the ones marked *)
====  ==============  ==========================================================
2     usage/input *   bad option or argument, malformed input file, wrong chip,
                      an address owned by a kernel driver
3     undetermined    ``calibrate --sensor mag``: the rotation does not determine
                      the calibration (nothing written; not an error line)
69    unavailable     the device: no I2C bus, no acknowledge from the chip, bus
                      errors at start (wiring, power: may come back)
73    cannot create * an output file, socket or directory cannot be created
74    I/O error       reading or writing failed (disk full, read-only, EIO)
75    temporary       another imucald holds the runtime/state directory (its lock), or listens on a socket path
78    config *        the configuration file is wrong
====  ==============  ==========================================================

systemd/imucald.service's ``RestartPreventExitStatus=`` lists the starred ones.
"""

EX_USAGE = 2
EX_UNDETERMINED = 3
EX_UNAVAILABLE = 69
EX_CANTCREAT = 73
EX_IOERR = 74
EX_TEMPFAIL = 75
EX_CONFIG = 78

#: exit codes a restart cannot fix (the unit's RestartPreventExitStatus=)
NO_RESTART = (EX_USAGE, EX_CANTCREAT, EX_CONFIG)


def install_hint(extra: str) -> str:
    """The command that installs imucald's optional ``extra`` for the Python running imucald
    (pip takes the extra from the installed imucald, however it was installed; a bare
    ``pip`` may be another Python's, and Bookworm's system pip refuses)."""
    import shlex
    import sys
    return f"{shlex.quote(sys.executable or 'python3')} -m pip install 'imucald[{extra}]'"


class UserError(Exception):
    """An error in the user's input or setup; its message is the whole explanation."""

    exit_code = EX_USAGE


class DeviceUnavailable(UserError):
    """The sensor or its bus cannot be reached (exit 69)."""

    exit_code = EX_UNAVAILABLE


class CannotCreate(UserError):
    """An output file, socket or directory cannot be created (exit 73)."""

    exit_code = EX_CANTCREAT


class IOFailure(UserError):
    """Reading or writing failed (exit 74)."""

    exit_code = EX_IOERR


class AlreadyRunning(UserError):
    """Another instance holds the lock (exit 75: try again once it has stopped)."""

    exit_code = EX_TEMPFAIL


def os_error_line(e: OSError, what: str = "") -> str:
    """One line for an OSError: the file it names, what was attempted, the reason."""
    name = e.filename if getattr(e, "filename", None) is not None else ""
    reason = e.strerror or str(e)
    parts = [p for p in (str(name), what) if p]
    return f"{': '.join(parts)}: {reason}" if parts else reason


def snippet(text, limit: int = 40, quote: bool = True) -> str:
    """``text`` (str or bytes) quoted for a one-line message: at most ``limit`` characters
    of it, control characters and NUL escaped (a run of one repeated control character
    as ``\\x00*N``, not N copies), ``...`` when cut.  Messages quote input only through
    this, so a hostile file can neither flood a log line nor inject a newline or a
    terminal escape into it."""
    if isinstance(text, (bytes, bytearray)):
        text = bytes(text[:4 * limit + 4]).decode("utf-8", errors="replace")
    out, n, i, cut = [], 0, 0, False
    s = str(text)
    while i < len(s):
        if n >= limit:
            cut = True
            break
        c = s[i]
        if c.isprintable() and c != "\\" and (c != "'" or not quote):
            out.append(c)
            i += 1
        else:
            j = i
            while j < len(s) and s[j] == c:
                j += 1
            esc = "\\\\" if c == "\\" else "\\'" if c == "'" else \
                (f"\\x{ord(c):02x}" if ord(c) < 0x100 else f"\\u{ord(c):04x}")
            run = j - i
            if run > 3 and c not in "\\'":
                out.append(f"{esc}*{run}")
                i = j
            else:
                out.append(esc)
                i += 1
        n += 1
    q = "'" if quote else ""
    return q + "".join(out) + q + ("..." if cut else "")


#: errnos of a write that failed for want of room or a working device: an I/O error (74),
#: which may pass (free some space); the others (permission, no such directory) are 73
_IO_ERRNOS = frozenset({5, 28, 30, 122})      # EIO, ENOSPC, EROFS, EDQUOT


def write_failure(e: OSError, flag: str, path: str) -> UserError:
    """The one-line error for writing ``path`` (given by ``flag``) failing with ``e``:
    IOFailure (74) for disk full, a read-only file system, EIO or a quota, as the README's
    exit-code table says; CannotCreate (73) otherwise; a refusal (CannotCreate) as it is."""
    if isinstance(e, UserError):
        return e
    cls = IOFailure if getattr(e, "errno", None) in _IO_ERRNOS else CannotCreate
    return cls(f"{flag + ' ' if flag else ''}{path}: cannot write: {e.strerror or e}")
