"""The README's troubleshooting fault table stays true: every row names the test that
reproduces it, that test exists, and every exit code it states is a documented one."""
import os
import re

from imucald import errors

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _rows():
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    sec = text[text.index("## Troubleshooting"):]
    sec = sec[:sec.index("\n## ", 5)]
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
