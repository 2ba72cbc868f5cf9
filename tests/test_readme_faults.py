"""The troubleshooting fault table (docs/troubleshooting.md, once the README's) stays true: every row names the test that
reproduces it, that test exists, and every exit code it states is a documented one."""
import os
import re

from imucald import errors

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _rows():
    sec = open(os.path.join(ROOT, "docs", "troubleshooting.md"), encoding="utf-8").read()
    head = sec.index("| fault | what imucald does | exit | test |")
    rows = []
    for line in sec[head:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split(" | ")])
    return rows


def test_every_fault_row_names_an_existing_test_and_a_documented_exit():
    rows = _rows()
    assert len(rows) >= 20
    codes = {str(getattr(errors, n)) for n in dir(errors) if n.startswith("EX_")} | {"0"}
    for fault, does, code, tests in rows:
        refs = re.findall(r"`(test_\w+\.py)::(test_\w+)`", tests)
        assert refs, f"no test named for: {fault}"
        for f, name in refs:
            src = open(os.path.join(ROOT, "tests", f), encoding="utf-8").read()
            assert re.search(rf"^def {name}\(", src, re.M), f"{f}::{name} (row: {fault})"
        for c in re.findall(r"\d+", code):
            assert c in codes, f"exit {c} is not documented in imucald/errors.py (row: {fault})"


def test_the_exit_code_table_and_the_code_agree_on_a_full_disk():
    """The exit-code table's row that names a full disk / read-only file system is the code
    a failed output write exits with (errors.write_failure; test_reliability runs the
    commands).  Seen failing when simulate -o mapped every OSError to 73 (the table says 74)."""
    import errno
    docs = [os.path.join(ROOT, "README.md")]
    docs += [os.path.join(d, f) for d, _, fs in os.walk(os.path.join(ROOT, "docs")) for f in fs
             if f.endswith(".md")]
    rows = [m for p in docs if os.path.exists(p)
            for m in re.findall(r"^\| (\d+) \|[^\n]*disk full[^\n]*$", open(p, encoding="utf-8").read(), re.M)]
    assert rows, "no exit-code row names a full disk"
    for no in (errno.ENOSPC, errno.EROFS, errno.EIO):
        e = errors.write_failure(OSError(no, os.strerror(no)), "-o", "x.csv")
        assert {str(e.exit_code)} == set(rows), (no, e.exit_code, rows)
    e = errors.write_failure(OSError(errno.EACCES, os.strerror(errno.EACCES)), "-o", "x.csv")
    assert e.exit_code == errors.EX_CANTCREAT
