"""QST QMC5883L magnetometer: the chip most GY-273 and many GY-85 / "9DOF" boards
carry where the listing says HMC5883L (address 0x0D, a different register map).

Facts, with their sources:
  D = QST QMC5883L datasheet rev 1.0 (2016), section 9 "register map" and 9.2
      register definitions, as restated in i2cdevlib's QMC5883L.h ("Based on QST
      QMC5883L datasheet 1.0, 02/2016") and libdriver/qmc5883l driver_qmc5883l.c;
  A = ArduPilot libraries/AP_Compass/AP_Compass_QMC5883L.cpp (ID value 0xFF at
      register 0x0D, 0x0B written 0x01 before configuring, 8 G scale 1/3000 G per LSB,
      little-endian int16 X, Y, Z);
  L = libdriver/qmc5883l (temperature 100 LSB/degC, gain factory-calibrated but
      offset not: "only relative temperature value is accurate"; soft reset =
      CONTROL2 bit 7, then wait).
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from .bus import Bus, ChipMismatch, Clock, RealClock
from .regmap import Field, Register, RegisterMap

__all__ = ["REGMAP", "QMC5883L", "ADDR", "CHIP_ID", "LSB_PER_GAUSS", "RATES_HZ", "OSR",
           "TEMP_LSB_PER_C"]

ADDR = 0x0D                                                                 # D, A
CHIP_ID = 0xFF                                                              # D, A: reg 0x0D
REGMAP = RegisterMap(
    "qmc5883l",
    # 0x00-0x05: X LSB, X MSB, Y LSB, Y MSB, Z LSB, Z MSB: little-endian int16 (D, A)
    Register("DATA_X_L", 0x00, 0x00, read_only=True, length=6),
    # STATUS: DRDY new data (cleared when the data are read), OVL an axis out of range,
    # DOR a sample was skipped (overwritten unread; cleared by reading the data) (D)
    Register("STATUS", 0x06, 0x00, {"DOR": Field(0x04), "OVL": Field(0x02), "DRDY": Field(0x01)},
             read_only=True),
    # TOUT 0x07-0x08: int16 little-endian, 100 LSB/degC, offset not calibrated (D, L)
    Register("TOUT_L", 0x07, 0x00, read_only=True, length=2),
    # CONTROL1: OSR bits 7:6 (512/256/128/64), RNG 5:4 (2 G / 8 G), ODR 3:2
    # (10/50/100/200 Hz), MODE 1:0 (0 standby = power-on, 1 continuous) (D, A)
    Register("CONTROL1", 0x09, 0x00, {"OSR": Field(0xC0), "RNG": Field(0x30), "ODR": Field(0x0C),
                                      "MODE": Field(0x03)}),
    # CONTROL2: SOFT_RST bit 7 (restores every register's default), ROL_PNT bit 6
    # (the read pointer rolls over 0x06 -> 0x00), INT_ENB bit 0 (1 disables DRDY pin) (D, L)
    Register("CONTROL2", 0x0A, 0x00, {"SOFT_RST": Field(0x80), "ROL_PNT": Field(0x40),
                                      "INT_ENB": Field(0x01)}),
    # SET/RESET period (FBR): the datasheet recommends 0x01 (D, A writes 0x01)
    Register("SET_RESET", 0x0B, 0x00),
    Register("CHIP_ID", 0x0D, CHIP_ID, read_only=True),                     # D, A
)
#: CONTROL1.RNG code -> LSB per gauss: 2 G 12000, 8 G 3000 (D; A scales 8 G by 1/3000)
LSB_PER_GAUSS = {0: 12000, 1: 3000}
RANGE_GAUSS = {0: 2.0, 1: 8.0}
RATES_HZ = {0: 10.0, 1: 50.0, 2: 100.0, 3: 200.0}                           # D: CONTROL1.ODR
OSR = {0: 512, 1: 256, 2: 128, 3: 64}                                       # D: CONTROL1.OSR
TEMP_LSB_PER_C = 100.0                                                      # L (relative only)
SET_RESET_RECOMMENDED = 0x01                                                # D, A
MODE_STANDBY, MODE_CONTINUOUS = 0, 1                                        # D


def _code(table, value, what: str) -> int:
    for c, v in table.items():
        if abs(v - value) < 1e-9:
            return c
    raise ValueError(f"QMC5883L {what} {value:g}: allowed {', '.join(f'{v:g}' for v in table.values())}")


class QMC5883L:
    """Driver: identify, configure (continuous mode, range, rate, oversampling),
    read field (gauss, sensor X, Y, Z) with data-ready and overflow handling, and
    the relative die temperature."""

    name = "qmc5883l"

    def __init__(self, bus: Bus, addr: int = ADDR, clock: Optional[Clock] = None):
        self.bus, self.addr = bus, addr
        self.clock = clock or bus.clock or RealClock()
        self.range_code = 0
        self.rate_hz = 50.0
        self.temp_rel_c = float("nan")      #: last temperature, degC, offset uncalibrated (L)
        self.skipped = 0                    #: samples the chip reported as overwritten unread (DOR)
        self.overflows = 0
        self._cfg = {}

    def identify(self) -> None:
        cid = self.bus.read_byte(self.addr, REGMAP.CHIP_ID.addr)
        if cid != CHIP_ID:
            raise ChipMismatch(f"0x{self.addr:02X} answered CHIP_ID(0x0D)=0x{cid:02X}: not a QMC5883L "
                               f"(expected 0x{CHIP_ID:02X})")

    def soft_reset(self) -> None:
        R = REGMAP
        self.bus.write_byte(self.addr, R.CONTROL2.addr, R.encode("CONTROL2", 0, SOFT_RST=1))
        self.clock.sleep(0.01)                                              # L: wait after reset

    def setup(self, range_gauss: float = 2.0, rate_hz: float = 50.0, oversampling: int = 512) -> None:
        R = REGMAP
        rng = _code(RANGE_GAUSS, range_gauss, "range_gauss")
        odr = _code(RATES_HZ, rate_hz, "rate_hz")
        osr = _code(OSR, oversampling, "oversampling")
        self.identify()
        self.soft_reset()
        cfg = {R.SET_RESET.addr: SET_RESET_RECOMMENDED,
               R.CONTROL2.addr: R.encode("CONTROL2", 0, ROL_PNT=0, INT_ENB=0),
               R.CONTROL1.addr: R.encode("CONTROL1", 0, OSR=osr, RNG=rng, ODR=odr, MODE=MODE_CONTINUOUS)}
        self.bus.write_verified(self.addr, cfg, "QMC5883L")
        self._cfg = cfg
        self.range_code, self.rate_hz = rng, RATES_HZ[odr]

    @property
    def lsb_per_gauss(self) -> int:
        return LSB_PER_GAUSS[self.range_code]

    def still_configured(self) -> bool:
        """CONTROL1 still holds the mode written (a reset returns it to standby, 0x00)."""
        a = REGMAP.CONTROL1.addr
        return self.bus.read_byte(self.addr, a) == self._cfg.get(a)

    def read(self) -> Tuple[Optional[np.ndarray], bool]:
        """One 9-byte burst DATA..TOUT: (field gauss, X, Y, Z, overflow).

        None when there is no new sample (DRDY clear) or an axis overflowed (OVL,
        returned as True: lower the sensitivity, i.e. use the 8 G range)."""
        raw = self.bus.read_block(self.addr, REGMAP.DATA_X_L.addr, 9)
        st = raw[6]
        if not REGMAP.decode("STATUS", st, "DRDY"):
            return None, False
        self.temp_rel_c = float(np.frombuffer(raw[7:9], "<i2")[0]) / TEMP_LSB_PER_C
        if REGMAP.decode("STATUS", st, "DOR"):
            self.skipped += 1
        if REGMAP.decode("STATUS", st, "OVL"):
            self.overflows += 1
            return None, True
        xyz = np.frombuffer(raw[:6], "<i2").astype(float)
        return xyz / self.lsb_per_gauss, False
