"""Wall time of each optimiser on 25 poses (median of repeats), and fitness evaluations/s.

Targets (issue 2, one core of this machine): ga-paper full protocol < 1 s, ga < 0.2 s,
lm < 10 ms.  Usage: python bench/speed.py [--repeats N] [--markdown FILE]   (FILE: a validation page)
"""
import argparse
import time

from _common import SIGMA_POSE_G, Markdown, median_time, np

from imucald.fitting.models.accel import Triangular9
from imucald.fitting.solvers.lsq import Problem, lm
from imucald.fitting.solvers.ga import ga, ga_paper, hga
from imucald.sim.orientations import random_pose_set, up_vectors
from imucald.sim.sensor import draw_truth, simulate_pose_means


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--markdown", help="also write the figures as a Markdown page here")
    args = ap.parse_args()
    md = Markdown(args.markdown, "Optimiser speed", f"python bench/speed.py --repeats {args.repeats}")
    md.text(f"Wall time of each optimiser on 25 simulated MPU-6050 poses (triangular9), median, "
            f"minimum and maximum over {args.repeats} different data sets, and the fitness "
            "evaluations it made. The methods: [models and optimisers](../methods/models.md).")
    rows = []
    rng = np.random.default_rng(2024)
    m = Triangular9()
    cases = []
    for _ in range(args.repeats):
        tr = draw_truth("mpu6050", rng).accel
        ups = up_vectors(random_pose_set(25, rng))
        cases.append(simulate_pose_means(tr, ups, SIGMA_POSE_G, rng)[0])
    print(f"25 poses, triangular9, medians over {args.repeats} repeats (different data sets)")
    print(f"{'method':<10} {'median s':>10} {'min s':>9} {'max s':>9} {'fitness evals':>14} {'evals/s':>12}")
    for name, fn in (("ga-paper", ga_paper), ("hga", hga), ("ga", ga), ("lm", lm)):
        ts, ev = [], []
        for i, raw in enumerate(cases):
            p = Problem(m, raw)
            t = time.perf_counter()
            fn(p, rng=i)
            ts.append(time.perf_counter() - t)
            ev.append(p.nfev)
        ts = np.array(ts)
        print(f"{name:<10} {np.median(ts):10.4f} {ts.min():9.4f} {ts.max():9.4f} "
              f"{int(np.median(ev)):14d} {np.median(np.array(ev) / ts):12.3g}")
        rows.append([f"`{name}`", f"{np.median(ts):.4f}", f"{ts.min():.4f}", f"{ts.max():.4f}",
                     int(np.median(ev)), f"{np.median(np.array(ev) / ts):.3g}"])
    # raw population fitness throughput
    pop = m.nominal + rng.normal(scale=0.01, size=(4000, 9))
    dt, _ = median_time(lambda: m.fitness(pop, cases[0]), 50)
    print(f"population fitness: 4000 individuals x 25 poses in {dt * 1e3:.3f} ms "
          f"-> {4000 / dt:.3g} evaluations/s")
    md.table(["method", "median s", "min s", "max s", "fitness evaluations", "evaluations/s"], rows)
    md.text(f"Population fitness alone: 4000 individuals x 25 poses in {dt * 1e3:.3f} ms "
            f"({4000 / dt:.3g} evaluations/s).")
    md.write()


if __name__ == "__main__":
    main()
