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
one-sample gain latency.  The QMC5883L is in emu_qmc5883l.py.

Faults (:class:`Faults`): no-acknowledge probability, a stuck bus for a time
window, device resets at given times, a wrong chip ID, a disconnected device,
and an address owned by a kernel driver (EBUSY).
"""
from __future__ import annotations

import ctypes
import errno
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Set, Tuple, Union

import numpy as np

from ..sim.sensor import Truth, draw_truth
from ..sim.specs import ACCEL, GYRO, MAG
from . import adxl345 as _adxl, ak8963 as _ak, hmc5883l as _hmc, itg3200 as _itg, mpu6050 as _mpu
from .bus import BLOCK_MAX, Clock, VirtualClock
from .regmap import RegisterMap

__all__ = ["Faults", "EmulatedBus", "EmuMPU6xxx", "EmuAK8963", "EmuADXL345", "EmuITG3200",
           "EmuHMC5883L", "emulated_board"]

RngLike = Union[int, None, np.random.Generator]


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
        self.addr, self.clock, self.motion, self.truth, self.rng = addr, clock, motion, truth, rng
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


def _i16(x: np.ndarray, lo: int = -32768, hi: int = 32767) -> np.ndarray:
    return np.clip(np.round(x), lo, hi).astype(np.int64)


class EmuMPU6xxx(EmuDevice):
    """MPU-6050 (WHO_AM_I 0x68) or MPU-6500/9250 (0x70/0x71) accel + gyro + temperature."""

    regmap = _mpu.REGMAP
    fifo_ports = (_mpu.REGMAP.FIFO_R_W.addr,)

    def __init__(self, addr, clock, motion, truth, rng, variant: str = "mpu6050"):
        self.variant = variant
        self.who = {"mpu6050": 0x68, "mpu6500": 0x70, "mpu9250": 0x71}[variant]
        self.spec_a = ACCEL["mpu6050" if variant == "mpu6050" else "mpu9250"]
        self.spec_g = GYRO["mpu6050" if variant == "mpu6050" else "mpu9250"]
        self.fifo_size = _mpu.FIFO_SIZE[variant]
        super().__init__(addr, clock, motion, truth, rng)

    def on_reset(self):
        self.fifo = bytearray()
        self.latest = bytes(14)
        self.overflows = 0
        self.samples = 0

    def read_reg(self, r):
        R = self.regmap
        if r == R.WHO_AM_I.addr:
            return self.who if self.id_override is None else self.id_override
        if R.ACCEL_XOUT_H.addr <= r < R.ACCEL_XOUT_H.addr + 14:
            return self.latest[r - R.ACCEL_XOUT_H.addr]
        if r == R.FIFO_COUNTH.addr:
            return len(self.fifo) >> 8
        if r == R.FIFO_COUNTH.addr + 1:
            return len(self.fifo) & 0xFF
        if r == R.FIFO_R_W.addr:
            if not self.fifo:
                return 0xFF
            b = self.fifo[0]
            del self.fifo[0]
            return b
        return self.regs[r]

    def read(self, reg, n):
        R = self.regmap
        if reg == R.FIFO_R_W.addr:          # bulk pop, same semantics as byte-by-byte
            self.sync(self.clock.now())
            k = min(n, len(self.fifo))
            out = bytes(self.fifo[:k]) + b"\xff" * (n - k)
            del self.fifo[:k]
            return out
        return super().read(reg, n)

    def after_read(self, reg, n):
        R = self.regmap
        if reg <= R.INT_STATUS.addr < reg + n:
            self.regs[R.INT_STATUS.addr] = 0            # read clears (D 4.17)

    def write_reg(self, r, v):
        R = self.regmap
        if r == R.PWR_MGMT_1.addr and R.decode("PWR_MGMT_1", v, "DEVICE_RESET"):
            self.power_on_reset()
            return
        if r == R.ACCEL_CONFIG2.addr and self.variant == "mpu6050":
            return                                      # not present on the MPU-6050
        if r == R.USER_CTRL.addr:
            if R.decode("USER_CTRL", v, "FIFO_RESET"):
                self.fifo.clear()
            v &= ~R.USER_CTRL.fields["FIFO_RESET"].mask  # self-clearing
        super().write_reg(r, v)

    def running(self):
        return not self.regmap.decode("PWR_MGMT_1", self.regs[self.regmap.PWR_MGMT_1.addr], "SLEEP")

    def _dlpf(self):
        return self.regmap.decode("CONFIG", self.regs[self.regmap.CONFIG.addr], "DLPF_CFG")

    def odr_hz(self):
        dl = self._dlpf()
        base = 8000.0 if dl in (0, 7) else 1000.0
        return base / (1 + self.regs[self.regmap.SMPLRT_DIV.addr])

    def startup_s(self):
        return 0.03

    def emit(self, t, skipped):
        R = self.regmap
        m = self.motion.sample(t)
        afs = R.decode("ACCEL_CONFIG", self.regs[R.ACCEL_CONFIG.addr], "AFS_SEL")
        fs = R.decode("GYRO_CONFIG", self.regs[R.GYRO_CONFIG.addr], "FS_SEL")
        a_lsb = [16384.0, 8192.0, 4096.0, 2048.0][afs]
        g_lsb = [131.0, 65.5, 32.8, 16.4][fs]
        bw_a, bw_g = _mpu.DLPF_HZ.get(self._dlpf(), (260, 256))
        n = len(t)
        acc = self.truth.accel_raw(m["f"]) + self._noise(
            self.spec_a.noise_density_g_rthz, min(bw_a, self.odr_hz() / 2), (n, 3))
        gyr = self.truth.gyro_raw(m["w"]) + self._noise(
            self.spec_g.noise_density_dps_rthz, min(bw_g, self.odr_hz() / 2), (n, 3))
        div, off = _mpu.TEMP_FORMULA[self.variant]
        vals = np.empty((n, 7), np.int64)
        vals[:, 0:3] = _i16(acc * a_lsb)
        vals[:, 3] = _i16((m["temp"] - off) * div)
        vals[:, 4:7] = _i16(gyr * g_lsb)
        frames = vals.astype(">i2").tobytes()
        self.latest = frames[-14:]
        self.samples += n
        self.regs[R.INT_STATUS.addr] |= R.INT_STATUS.fields["DATA_RDY_INT"].mask
        fe = self.regs[R.FIFO_EN.addr]
        if R.decode("USER_CTRL", self.regs[R.USER_CTRL.addr], "FIFO_EN") and fe:
            # frame layout follows the enabled sources in register order (K inv_mpu_ring.c)
            cols = []
            if fe & 0x08:
                cols += [0, 1, 2]
            if fe & 0x80:
                cols += [3]
            for bit, c in ((0x40, 4), (0x20, 5), (0x10, 6)):
                if fe & bit:
                    cols.append(c)
            data = vals[:, cols].astype(">i2").tobytes()
            self.fifo += data
            if len(self.fifo) > self.fifo_size or skipped:
                # overflow: the oldest bytes are dropped (D), which misaligns frames
                del self.fifo[:max(0, len(self.fifo) - self.fifo_size)]
                self.regs[R.INT_STATUS.addr] |= R.INT_STATUS.fields["FIFO_OFLOW_INT"].mask
                self.overflows += 1


class EmuAK8963(EmuDevice):
    """AK8963, visible at 0x0C only while the host MPU-9250 has its bypass enabled."""

    regmap = _ak.REGMAP

    def __init__(self, addr, clock, motion, truth, rng, host: EmuMPU6xxx):
        self.host = host
        self.asa_raw = np.array(rng.integers(160, 190, 3), dtype=np.uint8)  # fuse ROM
        super().__init__(addr, clock, motion, truth, rng)

    def reachable(self):
        R = _mpu.REGMAP
        h = self.host
        return bool(h.regs[R.INT_PIN_CFG.addr] & R.INT_PIN_CFG.fields["I2C_BYPASS_EN"].mask) and \
            not (h.regs[R.USER_CTRL.addr] & R.USER_CTRL.fields["I2C_MST_EN"].mask)

    def on_reset(self):
        self.data = bytes(6)
        self.drdy = False
        self.hofl = False

    def _mode(self):
        return self.regmap.decode("CNTL1", self.regs[self.regmap.CNTL1.addr], "MODE")

    def read_reg(self, r):
        R = self.regmap
        if r == R.WIA.addr:
            return _ak.WIA_ID if self.id_override is None else self.id_override
        if r == R.ST1.addr:
            return int(self.drdy)
        if R.HXL.addr <= r < R.HXL.addr + 6:
            return self.data[r - R.HXL.addr]
        if r == R.ST2.addr:
            return 0x10 | (0x08 if self.hofl else 0)
        if R.ASAX.addr <= r < R.ASAX.addr + 3:
            return int(self.asa_raw[r - R.ASAX.addr]) if self._mode() == _ak.MODE_FUSE_ROM else 0
        return self.regs[r]

    def after_read(self, reg, n):
        if reg <= self.regmap.ST2.addr < reg + n:      # reading ST2 releases the data lock
            self.drdy = False

    def write_reg(self, r, v):
        if r == self.regmap.CNTL2.addr and v & 0x01:
            self.power_on_reset()
            return
        super().write_reg(r, v)

    def running(self):
        return self._mode() in (_ak.MODE_CONT_8HZ, _ak.MODE_CONT_100HZ)

    def odr_hz(self):
        return 100.0 if self._mode() == _ak.MODE_CONT_100HZ else 8.0

    def startup_s(self):
        return 0.01

    def emit(self, t, skipped):
        m = self.motion.sample(t[-1:])
        mag = self.truth.mag_raw(m["h"])
        mag = mag + self.rng.normal(scale=MAG["ak8963"].noise_gauss, size=mag.shape)
        ak = np.array([mag[0, 1], mag[0, 0], -mag[0, 2]])        # MPU frame -> AK8963 frame (K)
        adj = (self.asa_raw.astype(float) - 128) * 0.5 / 128 + 1
        counts = np.round(ak / (_ak.GAUSS_PER_LSB_16 * adj))
        self.hofl = bool(np.any(np.abs(counts) > 32760))
        self.data = _i16(counts, -32760, 32760).astype("<i2").tobytes()
        self.drdy = True


class EmuADXL345(EmuDevice):
    regmap = _adxl.REGMAP

    def on_reset(self):
        self.fifo: List[bytes] = []
        self.latest = bytes(6)
        self.overrun = False

    def _fifo_mode(self):
        return self.regmap.decode("FIFO_CTL", self.regs[self.regmap.FIFO_CTL.addr], "FIFO_MODE")

    def read_reg(self, r):
        R = self.regmap
        if r == R.DEVID.addr:
            return _adxl.DEVID if self.id_override is None else self.id_override
        if R.DATAX0.addr <= r < R.DATAX0.addr + 6:
            src = self.fifo[0] if (self._fifo_mode() and self.fifo) else self.latest
            return src[r - R.DATAX0.addr]
        if r == R.FIFO_STATUS.addr:
            return min(len(self.fifo), 33) & 0x3F
        if r == R.INT_SOURCE.addr:
            return (0x80 if self.fifo or self.latest else 0) | (0x01 if self.overrun else 0)
        return self.regs[r]

    def after_read(self, reg, n):
        R = self.regmap
        if reg <= R.DATAX0.addr + 5 < reg + n and self._fifo_mode() and self.fifo:
            self.fifo.pop(0)                 # reading the data registers pops one entry (D)
            self.overrun = False

    def running(self):
        return bool(self.regs[self.regmap.POWER_CTL.addr] & 0x08)

    def odr_hz(self):
        return 0.09765625 * 2 ** self.regmap.decode("BW_RATE", self.regs[self.regmap.BW_RATE.addr], "RATE")

    def emit(self, t, skipped):
        R = self.regmap
        spec = ACCEL["adxl345"]
        m = self.motion.sample(t)
        acc = self.truth.accel_raw(m["f"]) + self._noise(
            spec.noise_density_g_rthz, self.odr_hz() / 2, (len(t), 3))
        df = self.regs[R.DATA_FORMAT.addr]
        rng_g = (2, 4, 8, 16)[df & 0x03]
        if df & 0x08:                                     # full resolution: 3.9 mg/LSB
            lim = int(rng_g / _adxl.G_PER_LSB_FULL_RES)
            counts = _i16(acc / _adxl.G_PER_LSB_FULL_RES, -lim, lim - 1)
        else:                                             # 10-bit: 512 counts over the range
            lim = 512
            counts = _i16(acc / (rng_g / 512.0), -lim, lim - 1)
        rows = [c.astype("<i2").tobytes() for c in counts]
        self.latest = rows[-1]
        if self._fifo_mode():
            self.fifo.extend(rows)
            if len(self.fifo) > _adxl.FIFO_DEPTH or skipped:
                del self.fifo[:len(self.fifo) - _adxl.FIFO_DEPTH]
                self.overrun = True


class EmuITG3200(EmuDevice):
    regmap = _itg.REGMAP

    def on_reset(self):
        self.latest = bytes(8)

    def read_reg(self, r):
        R = self.regmap
        if r == R.WHO_AM_I.addr:
            return 0x68 if self.id_override is None else self.id_override
        if R.TEMP_OUT_H.addr <= r < R.TEMP_OUT_H.addr + 8:
            return self.latest[r - R.TEMP_OUT_H.addr]
        return self.regs[r]

    def write_reg(self, r, v):
        if r == self.regmap.PWR_MGM.addr and v & 0x80:
            self.power_on_reset()
            return
        super().write_reg(r, v)

    def running(self):
        return not (self.regs[self.regmap.PWR_MGM.addr] & 0x40)

    def odr_hz(self):
        dl = self.regs[self.regmap.DLPF_FS.addr] & 0x07
        return (8000.0 if dl == 0 else 1000.0) / (1 + self.regs[self.regmap.SMPLRT_DIV.addr])

    def startup_s(self):
        return 0.05

    def emit(self, t, skipped):
        spec = GYRO["itg3200"]
        m = self.motion.sample(t[-1:])
        dl = self.regs[self.regmap.DLPF_FS.addr] & 0x07
        gyr = self.truth.gyro_raw(m["w"]) + self._noise(
            spec.noise_density_dps_rthz, min(_itg.DLPF_HZ.get(dl, 256), self.odr_hz() / 2), (1, 3))
        fs3 = ((self.regs[self.regmap.DLPF_FS.addr] >> 3) & 3) == 3
        lsb = _itg.LSB_PER_DPS if fs3 else _itg.LSB_PER_DPS * 4   # other FS_SEL values: undocumented
        vals = np.empty(4, np.int64)
        vals[0] = _i16((m["temp"][0] - 35.0) * 280.0 - 13200.0)
        vals[1:] = _i16(gyr[0] * lsb)
        self.latest = vals.astype(">i2").tobytes()


class EmuHMC5883L(EmuDevice):
    regmap = _hmc.REGMAP

    def on_reset(self):
        self.latest = bytes(6)
        self.rdy = False
        self.gain_in_use = self.regmap.decode("CONFIG_B", self.regmap.CONFIG_B.reset, "GN")
        self.single_pending = True                  # power-on MODE = single: one measurement

    def read_reg(self, r):
        R = self.regmap
        if R.DATA_X_H.addr <= r < R.DATA_X_H.addr + 6:
            return self.latest[r - R.DATA_X_H.addr]
        if r == R.STATUS.addr:
            return int(self.rdy)
        if r == R.ID_A.addr and self.id_override is not None:
            return self.id_override
        return self.regs[r]

    def write_reg(self, r, v):
        if r == self.regmap.MODE.addr:
            self.single_pending = (v & 0x03) == 1
        super().write_reg(r, v)

    def _md(self):
        return self.regs[self.regmap.MODE.addr] & 0x03

    def running(self):
        return self._md() == 0 or (self._md() == 1 and self.single_pending)

    def odr_hz(self):
        return _hmc.RATES_HZ.get((self.regs[self.regmap.CONFIG_A.addr] >> 2) & 0x07, 15.0)

    def startup_s(self):
        return 2.0 / self.odr_hz() if self._md() == 0 else 0.006

    def emit(self, t, skipped):
        m = self.motion.sample(t[-1:])
        mag = self.truth.mag_raw(m["h"])
        mag = mag[0] + self.rng.normal(scale=MAG["hmc5883l"].noise_gauss, size=3)
        counts = np.round(mag * _hmc.GAIN_LSB_PER_GAUSS[self.gain_in_use]).astype(np.int64)
        counts = np.where((counts < -2048) | (counts > 2047), _hmc.OVERFLOW, counts)
        # a gain change takes effect one measurement late (M)
        self.gain_in_use = self.regmap.decode("CONFIG_B", self.regs[self.regmap.CONFIG_B.addr], "GN")
        self.latest = np.array([counts[0], counts[2], counts[1]]).astype(">i2").tobytes()  # X, Z, Y
        self.rdy = True
        if self._md() == 1:
            self.single_pending = False
            self.regs[self.regmap.MODE.addr] = 0x03 | (self.regs[self.regmap.MODE.addr] & ~0x03)


class EmulatedBus:
    """The smbus2 subset the drivers use, backed by emulated chips and a clock."""

    def __init__(self, clock: Optional[Clock] = None, faults: Optional[Faults] = None,
                 rng: RngLike = None):
        self.clock = clock or VirtualClock()
        self.faults = faults or Faults()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
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


def emulated_board(board: str, motion, rng: RngLike = None, clock: Optional[Clock] = None,
                   faults: Optional[Faults] = None, truth: Optional[Truth] = None,
                   addrs: Optional[Dict[str, int]] = None, mag: Optional[str] = None) -> EmulatedBus:
    """An EmulatedBus holding the chips of ``board``: mpu6050, mpu6500, mpu9250, 9dof
    (ADXL345 + ITG3200 + a magnetometer), gy273 (a magnetometer alone).  ``mag``
    picks the magnetometer of 9dof and gy273 boards: hmc5883l (9dof default) or
    qmc5883l (gy273 default; ``9dof-qmc`` is the 9dof board with it)."""
    from .emu_qmc5883l import EmuQMC5883L
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
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
        mpu = bus.add(EmuMPU6xxx(a.get("mpu", 0x68), clock, motion, truth, rng, board))
        if board == "mpu9250":
            bus.add(EmuAK8963(_ak.ADDR, clock, motion, truth, rng, host=mpu))
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
