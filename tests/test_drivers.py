"""Drivers against their register-accurate emulators: identification, configuration,
scaling, byte order, temperature, FIFO parsing and overflow, burst reads."""
import numpy as np
import pytest

from imucald.fitting.models.accel import Triangular9
from imucald.drivers import adxl345, ak8963, hmc5883l, itg3200, mpu6050
from imucald.drivers.board import make_board
from imucald.drivers.bus import Bus, ChipMismatch, VirtualClock
from imucald.sim.emulators import Faults, emulated_board
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import rotation_from_up
from imucald.specs import ACCEL, GYRO

T9 = Triangular9()


def still(up=(0, 0, 1), hold=1e6, temp0=25.0, rise=0.0):
    """A board resting in one orientation for ever."""
    R = rotation_from_up(np.asarray(up, float))[None]
    return PoseTour(R, rng=0, hold_s=hold, lead_s=0, temp0_c=temp0, temp_rise_c=rise)


def rig(board, motion=None, faults=None, seed=1):
    clk = VirtualClock()
    eb = emulated_board(board, motion or still(), rng=seed, clock=clk, faults=faults)
    return eb, Bus(eb, "emu", clock=clk), clk


# --- identification ---------------------------------------------------------------------

def test_mpu_identification_and_mismatch_messages():
    eb, bus, _ = rig("mpu6500")
    with pytest.raises(ChipMismatch) as e:
        mpu6050.MPU6xxx(bus, 0x68, "mpu9250").identify()
    assert "0x68 answered WHO_AM_I=0x70: an MPU6500, not the configured MPU9250" in str(e.value)
    assert "no magnetometer" in str(e.value)
    assert mpu6050.MPU6xxx(bus, 0x68, "mpu6500").identify() == "mpu6500"
    eb, bus, _ = rig("mpu6050", faults=Faults(wrong_id={0x68: 0x42}))
    with pytest.raises(ChipMismatch, match="WHO_AM_I=0x42: not an InvenSense MPU"):
        mpu6050.MPU6xxx(bus).identify()


@pytest.mark.parametrize("cls,addr,msg", [
    (adxl345.ADXL345, 0x53, "not an ADXL345"), (itg3200.ITG3200, 0x68, "not an ITG3200"),
    (hmc5883l.HMC5883L, 0x1E, "not an HMC5883L")])
def test_nine_dof_wrong_ids(cls, addr, msg):
    _, bus, _ = rig("9dof", faults=Faults(wrong_id={addr: 0x00}))
    with pytest.raises(ChipMismatch, match=msg):
        cls(bus, addr).identify()


# --- configuration written ---------------------------------------------------------------

@pytest.mark.parametrize("arange,grange,rate", [(2, 250, 100), (4, 500, 200), (8, 1000, 1000),
                                                (16, 2000, 50)])
def test_mpu_configuration_registers(arange, grange, rate):
    eb, bus, _ = rig("mpu6050")
    m = mpu6050.MPU6xxx(bus)
    m.setup(arange, grange, rate)
    regs = eb.devices[0x68].regs
    R = mpu6050.REGMAP
    assert R.decode("PWR_MGMT_1", regs[R.PWR_MGMT_1.addr], "SLEEP") == 0
    assert R.decode("PWR_MGMT_1", regs[R.PWR_MGMT_1.addr], "CLKSEL") == 1
    assert R.decode("ACCEL_CONFIG", regs[R.ACCEL_CONFIG.addr], "AFS_SEL") == [2, 4, 8, 16].index(arange)
    assert R.decode("GYRO_CONFIG", regs[R.GYRO_CONFIG.addr], "FS_SEL") == [250, 500, 1000, 2000].index(grange)
    dl = R.decode("CONFIG", regs[R.CONFIG.addr], "DLPF_CFG")
    # the widest DLPF that still filters (184 Hz) when rate/2 exceeds it
    assert 1 <= dl <= 6 and mpu6050.DLPF_HZ[dl][0] >= min(rate / 2, 184)
    assert R.decode("CONFIG", regs[R.CONFIG.addr], "EXT_SYNC_SET") == 0    # Adafruit #45's bug
    assert 1000.0 / (1 + regs[R.SMPLRT_DIV.addr]) == rate
    assert regs[R.FIFO_EN.addr] == 0xF8
    assert R.decode("USER_CTRL", regs[R.USER_CTRL.addr], "FIFO_EN") == 1


def test_nine_dof_configuration_registers():
    eb, bus, _ = rig("9dof")
    adxl345.ADXL345(bus).setup(16, 200)
    itg3200.ITG3200(bus).setup(100)
    hmc5883l.HMC5883L(bus).setup(gain=1, rate_hz=75)
    a = eb.devices[0x53].regs
    assert a[0x31] == 0x08 | 0x03 and a[0x2C] == 0x0B and a[0x2D] == 0x08 and a[0x38] >> 6 == 2
    g = eb.devices[0x68].regs
    assert (g[0x16] >> 3) & 3 == 3                      # FS_SEL must be 3
    assert g[0x3E] & 0x07 == 1 and 1000 / (1 + g[0x15]) == 100
    h = eb.devices[0x1E].regs
    assert h[0x02] & 3 == 0 and (h[0x00] >> 2) & 7 == 6 and h[0x01] >> 5 == 1


# --- asleep at power-on -----------------------------------------------------------------------

def test_chips_read_zero_until_woken():
    eb, bus, clk = rig("mpu6050")
    clk.advance(1.0)
    assert bus.read_block(0x68, 0x3B, 14) == bytes(14)      # SLEEP set at power-on
    eb, bus, clk = rig("9dof")
    clk.advance(1.0)
    assert bus.read_block(0x53, 0x32, 6) == bytes(6)        # ADXL345 in standby


# --- noise level: the whole DLPF band aliases into each sample ----------------------------

def _var_check(x, density, band_hz, lsb):
    """Per-axis sample variance against density^2 * band + LSB^2/12 (white noise sampled
    without anti-aliasing beyond the DLPF keeps its whole variance); tolerance 4 standard
    errors of a variance estimate from k samples, sqrt(2/(k-1))."""
    k = len(x)
    want = density ** 2 * band_hz + lsb ** 2 / 12
    got = x.var(0, ddof=1)
    assert np.all(np.abs(got / want - 1) < 4 * np.sqrt(2 / (k - 1))), (got, want)


def test_mpu_noise_is_the_whole_dlpf_band_at_100hz():
    eb, bus, clk = rig("mpu6050")
    m = mpu6050.MPU6xxx(bus)
    m.setup(2, 250, 100)
    R = mpu6050.REGMAP
    dl = R.decode("CONFIG", bus.read_byte(0x68, R.CONFIG.addr), "DLPF_CFG")
    bw_a, bw_g = mpu6050.DLPF_HZ[dl]
    assert bw_a > 50                          # the case in point: a band wider than ODR/2
    acc, gyr = [], []
    for _ in range(16):
        clk.advance(0.5)
        fr = m.read_fifo()
        acc.append(fr.acc_g)
        gyr.append(fr.gyro_dps)
    _var_check(np.concatenate(acc), ACCEL["mpu6050"].noise_density_g_rthz, bw_a, 2 / 32768)
    _var_check(np.concatenate(gyr), GYRO["mpu6050"].noise_density_dps_rthz, bw_g, 1 / 131)


def test_itg3200_noise_is_the_whole_dlpf_band_at_100hz():
    eb, bus, clk = rig("9dof")
    g = itg3200.ITG3200(bus)
    g.setup(100)
    band = itg3200.DLPF_HZ[bus.read_byte(0x68, itg3200.REGMAP.DLPF_FS.addr) & 0x07]
    assert band > 50
    clk.advance(0.2)                          # past the start-up time (zeros before it)
    w = []
    for _ in range(800):
        clk.advance(0.01)
        w.append(g.read()[0])
    _var_check(np.array(w), GYRO["itg3200"].noise_density_dps_rthz, band, 1 / 14.375)


# --- scaling, byte order and sign, temperature -------------------------------------------------

@pytest.mark.parametrize("arange", [2, 4, 8, 16])
@pytest.mark.parametrize("up", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, -1, 0)])
def test_mpu_scaling_sign_and_temperature(arange, up):
    eb, bus, clk = rig("mpu6050", still(up, temp0=31.0))
    m = mpu6050.MPU6xxx(bus)
    m.setup(arange, 250, 100)
    clk.advance(0.5)
    fr = m.read_fifo()
    truth = eb.truth
    expect = T9.inverse(truth.accel, np.array([up], float))[0]
    n = len(fr.acc_g)
    assert n >= 40
    # noise per sample: density over the DLPF band (94/98 Hz at 100 Hz); quantisation of the LSB
    sig = np.hypot(ACCEL["mpu6050"].noise_density_g_rthz * np.sqrt(94), (arange / 32768) / np.sqrt(12))
    assert np.all(np.abs(fr.acc_g.mean(0) - expect) < 5 * sig / np.sqrt(n))
    gexp = truth.gyro_bias_dps
    gsig = np.hypot(GYRO["mpu6050"].noise_density_dps_rthz * np.sqrt(98), 1 / 131 / np.sqrt(12))
    assert np.all(np.abs(fr.gyro_dps.mean(0) - gexp) < 5 * gsig / np.sqrt(n))
    assert np.all(np.abs(fr.temp_c - 31.0) <= 0.5 / 340 + 1e-9)      # raw/340 + 36.53


def test_adxl_itg_hmc_scaling_order_and_temperature():
    eb, bus, clk = rig("9dof", still((0, 1, 0), temp0=20.0))
    a = adxl345.ADXL345(bus); a.setup(16, 100)
    g = itg3200.ITG3200(bus); g.setup(100)
    h = hmc5883l.HMC5883L(bus); h.setup(gain=7, rate_hz=75)     # +-8.1 G: no overflow
    clk.advance(0.3)
    acc, over = a.read_fifo()
    tr = eb.truth
    assert not over and 29 <= len(acc) <= 31
    expect = T9.inverse(tr.accel, np.array([[0.0, 1.0, 0.0]]))[0]
    sig = np.hypot(ACCEL["adxl345"].noise_density_g_rthz * np.sqrt(50), 0.0039 / np.sqrt(12))
    assert np.all(np.abs(acc.mean(0) - expect) < 5 * sig / np.sqrt(len(acc)))
    w, temp = g.read()
    assert abs(temp - 20.0) <= 0.5 / 280 + 1e-9                  # 35 + (raw + 13200)/280
    assert np.all(np.abs(w - tr.gyro_bias_dps) < 5 * 0.03 * np.sqrt(98) + 0.5 / 14.375)
    mag, over = h.read()                                          # first sample after gain change:
    assert mag is None and not over                               # discarded (old gain)
    clk.advance(0.05)
    mag, over = h.read()
    R = rotation_from_up(np.array([0, 1.0, 0]))
    hb = R.T @ still().B_world
    m_true = np.linalg.inv(tr.mag_soft_iron) @ hb + tr.mag_hard_iron_gauss
    assert np.all(np.abs(mag - m_true) < 5 * 0.002 + 1 / 230)    # X, Y, Z from X, Z, Y order


def test_hmc_overflow_reads_minus_4096():
    eb, bus, clk = rig("9dof")
    eb.truth.mag_hard_iron_gauss[:] = [2.0, 0, 0]                 # beyond +-0.88 G
    h = hmc5883l.HMC5883L(bus)
    h.setup(gain=0, rate_hz=75)
    clk.advance(0.1)
    h.read()
    clk.advance(0.05)
    raw = bus.read_block(0x1E, 0x03, 6)
    assert int.from_bytes(raw[0:2], "big", signed=True) == -4096
    assert h.read() == (None, True)


def test_ak8963_asa_frame_and_data_lock():
    eb, bus, clk = rig("mpu9250", still((0, 0, 1)))
    m = mpu6050.MPU6xxx(bus, 0x68, "mpu9250")
    m.setup(2, 250, 100, bypass=True)
    ak = ak8963.AK8963(bus)
    ak.setup()
    dev = eb.devices[0x0C]
    assert np.allclose(ak.asa, (dev.asa_raw - 128) * 0.5 / 128 + 1)
    clk.advance(0.05)
    mag, over = ak.read()
    tr = eb.truth
    m_true = np.linalg.inv(tr.mag_soft_iron) @ still().B_world + tr.mag_hard_iron_gauss
    assert np.all(np.abs(mag - m_true) < 5 * 0.004 + 0.0015 * 1.3)    # AK frame -> MPU frame
    assert ak.read() == (None, False)           # reading ST2 released the lock: no new data yet
    # without the bypass the AK8963 does not answer
    bus.write_byte(0x68, 0x37, 0)
    from imucald.drivers.bus import NoAcknowledge
    with pytest.raises(NoAcknowledge):
        ak.read()


# --- FIFO parsing ---------------------------------------------------------------------------

def test_fifo_partial_frame_is_ignored():
    m = mpu6050.MPU6xxx(Bus(None), 0x68)
    m.accel_range_g, m.gyro_range_dps = 2, 250
    vals = np.array([[16384, -16384, 8192, -521 + 0, 131, -262, 0]] * 3, ">i2").tobytes()
    fr = m.parse_frames(vals + vals[:5])
    assert len(fr.acc_g) == 3
    assert np.allclose(fr.acc_g[0], [1, -1, 0.5]) and np.allclose(fr.gyro_dps[0], [1, -2, 0])
    assert np.isclose(fr.temp_c[0], -521 / 340 + 36.53)


def test_fifo_overflow_is_detected_reset_and_reported_as_a_gap():
    eb, bus, clk = rig("mpu6050")
    b = make_board("mpu6050", bus, clk, rate_hz=1000)
    b.start()
    seqs = [b.read_batch().seq for _ in range(10)]
    clk.advance(0.2)                      # 200 samples = 2800 bytes > 1024: the FIFO overflows
    bt = b.read_batch()
    assert bt.gaps and bt.gaps[0][1] >= 150
    assert b.stats.fifo_resets == 1
    seqs.append(bt.seq)
    seqs += [b.read_batch().seq for _ in range(10)]
    s = np.concatenate(seqs)
    assert np.all(np.diff(s) >= 1)                                  # never duplicated
    jumps = np.flatnonzero(np.diff(s) > 1)
    assert len(jumps) == 1                                          # and the gap is reported once
    # frames stay aligned after the reset: all readings are the still pose
    last = b.read_batch()
    assert np.all(np.abs(np.linalg.norm(last.acc, axis=1) - 1) < 0.1)


def _race_rig():
    """An MPU-6050 at 1 kHz, read for 5 batches, whose next burst read comes after a 30-ms
    stall of the host (between the count and the burst: 30 more frames arrive), with 60
    frames (840 bytes, under the reset threshold) waiting: 60 + 30 frames overflow 1024
    bytes.  Returns (board, armed): armed[0] turns False once the stall happened."""
    eb, bus, clk = rig("mpu6050", still(temp0=25.0))
    b = make_board("mpu6050", bus, clk, rate_hz=1000)
    b.start()
    for _ in range(5):
        b.read_batch()
    dev = eb._dev(0x68)
    read, armed = dev.read, [True]

    def late_read(reg, n):              # the host stalls between the count and the burst
        if reg == mpu6050.REGMAP.FIFO_R_W.addr and armed[0]:
            armed[0] = False
            clk.advance(0.030)
        return read(reg, n)
    dev.read = late_read
    clk.advance(0.060)
    return b, armed


def test_fifo_overflow_between_count_and_read_never_yields_misaligned_frames():
    """The race a loaded host (or a 100x emulated clock) hits: the count is read below the
    reset threshold, the FIFO overflows before the burst is read, the chip drops its oldest
    bytes (1024 is not a multiple of 14) and every frame after is shifted.  The overflow bit
    (INT_STATUS.FIFO_OFLOW_INT) is what tells: the batch is dropped, the FIFO reset and the
    loss reported.  Without that check (the driver before this test) the next batches read
    temperature and gyro bytes as acceleration: |acc| far from 1 g, and no pose is ever still
    again (the CI failure of docs/guide/daemon.md: 4 poses, then none for 200 s)."""
    b, armed = _race_rig()
    batches = [b.read_batch() for _ in range(20)]
    acc = np.concatenate([x.acc for x in batches])
    temp = np.concatenate([x.temp for x in batches])
    assert not armed[0] and len(acc) > 100
    # the still pose at 1000 Hz: |acc| within 0.1 g of 1 (noise ~4 mg), the die at 25 C
    assert np.all(np.abs(np.linalg.norm(acc, axis=1) - 1) < 0.1)
    assert np.all(np.abs(temp - 25.0) < 2.0)
    # the loss counted to the reset: the 60 frames read and dropped and the 30 of the stall
    # (counted to the time before the count was read, it said 60, and every later sample's
    # sequence number, and so its time, stayed 30 behind)
    assert abs(sum(k for x in batches for _, k in x.gaps) - 90) <= 1


def test_a_bus_fault_during_the_overflow_reset_leaves_no_shifted_frames():
    """The reset after an overflow fails (retries exhausted: a NACK burst): the overflow flag
    was already cleared by reading it, so without the driver's resync marker every later
    burst passed the check and was read shifted (365 of 365 samples, no gap reported: seen
    with the marker removed).  With it, the next read resets first and reports the loss."""
    from imucald.drivers.bus import BusError
    b, armed = _race_rig()
    reset, fail = b.mpu.fifo_reset, [True]

    def flaky_reset():
        if fail[0]:
            fail[0] = False
            raise BusError("a NACK on the reset's first write", 0x68, 121)
        return reset()
    b.mpu.fifo_reset = flaky_reset
    batches = [b.read_batch() for _ in range(20)]
    acc = np.concatenate([x.acc for x in batches])
    assert not armed[0] and not fail[0] and b.stats.bus_faults == 1 and len(acc) > 100
    assert np.all(np.abs(np.linalg.norm(acc, axis=1) - 1) < 0.1)
    assert sum(k for x in batches for _, k in x.gaps) >= 90


def _adxl_lag_s(b, clk):
    """How far the newest sample's time (its sequence number over the rate) is behind the
    clock, s: constant while nothing is lost unaccounted."""
    return (clk.now() - b.t0) - b.seq / b.rate_hz


@pytest.mark.parametrize("stall_s,at_read,overwritten,nack", [
    (0.0, 0, 18, False), (0.030, 0, 21, False), (0.030, 16, 18, False), (0.030, 16, 18, True)])
def test_adxl345_overrun_counts_the_samples_lost_up_to_the_read(stall_s, at_read, overwritten, nack):
    """The 9DOF board's ADXL345 FIFO (32 entries, stream mode) overruns when the host stops
    reading for more than 0.32 s at 100 Hz: the chip overwrites its oldest entries, and the
    driver reports the loss as a gap.  A stall of 30 ms (3 samples) between the entry count
    and the data reads overwrites 3 more; the same stall after 16 of the 32 reads overwrites
    none (the reads made room) and leaves 3 waiting in the FIFO.  Counted to the time before
    the count, the first loss was 3 short and every later sample's sequence number, and so
    its time, stayed 30 ms behind the clock; counted to the end of the read without what
    waits, the second was 3 over.  The newest sample's lag after the overrun is what it was
    before (within one sample period: the poll's phase).  If the count of what waits cannot
    be read after the data (a NACK), it is taken as what the chip made during the read (3
    here): taken as none, the loss was 3 over and the fault uncounted.  Broken once each: the
    count to the time before the read (case 2 fails), the 'waiting' term dropped (case 3),
    the NACK fallback as 0 (case 4)."""
    from imucald.drivers.bus import BusError
    eb, bus, clk = rig("9dof")
    b = make_board("9dof", bus, clk, rate_hz=100)
    b.start()
    for _ in range(10):
        b.read_batch(batch_s=0.05)
    lag0 = _adxl_lag_s(b, clk)
    dev = eb._dev(0x53)
    read, reads = dev.read, [0]

    def late_read(reg, n):              # the host stalls once, at the given data read
        if reg == adxl345.REGMAP.DATAX0.addr:
            if reads[0] == at_read:
                clk.advance(stall_s)
            reads[0] += 1
        return read(reg, n)
    dev.read = late_read
    entries, nacked = b.acc.entries, [False]

    def flaky_entries():                # the count after the data reads NACKs, once
        if nack and reads[0] > at_read and not nacked[0]:
            nacked[0] = True
            raise BusError("a NACK on FIFO_STATUS", 0x53, 121)
        return entries()
    b.acc.entries = flaky_entries
    clk.advance(0.5)                    # 50 samples: 18 more than the FIFO holds
    batches = [b.read_batch(batch_s=0.05) for _ in range(10)]
    assert reads[0] > at_read and b.stats.fifo_resets == 1
    assert nacked[0] == nack and b.stats.bus_faults == int(nack)
    assert abs(sum(k for x in batches for _, k in x.gaps) - overwritten) <= 1
    assert abs(_adxl_lag_s(b, clk) - lag0) <= 1 / b.rate_hz


# --- efficiency: burst reads --------------------------------------------------------------

def test_mpu_burst_reads_three_transactions_per_batch_and_sustains_1khz():
    eb, bus, clk = rig("mpu6050")
    b = make_board("mpu6050", bus, clk, rate_hz=1000)
    b.start()
    b.read_batch()
    t0, n0 = bus.stats.transactions, b.stats.samples
    for _ in range(250):                                             # 5 s at 20 ms batches
        b.read_batch()
    batches = 250
    # count, one burst and the overflow flag per batch (the flag: a FIFO that overflowed
    # between count and burst is read shifted), plus the 2-read configuration check once a second
    assert bus.stats.transactions - t0 <= 3 * batches + 2 * 6
    got = b.stats.samples - n0
    assert abs(got - 5000) <= 20 and b.stats.missing == 0


@pytest.mark.parametrize("grange", [250, 500, 1000, 2000])
@pytest.mark.parametrize("variant,formula", [("mpu6050", (340.0, 36.53)), ("mpu9250", (333.87, 21.0))])
def test_mpu_gyro_scaling_per_range_and_temperature_per_variant(grange, variant, formula):
    eb, bus, clk = rig(variant, still((0, 0, 1), temp0=18.0))
    m = mpu6050.MPU6xxx(bus, 0x68, variant)
    m.setup(2, grange, 200)
    clk.advance(0.15)                      # 30 frames: within the 512-byte MPU-9250 FIFO
    fr = m.read_fifo()
    n = len(fr.gyro_dps)
    assert n >= 25 and not fr.reset
    spec = GYRO["mpu6050" if variant == "mpu6050" else "mpu9250"]
    lsb = 1 / {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}[grange]
    sig = np.hypot(spec.noise_density_dps_rthz * np.sqrt(94), lsb / np.sqrt(12))
    assert np.all(np.abs(fr.gyro_dps.mean(0) - eb.truth.gyro_bias_dps) < 5 * sig / np.sqrt(n) + lsb / 2)
    # every value is a whole number of this range's LSB
    assert np.allclose(fr.gyro_dps / lsb, np.round(fr.gyro_dps / lsb), atol=1e-6)
    div, off = formula
    assert np.all(np.abs(fr.temp_c - 18.0) <= 0.5 / div + 1e-9)


@pytest.mark.parametrize("popped,gyro_fails", [(False, False), (True, False), (True, True)])
def test_adxl345_bus_fault_mid_read_keeps_the_entries_read_and_counts_the_loss(popped, gyro_fails):
    """A host that stalled 0.25 s finds 25 entries in the ADXL345 FIFO; a bus fault (retries
    exhausted) on the 11th data read cuts the drain short after 10 entries were popped.  Those
    10 were dropped with the exception and nothing said so: every later sample's sequence
    number, and so its time, stayed 10 samples (0.1 s) behind the clock, with no gap.  Now the
    10 come with the next read, and what the cut lost (the failed burst's own entry, when it
    was popped: ``popped``) is counted by time.  With ``gyro_fails`` the gyro read after the
    next drain fails too: the entries drained then are kept the same way (they were dropped:
    25 samples and 0.26 s, a cold review).  The emulated clock is exact, so exactly that entry
    is lost, the gaps say so, the samples delivered are those made less it, and the newest
    sample's lag behind the clock is what it was before.  Broken once: the FifoCut carry
    dropped (the lag 0.1 s behind: fails); the gyro's fault not keeping the drain (fails)."""
    from imucald.drivers.bus import BusError
    eb, bus, clk = rig("9dof")
    b = make_board("9dof", bus, clk, rate_hz=100)
    b.start()
    for _ in range(10):
        b.read_batch(batch_s=0.05)
    lag0, seq0 = _adxl_lag_s(b, clk), b.seq
    real, reads, gyro_fault = b.acc.bus.read_block, [0], [0]

    def faulty_block(addr, reg, n, fifo=False):     # the 11th data read fails, once
        if reg == adxl345.REGMAP.DATAX0.addr:
            reads[0] += 1
            if reads[0] == 11:
                if popped:
                    real(addr, reg, n, fifo)
                gyro_fault[0] = int(gyro_fails)
                raise BusError("a NACK on DATAX0 (retries exhausted)", addr, 121)
        return real(addr, reg, n, fifo)
    b.acc.bus = type("B", (), {"read_block": staticmethod(faulty_block),
                               "read_byte": bus.read_byte, "write_byte": bus.write_byte})()
    gyro_read = b.gyr.read

    def faulty_gyro():                              # the next gyro read fails, once
        if gyro_fault[0]:
            gyro_fault[0] = 0
            raise BusError("a NACK on the ITG3200", b.gyr.addr, 121)
        return gyro_read()
    b.gyr.read = faulty_gyro
    clk.advance(0.25)
    batches = [b.read_batch(batch_s=0.05) for _ in range(10)]
    assert reads[0] > 11 and b.stats.bus_faults == 1 + int(gyro_fails) and b.stats.fifo_resets == 0
    lost = sum(k for x in batches for _, k in x.gaps)
    assert lost == int(popped)
    assert sum(len(x.acc) for x in batches) + lost == b.seq - seq0
    assert abs(_adxl_lag_s(b, clk) - lag0) < 1e-9


@pytest.mark.parametrize("rng_g", [2, 4, 8, 16])
def test_adxl345_full_resolution_scale_is_the_same_for_every_range(rng_g):
    eb, bus, clk = rig("9dof", still((0, 0, -1)))
    a = adxl345.ADXL345(bus)
    a.setup(rng_g, 100)
    assert eb.devices[0x53].regs[0x31] & 0x03 == [2, 4, 8, 16].index(rng_g)
    clk.advance(0.3)
    acc, _ = a.read_fifo()
    expect = T9.inverse(eb.truth.accel, np.array([[0.0, 0.0, -1.0]]))[0]
    assert np.allclose(acc / 0.0039, np.round(acc / 0.0039), atol=1e-6)     # 3.9 mg/LSB
    sig = np.hypot(ACCEL["adxl345"].noise_density_g_rthz * np.sqrt(50), 0.0039 / np.sqrt(12))
    assert np.all(np.abs(acc.mean(0) - expect) < 5 * sig / np.sqrt(len(acc)))
