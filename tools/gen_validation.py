"""Regenerate the validation pages: each is written by the bench script that measures it
(`--markdown FILE`), with the commit and the machine in its first lines, so no figure in
the documentation is copied by hand.  Minutes, not seconds: run it by hand on a quiet
machine and commit the pages (CI runs tools/gen_docs.py, which is fast, not this).

    python tools/gen_validation.py [NAME ...]    # default: all of PAGES
"""
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: page (docs/validation/NAME.md) -> the bench script and its arguments
PAGES = {
    "record-speed": ["bench/record_speed.py", "--repeats", "5"],
    "optimiser-speed": ["bench/speed.py", "--repeats", "7"],
    "real-magcal": ["bench/real_magcal.py", "--repeats", "5"],
}


def main(names):
    for name in names or PAGES:
        out = os.path.join(ROOT, "docs", "validation", f"{name}.md")
        cmd = [sys.executable] + PAGES[name] + ["--markdown", out]
        print("+ " + " ".join(cmd[1:]), flush=True)
        subprocess.run(cmd, cwd=ROOT, check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
