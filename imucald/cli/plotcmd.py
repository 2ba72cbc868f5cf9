"""The pictures of ``status --plot FILE`` and ``calibrate --plot DIR`` (the plots extra):
gathers the data, imucald.plots draws."""
from __future__ import annotations

import os

import numpy as np

__all__ = ["status_plot", "calibrate_plots"]


def status_plot(path: str, status: dict, poses: dict) -> str:
    """The running daemon's pose-coverage sphere: its pose means (control ``poses``) and
    the orientation its log asks for next (``status``)."""
    from ..plots.coverage import write_coverage
    acc = np.array([p["acc_g"] for p in poses.get("poses", [])], float).reshape(-1, 3)
    return write_coverage(path, acc, title=f"imucald status ({status.get('board', '?')})",
                          next_orientation=status.get("next_orientation"))


def calibrate_plots(outdir: str, poses, part, name: str = "") -> list:
    """``coverage.png`` (the still poses found) and ``residuals.png`` (|a| - 1 g per pose,
    raw and corrected by ``part``, the accelerometer calibration just fitted) in ``outdir``."""
    from ..fitting.judging.coverage import cube_coverage, next_orientation
    from ..errors import CannotCreate
    from ..plots.coverage import write_coverage
    from ..plots.residuals import write_residuals
    try:
        os.makedirs(outdir, exist_ok=True)
    except OSError as e:
        raise CannotCreate(f"--plot {outdir}: cannot create the directory: {e.strerror}") from None
    acc = np.asarray(poses.acc, float)
    miss = cube_coverage(acc / np.linalg.norm(acc, axis=1, keepdims=True))["missing"]
    out = [write_coverage(os.path.join(outdir, "coverage.png"), acc, title=name or "calibrate",
                          next_orientation=next_orientation(miss, {}))]
    temp = getattr(poses, "temp", None)
    if part.thermal is None or temp is None or not np.all(np.isfinite(temp)):
        temp = None
    after = part.apply(acc, temp) if temp is not None or part.thermal is None else None
    if after is not None:
        out.append(write_residuals(os.path.join(outdir, "residuals.png"),
                                   np.linalg.norm(acc, axis=1) - 1, np.linalg.norm(after, axis=1) - 1,
                                   title=(name + ": " if name else "") + f"{part.model} ({part.method})"))
    return out
