"""The daemon's stillness detector is the one in :mod:`imucald.calib.stillness`
(also run, over a whole file, by ``calibrate``, ``replay`` and ``gap``).

A re-export kept only for daemon/pipeline.py; import from :mod:`imucald.calib.stillness`
(this module goes once pipeline.py does, issue 24)."""
from ..calib.stillness import DEFAULTS, StaticInterval, StillnessDetector

__all__ = ["StaticInterval", "StillnessDetector", "DEFAULTS"]
