import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
SHARED = (ROOT / ".." / "shared").resolve()
REAL = SHARED / "data" / "real"


def real_path(*parts):
    """Path into ../shared/data/real, or skip the test saying why."""
    p = REAL.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real recording {p} is absent (../shared is not beside the checkout)")
    return p
