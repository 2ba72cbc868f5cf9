"""The gyro bias-vs-temperature model on a real warm-up (issue 11, acceptance).

../shared/data/real/freeimu_mpu6050_tempsweep: an MPU-6050 lying still, z up, warming
from 10 to 29 degC over 36 minutes (SOURCE.md; gyro at +-2000 deg/s, 16.4 counts per
deg/s).  The record is cut into blocks of --block samples (contiguous, no gap > 0.1 s);
blocks whose die temperature falls in every other 2 degC bin (10-12, 14-16, ...) train
fitting/thermal/terms.py's fit_bias_series (order by the held-out test, variances inflated by the
scatter the richest order leaves); each bin in between (12-14, 16-18, ...) is predicted at
its blocks' mean temperature.  The bin's observed mean has the standard error of its block
means (their scatter, so slow wander is counted); the prediction, the fit's covariance.
z = (observed - predicted) / sqrt(se_obs^2 + se_pred^2) per axis; |z| <= 2 passes.
A bin beyond the training range (28-30: training ends at 28 degC) is predicted with the
terms held at the edge value, as the daemon applies them, and reported apart.
Usage: python bench/real_thermal.py [--block 40]
"""
import argparse
import os

from _common import np

from real_gap import REAL, tempsweep  # the one reader of the recording (counts -> g, dps, degC)

from imucald.fitting.thermal.terms import thermal_design, fit_bias_series

PATH = os.path.join(REAL, "freeimu_mpu6050_tempsweep", "Tempdata01-02-14.csv")


def blocks(block):
    rec = tempsweep()
    t, g, T = rec.t, rec.gyro, rec.temp
    cut = np.flatnonzero(np.diff(t) > 0.1) + 1
    out = []
    for seg in np.split(np.arange(len(t)), cut):
        for i in range(0, len(seg) - block + 1, block):
            s = seg[i:i + block]
            out.append((T[s].mean(), g[s].mean(0), g[s].var(0, ddof=1) / len(s)))
    Tb = np.array([o[0] for o in out])
    return Tb, np.array([o[1] for o in out]), np.maximum(np.array([o[2] for o in out]), 1e-10)


def predict(tf, T):
    """Bias and its standard error at temperatures T (N,) -> (N, 3), (N, 3)."""
    u = (np.clip(T, tf.t_min_c, tf.t_max_c) - tf.t_ref_c) / tf._scale_c
    X = thermal_design(u, tf.order)
    y = X @ np.concatenate([tf.base, (tf.bias_poly * np.array([tf._scale_c ** (k + 1)
                                                                for k in range(tf.order)])[:, None]).ravel()])
    var = np.einsum("ij,jk,ik->i", X, tf.cov, X)
    return y.reshape(-1, 3), np.sqrt(var).reshape(-1, 3)


def held_out_bins(block=40):
    """The fit on every other 2 degC bin and, per bin in between, (bin start degC, blocks,
    observed, se_obs, predicted, se_pred, z, beyond the fitted range)."""
    T, g, v = blocks(block)
    b = np.floor((T - 10.0) / 2.0).astype(int)          # 2 degC bins from 10 degC
    train = b % 2 == 0
    tf = fit_bias_series(T[train], g[train], v[train], rng=0)
    rows = []
    for k in sorted(set(b[~train])):
        m = b == k
        if m.sum() < 3:
            continue
        obs = g[m].mean(0)
        se_obs = g[m].std(0, ddof=1) / np.sqrt(m.sum())
        pred, se_pred = predict(tf, np.array([T[m].mean()]))
        z = (obs - pred[0]) / np.sqrt(se_obs ** 2 + se_pred[0] ** 2)
        out = T[m].mean() > tf.t_max_c or T[m].mean() < tf.t_min_c
        rows.append((10 + 2 * int(k), int(m.sum()), obs, se_obs, pred[0], se_pred[0], z, bool(out)))
    return tf, rows, sorted({10 + 2 * int(k) for k in set(b[train])}), int(train.sum()), len(T)


def against_constant(rows):
    """Per axis over the bins in between (inside the fitted range): RMS of observed -
    predicted, of observed - the best constant for those bins (their own mean: no constant
    calibration can do better) and of the stated standard error of observed - predicted,
    deg/s (3,) each."""
    ins = [r for r in rows if not r[7]]
    obs, pred = np.array([r[2] for r in ins]), np.array([r[4] for r in ins])
    se = np.array([np.hypot(r[3], r[5]) for r in ins])
    f = lambda e: np.sqrt(np.mean(e ** 2, axis=0))
    return f(obs - pred), f(obs - obs.mean(0)), f(se)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--block", type=int, default=40)
    a = ap.parse_args()
    if not os.path.exists(PATH):
        print(f"skipped: {PATH} is absent")
        return
    tf, rows, bins, ntrain, nblocks = held_out_bins(a.block)
    print(f"{nblocks} blocks of {a.block} samples; trained on {ntrain} blocks in the bins from "
          + ", ".join(str(x) for x in bins) + " degC")
    print(f"fit: {tf.note}; inflation x{tf.inflation:.1f}")
    for k in range(tf.order):
        print(f"  (T - {tf.t_ref_c:.1f})^{k + 1}: " + ", ".join(
            f"{c * 1e3:+.3f}+-{s * 1e3:.3f}" for c, s in zip(tf.bias_poly[k], tf.bias_poly_stderr[k])) + f" mdps/degC^{k + 1}")
    print(" bin degC  blocks   observed (mdps)                 predicted (mdps)                 z")
    f = lambda x, s: "[" + ", ".join(f"{xi * 1e3:+7.1f}+-{si * 1e3:4.1f}" for xi, si in zip(x, s)) + "]"
    for b0, n, obs, se_obs, pred, se_pred, z, out in rows:
        print(f" {b0:2d}-{b0 + 2:2d}  {n:5d}   {f(obs, se_obs)}  {f(pred, se_pred)}  "
              + " ".join(f"{zi:+5.1f}" for zi in z) + ("  (beyond the fitted range: held)" if out else ""))
    zs = np.array([r[6] for r in rows if not r[7]])
    beyond = [r[6] for r in rows if r[7]]
    print(f"inside the fitted range: |z| <= 2 in {int((np.abs(zs) <= 2).sum())} of {zs.size} (bin, axis) "
          f"predictions; per axis RMS z " + ", ".join(f"{a} {np.sqrt(np.mean(zs[:, i] ** 2)):.2f}"
                                                     for i, a in enumerate("xyz")))
    e, e0, se = against_constant(rows)
    print("held-out RMS error per axis (mdps), thermal terms / the best constant / stated: " + "; ".join(
        f"{ax} {x * 1e3:.1f} / {y * 1e3:.1f} / {z * 1e3:.1f}" for ax, x, y, z in zip("xyz", e, e0, se)))
    if beyond:
        print("beyond it: z " + "; ".join(" ".join(f"{zi:+.1f}" for zi in z) for z in beyond))


if __name__ == "__main__":
    main()
