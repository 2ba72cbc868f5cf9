"""`imucald calibration merge`: parts fitted separately become the one file the daemon
loads; conflicting identities and a part given twice are refused in one line."""
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from imucald.calibration import load
from imucald.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def parts(tmp_path_factory):
    d = tmp_path_factory.mktemp("merge")
    rec = str(d / "s.csv")
    assert main(["simulate", "-o", rec, "--board", "9dof", "--poses", "16", "--hold", "3", "--seed", "2"]) == 0
    assert main(["calibrate", rec, "--method", "lm", "-o", str(d / "accel.yaml")]) == 0
    assert main(["calibrate", rec, "--sensor", "gyro", "--model", "mean", "-o", str(d / "gyro.yaml")]) == 0
    assert main(["calibrate", rec, "--sensor", "mag", "--method", "lm", "-o", str(d / "mag.yaml")]) == 0
    return d, rec


def test_merge_keeps_every_part_as_fitted_and_replay_applies_all_three(parts, capsys):
    """Breakage it catches: merge dropping or mixing up a part (the applied values would
    differ from the part's own file), or a merged file the daemon's replay cannot load."""
    d, rec = parts
    out = str(d / "calibration.yaml")
    capsys.readouterr()
    assert main(["calibration", "merge", str(d / "accel.yaml"), str(d / "gyro.yaml"), str(d / "mag.yaml"),
                 "-o", out]) == 0
    assert "accel from" in capsys.readouterr().out
    m = load(out)
    raw = np.array([[0.1, -0.2, 0.98], [-0.5, 0.4, 0.7]])
    for part in ("accel", "gyro", "mag"):
        one = load(str(d / f"{part}.yaml")).part(part)
        assert m.part(part) is not None
        kw = {"acc_g": raw} if part == "gyro" and "g_sens_dps_per_g" in one.params else {}
        np.testing.assert_allclose(m.part(part).apply(raw, **kw), one.apply(raw, **kw), rtol=0, atol=0)
    assert m.board == "9dof"
    # the daemon's replay starts from it: the stream's corrected magnetometer has a constant
    # norm (hard and soft iron removed), the raw one does not
    st = d / "state"
    st.mkdir()
    os.replace(out, st / "calibration.yaml")
    p = subprocess.run([sys.executable, "-m", "imucald.cli", "replay", rec, "--state-dir", str(st)],
                       capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=ROOT))
    assert p.returncode == 0, p.stderr
    assert "starting from calibration" in p.stderr
    imu = [json.loads(l) for l in p.stdout.splitlines()[1:400] if '"class":"IMU"' in l]
    imu = [r for r in imu if r["cal"] == m.id]       # before the replay's own first calibration
    assert len(imu) > 100
    from imucald.files.recording import read_recording
    r = read_recording(rec)
    i = np.array([x["seq"] for x in imu])
    want = {"acc_g": m.apply_accel(r.acc[i], r.temp[i]), "mag_gauss": m.apply_mag(r.mag[i], r.temp[i])}
    want["gyro_dps"] = m.apply_gyro(r.gyro[i], r.temp[i], want["acc_g"])
    for key, raw in (("acc_g", r.acc[i]), ("gyro_dps", r.gyro[i]), ("mag_gauss", r.mag[i])):
        got = np.array([x[key] for x in imu])
        np.testing.assert_allclose(got, want[key], rtol=1e-4, atol=1e-5, err_msg=key)   # printed digits
        assert np.abs(got - raw).max() > 1e-3, f"{key}: the stream is the raw reading"


def test_conflicts_and_duplicates_are_refused_in_one_line(parts, tmp_path, capsys):
    """Breakage it catches: a merge that silently takes one of two boards, or one of two
    copies of a part (which one would be an accident); one file named twice said as that
    (broken once: the given-twice check removed, "the accel part is also in" instead: fails)."""
    d, rec = parts
    other = str(tmp_path / "o.csv")
    assert main(["simulate", "-o", other, "--board", "mpu6050", "--poses", "12", "--hold", "3", "--seed", "3"]) == 0
    assert main(["calibrate", other, "--sensor", "gyro", "--model", "mean", "-o", str(tmp_path / "g.yaml")]) == 0
    capsys.readouterr()
    assert main(["calibration", "merge", str(d / "accel.yaml"), str(tmp_path / "g.yaml"),
                 "-o", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "board 'mpu6050' conflicts with" in err and "accel.yaml" in err
    assert main(["calibration", "merge", str(d / "accel.yaml"), str(d / "accel.yaml"),
                 "-o", str(tmp_path / "x.yaml")]) == 2
    # the same name twice is said as that (it read "the accel part is also in accel.yaml")
    assert capsys.readouterr().err.strip() == f"imucald: error: {d / 'accel.yaml'}: given twice: name each file once"
    shutil.copy(d / "accel.yaml", tmp_path / "copy.yaml")
    assert main(["calibration", "merge", str(d / "accel.yaml"), str(tmp_path / "copy.yaml"),
                 "-o", str(tmp_path / "x.yaml")]) == 2
    assert "the accel part is also in" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "x.yaml")
    assert main(["calibration", "merge", str(tmp_path / "missing.yaml"), "-o", str(tmp_path / "x.yaml")]) == 2
    assert "missing.yaml: cannot read" in capsys.readouterr().err


def test_a_chip_or_sensor_conflict_is_refused(parts, tmp_path, capsys):
    from imucald.cli.calfiles import merge_calibrations
    from imucald.errors import UserError
    d, _ = parts
    a, g = load(str(d / "accel.yaml")), load(str(d / "gyro.yaml"))
    with pytest.raises(UserError, match=r"g.yaml: mag chip 'qmc5883l' conflicts with a.yaml's 'hmc5883l'"):
        merge_calibrations([("a.yaml", a), ("g.yaml", g.replace(chips={**g.chips, "mag": "qmc5883l"}))])
    with pytest.raises(UserError, match=r"g.yaml: sensor bbb conflicts with a.yaml's sensor aaa"):
        merge_calibrations([("a.yaml", a.replace(sensor="aaa")), ("g.yaml", g.replace(sensor="bbb"))])
    m, where = merge_calibrations([("a.yaml", a.replace(id=3)), ("g.yaml", g.replace(id=5, sensor="ccc"))])
    assert (m.id, m.sensor, where) == (5, "ccc", {"accel": "a.yaml", "gyro": "g.yaml"})
