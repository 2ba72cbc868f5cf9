"""The acceptance gate (fitting/gate.py), measured against the simulated truth.

"Truly worse" and "truly better" are judged by the truth: the RMS error of the
corrected specific force over 2000 directions spread on the sphere.  Three scenarios,
each printed with the rates, their 95 % Wilson intervals, and the former rule (the
incumbent scored on every pose, its own fitting poses included) on the same draws:

1. independent sessions: the calibration in force was fitted on an earlier session of
   the same size (none of its poses is among the candidate's, so the gate scores both
   on every pose and only rule 2, 'significantly better', applies).  Candidate and
   incumbent are equally good in distribution: about half the candidates are truly worse.
2. the daemon's sequence: a raw sensor, a provisional fit on the first 10 hand-held
   poses, then a candidate at 15, 20 and 25 poses (calibration.recalibrate_every_poses
   5), each gated against the calibration in force then (rule 1 applies: the poses
   grow).  Printed: the rate at which a truly better 25-pose candidate (true error
   >= 1.5x lower than the provisional fit's) is applied by pose 25, and the truly
   worse applied per decision, with the 'always apply' rate for scale.
3. contaminated new poses: in force a fit on 15 poses; 10 new poses of which 1-2 were
   taken in slow motion or after a bump (3-10 mg off in a random direction); the
   candidate, fitted on all 25, is then often truly worse.

Poses are hand-held: 2 s holds at 100 Hz with the MPU-6050's datasheet noise, each
pose's noise inflated by a factor in [1, 3] (tremor), spread like a person places
them (randomly rotated lattice, 3 degree hand jitter).  Fits: lm with the datasheet
prior, as the daemon (calibration.method ga refines the same optimum).

    nice -n 10 python bench/gate.py [--trials 1000] [--alpha 0.05] [--seed 1]
"""
import argparse
import math
import time

import _common  # noqa: F401  (sys.path)
import numpy as np

from imucald.fitting.judging.coverage import sphere_lattice
from imucald.fitting.fit import fit_norm
from imucald.fitting.gate import gate_accel, paired_gate
from imucald.fitting.models.accel import Triangular9
from imucald.sim.orientations import random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, pose_sigma
from imucald.specs import ACCEL

T9 = Triangular9()
SIGMA_POSE_G = pose_sigma(ACCEL["mpu6050"].noise_density_g_rthz, 100.0, 2.0)[1]
DIRS = sphere_lattice(2000)
CHIP = "mpu6050"


def truth_error_g(theta, truth):
    """RMS over the sphere of |corrected - true| specific force (g)."""
    raw = T9.inverse(truth, DIRS)
    return float(np.sqrt(np.mean(np.sum((T9.forward(theta, raw) - DIRS) ** 2, 1))))


def session(truth, n, rng):
    ups = up_vectors(random_pose_set(n, rng))
    s = SIGMA_POSE_G * rng.uniform(1.0, 3.0, n)
    raw = T9.inverse(truth, ups) + rng.normal(size=(n, 3)) * s[:, None]
    return raw, np.eye(3)[None] * (s ** 2)[:, None, None]


def wilson(k, n, z=1.96):
    """95 % Wilson score interval of a binomial proportion k/n."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def rate(k, n):
    lo, hi = wilson(k, n)
    return f"{k / max(n, 1):.1%} ({k}/{n}; 95 % CI {lo:.1%}-{hi:.1%})"


def fit(raw, cov, seed):
    return fit_norm(raw, "triangular9", "lm", pose_cov=cov, rng=seed, heldout=False, chip=CHIP).theta


def gate(raw, cov, inc_theta, fitted, alpha, seed, former_theta=None):
    """The daemon's gate (fitting.gate.gate_accel) and, on the same candidate fit, the former
    rule (the incumbent ``former_theta``, default the same, scored on every pose)."""
    cal, r_cv, dec = gate_accel(raw, cov, T9.forward(inc_theta, raw), "lm", alpha, rng=seed, chip=CHIP,
                                fitted=fitted, nested=bool(fitted is not None and fitted.any()),
                                incumbent=("triangular9", inc_theta))
    r_inc = T9.residual(inc_theta if former_theta is None else former_theta, raw)
    return cal.theta, dec, paired_gate(r_inc ** 2, r_cv ** 2, alpha).accept


def independent(trials, n, alpha, rng):
    rows = []
    for t in range(trials):
        truth = draw_truth(CHIP, rng).accel
        raw0, cov0 = session(truth, n, rng)
        inc = fit(raw0, cov0, t)
        raw, cov = session(truth, n, rng)
        th, dec, old = gate(raw, cov, inc, None, alpha, t)
        rows.append((dec.accept, truth_error_g(th, truth) > truth_error_g(inc, truth), old))
    return np.array(rows, bool)


def sequence(trials, alpha, rng, steps=(15, 20, 25), first=10):
    """Per trial: (the 25-pose candidate >= 1.5x better than the provisional fit, a later
    fit in force by pose 25, the same under the former rule, final truth error over the
    provisional's); per decision: (applied, truly worse than the one in force; the same
    two under the former rule; truly worse by 1.5x or more)."""
    per_trial, per_dec = [], []
    for t in range(trials):
        truth = draw_truth(CHIP, rng).accel.copy()
        b = rng.normal(size=3)
        truth[6:9] = 0.05 * b / np.linalg.norm(b)            # a raw bias of 50 mg
        raw, cov = session(truth, steps[-1], rng)
        prov = fit(raw[:first], cov[:first], t)
        e_prov = truth_error_g(prov, truth)
        cur, cur_n, e_cur = prov, first, e_prov               # the gate
        old, old_n, e_old = prov, first, e_prov               # the former rule
        for k in steps:
            th, dec, acc_old = gate(raw[:k], cov[:k], cur, np.arange(k) < cur_n, alpha, t, old)
            e_th = truth_error_g(th, truth)
            per_dec.append((dec.accept, e_th > e_cur, acc_old, e_th > e_old, e_th >= 1.5 * e_cur))
            if dec.accept:
                cur, cur_n, e_cur = th, k, e_th
            if acc_old:
                old, old_n, e_old = th, k, e_th
        per_trial.append((e_th * 1.5 <= e_prov, cur_n > first, old_n > first, e_cur / e_prov))
    return np.array(per_trial), np.array(per_dec, bool)


def contaminated(trials, alpha, rng, n_old=15, n_new=10):
    """(applied, truly worse, former rule applied, truly worse by 1.5x or more) per trial."""
    rows = []
    for t in range(trials):
        truth = draw_truth(CHIP, rng).accel
        raw, cov = session(truth, n_old + n_new, rng)
        bad = n_old + rng.choice(n_new, rng.integers(1, 3), replace=False)
        d = rng.normal(size=(len(bad), 3))
        raw[bad] += d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.003, 0.010, (len(bad), 1))
        inc = fit(raw[:n_old], cov[:n_old], t)
        th, dec, old = gate(raw, cov, inc, np.arange(n_old + n_new) < n_old, alpha, t)
        e_th, e_inc = truth_error_g(th, truth), truth_error_g(inc, truth)
        rows.append((dec.accept, e_th > e_inc, old, e_th >= 1.5 * e_inc))
    return np.array(rows, bool)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--poses", type=int, default=25)
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    t0 = time.perf_counter()
    r = independent(a.trials, a.poses, a.alpha, rng)
    print(f"1. independent sessions: {a.trials} trials, {a.poses} hand-held poses, in force a fit on an "
          f"earlier session of {a.poses} (lm, datasheet prior); truth error over {len(DIRS)} directions")
    print(f"   candidate truly worse than the one in force in {r[:, 1].mean():.1%} of trials")
    print(f"   gate: applied {rate(int(r[:, 0].sum()), a.trials)}")
    print(f"         truly worse applied {rate(int((r[:, 0] & r[:, 1]).sum()), a.trials)}")
    print(f"   former rule: truly worse applied {rate(int((r[:, 2] & r[:, 1]).sum()), a.trials)}")
    print(f"   [{time.perf_counter() - t0:.0f} s]")
    t0 = time.perf_counter()
    pt, pd = sequence(a.trials, a.alpha, rng)
    better = pt[:, 0].astype(bool)
    print(f"2. the daemon's sequence: {a.trials} trials, provisional fit on 10 hand-held poses, "
          f"candidates at 15, 20, 25 poses")
    print(f"   25-pose candidate truly >= 1.5x better than the provisional fit in {better.mean():.1%} "
          f"of trials")
    print(f"   gate: such a candidate applied by pose 25 (a later fit in force) "
          f"{rate(int(pt[better, 1].sum()), int(better.sum()))}")
    print(f"         in all trials, final truth error / provisional's: median {np.median(pt[:, 3]):.2f}, "
          f"worse than the provisional in {rate(int((pt[:, 3] > 1).sum()), a.trials)}")
    nd = len(pd)
    print(f"         decisions: {nd}, truly worse applied {rate(int((pd[:, 0] & pd[:, 1]).sum()), nd)}"
          f" (applying every candidate: {rate(int(pd[:, 1].sum()), nd)})")
    print(f"         materially worse (true error >= 1.5x the one in force) applied "
          f"{rate(int((pd[:, 0] & pd[:, 4]).sum()), len(pd))} (applying every candidate: "
          f"{rate(int(pd[:, 4].sum()), len(pd))})")
    print(f"   former rule: applied by pose 25 {rate(int(pt[better, 2].sum()), int(better.sum()))}; "
          f"truly worse applied {rate(int((pd[:, 2] & pd[:, 3]).sum()), len(pd))} of decisions")
    print(f"   [{time.perf_counter() - t0:.0f} s]")
    t0 = time.perf_counter()
    nc = max(a.trials // 2, 1)
    c = contaminated(nc, a.alpha, rng)
    print(f"3. contaminated new poses: {nc} trials, in force a fit on 15 poses, 10 new of which 1-2 are "
          f"3-10 mg off; candidate truly worse in {c[:, 1].mean():.1%}")
    print(f"   gate: applied {rate(int(c[:, 0].sum()), nc)}, truly worse applied "
          f"{rate(int((c[:, 0] & c[:, 1]).sum()), nc)}")
    print(f"         materially worse (true error >= 1.5x the one in force) applied "
          f"{rate(int((c[:, 0] & c[:, 3]).sum()), nc)} "
          f"(applying every candidate: {rate(int(c[:, 3].sum()), nc)})")
    print(f"   former rule: truly worse applied {rate(int((c[:, 2] & c[:, 1]).sum()), nc)}")
    print(f"   [{time.perf_counter() - t0:.0f} s]")


if __name__ == "__main__":
    main()
