"""BROAD trials (Laidig et al., Data 2021, CC BY 4.0; ../shared/data/real/broad/SOURCE.md) as
imucald recordings, and BROAD's official error metric.

    python bench/broad.py TRIAL.hdf5 -o trial.csv     # then: imucald replay trial.csv

The HDF5 files hold SI units (m/s^2, rad/s, uT) at 285.714 Hz with the optical reference
``opt_quat`` ([w, x, y, z], sensor -> ENU) and the ``movement`` mask.  The recording gets the
imucald units (g = 9.80665 m/s^2, deg/s, gauss = 100 uT), ``board: unknown`` (the myon aktos-t
is none of imucald's boards, so no datasheet figure is assumed) and the trial's rate.  h5py is
needed here (the ``test`` and ``bench`` extras), never by imucald at run time.
"""
import argparse
import os
import sys

from _common import np

from imucald.orientation.quat import error_angles_rad, rmse_deg
from imucald.files.recording import Recording, write_recording

#: standard gravity, m/s^2 per g; 1 gauss = 100 uT
G_MS2 = 9.80665
UT_PER_GAUSS = 100.0

HERE = os.path.dirname(os.path.abspath(__file__))
BROAD_DIR = os.path.normpath(os.path.join(HERE, "..", "..", "shared", "data", "real", "broad"))


def trials(directory=BROAD_DIR):
    """The HDF5 trials in ``directory``, sorted by name ([] when it is absent)."""
    if not os.path.isdir(directory):
        return []
    return sorted(os.path.join(directory, f) for f in os.listdir(directory) if f.endswith(".hdf5"))


def load(path):
    """One trial: dict of rate_hz, acc_ms2, gyr_rads, mag_ut, q_ref, movement, name."""
    try:
        import h5py
    except ImportError:
        sys.exit("bench/broad.py: reading BROAD's HDF5 needs h5py: pip install h5py "
                 "(or pip install 'imucald[test]')")
    with h5py.File(path, "r") as f:
        return {"rate_hz": float(f.attrs["sampling_rate"]), "acc_ms2": f["imu_acc"][:],
                "gyr_rads": f["imu_gyr"][:], "mag_ut": f["imu_mag"][:], "q_ref": f["opt_quat"][:],
                "movement": f["movement"][:].astype(bool),
                "name": os.path.basename(path)[:-5]}


def to_recording(tr, mag=True):
    """The trial as an imucald Recording (g, deg/s, gauss; t from the sample index)."""
    n = len(tr["acc_ms2"])
    meta = {"board": "unknown", "rate_hz": f"{tr['rate_hz']:.9g}",
            "source": f"BROAD {tr['name']} (Laidig et al., Data 2021, CC BY 4.0), myon aktos-t"}
    return Recording(np.arange(n) / tr["rate_hz"], tr["acc_ms2"] / G_MS2, np.degrees(tr["gyr_rads"]),
                     tr["mag_ut"] / UT_PER_GAUSS if mag else None, None, meta)


def score(q_est, tr):
    """BROAD's metric over the movement phase: (total, heading, inclination) RMSE, degrees."""
    tot, hd, inc = error_angles_rad(q_est, tr["q_ref"])
    m = tr["movement"]
    return rmse_deg(tot, m), rmse_deg(hd, m), rmse_deg(inc, m)


def main(argv=None):
    ap = argparse.ArgumentParser(description="convert a BROAD trial to an imucald recording")
    ap.add_argument("trial", help="a BROAD .hdf5 file")
    ap.add_argument("-o", "--output", required=True, help="the recording to write")
    ap.add_argument("--no-mag", action="store_true", help="leave the magnetometer out (a 6D board)")
    a = ap.parse_args(argv)
    rec = to_recording(load(a.trial), mag=not a.no_mag)
    write_recording(rec, a.output)
    print(f"wrote {a.output}: {len(rec)} samples at {rec.rate_hz:.6g} Hz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
