"""Analog Devices ADXL345 accelerometer (9DOF board).

Facts (K = Linux drivers/iio/accel/adxl345_core.c; A = Adafruit ADXL34x;
D = ADXL345 datasheet Rev E), as collected in
../shared/reference/daemon-and-chips.md section 4.3.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .bus import Bus, BusError, ChipMismatch, Clock, RealClock
from .regmap import Field, Register, RegisterMap

__all__ = ["REGMAP", "ADXL345", "DEVID", "ADDRS", "rate_code", "FifoCut"]

ADDRS = (0x53, 0x1D)                                                      # A: ALT ADDRESS low/high
DEVID = 0xE5                                                              # K
REGMAP = RegisterMap(
    "adxl345",
    Register("DEVID", 0x00, DEVID, read_only=True),
    Register("OFSX", 0x1E, 0x00, length=3),                               # signed, 15.6 mg/LSB (D)
    Register("BW_RATE", 0x2C, 0x0A, {"LOW_POWER": Field(0x10), "RATE": Field(0x0F)}),  # D: reset 100 Hz
    Register("POWER_CTL", 0x2D, 0x00, {"LINK": Field(0x20), "AUTO_SLEEP": Field(0x10),
                                       "MEASURE": Field(0x08), "SLEEP": Field(0x04),
                                       "WAKEUP": Field(0x03)}),           # K, A: standby at power-on
    Register("INT_ENABLE", 0x2E, 0x00, {"DATA_READY": Field(0x80), "WATERMARK": Field(0x02),
                                        "OVERRUN": Field(0x01)}),
    Register("INT_SOURCE", 0x30, 0x02, {"DATA_READY": Field(0x80), "WATERMARK": Field(0x02),
                                        "OVERRUN": Field(0x01)}, read_only=True),
    Register("DATA_FORMAT", 0x31, 0x00, {"SELF_TEST": Field(0x80), "SPI": Field(0x40),
                                         "INT_INVERT": Field(0x20), "FULL_RES": Field(0x08),
                                         "JUSTIFY": Field(0x04), "RANGE": Field(0x03)}),  # K
    # DATAX0..DATAZ1: little-endian signed 16-bit (A "<hhh", K __le16)
    Register("DATAX0", 0x32, 0x00, read_only=True, length=6),
    Register("FIFO_CTL", 0x38, 0x00, {"FIFO_MODE": Field(0xC0), "TRIGGER": Field(0x20),
                                      "SAMPLES": Field(0x1F)}),           # K
    Register("FIFO_STATUS", 0x39, 0x00, {"FIFO_TRIG": Field(0x80), "ENTRIES": Field(0x3F)},
             read_only=True),                                             # K, D
)
FIFO_DEPTH = 32                                                           # D
FIFO_STREAM = 2
#: full resolution: 3.9 mg/LSB at every range (K 38300 um/s^2/LSB; D Table 1: 256 LSB/g)
G_PER_LSB_FULL_RES = 0.0039
RANGES_G = (2, 4, 8, 16)


def rate_code(rate_hz: float) -> int:
    """BW_RATE code: f = 0.09765625 Hz * 2^code (K ADXL345_BASE_RATE_NANO_HZ), 0..15."""
    code = int(round(np.log2(rate_hz / 0.09765625)))
    if not 0 <= code <= 15 or abs(0.09765625 * 2 ** code - rate_hz) > 1e-6 * rate_hz + 1e-9:
        allowed = ", ".join(f"{0.09765625 * 2 ** c:g}" for c in range(6, 16))
        raise ValueError(f"ADXL345 rate_hz {rate_hz}: allowed {allowed}")
    return code


class FifoCut(BusError):
    """A bus fault part-way through draining the FIFO.  The entries read before it are popped
    from the chip and held here (``acc_g``, (k, 3)) for the caller to keep; whether the
    failed burst popped its own entry is not known (the FIFO advances at the end of a
    data-register read, D), so the caller counts what is missing by time."""

    def __init__(self, cause: BusError, acc_g: np.ndarray):
        super().__init__(str(cause), cause.addr, cause.errno)
        self.cause = cause              #: the bus layer's error (NoAcknowledge, BusIOError...)
        self.acc_g = acc_g


class ADXL345:
    def __init__(self, bus: Bus, addr: int = 0x53, clock: Optional[Clock] = None):
        self.bus, self.addr = bus, addr
        self.clock = clock or bus.clock or RealClock()
        self.range_g = 16
        self.rate_hz = 100.0

    def identify(self) -> None:
        d = self.bus.read_byte(self.addr, REGMAP.DEVID.addr)
        if d != DEVID:
            raise ChipMismatch(f"0x{self.addr:02X} answered DEVID=0x{d:02X}: not an ADXL345 "
                               f"(expected 0x{DEVID:02X})")

    def setup(self, range_g: int = 16, rate_hz: float = 100.0) -> None:
        """Full resolution, range, rate, FIFO in stream mode, then MEASURE (it powers up in
        standby and reads zeros until then)."""
        if range_g not in RANGES_G:
            raise ValueError(f"ADXL345 range_g {range_g}: allowed {RANGES_G}")
        R, b, a = REGMAP, self.bus, self.addr
        self.identify()
        b.write_byte(a, R.POWER_CTL.addr, 0)                              # standby while configuring
        cfg = {R.BW_RATE.addr: R.encode("BW_RATE", 0, RATE=rate_code(rate_hz)),
               R.DATA_FORMAT.addr: R.encode("DATA_FORMAT", 0, FULL_RES=1, RANGE=RANGES_G.index(range_g)),
               R.FIFO_CTL.addr: R.encode("FIFO_CTL", 0, FIFO_MODE=FIFO_STREAM, SAMPLES=16),
               R.POWER_CTL.addr: R.encode("POWER_CTL", 0, MEASURE=1)}
        b.write_verified(a, cfg, "ADXL345")
        self._cfg = cfg
        self.range_g, self.rate_hz = range_g, 0.09765625 * 2 ** rate_code(rate_hz)

    def still_configured(self) -> bool:
        R = REGMAP
        return self.bus.read_byte(self.addr, R.POWER_CTL.addr) == self._cfg.get(R.POWER_CTL.addr)

    def entries(self) -> int:
        return REGMAP.decode("FIFO_STATUS", self.bus.read_byte(self.addr, REGMAP.FIFO_STATUS.addr),
                             "ENTRIES")

    def read_fifo(self) -> tuple:
        """(acc g (k, 3), overrun).  Each 6-byte burst of DATAX0..DATAZ1 pops one entry (D);
        a full FIFO (32 entries) in stream mode means older samples were overwritten.  A bus
        fault after some entries were popped raises :class:`FifoCut` holding them."""
        n = self.entries()
        out = np.zeros((n, 3))
        for i in range(n):
            try:
                out[i] = np.frombuffer(self.bus.read_block(self.addr, REGMAP.DATAX0.addr, 6), "<i2")
            except BusError as e:
                raise FifoCut(e, out[:i] * G_PER_LSB_FULL_RES) from None
        return out * G_PER_LSB_FULL_RES, n >= FIFO_DEPTH
