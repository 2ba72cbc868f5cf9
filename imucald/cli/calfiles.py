"""``imucald calibration merge A.yaml B.yaml ... -o calibration.yaml``: one calibration file
from parts fitted separately (``calibrate -o`` writes the part it fitted: accelerometer,
gyro, or magnetometer, each with its thermal terms).

Each input is read with the validated loader (imucald/calibration.py), so a bad file is
refused with the key at fault.  The inputs must describe one sensor: the same board, the
same chip in each role both name, the same sensor fingerprint where both carry one.  Each
part (accel, gyro, mag) is taken from the one file that holds it; a part in two files is
refused (which to keep is the user's call: drop one file).  The result gets the highest
id of the inputs (the daemon's stream shows it as ``cal``), the time of the merge, the
union of the temperature ranges, and the accelerometer file's pose table and
provisional flag.  Written atomically.
"""
from __future__ import annotations

from datetime import datetime, timezone
from typing import List, Tuple

from ..errors import CannotCreate, UserError

__all__ = ["merge_calibrations", "cmd_merge"]

_PARTS = ("accel", "gyro", "mag")


def merge_calibrations(named: List[Tuple[str, object]], created: str = ""):
    """One Calibration from ``named`` = [(file name, Calibration), ...] (pure: no I/O).
    UserError (one line, naming both files) on conflicting identity or a part given twice."""
    from ..calibration import Calibration
    if not named:
        raise UserError("calibration merge: no input files")
    import os
    names = [os.path.normpath(n) for n, _ in named]     # ./a.yaml is a.yaml
    twice = next((named[i][0] for i, n in enumerate(names) if n in names[:i]), None)
    if twice is not None:
        raise UserError(f"{twice}: given twice: name each file once")
    first_name, first = named[0]
    board, chips, sensor = first.board, dict(first.chips), first.sensor
    src_board = {k: first_name for k in chips}
    src_sensor = first_name if sensor else ""
    parts, where = {}, {}
    for name, cal in named:
        if cal.board != board:
            raise UserError(f"{name}: board {cal.board!r} conflicts with {first_name}'s {board!r}: "
                            "merge only files made for one board")
        for role, chip in cal.chips.items():
            if role in chips and chips[role] != chip:
                raise UserError(f"{name}: {role} chip {chip!r} conflicts with {src_board[role]}'s "
                                f"{chips[role]!r}: merge only files of one sensor")
            chips.setdefault(role, chip)
            src_board.setdefault(role, name)
        if cal.sensor:
            if sensor and cal.sensor != sensor:
                raise UserError(f"{name}: sensor {cal.sensor} conflicts with {src_sensor}'s sensor "
                                f"{sensor}: these were made on different physical sensors")
            sensor, src_sensor = cal.sensor, src_sensor or name
        for p in _PARTS:
            part = cal.part(p)
            if part is None:
                continue
            if p in parts:
                raise UserError(f"{name}: the {p} part is also in {where[p]}: keep one of them "
                                "(merge takes each part from one file)")
            parts[p], where[p] = part, name
    if not parts:
        raise UserError(", ".join(n for n, _ in named) + ": no calibrated part (accel, gyro, mag) to merge")
    ranges = [c.temperature_range_c for _, c in named if c.temperature_range_c is not None]
    tr = (min(r[0] for r in ranges), max(r[1] for r in ranges)) if ranges else None
    acc_src = next((c for n, c in named if n == where.get("accel")), None)
    merged = Calibration(board, chips, id=max(int(c.id) for _, c in named), created=created,
                         temperature_range_c=tr, poses_used=acc_src.poses_used if acc_src else None,
                         provisional=acc_src.provisional if acc_src else None, sensor=sensor, **parts)
    return merged, where


def cmd_merge(args) -> int:
    from ..calibration import load, save
    named = [(path, load(path)) for path in args.files]
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    cal, where = merge_calibrations(named, now)
    try:
        save(cal, args.output)
    except OSError as e:
        raise CannotCreate(f"-o {args.output}: cannot write: {e.strerror}") from None
    print(f"wrote {args.output}: board {cal.board}, id {cal.id}; "
          + ", ".join(f"{p} from {where[p]}" for p in _PARTS if p in where))
    return 0
