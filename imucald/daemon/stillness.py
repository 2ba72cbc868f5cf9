"""The daemon's stillness detector is the one in :mod:`imucald.calib.stillness`
(also run, over a whole file, by ``calibrate``, ``replay`` and ``gap``)."""
from ..calib.stillness import DEFAULTS, StaticInterval, StillnessDetector

__all__ = ["StaticInterval", "StillnessDetector", "DEFAULTS"]
