"""QMC5883L driver against its register-accurate emulator, and the boards that carry it."""
import numpy as np
import pytest

from imucald.drivers import qmc5883l
from imucald.drivers.board import make_board
from imucald.drivers.bus import Bus, ChipMismatch, VirtualClock
from imucald.sim.emulators import Faults, emulated_board
from imucald.drivers.probe import detect_board, magnetometer, probe
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import rotation_from_up
from imucald.specs import MAG

R = qmc5883l.REGMAP
NOISE = MAG["qmc5883l"].noise_gauss


def still(temp0=25.0, rise=0.0, tau=100.0):
    Rm = rotation_from_up(np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9]))[None]
    return PoseTour(Rm, rng=0, hold_s=1e6, lead_s=0, temp0_c=temp0, temp_rise_c=rise, temp_tau_s=tau)


def rig(board="gy273", motion=None, faults=None, truth=None, mag=None):
    clk = VirtualClock()
    eb = emulated_board(board, motion or still(), rng=2, clock=clk, faults=faults, truth=truth, mag=mag)
    return eb, Bus(eb, "emu", clock=clk), clk


def test_register_map_matches_datasheet_encodings():
    # ArduPilot's init value: continuous | 100 Hz | OSR 512 | 8 G = 0x01 | 0x08 | 0x00 | 0x10
    assert R.encode("CONTROL1", 0, MODE=1, ODR=2, OSR=0, RNG=1) == 0x19
    # the tomisuarez sketch: continuous, 50 Hz, 2 G, OSR 512
    assert R.encode("CONTROL1", 0, MODE=1, ODR=1, OSR=0, RNG=0) == 0x05
    assert R.encode("CONTROL1", 0, OSR=3) == 0xC0 and R.encode("CONTROL2", 0, SOFT_RST=1) == 0x80
    assert R.encode("CONTROL2", 0, ROL_PNT=1) == 0x40 and R.encode("CONTROL2", 0, INT_ENB=1) == 0x01
    assert [R.decode("STATUS", 1 << b, f) for b, f in enumerate(("DRDY", "OVL", "DOR"))] == [1, 1, 1]
    assert R.CHIP_ID.addr == 0x0D and R.CHIP_ID.reset == 0xFF and R.SET_RESET.addr == 0x0B


def test_identify_and_wrong_id():
    _, bus, _ = rig()
    qmc5883l.QMC5883L(bus).identify()
    _, bus, _ = rig(faults=Faults(wrong_id={0x0D: 0x00}))
    with pytest.raises(ChipMismatch, match=r"0x0D answered CHIP_ID\(0x0D\)=0x00: not a QMC5883L"):
        qmc5883l.QMC5883L(bus).identify()


def test_power_on_standby_then_configured():
    eb, bus, clk = rig()
    q = qmc5883l.QMC5883L(bus)
    clk.advance(0.5)
    assert q.read() == (None, False)                    # standby: no conversion, DRDY clear
    q.setup(range_gauss=8.0, rate_hz=200.0, oversampling=64)
    regs = eb.devices[0x0D].regs
    assert regs[0x09] == R.encode("CONTROL1", 0, MODE=1, ODR=3, RNG=1, OSR=3)
    assert regs[0x0B] == 0x01 and q.rate_hz == 200.0 and q.lsb_per_gauss == 3000
    with pytest.raises(ValueError, match="rate_hz 75: allowed 10, 50, 100, 200"):
        q.setup(rate_hz=75.0)


@pytest.mark.parametrize("rng_g,lsb", [(2.0, 12000), (8.0, 3000)])
def test_field_scaling_and_byte_order(rng_g, lsb):
    eb, bus, clk = rig()
    q = qmc5883l.QMC5883L(bus)
    q.setup(range_gauss=rng_g, rate_hz=100.0)
    truth = eb.truth.mag_raw(still().sample(np.array([0.0]))["h"])[0]
    got = []
    for _ in range(200):
        clk.advance(0.01)
        m, ovl = q.read()
        assert not ovl
        if m is not None:
            got.append(m)
    got = np.array(got)
    assert len(got) >= 190
    # mean of n samples: noise/sqrt(n) plus half an LSB of quantisation, 5 sigma
    tol = 5 * np.hypot(NOISE / np.sqrt(len(got)), 0.5 / lsb)
    assert np.allclose(got.mean(0), truth, atol=tol)
    assert np.allclose(got.std(0), NOISE, rtol=0.25)


def test_data_ready_clears_on_read_and_overrun_is_counted():
    _, bus, clk = rig()
    q = qmc5883l.QMC5883L(bus)
    q.setup(rate_hz=50.0)
    clk.advance(0.03)
    assert q.read()[0] is not None
    s0 = q.skipped
    assert q.read()[0] is None                      # DRDY cleared by reading the data
    clk.advance(0.02 * 3)                          # three conversions, none read
    assert q.read()[0] is not None and q.skipped == s0 + 1
    clk.advance(0.02)
    assert q.read()[0] is not None and q.skipped == s0 + 1


def test_overflow_sets_ovl_and_is_not_returned_as_a_reading():
    from imucald.sim.sensor import draw_truth
    tr = draw_truth("9dof-qmc", 0)
    tr.mag_hard_iron_gauss = np.array([3.0, 0.0, 0.0])      # beyond int16 at 12000 LSB/G
    _, bus, clk = rig(truth=tr)
    q = qmc5883l.QMC5883L(bus)
    q.setup(range_gauss=2.0, rate_hz=100.0)
    clk.advance(0.02)
    assert q.read() == (None, True) and q.overflows == 1
    q.setup(range_gauss=8.0, rate_hz=100.0)                 # 3000 LSB/G: 3 G fits
    clk.advance(0.02)
    m, ovl = q.read()
    assert not ovl and abs(m[0] - 3.0) < 0.5


def test_temperature_is_relative_and_tracks_changes():
    _, bus, clk = rig(motion=still(temp0=20.0, rise=10.0, tau=5.0))
    q = qmc5883l.QMC5883L(bus)
    q.setup(rate_hz=10.0)
    clk.advance(0.2)
    q.read()
    t1 = q.temp_rel_c
    clk.advance(10.0)
    q.read()
    t2 = q.temp_rel_c
    true_rise = 10.0 * (np.exp(-0.2 / 5.0) - np.exp(-10.2 / 5.0))
    assert abs((t2 - t1) - true_rise) < 0.02                # 100 LSB/degC


def test_soft_reset_and_silent_reset_detection():
    eb, bus, clk = rig(faults=Faults(resets={0x0D: [1.0]}))
    q = qmc5883l.QMC5883L(bus)
    q.setup()
    assert q.still_configured()
    clk.advance(1.5)
    assert not q.still_configured()                         # back in standby after the reset
    q.setup()
    q.soft_reset()
    assert eb.devices[0x0D].regs[0x09] == 0x00 and eb.devices[0x0D].regs[0x0B] == 0x00


def test_pointer_roll_over():
    eb, bus, clk = rig()
    q = qmc5883l.QMC5883L(bus)
    q.setup(rate_hz=100.0)
    bus.write_byte(0x0D, 0x0A, R.encode("CONTROL2", 0, ROL_PNT=1))
    clk.advance(0.05)
    raw = bus.read_block(0x0D, 0x00, 10)
    assert raw[7:10] == raw[0:3]                             # 0x06 -> 0x00


@pytest.mark.parametrize("board,mag,chips", [
    ("9dof", "qmc5883l", {"accel": "adxl345", "gyro": "itg3200", "mag": "qmc5883l"}),
    ("9dof", "hmc5883l", {"accel": "adxl345", "gyro": "itg3200", "mag": "hmc5883l"}),
    ("gy273", "qmc5883l", {"mag": "qmc5883l"}), ("gy273", "hmc5883l", {"mag": "hmc5883l"})])
def test_boards_find_either_magnetometer(board, mag, chips):
    eb, bus, clk = rig(board, mag=mag)
    found = probe(bus)
    assert detect_board(found) == board and magnetometer(found) == mag
    b = make_board(board, bus, rate_hz=100.0)              # mag="auto": found by ID
    b.start()
    assert b.chips() == chips
    n = fresh = 0
    for _ in range(20):
        bt = b.read_batch(True, 0.1)
        n, fresh = n + len(bt), fresh + int(bt.mag_fresh.sum())
        assert not bt.gaps
    assert n == pytest.approx(2.0 * b.rate_hz, abs=2)
    truth = eb.truth.mag_raw(still().sample(np.array([0.0]))["h"])[0]
    assert np.allclose(bt.mag[-1], truth, atol=6 * NOISE)
    if board == "gy273":
        assert np.all(np.isnan(bt.acc)) and fresh == n


def test_gy273_reports_lost_readings_as_a_gap():
    eb, bus, clk = rig("gy273")
    b = make_board("gy273", bus, rate_hz=50.0)
    b.start()
    b.read_batch(True, 0.1)
    clk.advance(0.2)                                         # the host stalls: 10 conversions
    bt = b.read_batch(False)
    assert bt.gaps and bt.gaps[0][1] >= 1
