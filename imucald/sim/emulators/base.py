"""The emulated bus and the chip base class: register file from the driver's map,
sample generation at the output rate, and injected faults.

Faults (:class:`Faults`): no-acknowledge probability, a stuck bus for a time
window, device resets at given times, a wrong chip ID, a disconnected device,
and an address owned by a kernel driver (EBUSY).
"""
from __future__ import annotations

import ctypes
import errno
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Set, Tuple

import numpy as np

from ...numerics.rng import RngLike, as_rng

from ...drivers.bus import BLOCK_MAX, Clock, VirtualClock
from ...drivers.regmap import RegisterMap
from ..sensor import Truth

__all__ = ["Faults", "EmuDevice", "EmulatedBus", "RngLike", "i16"]



def _oserror(code: int) -> OSError:
    import os
    return OSError(code, os.strerror(code))


@dataclass
class Faults:
    """Faults to inject.  Times are on the emulator's clock, in s."""

    nack_prob: float = 0.0                                    #: per transaction
    stuck: List[Tuple[float, float]] = field(default_factory=list)   #: bus stuck in [t0, t1)
    resets: Dict[int, List[float]] = field(default_factory=dict)     #: addr -> reset times
    wrong_id: Dict[int, int] = field(default_factory=dict)           #: addr -> ID register value
    disconnected: Dict[int, Tuple[float, float]] = field(default_factory=dict)  #: addr -> window
    busy: Set[int] = field(default_factory=set)                      #: owned by a kernel driver


class EmuDevice:
    """A chip at one address: register file + sample generation."""

    regmap: RegisterMap
    fifo_ports: Tuple[int, ...] = ()

    def __init__(self, addr: int, clock: Clock, motion, truth: Truth, rng: np.random.Generator):
        self.addr, self.clock, self.truth, self.rng = addr, clock, truth, rng
        self.motion = GridMotion(motion, self) if motion is not None else None
        self.id_override: Optional[int] = None
        self.power_on_reset()

    # -- register file ---------------------------------------------------------------
    def power_on_reset(self) -> None:
        self.regs = self.regmap.power_on()
        self.t_next: Optional[float] = None
        self.on_reset()

    def on_reset(self) -> None:
        pass

    def reachable(self) -> bool:
        return True

    def read(self, reg: int, n: int) -> bytes:
        self.sync(self.clock.now())
        out = bytearray()
        r = reg
        for _ in range(n):
            out.append(self.read_reg(r) & 0xFF)
            if r not in self.fifo_ports:
                r = (r + 1) & 0xFF
        self.after_read(reg, n)
        return bytes(out)

    def write(self, reg: int, data: Sequence[int]) -> None:
        self.sync(self.clock.now())
        r = reg
        for v in data:
            self.write_reg(r, int(v) & 0xFF)
            r = (r + 1) & 0xFF

    def read_reg(self, r: int) -> int:
        return self.regs[r]

    def write_reg(self, r: int, v: int) -> None:
        reg = self.regmap.at(r)
        if reg is not None and not reg.read_only:
            self.regs[r] = v

    def after_read(self, reg: int, n: int) -> None:
        pass

    # -- sampling --------------------------------------------------------------------
    def running(self) -> bool:
        return False

    def odr_hz(self) -> float:
        return 100.0

    def sync(self, now: float, cap: int = 2048) -> None:
        """Generate every sample due at or before ``now`` (at most ``cap`` of them)."""
        if not self.running():
            self.t_next = None
            return
        dt = 1.0 / self.odr_hz()
        if self.t_next is None:
            self.t_next = now + self.startup_s()
            return
        if now < self.t_next:
            return
        n = int(np.floor((now - self.t_next) / dt)) + 1
        skipped = max(0, n - cap)
        t = self.t_next + (np.arange(skipped, n)) * dt
        self.t_next += n * dt
        self.emit(t, skipped)

    def startup_s(self) -> float:
        return 0.0

    def emit(self, t: np.ndarray, skipped: int) -> None:
        raise NotImplementedError

    def _noise(self, density: float, bw_hz: float, shape) -> np.ndarray:
        return self.rng.normal(scale=density * np.sqrt(bw_hz), size=shape)


class GridMotion:
    """The motion (``PoseTour``) as one chip sees it: evaluated on the chip's sample grid
    a block of :attr:`BLOCK` samples at a time and served from that block.

    Why: a chip without a FIFO (the 9DOF board's ITG-3200, the magnetometers) is polled
    once per sample period, so the emulated chips asked the motion for one or two
    samples per I2C transaction, each call paying numpy's per-call overhead on (1, 3)
    arrays (~90 us): that was most of ``record --board 9dof --emulate``'s time (300 s
    of data took 27.6 s on a loaded 2-core machine).  The motion is a deterministic
    function of time, so a block evaluated ahead gives the same values (to the grid
    time's rounding: < 1e-8 s here) in one vectorised call."""

    BLOCK = 512
    _TOL = 1e-6                     # of a sample period: a request on the grid

    def __init__(self, motion, dev: "EmuDevice"):
        self.motion, self.dev = motion, dev
        self._t0 = self._dt = None
        self._m: Optional[Dict[str, np.ndarray]] = None

    def __getattr__(self, name):    # everything else of the motion (holds, duration_s, ...)
        return getattr(self.motion, name)

    def _hit(self, t: np.ndarray, dt: float):
        if self._m is None or self._dt != dt:
            return None
        j = (t - self._t0) / dt
        k = np.rint(j)
        if k[0] < 0 or k[-1] >= self.BLOCK or np.abs(j - k).max() > self._TOL:
            return None
        return _Rows(self._m, k.astype(np.intp))

    def sample(self, t) -> Dict[str, np.ndarray]:
        t = np.atleast_1d(np.asarray(t, float))
        if len(t) == 0 or len(t) > 16:
            return self.motion.sample(t)
        dt = 1.0 / self.dev.odr_hz()
        m = self._hit(t, dt)
        if m is None:
            self._t0, self._dt = float(t[0]), dt
            self._m = self.motion.sample(self._t0 + dt * np.arange(self.BLOCK))
            m = self._hit(t, dt)
        return m if m is not None else self.motion.sample(t)


class _Rows:
    """Rows ``idx`` of a block of motion arrays, sliced when a key is read (a chip reads
    two or three of the six)."""

    __slots__ = ("_m", "_i")

    def __init__(self, m, idx):
        self._m, self._i = m, idx

    def __getitem__(self, key):
        return self._m[key][self._i]

    def keys(self):
        return self._m.keys()


def i16(x: np.ndarray, lo: int = -32768, hi: int = 32767) -> np.ndarray:
    return np.clip(np.round(x), lo, hi).astype(np.int64)


class EmulatedBus:
    """The smbus2 subset the drivers use, backed by emulated chips and a clock."""

    def __init__(self, clock: Optional[Clock] = None, faults: Optional[Faults] = None,
                 rng: RngLike = None):
        self.clock = clock or VirtualClock()
        self.faults = faults or Faults()
        self.rng = as_rng(rng)
        self.devices: Dict[int, EmuDevice] = {}
        self.transactions = 0
        self._done_resets: Set[Tuple[int, float]] = set()

    def add(self, dev: EmuDevice) -> EmuDevice:
        if dev.addr in self.faults.wrong_id:
            dev.id_override = self.faults.wrong_id[dev.addr]
        self.devices[dev.addr] = dev
        return dev

    def _dev(self, addr: int) -> EmuDevice:
        now = self.clock.now()
        f = self.faults
        self.transactions += 1
        if addr in f.busy:
            raise _oserror(errno.EBUSY)
        for t0, t1 in f.stuck:
            if t0 <= now < t1:
                raise _oserror(errno.ETIMEDOUT)
        w = f.disconnected.get(addr)
        if w is not None and w[0] <= now < w[1]:
            raise _oserror(errno.EREMOTEIO)
        dev = self.devices.get(addr)
        if dev is None or not dev.reachable():
            raise _oserror(errno.EREMOTEIO)
        for tr in f.resets.get(addr, []):
            if tr <= now and (addr, tr) not in self._done_resets:
                self._done_resets.add((addr, tr))
                dev.power_on_reset()
        if f.nack_prob and self.rng.random() < f.nack_prob:
            raise _oserror(errno.EREMOTEIO)
        return dev

    # smbus2 API subset ---------------------------------------------------------------
    def read_byte_data(self, addr: int, reg: int) -> int:
        return self._dev(addr).read(reg, 1)[0]

    def write_byte_data(self, addr: int, reg: int, value: int) -> None:
        self._dev(addr).write(reg, [value])

    def read_i2c_block_data(self, addr: int, reg: int, length: int) -> List[int]:
        if length > BLOCK_MAX:
            raise ValueError("Desired block length over %d bytes" % BLOCK_MAX)  # as smbus2
        return list(self._dev(addr).read(reg, length))

    def write_i2c_block_data(self, addr: int, reg: int, data: Sequence[int]) -> None:
        if len(data) > BLOCK_MAX:
            raise ValueError("Data length cannot exceed %d bytes" % BLOCK_MAX)
        self._dev(addr).write(reg, data)

    def i2c_rdwr(self, *msgs) -> None:
        """Combined transactions with smbus2.i2c_msg objects: [write reg] + read n."""
        reg = None
        for m in msgs:
            if m.flags & 0x0001:                      # I2C_M_RD
                if reg is None:
                    raise _oserror(errno.EINVAL)
                data = self._dev(m.addr).read(reg, m.len)
                ctypes.memmove(m.buf, bytes(data), m.len)
            else:
                b = bytes(list(m))
                dev = self._dev(m.addr)
                reg = b[0]
                if len(b) > 1:
                    dev.write(reg, b[1:])

    def close(self) -> None:
        pass
