"""The library entry points behind ``imucald``'s public names (see ``imucald/__init__``):
find poses in a recording and fit a :class:`~imucald.calibration.Calibration` to them."""
from __future__ import annotations

from typing import Optional

from .calibration import Calibration, SensorCal, build_calibration
from .fitting.stillness.poses import PoseSet, poses_from_recording
from .files.recording import Recording

__all__ = ["find_poses", "fit"]


def find_poses(rec: Recording, **detector_kw) -> PoseSet:
    """The still poses of a recording, each averaged (mean, covariance, count,
    temperature, times); ``detector_kw`` as ``imucald calibrate``'s detector options."""
    return poses_from_recording(rec, **detector_kw)


def fit(poses: PoseSet, model: str = "triangular9", method: str = "ga", seed: Optional[int] = 0,
        board: Optional[str] = None) -> Calibration:
    """Calibrate the accelerometer (and the gyro bias, when the poses have gyro means)
    from still poses; returns a Calibration for ``board`` (default: the recording's)."""
    from .fitting.fit import fit_gyro_bias, fit_norm
    from .specs import BOARDS
    meta = poses.meta if board is None or board == poses.meta.get("board") else {"board": board}
    board = board or poses.meta.get("board", "unknown")
    chip = BOARDS.get(board, (None,))[0]
    f = fit_norm(poses.acc, model, method, pose_cov=poses.acc_cov, rng=seed, chip=chip, temp_c=poses.temp)
    parts = {"accel": SensorCal.from_fit(f, {"fitness": float(f.fitness)})}
    if poses.gyro is not None:
        parts["gyro"] = SensorCal.from_fit(fit_gyro_bias(poses.gyro, poses.n, poses.gyro_cov))
    t = poses.temp
    tr = None
    if t is not None and (t == t).any():
        tr = (round(float(t[t == t].min()), 2), round(float(t[t == t].max()), 2))
    return build_calibration(parts, board=board, meta=meta, temperature_range_c=tr)
