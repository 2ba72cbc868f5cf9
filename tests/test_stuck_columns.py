"""calibrate on a recording with a dead or stuck axis (a column that reads one value in every
sample, or a column mapped to nothing).  Before, `imucald calibrate` fitted it and wrote a
calibration: with ay at 0.0 the accelerometer fit ended with an excess scatter of x1.1e6 and
exit 0; with gz at 0.0 the gyro got bias 0 on z and a matrix "not determined" (mean held-out
gravity-direction error 39 deg), exit 0.  Now the sensor asked for is refused in one line
naming the file, the column and what to check (exit 2, docs/reference/exit-codes.md), and
--sensor all leaves that part out with the same reason and calibrates the others.
The check itself (fitting/inputs.stuck_columns) is gap's too (tests/test_gap.py)."""
import json
import subprocess
import sys

import pytest

from imucald.cli import main


def _with_column_at(src, dst, name, value="0.0"):
    lines = src.read_text().splitlines()
    hi = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    k = lines[hi].split(",").index(name)
    out = lines[:hi + 1]
    for ln in lines[hi + 1:]:
        f = ln.split(",")
        f[k] = value
        out.append(",".join(f))
    dst.write_text("\n".join(out) + "\n")
    return dst


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    d = tmp_path_factory.mktemp("stuck")
    src = d / "s.csv"
    assert main(["simulate", "-o", str(src), "--seed", "3", "--poses", "20"]) == 0
    return d, src


def _run(*argv):
    return subprocess.run([sys.executable, "-m", "imucald.cli", *argv], capture_output=True, text=True)


@pytest.mark.parametrize("column,sensor", [("ay", "accel"), ("gz", "gyro")])
def test_a_dead_axis_is_refused_in_one_line(rec, column, sensor):
    """Seen to fail with the check in cli/offline.py removed: exit 0 and a calibration."""
    d, src = rec
    bad = _with_column_at(src, d / f"dead_{column}.csv", column)
    p = _run("calibrate", str(bad), "--sensor", sensor, "-o", str(d / f"{column}.yaml"))
    assert p.returncode == 2, (p.returncode, p.stderr[-500:])
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr[-800:]
    assert str(bad) in lines[0] and f"{column} (always 0)" in lines[0] and "--columns" in lines[0]
    assert not (d / f"{column}.yaml").exists()


def test_sensor_all_leaves_the_dead_part_out_and_calibrates_the_rest(rec):
    """Seen to fail with the check in cli/calall.py _gyro removed (the gyro part fitted)."""
    d, src = rec
    bad = _with_column_at(src, d / "dead_gz_all.csv", "gz")
    p = _run("calibrate", str(bad), "--sensor", "all", "--json")
    assert p.returncode == 0, p.stderr[-500:]
    out = json.loads(p.stdout)
    assert out["parts"] == ["accel"], out["parts"]
    assert "gz (always 0)" in out["skipped"]["gyro"]


def test_a_moving_column_is_not_stuck(rec):
    """The same recording untouched: every part calibrated (the check does not fire on a
    live axis, whose noise moves it every few samples)."""
    d, src = rec
    p = _run("calibrate", str(src), "--sensor", "all", "--json")
    assert p.returncode == 0, p.stderr[-500:]
    assert json.loads(p.stdout)["parts"] == ["accel", "gyro"]


def test_a_pose_file_with_a_dead_axis_is_refused(rec):
    """A pose file (what the daemon saves) whose gz mean is the same 0.0 in every pose: it was
    calibrated and written (bias_dps z 0.0 +- 0.0, exit 0).  Seen to fail with the pose-file
    branch of the check in cli/offline.py removed.  The same poses untouched calibrate."""
    import numpy as np
    from imucald.fitting.inputs import load_input
    from imucald.fitting.stillness.poses import poses_and_pieces, write_poses
    d, src = rec
    ps, _ = poses_and_pieces(load_input(str(src))[1])
    write_poses(ps, str(d / "p_ok.txt"))
    bad = ps.subset(np.arange(len(ps)))
    bad.gyro = bad.gyro.copy()
    bad.gyro[:, 2] = 0.0
    bad.gyro_cov = bad.gyro_cov.copy()
    bad.gyro_cov[:, 2, :] = bad.gyro_cov[:, :, 2] = 0.0
    write_poses(bad, str(d / "p_gz.txt"))
    p = _run("calibrate", str(d / "p_gz.txt"), "--sensor", "gyro", "-o", str(d / "pg.yaml"))
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr[-800:]
    assert "gz (always 0)" in p.stderr and "every pose" in p.stderr and not (d / "pg.yaml").exists()
    assert _run("calibrate", str(d / "p_ok.txt"), "--sensor", "gyro").returncode == 0


def test_the_daemon_does_not_fit_a_dead_axis(rec, tmp_path):
    """The daemon's calibration job (daemon/fitjob.py) on poses whose gz mean is the same 0.0
    in every pose: it fitted and applied a gyro bias of 0.0 +- 0.0 on z.  Now the gyro is not
    fitted, the outcome line names gz, and the accelerometer is still calibrated.  Seen to
    fail with the stuck check in calibration_job removed (a gyro part saved)."""
    d, src = rec
    bad = _with_column_at(src, d / "dead_gz_daemon.csv", "gz")
    p = _run("replay", str(bad), "--state-dir", str(tmp_path))
    assert p.returncode == 0, p.stderr[-800:]
    assert "gyro not fitted: column gz (always 0) holds one value in every pose" in p.stderr
    import yaml
    saved = yaml.safe_load((tmp_path / "calibration.yaml").read_text())
    assert "accel" in saved and "gyro" not in saved, sorted(saved)


def test_a_dead_accelerometer_axis_leaves_the_gyro_bias_only(rec):
    """With ay at 0.0, `calibrate --sensor gyro` fitted the gyro's matrix and g-sensitivity
    against the broken accelerometer's gravity directions (excess scatter x3e5, 19 deg) and
    never said why.  Now the rotations are not fitted, with the reason, and the bias from the
    still poses stays.  Seen to fail with the check in cli/gyrorot.fit_rotations removed."""
    d, src = rec
    bad = _with_column_at(src, d / "dead_ay_gyro.csv", "ay")
    p = _run("calibrate", str(bad), "--sensor", "gyro")
    assert p.returncode == 0, p.stderr[-800:]
    assert "scale/misalignment: not fitted (the accelerometer's column ay (always 0)" in p.stdout
    assert "bias_dps" in p.stdout
