"""Register-accurate emulated QMC5883L behind the smbus2 API (see the emulators package).

Shares the driver's register map (:mod:`imucald.drivers.qmc5883l`).  Modelled
(D = QMC5883L datasheet rev 1.0, section 9; L = libdriver/qmc5883l): power-on in
standby (CONTROL1 = 0, no conversions), continuous mode at the ODR of CONTROL1,
range 2 G / 8 G at 12000 / 3000 LSB/G, little-endian X, Y, Z, DRDY set by a new
sample and cleared when the data registers are read, DOR when a sample was
overwritten unread, OVL with the outputs saturated at the int16 limits, soft reset
(CONTROL2 bit 7) restoring every register, the pointer roll-over option, CHIP_ID
0xFF, and a temperature output whose offset is uncalibrated (100 LSB/degC, L).
"""
from __future__ import annotations

import numpy as np

from ...specs import MAG
from ...drivers import qmc5883l as _qmc
from .base import EmuDevice

__all__ = ["EmuQMC5883L"]


_Q = _qmc.REGMAP
#: addresses and fields read on every poll, looked up once (a gy273 is polled once per
#: sample: the register map's attribute lookups were a sixth of `record`'s time)
_DATA, _STATUS, _TOUT, _CHIP_ID, _CONTROL1, _CONTROL2 = (
    _Q.DATA_X_L.addr, _Q.STATUS.addr, _Q.TOUT_L.addr, _Q.CHIP_ID.addr, _Q.CONTROL1.addr, _Q.CONTROL2.addr)
_ROL_PNT = _Q.CONTROL2.fields["ROL_PNT"].mask
_CLEAR_ON_READ = _Q.STATUS.fields["DRDY"].mask | _Q.STATUS.fields["DOR"].mask
_C1 = _Q.CONTROL1.fields


class EmuQMC5883L(EmuDevice):
    regmap = _qmc.REGMAP

    def on_reset(self):
        self.latest = bytes(6)
        self.status = 0
        if not hasattr(self, "temp_offset_c"):       # a property of the part: survives resets
            self.temp_offset_c = float(self.rng.normal(scale=5.0))
        self.tout = bytes(2)

    def read(self, reg, n):
        R = self.regmap
        if self.regs[_CONTROL2] & _ROL_PNT and reg <= _STATUS:
            # roll-over: the pointer wraps from 0x06 back to 0x00 (D, CONTROL2.ROL_PNT)
            self.sync(self.clock.now())
            data = bytes(self.read_reg(r) for r in range(R.STATUS.addr + 1))
            out = bytes(data[(reg + i) % len(data)] for i in range(n))
            self.after_read(reg, n)
            return out
        return super().read(reg, n)

    def read_reg(self, r):
        if _DATA <= r < _DATA + 6:
            return self.latest[r - _DATA]
        if r == _STATUS:
            return self.status
        if _TOUT <= r < _TOUT + 2:
            return self.tout[r - _TOUT]
        if r == _CHIP_ID and self.id_override is not None:
            return self.id_override
        return self.regs[r]

    def after_read(self, reg, n):
        if reg < _DATA + 6 and reg + n > _DATA:
            # reading the data clears DRDY and DOR (D, status register)
            self.status &= ~_CLEAR_ON_READ & 0xFF

    def write_reg(self, r, v):
        R = self.regmap
        if r == R.CONTROL2.addr and v & R.CONTROL2.fields["SOFT_RST"].mask:
            self.power_on_reset()                   # every register back to its default (D)
            return
        super().write_reg(r, v)

    def _field(self, name):
        return _C1[name].get(self.regs[_CONTROL1])

    def running(self):
        return self._field("MODE") == _qmc.MODE_CONTINUOUS

    def odr_hz(self):
        return _qmc.RATES_HZ[self._field("ODR")]

    def startup_s(self):
        return 1.0 / self.odr_hz()

    def emit(self, t, skipped):
        R = self.regmap
        m = self.motion.sample(t[-1:])
        mag = self.truth.mag_raw(m["h"])[0] + self.rng.normal(scale=MAG["qmc5883l"].noise_gauss, size=3)
        rng = self._field("RNG")
        counts = np.round(mag * _qmc.LSB_PER_GAUSS.get(rng, 12000))
        ovl = bool(np.any((counts < -32768) | (counts > 32767)))
        self.latest = np.clip(counts, -32768, 32767).astype("<i2").tobytes()
        self.tout = np.array([round((m["temp"][0] + self.temp_offset_c) * _qmc.TEMP_LSB_PER_C)],
                             "<i2").tobytes()
        st = self.status
        lost = len(t) + skipped - 1 + (1 if st & R.STATUS.fields["DRDY"].mask else 0)
        st = R.STATUS.fields["DRDY"].mask
        if lost > 0:
            st |= R.STATUS.fields["DOR"].mask
        if ovl:
            st |= R.STATUS.fields["OVL"].mask
        self.status = st
