"""imucald noise: overlapping Allan deviation, fitted figures with intervals, kalibr/ROS exports."""
import json
import math
import re

import numpy as np
import pytest
import yaml

from imucald.fitting.noise.allan import (
    characterise, chi2_ppf, edf_overlapping, read_figures
)
from imucald.fitting.noise.colour import allan_deviation
from imucald.cli import main
from imucald.files.recording import Recording, write_recording

from .conftest import real_path

FS = 100.0


def coloured(rng, n, fs, N, B, K, d=3):
    """White noise of density N (u/sqrt(Hz): per-sample sigma N sqrt(fs)), flicker noise of
    bias instability B (one-sided PSD h/f with h = B^2/pi, so the Allan floor 2 ln2 h is
    (0.664 B)^2, IEEE Std 952 C.1.3) shaped in the frequency domain, and a rate random walk K
    (u/sqrt(s): AVAR K^2 tau / 3)."""
    w = rng.standard_normal((n, d)) * N * math.sqrt(fs)
    f = np.fft.rfftfreq(n, 1 / fs)
    S = np.zeros_like(f)
    S[1:] = B * B / math.pi / f[1:]
    W = np.fft.rfft(rng.standard_normal((n, d)), axis=0)
    fl = np.fft.irfft(W * np.sqrt(S * fs / 2)[:, None], n, axis=0)
    rw = np.cumsum(rng.standard_normal((n, d)) * K / math.sqrt(fs), axis=0)
    return w + fl + rw


def test_overlapping_and_plain_allan_agree_on_white_noise_and_overlapping_is_tighter():
    rng = np.random.default_rng(1)
    taus = [0.05, 0.5, 5.0]
    plain, over = [], []
    for _ in range(30):
        x = rng.standard_normal((20000, 1))
        plain.append(allan_deviation(x, FS, taus)[:, 0])
        over.append(allan_deviation(x, FS, taus, overlapping=True)[:, 0])
    plain, over = np.array(plain), np.array(over)
    truth = 1 / np.sqrt(FS * np.array(taus))
    # both unbiased: the mean of 30 within 4 of its standard errors of 1/sqrt(m)
    for est in (plain, over):
        assert np.all(np.abs(est.mean(0) - truth) < 4 * est.std(0, ddof=1) / np.sqrt(30))
    assert over.std(0)[2] < plain.std(0)[2]             # more averages at long tau


def test_chi_square_quantiles_and_edf():
    stats = pytest.importorskip("scipy.stats")
    for nu in (3, 7.5, 30, 101, 999, 1001, 50000):
        for p in (0.005, 0.025, 0.5, 0.975, 0.995):
            # exact up to 1000 dof, Wilson-Hilferty (documented error < 1e-5) above
            assert chi2_ppf(p, nu) == pytest.approx(stats.chi2.ppf(p, nu), rel=1e-6 if nu < 1000 else 1e-5)
    # white FM at m = 1: (3(N-1)/2 - 2(N-2)/N) 4/9 -> about 2n/3 for long records
    assert edf_overlapping(10000, 1, 0) == pytest.approx(2 * 10000 / 3, rel=1e-3)
    assert edf_overlapping(10000, 100, 0) > edf_overlapping(10000, 100, -1) > edf_overlapping(10000, 100, -2)


def test_interval_coverage_on_known_noise():
    """Over 20 recordings x 3 axes the 95 % intervals hold the truth about 95 % of the time:
    binomial(60, 0.95) falls below 51 with probability < 0.1 %."""
    N, B, K = 0.01, 0.004, 0.0
    hit = {"white_density": 0, "bias_instability": 0}
    for s in range(20):
        x = coloured(np.random.default_rng(100 + s), int(400 * FS), FS, N, B, K)
        for r in characterise(x, FS, "xyz"):
            for key, truth in (("white_density", N), ("bias_instability", B)):
                lo, hi = r[key + "_ci"]
                hit[key] += lo <= truth <= hi
    assert hit["white_density"] >= 51 and hit["bias_instability"] >= 51, hit


@pytest.mark.xfail(strict=True, reason="bias instability reads ~7 % low (4.6 standard errors) on "
                   "2000 s flicker records: not understood yet (reading-tau subtraction?)")
def test_bias_instability_is_unbiased_where_the_floor_is_resolved():
    """2000 s records fitted up to 50 s (the flicker floor dominates from 14 s; the generated
    flicker has no power below 1/2000 Hz, which lowers its Allan variance by 0.4 % at 50 s
    but by 7 % at the default limit of 200 s): the mean of 30 estimates lies within 3 of its
    standard errors of B."""
    N, B = 0.01, 0.004
    est = []
    for s in range(10):
        x = coloured(np.random.default_rng(300 + s), int(2000 * FS), FS, N, B, 0.0)
        est += [r["bias_instability"] for r in characterise(x, FS, "xyz", tau_max_s=50.0)]
    est = np.array(est)
    assert abs(est.mean() - B) < 3 * est.std(ddof=1) / np.sqrt(len(est)), (est.mean(), B)


def test_cli_recovers_simulated_noise_and_writes_kalibr_and_ros(tmp_path):
    """A 1000 s still recording: gyro N 0.01 deg/s/sqrt(Hz), B 0.004 deg/s; accel N 200 ug/sqrt(Hz),
    B 50 ug; the truth lies inside each reported 99 % interval."""
    n = int(1000 * FS)
    rng = np.random.default_rng(7)
    gyro = coloured(rng, n, FS, 0.01, 0.004, 0.0) + [0.5, -0.2, 0.1]
    acc = coloured(rng, n, FS, 200e-6, 50e-6, 0.0) + [0.0, 0.0, 1.0]
    rec = Recording(np.arange(n) / FS, acc=acc, gyro=gyro, meta={"board": "mpu6050", "rate_hz": "100"})
    path = tmp_path / "still.csv"
    write_recording(rec, str(path))
    out, kal = tmp_path / "noise.yaml", tmp_path / "imu.yaml"
    assert main(["noise", str(path), "-o", str(out), "--kalibr", str(kal), "--confidence", "0.99"]) == 0
    doc = yaml.safe_load(out.read_text())
    for sensor, u, N, B in (("gyro", "dps", 0.01, 0.004), ("accel", "g", 200e-6, 50e-6)):
        sec = doc[sensor]
        for i in range(3):
            lo, hi = sec[f"white_density_{u}_rthz_ci"][i]
            assert lo <= N <= hi, (sensor, i, lo, hi)
            lo, hi = sec[f"bias_instability_{u}_ci"][i]
            assert lo <= B <= hi, (sensor, i, lo, hi)
    k = yaml.safe_load(kal.read_text())
    assert set(k) == {"accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                      "gyroscope_random_walk", "update_rate", "rostopic"}
    assert k["update_rate"] == pytest.approx(FS)
    assert k["gyroscope_noise_density"] == pytest.approx(
        max(doc["gyro"]["white_density_dps_rthz"]) * math.pi / 180, rel=1e-5)
    assert k["accelerometer_noise_density"] == pytest.approx(
        max(doc["accel"]["white_density_g_rthz"]) * 9.80665, rel=1e-5)
    assert "m/s^2/sqrt(Hz)" in kal.read_text() and "rad/s^2/sqrt(Hz)" in kal.read_text()
    ros = doc["ros_sensor_msgs_imu"]
    cov = np.array(ros["angular_velocity_covariance"]).reshape(3, 3)
    # one sample's variance: (N sqrt(rate))^2 in (rad/s)^2, on the diagonal
    assert np.diag(cov) == pytest.approx((np.array(doc["gyro"]["white_density_dps_rthz"]) * math.pi / 180) ** 2 * FS)
    assert ros["orientation_covariance"][0] == -1
    fig = read_figures(str(out))
    assert fig["gyro"]["white"] == pytest.approx(doc["gyro"]["white_density_dps_rthz"])


def test_short_or_bad_input_is_one_line(tmp_path, capsys):
    rec = Recording(np.arange(500) / FS, acc=np.zeros((500, 3)) + 1e-3 * np.random.default_rng(0).standard_normal((500, 3)),
                    meta={"board": "mpu6050", "rate_hz": "100"})
    p = tmp_path / "short.csv"
    write_recording(rec, str(p))
    assert main(["noise", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "longer still stretch" in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: something\n")
    with pytest.raises(Exception, match="imucald-noise-1"):
        read_figures(str(bad))


def test_a_stuck_axis_is_one_line_not_zero_figures(tmp_path, capsys):
    """An axis that holds one value (a dead axis, a column mapped to nothing, or a noise
    below half an LSB) has no noise to read: one line naming it, exit 2, as calibrate and gap
    say.  Before, noise printed figures of 0 with numpy's divide-by-zero warnings.  Broken once:
    the stuck check skipped (fails)."""
    x = 1e-3 * np.random.default_rng(1).standard_normal((20000, 3))
    x[:, 1] = 0.25
    rec = Recording(np.arange(20000) / FS, acc=x, meta={"board": "mpu6050", "rate_hz": "100"})
    p = tmp_path / "stuck.csv"
    write_recording(rec, str(p))
    assert main(["noise", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "accel: column ay (always 0.25) holds one value" in err
    x[:, 1] = x[:, 0]
    write_recording(Recording(rec.t, acc=x, meta=rec.meta), str(p))
    assert main(["noise", str(p)]) == 0


def test_real_mpu6050_white_noise_is_a_property_of_the_sensor():
    """sunsided MPU-6050, same pose: the 10-minute and the 2-minute recordings give the same
    white densities (their 95 % intervals overlap on every axis; the noise does not depend on
    how long one records), near the per-sample spread of SOURCE.md (gyro 0.09-0.14 deg/s,
    acc 0.0030-0.0051 g at ~99 Hz)."""
    from imucald.fitting.inputs import load_input
    out = []
    for name in ("unmoved-with-x-pointing-forward-10min", "unmoved-with-x-pointing-forward"):
        p = real_path("sunsided_mpu6050_hmc5883l", name, "mpu6050.csv")
        _, rec = load_input(str(p), "t,ax,ay,az,gx,gy,gz,temp".split(","))
        rate = (len(rec.t) - 1) / (rec.t[-1] - rec.t[0])
        out.append([characterise(x, rate, "xyz") for x in (rec.acc, rec.gyro)])
    for s in range(2):
        for a in range(3):
            lo1, hi1 = out[0][s][a]["white_density_ci"]
            lo2, hi2 = out[1][s][a]["white_density_ci"]
            assert lo1 <= hi2 and lo2 <= hi1, (s, a, (lo1, hi1), (lo2, hi2))
            sigma = out[0][s][a]["white_density"] * math.sqrt(99.3)
            assert (0.0025 if s == 0 else 0.08) < sigma < (0.0055 if s == 0 else 0.15)


def test_a_board_that_moved_is_said_and_the_guides_still_board_is_still(tmp_path, capsys):
    """The noise guide's example (`record --emulate --poses 1`) lifted the board every pass of
    its one-pose tour (a move back to where it was), and `noise` read that motion as noise
    (white density 0, bias instability 5.6 mg) with no word (a newcomer's walk).  Now the
    one-pose tour holds still, its figures are the emulated chip's (the MPU-6050's 400
    ug/sqrt(Hz) resolved, a bias instability below 1 mg), and no warning is given; the same recording with
    two 2-s bumps of 0.3 g is said to have moved, twice, naming when.  Measured beside it:
    no warning on 21 emulated still recordings (3 boards x 7 seeds) nor on the real ones
    left still (sunsided's four, the FreeIMU warm-up); the old tour's 8 lifts in 120 s all
    named.  Broken once (the tour's move back put in again): fails (a warning, and figures);
    and once each for a cold review's mends below (the no-still-stretch line dropped, the
    leading move not looked for, --rate-hz passed to the ignored-options warning): fails."""
    from imucald.files.recording import read_recording
    still, moved = tmp_path / "still.csv", tmp_path / "moved.csv"
    assert main(["record", "-o", str(still), "--board", "mpu6050", "--emulate", "--poses", "1",
                 "--seconds", "60", "--seed", "4"]) == 0
    capsys.readouterr()
    assert main(["noise", str(still), "--json"]) == 0
    out = capsys.readouterr()
    assert "warning" not in out.err, out.err
    doc = json.loads(out.out)
    # the moving tour read "white density < [0, 0]" and a bias instability of 3.9-9.3 mg
    for lo, hi in doc["accel"]["white_density_g_rthz_ci"]:
        assert 300e-6 < lo < hi < 500e-6, (lo, hi)      # the datasheet's 400 ug/sqrt(Hz), resolved
    for lo, hi in doc["accel"]["bias_instability_g_ci"]:
        assert hi < 1e-3, (lo, hi)
    rec = read_recording(str(still))
    for t0 in (20.0, 40.0):
        k = (rec.t >= t0) & (rec.t < t0 + 2.0)
        rec.acc[k, 0] += 0.3 * np.sin(np.pi * (rec.t[k] - t0) / 2.0)
    write_recording(rec, str(moved))
    assert main(["noise", str(moved)]) == 0
    err = capsys.readouterr().err
    m = re.search(r"the board moved in the stretch \(2 time\(s\): ([\d.]+)-([\d.]+) s, ([\d.]+)-([\d.]+) s after", err)
    assert m, err
    a0, a1, b0, b1 = map(float, m.groups())      # each named within a second of the bump
    assert abs(a0 - 20) < 1 and abs(a1 - 22) < 1 and abs(b0 - 40) < 1 and abs(b1 - 42) < 1, err
    # a cold review (helper-89): a board moving throughout crashed (IndexError), and a move in
    # the first seconds (the hand leaving the board) went unsaid
    rec = read_recording(str(still))
    ang = np.radians(20.0) * np.sin(2 * np.pi * 0.3 * rec.t)
    g = float(np.linalg.norm(rec.acc.mean(0)))
    rec.acc = np.column_stack([np.sin(ang), np.zeros_like(ang), np.cos(ang)]) * g + (rec.acc - rec.acc.mean(0))
    write_recording(rec, str(moved))
    assert main(["noise", str(moved)]) == 0
    err = capsys.readouterr().err
    assert "no still stretch in samples 0..5999 by calibrate's detector" in err and "Traceback" not in err, err
    rec = read_recording(str(still))
    k = (rec.t >= 0.5) & (rec.t < 2.5)
    rec.acc[k, 0] += 0.3 * np.sin(np.pi * (rec.t[k] - 0.5) / 2.0)
    write_recording(rec, str(moved))
    assert main(["noise", str(moved), "--rate-hz", "100"]) == 0
    err = capsys.readouterr().err
    assert "the board moved in the stretch (1 time(s): 0.0-" in err, err
    assert "ignored" not in err, err              # noise applies --rate-hz to a recording too
