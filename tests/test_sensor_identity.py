"""Calibrations tied to the physical sensor: fingerprints from chip ID, bus, address and
factory trim; per-sensor state; a swapped board never gets another board's calibration."""
import os
import signal
import subprocess
import time

import numpy as np
import pytest
import yaml

from imucald.calibration import Calibration, SensorCal
from imucald.cli.boards import emulated_bus
from imucald.daemon.sensors import adopt_sensor, fingerprint_id
from imucald.daemon.state import load_calibration, save_calibration
from imucald.drivers.board import make_board
from imucald.drivers.bus import Bus, VirtualClock
from imucald.sim.emulators import emulated_board
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import random_pose_set

from .test_daemon import control, start_daemon, wait_for

TRIM_A = {"self_test": bytes([0x3E, 0x4F, 0xEF, 0x03]), "accel_offset": bytes.fromhex("04aa07b3f85e")}
TRIM_B = {"self_test": bytes([0x3E, 0x4F, 0xEF, 0x03]), "accel_offset": bytes.fromhex("04aa07b3f85f")}


def _board(name, trim=None, seed=0):
    rng = np.random.default_rng(seed)
    clock = VirtualClock()
    motion = PoseTour(random_pose_set(6, rng), rng=rng, loop=True)
    eb = emulated_board(name, motion, rng=rng, clock=clock, trim=trim)
    b = make_board(name, Bus(eb, name=f"emulated {name}", clock=clock))
    b.start()
    return b


def test_fingerprint_reads_the_factory_trim_registers():
    b = _board("mpu6050", TRIM_A)
    fp = b.fingerprint()["chips"]["mpu"]
    assert fp["self_test"] == "3e4fef03" and fp["accel_offset"] == "04aa07b3f85e"
    assert fp["address"] == "0x68" and fp["chip"] == "mpu6050"
    # one bit of one trim register is another sensor; the same trim (another seed: other
    # noise and motion) is the same sensor
    assert fingerprint_id(_board("mpu6050", TRIM_B).fingerprint()) != fingerprint_id(b.fingerprint())
    assert fingerprint_id(_board("mpu6050", TRIM_A, seed=5).fingerprint()) == fingerprint_id(b.fingerprint())


def test_mpu9250_fingerprint_has_its_own_registers_and_the_ak8963_fuse_rom():
    trim = {"self_test": bytes(range(1, 7)), "accel_offset": bytes.fromhex("0102030405aa"),
            "asa": bytes([170, 171, 172])}
    fp = _board("mpu9250", trim).fingerprint()["chips"]
    # SELF_TEST_X/Y/Z_GYRO 0x00-0x02 then SELF_TEST_X/Y/Z_ACCEL 0x0D-0x0F; offsets at 0x77..0x7E
    assert fp["mpu"]["self_test"] == "010203040506" and fp["mpu"]["accel_offset"] == "0102030405aa"
    assert fp["ak8963"] == {"address": "0x0C", "asa": "aaabac"}


def test_trim_survives_a_device_reset_and_other_seeds_draw_other_trim():
    b = _board("mpu6050", TRIM_A)
    b.mpu.setup()                                  # DEVICE_RESET inside: factory values reload
    assert b.mpu.factory_trim()["accel_offset"] == "04aa07b3f85e"
    fa = make_board("mpu6050", emulated_bus("mpu6050", seed=1))
    fb = make_board("mpu6050", emulated_bus("mpu6050", seed=2))
    fa.start(), fb.start()
    assert fa.mpu.factory_trim() != fb.mpu.factory_trim()


def _cal(sensor, i=1):
    return Calibration("mpu6050", {"accel": "mpu6050", "gyro": "mpu6050"}, id=i,
                       created="2026-11-24T06:00:00+00:00",
                       accel=SensorCal.accel("triangular9", np.r_[0, 0, 0, 1, 1, 1, 0.01, 0, 0]),
                       sensor=sensor)


def test_state_is_kept_per_sensor_with_a_dated_history(tmp_path):
    sd = str(tmp_path)
    fa, fb = {"chips": {"mpu": {"accel_offset": "aa"}}}, {"chips": {"mpu": {"accel_offset": "bb"}}}
    a, b = fingerprint_id(fa), fingerprint_id(fb)
    assert adopt_sensor(sd, fa)["status"] == "first"
    save_calibration(sd, _cal(a), history=5)
    assert os.listdir(tmp_path / "history") == ["calibration-000001-20261124T060000.yaml"]
    assert adopt_sensor(sd, fa)["status"] == "same"
    assert load_calibration(sd, "mpu6050", None, a).id == 1
    r = adopt_sensor(sd, fb)                      # the board was swapped
    assert r["status"] == "changed" and r["previous"] == a
    assert load_calibration(sd, "mpu6050", None, b) is None
    assert load_calibration(str(tmp_path / "sensors" / a), "mpu6050", None, a).id == 1   # kept
    assert (tmp_path / "sensors" / a / "history").is_dir()
    r = adopt_sensor(sd, fa)                      # and swapped back: its own calibration returns
    assert r["status"] == "returned" and load_calibration(sd, "mpu6050", None, a).id == 1
    assert yaml.safe_load((tmp_path / "sensor.yaml").read_text())["id"] == a


def test_a_calibration_of_another_sensor_copied_in_is_moved_not_applied(tmp_path):
    sd = str(tmp_path)
    fa = {"chips": {"mpu": {"accel_offset": "aa"}}}
    save_calibration(sd, _cal("0123456789ab"), history=0)
    adopt_sensor(sd, fa)
    assert load_calibration(sd, "mpu6050", None, fingerprint_id(fa)) is None
    assert (tmp_path / "sensors" / "0123456789ab" / "calibration.yaml").exists()
    # and a calibration naming another sensor is refused even if it sits in the state dir
    assert _cal("0123456789ab").mismatch("mpu6050", None, fingerprint_id(fa)).startswith("made on sensor")


def _run_once(tmp_path, seed, query=False):
    """One daemon start on the emulated MPU-6050 of ``seed``, stopped by SIGTERM once it has
    written the identity (at the first sample) and, with ``query``, answered a status that
    carries it.  It used to run a fixed 10 s of sensor time at 5x (2 s of wall time), which
    under load could end before the status query connected (ConnectionRefusedError, seen
    once on two pytest workers)."""
    p, rt, st = start_daemon(tmp_path, "--speed", "5", "--seed", str(seed), "--duration", "600")
    status = None
    try:
        if query:
            wait_for(rt / "control.sock", p)
            deadline = time.time() + 60
            while time.time() < deadline:
                try:
                    status = control(rt, "status")
                except ConnectionRefusedError:      # bound, not yet listening
                    status = None
                if status and "sensor" in status:
                    break
                time.sleep(0.05)
        else:
            wait_for(st / "sensor.yaml", p)
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    return st, err, status


def test_swapped_chip_between_two_daemon_starts_does_not_get_the_first_calibration(tmp_path):
    st, err, _ = _run_once(tmp_path, seed=1)
    a = yaml.safe_load((st / "sensor.yaml").read_text())["id"]
    save_calibration(str(st), _cal(a), history=3)          # the first board's calibration
    st, err, status = _run_once(tmp_path, seed=1, query=True)
    assert "loaded calibration #1" in err and status["calibration_id"] == 1
    assert status["sensor"]["id"] == a and status["sensor"]["status"] == "same"
    # another physical MPU-6050 (other factory trim) on the same bus and address
    st, err, status = _run_once(tmp_path, seed=2, query=True)
    assert "loaded calibration" not in err
    assert "a different sensor than last time" in err and "starts uncalibrated" in err
    assert status["calibration_id"] == 0
    assert status["sensor"]["status"] == "changed" and status["sensor"]["previous"] == a
    assert load_calibration(str(st / "sensors" / a)).id == 1      # the old one is kept on file
    st, err, status = _run_once(tmp_path, seed=1, query=True)     # the first board is back
    assert "loaded calibration #1" in err and status["sensor"]["status"] == "returned"


def test_two_imus_two_instances_keep_their_own_state(tmp_path):
    """imucald@imu0 and imucald@imu1: two MPU-6050s at 0x68 and 0x69, each daemon with its own
    configuration, state and sockets (as the template unit passes them)."""
    procs = []
    for name, addr in (("imu0", "0x68"), ("imu1", "0x69")):
        d = tmp_path / name
        d.mkdir()
        (d / "c.yaml").write_text(f"sensor:\n  address: \"{addr}\"\n")
        procs.append(start_daemon(d, "--config", str(d / "c.yaml"), "--speed", "5", "--seed", "1",
                                  "--duration", "5"))
    ids = []
    for p, rt, st in procs:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
        rec = yaml.safe_load((st / "sensor.yaml").read_text())
        ids.append(rec["id"])
        assert rec["fingerprint"]["chips"]["mpu"]["address"] in ("0x68", "0x69")
    assert ids[0] != ids[1]
    unit = open(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                             "systemd", "imucald@.service")).read()
    # the instance's directories beside the main unit's, never inside them (issue 22)
    for key in ("--config /etc/imucald/%i.yaml", "--state-dir /var/lib/imucald-%i",
                "--runtime-dir /run/imucald-%i", "StateDirectory=imucald-%i", "RuntimeDirectory=imucald-%i",
                "PrivateNetwork=yes", "RestrictAddressFamilies=AF_UNIX"):
        assert key in unit


def test_template_unit_verifies(tmp_path):
    import shutil
    import sys
    sa = shutil.which("systemd-analyze")
    if sa is None:
        pytest.skip("systemd-analyze is absent (apt-get install systemd to run this check)")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    unit = open(os.path.join(root, "systemd", "imucald@.service")).read()
    (tmp_path / "imucald@imu0.service").write_text(unit.replace("/opt/imucald/bin/imucald", sys.executable))
    r = subprocess.run([sa, "verify", str(tmp_path / "imucald@imu0.service")], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr.strip() == "", r.stderr


@pytest.mark.parametrize("text,why", [
    ("id: 5\n", "id: 5 is not text"), ("first_seen: x\n", "no id"), ("- a\n", "not a mapping of keys")])
def test_a_bad_sensor_record_is_set_aside_saying_what_is_wrong(tmp_path, caplog, text, why):
    """A cold review: a sensor.yaml holding ``id: 5`` was set aside as "no id".  Seen to fail
    with every case called "no id"."""
    import logging
    from imucald.daemon.sensors import _read_sensor
    (tmp_path / "sensor.yaml").write_text(text)
    with caplog.at_level(logging.WARNING, logger="imucald"):
        assert _read_sensor(str(tmp_path)) is None
    assert f"unreadable sensor record ({why}" in caplog.text, caplog.text
