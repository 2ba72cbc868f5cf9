"""A calibration in force that the new poses reject is challenged before the pose set is ready.

The daemon fitted, with a final calibration in force, only once the poses needed (25) were
collected.  A cold review put the calibration of another simulated board (28-120 mg off) in
the state directory and replayed a good hand-held session: no fit was tried at poses 10, 15
or 20 in 20 of 20 sessions, every streamed sample was corrected by the wrong calibration, and
with 20 poses it was saved back untouched.  Now the daemon tests the calibration in force on
the poses it was not fitted on (fitting/gate.py in_force_check: the chi-square of |a| - 1 g
over each pose mean's radial variance plus the calibration's own held-out RMS squared) and
fits as soon as it rejects at IN_FORCE_CHALLENGE_LEVEL (1e-3); the gate judges the fit.

Error rates (measured with the same check at every pose count from 10 to 25, on sessions of
the board a calibration was fitted on, with `calibrate -o` on another of its sessions): 0 of
95 sessions challenged (bench 6-8 s holds, hand-held tremor, a sway of 0.1 deg, a 12 degC
warm-up, the 9DOF board); the smallest p-value of a session 0.087, the median 0.75-1.0.
The check adds the calibration's held-out RMS to the noise, so it is conservative: a
calibration a few tenths of a mg off is left to the periodic refits, as before."""
import json
import subprocess
import sys

import numpy as np

from imucald.cli import main
from imucald.files.recording import write_recording
from imucald.fitting.gate import in_force_check
from imucald.fitting.stillness.poses import poses_and_pieces
from imucald.calibration import load
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import draw_truth, simulate_session


def _replay_log(rec, state):
    p = subprocess.run([sys.executable, "-m", "imucald.cli", "replay", str(rec), "--state-dir", str(state),
                        "--orientation", "no"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return p.stderr.splitlines(), [json.loads(x) for x in p.stdout.splitlines() if '"CAL"' in x]


def test_another_boards_calibration_in_force_is_challenged_at_the_tenth_pose(tmp_path):
    """Broken once (_challenged returning False): no fit before the 20-pose file ends, no CAL."""
    other, rec = tmp_path / "other.csv", tmp_path / "rec.csv"
    assert main(["simulate", "-o", str(other), "--poses", "25", "--hold", "3", "--seed", "5"]) == 0
    assert main(["simulate", "-o", str(rec), "--poses", "20", "--hold", "3", "--seed", "4"]) == 0
    state = tmp_path / "st"
    state.mkdir()
    assert main(["calibrate", str(other), "-o", str(state / "calibration.yaml")]) == 0
    log, cals = _replay_log(rec, state)
    i10 = next(i for i, x in enumerate(log) if "pose 10/25" in x)
    said = [i for i, x in enumerate(log) if "the calibration in force disagrees with the" in x]
    assert said and said[0] == i10 + 1, "\n".join(log)
    assert "fitting now, before the 25 poses needed" in log[said[0]]
    assert cals and cals[0]["applied"], "\n".join(log)
    # (once per recalibrate_every_poses while the gate refuses: the gate takes this first
    # challenge's fit; test_a_refused_challenge_is_not_retried_at_every_pose checks the rest)


def test_the_same_boards_calibration_in_force_is_not_challenged(tmp_path):
    """The null: the calibration `calibrate -o` fits on one hand-held session of a board, in
    force over another session of that board: at every pose count 10-25 the check keeps it
    (p >= 1e-3) on 4 seeds, and the daemon says nothing of it.  Seen to fail with the
    calibration's own held-out RMS left out of the variance (seed 0: p 8e-4)."""
    for seed in range(4):
        g = np.random.default_rng(2000 + seed)
        tr = draw_truth("mpu6050", g)
        kw = dict(hold_s=(1.5, 3), move_s=(1.5, 3), tremor_dps=1.5)
        A = simulate_session("mpu6050", random_pose_set(25, g), g, truth=tr, **kw)
        B = simulate_session("mpu6050", random_pose_set(25, g), g, truth=tr, **kw)
        fa, fb = tmp_path / f"a{seed}.csv", tmp_path / f"b{seed}.csv"
        write_recording(A.recording, str(fa))
        write_recording(B.recording, str(fb))
        state = tmp_path / f"st{seed}"
        state.mkdir()
        assert main(["calibrate", str(fa), "-o", str(state / "calibration.yaml")]) == 0
        cal = load(str(state / "calibration.yaml"))
        ps, _ = poses_and_pieces(B.recording)
        p = [in_force_check(cal, ps.acc[:n], ps.acc_cov[:n], ps.temp[:n])[0] for n in range(10, len(ps) + 1)]
        assert min(p) >= 1e-3, (seed, min(p))
        # a calibration without quality figures (written by hand) is not tested at all: the
        # poses' noise alone challenged a right one (p 8e-4 on seed 0: a cold review)
        from dataclasses import replace
        bare = replace(cal, accel=replace(cal.accel, quality={}))
        assert in_force_check(bare, ps.acc, ps.acc_cov, ps.temp)[0] == 1.0
        if seed == 0:
            log, _ = _replay_log(fb, state)
            assert not any("disagrees" in x for x in log), "\n".join(log)


def test_a_refused_challenge_is_not_retried_at_every_pose(tmp_path):
    """The challenge fits at most once per recalibrate_every_poses (5) new poses: when the gate
    keeps the calibration in force (here: every job is dropped, nothing applied), the next
    challenge waits 5 poses.  Broken once (_challenge_at not set): a job at every pose from the
    10th (11 jobs instead of 3)."""
    from concurrent.futures import Executor, Future
    from dataclasses import replace
    from imucald.daemon.config import validate
    from imucald.daemon.pipeline import Pipeline
    from imucald.fitting.stillness.detector import StillnessDetector

    class Capture(Executor):
        def __init__(self):
            self.jobs = []

        def submit(self, fn, *a, **kw):
            self.jobs.append(a[0])
            return Future()         # never done: the test drops it, as a refusal would leave things

    other = tmp_path / "other.csv"
    assert main(["simulate", "-o", str(other), "--poses", "25", "--hold", "3", "--seed", "5"]) == 0
    assert main(["calibrate", str(other), "-o", str(tmp_path / "cal.yaml")]) == 0
    cal = load(str(tmp_path / "cal.yaml"))
    g = np.random.default_rng(9)
    rec = simulate_session("mpu6050", random_pose_set(20, g), g, hold_s=3.0).recording
    det = StillnessDetector(rec.rate_hz, chip="mpu6050", keep_structure=True)
    ivs = det.update(rec.t, rec.acc, rec.gyro, rec.temp)[1] + det.flush()
    ex = Capture()
    pipe = Pipeline(validate({}), "mpu6050", rec.rate_hz, False, executor=ex, chips={"accel": "mpu6050"})
    pipe.applied = replace(cal, id=1, provisional=None)
    at = []
    for iv in ivs:
        pipe.acc.add(iv)
        n = len(ex.jobs)
        pipe.maybe_calibrate()
        if len(ex.jobs) > n:
            at.append(len(pipe.acc))
            pipe.pending = None
    assert len(pipe.acc) == 20 and at == [10, 15, 20], at
