"""Opening a board: the one factory behind ``probe``, ``record`` and ``run``.

The real I2C bus is used whenever one exists, unless the emulator is asked for
(or there is no bus and emulation is allowed).  The daemon never builds a board
itself: it receives the one built here, so the production path imports neither
the emulator nor the simulator.
"""
from __future__ import annotations

from typing import Any, Dict, Optional, Tuple

from ..errors import DeviceUnavailable, UserError

#: boards the emulator can build ("9dof-qmc": a 9DOF board whose magnetometer is a QMC5883L
#: clone; "gy273": a magnetometer alone)
EMULATED_BOARDS = ("mpu6050", "mpu6500", "mpu9250", "9dof", "gy273", "9dof-qmc")


def emulated_bus(board: str, speed: Optional[float] = None, seed: int = 0, poses: int = 30,
                 faults=None, tour: Optional[Dict[str, Any]] = None, mag: Optional[str] = None,
                 addrs: Optional[Dict[str, int]] = None):
    """A :class:`Bus` over the emulated chips of ``board``, moved through ``poses`` random
    orientations (looped) by a tour drawn from ``seed``; ``tour`` overrides its hold/move times;
    ``mag`` picks the magnetometer of a 9dof or gy273 board (None: the board's usual one).

    Its clock is virtual time (``speed`` None: reads never wait) or wall-clock time ``speed``
    times faster.  The clock starts at zero here, after the imports, so that the tour and
    its warm-up begin when the board does."""
    import numpy as np

    from ..drivers.bus import Bus, ScaledClock, VirtualClock
    from ..sim.emulators import emulated_board
    from ..sim.motion import PoseTour
    from ..sim.orientations import random_pose_set
    clock = VirtualClock() if speed is None else ScaledClock(speed)
    rng = np.random.default_rng(seed)
    motion = PoseTour(random_pose_set(poses, rng), rng=rng, loop=True, **(tour or {}))
    eb = emulated_board(board, motion, rng=rng, clock=clock, faults=faults, mag=mag, addrs=addrs)
    return Bus(eb, name=f"emulated {board}", clock=clock)


#: the emulated board's tour under `imucald run` (and `make run`): hand-held, short holds;
#: the tremor comes from --tremor-dps
RUN_TOUR = dict(hold_s=(1.5, 4.0), move_s=(1.2, 1.8), lead_s=1.0)


def real_bus_number(emulate: str, bus: Optional[int]) -> Optional[int]:
    """The /dev/i2c-N number to open, or None to emulate.  ``emulate``: yes, no or auto
    (auto emulates only when no bus is given and none exists)."""
    from ..drivers.bus import real_bus_numbers
    nums = real_bus_numbers()
    if emulate == "yes" or (emulate == "auto" and bus is None and not nums):
        return None
    if bus is None and not nums:
        raise DeviceUnavailable("sensor.emulate is 'no' but there is no I2C bus (/dev/i2c-* absent): "
                        "enable I2C or set sensor.emulate: auto")
    return bus if bus is not None else (1 if 1 in nums else nums[0])


def open_board(board: str, rate_hz: float, emulate: str = "auto", bus: Optional[int] = None,
               speed: Optional[float] = None, seed: int = 0, poses: int = 30, faults=None,
               tour: Optional[Dict[str, Any]] = None, mag: str = "auto",
               **driver_kw) -> Tuple[Any, Any, str]:
    """(board, bus, description) for ``board`` at ``rate_hz``: on /dev/i2c-``bus`` (or the
    first bus present), or emulated (see :func:`emulated_bus` for ``speed``) when
    :func:`real_bus_number` says so.  ``mag`` (auto, hmc5883l, qmc5883l) picks the magnetometer
    of a 9dof or gy273 board; ``driver_kw`` goes to the driver (address, ranges)."""
    from ..drivers.board import make_board
    from ..drivers.bus import open_bus
    num = real_bus_number(emulate, bus)
    if num is None:
        addrs = {"mpu": driver_kw["addr"]} if "addr" in driver_kw else None     # sensor.address
        b = emulated_bus(board, speed, seed, poses, faults, tour, None if mag == "auto" else mag, addrs)
        desc = (f"emulated {board} ({'no I2C bus found' if emulate == 'auto' else 'no hardware'}), "
                f"moved through {poses} orientations"
                + (f" at {speed:g}x speed" if speed not in (None, 1.0) else ""))
    else:
        if faults is not None:
            raise UserError("--fault applies only to the emulated board (--emulate)")
        b = open_bus(num)
        desc = f"{board} on /dev/i2c-{num}"
    if board in ("9dof", "gy273"):
        driver_kw["mag"] = mag
    return make_board(board, b, rate_hz=rate_hz, **driver_kw), b, desc
