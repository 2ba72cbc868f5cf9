"""imucald.npstats.median: numpy.median's values without importing numpy.ma."""
import subprocess
import sys

import numpy as np
import pytest

from imucald.npstats import median


@pytest.mark.parametrize("shape", [(1,), (2,), (7,), (8,), (5, 3), (6, 3), (4, 5, 3)])
def test_median_equals_numpy_bit_for_bit(shape):
    rng = np.random.default_rng(len(shape) * 10 + shape[0])
    for axis in [None, *range(len(shape))]:
        a = rng.normal(size=shape)
        for x in (a, np.round(a * 3).astype(int)):
            want, got = np.median(x, axis=axis), median(x, axis=axis)
            assert np.shape(got) == np.shape(want) and np.asarray(got).dtype == np.asarray(want).dtype
            assert np.array_equal(got, want)
        a[(0,) * a.ndim] = np.nan                      # a NaN makes its slices NaN, as numpy's
        assert np.array_equal(median(a, axis=axis), np.median(a, axis=axis), equal_nan=True)


def test_median_does_not_import_numpy_ma():
    code = ("import sys, numpy as np; from imucald.npstats import median; "
            "median(np.arange(6.0).reshape(2, 3), axis=0); print('numpy.ma' in sys.modules)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"
