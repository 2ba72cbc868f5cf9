"""imucald: field calibration of MEMS inertial sensors on the board itself.

The public API (imported lazily: ``import imucald`` stays light)::

    import imucald
    rec = imucald.read_recording("session.csv")        # samples in g, deg/s, gauss
    poses = imucald.find_poses(rec)                      # still poses, averaged
    cal = imucald.fit(poses)                             # a Calibration
    imucald.save_calibration(cal, "calibration.yaml")
    cal = imucald.load_calibration("calibration.yaml")   # validated; CalibrationError if not
    acc_g = cal.apply_accel(rec.acc)                     # (N, 3) arrays in, corrected out
    with imucald.connect("/run/imucald/imucald.sock") as stream:   # the daemon's stream
        for record in stream: ...
"""
__version__ = "0.1.0"

_API = {
    "Calibration": ("calibration", "Calibration"),
    "SensorCal": ("calibration", "SensorCal"),
    "CalibrationError": ("calibration", "CalibrationError"),
    "load_calibration": ("calibration", "load"),
    "save_calibration": ("calibration", "save"),
    "apply": ("calibration", "apply"),
    "Recording": ("files.recording", "Recording"),
    "read_recording": ("files.recording", "read_recording"),
    "PoseSet": ("fitting.stillness.poses", "PoseSet"),
    "find_poses": ("api", "find_poses"),
    "fit": ("api", "fit"),
    "StreamClient": ("client", "StreamClient"),
    "connect": ("client", "connect"),
    "UserError": ("errors", "UserError"),
}

__all__ = ["__version__", *_API]


def __getattr__(name):
    if name not in _API:
        raise AttributeError(f"module 'imucald' has no attribute {name!r}")
    import importlib
    mod, attr = _API[name]
    value = getattr(importlib.import_module(f"{__name__}.{mod}"), attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
