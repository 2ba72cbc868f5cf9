"""Distribution tails without scipy: chi-square and normal survival functions.

The chi-square survival function is the regularised upper incomplete gamma
function Q(k/2, x/2), evaluated by its power series for x < a + 1 and by its
continued fraction (modified Lentz) otherwise; both are textbook definitions
(Abramowitz & Stegun 6.5.29 and 6.5.31).  Tests check them against scipy.
"""
from __future__ import annotations

import math

__all__ = ["chi2_sf", "chi2_logsf", "norm_sf2"]


def _log_gamma_q(a: float, x: float) -> float:
    """log Q(a, x), stable far into the tail."""
    if x <= 0:
        return 0.0
    lg = math.lgamma(a)
    if x < a + 1.0:
        # P by the series, Q = 1 - P
        term = 1.0 / a
        s = term
        n = a
        for _ in range(10000):
            n += 1.0
            term *= x / n
            s += term
            if abs(term) < abs(s) * 1e-16:
                break
        logp = math.log(s) - x + a * math.log(x) - lg
        p = math.exp(logp)
        return math.log1p(-p) if p < 1 else -745.0
    # continued fraction for Q
    tiny = 1e-300
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, 10000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return math.log(h) - x + a * math.log(x) - lg


def chi2_logsf(x: float, k: float) -> float:
    """log of P(chi2_k >= x)."""
    if k <= 0:
        raise ValueError("degrees of freedom must be positive")
    return _log_gamma_q(k / 2.0, max(x, 0.0) / 2.0)


def chi2_sf(x: float, k: float) -> float:
    """P(chi2_k >= x) (0.0 when it underflows; use chi2_logsf there)."""
    return math.exp(chi2_logsf(x, k))


def norm_sf2(z: float) -> float:
    """Two-sided normal tail P(|Z| >= |z|)."""
    return math.erfc(abs(z) / math.sqrt(2.0))
