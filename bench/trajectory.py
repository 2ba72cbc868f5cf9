"""The trajectory generator's statistics, as the simulator and the emulators see it.

Prints, over a few seeds, for ``simulate_session`` (sampled at the logger's 100 Hz) and for
the emulators' looped ``PoseTour`` (sampled at 100 Hz as a chip would): hold lengths against
the drawn range, the tremor's RMS rate per axis (whole session and per 2-s window in the
holds), the fraction of its power in 6-12 Hz, its excess kurtosis (0: Gaussian), the still
gyro's per-hold standard deviation (what tests/test_stillness.py and test_hand_held.py
check), and the pose directions' coverage (the largest angle from any direction to the
nearest pose).  Only public APIs, so the same script runs on an older tree for a before/after.

    python bench/trajectory.py [--seeds 5]
"""
import argparse

import _common  # noqa: F401  (puts the repository on sys.path)
import numpy as np

from imucald.sim.motion import PoseTour
from imucald.sim.orientations import random_pose_set, up_vectors
from imucald.sim.sensor import simulate_session

RATE_HZ = 100.0
HOLD_S = (6.0, 10.0)
TREMOR_DPS = 1.5


def _hold_rates(t, w, holds, trim_s=0.0):
    return [w[(t >= a + trim_s) & (t <= b - trim_s)] for a, b in holds]


def _tremor_figures(pieces):
    """RMS per axis, per-2-s-window RMS percentiles, 6-12 Hz power fraction, excess kurtosis."""
    x = np.concatenate([p - p.mean(0) for p in pieces])
    rms = np.sqrt((x ** 2).mean(0))
    win = int(2 * RATE_HZ)
    wr = [np.sqrt((p[i:i + win] ** 2).mean(0)).mean() for p in pieces
          for i in range(0, len(p) - win + 1, win)]
    band = tot = 0.0
    for p in pieces:
        if len(p) < 64:
            continue
        P = np.abs(np.fft.rfft(p - p.mean(0), axis=0)) ** 2
        f = np.fft.rfftfreq(len(p), 1 / RATE_HZ)
        band += P[(f >= 5.9) & (f <= 12.1)].sum()
        tot += P[f > 0].sum()
    k = ((x ** 4).mean(0) / (x ** 2).mean(0) ** 2 - 3).mean()
    return rms, np.percentile(wr, [10, 50, 90]), band / tot, k


def _coverage_deg(R, probes):
    ups = up_vectors(R)
    return float(np.degrees(np.arccos(np.clip((probes @ ups.T).max(1), -1, 1))).max())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    a = ap.parse_args(argv)
    probes = np.random.default_rng(99).normal(size=(4000, 3))
    probes /= np.linalg.norm(probes, axis=1, keepdims=True)
    for src in ("simulate_session", "PoseTour (emulators)"):
        lens, pieces, gstd, cover = [], [], [], []
        for seed in range(a.seeds):
            rng = np.random.default_rng(seed)
            R = random_pose_set(30, rng)
            cover.append(_coverage_deg(R, probes))
            if src == "simulate_session":
                s = simulate_session("mpu6050", R, rng, rate_hz=RATE_HZ, hold_s=HOLD_S, move_s=(2, 4),
                                     lead_s=0.0, tremor_dps=TREMOR_DPS)
                t, w, holds = s.recording.t, s.rate_dps, s.hold
                lens += [b - a + 1 / RATE_HZ for a, b in holds]
                gstd += [p.std(0).mean() for p in _hold_rates(t, s.recording.gyro, holds, 0.3)]
            else:
                tour = PoseTour(R, rng=rng, hold_s=HOLD_S, move_s=(2, 4), lead_s=0.0, loop=True,
                                tremor_dps=TREMOR_DPS)
                t = np.arange(0, tour.duration_s, 1 / RATE_HZ)
                w, holds = tour.sample(t)["w"], tour.holds()
                lens += [b - a for a, b in holds]
            pieces += _hold_rates(t, w, holds)
        rms, wr, band, kurt = _tremor_figures(pieces)
        lens = np.array(lens)
        print(f"{src}: {a.seeds} seeds x 30 poses, hold_s={HOLD_S}, tremor {TREMOR_DPS} dps at {RATE_HZ:g} Hz")
        print(f"  hold length: mean {lens.mean():.2f} s, sd {lens.std():.2f} s, range {lens.min():.2f}-"
              f"{lens.max():.2f} s (uniform {HOLD_S}: mean {np.mean(HOLD_S):.2f}, sd "
              f"{(HOLD_S[1] - HOLD_S[0]) / np.sqrt(12):.2f})")
        print(f"  tremor rate in the holds: RMS per axis {np.round(rms, 3).tolist()} dps; per 2-s window "
              f"10/50/90 % {wr[0]:.2f}/{wr[1]:.2f}/{wr[2]:.2f} dps; {100 * band:.1f} % of the power in "
              f"6-12 Hz; excess kurtosis {kurt:+.2f}")
        if gstd:
            print(f"  still gyro sd per hold (0.3 s trimmed), mean over axes: median {np.median(gstd):.3f} dps, "
                  f"10-90 % {np.percentile(gstd, 10):.3f}-{np.percentile(gstd, 90):.3f}")
        print(f"  pose coverage: largest angle to the nearest of 30 poses {min(cover):.1f}-{max(cover):.1f} deg")


if __name__ == "__main__":
    main()
