"""Replay: golden-file comparison of the stream, and the calibration it reaches."""
import json
import os
import subprocess
import sys

import numpy as np
import yaml

from imucald.cli import main

HERE = os.path.dirname(os.path.abspath(__file__))
GOLDEN = os.path.join(HERE, "golden", "replay_mpu6050_seed7.ndjson")
PY = sys.executable


def _replay(rec, *args):
    p = subprocess.run([PY, "-m", "imucald.cli", "replay", str(rec), *args], capture_output=True)
    assert p.returncode == 0, p.stderr.decode()
    return p.stdout.decode().splitlines(), p.stderr.decode()


def _digest(lines):
    """Every non-sample object but the banner, and every 40th sample."""
    out, k = [], 0
    for l in lines:
        o = json.loads(l)
        if o["class"] == "VERSION":
            continue
        if o["class"] == "IMU":
            k += 1
            if k % 40:
                continue
        out.append(o)
    return out


def _close(a, b, path=""):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        # printed values are rounded to 6 digits; allow one unit in the last place
        assert abs(a - b) <= 2e-6 + 1e-6 * abs(b), f"{path}: {a} != {b}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def test_replay_stream_matches_the_golden_file(tmp_path):
    rec = tmp_path / "g.csv"
    assert main(["simulate", "-o", str(rec), "--board", "mpu6050", "--poses", "14", "--hold", "4",
                 "--move", "2", "--rate", "50", "--seed", "7"]) == 0
    lines, err = _replay(rec, "--min-poses", "12")
    got = _digest(lines)
    if os.environ.get("IMUCALD_UPDATE_GOLDEN"):
        with open(GOLDEN, "w") as fh:
            fh.write("".join(json.dumps(o) + "\n" for o in got))
    with open(GOLDEN) as fh:
        want = [json.loads(l) for l in fh]
    assert len(got) == len(want)
    for g, w in zip(got, want):
        _close(g, w)
    assert any(o["class"] == "CAL" for o in got)
    assert json.loads(lines[0])["class"] == "VERSION"


def test_replay_reaches_the_true_calibration_and_saves_it(tmp_path, capsys):
    rec, truth = tmp_path / "r.csv", tmp_path / "t.json"
    assert main(["simulate", "-o", str(rec), "--board", "9dof", "--poses", "30", "--hold", "6",
                 "--seed", "11", "--truth", str(truth)]) == 0
    lines, err = _replay(rec, "--state-dir", str(tmp_path / "st"))
    doc = yaml.safe_load(open(tmp_path / "st" / "calibration.yaml"))
    tr = json.load(open(truth))
    p, se = doc["accel"]["params"], doc["accel"]["stderr"]
    assert set(p) == {"alpha", "scale", "bias_g"}
    est = np.array(p["alpha"] + p["scale"] + p["bias_g"])
    sd = np.array(se["alpha"] + se["scale"] + se["bias_g"])
    # fitted on the training poses; 4 standard errors (plus the pose-edge motion the
    # detector leaves, well under the noise)
    assert np.all(np.abs(est - tr["accel_triangular9"]) < 4 * sd + 2e-4)
    assert np.all(np.abs(np.array(doc["gyro"]["params"]["bias_dps"]) - tr["gyro_bias_dps"]) < 0.05)
    # the same names as `imucald calibrate --json`
    assert main(["calibrate", str(rec), "--json"]) == 0
    cj = json.loads(capsys.readouterr().out)
    assert cj["params"].keys() == p.keys()
    # samples after the calibration are corrected: still ones have |a| = 1 g
    imu = [json.loads(l) for l in lines if '"IMU"' in l]
    still = np.array([o["acc_g"] for o in imu if o["still"] and o["cal"] >= 1])
    assert abs(np.median(np.linalg.norm(still, axis=1)) - 1) < 1e-3
