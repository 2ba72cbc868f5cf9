"""Property-based fuzzing of the recording reader and the raw-table reader (hypothesis).

Each reader, given any bytes, returns a valid result or raises the project's UserError
with a one-line message naming the file; never another exception.  The bulk (numpy)
path must agree exactly with the line-by-line reference parser on every text.
"""
import os
import tempfile

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

from imucald.fitting.inputs import read_table  # noqa: E402
from imucald.errors import UserError  # noqa: E402
from imucald.files.recording import MAGIC, read_recording  # noqa: E402
from imucald.files.tables import TableSpec, _parse_fast, _parse_slow  # noqa: E402

N = 2000
FUZZ = settings(max_examples=N, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])

# Drawn from fixed token lists (one draw per token keeps 2,000 cases within seconds): numbers
# valid and not, separators right and wrong, and the bytes that trip parsers.
_NUMS = ["0", "1", "-1", "0.5", "2.5e-3", "-0.0", "7", "1e3", "32768", "65535", "1e308", "-1e308",
         "1e999", "nan", "inf", "-inf", "NaN", "Infinity", "1_0", "+.5", "1.", ".", "e5", "0x10", "1e",
         "--1", "\u0661", "", " ", "0.30000000000000004", "4.9e-324", "123456789012345678901"]
_ODD = ["", "#x", "% c", "  ", "\r", "\u00e9", "\x00", "\x0c"]
_row = st.tuples(st.lists(st.sampled_from(_NUMS), max_size=6),
                 st.sampled_from([",", ",", ", ", " ,", " ", "\t", "  ", ";"]))
line = st.one_of(_row.map(lambda v: v[1].join(v[0])), st.sampled_from(_ODD))
eol = st.sampled_from(["\n", "\n", "\n", "\r\n", "\r"])
text = st.lists(st.tuples(line, eol), max_size=8).map(lambda ls: "".join(a + b for a, b in ls))
junk = st.binary(max_size=300)

_DIR = None     # set by _scratch: a RAM file system where there is one (thousands of small files)


@pytest.fixture(scope="module", autouse=True)
def _scratch():
    import shutil
    global _DIR
    _DIR = tempfile.mkdtemp(prefix="imucald-fuzz-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
    yield
    shutil.rmtree(_DIR, ignore_errors=True)


def _file(data: bytes) -> str:
    p = os.path.join(_DIR, "f.csv")
    with open(p, "wb") as fh:
        fh.write(data)
    return p


def _expect_result_or_user_error(fn, path):
    try:
        return fn()
    except UserError as e:
        msg = str(e)
        assert msg and "\n" not in msg and path in msg, msg
        return None


@pytest.mark.parametrize("comma_only", [True, False])
@FUZZ
@given(body=text, prev=st.sampled_from([-np.inf, 0.0, 5.0]))
def test_bulk_parser_agrees_with_reference(comma_only, body, prev):
    spec = TableSpec("x.csv", ["t", "ax", "ay", "az"], comma_only=comma_only,
                     skip="#" if comma_only else "#%", halfwidth=[np.inf, 1e6, 1e6, 1e6], tcol=0)
    fast = _parse_fast(body, spec, prev)
    try:
        ref = _parse_slow(body, spec, 1, prev)
    except UserError as e:
        assert fast is None, f"bulk accepted what the reference rejects: {e}"
        assert "\n" not in str(e) and str(e).startswith("x.csv:")
        return
    if fast is not None:
        assert fast.shape == ref.shape and np.array_equal(fast, ref)
    assert np.isfinite(ref).all() and (np.diff(ref[:, 0]) >= 0).all() and (ref[:, 0] >= prev).all()


@FUZZ
@given(body=st.one_of(text.map(str.encode), junk),
       rate=st.sampled_from(["100", "nan", "0", "-1", "inf", "1e3", "x", ""]),
       cols=st.sampled_from(["t,ax,ay,az", "t,ax,ay,az,gx,gy,gz,temp", "t,ax,ay", "ax,t,ay,az", "t,t",
                             "t,mx,my,mz", ""]))
def test_recording_reader_fuzz(body, rate, cols):
    data = f"{MAGIC}\n# board: x\n# rate_hz: {rate}\n{cols}\n".encode() + body
    path = _file(data)
    rec = _expect_result_or_user_error(lambda: read_recording(path), path)
    if rec is not None:
        assert len(rec) > 0 and float(rec.meta["rate_hz"]) > 0
        assert np.isfinite(rec.t).all() and (np.diff(rec.t) >= 0).all()
        for a in (rec.acc, rec.gyro, rec.mag, rec.temp):
            assert a is None or (len(a) == len(rec) and np.isfinite(a).all())


@FUZZ
@given(data=st.one_of(junk, st.binary(max_size=40).map(lambda b: MAGIC.encode() + b)))
def test_recording_reader_any_bytes(data):
    path = _file(data)
    _expect_result_or_user_error(lambda: read_recording(path), path)


@FUZZ
@given(body=st.one_of(text.map(str.encode), junk),
       cols=st.sampled_from([["t", "ax", "ay", "az"], ["ax", "ay", "az"], ["t", "-", "ax", "ay", "az"],
                             ["t", "gx", "gy", "gz", "temp"]]),
       scale=st.sampled_from([1.0, 16384.0, -2.0]), rate=st.sampled_from([None, 100.0]))
def test_table_reader_fuzz(body, cols, scale, rate):
    path = _file(body)
    rec = _expect_result_or_user_error(lambda: read_table(path, cols, scale, 32768.0, rate), path)
    if rec is not None:
        assert len(rec) > 0 and np.isfinite(rec.t).all() and float(rec.meta["rate_hz"]) > 0
        for a in (rec.acc, rec.gyro, rec.temp):
            assert a is None or (len(a) == len(rec) and np.isfinite(a).all()
                                 and (np.abs(a) <= 1e6 * (1 + 1e-12)).all())


# --- trailing garbage (issue 21): a cut last line, NUL tails, binary junk ----------------------

_GOOD_ROWS = b"".join(f"{i * 0.01:.2f},0.01,-0.02,1.0\n".encode() for i in range(30))
_TAILS = [b"", b"0.30,0.01", b"0.30,0.0", b"0.3", b"\x00" * 5000, b"0.30,0.01\x00\x00\x00",
          b"\x00\x00junk", b"\xff\xfe", b"\n\n", b"# c", b"0.30,1e999", b"1" * 70000]


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(tail=st.lists(st.one_of(st.sampled_from(_TAILS), st.binary(max_size=40)), max_size=3).map(b"".join),
       chunk=st.sampled_from([64, 1 << 20]))
def test_trailing_garbage_is_dropped_with_a_warning_or_a_one_line_error(tail, chunk, capsys):
    """After 30 good rows, any tail: the 30 rows (+ whole valid rows of the tail) or the
    one-line error; a tail that is NUL bytes only, or one cut row (no newline, not a valid
    row), keeps exactly the 30 rows with exactly one warning line naming the file."""
    from imucald.files.recording import RecordingReader
    path = _file(f"{MAGIC}\n# board: x\n# rate_hz: 100\nt,ax,ay,az\n".encode() + _GOOD_ROWS + tail)

    def read():
        with RecordingReader(path) as r:
            return r.read(chunk_bytes=chunk)
    rec = _expect_result_or_user_error(read, path)
    err = capsys.readouterr().err
    warns = [ln for ln in err.splitlines() if ln.startswith("imucald: warning:")]
    assert all(path in w and "\n" not in w for w in warns) and len(warns) <= 1
    if rec is not None:
        assert len(rec) >= 30 and np.array_equal(rec.t[:30], np.round(np.arange(30) * 0.01, 2))
    nul_only = tail and not tail.strip(b"\x00")
    cut = tail in (b"0.30,0.01", b"0.30,0.0", b"0.3")
    if nul_only or cut:
        assert rec is not None and len(rec) == 30 and len(warns) == 1, (tail[:20], err)
