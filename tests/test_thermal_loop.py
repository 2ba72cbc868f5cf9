"""The loop of README "Closing the loop": gap names a thermal bias in a simulated recording,
calibrate fits the thermal term, apply corrects the recording, gap on it says none; and the
corrected readings agree with the simulated truth at every temperature of the range."""
import json

import numpy as np
import pytest

from imucald.fitting.judging.coverage import sphere_lattice
from imucald.fitting.models.accel import Triangular9
from imucald.calibration import load
from imucald.cli import main
from imucald.files.recording import read_recording


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
    # seed 2 again (it was moved to 3 when the one trajectory generator of issue 24 changed
    # every session and gap said thermal_bias after apply): the mag is now checked by what
    # gap measures, not by its verdict (see the test), and that check holds on every seed
    return _simulate(tmp_path_factory.mktemp("loop9"), "warm9", "--board", "9dof", "--effect",
                     "mag.thermal_bias=0.001", "--seed", "2")


def _gap(capsys, *args):
    capsys.readouterr()
    assert main(["gap", *args, "--json", "--sims", "200"]) == 0
    return json.loads(capsys.readouterr().out)["sensors"]


def _verdicts(sensors):
    return {k: v["verdict"] for k, v in sensors.items()}


def _residual_slope(report):
    """gap's thermal_bias slope (per degC) on the corrected recording and its standard error:
    the part of the simulated slope that calibrate + apply left."""
    eff = next(e for e in report["effects"] if e["name"] == "thermal_bias")
    key = next(k for k in eff["params"] if k.startswith("thermal_bias_") and "curvature" not in k)
    return np.asarray(eff["params"][key]), np.asarray(eff["stderr"][key])


@pytest.mark.parametrize("sensor", ["accel", "gyro", "mag"])
def test_gap_names_it_calibrate_removes_it_gap_says_none(request, capsys, sensor):
    """gap names the thermal bias; calibrate fits it within 4 of its standard errors of the
    simulated coefficient; after apply, the slope gap measures on the corrected recording is
    within 4 x sqrt(calibrate's SE^2 + gap's SE^2) of zero per axis (the calibration's own
    error, as it states it, seen through gap's estimate); and for accel and gyro gap says
    "none".  Measured on seeds 0-19 (this generator): gap names it before on 20/20 for each
    sensor; calibrate's |coef - truth| / SE at most 2.7; the residual slope over the combined
    SE at most 1.4 (accel, gyro) and 2.2 (mag); gap says "none" after apply on 20/20 (accel),
    20/20 (gyro) and only 9/20 (mag).
    The mag's "none" is not asserted, because there the code is weak, not the seed: the
    standard error calibrate states for the mag's thermal slope is 4-9x the one of gap's
    estimate (gap fits ~700 points of the corrected recording), so the 2-14 % of the
    simulated slope calibrate leaves (about one of its SEs) is for gap a residual at
    p ~ 1e-12..1e-58 on 11/20 sessions.  The
    verdict was a coin flip per seed (seed 2 -> 3 when the generator changed); the residual
    check holds on every seed (P(|z| > 4) ~ 6e-5 per axis if calibrate's SE is right).
    Seen to fail: apply not applying the thermal terms (calibration.py thermal_offset
    returning raw): the residual is the whole simulated slope, 17-26 combined SEs for the mag
    (4-7x the bound), and accel and gyro fail earlier, against the truth."""
    d, rec, truth = request.getfixturevalue("warm9" if sensor == "mag" else "warm")
    assert _verdicts(_gap(capsys, str(rec), "--sensor", sensor)) == {sensor: "thermal_bias"}
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
    if sensor != "mag":
        _corrected_matches_the_truth(part, rec, truth, sensor)
    assert main(["apply", str(cal_path), str(rec), "-o", str(out)]) == 0
    after = _gap(capsys, str(out), "--sensor", sensor)
    res, se_gap = _residual_slope(after[sensor])
    assert np.all(np.abs(res) <= 4 * np.hypot(se, se_gap)), (res, se, se_gap)
    if sensor != "mag":
        assert _verdicts(after) == {sensor: "none"}


def _corrected_matches_the_truth(part, rec, truth, sensor):
    """The corrected reading of the simulated sensor at 8 temperatures over the fitted range
    (accel: specific force over 500 directions; gyro: a still sensor's rate) against the
    truth, per axis within 4x the calibration's own standard errors propagated there (bias,
    scale, non-orthogonality, thermal coefficient times the largest |T - t_ref|).
    gap cannot see this: it refits a constant bias that absorbs a thermal term referenced
    to the wrong temperature.  Seen to catch: calibration.py thermal_offset taking T - t_min
    instead of T - t_ref: accel 4.0-4.9 mg off against a 0.6 mg bound."""
    th = part.thermal
    unit = {"accel": "g", "gyro": "dps"}[sensor]
    eff = next(e for e in truth["effects"] if e["name"] == f"{sensor}.thermal_bias")
    coef = np.asarray(eff["params"]["coef"])
    t0 = float(read_recording(rec).temp[0])     # sim/effects.py: coef * (T - T[0]) on the raw reading
    lo, ref, hi = th["t_min_c"], th["t_ref_c"], th["t_max_c"]
    se, se_p = part.stderr, np.asarray(th[f"bias_poly_stderr_{unit}"][0])
    if sensor == "accel":
        T9 = Triangular9()
        U = sphere_lattice(500)
        th_true = np.asarray(truth["accel_triangular9"])
        true_raw = lambda T: T9.inverse(th_true, U) + coef * (T - t0)
        want = U
        var = se["bias_g"] ** 2 + se["scale"] ** 2 + 2 * np.max(se["alpha"]) ** 2
    else:
        true_raw = lambda T: (np.asarray(truth["gyro_bias_dps"]) + coef * (T - t0))[None]
        want = np.zeros((1, 3))
        var = se["bias_dps"] ** 2
    bound = 4 * np.sqrt(var + (se_p * max(hi - ref, ref - lo)) ** 2)
    for T in np.linspace(lo, hi, 8):
        raw = true_raw(T)
        err = np.abs(part.apply(raw, np.full(len(raw), T)) - want).max(0)
        assert np.all(err <= bound), (T, err, bound)


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


@pytest.mark.parametrize("sensor", ["accel", "mag"])
def test_text_and_json_give_the_parameters_the_file_holds_when_thermal_terms_move_them(request, capsys, sensor):
    """With thermal terms the file holds the parameters refitted with them, at the reference
    temperature; the constant fit printed first averages over the temperatures (a probe's
    independent warm-up tours: up to 9 mg apart, and 3-6 mg off the truth at t_ref, which a user
    copying --json's ``params`` took).  --json gives the file's under ``thermal.file_params``
    and ``file_stderr``, the text under "in the calibration file (-o)", equal to the file's.
    Broken once (calibrate without the file's part passed to thermal_json and thermal_lines):
    ``file_params`` missing, and no such line."""
    d, rec, _ = request.getfixturevalue("warm" if sensor == "accel" else "warm9")
    out = d / f"file_params_{sensor}.yaml"
    capsys.readouterr()
    assert main(["calibrate", str(rec), "--sensor", sensor, "--json", "-o", str(out)]) == 0
    j = json.loads(capsys.readouterr().out)
    th = j["thermal"]
    assert th["order"] >= 1, th
    part = getattr(load(str(out)), sensor)
    assert set(th["file_params"]) == set(part.params)
    for g, v in part.params.items():
        np.testing.assert_array_equal(th["file_params"][g], np.asarray(v, float).ravel())
        np.testing.assert_array_equal(th["file_stderr"][g], np.asarray(part.stderr[g], float).ravel())
    key = "bias_g" if sensor == "accel" else "hard_iron_gauss"
    assert not np.allclose(j["params"][key], th["file_params"][key], rtol=0, atol=1e-9), "the terms moved nothing"
    assert main(["calibrate", str(rec), "--sensor", sensor]) == 0
    text = capsys.readouterr().out
    at = text.index("in the calibration file (-o)")
    row = next(ln for ln in text[at:].splitlines() if ln.split()[:1] == [key])
    np.testing.assert_allclose([float(x) for x in row.split("[")[1].split("]")[0].split(",")],
                               np.asarray(part.params[key], float).ravel(), rtol=0, atol=5e-7)
