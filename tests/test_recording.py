"""The recording format: round trip and errors that name the file and line."""
import math

import numpy as np
import pytest

from imucald.files.recording import (
    MAGIC, Recording, RecordingError, read_recording, write_recording
)


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
    (MAGIC + "\n# board: x\n# rate_hz: 100\nt,ax,ay,az\n1,0,0,1\n0,0,0,1\n", ":6:", "time goes backwards"),
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


# --- faults from issue 12: one line naming the place, never a traceback -----------------

HEAD = MAGIC + "\n# board: mpu6050\n# rate_hz: 100\nt,ax,ay,az\n"


def _one_line_error(fn, *a, cls=RecordingError):
    with pytest.raises(cls) as e:
        fn(*a)
    msg = str(e.value)
    assert "\n" not in msg and msg
    return msg


def test_non_utf8_after_header_names_line_and_offset(tmp_path):
    body = "0,0,0,1\n0.01,0,0,1\n0.02,0,0,1 \xb0C\n"
    p = tmp_path / "latin1.csv"
    p.write_bytes((HEAD + body).encode("latin-1"))
    msg = _one_line_error(read_recording, p)
    off = (HEAD + body).encode("latin-1").index(b"\xb0")
    assert f"{p}:7:" in msg and f"offset {off}" in msg and "0xb0" in msg and "not UTF-8" in msg


def test_non_utf8_in_header(tmp_path):
    p = tmp_path / "h.csv"
    p.write_bytes((MAGIC + "\n# note: 25 \xb0C\n").encode("latin-1"))
    msg = _one_line_error(read_recording, p)
    assert f"{p}:2:" in msg and "offset" in msg


def test_binary_garbage(tmp_path):
    p = tmp_path / "garbage.bin"
    p.write_bytes(np.random.default_rng(1).bytes(200_000))
    msg = _one_line_error(read_recording, p)
    assert f"{p}:1: not an imucald recording" in msg


@pytest.mark.parametrize("rate", ["nan", "inf", "-inf", "0", "-100", "1e400"])
def test_rate_must_be_positive_finite(tmp_path, rate):
    p = _write(tmp_path, HEAD.replace("rate_hz: 100", f"rate_hz: {rate}") + "0,0,0,1\n")
    msg = _one_line_error(read_recording, p)
    assert f"{p}:3:" in msg and "rate_hz" in msg and "> 0" in msg


@pytest.mark.parametrize("value,what", [("1e308", "beyond what a sensor reads"), ("nan", "not a finite"),
                                        ("-inf", "not a finite")])
def test_recording_non_finite_or_absurd_value_named(tmp_path, value, what):
    p = _write(tmp_path, HEAD + "0,0,0,1\n0.01,0,0,1\n0.02,0," + value + ",1\n0.03,0,0,1\n")
    msg = _one_line_error(read_recording, p)
    assert f"{p}:7:" in msg and "column ay" in msg and what in msg


def test_missing_file_and_directory(tmp_path):
    assert "No such file" in _one_line_error(read_recording, tmp_path / "nope.csv")
    assert "is a directory" in _one_line_error(read_recording, tmp_path)


def test_chunked_read_matches_whole_and_lines_count_across_blocks(tmp_path):
    from imucald.files.recording import open_recording
    r = _rec(n=3000, mag=True)
    p = tmp_path / "r.csv"
    write_recording(r, p)
    whole = read_recording(p)
    with open_recording(p) as rd:
        parts = list(rd.chunks(chunk_bytes=4096))
    assert len(parts) > 20
    for name in ("t", "acc", "gyro", "mag", "temp"):
        assert np.array_equal(np.concatenate([getattr(c, name) for c in parts]), getattr(whole, name))
    with open_recording(p) as rd:
        small = rd.read(chunk_bytes=1000)
    assert np.array_equal(small.acc, whole.acc) and small.acc.flags.c_contiguous
    # a bad value deep in the file: the line number counts every block before it
    lines = p.read_text().splitlines()
    k = len(lines) - 17
    lines[k] = lines[k].replace(",", ",nan,", 1).replace(",nan,", ",", 1).rsplit(",", 1)[0] + ",inf"
    p.write_text("\n".join(lines) + "\n")
    with open_recording(p) as rd:
        with pytest.raises(RecordingError, match=f":{k + 1}: column temp: inf"):
            for _ in rd.chunks(chunk_bytes=4096):
                pass


def test_whole_read_when_later_lines_are_shorter_than_the_first_block(tmp_path):
    """read() sizes its arrays from the first block's bytes per row; lines that are shorter
    later (fewer digits) overrun that estimate: the arrays grow and hold every row."""
    from imucald.files.recording import open_recording
    n = 4000
    t = np.arange(n) / 100.0
    acc = np.where(np.arange(n)[:, None] < 200, np.pi * np.arange(1, 4), 0.0) + np.zeros((n, 3))
    body = "".join(f"{a:.6f},{float(x)!r},{float(y)!r},{float(z)!r}\n" if i < 200 else
                   f"{a:.2f},{x:.0f},{y:.0f},{z:.0f}\n" for i, (a, (x, y, z)) in enumerate(zip(t, acc)))
    p = tmp_path / "grow.csv"
    p.write_text("# imucald recording v1\n# board: mpu6050\n# rate_hz: 100\nt,ax,ay,az\n" + body)
    with open_recording(p) as rd:
        r = rd.read(chunk_bytes=2000)
    assert len(r) == n and np.array_equal(r.acc, acc) and np.allclose(r.t, t)
    assert r.acc.flags.c_contiguous


def test_table_nan_and_1e308_named(tmp_path):
    from imucald.fitting.inputs import read_table
    p = tmp_path / "raw.txt"
    rows = [f"{i / 100:.2f} 32768 32768 {32768 + 16384}" for i in range(50)]
    for bad, what in (("nan", "not a finite"), ("1e308", "beyond what a sensor reads")):
        rr = list(rows)
        rr[30] = f"0.30 32768 {bad} 49152"
        p.write_text("% t ax ay az\n" + "\n".join(rr) + "\n")
        msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, 32768.0,
                              cls=UserError)
        assert f"{p}:32: column ay" in msg and what in msg
    p.write_text("% t ax ay az\n" + "\n".join(rows) + "\n")
    rec = read_table(str(p), ["t", "ax", "ay", "az"], 16384.0, 32768.0)
    assert len(rec) == 50 and np.allclose(rec.acc[:, 2], 1.0) and rec.meta["rate_hz"] == "100"


def test_table_time_in_milliseconds_or_microseconds(tmp_path):
    """A logger's millis() (or micros()) is read through a time column named t_ms (t_us): the
    same recording as seconds in t.  The same column named t (seconds) would make a 10-ms
    logger a 0.1 Hz one, whose poses hold a few samples each (the freeimu warm-up, logged in
    ms: 'no still moment ... 3 distinct samples'): refused, naming t_ms, unless --rate-hz
    confirms so low a rate.  Broken once each: without the ms/us scaling (the times differ),
    without the slow-step check (no error), with --rate-hz checked against the median step."""
    from imucald.fitting.inputs import read_table
    rng = np.random.default_rng(3)
    t_ms = 17139 + np.cumsum(rng.integers(9, 12, 200))              # 10 +- 1 ms steps
    acc = np.round(rng.normal(0, 20, (200, 3)) + [0, 0, 16384])
    cols = ["t", "ax", "ay", "az"]
    p_s, p_ms, p_us = tmp_path / "s.csv", tmp_path / "ms.csv", tmp_path / "us.csv"
    for p, t in ((p_s, t_ms / 1e3), (p_ms, t_ms), (p_us, t_ms * 1000)):
        p.write_text("".join(f"{a},{b},{c},{x!r}\n" for (a, b, c), x in zip(acc, t.tolist())))
    # the time column last, as the freeimu logger writes it
    ref = read_table(str(p_s), cols[1:] + ["t"], 16384.0)
    for p, name in ((p_ms, "t_ms"), (p_us, "t_us")):
        rec = read_table(str(p), cols[1:] + [name], 16384.0)
        assert np.allclose(rec.t, ref.t, rtol=0, atol=1e-9) and np.array_equal(rec.acc, ref.acc)
        # t: the median step, 10 ms; t_ms, t_us: the mean of the whole-unit steps (9-11 ms,
        # drawn uniformly: within 1 % of 10 ms over 199 steps)
        assert ref.meta["rate_hz"] == "100" and abs(float(rec.meta["rate_hz"]) / 100 - 1) < 0.01
    names = "name the time column by its unit (t: s, t_ms: ms, t_us: us, t_ns: ns)"
    msg = _one_line_error(read_table, str(p_ms), cols[1:] + ["t"], 16384.0, cls=UserError)
    assert msg.startswith(f"{p_ms}: t advances by a median 10 s a row (0.1 Hz), slower than")
    assert names in msg and msg.endswith("give --rate-hz 0.1")
    assert len(read_table(str(p_ms), cols[1:] + ["t"], 16384.0, rate_hz=0.1)) == 200
    # a rate given beside the wrong unit does not silence it (a logger's 100 Hz, its ms as s)
    msg = _one_line_error(read_table, str(p_ms), cols[1:] + ["t"], 16384.0, 0.0, 100.0, cls=UserError)
    assert msg.startswith(f"{p_ms}: --rate-hz 100 but t spans ") and "over 200 rows" in msg and names in msg
    # seconds named t_ms: 100 k rows a second
    msg = _one_line_error(read_table, str(p_s), cols[1:] + ["t_ms"], 16384.0, cls=UserError)
    assert f"{p_s}: t_ms spans " in msg and "faster than an IMU is read at" in msg and names in msg
    msg = _one_line_error(read_table, str(p_ms), ["ax", "ay", "az", "t_ms", "t"], 16384.0, cls=UserError)
    assert "two time columns (t_ms, t)" in msg


@pytest.mark.parametrize("cols,scale,rows,why", [
    ("ax,ay,az", 1.0, "0,0,16384", "g after --nominal-scale (none given): raw counts (or mg)? give --nominal-scale"),
    ("ax,ay,az", 1.0, "0,0,9.81", "g after --nominal-scale (none given): m/s^2? give --nominal-scale accel=9.80665"),
    ("ax,ay,az", 16384.0, "0,0,1.0", "g after --nominal-scale: already in g? then leave --nominal-scale out"),
    # IMU-TK's SOURCE.md gives 415 counts per m/s^2: given as counts per g, the file reads
    # ~9.8 g, and "give accel=9.80665" sent a newcomer round in a loop (helper-87)
    ("ax,ay,az", 415.0, "0,0,4069.76", "g after --nominal-scale: is 415 counts per m/s^2? counts per g are "
                                       "4069.76: give --nominal-scale accel=4069.76"),
    ("ax,ay,az", 131.0, "0,0,16384", "(accel=N,gyro=N when the gyro's differ; - in --columns leaves a sensor "
                                     "out); the scale that reads this median as 1 g is 1.638e+04"),
    ("mx,my,mz", 1.0, "20,-5,-40", "gauss after --nominal-scale (none given): microtesla (--nominal-scale mag=100)"),
    ("mx,my,mz", 1.0, "218,-55,-436", "gauss after --nominal-scale (none given): raw counts or milligauss?"),
    ("mx,my,mz", 1090.0, "0.2,-0.05,-0.4", "gauss after --nominal-scale: already in gauss? then leave its")])
def test_a_raw_table_in_other_units_is_warned_of(tmp_path, capsys, cols, scale, rows, why):
    """Counts read without --nominal-scale (a newcomer's first try), m/s^2, a scale given to
    a file already in g, microtesla: each read as plausible-looking numbers that the fit then
    failed on ('no still moment: ... 4.37e+04 mg per axis: hold the board still') or that
    apply wrote out in silence.  Judged on the median magnitude (about 1 g at rest and in a
    hand's motion; Earth's field 0.25-0.65 gauss): one warning line naming the scale to give.
    A warning, not a refusal: a centrifuge, free fall or a sensor the command does not use
    is no error.  1 g and 0.5 gauss say nothing.  A magnetometer file already in gauss given
    the HMC5883L's 1090 failed as 'only 0 direction cells: rotate the sensor' (a new user's
    walk-through).  A scale given in counts per m/s^2 (or the gyro's) is named with the one
    that reads the median as 1 g.  Broken once: _unit_warnings returning none (8 of 8 fail)."""
    from imucald.fitting.inputs import read_table
    rng = np.random.default_rng(0)
    base = np.array([float(x) for x in rows.split(",")])
    p = tmp_path / "u.csv"
    p.write_text("".join(f"{i / 100:.2f}," + ",".join(f"{v:.6g}" for v in base * (1 + 0.01 * rng.standard_normal(3)))
                         + "\n" for i in range(200)))
    assert len(read_table(str(p), ["t"] + cols.split(","), scale)) == 200
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"imucald: warning: {p}: the ") and why in err, err
    good = base / np.linalg.norm(base) * (1.0 if cols[0] == "a" else 0.5) * scale
    p.write_text("".join(f"{i / 100:.2f}," + ",".join(f"{v:.6g}" for v in good) + "\n" for i in range(200)))
    assert len(read_table(str(p), ["t"] + cols.split(","), scale)) == 200
    assert capsys.readouterr().err == ""
    # free fall in g, no scale given: no advice to leave out a scale that was not given
    p.write_text("".join(f"{i / 100:.2f},0,0,0.02\n" for i in range(200)))
    read_table(str(p), ["t", "ax", "ay", "az"], 1.0)
    assert capsys.readouterr().err == ""


def test_a_phone_log_in_si_units_with_nanosecond_stamps(tmp_path):
    """A phone's sensor log (Android: event times in ns since boot, m/s^2 and rad/s) is read
    with t_ns and a scale per sensor: the same samples as the recording it was made from
    (times within the 256 ns a double keeps of a 1.7e18 ns stamp).  Broken once: t_ns taken out
    of files/tables.TIME_UNITS (an unknown column: fails)."""
    from imucald.fitting.inputs import read_table
    from imucald.cli import main
    rec_path, tab = tmp_path / "r.csv", tmp_path / "phone.csv"
    assert main(["simulate", "-o", str(rec_path), "--poses", "12", "--rate", "50", "--seed", "3"]) == 0
    r = read_recording(str(rec_path))
    g, rad = 9.80665, math.pi / 180
    t_ns = 1_700_000_000_000_000_000 + np.round(r.t * 1e9)
    with open(tab, "w") as fh:
        fh.write("timestamp_ns,ax_ms2,ay_ms2,az_ms2,gx_rads,gy_rads,gz_rads\n")
        fh.writelines(f"{t:.0f}," + ",".join(repr(float(x)) for x in (*a, *w)) + "\n"
                      for t, a, w in zip(t_ns, r.acc * g, r.gyro * rad))
    got = read_table(str(tab), ["t_ns", "ax", "ay", "az", "gx", "gy", "gz"],
                     {"accel": g, "gyro": rad})
    assert np.allclose(got.acc, r.acc, rtol=1e-12, atol=0) and np.allclose(got.gyro, r.gyro, rtol=1e-12, atol=1e-12)
    assert np.allclose(got.t - got.t[0], r.t - r.t[0], rtol=0, atol=1e-6)
    assert abs(float(got.meta["rate_hz"]) - 50) < 0.01


def test_table_rate_of_whole_millisecond_steps_bursts_and_coarse_clocks(tmp_path):
    """A 400 Hz chip logged with millis() steps by 2 and 3 ms: the median says 333 or 500 Hz;
    the mean of the steps near it says 400.  Two loggers whose steps are not their rate are
    judged by their rows a second: one that stamps each row of a FIFO burst as it prints it (4
    rows 15 us apart every 40 ms: 100 rows a second) is not refused as too fast, and its
    --rate-hz 100 is taken; one with a whole-second clock at 200 Hz is refused without
    --rate-hz, the message giving the rate its rows have, and read with it.  Broken once each:
    the median alone for whole-unit steps, --rate-hz checked against the median step, the fast
    check on the median step, the coarse-clock branch removed: each fails."""
    from imucald.fitting.inputs import read_table
    i = np.arange(4000)
    cases = ((np.floor(i * 2.5), "t_ms", None, 400.0), ((i // 4) * 40000 + (i % 4) * 15, "t_us", 100.0, 100.0),
             (np.floor(i / 200), "t", 200.0, 200.0))
    for t, name, given, want in cases:
        p = tmp_path / f"{name}.csv"
        p.write_text("".join(f"{x:.0f},0,0,16384\n" for x in t))
        rec = read_table(str(p), [name, "ax", "ay", "az"], 16384.0, 0.0, given)
        # 3999 steps: 2000 of one length and 1999 of the other, 1 in 4000
        assert len(rec) == 4000 and abs(float(rec.meta["rate_hz"]) - want) <= want / 4000
    read_table(str(tmp_path / "t_us.csv"), ["t_us", "ax", "ay", "az"], 16384.0)      # not refused
    msg = _one_line_error(read_table, str(tmp_path / "t.csv"), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert "t advances by a median 1 s a row but t spans 19 s over 4000 rows (210.5 rows a second)" in msg
    assert "a clock coarser than the samples; give --rate-hz, the rate it was logged at (about 210.5" in msg


def test_table_time_backwards_in_its_unit_and_a_micros_wrap_named(tmp_path):
    """A time column that steps back is named in its own unit; in t_us a step back by more
    than 2**31 us is an Arduino's 32-bit micros() wrapping (every 71.6 min), said as such.
    Broken once: the wrap threshold at 2**40 (the generic message: fails); the step back's
    seconds taken as its units (25 ms read as a restart: fails)."""
    from imucald.fitting.inputs import read_table
    p = tmp_path / "us.csv"
    t = [2 ** 32 - 30000 + 10000 * i for i in range(3)] + [(10000 * i) % 2 ** 32 for i in range(1, 4)]
    p.write_text("".join(f"0,0,16384,{x}\n" for x in t))
    msg = _one_line_error(read_table, str(p), ["ax", "ay", "az", "t_us"], 16384.0, cls=UserError)
    assert msg.startswith(f"{p}:4: time goes backwards (10000 us after 4294957296 us)")
    assert "micros() counter wraps every 71.6 min" in msg
    p.write_text("".join(f"0,0,16384,{x}\n" for x in (10, 20, 30, 25, 40)))
    msg = _one_line_error(read_table, str(p), ["ax", "ay", "az", "t_ms"], 16384.0, cls=UserError)
    assert msg.startswith(f"{p}:4: time goes backwards (25 ms after 30 ms); sort the rows")
    # back by more than a second: a logger that restarted (sorting would mix two recordings);
    # said so, with the split (a cold review: "sort the rows" for an Arduino's reset)
    p.write_text("".join(f"0,0,16384,{x}\n" for x in (118421, 118441, 1830, 1840)))
    msg = _one_line_error(read_table, str(p), ["ax", "ay", "az", "t_ms"], 16384.0, cls=UserError)
    assert msg == (f"{p}:3: time goes backwards (1830 ms after 118441 ms): the logger restarted or its "
                   f"time counter wrapped; split the file there (head -n 2 {p} > part1.csv, and the rest "
                   f"from line 3, below the header lines if the file has them: each part is a recording)"), msg


def test_every_row_one_value_short_or_one_a_line_is_named_a_layout_not_a_line_to_repair(tmp_path):
    """A logger writing 7 values under an 8-column header, or a file separated by ';' with
    decimal points (one value a line): the fix is the column names or the separator, and the
    message said "repair or delete this line" of the first row (a helper).  Now it names the
    count, the columns and the fix; a few rows of another count among good ones still get the
    line's own message.  Broken once: the layout branch removed (the old message: fails)."""
    p = tmp_path / "seven.csv"
    head = "# imucald recording v1\n# board: mpu6050\n# rate_hz: 100\nt,ax,ay,az,gx,gy,gz,temp\n"
    body = [f"{i * 0.01:.2f},0,0,1,0.1,0.2,0.3" for i in range(40)]
    p.write_text(head + "\n".join(body) + "\n")
    msg = _one_line_error(read_recording, p)
    assert msg == (f"{p}:5: 40 lines from here to line 44 hold 7 values each, the columns name 8 "
                   f"(t,ax,ay,az,gx,gy,gz,temp): the file's layout is not these columns; name its "
                   f"columns as the file writes them (its header line or --columns)"), msg
    p.write_text(head + "\n".join(r.replace(",", ";") + ";22.0" for r in body) + "\n")
    msg = _one_line_error(read_recording, p)
    assert "hold 1 value each" in msg and "not separated by ',' or white space" in msg, msg
    body[7] = "0.07,0,0,1,0.1,0.2"
    p.write_text(head + "\n".join(r + ",22.0" if k != 7 else r for k, r in enumerate(body)) + "\n")
    msg = _one_line_error(read_recording, p)
    assert msg.startswith(f"{p}:12: expected 8 values") and "(repair or delete this line)" in msg, msg


def test_garbled_lines_after_the_first_are_listed_in_the_same_error(tmp_path):
    """Several garbled lines (a logger's serial noise): the error names the first, in full, and
    lists the others read with it, so one run shows what to repair; a file with one garbled
    line keeps the plain message; a step back in time still stops at its line (what follows
    depends on it).  Broken once: with _parse_slow raising at the first bad line (no list),
    the first assertion failed; with at_end always False, the file's end was "later lines
    not checked" again (fails)."""
    from imucald.fitting.inputs import read_table
    p = tmp_path / "serial.csv"
    rows = [f"{i * 0.01:.2f},0,0,16384" for i in range(20)]
    for k, bad in ((3, "0.03,0,,16384"), (7, "0.07,0,x,16384"), (8, "garbage"), (15, "0.15,0,0,inf")):
        rows[k] = bad
    p.write_text("t,ax,ay,az\n" + "\n".join(rows) + "\n")
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg.startswith(f"{p}:5: column ay is empty (repair or delete this line)"), msg
    assert msg.endswith("(also garbled: lines 9, 10, 17, up to the file's end)"), msg
    # a file longer than the block the list was read in says where it stopped (session 20, a
    # helper: "later lines not checked" was said of a file's last line too)
    big = rows + [f"{(20 + i) * 0.01:.2f},0,0,16384" for i in range(100_000)]
    p.write_text("t,ax,ay,az\n" + "\n".join(big) + "\n")
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg.endswith("; later lines not checked)") and "up to line " in msg, msg
    assert int(msg.split("up to line ")[1].split(";")[0]) < len(big) + 1, msg
    rows = [f"{i * 0.01:.2f},0,0,16384" for i in range(20)]
    rows[3] = "0.03,0,x,16384"
    p.write_text("t,ax,ay,az\n" + "\n".join(rows) + "\n")
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg == f"{p}:5: column ay: 'x' is not a number", msg
    rows[3] = "0.03,0,0,16384"
    rows[12] = "0.01,0,0,16384"
    rows[14] = "garbage"
    p.write_text("t,ax,ay,az\n" + "\n".join(rows) + "\n")
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg.startswith(f"{p}:14: time goes backwards") and "also garbled" not in msg, msg


def test_a_column_header_repeated_mid_file_is_named_with_both_fixes(tmp_path):
    """A logger that restarted and appended writes its header again mid-file: named as that,
    with the delete (time carries on) and the split (time starts again), not as "'t' is not a
    number".  A logger's own error line of names ("I2C,timeout,...") keeps the plain message.
    Broken once: with _header_again returning False the first assertion failed.  The split of an
    imucald recording appended to itself gives two readable recordings."""
    from imucald.fitting.inputs import read_table
    from imucald.files.recording import RecordingError, read_recording
    p = tmp_path / "log.csv"
    rows = [f"{i * 0.01:.2f},0,0,16384" for i in range(6)]
    p.write_text("t,ax,ay,az\n" + "\n".join(rows[:3] + ["t,ax,ay,az"] + rows[3:]) + "\n")
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg == (f"{p}:5: a column header again ('t,ax,ay,az'): a logger that restarted and appended? "
                   f"If the time carries on below it, delete this line (sed -i '5d' {p}); if it starts "
                   f"again, split the file there (head -n 4 {p} > part1.csv; tail -n +5 {p} > part2.csv: "
                   f"each part is a recording)"), msg
    p.write_text("t,ax,ay,az\n" + "\n".join(rows[:3] + ["I2C,timeout,retry,later"] + rows[3:]) + "\n")
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg == f"{p}:5: column t: 'I2C' is not a number", msg
    q = tmp_path / "rec.csv"           # an imucald recording appended to itself
    head = "# imucald recording v1\n# board: mpu6050\n# rate_hz: 100\nt,ax,ay,az\n"
    body = "\n".join(r.replace(",16384", ",1") for r in rows[:3]) + "\n"
    q.write_text(head + body + head + body)
    msg = _one_line_error(read_recording, str(q), cls=RecordingError)
    # the split takes the second header's '#' lines with the second part (a cold review: the
    # part from the line after the column names had no header, and calibrate refused it;
    # broken once with the split at the column-names line: part 2 unreadable, fails)
    assert f"{q}:11: a column header again" in msg and f"head -n 7 {q} > part1.csv; tail -n +8 {q}" in msg, msg
    lines = q.read_text().splitlines(keepends=True)
    for k, part in enumerate((lines[:7], lines[7:])):
        f = tmp_path / f"part{k + 1}.csv"
        f.write_text("".join(part))
        assert len(read_recording(str(f))) == 3


@pytest.mark.parametrize("sep", [";", "\t"])
def test_table_with_a_decimal_comma_is_read(tmp_path, capsys, sep):
    """A spreadsheet's or phyphox's export in a locale whose decimal mark is the comma
    (0,01;0,5;-0,25;16384, or tabs between values) was refused ("a decimal comma? export it
    with ','"; tabs gave "expected 4 values, found 8").  It is read, the same numbers as the
    '.' table, with a warning naming the line, and an error later in it names its own line.
    A plain CSV whose rows split into as many values as columns stays a CSV.  Broken once:
    _first_row without the decimal-comma test (tabs: "expected 4 values, found 6"; ";": no rows),
    and without the look past a row of whole numbers (the tab case: "found 7"); spec.quoted
    without the file's own text ('1.2.3' is quoted: fails)."""
    from imucald.fitting.inputs import read_table
    p = tmp_path / "semi.csv"
    rows = [(i / 100, 0.5, -0.25, 16384 - i) for i in range(300)]
    body = "".join(sep.join(f"{v:g}".replace(".", ",") for v in r) + "\n" for r in rows)
    p.write_text(f"time{sep}ax{sep}ay{sep}az\n" + body)
    rec = read_table(str(p), ["t", "ax", "ay", "az"], 16384.0)
    ref = np.array(rows)
    assert np.array_equal(rec.t, ref[:, 0]) and np.array_equal(rec.acc, ref[:, 1:] / 16384.0)
    err = capsys.readouterr().err
    assert f"{p}:2: read as a spreadsheet's export" in err and err.count("\n") == 1
    lines = body.splitlines(True)
    lines[40] = sep.join(["0,41", "zz", "0", "1"]) + "\n"            # the file's line 42
    p.write_text(f"time{sep}ax{sep}ay{sep}az\n" + "".join(lines))
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg.startswith(f"{p}:42: column ax: 'zz' is not a number"), msg
    # the quote is the file's own text, not the translated one (it read '1.2.3' for 1,2,3 and
    # '3.0e9' for 3,0e9: a user searching the file for it found nothing)
    for bad, said in (("1,2,3", "column ax: '1,2,3' is not a number"),
                      ("3,0e9", "column ax: 3,0e9 is beyond what a sensor reads")):
        lines[40] = sep.join(["0,41", bad, "0", "1"]) + "\n"
        p.write_text(f"time{sep}ax{sep}ay{sep}az\n" + "".join(lines))
        msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 1.0, cls=UserError)
        assert msg.startswith(f"{p}:42: {said}"), msg
    # a line of the wrong count is quoted as written too, and an empty field named (a cold review:
    # "found 6: '0.50 0.01 ...'" for 0,50;0,01;...)
    if sep == ";":
        for bad, said in (("0,41;0,5;;1", "column ay is empty (repair or delete this line)"),
                          ("0,41;0,5;1,5;1;2", "expected 4 values (t,ax,ay,az), found 5: '0,41;0,5;1,5;1;2' "
                                               "(repair or delete this line)")):
            lines[40] = bad + "\n"
            p.write_text(f"time{sep}ax{sep}ay{sep}az\n" + "".join(lines))
            msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 1.0, cls=UserError)
            assert msg == f"{p}:42: {said}", msg
    capsys.readouterr()
    # a wrong --columns (an extra column in the file) gets the count's own message, not "not a
    # numeric table" (a newcomer's walk: phyphox's "Absolute acceleration" column)
    p.write_text(f"time{sep}ax{sep}ay{sep}az{sep}abs\n" + "".join(
        sep.join(f"{v:g}".replace(".", ",") for v in (*r, 1.5)) + "\n" for r in rows))
    # (session 20, a helper: every row holding 5 values is a layout, not a line to repair or
    # delete; the message says so and names the columns)
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg == (f"{p}:2: 300 lines from here to line 301 hold 5 values each, the columns name 4 "
                   f"(t,ax,ay,az): the file's layout is not these columns; name its columns as the "
                   f"file writes them (its header line or --columns)"), msg
    capsys.readouterr()
    # a first row of whole numbers (t = 0, counts) says nothing of the mark: the first row
    # with a ',' decides (a cold review: "expected 4 values, found 5" on the second row)
    p.write_text("".join(sep.join(f"{v:g}".replace(".", ",") for v in r) + "\n"
                         for r in [(0, 1, 2, 16384)] + rows[1:]))
    rec = read_table(str(p), ["t", "ax", "ay", "az"], 16384.0)
    assert np.array_equal(rec.t, ref[:, 0]) and rec.acc[0, 0] == 1 / 16384.0
    capsys.readouterr()
    # a CSV with ", " between integers reads as 4 numbers either way: it stays a CSV
    p.write_text("".join(f"{10 * i}, 0, 0, {16384 + i % 7}\n" for i in range(300)))
    rec = read_table(str(p), ["t_ms", "ax", "ay", "az"], 16384.0)
    assert np.allclose(rec.t, np.arange(300) / 100) and rec.acc[6, 2] == (16384 + 6) / 16384
    assert "spreadsheet" not in capsys.readouterr().err


def test_table_nominal_scale_and_offset_per_sensor(tmp_path):
    """An MPU-6050 logged in counts has 16384 counts per g and 131 per deg/s: one scale for
    both read the gyro 125x too small (the freeimu warm-up's gyro in gap: thermal terms of
    1e-6 deg/s/degC).  Per sensor, each is converted with its own; a per-sensor value that
    leaves out a sensor whose columns the table has is refused, naming it.  Broken once: the
    accelerometer's value used for every sensor (the gyro reads 131x off: fails)."""
    from imucald.cli.checks import per_sensor
    from imucald.fitting.inputs import read_table
    p = tmp_path / "raw.csv"
    p.write_text("".join(f"{i * 0.01:.2f},0,0,16384,{131 * 2 + 32768},32768,{32768 - 131}\n"
                         for i in range(50)))
    cols = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    rec = read_table(str(p), cols, per_sensor("accel=16384,gyro=131"), per_sensor("accel=0,gyro=32768"))
    assert np.allclose(rec.acc, [0, 0, 1]) and np.allclose(rec.gyro, [2, 0, -1])
    rec = read_table(str(p), cols, 16384.0, 0.0)                         # one for both: as before
    assert np.allclose(rec.gyro[0], [(131 * 2 + 32768) / 16384, 2, (32768 - 131) / 16384])
    msg = _one_line_error(read_table, str(p), cols, {"accel": 16384.0}, 0.0, cls=UserError)
    assert "--nominal-scale: no value for the gyro columns (gx,gy,gz): add gyro=N" in msg
    msg = _one_line_error(read_table, str(p), cols, {"accel": 16384.0, "gyro": 0.0}, 0.0, cls=UserError)
    assert "--nominal-scale 0 (gyro): must be a finite, non-zero number" in msg
    import argparse
    for bad, what in (("accel=16384,gyr=131", "expected accel=N, gyro=N, mag=N and temp=N"),
                      ("accel=1,accel=2", "each at most once"),
                      ("accel=x,gyro=131", "'accel=x' in 'accel=x,gyro=131': 'x' is not a number"),
                      ("inf", "inf is not a finite number \\(one for every sensor, or accel=N"),
                      ("16k", "'16k' is not a number \\(one for every sensor")):
        with pytest.raises(argparse.ArgumentTypeError, match=what):
            per_sensor(bad)
    assert per_sensor("4069.76") == 4069.76


def test_table_temperature_in_counts_is_converted_when_named_and_warned_of_otherwise(tmp_path, capsys):
    """An MPU-6050 logger's temperature column is its TEMP_OUT register (the FreeIMU file's
    dTemp): read as degC it gave 'thermal (-7822.8..-2595.8 degC ...)' with exit 0, and no
    option converted it (a new user's walk-through).  ``temp=N`` in --nominal-scale and
    --nominal-offset converts it (temp=340 and temp=-12420.2: the datasheet's T = counts /
    340 + 36.53), an offset naming only temp leaves the sensors at 0, one number leaves the
    temperature as it is, and a median outside any die's range (-60..150 degC) is warned of,
    naming the conversion.  Refused: one of the two without the other, a scale naming temp
    alone beside a sensor's columns, a scale <= 0.  Broken once each: the conversion skipped,
    the warning removed, the scale-without-offset check removed (fail)."""
    from imucald.cli.checks import per_sensor
    from imucald.fitting.inputs import read_table
    counts = np.linspace(-8000, -2600, 50)                 # 13.0 .. 28.9 degC
    p = tmp_path / "t.csv"
    p.write_text("".join(f"{i * 10},0,0,16384,{c:.0f}\n" for i, c in enumerate(counts)))
    cols = ["t_ms", "ax", "ay", "az", "temp"]
    rec = read_table(str(p), cols, per_sensor("accel=16384,temp=340"), per_sensor("temp=-12420.2"))
    np.testing.assert_allclose(rec.temp, np.round(counts) / 340 + 36.53, rtol=0, atol=1e-9)
    assert np.allclose(rec.acc, [0, 0, 1]) and capsys.readouterr().err == ""
    rec = read_table(str(p), cols, 16384.0, 0.0)
    assert np.array_equal(rec.temp, np.round(counts))
    err = capsys.readouterr().err
    assert "the temperature reads a median of -5300 degC, outside any die's: raw counts? give " \
           "--nominal-scale temp=N and --nominal-offset temp=N" in err
    # a cold review: the scale without its offset read the FreeIMU warm-up as -23..-8 degC
    # (inside any die's range: no warning) and wrote thermal terms that never act on a board
    # reading degC; a scale naming temp alone read the gyro's counts as deg/s
    msg = _one_line_error(read_table, str(p), cols, per_sensor("accel=16384,temp=340"), 0.0, cls=UserError)
    assert msg.startswith("--nominal-scale temp=N without --nominal-offset temp=N") and "needs neither" not in msg
    # temp=1 alone: a column already in degC, which needs neither (a cold review: told it needs
    # an offset); said so (broken once: the hint left out)
    msg = _one_line_error(read_table, str(p), cols, per_sensor("accel=16384,temp=1"), 0.0, cls=UserError)
    assert msg.endswith("; a column already in degC needs neither: leave temp= out of --nominal-scale"), msg
    g = tmp_path / "g.csv"
    g.write_text("".join(f"{i * 10},0,0,131,{c:.0f}\n" for i, c in enumerate(counts)))
    msg = _one_line_error(read_table, str(g), ["t_ms", "gx", "gy", "gz", "temp"], per_sensor("temp=340"),
                          per_sensor("temp=-12420.2"), cls=UserError)
    assert "--nominal-scale: no value for the gyro columns (gx,gy,gz): add gyro=N" in msg
    msg = _one_line_error(read_table, str(p), cols, per_sensor("accel=16384,temp=-340"), per_sensor("temp=0"),
                          cls=UserError)
    assert "--nominal-scale temp=-340: must be the counts per degC, a number > 0" in msg


def test_join_holds_a_slower_chips_file_beside_the_first_tables_rows(tmp_path, capsys):
    """A logger that writes each chip to its own file (the sunsided MPU-6050 and HMC5883L
    files; IMU-TK's accelerometer and gyro): ``--join`` gives each row of the first table
    the latest row of the second at or before its time (the same stamps: row for row).
    Here a magnetometer file at a quarter of the rate, starting 0.25 s later: each row gets
    the mag row whose time is the last not after its own, exactly; the two rows before the
    magnetometer's first are dropped, with a warning; so are the rows in a 5-s hole in its file
    (its last reading is held for 1.5x its usual longest step, not across the hole), but not
    those between a logger's bursts (4 rows in 3 ms every 2 s: the usual step); two tables with
    the same stamps, one repeated, pair row for row.  Refused in one line each: a sensor in
    both tables, times that do not overlap, a table without a time column, a joined table
    naming no sensor or an unknown column (named as --join-columns'), --join without
    --join-columns (and the reverse), a joined imucald recording.  Broken once each: the row
    before (searchsorted side='left': the exact-stamp rows take the previous reading), the
    hold not limited within the file (fail)."""
    from imucald.cli import main
    from imucald.fitting.inputs import load_input
    t = np.arange(40) * 0.125                       # 8 Hz (times exact in binary)
    a = tmp_path / "mpu.csv"
    a.write_text("".join(f"{x:.17g},0,0,1,{i},0,0\n" for i, x in enumerate(t)))
    tm = t[2::4]                                    # 2 Hz, its first at 0.25 s
    m = tmp_path / "hmc.csv"
    m.write_text("".join(f"{x:.17g},{k},0.2,-0.4\n" for k, x in enumerate(tm)))
    cols, mcols = "t,ax,ay,az,gx,gy,gz".split(","), "t,mx,my,mz".split(",")
    _, rec = load_input(str(a), cols, join=(str(m), mcols))
    assert np.array_equal(rec.t, t[2:]) and np.array_equal(rec.gyro[:, 0], np.arange(2, 40))
    assert np.array_equal(rec.mag[:, 0], (np.arange(2, 40) - 2) // 4)      # held, exactly
    assert "2 of 40 rows dropped: no row of --join" in capsys.readouterr().err
    # a 5-s hole in a minute of the magnetometer's file: its last reading is not held across it
    # (held 1.5x its usual longest step, 0.5 s); a logger's bursts are usual steps, not holes
    t8 = np.arange(480) * 0.125
    a8, hole, burst = tmp_path / "a8.csv", tmp_path / "hole.csv", tmp_path / "burst.csv"
    a8.write_text("".join(f"{x:.17g},0,0,1,{i},0,0\n" for i, x in enumerate(t8)))
    t2 = t8[::4]
    hole.write_text("".join(f"{x:.17g},{k},0.2,-0.4\n" for k, x in enumerate(t2) if not 20 < x < 25))
    _, rec = load_input(str(a8), cols, join=(str(hole), mcols))
    assert not np.any((rec.t > 20.0 + 0.75) & (rec.t < 25)) and np.sum(rec.t <= 20.75) == 167
    assert "rows dropped" in capsys.readouterr().err
    # a short file (40 rows) with one 3-s hole: its 99th percentile would be the hole itself
    short = tmp_path / "short.csv"
    ts = np.r_[np.arange(20) * 0.5, 12.5 + np.arange(20) * 0.5]
    short.write_text("".join(f"{x:.17g},{k},0.2,-0.4\n" for k, x in enumerate(ts)))
    _, rec = load_input(str(a8), cols, join=(str(short), mcols))
    assert not np.any((rec.t > 9.5 + 0.75) & (rec.t < 12.5))
    capsys.readouterr()
    tb = np.repeat(t8[::16], 4) + np.tile([0, 0.001, 0.002, 0.003], 30)   # 4 rows in 3 ms, every 2 s
    burst.write_text("".join(f"{x:.17g},{k},0.2,-0.4\n" for k, x in enumerate(tb)))
    _, rec = load_input(str(a8), cols, join=(str(burst), mcols))
    i = np.arange(480)          # a row at a burst's first stamp takes that row, the others its last
    assert len(rec.t) == 480 and np.array_equal(rec.mag[:, 0], (i // 16) * 4 + np.where(i % 16, 3, 0))
    # the same stamps, one of them repeated: row for row
    dup = np.r_[t[:10], t[9:39]]
    a2, g2 = tmp_path / "a2.csv", tmp_path / "g2.csv"
    a2.write_text("".join(f"{x:.17g},0,0,1\n" for x in dup))
    g2.write_text("".join(f"{x:.17g},{i},0,0\n" for i, x in enumerate(dup)))
    _, rec = load_input(str(a2), ["t", "ax", "ay", "az"], join=(str(g2), ["t", "gx", "gy", "gz"]))
    assert np.array_equal(rec.gyro[:, 0], np.arange(40))
    msg = _one_line_error(load_input, str(a), cols, 1.0, 0.0, None, (str(a), cols), cls=UserError)
    assert "accelerometer columns in both tables" in msg
    late = tmp_path / "late.csv"
    late.write_text("".join(f"{x + 100:.17g},{k},0.2,-0.4\n" for k, x in enumerate(tm)))
    msg = _one_line_error(load_input, str(a), cols, 1.0, 0.0, None, (str(late), mcols), cls=UserError)
    assert "do not overlap" in msg and "must share a clock" in msg
    msg = _one_line_error(load_input, str(a), cols, 1.0, 0.0, None, (str(m), ["-", "mx", "my", "mz"]),
                          cls=UserError)
    assert msg.startswith("--join-columns: no time column")
    msg = _one_line_error(load_input, str(a), cols, 1.0, 0.0, None, (str(m), ["t", "-", "-", "-"]), cls=UserError)
    assert "names no sensor column to join" in msg
    msg = _one_line_error(load_input, str(a), cols, 1.0, 0.0, None, (str(m), ["t", "mx", "my", "mq"]), cls=UserError)
    assert msg.startswith("--join-columns: unknown column 'mq'")
    for argv, what in ((["--join", str(m)], "name its columns with --join-columns"),
                       (["--join-columns", "t,mx,my,mz"], "give the table it names with --join FILE")):
        assert main(["calibrate", str(a), "--columns", ",".join(cols), *argv]) == 2
        assert what in capsys.readouterr().err
    rec_file = tmp_path / "rec.csv"
    write_recording(rec, str(rec_file))
    msg = _one_line_error(load_input, str(a), cols, 1.0, 0.0, None, (str(rec_file), mcols), cls=UserError)
    assert "an imucald file; --join takes a raw table" in msg


@pytest.mark.parametrize("make,expect", [
    (lambda d: d / "nope.csv", "No such file"),
    (lambda d: d, "is a directory"),
])
def test_cli_missing_or_directory_one_line(tmp_path, capsys, make, expect):
    from imucald.cli import main
    for argv in (["calibrate", str(make(tmp_path))], ["gap", str(make(tmp_path))],
                 ["replay", str(make(tmp_path))]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and expect in err and "Traceback" not in err


def test_cli_replay_binary_garbage_one_line(tmp_path, capsys):
    from imucald.cli import main
    p = tmp_path / "g.bin"
    p.write_bytes(bytes(range(256)) * 100)
    assert main(["replay", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an imucald recording" in err


from imucald.errors import UserError  # noqa: E402


def test_replay_streamed_in_small_blocks_gives_the_same_stream(tmp_path, monkeypatch, capsysbinary):
    """Replay reads the recording block by block; the stream (batch boundaries, sequence
    numbers) must not depend on where the blocks end."""
    from imucald.files import tables
    from imucald.cli import main
    p = tmp_path / "m.csv"
    assert main(["simulate", "-o", str(p), "--board", "mpu9250", "--poses", "3", "--hold", "2",
                 "--move", "1", "--rate", "200"]) == 0
    capsysbinary.readouterr()
    assert main(["replay", str(p)]) == 0
    whole = capsysbinary.readouterr().out
    monkeypatch.setattr(tables, "CHUNK_BYTES", 777)
    assert main(["replay", str(p)]) == 0
    small = capsysbinary.readouterr().out
    assert whole == small and whole.count(b"\n") > 1000


@pytest.mark.parametrize("argv", [["--help"], ["status", "--runtime-dir", "{d}"], ["watch", "--runtime-dir", "{d}"]])
def test_light_commands_do_not_import_numpy(tmp_path, argv):
    """--help, status and watch start without numpy or the calibration code (issue 15)."""
    import subprocess
    import sys
    code = ("import sys\nfrom imucald.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n"
            "    pass\nprint(sorted(m for m in ('numpy', 'imucald.fitting', 'imucald.files.recording') "
            "if m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code, *[a.format(d=tmp_path) for a in argv]],
                       capture_output=True, text=True)
    assert p.stdout.strip().splitlines()[-1] == "[]", p.stdout + p.stderr


def test_a_fifo_burst_table_has_its_rows_rate_and_a_doubled_one_its_stamps(tmp_path):
    """A logger that stamps each FIFO burst with its read time (40 rows at 400 Hz under one
    stamp every 0.1 s) was a 10-Hz recording: gap, the gyro's windows and the replay took
    each pose as 40 times longer than it was (an independent probe's bursty null: gyro
    'unexplained', ratio 1.48; 1.13 and 'none' with the rate right).  The rate is the rows'
    when most rows share the stamp before and differ from its row; a row written twice (the
    same stamp, the same values) is one sample.  Broken once: _burst_rate returning None
    (10 Hz: fails)."""
    from imucald.fitting.inputs import read_table
    rng = np.random.default_rng(3)
    n = 4000
    acc = rng.normal([0, 0, 16384], 20, (n, 3)).round()
    stamp = (np.arange(n) // 40 + 1) * 0.1                   # the burst's read time, s
    p = tmp_path / "burst.csv"
    np.savetxt(p, np.column_stack([stamp, acc]), delimiter=",", fmt="%.6f")
    rec = read_table(str(p), ["t", "ax", "ay", "az"], 16384.0)
    # 4000 rows under 100 stamps 0.1 s apart: 99 steps (9.9 s) with 40 rows each (the first
    # stamp's rows come before any step)
    assert rec.rate_hz == pytest.approx(3960 / 9.9, rel=1e-6)
    twice = np.repeat(np.column_stack([np.arange(n // 2) / 400.0, acc[: n // 2]]), 2, axis=0)
    np.savetxt(p, twice, delimiter=",", fmt="%.6f")
    assert read_table(str(p), ["t", "ax", "ay", "az"], 16384.0).rate_hz == pytest.approx(400.0)


def test_rows_of_one_value_on_every_axis_are_failed_reads_left_out(tmp_path, capsys):
    """An MPU-6050 on a disturbed I2C bus returns 0x0000 or 0xFFFF in every register, and an
    Arduino logger writes the row anyway: rows of 0 (or -1) counts on all six axes.  They were
    data: a cold review's 20 such rows in 22,627 made 36 poses of 28 holds and the gyro's
    scale 0.1-0.3 % off.  Taken out now as lost samples, with one warning; the table then
    reads as the one without them.  An accelerometer-only table keeps its rows (three equal
    values are a free fall's 0 g).  Broken once (_drop_failed_reads returning at once): the
    rows are read (the length and the warning fail); the time from the count of rows kept
    (np.arange): the no-time-column case fails."""
    from imucald.fitting.inputs import read_table
    rng = np.random.default_rng(5)
    n = 400
    raw = np.column_stack([np.arange(n) * 10, rng.integers(-300, 300, (n, 2)), 16384 + rng.integers(-300, 300, n),
                           rng.integers(-200, 200, (n, 3))])
    bad = [50, 51, 200]
    for i, v in zip(bad, (0, 0, -1)):
        raw[i, 1:] = v
    cols = ["t_ms", "ax", "ay", "az", "gx", "gy", "gz"]
    p, q = tmp_path / "raw.csv", tmp_path / "clean.csv"
    p.write_text("".join(",".join(map(str, r)) + "\n" for r in raw))
    q.write_text("".join(",".join(map(str, r)) + "\n" for i, r in enumerate(raw) if i not in bad))
    scale = {"accel": 16384.0, "gyro": 131.0}
    rec = read_table(str(p), cols, scale)
    err = capsys.readouterr().err
    assert f"{p}: 3 rows read one value (-1, 0) on every axis: reads that failed" in err, err
    ref = read_table(str(q), cols, scale)
    assert len(rec.t) == n - 3 and np.array_equal(rec.t, ref.t) and np.array_equal(rec.acc, ref.acc) \
        and np.array_equal(rec.gyro, ref.gyro)
    # without a time column the rows' numbers are the time: a failed read is a sample lost,
    # not closed up (it was: a cold review's rotations then read the motion short)
    p.write_text("".join(",".join(map(str, r[1:])) + "\n" for r in raw))
    rec = read_table(str(p), cols[1:], scale, rate_hz=100.0)
    capsys.readouterr()
    assert np.array_equal(rec.t, np.delete(np.arange(n), bad) / 100.0)
    # three columns alike (an accelerometer alone): kept
    p.write_text("".join(",".join(map(str, r[:4])) + "\n" for r in raw))
    assert len(read_table(str(p), cols[:4], 16384.0).t) == n
    assert "failed" not in capsys.readouterr().err


def test_a_garbled_line_is_quoted_and_an_empty_field_named(tmp_path):
    """A serial logger's file: a banner line written again after a reset, a line cut short, an
    empty field.  The error said "expected 7 values (...), found 3" without the line (which
    was it: a banner, two rows run together?) and "found 6" for an empty field (a cold review).
    Now the line itself, quoted, and the empty column by name, each with what to do.  Broken
    once (the former message): fails."""
    from imucald.fitting.inputs import read_table
    cols = ["t_ms", "ax", "ay", "az", "gx", "gy", "gz"]
    rows = [f"{10 * i},12,-40,16384,3,-2,1" for i in range(20)]
    p = tmp_path / "serial.csv"
    for bad, said in (("Initializing I2C devices...",
                       "expected 7 values (t_ms,ax,ay,az,gx,gy,gz), found 3: 'Initializing I2C devices...' "
                       "(repair or delete this line)"),
                      ("110,12", "expected 7 values (t_ms,ax,ay,az,gx,gy,gz), found 2: '110,12' (repair "
                                 "or delete this line)"),
                      ("110,12,,16384,3,-2,1", "column ay is empty (repair or delete this line)")):
        p.write_text("\n".join(rows[:11] + [bad] + rows[12:]) + "\n")
        msg = _one_line_error(read_table, str(p), cols, 16384.0, cls=UserError)
        assert msg == f"{p}:12: {said}", msg


@pytest.mark.parametrize("fmt", ["iso_t", "iso_space", "time_of_day", "whitespace", "semicolon"])
def test_a_date_time_column_says_how_to_read_it(tmp_path, fmt):
    """Loggers write their time as a date and time (ISO 8601 with 'T' or a space, or a serial
    terminal's time of day), which no reader takes as a number: the table was "not a
    numeric table" after 1000 lines, naming neither the column nor the way in.  Now the
    first such row names the line, the column and its text, and the --columns that skips it
    (one '-' per field the readers split it into: a date and its time at white space are
    two), with --rate-hz; that command reads the table as the one with numbers there,
    including a ';'-separated one (its skipped column may hold text too).  Broken once (no
    date-time check in the first-row search: "no row of 4 numbers"; the skipped columns not
    exempted in the decimal-comma test: the ';' table "not a numeric table"): fails."""
    from imucald.fitting.inputs import read_table
    rows = [(i, 0.01 * (i % 7), -0.02, 1.0 - 0.001 * (i % 3)) for i in range(300)]
    stamp = {"iso_t": "2026-01-01T12:00:{:06.3f}", "iso_space": "2026-01-01 12:00:{:06.3f}",
             "time_of_day": "12:00:{:06.3f}", "whitespace": "2026-01-01 12:00:{:06.3f}",
             "semicolon": "2026-01-01T12:00:{:06.3f}"}[fmt]
    sep = {"whitespace": " ", "semicolon": ";"}.get(fmt, ",")
    p, q = tmp_path / "dated.csv", tmp_path / "num.csv"
    p.write_text("time,ax,ay,az\n" + "".join(sep.join([stamp.format(0.01 * i), f"{x}", f"{y}", f"{z}"]) + "\n"
                                            for i, x, y, z in rows))
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 1.0, cls=UserError)
    skip = "-,-" if fmt in ("iso_space", "whitespace") else "-"
    assert msg == (f"{p}:2: column 1 (t) reads {stamp.format(0.0)!r}, a date and time, not a number: "
                   f"skip it (--columns {skip},ax,ay,az) and give the sample rate (--rate-hz), or write "
                   f"the time as a number (t: s, t_ms: ms, t_us: us, t_ns: ns)"), msg
    q.write_text("".join(f"{x},{y},{z}\n" for _, x, y, z in rows))
    a = read_table(str(p), skip.split(",") + ["ax", "ay", "az"], 1.0, rate_hz=100.0)
    b = read_table(str(q), ["ax", "ay", "az"], 1.0, rate_hz=100.0)
    assert np.array_equal(a.acc, b.acc) and np.array_equal(a.t, b.t) and len(a.t) == 300


@pytest.mark.parametrize("fmt", ["comma", "semicolon_decimal_comma", "comma_decimal_comma"])
def test_quoted_values(tmp_path, fmt):
    """Some exporters quote every value ("0.01","9.81"): such a table was "not a numeric table"
    after 1000 lines.  Now the quotes are read as spaces, byte for byte (line numbers and
    offsets stay the file's), also with ';' between values and ',' as the decimal mark; a
    quoted decimal comma with ',' between the values cannot be split by bytes and is refused
    in one line naming the line, a value and the export to make.  Broken once (the quotes
    not recognised): the first two fail with "no row of 4 numbers"."""
    from imucald.fitting.inputs import read_table
    rows = [(0.01 * i, 0.01 * (i % 7), -0.02, 1.0 - 0.001 * (i % 3)) for i in range(300)]
    sep, dec = {"comma": (",", "."), "semicolon_decimal_comma": (";", ","),
                "comma_decimal_comma": (",", ",")}[fmt]
    q = lambda v: '"' + f"{v:.3f}".replace(".", dec) + '"'
    p, n = tmp_path / "quoted.csv", tmp_path / "num.csv"
    p.write_text(sep.join(f'"{c}"' for c in ("t", "ax", "ay", "az")) + "\n"
                 + "".join(sep.join(q(v) for v in r) + "\n" for r in rows))
    cols = ["t", "ax", "ay", "az"]
    if fmt == "comma_decimal_comma":
        msg = _one_line_error(read_table, str(p), cols, 1.0, cls=UserError)
        assert msg == (f'{p}:2: values in quotes with "," as their decimal mark ("0,000") and "," between '
                       f'them: export the table with ";" between values or "." as the decimal mark'), msg
        return
    n.write_text("".join(",".join(f"{v:.3f}" for v in r) + "\n" for r in rows))
    a, b = read_table(str(p), cols, 1.0), read_table(str(n), cols, 1.0)
    assert np.array_equal(a.acc, b.acc) and np.array_equal(a.t, b.t) and len(a.t) == 300


@pytest.mark.parametrize("sep", [",", ";", '";"'])
def test_a_loggers_own_header_repeated_mid_file_is_named(tmp_path, sep):
    """A logger's own column names ("time_ms,AcX,...,GyZ": an Arduino sketch's) written again
    mid-file after a restart were "column t_ms: 'time_ms' is not a number": only names imucald
    knows (t, ax, ...) were taken for a header.  Now the file's own header line again is named
    as one, with the delete and the split, also in a ';' table read with a decimal comma and a
    quoted one, quoting the line as the file writes it.  Broken once (the header lines not
    kept): "is not a number"; fails."""
    from imucald.fitting.inputs import read_table
    q = '"' if sep == '";"' else ""
    line = lambda vals: q + sep.join(vals) + q
    head = line(["time_ms", "AcX", "AcY", "AcZ"])
    rows = [line([str(10 * i), "0", "0", "16384"]) for i in range(6)]
    p = tmp_path / "log.csv"
    p.write_text("\n".join([head] + rows[:3] + [head] + rows[3:]) + "\n")
    msg = _one_line_error(read_table, str(p), ["t_ms", "ax", "ay", "az"], 16384.0, cls=UserError)
    assert msg.startswith(f"{p}:5: a column header again ({head!r}): a logger that restarted"), msg


def test_a_temperature_beyond_any_die_is_warned_of(tmp_path, capsys):
    """A temperature column whose median is plausible but whose span no die reaches (a ramp to
    222 degC: a conversion off in its slope; a black-box helper's odd input) was read without
    a word, and thermal terms fitted over it.  One warning now names the span and the rows
    outside -60..150 degC; a warm-up of 22..40 degC says nothing.  Broken once (the span not
    checked): fails."""
    from imucald.fitting.inputs import read_table
    p = tmp_path / "hot.csv"
    for top, said in ((222.0, True), (40.0, False)):
        temp = np.linspace(22.0, top, 300)
        p.write_text("".join(f"{i / 100:.2f},0,0,1,{t:.3f}\n" for i, t in enumerate(temp)))
        assert len(read_table(str(p), ["t", "ax", "ay", "az", "temp"], 1.0)) == 300
        err = capsys.readouterr().err
        k = int(np.count_nonzero(temp > 150.0))
        want = f"imucald: warning: {p}: the temperature spans 22..{top:g} degC, {k} row(s) outside any die's -60..150"
        assert (want in err) == said and err.count("\n") == int(said), err


def test_a_skipped_column_may_hold_text(tmp_path):
    """A ROS `rostopic echo -p` export has a text column (field.header.frame_id, "imu_link")
    among its numbers: skipped with '-', the file was still "not a numeric table" (a cold
    review), and the only way in was editing it.  A skipped column may now hold text; the
    table reads as the one with a number there.  A named column holding text is still an
    error ("no numeric rows").  Broken once (the first-row test without the skipped columns):
    "no numeric rows" for the ROS file; fails."""
    from imucald.fitting.inputs import read_table
    rows = [(1_000_000_000 + 10_000_000 * i, 0.01 * i, -0.02, 9.8) for i in range(300)]
    p, q = tmp_path / "ros.csv", tmp_path / "num.csv"
    p.write_text("%time,field.header.frame_id,ax,ay,az\n" + "".join(f"{t},imu_link,{x},{y},{z}\n" for t, x, y, z in rows))
    q.write_text("".join(f"{t},0,{x},{y},{z}\n" for t, x, y, z in rows))
    cols = ["t_ns", "-", "ax", "ay", "az"]
    a, b = read_table(str(p), cols, 9.80665), read_table(str(q), cols, 9.80665)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.acc, b.acc) and len(a.t) == 300
    msg = _one_line_error(read_table, str(p), ["t_ns", "ax", "ay", "az", "-"], 9.80665, cls=UserError)
    assert f"{p}: no numeric rows (expected 5 numbers per line: t_ns,ax,ay,az,-)" == msg, msg


@pytest.mark.parametrize("emulate", [False, True])
def test_record_without_a_bus_says_it_records_the_emulator(tmp_path, capsys, monkeypatch, emulate):
    """`record` without --emulate on a machine with no I2C bus records the emulated board (the
    daemon's `emulate: auto`); on a Pi whose I2C is off that wrote a simulated session, said
    only in the description of the first line, which calibrate then fitted (a newcomer's
    walk).  Now a warning says so and how to enable I2C; with --emulate, none.  Broken once
    (the warning removed): fails."""
    import imucald.drivers.bus as bus
    from imucald.cli import main
    monkeypatch.setattr(bus, "real_bus_numbers", lambda: [])
    rec = tmp_path / "r.csv"
    assert main(["record", "-o", str(rec), "--board", "mpu6050", "--seconds", "1"]
                + (["--emulate"] if emulate else [])) == 0
    err = capsys.readouterr().err
    warned = "imucald: warning: no I2C bus on this machine (/dev/i2c-* absent): recording the EMULATED board" in err
    assert warned != emulate, err
    assert len(read_recording(str(rec))) == 100


@pytest.mark.parametrize("header,cols", [
    ("t_s,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z,temp", "t,ax,ay,az,gx,gy,gz,temp"),      # sunsided's
    ("time_ms,AcX,AcY,AcZ,Tmp,GyX,GyY,GyZ", "t_ms,ax,ay,az,temp,gx,gy,gz"),               # an Arduino sketch's
    ('"Time (s)","Acceleration x (m/s^2)","Acceleration y (m/s^2)","Acceleration z (m/s^2)"', "t,ax,ay,az"),
    ("%time,field.header.frame_id,field.linear_acceleration.x,field.linear_acceleration.y,"
     "field.linear_acceleration.z", "t_ns,-,ax,ay,az"),                                  # ROS rostopic -p
    ("idx,magX,magY,magZ", "-,mx,my,mz"),
    ("Time (ms),AccX [g],AccY [g],AccZ [g]", "t_ms,ax,ay,az"),       # a unit in brackets (a review)
    ("timestamp [us];ax;ay;az", "t_us,ax,ay,az"),
    ("foo,bar", None), ("0.1,0.2,0.3", None), ("t,ax,ax,az", None)])
def test_a_headed_table_without_columns_is_told_the_columns_its_header_names(tmp_path, header, cols):
    """A logger's CSV with a header of names and no --columns was "not an imucald recording
    ...: e.g. --columns t,ax,ay,az" whatever its header said (a newcomer's walk).  Now the
    header's names, read as imucald's columns (aliases of loggers, phone apps and ROS), are
    offered as the --columns to give, with the units to check; a header that names no sensor,
    a row of numbers or a name twice keep the plain example.  Broken once (no guess): fails."""
    from imucald.fitting.inputs import load_input
    p = tmp_path / "log.csv"
    p.write_text(header + "\n0,0,0,1\n")
    msg = _one_line_error(load_input, str(p), cls=UserError)
    head = f"{p}: not an imucald recording or pose file; for a raw numeric table name its columns"
    if cols is None:
        assert msg == head + ", e.g. --columns t,ax,ay,az", msg
    else:
        rate = " and --rate-hz" if not cols.split(",")[0].startswith("t") else ""
        assert msg == head + f": its header reads as --columns {cols} (check each unit: --nominal-scale{rate})", msg


def test_what_a_review_found_in_the_new_table_paths_reads_as_before(tmp_path):
    """A cold review (helper-89) of the date-time, quoted and header-again paths: each of these
    read before them and must still read as the plain table does.  (1) A logger's metadata line
    that looks like a date-stamped row above the table ("2026-01-01T12:00:00,100,2,250") was
    refused as a date-time column; (2) an empty quoted text field in a skipped column (csv's
    QUOTE_NONNUMERIC) lost its field when the quotes were read as spaces; (3) a ';' table with
    a decimal comma and a terminal's time of day was not recognised, and its skip is one '-';
    (4) a status line above the header, written again mid-file, is no "header again".
    Broken once each (the date-time error raised at once; quotes taken with empty fields; the
    fields split at ',' first; every skipped line kept as a header): fails."""
    from imucald.fitting.inputs import read_table
    rows = [(0.01 * i, 0.01 * (i % 7), -0.02, 1.0 - 0.001 * (i % 3)) for i in range(300)]
    plain = tmp_path / "plain.csv"
    plain.write_text("".join(f"{t:.2f},{x:.3f},{y:.3f},{z:.3f}\n" for t, x, y, z in rows))
    ref = read_table(str(plain), ["t", "ax", "ay", "az"], 1.0)
    p = tmp_path / "meta.csv"
    p.write_text("2026-01-01T12:00:00,100,2,250\n" + plain.read_text())
    a = read_table(str(p), ["t", "ax", "ay", "az"], 1.0)
    assert np.array_equal(a.acc, ref.acc) and np.array_equal(a.t, ref.t)
    p = tmp_path / "emptyq.csv"
    p.write_text("".join(f'{t:.2f},"",{x:.3f},{y:.3f},{z:.3f}\n' for t, x, y, z in rows))
    a = read_table(str(p), ["t", "-", "ax", "ay", "az"], 1.0)
    assert np.array_equal(a.acc, ref.acc) and np.array_equal(a.t, ref.t)
    p = tmp_path / "tod.csv"
    p.write_text("t;ax;ay;az\n" + "".join(f"12:00:{t:06.3f};{x:.3f};{y:.3f};{z:.3f}\n".replace(".", ",")
                                         for t, x, y, z in rows))
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 1.0, cls=UserError)
    assert f"{p}:2: column 1 (t) reads '12:00:00,000', a date and time" in msg and "(--columns -,ax,ay,az)" in msg, msg
    a = read_table(str(p), ["-", "ax", "ay", "az"], 1.0, rate_hz=100.0)
    assert np.array_equal(a.acc, ref.acc)
    p = tmp_path / "status.csv"
    lines = plain.read_text().splitlines()
    p.write_text("\n".join(["NACK,NACK,NACK,NACK", "t,ax,ay,az"] + lines[:5] + ["NACK,NACK,NACK,NACK"] + lines[5:]) + "\n")
    msg = _one_line_error(read_table, str(p), ["t", "ax", "ay", "az"], 1.0, cls=UserError)
    assert msg == f"{p}:8: column t: 'NACK' is not a number", msg
