"""Error rates of the stillness detector on simulated sessions with known truth, by class of
session, over seeds (the detector as calibrate runs it: fitting.stillness.poses.detect).

Per class: true holds found whole (exactly one pose inside the hold), split (several), lost
(none); false still time (pose samples outside every true hold, over the time outside the
holds); the pose-mean bias the detector lets in, noise-free: | |mean true specific force
over the pose's rows| - 1 g | (motion samples in a pose show here; a hand's sway adds
~theta^2, 0.01-0.1 mg), median and max, mg; the worst rotation within a pose, deg (the
true orientation's largest angle from its mean over the pose's rows).  Tumbles and slow
turns (no hold at all): poses per session must be 0.

Classes: bench holds (10 s, no tremor); hand-held (1.5-3 s holds, tremor 1-3 deg/s RMS,
sway 0.05-0.4 deg RMS at 0.2-2 Hz: sim.motion.PoseTour; and at a fixed sway of 0.25 and 0.4
deg with 2 deg/s of tremor); both at 25 Hz; a warming gyro
(temperature +15 C, 0.1 deg/s/C: 1.5 deg/s of bias drift; and hand-held with 4-8 s holds,
0.3 deg of sway, +17 C); sample-and-hold loggers (2-4x);
duplicated rows (30 % of the rows logged twice); slow tumbles (15-60 deg/s) and slow turns
(2-10 deg/s, no linear acceleration) with the gyro at 100 Hz.
Usage: python bench/stillness_holds.py [SEEDS]   (default 20)
"""
import sys

from _common import np

from imucald.fitting.stillness.poses import detect
from imucald.sim.effects import make_effect
from imucald.sim.orientations import random_pose_set
from imucald.sim.sensor import hold_samples, simulate_session, simulate_tumble
from imucald.files.recording import Recording


def _session(seed, hand, rate=100.0, drift=False, board="mpu6050", sway=None, long_holds=False):
    rng = np.random.default_rng(seed)
    kw = dict(hold_s=(1.5, 3.0), move_s=(1.5, 3.0), tremor_dps=float(rng.uniform(1.0, 3.0)),
              sway_deg=float(rng.uniform(0.05, 0.4))) if hand else dict(hold_s=10.0, move_s=2.0)
    if sway is not None:
        kw.update(sway_deg=sway, tremor_dps=2.0)
    if long_holds:
        kw.update(hold_s=(4.0, 8.0))
    eff = []
    if drift:
        e = make_effect("gyro.thermal_bias", 0.1, rng)
        eff = [e["apply"]]
        kw.update(temp_kind="warmup", temp_rise_c=17.0 if long_holds else 15.0)
    n = 20 if hand else 10
    return simulate_session(board, random_pose_set(n, rng), rng, rate_hz=rate, lead_s=0.0,
                            effects=eff, **kw)


def _duplicated(rec, rng):
    k = 1 + (rng.random(len(rec.t)) < 0.3)
    idx = np.repeat(np.arange(len(rec.t)), k)
    return Recording(t=rec.t[idx], acc=rec.acc[idx], gyro=rec.gyro[idx], temp=rec.temp[idx],
                     meta=dict(rec.meta)), idx


def _judge(rec, f_rows, holds, chip, tot, w_rows):
    """Add one session's counts to tot.  f_rows, w_rows: the true specific force (g) and
    angular rate (deg/s) of each row."""
    ivs, _, _ = detect(rec.t, rec.acc, rec.gyro, rec.rate_hz, chip=chip)
    t = rec.t
    spans = [(t[iv.i0], t[iv.i1 - 1], iv) for iv in ivs]
    dt = 1.0 / rec.rate_hz
    for h0, h1 in holds:
        k = sum(a < h1 and b > h0 for a, b, _ in spans)
        tot["holds"] += 1
        tot["whole" if k == 1 else "split" if k > 1 else "lost"] += 1
    inhold = np.zeros(len(t), bool)
    for h0, h1 in holds:
        inhold |= (t >= h0 - dt) & (t <= h1 + dt)
    for a, b, iv in spans:
        rows = np.arange(iv.i0, iv.i1)
        out = rows[~inhold[rows]]
        tot["false_s"] += len(np.unique(t[out])) * dt
        f = f_rows[rows]
        m = f.mean(0)
        tot["bias_mg"].append(abs(np.linalg.norm(m) - 1.0) * 1e3)
        tt = t[rows]
        th = np.concatenate([[np.zeros(3)], np.cumsum(w_rows[rows][:-1] * np.diff(tt)[:, None], 0)])
        tot["turn_deg"].append(float(np.sqrt(((th - th.mean(0)) ** 2).sum(1)).max()))
    tot["moving_s"] += (t[-1] - t[0]) - sum(h1 - h0 for h0, h1 in holds)
    tot["poses"] += len(ivs)


def _line(name, tot):
    b = np.array(tot["bias_mg"] or [np.nan])
    r = np.array(tot["turn_deg"] or [np.nan])
    h = max(tot["holds"], 1)
    return (f"{name:<34} holds {tot['holds']:4d}: whole {tot['whole'] / h:6.1%} split {tot['split'] / h:6.1%} "
            f"lost {tot['lost'] / h:6.1%}; false still {tot['false_s'] / max(tot['moving_s'], 1e-9):6.2%} "
            f"of moving time; pose |f|-1g median {np.nanmedian(b):.3f} max {np.nanmax(b):.2f} mg; "
            f"true turn in pose max {np.nanmax(r):.2f} deg from its mean")


def _new():
    return {"holds": 0, "whole": 0, "split": 0, "lost": 0, "false_s": 0.0, "moving_s": 0.0,
            "bias_mg": [], "turn_deg": [], "poses": 0}


def holds_classes(seeds):
    classes = {
        "bench 10 s, 100 Hz": dict(hand=False),
        "bench 10 s, 9dof (adxl345)": dict(hand=False, board="9dof"),
        "hand-held 1.5-3 s, 100 Hz": dict(hand=True),
        "hand-held, sway 0.25 deg, tremor 2": dict(hand=True, sway=0.25),
        "hand-held, sway 0.4 deg, tremor 2": dict(hand=True, sway=0.4),
        "bench 10 s, 25 Hz": dict(hand=False, rate=25.0),
        "hand-held 1.5-3 s, 25 Hz": dict(hand=True, rate=25.0),
        "bench, warming gyro": dict(hand=False, drift=True),
        "hand-held, warming gyro": dict(hand=True, drift=True),
        "hand 4-8 s, sway 0.3, warming 17 C": dict(hand=True, drift=True, sway=0.3, long_holds=True),
    }
    chip = {"mpu6050": "mpu6050", "9dof": "adxl345"}
    for name, kw in classes.items():
        tot = _new()
        for s in range(seeds):
            ss = _session(5000 + s, **kw)
            _judge(ss.recording, ss.specific_force_g, ss.hold, chip[kw.get("board", "mpu6050")], tot, ss.rate_dps)
        print(_line(name, tot), flush=True)
    for hand in (False, True):
        tot, dup = _new(), _new()
        for s in range(seeds):
            ss = _session(6000 + s, hand)
            rec = ss.recording
            factor = 2.0 + 2.0 * (s % 5) / 4
            h = hold_samples(rec, factor * rec.rate_hz, phase=0.37)
            src = np.clip(np.searchsorted(rec.t, h.t + 1e-9, side="right") - 1, 0, len(rec.t) - 1)
            _judge(h, ss.specific_force_g[src], ss.hold, "mpu6050", tot, ss.rate_dps[src])
            d, idx = _duplicated(rec, np.random.default_rng(s))
            _judge(d, ss.specific_force_g[idx], ss.hold, "mpu6050", dup, ss.rate_dps[idx])
        kind = "hand-held" if hand else "bench"
        print(_line(f"{kind}, sample-and-hold 2-4x", tot), flush=True)
        print(_line(f"{kind}, 30 % rows duplicated", dup), flush=True)


def motion_classes(seeds):
    for name, speed, acc_g in (("tumble 15-60 deg/s", (15.0, 60.0), 0.05), ("slow turn 2-10 deg/s", (2.0, 10.0), 0.0),
                               ("slow turn 0.5-3 deg/s", (0.5, 3.0), 0.0)):
        for rate in (100.0, 25.0):
            any_pose = poses = 0
            turn = []
            for s in range(seeds):
                ss = simulate_tumble("mpu6050", np.random.default_rng(7000 + s), rate_hz=rate, duration_s=60,
                                     speed_dps=speed, move_accel_g=acc_g)
                tot = _new()
                _judge(ss.recording, ss.specific_force_g, [], "mpu6050", tot, ss.rate_dps)
                any_pose += tot["poses"] > 0
                poses += tot["poses"]
                turn += tot["turn_deg"]
            print(f"{name} with gyro, {rate:g} Hz: {any_pose}/{seeds} sessions with a pose, {poses} poses"
                  + (f", true turn within them up to {max(turn):.1f} deg from their mean" if turn else ""), flush=True)


def main():
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    print(f"seeds per class: {seeds}")
    holds_classes(seeds)
    motion_classes(seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
