"""Magnetometer-only calibration from rotation on the real QMC5883L recordings
(../shared/data/real/tomisuarez_qmc5883l): relative std of the corrected field norm for
imucald and for the authors' 12 parameters (authors_results/paramters_mag.csv, their
model m_cal = A m_raw + B) on the same samples, the held-out figure (fit on the first
70 % of the samples in time, test on the last 30 %), the spread the measured noise
alone predicts, and the wall time (median over repeats).

Usage: python bench/real_magcal.py [--repeats N] [--markdown FILE]   (FILE: a validation page)
"""
import argparse
import os

from _common import Markdown, median_time, np

from imucald.fitting.magcal import calibrate_rotation, rel_std
from imucald.fitting.models.mag import MagModel

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "..", "shared",
                    "data", "real", "tomisuarez_qmc5883l")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--markdown", help="also write the figures as a Markdown page here")
    args = ap.parse_args()
    if not os.path.isdir(DATA):
        print(f"{DATA} is absent (../shared is not beside the checkout): nothing to measure")
        return
    md = Markdown(args.markdown, "Magnetometer from rotation: the real GY-273 (QMC5883L)",
                  f"python bench/real_magcal.py --repeats {args.repeats}")
    md.text("The two real GY-273 recordings of `../shared/data/real/tomisuarez_qmc5883l` (QMC5883L, "
            "+-2 G, 50 Hz, 60 s still then about 400 s of hand rotation), calibrated from the "
            "rotation cloud (`imucald calibrate FILE --columns mx,my,mz --rate-hz 50 --nominal-scale "
            "12000`, the `mag_sym` model). Figure: the relative std of the corrected field norm "
            "(std / mean; 0 for a perfect sphere); *held out*: fitted on the first 70 % of the "
            "samples, evaluated on the last 30 %; *noise*: what the measured noise alone gives; "
            "the authors' A, B from their `authors_results/paramters_mag.csv` on the same samples "
            "(fitted by them on `noisy_raw_data.csv` as a whole, so their 'last 30 %' is not held "
            "out on that file); the wall time is the median over the repeats.")
    rows = []
    p = np.loadtxt(os.path.join(DATA, "authors_results", "paramters_mag.csv"))
    A, B = p[:9].reshape(3, 3), p[9:]
    print("relative std of |corrected field| (std / mean); held out = last 30 % of the samples")
    print(f"{'file':<24} {'who':<16} {'all':>7} {'last 30%':>9} {'held out':>9} {'noise':>7} "
          f"{'coverage':>9} {'median s':>9}")
    for name in ("noisy_raw_data.csv", "filtered_raw_data.csv"):
        m = np.loadtxt(os.path.join(DATA, name), delimiter=",", skiprows=3)
        k = int(round(len(m) * 0.7))
        for method in ("lm", "ga"):
            dt, r = median_time(lambda: calibrate_rotation(m, method=method, rng=0), args.repeats)
            last = rel_std(np.linalg.norm(MagModel("sym").forward(r["calibration"].theta, m[k:]), axis=1))
            print(f"{name:<24} {'imucald ' + method:<16} {r['norm_rel_std']:7.4f} "
                  f"{last:9.4f} {r['heldout']['norm_rel_std']:9.4f} {r['predicted_rel_std']:7.4f} "
                  f"{r['coverage']['fraction']:9.2f} {dt:9.3f}")
            rows.append([f"`{name}`", f"imucald {method}", f"{r['norm_rel_std']:.4f}", f"{last:.4f}",
                         f"{r['heldout']['norm_rel_std']:.4f}", f"{r['predicted_rel_std']:.4f}",
                         f"{r['coverage']['fraction']:.0%}", f"{dt:.3f}"])
        a = np.linalg.norm(m @ A.T + B, axis=1)
        print(f"{name:<24} {'authors (A, B)':<16} {rel_std(a):7.4f} {rel_std(a[k:]):9.4f} "
              f"{'n/a':>9} {'':>7} {'':>9} {'':>9}")
        rows.append([f"`{name}`", "authors (A, B)", f"{rel_std(a):.4f}", f"{rel_std(a[k:]):.4f}",
                     "", "", "", ""])
    print("authors' parameters were fitted on noisy_raw_data.csv as a whole (their test script), "
          "so 'last 30%' is not held out for them on that file")
    md.table(["file", "who", "all samples", "last 30 %", "held out", "noise alone", "coverage",
              "median s"], rows)
    md.write()


if __name__ == "__main__":
    main()
