"""The acceptance gate, measured against the truth (calib/gate.py).

1. False accepts: the calibration in force is near the truth (it was fitted on an
   earlier session of the same size, so it carries its own estimation error); a new
   session gives a candidate.  "Truly worse" is judged by the truth: the RMS error of
   the corrected specific force over 2000 directions spread on the sphere.  Printed:
   the rate at which a truly worse calibration is applied, by the gate and by the
   former bare comparison (fit on 80 %, RMS on the 20 % held out, no margin).
2. First calibration: a raw sensor (about 100 mg bias plus datasheet scale and
   cross-axis errors) receives hand-held poses one by one; at every pose from the
   fewest a fit needs, the candidate is gated against the raw readings.  Printed:
   the median number of poses to the first calibration.

Poses are hand-held: 2 s holds at 100 Hz with the MPU-6050's datasheet noise, each
pose's noise inflated by a factor in [1, 3] (tremor), spread like a person places
them (randomly rotated lattice, 3 degree hand jitter).

    python bench/gate.py [--trials 200] [--poses 25] [--alpha 0.05] [--seed 1]
"""
import argparse

import _common  # noqa: F401  (sys.path)
import numpy as np

from imucald.calib.fit import accel_bounds, fit_norm
from imucald.calib.gate import gate_accel, poses_needed
from imucald.calib.models import Triangular9
from imucald.sim.poses import random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, pose_sigma
from imucald.calib.coverage import sphere_lattice
from imucald.specs import ACCEL

T9 = Triangular9()
SIGMA_POSE_G = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 100.0, 2.0)[1]


DIRS = sphere_lattice(2000)


def truth_error_g(theta, truth):
    """RMS over the sphere of |corrected - true| specific force (g)."""
    raw = T9.inverse(truth, DIRS)
    return float(np.sqrt(np.mean(np.sum((T9.forward(theta, raw) - DIRS) ** 2, 1))))


def session(truth, n, rng):
    ups = up_vectors(random_pose_set(n, rng))
    s = SIGMA_POSE_G * rng.uniform(1.0, 3.0, n)
    raw = T9.inverse(truth, ups) + rng.normal(size=(n, 3)) * s[:, None]
    return raw, np.eye(3)[None] * (s ** 2)[:, None, None]


def bare_gate(raw, cov, incumbent_theta, method, seed):
    """The former gate: fit on 80 %, bare RMS on every 5th pose, no margin."""
    ho = np.zeros(len(raw), bool)
    ho[4::5] = True
    cal = fit_norm(raw[~ho], "triangular9", method, pose_cov=cov[~ho], rng=seed, heldout=False)
    e_new = np.sqrt(np.mean(T9.residual(cal.theta, raw[ho]) ** 2))
    e_cur = np.sqrt(np.mean(T9.residual(incumbent_theta, raw[ho]) ** 2))
    return e_new < e_cur, cal.theta


def false_accepts(trials, n, alpha, method, rng):
    rows = []
    for t in range(trials):
        truth = draw_truth("mpu6050", rng).accel
        raw0, cov0 = session(truth, n, rng)
        inc = fit_norm(raw0, "triangular9", method, pose_cov=cov0, rng=t, heldout=False).theta
        raw, cov = session(truth, n, rng)
        cal, _, dec = gate_accel(raw, cov, T9.forward(inc, raw), method, alpha, rng=t)
        bare, th_bare = bare_gate(raw, cov, inc, method, t)
        e_inc = truth_error_g(inc, truth)
        rows.append((dec.accept, truth_error_g(cal.theta, truth) > e_inc,
                     bare, truth_error_g(th_bare, truth) > e_inc))
    r = np.array(rows, bool)
    return r


def first_calibration(trials, n_max, alpha, method, rng):
    need = poses_needed(T9.k)
    out = []
    for t in range(trials):
        truth = draw_truth("mpu6050", rng).accel.copy()
        b = rng.normal(size=3)
        truth[6:9] = 0.1 * b / np.linalg.norm(b)            # ~100 mg raw bias
        raw, cov = session(truth, n_max, rng)
        first = None
        for k in range(need, n_max + 1):
            _, _, dec = gate_accel(raw[:k], cov[:k], raw[:k], method, alpha, against="raw", rng=t)
            if dec.accept:
                first = k
                break
        out.append(first if first is not None else n_max + 1)
    return np.array(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--poses", type=int, default=25)
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--method", default="lm")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    r = false_accepts(a.trials, a.poses, a.alpha, a.method, rng)
    print(f"false accepts: {a.trials} trials, {a.poses} hand-held poses, incumbent fitted on an earlier "
          f"session of {a.poses} ({a.method}); truth error over {len(DIRS)} directions")
    print(f"  candidate truly worse than the incumbent in {r[:, 1].mean():.1%} of trials")
    print(f"  gate (cross-validated, signed-rank, alpha {a.alpha:g}): accepted {r[:, 0].mean():.1%}, "
          f"truly worse applied {(r[:, 0] & r[:, 1]).mean():.1%} "
          f"({int((r[:, 0] & r[:, 1]).sum())}/{a.trials})")
    print(f"  former bare 80/20 comparison:  accepted {r[:, 2].mean():.1%}, "
          f"truly worse applied {(r[:, 2] & r[:, 3]).mean():.1%} "
          f"({int((r[:, 2] & r[:, 3]).sum())}/{a.trials})")
    n_first = max(a.trials // 4, 50)
    f = first_calibration(n_first, 25, a.alpha, a.method, rng)
    print(f"first calibration from a raw sensor (~100 mg bias), {n_first} hand-held sessions: "
          f"median {np.median(f):.0f} poses (fewest a fit needs: {poses_needed(T9.k)}; "
          f"10th-90th percentile {np.percentile(f, 10):.0f}-{np.percentile(f, 90):.0f}; "
          f"{np.mean(f > 25):.0%} not reached by pose 25)")


if __name__ == "__main__":
    main()
