"""Thermal terms learnt passively by the daemon's pipeline from a replayed recording:
learnt once the still intervals span thermal_min_span_c, the coefficients within 3 standard
errors of the simulated ones, the stream's still |a| error and gyro rate below the
constant-only daemon's, and below the span only a constant is
applied and the status says why (bench/thermal.py measures the same over seeds)."""
import importlib.util
import os

import numpy as np
import pytest

BENCH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench")


@pytest.fixture(scope="module")
def bt():
    import sys
    sys.path.insert(0, BENCH)
    spec = importlib.util.spec_from_file_location("bench_thermal", os.path.join(BENCH, "thermal.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _within_3_se_of_the_truth(th, unit, coef):
    """Every learnt thermal coefficient within 3 of its standard errors of the simulated
    truth: the linear bias row = coef, higher powers and a scale term = 0."""
    c = np.asarray(th[f"bias_poly_{unit}"], float)
    se = np.asarray(th[f"bias_poly_stderr_{unit}"], float)
    want = np.zeros_like(c)
    want[0] = coef
    z = (c - want) / se
    if "scale_poly" in th:
        z = np.vstack([z, np.asarray(th["scale_poly"], float) / np.asarray(th["scale_poly_stderr"], float)])
    assert np.all(np.abs(z) <= 3), (unit, z, c, want)


def test_learnt_in_the_field_and_the_stream_corrected(bt):
    rec, truth = bt.session(0, 15.0, 0.75, 0.02, poses=40, rate_hz=50.0, truth=True)
    pipe, lines, first = bt.replay(rec, 10.0)
    assert first is not None, pipe.thermal_status()
    a, g = pipe.applied.accel.thermal, pipe.applied.gyro.thermal
    assert a["order"] >= 1 and g["order"] >= 1, (a["note"], g["note"])
    assert a["t_max_c"] - a["t_min_c"] >= 10.0
    _, lines0, _ = bt.replay(rec, 1e3)          # the constant-only daemon on the same recording
    t_first = next(d["t"] for d in lines if d["cal"] >= first)
    th = bt.still_runs(lines, first)
    c0 = bt.still_runs([d for d in lines0 if d["t"] >= t_first], 0)
    assert len(th) >= 10 and len(c0) == len(th)
    # the terms learnt are the simulated ones within their stated errors (the acceptance
    # figure, the shrink of the stream's still |a| error and gyro rate, is bench/thermal.py's)
    _within_3_se_of_the_truth(a, "g", truth["accel"])
    _within_3_se_of_the_truth(g, "dps", truth["gyro"])
    # and the stream once they are applied is closer to the truth than the constant-only one's
    assert bt.rms(c0, 0) > bt.rms(th, 0) and bt.rms(c0, 1) > bt.rms(th, 1), (bt.rms(c0, 0), bt.rms(th, 0))
    st = pipe.status()["thermal"]
    assert "why" not in st and st["accel"]["order"] == a["order"]


def test_below_the_minimum_span_only_a_constant_and_the_status_says_why(bt):
    rec = bt.session(100, 7.0, 0.75, 0.02, poses=30, rate_hz=50.0)
    pipe, lines, first = bt.replay(rec, 10.0)
    assert first is None and pipe.applied.accel is not None
    assert not pipe.applied.accel.thermal and not (pipe.applied.gyro and pipe.applied.gyro.thermal)
    st = pipe.status()["thermal"]
    assert st["span_c"] < 10 and "(calibration.thermal_min_span_c): constant only" in st["why"]


def test_the_magnetometer_hard_iron_learnt_in_the_field(bt):
    from imucald.sim.effects import effect_session
    from imucald.sim.orientations import random_pose_set
    rng = np.random.default_rng(3)
    s, eff = effect_session("9dof", random_pose_set(36, rng), rng, [("mag.thermal_bias", 1e-3)], 100.0,
                            (6.4, 9.6), (2.1, 3.9), "heatcool", 15.0)
    pipe, _, _ = bt.replay(s.recording, 10.0)
    th = pipe.applied.mag.thermal
    assert th and th["order"] == 1, pipe.thermal_status()
    # the simulator adds the coefficient to the raw reading, as the terms remove it
    want = np.asarray(eff[0]["params"]["coef"])
    assert np.all(np.abs(th["bias_poly_gauss"][0] - want) <= 4 * th["bias_poly_stderr_gauss"][0]), (th, want)
    assert pipe.status()["thermal"]["mag"]["order"] == 1


def test_the_thermal_log_survives_a_restart(tmp_path):
    """The log is saved as thermal.csv (a pose file with the gyro's deviations) and resumed:
    a daemon that reboots every day keeps learning over the days."""
    from imucald.fitting.stillness.detector import StaticInterval
    from imucald.daemon.state import load_poses, save_poses
    from imucald.daemon.thermallog import ThermalLog
    rng = np.random.default_rng(1)
    log = ThermalLog()
    for i in range(20):
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        gc = np.diag(rng.uniform(1e-6, 4e-6, 3))
        sc = np.diag(rng.uniform(1e-6, 2e-6, 3))
        assert log.add(StaticInterval(a, sc / 500, sc, 500, 10.0 * i, 10.0 * i + 5, 20 + 0.7 * i,
                                      rng.normal(size=3), gc))
    assert not log.add(StaticInterval(np.ones(3), np.eye(3), np.eye(3), 5, 0, 1, np.nan))
    save_poses(str(tmp_path), log.pose_set(), "thermal.csv")
    back = ThermalLog()
    back.load(load_poses(str(tmp_path), "thermal.csv"))
    a, b = log.arrays(), back.arrays()
    assert len(back) == 20 and back.span_c() == pytest.approx(log.span_c())
    for k in ("acc", "temp", "gyro", "gyro_var", "n"):
        assert np.allclose(a[k], b[k], rtol=1e-7, atol=0), k


def test_the_log_is_bounded_and_a_long_still_spell_does_not_push_out_the_range():
    from imucald.fitting.stillness.detector import StaticInterval
    from imucald.daemon.thermallog import ThermalLog
    log = ThermalLog(max_intervals=50)
    c = np.eye(3) * 1e-8
    up = np.array([0.0, 0.0, 1.0])
    for T in np.arange(10.0, 30.0, 1.0):                 # one pose per degC, 20 in all
        log.add(StaticInterval(up, c, c, 100, 0, 1, T))
    for i in range(500):                                  # hours still at 30 degC
        log.add(StaticInterval(up, c, c, 100, 0, 1, 30.0 + 0.001 * i))
    assert len(log) == 50 and log.span_c() >= 20.0
    assert sorted(p.temp for p in log.items)[:20] == list(np.arange(10.0, 30.0, 1.0))


def test_imucald_status_prints_the_thermal_terms_and_why_there_are_none(bt, tmp_path, monkeypatch, capsys):
    """`imucald status` text: the span against the minimum and, per sensor, the terms in force."""
    import imucald.daemon.control as control
    from imucald.cli import main
    rec = bt.session(100, 7.0, 0.75, 0.02, poses=30, rate_hz=50.0)
    pipe, _, _ = bt.replay(rec, 10.0)
    st = pipe.status()
    st.update(board="mpu6050", rate_hz=50.0, bus="emulated", clients=0, clients_dropped=0,
              board_stats={"samples": 1, "gaps": 0, "missing": 0, "bus_faults": 0})
    monkeypatch.setattr(control, "request", lambda path, cmd: st)
    assert main(["status", "--runtime-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"thermal: {st['thermal']['intervals']} still intervals over " in out
    assert "(calibration.thermal_min_span_c): constant only" in out
    st["thermal"] = {"intervals": 40, "span_c": 14.1, "min_span_c": 10.0,
                     "accel": {"order": 1, "t_min_c": 22.3, "t_max_c": 35.2, "note": "order 1: why"}}
    assert main(["status", "--runtime-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "thermal: 40 still intervals over 14.1 degC\n  accel: order 1 over 22.3..35.2 degC: order 1: why" in out
