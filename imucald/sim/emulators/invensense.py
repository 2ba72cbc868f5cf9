"""Emulated InvenSense chips: MPU-6050/6500/9250 (FIFO, sleep, reset, die temperature)
and the MPU-9250's AK8963 magnetometer behind its bypass gate."""
from __future__ import annotations

from typing import Dict, Optional

import numpy as np

from ...drivers import ak8963 as _ak, mpu6050 as _mpu
from ...specs import ACCEL, GYRO, MAG
from .base import EmuDevice, i16

__all__ = ["EmuMPU6xxx", "EmuAK8963"]


class EmuMPU6xxx(EmuDevice):
    """MPU-6050 (WHO_AM_I 0x68) or MPU-6500/9250 (0x70/0x71) accel + gyro + temperature."""

    regmap = _mpu.REGMAP
    fifo_ports = (_mpu.REGMAP.FIFO_R_W.addr,)

    def __init__(self, addr, clock, motion, truth, rng, variant: str = "mpu6050",
                 trim: Optional[Dict[str, bytes]] = None):
        """``trim``: the factory trim the chip reports ({"self_test": 4 bytes (3 gyro + 3
        accel = 6 on the 6500/9250), "accel_offset": 6 bytes}), drawn from a child of
        ``rng`` when None (the parent's stream is not consumed, so other draws do not move)."""
        self.variant = variant
        self.trim = dict(trim) if trim is not None else _draw_trim(rng, variant)
        self.who = {"mpu6050": 0x68, "mpu6500": 0x70, "mpu9250": 0x71}[variant]
        self.spec_a = ACCEL["mpu6050" if variant == "mpu6050" else "mpu9250"]
        self.spec_g = GYRO["mpu6050" if variant == "mpu6050" else "mpu9250"]
        self.fifo_size = _mpu.FIFO_SIZE[variant]
        super().__init__(addr, clock, motion, truth, rng)

    def on_reset(self):
        # the factory trim reloads at power-on and after DEVICE_RESET (reference 4.1)
        R, st, off = self.regmap, self.trim["self_test"], self.trim["accel_offset"]
        if self.variant == "mpu6050":
            self.regs[R.SELF_TEST.addr:R.SELF_TEST.addr + 4] = st
            self.regs[R.XA_OFFS_H.addr:R.XA_OFFS_H.addr + 6] = off
        else:
            self.regs[R.SELF_TEST_GYRO.addr:R.SELF_TEST_GYRO.addr + 3] = st[:3]
            self.regs[R.SELF_TEST.addr:R.SELF_TEST.addr + 3] = st[3:]
            for i, a in enumerate((0x77, 0x78, 0x7A, 0x7B, 0x7D, 0x7E)):
                self.regs[a] = off[i]
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
        # white noise over the whole DLPF band: sampling at ODR does not shrink it, a band
        # wider than ODR/2 aliases its full variance into each sample
        acc = self.truth.accel_raw(m["f"]) + self._noise(
            self.spec_a.noise_density_g_rthz, bw_a, (n, 3))
        gyr = self.truth.gyro_raw(m["w"]) + self._noise(
            self.spec_g.noise_density_dps_rthz, bw_g, (n, 3))
        div, off = _mpu.TEMP_FORMULA[self.variant]
        vals = np.empty((n, 7), np.int64)
        vals[:, 0:3] = i16(acc * a_lsb)
        vals[:, 3] = i16((m["temp"] - off) * div)
        vals[:, 4:7] = i16(gyr * g_lsb)
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


def _draw_trim(rng: np.random.Generator, variant: str) -> Dict[str, bytes]:
    """Factory trim of one emulated chip: self-test codes and accelerometer offsets of a few
    thousand LSB, as real parts report, from a child generator of ``rng``."""
    bg = rng.bit_generator
    ss = getattr(bg, "seed_seq", None) or getattr(bg, "_seed_seq", None)
    child = np.random.default_rng(ss.spawn(1)[0]) if ss is not None else np.random.default_rng()
    n_st = 4 if variant == "mpu6050" else 6
    st = bytes(child.integers(0, 256, n_st, dtype=np.uint8).tolist())
    off = child.integers(-3000, 3000, 3).astype(">i2").tobytes()
    return {"self_test": st, "accel_offset": off}


class EmuAK8963(EmuDevice):
    """AK8963, visible at 0x0C only while the host MPU-9250 has its bypass enabled."""

    regmap = _ak.REGMAP

    def __init__(self, addr, clock, motion, truth, rng, host: EmuMPU6xxx, asa: Optional[bytes] = None):
        """``asa``: the 3 fuse-ROM sensitivity-adjustment bytes (drawn from rng when None)."""
        self.host = host
        drawn = np.array(rng.integers(160, 190, 3), dtype=np.uint8)        # fuse ROM
        self.asa_raw = drawn if asa is None else np.frombuffer(bytes(asa), dtype=np.uint8).copy()
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
        self.data = i16(counts, -32760, 32760).astype("<i2").tobytes()
        self.drdy = True
