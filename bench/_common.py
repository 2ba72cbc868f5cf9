"""Shared set-up for the benchmark scripts (run them from the repository root)."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from imucald.specs import ACCEL  # noqa: E402
from imucald.sim.sensor import pose_sigma  # noqa: E402

#: Paper 000 does not state its simulation noise.  We use the MPU-6050 datasheet
#: density (400 ug/rtHz) at the paper's real-experiment settings, 50 Hz for 20 s
#: per pose, samples independent over the 25 Hz Nyquist band: sigma_sample = 2.0 mg,
#: sigma_pose = 63 ug.  Paper 000's reported error STDs (2e-5 g bias, 2.5e-5 scale)
#: are of this order, which supports the choice.
SIGMA_POSE_G = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 50.0, 20.0)[1]


def median_time(fn, repeats):
    import time
    ts = []
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), out
