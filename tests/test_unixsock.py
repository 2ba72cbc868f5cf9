"""The socket-server base: a socket file that exists accepts connections."""
import os
import shutil
import socket
import tempfile

import pytest

from imucald.daemon import unixsock


@pytest.fixture
def short_dir():
    """A directory with a short path (pytest's tmp_path can exceed a socket path's 107
    bytes with a long $TMPDIR or user name, and then the socket is bound in place)."""
    d = tempfile.mkdtemp(prefix="us", dir="/tmp")
    yield d
    shutil.rmtree(d, ignore_errors=True)


def test_socket_file_appears_only_once_listening(short_dir, monkeypatch):
    """The path is visible only after listen(): a client that waits for the file (as
    systemd units, scripts and the tests do) is never refused. Seen to fail with the
    socket bound at the final path before listen() (the file existed at listen time)."""
    path = os.path.join(short_dir, "imucald.sock")
    seen = []

    class Probe(socket.socket):
        def listen(self, *a):
            seen.append(os.path.lexists(path))
            return super().listen(*a)

    monkeypatch.setattr(unixsock.socket, "socket", Probe)
    s = unixsock.listen_unix(path, "0660", None, 4)
    try:
        assert seen == [False]
        assert oct(os.stat(path).st_mode & 0o777) == "0o660"
        assert sorted(os.listdir(short_dir)) == ["imucald.sock"]     # no temporary name left
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(path)
        c.close()
    finally:
        s.close()


def test_stale_socket_replaced(short_dir):
    """A socket file left by a killed daemon is replaced, and the new one answers."""
    path = os.path.join(short_dir, "c.sock")
    old = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    old.bind(path)
    old.close()
    s = unixsock.listen_unix(path, "0600", None, 4)
    try:
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(path)
        c.close()
    finally:
        s.close()
