"""The socket-server base: a socket file that exists accepts connections."""
import os
import socket

from imucald.daemon import unixsock


def test_socket_file_appears_only_once_listening(tmp_path, monkeypatch):
    """The path is visible only after listen(): a client that waits for the file (as
    systemd units, scripts and the tests do) is never refused. Seen to fail with the
    socket bound at the final path before listen() (the file existed at listen time)."""
    path = str(tmp_path / "imucald.sock")
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
        assert sorted(os.listdir(tmp_path)) == ["imucald.sock"]     # no temporary name left
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(path)
        c.close()
    finally:
        s.close()


def test_stale_socket_replaced(tmp_path):
    """A socket file left by a killed daemon is replaced, and the new one answers."""
    path = str(tmp_path / "c.sock")
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
