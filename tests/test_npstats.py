"""imucald.numerics.npstats.median: numpy.median's values without importing numpy.ma."""
import subprocess
import sys

import numpy as np
import pytest

from imucald.numerics.npstats import median


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
    code = ("import sys, numpy as np; from imucald.numerics.npstats import median; "
            "median(np.arange(6.0).reshape(2, 3), axis=0); print('numpy.ma' in sys.modules)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"


@pytest.mark.parametrize("k", [1, 2, 3, 6, 7, 8, 11])
def test_row_reductions_equal_numpy_bit_for_bit(k):
    """row_sum/row_all/row_max give numpy's x.sum(1)/all(1)/max(1) exactly (the stillness
    detector's poses depend on them bit for bit).  Breakage it catches: summing the columns
    in another order (e.g. x[:, 0] + (x[:, 1] + x[:, 2])) differs in the last bit on about
    a third of the rows; dropping the >= 8 fallback fails k = 8 and 11 (numpy sums those
    pairwise); a max that drops NaN (fmax) fails the NaN row."""
    from imucald.numerics.npstats import row_all, row_max, row_sum
    rng = np.random.default_rng(k)
    x = rng.normal(size=(5000, k)) * rng.lognormal(0, 3, size=(5000, k))
    assert np.array_equal(row_sum(x), x.sum(1))
    x[7, k - 1] = np.nan
    assert np.array_equal(row_max(x), x.max(1), equal_nan=True)
    b = rng.random((5000, k)) < 0.8
    assert np.array_equal(row_all(b), b.all(1))
    assert row_sum(x[:0]).shape == (0,) and row_all(b[:0]).shape == (0,)


def test_nanmedian_equals_numpy_bit_for_bit():
    """nanmedian gives numpy.nanmedian's values, dtype and all-NaN warning (calibrate pools
    the pose variances with it).  Breakage it catches: keeping the NaNs in the slice (the
    median of a slice with a NaN is NaN), averaging the two middle values as a/2 + b/2
    (differs in the last bit), returning float64 for float32 input."""
    import warnings
    from imucald.numerics.npstats import nanmedian
    rng = np.random.default_rng(3)
    for trial in range(300):
        n = int(rng.integers(1, 700 if trial % 20 == 0 else 40))
        a = rng.normal(size=(n, 3)) * rng.lognormal(0, 3, size=3)
        a[rng.random(a.shape) < rng.random() * 0.8] = np.nan
        if trial % 7 == 0:
            a[:, 1] = np.nan
        if trial % 5 == 0:
            a = a.astype(np.float32)
        for axis in (0, 1):
            with warnings.catch_warnings(record=True) as w_want:
                warnings.simplefilter("always")
                want = np.nanmedian(a, axis=axis)
            with warnings.catch_warnings(record=True) as w_got:
                warnings.simplefilter("always")
                got = nanmedian(a, axis=axis)
            assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=True)
            assert len(w_got) == len(w_want)
    code = ("import sys, numpy as np; from imucald.numerics.npstats import nanmedian; "
            "nanmedian(np.array([[1.0, np.nan], [2.0, 3.0]])); print('numpy.ma' in sys.modules)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"


@pytest.mark.parametrize("C", [1, 3, 6])
def test_window_var_equals_numpy_bit_for_bit(C):
    """window_var(b) is numpy's b.var(1, ddof=1) exactly (the stillness detector's noise floor
    depends on it bit for bit), on C-order windows, on the strided first-3-columns view
    the detector passes with a gyro, on one column and on column-major windows (numpy's own
    var there: it sums those pairwise), offsets large against the scatter (where the order of
    the sums shows), a NaN and an inf.  Breakage it catches (measured on windows like these): a
    copy laid out (m, C, w), whose sums run along the innermost axis, which numpy adds
    pairwise (459 of 654 values differ at C = 3); the copy's path taken for one column, where
    numpy's own sum is the pairwise one (150 of 218); centring the caller's windows in place
    (a single window's transpose is C-contiguous already: no copy without order="C")."""
    from imucald.numerics.npstats import window_var
    rng = np.random.default_rng(C)
    for m, w in [(1, 3), (2, 8), (7, 100), (163, 100), (40, 9), (5, 400)]:
        x = rng.normal(size=(m * w, 2 * C)) * 10.0 ** rng.uniform(-6, 1, 2 * C) + 10.0 ** rng.uniform(-1, 4, 2 * C)
        b = x.reshape(m, w, 2 * C)
        for v in (b[:, :, :C], np.ascontiguousarray(b[:, :, :C])):
            want, keep = v.var(1, ddof=1), v.copy()
            assert np.array_equal(window_var(v), want)
            assert np.array_equal(v, keep)          # the windows themselves left as they were
        f = np.asfortranarray(x[:, :C]).reshape(m, w, C)   # column-major: numpy sums it pairwise
        assert np.array_equal(window_var(f), f.var(1, ddof=1))
    b = rng.normal(size=(4, 10, C))
    b[1, 3, 0], b[2, 5, C - 1] = np.nan, np.inf
    with np.errstate(invalid="ignore"):
        assert np.array_equal(window_var(b), b.var(1, ddof=1), equal_nan=True)
