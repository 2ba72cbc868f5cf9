"""Blind test of `imucald gap` on recordings from tests/blindgen.py (motion, noise and effect
code written apart from the simulator and the candidate library).  Prints hits per class,
the null false-alarm rate, and how often the truth lies within 3 standard errors of a
named effect's coefficients.  Usage: python bench/gap_blind.py [--per-class N] [--nulls M]"""
import argparse
import os
import sys
import time
from collections import defaultdict

from _common import np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from tests.blindgen import CLASSES, hit, make_case  # noqa: E402

from imucald.errors import UserError  # noqa: E402
from imucald.gap.diagnose import diagnose  # noqa: E402

NULLS = [c for c in CLASSES if c.endswith("null") or c in ("null", "null_flicker")]


def coefficient(res_sensor, key):
    """The named effect's coefficients and standard errors for ``key`` (None when absent)."""
    for e in res_sensor.get("effects", []):
        if e.get("significant") and key in e.get("params", {}) and e["name"] in res_sensor["verdict"]:
            return np.asarray(e["params"][key]), np.asarray(e["stderr"][key])
    return None


def run_case(kind, seed):
    rec, lab = make_case(kind, seed)
    try:
        res = diagnose(rec, sims=100, seed=seed)
    except UserError as e:
        return lab, None, str(e)
    return lab, res, None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-class", type=int, default=10)
    ap.add_argument("--nulls", type=int, default=60, help="null recordings over the null classes")
    args = ap.parse_args()
    hits = defaultdict(lambda: [0, 0])
    gyro = defaultdict(lambda: [0, 0])
    cover = [0, 0]
    false_alarm = [0, 0]
    times = []
    plan = [(k, s) for k in CLASSES if k not in NULLS for s in range(args.per_class)]
    plan += [(NULLS[i % len(NULLS)], 1000 + i) for i in range(args.nulls)]
    for kind, seed in plan:
        t = time.perf_counter()
        lab, res, err = run_case(kind, seed)
        times.append(time.perf_counter() - t)
        s = lab["sensor"]
        v = res["sensors"][s]["verdict"] if res else f"error: {err[:60]}"
        h = hit(v, lab["expect"])
        hits[kind][0] += h
        hits[kind][1] += 1
        if res and "gyro" in res["sensors"]:
            gexp = {"thermal_bias"} if kind == "single_warmup_thermal" else {"none"}
            gyro[kind][0] += hit(res["sensors"]["gyro"]["verdict"], gexp)
            gyro[kind][1] += 1
        if kind in NULLS:
            false_alarm[0] += v != "none"
            false_alarm[1] += 1
        for key, tv in lab["truth"].items():
            sens = "gyro" if key.startswith("gyro_") else "mag" if key.startswith("mag_") else "accel"
            k2 = key.replace("gyro_", "").replace("mag_", "", 1)
            if res and sens in res["sensors"]:
                got = coefficient(res["sensors"][sens], k2)
                if got is not None:
                    z = np.abs(got[0] - np.asarray(tv)) / np.maximum(got[1], 1e-300)
                    cover[0] += int(np.sum(z <= 3))
                    cover[1] += len(z)
        if not h:
            print(f"  miss: {kind} seed {seed}: {s} verdict {v!r}, expected {sorted(lab['expect'])}")
    print("class                     hits (named sensor)   gyro as expected")
    for k in CLASSES:
        if hits[k][1]:
            print(f"{k:26s}{hits[k][0]:3d}/{hits[k][1]:<3d}                {gyro[k][0]:3d}/{gyro[k][1]}")
    print(f"null false alarms (named sensor): {false_alarm[0]}/{false_alarm[1]}")
    if cover[1]:
        print(f"truth within 3 standard errors: {cover[0]}/{cover[1]} coefficients of named effects")
    print(f"per recording: median {np.median(times):.2f} s")


if __name__ == "__main__":
    main()
