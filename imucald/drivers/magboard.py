"""GY-273-style board: a magnetometer alone (no accelerometer, no gyro)."""
from __future__ import annotations

from typing import Optional

import numpy as np

from . import hmc5883l, qmc5883l
from .board import Board, SampleBatch
from .bus import Bus, Clock
from .magnetometer import MAG_DEFAULT_HZ, mag_name, mag_setup, open_magnetometer

__all__ = ["MagOnlyBoard"]


class MagOnlyBoard(Board):
    """A magnetometer alone (GY-273: an HMC5883L or a QMC5883L, found by ID unless
    ``mag`` names one).  No FIFO: the chip is polled and each new reading is one
    sample; readings the chip reports as overwritten unread (QMC5883L DOR) are
    reported as a gap.  There is no accelerometer or gyro (NaN);
    ``temp`` is the QMC5883L's die temperature, whose offset is not calibrated
    (relative only), NaN for the HMC5883L."""

    name = "gy273"
    has_mag = True
    has_acc = False

    def __init__(self, bus: Bus, addr: Optional[int] = None, rate_hz: Optional[float] = None,
                 clock: Optional[Clock] = None, mag: str = "auto"):
        super().__init__(bus, clock, rate_hz or 0.0)
        self.mag_choice, self.mag_addr, self.mag = mag, addr, None
        self.req_rate_hz = rate_hz

    def chips(self):
        return {"mag": mag_name(self.mag) if self.mag is not None else self.mag_choice}

    def _init_chips(self):
        if self.mag is None:
            a = {} if self.mag_addr is None else {"hmc_addr": self.mag_addr, "qmc_addr": self.mag_addr}
            self.mag = open_magnetometer(self.bus, self.mag_choice, self.clock, **a)
        name = mag_name(self.mag)
        allowed = sorted((qmc5883l.RATES_HZ if name == "qmc5883l" else hmc5883l.RATES_HZ).values())
        want = self.req_rate_hz or MAG_DEFAULT_HZ[name]
        # the fastest output rate the chip has at or below the one asked for
        rate = max([r for r in allowed if r <= want + 1e-9] or allowed[:1])
        mag_setup(self.mag, rate)
        self.rate_hz = rate

    def _configured(self):
        return self.mag.still_configured()

    def _flush(self):
        self.mag.read()

    def _read(self, now):
        before = getattr(self.mag, "skipped", 0)
        mag, _ = self.mag.read()
        lost = getattr(self.mag, "skipped", 0) - before     # DOR: at least one reading lost
        if mag is None:
            return self._emit(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), None, False, lost)
        temp = getattr(self.mag, "temp_rel_c", np.nan)
        nan3 = np.full((1, 3), np.nan)
        return self._emit(nan3, nan3.copy(), np.array([temp]), mag, True, lost)

    def read_batch(self, wait: bool = True, batch_s: Optional[float] = None) -> SampleBatch:
        # the QMC5883L clears DRDY when its data are read: poll at twice its rate; the
        # HMC5883L's RDY stays set until the next conversion: poll at its rate
        k = 0.5 if mag_name(self.mag) == "qmc5883l" else 1.0
        return self._polled(wait, batch_s, k / self.rate_hz)
