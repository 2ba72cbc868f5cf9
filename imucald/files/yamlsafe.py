"""The one YAML loader for every file imucald reads (configuration, calibration,
sensor record, noise figures): bounded in size, depth and node count, with aliases refused.

A YAML "billion laughs" (an anchor whose alias is repeated, nested a few levels) expands
a few hundred bytes into gigabytes when the document is built, or when an error message
formats the value; imucald's files never need aliases, so an alias (``*name``) is refused
at the first one, before anything is expanded, naming file:line.  Limits:

* ``MAX_BYTES`` (256 KiB for the configuration, 4 MiB otherwise): a larger file is refused
  unread;
* ``MAX_DEPTH`` (32) nested collections;
* ``MAX_NODES`` (200,000) nodes: parsing stops there, so a file's parse takes bounded time
  and memory (PyYAML's events are pulled one at a time).

Errors are raised as the caller's error class (one line, ``file:line: ...``), quoting at
most a bounded, escaped snippet (errors.snippet).  PyYAML is imported at the first load.
"""
from __future__ import annotations

from typing import Any, Optional

from ..errors import UserError, snippet

__all__ = ["MAX_BYTES", "MAX_DEPTH", "MAX_NODES", "loader_class", "load", "compose", "YamlLimit"]

MAX_BYTES = 4 << 20
MAX_DEPTH = 32
MAX_NODES = 200_000
BOM = "\ufeff"

_CLASSES: dict = {}


class YamlLimit(UserError):
    """A YAML file beyond a limit, or with an alias (raised as the caller's class)."""


def loader_class(base=None):
    """``base`` (PyYAML's SafeLoader by default) with the limits: aliases refused, depth and
    node count bounded.  One subclass per base, made once."""
    import yaml
    base = base or yaml.SafeLoader
    if base in _CLASSES:
        return _CLASSES[base]

    class Bounded(base):
        _imucald_path = "<yaml>"
        _imucald_error = YamlLimit

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                ev = self.peek_event()
                raise self._imucald_error(
                    f"{self._imucald_path}:{ev.start_mark.line + 1}: a YAML alias "
                    f"(*{snippet(ev.anchor, 40, quote=False)}) is not accepted in imucald files "
                    f"(aliases can expand a small file into gigabytes): write the value out")
            depth = getattr(self, "_imucald_depth", 0) + 1
            nodes = getattr(self, "_imucald_nodes", 0) + 1
            self._imucald_depth, self._imucald_nodes = depth, nodes
            if depth > MAX_DEPTH:
                ev = self.peek_event()
                raise self._imucald_error(f"{self._imucald_path}:{ev.start_mark.line + 1}: nested "
                                          f"more than {MAX_DEPTH} levels deep: not an imucald file")
            if nodes > MAX_NODES:
                ev = self.peek_event()
                raise self._imucald_error(f"{self._imucald_path}:{ev.start_mark.line + 1}: more than "
                                          f"{MAX_NODES} YAML nodes: not an imucald file")
            try:
                return super().compose_node(parent, index)
            finally:
                self._imucald_depth -= 1

    Bounded.__name__ = f"Bounded{base.__name__}"
    _CLASSES[base] = Bounded
    return Bounded


def _text(data, path: str, error, max_bytes: int) -> str:
    if isinstance(data, (bytes, bytearray)):
        if len(data) > max_bytes:
            raise error(f"{path}: {len(data)} bytes, more than the {max_bytes >> 10} KiB an imucald "
                        f"YAML file may hold: is it the right file?")
        try:
            data = bytes(data).decode("utf-8")
        except UnicodeDecodeError as e:
            line = data[:e.start].count(b"\n") + 1
            raise error(f"{path}:{line}: byte 0x{data[e.start]:02x} at offset {e.start} is not UTF-8 "
                        f"(a Latin-1 '\u00b0' is 0xb0): save the file as UTF-8") from None
    elif len(data) > max_bytes:
        raise error(f"{path}: more than the {max_bytes >> 10} KiB an imucald YAML file may hold: "
                    f"is it the right file?")
    return data[1:] if data.startswith(BOM) else data


def _loader(text: str, path: str, error, base):
    ld = loader_class(base)(text)
    ld._imucald_path, ld._imucald_error = path, error
    return ld


def _yaml_error(e, path: str, error):
    mark = getattr(e, "problem_mark", None)
    line = f":{mark.line + 1}" if mark is not None else ""
    if isinstance(getattr(e, "position", None), int) and isinstance(getattr(e, "character", None), str):
        return error(f"{path}: character {snippet(e.character, quote=False)} at offset {e.position} "
                     f"is not allowed in YAML (a NUL or control character: binary or damaged file)")
    prob = getattr(e, "problem", None) or str(e).splitlines()[0]
    return error(f"{path}{line}: not valid YAML: {snippet(prob, 120, quote=False)}")


def _run(data, path: str, error, base, max_bytes: int, get):
    """``get`` (a loader method's name) on ``data`` with the limits; every failure one line."""
    import yaml
    text = _text(data, path, error, max_bytes)
    ld = None
    try:
        ld = _loader(text, path, error, base)
        return getattr(ld, get)()
    except yaml.YAMLError as e:
        raise _yaml_error(e, path, error) from None
    except RecursionError:
        raise error(f"{path}: not valid YAML: nested too deeply") from None
    finally:
        if ld is not None:
            ld.dispose()


def compose(data, path: str, error=UserError, base=None, max_bytes: int = MAX_BYTES):
    """The YAML node tree of ``data`` (bytes or str) with the limits (None for an empty file)."""
    return _run(data, path, error, base, max_bytes, "get_single_node")


def load(data, path: str, error=UserError, base=None, max_bytes: int = MAX_BYTES) -> Any:
    """The Python value of ``data`` (bytes or str): one document, with the limits; ``error``
    (a UserError class) for every failure, one line naming ``path`` and the line."""
    return _run(data, path, error, base, max_bytes, "get_single_data")


def load_file(path: str, error=UserError, base=None, max_bytes: int = MAX_BYTES,
              what: str = "") -> Optional[Any]:
    """``load`` of the file at ``path``, read at most ``max_bytes`` + 1 bytes."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)
    except IsADirectoryError:
        raise error(f"{what}{path}: is a directory") from None
    except OSError as e:
        raise error(f"{what}{path}: cannot read: {e.strerror}") from None
    return load(raw, path, error, base, max_bytes)
