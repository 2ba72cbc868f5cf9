"""Honeywell HMC5883L magnetometer (9DOF board).

Facts (K = Linux drivers/iio/magnetometer/hmc5843_core.c; I = i2cdevlib
HMC5883L; M = MultiWii-derived hmc5883.cpp), as collected in
../shared/reference/daemon-and-chips.md section 4.5.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from .bus import Bus, ChipMismatch, Clock, RealClock
from .regmap import Field, Register, RegisterMap

__all__ = ["REGMAP", "HMC5883L", "ADDR", "GAIN_LSB_PER_GAUSS", "OVERFLOW"]

ADDR = 0x1E                                                                 # I
REGMAP = RegisterMap(
    "hmc5883l",
    Register("CONFIG_A", 0x00, 0x10, {"MA": Field(0x60), "DO": Field(0x1C), "MS": Field(0x03)}),  # K, I
    Register("CONFIG_B", 0x01, 0x20, {"GN": Field(0xE0)}),                   # I: gain 1 default
    Register("MODE", 0x02, 0x01, {"MD": Field(0x03)}),                       # K, I: single at power-on
    # DXRA..DYRB 0x03-0x08: X, Z, Y, big-endian signed; -4096 = overflow (K, I)
    Register("DATA_X_H", 0x03, 0x00, read_only=True, length=6),
    Register("STATUS", 0x09, 0x00, {"LOCK": Field(0x02), "RDY": Field(0x01)}, read_only=True),
    Register("ID_A", 0x0A, ord("H"), read_only=True),                        # K, I: 'H', '4', '3'
    Register("ID_B", 0x0B, ord("4"), read_only=True),
    Register("ID_C", 0x0C, ord("3"), read_only=True),
)
#: CONFIG_B gain code -> LSB per gauss (I table; K nanoscale = 1e7/gain)
GAIN_LSB_PER_GAUSS = {0: 1370, 1: 1090, 2: 820, 3: 660, 4: 440, 5: 390, 6: 330, 7: 230}
GAIN_RANGE_GAUSS = {0: 0.88, 1: 1.3, 2: 1.9, 3: 2.5, 4: 4.0, 5: 4.7, 6: 5.6, 7: 8.1}
#: CONFIG_A DO code -> output rate, Hz (K, I)
RATES_HZ = {0: 0.75, 1: 1.5, 2: 3.0, 3: 7.5, 4: 15.0, 5: 30.0, 6: 75.0}
OVERFLOW = -4096                                                            # I
MODE_CONTINUOUS = 0


class HMC5883L:
    def __init__(self, bus: Bus, addr: int = ADDR, clock: Optional[Clock] = None):
        self.bus, self.addr = bus, addr
        self.clock = clock or bus.clock or RealClock()
        self.gain = 1
        self.rate_hz = 75.0
        self._discard = 0

    def identify(self) -> None:
        ident = self.bus.read_block(self.addr, REGMAP.ID_A.addr, 3)
        if ident != b"H43":
            raise ChipMismatch(f"0x{self.addr:02X} answered ID={ident!r}: not an HMC5883L "
                               f"(expected b'H43')")

    def setup(self, gain: int = 1, rate_hz: float = 75.0, averaging: int = 1) -> None:
        R, b, a = REGMAP, self.bus, self.addr
        if gain not in GAIN_LSB_PER_GAUSS:
            raise ValueError(f"HMC5883L gain {gain}: allowed 0..7")
        codes = [c for c, hz in RATES_HZ.items() if abs(hz - rate_hz) < 1e-9]
        if not codes:
            raise ValueError(f"HMC5883L rate_hz {rate_hz}: allowed {sorted(RATES_HZ.values())}")
        self.identify()
        ma = {1: 0, 2: 1, 4: 2, 8: 3}[averaging]
        cfg = {R.CONFIG_A.addr: R.encode("CONFIG_A", 0, MA=ma, DO=codes[0], MS=0),
               R.CONFIG_B.addr: R.encode("CONFIG_B", 0, GN=gain),
               R.MODE.addr: R.encode("MODE", 0, MD=MODE_CONTINUOUS)}
        b.write_verified(a, cfg, "HMC5883L")
        self._cfg = cfg
        self.gain, self.rate_hz = gain, RATES_HZ[codes[0]]
        # "the very first measurement after a gain change maintains the same gain as the
        # previous setting" (M): the first sample is discarded
        self._discard = 1

    def still_configured(self) -> bool:
        R = REGMAP
        return self.bus.read_byte(self.addr, R.MODE.addr) == self._cfg.get(R.MODE.addr)

    def read(self) -> Tuple[Optional[np.ndarray], bool]:
        """One 7-byte burst DATA..STATUS: (field gauss in sensor X, Y, Z order, overflow).

        Returns None when the status shows no new sample (RDY clear), the first
        sample after a gain change, or an overflowed axis (-4096)."""
        raw = self.bus.read_block(self.addr, REGMAP.DATA_X_H.addr, 7)
        if not REGMAP.decode("STATUS", raw[6], "RDY"):
            return None, False
        x, z, y = np.frombuffer(raw[:6], ">i2").astype(int)
        if self._discard:
            self._discard -= 1
            return None, False
        if OVERFLOW in (x, y, z):
            return None, True
        return np.array([x, y, z], float) / GAIN_LSB_PER_GAUSS[self.gain], False
