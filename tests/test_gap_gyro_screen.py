"""gap's gyro step leaves out a hold whose gyro scatters far more than the others' (the board
turned during it), which the accelerometer's screen cannot see when the turning is about
gravity.  An independent probe's table-and-hand nulls were called `unexplained` for it
(mixed_1028: one 1.1-s hand hold among table holds, its pose mean 20 of the pooled standard
errors off; 3 false alarms in 93 nulls, 1 after)."""
import numpy as np

from imucald.gap.diagnose import diagnose

from .blindgen2 import make_case

TREMOR_DPS, TREMOR_HZ, DRIFT_DPS = 1.5, 9.0, 0.2      # a hand's tremor and slow turn


def _wobbled(kind="null", seed=4003):
    """The blind generator's table null with one mid-recording hold held by hand, turning about
    gravity: TREMOR_DPS at TREMOR_HZ plus a slow DRIFT_DPS (its pose mean moves 0.2 dps,
    ~100 of a table hold's standard errors); returns the recording and the hold's start (s)."""
    rec, lab = make_case(kind, seed)
    pid = np.asarray(lab["pose_id"])
    p = int(np.median(pid[pid >= 0]))
    idx = np.flatnonzero(pid == p)
    t0 = rec.t[idx[0]]
    up = lab["noise_free"]["acc"][idx].mean(0)
    up /= np.linalg.norm(up)
    w = TREMOR_DPS * np.sin(2 * np.pi * TREMOR_HZ * (rec.t[idx] - t0)) + DRIFT_DPS
    rec.gyro[idx] += w[:, None] * up[None, :]
    return rec, t0


def test_a_hand_hold_among_table_holds_is_left_out_of_the_gyro_diagnosis():
    """The null stays `none` (before: `unexplained`), and the note and `where` name the hold.
    Seen to fail with gap/diagnose.py _gyro_disturbed leaving every pose in: `unexplained`,
    ratio 8.9."""
    rec, t0 = _wobbled()
    r = diagnose(rec, sensors=["gyro"], sims=50, seed=1)["sensors"]["gyro"]
    assert r["verdict"] == "none", (r["verdict"], r["ratio_before"])
    moved = r["where"]["gyro_disturbed_poses"]
    assert len(moved["indices"]) == 1 and abs(moved["t0_s"][0] - t0) < 1.0, (moved, t0)
    assert any("left out of the gyro's diagnosis" in n for n in r["notes"]), r.get("notes")


def test_the_untouched_null_leaves_no_gyro_pose_out():
    """The same null without the hand hold: no hold is left out (the screen's limit is the
    accelerometer's, chi-square's 99.9 % point times 1.5 over the median hold).  It guards
    against over-flagging only; seen to fail with the limit replaced by the median itself
    (every hold above the median left out)."""
    rec, _ = make_case("null", 4003)
    r = diagnose(rec, sensors=["gyro"], sims=50, seed=1)["sensors"]["gyro"]
    assert r["verdict"] == "none" and "gyro_disturbed_poses" not in r["where"], r["where"].keys()


def test_a_gyro_held_below_its_lsb_leaves_no_pose_out():
    """An un-dithered gyro read at 14.375 LSB/dps holds one value inside most holds (blindgen2
    null_flicker 4012): the median within-pose variance is ~0, and a hold whose reading flips
    between two values is no turn.  Seen to fail without the one-LSB^2 floor of
    _gyro_disturbed: 11 of its holds left out."""
    rec, _ = make_case("null_flicker", 4012)
    r = diagnose(rec, sensors=["gyro"], sims=50, seed=1)["sensors"]["gyro"]
    assert "gyro_disturbed_poses" not in r["where"], r["where"].get("gyro_disturbed_poses")
