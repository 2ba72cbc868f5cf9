"""The bus layer: a thin shell over an smbus2.SMBus (or its emulator).

* OS errors stop here: errno values become a few imucald exceptions whose
  messages say what to check (errno meanings from smbus2's troubleshooting doc
  and the Linux i2c-dev interface: 121 EREMOTEIO = no acknowledge, 5 EIO = bus
  error, 110 ETIMEDOUT, 16 EBUSY = a kernel driver owns the address).
* Transient errors (no acknowledge, EIO, timeout) are retried with exponential
  backoff, a bounded number of times.
* Every transaction and byte is counted, wire overhead included, so that the
  cost per delivered sample can be measured.

The bus is *passed in* (``Bus(smbus2.SMBus(1))``); drivers never open it.
"""
from __future__ import annotations

import errno
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

from ..errors import DeviceUnavailable, UserError

__all__ = ["BusError", "NoAcknowledge", "BusIOError", "BusTimeout", "AddressBusy",
           "ChipMismatch", "BusUnavailable", "Bus", "Clock", "RealClock", "VirtualClock", "ScaledClock",
           "open_bus", "kernel_driver_for", "BLOCK_MAX"]

#: smbus2's I2C_SMBUS_BLOCK_MAX: read_i2c_block_data takes at most 32 bytes
BLOCK_MAX = 32


class BusError(Exception):
    """A failed I2C transaction (after retries)."""

    def __init__(self, msg: str, addr: Optional[int] = None, err: Optional[int] = None):
        super().__init__(msg)
        self.addr = addr
        self.errno = err


class NoAcknowledge(BusError):
    """Nothing acknowledged the address (errno 121 EREMOTEIO / 6 ENXIO)."""


class BusIOError(BusError):
    """A bus-level I/O error (errno 5 EIO): a glitch, a loose wire, motor noise."""


class BusTimeout(BusError):
    """The transaction timed out (errno 110): the bus is stuck or clock-stretched."""


class AddressBusy(BusError, UserError):
    """A kernel driver owns the address (errno 16 EBUSY)."""


class ChipMismatch(UserError):
    """The address answered, but with another chip's identity."""


class BusUnavailable(DeviceUnavailable):
    """/dev/i2c-N cannot be opened (exit 69)."""


_TRANSIENT = (NoAcknowledge, BusIOError, BusTimeout)


class Clock:
    """Time source for drivers and emulators: ``now()`` in s, ``sleep(s)``."""

    def now(self) -> float:
        raise NotImplementedError

    def sleep(self, s: float) -> None:
        raise NotImplementedError


class RealClock(Clock):
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, s: float) -> None:
        if s > 0:
            time.sleep(s)


class VirtualClock(Clock):
    """Simulated time: ``sleep`` advances it instantly (tests, benchmarks, replay)."""

    def __init__(self, t0: float = 0.0):
        self.t = float(t0)

    def now(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        if s > 0:
            self.t += s

    def advance(self, s: float) -> None:
        self.t += s


class ScaledClock(Clock):
    """Wall-clock time running ``speed`` times faster (emulated demos and tests)."""

    def __init__(self, speed: float = 1.0):
        self.speed = float(speed)
        self._m0 = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._m0) * self.speed

    def sleep(self, s: float) -> None:
        if s > 0:
            time.sleep(s / self.speed)


@dataclass
class BusStats:
    transactions: int = 0
    bytes_read: int = 0           #: payload bytes read
    bytes_written: int = 0        #: payload bytes written (register pointers included)
    wire_bytes: int = 0           #: everything on the wire: addresses, pointers, data
    retries: int = 0
    errors: Dict[str, int] = field(default_factory=dict)
    per_addr: Dict[int, int] = field(default_factory=dict)   #: transactions per address

    def as_dict(self) -> Dict[str, object]:
        return {"transactions": self.transactions, "bytes_read": self.bytes_read,
                "bytes_written": self.bytes_written, "wire_bytes": self.wire_bytes,
                "retries": self.retries, "errors": dict(self.errors),
                "per_addr": {f"0x{a:02X}": n for a, n in self.per_addr.items()}}


def _classify(e: OSError, addr: int, bus_name: str) -> BusError:
    en = e.errno
    a = f"0x{addr:02X}"
    if en in (errno.EREMOTEIO, errno.ENXIO):
        return NoAcknowledge(f"no acknowledge from {a} on {bus_name} (errno {en}): check wiring/address "
                             f"(power, SDA/SCL, the AD0 strap: 0x68 or 0x69; 'imucald probe' lists what "
                             f"answers); on a motor robot, bus noise", addr, en)
    if en == errno.EIO:
        return BusIOError(f"I/O error talking to {a} on {bus_name} (errno 5): loose wire, "
                          f"missing pull-ups or electrical noise", addr, en)
    if en == errno.ETIMEDOUT:
        return BusTimeout(f"timeout talking to {a} on {bus_name} (errno 110): the bus is stuck "
                          f"or the clock too fast (use i2c_arm_baudrate=400000 or less)", addr, en)
    if en == errno.EBUSY:
        return AddressBusy(f"{bus_name}: address {a} is busy (errno 16): a kernel driver owns it; "
                           f"{kernel_driver_hint(bus_name, addr)}", addr, en)
    return BusError(f"{bus_name}: error talking to {a}: {os.strerror(en) if en else e}", addr, en)


def kernel_driver_for(bus_num: Optional[int], addr: int, sysfs: str = "/sys/bus/i2c/devices"
                      ) -> Optional[str]:
    """Name of the kernel driver bound to bus_num-00addr, from sysfs, or None."""
    if bus_num is None:
        return None
    link = os.path.join(sysfs, f"{bus_num}-{addr:04x}", "driver")
    try:
        return os.path.basename(os.readlink(link))
    except OSError:
        return None


_OVERLAY_HINT = {
    "inv-mpu6050-i2c": "remove 'dtoverlay=i2c-sensor,mpu6050' (or mpu9250) from /boot/firmware/config.txt",
    "rtc-ds1307": "an RTC overlay (i2c-rtc,ds1307/ds3231) shares 0x68: strap the IMU's AD0 high to use 0x69",
    "adxl34x": "remove 'dtoverlay=i2c-sensor,adxl345' from /boot/firmware/config.txt",
}


def kernel_driver_hint(bus_name: str, addr: int, sysfs: str = "/sys/bus/i2c/devices") -> str:
    num = None
    if bus_name.startswith("/dev/i2c-"):
        try:
            num = int(bus_name.rsplit("-", 1)[1])
        except ValueError:
            num = None
    drv = kernel_driver_for(num, addr, sysfs)
    if drv is None:
        return "find it with 'i2cdetect -y N' (shows UU) and unbind it or move the sensor"
    hint = _OVERLAY_HINT.get(drv, f"unbind it: echo {num}-{addr:04x} > "
                                  f"/sys/bus/i2c/drivers/{drv}/unbind")
    return f"driver '{drv}' is bound; {hint}"


class Bus:
    """Counting, retrying, error-translating access to one I2C bus.

    ``smbus`` is an smbus2.SMBus or anything with the same subset
    (read_byte_data, write_byte_data, read_i2c_block_data, i2c_rdwr).
    One Bus per physical bus, shared by all drivers on it; a lock serialises
    transactions (smbus2 best practice).
    """

    def __init__(self, smbus, name: str = "i2c", retries: int = 3, backoff_s: float = 0.001,
                 clock: Optional[Clock] = None):
        self.smbus = smbus
        self.name = name
        self.retries = retries
        self.backoff_s = backoff_s
        self.clock = clock or RealClock()
        self.stats = BusStats()
        self._lock = threading.Lock()
        self._has_rdwr = hasattr(smbus, "i2c_rdwr")

    # -- core ------------------------------------------------------------------------
    def _do(self, addr: int, fn: Callable, wire: int, nread: int, nwrite: int):
        attempt = 0
        while True:
            try:
                with self._lock:
                    out = fn()
                st = self.stats
                st.transactions += 1
                st.wire_bytes += wire
                st.bytes_read += nread
                st.bytes_written += nwrite
                st.per_addr[addr] = st.per_addr.get(addr, 0) + 1
                return out
            except OSError as e:
                err = _classify(e, addr, self.name)
                key = type(err).__name__
                self.stats.errors[key] = self.stats.errors.get(key, 0) + 1
                if not isinstance(err, _TRANSIENT) or attempt >= self.retries:
                    raise err from None
                self.stats.retries += 1
                self.clock.sleep(self.backoff_s * (2 ** attempt))
                attempt += 1

    # -- transactions ----------------------------------------------------------------
    def read_byte(self, addr: int, reg: int) -> int:
        """One register.  Wire: addr+W, reg, addr+R, data = 4 bytes."""
        return self._do(addr, lambda: self.smbus.read_byte_data(addr, reg), 4, 1, 1)

    def write_byte(self, addr: int, reg: int, value: int) -> None:
        """Wire: addr+W, reg, value = 3 bytes."""
        self._do(addr, lambda: self.smbus.write_byte_data(addr, reg, value & 0xFF), 3, 0, 2)

    def write_verified(self, addr: int, cfg: Dict[int, int], chip: str) -> None:
        """Write each register of ``cfg`` (address -> value), then read every one back:
        a chip that did not take its configuration is a ChipMismatch, not silent zeros."""
        for reg, val in cfg.items():
            self.write_byte(addr, reg, val)
        for reg, val in cfg.items():
            got = self.read_byte(addr, reg)
            if got != val:
                raise ChipMismatch(f"0x{addr:02X}: {chip} register 0x{reg:02X} reads back 0x{got:02X} "
                                   f"after writing 0x{val:02X}: the chip did not take its configuration")

    def read_block(self, addr: int, reg: int, n: int, fifo: bool = False) -> bytes:
        """n bytes starting at register ``reg``, in one transaction when possible
        (i2c_rdwr), else in <= 32-byte smbus block reads.  ``fifo``: the register is
        a FIFO port whose address does not advance (MPU FIFO_R_W)."""
        if n <= BLOCK_MAX or not self._has_rdwr:
            out = bytearray()
            r = reg
            while len(out) < n:
                k = min(BLOCK_MAX, n - len(out))
                out += bytes(self._do(addr, lambda r=r, k=k: self.smbus.read_i2c_block_data(addr, r, k),
                                      3 + k, k, 1))
                if not fifo:
                    r += k
            return bytes(out)
        from smbus2 import i2c_msg

        def xfer():
            w = i2c_msg.write(addr, [reg])
            rd = i2c_msg.read(addr, n)
            self.smbus.i2c_rdwr(w, rd)
            return bytes(list(rd))
        return self._do(addr, xfer, 3 + n, n, 1)


def open_bus(num: int, clock: Optional[Clock] = None, dev_dir: str = "/dev") -> Bus:
    """Open /dev/i2c-N with smbus2 and wrap it; errors say what to do."""
    path = os.path.join(dev_dir, f"i2c-{num}")
    if not os.path.exists(path):
        raise BusUnavailable(f"{path} does not exist: enable I2C (raspi-config -> Interface "
                             f"Options -> I2C, or dtparam=i2c_arm=on) or pick another --bus")
    try:
        from smbus2 import SMBus
        sm = SMBus(num)
    except PermissionError:
        raise BusUnavailable(f"{path}: permission denied: add the user to the 'i2c' group "
                             f"(sudo adduser $USER i2c) and log in again") from None
    except OSError as e:
        raise BusUnavailable(f"{path}: cannot open: {e.strerror}") from None
    return Bus(sm, name=path, clock=clock)


def real_bus_numbers(dev_dir: str = "/dev") -> List[int]:
    """I2C bus numbers present on this machine, ascending."""
    out = []
    try:
        for n in os.listdir(dev_dir):
            if n.startswith("i2c-") and n[4:].isdigit():
                out.append(int(n[4:]))
    except OSError:
        pass
    return sorted(out)
