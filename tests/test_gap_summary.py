"""`imucald gap`'s text summary says what the verdict names, from the search's joint fit."""
from imucald.cli.gap import gap_summary


def _sensor(members, effects):
    return {"unit": "g", "verdict": "thermal_bias+nonlinearity", "explained": "closed", "shrink": 0.9,
            "ratio_before": 4.0, "ratio_after": 1.02, "p_value": 1e-9, "heldout_rms": 4e-4,
            "twin_heldout_rms": 1e-4, "effects": effects, "search": {"members": members}}


def test_summary_prints_the_named_members_joint_fit():
    """A pair's members are printed with their joint-fit coefficients and both tests' p-values;
    the single fits (whose coefficients differ from the pair's) only as "also significant alone"
    for an effect outside the pair, and a random walk's intensity once with its interval.
    Breakage caught: printing r["effects"] (the single fits) instead of the members, which showed
    thermal_bias's single-fit slope 9.9 and no nonlinearity."""
    members = [
        {"name": "thermal_bias", "coefficient_p_value": 1e-6, "heldout_p_value": 1e-4,
         "params": {"thermal_bias_g/C": [5e-4, 0.0, 1e-4]},
         "stderr": {"thermal_bias_g/C": [5e-5, 5e-5, 5e-5]}},
        {"name": "nonlinearity", "coefficient_p_value": 2e-5, "heldout_p_value": 3e-3,
         "params": {"k2_g^-1": [1e-3, 2e-3]}, "stderr": {"k2_g^-1": [2e-4, 2e-4]}}]
    effects = [{"name": "thermal_bias", "significant": True, "ratio_after": 2.0,
                "params": {"thermal_bias_g/C": [9.9, 9.9, 9.9]},
                "stderr": {"thermal_bias_g/C": [1.0, 1.0, 1.0]}},
               {"name": "bias_drift", "significant": True, "ratio_after": 3.1,
                "params": {"bias_drift_g/s": [1e-7, 2e-7, 3e-7]},
                "stderr": {"bias_drift_g/s": [1e-7, 1e-7, 1e-7]}}]
    txt = gap_summary({"poses_found": 30, "sensors": {"accel": _sensor(members, effects)}})
    assert "thermal_bias (joint fit; coefficient p = 1e-06, held-out p = 0.0001): " \
           "thermal_bias_g/C = [0.0005+-5e-05, 0+-5e-05, 0.0001+-5e-05]" in txt
    assert "nonlinearity (joint fit;" in txt and "9.9" not in txt
    assert "bias_drift (also significant alone): ratio after 3.10" in txt
    walk = [{"name": "wandering_bias", "coefficient_p_value": 1e-9, "heldout_p_value": 1e-8,
             "params": {"random_walk_intensity_g^2/s": [2e-10] * 3},
             "random_walk": {"q_ci95": [1e-10, 4e-10]}}]
    txt = gap_summary({"poses_found": 30, "sensors": {"accel": _sensor(walk, [])}})
    assert "random_walk_intensity_g^2/s = 2e-10 (95 % interval 1e-10 .. 4e-10)" in txt


def test_summary_takes_scalar_and_odd_parameters():
    """A single fit's parameters may hold scalars (a spline's knot count) and lists of lists:
    the summary prints them instead of failing.  Seen to fail (TypeError: 'int' object is not
    iterable, a traceback from `imucald gap` on the real temperature sweep) with every value
    taken as a vector."""
    effects = [{"name": "wandering_bias", "significant": True, "ratio_after": 1.47,
                "params": {"interior_knots": 2, "curve_rms_dps": [0.014, 0.091, 0.007],
                           "grid": [[1, 2], [3, 4]]}}]
    r = _sensor([], effects)
    r["verdict"] = "wandering_bias"
    txt = gap_summary({"poses_found": 30, "sensors": {"gyro": r}})
    assert "interior_knots = 2; curve_rms_dps = [0.014, 0.091, 0.007]; grid = [[1, 2], [3, 4]]" in txt
