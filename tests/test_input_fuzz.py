"""Property-based fuzzing (hypothesis) of the other inputs a user or a client hands imucald:
the configuration file, the calibration file, pose files and control-socket requests.

Each input, whatever it holds, gives a valid result or the project's one-line UserError
naming the file (config: ConfigError, exit 78; calibration: CalibrationError; pose file:
UserError, exit 2); never another exception.  A control request always gets one JSON reply
line (strict JSON) of a known class; an error reply is one line.  2,000 cases per input,
drawn from token lists (cheap), derandomized so CI is reproducible.
"""
import json
import math
import os
import socket
import stat
import tempfile

import numpy as np
import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

from imucald.fitting.stillness.poses import POSES_MAGIC, read_poses  # noqa: E402
from imucald.calibration import Calibration, CalibrationError, SensorCal, load  # noqa: E402
from imucald.daemon import control as ctl  # noqa: E402
from imucald.daemon.config import SCHEMA, ConfigError, parse_yaml, validate  # noqa: E402
from imucald.errors import UserError  # noqa: E402
from imucald.files.recording import read_recording  # noqa: E402

from ._helpers import or_none, wait_until  # noqa: E402

N = 2000
FUZZ = settings(max_examples=N, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])

_DIR = None


@pytest.fixture(scope="module", autouse=True)
def _scratch():
    import shutil
    global _DIR
    _DIR = tempfile.mkdtemp(prefix="imucald-fuzz-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
    yield
    shutil.rmtree(_DIR, ignore_errors=True)


def _file(name: str, data: bytes) -> str:
    p = os.path.join(_DIR, name)
    with open(p, "wb") as fh:
        fh.write(data)
    return p


def _one_line(e: Exception, path: str = "") -> None:
    msg = str(e)
    assert msg and "\n" not in msg and "Traceback" not in msg, msg
    assert not path or msg.startswith(path), msg


# --- the configuration file -------------------------------------------------------------------

_KEYS = sorted(SCHEMA) + ["sensor.nope", "bogus.key", "sensor.emulate.x"]
_SCALARS = ["yes", "no", "true", "false", "0660", '"0660"', "'0o660'", "0o660", "0x68", "104", "0",
            "-1", "1e3", "1.5", ".nan", ".inf", "-.inf", "~", "null", "''", "100", "1000", "1001",
            "mpu6050", "9dof", "ga", "ndjson", "info", "[1, 2]", "{a: 1}", "!!python/object:os.system",
            "&a 1", "*a", "*b", "\"\\xff\"", "'unterminated", "\u00b0C", "x" * 200, "2.5e-3", "25", "5",
            "4", "0.001", "60", "10"]
_SEPS = [": ", ":", ":  ", " : "]


def _default_text(key):
    """The key's default as it would be written in the file (quoted where it is text)."""
    d = SCHEMA[key][0]
    if d is None:
        return "~"
    if isinstance(d, bool):
        return "true" if d else "false"
    return f'"{d}"' if isinstance(d, str) else str(d)


def _config_text(b: bytes) -> str:
    """A configuration from a byte string, one byte per choice (one hypothesis draw per file):
    known keys grouped in their sections, each value its default, an allowed-looking scalar or
    a hostile one; sometimes a hostile line."""
    it = iter(b)

    def pick(seq):
        return seq[next(it, 0) % len(seq)]
    sections = {}
    for _ in range(pick(range(7))):
        key = pick(_KEYS)
        sec, name = key.split(".", 1)
        v = next(it, 0)
        value = _default_text(key) if v < 96 and key in SCHEMA else pick(_SCALARS)
        sections.setdefault(sec, []).append(f"{pick(['  ', '  ', '    ', chr(9)])}{name}{pick(_SEPS)}{value}"
                                            f"{pick(['', '', '  # c', ' #' + chr(176)])}")
    lines = []
    for sec, body in sections.items():
        lines += [f"{sec}:"] + body
    if next(it, 0) >= 160:
        lines.insert(pick(range(len(lines) + 1)),
                     pick(["---", "...", "- a", "[", "}", "%YAML 1.1", "? [a]\n: 1", "sensor: [a, b]", "sensor: 3",
                           "&x sensor: {}", "<<: *x", "log: {level: debug}", "sensor:\n  board: 9dof\n  rate_hz: 150"]))
    return "\n".join(lines) + pick(["\n", "", "\r\n"])


@FUZZ
@given(text=st.binary(min_size=1, max_size=60).map(_config_text), tail=st.sampled_from([b"", b"\xb0", b"\x00", b"\xef\xbb\xbf", b"\t: x"]))
def test_config_loader_fuzz(text, tail):
    raw = text.encode() + tail
    try:
        data, lines, plain = parse_yaml(raw, "c.yaml")
        cfg = validate(data, "c.yaml", lines, plain)
    except ConfigError as e:
        _one_line(e, "c.yaml")
        assert e.exit_code == 78
        return
    for key, (_, kind, allowed) in SCHEMA.items():
        sec, k = key.split(".")
        v = cfg[sec][k]
        if kind in ("int", "float"):
            assert not isinstance(v, bool) and allowed[0] <= v <= allowed[1], (key, v)
        elif kind == "choice":
            assert v in allowed, (key, v)
        elif kind == "mode":
            assert isinstance(v, str) and len(v) == 4 and int(v, 8) <= 0o777


@FUZZ
@given(data=st.binary(max_size=200))
def test_config_loader_any_bytes(data):
    try:
        validate(*parse_yaml(data, "c.yaml")[:1], "c.yaml")
    except ConfigError as e:
        _one_line(e, "c.yaml")


# --- the calibration file ---------------------------------------------------------------------

def _good_doc():
    from imucald.fitting.models.registry import get_model
    acc = SensorCal.accel("triangular9", get_model("triangular9").nominal, np.full(9, 1e-4),
                          method="ga", quality={"poses": 25, "rms_g": 0.001})
    acc = SensorCal(acc.sensor, acc.model, acc.params, acc.stderr, acc.flags, acc.method, acc.quality, {
        "order": 1, "t_min_c": 20.0, "t_ref_c": 25.0, "t_max_c": 35.0,
        "bias_poly_g": np.array([[6e-4, -8e-4, 5e-4]]), "bias_poly_stderr_g": np.array([[1e-5, 1e-5, 1e-5]]),
        "scale_poly": np.array([[1e-4, -2e-4, 0]]), "note": ""})
    gyro = SensorCal("gyro", "bias", {"bias_dps": np.array([0.1, -0.2, 0.3]), "matrix": np.eye(3).ravel(),
                                      "bias_temp_poly_dps": np.zeros((2, 3)), "temp_ref_c": np.array(25.0)},
                     {"bias_dps": np.full(3, 0.01)}, method="mean")
    mag = SensorCal("mag", "mag_sym", {"hard_iron_gauss": np.array([0.1, 0.0, -0.1]),
                                       "soft_iron": np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0]),
                                       "field_gauss": np.array(0.5)},
                    thermal={"order": 1, "t_min_c": 21.5, "t_ref_c": 25.0, "t_max_c": 30.25,
                             "bias_poly_gauss": np.array([[5e-4, 0, -1e-4]]), "note": ""})
    cal = Calibration("9dof", {"accel": "adxl345"}, 4, "2026-01-01T00:00:00Z", (20.0, 30.0), acc, gyro, mag,
                      {"columns": ["ax", "ay", "az"], "rows": [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]},
                      {"poses": 12, "poses_for_final": 25, "missing_orientations": ["-Z up"]}, "abc123")
    return cal.to_dict()


GOOD = _good_doc()


def _paths(d, pre=()):
    out = [pre] if pre else []
    if isinstance(d, dict):
        for k, v in d.items():
            out += _paths(v, pre + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            out += _paths(v, pre + (i,))
    return out


_PATHS = _paths(GOOD)
_DELETE = object()
_VALUES = [None, "abc", "", math.nan, math.inf, -math.inf, -1, 0, 1, 2, 1.5, 1e308, -1e308, True, False,
           [], {}, [1.0, 2.0], [1.0, 2.0, 3.0], [[1.0, 2.0, 3.0]], [None, 1.0, 2.0], ["a", "b", "c"],
           {"x": 1}, "mpu6050", "triangular9", "bias", "mag_sym", "full12", "determined", 10 ** 30,
           ["determined"] * 3, [[]], [[1.0, math.nan, 3.0]], "2026", 1, 3, _DELETE, "unknown_key"]


def _mutate(doc, path, value):
    if not path:
        return value if value is not _DELETE else None
    d = doc
    for k in path[:-1]:
        d = d[k]
    if value == "unknown_key" and isinstance(d[path[-1]], dict):
        d[path[-1]]["zz_unknown"] = 1
    elif value is _DELETE:
        if isinstance(d, dict):
            del d[path[-1]]
        else:
            d.pop(path[-1])
    else:
        d[path[-1]] = value
    return doc


@FUZZ
@given(muts=st.lists(st.tuples(st.sampled_from(_PATHS), st.sampled_from(_VALUES)), min_size=1, max_size=3),
       v1=st.booleans())
def test_calibration_from_dict_fuzz(muts, v1):
    doc = json.loads(json.dumps(GOOD))
    if v1:
        doc["format_version"] = 1
    for path, value in muts:
        try:
            doc = _mutate(doc, path, value)
        except (KeyError, IndexError, TypeError):
            pass                     # an earlier mutation removed or replaced the parent
    try:
        cal = Calibration.from_dict(doc)
    except CalibrationError as e:
        _one_line(e)
        return
    for s in ("accel", "gyro", "mag"):       # what loads corrects finitely
        p = cal.part(s)
        if p is not None:
            out = p.apply(np.array([[0.1, -0.9, 0.2], [0.0, 0.5, 0.9]]), np.array([30.0, 80.0]))
            assert np.isfinite(out).all(), (s, p.params)
    assert Calibration.from_dict(cal.to_dict()).to_dict() == cal.to_dict()


# the byte edits damage the YAML itself (the content is fuzzed through from_dict above): a
# small document keeps 2,000 pure-Python YAML parses within seconds
_SMALL = {k: GOOD[k] for k in ("format_version", "id", "board", "units", "gyro")}
_GOOD_TEXT = yaml.safe_dump(_SMALL, sort_keys=False, default_flow_style=None, width=100)
_EDITS = [b"", b"\xb0", b"\x00", b"[", b"{", b"]", b":", b"- ", b"!!python/name:os.system", b"*x", b"&x ",
          b".nan", b"~", b"'", b'"', b"\t", b"\n", b"  ", b"1e999", b"0x10", b"yes", b"? ", b"%", b"---\n"]


@FUZZ
@given(cuts=st.lists(st.tuples(st.integers(0, len(_GOOD_TEXT)), st.integers(0, 8), st.sampled_from(_EDITS)),
                     min_size=1, max_size=3))
def test_calibration_file_fuzz(cuts):
    raw = bytearray(_GOOD_TEXT.encode())
    for at, drop, ins in cuts:
        raw[at:at + drop] = ins
    path = _file("calibration.yaml", bytes(raw))
    try:
        load(path)
    except CalibrationError as e:
        _one_line(e, path)


# --- pose files -------------------------------------------------------------------------------

_PCOLS = ["t0", "t1", "n", "ax", "ay", "az", "sax", "say", "saz", "gx", "gy", "gz", "mx", "my", "mz",
          "temp", "x"]
_PGOOD = ["0", "1", "-1", "0.5", "200", "2.5", "1e3", "0.004", "-0.7", "3"]
_PBAD = ["1e6", "1e7", "1e308", "1e999", "nan", "inf", "-inf", "NaN", "x", "", " ", "1_0", "0x10", "-0.0",
         "4.9e-324", "\u0661", "123456789012345678901", "0.5.1"]


def _pose_file(b: bytes) -> bytes:
    """A pose file from a byte string, one byte per choice (one hypothesis draw per file keeps
    2,000 cases within seconds; shrinking still works on the bytes).  Choices lean to what is
    valid (the right magic, whole rows of good numbers) so that many files parse and their
    contents are checked; the rest are the faults."""
    it = iter(b)

    def pick(seq):
        return seq[next(it, 0) % len(seq)]

    def value():
        v = next(it, 0)
        return _PGOOD[v % len(_PGOOD)] if v < 232 else _PBAD[v % len(_PBAD)]
    full = ["t0", "t1", "n", "ax", "ay", "az", "sax", "say", "saz", "temp"]
    c = next(it, 0)
    cols = full if c < 160 else (full[3:6] if c < 200 else [pick(_PCOLS) for _ in range(1 + pick(range(8)))])
    head = [POSES_MAGIC if next(it, 0) < 224 else pick([POSES_MAGIC + " ", "# imucald poses v2", "ax"])]
    head += [pick(["# board: mpu6050", "# rate_hz: 100", "#", "# a: b: c"]) for _ in range(pick(range(3)))]
    rows = [[value() for _ in range(len(cols) + (0 if next(it, 0) < 240 else pick([-1, 1])))]
            for _ in range(pick(range(1, 6)))]
    body = [",".join(cols)] + [",".join(r) for r in rows]
    if next(it, 0) >= 224:
        body.insert(pick(range(len(body) + 1)), pick(["", "# c", "\u00e9", "\x00", ",,,"]))
    return ("\n".join(head + body) + pick(["\n", "", "\r\n"])).encode()


@FUZZ
@given(data=st.one_of(st.binary(min_size=1, max_size=120).map(_pose_file), st.binary(max_size=200).map(lambda b: POSES_MAGIC.encode() + b"\n" + b)))
def test_pose_file_fuzz(data):
    path = _file("poses.csv", data)
    try:
        ps = read_poses(path)
    except UserError as e:
        _one_line(e, path)
        return
    assert len(ps) > 0 and (ps.n >= 1).all()
    for a in (ps.acc, ps.t0, ps.t1, ps.gyro, ps.mag, ps.acc_sample_cov):
        assert a is None or (np.isfinite(a).all() and (np.abs(a) <= 1e12).all())


# --- control-socket requests ------------------------------------------------------------------

_REPLY_CLASS = {"status": "STATUS", "poses": "POSES", "coverage": "COVERAGE", "recalibrate": "RECALIBRATE",
                "reset": "RESET", "reload": "RELOAD"}


class _Handler:
    """Stands in for the daemon's command handler: answers a known command by class, and
    for some raises, as a failing part of the daemon would."""

    def __init__(self):
        self.calls = []

    def __call__(self, cmd):
        self.calls.append(cmd)
        if cmd == "reset":
            raise ValueError("bad\nthing")
        return {"class": _REPLY_CLASS[cmd], "value": 1.5}


_WORDS = list(ctl.COMMANDS) + ["", " ", "STATUS", "status ", "stat", "{", "}", '{"cmd":', '"status"', "null",
                               "[]", "1e999", '"cmd"', ":", ",", "\u00e9", "\x00", "\\u0000", "\\ud800", "{}",
                               '{"cmd": 1}', '{"cmd": null}', '{"cmd": ["status"]}', '{"cmd": "status"}',
                               '{"cmd": "reset", "x": NaN}', "9" * 5000, "[" * 2000, '{"a":' * 600]


@FUZZ
@given(parts=st.lists(st.one_of(st.sampled_from(_WORDS), st.text(max_size=8)), max_size=5),
       junk=st.binary(max_size=12))
def test_control_request_fuzz(parts, junk):
    h = _Handler()
    srv = ctl.ControlServer.__new__(ctl.ControlServer)     # dispatch only: no socket
    srv.handler = h
    raw = "".join(parts).encode("utf-8", "surrogatepass") + junk
    reply = srv.dispatch(raw.replace(b"\n", b" "))
    line = ctl._reply(reply)
    assert line.endswith(b"\n") and line.count(b"\n") == 1
    back = json.loads(line, parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))
    assert back["class"] in set(_REPLY_CLASS.values()) | {"ERROR"}
    if back["class"] == "ERROR":
        assert back["message"] and "\n" not in back["message"]
    else:
        assert h.calls and _REPLY_CLASS[h.calls[-1]] == back["class"]


def test_a_key_given_twice_in_a_control_request_is_refused():
    """{"cmd": "status", "cmd": "reset"} ran "reset" (JSON's last key wins) and wiped the
    poses with nothing in the log (a cold review).  Seen to fail with the plain json.loads
    (the handler called with "reset")."""
    h = _Handler()
    srv = ctl.ControlServer.__new__(ctl.ControlServer)
    srv.handler = h
    for raw in (b'{"cmd": "status", "cmd": "reset"}', b'{"cmd": "reset", "x": {"a": 1, "a": 2}}'):
        reply = srv.dispatch(raw)
        assert reply["class"] == "ERROR" and "given twice" in reply["message"], reply
    assert h.calls == []


def test_control_requests_through_a_real_socket(tmp_path):
    """Hostile lines through the real server: one reply line per request line, in order,
    each strict JSON; an over-long line ends that client only."""
    import random
    h = _Handler()
    srv = ctl.ControlServer(str(tmp_path / "c.sock"), h, "0600")
    rnd = random.Random(7)
    lines = [b"status", b"\xff\xfe", b'{"cmd": "poses"}', b"{", b"\x00reset", b'{"cmd": 1}', b"coverage",
             bytes(rnd.randrange(256) for _ in range(40)).replace(b"\n", b""), b"reload"]
    try:
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(str(tmp_path / "c.sock"))
        c.settimeout(0.01)
        c.sendall(b"\n".join(lines) + b"\n")
        buf = b""
        for _ in range(2000):
            srv.poll()
            try:
                buf += c.recv(65536)
            except socket.timeout:
                pass
            if buf.count(b"\n") >= len(lines):
                break
        replies = [json.loads(x) for x in buf.splitlines()]
        assert [r["class"] for r in replies] == ["STATUS", "ERROR", "POSES", "ERROR", "ERROR", "ERROR",
                                                 "COVERAGE", "ERROR", "RELOAD"]
        assert all("\n" not in r.get("message", "") for r in replies)
        # an over-long line: one ERROR, then the connection is closed; others go on
        c.sendall(b"s" * (ctl.MAX_LINE + 10))
        c.settimeout(0.01)
        buf = b""
        for _ in range(2000):
            srv.poll()
            try:
                d = c.recv(65536)
                if not d:
                    break
                buf += d
            except socket.timeout:
                pass
            except ConnectionResetError:     # closed with the rest of the line unread
                break
        assert json.loads(buf)["class"] == "ERROR" and srv.dropped == 1
        c.close()
    finally:
        srv.close()


def test_hostile_requests_to_a_running_daemon(tmp_path):
    """The real daemon's handler behind the real socket: every command and hostile lines in
    one write; one strict-JSON reply line each, in order; the daemon samples on and ends
    cleanly."""
    import signal
    import subprocess
    import sys
    import time
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    rt = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "imucald.cli", "run", "--emulate", "--speed", "5", "--state-dir",
                          str(tmp_path / "st"), "--runtime-dir", str(rt)], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, cwd=root)
    lines = [b"status", b"poses", b"coverage", b"\xff\xfe\x00", b'{"cmd": "status", "x": NaN}', b"[" * 900,
             b'{"cmd": ["reset"]}', b"recalibrate", b"reset", b"reload", b"STATUS", b"status"]
    want = ["STATUS", "POSES", "COVERAGE", "ERROR", "STATUS", "ERROR", "ERROR", "ERROR", "RESET", "RELOAD",
            "ERROR", "STATUS"]
    try:
        t0 = time.time()
        while not (rt / "control.sock").exists() and p.poll() is None and time.time() - t0 < 120:
            time.sleep(0.05)
        def connect():
            c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                c.connect(str(rt / "control.sock"))
                return c
            except OSError:
                c.close()
                raise
        # the socket file exists a moment before it listens (bind, chmod, listen): retry
        c = wait_until(lambda: or_none(connect), timeout=60)
        c.settimeout(30)
        c.sendall(b"\n".join(lines) + b"\n")
        buf = b""
        while buf.count(b"\n") < len(lines):
            d = c.recv(65536)
            if not d:
                break
            buf += d
        c.close()
        strict = [json.loads(x, parse_constant=lambda k: pytest.fail(f"non-strict JSON {k} in {x[:80]!r}"))
                  for x in buf.splitlines()]
        assert [r["class"] for r in strict] == want, strict
        assert all("\n" not in r.get("message", "") for r in strict)
        assert strict[-1]["board_stats"]["samples"] > strict[0]["board_stats"]["samples"]
    finally:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        err = p.communicate(timeout=60)[1]
    assert p.returncode == 0 and "Traceback" not in err, err


# --- YAML aliases and output paths (issue 21) ------------------------------------------------

def _alias_bomb(depth: int, fan: int, where: str) -> str:
    sec, key = where.split(".")
    lines = [f"{sec}:", f"  {key}: &a0 [" + ", ".join(["lol"] * fan) + "]"]
    lines += [f"  k{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * fan) + "]" for i in range(1, depth)]
    return "\n".join(lines) + "\n"


@settings(max_examples=100, deadline=None, derandomize=True, database=None)
@given(depth=st.integers(1, 12), fan=st.integers(1, 12),
       where=st.sampled_from(["sensor.board", "mqtt.host", "log.level", "nope.x", "sensor.nope"]))
def test_config_yaml_aliases_are_refused_before_any_expansion(depth, fan, where):
    """Billion laughs of any depth and fan-out (up to 12^12 leaves), under a known or an
    unknown key: refused at the first alias (or, depth 1, no alias: the value's own error),
    in one line naming c.yaml:LINE; tracemalloc peak < 5 MB."""
    import tracemalloc
    text = _alias_bomb(depth, fan, where)
    tracemalloc.start()
    try:
        with pytest.raises(ConfigError) as e:
            data, lines, plain = parse_yaml(text.encode(), "c.yaml")
            validate(data, "c.yaml", lines, plain)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    _one_line(e.value, "c.yaml")
    if depth > 1:
        assert str(e.value).startswith("c.yaml:3: a YAML alias (*a0)"), str(e.value)
    assert peak < 5 << 20 and len(str(e.value)) < 400


@settings(max_examples=100, deadline=None, derandomize=True, database=None)
@given(depth=st.integers(2, 10), fan=st.integers(2, 10), key=st.sampled_from(["chips", "board", "accel", "x"]))
def test_calibration_yaml_aliases_are_refused(depth, fan, key):
    """The same bombs in a calibration file (e.g. chips.accel): one line naming the alias."""
    body = _alias_bomb(depth, fan, f"{key}.accel")
    path = _file("calibration.yaml", (yaml.safe_dump(_SMALL, sort_keys=False) + body).encode())
    with pytest.raises(CalibrationError) as e:
        load(path)
    _one_line(e.value, path)
    assert "a YAML alias (*a0) is not accepted" in str(e.value)


_KINDS = ["absent", "file", "dir", "fifo", "socket", "link-file", "link-fifo", "link-dir", "dangling",
          "devnull"]


@settings(max_examples=120, deadline=None, derandomize=True, database=None)
@given(kind=st.sampled_from(_KINDS), how=st.sampled_from(["atomic", "recording", "growing"]),
       data=st.binary(max_size=64))
def test_output_paths_only_ever_replace_a_regular_file(kind, how, data):
    """Whatever is at an output path: written (it was absent, a regular file or a link to one:
    the path is then a regular file with the data) or refused with NotAFile (exit 73), the
    thing left as it was; no temporary file left either way."""
    import shutil
    import socket as so
    from imucald.files.atomic import GrowingFile, NotAFile, atomic_write_bytes
    from imucald.files.recording import Recording, write_recording
    d = tempfile.mkdtemp(dir=_DIR)
    p = os.path.join(d, "out")
    s = None
    target = {"link-file": "f", "link-fifo": "q", "link-dir": "dd", "dangling": "none"}.get(kind)
    if kind == "devnull":
        p = os.devnull
    elif kind in ("file",):
        open(p, "w").write("old")
    elif kind == "dir":
        os.mkdir(p)
    elif kind == "fifo":
        os.mkfifo(p)
    elif kind == "socket":
        s = so.socket(so.AF_UNIX)
        s.bind(p)
    elif target:
        t = os.path.join(d, target)
        if kind == "link-file":
            open(t, "w").write("old")
        elif kind == "link-fifo":
            os.mkfifo(t)
        elif kind == "link-dir":
            os.mkdir(t)
        os.symlink(t, p)
    before = os.lstat(p) if os.path.lexists(p) else None
    try:
        if how == "atomic":
            atomic_write_bytes(p, data)
            expect = data
        elif how == "recording":
            write_recording(Recording(t=np.arange(3) * 0.01, acc=np.zeros((3, 3))), p)
            expect = None
        else:
            g = GrowingFile(p, b"head\n")
            g.write(data)
            g.close()
            expect = b"head\n" + data
        assert kind in ("absent", "file", "link-file", "dangling"), kind
        st_ = os.lstat(p)
        assert stat.S_ISREG(st_.st_mode)
        if expect is not None:
            assert open(p, "rb").read() == expect
        else:
            assert read_recording(p).t.size == 3
    except NotAFile as e:
        _one_line(e, p)
        assert kind in ("dir", "fifo", "socket", "link-fifo", "link-dir", "devnull"), kind
        after = os.lstat(p)
        assert (after.st_ino, stat.S_IFMT(after.st_mode)) == (before.st_ino, stat.S_IFMT(before.st_mode))
    finally:
        if s is not None:
            s.close()
        left = [f for f in os.listdir(d) if f.endswith(".tmp")]
        shutil.rmtree(d, ignore_errors=True)
    assert not left, left
