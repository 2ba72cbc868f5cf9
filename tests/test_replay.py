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
    # orientation off: the golden stream must not depend on whether the orientation extra
    # is installed (tests/test_orientation.py covers the orientation fields)
    lines, err = _replay(rec, "--min-poses", "12", "--orientation", "no")
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


def test_a_provisional_calibration_is_refitted_when_the_poses_needed_are_reached(tmp_path):
    """14 poses with --min-poses 12: the provisional calibration of the 10th pose is refitted at
    the 12th, where the log says the poses needed are reached (a user may stop there), not at
    the next 5-pose mark (the 15th, which this file never reaches: it stayed provisional), and
    the end of the replay says how many poses the calibration in force was fitted on.  Seen to
    fail with the pipeline's refit at readiness (Pipeline._just_ready) removed: #1 stays in
    force, "fitted on 10 of the 14"."""
    rec = tmp_path / "g.csv"
    assert main(["simulate", "-o", str(rec), "--board", "mpu6050", "--poses", "14", "--hold", "4",
                 "--move", "2", "--rate", "50", "--seed", "7"]) == 0
    _, err = _replay(rec, "--min-poses", "12", "--orientation", "no")
    log = err.splitlines()
    at12 = next(i for i, l in enumerate(log) if "pose 12/12" in l)
    at13 = next(i for i, l in enumerate(log) if "pose 13 " in l)
    assert any("calibration #2 applied:" in l for l in log[at12:at13]), log[at12:at13]
    assert "calibration #2 is in force, its accelerometer part fitted on 12 of the 14 still poses" in log[-1]


def test_the_refit_at_the_poses_needed_runs_once(tmp_path):
    """A pose set that reaches the poses needed (12) but never the uncertainty target (set far
    below reach) keeps getting provisional calibrations: the fit at the 12th pose runs once,
    then the 5-pose mark resumes (12, 17, 22, 27), and no fit runs on poses its predecessor
    was fitted on.  Keyed on the calibration in force (a cold review found), each new
    provisional id re-armed it: 9 fits instead of 5, four with "nothing to score it on out of
    sample".  Seen to fail with Pipeline._ready_tried never set: fits at 12, 12, 13, 13, 14..."""
    rec, cfg = tmp_path / "g.csv", tmp_path / "c.yaml"
    cfg.write_text("calibration:\n  target_bias_g: 0.000001\n  target_scale: 0.000001\n")
    assert main(["simulate", "-o", str(rec), "--board", "mpu6050", "--poses", "30", "--hold", "4",
                 "--move", "2", "--rate", "50", "--seed", "7"]) == 0
    _, err = _replay(rec, "--config", str(cfg), "--min-poses", "12", "--orientation", "no")
    fits = [l.split(" on ")[1].split()[0] for l in err.splitlines() if "calibrating in the background" in l]
    assert fits == ["10", "12", "17", "22", "27"], fits
    assert "nothing to score it on out of sample" not in err


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


def test_replay_of_ten_hand_poses_applies_a_provisional_calibration_at_the_tenth(tmp_path):
    """Ten poses, the fewest the 9-parameter fit and its leave-one-pose-out scoring
    need: the first calibration beats the raw readings significantly and is applied as
    provisional, naming the orientations still missing; no held-out figure is NaN."""
    rec, truth = tmp_path / "h.csv", tmp_path / "t.json"
    assert main(["simulate", "-o", str(rec), "--poses", "10", "--hold", "6", "--seed", "4",
                 "--truth", str(truth)]) == 0
    lines, err = _replay(rec, "--log-level", "info", "--state-dir", str(tmp_path / "st"))
    log = err.splitlines()
    i10 = next(i for i, l in enumerate(log) if "pose 10/25" in l)
    applied = [i for i, l in enumerate(log) if "calibration #1 applied as provisional" in l]
    assert applied and applied[0] > i10, err
    assert "missing orientations: " in log[applied[0]] and "p = " in log[applied[0]]
    assert "nan" not in err.lower()
    cal = [json.loads(l) for l in lines if '"CAL"' in l]
    assert cal[0]["applied"] and cal[0]["provisional"] is True
    doc = yaml.safe_load(open(tmp_path / "st" / "calibration.yaml"))
    assert doc["provisional"]["poses"] == 10 and doc["provisional"]["missing_orientations"]
    q = doc["accel"]["quality"]
    assert q["poses"] == 10 and q["gate_p_value"] <= q["false_accept_rate"] == 0.05
    assert q["heldout_rms_g"] < q["heldout_rms_before_g"]
    # the applied parameters are the fit on all ten poses: bias within 3 reported std
    tr = json.load(open(truth))
    b, sb = np.array(doc["accel"]["params"]["bias_g"]), np.array(doc["accel"]["stderr"]["bias_g"])
    assert np.all(np.abs(b - np.array(tr["accel_triangular9"][6:9])) < 3 * sb), (b, sb, tr)


def test_recalibrate_refuses_up_front_with_the_poses_needed_and_status_says_provisional(tmp_path):
    from imucald.daemon.config import validate
    from imucald.daemon.pipeline import Pipeline
    from imucald.daemon.run import Daemon
    from imucald.drivers.board import SampleBatch
    from imucald.files.recording import read_recording
    rec = tmp_path / "h.csv"
    assert main(["simulate", "-o", str(rec), "--poses", "10", "--hold", "6", "--seed", "4"]) == 0
    r = read_recording(str(rec))
    pipe = Pipeline(validate({"calibration": {"method": "lm"}}), "mpu6050", r.rate_hz, False)
    d = object.__new__(Daemon)          # the control handler alone, on this pipeline
    d.pipe = pipe
    seq = np.arange(len(r))
    end7 = None
    for i in range(0, len(r), 10):
        sl = slice(i, i + 10)
        pipe.process(SampleBatch(r.t[sl], seq[sl], r.acc[sl], r.gyro[sl], r.temp[sl], None, None))
        if len(pipe.acc) == 7 and end7 is None:
            end7 = d._command("recalibrate")
    assert end7["class"] == "ERROR" and end7["message"].startswith("only 7 poses:") and \
        "at least 10" in end7["message"] and "3 more orientations" in end7["message"]
    pipe.end_of_stream()
    s = pipe.status()
    assert s["calibration_id"] == 1 and s["calibration_provisional"] is True
    assert s["missing_orientations"] == pipe.acc.coverage()["missing"]


def test_replay_starts_from_the_calibration_in_the_state_dir(tmp_path, capsys):
    """replay --state-dir D starts from D/calibration.yaml, as the daemon does: a gyro file
    from calibrate --sensor gyro keeps its K and G through the replay's calibrations (it was
    overwritten by a bias-only id 1), and the file it started from goes to D/history, not
    lost; a file for another board is refused in one line and left as it is.  Broken once:
    the start's copy to history removed (fails)."""
    from imucald.calibration import load
    rec, d = tmp_path / "r.csv", tmp_path / "st"
    d.mkdir()
    assert main(["simulate", "-o", str(rec), "--board", "mpu6050", "--poses", "24", "--hold", "6",
                 "--seed", "5"]) == 0
    assert main(["calibrate", str(rec), "--sensor", "gyro", "-o", str(d / "calibration.yaml")]) == 0
    before, original = load(d / "calibration.yaml"), (d / "calibration.yaml").read_bytes()
    assert "matrix" in before.gyro.params and "g_sens_dps_per_g" in before.gyro.params
    capsys.readouterr()
    assert main(["replay", str(rec), "--state-dir", str(d)]) == 0
    after = load(d / "calibration.yaml")
    assert after.id > before.id and after.accel is not None
    for k in ("matrix", "g_sens_dps_per_g"):
        assert np.array_equal(after.gyro.params[k], before.gyro.params[k]), k
    # the file it started from is not lost: it was overwritten (a new user's walk-through),
    # and kept under a name the history's trimming by id never removes (a cold review)
    kept = list((d / "history").iterdir())
    assert [f.name[:9] for f in kept] == ["replaced-"] and kept[0].read_bytes() == original
    text = (d / "calibration.yaml").read_text().replace("board: mpu6050", "board: 9dof")
    (d / "calibration.yaml").write_text(text)
    capsys.readouterr()
    assert main(["replay", str(rec), "--state-dir", str(d)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(d / "calibration.yaml") in err and "9dof" in err, err
    assert (d / "calibration.yaml").read_text() == text


def _as_logger_table(rec_path, out_path):
    """The recording as a logger writes it: counts (16384 per g, 131 per deg/s), the time in
    milliseconds, a header line, the time column last."""
    from imucald.files.recording import read_recording
    r = read_recording(rec_path)
    rows = np.column_stack([r.acc * 16384, r.gyro * 131, r.temp, r.t * 1000])
    with open(out_path, "w") as fh:
        fh.write("ax,ay,az,gx,gy,gz,temp,millis\n")
        fh.writelines(",".join(repr(float(v)) for v in row) + "\n" for row in rows)
    return r


RAW = ["--columns", "ax,ay,az,gx,gy,gz,temp,t_ms", "--nominal-scale", "accel=16384,gyro=131"]


def test_replay_and_apply_read_a_raw_logger_table(tmp_path, capsys):
    """A logger's table (counts, milliseconds) is replayed and corrected as the recording it
    holds: replay streams every row with the same samples as the recording's replay until a
    calibration is applied, and reaches one; apply writes the same corrected samples.
    (Before, both read imucald recordings only: a user had to convert the file first.)  Broken
    once each: the table reader dropping a row per chunk, and every file read as a table
    (the recording-with---columns case): each fails."""
    rec, tab = tmp_path / "r.csv", tmp_path / "logger.csv"
    assert main(["simulate", "-o", str(rec), "--board", "mpu6050", "--poses", "14", "--hold", "4",
                 "--move", "2", "--rate", "50", "--seed", "7"]) == 0
    r = _as_logger_table(rec, tab)
    a, _ = _replay(rec, "--min-poses", "12", "--orientation", "no")
    b, _ = _replay(tab, "--min-poses", "12", "--orientation", "no", *RAW)
    ia = [json.loads(l) for l in a if '"IMU"' in l]
    ib = [json.loads(l) for l in b if '"IMU"' in l]
    assert len(ib) == len(ia) == len(r)
    raw = [(x, y) for x, y in zip(ia, ib) if x["cal"] == 0 and y["cal"] == 0]
    assert len(raw) > len(r) // 2
    for x, y in raw:            # the stream prints 6 digits: one unit in the last place
        _close({k: x[k] for k in ("seq", "t", "acc_g", "gyro_dps", "temp_c")},
               {k: y[k] for k in ("seq", "t", "acc_g", "gyro_dps", "temp_c")})
    assert any('"CAL"' in l for l in b)
    cal = tmp_path / "cal.yaml"
    assert main(["calibrate", str(rec), "--sensor", "all", "-o", str(cal)]) == 0
    assert main(["apply", str(cal), str(rec), "-o", str(tmp_path / "a.csv")]) == 0
    assert main(["apply", str(cal), str(tab), "-o", str(tmp_path / "b.csv"), *RAW]) == 0
    from imucald.files.recording import read_recording
    ca, cb = read_recording(tmp_path / "a.csv"), read_recording(tmp_path / "b.csv")
    assert np.allclose(ca.acc, cb.acc, rtol=0, atol=1e-9) and np.allclose(ca.gyro, cb.gyro, rtol=0, atol=1e-9)
    assert np.allclose(ca.t, cb.t, rtol=0, atol=1e-9)
    # the counts without their scale: said (it wrote 16000-g samples in silence)
    assert main(["apply", str(cal), str(tab), "-o", str(tmp_path / "d.csv"), *RAW[:2]]) == 0
    assert "median |a| of 1.6" in capsys.readouterr().err
    # an imucald recording is read as one whatever --columns says (its header names its board,
    # which apply checks): the same output as without the options
    assert main(["apply", str(cal), str(rec), "-o", str(tmp_path / "c.csv"), *RAW]) == 0
    cc = read_recording(tmp_path / "c.csv")
    assert np.array_equal(cc.acc, ca.acc) and cc.meta["board"] == "mpu6050"


FREEIMU_ARGS = ("--orientation", "no", "--columns", "ax,ay,az,gx,gy,gz,-,-,-,-,temp,-,t_ms",
                "--nominal-scale", "accel=16384,gyro=16.4")


def _pose_lines(err):
    return [l for l in err.splitlines() if l.startswith("imucald: pose ")]


def test_a_warm_up_resting_in_one_placement_is_one_pose():
    """The real FreeIMU warm-up (one placement for 18 min, 10 -> 29 degC, ms timestamps,
    counts): the detector cuts the rest every 20 s and the pose means drift with the
    temperature, far beyond their noise.  The daemon counted each piece a new pose (25 in one
    orientation, 'pose 20/25') and ran 46 background fits on them; calibrate joins the pieces
    into one pose.  Now a piece that continues the same still run refines the pose before it
    (without a log line each 20 s): one pose, and no fit started.  Broken once: the
    accumulator's same-run rule removed (pose 2/25 new: fails)."""
    from .conftest import real_path
    f = real_path("freeimu_mpu6050_tempsweep", "Tempdata01-02-14.csv")
    _, err = _replay(f, *FREEIMU_ARGS, "--log-level", "debug")
    poses = _pose_lines(err)
    assert len(poses) == 1 and poses[0].startswith("imucald: pose 1/25 (new, "), poses[:3]
    assert err.count("the rest goes on: its pose refined by ") > 40
    assert "calibrating" not in err


def test_a_warm_up_set_down_again_in_one_orientation_applies_no_accelerometer_part(tmp_path):
    """The same warm-up with the board lifted (a 1-s, 30-degree tilt with a turn) and set down
    again in the same orientation about every 50 s, written into a copy: each new still run's
    mean has drifted with the temperature beyond its noise, so the daemon keeps it as a pose of
    its own (a few degrees of tilt carry information) and fits on them.  The accelerometer fit
    on one orientation determines none of its 9 parameters (all held at the datasheet prior)
    yet scored 'better' on held-out poses from that same orientation, and was applied.  Such a
    part is not applied and the log says why; the gyro bias still is.  Broken once: the guard
    removed (an accelerometer part applied: fails)."""
    from .conftest import real_path
    src = real_path("freeimu_mpu6050_tempsweep", "Tempdata01-02-14.csv")
    lines = src.read_text().splitlines()
    rows = [l.split(",") for l in lines[1:]]
    for k in range(1500, len(rows) - 60, 3000):
        for r in rows[k:k + 60]:                      # lifted: tilted 30 deg about y, turning
            r[0], r[2], r[4] = "8192", "14189", "1500"
    f = tmp_path / "bumped.csv"
    f.write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    _, err = _replay(f, *FREEIMU_ARGS)
    assert sum("(new," in l for l in _pose_lines(err)) >= 10, err[-500:]
    heads = [l for l in err.splitlines() if l.startswith("imucald: calibration #") and " applied" in l]
    assert heads, err[-500:]
    assert all("(gyro part; accel not applied)" in h for h in heads), heads[:2]
    assert "accel not applied: the poses determine none of its parameters" in err


def _revisits(tmp_path):
    """12 orientations, the same 12 again, then 2 new ones (MPU-6050, 50 Hz, 3.5-4.5 s holds)."""
    from imucald.files.recording import write_recording
    from imucald.sim.orientations import random_pose_set
    from imucald.sim.sensor import simulate_session
    g = np.random.default_rng(3)
    R = random_pose_set(12, g)
    s = simulate_session("mpu6050", np.concatenate([R, R, random_pose_set(2, g)]), g, rate_hz=50,
                         hold_s=(3.5, 4.5), move_s=(1.5, 2.5))
    rec = tmp_path / "revisits.csv"
    write_recording(s.recording, rec)
    return rec


def test_revisited_orientations_start_no_refit_until_a_new_one(tmp_path):
    """A tour of 12 orientations, then the same 12 again (each revisit refines a pose and
    adds none), then 2 new ones, with --min-poses 12: once the calibration in force was
    fitted on all 12, the revisits start no fit (the gate could score none: "no pose the
    current one was not fitted on"), the log says why once, and the first new orientation
    starts one.  Seen to fail with Pipeline._nothing_to_score always False: two fits on the
    revisits, both "not applied", and no such line."""
    rec = _revisits(tmp_path)
    _, err = _replay(rec, "--min-poses", "12", "--orientation", "no")
    log = [l for l in err.splitlines() if l.startswith("imucald: ")]
    first_revisit = next(i for i, l in enumerate(log) if "(refined" in l)
    first_new = next(i for i, l in enumerate(log) if "pose 13 " in l)
    fits_on_revisits = [l for l in log[first_revisit:first_new] if "calibrating in the background" in l]
    said = [l for l in log if l.startswith("imucald: no refit: all 12 poses")]
    assert fits_on_revisits == [] and len(said) == 1, (fits_on_revisits, said)
    assert "calibrating in the background on 13 poses" in log[first_new + 1], log[first_new:first_new + 3]
    assert "nothing to score it on out of sample" not in err


def test_a_replay_that_reaches_no_calibration_says_why(tmp_path):
    """Three poses, no --state-dir: the replay's last line says no calibration was reached and
    why (the poses a first one needs).  Seen to fail with the reason said only under
    --state-dir (service.py before): the file ended on its last pose line, without a word."""
    rec = tmp_path / "g.csv"
    assert main(["simulate", "-o", str(rec), "--board", "mpu6050", "--poses", "3", "--hold", "4",
                 "--move", "2", "--rate", "50", "--seed", "7"]) == 0
    _, err = _replay(rec, "--orientation", "no")
    assert err.splitlines()[-1] == ("imucald: no calibration was reached (3 still poses; a first "
                                    "calibration needs 10 in different orientations)"), err


def test_revisits_still_refit_while_no_gyro_part_is_in_force(tmp_path, capsys, caplog, monkeypatch):
    """The same tour, with the gyro gate refusing the first two fits' gyro part (as when the
    bias is not yet clear of the scatter between poses): the calibration in force has no
    gyro part, whose gate scores against the raw readings on every pose, so revisits still
    start fits and one applies the gyro bias before any new orientation; only then are
    they held back (a cold review found them held back at once: the gyro bias waited for a
    new orientation).  Seen to fail with Pipeline._nothing_to_score's gyro exception
    removed: "no refit" right after the accelerometer's fit, no gyro bias applied."""
    import dataclasses

    import imucald.daemon.fitjob as fitjob
    orig, calls = fitjob.gate_gyro_bias, [0]

    def refuse_twice(*a, **k):
        bias, dec = orig(*a, **k)
        calls[0] += 1
        return bias, (dataclasses.replace(dec, accept=False) if calls[0] <= 2 else dec)

    monkeypatch.setattr(fitjob, "gate_gyro_bias", refuse_twice)
    import logging
    rec = _revisits(tmp_path)
    caplog.set_level(logging.INFO, logger="imucald")
    assert main(["replay", str(rec), "--min-poses", "12", "--orientation", "no"]) == 0
    capsys.readouterr()                                  # the stream
    log = caplog.messages
    first_new = next(i for i, l in enumerate(log) if "pose 13 " in l)
    gyro = [i for i, l in enumerate(log[:first_new]) if "gyro bias applied" in l]
    held = [i for i, l in enumerate(log[:first_new]) if l.startswith("no refit")]
    assert gyro and all(i > gyro[0] for i in held), log           # then no refit: nothing new
