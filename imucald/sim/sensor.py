"""The sensor simulator: true error parameters, pose averages and raw sample streams.

Error model (what the calibration must undo), body frame:

* accelerometer: raw = (T K)^-1 f + b  (the inverse of paper 000's triangular9
  correction), f the specific force in g;
* gyro: raw = M w + b_g, M = diag(1 + scale error) + cross-axis terms, w in deg/s;
* magnetometer: raw = W^-1 h + v, W symmetric (soft iron), v hard iron, h the
  field in the body frame, gauss;

followed by optional extra effects (a hook for the gap diagnosis), white noise
at the chip's noise density over the bandwidth, ADC quantisation and range
clipping.  Every function takes a seed or a numpy Generator.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from ..numerics.rng import RngLike, as_rng

from ..fitting.models.accel import Triangular9
from ..files.recording import Recording
from .motion import PoseTour, Tumble, earth_rate_body_dps
from ..specs import ACCEL, BOARDS, GYRO, MAG

__all__ = ["Truth", "draw_truth", "pose_sigma", "simulate_pose_means", "Session",
           "simulate_session", "simulate_tumble", "sense", "hold_samples", "duplicate_rows"]

_T9 = Triangular9()



def _clipped_normal(rng, tol, size=None):
    tol = np.asarray(tol, float)
    return np.clip(rng.normal(scale=tol / 2, size=size if size is not None else tol.shape), -tol, tol)


@dataclass
class Truth:
    """The true errors of one simulated board."""

    board: str
    accel: np.ndarray                       #: triangular9 correction parameters (9,)
    gyro_bias_dps: np.ndarray               #: (3,)
    gyro_matrix: np.ndarray                 #: raw = M w + b_g  (3, 3)
    mag_hard_iron_gauss: Optional[np.ndarray] = None   #: v (3,)
    mag_soft_iron: Optional[np.ndarray] = None         #: W (3, 3), h = W (m - v)
    field_gauss: float = 0.5                #: local field magnitude
    dip_deg: float = 60.0                   #: inclination (field points down in the north)

    # the error model, in one place for the simulator and the emulated chips
    def accel_raw(self, f_g: np.ndarray) -> np.ndarray:
        """Measured acceleration (g, before noise) for true specific force f (n, 3)."""
        return _T9.inverse(self.accel, f_g)

    def gyro_raw(self, w_dps: np.ndarray) -> np.ndarray:
        """Measured rate (deg/s, before noise) for true rate w (n, 3)."""
        return w_dps @ self.gyro_matrix.T + self.gyro_bias_dps

    def mag_raw(self, h_gauss: np.ndarray) -> np.ndarray:
        """Measured field (gauss, before noise) for true body-frame field h (n, 3)."""
        return h_gauss @ np.linalg.inv(self.mag_soft_iron).T + self.mag_hard_iron_gauss


def draw_truth(board: str = "mpu6050", rng: RngLike = None) -> Truth:
    """True errors drawn within the board's datasheet tolerances (N(0, tol/2), clipped)."""
    if board not in BOARDS:
        raise ValueError(f"unknown board {board!r}: allowed {', '.join(BOARDS)}")
    rng = as_rng(rng)
    an, gn, mn = BOARDS[board]
    a = ACCEL[an]
    bias = _clipped_normal(rng, np.array(a.bias_tol_g))
    scale_err = _clipped_normal(rng, np.full(3, a.scale_tol))
    alpha = _clipped_normal(rng, np.full(3, a.cross_axis_tol))
    theta = np.concatenate([alpha, 1.0 / (1.0 + scale_err), bias])
    g = GYRO[gn]
    gb = _clipped_normal(rng, np.full(3, g.bias_tol_dps))
    M = np.diag(1.0 + _clipped_normal(rng, np.full(3, g.scale_tol)))
    M += (1 - np.eye(3)) * _clipped_normal(rng, np.full((3, 3), g.cross_axis_tol))
    truth = Truth(board, theta, gb, M)
    if mn is not None:
        m = MAG[mn]
        truth.mag_hard_iron_gauss = rng.normal(scale=0.15, size=3)
        Wp = np.diag(_clipped_normal(rng, np.full(3, m.scale_tol)))
        off = _clipped_normal(rng, np.full(3, m.cross_axis_tol))
        Wp[0, 1] = Wp[1, 0] = off[0]
        Wp[0, 2] = Wp[2, 0] = off[1]
        Wp[1, 2] = Wp[2, 1] = off[2]
        truth.mag_soft_iron = np.eye(3) + Wp
        truth.field_gauss = float(rng.uniform(0.25, 0.65))
        truth.dip_deg = float(rng.uniform(-70, 70))
    return truth


def pose_sigma(noise_density: float, rate_hz: float, pose_s: float,
               bandwidth_hz: Optional[float] = None) -> Tuple[float, float]:
    """(per-sample sigma, pose-mean sigma) for white noise, in the density's unit.

    sigma_sample = ND * sqrt(bandwidth) (bandwidth defaults to rate/2, i.e. samples
    are independent), sigma_pose = sigma_sample / sqrt(rate * pose_s).
    """
    bw = rate_hz / 2.0 if bandwidth_hz is None else bandwidth_hz
    s = noise_density * np.sqrt(bw)
    return float(s), float(s / np.sqrt(rate_hz * pose_s))


def simulate_pose_means(theta: np.ndarray, ups: np.ndarray, sigma_pose: float,
                        rng: RngLike = None, model=_T9) -> Tuple[np.ndarray, np.ndarray]:
    """Pose averages: raw means (N, 3) = model.inverse(theta, ups) + N(0, sigma_pose^2 I).

    Returns (means, pose_cov) with pose_cov (N, 3, 3) the covariance of each mean.
    """
    rng = as_rng(rng)
    ups = np.asarray(ups, float)
    raw = model.inverse(theta, ups) + rng.normal(scale=sigma_pose, size=ups.shape)
    cov = np.broadcast_to(np.eye(3) * sigma_pose ** 2, (len(ups), 3, 3)).copy()
    return raw, cov


@dataclass
class Session:
    """A simulated session: the recording plus what produced it."""

    recording: Recording
    truth: Truth
    hold: List[Tuple[float, float]]          #: (start, end) of each still interval, s
    rotations: np.ndarray                    #: (N, 3, 3) pose orientations
    specific_force_g: np.ndarray = field(repr=False, default=None)  #: true f, (n, 3)
    rate_dps: np.ndarray = field(repr=False, default=None)          #: true w, (n, 3)


#: An effect modifies raw sensor arrays in place before noise: f(sensor, raw, ctx).
Effect = Callable[[str, np.ndarray, Dict[str, np.ndarray]], None]


def simulate_session(board: str, rotations: np.ndarray, rng: RngLike = None,
                     rate_hz: float = 100.0, hold_s: Union[float, Tuple[float, float]] = 10.0,
                     move_s: Union[float, Tuple[float, float]] = 3.0, lead_s: float = 2.0,
                     truth: Optional[Truth] = None, temp_kind: str = "warmup",
                     temp0_c: float = 22.0, temp_rise_c: float = 6.0,
                     effects: Sequence[Effect] = (), move_accel_g: float = 0.2,
                     quantise: bool = True, tremor_dps: Union[float, Sequence[float]] = 0.0,
                     tremor_lever_m: float = 0.025, latitude_deg: float = 48.0,
                     sway_deg: float = 0.0) -> Session:
    """Raw sample stream for a board moved through ``rotations``: the trajectory generator
    the emulated chips also sample (:class:`imucald.sim.motion.PoseTour`), evaluated at the
    logger's times k / ``rate_hz``, then sensed (:func:`sense`).

    The board rests ``lead_s`` in the first pose, then for each pose holds still
    for ``hold_s`` (a number or a (lo, hi) range drawn uniformly) and moves to the
    next in ``move_s``: a smooth (smoothstep) rotation about a fixed body axis,
    with a hand-like linear acceleration bump of up to ``move_accel_g``.

    ``tremor_dps`` > 0 adds hand tremor throughout: a small angular oscillation in 6-12 Hz
    (its components above the logger's Nyquist frequency left out, as the chip's anti-alias
    filter would), whose rate has that RMS per axis (0.5-2 deg/s for real hands), physical
    (gravity tilt and the tangential acceleration ``tremor_lever_m`` from the pivot: see
    :class:`~imucald.sim.motion.PoseTour`).  A sequence gives each pose its own: e.g. 10
    bench poses (0) then 10 hand-held ones (1.5).  The die temperature follows ``temp_kind``
    over the session (:func:`~imucald.sim.motion.temperature_profile`); the gyro also senses
    Earth's rotation at ``latitude_deg``.  ``sway_deg`` > 0 adds a hand's slow sway (0.2-2 Hz,
    that RMS angle per axis; real hands 0.05-0.4 deg; drawn last, so the rest is unchanged).

    Random draws, in order: the truth (unless given), the tour (holds, bumps, moves, tremor),
    then the sensor noise.
    """
    rng = as_rng(rng)
    truth = truth or draw_truth(board, rng)
    tour = PoseTour(rotations, rng, hold_s=hold_s, move_s=move_s, lead_s=lead_s,
                    move_accel_g=move_accel_g, field_gauss=truth.field_gauss, dip_deg=truth.dip_deg,
                    temp0_c=temp0_c, temp_rise_c=temp_rise_c, temp_kind=temp_kind,
                    tremor_dps=tremor_dps, tremor_lever_m=tremor_lever_m, sway_deg=sway_deg)
    t = tour.sample_times(rate_hz)
    m = tour.sample(t, max_hz=rate_hz / 2)
    return sense(board, truth, t, m, rate_hz, rng, effects, quantise, latitude_deg,
                 holds=_sampled_holds(tour.holds(), t), rotations=rotations)


def _sampled_holds(holds, t_s: np.ndarray) -> List[Tuple[float, float]]:
    """Each still interval as the times of its first and last sample, s (the interval
    itself when no sample falls in it)."""
    out = []
    for a, b in holds:
        i0, i1 = np.searchsorted(t_s, [a, b])
        out.append((float(t_s[i0]), float(t_s[i1 - 1])) if i1 > i0 else (float(a), float(b)))
    return out


def sense(board: str, truth: Truth, t_s: np.ndarray, motion: Dict[str, np.ndarray], rate_hz: float,
          rng: RngLike = None, effects: Sequence[Effect] = (), quantise: bool = True,
          latitude_deg: float = 48.0, holds: Sequence[Tuple[float, float]] = (),
          rotations: Optional[np.ndarray] = None) -> Session:
    """The board's sensors on a sampled trajectory (``motion``: a trajectory's ``sample(t_s)``,
    keys f (g), w (deg/s), R, temp (degC), h (gauss)): the error model, Earth's rotation,
    effects, white noise at the datasheet density over rate_hz / 2, quantisation and
    clipping, and the die temperature at the chip's resolution."""
    rng = as_rng(rng)
    an, gn, mn = BOARDS[board]
    aspec, gspec = ACCEL[an], GYRO[gn]
    mspec = MAG[mn] if mn else None
    f, w_dps, R, temp = motion["f"], motion["w"], motion["R"], motion["temp"]
    ctx = {"t": t_s, "temp": temp, "f": f, "w": w_dps, "R": R}
    acc = truth.accel_raw(f)
    gyro = truth.gyro_raw(w_dps + earth_rate_body_dps(R, latitude_deg))
    mag = None
    if mspec is not None:
        ctx["h"] = motion["h"]
        mag = truth.mag_raw(motion["h"])
    for eff in effects:
        eff("accel", acc, ctx)
        eff("gyro", gyro, ctx)
        if mag is not None:
            eff("mag", mag, ctx)
    sa, _ = pose_sigma(aspec.noise_density_g_rthz, rate_hz, 1.0)
    sg, _ = pose_sigma(gspec.noise_density_dps_rthz, rate_hz, 1.0)
    acc = acc + rng.normal(scale=sa, size=acc.shape)
    gyro = gyro + rng.normal(scale=sg, size=gyro.shape)
    if mag is not None:
        mag = mag + rng.normal(scale=mspec.noise_gauss, size=mag.shape)

    def q(x, lsb, rng_):
        if quantise:
            x = np.round(x / lsb) * lsb
        return np.clip(x, -rng_, rng_ - lsb)

    acc = q(acc, aspec.lsb_g, aspec.range_g)
    gyro = q(gyro, gspec.lsb_dps, gspec.range_dps)
    if mag is not None:
        mag = q(mag, mspec.lsb_gauss, mspec.range_gauss)
    tl = aspec.temp_lsb_c or gspec.temp_lsb_c
    if tl and quantise:
        temp = np.round(temp / tl) * tl
    meta = {"board": board, "rate_hz": f"{rate_hz:g}", "accel_range_g": f"{aspec.range_g:g}",
            "gyro_range_dps": f"{gspec.range_dps:g}", "source": "imucald simulate"}
    if mspec is not None:
        meta["mag_range_gauss"] = f"{mspec.range_gauss:g}"
    rec = Recording(t=t_s, acc=acc, gyro=gyro, mag=mag, temp=temp, meta=meta)
    rot = np.asarray(rotations) if rotations is not None else R[:1]
    return Session(rec, truth, list(holds), rot, f, w_dps)


def simulate_tumble(board: str, rng: RngLike = None, rate_hz: float = 5.0, duration_s: float = 120.0,
                    speed_dps: Tuple[float, float] = (15.0, 60.0), truth: Optional[Truth] = None,
                    quantise: bool = True, move_accel_g: float = 0.05) -> Session:
    """A board turned slowly by hand without ever stopping (:class:`~imucald.sim.motion.Tumble`:
    the rate's direction wanders, its magnitude within ``speed_dps``, a small 0.5-Hz linear
    acceleration of ``move_accel_g``), sampled at ``rate_hz`` (real loggers of such tumbles:
    3-10 Hz) and sensed.  Session.hold is empty."""
    rng = as_rng(rng)
    truth = truth or draw_truth(board, rng)
    tumble = Tumble(rng, duration_s, speed_dps, move_accel_g, field_gauss=truth.field_gauss,
                    dip_deg=truth.dip_deg)
    t = tumble.sample_times(rate_hz)
    return sense(board, truth, t, tumble.sample(t), rate_hz, rng, quantise=quantise)


def hold_samples(rec: Recording, logger_rate_hz: float, phase: float = 0.0) -> Recording:
    """Sample-and-hold: the recording (the chip's output at its rate) read by a logger at
    ``logger_rate_hz`` (faster), each row the chip's latest sample: every value is held
    logger_rate / rate times (2.5: alternately 2 and 3; an FXOS8700 at ~104 Hz read at
    400 Hz: 3-4).  ``phase``: the logger's first read, in chip sample periods (0..1)."""
    rate = rec.rate_hz
    tl = np.arange(0.0, float(rec.t[-1]) + 1.0 / rate, 1.0 / logger_rate_hz)
    idx = np.floor((tl - rec.t[0]) * rate + phase + 1e-9).astype(int)
    keep = idx < len(rec.t)
    tl, idx = tl[keep], idx[keep]
    pick = lambda a: None if a is None else np.asarray(a)[idx]
    meta = dict(rec.meta, rate_hz=f"{logger_rate_hz:g}")
    return Recording(t=tl, acc=pick(rec.acc), gyro=pick(rec.gyro), mag=pick(rec.mag),
                     temp=pick(rec.temp), meta=meta)






def burst_stamps(rec: Recording, burst_s: float) -> Recording:
    """The rows as a logger writes them that drains the chip's FIFO every ``burst_s`` seconds
    and stamps each burst's rows with its read time (the end of the burst): ``burst_s`` x rate
    rows under one stamp, the values untouched (what an Arduino sketch reading a FIFO and
    printing ``millis()`` beside each row does)."""
    t0 = float(rec.t[0])
    t = t0 + (np.floor((rec.t - t0) / burst_s + 1e-9) + 1.0) * burst_s
    return Recording(t=t, acc=rec.acc, gyro=rec.gyro, mag=rec.mag, temp=rec.temp, meta=dict(rec.meta))


def duplicate_rows(rec: Recording, times: int = 2) -> Recording:
    """Every row written ``times`` times, timestamps included (a logger bug seen in the wild)."""
    idx = np.repeat(np.arange(len(rec.t)), times)
    pick = lambda a: None if a is None else np.asarray(a)[idx]
    return Recording(t=rec.t[idx], acc=pick(rec.acc), gyro=pick(rec.gyro), mag=pick(rec.mag),
                     temp=pick(rec.temp), meta=dict(rec.meta))
