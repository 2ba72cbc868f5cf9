"""What answers on a bus, and what each device is (``imucald probe``).

Only ID registers are read (plus, for an MPU-9250, its bypass bit is set so the
AK8963 behind it can answer).  Each candidate address is tried; an address a
kernel driver owns is reported with the driver's name.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

from . import adxl345, ak8963, hmc5883l, itg3200, mpu6050, qmc5883l
from .bus import AddressBusy, Bus, BusError, NoAcknowledge, kernel_driver_for

__all__ = ["Found", "probe", "detect_board", "magnetometer"]

CANDIDATES = (0x0C, 0x0D, 0x1D, 0x1E, 0x53, 0x68, 0x69)


@dataclass
class Found:
    addr: int
    chip: str                 #: e.g. 'mpu6050', 'adxl345', 'qmc5883l', 'busy', 'unknown'
    detail: str

    def line(self) -> str:
        return f"0x{self.addr:02X}  {self.chip:<10} {self.detail}"


def _identify(bus: Bus, addr: int) -> Found:
    if addr in (0x68, 0x69):
        who = bus.read_byte(addr, mpu6050.REGMAP.WHO_AM_I.addr)
        chip = mpu6050.WHO_AM_I_IDS.get(who)
        if chip is not None:
            note = {"mpu6500": "accel + gyro, no magnetometer (often sold as 'MPU9250')",
                    "mpu9250": "accel + gyro + AK8963 magnetometer behind the bypass"}.get(chip, "accel + gyro")
            return Found(addr, chip, f"WHO_AM_I=0x{who:02X}: {chip.upper()}, {note}")
        w = bus.read_byte(addr, itg3200.REGMAP.WHO_AM_I.addr)
        if itg3200.REGMAP.decode("WHO_AM_I", w, "ID") == itg3200.ID:
            return Found(addr, "itg3200", f"WHO_AM_I=0x{w:02X}: ITG-3200 gyro")
        return Found(addr, "unknown", f"answers, WHO_AM_I(0x75)=0x{who:02X}, reg 0x00=0x{w:02X}: "
                                      f"not a supported chip (an RTC such as the DS3231 also lives at 0x68)")
    if addr in adxl345.ADDRS:
        d = bus.read_byte(addr, adxl345.REGMAP.DEVID.addr)
        if d == adxl345.DEVID:
            return Found(addr, "adxl345", "DEVID=0xE5: ADXL345 accelerometer")
        return Found(addr, "unknown", f"answers, DEVID=0x{d:02X}: not an ADXL345")
    if addr == hmc5883l.ADDR:
        ident = bus.read_block(addr, hmc5883l.REGMAP.ID_A.addr, 3)
        if ident == b"H43":
            return Found(addr, "hmc5883l", "ID='H43': HMC5883L magnetometer")
        return Found(addr, "unknown", f"answers, ID={ident!r}: not an HMC5883L")
    if addr == qmc5883l.ADDR:
        cid = bus.read_byte(addr, qmc5883l.REGMAP.CHIP_ID.addr)
        if cid == qmc5883l.CHIP_ID:
            return Found(addr, "qmc5883l", "CHIP_ID=0xFF: QMC5883L magnetometer (often sold as "
                                           "'HMC5883L' on GY-273 / GY-85 boards)")
        return Found(addr, "unknown", f"answers, reg 0x0D=0x{cid:02X}: not a QMC5883L")
    if addr == ak8963.ADDR:
        wia = bus.read_byte(addr, ak8963.REGMAP.WIA.addr)
        if wia == ak8963.WIA_ID:
            return Found(addr, "ak8963", "WIA=0x48: AK8963 magnetometer (MPU-9250 bypass)")
        return Found(addr, "unknown", f"answers, WIA=0x{wia:02X}")
    return Found(addr, "unknown", "answers")


def probe(bus: Bus, bus_num: Optional[int] = None, sysfs: str = "/sys/bus/i2c/devices"
          ) -> List[Found]:
    out: List[Found] = []
    for addr in CANDIDATES:
        drv = kernel_driver_for(bus_num, addr, sysfs)
        try:
            f = _identify(bus, addr)
        except AddressBusy:
            out.append(Found(addr, "busy", f"owned by kernel driver '{drv or 'unknown'}' (i2cdetect "
                                           f"shows UU): remove its overlay or unbind it to use imucald"))
            continue
        except NoAcknowledge:
            continue
        except BusError as e:
            out.append(Found(addr, "error", str(e)))
            continue
        out.append(f)
        if f.chip == "mpu9250" and not any(x.addr == ak8963.ADDR for x in out):
            try:      # open the bypass so the AK8963 can answer
                R = mpu6050.REGMAP
                bus.write_byte(addr, R.PWR_MGMT_1.addr, R.encode("PWR_MGMT_1", 0, CLKSEL=1))
                bus.write_byte(addr, R.USER_CTRL.addr, 0)
                bus.write_byte(addr, R.INT_PIN_CFG.addr, R.encode("INT_PIN_CFG", 0, I2C_BYPASS_EN=1))
                out.append(_identify(bus, ak8963.ADDR))
            except NoAcknowledge:
                out.append(Found(ak8963.ADDR, "missing", "no AK8963 behind the bypass: this "
                                                         "'MPU9250' has no working magnetometer"))
    return sorted(out, key=lambda f: f.addr)


MAGNETOMETERS = ("hmc5883l", "qmc5883l")


def detect_board(found: List[Found]) -> Optional[str]:
    """Board name from probe results: 9dof (0x53 + 0x68/0x69 + an HMC5883L at 0x1E or a
    QMC5883L at 0x0D), mpu9250, mpu6500, mpu6050, or gy273 (a magnetometer alone)."""
    chips = {f.chip for f in found}
    if "adxl345" in chips and "itg3200" in chips and chips & set(MAGNETOMETERS):
        return "9dof"
    for c in ("mpu9250", "mpu6500", "mpu6050"):
        if c in chips:
            return c
    if chips & set(MAGNETOMETERS):
        return "gy273"
    return None


def magnetometer(found: List[Found]) -> Optional[str]:
    """The 9dof/gy273 magnetometer probe found (the HMC5883L if both answer)."""
    chips = [f.chip for f in found]
    return next((m for m in MAGNETOMETERS if m in chips), None)
