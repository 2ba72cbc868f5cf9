"""The error boundary: every fault of issue 12's "Tracebacks" list ends in one line naming the
place and the fix, with its documented exit code (imucald/errors.py), and nothing opened first."""
import json
import os
import re
import subprocess
import time

import numpy as np
import pytest

from imucald.errors import NO_RESTART

from ._helpers import PY, ROOT, one_line, run_main


@pytest.mark.parametrize("argv,code,msg", [
    # a chip that never answers
    (["record", "--emulate", "-o", "{d}/r.csv", "--seconds", "1", "--fault", "nack=1"], 69,
     "no acknowledge from 0x68 on emulated mpu6050 (errno 121): check wiring/address"),
    # rates the board cannot run at, checked before the board is opened
    (["record", "--emulate", "--board", "9dof", "--rate", "150", "-o", "{d}/r.csv"], 2,
     "--rate 150: 150 Hz is not a rate of the 9dof board's ADXL345; allowed 6.25, 12.5, 25, 50, 100, "
     "200, 400, 800, 1600 Hz (nearest: 100 or 200)"),
    (["record", "--emulate", "--rate", "0", "-o", "{d}/r.csv"], 2, "argument --rate: 0 is not a number > 0"),
    (["record", "--emulate", "--rate", "5000", "-o", "{d}/r.csv"], 2,
     "--rate 5000: 5000 Hz is beyond the MPU6050's 3.91..1000 Hz"),
    (["record", "--emulate", "--poses", "0", "-o", "{d}/r.csv"], 2, "argument --poses: 0 is too few: at least 1"),
    (["run", "--emulate", "--speed", "0"], 2, "argument --speed: 0 is not a number > 0"),
    (["run", "--emulate", "--speed", "-1"], 2, "argument --speed: -1 is not a number > 0"),
    (["run", "--emulate", "--board", "9dof", "--rate", "150"], 2,
     "--rate: sensor.rate_hz: 150 Hz is not a rate of the 9dof board's ADXL345"),
    (["run", "--emulate", "--rate", "5000"], 2, "--rate: sensor.rate_hz: 5000.0 is out of range; allowed 4.0..1000.0"),
    (["run", "--emulate", "--config", "{d}/c9.yaml"], 78,
     "c9.yaml:3: sensor.rate_hz: 150 Hz is not a rate of the 9dof board's ADXL345"),
    (["simulate", "--poses", "0", "-o", "{d}/r.csv"], 2, "argument --poses: 0 is too few: at least 1"),
    (["gap", "{sim}", "--sims", "0"], 2, "argument --sims: 0 is too few: at least 20"),
    # nan turned the minimum-span check off (span < nan is False) and -5 meant "any span"
    (["calibrate", "{sim}", "--thermal-min-span", "-5"], 2, "argument --thermal-min-span: -5 is not a number > 0"),
    (["calibrate", "{sim}", "--thermal-min-span", "nan"], 2, "argument --thermal-min-span: nan is not a number > 0"),
    # outputs that cannot be created: said before the work, not after it
    (["record", "--emulate", "-o", "{d}/missing/r.csv"], 73, "directory {d}/missing does not exist"),
    (["record", "--emulate", "-o", "{d}"], 73, "-o {d}: is a directory; give a file name"),
    (["simulate", "-o", "{d}/missing/r.csv"], 73, "directory {d}/missing does not exist"),
    (["calibrate", "{sim}", "-o", "{d}/missing/c.yaml"], 73, "--output {d}/missing/c.yaml: directory"),
    (["gap", "{sim}", "--sims", "20", "--report", "{d}/afile/plots"], 73,
     "--report {d}/afile/plots: {d}/afile is not a directory"),
    (["replay", "{sim}", "--state-dir", "{d}/afile"], 73, "--state-dir {d}/afile: exists and is not a directory"),
    # no daemon to talk to
    (["status", "--runtime-dir", "{d}/norun"], 69, "no control socket: is imucald running?"),
])
def test_bad_arguments_and_places_exit_with_one_line(tmp_path, capsys, sim, argv, code, msg):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "c9.yaml").write_text("sensor:\n  board: 9dof\n  rate_hz: 150\n")
    argv = [a.format(d=tmp_path, sim=sim) for a in argv]
    rc, out, err = run_main(capsys, *argv)
    line = one_line(err)
    assert rc == code, err
    assert msg.format(d=tmp_path) in line
    assert not (tmp_path / "r.csv").exists()


def _variant(src: bytes, tmp_path, name, fn):
    p = tmp_path / name
    p.write_bytes(fn(src))
    return p


@pytest.mark.parametrize("cmd", ["calibrate", "gap", "replay"])
@pytest.mark.parametrize("name,fn,msg", [
    ("latin.csv", lambda s: s.replace(b"\n0.200000,", b"\n0.2\xb0,", 1), "byte 0xb0 at offset"),
    ("garbage.csv", lambda s: bytes(range(256)) * 8, "not an imucald recording"),
    ("ratenan.csv", lambda s: s.replace(b"rate_hz: 100", b"rate_hz: nan"), "header rate_hz='nan' is not"),
    ("rateinf.csv", lambda s: s.replace(b"rate_hz: 100", b"rate_hz: inf"), "header rate_hz='inf' is not"),
    ("rate0.csv", lambda s: s.replace(b"rate_hz: 100", b"rate_hz: 0"), "header rate_hz='0' is not"),
    ("big.csv", lambda s: re.sub(rb"\n(4\.000000),[^,]+,", rb"\n\1,1e308,", s, count=1),
     "column ax: 1e308 is beyond what a sensor reads"),
    ("nan.csv", lambda s: re.sub(rb"\n(4\.000000),[^,]+,", rb"\n\1,nan,", s, count=1),
     "column ax: nan is not a finite number"),
])
def test_bad_recordings_exit_2_with_one_line(tmp_path, capsys, sim, cmd, name, fn, msg):
    p = _variant(sim.read_bytes(), tmp_path, name, fn)
    rc, out, err = run_main(capsys, cmd, p, *(["--sims", "20"] if cmd == "gap" else []))
    line = one_line(err.replace("imucald: 0 still poses", ""))
    assert rc == 2 and msg in line, err
    assert f"{name}:" in line


def test_pose_file_with_zero_deviations_calibrates_without_thermal_terms(tmp_path, capsys, sim):
    """Pose means without within-pose deviations (s* columns 0: hand-made means, one-sample
    poses) fit as before; the thermal fit, which weights poses by those deviations, has no
    pose to use and is left out (it was a ValueError traceback)."""
    from imucald.fitting.stillness.poses import poses_from_recording, write_poses
    from imucald.files.recording import read_recording
    p = tmp_path / "p.csv"
    write_poses(poses_from_recording(read_recording(str(sim))), str(p))
    lines = p.read_text().splitlines()
    h = next(i for i, l in enumerate(lines) if l.startswith("t0,"))
    cols = lines[h].split(",")
    for i in range(h + 1, len(lines)):
        row = lines[i].split(",")
        for c in cols:
            if c.startswith("s"):
                row[cols.index(c)] = "0"
        lines[i] = ",".join(row)
    p.write_text("\n".join(lines) + "\n")
    rc, out, err = run_main(capsys, "calibrate", p, "--json")
    assert rc == 0 and "Traceback" not in err, err
    d = json.loads(out)
    assert "thermal" not in d and d["poses"] == 12 and d["noise_source"] == "residuals", d
    assert np.isfinite(np.hstack(list(d["params"].values()))).all() and d["heldout_rms_g"] < 1e-3, d


def test_nan_in_a_raw_table_is_named(tmp_path, capsys):
    t = tmp_path / "t.txt"
    t.write_text("0 0 0 1\n0.01 nan 0 1\n")
    rc, out, err = run_main(capsys, "calibrate", t, "--columns", "t,ax,ay,az")
    assert rc == 2 and "t.txt:2: column ax: nan is not a finite number" in one_line(err)


# --- the daemon: start-up faults (subprocesses: the daemon installs signal handlers) -------

def daemon(tmp_path, *extra, rt=None):
    rt = rt or tmp_path / "run"
    return subprocess.Popen([PY, "-m", "imucald.cli", "run", "--emulate", "--state-dir",
                             str(tmp_path / "state"), "--runtime-dir", str(rt), *map(str, extra)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)


def errline(err):
    lines = [l for l in err.splitlines() if l.startswith("imucald: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_daemon_chip_that_never_answers_exits_69_and_leaves_no_socket(tmp_path):
    p = daemon(tmp_path, "--duration", "1", "--fault", "nack=1")
    out, err = p.communicate(timeout=60)
    assert p.returncode == 69
    assert "no acknowledge from 0x68 on emulated mpu6050 (errno 121): check wiring/address" in errline(err)
    assert [f for f in os.listdir(tmp_path / "run") if f.endswith(".sock")] == []


def test_runtime_dir_too_long_for_a_socket_exits_73(tmp_path):
    rt = tmp_path / ("r" * 110)
    p = daemon(tmp_path, "--duration", "1", rt=rt)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 73
    assert re.search(r"output.socket: .* is \d+ bytes; a Unix socket path holds at most 107: choose a "
                     r"shorter runtime.directory", errline(err))


@pytest.mark.parametrize("name,make,what", [
    ("imucald.sock", lambda p: p.write_text("not a socket"), "a file"),
    ("control.sock", lambda p: p.mkdir(), "a directory"),
])
def test_a_file_where_a_socket_belongs_exits_73_untouched(tmp_path, name, make, what):
    rt = tmp_path / "run"
    rt.mkdir()
    make(rt / name)
    p = daemon(tmp_path, "--duration", "1")
    out, err = p.communicate(timeout=60)
    assert p.returncode == 73
    assert f"{rt / name} exists and is {what}, not a socket" in errline(err)
    assert (rt / name).exists() and not (rt / "control.sock" if name == "imucald.sock" else
                                         rt / "imucald.sock").exists()


def test_second_instance_exits_75_and_leaves_the_first_alone(tmp_path):
    first = daemon(tmp_path, "--speed", "5")
    try:
        t0 = time.time()
        while not (tmp_path / "run" / "control.sock").exists():
            assert first.poll() is None and time.time() - t0 < 60, first.stderr.read()
            time.sleep(0.05)
        ino = os.stat(tmp_path / "run" / "imucald.sock").st_ino
        second = daemon(tmp_path, "--duration", "1")
        out, err = second.communicate(timeout=60)
        assert second.returncode == 75
        assert f"runtime.directory: another imucald (pid {first.pid}) holds" in errline(err)
        assert os.stat(tmp_path / "run" / "imucald.sock").st_ino == ino     # its socket untouched
        assert first.poll() is None
    finally:
        first.terminate()
        first.communicate(timeout=30)
    assert first.returncode == 0
    assert not (tmp_path / "run" / "imucald.sock").exists()


def test_unit_prevents_restart_exactly_for_the_unfixable_codes():
    unit = open(os.path.join(ROOT, "systemd", "imucald.service")).read()
    line = next(l for l in unit.splitlines() if l.startswith("RestartPreventExitStatus="))
    assert {int(x) for x in line.split("=", 1)[1].split()} == set(NO_RESTART) == {2, 73, 78}


@pytest.mark.parametrize("body,msg", [
    (b"sensor:\n  board: mpu6050  # 20 \xb0C\n", "c.yaml:2: byte 0xb0 at offset 31 is not UTF-8"),
    (b"output:\n  socket_mode: 0660\n", 'c.yaml:2: output.socket_mode: 0660 unquoted is a number to YAML'),
    (b"sensor:\n  board: mpu6050\n  board: 9dof\n", "c.yaml:3: sensor.board is given twice"),
    (b"sensor:\n  emulate: maybe\n", "c.yaml:2: sensor.emulate: 'maybe' is not allowed"),
    (b"? [a]\n: 1\n", "c.yaml:1: a key must be a name"),
])
def test_a_bad_configuration_stops_the_daemon_at_start_with_78(tmp_path, capsys, body, msg):
    (tmp_path / "c.yaml").write_bytes(body)
    rc, out, err = run_main(capsys, "run", "--emulate", "--config", tmp_path / "c.yaml",
                            "--runtime-dir", tmp_path / "run", "--state-dir", tmp_path / "st")
    assert rc == 78 and msg in one_line(err), err
    assert not (tmp_path / "run").exists() or not os.listdir(tmp_path / "run")


@pytest.mark.parametrize("row,msg", [
    ("0,1,200,nan,0,1,0.004,0.004,0.004", "p.csv:4: column ax: nan is not a finite number"),
    ("0,1,200,1e300,0,1,0.004,0.004,0.004", "p.csv:4: column ax: 1e+300 is beyond 1e+06"),
    ("0,1,-5,0,0,1,0.004,0.004,0.004", "p.csv:4: column n: -5.0 is not a sample count"),
])
def test_a_bad_pose_file_exits_2_with_one_line(tmp_path, capsys, row, msg):
    good = "\n".join(f"{i},{i + 1},200,{x},{y},{z},0.004,0.004,0.004" for i, (x, y, z) in
                     enumerate([(1, 0, 0), (0, 1, 0), (0, 0, 1)]))
    (tmp_path / "p.csv").write_text(f"# imucald poses v1\n# board: mpu6050\nt0,t1,n,ax,ay,az,sax,say,saz\n"
                                    f"{row}\n{good}\n")
    rc, out, err = run_main(capsys, "calibrate", tmp_path / "p.csv")
    assert rc == 2 and msg in one_line(err), err


@pytest.mark.parametrize("acc", ["0,0,0", "1e6,0,0", "0,0,0.2"])
def test_a_pose_that_is_not_at_rest_under_gravity_exits_2(tmp_path, capsys, acc):
    # a zero pose was a LinAlgError traceback; 1e6 g fitted "excess scatter x4e18"
    rows = [f"{i},{i + 1},200,{x},{y},{z},0.004,0.004,0.004" for i, (x, y, z) in
            enumerate([(1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1),
                       (0.6, 0.8, 0), (0, 0.6, 0.8), (0.8, 0, 0.6), (-0.6, 0, 0.8), (0.6, -0.8, 0)])]
    rows[4] = "4,5,200," + acc + ",0.004,0.004,0.004"
    (tmp_path / "p.csv").write_text("# imucald poses v1\n# board: mpu6050\nt0,t1,n,ax,ay,az,sax,say,saz\n"
                                    + "\n".join(rows) + "\n")
    rc, out, err = run_main(capsys, "calibrate", tmp_path / "p.csv")
    line = one_line(err)
    assert rc == 2 and "p.csv: pose 5 (t0 4 s)" in line and "not ~1 g" in line, err


@pytest.mark.parametrize("mag", ["zero", "same", "plane"])
def test_magnetometer_pose_means_that_do_not_span_3d_exit_2(tmp_path, capsys, mag):
    # all-zero or identical magnetometer means were a LinAlgError traceback
    import numpy as np
    rng = np.random.default_rng(3)
    acc = rng.normal(size=(14, 3))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    m = {"zero": np.zeros((14, 3)), "same": np.tile([0.2, 0.1, 0.4], (14, 1)),
         "plane": np.c_[0.3 * np.cos(np.arange(14)), 0.3 * np.sin(np.arange(14)), np.full(14, 0.2)]}[mag]
    rows = [f"{i},{i + 2},200,{a[0]},{a[1]},{a[2]},0.004,0.004,0.004,{b[0]},{b[1]},{b[2]}"
            for i, (a, b) in enumerate(zip(acc, m))]
    (tmp_path / "p.csv").write_text("# imucald poses v1\n# board: 9dof\nt0,t1,n,ax,ay,az,sax,say,saz,mx,my,mz\n"
                                    + "\n".join(rows) + "\n")
    rc, out, err = run_main(capsys, "calibrate", tmp_path / "p.csv", "--sensor", "mag")
    line = one_line(err)
    assert rc == 2 and "p.csv: the magnetometer pose means do not span three dimensions" in line, err
