"""The public API: the examples of docs/guide/api.md run as written (on a simulated recording, and
against the emulated daemon), and ``import imucald`` stays light."""
import json
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

import imucald
from imucald.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


API_PAGE = os.path.join(ROOT, "docs", "guide", "api.md")


def readme_block(marker):
    text = open(API_PAGE, encoding="utf-8").read()
    m = re.search(re.escape(marker) + r"[^\n]*\n```python\n(.*?)```", text, re.S)
    assert m, f"docs/guide/api.md has no python block after {marker!r}"
    return m.group(1)


def test_import_is_light_and_names_resolve():
    code = ("import sys, imucald; assert 'numpy' not in sys.modules, 'numpy imported'; "
            "print(sorted(n for n in imucald.__all__ if getattr(imucald, n) is None))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0 and p.stdout.strip() == "[]", p.stderr
    with pytest.raises(AttributeError):
        imucald.no_such_name


def test_readme_example_fits_loads_and_applies(tmp_path, monkeypatch, capsys):
    truth = tmp_path / "truth.json"
    assert main(["simulate", "-o", str(tmp_path / "session.csv"), "--board", "mpu6050", "--poses", "24",
                 "--hold", "5", "--seed", "5", "--truth", str(truth)]) == 0
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    exec(compile(readme_block("<!-- api-example:"), API_PAGE, "exec"), {})
    out = capsys.readouterr().out
    assert re.match(r"\d+ poses; ", out), out
    cal = imucald.load_calibration(tmp_path / "calibration.yaml")
    tr = json.load(open(truth))
    est, sd = cal.accel.theta, np.concatenate([cal.accel.stderr[g] for g in ("alpha", "scale", "bias_g")])
    # 4 standard errors, plus the pose-edge motion the detector leaves (as test_replay)
    assert np.all(np.abs(est - tr["accel_triangular9"]) < 4 * sd + 2e-4)
    assert np.all(np.abs(cal.gyro.params["bias_dps"] - tr["gyro_bias_dps"]) < 0.05)
    assert cal.board == "mpu6050"


def test_readme_stream_example_reads_the_daemon(tmp_path, capsys):
    rt = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "imucald.cli", "run", "--emulate", "--speed", "10",
                          "--duration", "60", "--state-dir", str(tmp_path / "st"), "--runtime-dir",
                          str(rt)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        t0 = time.time()
        while not os.path.exists(rt / "control.sock"):         # bound after the data socket
            assert p.poll() is None and time.time() - t0 < 120, p.stderr.read() if p.poll() else "timeout"
            time.sleep(0.05)
        code = readme_block("<!-- api-example-stream:").replace("/run/imucald/imucald.sock",
                                                               str(rt / "imucald.sock"))
        capsys.readouterr()
        exec(compile(code, API_PAGE, "exec"), {})
        out = capsys.readouterr().out.splitlines()
    finally:
        p.terminate()
        p.communicate(timeout=30)
    assert out[0].startswith("mpu6050 ")
    rows = [l.split(" ", 1) for l in out[1:]]
    assert len(rows) > 50 and all(int(a) >= 0 and b.startswith("[") for a, b in rows)


def test_client_says_when_no_daemon_runs(tmp_path):
    with pytest.raises(imucald.UserError, match=r"cannot connect .*is imucald running"):
        imucald.connect(str(tmp_path / "nothing.sock"))


def test_calibrate_output_writes_the_calibration_file(tmp_path, capsys):
    rec = tmp_path / "s.csv"
    assert main(["simulate", "-o", str(rec), "--poses", "16", "--hold", "4", "--seed", "2"]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(rec), "--method", "lm", "--json", "-o", str(tmp_path / "c.yaml")]) == 0
    js = json.loads(capsys.readouterr().out)
    cal = imucald.load_calibration(tmp_path / "c.yaml")
    assert cal.board == "mpu6050" and cal.gyro is None and cal.accel.method == "lm"
    for g, v in js["params"].items():
        assert np.allclose(cal.accel.params[g], v, rtol=0, atol=1e-12)
    from imucald.fitting.models.accel import Triangular9
    raw = np.random.default_rng(0).normal(size=(20, 3))
    th = np.concatenate([js["params"][g] for g in ("alpha", "scale", "bias_g")])
    assert np.allclose(cal.apply_accel(raw), Triangular9().forward(th, raw), atol=1e-12)
