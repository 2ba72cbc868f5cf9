"""Every shell example in README.md and docs/ runs as written, so the examples cannot rot.

What counts as an example: a fenced block marked ```sh (or ```bash). Output shown to the
reader is fenced ```text and is not run. The blocks of one page run in order, in one temporary directory (a
later block may use the file an earlier one wrote), each under `bash -e`, with `imucald`
being this tree's command line.

A block preceded by `<!-- example: skip REASON -->` is not run; the reason is required
(e.g. system commands that need root and systemd: tests/test_install.py covers them).
Any other `<!-- example: ... -->` comment is a note to the reader. A block whose commands
are those of a block that already ran (the README repeats the quick start's probe, run,
status) and that reads no file is not run twice.

Where a block names hardware it runs on the emulated board (the transformations are
applied per command, and the file and line are named when one fails):
- `imucald probe` gets `--emulate 9dof`, `imucald record` gets `--emulate`;
- `imucald run` gets `--emulate`, a fast clock (`--speed 100`), a bounded `--duration`
  and this page's state and runtime directories, runs in the background, and the next
  command waits for its control socket; it is stopped at the end of the block (or at a
  `wait`);
- `imucald status`, `recalibrate`, `watch` get that runtime directory (`watch` also
  `-n 5`), `/run/imucald/` means it too, and a `sleep N` lasts at most 3 s;
- shorter, to keep the suite fast (the examples' results are not the point here, that
  they run is): `record --seconds` at most 120, `simulate --poses` at most 16 held at
  most 3 s each, `gap --sims` 20 (the least it takes), `run --speed` 100;
- `imucald recalibrate` first waits (up to 60 s) until the daemon holds the 10 poses it
  needs, as a user reads `status` before asking.
"""
import os
import re
import shlex
import subprocess
import sys
import time

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FENCE = re.compile(r"(?:<!--\s*example:(?P<note>[^>]*)-->\s*\n)?^```(?:sh|bash)[ \t]*\n(?P<body>.*?)^```",
                   re.M | re.S)


def pages():
    out = [os.path.join(ROOT, "README.md")]
    for d, dirs, files in os.walk(os.path.join(ROOT, "docs")):
        dirs[:] = sorted(dirs)
        out += [os.path.join(d, f) for f in sorted(files) if f.endswith(".md")]
    return out


def blocks(path):
    """(line number, note, body) of every sh block of a page."""
    text = open(path, encoding="utf-8").read()
    for m in FENCE.finditer(text):
        yield text.count("\n", 0, m.start("body")) + 1, (m.group("note") or "").strip(), m.group("body")


_SEP = re.compile(r"(\s*(?:&&|\|\||;|\||&(?!>))\s*)")


def _segment(seg: str, rt: str, st: str):
    """One simple command, transformed to run on the emulated board; returns (text,
    starts_daemon)."""
    words = seg.split()
    if not words:
        return seg, False
    if words[0] == "sleep" and len(words) == 2:
        return f"sleep {min(float(words[1]), 3.0):g}", False
    if words[0] == "wait" and len(words) == 1:
        return "__stop_daemons", False
    if words[0] != "imucald" or len(words) < 2:
        return seg, False
    cmd, has = words[1], lambda flag: any(w == flag or w.startswith(flag + "=") for w in words)
    add = []
    if cmd in ("record", "simulate", "gap"):
        seg = _cap(seg, {"record": ("--seconds", 120.0), "simulate": ("--hold", 3.0),
                         "gap": ("--sims", 20)}[cmd])
        if cmd == "simulate":
            seg = _cap(seg, ("--poses", 16))
            if not has("--hold"):
                add.append("--hold 3")
        if cmd == "gap" and not has("--sims"):
            add.append("--sims 20")
    if cmd == "probe" and not has("--emulate"):
        add.append("--emulate 9dof")
    if cmd == "record" and not has("--emulate"):
        add.append("--emulate")
    if cmd == "run":
        seg = re.sub(r"--speed\s+\S+", "--speed 100", seg)
        add += [a for f, a in (("--emulate", "--emulate"), ("--speed", "--speed 100"),
                               ("--duration", "--duration 100000"), ("--state-dir", f"--state-dir {st}"),
                               ("--runtime-dir", f"--runtime-dir {rt}")) if not has(f)]
    if cmd in ("status", "recalibrate", "watch", "mqtt") and not has("--runtime-dir"):
        add.append(f"--runtime-dir {rt}")
    if cmd == "watch" and not (has("-n") or has("--count")):
        add.append("-n 5")
    if cmd == "recalibrate":
        seg = f"__wait_poses 10 {shlex.quote(rt)}; " + seg.lstrip()
    # the options go before a comment or a redirection
    m = re.search(r"\s(#|>|2>|<)", seg)
    head, tail = (seg[:m.start()], seg[m.start():]) if m else (seg, "")
    return " ".join([head.rstrip()] + add) + tail, cmd == "run"


def _cap(seg: str, rule) -> str:
    flag, most = rule
    return re.sub(rf"({flag}[ =])(\S+)", lambda m: m.group(1) + (f"{min(float(m.group(2)), most):g}"
                  if re.fullmatch(r"[0-9.]+", m.group(2)) else m.group(2)), seg)


def _runtime_dir(seg: str, rt: str) -> str:
    m = re.search(r"--runtime-dir[ =](\S+)", seg)
    return m.group(1) if m else rt


def transform(body: str, rt: str, st: str) -> str:
    out = []
    for line in body.replace("\\\n", " ").splitlines():
        line = line.replace("/run/imucald/", rt + "/")
        code, _, comment = line.partition(" #") if not line.lstrip().startswith("#") else ("", "", line)
        parts = _SEP.split(code)
        text, daemon, wait_on = [], False, rt
        for i, p in enumerate(parts):
            if i % 2:                       # a separator
                text.append(" & " if daemon and p.strip() in ("&", ";", "&&") else p)
                if daemon:
                    text.append(f"__wait_socket {shlex.quote(wait_on)}; ")
                    daemon = False
                continue
            t, d = _segment(p, rt, st)
            text.append(t)
            if d:
                daemon, wait_on = True, _runtime_dir(t, rt)
        if daemon:                          # the daemon ended the line: in the background
            text.append(f" & __wait_socket {shlex.quote(wait_on)}")
        out.append("".join(text))
    return "\n".join(out) + "\n"


PRELUDE = r"""
set -e
__pids=""
__wait_socket() {  # the daemon just started in the background: wait for its control socket
  __pids="$__pids $!"
  for i in $(seq 1 600); do [ -S "$1/control.sock" ] && return 0; kill -0 $! 2>/dev/null || break; sleep 0.1; done
  echo "the daemon did not bind $1/control.sock" >&2; return 1
}
__wait_poses() {  # until the daemon at runtime dir $2 holds $1 poses (a deadline in time, not in
  # polls: under load each status call takes longer and the emulated board runs slower)
  local end=$((SECONDS + 200))
  while [ $SECONDS -lt $end ]; do
    n=$(imucald status --json --runtime-dir "$2" | "$__PY" -c 'import json,sys; print(json.load(sys.stdin).get("poses", 0))')
    [ "$n" -ge "$1" ] && return 0; sleep 0.5   # each poll starts two Pythons: ~0.2 s of CPU
  done; echo "the daemon has only $n poses" >&2; return 1
}
__stop_daemons() { for p in $__pids; do kill $p 2>/dev/null || true; done; for p in $__pids; do wait $p 2>/dev/null || true; done; __pids=""; }
trap __stop_daemons EXIT
"""


def _shim(bindir):
    os.makedirs(bindir, exist_ok=True)
    p = os.path.join(bindir, "imucald")
    with open(p, "w") as f:
        f.write(f"#!/bin/sh\nexec {shlex.quote(sys.executable)} -m imucald.cli \"$@\"\n")
    os.chmod(p, 0o755)


def _cases():
    for path in pages():
        bl = list(blocks(path))
        if bl:
            yield pytest.param(path, bl, id=os.path.relpath(path, ROOT))


def test_the_runner_finds_the_examples_and_every_skip_has_a_reason():
    """Fails if the fence pattern stops matching (a runner that runs nothing passes
    nothing), or a skip marker carries no reason."""
    n = skipped = 0
    for path in pages():
        for line, note, body in blocks(path):
            n += 1
            if note.startswith("skip"):
                skipped += 1
                assert len(note) > len("skip") + 10, f"{os.path.relpath(path, ROOT)}:{line}: skip without a reason"
    assert n >= 20 and skipped < n / 2, (n, skipped)


def test_transform_puts_hardware_commands_on_the_emulated_board():
    """The transformations themselves: dropping one (e.g. --emulate for probe) fails here."""
    t = transform("imucald probe   # what answers\nimucald run\nimucald status\nimucald watch -n 2 > s.txt\n"
                  "sleep 20; imucald record -o s.csv --board 9dof\nwait\n", "/R", "/S")
    lines = t.splitlines()
    assert lines[0].startswith("imucald probe --emulate 9dof")
    assert "--emulate" in lines[1] and "--runtime-dir /R" in lines[1] and lines[1].endswith("__wait_socket /R")
    assert lines[2] == "imucald status --runtime-dir /R"
    assert lines[3] == "imucald watch -n 2 --runtime-dir /R > s.txt"
    assert lines[4] == "sleep 3; imucald record -o s.csv --board 9dof --emulate"
    t = transform("imucald run --emulate --speed 20 --runtime-dir run &\nimucald gap s.csv --sims 200\n"
                  "imucald record -o r.csv --seconds 300 --emulate\n", "/R", "/S").splitlines()
    assert "--speed 100 " in t[0] and "--runtime-dir run " in t[0] and "/R" not in t[0], t[0]
    assert t[0].endswith(" & __wait_socket run; "), t[0]
    assert t[1] == "imucald gap s.csv --sims 20" and t[2] == "imucald record -o r.csv --seconds 120 --emulate"
    assert lines[5] == "__stop_daemons"


_RAN = set()     # commands already run by an earlier page (the README repeats the quick start)


def _key(body: str) -> str:
    """The commands of a block, comments and spacing aside."""
    return "\n".join(" ".join(l.split(" #")[0].split()) for l in body.splitlines() if l.strip())


@pytest.mark.parametrize("path,bl", list(_cases()))
def test_shell_examples_run(path, bl, tmp_path):
    bindir = tmp_path / "bin"
    _shim(str(bindir))
    work = tmp_path / "work"
    work.mkdir()
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ['PATH']}", __PY=sys.executable,
               PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""), HOME=str(tmp_path))
    rel = os.path.relpath(path, ROOT)
    ran = 0
    for line, note, body in bl:
        if note.startswith("skip"):
            continue
        if _key(body) in _RAN and ".csv" not in body and ".yaml" not in body:
            ran += 1                # the same commands, reading no file, already ran as written
            continue
        rt, st = str(tmp_path / f"run{line}"), str(tmp_path / f"state{line}")
        script = PRELUDE + transform(body, rt, st)
        t0 = time.time()
        p = subprocess.run(["bash", "-c", script], cwd=work, env=env, capture_output=True, text=True,
                           timeout=300)
        assert p.returncode == 0, (f"{rel}:{line}: the example failed (exit {p.returncode}) after "
                                   f"{time.time() - t0:.1f} s\n{script}\n--- stderr:\n{p.stderr[-3000:]}"
                                   f"\n--- stdout:\n{p.stdout[-1500:]}")
        ran += 1
        _RAN.add(_key(body))
    if not ran:
        pytest.skip(f"{rel}: every example is marked skip (with its reason)")
