"""Thermal terms learnt passively by the daemon (issue 11, acceptance).

A simulated MPU-6050 session (60 poses, heat then cool over --rise degC, accelerometer
thermal bias --acc-mg mg/degC and gyro thermal bias --gyro-dps deg/s/degC per axis, signs
and axis weights drawn per seed) is replayed through the daemon's pipeline twice: with
the default calibration.thermal_min_span_c (10 degC) and with a minimum above the span
(constant only).  From the stream itself (the hot path's corrected output), over the
still samples after the thermal terms were first applied, per still run: |a| - 1 g and
the gyro's mean rate; the figures are the RMS over runs (and per 2 degC bin), the ratio
between the two replays, and the same with a span below the minimum (--rise-small).
Usage: python bench/thermal.py [--seeds 5]
"""
import argparse
import copy
import json

from _common import np

from imucald.daemon.config import DEFAULTS
from imucald.daemon.pipeline import Pipeline
from imucald.drivers.board import SampleBatch
from imucald.sim.effects import effect_session
from imucald.sim.orientations import random_pose_set


def session(seed, rise, acc_mg, gyro_dps, poses=60, rate_hz=100.0, truth=False):
    """The recording (with ``truth``: and the true thermal coefficients, accel g/degC and
    gyro deg/s/degC, in the raw frame the calibration's terms are in)."""
    rng = np.random.default_rng(seed)
    s, eff = effect_session("mpu6050", random_pose_set(poses, rng), rng,
                            [("accel.thermal_bias", acc_mg * 1e-3), ("gyro.thermal_bias", gyro_dps)],
                            rate_hz, (6.4, 9.6), (2.1, 3.9), "heatcool", rise)
    if not truth:
        return s.recording
    coef = {e["name"]: np.asarray(e["params"]["coef"], float) for e in eff}
    # the simulator adds both to the raw reading (sim/sensor.py: after the sensor's matrix),
    # where the calibration subtracts its terms (calibration.py thermal_offset)
    return s.recording, {"accel": coef["accel.thermal_bias"], "gyro": coef["gyro.thermal_bias"]}


def replay(rec, min_span_c, applied=None):
    """The pipeline as `imucald replay` runs it; returns (pipeline, IMU lines, the first
    calibration id carrying thermal terms or None).  ``applied``: start with this
    calibration and calibrate no more (the next day's stream)."""
    cfg = copy.deepcopy(DEFAULTS)
    cfg["calibration"]["method"] = "lm"
    cfg["calibration"]["thermal_min_span_c"] = float(min_span_c)
    has_mag = rec.mag is not None
    pipe = Pipeline(cfg, rec.meta.get("board", "mpu6050"), rec.rate_hz, has_mag)
    if applied is not None:
        cfg["calibration"]["min_poses"] = 500          # never ready: no job is started
        pipe.applied = applied
    step = max(1, int(round(cfg["sensor"]["batch_s"] * rec.rate_hz)))
    out, first = [], None
    # a new magnetometer reading differs from the one before it (as `imucald replay` tells)
    fresh = None if not has_mag else np.r_[True, np.any(np.diff(rec.mag, axis=0) != 0, axis=1)]
    for i in range(0, len(rec), step):
        sl = slice(i, i + step)
        b = SampleBatch(rec.t[sl], np.arange(i, min(i + step, len(rec))), rec.acc[sl], rec.gyro[sl],
                        rec.temp[sl], None if not has_mag else rec.mag[sl], None if not has_mag else fresh[sl])
        out.append(pipe.process(b))
        a = pipe.applied
        if first is None and a.accel is not None and a.accel.thermal and a.accel.thermal["order"]:
            first = a.id
    out.append(pipe.end_of_stream())
    lines = [json.loads(x) for x in b"".join(out).splitlines() if x.startswith(b'{"class":"IMU"')]
    return pipe, lines, first


def still_runs(lines, from_id):
    """Per still run (from calibration from_id on): mean |a| - 1 (g), mean gyro (dps), mean T."""
    runs, cur = [], []
    for d in lines:
        if d["still"] and d["cal"] >= from_id:
            cur.append(d)
        elif cur:
            runs.append(cur)
            cur = []
    if cur:
        runs.append(cur)
    out = []
    for r in runs:
        if len(r) < 100:
            continue
        # the middle half: the accelerometer-led still flag keeps the slow ends of a turn,
        # whose rate a gyro mean would carry (gap/gyrostill.py cuts them the same way)
        r = r[len(r) // 4:len(r) - len(r) // 4]
        a = np.array([x["acc_g"] for x in r])
        g = np.array([x["gyro_dps"] for x in r])
        out.append((float(np.mean(np.linalg.norm(a, axis=1)) - 1), g.mean(0), float(np.mean([x["temp_c"] for x in r]))))
    return out


def binned(runs, k):
    T = np.array([r[2] for r in runs])
    v = np.array([np.linalg.norm(np.atleast_1d(r[k])) for r in runs])
    edges = np.arange(np.floor(T.min()), T.max() + 2, 2.0)
    return [(float(e), float(np.sqrt(np.mean(v[(T >= e) & (T < e + 2)] ** 2))))
            for e in edges if np.any((T >= e) & (T < e + 2))]


def rms(runs, k):
    return float(np.sqrt(np.mean([np.sum(np.atleast_1d(r[k]) ** 2) for r in runs])))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--rise", type=float, default=15.0)
    ap.add_argument("--rise-small", type=float, default=7.0)
    ap.add_argument("--acc-mg", type=float, default=0.75)
    ap.add_argument("--gyro-dps", type=float, default=0.02)
    a = ap.parse_args()
    ra, rg, sa, sg = [], [], [], []
    for seed in range(a.seeds):
        rec = session(seed, a.rise, a.acc_mg, a.gyro_dps)
        pipe, lines, first = replay(rec, 10.0)
        if first is None:
            print(f"seed {seed}: thermal terms not learnt: {pipe.thermal_status()}")
            continue
        p0, lines0, _ = replay(rec, 1e3)
        t_first = next(d["t"] for d in lines if d["cal"] >= first)
        th = still_runs(lines, first)
        c0 = still_runs([d for d in lines0 if d["t"] >= t_first], 0)
        acc = (rms(c0, 0) * 1e3, rms(th, 0) * 1e3)
        gyr = (rms(c0, 1), rms(th, 1))
        ra.append(acc[0] / acc[1])
        rg.append(gyr[0] / gyr[1])
        st = pipe.thermal_status()
        print(f"seed {seed}: learnt at calibration #{first} ({st['accel']['note'].split(':')[0]}, "
              f"{st['accel']['t_min_c']:.1f}..{st['accel']['t_max_c']:.1f} degC; gyro "
              f"{st['gyro']['note'].split(':')[0]}); {len(th)} still runs after it")
        print(f"  still |a| - 1 g RMS: constant only {acc[0]:.3f} mg -> thermal {acc[1]:.3f} mg "
              f"({acc[0] / acc[1]:.1f}x); gyro still rate RMS {gyr[0]:.4f} -> {gyr[1]:.4f} deg/s "
              f"({gyr[0] / gyr[1]:.1f}x)")
        print("  per 2 degC bin, |a| error mg (constant -> thermal): " + ", ".join(
            f"{e:.0f}: {x * 1e3:.2f}->{y * 1e3:.2f}" for (e, x), (_, y) in zip(binned(c0, 0), binned(th, 0))))
        print("  per 2 degC bin, gyro rate deg/s (constant -> thermal): " + ", ".join(
            f"{e:.0f}: {x:.4f}->{y:.4f}" for (e, x), (_, y) in zip(binned(c0, 1), binned(th, 1))))
        # once learnt: the same session streamed again with each daemon's final calibration
        th2 = still_runs(replay(rec, 1e3, pipe.applied)[1], 0)
        c02 = still_runs(replay(rec, 1e3, p0.applied)[1], 0)
        acc2, gyr2 = (rms(c02, 0) * 1e3, rms(th2, 0) * 1e3), (rms(c02, 1), rms(th2, 1))
        sa.append(acc2[0] / acc2[1])
        sg.append(gyr2[0] / gyr2[1])
        print(f"  the whole session again with the final calibrations: |a| {acc2[0]:.3f} -> {acc2[1]:.3f} mg "
              f"({sa[-1]:.1f}x), gyro {gyr2[0]:.4f} -> {gyr2[1]:.4f} deg/s ({sg[-1]:.1f}x)")
    if ra:
        print(f"shrink over {len(ra)} seeds: accel |a| error median {np.median(ra):.1f}x (min {min(ra):.1f}x), "
              f"gyro rate median {np.median(rg):.1f}x (min {min(rg):.1f}x); target >= 5x")
        print(f"with the final calibrations over the whole session: accel median {np.median(sa):.1f}x "
              f"(min {min(sa):.1f}x), gyro median {np.median(sg):.1f}x (min {min(sg):.1f}x)")
    # a span below the minimum: only a constant
    for seed in range(min(a.seeds, 3)):
        rec = session(100 + seed, a.rise_small, a.acc_mg, a.gyro_dps)
        pipe, _, first = replay(rec, 10.0)
        ap_ = pipe.applied
        terms = [s for s in ("accel", "gyro") if ap_.part(s) is not None and ap_.part(s).thermal
                 and ap_.part(s).thermal.get("order")]
        print(f"span {pipe.thermal_log.span_c():.1f} degC (seed {100 + seed}): calibration #{ap_.id}, "
              f"thermal terms applied: {terms or 'none'}; status: {pipe.thermal_status().get('why')}")


if __name__ == "__main__":
    main()
