"""The calibration file's YAML text without importing PyYAML (7-10 ms of a ``calibrate -o``).

:func:`dump` gives the text ``yaml.safe_dump(doc, sort_keys=False, default_flow_style=None,
width=WIDTH)`` gives, byte for byte, for the documents a calibration file holds: a mapping
of str keys whose values are mappings, lists, str, int, float, bool or None.  The layout
is YAML's block/flow form as that call lays it out: a collection of scalars only is written
in flow style (``[a, b]``, ``{k: v}``), any other in block style (a list inside a mapping
not indented); a flow collection wraps after the comma whose column passes WIDTH, indented
two beyond its key; a string with spaces breaks at a single space whose column passes
WIDTH, indented two more.  Scalars: floats as ``repr`` (lower case, ``1.0e-05`` for
``1e-05``; ``.inf``, ``-.inf``, ``.nan``), ints as ``str``, ``true``/``false``, ``null``;
a string plain when YAML would read it back as that string and it holds no indicator,
single-quoted when it is an ISO timestamp or holds ``: `` or `` #``.

Anything outside what it knows (a key that is not a plain word, a string starting with a
digit other than a timestamp, a quote, a non-ASCII character, a list of mappings, a numpy
scalar, ...) makes :func:`dump` return None, and the caller uses PyYAML
(:func:`imucald.calibration.save`); tests/test_yamlout.py checks the text against PyYAML's
on random documents of the calibration file's shapes (and bench/imutk.py the Xsens file's).
"""
from __future__ import annotations

import math
import re
from typing import List, Optional

__all__ = ["dump", "WIDTH"]

WIDTH = 100                 #: the ``width`` of the safe_dump call this reproduces
_INDENT = 2
#: strings YAML 1.1 reads as booleans or null (case-insensitive here: a mixed-case one is
#: left to PyYAML rather than guessed)
_WORDS = {"yes", "no", "true", "false", "on", "off", "null", "y", "n", "~"}
_PLAIN = re.compile(r"[A-Za-z][A-Za-z0-9_./()+=<>-]*( [A-Za-z0-9_./()+=<>-]+)*\Z")
_QUOTED = re.compile(r"[ -&(-~]*\Z")           # printable ASCII without "'"
#: a word starting with a digit that YAML 1.1 cannot read as a number or a date (a letter
#: no int, float or timestamp holds: e.g. the board "9dof")
_DIGIT_WORD = re.compile(r"[0-9][A-Za-z0-9_]*[g-suvwyzG-SUVWYZ][A-Za-z0-9_]*\Z")
_STAMP = re.compile(r"[0-9]{4}-[0-9]{2}-[0-9]{2}T[0-9]{2}:[0-9]{2}:[0-9]{2}(\.[0-9]+)?(Z|[+-][0-9]{2}:[0-9]{2})?\Z")


class _Unknown(Exception):
    """Something :func:`dump` leaves to PyYAML."""


def _scalar_text(v) -> str:
    """One scalar as YAML writes it (raises _Unknown for what is left to PyYAML)."""
    t = type(v)
    if v is None:
        return "null"
    if t is bool:
        return "true" if v else "false"
    if t is int:
        return str(v)
    if t is float:
        if v != v:
            return ".nan"
        if math.isinf(v):
            return ".inf" if v > 0 else "-.inf"
        s = repr(v).lower()
        if "." not in s and "e" in s:
            s = s.replace("e", ".0e", 1)
        return s
    if t is str:
        if (_PLAIN.match(v) and v.lower() not in _WORDS) or _DIGIT_WORD.match(v):
            return v
        # quoted: a timestamp (YAML would read a date), or ': ' / ' #' inside (an indicator
        # in any context); other punctuation is left to PyYAML
        if _STAMP.match(v) or (v[:1].isalpha() and _QUOTED.match(v) and (": " in v or " #" in v)
                               and "  " not in v and not v.endswith(" ")):
            return "'" + v + "'"
        raise _Unknown
    raise _Unknown


def _leaf(v) -> bool:
    """A collection YAML writes in flow style: all its items scalars."""
    items = v.values() if type(v) is dict else v
    return all(type(x) not in (dict, list) for x in items)


class _Out:
    """The text written so far and the column of its last line."""

    def __init__(self):
        self.parts: List[str] = []
        self.column = 0

    def write(self, s: str) -> None:
        self.parts.append(s)
        self.column += len(s)

    def newline(self, indent: int) -> None:
        self.parts.append("\n" + " " * indent)
        self.column = indent

    def scalar(self, text: str, indent: int) -> None:
        """A scalar; one with spaces breaks at a single space past WIDTH, to ``indent``."""
        if " " not in text:
            self.write(text)
            return
        words = text.split(" ")
        self.write(words[0])
        for w in words[1:]:
            if self.column > WIDTH:
                self.newline(indent)
            else:
                self.write(" ")
            self.write(w)


def _key(k) -> str:
    # PyYAML writes a key of 128 characters or more as a complex key ("? key")
    if type(k) is not str or len(k) >= 128 or not _PLAIN.match(k) or " " in k or k.lower() in _WORDS:
        raise _Unknown
    return k


def _flow(out: _Out, v, indent: int) -> None:
    """A flow collection at flow indent ``indent`` (its key's + 2)."""
    is_map = type(v) is dict
    out.write("{" if is_map else "[")
    items = list(v.items()) if is_map else list(v)
    for i, item in enumerate(items):
        if i:
            out.write(",")
        if out.column > WIDTH:
            out.newline(indent)
        elif i:
            out.write(" ")
        if is_map:
            out.write(_key(item[0]) + ":")
            out.write(" ")
            out.scalar(_scalar_text(item[1]), indent + _INDENT)
        else:
            out.scalar(_scalar_text(item), indent + _INDENT)
    out.write("}" if is_map else "]")


def _value(out: _Out, v, indent: int) -> None:
    """The value after ``key:`` of a block mapping whose keys are at ``indent``."""
    t = type(v)
    if t in (dict, list) and _leaf(v):
        out.write(" ")
        _flow(out, v, indent + _INDENT)
    elif t is dict:
        _block_map(out, v, indent + _INDENT)
    elif t is list:
        for item in v:          # a list inside a mapping is not indented
            out.newline(indent)
            out.write("-")
            if type(item) is list and _leaf(item):
                out.write(" ")
                _flow(out, item, indent + _INDENT)
            elif type(item) in (dict, list):
                raise _Unknown
            else:
                out.write(" ")
                out.scalar(_scalar_text(item), indent + _INDENT)
    else:
        out.write(" ")
        out.scalar(_scalar_text(v), indent + _INDENT)


def _block_map(out: _Out, d: dict, indent: int) -> None:
    for k, v in d.items():
        if out.parts:
            out.newline(indent)
        else:
            out.write(" " * indent)
        out.write(_key(k) + ":")
        _value(out, v, indent)


def dump(doc) -> Optional[str]:
    """``yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=WIDTH)``'s
    text, or None when ``doc`` holds what this module leaves to PyYAML (module doc)."""
    if type(doc) is not dict or not doc or _leaf(doc):
        return None
    out = _Out()
    try:
        _block_map(out, doc, 0)
    except _Unknown:
        return None
    return "".join(out.parts) + "\n"
