"""Blind test of the gap diagnosis on recordings from tests/blindgen.py: motion, noise and
effects written apart from the simulator and the candidate library (other
parametrisations, forms outside the library, coloured noise, tremor, short holds,
Earth's rate, ordinary soft iron, single-orientation warm-ups).  A CI-sized subset;
bench/gap_blind.py runs the full set (>= 50 nulls) and prints the figures.

Pass marks from ../shared/reference/error-models.md section 5: false alarms <= 3 %
(here at most 1 of the 12 nulls: P(>= 2 | 3 %) = 5 %), naming >= 85 %, and the truth
within 3 standard errors for >= 90 % of a named effect's coefficients."""
import numpy as np
import pytest

from imucald.gap.diagnose import diagnose

from .blindgen import hit, make_case

NULLS = ["null", "null_flicker", "tremor_null", "short_holds_null", "mag_null", "single_warmup_null"]
EFFECTS = ["thermal_bias", "thermal_scale", "quadratic", "random_walk", "single_warmup_thermal", "mag_thermal"]
OUTSIDE = ["cubic", "triple_product", "hysteresis"]


def _run(kinds, seeds):
    out = []
    for k in kinds:
        for s in seeds:
            rec, lab = make_case(k, s)
            out.append((k, s, lab, diagnose(rec, sims=100, seed=s)))
    return out


@pytest.fixture(scope="module")
def nulls():
    return _run(NULLS, (500, 501))


@pytest.fixture(scope="module")
def effects():
    return _run(EFFECTS + OUTSIDE, (700, 701))


def test_coloured_noise_tremor_short_holds_soft_iron_nulls_are_none(nulls):
    false = [(k, s, res["sensors"][lab["sensor"]]["verdict"])
             for k, s, lab, res in nulls if res["sensors"][lab["sensor"]]["verdict"] != "none"]
    assert len(false) <= 1, f"nulls called an effect: {false}"


def test_gyro_nulls_are_none(nulls):
    false = [(k, s) for k, s, lab, res in nulls if res["sensors"]["gyro"]["verdict"] != "none"]
    assert len(false) <= 1, f"gyro called an effect on nulls: {false}"


def test_plain_9dof_with_ordinary_soft_iron_is_none_for_the_magnetometer(nulls):
    mags = [res["sensors"]["mag"]["verdict"] for k, s, lab, res in nulls if k == "mag_null"]
    assert mags == ["none", "none"]


def test_library_effects_are_named_and_forms_outside_it_are_not(effects):
    misses = [(k, s, res["sensors"][lab["sensor"]]["verdict"]) for k, s, lab, res in effects
              if not hit(res["sensors"][lab["sensor"]]["verdict"], lab["expect"])]
    inside = [m for m in misses if m[0] in EFFECTS]
    outside = [m for m in misses if m[0] in OUTSIDE]
    assert len(inside) <= 1, f"library effects missed: {inside}"            # >= 90 % of 12
    # a cubic aliases into the cross-axis quadratic and scale on random orientations, and a
    # pose-to-pose hysteresis into a wandering bias (their hit rates: `python bench/gap_blind.py`;
    # no figure is copied here, it would go stale)
    assert len(outside) <= 2, f"forms outside the library given a library name: {outside}"


def test_truth_lies_within_three_standard_errors(effects):
    z = []
    for k, s, lab, res in effects:
        for key, truth in lab["truth"].items():
            sensor = "gyro" if key.startswith("gyro_") else "mag" if key.startswith("mag_") else "accel"
            key = key.replace("gyro_", "").replace("mag_", "", 1)
            r = res["sensors"][sensor]
            if key.split("_g")[0].split("_dps")[0] not in r["verdict"]:
                continue
            e = next(e for e in r["effects"] if e.get("significant") and key in e.get("params", {}))
            z += list(np.abs(np.subtract(e["params"][key], truth)) / np.asarray(e["stderr"][key]))
    assert len(z) >= 9
    assert np.mean(np.asarray(z) <= 3) >= 0.9, f"|error| / stderr: {np.round(z, 1).tolist()}"
