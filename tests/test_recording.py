"""The recording format: round trip and errors that name the file and line."""
import numpy as np
import pytest

from imucald.recording import MAGIC, Recording, RecordingError, read_recording, write_recording


def _rec(n=50, mag=False):
    rng = np.random.default_rng(0)
    return Recording(t=np.arange(n) / 100.0, acc=rng.normal(size=(n, 3)),
                     gyro=rng.normal(size=(n, 3)), mag=rng.normal(size=(n, 3)) if mag else None,
                     temp=20 + rng.random(n), meta={"board": "mpu6050", "rate_hz": "100",
                                                   "accel_range_g": "2", "gyro_range_dps": "250"})


@pytest.mark.parametrize("mag", [False, True])
def test_round_trip(tmp_path, mag):
    r = _rec(mag=mag)
    p = tmp_path / "r.csv"
    write_recording(r, p)
    lines = p.read_text().splitlines()
    assert lines[0] == MAGIC
    assert "# board: mpu6050" in lines
    header = [l for l in lines if not l.startswith("#")][0]
    assert header == ("t,ax,ay,az,gx,gy,gz,mx,my,mz,temp" if mag else "t,ax,ay,az,gx,gy,gz,temp")
    b = read_recording(p)
    assert b.meta["rate_hz"] == "100"
    assert np.allclose(b.t, r.t) and np.allclose(b.acc, r.acc, atol=1e-7)
    assert np.allclose(b.gyro, r.gyro, atol=1e-5) and np.allclose(b.temp, r.temp, atol=1e-3)
    assert (b.mag is None) == (not mag)


def _write(tmp_path, text):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    return p


@pytest.mark.parametrize("text,where,what", [
    ("t,ax\n", ":1:", "not an imucald recording"),
    (MAGIC + "\n# board: x\n# rate_hz: 100\nt,ax,ay,az\n0,1,2,3\n0.01,1,2\n", ":6:", "expected 4 values"),
    (MAGIC + "\n# board: x\n# rate_hz: 100\nt,ax,ay,az\n0,1,2,3\n0.01,1,zz,3\n", ":6:", "'zz' is not a number"),
    (MAGIC + "\n# board: x\n# rate_hz: 100\nt,ax,ay,bz\n", ":4:", "unknown column 'bz'"),
    (MAGIC + "\n# board: x\n# rate_hz: 100\nt,ax,ay\n", ":4:", "must come together"),
    (MAGIC + "\n# board: x\nt,ax,ay,az\n0,1,2,3\n", "bad.csv:", "required key 'rate_hz'"),
    (MAGIC + "\n# board: x\n# rate_hz: fast\nt,ax,ay,az\n0,1,2,3\n", "bad.csv:", "not a number"),
    (MAGIC + "\n# board: x\n# rate_hz: 100\nt,ax,ay,az\n", ":4:", "no samples"),
    (MAGIC + "\n# board: x\n# rate_hz: 100\nt,ax,ay,az\n1,0,0,1\n0,0,0,1\n", "sample 2", "backwards"),
])
def test_errors_name_file_and_line(tmp_path, text, where, what):
    p = _write(tmp_path, text)
    with pytest.raises(RecordingError) as e:
        read_recording(p)
    msg = str(e.value)
    assert str(p) in msg and where in msg and what in msg
    assert "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(RecordingError, match="cannot open"):
        read_recording(tmp_path / "nope.csv")
