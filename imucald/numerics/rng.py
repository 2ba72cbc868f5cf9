"""Random-number coercion: the one place that turns a seed into a generator.

Every random process in imucald takes ``rng``: an ``int`` seed, ``None`` (fresh entropy)
or a :class:`numpy.random.Generator` (used as is, so that a caller can thread one stream
through several processes).  This module is a leaf: it imports numpy only.
"""
from __future__ import annotations

from typing import Union

import numpy as np

__all__ = ["RngLike", "as_rng"]

#: the Generator named as a string: evaluating np.random here would import numpy.random
#: (~7 MB resident with the hashlib it pulls in) into every process that only names the type,
#: the daemon among them (its random numbers are all drawn in the calibration worker)
RngLike = Union[int, None, "np.random.Generator"]


def as_rng(rng: RngLike) -> np.random.Generator:
    """``rng`` as a Generator: passed through when it is one, else seeded from it."""
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
