"""The 9dof / GY-273 magnetometer: an HMC5883L or a QMC5883L, told apart by ID register
(boards sold as "HMC5883L" very often carry the QMC5883L at 0x0D)."""
from __future__ import annotations

from typing import Optional

from .bus import Bus, ChipMismatch, Clock, NoAcknowledge
from .hmc5883l import HMC5883L
from .qmc5883l import QMC5883L

__all__ = ["open_magnetometer", "mag_name", "mag_setup", "MAG_CHIPS", "MAG_DEFAULT_HZ"]

MAG_CHIPS = ("auto", "hmc5883l", "qmc5883l")
#: the magnetometer's output rate when none is asked for, Hz
MAG_DEFAULT_HZ = {"hmc5883l": 75.0, "qmc5883l": 100.0}


def open_magnetometer(bus: Bus, which: str = "auto", clock: Optional[Clock] = None,
                      hmc_addr: int = 0x1E, qmc_addr: int = 0x0D):
    """The board's magnetometer driver, identified by its ID register.  ``auto``: the
    HMC5883L at 0x1E if it answers with its ID, else the QMC5883L at 0x0D (the part
    most GY-273 / GY-85 boards carry under the HMC5883L name)."""
    if which == "hmc5883l":
        m = HMC5883L(bus, hmc_addr, clock)
    elif which == "qmc5883l":
        m = QMC5883L(bus, qmc_addr, clock)
    elif which == "auto":
        why = []
        for m in (HMC5883L(bus, hmc_addr, clock), QMC5883L(bus, qmc_addr, clock)):
            try:
                m.identify()
                return m
            except NoAcknowledge:
                why.append(f"nothing at 0x{m.addr:02X}")
            except ChipMismatch as e:
                why.append(str(e))
        raise ChipMismatch("no magnetometer found: neither an HMC5883L at 0x1E nor a QMC5883L at "
                           f"0x0D ({'; '.join(why)}): check the wiring, or run 'imucald probe'")
    else:
        raise ValueError(f"magnetometer {which!r}: allowed {', '.join(MAG_CHIPS)}")
    m.identify()
    return m


def mag_name(m) -> str:
    return "qmc5883l" if isinstance(m, QMC5883L) else "hmc5883l"


def mag_setup(m, rate_hz: float) -> None:
    if isinstance(m, QMC5883L):
        m.setup(range_gauss=2.0, rate_hz=rate_hz)
    else:
        m.setup(rate_hz=rate_hz)
