"""The daemon's pipeline on boards whose magnetometer is calibrated from rotation:
the GY-273 (a QMC5883L alone) and the 9DOF board carrying a QMC5883L."""
import numpy as np

from imucald.daemon.config import load_config
from imucald.daemon.pipeline import Pipeline
from imucald.drivers.board import make_board
from imucald.drivers.bus import Bus, VirtualClock
from imucald.sim.emulators import emulated_board
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import random_pose_set
from imucald.specs import MAG


def _run(board, tour, seconds, seed=4, mag=None):
    cfg = load_config(None)
    clk = VirtualClock()
    eb = emulated_board(board, tour, rng=seed, clock=clk, mag=mag)
    b = make_board(board, Bus(eb, "emu", clock=clk), rate_hz=100.0)
    b.start()
    pipe = Pipeline(cfg, b.name, b.rate_hz, b.has_mag, chips=b.chips(), has_acc=b.has_acc)
    raw, out = [], []
    while clk.now() < seconds:
        bt = b.read_batch(True, 0.1)
        out.append(pipe.process(bt))
        if len(bt) and bt.mag_fresh.any():
            raw.append(bt.mag[bt.mag_fresh])
    return eb, b, pipe, np.vstack(raw), b"".join(out)


def test_gy273_calibrates_from_rotation_alone():
    tour = PoseTour(random_pose_set(30, 1), rng=1, hold_s=(0.5, 1.0), move_s=(1.0, 2.0), lead_s=0.5)
    eb, b, pipe, raw, stream = _run("gy273", tour, 60.0)
    assert b.chips() == {"mag": "qmc5883l"} and not b.has_acc
    ap = pipe.applied
    assert ap.id >= 1 and ap.mag is not None, list(pipe.events)
    assert len(pipe.acc) == 0                                   # no still poses were needed
    tr = eb.truth
    # corrected field magnitude: the truth's F, to the noise-limited accuracy
    h = ap.apply_mag(raw[-500:])
    F = tour.sample(np.array([0.0]))["h"]
    F = float(np.linalg.norm(F))
    sigma = MAG["qmc5883l"].noise_gauss
    assert abs(np.linalg.norm(h, axis=1).mean() / F - 1) < 0.02
    assert np.linalg.norm(h, axis=1).std() < 2.5 * sigma
    assert np.allclose(ap.mag.params["hard_iron_gauss"], tr.mag_hard_iron_gauss, atol=6 * sigma)
    assert b'"acc_g"' not in stream and b'"mag_gauss"' in stream
    doc = pipe.applied.to_dict()
    assert doc["chips"]["mag"] == "qmc5883l"
    assert doc["mag"]["quality"]["coverage_min_eigenvalue"] > 0.05       # a 3-D cloud


def test_gy273_flat_swing_is_not_applied():
    # turning about the vertical only: the reservoir cloud is one ring
    ang = np.radians(np.arange(0, 360, 10.0))
    Rz = np.array([[[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]] for a in ang])
    tour = PoseTour(Rz, rng=1, hold_s=0.2, move_s=0.3, lead_s=0.1, loop=True)
    eb, b, pipe, raw, _ = _run("gy273", tour, 40.0)
    assert pipe.reservoir.coverage() < 0.5           # a ring reaches few cells
    assert pipe.request_calibration()
    pipe.process(b.read_batch(True, 0.1))
    assert pipe.applied.id == 0
    assert any("one plane" in e for e in pipe.events), list(pipe.events)


def test_nine_dof_with_qmc_reaches_an_accel_and_mag_calibration():
    tour = PoseTour(random_pose_set(30, 2), rng=2, hold_s=(3.0, 4.0), move_s=(1.2, 1.8), lead_s=1.0)
    eb, b, pipe, raw, stream = _run("9dof", tour, tour.period, mag="qmc5883l")
    assert b.chips()["mag"] == "qmc5883l"
    pipe.request_calibration()
    pipe.process(b.read_batch(True, 0.1))
    ap = pipe.applied
    assert ap.accel is not None and ap.mag is not None, list(pipe.events)
    h = ap.apply_mag(raw[-300:])
    F = float(np.linalg.norm(tour.sample(np.array([0.0]))["h"]))
    assert abs(np.linalg.norm(h, axis=1).mean() / F - 1) < 0.02
