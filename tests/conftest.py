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


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A simulated 12-pose recording (3 s holds), one per test module."""
    from imucald.cli import main
    rec = tmp_path_factory.mktemp("sim") / "sim.csv"
    assert main(["simulate", "-o", str(rec), "--poses", "12", "--hold", "3", "--move", "1"]) == 0
    return rec
