"""Acceptance on the command line: the emulated 9DOF board with a QMC5883L runs end to end
(run, status, stream, calibration file), a GY-273 recording replays to a magnetometer
calibration, and probe reports both boards as supported."""
import json
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import yaml

from imucald.cli import main
from imucald.daemon.state import load_calibration

from ._helpers import or_none, wait_until
from .test_daemon import control, sock_file, start_daemon, wait_for


def test_probe_reports_qmc_boards_as_supported(capsys):
    for board, line in (("9dof-qmc", "board: 9dof (magnetometer: QMC5883L)"),
                        ("gy273", "board: gy273 (magnetometer: QMC5883L)")):
        assert main(["probe", "--emulate", board]) == 0
        out = capsys.readouterr().out
        assert line in out and "0x0D  qmc5883l" in out and "not supported" not in out


def _has_accel_and_mag(st):
    cal = load_calibration(str(st))
    return cal is not None and "accel" in cal.to_dict() and "mag" in cal.to_dict()


def test_run_nine_dof_with_qmc_end_to_end(tmp_path):
    """Runs until the calibration in force holds the accelerometer and the magnetometer (a
    condition, not a fixed sensor time: on a loaded machine the background fits finish later
    in the tour; with --duration 150 it failed under two CPU hogs), then stops on SIGTERM."""
    p, rt, st = start_daemon(tmp_path, "--board", "9dof", "--mag", "qmc5883l", "--speed", "10",
                             "--seed", "2", "--method", "lm", "--duration", "1200")
    err_lines = []
    drain = threading.Thread(target=lambda: err_lines.extend(p.stderr), daemon=True)
    try:
        wait_for(rt / "control.sock", p, timeout=120)
        drain.start()
        # the socket file exists a moment before it listens: wait for an answer
        s = wait_until(lambda: or_none(lambda: control(rt, "status", 90)), timeout=120, step=0.1)
        assert s["chips"] == {"accel": "adxl345", "gyro": "itg3200", "mag": "qmc5883l"}
        f = sock_file(rt / "imucald.sock")()
        banner = json.loads(f.readline())
        assert banner["chips"]["mag"] == "qmc5883l"
        objs = [json.loads(f.readline()) for _ in range(300)]
        imu = [o for o in objs if o["class"] == "IMU" and "mag_gauss" in o]
        assert imu and all("acc_g" in o for o in imu)
        f.close()
        t_end = time.monotonic() + 110          # 1200 s of sensor time at 10x is 120 s of wall
        while not _has_accel_and_mag(st) and p.poll() is None and time.monotonic() < t_end:
            time.sleep(0.2)
        p.send_signal(signal.SIGTERM)
        p.wait(timeout=60)
        drain.join(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    err = "".join(err_lines)
    assert p.returncode == 0, err
    assert "mag QMC5883L" in err
    cal = load_calibration(str(st))
    assert cal is not None, err
    doc = cal.to_dict()
    assert doc["chips"]["mag"] == "qmc5883l" and "accel" in doc and "mag" in doc, err
    # the field the emulator was given (0.5 G) seen through the board's soft iron W: the
    # fit normalises W to det 1, so corrected readings have |h| = 0.5 / det(W)^(1/3); the
    # board (its truth) is drawn from the same seed and tour as the daemon's
    from imucald.cli.boards import RUN_TOUR, emulated_bus
    W = emulated_bus("9dof", None, 2, 30, None, dict(RUN_TOUR, tremor_dps=1.0), "qmc5883l",
                     None).smbus.truth.mag_soft_iron
    want = 0.5 / np.cbrt(np.linalg.det(W))
    got, se = doc["mag"]["params"]["field_gauss"], doc["mag"]["stderr"]["field_gauss"]
    assert abs(got - want) < 3 * se, (got, want, se)


def test_gy273_record_replay_calibrates_the_magnetometer(tmp_path, capsys):
    rec = tmp_path / "g.csv"
    assert main(["record", "-o", str(rec), "--board", "gy273", "--seconds", "240", "--poses", "60",
                 "--emulate"]) == 0
    text = rec.read_text()
    assert "# chips: mag=qmc5883l" in text and ",ax," not in text
    r = subprocess.run([sys.executable, "-m", "imucald.cli", "replay", str(rec), "--state-dir",
                        str(tmp_path / "st")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert lines[0]["chips"] == {"mag": "qmc5883l"}
    assert any(o["class"] == "CAL" and o["applied"] for o in lines)
    doc = yaml.safe_load((tmp_path / "st" / "calibration.yaml").read_text())
    assert doc["chips"]["mag"] == "qmc5883l" and "accel" not in doc
    # after calibration the corrected norm is the field (0.5 G) to within the noise
    cal = [o for o in lines if o["class"] == "IMU" and o["cal"] >= 1]
    h = np.linalg.norm([o["mag_gauss"] for o in cal], axis=1)
    assert abs(h.mean() - 0.5) < 0.005 and h.std() < 0.005
