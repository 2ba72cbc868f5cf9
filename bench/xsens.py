"""Real data: the IMU-TK Xsens MTi recording (../shared/data/real/imutk_xsens_mti).

Raw unsigned 16-bit counts; converted with offset 32768 and IMU-TK's "datasheet"
scale 415 counts per m/s^2 (= 4069.8 counts per g).  Still poses are found by
imucald's detector; each method's in-sample and held-out (leave-one-pose-out)
RMS of |a| - 1 g is printed.  A published 9-parameter Ceres fit reaches 0.11 mg
in-sample on these poses.  Then the check of the predicted uncertainty: the held-out
residuals divided by their predicted std should have RMS near 1, under three noise
models (one pooled white level as before issue 9; each pose's own noise with the
coloured-noise inflation; plus the excess-scatter scaling).
Usage: python bench/xsens.py
"""
import os
import sys
import time

from _common import np

from imucald.fitting.fit import fit_norm
from imucald.fitting.inputs import read_table
from imucald.fitting.noise.colour import pose_colour_inflation
from imucald.fitting.stillness.poses import poses_from_recording

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PATH = os.path.join(ROOT, "..", "shared", "data", "real", "imutk_xsens_mti", "xsens_acc.mat")


def main():
    if not os.path.exists(PATH):
        print(f"skipped: {PATH} is absent (../shared is not beside the checkout)")
        return 0
    rec = read_table(PATH, ["t", "ax", "ay", "az"], 415 * 9.80665, 32768.0)
    ps = poses_from_recording(rec)
    print(f"Xsens MTi: {len(rec)} samples, {len(ps)} still poses found; "
          f"median within-pose sd {np.median(np.sqrt(np.einsum('nii->ni', ps.acc_sample_cov))) * 1e3:.3f} mg")
    un = np.linalg.norm(ps.acc, axis=1) - 1
    print(f"uncalibrated |a| - 1 RMS over poses: {np.sqrt(np.mean(un ** 2)) * 1e3:.2f} mg")
    print(f"{'method':<9} {'model':<12} {'in-sample mg':>12} {'held-out mg':>12} {'noise mg':>9} {'s':>7}")
    k, kinfo = pose_colour_inflation(rec.t, rec.acc, rec.rate_hz, ps.t0, ps.t1, ps.n)
    print(f"coloured-noise inflation per pose: {kinfo}")
    for model in ("triangular9", "full12", "cosine", "auto"):
        for method in ("ga-paper", "hga", "ga", "lm"):
            t = time.perf_counter()
            cal = fit_norm(ps.acc, model, method, pose_cov=ps.acc_cov, rng=0, noise_inflation=k)
            dt = time.perf_counter() - t
            print(f"{method:<9} {model:<12} {cal.rms * 1e3:12.4f} {cal.heldout_rms * 1e3:12.4f} "
                  f"{cal.noise * 1e3:9.4f} {dt:7.3f}")
    print("held-out residual / predicted std, RMS (1 = the uncertainty holds), triangular9 lm:")
    N = len(ps)
    pooled = np.full(N, np.median(np.einsum("nii->n", ps.acc_cov) / 3))
    for label, cov, infl in (("one pooled white level (before)", pooled, None),
                             ("per-pose noise x colour", ps.acc_cov, k),
                             ("per-pose noise x colour, no excess-scatter scaling", ps.acc_cov, k)):
        cal = fit_norm(ps.acc, "triangular9", "lm", pose_cov=cov, noise_inflation=infl)
        z = cal.info["heldout_normalised_rms"]
        phi = cal.info["noise_model"]["excess_scatter"]
        if label.endswith("scaling"):
            z = z * np.sqrt(phi)       # the prediction without the scaling is sqrt(phi) smaller
        elif label.endswith("(before)"):
            z = z * np.sqrt(phi)
        print(f"  {label:<52} {z:6.3f}   (excess scatter {phi:.2f})")
    print(f"  band for N = {N} unit normals: 1 +- {3 / np.sqrt(2 * N):.3f} (3 s.e.)")
    cal = fit_norm(ps.acc, "triangular9", "lm", pose_cov=ps.acc_cov)
    b = np.array(cal.params["bias_g"]) * 415 * 9.80665 + 32768
    print(f"triangular9 bias in counts: {np.round(b, 1)} (IMU-TK: 33124.2, 33275.2, 32364.4)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
