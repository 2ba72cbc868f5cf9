"""The NDJSON stream is strict JSON: no NaN, Infinity or null, and a value that is not
known (temperature, gyro of an accelerometer-only recording) is omitted, gpsd-style."""
import json
import subprocess
import sys

import numpy as np

from imucald.cli import main
from imucald.daemon.accumulator import PoseAccumulator
from imucald.daemon.outputs import encode_samples
from imucald.fitting.stillness.detector import StaticInterval
from imucald.files.recording import Recording, read_recording, write_recording


def strict(line):
    def bad(c):
        raise ValueError(f"{c} in {line!r}")
    o = json.loads(line, parse_constant=bad)
    stack = [o]
    while stack:                    # no null anywhere either
        x = stack.pop()
        assert x is not None, line
        stack.extend(x.values() if isinstance(x, dict) else x if isinstance(x, list) else [])
    return o


def _replay(path, *args):
    p = subprocess.run([sys.executable, "-m", "imucald.cli", "replay", str(path), *args],
                       capture_output=True)
    assert p.returncode == 0, p.stderr.decode()
    return p.stdout.decode().splitlines()


def test_accelerometer_only_recording_without_temperature_streams_strict_json(tmp_path):
    full = tmp_path / "full.csv"
    assert main(["simulate", "-o", str(full), "--board", "mpu6050", "--poses", "16", "--hold", "4",
                 "--move", "2", "--rate", "50", "--seed", "3"]) == 0
    rec = read_recording(full)
    acc_only = tmp_path / "acc.csv"
    write_recording(Recording(rec.t, rec.acc, meta=dict(rec.meta)), acc_only)
    lines = _replay(acc_only, "--min-poses", "12")
    objs = [strict(l) for l in lines]
    imu = [o for o in objs if o["class"] == "IMU"]
    assert len(imu) == len(rec)
    assert all("temp_c" not in o and "gyro_dps" not in o and len(o["acc_g"]) == 3 for o in imu)
    assert any(o["class"] == "CAL" and o["applied"] for o in objs)       # it calibrated too
    # the full recording: the same fields present, and still strict
    objs = [strict(l) for l in _replay(full, "--min-poses", "12")]
    assert all("temp_c" in o and "gyro_dps" in o for o in objs if o["class"] == "IMU")


def test_encoder_omits_unknown_and_non_finite_values():
    n = 4
    acc = np.ones((n, 3))
    acc[1, 2] = np.inf
    temp = np.array([20.0, np.nan, 21.0, np.nan])
    mag = np.full((n, 3), 0.3)
    mag[2] = np.nan
    out = encode_samples("ndjson", np.arange(n), np.arange(n) * 0.01, acc, None, temp, mag,
                         np.zeros(n, bool), 0).decode().splitlines()
    objs = [strict(l) for l in out]
    assert ["acc_g" in o for o in objs] == [True, False, True, True]
    assert ["temp_c" in o for o in objs] == [True, False, True, False]
    assert ["mag_gauss" in o for o in objs] == [True, True, False, True]
    assert not any("gyro_dps" in o for o in objs)
    csv = encode_samples("csv", np.arange(n), np.arange(n) * 0.01, acc, None, temp, mag,
                         np.zeros(n, bool), 0).decode().splitlines()
    assert all("nan" not in l and "inf" not in l for l in csv)


def _iv(acc, temp, n=100):
    sc = np.eye(3) * 1e-6
    return StaticInterval(np.asarray(acc, float), sc / n, sc, n, 0.0, 1.0, temp)


def test_merging_poses_keeps_an_unknown_temperature_unknown():
    for ta, tb, want in ((np.nan, np.nan, np.nan), (25.0, np.nan, 25.0), (np.nan, 25.0, 25.0),
                         (20.0, 30.0, 25.0)):
        a = PoseAccumulator()
        assert a.add(_iv([0, 0, 1], ta)) == "new"
        assert a.add(_iv([0, 0, 1.00001], tb)) == "refined"
        got = a.poses[0].temp
        assert (np.isnan(got) and np.isnan(want)) or abs(got - want) < 1e-9, (ta, tb, got)


def test_real_accelerometer_only_recording_streams_strict_json(tmp_path):
    """The Xsens MTi log: accelerometer only, no temperature; replayed as a user would."""
    from imucald.fitting.inputs import read_table
    from imucald.calibration import load
    from .conftest import real_path
    rec = read_table(str(real_path("imutk_xsens_mti", "xsens_acc.mat")), ["t", "ax", "ay", "az"],
                     415 * 9.80665, 32768.0)
    write_recording(rec, tmp_path / "xsens.csv")
    lines = _replay(tmp_path / "xsens.csv", "--state-dir", str(tmp_path / "st"), "--min-poses", "10")
    objs = [strict(l) for l in lines]
    assert sum(o["class"] == "IMU" for o in objs) == len(rec)
    assert not any("temp_c" in o or "gyro_dps" in o for o in objs)
    cal = load(tmp_path / "st" / "calibration.yaml")          # what replay saved reads back
    assert cal.temperature_range_c is None and cal.accel is not None
