"""InvenSense ITG-3200 gyro (9DOF board).

Facts (K = Linux drivers/iio/gyro/itg3200_core.c; I = i2cdevlib ITG3200), as
collected in ../shared/reference/daemon-and-chips.md section 4.4.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from .bus import Bus, ChipMismatch, Clock, RealClock
from .regmap import Field, Register, RegisterMap

__all__ = ["REGMAP", "ITG3200", "ADDRS"]

ADDRS = (0x68, 0x69)                                                        # I (AD0 low/high)
REGMAP = RegisterMap(
    "itg3200",
    Register("WHO_AM_I", 0x00, 0x68, {"ID": Field(0x7E)}),                  # K: bits 6:1 = 0x34
    Register("SMPLRT_DIV", 0x15, 0x00),                                    # K
    Register("DLPF_FS", 0x16, 0x00, {"FS_SEL": Field(0x18), "DLPF_CFG": Field(0x07)}),  # K, I
    Register("INT_CFG", 0x17, 0x00, {"ACTL": Field(0x80), "OPEN": Field(0x40),
                                     "LATCH_INT_EN": Field(0x20), "INT_ANYRD_2CLEAR": Field(0x10),
                                     "ITG_RDY_EN": Field(0x04), "RAW_RDY_EN": Field(0x01)}),
    Register("INT_STATUS", 0x1A, 0x00, {"ITG_RDY": Field(0x04), "RAW_DATA_RDY": Field(0x01)},
             read_only=True),                                              # K
    # TEMP_OUT_H 0x1B .. GYRO_ZOUT_L 0x22: 8 bytes, big-endian signed (K, I)
    Register("TEMP_OUT_H", 0x1B, 0x00, read_only=True, length=8),
    Register("PWR_MGM", 0x3E, 0x00, {"H_RESET": Field(0x80), "SLEEP": Field(0x40),
                                     "STBY_XG": Field(0x20), "STBY_YG": Field(0x10),
                                     "STBY_ZG": Field(0x08), "CLK_SEL": Field(0x07)}),  # K, I
)
ID = 0x34
FS_SEL_2000 = 3                                 # must be 3 for +-2000 deg/s (K ITG3200_DLPF_FS_SEL_2000)
LSB_PER_DPS = 14.375                            # K
DLPF_HZ = {0: 256, 1: 188, 2: 98, 3: 42, 4: 20, 5: 10, 6: 5}               # K, I


def temp_c(raw: int) -> float:
    """degC = 35 + (raw + 13200) / 280 (K: offset 23000, scale 1/280)."""
    return 35.0 + (raw + 13200) / 280.0


class ITG3200:
    def __init__(self, bus: Bus, addr: int = 0x68, clock: Optional[Clock] = None):
        self.bus, self.addr = bus, addr
        self.clock = clock or bus.clock or RealClock()
        self.rate_hz = 100.0

    def identify(self) -> None:
        w = self.bus.read_byte(self.addr, REGMAP.WHO_AM_I.addr)
        if REGMAP.decode("WHO_AM_I", w, "ID") != ID:
            hint = ""
            if w in (0x68, 0x70, 0x71, 0x73):
                hint = " (0x75-style InvenSense MPU ID: is an MPU6050/9250 at this address?)"
            raise ChipMismatch(f"0x{self.addr:02X} answered WHO_AM_I=0x{w:02X}: not an ITG3200 "
                               f"(expected bits 6:1 = 0x{ID:02X}){hint}")

    def setup(self, rate_hz: float = 100.0, dlpf_cfg: Optional[int] = None) -> None:
        R, b, a = REGMAP, self.bus, self.addr
        self.identify()
        b.write_byte(a, R.PWR_MGM.addr, R.encode("PWR_MGM", 0, H_RESET=1))
        self.clock.sleep(0.0015)                                            # K: 1.5 ms for the PLL
        if dlpf_cfg is None:
            dlpf_cfg = max(c for c, hz in DLPF_HZ.items() if hz >= rate_hz / 2 or c == 0)
        base = 8000.0 if dlpf_cfg == 0 else 1000.0                          # K
        div = int(round(base / rate_hz)) - 1
        if not 0 <= div <= 255:
            raise ValueError(f"ITG3200 rate_hz {rate_hz}: allowed {base / 256:.2f}..{base:.0f}")
        cfg = {R.PWR_MGM.addr: R.encode("PWR_MGM", 0, CLK_SEL=1),
               R.SMPLRT_DIV.addr: div,
               R.DLPF_FS.addr: R.encode("DLPF_FS", 0, FS_SEL=FS_SEL_2000, DLPF_CFG=dlpf_cfg),
               R.INT_CFG.addr: R.encode("INT_CFG", 0, RAW_RDY_EN=1)}
        b.write_verified(a, cfg, "ITG3200")
        self._cfg = cfg
        self.rate_hz = base / (div + 1)

    def still_configured(self) -> bool:
        R = REGMAP
        return self.bus.read_byte(self.addr, R.DLPF_FS.addr) == self._cfg.get(R.DLPF_FS.addr)

    def read(self) -> Tuple[np.ndarray, float]:
        """One 8-byte burst: (gyro deg/s (3,), temperature degC)."""
        v = np.frombuffer(self.bus.read_block(self.addr, REGMAP.TEMP_OUT_H.addr, 8), ">i2")
        return v[1:4].astype(float) / LSB_PER_DPS, temp_c(int(v[0]))
