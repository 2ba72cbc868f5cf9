"""The thermal terms (fitting/thermal/terms.py): the order the gap's held-out test chooses, the
coefficients within their stated standard errors, and only a constant below the span."""
import re

import numpy as np
import pytest

from imucald.fitting.fit import accel_prior
from imucald.fitting.models.accel import Triangular9
from imucald.fitting.thermal.terms import fit_bias_series, fit_norm_thermal

SD_DPS = 0.004          # a still interval's mean rate: ~0.05 dps/sqrt(Hz) over ~150 samples


def _series(rng, T, curve):
    y = np.array([0.5, -0.3, 0.1]) + curve(T - 25.0) + rng.normal(size=(len(T), 3)) * SD_DPS
    return fit_bias_series(T, y, np.full((len(T), 3), SD_DPS ** 2), rng=rng)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_gyro_bias_order_and_coefficients(order):
    rng = np.random.default_rng(10 + order)
    T = np.sort(rng.uniform(18, 36, 50))
    c = np.array([[0.02, -0.015, 0.01], [8e-4, 6e-4, -1e-3]])[:order]
    f = _series(rng, T, lambda d: sum(np.outer(d ** (k + 1), c[k]) for k in range(order)))
    assert f.order == order, f.note
    if order == 2:                  # the truth about the fit's reference temperature
        c = np.array([c[0] + 2 * (f.t_ref_c - 25.0) * c[1], c[1]])
    assert np.all(np.abs(f.bias_poly - c) <= 4 * f.bias_poly_stderr), (f.bias_poly, c, f.bias_poly_stderr)
    assert f.t_min_c == T.min() and f.t_max_c == T.max()


def test_a_span_below_the_minimum_gives_a_constant_and_says_why():
    rng = np.random.default_rng(3)
    T = np.sort(rng.uniform(25, 31, 40))           # 6 degC < 10
    f = _series(rng, T, lambda d: np.outer(d, [0.05, 0.05, 0.05]))
    assert f.order == 0 and "< 10 degC (calibration.thermal_min_span_c): constant only" in f.note
    g = fit_bias_series(T, np.ones((40, 3)) + np.outer(T - 28, [0.05] * 3), np.full((40, 3), SD_DPS ** 2),
                        min_span_c=5.0, rng=1)
    assert g.order >= 1


def test_accel_thermal_bias_through_the_norm_model():
    rng = np.random.default_rng(5)
    m = Triangular9()
    th = np.array([0.01, -0.02, 0.005, 1.02, 0.98, 1.01, 0.03, -0.02, 0.01])
    N, sd = 48, 2e-4
    T = np.sort(rng.uniform(20, 35, N))
    U = rng.normal(size=(N, 3))
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    c = np.array([7e-4, -6e-4, 8e-4])               # g/degC
    x = m.inverse(th, U) + np.outer(T - 20, c) + rng.normal(size=(N, 3)) * sd
    f = fit_norm_thermal(m, x, np.full(N, sd ** 2), T, th, accel_prior(m, "mpu6050"), rng=rng)
    assert f.order == 1 and f.scale_poly is None, f.note
    assert np.all(np.abs(f.bias_poly[0] - c) <= 4 * f.bias_poly_stderr[0]), (f.bias_poly, f.bias_poly_stderr)
    # the base part is the bias at t_ref_c
    want = th[6:9] + c * (f.t_ref_c - 20)
    assert np.all(np.abs(f.base[6:9] - want) <= 4 * f.base_stderr[6:9]), (f.base[6:9], want)


def test_accel_thermal_scale_is_chosen_when_the_data_support_it():
    rng = np.random.default_rng(8)
    m = Triangular9()
    th = np.array([0, 0, 0, 1.02, 0.98, 1.01, 0.03, -0.02, 0.01])
    N, sd = 60, 2e-4
    T = np.sort(rng.uniform(20, 40, N))
    U = rng.normal(size=(N, 3))
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    c = np.array([3e-4, -4.5e-4, 4e-4])             # 1/degC on the true input
    x = m.inverse(th, U * (1 + np.outer(T - 20, c))) + rng.normal(size=(N, 3)) * sd
    f = fit_norm_thermal(m, x, np.full(N, sd ** 2), T, th, accel_prior(m, "mpu6050"), rng=rng)
    assert f.order == 1 and f.scale_poly is not None, f.note
    assert np.all(np.abs(f.scale_poly[0] - c) <= 4 * f.scale_poly_stderr[0]), (f.scale_poly, f.scale_poly_stderr)
    assert np.all(np.abs(f.bias_poly[0]) <= 4 * f.bias_poly_stderr[0])
    assert f.inflation < 1.5                        # the scale variant leaves only the noise


@pytest.mark.parametrize("n", [1, 2, 3])
def test_too_few_still_intervals_give_a_constant_untested_and_say_so(n):
    # one interval made the twin's residual exactly 0 and the held-out ratio a division by 0
    y = np.array([[0.5, 0.2, -1.3], [0.51, 0.21, -1.29], [0.52, 0.2, -1.31]])[:n]
    v = np.array([[1e-8, 2e-7, 3e-8]] * n)
    f = fit_bias_series(np.linspace(20.0, 34.0, n), y, v, rng=0)
    assert f.order == 0 and "a temperature term needs at least 4: constant only" in f.note, f.note
    assert np.allclose(f.base, np.average(y, axis=0, weights=1 / v))


def test_calibrate_gyro_on_one_still_pose_notes_it_and_exits_0(tmp_path, capsys):
    import json
    from imucald.cli import main
    from imucald.files.recording import Recording, write_recording
    rng = np.random.default_rng(5)
    n = 6000                                       # 60 s at 100 Hz, never moved
    rec = Recording(t=np.arange(n) / 100.0, acc=np.array([0.0, 0.0, 1.0]) + rng.normal(size=(n, 3)) * 2e-3,
                    gyro=np.array([0.497, 0.247, -1.306]) + rng.normal(size=(n, 3)) * 0.05,
                    temp=np.full(n, 26.3), meta={"board": "mpu6050", "rate_hz": "100"})
    p = str(tmp_path / "still.csv")
    write_recording(rec, p)
    assert main(["calibrate", p, "--sensor", "gyro"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"order 0: [123] still intervals?: a temperature term needs at least 4", out), out
    assert main(["calibrate", p, "--sensor", "gyro", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["thermal"]["order"] == 0


def test_the_reference_temperature_lies_within_the_range_even_at_one_temperature():
    # rounded to 0.01 degC, 26.342 gave t_ref 26.34 < t_min 26.342: calibrate -o wrote a file
    # that load() refused
    f = fit_bias_series(np.full(5, 26.342), np.ones((5, 3)), np.full((5, 3), 1e-6), rng=0)
    th = f.to_thermal("dps")
    assert th["t_min_c"] <= th["t_ref_c"] <= th["t_max_c"], th


@pytest.mark.parametrize("sensor", ["accel", "gyro"])
def test_a_trend_below_the_minimum_span_is_named_with_the_option_that_fits_it(tmp_path, capsys, sensor):
    """A 7 degC warm-up with a thermal bias (5x the datasheet's): "constant only" (the span is
    under calibration.thermal_min_span_c), and the note now adds that the held-out test would
    choose a term over these degrees, and the --thermal-min-span that fits it (a cold review:
    a 9.5 degC warm-up's constant missed the truth by 3 standard errors with no hint).
    Without the effect the note stays as it was (the test's own rate: THERMAL_TREND_LEVEL,
    1 %).  Broken once (fit_thermal without the second look): no hint; fails."""
    from imucald.cli import main
    from imucald.files.recording import write_recording
    from imucald.sim.effects import DEFAULT_MAGNITUDE, effect_session
    from imucald.sim.orientations import random_pose_set
    name = f"{sensor}.thermal_bias"
    for eff in ([(name, 5 * DEFAULT_MAGNITUDE[name])], []):
        g = np.random.default_rng(11)
        s, _ = effect_session("mpu6050", random_pose_set(25, g), g, eff, hold_s=(3.0, 5.0),
                              temp_kind="warmup", temp_rise_c=7.0)
        p = tmp_path / "warm.csv"
        write_recording(s.recording, str(p))
        assert main(["calibrate", str(p), "--sensor", sensor]) == 0
        line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("  thermal ("))
        assert "degC < 10 degC (calibration.thermal_min_span_c): constant only" in line, line
        hint = re.search(r"; over these ([\d.]+) degC the held-out test would choose order \d.*"
                         r": --thermal-min-span ([\d.]+) fits it$", line)
        assert bool(hint) == bool(eff), line
        if hint:
            assert float(hint.group(2)) <= float(hint.group(1)) < 10
            assert main(["calibrate", str(p), "--sensor", sensor, "--thermal-min-span", hint.group(2)]) == 0
            line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("  thermal ("))
            assert re.search(r"\): order [1-3]", line), line


def test_an_order_0_constant_names_the_temperature_it_stands_for():
    """Below the minimum span the bias is a constant; the file's t_ref_c says where it holds:
    the weighted mean of the poses' temperatures, not the range's middle.  A warm-up of 8 degC
    (exponential: most still intervals near the end), a gyro bias of 0.1 deg/s/degC and still
    means of 0.002 deg/s: the constant lies within 3 sd of the bias at t_ref_c on every axis,
    where at the middle of the range it was 0.12-0.24 deg/s off (sd 0.0003; broken once: fails).  On
    a black-box helper's 8-degC warm-ups (30 seeds, accelerometer) the sessions with a
    parameter beyond 3 sd went 17 -> 7 (bias within 2 sd 53/90 -> 79/90)."""
    rng = np.random.default_rng(3)
    t = np.linspace(0, 600, 40)
    T = 25 + 8 * (1 - np.exp(-t / 120))                     # a warm-up: settles near 33 degC
    slope = np.array([0.1, -0.05, 0.08])
    b0 = np.array([1.0, -2.0, 0.5])
    y = b0 + np.outer(T - 25, slope) + rng.normal(0, 0.002, (40, 3))
    tf = fit_bias_series(T, y, np.full((40, 3), 0.002 ** 2), min_span_c=10.0, rng=0)
    assert tf.order == 0 and tf.t_max_c - tf.t_min_c < 10
    truth = b0 + slope * (tf.t_ref_c - 25)
    assert np.all(np.abs(tf.base - truth) <= 3 * tf.base_stderr), (tf.t_ref_c, tf.base - truth, tf.base_stderr)
