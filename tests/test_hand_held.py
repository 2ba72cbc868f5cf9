"""Issue 9's acceptance on hand-held sessions: short holds (1.5-3 s) with hand tremor
(1.5 deg/s RMS per gyro axis, the accelerometer at 1.3-3x its floor), in the simulator and
on the emulated board.  `calibrate` finds every pose and lands within 3 reported standard
errors of the truth; a parameter these poses cannot determine is flagged and stays within
its datasheet prior; `replay` applies a first (provisional) calibration after the 10th
pose and names what it could not determine."""
import json

import numpy as np

from imucald.cli import main
from imucald.drivers.board import make_board
from imucald.drivers.bus import Bus, VirtualClock
from imucald.files.recording import Recording, write_recording
from imucald.sim.emulators import emulated_board
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import random_pose_set, rotation_from_up
from imucald.sim.sensor import draw_truth, simulate_session

from .test_replay import _replay

_C = np.cos(np.radians(45))
#: ten hand-placed orientations: the six faces and four 45-degree tilts; no pose has large
#: y and z components of opposite sign... and none tilts x against y: alpha_yz is left to
#: the prior (the real MPU-6050 log of issue 9 has the same gap)
HAND = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
                 [_C, 0, _C], [-_C, 0, _C], [0, _C, _C], [0, -_C, -_C]], float)
NAMES = ["alpha_yz", "alpha_zy", "alpha_zx", "scale_x", "scale_y", "scale_z",
         "bias_x_g", "bias_y_g", "bias_z_g"]
TREMOR_DPS = 1.5


def _hand_rotations(rng):
    ups = HAND + rng.normal(scale=np.radians(1.0), size=HAND.shape)   # hands are not exact
    return np.array([rotation_from_up(u, rng.uniform(0, 2 * np.pi)) for u in ups])


def _hand_recording(tmp_path, seed):
    """A simulated 10-pose hand-held session (1.5-3 s holds, tremor) written to a file."""
    rng = np.random.default_rng(seed)
    truth = draw_truth("mpu6050", rng)
    s = simulate_session("mpu6050", _hand_rotations(rng), rng, hold_s=(1.5, 3.0),
                         move_s=(1.5, 3.0), lead_s=0.0, tremor_dps=TREMOR_DPS, truth=truth)
    path = tmp_path / "hand.csv"
    write_recording(s.recording, str(path))
    return path, truth


def _calibrate_json(path, capsys):
    assert main(["calibrate", str(path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _check_against_truth(d, truth9):
    """Every determined parameter within 3 reported standard errors of the truth; a
    flagged one within 3 of its prior's standard deviations of the prior mean (0 for the
    non-orthogonality angles) and within 3 posterior std of the truth.

    The standard errors are bounded too (issue 20): a determined parameter's own part (the
    stated one less the terms left out, ``left_out_std``) is at most
    1.2x its data-only Cramer-Rao bound (the prior can only narrow it; 1.2: the bound is
    evaluated at the estimate, the error at the MAP re-polish) and a tenth of its prior's
    (the poses, not the datasheet, determine it); and the fit beats the nominal values:
    the RMS of (estimate - truth) / prior std over the determined parameters is under a
    fifth of the nominal's (the nominal's is ~0.5: truths are drawn N(0, tol/2); the fit's
    ~SE / prior std ~ 0.01).  Seen to catch: a fit returning the datasheet prior (nominal
    values, the tolerances as standard errors) passed the 3-SE check; it fails both bounds."""
    theta = np.concatenate([d["params"][g] for g in ("alpha", "scale", "bias_g")])
    se = np.concatenate([d["stderr"][g] for g in ("alpha", "scale", "bias_g")])
    flagged = {f["name"] for f in d["flags"]}
    nominal = np.array([0, 0, 0, 1, 1, 1, 0, 0, 0], float)
    err_fit, err_nom = [], []
    for i, n in enumerate(NAMES):
        assert abs(theta[i] - truth9[i]) < 3 * se[i], (n, theta[i], truth9[i], se[i])
        prior_sd = d["determination"][n]["prior_std"]
        if n in flagged:
            centre = 1.0 if n.startswith("scale") else 0.0
            assert abs(theta[i] - centre) < 3 * prior_sd, (n, theta[i], prior_sd)
        else:
            # the bound is on the fit's own part: the sessions warm up by 6 degC (the
            # simulator's default), and the bias's temperature slope the constant leaves out
            # is part of the stated std (left_out_std; docs/methods/models.md)
            crlb, left = d["crlb_std"][n], d["determination"][n].get("left_out_std") or 0.0
            own = np.sqrt(max(se[i] ** 2 - left ** 2, 0.0))
            assert own <= 1.2 * crlb and se[i] <= prior_sd / 10, (n, se[i], left, crlb, prior_sd)
            err_fit.append((theta[i] - truth9[i]) / prior_sd)
            err_nom.append((nominal[i] - truth9[i]) / prior_sd)
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))
    assert rms(err_fit) < 0.2 * rms(err_nom), (rms(err_fit), rms(err_nom))
    return flagged


def _hand_session_fails(tmp_path, capsys, seed):
    """Why the hand-held session ``seed`` fails this file's per-session checks ('' if it
    passes): ten poses found, _check_against_truth, alpha_yz flagged, bias_x_g not."""
    path, truth = _hand_recording(tmp_path, seed)
    d = _calibrate_json(path, capsys)
    if d["poses"] != 10:
        return f"{d['poses']} poses found"
    try:
        flagged = _check_against_truth(d, truth.accel)
    except AssertionError as e:
        return "against the truth: " + str(e).splitlines()[0]
    if "alpha_yz" not in flagged:                      # nothing tilts y against z here
        return "alpha_yz not flagged"
    if "bias_x_g" in flagged:
        return "bias_x_g flagged"
    return ""


#: the rule below: of the hand-held sessions with these seeds, at least HAND_MIN_PASS pass
HAND_SEEDS = range(1, 25)
HAND_MIN_PASS = 13


def test_calibrate_finds_every_hand_held_pose_with_tremor(tmp_path, capsys):
    """A stated-rate rule, not one fixed seed (whose pass was the draw's: the one trajectory
    generator of issue 24 turned seed 2 from pass to fail).  Per session the checks of
    _hand_session_fails pass at a measured rate of 146/200 (73.0 %, 95 % interval 66-79 %;
    seeds 1-200, this generator; 141/200 when the rule was set, 145/200 before the bias's
    temperature slope joined the stated std).  The failures are the sessions', not a fault:
    in 52/200 the hands' 1-degree jitter gives alpha_yz a posterior std under half its
    prior's, so calibrate (fitting/judging/uncertainty.py UNDETERMINED_RATIO) calls it
    determined, while its standard error stays above the tenth of the prior this file
    requires of a determined parameter; 2/200 find 8 or 9 of the 10 poses.
    Rule: at least 13 of the 24 sessions (seeds 1-24) pass.  Binomial: P(the rule passes |
    sessions pass at 73 %) = 0.986 (0.927 at the interval's lower end), P(passes | the rate
    halves to 36.5 %) = 0.059.  With the seeds fixed the outcome is fixed (20/24 pass now); the
    figures are the odds that a change of the simulator (new draws) leaves it passing.
    Seen to fail, 0 of 24 passing: the fit returning its starting point (fitting/fit.py _solve
    with theta = the prior mean: every session fails the 3-SE check)."""
    fails = {s: _hand_session_fails(tmp_path, capsys, s) for s in HAND_SEEDS}
    failed = {s: why for s, why in fails.items() if why}
    assert len(HAND_SEEDS) - len(failed) >= HAND_MIN_PASS, failed


def _emulated_tour_fails(tmp_path, capsys, seed):
    """Why the emulated tremor tour ``seed`` fails the per-session checks ('' if it passes)."""
    rng = np.random.default_rng(seed)
    tour = PoseTour(random_pose_set(10, rng), rng=rng, hold_s=(1.5, 3.0), move_s=(1.5, 3.0),
                    lead_s=1.0, tremor_dps=TREMOR_DPS)
    clock = VirtualClock()
    eb = emulated_board("mpu6050", tour, rng=rng, clock=clock)
    board = make_board("mpu6050", Bus(eb, "emulated", clock=clock), rate_hz=100.0)
    board.start()
    parts = []
    while not parts or parts[-1].t.size == 0 or parts[-1].t[-1] < tour.duration_s:
        b = board.read_batch()
        if len(b):
            parts.append(b)
    cat = lambda k: np.concatenate([getattr(p, k) for p in parts])
    keep = cat("t") < tour.duration_s
    rec = Recording(t=cat("t")[keep], acc=cat("acc")[keep], gyro=cat("gyro")[keep],
                    temp=cat("temp")[keep], meta={"board": "mpu6050", "rate_hz": "100"})
    still_gyro = np.concatenate([rec.gyro[(rec.t > h0 + 0.3) & (rec.t < h1 - 0.3)] for h0, h1 in tour.holds()])
    assert np.median(still_gyro.std(0)) > 0.8 * TREMOR_DPS      # the tremor is really there
    path = tmp_path / f"emu{seed}.csv"
    write_recording(rec, str(path))
    d = _calibrate_json(path, capsys)
    if d["poses"] != 10:
        return f"{d['poses']} poses found"
    try:
        _check_against_truth(d, eb.truth.accel)
    except AssertionError as e:
        return "against the truth: " + str(e).splitlines()[0]
    return ""


def test_calibrate_on_the_emulated_boards_tremor_tour(tmp_path, capsys):
    """The emulated MPU-6050 read through its driver while a trembling hand carries it
    through ten well-spread orientations with 1.5-3 s holds.  Per tour the checks pass on
    38/40 (seeds 0-39; the two misses: one parameter beyond 3 SE, as 9 parameters at 3 SE
    give ~2.4 %).  Rule: at least 2 of the tours of seeds 7-9 pass: P = 0.993 at 95 %;
    0 of 3 pass when the fit returns its starting point (fitting/fit.py _solve, theta = the
    prior mean), the breakage _check_against_truth names."""
    fails = {s: _emulated_tour_fails(tmp_path, capsys, s) for s in (7, 8, 9)}
    assert sum(not why for why in fails.values()) >= 2, fails


def test_replay_of_a_hand_held_session_applies_a_provisional_calibration_naming_the_undetermined(
        tmp_path, capsys):
    """Run on the first hand-held session (seeds 1, 2, ...) whose jitter leaves alpha_yz
    undetermined and nothing else flagged (74.5 % of sessions, seeds 1-200: the first of ten
    is one but for 0.255**10 ~ 1e-6), not on a fixed seed: which sessions these are is the
    trajectory generator's draw (seed 1 is one now)."""
    for seed in range(1, 11):
        rec, _ = _hand_recording(tmp_path, seed)
        d = _calibrate_json(rec, capsys)
        if {f["name"]: f["reason"] for f in d["flags"]} == {"alpha_yz": "undetermined"}:
            break
    assert {f["name"]: f["reason"] for f in d["flags"]} == {"alpha_yz": "undetermined"}
    lines, err = _replay(rec, "--log-level", "info", "--state-dir", str(tmp_path / "st"))
    log = err.splitlines()
    i10 = next(i for i, l in enumerate(log) if "pose 10/" in l)
    applied = [i for i, l in enumerate(log) if "calibration #1 applied as provisional" in l]
    assert applied and applied[0] > i10, err
    assert "alpha_yz (undetermined)" in log[applied[0]], log[applied[0]]
    cal = [json.loads(l) for l in lines if '"CAL"' in l]
    assert cal[0]["applied"] and cal[0]["provisional"] is True
    assert cal[0]["undetermined"].get("alpha_yz") == "undetermined"
    assert cal[0]["missing_orientations"]


def test_a_ready_fit_that_only_improves_the_gyro_still_confirms_the_provisional_accel():
    """The job on a ready pose set does no significantly better for the accelerometer but
    does for the gyro bias: the gyro is applied and the provisional accelerometer part is
    confirmed as final at the same time (it stayed provisional for ever before)."""
    from imucald.fitting.gate import Decision
    from imucald.calibration import Calibration, SensorCal
    from imucald.daemon.fitjob import JobResult
    from imucald.daemon.config import load_config
    from imucald.daemon.pipeline import Pipeline
    from imucald.fitting.stillness.poses import PoseSet
    pipe = Pipeline(load_config(None), "mpu6050", 100.0, has_mag=False, chips={"accel": "mpu6050"})
    pipe.persist = lambda *a: None
    theta = np.array([0, 0, 0, 1, 1, 1, 0.01, 0, 0], float)
    prov = {"poses": 10, "poses_for_final": 25, "missing_orientations": ["-Z up"]}
    pipe.applied = Calibration("mpu6050", {"accel": "mpu6050"}, id=1, provisional=prov,
                               accel=SensorCal.accel("triangular9", theta))
    cand = Calibration("mpu6050", {"accel": "mpu6050"}, accel=SensorCal.accel("triangular9", theta),
                       gyro=SensorCal("gyro", "bias", {"bias_dps": np.array([0.1, 0.2, 0.3])}))
    gates = {"accel": Decision(False, 0.6, 0.05, 26, 3e-4, 3.1e-4, "current"),
             "gyro": Decision(True, 0.01, 0.05, 26, 0.01, 0.2, "current")}
    res = JobResult(cand, {"accel": False, "gyro": True}, 0.1, {"gate": gates})
    empty = PoseSet(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, int), np.zeros(0), np.zeros(0),
                    np.zeros((0, 3, 3)))
    pipe._job_ready = True
    line = pipe._apply(res, empty)
    assert pipe.applied.id == 2 and pipe.applied.gyro is not None
    assert pipe.applied.provisional is None
    cal = json.loads(line)
    assert cal["applied"] and cal["provisional"] is False
    pipe._job_ready = False                      # a pose set short of the targets: stays provisional
    pipe.applied = pipe.applied.replace(provisional=prov)
    pipe._apply(res, empty)
    assert pipe.applied.provisional == prov


def test_nine_hand_held_poses_calibrate_with_a_model_they_determine(tmp_path, capsys):
    """Issue 20: 9 hand-held poses.  `--model auto` returns a calibration with its held-out
    error and the model it chose (the 9- and 12-parameter candidates fitted with their
    undetermined terms held at the prior, and said); an explicit smaller model (diag6) is
    not refused for triangular9's pose count; explicit triangular9 is refused in one line
    naming the way out.  Seen to catch: the old refusal ('the 9-parameter model needs at
    least 10') applied to every model made all three exit 2.  (One seed: these checks
    passed on 40/40 sessions, seeds 0-39, so the draw does not decide.)"""
    rng = np.random.default_rng(9)
    truth = draw_truth("mpu6050", rng)
    s = simulate_session("mpu6050", _hand_rotations(rng)[:9], rng, hold_s=(1.5, 3.0),
                         move_s=(1.5, 3.0), lead_s=0.0, tremor_dps=TREMOR_DPS, truth=truth)
    path = tmp_path / "nine.csv"
    write_recording(s.recording, str(path))
    assert main(["calibrate", str(path), "--json", "--method", "lm", "--model", "auto"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["poses"] == 9 and d["heldout_rms_g"] > 0
    ms = d["model_selection"]
    assert ms["chosen"] == d["model"] and "diag6" in ms["heldout_rms_g"]
    assert ms["held_at_prior"] == ["full12", "triangular9"]
    assert main(["calibrate", str(path), "--json", "--method", "lm", "--model", "diag6"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == "diag6"
    assert main(["calibrate", str(path), "--method", "lm", "--model", "triangular9"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--model auto" in err, err


def test_tremor_does_not_widen_the_standard_errors(tmp_path, capsys):
    """The same 12 poses (10 s holds) calibrated without and with hand tremor (3 deg/s):
    tremor averages out of a pose mean, so the reported standard errors of the scales and
    biases are the sensor noise's in both.  Per session the median ratio (tremor / none)
    is within 0.75-1.35 on 91/100 sessions (seeds 0-99; the poses' estimated covariances
    scatter by ~10 %); the other 9 are at 1.60-2.14 (5) and 0.44-0.72 (4), not
    investigated here; they made one fixed seed a 90 % coin flip.  Rule: the median over the six sessions of seeds 0-5 of that ratio is
    within 0.75-1.35; it leaves the band only if 3 of the 6 do: P ~ 0.012 at the measured
    9 %.  Seen to fail with the pose covariance as the per-sample variance over n
    (fitting/stillness/poses.py _structure returning the set unscaled): median 2.58, every
    session at 2.5-2.8; and z-scores against the truth with RMS 0.48 (bench/calib_se.py)."""
    def stderr(seed, tremor):
        rng = np.random.default_rng(seed)
        truth = draw_truth("mpu6050", rng)
        rots = random_pose_set(12, rng)
        s = simulate_session("mpu6050", rots, np.random.default_rng(seed + 100), hold_s=10.0,
                             move_s=(1.5, 3.0), lead_s=0.0, tremor_dps=tremor, truth=truth)
        path = tmp_path / f"t{seed}_{tremor:g}.csv"
        write_recording(s.recording, str(path))
        assert main(["calibrate", str(path), "--json", "--method", "lm"]) == 0
        d = json.loads(capsys.readouterr().out)
        return np.array(d["stderr"]["scale"] + d["stderr"]["bias_g"])
    ratios = [float(np.median(stderr(seed, 3.0) / stderr(seed, 0.0))) for seed in range(6)]
    assert 0.75 < np.median(ratios) < 1.35, ratios
