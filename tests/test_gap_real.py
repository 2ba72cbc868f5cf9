"""`imucald gap` on the real recordings (../shared/data/real; skipped with the reason when absent).

Figures compared with each recording's SOURCE.md (see README, "Gap diagnosis on real data")."""
import os
import sys

import pytest

from .conftest import real_path

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(__file__)), "bench"))


@pytest.fixture(scope="module")
def tempsweep_result():
    real_path("freeimu_mpu6050_tempsweep")
    from real_gap import tempsweep
    from imucald.gap.diagnose import diagnose
    return diagnose(tempsweep(), sims=100)


def _coef(r, name):
    e = next(e for e in r["effects"] if e["name"] == name and e.get("significant") and e["step"] == 1)
    k = next(iter(e["params"]))
    return e["params"][k], e["stderr"][k]


def test_tempsweep_one_orientation_gets_a_thermal_verdict_with_the_source_slopes(tempsweep_result):
    res = tempsweep_result
    assert res["mode"] == "time_series" and res["poses_found"] == 1
    a = res["sensors"]["accel"]
    # the linear thermal term comes first and closes most of the gap (a curvature over the
    # 19 degC warm-up remains: the authors fit a cubic in temperature)
    assert a["verdict"].split("+")[0] == "thermal_bias" and a["shrink"] > 0.9
    assert a["along_gravity_axis"] == "+z"
    c, se = _coef(a, "thermal_bias")
    # SOURCE.md: least-squares slopes over all samples, counts/degC at 16384 counts/g:
    # Ax +4.61, Ay -1.54, Az -28.21.  The warm-up curve is not a straight line in
    # temperature (the authors fit a cubic), so a sample-weighted and a block-weighted
    # slope differ by more than their noise: 10 % of the slope is the tolerance.
    for got, src in zip(c, (4.61, -1.54, -28.21)):
        assert got * 16384 == pytest.approx(src, rel=0.10)
    # the class the recording cannot split: z bias vs z scale along gravity
    assert any(set(x["effects"]) == {"thermal_bias", "thermal_scale_z"} for x in a["confusable"])


def test_tempsweep_gyro_thermal_slope_matches_the_source(tempsweep_result):
    g = tempsweep_result["sensors"]["gyro"]
    assert "thermal_bias" in g["verdict"].split("+") and g["shrink"] > 0.9
    c, se = _coef(g, "thermal_bias")
    # SOURCE.md: Gy +0.455 counts/degC at 16.4 counts/(deg/s) (the +-2000 dps range FreeIMU sets)
    assert c[1] * 16.4 == pytest.approx(0.455, rel=0.10)
    assert any(set(x["effects"]) == {"thermal_bias", "wandering_bias"} for x in g["confusable"])


def test_xsens_accel_wanders_and_gyro_has_g_sensitivity():
    real_path("imutk_xsens_mti")
    from real_gap import xsens
    from imucald.gap.diagnose import diagnose
    res = diagnose(xsens(), sims=100)
    assert res["poses_found"] >= 36
    assert any("no temperature" in n for n in res["notes"])
    a, g = res["sensors"]["accel"], res["sensors"]["gyro"]
    # the real residual (about 0.1 mg) is well above the pose noise the data shows
    assert a["p_value"] < 0.01 and a["ratio_before"] > 1.5
    # a bias that moves over the 8.5 minutes, not a straight line, and not orientation-shaped
    assert a["verdict"] == "wandering_bias" and a["shrink"] > 0.5
    # the gyro's pose means depend on orientation beyond Earth's rate: g-sensitivity
    assert g["verdict"] == "g_sensitivity" and g["shrink"] > 0.9


def test_sunsided_ten_minutes_unmoved_accel_drifts_gyro_none_mag_not_diagnosable():
    real_path("sunsided_mpu6050_hmc5883l", "unmoved-with-x-pointing-forward-10min")
    from real_gap import sunsided
    from imucald.gap.diagnose import diagnose
    res = diagnose(sunsided("unmoved-with-x-pointing-forward-10min"), sims=100)
    assert res["mode"] == "time_series" and res["orientations"] == 1
    a, g = res["sensors"]["accel"], res["sensors"]["gyro"]
    # 0.22 degC of temperature: thermal effects untested; the accelerometer's y bias moves
    # over the 10 minutes (about -0.56 mg), which closes the gap.  Issue 20: gap works on the
    # distinct samples (this loader's 100 Hz grid repeats 61 % of its rows); there the move is
    # best a smooth wandering bias (the raw log's minute means of y: 66.17, 66.01, 65.82, ...
    # 65.60 mg, fast first), the straight line still significant at step 1
    assert a["verdict"] == "wandering_bias" and a["explained"] == "closed"
    c, se = _coef(a, "bias_drift")
    assert c[1] / se[1] < -4                         # y: clear of its standard error
    assert abs(c[0]) / se[0] < 3                     # x: within its noise
    # the gyro's x bias drifts: the raw log's minute means go 4.542 -> 4.526 deg/s over the 10
    # minutes (-2.7e-5 deg/s/s, each mean +-0.0016); on the held rows gap saw none (issue 20)
    assert g["verdict"] == "bias_drift"
    c, se = _coef(g, "bias_drift")
    assert c[0] / se[0] < -4 and -6e-5 < c[0] < -1.5e-5
    # the board never turned: the magnetometer cannot be fitted, and the output says why
    assert "mag" not in res["sensors"] and any("mag: not diagnosed" in n for n in res["notes"])


def test_tempsweep_summary_says_which_fits_were_made_beside_the_first_effect(tempsweep_result):
    """The time-series path fits its candidates alone, then beside the first effect chosen:
    the summary listed 'thermal_bias' twice for the gyro with different slopes and nothing
    saying which was which (a new user's walk-through).  The second step's lines now say what
    they were fitted beside, and within a sensor no line repeats another's label.  Broken
    once: the label removed (fails)."""
    from imucald.cli.gap import gap_summary
    text = gap_summary(tempsweep_result)
    assert "  wandering_bias (beside thermal_bias): ratio after" in text
    assert "  thermal_bias (beside wandering_bias): ratio after" in text
    for block in text.split("\ngyro: ")[0], text.split("\ngyro: ")[1]:
        labels = [line.split(": ratio after")[0] for line in block.splitlines() if ": ratio after" in line]
        assert len(labels) == len(set(labels)), labels
