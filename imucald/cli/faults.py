"""``--fault`` option parsing (record, run): the one place its forms are read."""
from __future__ import annotations

from typing import TYPE_CHECKING, Optional

from ..errors import UserError

if TYPE_CHECKING:
    from ..sim.emulators import Faults


def parse_fault(spec: str, faults) -> None:
    """--fault forms: nack=P, stuck=T+D, busy=ADDR, wrong-id=ADDR:ID, reset=ADDR@T,
    disconnect=ADDR@T+D (times and durations in s, addresses in hex)."""
    try:
        kind, val = spec.split("=", 1)
        if kind == "nack":
            faults.nack_prob = float(val)
        elif kind == "stuck":
            t, d = val.split("+")
            faults.stuck.append((float(t), float(t) + float(d)))
        elif kind == "busy":
            faults.busy.add(int(val, 16))
        elif kind == "wrong-id":
            a, i = val.split(":")
            faults.wrong_id[int(a, 16)] = int(i, 16)
        elif kind == "reset":
            a, t = val.split("@")
            faults.resets.setdefault(int(a, 16), []).append(float(t))
        elif kind == "disconnect":
            a, w = val.split("@")
            t, d = w.split("+")
            faults.disconnected[int(a, 16)] = (float(t), float(t) + float(d))
        else:
            raise ValueError
    except ValueError:
        raise UserError(f"--fault {spec!r}: allowed nack=P, stuck=T+D, busy=0xAA, wrong-id=0xAA:0xII, "
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
