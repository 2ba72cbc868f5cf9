"""The control channel: a Unix socket separate from the data socket.

Requests are one line each, a bare command or a JSON object
(``status`` or ``{"cmd": "status"}``); each reply is one JSON line with a
``class`` field.  Commands: status, calibration, poses, coverage, recalibrate, reset, reload.

The sampler calls :meth:`ControlServer.poll` once per batch and it never waits:
sockets are non-blocking, and what one poll does is bounded -- at most
:data:`MAX_CLIENTS` connections, :data:`PER_POLL` requests in all (round robin),
each client :data:`RATE_PER_S` requests per second (a token bucket, burst
:data:`BURST`), a request line at most :data:`MAX_LINE` bytes.  A client that
does not read its replies stops being served once :data:`MAX_OUT` bytes wait
for it (its requests wait in its own socket buffer), so unread replies cannot
grow the daemon.
"""
from __future__ import annotations

import json
import socket
import time
from typing import Callable, Dict, List, Optional

from .unixsock import UnixServer

__all__ = ["ControlServer", "request", "COMMANDS", "MAX_CLIENTS", "MAX_LINE", "MAX_OUT",
           "PER_POLL", "RATE_PER_S", "BURST"]

COMMANDS = ("status", "calibration", "poses", "coverage", "recalibrate", "reset", "reload")
MAX_CLIENTS = 16          #: control connections at once; more are refused with one line
MAX_LINE = 1024           #: bytes of one request line
MAX_OUT = 64 * 1024       #: reply bytes waiting for one client before its requests wait
PER_POLL = 4              #: requests answered per poll, all clients together
RATE_PER_S = 20.0         #: requests per second per client, sustained
BURST = 20.0              #: ... and at once

#: the other place a running daemon's sockets may be (status, watch, recalibrate say it)
RUNTIME_DIR_HINT = "one started with --runtime-dir DIR, as make run does, takes the same --runtime-dir here"


def _reply(d: Dict) -> bytes:
    return (json.dumps(d, separators=(",", ":")) + "\n").encode()


class _Conn:
    __slots__ = ("sock", "inbuf", "outbuf", "tokens", "t", "closing")

    def __init__(self, sock, now: float):
        self.sock, self.inbuf, self.outbuf = sock, bytearray(), bytearray()
        self.tokens, self.t, self.closing = BURST, now, False


class ControlServer(UnixServer):
    def __init__(self, path: str, handler: Callable[[str], Dict], mode: str = "0660",
                 group: Optional[str] = None, clock: Callable[[], float] = time.monotonic):
        self.handler, self.clock = handler, clock
        super().__init__(path, mode, group, 8, "control.socket")
        self.conns: List[_Conn] = []
        self.refused = 0         #: connections refused (MAX_CLIENTS)
        self.dropped = 0         #: clients dropped for an over-long request line
        self.throttled = 0       #: polls in which a client waited for its rate or its reader
        self._next = 0           # round-robin start

    def stats(self) -> Dict[str, int]:
        return {"clients": len(self.conns), "refused": self.refused, "dropped": self.dropped,
                "throttled": self.throttled}

    def poll(self) -> None:
        now = self.clock()
        self._accept(now)
        if not self.conns:
            return
        budget = PER_POLL
        n = len(self.conns)
        order = [self.conns[(self._next + i) % n] for i in range(n)]
        self._next = (self._next + 1) % n
        for c in order:
            budget -= self._serve(c, now, budget)
        self.conns = [c for c in self.conns if not self._flush_or_close(c)]

    def _accept(self, now: float) -> None:
        while True:
            try:
                s, _ = self.lsock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:             # EMFILE and the like: try again next poll
                return
            s.setblocking(False)
            if len(self.conns) >= MAX_CLIENTS:
                self.refused += 1
                try:
                    s.send(_reply({"class": "ERROR", "message": f"too many control clients "
                                   f"({MAX_CLIENTS}); try again later"}))
                except OSError:
                    pass
                s.close()
                continue
            self.conns.append(_Conn(s, now))

    def _serve(self, c: _Conn, now: float, budget: int) -> int:
        """Read what fits, answer up to ``budget`` requests; returns how many were answered."""
        c.tokens = min(BURST, c.tokens + (now - c.t) * RATE_PER_S)
        c.t = now
        room = MAX_LINE + 1 - len(c.inbuf)
        if not c.closing and room > 0 and b"\n" not in c.inbuf:
            try:
                d = c.sock.recv(max(room, 256))
                if not d:
                    c.closing = True
                c.inbuf += d
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                c.closing = True
                c.outbuf.clear()
                return 0
        done = 0
        while b"\n" in c.inbuf:
            if done >= budget or c.tokens < 1 or len(c.outbuf) >= MAX_OUT:
                self.throttled += 1
                break
            line, _, rest = bytes(c.inbuf).partition(b"\n")
            c.inbuf[:] = rest
            c.tokens -= 1
            done += 1
            c.outbuf += _reply(self.dispatch(line))
        if b"\n" not in c.inbuf and len(c.inbuf) > MAX_LINE:
            self.dropped += 1
            c.outbuf += _reply({"class": "ERROR", "message": f"request longer than {MAX_LINE} bytes"})
            c.inbuf.clear()
            c.closing = True
        return done

    def _flush_or_close(self, c: _Conn) -> bool:
        """Send what waits; True when the connection is finished with."""
        try:
            while c.outbuf:
                n = c.sock.send(c.outbuf)
                del c.outbuf[:n]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            c.sock.close()
            return True
        if c.closing and not c.outbuf and b"\n" not in c.inbuf:
            c.sock.close()
            return True
        return False

    def dispatch(self, raw: bytes) -> Dict:
        """One request line (bytes, without its newline) -> one reply object; never raises."""
        line = raw.decode("utf-8", "replace").strip()
        cmd = line
        if line.startswith("{"):
            try:
                obj = json.loads(line, object_pairs_hook=_no_repeated_keys)
            except _RepeatedKey as e:
                # which of two "cmd"s is meant is not for the daemon to guess: {"cmd": "status",
                # "cmd": "reset"} reset the poses, the last one winning (a cold review)
                return {"class": "ERROR", "message": f"key {str(e)[:40]!r} given twice in the request; "
                        "give it once"}
            except (ValueError, RecursionError):
                return {"class": "ERROR", "message": "request is not valid JSON; send a command "
                        "name or {\"cmd\": \"status\"}"}
            cmd = obj.get("cmd", "") if isinstance(obj, dict) else None
            if not isinstance(cmd, str):
                return {"class": "ERROR", "message": 'a JSON request is {"cmd": "<command>"}; allowed: '
                        + ", ".join(COMMANDS)}
        if cmd not in COMMANDS:
            return {"class": "ERROR", "message": f"unknown command {cmd[:40]!r}; allowed: {', '.join(COMMANDS)}"}
        try:
            return self.handler(cmd)
        except Exception as e:          # a control request must never kill the sampler
            return {"class": "ERROR", "message": f"{cmd} failed: {' '.join(str(e).split())}"}

    def connections(self) -> List[_Conn]:
        return self.conns


class _RepeatedKey(ValueError):
    pass


def _no_repeated_keys(pairs):
    """json.loads's object hook: a dict, or _RepeatedKey naming the first key given twice."""
    out = {}
    for k, v in pairs:
        if k in out:
            raise _RepeatedKey(k)
        out[k] = v
    return out


def request(path: str, cmd: str, timeout: float = 5.0) -> Dict:
    """One request/reply on the control socket (used by `imucald status` and friends)."""
    from ..errors import DeviceUnavailable as UserError      # exit 69: the service is not there
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    try:
        s.connect(path)
    except FileNotFoundError:
        raise UserError(f"{path}: no control socket: is imucald running? (systemctl status imucald; "
                        f"{RUNTIME_DIR_HINT})") from None
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
