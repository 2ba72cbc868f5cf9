"""Persistence: the calibration (YAML) and the poses, in the state directory.

Both are written atomically (temp file, fsync, rename, fsync of the directory),
so a power cut or kill -9 at any moment leaves the previous file intact.  A
corrupt file is set aside as ``NAME.corrupt-<time>`` with one log line; the
daemon carries on without it.
"""
from __future__ import annotations

import logging
import os
import time
from typing import Any, Dict, Optional

import numpy as np
import yaml

from ..atomic import atomic_write_text
from ..calib.poses import PoseSet, read_poses, write_poses
from ..errors import UserError

__all__ = ["FORMAT_VERSION", "save_calibration", "load_calibration", "save_poses", "load_poses",
           "set_aside"]

FORMAT_VERSION = 1
log = logging.getLogger("imucald")


def _plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def set_aside(path: str, why: str) -> str:
    dst = f"{path}.corrupt-{time.strftime('%Y%m%dT%H%M%S')}"
    os.replace(path, dst)
    log.warning("%s: %s; set aside as %s, continuing without it", path, why, dst)
    return dst


def save_calibration(state_dir: str, doc: Dict[str, Any], history: int = 10) -> str:
    doc = dict(doc)
    doc["format_version"] = FORMAT_VERSION
    text = "# imucald calibration (see README: calibration file)\n" + yaml.safe_dump(
        _plain(doc), sort_keys=False, default_flow_style=None, width=100)
    path = os.path.join(state_dir, "calibration.yaml")
    atomic_write_text(path, text)
    if history:
        hd = os.path.join(state_dir, "history")
        os.makedirs(hd, exist_ok=True)
        atomic_write_text(os.path.join(hd, f"calibration-{int(doc.get('id', 0)):06d}.yaml"), text)
        old = sorted(f for f in os.listdir(hd) if f.startswith("calibration-"))
        for f in old[:-history]:
            os.unlink(os.path.join(hd, f))
    return path


def load_calibration(state_dir: str) -> Optional[Dict[str, Any]]:
    path = os.path.join(state_dir, "calibration.yaml")
    if not os.path.exists(path):
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            doc = yaml.safe_load(fh)
        if not isinstance(doc, dict) or doc.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"not a format_version {FORMAT_VERSION} calibration")
        acc = doc.get("accel")
        if acc is not None and len(acc.get("theta", [])) != 9:
            raise ValueError("accel.theta must have 9 numbers")
        return doc
    except (OSError, yaml.YAMLError, ValueError, AttributeError, TypeError) as e:
        set_aside(path, f"unreadable calibration ({str(e).splitlines()[0]})")
        return None


def save_poses(state_dir: str, ps: PoseSet) -> None:
    write_poses(ps, os.path.join(state_dir, "poses.csv"))


def load_poses(state_dir: str) -> Optional[PoseSet]:
    path = os.path.join(state_dir, "poses.csv")
    if not os.path.exists(path):
        return None
    try:
        ps = read_poses(path)
        if ps.acc_sample_cov is None:
            raise UserError("no within-pose deviations")
        return ps
    except (UserError, ValueError, IndexError) as e:
        set_aside(path, f"unreadable poses ({e})")
        return None
