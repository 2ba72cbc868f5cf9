"""imucald's exception hierarchy.

A :class:`UserError` is something the user can fix (bad input file, bad option,
wrong chip).  The command line prints its message on one line and exits
non-zero, with no traceback.
"""


class UserError(Exception):
    """An error in the user's input or setup; its message is the whole explanation."""

    exit_code = 2
