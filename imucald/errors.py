"""imucald's exception hierarchy and exit codes.

A :class:`UserError` is something the user can fix (bad input file, bad option,
wrong chip).  The command line prints its message on one line and exits with
the error's ``exit_code``, with no traceback.  The codes follow sysexits(3):

====  ==============  ==========================================================
code  name            meaning (a restart cannot fix the ones marked *)
====  ==============  ==========================================================
2     usage/input *   bad option or argument, malformed input file, wrong chip,
                      an address owned by a kernel driver
69    unavailable     the device: no I2C bus, no acknowledge from the chip, bus
                      errors at start (wiring, power: may come back)
73    cannot create * an output file, socket or directory cannot be created
74    I/O error       reading or writing failed (disk full, read-only, EIO)
75    temporary       another imucald holds the runtime/state directory (its lock)
78    config *        the configuration file is wrong
====  ==============  ==========================================================

systemd/imucald.service's ``RestartPreventExitStatus=`` lists the starred ones.
"""

EX_USAGE = 2
EX_UNAVAILABLE = 69
EX_CANTCREAT = 73
EX_IOERR = 74
EX_TEMPFAIL = 75
EX_CONFIG = 78

#: exit codes a restart cannot fix (the unit's RestartPreventExitStatus=)
NO_RESTART = (EX_USAGE, EX_CANTCREAT, EX_CONFIG)


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
