"""The fixed-width reader (files/tables.py ``_parse_fixed``: numbers read by numpy arithmetic on
the columns of bytes of tables whose lines all have one layout, e.g. MATLAB's ``save -ascii``
and the IMU-TK Xsens files) gives exactly the bits of numpy's tokenizer, the path it
shortcuts, and of the reference parser, on every table it takes; and it refuses (None: the
tokenizer reads the block) every block that is not one layout.

Breakage each test was checked against (restored after): the exponent's sign ignored
(``MX[:, ncol:] * es`` with ``es`` replaced by 1) fails ``test_the_xsens_layout_is_read_by_the_fixed_path_to_the_same_bits``
(its times and scaled values have negative exponents); a '-' in a sign slot not applied
(``np.multiply(M, sg, out=out)`` with ``sg`` replaced by 1) fails it and
``test_fixed_width_tables_read_to_the_same_bits`` (any negative value); the sign slot allowed after a single separating
space in whitespace tables (``or row[s - 2] in sep`` dropped) fails
``test_layouts_it_must_refuse`` ("1.5 2.5" then "1.5-2.5", one token to the tokenizer);
the einsum path's weights reversed (``w[::-1]``) fails the property test and the Xsens
layout's ``[False]`` case (the matrix product's path, ``[True]``, still passes).
"""
import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

from imucald.errors import UserError  # noqa: E402
from imucald.files.tables import TableSpec, _parse_fast, _parse_fixed, _parse_slow  # noqa: E402
from imucald.numerics import blas  # noqa: E402

FMTS = ["%15.7e", "%16.7e", "%+.3e", "%12.6f", "%10.3f", "%.4f", "%8.0f", "%14.6E", "%7.2f",
        "%.15e", "%.14e", "%22.15f", "%5.1f"]
# most values of one magnitude band with either sign (what makes a fixed-width table: the
# layout the path reads); some from 1e-30 to 1e30, where exponents beyond 22 and the longer
# lines must be refused to the tokenizer, not misread
_BAND = st.builds(lambda m, neg: -m if neg else m, st.floats(1000, 9990), st.booleans())
VALUES = st.one_of(_BAND, st.sampled_from([0.0, -0.0, 1e-30, -1e30, 5e22, 1e-23, 0.1, 2.5e-3]),
                   st.floats(-1e30, 1e30, allow_nan=False, allow_infinity=False))
TAKEN = []     # tables the fixed path read itself, in the property test
SEPS = [" ", "  ", "\t", " \t", ",", ", ", " , "]

SETTINGS = settings(max_examples=400, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


def _spec(ncol, comma_only):
    return TableSpec("x.csv", [f"c{i}" for i in range(ncol)], comma_only=comma_only, skip="#%")


def _reference(body: bytes, spec):
    try:
        return _parse_slow(body.decode("ascii"), spec, 1, -np.inf)
    except UserError:
        return None


def _same_bits(a, b):
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


@SETTINGS
@given(fmt=st.lists(st.sampled_from(FMTS), min_size=1, max_size=5),
       rows=st.integers(1, 12), sep=st.sampled_from(SEPS), lead=st.sampled_from(["", " ", "  "]),
       crlf=st.booleans(), data=st.data())
def test_fixed_width_tables_read_to_the_same_bits(fmt, rows, sep, lead, crlf, data):
    ncol = len(fmt)
    cell = data.draw(st.sampled_from([_BAND, _BAND, _BAND, VALUES]))     # 3/4 of tables: one band
    vals = data.draw(st.lists(st.lists(cell, min_size=ncol, max_size=ncol), min_size=rows, max_size=rows))
    eol = "\r\n" if crlf else "\n"
    body = "".join(lead + sep.join(f % v for f, v in zip(fmt, r)) + eol for r in vals).encode()
    comma = "," in sep
    for comma_only in ([True, False] if comma else [False]):
        spec = _spec(ncol, comma_only)
        ref = _reference(body, spec)
        got = _parse_fast(body, spec, -np.inf)          # fixed-width path where it applies
        tok = _parse_fast(body.decode(), spec, -np.inf)  # numpy's tokenizer (a str never takes it)
        if ref is None:
            assert got is None
            continue
        assert got is not None and _same_bits(got, ref)
        assert tok is not None and _same_bits(tok, ref)
    lines = body.replace(b"\r\n", b"\n")
    one = blas.ONE_THREAD
    try:
        for blas.ONE_THREAD in (True, False):   # digits summed by a matrix product, by einsum
            fixed = _parse_fixed(lines, _spec(ncol, comma), rows, comma)
            if fixed is not None:       # when it reads the block itself: the same bits
                TAKEN.append(blas.ONE_THREAD)
                assert _same_bits(fixed, _reference(lines, _spec(ncol, comma)))
    finally:
        blas.ONE_THREAD = one


def test_the_property_test_exercised_the_fixed_path():
    """Runs after the property test (file order): the fixed path read a good share of its
    tables itself (else that test compared the tokenizer with itself)."""
    assert TAKEN.count(True) >= 100 and TAKEN.count(False) >= 100, len(TAKEN)


@pytest.mark.parametrize("one_thread", [True, False])
def test_the_xsens_layout_is_read_by_the_fixed_path_to_the_same_bits(one_thread, monkeypatch):
    """The IMU-TK layout (MATLAB ``save -ascii``: ``%16.7e``), exponents of both signs,
    and its signed form (a '-' in the sign slot): read by the fixed-width path, not handed
    to the tokenizer, and equal to it bit for bit, the digits summed by a matrix product
    (the BLAS at one thread: the CLI) or by einsum (numerics/blas.py)."""
    monkeypatch.setattr(blas, "ONE_THREAD", one_thread)
    rng = np.random.default_rng(5)
    x = np.column_stack([np.arange(1, 400) * 0.0099873, rng.integers(0, 65536, (399, 3)).astype(float)])
    for v in (x, x - 32768.0, x * 1e-9):
        body = "".join("".join("%16.7e" % a for a in r) + "\n" for r in v).encode()
        spec = _spec(4, False)
        fixed = _parse_fixed(body, spec, len(v), False)
        assert fixed is not None
        assert _same_bits(fixed, np.loadtxt(body.decode().splitlines(), ndmin=2))


@pytest.mark.parametrize("body", [
    b"1.5 2.5\n1.5-2.5\n",              # the '-' would join two tokens
    b" 1.5 2.5\n 1.5 x.5\n",           # not a digit
    b"1.5 2.5\n1.5 2.5 \n",             # lines of two lengths
    b"nan 2.5\nnan 2.5\n",
    b"1e99 2.5\n1e99 2.5\n",            # exponent beyond 22
    b"1234567890123456 1\n1234567890123456 1\n",     # 16 digits
    b"1.5\v2.5\n1.5\v2.5\n",            # a separator numpy takes and the layout does not
    b"#1.5 2\n#1.5 2\n",
    b"1.5 2.5\n1.5 2.5\n1.5 2.5",       # no newline at the end
])
def test_layouts_it_must_refuse(body):
    """Blocks the fixed path must leave to the tokenizer (None), whatever they hold."""
    n = body.count(b"\n") + (0 if body.endswith(b"\n") else 1)
    assert _parse_fixed(body, _spec(2, False), n, False) is None


@pytest.mark.parametrize("chunk", [64, 700, 1 << 20])
def test_blocks_read_in_place_keep_the_line_numbers(chunk, tmp_path):
    """A fixed-width file read block by block (iter_blocks: whole blocks of one layout are
    read in place, without the copy and the line count of the general path): the rows are
    the reference parser's, and an error after them names its true line (breakage checked:
    ``lineno += len(rows) - 1`` in iter_blocks names a line before 301 here, failing this
    test at the chunk sizes that split the file, 64 and 700 bytes; at 1 MB the bad line is in
    the one block, which the general path reads)."""
    import io
    from imucald.files.tables import iter_blocks
    rng = np.random.default_rng(2)
    v = np.column_stack([np.arange(300) * 0.01, rng.uniform(-2, 2, (300, 3))])
    good = "".join("".join("%16.7e" % a for a in r) + "\n" for r in v).encode()
    spec = _spec(4, False)
    rows = np.concatenate(list(iter_blocks(io.BytesIO(good), spec, 1, 0, chunk_bytes=chunk)))
    assert _same_bits(rows, _reference(good, spec))
    with pytest.raises(UserError, match=r"^x.csv:301: "):
        list(iter_blocks(io.BytesIO(good + b"   1.0 oops\n"), spec, 1, 0, chunk_bytes=chunk))


def test_a_long_line_after_a_fixed_width_block_is_refused_before_its_rows(tmp_path):
    """A streaming reader (RecordingReader.chunks: replay's loop) gets no row of a block
    before the line longer than MAX_LINE_BYTES after it is refused, as before the in-place
    fixed-width path.  Seen to fail with the check after the block's yield (3000 rows first)."""
    from imucald.errors import UserError
    from imucald.files.recording import open_recording
    p = tmp_path / "long.csv"
    with open(p, "w") as f:
        f.write("# imucald recording v1\n# board: unknown\n# rate_hz: 100\nt,ax,ay,az\n")
        for i in range(3000):
            f.write("%.2f,%+.4f,%+.4f,%+.4f\n" % (10 + i * 0.01, 0.1, -0.2, 0.98))
        f.write("1" * 300000 + "\n")
    seen = 0
    with pytest.raises(UserError, match=r"long\.csv:3005: line longer than"):
        for r in open_recording(str(p)).chunks(200000):
            seen += len(r.t)
    assert seen == 0
