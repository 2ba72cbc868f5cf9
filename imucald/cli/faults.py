"""``--fault`` option parsing (record, run): the one place its forms are read."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Optional

from ..errors import UserError

if TYPE_CHECKING:
    from ..sim.emulators import Faults


def _time_s(text: str) -> float:
    """A time or a duration of a fault, s: a finite number >= 0."""
    v = float(text)
    if not 0 <= v < math.inf:
        raise ValueError(f"{text} s is not a time >= 0")
    return v


def _span_s(t: str, d: str) -> tuple:
    """(start, end) s of a fault from T+D: both times >= 0, the end finite too."""
    t0 = _time_s(t)
    t1 = t0 + _time_s(d)
    if not t1 < math.inf:
        raise ValueError(f"{t}+{d} s is not a time >= 0")
    return t0, t1


def _address(text: str) -> int:
    """A 7-bit I2C address in hex (0x03..0x77, the ones a device may answer at)."""
    v = int(text, 16)
    if not 0x03 <= v <= 0x77:
        raise ValueError(f"{text} is not a 7-bit device address 0x03..0x77")
    return v


def parse_fault(spec: str, faults) -> None:
    """--fault forms: nack=P, stuck=T+D, busy=ADDR, wrong-id=ADDR:ID, reset=ADDR@T,
    disconnect=ADDR@T+D (P a probability 0..1, times and durations in s >= 0, addresses in
    hex, ID a byte)."""
    try:
        kind, val = spec.split("=", 1)
        if kind == "nack":
            p = float(val)
            if not 0 <= p <= 1:
                raise ValueError(f"{val} is not a probability 0..1")
            faults.nack_prob = p
        elif kind == "stuck":
            t, d = val.split("+")
            faults.stuck.append(_span_s(t, d))
        elif kind == "busy":
            faults.busy.add(_address(val))
        elif kind == "wrong-id":
            a, i = val.split(":")
            if not 0 <= int(i, 16) <= 0xFF:
                raise ValueError(f"{i} is not a byte 0x00..0xFF")
            faults.wrong_id[_address(a)] = int(i, 16)
        elif kind == "reset":
            a, t = val.split("@")
            faults.resets.setdefault(_address(a), []).append(_time_s(t))
        elif kind == "disconnect":
            a, w = val.split("@")
            t, d = w.split("+")
            faults.disconnected[_address(a)] = _span_s(t, d)
        else:
            raise ValueError
    except ValueError as e:
        why = f" ({e})" if " is not " in str(e) else ""
        raise UserError(f"--fault {spec!r}{why}: allowed nack=P, stuck=T+D, busy=0xAA, wrong-id=0xAA:0xII, "
                        f"reset=0xAA@T, disconnect=0xAA@T+D") from None


def faults_from_options(specs) -> "Optional[Faults]":
    """The emulator's :class:`Faults` from repeated ``--fault`` options; None when none given."""
    if not specs:
        return None
    from ..sim.emulators import Faults
    faults = Faults()
    for f in specs:
        parse_fault(f, faults)
    return faults
