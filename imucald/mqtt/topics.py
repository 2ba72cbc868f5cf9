"""The MQTT bridge's topic tree and payloads: pure functions, no network, no paho.

Topic tree (``P`` = ``mqtt.topic_prefix``, ``ID`` = the sensor's fingerprint id, the 12 hex
digits ``imucald status`` shows, so two boards on one broker never mix)::

    P/ID/status        retained  "online" | "offline" (the last will: a bridge that dies says offline)
    P/ID/info          retained  board, chips, fingerprint, bus, release of the daemon
    P/ID/imu                     decimated corrected samples (the stream's IMU objects)
    P/ID/health        retained  sample rate, gaps, faults, calibration age, the bridge's own counters
    P/ID/calibration   retained  the calibration in force: parameters, standard errors, quality
    P/ID/event/cal               each calibration attempt (applied or not), quality and uncertainties
    P/ID/event/gap               each gap in the sample stream (the stream's GAP objects)
    P/ID/event/sensor            the sensor changed under the daemon (a swapped board)

Payloads are JSON objects (status is the bare word); units are in the field names as in
the stream (``_g``, ``_dps``, ``_gauss``, ``_c``, ``_s``, ``_hz``).
"""
from __future__ import annotations

import collections
import json
import math
from datetime import datetime, timezone
from typing import Any, Deque, Dict, List, Optional, Tuple

__all__ = ["Topics", "Decimator", "OutBuffer", "sample_payload", "cal_payload", "health_payload",
           "info_payload", "calibration_summary", "discovery_messages", "dumps"]

Message = Tuple[str, bytes, int, bool]      # topic, payload, qos, retain


def dumps(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


class Topics:
    """The topics of one sensor under ``prefix``."""

    def __init__(self, prefix: str, sensor_id: str):
        self.base = f"{prefix.strip('/')}/{sensor_id}"
        self.status = f"{self.base}/status"
        self.info = f"{self.base}/info"
        self.imu = f"{self.base}/imu"
        self.health = f"{self.base}/health"
        self.calibration = f"{self.base}/calibration"

    def event(self, kind: str) -> str:
        return f"{self.base}/event/{kind}"


class Decimator:
    """Passes one sample per 1/rate_hz of the stream's own clock ``t`` (s): the first
    sample of each interval, so the choice does not depend on batching or on when the
    bridge connected, and a restart of the bridge picks the same samples."""

    def __init__(self, rate_hz: float):
        self.period_s = 1.0 / float(rate_hz)
        self.last: Optional[int] = None

    def accept(self, t_s: float) -> bool:
        k = math.floor(t_s / self.period_s + 1e-9)
        if k == self.last:
            return False            # same interval (a t behind it: the daemon restarted)
        self.last = k
        return True


class OutBuffer:
    """Messages waiting for the broker, at most ``size``; when full the oldest is dropped
    and counted (``dropped``, per topic kind in ``dropped_by``), so a broker that is away
    never grows the bridge and what arrives afterwards is the newest."""

    def __init__(self, size: int):
        self.q: Deque[Message] = collections.deque()
        self.size = int(size)
        self.dropped = 0
        self.dropped_by: Dict[str, int] = {}

    def __len__(self) -> int:
        return len(self.q)

    def put(self, msg: Message) -> None:
        if len(self.q) >= self.size:
            old = self.q.popleft()
            self.dropped += 1
            kind = old[0].rsplit("/", 1)[-1]
            self.dropped_by[kind] = self.dropped_by.get(kind, 0) + 1
        self.q.append(msg)

    def put_front(self, msg: Message) -> None:
        """A message taken but not handed over (the connection went meanwhile)."""
        if len(self.q) >= self.size:
            self.dropped += 1
            return
        self.q.appendleft(msg)

    def get(self) -> Optional[Message]:
        return self.q.popleft() if self.q else None


def sample_payload(rec: Dict[str, Any], now_s: float) -> Dict[str, Any]:
    """An IMU record as published: the stream's fields unchanged (``seq``, ``t`` s since the
    daemon started, ``acc_g``, ``gyro_dps``, ``mag_gauss``, ``temp_c``, ``still``, ``cal``, and
    ``acc_var_g2``/``gyro_var_dps2`` when the daemon streams them; with orientation on ``q``
    [w, x, y, z] body -> ENU, ``lin_acc_g``, ``heading``, ``incl_std_deg``, ``heading_std_deg``,
    ``q_cov_rad2``) plus ``time``: Unix time (s) at which the bridge read it, and with ``q``
    also ``roll_deg``, ``pitch_deg``, ``heading_deg`` (compass, from magnetic north or
    arbitrary as ``heading`` says; :func:`imucald.client.attitude_deg`)."""
    out = {k: v for k, v in rec.items() if k != "class"}
    out["time"] = round(now_s, 6)
    q = rec.get("q")
    if q is not None:
        from ..client import attitude_deg
        r, p, h = attitude_deg(q)
        out["roll_deg"], out["pitch_deg"], out["heading_deg"] = round(r, 3), round(p, 3), round(h, 3)
    return out


def calibration_summary(cal: Dict[str, Any]) -> Dict[str, Any]:
    """The control socket's ``calibration`` reply, per sensor part: model, parameters,
    their standard errors (null where not determined) and the quality figures."""
    out: Dict[str, Any] = {k: cal[k] for k in ("id", "created", "board", "sensor", "units",
                                               "temperature_range_c") if k in cal}
    out["provisional"] = cal.get("provisional") is not None
    if cal.get("provisional"):
        out["missing_orientations"] = cal["provisional"].get("missing_orientations", [])
    for part in ("accel", "gyro", "mag"):
        p = cal.get(part)
        if p:
            out[part] = {k: p[k] for k in ("model", "method", "params", "stderr", "quality") if k in p}
    return out


def cal_payload(event: Dict[str, Any], cal: Optional[Dict[str, Any]], now_s: float) -> Dict[str, Any]:
    """A CAL event: the stream's quality figures (held-out RMS after and before, g, and the
    predicted one), plus, when it was applied, the standard errors of the calibration now
    in force (``stderr`` per part) from the control socket."""
    out = {k: v for k, v in event.items() if k != "class"}
    out["time"] = round(now_s, 3)
    if cal is not None and event.get("applied") and cal.get("id") == event.get("id"):
        s = calibration_summary(cal)
        for part in ("accel", "gyro", "mag"):
            if part in s:
                out[part] = {k: s[part][k] for k in ("model", "stderr", "quality") if k in s[part]}
    return out


def _age_s(created: Optional[str], now_s: float) -> Optional[float]:
    if not created:
        return None
    try:
        t = datetime.fromisoformat(created)
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    return round(now_s - t.timestamp(), 1)


def health_payload(status: Dict[str, Any], measured_rate_hz: Optional[float], bridge: Dict[str, Any],
                   now_s: float) -> Dict[str, Any]:
    """Health from the control socket's ``status`` reply and the bridge's own counters."""
    bs = status.get("board_stats") or {}
    st = status.get("state") or {}
    wk = status.get("worker") or {}
    errs = (status.get("bus_stats") or {}).get("errors") or {}
    cid = status.get("calibration_id", 0)
    out = {
        "time": round(now_s, 3),
        "rate_hz": status.get("rate_hz"),
        "measured_rate_hz": None if measured_rate_hz is None else round(measured_rate_hz, 2),
        "samples": bs.get("samples", status.get("samples")),
        "gaps": bs.get("gaps", 0), "missing_samples": bs.get("missing", 0),
        "faults": {"bus_faults": bs.get("bus_faults", 0), "reinits": bs.get("reinits", 0),
                   "fifo_resets": bs.get("fifo_resets", 0), "bus_errors": sum(errs.values()),
                   "worker_died": wk.get("died", 0), "worker_timeouts": wk.get("timeouts", 0),
                   "state_ok": bool(st.get("ok", True))},
        "calibration_id": cid,
        "calibration_age_s": _age_s(status.get("calibration_created"), now_s) if cid else None,
        "calibration_provisional": status.get("calibration_provisional") if cid else None,
        "calibrating": status.get("calibrating"),
        "poses": status.get("poses"), "poses_needed": status.get("poses_needed"),
        "coverage": status.get("coverage"),
        "sensor_status": (status.get("sensor") or {}).get("status"),
        "stream_clients_dropped": status.get("clients_dropped"),
        "bridge": bridge,
    }
    if status.get("last_event"):
        out["last_event"] = status["last_event"]
    return out


def info_payload(status: Dict[str, Any], version: Optional[Dict[str, Any]]) -> Dict[str, Any]:
    sn = status.get("sensor") or {}
    out = {"sensor_id": sn.get("id"), "board": status.get("board"), "chips": status.get("chips"),
           "bus": status.get("bus"), "rate_hz": status.get("rate_hz"),
           "fingerprint": sn.get("fingerprint")}
    if version:
        out["release"] = version.get("release")
        out["proto"] = f"{version.get('proto_major')}.{version.get('proto_minor')}"
        if version.get("orientation"):
            out["orientation"] = version["orientation"]
    return out


#: Home Assistant sensors: key, name, value template (on P/ID/health), unit, device class
_HA_HEALTH = (
    ("rate", "sample rate", "{{ value_json.measured_rate_hz }}", "Hz", "frequency"),
    ("gaps", "stream gaps", "{{ value_json.gaps }}", None, None),
    ("missing", "samples lost", "{{ value_json.missing_samples }}", None, None),
    ("bus_faults", "bus faults", "{{ value_json.faults.bus_faults }}", None, None),
    ("cal_id", "calibration id", "{{ value_json.calibration_id }}", None, None),
    ("cal_age", "calibration age", "{{ value_json.calibration_age_s }}", "s", "duration"),
    ("poses", "poses", "{{ value_json.poses }}", None, None),
    ("dropped", "MQTT messages dropped", "{{ value_json.bridge.dropped }}", None, None),
)
_HA_IMU = (
    ("temp", "temperature", "{{ value_json.temp_c }}", "°C", "temperature"),
    ("acc_x", "acceleration x", "{{ value_json.acc_g[0] }}", "g", None),
    ("acc_y", "acceleration y", "{{ value_json.acc_g[1] }}", "g", None),
    ("acc_z", "acceleration z", "{{ value_json.acc_g[2] }}", "g", None),
)
#: with orientation on (the info payload's ``orientation``)
_HA_ORIENT = (
    ("roll", "roll", "{{ value_json.roll_deg }}", "°", None),
    ("pitch", "pitch", "{{ value_json.pitch_deg }}", "°", None),
    ("heading", "heading", "{{ value_json.heading_deg }}", "°", None),
)


def discovery_messages(prefix: str, topics: Topics, info: Dict[str, Any]) -> List[Tuple[str, bytes]]:
    """Home Assistant MQTT discovery: one retained config per sensor entity
    (``<discovery prefix>/sensor/imucald_<ID>/<key>/config``), grouped as one device per
    physical sensor, available while ``P/ID/status`` is ``online``."""
    sid = info.get("sensor_id") or topics.base.rsplit("/", 1)[-1]
    device = {"identifiers": [f"imucald_{sid}"], "name": f"imucald {info.get('board')} {sid}",
              "model": info.get("board"), "manufacturer": "imucald", "sw_version": info.get("release")}
    out = []
    groups = [(_HA_HEALTH, topics.health), (_HA_IMU, topics.imu)]
    if info.get("orientation") == "on":
        groups.append((_HA_ORIENT, topics.imu))
    for group, state_topic in groups:
        for key, name, tmpl, unit, dclass in group:
            if key == "temp" and not info.get("chips"):
                continue
            cfg = {"name": name, "unique_id": f"imucald_{sid}_{key}", "state_topic": state_topic,
                   "value_template": tmpl, "availability_topic": topics.status,
                   "payload_available": "online", "payload_not_available": "offline",
                   "device": device}
            if unit:
                cfg["unit_of_measurement"] = unit
            if dclass:
                cfg["device_class"] = dclass
            if group is not _HA_IMU or key == "temp":
                cfg["state_class"] = "measurement"
            out.append((f"{prefix.strip('/')}/sensor/imucald_{sid}/{key}/config", dumps(cfg)))
    return out
