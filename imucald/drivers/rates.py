"""Which sample rates each board can run at: checked before a bus is opened (numpy-free).

* MPU-6050/6500/9250: SMPLRT_DIV is 8 bits over the 1 kHz internal rate when the
  DLPF is on (register map RM-MPU-6000A section 4.2): 1000/256 = 3.91 .. 1000 Hz,
  rounded to 1000/n.
* 9DOF: the ADXL345's BW_RATE codes give 3200/2^k Hz only (datasheet Rev E,
  Table 7); the ITG-3200 follows (8 kHz/n or 1 kHz/n, PS-ITG-3200A section 8.2),
  which rules out 3200 Hz (8000/3200 is not whole).
* GY-273: the magnetometer runs at its fastest output rate at or below the one asked
  for (HMC5883L 75 Hz at most, QMC5883L 10/50/100/200 Hz), so any rate is taken.

And how long the daemon may wait between drains (``sensor.batch_s``): the MPU boards
buffer samples in their FIFO (1024 bytes on the MPU-6050, 512 on the MPU-6500/9250;
Linux inv_mpu_iio.h hw_info) in frames of 14 bytes; a drain later than the FIFO holds
loses samples at every drain.  The 9DOF and GY-273 boards are polled once per sample.
"""
from __future__ import annotations

import math
from typing import Optional

__all__ = ["ADXL345_RATES_HZ", "rate_problem", "batch_limit_s", "batch_problem", "MPU_FIFO_BYTES",
           "MPU_FRAME_BYTES", "DRAIN_SLACK_S"]

#: ADXL345 BW_RATE output data rates, Hz (Table 7: code k -> 0.09765625 * 2**k)
ADXL345_RATES_HZ = tuple(0.09765625 * 2 ** k for k in range(16))
#: the 9DOF board's rates: ADXL345 rates the ITG-3200 can also sample at
NINEDOF_RATES_HZ = tuple(r for r in ADXL345_RATES_HZ if 6.25 <= r <= 1600)
MPU_MIN_HZ, MPU_MAX_HZ = 1000.0 / 256, 1000.0
#: FIFO bytes per MPU chip (Linux drivers/iio/imu/inv_mpu6050/inv_mpu_core.c hw_info)
MPU_FIFO_BYTES = {"mpu6050": 1024, "mpu6500": 512, "mpu9250": 512, "mpu9255": 512}
#: bytes per FIFO frame: accelerometer, temperature, gyro, 2 bytes each per axis
MPU_FRAME_BYTES = 14
#: a drain may come this much later than ``batch_s`` (a scheduler time slice on a busy
#: board) and still find room in the FIFO
DRAIN_SLACK_S = 0.010


def _fmt(r: float) -> str:
    return f"{r:g}"


def rate_problem(board: str, rate_hz: float) -> Optional[str]:
    """Why ``board`` cannot sample at ``rate_hz`` (a phrase naming what it can), or None."""
    if not isinstance(rate_hz, (int, float)) or not math.isfinite(rate_hz) or rate_hz <= 0:
        return f"{rate_hz!r} is not a positive number of samples per second"
    if board in ("mpu6050", "mpu6500", "mpu9250"):
        if not MPU_MIN_HZ - 1e-9 <= rate_hz <= MPU_MAX_HZ + 1e-9:
            return (f"{rate_hz:g} Hz is beyond the {board.upper()}'s {MPU_MIN_HZ:.2f}..{MPU_MAX_HZ:g} Hz "
                    f"(1 kHz / 1..256)")
        return None
    if board in ("9dof", "9dof-qmc"):
        if any(abs(rate_hz - r) <= 1e-6 * r for r in NINEDOF_RATES_HZ):
            return None
        lo = max([r for r in NINEDOF_RATES_HZ if r < rate_hz] or [NINEDOF_RATES_HZ[0]])
        hi = min([r for r in NINEDOF_RATES_HZ if r > rate_hz] or [NINEDOF_RATES_HZ[-1]])
        near = _fmt(lo) if lo == hi else f"{_fmt(lo)} or {_fmt(hi)}"
        return (f"{rate_hz:g} Hz is not a rate of the 9dof board's ADXL345; allowed "
                f"{', '.join(map(_fmt, NINEDOF_RATES_HZ))} Hz (nearest: {near})")
    return None


def batch_limit_s(board: str, rate_hz: float) -> float:
    """Longest ``sensor.batch_s`` for ``board`` at ``rate_hz``: what its FIFO holds, less
    :data:`DRAIN_SLACK_S` (infinite for the polled boards)."""
    if board not in MPU_FIFO_BYTES:
        return math.inf
    return (MPU_FIFO_BYTES[board] // MPU_FRAME_BYTES) / float(rate_hz) - DRAIN_SLACK_S


def batch_problem(board: str, rate_hz: float, batch_s: float) -> Optional[str]:
    """Why draining ``board`` every ``batch_s`` at ``rate_hz`` loses samples, or None."""
    lim = batch_limit_s(board, rate_hz)
    if batch_s <= lim:
        return None
    frames = MPU_FIFO_BYTES[board] // MPU_FRAME_BYTES
    return (f"{batch_s:g} s between drains at {rate_hz:g} Hz is {batch_s * rate_hz:.0f} samples, beyond what the "
            f"{board.upper()}'s FIFO holds ({frames} samples = {frames / rate_hz * 1000:.0f} ms, less "
            f"{DRAIN_SLACK_S * 1000:.0f} ms for a late drain): samples would be lost at every drain; "
            f"allowed up to {lim:.3g} s at this rate")
