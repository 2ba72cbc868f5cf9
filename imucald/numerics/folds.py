"""The cross-validation scheme over poses, without numpy (the configuration checks use
it at load time, and light commands must not import numpy or imucald.fitting).

Leave-one-pose-out up to LOO_MAX_POSES poses, KFOLDS contiguous folds beyond (the
scheme fitting.fit.heldout_residuals and fitting.gate use)."""
from __future__ import annotations

from typing import List, Optional

__all__ = ["LOO_MAX_POSES", "KFOLDS", "default_folds", "fold_sizes", "poses_needed"]

LOO_MAX_POSES = 60
KFOLDS = 10


def default_folds(n: int) -> int:
    """The number of folds for n poses: n (leave-one-pose-out) up to LOO_MAX_POSES, else KFOLDS."""
    return n if n <= LOO_MAX_POSES else KFOLDS


def fold_sizes(n: int, folds: Optional[int] = None) -> List[int]:
    """Sizes of the held-out groups for n poses (as numpy.array_split splits them)."""
    if folds is None:
        folds = default_folds(n)
    f = max(1, min(folds, n))
    q, r = divmod(n, f)
    return [q + 1] * r + [q] * (f - r)


def poses_needed(n_params: int, folds: Optional[int] = None) -> int:
    """Fewest poses for which the full fit keeps one degree of freedom for the noise
    (n >= k + 1) and every cross-validation refit still has at least k poses."""
    n = n_params + 1
    while min(n - s for s in fold_sizes(n, folds)) < n_params:
        n += 1
    return n
