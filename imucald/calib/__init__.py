"""Calibration math: pure functions over numpy arrays."""

#: The one set of stillness-detector defaults (meaning: :mod:`imucald.calib.stillness`).
#: Here, numpy-free, so the daemon's config table can read it without importing numpy.
STILLNESS_DEFAULTS = {"window_s": 1.0, "k": 6.0, "min_still_s": 1.0, "max_pose_s": 20.0,
                      "trim_s": 0.25, "max_turn_deg": 0.5}
