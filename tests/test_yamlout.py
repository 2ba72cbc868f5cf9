"""imucald.files.yamlout.dump writes a calibration file's YAML without PyYAML: its text must
be PyYAML's ``safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)`` byte for
byte, or None (then calibration.save uses PyYAML)."""
import math

import numpy as np
import yaml

from imucald.files.yamlout import WIDTH, dump

_WORDS = ["determined", "prior-held", "g", "deg/s", "degC", "gauss", "s", "mpu6050", "9dof",
          "triangular9", "mag_sym", "ga", "unknown", "calibration.thermal_min_span_c"]
_TRICKY = ["yes", "No", "null", "~", "", " lead", "trail ", "a: b", "x #y", "#c", "a,b", "[x]",
           "it's", "2026-11-26T14:22:16+00:00", "2026-11-26", "1e5", "0x1f", "12", "1.5", "-a",
           "é", "a\nb", "a  b", ".inf", "3t", "on", "- a", "%x", "@x", "a:b", "=", "<<"]


def _note(rng):
    words = ["order", "1:", "held-out", "ratio", "19.38", "at", "the", "constant", "->", "1.40",
             "(twin", "99", "%", "1.53,", "closed;", "simplest", "that", "closes", "of", "0,"]
    return "order 1: " + " ".join(rng.choice(words, int(rng.integers(1, 40))))


def _scalar(rng, tricky):
    k = rng.integers(0, 10)
    if k < 5:
        mag = 10.0 ** rng.integers(-20, 20)
        v = float(rng.normal() * mag)
        special = [v, 0.0, -0.0, math.inf, -math.inf, math.nan, 1e16, 1e-5, 2.5, round(v, 3)]
        return special[int(rng.integers(0, len(special)))] if rng.random() < 0.2 else v
    if k == 5:
        return int(rng.integers(-10 ** 6, 10 ** 6))
    if k == 6:
        return bool(rng.random() < 0.5) if rng.random() < 0.7 else None
    if k == 7:
        return _note(rng)
    pool = _WORDS + (_TRICKY if tricky else [])
    return str(pool[int(rng.integers(0, len(pool)))])


def _value(rng, depth, tricky):
    k = rng.integers(0, 10)
    if k < 3 or depth > 2:
        return _scalar(rng, tricky)
    if k < 6:
        return [_scalar(rng, tricky) for _ in range(int(rng.integers(0, 14)))]
    if k < 7:
        return [[_scalar(rng, tricky) for _ in range(int(rng.integers(0, 5)))]
                for _ in range(int(rng.integers(1, 4)))]
    return {f"k{int(rng.integers(0, 99))}_{'x' * int(rng.integers(0, 30))}": _value(rng, depth + 1, tricky)
            for _ in range(int(rng.integers(0, 8)))}


def test_dump_is_pyyaml_text_or_none():
    """Random calibration-shaped documents (floats of every magnitude, inf/nan/-0.0, ints,
    bools, None, words, notes that wrap, flow lists that wrap, lists of lists, nested and
    empty mappings), with and without strings PyYAML quotes or reads as other types.
    Breakage it catches: wrapping a flow list one item late (column >= WIDTH instead of >),
    writing 1e-05 instead of 1.0e-05, a plain 'yes' or '2026-11-26' (read back as a bool or
    a date), the continuation indent of a broken note off by two."""
    rng = np.random.default_rng(24)
    known = 0
    for trial in range(400):
        tricky = trial % 2 == 1
        doc = {f"key{i}": _value(rng, 0, tricky) for i in range(int(rng.integers(1, 7)))}
        doc["units"] = {"accel": "g", "gyro": "deg/s"}
        got = dump(doc)
        want = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=WIDTH)
        if got is not None:
            assert got == want, (trial, doc)
            known += not tricky
    assert known == 200              # every document without tricky strings is written here


def test_dump_leaves_the_unknown_to_pyyaml():
    """A numpy scalar (safe_dump refuses it), a list of mappings, a quote: None."""
    assert dump({"a": {"b": np.float64(1.0)}}) is None
    assert dump({"a": [{"b": 1.0}]}) is None
    assert dump({"a": {"b": "it's"}}) is None
    assert dump({"a": 1.0}) is None             # a mapping of scalars only: a flow document


def test_each_string_alone():
    """Each word and each string PyYAML quotes or reads as another type, alone in a block
    value, a flow list and a flow mapping: PyYAML's text or None (a plain 'yes' or
    '2026-11-26' would read back as a bool or a date)."""
    for s in _WORDS + _TRICKY + ["order 0: x", "datasheet tolerances (generic)"]:
        doc = {"a": {"b": s, "c": [s, "g"], "d": {"e": s}}}
        got = dump(doc)
        assert got is None or got == yaml.safe_dump(doc, sort_keys=False, default_flow_style=None,
                                                    width=WIDTH), s
        assert got is not None or s not in _WORDS, s


def test_long_plain_strings_break_as_pyyaml_breaks_them():
    """Plain multi-word strings (no ': ') past the width, in a block value, a flow list, a
    flow mapping and a block list: broken at the same spaces, indented the same.
    Breakage it catches: breaking at a space whose column is at the width (>= instead of >),
    the continuation indent of a block value's string off by two."""
    rng = np.random.default_rng(7)
    words = ["order", "held-out", "ratio", "19.38", "at", "the", "->", "(twin", "99", "1.53)",
             "closed", "x", "a/b", "deg/s", "=", "<"]
    for _ in range(500):
        s = "w " + " ".join(rng.choice(words, int(rng.integers(1, 50))))
        doc = {"a": {"k" * int(rng.integers(1, 40)): s, "l": [s, 1.5], "m": {"nn": s}},
               "b": [[s, 2.0]], "c": [s, [1.0]]}
        assert dump(doc) == yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=WIDTH), s
