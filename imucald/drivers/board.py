"""Board abstraction: whatever the chips, timestamped batches in physical units.

A :class:`SampleBatch` holds n samples with a sequence number each; the daemon
never sees a register.  Timestamps come from the sample index and the chip's
configured period (not from Python wall time), anchored at start-up; when
samples are lost (FIFO overflow, a device reset, a bus fault) the sequence
number jumps by the estimated number lost and the gap is reported in the batch,
never silently.

Boards recover by themselves from transient bus faults and from a chip that
reset under them (they re-initialise it); identification and configuration
errors at start-up are raised as one-line :class:`~imucald.errors.UserError`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np

from .adxl345 import ADXL345, FifoCut
from .adxl345 import FIFO_DEPTH as ADXL_FIFO_DEPTH
from .ak8963 import AK8963
from .bus import Bus, BusError, Clock, RealClock
from .itg3200 import ITG3200
from .magnetometer import MAG_CHIPS, MAG_DEFAULT_HZ, mag_name, mag_setup, open_magnetometer
from .mpu6050 import MPU6xxx

__all__ = ["SampleBatch", "Board", "MPUBoard", "NineDofBoard", "make_board", "merge_batches",
           "BOARD_NAMES", "MAG_CHIPS"]

BOARD_NAMES = ("mpu6050", "mpu6500", "mpu9250", "9dof", "gy273")


@dataclass
class SampleBatch:
    t: np.ndarray                      #: s since the board started, (n,)
    seq: np.ndarray                    #: sample sequence numbers, (n,) int64
    acc: np.ndarray                    #: g, body frame (n, 3)
    gyro: np.ndarray                   #: deg/s (n, 3)
    temp: np.ndarray                   #: degC (n,)
    mag: Optional[np.ndarray] = None   #: gauss (n, 3), the latest reading held
    mag_fresh: Optional[np.ndarray] = None   #: True where mag is a new reading
    gaps: List[Tuple[int, int]] = field(default_factory=list)  #: (first missing seq, count)

    def __len__(self):
        return len(self.t)


@dataclass
class BoardStats:
    samples: int = 0
    gaps: int = 0
    missing: int = 0
    reinits: int = 0
    bus_faults: int = 0
    fifo_resets: int = 0

    def as_dict(self):
        return dict(self.__dict__)


class Board:
    name = "board"
    has_mag = False
    has_acc = True

    def __init__(self, bus: Bus, clock: Optional[Clock] = None, rate_hz: float = 100.0):
        self.bus = bus
        self.clock = clock or bus.clock or RealClock()
        self.rate_hz = rate_hz
        self.stats = BoardStats()
        self.seq = 0
        self.t0: Optional[float] = None
        self._last_ok = None
        self._last_check = None
        self._next_poll: Optional[float] = None
        self.mag_last: Optional[np.ndarray] = None

    # subclasses: _init_chips(), _read() -> (acc, gyro, temp, mag or None, lost_estimate), _configured()
    #: after (re-)initialisation, data for this long is discarded (sensor start-up,
    #: DLPF settling; the ITG3200 reads zeros until its first conversion)
    settle_s = 0.1
    #: transient bus faults are only counted at first; if reads keep failing this long,
    #: the chips are re-initialised
    reinit_after_s = 0.5

    def chips(self) -> dict:
        """Chip names by role (accel, gyro, mag), for the stream, status and recordings."""
        return {}

    def fingerprint(self) -> dict:
        """What identifies this physical sensor (after :meth:`start`): board, bus, and per chip
        its address, ID and any factory trim it exposes (MPU self-test and accelerometer
        offset registers, AK8963 fuse ROM).  Chips without trim (ADXL345, ITG3200, the
        magnetometers) are told apart by bus and address only."""
        return {"board": self.name, "bus": getattr(self.bus, "name", "?"),
                "chips": {role: {"chip": c} for role, c in self.chips().items()}}

    def start(self) -> None:
        self._last_ok = self._last_check = self.clock.now()
        self._init_chips()
        self._settle()
        self.t0 = self.clock.now()
        self._last_ok = self._last_check = self.t0
        self._fault_since = None

    def _settle(self) -> None:
        """Wait, then drop what arrived (the caller accounts for it as a reported gap)."""
        self.clock.sleep(self.settle_s)
        self._flush()

    def _emit(self, acc, gyro, temp, mag, fresh_last: bool, lost: int) -> SampleBatch:
        gaps = []
        if lost > 0:
            gaps.append((self.seq, lost))
            self.seq += lost
            self.stats.gaps += 1
            self.stats.missing += lost
        n = len(acc)
        seq = np.arange(self.seq, self.seq + n, dtype=np.int64)
        self.seq += n
        self.stats.samples += n
        t = seq / self.rate_hz
        mg = fr = None
        if self.has_mag:
            if mag is not None:
                self.mag_last = mag
            held = self.mag_last if self.mag_last is not None else np.full(3, np.nan)
            mg = np.broadcast_to(held, (n, 3)).copy()
            fr = np.zeros(n, bool)
            if fresh_last and n:
                fr[-1] = True
        return SampleBatch(t, seq, acc, gyro, temp, mg, fr, gaps)

    def read_batch(self, wait: bool = True, batch_s: float = 0.02) -> SampleBatch:
        """Samples since the last call.  With ``wait``, sleeps one batch period first
        (the only sleep in the sampling path: waiting for data)."""
        if wait:
            # sleep to the next poll deadline (not a fixed period), so processing time
            # does not stretch the poll interval
            now = self.clock.now()
            nxt = (now if self._next_poll is None else self._next_poll) + batch_s
            if nxt < now - batch_s:
                nxt = now
            self.clock.sleep(nxt - now)
            self._next_poll = nxt
        now = self.clock.now()
        try:
            if now - self._last_check > 1.0:           # cheap check for a silent reset
                self._last_check = now
                if not self._configured():
                    return self._recover(now, "the chip lost its configuration (reset or brown-out)")
            out = self._read(now)
            self._last_ok = max(self._last_ok, now)
            self._fault_since = None
            return out
        except BusError as e:
            # a glitch (retries exhausted): the chip's FIFO keeps sampling meanwhile, so
            # only re-initialise when the faults persist
            self.stats.bus_faults += 1
            self.last_fault = str(e)
            if self._fault_since is None:
                self._fault_since = now
            if now - self._fault_since >= self.reinit_after_s:
                return self._recover(now, str(e))
            return self._empty()

    def _polled(self, wait: bool, batch_s: Optional[float], period: float) -> SampleBatch:
        """Chips without a FIFO: poll every ``period`` and return the polls of ``batch_s``
        together."""
        if batch_s is None or batch_s <= period:
            return Board.read_batch(self, wait, period)
        parts = []
        t_end = self.clock.now() + batch_s
        while True:
            parts.append(Board.read_batch(self, wait, period))
            if self.clock.now() >= t_end - 0.5 * period:
                break
        return merge_batches(parts)

    def _empty(self) -> SampleBatch:
        return self._emit(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), None, False, 0)

    def _recover(self, now: float, why: str) -> SampleBatch:
        """Re-initialise and account for the samples lost since the last good read."""
        self.last_fault = why
        try:
            self._init_chips()
            self._settle()
            self.stats.reinits += 1
        except BusError:
            self.stats.bus_faults += 1
            return self._empty()
        self._fault_since = None
        after = self.clock.now()
        lost = max(0, int(round((after - self._last_ok) * self.rate_hz)))
        self._last_ok = after
        self._last_check = after
        return self._emit(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), None, False, lost)


class MPUBoard(Board):
    """MPU-6050 / MPU-6500 / MPU-9250 (+ AK8963 through the bypass), read through the FIFO."""

    def __init__(self, bus: Bus, chip: str = "mpu6050", addr: int = 0x68, accel_range_g: int = 2,
                 gyro_range_dps: int = 250, rate_hz: float = 100.0, clock: Optional[Clock] = None):
        super().__init__(bus, clock, rate_hz)
        self.name = chip
        self.has_mag = chip == "mpu9250"
        self.mpu = MPU6xxx(bus, addr, chip, self.clock)
        self.ak = AK8963(bus, clock=self.clock) if self.has_mag else None
        self.cfg = dict(accel_range_g=accel_range_g, gyro_range_dps=gyro_range_dps, rate_hz=rate_hz)
        self._mag_next = 0.0

    @property
    def gyro_range_dps(self) -> float:
        """The gyro's full scale as set up, deg/s (GYRO_CONFIG FS_SEL)."""
        return float(self.cfg["gyro_range_dps"])

    def chips(self):
        c = {"accel": self.name, "gyro": self.name}
        return {**c, "mag": "ak8963"} if self.has_mag else c

    def fingerprint(self):
        ch = {"mpu": {"chip": self.mpu.chip or self.name, "address": f"0x{self.mpu.addr:02X}",
                      **self.mpu.factory_trim()}}
        if self.ak is not None:
            ch["ak8963"] = {"address": f"0x{self.ak.addr:02X}", "asa": bytes(self.ak.asa_raw).hex()}
        return {"board": self.name, "bus": getattr(self.bus, "name", "?"), "chips": ch}

    def _init_chips(self):
        self.mpu.chip = None
        self.mpu.identify()
        self.mpu.setup(bypass=self.has_mag, **self.cfg)
        self.rate_hz = self.mpu.rate_hz
        if self.ak is not None:
            self.ak.setup()

    def _configured(self):
        return self.mpu.still_configured()

    def _flush(self):
        self.mpu.fifo_reset()

    def _read(self, now):
        fr = self.mpu.read_fifo()
        lost = 0
        if fr.reset:
            self.stats.fifo_resets += 1
            # counted to the reset, not to ``now`` (before the count was read): an overflow
            # between the count and the burst means the host stalled after ``now``, and the
            # samples after the reset start there (read_batch keeps the later _last_ok)
            after = self.clock.now()
            lost = max(1, int(round((after - self._last_ok) * self.rate_hz)))
            self._last_ok = after
        mag, fresh = None, False
        if self.ak is not None and now >= self._mag_next:
            mag, _ = self.ak.read()
            fresh = mag is not None
            self._mag_next = now + 1.0 / 100.0
        return self._emit(fr.acc_g, fr.gyro_dps, fr.temp_c, mag, fresh, lost)


class NineDofBoard(Board):
    """ADXL345 + ITG3200 + a magnetometer (HMC5883L or QMC5883L, found by ID unless
    ``mag`` names one).  The ADXL345 FIFO sets the sample clock; the gyro (no FIFO)
    and the magnetometer are read once per poll and held."""

    #: the ITG-3200's full scale, deg/s: DLPF_FS's FS_SEL must be 3, +-2000 deg/s (Linux
    #: drivers/iio/gyro/itg3200_core.c ITG3200_DLPF_FS_SEL_2000; drivers/itg3200.py FS_SEL_2000)
    gyro_range_dps = 2000.0

    name = "9dof"
    has_mag = True

    def __init__(self, bus: Bus, accel_addr: int = 0x53, gyro_addr: int = 0x68,
                 mag_addr: Optional[int] = None, accel_range_g: int = 16, rate_hz: float = 100.0,
                 mag_rate_hz: Optional[float] = None, clock: Optional[Clock] = None, mag: str = "auto"):
        super().__init__(bus, clock, rate_hz)
        self.acc = ADXL345(bus, accel_addr, self.clock)
        self.gyr = ITG3200(bus, gyro_addr, self.clock)
        self.mag_choice, self.mag_addr = mag, mag_addr
        self.mag = None
        self.accel_range_g, self.mag_rate_hz = accel_range_g, mag_rate_hz
        self._mag_next = 0.0
        #: the entries a bus fault cut a FIFO read short after (adxl345.FifoCut): emitted
        #: with the next read, whose loss is then counted by time
        self._carry: Optional[np.ndarray] = None

    def chips(self):
        return {"accel": "adxl345", "gyro": "itg3200",
                "mag": mag_name(self.mag) if self.mag is not None else self.mag_choice}

    def fingerprint(self):
        ch = {"adxl345": {"address": f"0x{self.acc.addr:02X}"}, "itg3200": {"address": f"0x{self.gyr.addr:02X}"}}
        if self.mag is not None:
            ch[mag_name(self.mag)] = {"address": f"0x{self.mag.addr:02X}"}
        return {"board": self.name, "bus": getattr(self.bus, "name", "?"), "chips": ch}

    def _init_chips(self):
        self.acc.setup(self.accel_range_g, self.rate_hz)
        self.gyr.setup(self.rate_hz)
        if self.mag is None:
            a = {} if self.mag_addr is None else {"hmc_addr": self.mag_addr, "qmc_addr": self.mag_addr}
            self.mag = open_magnetometer(self.bus, self.mag_choice, self.clock, **a)
        name = mag_name(self.mag)
        self.mag_rate_hz = self.mag_rate_hz or MAG_DEFAULT_HZ[name]
        mag_setup(self.mag, self.mag_rate_hz)
        self.rate_hz = self.acc.rate_hz

    def _configured(self):
        return self.acc.still_configured() and self.gyr.still_configured() and \
            self.mag.still_configured()

    def _flush(self):
        self._carry = None          # a re-initialisation counts them lost by time (_recover)
        self.acc.read_fifo()

    def _read(self, now):
        try:
            acc, overrun = self.acc.read_fifo()
        except FifoCut as e:
            # the entries popped before the fault are kept for the next read (read_batch
            # counts the fault); the loss is counted then, by time
            self._keep(e.acc_g)
            raise
        if overrun:
            self.stats.fifo_resets += 1
        try:
            g, temp = self.gyr.read() if len(acc) or self._carry is not None else (np.zeros(3), np.nan)
            mag, fresh = None, False
            if now >= self._mag_next:
                mag, _ = self.mag.read()
                fresh = mag is not None
                self._mag_next = now + 1.0 / self.mag_rate_hz
        except BusError:
            # the entries drained are popped from the chip: kept, as after a cut (an overrun's
            # loss is then counted by time too, at the next read)
            self._keep(acc)
            raise
        cut, self._carry = self._carry, None
        if cut is not None:
            acc = np.concatenate([cut, acc])
        lost = self._loss_by_time(len(acc), now) if overrun or cut is not None else 0
        n = len(acc)
        return self._emit(acc, np.broadcast_to(g, (n, 3)).copy(), np.full(n, temp), mag, fresh, lost)

    def _keep(self, acc: np.ndarray) -> None:
        """Hold entries popped from the ADXL345 for the next read (a bus fault came before
        they could be emitted); that read counts the loss by time."""
        self._carry = acc if self._carry is None else np.concatenate([self._carry, acc])

    def _loss_by_time(self, n_read: int, before: float) -> int:
        """Samples lost since the last good read, when the entry counts cannot tell: the
        ADXL345 overwrote some (stream mode, full FIFO), or a bus fault cut a read short
        after popping entries (FifoCut: those read are in ``n_read``; the failed burst's own
        entry may be gone).  The ones the chip made up to now, less the ``n_read`` read and
        what already waits in the FIFO again (what came during the reads).  Counted to the
        end of the read, not to the time ``before`` the entry count: a host stalled between
        the count and the data reads loses more than the count says (each new sample
        overwrites the oldest), and counted short every later sample's time stays behind by
        the stall.  The gap is placed before the batch's rows (a cut's carried rows
        included: their times may be late by the one entry the failed burst took)."""
        after = self.clock.now()
        try:
            waiting = self.acc.entries()
        except BusError as e:
            # the samples read are kept; what waits is taken as what the chip made during the
            # read (right unless the FIFO overflowed in it, when that many too few are counted)
            self.stats.bus_faults += 1
            self.last_fault = str(e)
            waiting = min(ADXL_FIFO_DEPTH, max(0, int(round((after - before) * self.rate_hz))))
        made = int(round((after - self._last_ok) * self.rate_hz))
        self._last_ok = after - waiting / self.rate_hz
        return max(0, made - n_read - waiting)

    def read_batch(self, wait: bool = True, batch_s: Optional[float] = None) -> SampleBatch:
        """The gyro has no FIFO: poll once per sample period, so that each accelerometer
        sample gets its own gyro reading, and return the polls of ``batch_s`` together."""
        return self._polled(wait, batch_s, 1.0 / self.rate_hz)


def merge_batches(parts: List[SampleBatch]) -> SampleBatch:
    """One batch from consecutive ones (the 9DOF board polls per sample; the pipeline
    is cheaper per sample on larger batches)."""
    parts = [p for p in parts if len(p) or p.gaps]
    if len(parts) == 1:
        return parts[0]
    if not parts:
        return SampleBatch(np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)),
                           np.zeros(0))
    cat = lambda k: None if getattr(parts[0], k) is None else np.concatenate([getattr(p, k) for p in parts])
    return SampleBatch(cat("t"), cat("seq"), cat("acc"), cat("gyro"), cat("temp"), cat("mag"),
                       cat("mag_fresh"), [g for p in parts for g in p.gaps])


def make_board(name: str, bus: Bus, clock: Optional[Clock] = None, rate_hz: float = 100.0,
               **kw) -> Board:
    if name in ("mpu6050", "mpu6500", "mpu9250"):
        return MPUBoard(bus, name, rate_hz=rate_hz, clock=clock, **kw)
    if name == "9dof":
        return NineDofBoard(bus, rate_hz=rate_hz, clock=clock, **kw)
    if name == "gy273":
        from .magboard import MagOnlyBoard
        return MagOnlyBoard(bus, rate_hz=rate_hz, clock=clock, **kw)
    raise ValueError(f"unknown board {name!r}: allowed {', '.join(BOARD_NAMES)}")
