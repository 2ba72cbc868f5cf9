"""Listening Unix stream sockets: creating one (path checks, mode and group for systemd
units) and the base both servers on them share -- the corrected stream
(:class:`imucald.daemon.outputs.SocketSink`) and the control channel
(:class:`imucald.daemon.control.ControlServer`).

No numpy here: the client side of the control channel (``imucald status``) imports the
control module and stays light.
"""
from __future__ import annotations

import errno
import grp
import os
import socket
import stat
from typing import Iterable, Optional

__all__ = ["UNIX_PATH_MAX", "check_socket_path", "set_mode_group", "listen_unix", "UnixServer"]

#: longest path a Unix socket address holds (sun_path is 108 bytes with its NUL, unix(7))
UNIX_PATH_MAX = 107


def set_mode_group(path: str, mode: str, group: Optional[str], key: str = "socket",
                   shown: Optional[str] = None) -> None:
    """Mode and group of a socket or FIFO just made; one line naming the setting and the fix
    (exit 73, "cannot create": a restart cannot fix it, the unit does not retry it).
    ``shown``: the path the messages name (the final one, when ``path`` is a temporary name)."""
    from ..errors import CannotCreate
    real, path = path, shown or path
    try:
        os.chmod(real, int(mode, 8))
    except OSError as e:
        raise CannotCreate(f"{key}: cannot set mode {mode} on {path}: {e.strerror}") from None
    if group:
        try:
            gid = grp.getgrnam(group).gr_gid
        except KeyError:
            from .config import ConfigError
            raise ConfigError(f"socket_group: group {group!r} does not exist (getent group lists "
                              f"them; create it with groupadd or change the setting)") from None
        try:
            os.chown(real, -1, gid)
        except OSError as e:
            # EPERM: a process may give a file only to a group it is in (chown(2))
            raise CannotCreate(
                f"{key}: cannot give {path} to group {group!r} ({e.strerror}): this process "
                f"(uid {os.getuid()}) is not in that group: add SupplementaryGroups={group} to the "
                f"unit (systemctl edit imucald, or imucald@NAME) or choose a group it is in for "
                f"{key.split('.')[0]}.socket_group") from None


def check_socket_path(path: str, key: str) -> None:
    """A socket can be created at ``path``: short enough, and not taken by a file that
    is not a socket (``key`` names the setting, for the message)."""
    from ..errors import CannotCreate
    n = len(os.fsencode(path))
    if n > UNIX_PATH_MAX:
        raise CannotCreate(f"{key}: {path} is {n} bytes; a Unix socket path holds at most "
                           f"{UNIX_PATH_MAX}: choose a shorter runtime.directory (--runtime-dir)")
    if os.path.lexists(path) and not stat.S_ISSOCK(os.lstat(path).st_mode):
        what = "a directory" if os.path.isdir(path) else "a file"
        raise CannotCreate(f"{key}: {path} exists and is {what}, not a socket: move it away "
                           f"or choose another {key}")
    if os.path.lexists(path) and not _stale(path):
        # a live socket is another process's, even where no lock covers it (an absolute path
        # outside this runtime directory: a second daemon took a first one's sockets, and the
        # first removed them on its way out, a cold review); only a refused one is replaced
        from ..errors import AlreadyRunning
        raise AlreadyRunning(f"{key}: {path} is in use, or not ours to test (another process "
                             f"listens there, or its owner keeps us out): stop that process, or "
                             f"choose another {key}")


#: how long the probe of an existing socket waits for its answer, s
PROBE_TIMEOUT_S = 1.0


def _stale(path: str) -> bool:
    """Whether the Unix socket file at ``path`` is stale: a connection refused (no process
    listens) or the file gone.  Anything else is taken as in use: an answer, a full backlog
    (EAGAIN: a busy or hung listener), a timeout, a permission refused (another user's
    socket; a cold review found all three read as stale and the socket replaced)."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(PROBE_TIMEOUT_S)
    try:
        s.connect(path)
        return False
    except OSError as e:
        return e.errno in (errno.ECONNREFUSED, errno.ENOENT)
    finally:
        s.close()


def listen_unix(path: str, mode: str, group: Optional[str], backlog: int,
                key: str = "socket") -> socket.socket:
    """A non-blocking listening Unix stream socket at ``path`` (a stale one is replaced:
    the daemon holds the runtime directory's lock, so no other instance is using it).

    The socket is bound under a temporary name beside ``path``, given its mode and group,
    put to listen, and only then renamed into place: a client that sees ``path`` can
    connect at once (bound at ``path`` itself, a connect between bind and listen was
    refused)."""
    check_socket_path(path, key)
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.{os.getpid()}~")
    if len(os.fsencode(tmp)) > UNIX_PATH_MAX:    # then bound in place (the path itself fits)
        tmp = path
    for stale in (tmp, path):
        if os.path.lexists(stale):
            os.unlink(stale)
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.bind(tmp)
    except OSError as e:
        s.close()
        from ..errors import CannotCreate
        raise CannotCreate(f"{key}: cannot create the socket {path}: {e.strerror}") from None
    try:
        set_mode_group(tmp, mode, group, key, shown=path)
        s.listen(backlog)
        if tmp != path:
            os.replace(tmp, path)
    except Exception:
        s.close()
        if os.path.lexists(tmp):
            os.unlink(tmp)
        raise
    s.setblocking(False)
    return s


class UnixServer:
    """A listening Unix socket at ``path`` (``lsock``) with its connected clients; a
    subclass says where it keeps them (:meth:`connections`: objects with a ``sock``).
    :meth:`close` closes every client and the listener and removes the socket file."""

    def __init__(self, path: str, mode: str, group: Optional[str], backlog: int, key: str):
        self.path = path
        self.lsock = listen_unix(path, mode, group, backlog, key)

    def connections(self) -> Iterable:
        raise NotImplementedError

    def close(self) -> None:
        for c in self.connections():
            c.sock.close()
        self.lsock.close()
        try:
            os.unlink(self.path)
        except OSError:
            pass
