"""The stillness detector on BROAD's real recordings, judged by their optical reference
(Laidig et al., Data 2021, CC BY 4.0; ../shared/data/real/broad/SOURCE.md; h5py needed).

Each trial is a myon aktos-t (no datasheet figure assumed: generic bounds) at 285.7 Hz: rest
at the start and end, 85-130 s of movement between (slow or fast rotation, translation without
rotation, some with 10-s breaks, tapping, magnets).  For every pose found as calibrate finds
them (fitting.stillness.poses.detect): its true rotation, the largest angle between the
optical orientation at any of its samples and at its middle sample (NaN reference rows
skipped); its seconds inside the movement phase.  Printed per trial: poses, poses that
turn more than 3 deg by the reference, the largest true turn, and the pose seconds in the
movement phase.
Usage: python bench/stillness_broad.py
"""
import os
import sys

from _common import np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from broad import load, to_recording, trials  # noqa: E402

from imucald.fitting.stillness.poses import detect  # noqa: E402


def _turn_deg(q):
    """Largest rotation angle between the unit quaternions q (n, 4) and the middle one, deg."""
    q = q[np.all(np.isfinite(q), axis=1)]
    if len(q) < 2:
        return float("nan")
    q = q / np.linalg.norm(q, axis=1)[:, None]
    c = np.clip(np.abs(q @ q[len(q) // 2]), 0.0, 1.0)
    return float(np.degrees(2 * np.arccos(c.min())))


def main():
    paths = trials()
    if not paths:
        print("skipped: ../shared/data/real/broad is absent")
        return 0
    tot = {"poses": 0, "turned": 0, "move_s": 0.0}
    for p in paths:
        tr = load(p)
        rec = to_recording(tr)
        ivs, _, _ = detect(rec.t, rec.acc, rec.gyro, rec.rate_hz, mag=rec.mag, chip=None)
        turns = [_turn_deg(tr["q_ref"][iv.i0:iv.i1]) for iv in ivs]
        mv = sum(int(tr["movement"][iv.i0:iv.i1].sum()) for iv in ivs) / rec.rate_hz
        big = sum(t > 3.0 for t in turns)
        tot["poses"] += len(ivs)
        tot["turned"] += big
        tot["move_s"] += mv
        print(f"{tr['name']:<52} {len(ivs):3d} poses, {big:2d} turning > 3 deg (largest "
              f"{np.nanmax(turns) if turns else float('nan'):5.2f} deg), {mv:6.1f} s of poses in the movement phase",
              flush=True)
    print(f"all trials: {tot['poses']} poses, {tot['turned']} turning > 3 deg, {tot['move_s']:.1f} s in movement")
    return 0


if __name__ == "__main__":
    sys.exit(main())
