"""Blind test of `imucald gap`, blind in model space (tests/blindgen2.py: effect forms that
are not the library's, magnitudes log-uniform over 0.5x-5x the datasheet figures, random
sample rates, LSBs, latitudes).  Prints a per-class table (hits on the judged sensor, and
for out-of-library classes what they were called), the null false-alarm rate with its 95 %
Clopper-Pearson bound, the gyro's verdicts, and how often the truth lies within 3 SE.

Usage: python bench/gap_blind.py [--per-class N] [--nulls M] [--old]
(--old: the previous generator, tests/blindgen.py)"""
import argparse
import os
import sys
import time
from collections import Counter, defaultdict

from _common import np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from imucald.errors import UserError  # noqa: E402
from imucald.gap.diagnose import diagnose  # noqa: E402


def clopper_upper(k, n, conf=0.95):
    """One-sided upper bound of a binomial rate (bisection on the binomial tail)."""
    from math import comb
    if n == 0:
        return 1.0
    lo, hi = k / n, 1.0
    for _ in range(60):
        p = 0.5 * (lo + hi)
        tail = sum(comb(n, i) * p ** i * (1 - p) ** (n - i) for i in range(k + 1))
        lo, hi = (p, hi) if tail > 1 - conf else (lo, p)
    return hi


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-class", type=int, default=10)
    ap.add_argument("--nulls", type=int, default=200, help="null recordings over the null classes")
    ap.add_argument("--old", action="store_true", help="the previous generator (tests/blindgen.py)")
    args = ap.parse_args()
    if args.old:
        from tests import blindgen as G
        nulls = [c for c in G.CLASSES if c.endswith("null")]
        library = [c for c in G.CLASSES if c not in nulls and c not in ("cubic", "triple_product", "hysteresis")]
        outside = ["cubic", "triple_product", "hysteresis"]
    else:
        from tests import blindgen2 as G
        nulls, library, outside = G.NULLS, G.LIBRARY, G.OUTSIDE
    hits = defaultdict(lambda: [0, 0])
    called = defaultdict(Counter)
    gyro_none = [0, 0]
    false_alarm = [0, 0]
    times = []
    plan = [(k, s) for k in library + outside for s in range(args.per_class)]
    plan += [(nulls[i % len(nulls)], 1000 + i) for i in range(args.nulls)]
    for kind, seed in plan:
        t = time.perf_counter()
        rec, lab = G.make_case(kind, seed)
        try:
            res = diagnose(rec, sims=100, seed=seed)
            v = res["sensors"][lab["sensor"]]["verdict"]
        except UserError as e:
            res, v = None, f"error: {str(e)[:60]}"
        times.append(time.perf_counter() - t)
        h = G.hit(v, lab["expect"])
        hits[kind][0] += h
        hits[kind][1] += 1
        called[kind][v] += 1
        if kind in nulls:
            false_alarm[0] += v != "none"
            false_alarm[1] += 1
            if res and "gyro" in res["sensors"]:
                gyro_none[0] += res["sensors"]["gyro"]["verdict"] != "none"
                gyro_none[1] += 1
        if not h and kind not in outside:
            print(f"  miss: {kind} seed {seed}: {lab['sensor']} verdict {v!r}, expected {sorted(lab['expect'])}",
                  flush=True)
    print(f"{'class':26s}{'kind':10s}{'hits':>8s}   what it was called")
    for group, ks in (("null", nulls), ("library", library), ("outside", outside)):
        for k in ks:
            if hits[k][1]:
                calls = ", ".join(f"{v} {c}" for v, c in called[k].most_common())
                print(f"{k:26s}{group:10s}{hits[k][0]:4d}/{hits[k][1]:<3d}   {calls}")
    k, n = false_alarm
    print(f"null false alarms (judged sensor): {k}/{n} = {k / max(n, 1):.1%} "
          f"(95 % upper bound {clopper_upper(k, n):.1%})")
    print(f"gyro false alarms on the nulls: {gyro_none[0]}/{gyro_none[1]}")
    print(f"per recording: median {np.median(times):.2f} s over {len(times)}")


if __name__ == "__main__":
    main()
