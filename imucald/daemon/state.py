"""Persistence: the calibration (YAML) and the poses, in the state directory.

Both are written atomically (temp file, fsync, rename, fsync of the directory),
so a power cut or kill -9 at any moment leaves the previous file intact.  A
corrupt file is set aside as ``NAME.corrupt-<time>`` with one log line; the
daemon carries on without it.
"""
from __future__ import annotations

import logging
import os
import shutil
import time
from dataclasses import replace
from typing import Dict, Optional

import numpy as np

from ..fitting.stillness.poses import NoPoses, PoseSet, read_poses, write_poses
from ..files.atomic import read_own_file
from ..calibration import MAX_CALIBRATION_BYTES, Calibration, CalibrationError, load, save
from ..errors import UserError
from ..files.recording import MAX_SMALL_BYTES

__all__ = ["save_calibration", "load_calibration", "save_poses", "load_poses",
           "remove_stale_temporaries", "set_aside"]

log = logging.getLogger("imucald")


def set_aside(path: str, why: str) -> str:
    dst = _corrupt_name(path)
    os.replace(path, dst)
    log.warning("%s: %s; set aside as %s, continuing without it", path, why, dst)
    return dst


#: the files the daemon writes atomically in its state directory (files/atomic.py: a temporary
#: ".<name>.XXXX.tmp" beside each, renamed into place)
STATE_FILES = ("calibration.yaml", "poses.csv", "thermal.csv", "sensor.yaml")
#: a temporary older than this is a killed writer's, s
STALE_TEMPORARY_S = 60.0


def remove_stale_temporaries(state_dir: str) -> int:
    """The temporaries a killed daemon left beside its state files (SIGKILL between write and
    rename: a cold review found them never cleaned), removed when STALE_TEMPORARY_S old;
    called under the directory's lock.  Returns how many."""
    n = 0
    try:
        names = os.listdir(state_dir)
    except OSError:
        return 0
    now = time.time()
    for f in names:
        if f.endswith(".tmp") and any(f.startswith(f".{s}.") for s in STATE_FILES):
            p = os.path.join(state_dir, f)
            try:
                # a minute old at least: `imucald replay --state-dir` writes there without
                # the lock, for milliseconds (a cold review)
                if now - os.stat(p).st_mtime > STALE_TEMPORARY_S:
                    os.unlink(p)
                    n += 1
            except OSError:
                pass
    return n


def save_calibration(state_dir: str, cal: Calibration, history: int = 10) -> str:
    """calibration.yaml (and history/calibration-<id>-<created, UTC>.yaml, the last
    ``history`` kept: a dated record of the sensor's calibrations)."""
    path = os.path.join(state_dir, "calibration.yaml")
    save(cal, path)
    if history:
        try:
            _keep_history(os.path.join(state_dir, "history"), cal, history)
        except OSError as e:
            # calibration.yaml is saved: the history alone is lost (a cold review: a file named
            # "history" there made every save "fail" with "File exists", forever, no path named)
            log.warning("%s: cannot keep the calibration history there: %s (move it away); "
                        "calibration.yaml is saved", os.path.join(state_dir, "history"),
                        e.strerror or e)
    return path


def _keep_history(hd: str, cal: Calibration, history: int) -> None:
    """history/calibration-<id>-<created, UTC>.yaml, the last ``history`` kept."""
    os.makedirs(hd, exist_ok=True)
    stamp = "".join(ch for ch in cal.created[:19] if ch.isdigit() or ch == "T")
    me = f"calibration-{int(cal.id):06d}"
    for f in os.listdir(hd):          # the same id saved again (e.g. at shutdown)
        if f.startswith(me + "-") or f == me + ".yaml":
            os.unlink(os.path.join(hd, f))
    save(cal, os.path.join(hd, f"{me}{'-' + stamp if stamp else ''}.yaml"))
    # oldest first by when each was saved: the names' ids sort wrongly from 7 digits on and
    # after the id wraps (next_id), where the newest was pruned at once (a cold review)
    old = sorted((f for f in os.listdir(hd) if f.startswith("calibration-")),
                 key=lambda f: (os.stat(os.path.join(hd, f)).st_mtime_ns, f))
    for f in old[:-history]:
        os.unlink(os.path.join(hd, f))


def load_calibration(state_dir: str, board: Optional[str] = None,
                     chips: Optional[Dict[str, str]] = None, sensor: str = "") -> Optional[Calibration]:
    """The saved calibration, or None.  A file that fails validation, or that was made
    for another board or chip (when ``board`` is given), is set aside with the reason."""
    path = os.path.join(state_dir, "calibration.yaml")
    if not os.path.lexists(path):
        return None
    try:
        cal = load(path, read_own_file(path, MAX_CALIBRATION_BYTES, CalibrationError))
    except CalibrationError as e:
        set_aside(path, f"unreadable calibration ({str(e).splitlines()[0]})")
        return None
    why = cal.mismatch(board, chips, sensor) if board is not None else None
    if why:
        set_aside(path, f"calibration of another sensor ({why})")
        return None
    return cal


#: the median |a| of saved poses must lie here, g: raw (uncalibrated) poses of the supported
#: chips read 1 g within their scale and bias tolerances (+-10 % and 250 mg at worst, the
#: ADXL345's: imucald/specs.py); m/s^2 reads 9.8, counts hundreds or more
SAVED_POSE_MEDIAN_G = (0.5, 2.0)


def save_poses(state_dir: str, ps: PoseSet, name: str = "poses.csv", board: str = "") -> None:
    """Write the poses; ``board``, when given, goes in the header (load_poses checks it)."""
    if board:
        ps = replace(ps, meta={**ps.meta, "board": board, "units": "g"})
    write_poses(ps, os.path.join(state_dir, name))


def _foreign(ps: PoseSet, board: Optional[str], what: str = "poses") -> Optional[str]:
    """Why saved poses are not this daemon's to resume, or None: another board's header
    (files written before the header carried the board have none, and are taken), or a
    median |a| beyond :data:`SAVED_POSE_MEDIAN_G` (another tool's poses in m/s^2 or counts).
    ``what``: what the file holds, for the message (poses; the thermal log's still intervals)."""
    meta = {k.strip().lower(): str(v).strip() for k, v in ps.meta.items()}   # '# Board: X' too
    saved = meta.get("board")
    if board is not None and saved is not None and saved.lower() != board.lower():
        return f"{what} of board {saved!r}, this daemon runs {board!r}"
    if meta.get("units", "g").lower() != "g":
        return f"{what} in {meta['units']!r}: {what} are saved in g"
    if len(ps):
        m = float(np.median(np.linalg.norm(ps.acc, axis=1)))
        lo, hi = SAVED_POSE_MEDIAN_G
        if not lo <= m <= hi:
            return (f"median |a| of the {what} is {m:.4g}, not about 1 g "
                    f"({'m/s^2' if 5 <= m <= 15 else 'counts or another unit'}?): {what} are saved in g")
    return None


def _drop_foreign_rows(path: str, ps: PoseSet, what: str) -> PoseSet:
    """``ps`` without the rows whose |a| is outside :data:`SAVED_POSE_MEDIAN_G` (a pose in
    m/s^2 or counts among good ones: the median check passes it, and it blocked the fit, then
    was blamed on motion; a helper's black-box run).  The file as it was is kept beside it
    (nothing lost) and the kept rows written in its place; one warning names the rows (their
    order among the file's data rows).  A full or failing disk leaves the file as it is and
    the good rows resumed from memory (a cold review: the daemon exited 74 at start)."""
    a = np.linalg.norm(ps.acc, axis=1)
    lo, hi = SAVED_POSE_MEDIAN_G
    bad = ~((a >= lo) & (a <= hi))
    if not bad.any():
        return ps
    rows = ", ".join(f"{i + 1} (|a| {a[i]:.4g})" for i in np.flatnonzero(bad)[:5])
    more = f" and {int(bad.sum()) - 5} more" if bad.sum() > 5 else ""
    left = "the others resumed" if not bad.all() else "none left to resume"
    keep = _corrupt_name(path)
    kept = ps.subset(np.flatnonzero(~bad))
    try:
        shutil.copy2(path, keep)
        write_poses(kept, path)             # atomic: a restart before the next save finds it clean
        done = f"the file as it was is kept as {keep}, {os.path.basename(path)} rewritten without them"
    except OSError as e:
        done = f"the file is left as it was ({e.strerror or e}: not copied or rewritten)"
    log.warning("%s: %s (data rows) %s%s not about 1 g (another unit?): left out, %s; %s",
                path, what, rows, more, left, done)
    return kept


def _corrupt_name(path: str) -> str:
    """Where a file set aside goes: ``PATH.corrupt-DATE``, or ``.2``, ``.3``... after it when
    taken (two set-asides in one second)."""
    name = f"{path}.corrupt-{time.strftime('%Y%m%dT%H%M%S')}"
    k, out = 1, name
    while os.path.lexists(out):
        k += 1
        out = f"{name}.{k}"
    return out


def load_poses(state_dir: str, name: str = "poses.csv", board: Optional[str] = None) -> Optional[PoseSet]:
    """The saved poses (``name``: poses.csv, or thermal.csv: the thermal log), or None; an
    unreadable file, or one that is not this daemon's (:func:`_foreign`; ``board``: the
    running board's name, None to skip that check), is set aside."""
    path = os.path.join(state_dir, name)
    what = "still intervals" if name == "thermal.csv" else "poses"
    if not os.path.lexists(path):
        return None
    try:
        read_own_file(path, MAX_SMALL_BYTES, UserError)     # a link, not ours: set aside unread
        ps = read_poses(path)
        if ps.acc_sample_cov is None:
            raise UserError("no within-pose deviations")
        for name in ("acc", "acc_sample_cov", "n", "t0", "t1", "gyro", "mag"):
            v = getattr(ps, name)               # temp may be NaN: unknown
            if v is not None and not np.all(np.isfinite(v)):
                bad = int(np.flatnonzero(~np.isfinite(v.reshape(len(ps), -1)).all(1))[0])
                raise UserError(f"pose {bad + 1}: {name} is not finite")
        why = _foreign(ps, board, what)
        if why:
            set_aside(path, why)
            return None
        return _drop_foreign_rows(path, ps, what)
    except NoPoses:     # saved before the first pose or after a reset: nothing to restore
        return None
    except (UserError, ValueError, IndexError) as e:
        set_aside(path, f"unreadable {what} ({e})")
        return None
