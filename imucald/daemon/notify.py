"""systemd's notify protocol: one datagram of KEY=VALUE lines to $NOTIFY_SOCKET.

Written from sd_notify(3)'s description of the protocol (a leading '@' names the
abstract namespace); no dependency.
"""
from __future__ import annotations

import os
import socket
from typing import Optional

__all__ = ["notify", "watchdog_period_s"]


def notify(*fields: str) -> bool:
    """Send fields such as 'READY=1', 'STATUS=...'; False when not under systemd."""
    addr = os.environ.get("NOTIFY_SOCKET", "")
    if not addr or addr[0] not in "/@":
        return False
    if addr[0] == "@":
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
            s.connect(addr)
            s.sendall("\n".join(fields).encode())
    except OSError:
        return False
    return True


def watchdog_period_s() -> Optional[float]:
    """Half of WatchdogSec= (systemd's advice for the ping period), or None."""
    usec, pid = os.environ.get("WATCHDOG_USEC"), os.environ.get("WATCHDOG_PID")
    if not usec or (pid and int(pid) != os.getpid()):
        return None
    return int(usec) / 2e6
