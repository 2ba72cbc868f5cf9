"""Datasheet figures of the supported chips: a leaf module (it imports nothing from imucald)
that the calibration (priors, bounds), the simulator and the emulated chips all read.

Sources (as collected in ../shared/reference/error-models.md section 2, with the
datasheet section named beside each figure):

* MPU-6050: PS-MPU-6000A-00 rev 3.4 section 6.2 (accel) and 6.1 (gyro);
  temperature T = raw/340 + 36.53 (register map RM-MPU-6000A, TEMP_OUT).
* MPU-9250: PS-MPU-9250A-01 rev 1.0 Tables 1-2; AK8963 16-bit 0.15 uT/LSB
  (RM-MPU-9250A-00 Table 4).
* ADXL345: datasheet Rev E Table 1, "Noise performance" section.
* ITG-3200: PS-ITG-3200A rev 1.4 section 3.1 (figures marked [R] in the
  reference note: initial ZRO +-40 dps, 14.375 LSB/(deg/s)).
* HMC5883L: Honeywell datasheet, gain table p.13 (1090 LSB/G default).

Tolerances are the datasheet's limits; :func:`imucald.sim.sensor.draw_params`
draws true errors as N(0, tol/2) clipped to +-tol.
"""
from __future__ import annotations

from typing import Dict, NamedTuple, Optional

__all__ = ["AccelSpec", "GyroSpec", "MagSpec", "ACCEL", "GYRO", "MAG", "BOARDS", "recording_chips"]


class AccelSpec(NamedTuple):
    name: str
    range_g: float                  #: full scale, +- g
    lsb_g: float                    #: one count, g
    noise_density_g_rthz: float     #: white noise density, g/sqrt(Hz)
    bias_tol_g: tuple               #: zero-g tolerance per axis, +- g
    scale_tol: float                #: sensitivity tolerance, fraction
    cross_axis_tol: float           #: cross-axis sensitivity, fraction (~ rad)
    bias_tempco_g_per_c: tuple      #: zero-g change per degC (datasheet-implied)
    scale_tempco_per_c: float       #: sensitivity change per degC, fraction
    nonlinearity_fs: float          #: best-fit straight line, fraction of full scale
    temp_lsb_c: Optional[float]     #: temperature sensor resolution, degC (None: no sensor)


class GyroSpec(NamedTuple):
    name: str
    range_dps: float
    lsb_dps: float
    noise_density_dps_rthz: float
    bias_tol_dps: float
    scale_tol: float
    cross_axis_tol: float
    bias_tempco_dps_per_c: float
    g_sensitivity_dps_per_g: float
    temp_lsb_c: Optional[float]


class MagSpec(NamedTuple):
    name: str
    range_gauss: float
    lsb_gauss: float
    noise_gauss: float              #: per-sample rms noise, gauss
    scale_tol: float
    cross_axis_tol: float


ACCEL: Dict[str, AccelSpec] = {
    # MPU-6050 PS rev 3.4 s6.2: 16384 LSB/g at +-2 g, 400 ug/rtHz, zero-g X,Y +-50 mg, Z +-80 mg,
    # zero-g change X,Y +-35 mg and Z +-60 mg over 0..70 C, sensitivity +-3 %, +-0.02 %/C,
    # nonlinearity 0.5 %, cross-axis +-2 %.
    "mpu6050": AccelSpec("mpu6050", 2.0, 1 / 16384, 400e-6, (0.050, 0.050, 0.080), 0.03, 0.02,
                         (0.035 / 70, 0.035 / 70, 0.060 / 70), 0.0002, 0.005, 1 / 340),
    # MPU-9250 PS rev 1.0 Table 2: 300 ug/rtHz, zero-g X,Y +-60 mg, Z +-80 mg, +-1.5 mg/C,
    # sensitivity +-3 %, +-0.026 %/C, nonlinearity 0.5 %, cross-axis 2 %.
    # Temperature: 333.87 LSB/C (RM-MPU-9250A-00 TEMP_OUT).
    "mpu9250": AccelSpec("mpu9250", 2.0, 1 / 16384, 300e-6, (0.060, 0.060, 0.080), 0.03, 0.02,
                         (0.0015, 0.0015, 0.0015), 0.00026, 0.005, 1 / 333.87),
    # ADXL345 Table 1: full resolution 3.9 mg/LSB, 290 ug/rtHz X,Y and 430 ug/rtHz Z (one
    # density used: the larger), 0 g offset X,Y +-150 mg, Z +-250 mg, +-0.4/1.2 mg/C,
    # sensitivity 230..282 LSB/g (~+-10 %), +-0.01 %/C, nonlinearity 0.5 %, cross-axis 1 %.
    "adxl345": AccelSpec("adxl345", 16.0, 0.0039, 430e-6, (0.150, 0.150, 0.250), 0.10, 0.01,
                         (0.0004, 0.0004, 0.0012), 0.0001, 0.005, None),
}

GYRO: Dict[str, GyroSpec] = {
    # MPU-6050 s6.1: 131 LSB/(dps) at +-250 dps, 0.005 dps/rtHz, ZRO +-20 dps, ~0.16 dps/C,
    # sensitivity +-3 %, cross-axis 2 %, linear-acceleration sensitivity 0.1 dps/g.
    "mpu6050": GyroSpec("mpu6050", 250.0, 1 / 131, 0.005, 20.0, 0.03, 0.02, 0.16, 0.1, 1 / 340),
    # MPU-9250 Table 1: 0.01 dps/rtHz, ZRO +-5 dps, sensitivity +-3 %, cross-axis 2 %.
    "mpu9250": GyroSpec("mpu9250", 250.0, 1 / 131, 0.01, 5.0, 0.03, 0.02, 0.24, 0.1, 1 / 333.87),
    # ITG-3200 PS rev 1.4 s3.1 [R]: +-2000 dps at 14.375 LSB/dps, 0.03 dps/rtHz, ZRO +-40 dps,
    # sensitivity +-6 %; temperature T = 35 + (raw + 13200)/280 C.
    "itg3200": GyroSpec("itg3200", 2000.0, 1 / 14.375, 0.03, 40.0, 0.06, 0.02, 0.03, 0.1, 1 / 280),
}

MAG: Dict[str, MagSpec] = {
    # HMC5883L: 12-bit, gain 1090 LSB/G at +-1.3 G (default), ~2 mG resolution, gain
    # tolerance +-5 % and cross-axis +-0.2 %FS/G [R].
    "hmc5883l": MagSpec("hmc5883l", 1.3, 1 / 1090, 0.002, 0.05, 0.01),
    # QMC5883L datasheet rev 1.0: 16-bit, 12000 LSB/G at +-2 G, field resolution 2 mG;
    # gain and cross-axis tolerances taken as the HMC5883L's (the datasheet table is not
    # in the sources read).  The real GY-273 recording (tomisuarez_qmc5883l) shows
    # 1.8-4.6 mG per-sample noise at OSR 512, 50 Hz.
    "qmc5883l": MagSpec("qmc5883l", 2.0, 1 / 12000, 0.002, 0.05, 0.01),
    # AK8963 16-bit: 0.15 uT/LSB = 1.5 mG/LSB, +-4912 uT.
    "ak8963": MagSpec("ak8963", 49.12, 0.0015, 0.004, 0.05, 0.01),
}

#: board name -> (accel, gyro, mag) chip names; None where the board has no such sensor.
BOARDS = {
    "mpu6050": ("mpu6050", "mpu6050", None),
    "9dof": ("adxl345", "itg3200", "hmc5883l"),
    "9dof-qmc": ("adxl345", "itg3200", "qmc5883l"),     # a 9DOF/GY-85 board with the QMC5883L
    "mpu9250": ("mpu9250", "mpu9250", "ak8963"),
}


def recording_chips(meta) -> dict:
    """{accel, gyro, mag: chip} of a recording: its ``chips`` meta (``accel=mpu6050,...``,
    written by ``imucald record``), else the board's usual chips (a simulated or converted
    recording); {} for an unknown board."""
    chips = dict(kv.split("=", 1) for kv in str(meta.get("chips", "")).split(",") if "=" in kv)
    if not chips:
        chips = {k: v for k, v in zip(("accel", "gyro", "mag"), BOARDS.get(meta.get("board", ""), ()))
                 if v is not None}
    return chips
