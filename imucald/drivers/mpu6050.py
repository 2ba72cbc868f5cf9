"""InvenSense MPU-6050 and MPU-6500/MPU-9250 (accelerometer, gyro, temperature).

Register facts (K = Linux drivers/iio/imu/inv_mpu6050/inv_mpu_iio.h and
inv_mpu_core.c; A = Adafruit_CircuitPython_MPU6050; D = PS-MPU-6000A rev 3.4 /
RM-MPU-6000A register map; T = RM-MPU-9250A-00), as collected in
../shared/reference/daemon-and-chips.md section 4.1-4.2.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .bus import Bus, ChipMismatch, Clock, RealClock
from .rates import MPU_FIFO_BYTES, MPU_FRAME_BYTES
from .regmap import Field, Register, RegisterMap

__all__ = ["REGMAP", "WHO_AM_I_IDS", "MPU6xxx", "ACCEL_LSB_PER_G", "GYRO_LSB_PER_DPS",
           "DLPF_HZ", "FIFO_SIZE", "FRAME_BYTES"]

REGMAP = RegisterMap(
    "mpu6050",
    # factory trim, read for the sensor's fingerprint (never written by the driver):
    # MPU-6500/9250 SELF_TEST_X/Y/Z_GYRO 0x00-0x02 (T, registers 0-2: "the value in this register
    # indicates the self test output generated during manufacturing tests")
    Register("SELF_TEST_GYRO", 0x00, 0x00, read_only=True, length=3),
    # MPU-6050 accelerometer offsets XA/YA/ZA_OFFS_H/L 0x06-0x0B, big-endian int16; factory
    # values reload at every power-on, bit 0 of each low byte reserved (K; reference
    # section 4.1: kriswiner/MPU6050#8, jrowberg/i2cdevlib#396)
    Register("XA_OFFS_H", 0x06, 0x00, read_only=True, length=6),
    # MPU-6050 SELF_TEST_X/Y/Z/A 0x0D-0x10 (D registers 13-16, A); on the MPU-6500/9250 0x0D-0x0F
    # are SELF_TEST_X/Y/Z_ACCEL (T registers 13-15), 0x10 is not used
    Register("SELF_TEST", 0x0D, 0x00, read_only=True, length=4),
    Register("SMPLRT_DIV", 0x19, 0x00),                                        # K; D 4.2
    Register("CONFIG", 0x1A, 0x00, {"EXT_SYNC_SET": Field(0x38),               # K; D 4.3
                                    "DLPF_CFG": Field(0x07)}),
    Register("GYRO_CONFIG", 0x1B, 0x00, {"FS_SEL": Field(0x18)}),              # K, A; D 4.4
    Register("ACCEL_CONFIG", 0x1C, 0x00, {"AFS_SEL": Field(0x18)}),            # K, A; D 4.5
    Register("ACCEL_CONFIG2", 0x1D, 0x00, {"A_DLPF_CFG": Field(0x07)}),        # MPU6500/9250 only (T)
    Register("FIFO_EN", 0x23, 0x00, {"TEMP": Field(0x80), "XG": Field(0x40),  # K
                                     "YG": Field(0x20), "ZG": Field(0x10), "ACCEL": Field(0x08)}),
    Register("INT_PIN_CFG", 0x37, 0x00, {"INT_LEVEL": Field(0x80), "LATCH_INT_EN": Field(0x20),
                                         "INT_RD_CLEAR": Field(0x10),          # K; D 4.15
                                         "I2C_BYPASS_EN": Field(0x02)}),
    Register("INT_ENABLE", 0x38, 0x00, {"FIFO_OFLOW_EN": Field(0x10),          # K; D 4.16
                                        "DATA_RDY_EN": Field(0x01)}),
    Register("INT_STATUS", 0x3A, 0x00, {"FIFO_OFLOW_INT": Field(0x10),         # K; D 4.17
                                        "DATA_RDY_INT": Field(0x01)}, read_only=True),
    # ACCEL_XOUT_H..GYRO_ZOUT_L: 14 bytes, big-endian signed: ax ay az temp gx gy gz (K, A)
    Register("ACCEL_XOUT_H", 0x3B, 0x00, read_only=True, length=14),
    Register("SIGNAL_PATH_RESET", 0x68, 0x00, {"GYRO": Field(0x04), "ACCEL": Field(0x02),
                                               "TEMP": Field(0x01)}),           # K
    Register("USER_CTRL", 0x6A, 0x00, {"FIFO_EN": Field(0x40), "I2C_MST_EN": Field(0x20),
                                       "I2C_IF_DIS": Field(0x10), "FIFO_RESET": Field(0x04),
                                       "SIG_COND_RESET": Field(0x01)}),         # K
    # power-on: SLEEP set (D 4.28: "reset value 0x40"); the kernel notes OTP may differ,
    # so the driver always writes it explicitly
    Register("PWR_MGMT_1", 0x6B, 0x40, {"DEVICE_RESET": Field(0x80), "SLEEP": Field(0x40),
                                        "CYCLE": Field(0x20), "TEMP_DIS": Field(0x08),
                                        "CLKSEL": Field(0x07)}),                # K, A
    Register("PWR_MGMT_2", 0x6C, 0x00, {"LP_WAKE_CTRL": Field(0xC0), "STBY_A": Field(0x38),
                                        "STBY_G": Field(0x07)}),                # K, A
    Register("FIFO_COUNTH", 0x72, 0x00, read_only=True, length=2),             # K: big-endian
    Register("FIFO_R_W", 0x74, 0x00),                                          # K
    Register("WHO_AM_I", 0x75, 0x68, read_only=True),                          # K, A
    # MPU-6500/9250 accelerometer offsets XA_OFFSET_H/L 0x77-0x78, YA 0x7A-0x7B, ZA 0x7D-0x7E
    # (T, registers 119-126 "Accelerometer Offset Registers"; K): factory trim as on the 6050
    Register("XA_OFFSET_H", 0x77, 0x00, read_only=True, length=8),
)

#: WHO_AM_I values seen in the field (K; reference section 4.2; kriswiner/MPU9250 issues)
WHO_AM_I_IDS = {0x68: "mpu6050", 0x70: "mpu6500", 0x71: "mpu9250", 0x73: "mpu9255",
                0x74: "mpu6515", 0x75: "mpu6555 (or an unknown clone)", 0x19: "mpu6886",
                0x98: "icm20689", 0x12: "icm20602", 0x11: "icm20600"}
#: chips the driver supports, and which have a magnetometer behind the bypass
SUPPORTED = {"mpu6050": False, "mpu6500": False, "mpu9250": True, "mpu9255": True}

ACCEL_LSB_PER_G = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}             # A, K; D 6.2
GYRO_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}             # A, K; D 6.1
#: DLPF_CFG -> (accel bandwidth Hz, gyro bandwidth Hz), MPU-6050 (K enum, A Bandwidth)
DLPF_HZ = {0: (260, 256), 1: (184, 188), 2: (94, 98), 3: (44, 42), 4: (21, 20), 5: (10, 10),
           6: (5, 5)}
FIFO_SIZE = MPU_FIFO_BYTES      # K hw_info (one table: drivers/rates.py, numpy-free)
#: a FIFO frame with TEMP|XG|YG|ZG|ACCEL enabled: accel 6, temp 2, gyro 6 (register order)
FRAME_BYTES = MPU_FRAME_BYTES
#: temperature: degC = raw / 340 + 36.53 (MPU-6050, A/K); raw / 333.87 + 21 (MPU-6500/9250, T/K)
TEMP_FORMULA = {"mpu6050": (340.0, 36.53), "mpu6500": (333.87, 21.0), "mpu9250": (333.87, 21.0),
                "mpu9255": (333.87, 21.0)}


def dlpf_for_rate(rate_hz: float) -> int:
    """Largest-attenuation DLPF whose bandwidth stays at or above rate/2 (no aliasing
    beyond Nyquist is impossible; this keeps the signal band)."""
    best = 0
    for cfg in range(1, 7):
        if DLPF_HZ[cfg][0] >= rate_hz / 2:
            best = cfg
    return best or 1


@dataclass
class FifoRead:
    acc_g: np.ndarray          #: (k, 3)
    gyro_dps: np.ndarray       #: (k, 3)
    temp_c: np.ndarray         #: (k,)
    reset: bool = False        #: the FIFO was reset (near or after an overflow): samples were lost


class MPU6xxx:
    """Driver for one MPU-6050/6500/9250 at ``addr`` on ``bus`` (not opened here)."""

    def __init__(self, bus: Bus, addr: int = 0x68, expect: str = "mpu6050",
                 clock: Optional[Clock] = None):
        self.bus = bus
        self.addr = addr
        self.expect = expect
        self.clock = clock or bus.clock or RealClock()
        self.chip: Optional[str] = None
        self.accel_range_g = 2
        self.gyro_range_dps = 250
        self.rate_hz = 100.0
        self._cfg: dict = {}
        #: a burst is under way, or an overflowed FIFO awaits its reset: if a bus fault cuts
        #: either short, the FIFO may be left shifted, so the next read resets it first
        self._resync = False

    # -- identification ------------------------------------------------------------
    def identify(self) -> str:
        who = self.bus.read_byte(self.addr, REGMAP.WHO_AM_I.addr)
        found = WHO_AM_I_IDS.get(who)
        a = f"0x{self.addr:02X}"
        if found is None:
            raise ChipMismatch(f"{a} answered WHO_AM_I=0x{who:02X}: not an InvenSense MPU "
                               f"(expected {self.expect.upper()}); check the address")
        if found != self.expect:
            extra = ""
            if self.expect.startswith("mpu925") and found == "mpu6500":
                extra = ": it has no magnetometer (a common relabelled 'MPU9250' board); " \
                        "configure board: mpu6500 to use it as a 6-axis IMU"
            elif found in SUPPORTED:
                extra = f"; configure chip {found} to use it"
            raise ChipMismatch(f"{a} answered WHO_AM_I=0x{who:02X}: an {found.upper()}, not the "
                               f"configured {self.expect.upper()}{extra}")
        self.chip = found
        return found

    def factory_trim(self) -> dict:
        """The chip's factory trim as hex strings (fingerprint of the physical sensor): the
        self-test registers and the accelerometer offset registers (REGMAP comments)."""
        R, b, a = REGMAP, self.bus, self.addr
        chip = self.chip or self.expect
        if chip == "mpu6050":
            st = b.read_block(a, R.SELF_TEST.addr, 4)
            off = b.read_block(a, R.XA_OFFS_H.addr, 6)
        else:
            st = b.read_block(a, R.SELF_TEST_GYRO.addr, 3) + b.read_block(a, R.SELF_TEST.addr, 3)
            raw = b.read_block(a, R.XA_OFFSET_H.addr, 8)
            off = bytes(raw[i] for i in (0, 1, 3, 4, 6, 7))       # 0x79, 0x7C not used
        return {"self_test": st.hex(), "accel_offset": off.hex()}

    # -- setup ---------------------------------------------------------------------
    def setup(self, accel_range_g: int = 2, gyro_range_dps: int = 250, rate_hz: float = 100.0,
              dlpf_cfg: Optional[int] = None, bypass: bool = False) -> None:
        """Reset, wake, configure ranges/DLPF/rate, verify by reading back, start the FIFO."""
        if accel_range_g not in ACCEL_LSB_PER_G:
            raise ValueError(f"accel_range_g {accel_range_g}: allowed {sorted(ACCEL_LSB_PER_G)}")
        if gyro_range_dps not in GYRO_LSB_PER_DPS:
            raise ValueError(f"gyro_range_dps {gyro_range_dps}: allowed {sorted(GYRO_LSB_PER_DPS)}")
        if self.chip is None:
            self.identify()
        dl = dlpf_for_rate(rate_hz) if dlpf_cfg is None else int(dlpf_cfg)
        base = 8000.0 if dl in (0, 7) else 1000.0                    # K / D 4.2
        div = int(round(base / rate_hz)) - 1
        if not 0 <= div <= 255:
            raise ValueError(f"rate_hz {rate_hz}: allowed {base / 256:.2f}..{base:.0f} Hz "
                             f"with DLPF_CFG={dl}")
        R = REGMAP
        b, a = self.bus, self.addr
        b.write_byte(a, R.PWR_MGMT_1.addr, R.encode("PWR_MGMT_1", 0, DEVICE_RESET=1))
        self.clock.sleep(0.1)                                          # K: 100 ms after reset
        # wake before anything else, or the other writes may not take (i2cdevlib#531)
        b.write_byte(a, R.PWR_MGMT_1.addr, R.encode("PWR_MGMT_1", 0, CLKSEL=1))
        self.clock.sleep(0.06)                                         # gyro start-up (K)
        cfg = {
            R.SMPLRT_DIV.addr: div,
            R.CONFIG.addr: R.encode("CONFIG", 0, DLPF_CFG=dl),
            R.GYRO_CONFIG.addr: R.encode("GYRO_CONFIG", 0, FS_SEL=[250, 500, 1000, 2000].index(gyro_range_dps)),
            R.ACCEL_CONFIG.addr: R.encode("ACCEL_CONFIG", 0, AFS_SEL=[2, 4, 8, 16].index(accel_range_g)),
            # LATCH_INT_EN: the status bits (FIFO_OFLOW_INT, read by overflowed()) stay set until
            # INT_STATUS is read, whatever the INT pin does (unused here); kriswiner writes 0x22
            # (../shared/reference/daemon-and-chips.md, bypass row); INT_RD_CLEAR stays 0 (D 4.15)
            R.INT_PIN_CFG.addr: R.encode("INT_PIN_CFG", 0, LATCH_INT_EN=1, I2C_BYPASS_EN=int(bypass)),
            R.INT_ENABLE.addr: R.encode("INT_ENABLE", 0, DATA_RDY_EN=1, FIFO_OFLOW_EN=1),
        }
        if self.chip != "mpu6050":
            cfg[R.ACCEL_CONFIG2.addr] = R.encode("ACCEL_CONFIG2", 0, A_DLPF_CFG=min(dl, 6))
        b.write_verified(a, cfg, "MPU")
        self._cfg = cfg
        self.accel_range_g, self.gyro_range_dps = accel_range_g, gyro_range_dps
        self.rate_hz = base / (div + 1)
        self.fifo_reset()

    def fifo_reset(self) -> None:
        R = REGMAP
        b, a = self.bus, self.addr
        b.write_byte(a, R.USER_CTRL.addr, 0)
        b.write_byte(a, R.FIFO_EN.addr, 0)
        b.write_byte(a, R.USER_CTRL.addr, R.encode("USER_CTRL", 0, FIFO_RESET=1))
        b.write_byte(a, R.FIFO_EN.addr, R.encode("FIFO_EN", 0, TEMP=1, XG=1, YG=1, ZG=1, ACCEL=1))
        b.write_byte(a, R.USER_CTRL.addr, R.encode("USER_CTRL", 0, FIFO_EN=1))
        self.overflowed()               # clears an overflow flag from before the reset
        self._resync = False

    def still_configured(self) -> bool:
        """Cheap check for a silent reset (brown-out): awake and the ranges still set."""
        R = REGMAP
        pm = self.bus.read_byte(self.addr, R.PWR_MGMT_1.addr)
        if R.decode("PWR_MGMT_1", pm, "SLEEP"):
            return False
        return self.bus.read_byte(self.addr, R.ACCEL_CONFIG.addr) == self._cfg.get(R.ACCEL_CONFIG.addr)

    # -- data ----------------------------------------------------------------------
    def fifo_count(self) -> int:
        hi, lo = self.bus.read_block(self.addr, REGMAP.FIFO_COUNTH.addr, 2)
        return (hi << 8) | lo

    def read_fifo(self, max_frames: Optional[int] = None) -> FifoRead:
        """Drain whole frames.  Following the kernel (inv_mpu_ring.c): if the count is
        within 3 frames of the FIFO size the FIFO may already have dropped data, so it
        is reset and the read reports ``reset`` (the caller accounts for the gap); so is a
        burst read after the FIFO overflowed (:meth:`overflowed`: three transactions a batch)."""
        if self._resync:                # a burst or a reset that a bus fault cut short
            self.fifo_reset()
            return FifoRead(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), reset=True)
        size = FIFO_SIZE[self.chip or self.expect]
        count = self.fifo_count()
        if count >= size - 3 * FRAME_BYTES:
            self.fifo_reset()
            return FifoRead(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), reset=True)
        k = count // FRAME_BYTES
        if max_frames is not None:
            k = min(k, max_frames)
        if k == 0:
            return FifoRead(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        self._resync = True             # until the burst and the flag are read, or the reset done
        raw = self.bus.read_block(self.addr, REGMAP.FIFO_R_W.addr, k * FRAME_BYTES, fifo=True)
        if self.overflowed():
            # it overflowed between the count and the burst (a host stalled for more than the
            # 3 frames of margin): the chip dropped its oldest bytes, and as the FIFO's size is
            # not a multiple of a frame, every frame read may be shifted (temperature and gyro
            # bytes read as acceleration) and stays shifted until a reset
            self.fifo_reset()
            return FifoRead(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), reset=True)
        self._resync = False
        return self.parse_frames(raw)

    def overflowed(self) -> bool:
        """Whether the FIFO overflowed since the last call: INT_STATUS.FIFO_OFLOW_INT (D 4.17),
        cleared by this read (INT_PIN_CFG.INT_RD_CLEAR left 0, D 4.15)."""
        st = self.bus.read_byte(self.addr, REGMAP.INT_STATUS.addr)
        return bool(REGMAP.decode("INT_STATUS", st, "FIFO_OFLOW_INT"))

    def parse_frames(self, raw: bytes) -> FifoRead:
        """Whole 14-byte frames -> physical units; a trailing partial frame is ignored."""
        k = len(raw) // FRAME_BYTES
        v = np.frombuffer(raw[:k * FRAME_BYTES], dtype=">i2").reshape(k, 7).astype(float)
        div, off = TEMP_FORMULA[self.chip or self.expect]
        return FifoRead(v[:, 0:3] / ACCEL_LSB_PER_G[self.accel_range_g],
                        v[:, 4:7] / GYRO_LSB_PER_DPS[self.gyro_range_dps],
                        v[:, 3] / div + off)
