"""chance_repeats (fitting/stillness/repeats.py) runs its fixed point once per distinct row
of window counts; it must give the direct computation's value bit for bit (every row
iterated, as before issue 24's fast calibrate)."""
import numpy as np

from imucald.fitting.stillness.repeats import chance_repeats, repeat_flags, unconditional_rates
from imucald.numerics.npstats import row_prod


def _direct(full, eq, w):
    """The definition: per-row local rates over a centred window of w rows, solved for the
    unconditional ones on every row (the module's own fixed point: what this test checks is
    that solving it once per distinct row gives the same sum)."""
    m, rest = len(full) - 1, ~full[1:]          # (the caller handles m = 0 and all-repeat rows)
    w = int(min(max(w, 1), m))
    i = np.arange(m)
    hi, lo = np.minimum(m, i + (w - 1) // 2 + 1), np.maximum(0, i - w // 2)
    msum = lambda v: (np.concatenate([[0], np.cumsum(v)])[hi] - np.concatenate([[0], np.cumsum(v)])[lo]).astype(float)
    cnt = msum(rest)
    glob = np.array([np.count_nonzero(eq[1:, j] & rest) for j in range(eq.shape[1])]) / int(rest.sum())
    pc = np.stack([np.where(cnt > 0, msum(eq[1:, j] & rest) / np.maximum(cnt, 1.0), glob[j])
                   for j in range(eq.shape[1])], axis=1)
    return float(np.sum(row_prod(unconditional_rates(pc))))


def test_chance_repeats_equals_the_direct_computation():
    """Quantised still stretches and turns, some held 2-4x, 1/3/9 axes, windows 1-200.
    Breakage it catches: a distinct-row key that merges two count rows (e.g. base w instead
    of w + 1), summing each distinct row's product times its count (another float order:
    differs in the last bits), an off-by-one in the moving sum's window edges."""
    rng = np.random.default_rng(24)
    for trial in range(120):
        m, c = int(rng.integers(2, 3000)), int(rng.choice([1, 3, 3, 9]))
        x, i = np.zeros((m, c)), 0
        while i < m:
            L, still = int(rng.integers(5, 600)), rng.random() < 0.6
            lsb = rng.choice([1.0, 0.5, 0.25])
            seg = rng.normal(size=c) * 50 + (rng.normal(size=(L, c)) * rng.random() * 2 if still
                                              else np.cumsum(rng.normal(size=(L, c)) * 20, 0))
            x[i:i + L] = np.round(seg[:m - i] / lsb) * lsb
            i += L
        if trial % 3 == 0:
            h = int(rng.integers(2, 5))
            x = np.repeat(x[::h], h, axis=0)[:m]
        full, _, eq = repeat_flags(None, x)
        w = int(rng.choice([1, 8, 64, 200]))
        if (~full[1:]).any():
            assert chance_repeats(full, eq, w) == _direct(full, eq, w), (trial, m, c, w)
        else:                   # every row a whole repeat: all of them expected by chance
            assert chance_repeats(full, eq, w) == float(len(full) - 1), (trial, m, c, w)
    assert chance_repeats(np.zeros(1, bool), np.zeros((1, 3), bool)) == 0.0
