"""Calibrations tied to the physical sensor.

A sensor is known by its fingerprint (:meth:`imucald.drivers.board.Board.fingerprint`:
board, bus, chip addresses and IDs, and the factory trim the chips expose) and by the
fingerprint's id, the first 12 hex digits of its SHA-256.  The state directory holds
the files of the sensor the daemon last ran with; every other sensor seen there keeps
its own under ``sensors/<id>/``::

    STATE/sensor.yaml                       id, fingerprint, first_seen, last_seen
    STATE/calibration.yaml, poses.csv, thermal.csv, history/   that sensor's calibration, poses, thermal log
    STATE/sensors/<id>/...                  the same files of a sensor seen before

At start :func:`adopt_sensor` compares the running sensor with ``sensor.yaml``.  A
different one (a swapped board) moves the files beside it to ``sensors/<old id>/``
and brings back its own from ``sensors/<new id>/`` if it was seen before, else it
starts uncalibrated.  The steps are ordered so that a crash between them can only
leave the new sensor uncalibrated, never with another sensor's calibration; and
every calibration the daemon writes carries its sensor's id, checked again on load.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from datetime import datetime, timezone
from typing import Any, Dict, Optional

__all__ = ["fingerprint_id", "adopt_sensor", "SENSOR_FILE", "SENSOR_FILES"]

log = logging.getLogger("imucald")
SENSOR_FILE = "sensor.yaml"
#: the per-sensor files of the state directory
SENSOR_FILES = ("calibration.yaml", "poses.csv", "thermal.csv", "history")


def fingerprint_id(fp: Dict[str, Any]) -> str:
    """12 hex digits of the SHA-256 of the fingerprint's canonical JSON."""
    return hashlib.sha256(json.dumps(fp, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:12]


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _read_sensor(state_dir: str) -> Optional[Dict[str, Any]]:
    from ..files.atomic import read_own_file
    from ..errors import UserError
    from ..files.yamlsafe import load
    p = os.path.join(state_dir, SENSOR_FILE)
    if not os.path.lexists(p):
        return None
    try:
        d = load(read_own_file(p, 1 << 16, UserError), p, UserError)
        if isinstance(d, dict) and isinstance(d.get("id"), str):
            return d
        # say what is there (a cold review: "id: 5" read as "no id")
        why = ("not a mapping of keys" if not isinstance(d, dict) else "no id" if "id" not in d
               else f"id: {d['id']!r} is not text (the daemon writes 12 hex digits, e.g. id: 3f9a0c2be417)")
    except UserError as e:
        why = " ".join(str(e).split())[:160]
    from .state import set_aside
    set_aside(p, f"unreadable sensor record ({why})")
    return None


def _write_sensor(state_dir: str, d: Dict[str, Any]) -> None:
    import yaml
    from ..files.atomic import atomic_write_text
    atomic_write_text(os.path.join(state_dir, SENSOR_FILE),
                      "# imucald: the physical sensor the files beside this one belong to\n" +
                      yaml.safe_dump(d, sort_keys=False))


def _move_files(src: str, dst: str, names=(*SENSOR_FILES, SENSOR_FILE)) -> int:
    """Move the named files from src to dst, replacing; the count moved."""
    os.makedirs(dst, exist_ok=True)
    moved = 0
    for name in names:
        a, b = os.path.join(src, name), os.path.join(dst, name)
        if not os.path.exists(a):
            continue
        if os.path.isdir(b):
            shutil.rmtree(b)
        os.replace(a, b)
        moved += 1
    return moved


def _calibration_sensor(path: str) -> Optional[str]:
    """The ``sensor`` id a calibration file names ('' if none, None if unreadable)."""
    from ..files.atomic import read_own_file
    from ..errors import UserError
    from ..files.yamlsafe import load
    try:
        d = load(read_own_file(path, 1 << 20, UserError), path, UserError)
    except UserError:
        return None
    s = d.get("sensor", "") if isinstance(d, dict) else None
    return s if isinstance(s, str) else None


def adopt_sensor(state_dir: str, fp: Dict[str, Any]) -> Dict[str, Any]:
    """Make the state directory hold the running sensor's files (module doc).  Returns
    {"id", "status": first | same | changed | returned, "previous": old id (changed,
    returned), "kept_in": where the old sensor's files went}; logs a swap as a warning."""
    fid = fingerprint_id(fp)
    sensors = os.path.join(state_dir, "sensors")
    cur = _read_sensor(state_dir)
    now = _now()
    out: Dict[str, Any] = {"id": fid}
    if cur is not None and cur["id"] != fid:
        old = cur["id"]
        kept = os.path.join(sensors, old)
        _move_files(state_dir, kept)          # 1: the old sensor's files, sensor.yaml last
        out.update(previous=old, kept_in=kept)
        back = os.path.join(sensors, fid)
        rec = {"id": fid, "fingerprint": fp, "first_seen": now, "last_seen": now}
        if os.path.exists(os.path.join(back, SENSOR_FILE)):
            rec["first_seen"] = (_read_sensor(back) or {}).get("first_seen", now)
        _write_sensor(state_dir, rec)         # 2: the new sensor's record
        restored = _restore(back, state_dir)  # 3: its own files, if it was here before
        out["status"] = "returned" if restored else "changed"
        log.warning("a different sensor than last time (%s, was %s): %s; the calibration of %s "
                    "is kept in %s", fid, old,
                    "its own calibration from before is back" if restored else
                    "it starts uncalibrated", old, kept)
    else:
        out["status"] = "first" if cur is None else "same"
        rec = {"id": fid, "fingerprint": fp, "first_seen": (cur or {}).get("first_seen", now),
               "last_seen": now}
        _write_sensor(state_dir, rec)
        if not os.path.exists(os.path.join(state_dir, "calibration.yaml")):
            _restore(os.path.join(sensors, fid), state_dir)   # a swap interrupted before step 3
    _foreign_calibration(state_dir, fid, sensors)
    return out


def _restore(back: str, state_dir: str) -> int:
    """Bring a sensor's kept files back into the state directory; the count restored."""
    if not os.path.isdir(back):
        return 0
    n = _move_files(back, state_dir, SENSOR_FILES)
    if os.path.exists(os.path.join(back, SENSOR_FILE)):
        os.unlink(os.path.join(back, SENSOR_FILE))
    if not os.listdir(back):
        os.rmdir(back)
    return n


def _foreign_calibration(state_dir: str, fid: str, sensors: str) -> None:
    """A calibration.yaml made on another sensor (copied in by hand, or from before the
    swap bookkeeping) goes to that sensor's directory; it is never applied here."""
    p = os.path.join(state_dir, "calibration.yaml")
    if not os.path.exists(p):
        return
    s = _calibration_sensor(p)
    if s and s != fid:
        dst = os.path.join(sensors, s)
        os.makedirs(dst, exist_ok=True)
        target = os.path.join(dst, "calibration.yaml")
        if os.path.exists(target):
            target = os.path.join(dst, f"calibration.yaml.{datetime.now(timezone.utc):%Y%m%dT%H%M%S}")
        os.replace(p, target)
        log.warning("%s was made on sensor %s, not this one (%s): moved to %s, not applied",
                    p, s, fid, target)
