"""Magnetometer calibration from rotation alone: synthetic truth, a flat swing, the CLI,
and the two real QMC5883L recordings (tomisuarez_qmc5883l)."""
import json

import numpy as np
import pytest

from imucald.calib.magcal import (SphereReservoir, calibrate_rotation, flat_axis, rel_std,
                                  sample_noise)
from imucald.calib.models import MagModel
from imucald.cli import main
from imucald.recording import Recording, write_recording

from .conftest import real_path

F_GAUSS = 0.5
V_TRUE = np.array([0.30, -0.12, 0.45])                 # hard iron, gauss
W_TRUE = np.array([[1.10, 0.04, -0.02], [0.04, 0.85, 0.03], [-0.02, 0.03, 1.05]])   # soft iron


def _rot(axis, ang):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


def _swing(rng, n=6000, rate_hz=50.0, axis=None, noise_gauss=0.002):
    """Raw readings while the sensor turns: freely (axis None, a smooth random
    angular velocity) or about one fixed sensor axis."""
    f_world = F_GAUSS * np.array([np.cos(np.radians(60)), 0.0, -np.sin(np.radians(60))])
    R = np.eye(3)
    w = rng.normal(size=3)
    h = np.empty((n, 3))
    for k in range(n):
        if axis is None:
            w = 0.995 * w + 0.1 * rng.normal(size=3)
            step = w / rate_hz * 1.5
            R = R @ _rot(step, np.linalg.norm(step)) if np.linalg.norm(step) > 0 else R
        else:
            R = _rot(axis, 2 * np.pi * 0.2 * k / rate_hz)
        h[k] = R.T @ f_world
    raw = np.linalg.solve(W_TRUE, h.T).T + V_TRUE
    return raw + rng.normal(scale=noise_gauss, size=raw.shape)


def test_full_rotation_recovers_truth_within_crlb():
    rng = np.random.default_rng(3)
    raw = _swing(rng)
    res = calibrate_rotation(raw, rng=0)
    assert res["determined"]
    cal = res["calibration"]
    m = MagModel("sym")
    k = m.kw
    # hard iron against the truth, in units of the CRLB standard deviation
    z = (cal.theta[k:] - V_TRUE) / cal.crlb_std[k:]
    assert np.all(np.abs(z) < 4), z
    # the corrected field's magnitude and the soft-iron shape (W up to F)
    W_est = m.matrix(cal.theta)
    assert abs(1 / np.cbrt(np.linalg.det(W_est)) / (F_GAUSS / np.cbrt(np.linalg.det(W_TRUE))) - 1) < 0.01
    assert np.allclose(W_est / np.cbrt(np.linalg.det(W_est)), W_TRUE / np.cbrt(np.linalg.det(W_TRUE)),
                       atol=0.01)
    c = res["coverage"]
    assert c["fraction"] > 0.8
    assert min(c["direction_eigenvalues"]) > 0.2          # 1/3 for a uniform sphere
    # noise-limited: the corrected norm spreads as the noise predicts, also held out in time
    assert res["norm_rel_std"] < 1.2 * res["predicted_rel_std"]
    assert res["heldout"]["norm_rel_std"] < 1.5 * res["predicted_rel_std"]


def test_sample_noise_from_second_differences():
    rng = np.random.default_rng(1)
    raw = _swing(rng, n=4000, noise_gauss=0.003)
    # 4000 samples: the robust scale estimate is within a few percent
    assert np.allclose(sample_noise(raw), 0.003, rtol=0.08)


@pytest.mark.parametrize("axis", [[0, 0, 1], [1, 0.3, 0.2]])
def test_flat_swing_leaves_the_normal_axis_undetermined(axis):
    rng = np.random.default_rng(7)
    raw = _swing(rng, axis=axis)
    res = calibrate_rotation(raw, rng=0)
    assert res["determined"] is False and "calibration" not in res
    # the raw ring lies in the plane (W^T a) . m = const
    n_true = W_TRUE.T @ np.asarray(axis, float)
    n_true /= np.linalg.norm(n_true)
    assert abs(np.dot(res["flat"]["normal"], n_true)) > 0.999


def test_flatness_test_sees_a_tilted_cloud():
    # the same swing plus a second swing about another axis spans three dimensions
    rng = np.random.default_rng(7)
    raw = np.vstack([_swing(rng, n=3000, axis=[0, 0, 1]), _swing(rng, n=3000, axis=[1, 0, 0])])
    sigma = sample_noise(raw)
    assert flat_axis(raw, sigma) is None
    res = calibrate_rotation(raw, rng=0)
    assert res["determined"]


def test_daemon_reservoir_is_the_same_thinning():
    from imucald.daemon.calibrator import MagReservoir
    assert MagReservoir is SphereReservoir


def _mag_only_recording(path, raw, rate_hz=50.0):
    t = np.arange(len(raw)) / rate_hz
    write_recording(Recording(t=t, mag=raw, meta={"board": "gy273", "rate_hz": f"{rate_hz:g}"}), str(path))


def test_queued_reservoir_equals_one_binned_at_every_add():
    """The reservoir queues the daemon's 1-2 readings a batch and bins them in bulk; the
    points, counts and samples seen equal those of binning each add at once (the first
    centre fitted at the add that brings 50 points, the re-binning at each doubling),
    whenever the queue is read (here, now and then) and with non-finite rows mixed in."""
    rng = np.random.default_rng(4)
    adds = []
    for _ in range(1500):
        v = rng.normal(size=(int(rng.integers(0, 4)), 3))
        v = 0.5 * v / np.linalg.norm(v, axis=1, keepdims=True) + [0.1, -0.2, 0.05]
        if len(v) and rng.random() < 0.1:
            v[0, 2] = np.nan
        adds.append(v)
    def feed(queued):
        r, seen = SphereReservoir(), []
        for i, v in enumerate(adds):
            tags = np.full(len(v), i) if i % 2 else None
            if queued:
                r.add(v, tags)
            else:                        # the unqueued reference: each add binned at once
                f = np.all(np.isfinite(v), axis=1)
                r._add_one(v[f], np.full(int(f.sum()), -1 if tags is None else i))
            if i % 97 == 0:
                seen.append((r.seen, r.points().copy()))
        return r, seen
    a, sa = feed(False)
    b, sb = feed(True)
    assert a.seen == b.seen > 2000 and np.array_equal(a.count, b.count)
    assert np.array_equal(a.points(), b.points()) and len(a.points()) > 500
    assert np.array_equal(a.tags(), b.tags()) and (a.tags() >= 0).any() and (a.tags() < 0).any()
    assert all(x[0] == y[0] and np.array_equal(x[1], y[1]) for x, y in zip(sa, sb))


def test_cli_mag_only_recording(tmp_path, capsys):
    p = tmp_path / "m.csv"
    _mag_only_recording(p, _swing(np.random.default_rng(3)))
    assert main(["calibrate", str(p), "--method", "lm", "--json"]) == 0     # --sensor mag implied
    out = json.loads(capsys.readouterr().out)
    assert out["sensor"] == "mag" and out["determined"] is True
    assert np.allclose(out["params"]["hard_iron_gauss"], V_TRUE, atol=1e-3)
    assert set(out["heldout_time_split"]) >= {"norm_rel_std", "train_samples", "test_samples"}
    assert len(out["coverage"]["direction_eigenvalues"]) == 3


def test_cli_flat_swing_exit_3(tmp_path, capsys):
    p = tmp_path / "flat.csv"
    _mag_only_recording(p, _swing(np.random.default_rng(7), axis=[0, 0, 1]))
    assert main(["calibrate", str(p), "--method", "lm"]) == 3
    err = capsys.readouterr().err
    assert "one plane" in err and "not determined" in err
    assert main(["calibrate", str(p), "--method", "lm", "--json"]) == 3
    out = json.loads(capsys.readouterr().out)
    assert out["determined"] is False and abs(out["undetermined_axis"][2]) > 0.99
    assert "params" not in out


def test_cli_raw_table_with_header_block(tmp_path, capsys):
    # the tomisuarez format: 'Fs,50.00', 'Initialization time,60', 'mx,my,mz', then counts
    raw = np.round(_swing(np.random.default_rng(3)) * 12000)
    p = tmp_path / "raw.csv"
    p.write_text("Fs,50.00\nInitialization time,60\nmx,my,mz\n"
                 + "\n".join(",".join(f"{int(v)}" for v in r) for r in raw) + "\n")
    assert main(["calibrate", str(p), "--columns", "mx,my,mz", "--rate-hz", "50",
                 "--nominal-scale", "12000", "--method", "lm", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert np.allclose(out["params"]["hard_iron_gauss"], V_TRUE, atol=1e-3)


# --- the real recordings ----------------------------------------------------------------

def _authors():
    p = np.loadtxt(real_path("tomisuarez_qmc5883l", "authors_results", "paramters_mag.csv"))
    return p[:9].reshape(3, 3), p[9:]


@pytest.mark.parametrize("name", ["noisy_raw_data.csv", "filtered_raw_data.csv"])
def test_real_qmc5883l_rotation(name):
    m = np.loadtxt(real_path("tomisuarez_qmc5883l", name), delimiter=",", skiprows=3)
    res = calibrate_rotation(m, rng=0)
    assert res["determined"]
    pred = res["predicted_rel_std"]
    # Bound derived from the measured noise: the spread the sample noise alone gives
    # (second differences, propagated through the fit) doubled, i.e. model error at most
    # sqrt(3) noise-equivalents, held out in time (last 30 % of the rotation).
    assert res["heldout"]["norm_rel_std"] < 2.0 * pred
    assert res["norm_rel_std"] < 2.0 * pred
    # hand rotation over most of the sphere; the hard iron is ~5 field radii (SOURCE.md)
    assert res["coverage"]["fraction"] > 0.6
    cal = res["calibration"]
    assert np.linalg.norm(cal.params["hard_iron_gauss"]) > 4 * cal.params["field_gauss"]
    # the authors' 12 parameters on the same samples, for the record (printed with -s)
    A, B = _authors()
    auth = rel_std(np.linalg.norm(m @ A.T + B, axis=1))
    print(f"{name}: imucald {res['norm_rel_std']:.4f} (held out {res['heldout']['norm_rel_std']:.4f}), "
          f"authors {auth:.4f}, noise-predicted {pred:.4f}")


def test_a_still_sensor_is_not_mistaken_for_a_plane():
    # readings that only scatter with the noise: no axis is determined, and the
    # message says the sensor was hardly turned (not that it swung in a plane)
    rng = np.random.default_rng(5)
    raw = V_TRUE + rng.normal(scale=0.002, size=(3000, 3))
    res = calibrate_rotation(raw, rng=0)
    assert res["determined"] is False and res["flat"]["rank"] < 2
    from imucald.calib.magcal import flat_message
    assert "hardly turned" in flat_message(res)
