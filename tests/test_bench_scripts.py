"""The benchmark scripts import cleanly (they are run by hand; their figures go in the
closing notes, and no test asserts a wall time)."""
import importlib.util
import os

import pytest

BENCH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench")
SCRIPTS = sorted(f for f in os.listdir(BENCH) if f.endswith(".py") and not f.startswith("_"))


@pytest.mark.parametrize("name", SCRIPTS)
def test_bench_script_imports(name, monkeypatch):
    monkeypatch.syspath_prepend(BENCH)
    spec = importlib.util.spec_from_file_location(f"bench_{name[:-3]}", os.path.join(BENCH, name))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert callable(getattr(mod, "main"))


def test_budget_runs_quickly_and_scales_by_the_stated_pi_factors():
    """bench/budget.py on a little data (no time asserted): a row per board and rate, CPU %
    = us/sample x rate / 10^4, and the Pi columns that share times the stated 7-Zip ratio
    (this machine's rating given, so 7z is not run)."""
    import re
    import subprocess
    import sys
    p = subprocess.run([sys.executable, os.path.join(BENCH, "budget.py"), "--seconds", "0.5",
                        "--repeats", "1", "--mips", "4000"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    rows = [r.split() for r in p.stdout.splitlines() if re.match(r"^(mpu6050|mpu9250|9dof) ", r)]
    assert [(r[0], int(r[1])) for r in rows] == [("mpu6050", 100), ("mpu6050", 1000), ("mpu9250", 100),
                                                 ("mpu9250", 1000), ("9dof", 100), ("9dof", 400)]
    for r in rows:
        rate, us, here, zero2, pi4 = int(r[1]), *map(float, r[3:7])
        assert us > 0
        # printed rounded: us/sample to 0.1, the percentages to 0.01 and 0.1
        assert here == pytest.approx(us * rate / 1e4, abs=0.0051 + 0.051 * rate / 1e4)
        assert zero2 == pytest.approx(here * 4000 / 838, abs=0.05 + 0.006 * 4000 / 838)
        assert pi4 == pytest.approx(here * 4000 / 1769, abs=0.05 + 0.006 * 4000 / 1769)
