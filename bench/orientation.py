"""Orientation in the stream, measured on BROAD (issue 26).

On the BROAD trials in ../shared/data/real/broad (Laidig et al., Data 2021, CC BY 4.0; optical
motion-capture reference), each trial converted to an imucald recording (bench/broad.py) and run
through the daemon's pipeline as ``imucald replay`` runs it (binary stream, q decoded back):

1. accuracy with BROAD's official metric (error quaternion q_est * conj(q_ref) in the earth
   frame; total, heading and inclination RMSE over the movement phase, no offset removed), per
   trial and mean, 9D (magnetometer) and 6D (without: heading arbitrary, only inclination
   meaningful), with the reference figures beside it (SOURCE.md: the published Madgwick TAGP
   beta 0.12, and pip vqf on the raw SI data); the stream's incl_std_deg / heading_std_deg
   against the error actually made (ratio of RMS and the share of samples within 2 sigma);
2. CPU: the filter alone per sample, and the daemon pipeline per sample at 1 kHz (MPU-6050
   emulation, bench/pipeline.py's ``cost``) with and without orientation, here and scaled to
   a Pi core (bench/budget.py's 7-Zip ratio);
3. what calibration buys: each trial with a known miscalibration applied (datasheet-scale
   errors: gyro bias, accelerometer bias and scale, magnetometer hard and soft iron), the
   orientation error on the raw data vs after imucald's calibration fitted from the trial
   itself (gyro bias and accelerometer from its still phases, magnetometer from its rotation).

Usage: python bench/orientation.py [--trials DIR] [--repeats N] [--mips M]
       [--skip-accuracy] [--skip-cpu] [--skip-study]
       [--compare-still]   (also run the filter without imucald's still intervals)
Needs the orientation extra (vqf) and h5py.
"""
import argparse
import copy
import sys
import tempfile
import time

from _common import np

import broad

#: SOURCE.md's reference figures per trial: published Madgwick TAGP (beta 0.12) total / incl,
#: and pip vqf 2.1.2 default 9D total / incl on the raw SI data (this project), degrees
REFERENCE = {"02": (1.50, 0.80, 1.38, 0.43), "09": (2.48, 1.86, 1.49, 0.87), "10": (3.57, 3.13, 1.80, 0.30),
             "12": (3.34, 2.73, 1.36, 0.25), "14": (3.10, 2.65, 0.73, 0.41), "16": (4.82, 3.09, 0.74, 0.54),
             "24": (1.77, 1.26, 1.55, 0.61), "30": (5.57, 5.26, 2.57, 1.25), "32": (15.76, 4.97, 7.67, 0.56),
             "35": (3.27, 3.06, 1.09, 0.66)}
#: issue 26's acceptance (9D means, degrees)
ACCEPT_TOTAL_DEG, ACCEPT_INCL_DEG, ACCEPT_US = 2.1, 0.6, 20.0


def run_pipeline(rec, cal=None, still_bias=True):
    """The recording through the daemon's pipeline as replay feeds it (batches of
    sensor.batch_s); returns the decoded binary records (q, incl_std, heading_std...)."""
    from imucald.daemon.config import DEFAULTS
    from imucald.daemon.outputs import BINARY_DTYPE
    from imucald.daemon.pipeline import Pipeline
    from imucald.drivers.board import SampleBatch
    from imucald.orientation.filter import OrientationFilter
    cfg = copy.deepcopy(DEFAULTS)
    cfg["output"]["format"] = "binary"
    cfg["calibration"]["min_poses"] = 500          # no calibration of its own: the one given stays
    rate = rec.rate_hz
    has_mag = rec.mag is not None
    pipe = Pipeline(cfg, rec.meta.get("board", "unknown"), rate, has_mag)
    pipe.maybe_calibrate = lambda: None
    if cal is not None:
        pipe.applied = cal
    OrientationFilter.use_still_intervals = still_bias
    pipe.use_orientation("yes")
    n = len(rec)
    step = max(1, int(round(cfg["sensor"]["batch_s"] * rate)))
    out = []
    prev = None
    for i in range(0, n, step):
        sl = slice(i, min(n, i + step))
        m = None if not has_mag else rec.mag[sl]
        fresh = None
        if has_mag:
            before = np.vstack([m[:1] + 1 if prev is None else prev, m[:-1]])
            fresh = np.any(m != before, axis=1)
            prev = m[-1:]
        temp = np.full(sl.stop - sl.start, np.nan) if rec.temp is None else rec.temp[sl]
        out.append(pipe.process(SampleBatch(rec.t[sl], np.arange(sl.start, sl.stop), rec.acc[sl],
                                            rec.gyro[sl], temp, m, fresh)))
    OrientationFilter.use_still_intervals = True
    return np.frombuffer(b"".join(out), dtype=BINARY_DTYPE)


def vqf_alone(tr, mag=True):
    import vqf
    f = vqf.VQF(1.0 / tr["rate_hz"])
    t0 = time.process_time()
    o = f.updateBatch(np.ascontiguousarray(tr["gyr_rads"]), np.ascontiguousarray(tr["acc_ms2"]),
                      np.ascontiguousarray(tr["mag_ut"]) if mag else None)
    us = (time.process_time() - t0) / len(tr["acc_ms2"]) * 1e6
    vqf_alone.rest = o["restDetected"]
    return o["quat9D" if mag else "quat6D"], us


def sigma_check(recs, tr):
    """(RMS of the error / RMS of the stated std, share of samples with error <= 2 std),
    inclination, over the movement phase."""
    _, _, inc = broad.error_angles_rad(recs["q"].astype(float), tr["q_ref"])
    m = tr["movement"] & np.isfinite(inc)
    e, s = np.degrees(inc[m]), recs["incl_std"][m].astype(float)
    return float(np.sqrt(np.mean(e ** 2)) / np.sqrt(np.mean(s ** 2))), float(np.mean(e <= 2 * s))


def accuracy(paths, compare_still):
    print("1. accuracy, BROAD's metric (RMSE over the movement phase, deg), the pipeline as replay "
          "runs it; reference: Madgwick TAGP published | vqf alone on the SI data")
    hdr = (f"{'trial':<40} {'9D total':>8} {'head':>6} {'incl':>6} | {'6D tot*':>7} {'head*':>6} {'incl':>6} | "
           f"{'Madgwick tot/incl':>17} | {'vqf alone tot/incl':>18} | {'incl err/std':>12} {'<=2std':>6} | "
           f"{'still/rest':>10}")
    if compare_still:
        hdr += f" | {'no still-bias tot/incl':>22}"
    print(hdr)
    rows = []
    for p in paths:
        tr = broad.load(p)
        r9 = run_pipeline(broad.to_recording(tr))
        r6 = run_pipeline(broad.to_recording(tr, mag=False))
        s9, s6 = broad.score(r9["q"].astype(float), tr), broad.score(r6["q"].astype(float), tr)
        alone = broad.score(vqf_alone(tr)[0], tr)
        ratio, within = sigma_check(r9, tr)
        # imucald's still flag vs VQF's own rest detection: the share of samples they agree on
        agree = float(np.mean((r9["flags"] & 1).astype(bool) == vqf_alone.rest))
        ref = REFERENCE.get(tr["name"][:2], (np.nan,) * 4)
        row = [*s9, s6[2], ref[0], ref[1], alone[0], alone[2], ratio, within, agree, s6[0], s6[1]]
        line = (f"{tr['name']:<40} {s9[0]:8.2f} {s9[1]:6.2f} {s9[2]:6.2f} | {s6[0]:7.2f} {s6[1]:6.2f} {s6[2]:6.2f} | "
                f"{ref[0]:8.2f} / {ref[1]:<6.2f} | {alone[0]:8.2f} / {alone[2]:<7.2f} | {ratio:12.2f} {within:6.2f} | "
                f"{agree:10.3f}")
        if compare_still:
            ns = broad.score(run_pipeline(broad.to_recording(tr), still_bias=False)["q"].astype(float), tr)
            row += [ns[0], ns[2]]       # indices 13, 14
            line += f" | {ns[0]:10.3f} / {ns[2]:<9.3f}"
        rows.append(row)
        print(line, flush=True)
    R = np.array(rows)
    mu = R.mean(0)
    line = (f"{'mean of ' + str(len(rows)) + ' trials':<40} {mu[0]:8.2f} {mu[1]:6.2f} {mu[2]:6.2f} | "
            f"{mu[11]:7.2f} {mu[12]:6.2f} {mu[3]:6.2f} | "
            f"{mu[4]:8.2f} / {mu[5]:<6.2f} | {mu[6]:8.2f} / {mu[7]:<7.2f} | {mu[8]:12.2f} {mu[9]:6.2f} | "
            f"{mu[10]:10.3f}")
    if compare_still:
        line += f" | {mu[13]:10.3f} / {mu[14]:<9.3f}"
    print(line)
    print("  * 6D: no magnetometer, the heading is arbitrary (where the filter started), so the 6D total "
          "and heading errors measure that start, not the filter; only its inclination is meaningful")
    print(f"  mean 9D with more digits: total {mu[0]:.3f}, heading {mu[1]:.3f}, inclination {mu[2]:.3f} deg")
    ok = mu[0] <= ACCEPT_TOTAL_DEG and mu[2] <= ACCEPT_INCL_DEG
    print(f"acceptance (9D mean total <= {ACCEPT_TOTAL_DEG}, inclination <= {ACCEPT_INCL_DEG} deg): "
          f"{'met' if ok else 'NOT met'}")
    return R


def cpu(paths, repeats, mips=None):
    import budget
    import pipeline
    print("\n2. CPU per sample")
    tr = broad.load(paths[0])
    us = float(np.median([vqf_alone(tr)[1] for _ in range(repeats)]))
    print(f"  the filter alone (vqf updateBatch, 9D, {len(tr['acc_ms2'])} samples): {us:.2f} us/sample")
    here = mips or budget.mips_here()
    if here is None:
        print("  (7z is not installed and --mips was not given: no Pi columns; apt install p7zip-full)")
    fac = {k: here / v for k, v in budget.PI_MIPS.items()} if here else {}
    with tempfile.TemporaryDirectory() as tmp:
        for board in ("mpu6050", "mpu9250"):
            for fmt in ("ndjson", "binary"):
                base = float(np.median([pipeline.cost(board, 1000, 20.0, fmt, tmp)[0] for _ in range(repeats)]))
                ori = float(np.median([pipeline.cost(board, 1000, 20.0, fmt, tmp, orientation=True)[0]
                                       for _ in range(repeats)]))
                pi = "".join(f", {k} ~{ori * f:.0f} us" for k, f in fac.items())
                print(f"  pipeline {board} 1000 Hz {fmt:<6}: {base:5.1f} us/sample without orientation, "
                      f"{ori:5.1f} with (+{ori - base:.1f}; ratio {ori / base:.2f}){pi}"
                      f"{'' if ori <= ACCEPT_US else '  > ' + str(ACCEPT_US) + ' us'}", flush=True)
    if here:
        print(f"  (7-Zip single-thread rating here {here:.0f} MIPS; Pi factors "
              + ", ".join(f"{k} {f:.1f}" for k, f in fac.items()) + ", bench/budget.py)")


#: the miscalibration applied (MPU-9250 datasheet, imucald/specs.py: accel zero-g X,Y +-60 mg, Z
#: +-80 mg, sensitivity +-3 %; gyro ZRO +-5 deg/s, sensitivity +-3 %; AK8963 taken with the
#: HMC5883L's gain +-5 % and cross-axis 1 %), each drawn N(0, tol/2) clipped to +-tol as the
#: simulator draws them; the hard iron is a board's, which no datasheet bounds: N(0, 0.1 gauss)
#: per axis (10 uT, a quarter of the earth's field) clipped to +-0.2 gauss
HARD_IRON_GAUSS = 0.1


def miscalibration(rng):
    from imucald.specs import ACCEL, GYRO, MAG
    a, g, m = ACCEL["mpu9250"], GYRO["mpu9250"], MAG["ak8963"]
    d = lambda tol, k=3: np.clip(rng.normal(0, np.asarray(tol, float) / 2, k), -np.asarray(tol), np.asarray(tol))
    soft = np.eye(3) + np.diag(d(m.scale_tol))
    off = d(m.cross_axis_tol, 3)
    soft[0, 1] = soft[1, 0] = off[0]
    soft[0, 2] = soft[2, 0] = off[1]
    soft[1, 2] = soft[2, 1] = off[2]
    return {"acc_bias_g": d(a.bias_tol_g), "acc_scale": 1 + d(a.scale_tol),
            "gyro_bias_dps": d(np.full(3, g.bias_tol_dps)), "gyro_scale": 1 + d(g.scale_tol),
            "mag_soft": soft, "mag_hard_gauss": np.clip(rng.normal(0, HARD_IRON_GAUSS, 3), -0.2, 0.2)}


def miscalibrated(rec, e):
    """The recording as a sensor with errors ``e`` would have read it (body frame, nominal units)."""
    from imucald.files.recording import Recording
    return Recording(rec.t, rec.acc * e["acc_scale"] + e["acc_bias_g"], rec.gyro * e["gyro_scale"] + e["gyro_bias_dps"],
                     rec.mag @ e["mag_soft"].T + e["mag_hard_gauss"], None, dict(rec.meta))


def self_calibration(rec, seed):
    """imucald's calibration from the recording itself, as ``imucald calibrate`` fits it: the
    gyro bias from the still poses (--sensor gyro, model mean), the magnetometer from the
    rotation cloud (--sensor mag, mag_sym) when the rotation covers the share of the sphere
    the daemon waits for (calibration.mag_min_coverage, 50 %), the accelerometer from the
    still poses when there are the 10 it needs (--sensor accel); returns (Calibration, what
    was fitted or why not)."""
    from imucald.fitting.fit import fit_gyro_bias, fit_norm
    from imucald.fitting.magcal import calibrate_rotation
    from imucald.fitting.stillness.poses import poses_and_pieces
    from imucald.calibration import Calibration, SensorCal
    poses, _ = poses_and_pieces(rec)
    parts, what = {}, []
    if len(poses):
        parts["gyro"] = SensorCal.from_fit(fit_gyro_bias(poses.gyro, poses.n, poses.gyro_cov))
        what.append(f"gyro bias ({len(poses)} still pose{'s' if len(poses) > 1 else ''})")
    if len(poses) >= 10:
        parts["accel"] = SensorCal.from_fit(fit_norm(poses.acc, "triangular9", "ga", pose_cov=poses.acc_cov, rng=seed))
        what.append("accel")
    else:
        what.append(f"accel: not fitted ({len(poses)} poses < 10)")
    from imucald.daemon.config import DEFAULTS
    need = DEFAULTS["calibration"]["mag_min_coverage"]
    res = calibrate_rotation(rec.mag, "mag_sym", "ga", rng=seed)
    cov = res["coverage"]["fraction"]
    if res["determined"] and cov >= need:
        parts["mag"] = SensorCal.from_fit(res["calibration"])
        what.append(f"mag ({cov:.0%} of the sphere)")
    else:
        what.append(f"mag: not fitted ({cov:.0%} of the sphere < {need:.0%})")
    return Calibration(rec.meta.get("board", "unknown"), {}, id=1, **parts), what


def study(paths, seed):
    print("\n3. what calibration buys: each trial with a drawn MPU-9250-class miscalibration (seed "
          f"{seed} + trial index); 9D RMSE, deg, raw vs after imucald's calibration from the trial itself")
    print(f"{'trial':<40} {'raw total':>9} {'incl':>6} | {'calibrated total':>16} {'incl':>6} | "
          f"{'truth total':>11} {'incl':>6} | fitted from the trial")
    rows = []
    for i, p in enumerate(paths):
        tr = broad.load(p)
        rec = broad.to_recording(tr)
        bad = miscalibrated(rec, miscalibration(np.random.default_rng(seed + i)))
        raw = broad.score(run_pipeline(bad)["q"].astype(float), tr)
        cal, what = self_calibration(bad, seed)
        fixed = broad.score(run_pipeline(bad, cal)["q"].astype(float), tr)
        truth = broad.score(run_pipeline(rec)["q"].astype(float), tr)
        rows.append([raw[0], raw[2], fixed[0], fixed[2], truth[0], truth[2]])
        print(f"{tr['name']:<40} {raw[0]:9.2f} {raw[2]:6.2f} | {fixed[0]:16.2f} {fixed[2]:6.2f} | "
              f"{truth[0]:11.2f} {truth[2]:6.2f} | {', '.join(what) or 'nothing'}", flush=True)
    mu = np.array(rows).mean(0)
    print(f"{'mean':<40} {mu[0]:9.2f} {mu[1]:6.2f} | {mu[2]:16.2f} {mu[3]:6.2f} | {mu[4]:11.2f} {mu[5]:6.2f} |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", default=broad.BROAD_DIR, help="directory of BROAD .hdf5 trials")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-cpu", action="store_true")
    ap.add_argument("--mips", type=float, help="this machine's 7z b -mmt1 rating (bench/budget.py)")
    ap.add_argument("--skip-study", action="store_true")
    ap.add_argument("--seed", type=int, default=26, help="seed of the miscalibrations drawn")
    ap.add_argument("--compare-still", action="store_true",
                    help="also run without imucald's still intervals fed to the filter's bias")
    a = ap.parse_args()
    paths = broad.trials(a.trials)
    if not paths:
        print(f"no BROAD trials in {a.trials}")
        return 1
    if not a.skip_accuracy:
        accuracy(paths, a.compare_still)
    if not a.skip_cpu:
        cpu(paths, a.repeats, a.mips)
    if not a.skip_study:
        study(paths, a.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
