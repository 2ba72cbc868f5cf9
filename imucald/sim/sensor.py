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

from ..rng import RngLike, as_rng

from ..calib.models import Triangular9
from ..recording import Recording
from .motion import log_so3
from .poses import axis_angle
from ..specs import ACCEL, BOARDS, GYRO, MAG

__all__ = ["Truth", "draw_truth", "pose_sigma", "simulate_pose_means", "Session",
           "simulate_session", "simulate_tumble", "temperature_profile", "hold_samples",
           "duplicate_rows"]

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


def temperature_profile(t: np.ndarray, kind: str = "warmup", t0_c: float = 22.0,
                        dt_c: float = 6.0) -> np.ndarray:
    """Die temperature, degC: 'warmup' (exponential, tau = span/3), 'ramp' (linear),
    'heatcool' (up then down), or 'constant'."""
    span = max(float(t[-1] - t[0]), 1e-9)
    x = (t - t[0]) / span
    if kind == "warmup":
        return t0_c + dt_c * (1 - np.exp(-3 * x)) / (1 - np.exp(-3))
    if kind == "ramp":
        return t0_c + dt_c * x
    if kind == "heatcool":
        return t0_c + dt_c * (1 - np.abs(2 * x - 1))
    if kind == "constant":
        return np.full_like(t, t0_c, dtype=float)
    raise ValueError(f"unknown temperature profile {kind!r}: allowed warmup, ramp, heatcool, constant")


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


def hand_tremor(n: int, rate_hz: float, rms_dps: float, rng: RngLike = None):
    """Band-limited (6-12 Hz) hand tremor: (rate deg/s (n, 3), angle rad (n, 3)), body
    frame, each rate axis with RMS ``rms_dps``; the angle is the rate integrated."""
    rng = as_rng(rng)
    f = np.fft.rfftfreq(n, 1.0 / rate_hz)
    band = (f >= 6.0) & (f <= min(12.0, rate_hz / 2))
    spec = (rng.normal(size=(3, len(f))) + 1j * rng.normal(size=(3, len(f)))) * band
    rate = np.fft.irfft(spec, n).T
    rate *= rms_dps / np.maximum(rate.std(0), 1e-300)
    ang = np.cumsum(np.radians(rate), 0) / rate_hz
    return rate, ang - ang.mean(0)


def simulate_session(board: str, rotations: np.ndarray, rng: RngLike = None,
                     rate_hz: float = 100.0, hold_s: Union[float, Tuple[float, float]] = 10.0,
                     move_s: Union[float, Tuple[float, float]] = 3.0, lead_s: float = 2.0,
                     truth: Optional[Truth] = None, temp_kind: str = "warmup",
                     temp0_c: float = 22.0, temp_rise_c: float = 6.0,
                     effects: Sequence[Effect] = (), move_accel_g: float = 0.2,
                     quantise: bool = True, tremor_dps: Union[float, Sequence[float]] = 0.0,
                     tremor_lever_m: float = 0.025, latitude_deg: float = 48.0) -> Session:
    """Raw sample stream for a board moved through ``rotations``.

    The gyro also senses Earth's rotation, 7.2921e-5 rad/s (IERS), at ``latitude_deg``
    (world frame: x north, as the magnetic field's horizontal part, z up).

    The board rests ``lead_s`` in the first pose, then for each pose holds still
    for ``hold_s`` (a number or a (lo, hi) range drawn uniformly) and moves to the
    next in ``move_s``: a smooth (smoothstep) rotation about a fixed body axis,
    with a hand-like linear acceleration bump of up to ``move_accel_g``.

    ``tremor_dps`` > 0 adds hand tremor throughout: a small angular oscillation,
    band-limited to 6-12 Hz, whose rate has that RMS per axis (0.5-2 deg/s for real
    hands).  It is physical: the rotation enters the trajectory, so the gyro sees the
    rate and the accelerometer the gravity-direction wobble, plus the tangential
    acceleration of a point ``tremor_lever_m`` from the pivot (2.5 cm gives the
    accelerometer 1.3-3x its noise variance at 1.5 deg/s, as real hand poses show).
    A sequence gives each pose its own (over its hold and the move after it): e.g. 10 bench
    poses (0) then 10 hand-held ones (1.5).
    """
    rng = as_rng(rng)
    truth = truth or draw_truth(board, rng)
    tr = _pose_tour(rotations, rng, rate_hz, hold_s, move_s, lead_s, move_accel_g)
    _add_tremor(tr, tremor_dps, len(rotations), rate_hz, tremor_lever_m, rng)
    return _sense(board, truth, tr.R, tr.w_dps, tr.a_world, rotations, tr.holds, rate_hz, rng,
                  temp_kind, temp0_c, temp_rise_c, effects, quantise, latitude_deg)


@dataclass
class _Trajectory:
    """A board's motion sampled at the rate: body->world rotations R (n, 3, 3), body rates
    w_dps (n, 3), world linear acceleration a_world (n, 3, g), each pose's hold (t0, t1, s)
    and the sample count of each segment (hold, move, hold, ... in order)."""
    R: np.ndarray
    w_dps: np.ndarray
    a_world: np.ndarray
    holds: List[Tuple[float, float]]
    segments: List[int]


def _pose_tour(rotations, rng, rate_hz, hold_s, move_s, lead_s, move_accel_g) -> _Trajectory:
    """Holds at each pose and smoothstep moves between them, with a hand-like linear
    acceleration bump (see :func:`simulate_session`)."""
    dt = 1.0 / rate_hz
    draw = lambda v: float(rng.uniform(*v)) if isinstance(v, tuple) else float(v)
    Rs, ws, accs, holds = [], [], [], []
    t_cursor = 0.0
    N = len(rotations)
    for i in range(N):
        h = draw(hold_s) + (lead_s if i == 0 else 0.0)
        n = max(1, int(round(h * rate_hz)))
        Rs.append(np.broadcast_to(rotations[i], (n, 3, 3)))
        ws.append(np.zeros((n, 3)))
        accs.append(np.zeros((n, 3)))
        holds.append((t_cursor, t_cursor + (n - 1) * dt))
        t_cursor += n * dt
        if i + 1 < N:
            mt = draw(move_s)
            m = max(2, int(round(mt * rate_hz)))
            tau = (np.arange(m) + 0.5) / m
            s = 3 * tau ** 2 - 2 * tau ** 3
            sdot = 6 * tau * (1 - tau) / (m * dt)     # the motion lasts m samples (mt rounded)
            rel = rotations[i].T @ rotations[i + 1]
            rv = log_so3(rel)
            ang = np.linalg.norm(rv)
            ax = rv / ang if ang > 0 else np.array([1.0, 0, 0])
            Rm = np.array([rotations[i] @ axis_angle(ax, ang * sk) for sk in s])
            Rs.append(Rm)
            ws.append(np.degrees(rv)[None, :] * sdot[:, None])
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            amp = rng.uniform(0.3, 1.0) * move_accel_g
            accs.append(amp * np.sin(2 * np.pi * tau)[:, None] * d[None, :])
            t_cursor += m * dt
    return _Trajectory(np.concatenate(Rs), np.concatenate(ws), np.concatenate(accs), holds,
                       [len(x) for x in Rs])


def _add_tremor(tr: _Trajectory, tremor_dps, N: int, rate_hz: float, lever_m: float,
                rng) -> None:
    """Hand tremor into the trajectory, in place: the small rotation, its rate and the
    tangential acceleration at ``lever_m`` from the pivot (see :func:`simulate_session`)."""
    n = len(tr.R)
    per_pose = np.ndim(tremor_dps) > 0
    if per_pose and len(tremor_dps) != N:
        raise ValueError(f"tremor_dps: {len(tremor_dps)} values for {N} poses")
    if per_pose and np.any(np.asarray(tremor_dps, float) > 0):
        # each pose's tremor over its hold and the move that follows it (bench poses: 0)
        env = np.repeat(np.asarray(tremor_dps, float),
                        [sum(tr.segments[2 * i:2 * i + 2]) for i in range(N)])
        rate_dps, _ = hand_tremor(n, rate_hz, 1.0, rng)
        rate_dps *= env[:, None]
        ang = np.cumsum(np.radians(rate_dps), 0) / rate_hz
        ang -= ang.mean(0)
    elif not per_pose and tremor_dps > 0:
        rate_dps, ang = hand_tremor(n, rate_hz, tremor_dps, rng)
    else:
        return
    sk = np.zeros((n, 3, 3))                     # small-angle body rotation I + [ang]x
    sk[:, 0, 1], sk[:, 0, 2], sk[:, 1, 2] = -ang[:, 2], ang[:, 1], -ang[:, 0]
    sk -= np.transpose(sk, (0, 2, 1))
    tr.R = tr.R @ (np.eye(3) + sk)
    tr.w_dps = tr.w_dps + rate_dps
    alpha = np.gradient(np.radians(rate_dps), 1.0 / rate_hz, axis=0)      # rad/s^2, body
    lever = np.cross(alpha, np.array([lever_m, 0.0, 0.0])) / 9.80665      # g, body
    tr.a_world = tr.a_world + np.einsum("nij,nj->ni", tr.R, lever)


def _sense(board, truth, R, w_dps, a_world, rotations, holds, rate_hz, rng, temp_kind, temp0_c,
           temp_rise_c, effects, quantise, latitude_deg) -> Session:
    """The sensors on a trajectory: body->world rotations R (n, 3, 3), body rates w_dps
    (n, 3) and world linear acceleration a_world (n, 3, g), sampled at rate_hz: the error
    model, effects, white noise, quantisation and clipping."""
    an, gn, mn = BOARDS[board]
    aspec, gspec = ACCEL[an], GYRO[gn]
    mspec = MAG[mn] if mn else None
    n = len(R)
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    f = np.einsum("nji,nj->ni", R, a_world + np.array([0.0, 0.0, 1.0]))  # R^T (a + up)
    temp = temperature_profile(t, temp_kind, temp0_c, temp_rise_c)
    ctx = {"t": t, "temp": temp, "f": f, "w": w_dps, "R": R}

    acc = truth.accel_raw(f)
    lat = np.radians(latitude_deg)
    earth_dps = np.degrees(7.2921e-5) * np.array([np.cos(lat), 0.0, np.sin(lat)])
    gyro = truth.gyro_raw(w_dps + np.einsum("nji,j->ni", R, earth_dps))
    mag = None
    if mspec is not None:
        dip = np.radians(truth.dip_deg)
        B = truth.field_gauss * np.array([np.cos(dip), 0.0, -np.sin(dip)])
        h = np.einsum("nji,j->ni", R, B)
        mag = truth.mag_raw(h)
        ctx["h"] = h
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
    rec = Recording(t=t, acc=acc, gyro=gyro, mag=mag, temp=temp, meta=meta)
    return Session(rec, truth, holds, np.asarray(rotations), f, w_dps)


def simulate_tumble(board: str, rng: RngLike = None, rate_hz: float = 5.0, duration_s: float = 120.0,
                    speed_dps: Tuple[float, float] = (15.0, 60.0), truth: Optional[Truth] = None,
                    quantise: bool = True, move_accel_g: float = 0.05) -> Session:
    """A board turned slowly by hand without ever stopping: the body rate's direction wanders
    smoothly and its magnitude stays within ``speed_dps`` (a slow hand tumble; no still
    moment), with a small hand-like linear acceleration (``move_accel_g``, 0.5 Hz).  Sampled at
    ``rate_hz`` (real loggers of such tumbles: 3-10 Hz).  Session.hold is empty."""
    rng = as_rng(rng)
    truth = truth or draw_truth(board, rng)
    # simulated finely (200 Hz) so the attitude integrates well, then sampled at rate_hz
    fine = 200.0
    nf = int(round(duration_s * fine))
    tf = np.arange(nf) / fine
    nk = 8                                          # a few slow sinusoids per axis, 0.02-0.3 Hz
    fr = rng.uniform(0.02, 0.3, size=(nk, 3))
    ph = rng.uniform(0, 2 * np.pi, size=(nk, 3))
    amp = rng.normal(size=(nk, 3))
    d = (amp[None] * np.sin(2 * np.pi * fr[None] * tf[:, None, None] + ph[None])).sum(1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)                 # direction (never 0 speed)
    sp = np.interp(np.sin(2 * np.pi * rng.uniform(0.01, 0.05) * tf + rng.uniform(0, 6.3)),
                   [-1, 1], list(speed_dps))
    w_f = d * sp[:, None]                                          # deg/s, body
    R = np.empty((nf, 3, 3))
    Rc = axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
    for i in range(nf):
        R[i] = Rc
        wv = np.radians(w_f[i]) / fine
        ang = np.linalg.norm(wv)
        if ang > 0:
            Rc = Rc @ axis_angle(wv / ang, ang)
    acc_f = move_accel_g * np.sin(2 * np.pi * 0.5 * tf[:, None] + rng.uniform(0, 6.3, 3)[None])
    idx = np.round(np.arange(0, duration_s, 1.0 / rate_hz) * fine).astype(int)
    idx = idx[idx < nf]
    return _sense(board, truth, R[idx], w_f[idx], acc_f[idx], R[idx[:1]], [], rate_hz, rng,
                  "constant", 22.0, 0.0, (), quantise, 48.0)


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






def duplicate_rows(rec: Recording, times: int = 2) -> Recording:
    """Every row written ``times`` times, timestamps included (a logger bug seen in the wild)."""
    idx = np.repeat(np.arange(len(rec.t)), times)
    pick = lambda a: None if a is None else np.asarray(a)[idx]
    return Recording(t=rec.t[idx], acc=pick(rec.acc), gyro=pick(rec.gyro), mag=pick(rec.mag),
                     temp=pick(rec.temp), meta=dict(rec.meta))
