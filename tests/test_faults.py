"""Injected faults: each has its documented behaviour (retry, re-initialise, or a clear
one-line error); no sample is duplicated and every gap is reported."""
import os
import subprocess
import sys

import numpy as np
import pytest

from imucald.drivers.board import make_board
from imucald.drivers.bus import AddressBusy, Bus, ChipMismatch, VirtualClock, kernel_driver_for
from imucald.sim.emulators import Faults, emulated_board
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import random_pose_set


def run_board(board, faults, seconds=10.0, rate=200.0, seed=3):
    clk = VirtualClock()
    tour = PoseTour(random_pose_set(6, seed), rng=seed, loop=True)
    eb = emulated_board(board, tour, rng=seed, clock=clk, faults=faults)
    bus = Bus(eb, "emu", clock=clk)
    b = make_board(board, bus, clk, rate_hz=rate if board != "9dof" else 100.0)
    b.start()
    seqs, gaps = [], []
    while clk.now() < seconds:
        bt = b.read_batch()
        seqs.append(bt.seq)
        gaps += bt.gaps
    return b, bus, np.concatenate(seqs), gaps


def check_accounting(b, seqs, gaps):
    assert np.all(np.diff(seqs) >= 1), "a sample was duplicated or reordered"
    # every jump in the sequence is a reported gap, of exactly that size
    jumps = [(int(seqs[i] + 1), int(seqs[i + 1] - seqs[i] - 1))
             for i in np.flatnonzero(np.diff(seqs) > 1)]
    reported = [g for g in gaps if g[0] <= seqs[-1]]
    assert jumps == [(s, n) for s, n in reported if n > 0 and s > seqs[0]]
    assert b.seq == seqs[-1] + 1


@pytest.mark.parametrize("board", ["mpu6050", "mpu9250", "9dof"])
def test_no_acknowledge_noise_is_retried(board):
    # errno 121 on 5 % of transactions, as when motors start
    b, bus, seqs, gaps = run_board(board, Faults(nack_prob=0.05))
    assert bus.stats.retries > 20
    check_accounting(b, seqs, gaps)
    assert b.stats.missing < 0.01 * len(seqs)          # retries keep nearly everything


def test_stuck_bus_is_ridden_out_by_the_fifo():
    b, bus, seqs, gaps = run_board("mpu6050", Faults(stuck=[(4.0, 4.1)]))
    assert bus.stats.errors.get("BusTimeout", 0) > 0 and b.stats.bus_faults > 0
    assert b.stats.missing == 0                         # 100 ms < FIFO depth at 200 Hz
    check_accounting(b, seqs, gaps)


def test_long_stuck_bus_overflows_the_fifo_and_reports_the_gap():
    # re-initialisation is attempted after 0.5 s of faults but cannot reach the chip; once
    # the bus frees, the overflowed FIFO is reset and the lost time reported
    b, bus, seqs, gaps = run_board("mpu6050", Faults(stuck=[(4.0, 5.5)]))
    assert b.stats.bus_faults > 10 and len(gaps) == 1
    assert abs(b.stats.missing - 1.5 * 200) < 0.4 * 200
    check_accounting(b, seqs, gaps)


@pytest.mark.parametrize("board,addr", [("mpu6050", 0x68), ("mpu9250", 0x68), ("9dof", 0x53),
                                        ("9dof", 0x1E)])
def test_device_reset_mid_stream_is_detected_and_reinitialised(board, addr):
    b, bus, seqs, gaps = run_board(board, Faults(resets={addr: [3.0]}))
    assert b.stats.reinits == 1
    assert len(gaps) == 1 and gaps[0][1] > 0
    check_accounting(b, seqs, gaps)
    # after recovery the stream carries real data again (not a sleeping chip's zeros)
    assert b.stats.samples > 0.85 * 10 * b.rate_hz


def test_disconnected_device_comes_back():
    b, bus, seqs, gaps = run_board("9dof", Faults(disconnected={0x53: (3.0, 5.0)}))
    assert b.stats.bus_faults > 0 and len(gaps) == 1
    # 2 s at 100 Hz, less the 32 samples still in the ADXL345 FIFO when it comes back
    assert abs(b.stats.missing - (200 - 32)) <= 10
    check_accounting(b, seqs, gaps)


def test_wrong_chip_and_busy_address_fail_at_start():
    clk = VirtualClock()
    tour = PoseTour(random_pose_set(3, 0), rng=0)
    eb = emulated_board("mpu9250", tour, rng=0, clock=clk, faults=Faults(wrong_id={0x68: 0x70}))
    b = make_board("mpu9250", Bus(eb, "emu", clock=clk), clk)
    with pytest.raises(ChipMismatch, match="an MPU6500, not the configured MPU9250"):
        b.start()
    eb = emulated_board("mpu6050", tour, rng=0, clock=clk, faults=Faults(busy={0x68}))
    b = make_board("mpu6050", Bus(eb, "emu", clock=clk), clk)
    with pytest.raises(AddressBusy, match="busy"):
        b.start()


@pytest.mark.parametrize("fault,msg", [
    ("wrong-id=0x68:0x70", "0x68 answered WHO_AM_I=0x70: an MPU6500, not the configured MPU6050"),
    ("busy=0x68", "address 0x68 is busy (errno 16): a kernel driver owns it"),
])
def test_cli_exits_non_zero_with_one_line(tmp_path, fault, msg):
    p = subprocess.run([sys.executable, "-m", "imucald.cli", "record", "--emulate", "-o",
                        str(tmp_path / "r.csv"), "--seconds", "1", "--fault", fault],
                       capture_output=True, text=True)
    assert p.returncode == 2
    assert msg in p.stderr and p.stderr.count("\n") == 1 and "Traceback" not in p.stderr
    assert not (tmp_path / "r.csv").exists()


def test_kernel_driver_is_named_from_sysfs(tmp_path):
    d = tmp_path / "1-0068"
    d.mkdir()
    drv = tmp_path / "drivers" / "inv-mpu6050-i2c"
    drv.mkdir(parents=True)
    os.symlink(drv, d / "driver")
    assert kernel_driver_for(1, 0x68, str(tmp_path)) == "inv-mpu6050-i2c"
    assert kernel_driver_for(1, 0x69, str(tmp_path)) is None
    from imucald.drivers.bus import kernel_driver_hint
    assert "dtoverlay=i2c-sensor,mpu6050" in kernel_driver_hint("/dev/i2c-1", 0x68, str(tmp_path))


def test_record_cli_writes_a_readable_recording(tmp_path):
    from imucald.cli import main
    from imucald.files.recording import read_recording
    out = tmp_path / "r.csv"
    assert main(["record", "--emulate", "--board", "mpu9250", "-o", str(out), "--seconds", "3",
                 "--rate", "200", "--fault", "nack=0.02"]) == 0
    rec = read_recording(out)
    assert rec.meta["board"] == "mpu9250" and len(rec) > 0.95 * 600
    assert rec.mag is not None and np.all(np.isfinite(rec.mag))
    assert np.all(np.abs(np.linalg.norm(rec.acc, axis=1) - 1) < 0.6)


@pytest.mark.parametrize("spec,why", [
    ("nack=2", "2 is not a probability 0..1"), ("nack=nan", "nan is not a probability 0..1"),
    ("stuck=inf+1", "inf s is not a time >= 0"), ("disconnect=0x53@3+-2", "-2 s is not a time >= 0"),
    ("reset=0x68@nan", "nan s is not a time >= 0"), ("busy=0x300", "0x300 is not a 7-bit device address"),
    ("wrong-id=0x68:0x1ff", "0x1ff is not a byte")])
def test_a_fault_out_of_range_is_refused_saying_why(spec, why):
    """The emulator's --fault values were only parsed: nack=2 made every transaction fail
    (the run ended 'no acknowledge'), nack=-1, a negative duration or a NaN time ran as if no
    fault were asked for, silently.  Broken once: the parser before this change (7 of 7 fail)."""
    from imucald.cli.faults import faults_from_options
    from imucald.errors import UserError
    with pytest.raises(UserError) as e:
        faults_from_options([spec])
    assert f"--fault {spec!r} ({why}" in str(e.value) and "\n" not in str(e.value)
    assert faults_from_options(["nack=0.05", "stuck=4+0.1", "reset=0x68@3", "disconnect=0x53@3+2",
                                "busy=0x1e", "wrong-id=0x68:0x70"]) is not None
