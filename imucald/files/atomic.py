"""Atomic file writes: temp file in the same directory, fsync, rename, fsync the directory.

A crash (or kill -9) at any point leaves either the old file or the new one,
never a torn mix.

Only a regular file (or a symlink to one) is ever replaced, or a name that does not
exist yet: a device node, a FIFO, a socket or a directory at the path is refused with
:class:`NotAFile` (exit 73), checked before the temporary file is made and again just
before the rename (run as root, ``-o /dev/full`` used to replace the device node with an
ordinary file).  ``-`` is standard output.
"""
from __future__ import annotations

import errno
import os
import stat
import sys
from typing import BinaryIO, Optional

from ..errors import CannotCreate

__all__ = ["NotAFile", "check_output", "read_own_file", "atomic_write_bytes", "atomic_write_text", "GrowingFile",
           "fsync_dir"]


#: where ``-`` writes when the command's own report was moved to stderr (cli.checks), else
#: sys.stdout
STDOUT = None


def _mkstemp(prefix: str, suffix: str, dir: str):
    """(fd, path) of a new file ``dir/prefix + random + suffix``, created exclusively
    (O_EXCL, not following a symlink), mode 0600, as ``tempfile.mkstemp`` does, without
    importing tempfile (and shutil, bz2, lzma under it: ~2 ms of a ``calibrate -o``)."""
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
    for _ in range(10000):
        name = os.path.join(dir, prefix + os.urandom(6).hex() + suffix)
        try:
            return os.open(name, flags, 0o600), os.path.abspath(name)
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no unused temporary file name found", dir)


class NotAFile(CannotCreate, OSError):
    """The output path names something other than a regular file (exit 73).  Also an
    OSError, so that a writer that retries failed writes (the daemon's state writer) treats
    it as one: logged, retried, never the end of its thread."""

    def __str__(self):
        return str(self.args[0]) if self.args else ""


_KIND = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
         (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
         (stat.S_ISDIR, "a directory"))


def check_output(path: str, flag: str = "") -> None:
    """Raise NotAFile unless ``path`` is ``-``, absent, or a regular file (a symlink to one
    counts: the link itself is what a rename replaces)."""
    if path == "-":
        return
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return                  # (any other OSError, e.g. ENOTDIR, is the caller's to report)
    if stat.S_ISREG(st.st_mode):
        return
    kind = next((k for f, k in _KIND if f(st.st_mode)), "not a regular file")
    hint = (f"give a file name, e.g. {os.path.join(path, 'out')}" if stat.S_ISDIR(st.st_mode) else
            "imucald writes only regular files (through a temporary file and a rename); use - for "
            "standard output, e.g. -o - > PATH or -o - | reader")
    raise NotAFile(f"{flag + ' ' if flag else ''}{path}: is {kind}, not a regular file; it is left "
                   f"alone: {hint}")


def fsync_dir(d: str) -> None:
    dfd = os.open(d, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def atomic_write_bytes(path: str, data: bytes, mode: int = 0o644, flag: str = "") -> None:
    if path == "-":
        out = (STDOUT or sys.stdout).buffer
        out.write(data)
        out.flush()
        return
    check_output(path, flag)
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = _mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=d)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        check_output(path, flag)        # again: something may have appeared meanwhile
        os.replace(tmp, path)
    except BaseException:
        _remove_quietly(tmp)
        raise
    fsync_dir(d)


def _remove_quietly(path: str) -> None:
    """Remove a temporary file left by a failed write (gone already is fine)."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def atomic_write_text(path: str, text: str, mode: int = 0o644, flag: str = "") -> None:
    atomic_write_bytes(path, text.encode("utf-8"), mode, flag)


def read_own_file(path: str, max_bytes: int, error=CannotCreate) -> bytes:
    """The bytes of a state file (at most ``max_bytes``): opened without following a
    symbolic link, and only if it is a regular file owned by this process's user or by root
    (an administrator's ``sudo cp calibration.yaml /var/lib/imucald/``: the service runs as a
    systemd DynamicUser, whose uid no one can give a file; root can change the daemon itself,
    so a file of root's is no less trusted than the daemon's own); else ``error`` (a UserError
    class) saying which, without a byte of the file in it."""
    import errno
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise error(f"{path}: is a symbolic link; a state file must be a regular file "
                        f"(imucald never follows a link there)") from None
        raise error(f"{path}: cannot open: {e.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = next((k for f, k in _KIND if f(st.st_mode)), "not a regular file")
            raise error(f"{path}: is {kind}; a state file must be a regular file")
        if st.st_uid not in (os.geteuid(), 0):
            raise error(f"{path}: is owned by uid {st.st_uid}, not by imucald's user (uid "
                        f"{os.geteuid()}) or root; a state file must be imucald's own or root's")
        if st.st_size > max_bytes:
            raise error(f"{path}: {st.st_size} bytes, more than the {max_bytes} a state file may hold")
        chunks, n = [], 0
        while n <= max_bytes:
            b = os.read(fd, max_bytes + 1 - n)
            if not b:
                break
            chunks.append(b)
            n += len(b)
        if n > max_bytes:
            raise error(f"{path}: more than the {max_bytes} bytes a state file may hold")
        return b"".join(chunks)
    finally:
        os.close(fd)


class GrowingFile:
    """A file written as data comes (``record``): its first bytes go to a temporary file in
    the same directory, which is fsynced and renamed to ``path`` at once (so the name shows a
    valid file from then on, and an old file there is replaced only when writing has
    started); later writes are appended and flushed, and fsynced at most every ``fsync_s``
    seconds.  A kill -9 or a power cut loses at most the last ``fsync_s`` s of data and
    leaves a file whose last line may be cut (the readers drop it with a warning).
    ``-`` writes to standard output."""

    def __init__(self, path: str, head: bytes, flag: str = "", fsync_s: float = 1.0,
                 mode: int = 0o644, clock=None):
        import time
        self.path, self.fsync_s = path, fsync_s
        self._clock = clock or time.monotonic
        if path == "-":
            self._fh: Optional[BinaryIO] = (STDOUT or sys.stdout).buffer
            self._fd = None
            self._fh.write(head)
            self._fh.flush()
            self._last = self._clock()
            return
        check_output(path, flag)
        d = os.path.dirname(os.path.abspath(path))
        fd, tmp = _mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=d)
        try:
            view = memoryview(head)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
            os.fchmod(fd, mode)
            check_output(path, flag)
            os.replace(tmp, path)
        except BaseException:
            os.close(fd)
            _remove_quietly(tmp)
            raise
        fsync_dir(d)
        self._fd = fd
        self._fh = os.fdopen(fd, "ab", buffering=0)
        self._last = self._clock()
        self.partial_bytes = 0

    def write(self, data: bytes) -> None:
        """Append ``data`` and hand it to the kernel now (a SIGKILL loses none of it);
        fsync when ``fsync_s`` has passed since the last one.  ``partial_bytes``: the bytes of
        ``data`` the kernel took before an error (a full disk can take part of a write)."""
        self.partial_bytes = 0
        if self._fd is None:
            self._fh.write(data)
            self._fh.flush()
        else:
            view = memoryview(data)
            while view:
                k = os.write(self._fd, view)
                self.partial_bytes += k
                view = view[k:]
        now = self._clock()
        if now - self._last >= self.fsync_s:
            self.sync()

    def sync(self) -> None:
        if self._fd is not None:
            os.fsync(self._fd)
        self._last = self._clock()

    def close(self) -> None:
        if self._fh is None:
            return
        try:
            if self._fd is not None:
                os.fsync(self._fd)
                self._fh.close()
            else:
                self._fh.flush()
        finally:
            self._fh = None
