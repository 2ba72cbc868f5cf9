"""fitting/noise/posecov.py's fast paths give numpy's plain expressions' values bit for bit
(issue 24's fast calibrate: the calibration's pose covariances must not move)."""
import numpy as np

from imucald.fitting.noise.posecov import col_sumsq


def test_col_sumsq_is_the_sum_of_squares_bit_for_bit():
    """Increments of running sums (the structure function's), 1-9 columns, 2-20000 rows.
    Breakage it catches: einsum for one column (numpy's sum adds a contiguous vector
    pairwise, einsum does not: differs in the last bits in most cases), a transposed
    layout (pairwise along the rows)."""
    rng = np.random.default_rng(24)
    for trial in range(400):
        C = int(rng.choice([1, 2, 3, 3, 6, 9]))
        L = int(rng.integers(2, 20000))
        x = rng.normal(size=(L, C)) * 10.0 ** rng.integers(-6, 3)
        c = np.vstack([np.zeros((1, C)), np.cumsum(x, 0)])
        tau = int(rng.integers(1, L))
        d = c[tau:] - c[:-tau]
        assert np.array_equal(col_sumsq(d), (d * d).sum(0)), (C, L, tau)
