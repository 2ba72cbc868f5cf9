"""The one set of stillness-detector defaults (their meaning: :mod:`imucald.fitting.stillness.detector`).

A numpy-free leaf, so the CLI parser and the daemon's config table read it without
importing numpy or the calibration code (``--help``, ``status`` and ``watch`` stay light)."""

STILLNESS_DEFAULTS = {"window_s": 1.0, "k": 6.0, "min_still_s": 1.0, "max_pose_s": 20.0,
                      "trim_s": 0.25, "max_turn_deg": 3.0}
