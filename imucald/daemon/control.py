"""The control channel: a Unix socket separate from the data socket.

Requests are one line each, a bare command or a JSON object
(``status`` or ``{"cmd": "status"}``); each reply is one JSON line with a
``class`` field.  Commands: status, poses, coverage, recalibrate, reset, reload.
"""
from __future__ import annotations

import json
import os
import socket
from typing import Callable, Dict, List, Optional


__all__ = ["ControlServer", "request", "COMMANDS"]

COMMANDS = ("status", "poses", "coverage", "recalibrate", "reset", "reload")


class ControlServer:
    def __init__(self, path: str, handler: Callable[[str], Dict], mode: str = "0660",
                 group: Optional[str] = None):
        from .outputs import listen_unix     # here: the client side (status) stays without numpy
        self.path, self.handler = path, handler
        self.lsock = listen_unix(path, mode, group, 8, "control.socket")
        self.conns: List[list] = []          # [sock, inbuf, outbuf]

    def poll(self) -> None:
        while True:
            try:
                s, _ = self.lsock.accept()
            except (BlockingIOError, InterruptedError):
                break
            s.setblocking(False)
            self.conns.append([s, bytearray(), bytearray()])
        keep = []
        for c in self.conns:
            s, ib, ob = c
            alive = True
            try:
                while True:
                    d = s.recv(4096)
                    if not d:
                        alive = False
                        break
                    ib += d
                    if len(ib) > 65536:
                        alive = False
                        break
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                alive = False
            while b"\n" in ib:
                line, _, rest = bytes(ib).partition(b"\n")
                ib[:] = rest
                ob += (json.dumps(self._dispatch(line.decode("utf-8", "replace").strip()),
                                  separators=(",", ":")) + "\n").encode()
            try:
                while ob:
                    n = s.send(ob)
                    del ob[:n]
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                alive = False
            if alive or ob:
                keep.append(c) if alive else s.close()
            else:
                s.close()
        self.conns = keep

    def _dispatch(self, line: str) -> Dict:
        cmd = line
        if line.startswith("{"):
            try:
                cmd = json.loads(line).get("cmd", "")
            except (ValueError, AttributeError):
                return {"class": "ERROR", "message": "request is not valid JSON"}
        if cmd not in COMMANDS:
            return {"class": "ERROR", "message": f"unknown command {cmd!r}; allowed: {', '.join(COMMANDS)}"}
        try:
            return self.handler(cmd)
        except Exception as e:          # a control request must never kill the sampler
            return {"class": "ERROR", "message": f"{cmd} failed: {e}"}

    def close(self) -> None:
        for s, _, _ in self.conns:
            s.close()
        self.lsock.close()
        try:
            os.unlink(self.path)
        except OSError:
            pass


def request(path: str, cmd: str, timeout: float = 5.0) -> Dict:
    """One request/reply on the control socket (used by `imucald status` and friends)."""
    from ..errors import DeviceUnavailable as UserError      # exit 69: the service is not there
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    try:
        s.connect(path)
    except FileNotFoundError:
        raise UserError(f"{path}: no control socket: is imucald running? (systemctl status imucald)") from None
    except PermissionError:
        raise UserError(f"{path}: permission denied: join the socket's group, or use sudo") from None
    except OSError as e:
        raise UserError(f"{path}: cannot connect: {e.strerror}") from None
    with s:
        s.sendall((cmd + "\n").encode())
        buf = b""
        while not buf.endswith(b"\n"):
            try:
                d = s.recv(65536)
            except socket.timeout:
                raise UserError(f"{path}: no reply within {timeout:g} s") from None
            if not d:
                break
            buf += d
    return json.loads(buf.decode())
