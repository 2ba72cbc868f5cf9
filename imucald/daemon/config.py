"""The daemon's configuration: defaults, YAML loading, validation, overrides, reload.

Every key has a type and an allowed range; an error names the file and line,
the key, the bad value and what is allowed, on one line.

The file is read as YAML 1.2 (core schema) scalars: only ``true``/``false`` are
booleans, so ``emulate: yes`` is the string the documentation shows; ``0660`` is
a decimal number, so a file mode must be quoted (``socket_mode: "0660"``) and an
unquoted one is refused with that fix.  A key given twice is refused, as is a
byte that is not UTF-8 (its offset named).
"""
from __future__ import annotations

import copy
import os
import re
from typing import Any, Dict, List, Optional, Tuple

from ..errors import EX_CONFIG, UserError, snippet
from ..stillness_defaults import STILLNESS_DEFAULTS as _STILL  # one set of stillness defaults

__all__ = ["ConfigError", "FlagError", "DEFAULTS", "load_config", "validate", "set_override",
           "apply_overrides", "check_consistency", "accel_poses_needed", "needs_restart", "parse_yaml"]


class ConfigError(UserError):
    exit_code = EX_CONFIG   # 78: systemd's RestartPreventExitStatus= stops the retry loop


class FlagError(UserError):
    """A command-line override that is out of range or contradicts the configuration
    (a usage error: exit 2)."""


#: key -> (default, kind, allowed); kind: int, float, bool, str, choice, addr, list
SCHEMA: Dict[str, Tuple[Any, str, Any]] = {
    "sensor.board": ("mpu6050", "choice", ("mpu6050", "mpu6500", "mpu9250", "9dof", "gy273")),
    # 9dof / gy273: which magnetometer; auto = found by ID (HMC5883L at 0x1E, else QMC5883L
    # at 0x0D); for an emulated board, auto means the HMC5883L on 9dof, the QMC5883L on gy273
    "sensor.magnetometer": ("auto", "choice", ("auto", "hmc5883l", "qmc5883l")),
    "sensor.bus": (None, "int?", (0, 99)),
    "sensor.emulate": ("auto", "choice", ("auto", "yes", "no")),
    "sensor.address": (None, "addr?", (0x03, 0x77)),
    "sensor.rate_hz": (100.0, "float", (4.0, 1000.0)),
    "sensor.accel_range_g": (2, "choice", (2, 4, 8, 16)),
    "sensor.gyro_range_dps": (250, "choice", (250, 500, 1000, 2000)),
    "sensor.batch_s": (0.02, "float", (0.001, 0.5)),
    "stillness.window_s": (_STILL["window_s"], "float", (0.1, 10.0)),
    "stillness.k": (_STILL["k"], "float", (1.5, 100.0)),
    "stillness.min_still_s": (_STILL["min_still_s"], "float", (0.2, 60.0)),
    "stillness.max_pose_s": (_STILL["max_pose_s"], "float", (1.0, 600.0)),
    "stillness.trim_s": (_STILL["trim_s"], "float", (0.0, 5.0)),
    "poses.merge_angle_deg": (12.0, "float", (0.5, 45.0)),
    "poses.max_poses": (60, "int", (10, 500)),
    # the lower limit is what a fit needs (checked in check_consistency, from the model's
    # parameter count and the cross-validation scheme)
    "calibration.min_poses": (25, "int", (2, 500)),
    "calibration.method": ("ga", "choice", ("ga", "hga", "lm", "ga-paper")),
    "calibration.target_bias_g": (0.002, "float", (1e-6, 1.0)),
    "calibration.target_scale": (0.002, "float", (1e-6, 1.0)),
    # magnetometer cloud only: points withheld from its fit to validate it (poses are
    # cross-validated, every one of them)
    "calibration.holdout_fraction": (0.2, "float", (0.05, 0.5)),
    # the gate's stated rate of accepting a calibration that is no better (fitting/gate.py)
    "calibration.false_accept_rate": (0.05, "float", (0.001, 0.5)),
    "calibration.recalibrate_every_poses": (5, "int", (1, 1000)),
    "calibration.mag_min_coverage": (0.5, "float", (0.05, 1.0)),
    "calibration.history": (10, "int", (0, 1000)),
    # a calibration job running longer is stopped (its worker killed); the next one starts afresh
    "calibration.timeout_s": (300.0, "float", (5.0, 3600.0)),
    # thermal terms: fitted once the still intervals span this many degC (below: a constant only)
    "calibration.thermal_min_span_c": (10.0, "float", (1.0, 200.0)),
    "output.format": ("ndjson", "choice", ("ndjson", "csv", "binary")),
    "output.socket": ("imucald.sock", "str", None),
    "output.socket_mode": ("0660", "mode", None),
    "output.socket_group": (None, "str?", None),
    "output.fifo": (None, "str?", None),
    "output.client_buffer_bytes": (1048576, "int", (4096, 1 << 28)),
    "output.decimate": (1, "int", (1, 1000)),
    # per-sample variances in the NDJSON stream (acc_var_g2, gyro_var_dps2); needs noise.file
    "output.covariance": (False, "choice", (False, True)),
    # orientation (q, gravity-free acc, its uncertainty) in every IMU object: auto = when the
    # orientation extra is installed and the board has a gyro; yes = required (else a config error)
    "output.orientation": ("auto", "choice", ("auto", "yes", "no")),
    "control.socket": ("control.sock", "str", None),
    "control.socket_mode": ("0660", "mode", None),
    "control.socket_group": (None, "str?", None),
    # noise figures written by `imucald noise REC -o FILE`: per-sample covariance and the
    # coloured-noise inflation of pose covariances
    "noise.file": (None, "str?", None),
    "state.directory": ("/var/lib/imucald", "str", None),
    "runtime.directory": ("/run/imucald", "str", None),
    "log.level": ("info", "choice", ("debug", "info", "warning", "error")),
    # the MQTT bridge (`imucald mqtt`, its own process and unit): the daemon does not use
    # these, but loads and checks them like every key (a bad value stops it with 78)
    "mqtt.host": ("localhost", "str", None),
    "mqtt.port": (None, "int?", (1, 65535)),        # null: 1883, or 8883 with tls
    "mqtt.tls": (False, "choice", (False, True)),
    "mqtt.ca_file": (None, "str?", None),             # null: the system's CA store
    "mqtt.username": (None, "str?", None),
    "mqtt.password_file": (None, "str?", None),       # first line is the password; never on the command line
    "mqtt.client_id": (None, "str?", None),           # null: imucald-<sensor id>
    "mqtt.topic_prefix": ("imucald", "str", None),
    "mqtt.qos": (1, "choice", (0, 1, 2)),
    "mqtt.sample_rate_hz": (10.0, "float", (0.01, 1000.0)),
    "mqtt.status_interval_s": (5.0, "float", (0.2, 3600.0)),
    "mqtt.buffer": (1000, "int", (1, 1000000)),     # messages held while the broker is away; oldest dropped
    "mqtt.keepalive_s": (30, "int", (5, 3600)),
    "mqtt.discovery": (False, "choice", (False, True)),
    "mqtt.discovery_prefix": ("homeassistant", "str", None),
}

DEFAULTS: Dict[str, Dict[str, Any]] = {}
for _k, (_d, _, _) in SCHEMA.items():
    _s, _n = _k.split(".")
    DEFAULTS.setdefault(_s, {})[_n] = _d


#: keys that take effect on reload (SIGHUP); the others (the sensor, the sockets, the
#: directories, the stream's format) need a restart
RELOADABLE_SECTIONS = ("stillness", "poses", "calibration", "log",
                       "mqtt")     # read by the bridge only: never a reason to restart the daemon
RELOADABLE_KEYS = ("output.decimate", "output.client_buffer_bytes")


def needs_restart(key: str) -> bool:
    return key.split(".")[0] not in RELOADABLE_SECTIONS and key not in RELOADABLE_KEYS


_BOOL, _INT, _FLOAT = "tag:yaml.org,2002:bool", "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"


_LOADER = None
#: the largest configuration file read (the shipped one is ~10 KB); with the YAML limits
#: (yamlsafe: no aliases, depth 32) a reload's parse is bounded in time and memory
MAX_CONFIG_BYTES = 256 << 10


def _loader():
    """PyYAML's safe loader with YAML 1.2 core-schema scalars (booleans true/false
    only; integers decimal, 0o octal or 0x hex; floats with an exponent).  Made at the
    first file read: the schema alone (the command line's choices) does not import yaml."""
    global _LOADER
    if _LOADER is not None:
        return _LOADER
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    _Loader.yaml_implicit_resolvers = {
        ch: [(tag, rx) for tag, rx in rs if tag not in (_BOOL, _INT, _FLOAT)]
        for ch, rs in yaml.SafeLoader.yaml_implicit_resolvers.items()}
    _Loader.add_implicit_resolver(_BOOL, re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF"))
    _Loader.add_implicit_resolver(_INT, re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$"),
                                  list("-+0123456789"))
    _Loader.add_implicit_resolver(
        _FLOAT, re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                           r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"), list("-+.0123456789"))
    _Loader.add_constructor(_INT, _construct_int)
    _LOADER = _Loader
    return _Loader


def _construct_int(loader, node):
    t = loader.construct_scalar(node)
    return int(t, 0) if t[:2] in ("0o", "0x") else int(t, 10)


def _decode(raw: bytes, path: str) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[:e.start].count(b"\n") + 1
        raise ConfigError(f"{path}:{line}: byte 0x{raw[e.start]:02x} at offset {e.start} is not UTF-8 "
                          f"(a Latin-1 '\u00b0' is 0xb0): save the file as UTF-8, e.g. iconv -f latin1 "
                          f"-t utf-8") from None


def _scan(text: str, path: str) -> Tuple[Dict[str, int], Dict[str, str]]:
    """(key path -> 1-based line, key path -> the scalar as written, unquoted only),
    from the YAML nodes; a key given twice in one mapping is an error."""
    lines: Dict[str, int] = {}
    plain: Dict[str, str] = {}
    import yaml
    from ..files.yamlsafe import compose
    node = compose(text, path, ConfigError, base=_loader(), max_bytes=MAX_CONFIG_BYTES)

    def walk(n, prefix):
        if not isinstance(n, yaml.MappingNode):
            return
        seen: Dict[str, int] = {}
        for k, v in n.value:
            ln = k.start_mark.line + 1
            if not isinstance(k, yaml.ScalarNode):
                raise ConfigError(f"{path}:{ln}: a key must be a name, not a "
                                  f"{'list' if isinstance(k, yaml.SequenceNode) else 'mapping'}; "
                                  f"write section: / key: value")
            if k.tag.endswith((":null", ":bool")):
                # "~:" or "yes:" is a null or a boolean to YAML: no key's name, and the line
                # was lost on the way (a cold review: "c.yaml:?: unknown section 'None'")
                raise ConfigError(f"{path}:{ln}: {k.value!r} is not a key's name (YAML reads it as "
                                  f"{'null' if k.tag.endswith(':null') else 'true or false'}): "
                                  f"write section: / key: value")
            key = f"{prefix}{k.value}"
            if k.value in seen:
                raise ConfigError(f"{path}:{ln}: {key} is given twice (first at line {seen[k.value]}): "
                                  f"keep one")
            seen[k.value] = ln
            lines[key] = ln
            if isinstance(v, yaml.ScalarNode) and not v.style:
                plain[key] = v.value
            walk(v, key + ".")
    walk(node, "")
    return lines, plain


def _lines(text: str) -> Dict[str, int]:
    """key path -> 1-based line number (empty when the text is not valid YAML)."""
    import yaml
    try:
        return _scan(text, "")[0]
    except (yaml.YAMLError, ConfigError):
        return {}


def _quote(value: Any) -> str:
    """A value for a message, in YAML's words (null, true, false: a cold review read Python's
    "None is empty"), bounded and escaped (errors.snippet)."""
    if value is None or isinstance(value, bool):
        return {None: "null", True: "true", False: "false"}[value]
    if isinstance(value, str):
        return snippet(value)
    import reprlib

    class _YamlRepr(reprlib.Repr):   # YAML's words inside lists and mappings too
        def repr_NoneType(self, x, level):
            return "null"

        def repr_bool(self, x, level):
            return "true" if x else "false"

    r = _YamlRepr()                  # bounded however the value nests (never the whole of it)
    r.maxlevel, r.maxlist, r.maxdict, r.maxstring, r.maxother = 3, 6, 6, 40, 40
    return snippet(r.repr(value), 80, quote=False)


def _check(key: str, value: Any, where: str, plain: Optional[str] = None) -> Any:
    if key not in SCHEMA:
        sec = key.split(".")[0]
        known = sorted(k for k in SCHEMA if k.startswith(sec + "."))
        allowed = ", ".join(known) if known else ", ".join(sorted({k.split(".")[0] for k in SCHEMA}))
        raise ConfigError(f"{where}unknown key {snippet(key)}; allowed: {allowed}")
    default, kind, allowed = SCHEMA[key]
    bad = lambda what: ConfigError(f"{where}{key}: {_quote(value)} {what}")
    opt = kind.endswith("?")
    k = kind.rstrip("?")
    if value is None:
        if opt:
            return None
        raise bad(f"(empty) is not allowed: give a value (the default is {_quote(default)})")
    if k == "choice":
        for a in allowed:
            if value == a or (isinstance(a, str) and str(value) == a):
                return a
        raise bad(f"is not allowed; allowed: {', '.join(map(str, allowed))}")
    if k in ("int", "float"):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                (k == "int" and isinstance(value, float) and not value.is_integer()):
            raise bad(f"is not {'an integer' if k == 'int' else 'a number'} "
                      f"(allowed {allowed[0]}..{allowed[1]})")
        v = int(value) if k == "int" else float(value)
        if not allowed[0] <= v <= allowed[1]:
            raise bad(f"is out of range; allowed {allowed[0]}..{allowed[1]}")
        return v
    if k == "addr":
        try:
            v = int(value, 0) if isinstance(value, str) else int(value)
        except ValueError:
            raise bad("is not an I2C address (e.g. 0x68)") from None
        if not allowed[0] <= v <= allowed[1]:
            raise bad("is not a 7-bit I2C address (0x03..0x77)")
        return v
    if k == "mode":
        if not isinstance(value, str):
            text = plain if plain is not None else repr(value)
            fix = text if re.fullmatch(r"0?[0-7]{3}", text) else "0660"
            raise ConfigError(f"{where}{key}: {text} unquoted is a number to YAML, not a file mode; "
                              f'write it quoted: {key.split(".")[1]}: "{fix}"')
        if not re.fullmatch(r"0?[0-7]{3}", value.strip()):
            raise bad("is not an octal file mode 0000..0777 (e.g. '0660')")
        return f"{int(value, 8):04o}"
    if k == "str":
        if not isinstance(value, str) or not value:
            raise bad("is not a non-empty string")
        return value
    raise AssertionError(kind)


def validate(cfg: Dict[str, Any], path: str = "", lines: Optional[Dict[str, int]] = None,
             plain: Optional[Dict[str, str]] = None) -> Dict[str, Dict[str, Any]]:
    """Merge ``cfg`` over the defaults, checking every key (``plain``: key -> the unquoted
    scalar as written, for messages)."""
    lines, plain = lines or {}, plain or {}
    out = copy.deepcopy(DEFAULTS)
    if cfg is None:
        return out
    if not isinstance(cfg, dict):
        raise ConfigError(f"{path}: the configuration must be a mapping of sections")
    for sec, body in cfg.items():
        where = f"{path}:{lines.get(str(sec), '?')}: " if path else ""
        if sec not in DEFAULTS:
            raise ConfigError(f"{where}unknown section {snippet(str(sec))}; allowed: {', '.join(DEFAULTS)}")
        if body is None:
            continue
        if not isinstance(body, dict):
            raise ConfigError(f"{where}section {snippet(str(sec))} must be a mapping of keys")
        for k, v in body.items():
            key = f"{sec}.{k}"
            w = f"{path}:{lines.get(key, '?')}: " if path else ""
            out[sec][k] = _check(key, v, w, plain.get(key))
    check_consistency(out, path, lines)
    return out


#: parameters of the daemon's accelerometer model, triangular9 (a test checks it against
#: fitting.models.registry; not imported here: loading the configuration must not need numpy)
ACCEL_MODEL_PARAMS = 9


def accel_poses_needed() -> int:
    """Fewest poses the daemon's accelerometer fit (triangular9) and its
    leave-one-pose-out scoring need."""
    from ..numerics.folds import poses_needed
    return poses_needed(ACCEL_MODEL_PARAMS)


def check_consistency(cfg: Dict[str, Dict[str, Any]], path: str = "",
                      lines: Optional[Dict[str, int]] = None, flags: Optional[Dict[str, str]] = None
                      ) -> None:
    """Keys that are each in range but contradict one another or what a fit needs.

    flags: key -> the command-line flag that set it (named instead of file:line)."""
    lines, flags = lines or {}, flags or {}

    def where(key):
        if key in flags:
            return f"{flags[key]}: "
        return f"{path}:{lines.get(key, '?')}: " if path else ""

    def error(key, msg):
        return (FlagError if key in flags else ConfigError)(f"{where(key)}{msg}")
    s = cfg["sensor"]
    from ..drivers.rates import rate_problem
    why = rate_problem(s["board"], s["rate_hz"])
    if why:
        key = "sensor.rate_hz" if "sensor.rate_hz" in flags or "sensor.board" not in flags else "sensor.board"
        raise error(key, f"sensor.rate_hz: {why}" + (f" (sensor.board is {s['board']})"
                                                       if key == "sensor.rate_hz" else
                                                       f"; sensor.rate_hz is {s['rate_hz']:g}"))
    from ..drivers.rates import batch_problem
    why = batch_problem(s["board"], s["rate_hz"], s["batch_s"])
    if why:
        key = "sensor.rate_hz" if "sensor.rate_hz" in flags else "sensor.batch_s"
        raise error(key, f"sensor.batch_s: {why}")
    if cfg["output"]["covariance"] and not cfg["noise"]["file"]:
        raise error("output.covariance", "output.covariance: true needs noise.file (the "
                    "figures of `imucald noise STILL_RECORDING -o FILE`)")
    m = cfg["mqtt"]
    if m["ca_file"] and not m["tls"]:
        raise error("mqtt.ca_file", "mqtt.ca_file is set but mqtt.tls is false: set tls: true "
                    "(or remove ca_file)")
    if m["password_file"] and not m["username"]:
        raise error("mqtt.password_file", "mqtt.password_file needs mqtt.username")
    if any(c in m["topic_prefix"] for c in "+#\0"):
        raise error("mqtt.topic_prefix", f"mqtt.topic_prefix: {m['topic_prefix']!r} holds an MQTT "
                    f"wildcard (+ or #): use plain words, e.g. imucald or site/lab")
    _check_socket_paths(cfg, error)
    _check_files_and_groups(cfg, error)
    c = cfg["calibration"]
    need = accel_poses_needed()
    if c["min_poses"] < need:
        raise error('calibration.min_poses', f"calibration.min_poses: {c['min_poses']} is too "
                          f"few: the triangular9 fit (9 parameters) scored by leave-one-pose-out needs "
                          f"at least {need} poses; allowed {need}..500")
    mp = cfg["poses"]["max_poses"]
    if mp < c["min_poses"]:
        raise error('calibration.min_poses' if 'calibration.min_poses' in flags else 'poses.max_poses',
                    f"poses.max_poses: {mp} is below calibration.min_poses "
                          f"{c['min_poses']}, so a calibration would never start; allowed "
                          f"{c['min_poses']}..500 (or lower calibration.min_poses)")
    floor = 0.5 ** need
    if c["false_accept_rate"] < floor:
        raise error('calibration.false_accept_rate', f"calibration.false_accept_rate: "
                          f"{c['false_accept_rate']:g} is below {floor:.2g}, the smallest p-value {need} "
                          f"poses can give: the first calibration could never be accepted; allowed "
                          f"{floor:.2g}..0.5")


def _value(cfg: Dict[str, Dict[str, Any]], key: str) -> Any:
    """The value of a dotted key (``output.socket``) in a loaded configuration."""
    sec, k = key.split(".")
    return cfg[sec][k]


def _check_files_and_groups(cfg: Dict[str, Dict[str, Any]], error) -> None:
    """noise.file exists, and the socket groups do: said here with the file and line (a cold
    review: at start-up they came without either, noise.file's key twice)."""
    nf = cfg["noise"]["file"]
    # an absolute path only (a relative one is the daemon's working directory's, and `imucald
    # status` run elsewhere read it against its own: exit 78, a cold review), and only where
    # this user can look (a user the daemon's directories are closed to reads the same
    # configuration); the daemon checks it again when it reads the file
    if nf and os.path.isabs(nf) and os.access(os.path.dirname(nf), os.X_OK) and not os.path.isfile(nf):
        what = "is a directory" if os.path.isdir(nf) else "does not exist"
        raise error("noise.file", f"noise.file: {nf} {what}: make it with `imucald noise "
                                  f"STILL_RECORDING -o FILE`, or remove the key")
    import grp
    for key in ("output.socket_group", "control.socket_group"):
        g = _value(cfg, key)
        if g is None:
            continue
        try:
            grp.getgrnam(g)
        except KeyError:
            raise error(key, f"{key}: group {g!r} does not exist (getent group lists them; create "
                             f"it with groupadd or change the setting)") from None


def _check_socket_paths(cfg: Dict[str, Dict[str, Any]], error) -> None:
    """The data socket, the control socket and the FIFO: paths a socket can take (no NUL
    byte: a cold review's "a\\0b" ended in a traceback and a stray file), and three different
    ones (the control socket given the data socket's name left one socket, and the stream
    out of reach)."""
    rd = cfg["runtime"]["directory"]
    seen: Dict[str, str] = {}
    for key in ("output.socket", "control.socket", "output.fifo"):
        name = _value(cfg, key)
        if not name:
            continue
        if "\0" in name:
            raise error(key, f"{key}: {name!r} holds a NUL byte: give a plain file name, e.g. "
                             f"{SCHEMA[key][0] or 'imucald.fifo'}")
        full = os.path.normpath(os.path.join(rd, name))
        if full in seen:
            raise error(key, f"{key}: {name!r} is the same path as {seen[full]}: the data stream and "
                             f"the control channel each need their own; choose another name")
        seen[full] = key


def parse_yaml(raw: bytes, path: str) -> Tuple[Any, Dict[str, int], Dict[str, str]]:
    """(data, key lines, unquoted scalars) of a configuration file's bytes; ConfigError
    (one line, file:line) for bytes that are not UTF-8, invalid YAML or a duplicate key."""
    from ..files.yamlsafe import load
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: {len(raw)} bytes, more than the {MAX_CONFIG_BYTES >> 10} KiB a "
                          f"configuration may hold: is it the right file?")
    text = _decode(raw, path)
    lines, plain = _scan(text, path)
    data = load(text, path, ConfigError, base=_loader(), max_bytes=MAX_CONFIG_BYTES)
    return data, lines, plain


def load_config(path: Optional[str]) -> Dict[str, Dict[str, Any]]:
    if path is None:
        return validate({})
    raw = _read_config(path)
    data, lines, plain = parse_yaml(raw, path)
    return validate(data, path, lines, plain)


def _read_config(path: str) -> bytes:
    """The file's bytes (at most MAX_CONFIG_BYTES + 1): a regular file only, opened without
    blocking (a FIFO with no writer made start-up and SIGHUP hang)."""
    import os
    import stat
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the configuration: {e.strerror}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ConfigError(f"{path}: not a regular file: give the configuration file itself")
        with os.fdopen(os.dup(fd), "rb") as fh:
            return fh.read(MAX_CONFIG_BYTES + 1)
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the configuration: {e.strerror}") from None
    finally:
        os.close(fd)


def apply_overrides(cfg: Dict[str, Dict[str, Any]], overrides: List[Tuple[str, Any, str]],
                    path: Optional[str] = None) -> None:
    """Command-line overrides (key, value, flag) over a loaded configuration, checked
    with it (a start and every reload apply the same ones)."""
    if not overrides:
        return
    flags = {}
    for key, value, flag in overrides:
        set_override(cfg, key, value, flag)
        flags[key] = flag
    lines: Dict[str, int] = {}
    if path is not None:
        try:
            lines = _lines(_decode(_read_config(path), path))
        except (OSError, ConfigError):
            pass
    check_consistency(cfg, path or "", lines, flags)


def set_override(cfg: Dict[str, Dict[str, Any]], key: str, value: Any, flag: str) -> None:
    """Apply a command-line override (already parsed) with the same validation; call
    check_consistency once all overrides are in."""
    sec, k = key.split(".")
    try:
        cfg[sec][k] = _check(key, value, f"{flag}: ")
    except ConfigError as e:
        raise FlagError(str(e)) from None
