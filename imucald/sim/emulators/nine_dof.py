"""Emulated chips of the 9DOF (GY-85 class) board: ADXL345 accelerometer, ITG-3200
gyro and HMC5883L magnetometer (X/Z/Y order, -4096 overflow, one-sample gain latency)."""
from __future__ import annotations

from typing import List

import numpy as np

from ...drivers import adxl345 as _adxl, hmc5883l as _hmc, itg3200 as _itg
from ...specs import ACCEL, GYRO, MAG
from .base import EmuDevice, i16

__all__ = ["EmuADXL345", "EmuITG3200", "EmuHMC5883L"]


_A = _adxl.REGMAP
#: register addresses the emulated ADXL345 serves on every poll, looked up once (the 9DOF
#: board is polled once per sample: these lookups were a tenth of `record`'s time)
_A_DEVID, _A_DATA, _A_FIFO_STATUS, _A_INT_SOURCE, _A_FIFO_CTL = (
    _A.DEVID.addr, _A.DATAX0.addr, _A.FIFO_STATUS.addr, _A.INT_SOURCE.addr, _A.FIFO_CTL.addr)
_A_FIFO_MODE = _A._by_name["FIFO_CTL"].fields["FIFO_MODE"]


class EmuADXL345(EmuDevice):
    regmap = _adxl.REGMAP

    def on_reset(self):
        self.fifo: List[bytes] = []
        self.latest = bytes(6)
        self.overrun = False

    def _fifo_mode(self):
        return _A_FIFO_MODE.get(self.regs[_A_FIFO_CTL])

    def read_reg(self, r):
        if r == _A_DEVID:
            return _adxl.DEVID if self.id_override is None else self.id_override
        if _A_DATA <= r < _A_DATA + 6:
            src = self.fifo[0] if (self.fifo and self._fifo_mode()) else self.latest
            return src[r - _A_DATA]
        if r == _A_FIFO_STATUS:
            return min(len(self.fifo), 33) & 0x3F
        if r == _A_INT_SOURCE:
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
            counts = i16(acc / _adxl.G_PER_LSB_FULL_RES, -lim, lim - 1)
        else:                                             # 10-bit: 512 counts over the range
            lim = 512
            counts = i16(acc / (rng_g / 512.0), -lim, lim - 1)
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

    _WHO, _TEMP = _itg.REGMAP.WHO_AM_I.addr, _itg.REGMAP.TEMP_OUT_H.addr

    def read_reg(self, r):
        if r == self._WHO:
            return 0x68 if self.id_override is None else self.id_override
        if self._TEMP <= r < self._TEMP + 8:
            return self.latest[r - self._TEMP]
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
            spec.noise_density_dps_rthz, _itg.DLPF_HZ.get(dl, 256), (1, 3))   # whole DLPF band, aliased
        fs3 = ((self.regs[self.regmap.DLPF_FS.addr] >> 3) & 3) == 3
        lsb = _itg.LSB_PER_DPS if fs3 else _itg.LSB_PER_DPS * 4   # other FS_SEL values: undocumented
        vals = np.empty(4, np.int64)
        vals[0] = i16((m["temp"][0] - 35.0) * 280.0 - 13200.0)
        vals[1:] = i16(gyr[0] * lsb)
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
