"""AsahiKASEI AK8963 magnetometer inside the MPU-9250, reached through the MPU's
I2C bypass at 0x0C.

Facts (K = Linux inv_mpu_magn.c / ak8975.c; T = RM-MPU-9250A-00; W = kriswiner
MPU9250; P = PX4 ak8963 driver), as collected in
../shared/reference/daemon-and-chips.md section 4.2.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from .bus import Bus, ChipMismatch, Clock, RealClock
from .regmap import Field, Register, RegisterMap

__all__ = ["REGMAP", "AK8963", "WIA_ID", "ADDR"]

ADDR = 0x0C                                                                   # K, T, W
WIA_ID = 0x48                                                                 # K, T
REGMAP = RegisterMap(
    "ak8963",
    Register("WIA", 0x00, WIA_ID, read_only=True),
    Register("ST1", 0x02, 0x00, {"DOR": Field(0x02), "DRDY": Field(0x01)}, read_only=True),  # K
    # HXL..HZH 0x03-0x08 little-endian signed (T, W), then ST2 0x09
    Register("HXL", 0x03, 0x00, read_only=True, length=6),
    Register("ST2", 0x09, 0x00, {"BITM": Field(0x10), "HOFL": Field(0x08)}, read_only=True),  # K
    Register("CNTL1", 0x0A, 0x00, {"BIT": Field(0x10), "MODE": Field(0x0F)}),  # T, W, K
    Register("CNTL2", 0x0B, 0x00, {"SRST": Field(0x01)}),                      # K
    Register("ASAX", 0x10, 0x80, read_only=True, length=3),                    # fuse ROM (K, T)
)
MODE_POWER_DOWN, MODE_CONT_8HZ, MODE_CONT_100HZ, MODE_FUSE_ROM = 0x0, 0x2, 0x6, 0xF
#: 16-bit output: 0.15 uT/LSB = 0.0015 gauss/LSB (K, T)
GAUSS_PER_LSB_16 = 0.0015


class AK8963:
    def __init__(self, bus: Bus, addr: int = ADDR, clock: Optional[Clock] = None):
        self.bus, self.addr = bus, addr
        self.clock = clock or bus.clock or RealClock()
        self.asa = np.ones(3)
        self.asa_raw = b""           #: the fuse-ROM sensitivity adjustment bytes (factory trim)

    def identify(self) -> None:
        wia = self.bus.read_byte(self.addr, REGMAP.WIA.addr)
        if wia != WIA_ID:
            raise ChipMismatch(f"0x{self.addr:02X} answered WIA=0x{wia:02X}: not an AK8963 "
                               f"(expected 0x{WIA_ID:02X})")

    def setup(self, rate_hz: float = 100.0) -> None:
        """Soft reset, read the fuse-ROM sensitivity adjustment, start 16-bit continuous."""
        R, b, a = REGMAP, self.bus, self.addr
        self.identify()
        b.write_byte(a, R.CNTL2.addr, R.encode("CNTL2", SRST=1))
        self.clock.sleep(0.01)
        b.write_byte(a, R.CNTL1.addr, R.encode("CNTL1", MODE=MODE_FUSE_ROM))
        self.clock.sleep(0.01)
        self.asa_raw = bytes(b.read_block(a, R.ASAX.addr, 3))
        asa = np.frombuffer(self.asa_raw, dtype=np.uint8).astype(float)
        # H_adj = H * ((ASA - 128) * 0.5 / 128 + 1)   (K, T)
        self.asa = (asa - 128.0) * 0.5 / 128.0 + 1.0
        b.write_byte(a, R.CNTL1.addr, R.encode("CNTL1", MODE=MODE_POWER_DOWN))
        self.clock.sleep(0.001)                                         # >= 100 us between modes
        mode = MODE_CONT_100HZ if rate_hz > 8 else MODE_CONT_8HZ
        val = R.encode("CNTL1", BIT=1, MODE=mode)
        b.write_byte(a, R.CNTL1.addr, val)
        if b.read_byte(a, R.CNTL1.addr) != val:
            raise ChipMismatch(f"0x{a:02X}: AK8963 CNTL1 did not take 0x{val:02X}")
        self.rate_hz = 100.0 if mode == MODE_CONT_100HZ else 8.0

    def read(self) -> Tuple[Optional[np.ndarray], bool]:
        """One 8-byte burst ST1..ST2 (ST2 last releases the data lock, K/W).

        Returns (field in gauss in the *MPU accelerometer frame*, overflow);
        field is None when no new sample is ready or on magnetic overflow (HOFL).
        AK8963 X = MPU Y, Y = MPU X, Z = -MPU Z (K inv_mpu_magn_set_orient).
        """
        raw = self.bus.read_block(self.addr, REGMAP.ST1.addr, 8)
        st1, st2 = raw[0], raw[7]
        if not REGMAP.decode("ST1", st1, "DRDY"):
            return None, False
        if REGMAP.decode("ST2", st2, "HOFL"):
            return None, True
        v = np.frombuffer(raw[1:7], dtype="<i2").astype(float) * self.asa * GAUSS_PER_LSB_16
        return np.array([v[1], v[0], -v[2]]), False
