"""Paper 000's Monte Carlo study, with ga, hga and lm beside ga-paper, against the CRLB.

For each pose set (Nx, Ny, Nz) in (12,12,0), (8,6,4), (8,8,8): --sims simulations
(default 100), each with new true parameters drawn within the MPU-6050 datasheet
tolerances, a new random Euler pose set (3 deg hand jitter) and new noise.  Errors
are paper 000 eq. 7, d = lambda - lambda_hat.  Printed per parameter: mean and STD
of the error, the CRLB STD (RMS over simulations) and STD/CRLB; and the efficiency
1 / mean_k E[z_k^2], z = error / (that simulation's CRLB STD) (1 = attains the bound;
normalising per simulation keeps a few ill-conditioned random pose sets from
dominating).

Noise: see bench/_common.py (63 ug per pose mean: MPU-6050 density, 50 Hz, 20 s).
Usage: python bench/paper000_montecarlo.py [--sims N] [--jobs J]
"""
import argparse
import time
from multiprocessing import Pool

from _common import SIGMA_POSE_G, np

from imucald.fitting.models.accel import Triangular9
from imucald.fitting.solvers.lsq import Problem, lm
from imucald.fitting.solvers.ga import ga, ga_paper, hga
from imucald.fitting.judging.uncertainty import crlb, residual_variance
from imucald.sim.orientations import euler_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, simulate_pose_means

T9 = Triangular9()
NAMES = ["a_yz", "a_zy", "a_zx", "S_x", "S_y", "S_z", "b_x", "b_y", "b_z"]
POSE_SETS = [(12, 12, 0), (8, 6, 4), (8, 8, 8)]


def one(args):
    ps, seed = args
    rng = np.random.default_rng(seed)
    truth = draw_truth("mpu6050", rng).accel
    ups = up_vectors(euler_pose_set(*ps, rng))
    raw, _ = simulate_pose_means(truth, ups, SIGMA_POSE_G, rng)
    var = residual_variance(T9, truth, T9.inverse(truth, ups), np.full(len(ups), SIGMA_POSE_G ** 2))
    bound = crlb(T9, truth, T9.inverse(truth, ups), var).std
    out = {"crlb": bound}
    r = ga_paper(Problem(T9, raw), rng=seed)
    for i, it in enumerate(r.info["iterations"]):
        out[f"ga-paper it{i + 1}"] = truth - it["theta"]
    for name, fn in (("ga", ga), ("hga", hga), ("lm", lm)):
        out[name] = truth - fn(Problem(T9, raw), rng=seed).theta
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sims", type=int, default=100)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    t0 = time.time()
    print(f"paper 000 Monte Carlo: {args.sims} simulations per pose set, sigma_pose = "
          f"{SIGMA_POSE_G * 1e6:.1f} ug (MPU-6050, 50 Hz, 20 s per pose)")
    methods = ["ga-paper it1", "ga-paper it2", "ga-paper it3", "ga", "hga", "lm"]
    summary = []
    with Pool(args.jobs) as pool:
        for ps in POSE_SETS:
            res = pool.map(one, [(ps, 1000 * sum(ps) + k) for k in range(args.sims)])
            cr = np.sqrt(np.mean([r["crlb"] ** 2 for r in res], axis=0))
            print(f"\n=== (Nx, Ny, Nz) = {ps}; CRLB STD (RMS over sims):")
            print("  " + "  ".join(f"{n:>9}" for n in NAMES))
            print("  " + "  ".join(f"{v:9.2e}" for v in cr))
            for m in methods:
                e = np.array([r[m] for r in res])
                mean, sd = e.mean(0), e.std(0, ddof=1)
                z = e / np.array([r["crlb"] for r in res])
                eff = float(1.0 / np.mean(z ** 2))
                summary.append((ps, m, eff, sd))
                print(f"  {m}:  efficiency {eff:.3f}   overall-bias error mean "
                      f"{np.linalg.norm(e[:, 6:9], axis=1).mean():.2e} g")
                print("    mean " + "  ".join(f"{v:+9.1e}" for v in mean))
                print("    STD  " + "  ".join(f"{v:9.2e}" for v in sd))
                print("    /CRLB" + "  ".join(f"{v:9.2f}" for v in sd / cr))
    print("\nfindings:")
    for ps in POSE_SETS:
        sds = {m: sd for (p, m, _, sd) in summary if p == ps}
        s1, s2, s3 = (np.mean(sds[f"ga-paper it{i}"] / sds["lm"]) for i in (1, 2, 3))
        print(f"  {ps}: ga-paper error STD relative to lm, mean over parameters: it1 {s1:.2f}, "
              f"it2 {s2:.2f}, it3 {s3:.2f}")
    sd = {m: s for (p, m, _, s) in summary if p == (12, 12, 0)}
    worst = NAMES[int(np.argmax(sd["lm"][0:3]))]
    print(f"  (12, 12, 0): worst-determined non-orthogonality term: {worst}")
    for m in ("ga", "hga", "lm", "ga-paper it3"):
        effs = [e for (p, mm, e, _) in summary if mm == m]
        print(f"  {m}: efficiency per pose set " + ", ".join(f"{e:.3f}" for e in effs))
    print(f"\nwall time {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
