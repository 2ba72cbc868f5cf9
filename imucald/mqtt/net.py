"""The MQTT bridge's plumbing: paho (the ``mqtt`` extra, imported here only), the
password file, and paho's loop driven by ``select`` with a wake-up pipe, so that a
message put in the buffer is handed to paho at once rather than at the next poll."""
from __future__ import annotations

import logging
import os
import select

from ..daemon.config import ConfigError
from ..errors import DeviceUnavailable, install_hint

__all__ = ["read_password", "paho", "Waker", "loop_once"]

log = logging.getLogger("imucald.mqtt")


def read_password(path: str) -> str:
    """The first line of ``path`` (``$VAR`` expanded, e.g. ``$CREDENTIALS_DIRECTORY/mqtt``)."""
    p = os.path.expandvars(path)
    try:
        with open(p, "rb") as fh:
            raw = fh.read(4097)
    except OSError as e:
        raise ConfigError(f"mqtt.password_file: {p}: cannot read ({e.strerror}): create it with the "
                          f"password on its first line, mode 0600") from None
    try:
        line = raw.decode("utf-8").splitlines()[0] if raw.strip() else ""
    except UnicodeDecodeError:
        raise ConfigError(f"mqtt.password_file: {p}: not UTF-8 text") from None
    if not line:
        raise ConfigError(f"mqtt.password_file: {p}: is empty: write the password on its first line")
    try:
        if os.stat(p).st_mode & 0o004:
            log.warning("%s is readable by every user: chmod 0600 it", p)
    except OSError:
        pass
    return line


def paho():
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        raise DeviceUnavailable(f"the MQTT bridge needs paho-mqtt, the mqtt extra: {install_hint('mqtt')}") from None
    return mqtt


class Waker:
    """A non-blocking pipe: ``wake()`` from any thread ends the net thread's select."""

    def __init__(self):
        self.r, self.w = os.pipe()
        os.set_blocking(self.r, False)
        os.set_blocking(self.w, False)

    def wake(self) -> None:
        try:
            os.write(self.w, b"x")
        except OSError:
            pass                # already awake (the pipe is full) or closed

    def drain(self) -> None:
        try:
            os.read(self.r, 4096)
        except OSError:
            pass

    def close(self) -> None:
        for fd in (self.r, self.w):
            try:
                os.close(fd)
            except OSError:
                pass
        self.r = self.w = -1


def loop_once(mqtt, client, waker: Waker, timeout_s: float = 1.0) -> int:
    """One turn of paho's loop: wait for the broker's socket or a wake-up, then read,
    write and keep alive (paho's loop_read/loop_write/loop_misc); paho's return code."""
    sock = client.socket()
    if sock is None:
        return mqtt.MQTT_ERR_NO_CONN
    try:
        r, w, _ = select.select([sock, waker.r], [sock] if client.want_write() else [], [], timeout_s)
    except (OSError, ValueError):
        return mqtt.MQTT_ERR_CONN_LOST
    if waker.r in r:
        waker.drain()
    rc = mqtt.MQTT_ERR_SUCCESS
    if sock in r:
        rc = client.loop_read()
    if rc == mqtt.MQTT_ERR_SUCCESS and (sock in w or client.want_write()):
        rc = client.loop_write()
    if rc == mqtt.MQTT_ERR_SUCCESS:
        rc = client.loop_misc()
    return rc
