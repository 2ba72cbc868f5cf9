"""Register-accurate emulated chips behind the subset of the smbus2 API the drivers use.

Each emulated chip keeps a 256-byte register file initialised from the *same*
register map its driver uses (power-on values included), and generates samples
at its configured output rate from a continuous-time motion source
(:class:`imucald.sim.motion.PoseTour`) through the simulator's error model
(:mod:`imucald.sim.sensor`): so a whole calibration session can run end to end
with no hardware.

Modelled: power-on state and sleep/standby (zeros until woken), device reset,
FIFO fill at the output rate with overflow (oldest bytes dropped, status bit
set), data-ready, quantisation and saturation, die temperature, the AK8963
bypass gate and data lock, the HMC5883L X/Z/Y order, -4096 overflow and
one-sample gain latency, and the QMC5883L.

Faults (:class:`Faults`): no-acknowledge probability, a stuck bus for a time
window, device resets at given times, a wrong chip ID, a disconnected device,
and an address owned by a kernel driver (EBUSY).
"""
from __future__ import annotations

from typing import Dict, Optional

from ...numerics.rng import as_rng
from ...drivers import ak8963 as _ak, hmc5883l as _hmc
from ...drivers.bus import Clock, VirtualClock
from ..sensor import Truth, draw_truth
from .base import EmulatedBus, Faults, RngLike
from .invensense import EmuAK8963, EmuMPU6xxx
from .nine_dof import EmuADXL345, EmuHMC5883L, EmuITG3200
from .qmc5883l import EmuQMC5883L

__all__ = ["Faults", "EmulatedBus", "EmuMPU6xxx", "EmuAK8963", "EmuADXL345", "EmuITG3200",
           "EmuHMC5883L", "EmuQMC5883L", "emulated_board"]


def emulated_board(board: str, motion, rng: RngLike = None, clock: Optional[Clock] = None,
                   faults: Optional[Faults] = None, truth: Optional[Truth] = None,
                   addrs: Optional[Dict[str, int]] = None, mag: Optional[str] = None,
                   trim: Optional[Dict[str, bytes]] = None) -> EmulatedBus:
    """An EmulatedBus holding the chips of ``board``: mpu6050, mpu6500, mpu9250, 9dof
    (ADXL345 + ITG3200 + a magnetometer), gy273 (a magnetometer alone).  ``mag``
    picks the magnetometer of 9dof and gy273 boards: hmc5883l (9dof default) or
    qmc5883l (gy273 default; ``9dof-qmc`` is the 9dof board with it).  ``trim``: the
    MPU's factory trim (see :class:`EmuMPU6xxx`) and, under "asa", the AK8963's fuse ROM;
    drawn when None, so another seed is another physical sensor."""
    rng = as_rng(rng)
    clock = clock or VirtualClock()
    bus = EmulatedBus(clock, faults, rng)
    if board == "9dof-qmc":
        board, mag = "9dof", "qmc5883l"
    if mag is None:
        mag = "qmc5883l" if board == "gy273" else "hmc5883l"
    if mag not in ("hmc5883l", "qmc5883l"):
        raise ValueError(f"unknown emulated magnetometer {mag!r}: allowed hmc5883l, qmc5883l")
    tb = {"mpu6500": "mpu9250", "gy273": "9dof"}.get(board, board)
    if tb == "9dof" and mag == "qmc5883l":
        tb = "9dof-qmc"
    truth = truth or draw_truth(tb, rng)
    a = addrs or {}
    if board in ("mpu6050", "mpu6500", "mpu9250"):
        t = dict(trim or {})
        asa = t.pop("asa", None)
        mpu = bus.add(EmuMPU6xxx(a.get("mpu", 0x68), clock, motion, truth, rng, board, trim=t or None))
        if board == "mpu9250":
            bus.add(EmuAK8963(_ak.ADDR, clock, motion, truth, rng, host=mpu, asa=asa))
    elif board in ("9dof", "gy273"):
        if board == "9dof":
            bus.add(EmuADXL345(a.get("accel", 0x53), clock, motion, truth, rng))
            bus.add(EmuITG3200(a.get("gyro", 0x68), clock, motion, truth, rng))
        if mag == "hmc5883l":
            bus.add(EmuHMC5883L(_hmc.ADDR, clock, motion, truth, rng))
        else:
            bus.add(EmuQMC5883L(a.get("mag", 0x0D), clock, motion, truth, rng))
    else:
        raise ValueError(f"unknown emulated board {board!r}: allowed mpu6050, mpu6500, mpu9250, "
                         f"9dof, 9dof-qmc, gy273")
    bus.truth = truth
    return bus
