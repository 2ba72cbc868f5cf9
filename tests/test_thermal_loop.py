"""The loop of README "Closing the loop": gap names a thermal bias in a simulated recording,
calibrate fits the thermal term, apply corrects the recording, gap on it says none."""
import json

import numpy as np
import pytest

from imucald.calibration import load
from imucald.cli import main


def _simulate(d, name, *args):
    rec, truth = d / f"{name}.rec", d / f"{name}.json"
    assert main(["simulate", "-o", str(rec), "--poses", "30", "--hold", "8", "--temp-profile", "heatcool",
                 "--temp-rise", "15", *args, "--truth", str(truth)]) == 0
    return d, rec, json.loads(truth.read_text())


@pytest.fixture(scope="module")
def warm(tmp_path_factory):
    return _simulate(tmp_path_factory.mktemp("loop"), "warm", "--effect", "accel.thermal_bias=0.0007",
                     "--effect", "gyro.thermal_bias=0.02", "--seed", "4")


@pytest.fixture(scope="module")
def warm9(tmp_path_factory):
    return _simulate(tmp_path_factory.mktemp("loop9"), "warm9", "--board", "9dof", "--effect",
                     "mag.thermal_bias=0.001", "--seed", "2")


def _verdict(capsys, *args):
    capsys.readouterr()
    assert main(["gap", *args, "--json", "--sims", "200"]) == 0
    return {k: v["verdict"] for k, v in json.loads(capsys.readouterr().out)["sensors"].items()}


@pytest.mark.parametrize("sensor", ["accel", "gyro", "mag"])
def test_gap_names_it_calibrate_removes_it_gap_says_none(request, capsys, sensor):
    d, rec, truth = request.getfixturevalue("warm9" if sensor == "mag" else "warm")
    assert _verdict(capsys, str(rec), "--sensor", sensor) == {sensor: "thermal_bias"}
    cal_path, out = d / f"{sensor}.yaml", d / f"{sensor}_corrected.rec"
    assert main(["calibrate", str(rec), "--sensor", sensor, "--method", "lm", "-o", str(cal_path)]) == 0
    capsys.readouterr()
    part = load(cal_path).part(sensor)
    th = part.thermal
    assert th["order"] == 1, th["note"]
    unit = {"accel": "g", "gyro": "dps", "mag": "gauss"}[sensor]
    coef = np.asarray(th[f"bias_poly_{unit}"][0])
    se = np.asarray(th[f"bias_poly_stderr_{unit}"][0])
    want = np.asarray(next(e for e in truth["effects"] if e["name"] == f"{sensor}.thermal_bias")["params"]["coef"])
    # the simulator adds it to the raw reading (sim/sensor.py, after the gyro's matrix), where the
    # calibration subtracts it (calibration.py thermal_offset): the truth is coef itself
    assert np.all(np.abs(coef - want) <= 4 * se), (coef, want, se)
    assert main(["apply", str(cal_path), str(rec), "-o", str(out)]) == 0
    assert _verdict(capsys, str(out), "--sensor", sensor) == {sensor: "none"}


def test_apply_refuses_a_calibration_of_another_board_in_one_line(warm, warm9, capsys):
    d, rec, _ = warm
    _, rec9, _ = warm9
    cal = d / "g.yaml"
    assert main(["calibrate", str(rec), "--sensor", "gyro", "-o", str(cal)]) == 0
    capsys.readouterr()
    assert main(["apply", str(cal), str(rec9), "-o", str(d / "x.rec")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "made for board 'mpu6050', this is '9dof'" in err
    assert not (d / "x.rec").exists()
    assert main(["apply", str(cal), str(rec), "-o", str(d / "no" / "x.rec")]) == 73
