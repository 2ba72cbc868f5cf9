"""``imucald mqtt``: the bridge from the daemon's local sockets to an MQTT broker.

A process of its own (the daemon keeps ``PrivateNetwork=yes``): one thread reads the
NDJSON stream socket, the main loop polls the control socket every
``mqtt.status_interval_s``, paho's thread talks to the broker and a publisher thread hands
it the messages of a bounded buffer (:class:`~imucald.mqtt.topics.OutBuffer`, oldest
dropped and counted).  While the broker is away or refuses the login the bridge reconnects (0.1 s doubling
to 5 s, reset only by an accepted login; 5 logins refused for the credentials in a row: exit 78);
QoS 1/2 messages already handed to paho are resent by paho, at most ``INFLIGHT`` of them.
The sensor's identity (its fingerprint id) is in every topic and in the last will; when
the daemon comes back with another sensor the bridge says "offline" for the old one and
starts over under the new id.

paho-mqtt is imported here only (``pip install 'imucald[mqtt]'``).
"""
from __future__ import annotations

import logging
import os
import socket
import ssl
import threading
import time
from typing import Any, Callable, Dict, Optional

from ..daemon.config import ConfigError
from ..errors import UserError
from .net import Waker, loop_once, paho, read_password
from .topics import (Decimator, OutBuffer, Topics, cal_payload, calibration_summary, discovery_messages,
                     dumps, health_payload, info_payload, sample_payload)

__all__ = ["Bridge", "read_password", "INFLIGHT"]

log = logging.getLogger("imucald.mqtt")

#: messages handed to paho and not yet confirmed (QoS 0: written; 1/2: acknowledged)
INFLIGHT = 100

#: reconnect delay after a failed connect or a refused login: doubles from the first to the
#: last, and goes back to the first only once the broker accepted the login (CONNACK 0), not on
#: every TCP connect (a broker that accepts TCP and refuses the login is not hammered)
BACKOFF_S = (0.1, 5.0)

#: logins refused for the credentials (bad user name or password, not authorized) in a row
#: before the bridge gives up: exit 78 (configuration), which the unit does not restart
LOGIN_REFUSALS = 5

#: CONNACK reason codes that say the credentials are wrong (MQTT 5.0 0x86, 0x87; paho maps
#: MQTT 3.1.1's return codes 4 and 5 to them)
_BAD_LOGIN = (0x86, 0x87)


class Bridge:
    """One bridge.  ``cfg`` is the loaded configuration (its ``mqtt``, ``runtime``,
    ``output`` and ``control`` sections); ``stats`` holds the counters published in
    health's ``bridge`` object."""

    def __init__(self, cfg: Dict[str, Any], runtime_dir: Optional[str] = None,
                 clock: Callable[[], float] = time.time):
        self.mqtt = paho()
        self.m = dict(cfg["mqtt"])
        rt = runtime_dir or cfg["runtime"]["directory"]
        self.stream_path = os.path.join(rt, cfg["output"]["socket"])
        self.control_path = os.path.join(rt, cfg["control"]["socket"])
        if cfg["output"]["format"] != "ndjson":
            raise ConfigError(f"output.format: the MQTT bridge reads ndjson, the daemon is set to "
                              f"{cfg['output']['format']}: set output.format: ndjson")
        self.password = read_password(self.m["password_file"]) if self.m["password_file"] else None
        if self.m["tls"] and self.m["ca_file"] and not os.path.isfile(self.m["ca_file"]):
            raise ConfigError(f"mqtt.ca_file: {self.m['ca_file']}: no such file: give the CA "
                              f"certificate (PEM) that signed the broker's")
        self.port = self.m["port"] or (8883 if self.m["tls"] else 1883)
        self.clock = clock
        self.buf = OutBuffer(self.m["buffer"])
        self.cv = threading.Condition()
        self.connected = False
        self.inflight: Dict[int, int] = {}          # mid -> qos
        self.early: set = set()                     # mids confirmed before they were noted
        self.stats = {"published": 0, "dropped": 0, "lost_in_flight": 0, "connects": 0,
                      "disconnects": 0, "buffered": 0, "stream_reconnects": 0, "samples_read": 0,
                      "samples_out": 0, "gaps": 0, "missing_samples": 0, "unsent_at_stop": 0}
        self._stream = None
        #: one fetch-and-publish of the retained calibration at a time (the reader thread on a
        #: CAL event, the main loop when status shows a new id): see :meth:`_publish_calibration`
        self._cal_lock = threading.Lock()
        self.waker = Waker()
        self.version: Optional[Dict[str, Any]] = None
        self.last_connect_error: Optional[str] = None
        self.backoff_s = BACKOFF_S[0]
        self.refused = 0                            # logins refused in a row
        self.fatal: Optional[UserError] = None      # why the bridge gives up (exit code)
        self.stopping = False

    # -- the broker side ---------------------------------------------------------------
    def _client(self, topics: Topics, sensor_id: str):
        mqtt = self.mqtt
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=self.m["client_id"] or f"imucald-{sensor_id}",
                        protocol=mqtt.MQTTv311, clean_session=True)
        c.will_set(topics.status, b"offline", qos=self.m["qos"], retain=True)
        if self.m["username"]:
            c.username_pw_set(self.m["username"], self.password)
        if self.m["tls"]:
            c.tls_set(ca_certs=self.m["ca_file"], cert_reqs=ssl.CERT_REQUIRED)
        c.max_inflight_messages_set(INFLIGHT)

        def on_connect(client, userdata, flags, reason, props):
            if reason.is_failure:
                self.last_connect_error = str(reason)
                bad_login = getattr(reason, "value", None) in _BAD_LOGIN
                self.refused = self.refused + 1 if bad_login else 0
                if bad_login and self.refused >= LOGIN_REFUSALS:
                    self.fatal = ConfigError(
                        f"mqtt.username/mqtt.password_file: {self.m['host']}:{self.port} refused the login "
                        f"of {self.m['username'] or 'anonymous'!r} {self.refused} times in a row ({reason}): "
                        f"check the user name and the password file (and the broker's ACL), then "
                        f"restart the bridge")
                    log.error("%s:%d refused the connection: %s; giving up", self.m["host"], self.port, reason)
                else:
                    log.warning("%s:%d refused the connection: %s; retrying in %.1f s", self.m["host"],
                                self.port, reason, self.backoff_s)
                return
            self.backoff_s, self.refused = BACKOFF_S[0], 0
            self.stats["connects"] += 1
            log.info("connected to %s:%d (as %s)", self.m["host"], self.port, self.m["username"] or "anonymous")
            # birth and retained state first, straight to paho (it queues them ahead)
            q = self.m["qos"]
            client.publish(topics.status, b"online", qos=q, retain=True)
            client.publish(topics.info, dumps(self.info), qos=q, retain=True)
            if self.m["discovery"]:
                for t, p in discovery_messages(self.m["discovery_prefix"], topics, self.info):
                    client.publish(t, p, qos=q, retain=True)
            with self.cv:
                self.connected = True
                self.cv.notify_all()

        def on_disconnect(client, userdata, flags, reason, props):
            with self.cv:
                if self.stopping:
                    log.info("disconnected from %s:%d (clean stop)", self.m["host"], self.port)
                elif self.connected:
                    self.stats["disconnects"] += 1
                    log.warning("broker connection lost (%s); reconnecting, buffering up to %d messages",
                                reason, self.buf.size)
                self.connected = False
                lost = [mid for mid, qos in self.inflight.items() if qos == 0]
                for mid in lost:                    # QoS 0 not yet written: gone with the socket
                    del self.inflight[mid]
                self.stats["lost_in_flight"] += len(lost)

        def on_publish(client, userdata, mid, reason, props):
            with self.cv:
                if self.inflight.pop(mid, None) is not None:
                    self.stats["published"] += 1
                else:                               # confirmed before _hand_over noted it
                    self.early.add(mid)
                self.cv.notify_all()

        c.on_connect, c.on_disconnect, c.on_publish = on_connect, on_disconnect, on_publish
        return c

    def put(self, topic: str, payload: bytes, retain: bool = False) -> None:
        with self.cv:
            self.buf.put((topic, payload, self.m["qos"], retain))
            self.stats["dropped"] = self.buf.dropped
            self.cv.notify_all()
        self.waker.wake()

    def _net(self, client, end: threading.Event, topics: Topics) -> None:
        """The one thread that calls paho: connects, reconnects (0.1 s doubling to 5 s),
        runs paho's loop and hands it buffered messages, at most INFLIGHT unconfirmed.  (With
        paho's own loop thread, a publish from another thread racing the resend of a
        reconnect lost messages: here nothing calls paho concurrently.)"""
        mqtt = self.mqtt
        said, up, tried = False, False, False

        def back_off():
            end.wait(self.backoff_s)
            self.backoff_s = min(BACKOFF_S[1], self.backoff_s * 2)

        while not end.is_set() and self.fatal is None:
            if not up:
                try:
                    if tried:
                        client.reconnect()
                    else:
                        tried = True
                        client.connect(self.m["host"], self.port, keepalive=self.m["keepalive_s"])
                    up = True               # TCP only: the delay resets on the broker's CONNACK
                except (OSError, ssl.SSLError, ValueError) as e:
                    if not said:
                        log.warning("cannot reach the broker at %s:%d (%s); retrying",
                                    self.m["host"], self.port, e)
                    said = True
                    self.last_connect_error = str(e)
                    back_off()
                    continue
            rc = loop_once(mqtt, client, self.waker)
            if rc != mqtt.MQTT_ERR_SUCCESS:
                up = False
                if self.fatal is None:
                    back_off()
                continue
            self._hand_over(client)
        # stopping: the birth topic says offline (a clean disconnect sends no will)
        self.stopping = True
        if self.connected:
            info = client.publish(topics.status, b"offline", qos=self.m["qos"], retain=True)
            t_end = time.monotonic() + 2.0
            while not info.is_published() and time.monotonic() < t_end and \
                    client.loop(timeout=0.02) == mqtt.MQTT_ERR_SUCCESS:
                pass
            client.disconnect()
            client.loop(timeout=0.02)
        self.connected = False

    def _hand_over(self, client) -> None:
        mqtt = self.mqtt
        while True:
            with self.cv:
                if not (self.connected and len(self.buf) and len(self.inflight) < INFLIGHT):
                    return
                msg = self.buf.get()
            topic, payload, qos, retain = msg
            info = client.publish(topic, payload, qos=qos, retain=retain)
            with self.cv:
                if info.rc == mqtt.MQTT_ERR_SUCCESS or (qos > 0 and info.rc == mqtt.MQTT_ERR_NO_CONN):
                    # paho has it (QoS 1/2: resent by paho after a reconnect)
                    if info.mid in self.early:
                        self.early.discard(info.mid)
                        self.stats["published"] += 1
                    else:
                        self.inflight[info.mid] = qos
                else:
                    self.buf.put_front(msg)         # QoS 0 while the connection went: again later
                    self.stats["dropped"] = self.buf.dropped
                    return

    def _flush(self, timeout_s: float) -> None:
        t_end = time.monotonic() + timeout_s
        with self.cv:
            while (len(self.buf) or self.inflight) and self.connected and time.monotonic() < t_end:
                self.cv.wait(0.02)

    # -- the daemon side ---------------------------------------------------------------
    def _request(self, cmd: str) -> Dict[str, Any]:
        from ..daemon.control import request
        return request(self.control_path, cmd, timeout=5.0)

    def _wait_for_daemon(self, stop: threading.Event) -> Optional[Dict[str, Any]]:
        said = False
        while not stop.is_set():
            try:
                st = self._request("status")
                if st.get("class") == "STATUS":
                    return st
            except (UserError, OSError, ValueError) as e:
                if not said:
                    log.warning("waiting for the daemon: %s", " ".join(str(e).split()))
                    said = True
            stop.wait(1.0)
        return None

    def _reader(self, topics: Topics, sid: str, stop: threading.Event, changed: threading.Event) -> None:
        from ..client import StreamClient
        dec = Decimator(self.m["sample_rate_hz"])
        first = True
        while not stop.is_set():
            try:
                s = self._stream = StreamClient(self.stream_path, timeout_s=5.0)
            except (UserError, OSError) as e:      # not there yet, or no banner within 5 s
                refused = "refused this client" in str(e)
                if refused and not getattr(self, "_refusal_said", False):
                    log.warning("stream: %s", e)    # said once; retried as any absence
                self._refusal_said = refused
                if not refused:
                    log.debug("stream: %s", e)
                stop.wait(0.5)
                continue
            if not first:
                self.stats["stream_reconnects"] += 1
                # the daemon restarted: is it still the same sensor?
                try:
                    st = self._request("status")
                    if ((st.get("sensor") or {}).get("id") or st.get("board", "unknown")) != sid:
                        changed.set()
                        s.close()
                        return
                except (UserError, OSError, ValueError):
                    pass
            first = False
            if s.version != self.version:
                self.version = s.version        # the daemon's release goes into info and discovery
                self.info = info_payload(self.status0, s.version)
                self.put(topics.info, dumps(self.info), retain=True)
                if self.m["discovery"]:
                    for t, p in discovery_messages(self.m["discovery_prefix"], topics, self.info):
                        self.put(t, p, retain=True)
            try:
                for rec in s:
                    if stop.is_set():
                        break
                    self._record(rec, dec, topics)
            except socket.timeout:
                log.warning("stream: no data for 5 s; reconnecting")
            except (UserError, OSError) as e:
                log.warning("stream: %s", " ".join(str(e).split()))
            finally:
                s.close()

    def _record(self, rec: Dict[str, Any], dec: Decimator, topics: Topics) -> None:
        cls = rec.get("class")
        now = self.clock()
        if cls == "IMU":
            self.stats["samples_read"] += 1
            if dec.accept(rec.get("t", 0.0)):
                self.stats["samples_out"] += 1
                self.put(topics.imu, dumps(sample_payload(rec, now)))
        elif cls == "GAP":
            self.stats["gaps"] += 1
            self.stats["missing_samples"] += int(rec.get("missing", 0))
            self.put(topics.event("gap"), dumps({**{k: v for k, v in rec.items() if k != "class"},
                                                 "time": round(now, 3)}))
        elif cls == "CAL":
            cal = self._publish_calibration(topics) if rec.get("applied") else None
            self.put(topics.event("cal"), dumps(cal_payload(rec, cal, now)))

    def _publish_calibration(self, topics: Topics) -> Optional[Dict[str, Any]]:
        """Fetch the calibration in force from the control socket and publish it (retained);
        returns it, or None when the daemon did not give it.  Fetch and publish are one step
        under a lock: the reader thread (a CAL event) and the main loop (status naming a new
        id) both do this, and unlocked, a fetch of #5 published after another thread's #6
        left the older calibration retained (and cal_id at 5) until the next status poll."""
        with self._cal_lock:
            try:
                cal = self._request("calibration")
            except (UserError, OSError, ValueError):
                return None
            if not isinstance(cal, dict) or cal.get("class") != "CALIBRATION":
                return None
            self.put(topics.calibration, dumps(calibration_summary(cal)), retain=True)
            self.cal_id = cal.get("id")
            return cal

    # -- the whole -----------------------------------------------------------------------
    def run(self, stop: threading.Event) -> int:
        """Bridge until ``stop`` is set; 0 on a clean stop."""
        try:
            while not stop.is_set() and self.fatal is None:
                st = self._wait_for_daemon(stop)
                if st is None:
                    break
                self._session(st, stop)
        finally:
            self.waker.close()
        if self.fatal is not None:
            raise self.fatal
        log.info("stopped (clean stop): %d messages published, %d unsent", self.stats["published"],
                 self.stats["unsent_at_stop"])
        return 0

    def _session(self, st: Dict[str, Any], stop: threading.Event) -> None:
        sid = (st.get("sensor") or {}).get("id") or st.get("board", "unknown")
        topics = Topics(self.m["topic_prefix"], sid)
        self.status0 = st
        self.info = info_payload(st, self.version)
        self.cal_id = None
        log.info("bridging sensor %s (%s) to %s:%d under %s/", sid, st.get("board"), self.m["host"],
                 self.port, topics.base)
        client = self._client(topics, sid)
        self.stopping = False
        end, reading = threading.Event(), threading.Event()
        changed = threading.Event()
        reader = threading.Thread(target=self._reader, args=(topics, sid, reading, changed), daemon=True)
        publisher = threading.Thread(target=self._net, args=(client, end, topics), daemon=True)
        for t in (reader, publisher):
            t.start()
        last = None         # (wall time, samples) of the previous status
        try:
            while not stop.is_set() and not changed.is_set() and self.fatal is None:
                try:
                    st = self._request("status")
                except (UserError, OSError, ValueError):
                    st = None
                if st is not None and st.get("class") == "STATUS":
                    new_sid = (st.get("sensor") or {}).get("id") or st.get("board", "unknown")
                    if new_sid != sid:
                        log.warning("the daemon now reads sensor %s (was %s): starting over under its id",
                                    new_sid, sid)
                        break
                    self._health(st, topics, last)
                    bs = st.get("board_stats") or {}
                    last = (self.clock(), bs.get("samples", st.get("samples", 0)))
                t_next = time.monotonic() + self.m["status_interval_s"]
                while not (stop.is_set() or changed.is_set() or self.fatal) and time.monotonic() < t_next:
                    stop.wait(min(0.1, self.m["status_interval_s"]))
        finally:
            # stop reading first, so that what was read is sent (or counted as not sent)
            reading.set()
            sc = self._stream
            if sc is not None:
                try:
                    sc.sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
            reader.join(5.0)
            self._flush(2.0)
            with self.cv:
                self.stats["unsent_at_stop"] += len(self.buf) + len(self.inflight)
                self.buf.q.clear()
                self.inflight.clear()
            end.set()
            publisher.join(5.0)

    def _health(self, st: Dict[str, Any], topics: Topics, last) -> None:
        now = self.clock()
        bs = st.get("board_stats") or {}
        n = bs.get("samples", st.get("samples", 0))
        rate = None
        if last is not None and now > last[0] and n >= last[1]:
            rate = (n - last[1]) / (now - last[0])
        if st.get("calibration_id") and st.get("calibration_id") != self.cal_id:
            self._publish_calibration(topics)
        with self.cv:
            self.stats["buffered"] = len(self.buf)
            bridge = dict(self.stats, connected=self.connected)
        self.put(topics.health, dumps(health_payload(st, rate, bridge, now)), retain=True)
