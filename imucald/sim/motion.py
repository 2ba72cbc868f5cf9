"""The one trajectory generator: a board's motion as a continuous function of time.

Both consumers sample the same objects: :func:`imucald.sim.sensor.simulate_session`
evaluates a :class:`PoseTour` at the logger's sample times (then applies the sensor
error model, noise, quantisation and, on request, sample-and-hold), and the emulated
chips (:mod:`imucald.sim.emulators`) evaluate it at the times their output registers or
FIFOs fill, each at its own output rate.  :class:`Tumble` is the no-hold alternative
(a slow hand tumble) with the same ``sample`` interface.

A :class:`PoseTour` holds each pose, then turns to the next with a smoothstep profile
about a fixed body axis and a hand-like linear-acceleration bump; hand tremor
(:class:`HandTremor`) rides on top throughout; the die temperature follows a course
(:func:`temperature_profile`); with ``loop`` the tour repeats forever (the daemon demo).

Frames and units: the world frame is x north (the magnetic field's horizontal part),
z up; ``R`` maps body vectors to world vectors.  Specific force ``f`` in g (body),
angular rate ``w`` in deg/s (body, relative to the local level frame: Earth's rotation
is a sensing matter, see :func:`earth_rate_body_dps`), field ``h`` in gauss (body),
``temp`` in degC, time in s.

Measured statistics (``python bench/trajectory.py``: seeds 0-4, 30 poses each, sampled at
100 Hz, hold_s=(6, 10), tremor_dps=1.5): holds of mean 8.00 s, sd 1.24 s over 150 holds (a
uniform draw: 8.00, 1.15); the tremor rate in the holds has RMS 1.49-1.51 deg/s per axis,
per 2-s window 1.31/1.49/1.66 deg/s (10/50/90 %), 99.2 % of its power in 6-12 Hz and excess
kurtosis +0.02 (Gaussian: 0); ``random_pose_set(30)`` leaves no direction farther than
28.0-30.5 deg from a pose.  The simulator's sessions (the same generator, plus the sensor)
show the same figures; their still gyro's per-hold sd has median 1.49 deg/s (10-90 %:
1.40-1.57; with the simulator's former tremor, made on its own sample grid, 1.48, 1.41-1.57).
"""
from __future__ import annotations

from typing import Dict, Optional, Sequence, Tuple, Union

import numpy as np

from ..numerics.rng import RngLike, as_rng

__all__ = ["PoseTour", "Tumble", "HandTremor", "log_so3", "temperature_profile",
           "earth_rate_body_dps", "TREMOR_BAND_HZ", "SWAY_BAND_HZ", "EARTH_RATE_RAD_S"]

#: the band of physiological hand tremor the generator draws from, Hz
TREMOR_BAND_HZ = (6.0, 12.0)
#: the band of a hand's slow sway (the board's direction wandering within a hold), Hz
SWAY_BAND_HZ = (0.2, 2.0)
#: the grid the tremor is computed on (then interpolated), Hz: well above twice its band
TREMOR_GRID_HZ = 200.0
#: Earth's rotation rate, rad/s (IERS)
EARTH_RATE_RAD_S = 7.2921e-5
_G_M_S2 = 9.80665
_UP = np.array([0.0, 0.0, 1.0])


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of a rotation matrix."""
    c = np.clip((np.trace(R) - 1) / 2, -1, 1)
    ang = np.arccos(c)
    if ang < 1e-12:
        return np.zeros(3)
    if np.pi - ang < 1e-6:
        w, V = np.linalg.eigh((R + R.T) / 2)
        return V[:, np.argmax(w)] * ang
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2 * np.sin(ang))
    return v * ang


def _rodrigues_batch(axis: np.ndarray, ang: np.ndarray) -> np.ndarray:
    """Rotation matrices for unit axes (n, 3) and angles (n,), rad."""
    K = np.zeros((len(ang), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -axis[:, 2], axis[:, 1]
    K[:, 1, 0], K[:, 1, 2] = axis[:, 2], -axis[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -axis[:, 1], axis[:, 0]
    s, c = np.sin(ang)[:, None, None], np.cos(ang)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _rotvec_batch(v_rad: np.ndarray) -> np.ndarray:
    """Rotation matrices for rotation vectors (n, 3), rad."""
    a = np.linalg.norm(v_rad, axis=1)
    return _rodrigues_batch(v_rad / np.maximum(a, 1e-300)[:, None], a)


def temperature_profile(t_s: np.ndarray, kind: str = "warmup", t0_c: float = 22.0,
                        dt_c: float = 6.0, span_s: Optional[float] = None,
                        tau_s: float = 600.0) -> np.ndarray:
    """Die temperature, degC, at times ``t_s`` over a course of ``span_s`` seconds from
    ``t_s[0]`` (default: to ``t_s[-1]``): 'warmup' (exponential, tau = span/3, reaching
    t0_c + dt_c at the span's end), 'ramp' (linear), 'heatcool' (up then down), 'constant',
    or 'exponential' (t0_c + dt_c (1 - exp(-t/tau_s)) from t = 0, no span: the emulated
    board's warm-up).  Past the span the course stays at its end value."""
    t_s = np.asarray(t_s, float)
    if kind == "exponential":
        return t0_c + dt_c * (1 - np.exp(-t_s / tau_s))
    if kind == "constant":
        return np.full_like(t_s, t0_c, dtype=float)
    start = float(t_s[0]) if span_s is None else 0.0
    span = max(float(t_s[-1]) - start if span_s is None else float(span_s), 1e-9)
    x = np.clip((t_s - start) / span, 0.0, 1.0)
    if kind == "warmup":
        return t0_c + dt_c * (1 - np.exp(-3 * x)) / (1 - np.exp(-3))
    if kind == "ramp":
        return t0_c + dt_c * x
    if kind == "heatcool":
        return t0_c + dt_c * (1 - np.abs(2 * x - 1))
    raise ValueError(f"unknown temperature profile {kind!r}: allowed warmup, ramp, heatcool, "
                     f"constant, exponential")


def earth_rate_body_dps(R: np.ndarray, latitude_deg: float) -> np.ndarray:
    """Earth's rotation in the body frame, deg/s (n, 3), for body->world rotations R
    (n, 3, 3) at ``latitude_deg`` (world x north, z up)."""
    lat = np.radians(latitude_deg)
    earth_dps = np.degrees(EARTH_RATE_RAD_S) * np.array([np.cos(lat), 0.0, np.sin(lat)])
    return np.einsum("nji,j->ni", R, earth_dps)


def field_world_gauss(field_gauss: float, dip_deg: float) -> np.ndarray:
    """The local magnetic field in the world frame, gauss: north and down by ``dip_deg``."""
    dip = np.radians(dip_deg)
    return field_gauss * np.array([np.cos(dip), 0.0, -np.sin(dip)])


class HandTremor:
    """Hand tremor as a deterministic function of time (every sampler sees the same hand): a
    Gaussian process with a flat spectrum over ``band_hz``, made like the simulator's former
    tremor (complex normal Fourier coefficients on every line j / period of the band, the
    inverse FFT) but periodic over ``period_s`` and evaluable at any time: angle, rate and
    angular acceleration are computed exactly on a ``grid_hz`` grid and joined by quintic
    Hermite interpolation (angle, rate and acceleration continuous, consistent with each
    other; against the lines summed exactly: angle 2e-8, rate 4e-9, acceleration 5e-6 of
    their peaks).  RMS rate 1 deg/s per axis over the period (the tour multiplies by its envelope).

    A line spectrum of a few dozen cosines (the emulators' former tremor) is not the same
    process: its autocorrelation keeps a floor of ~1/sqrt(lines) at the lags a pose's
    structure function reads (1-5 s), which calibrate's pose covariance then counted."""

    def __init__(self, rng: RngLike = None, period_s: float = 60.0,
                 band_hz: Tuple[float, float] = TREMOR_BAND_HZ, grid_hz: float = TREMOR_GRID_HZ):
        rng = as_rng(rng)
        self.grid_hz = float(grid_hz)
        self.n = max(int(np.ceil(period_s * grid_hz)), 16)
        self.period_s = self.n / self.grid_hz
        self.freq_hz = np.fft.rfftfreq(self.n, 1.0 / self.grid_hz)
        band = (self.freq_hz >= band_hz[0]) & (self.freq_hz <= band_hz[1])
        shape = (3, len(self.freq_hz))
        spec = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) * band
        rate = np.fft.irfft(spec, self.n)
        self.spec_dps = spec / np.maximum(np.sqrt((rate ** 2).mean(1)), 1e-300)[:, None]
        self._grids: Dict[Optional[float], Tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def _grid(self, max_hz: Optional[float]):
        """(angle rad, rate rad/s, acceleration rad/s^2), each (n, 3), on the grid."""
        g = self._grids.get(max_hz)
        if g is None:
            spec = self.spec_dps if max_hz is None else self.spec_dps * (self.freq_hz <= max_hz)
            iw = 2j * np.pi * self.freq_hz
            iw[0] = 1.0                                              # DC is zero anyway
            spec = spec * (np.pi / 180.0)
            g = tuple(np.fft.irfft(x, self.n).T for x in (spec / iw, spec, spec * iw))
            self._grids[max_hz] = g
        return g

    def unit(self, t_s: np.ndarray, max_hz: Optional[float] = None):
        """(angle rad, rate deg/s, angular acceleration rad/s^2), each (n, 3), body frame, at
        RMS rate 1 deg/s; ``max_hz``: the lines above it left out (a sampler's anti-alias band)."""
        p, v, a = self._grid(max_hz)
        x = np.mod(np.asarray(t_s, float) * self.grid_hz, self.n)
        k0 = np.minimum(np.floor(x).astype(np.intp), self.n - 1)
        k1 = (k0 + 1) % self.n
        u = (x - k0)[:, None]
        h = 1.0 / self.grid_hz
        u2, u3 = u * u, u * u * u
        u4, u5 = u3 * u, u3 * u2
        # quintic Hermite basis (value, first and second derivative at both ends) and its
        # first and second derivatives in u
        H = [1 - 10 * u3 + 15 * u4 - 6 * u5, u - 6 * u3 + 8 * u4 - 3 * u5,
             (u2 - 3 * u3 + 3 * u4 - u5) / 2, (u3 - 2 * u4 + u5) / 2,
             -4 * u3 + 7 * u4 - 3 * u5, 10 * u3 - 15 * u4 + 6 * u5]
        D = [-30 * u2 + 60 * u3 - 30 * u4, 1 - 18 * u2 + 32 * u3 - 15 * u4,
             (2 * u - 9 * u2 + 12 * u3 - 5 * u4) / 2, (3 * u2 - 8 * u3 + 5 * u4) / 2,
             -12 * u2 + 28 * u3 - 15 * u4, 30 * u2 - 60 * u3 + 30 * u4]
        S = [-60 * u + 180 * u2 - 120 * u3, -36 * u + 96 * u2 - 60 * u3,
             (2 - 18 * u + 36 * u2 - 20 * u3) / 2, (6 * u - 24 * u2 + 20 * u3) / 2,
             -24 * u + 84 * u2 - 60 * u3, 60 * u - 180 * u2 + 120 * u3]
        c = (p[k0], h * v[k0], h * h * a[k0], h * h * a[k1], h * v[k1], p[k1])
        ang = sum(b * ci for b, ci in zip(H, c))
        rate = np.degrees(sum(b * ci for b, ci in zip(D, c)) / h)
        acc = sum(b * ci for b, ci in zip(S, c)) / (h * h)
        return ang, rate, acc


def _compose(R_tour, w_tour_dps, a_world_g, ang_rad, rate_dps, alpha_rad_s2, lever_m):
    """The tour's motion with a small body rotation (tremor) on top: R = R_tour Rot(ang),
    body rate Rot(ang)^T w_tour + J(ang) rate (J = I - [ang]x / 2, the rotation vector's
    right Jacobian to first order: the next term is ~|ang|^2 ~ 1e-6 of the rate), and the
    tangential acceleration alpha x r of a point ``lever_m`` along body x from the pivot,
    into the world acceleration (g)."""
    Q = _rotvec_batch(ang_rad)
    R = R_tour @ Q
    w = np.einsum("nji,nj->ni", Q, w_tour_dps) + rate_dps - 0.5 * np.cross(ang_rad, rate_dps)
    lever_g = np.cross(alpha_rad_s2, np.array([lever_m, 0.0, 0.0])) / _G_M_S2
    return R, w, a_world_g + np.einsum("nij,nj->ni", R, lever_g)


def _motion(R, w_dps, a_world_g, B_world_gauss, temp_c, still) -> Dict[str, np.ndarray]:
    f = np.einsum("nji,nj->ni", R, a_world_g + _UP)                    # R^T (a + up), g
    h = np.einsum("nji,j->ni", R, B_world_gauss)
    return {"f": f, "w": w_dps, "h": h, "temp": temp_c, "R": R, "still": still}


class PoseTour:
    """Hold each pose, then move to the next; evaluate at any times with :meth:`sample`.

    ``hold_s``/``move_s``: a number or a (lo, hi) range drawn uniformly per pose/move;
    the first hold is ``lead_s`` longer.  A looped tour of one pose holds it throughout.  Each move turns about a fixed body axis with a
    smoothstep angle profile and carries a linear-acceleration bump ``sin(2 pi tau)`` of up
    to ``move_accel_g`` (a uniform 0.3-1 fraction of it) in a random world direction.

    ``tremor_dps`` > 0 adds hand tremor (6-12 Hz, that RMS rate per axis; real hands
    0.5-2 deg/s): physical, the wobble rotates the board (the accelerometer sees gravity
    tilt), the gyro sees its rate, and a point ``tremor_lever_m`` from the wrist pivot sees
    alpha x r (2.5 cm gives the accelerometer 1.3-3x its noise variance at 1.5 deg/s, as
    real hand-held poses show).  A sequence gives each pose its own amplitude over its hold
    (e.g. 10 bench poses at 0 then 10 hand-held at 1.5); during the move after pose i the
    amplitude goes over to pose i+1's along the move's smoothstep, and the rate and
    acceleration carry the envelope's derivatives.

    ``sway_deg`` > 0 adds a hand's slow sway on top, throughout: the same Gaussian process
    (:class:`HandTremor`) over :data:`SWAY_BAND_HZ` (0.2-2 Hz), scaled to that RMS *angle*
    per axis (real hands: 0.05-0.4 deg), physical like the tremor.  Its draws come after
    all others, so a tour without sway is the one it always was.

    Temperature: ``temp_kind`` (see :func:`temperature_profile`) over the tour's first pass,
    or 'exponential' with ``temp_tau_s`` (the default: the emulated board warming up).
    Random draws, in order: per pose its hold, then (with a move) the bump's direction and
    amplitude and the move's duration; then the tremor's frequencies, phases and weights.
    """

    def __init__(self, rotations: np.ndarray, rng: RngLike = None,
                 hold_s=(6.0, 10.0), move_s=(2.0, 4.0), lead_s: float = 2.0,
                 move_accel_g: float = 0.2, field_gauss: float = 0.5, dip_deg: float = 60.0,
                 temp0_c: float = 22.0, temp_rise_c: float = 6.0, temp_tau_s: float = 600.0,
                 loop: bool = False, tremor_dps: Union[float, Sequence[float]] = 0.0,
                 tremor_lever_m: float = 0.025, temp_kind: str = "exponential",
                 sway_deg: float = 0.0):
        rng = as_rng(rng)
        draw = lambda v: float(rng.uniform(*v)) if isinstance(v, tuple) else float(v)
        self.R = np.asarray(rotations, float)
        n = len(self.R)
        self.loop = loop
        t = 0.0
        holds, moves, ends = [], [], []
        self.axis = np.zeros((n, 3))
        self.angle = np.zeros(n)
        self.bump_dir = np.zeros((n, 3))
        self.bump_amp = np.zeros(n)
        self.has_move = np.zeros(n, bool)
        for i in range(n):
            holds.append(t)
            t += draw(hold_s) + (lead_s if i == 0 else 0.0)
            moves.append(t)
            # a looped tour of one pose is a board left still (`record --poses 1`, the noise
            # guide's recording): no move back to where it is, which lifted it every pass
            if i + 1 < n or (loop and n > 1):
                nxt = self.R[(i + 1) % n]
                rv = log_so3(self.R[i].T @ nxt)
                ang = np.linalg.norm(rv)
                self.axis[i] = rv / ang if ang > 0 else np.array([1.0, 0, 0])
                self.angle[i] = ang
                d = rng.normal(size=3)
                self.bump_dir[i] = d / np.linalg.norm(d)
                self.bump_amp[i] = rng.uniform(0.3, 1.0) * move_accel_g
                self.has_move[i] = True
                t += draw(move_s)
            ends.append(t)
        self.t_hold0 = np.array(holds)
        self.t_move0 = np.array(moves)
        self.t_end = np.array(ends)
        self.period = t
        self.B_world = field_world_gauss(field_gauss, dip_deg)
        self.temp_kind = temp_kind
        self.temp0_c, self.temp_rise_c, self.temp_tau_s = temp0_c, temp_rise_c, temp_tau_s
        temperature_profile(np.zeros(1), temp_kind)                  # an unknown kind fails here
        env = np.broadcast_to(np.asarray(tremor_dps, float), (n,)) if np.ndim(tremor_dps) == 0 \
            else np.asarray(tremor_dps, float)
        if len(env) != n:
            raise ValueError(f"tremor_dps: {len(env)} values for {n} poses")
        self.tremor_env_dps = env
        self.tremor_dps = float(env.max()) if n else 0.0
        self.tremor_lever_m = float(tremor_lever_m)
        # the tremor's own period: the tour's, or for a looped tour 1.618 of it (the hand does
        # not repeat itself at each pass)
        self._tremor = HandTremor(rng, self.period * (1.618 if loop else 1.0) + 1.0) \
            if self.tremor_dps > 0 else None
        self.sway_deg = float(sway_deg)
        self._sway = None
        if self.sway_deg > 0:
            self._sway = HandTremor(rng, self.period * (1.618 if loop else 1.0) + 1.0, band_hz=SWAY_BAND_HZ)
            p = self._sway._grid(None)[0]                    # angle, rad, at RMS rate 1 deg/s
            self._sway_k = self.sway_deg / np.degrees(np.sqrt((p ** 2).mean(0)))   # per axis

    @property
    def duration_s(self) -> float:
        return self.period

    def holds(self):
        """(start, end) of every still interval in the first pass, s."""
        return list(zip(self.t_hold0, self.t_move0))

    def sample_times(self, rate_hz: float) -> np.ndarray:
        """A logger's sample times over the first pass: k / rate_hz for k = 0, 1, ... while
        before the tour's end, s."""
        n = int(np.floor(self.period * rate_hz - 1e-9)) + 1
        return np.arange(max(n, 1)) / rate_hz

    def _segments(self, t):
        tt = np.mod(t, self.period) if self.loop else np.clip(t, 0, self.period)
        i = np.clip(np.searchsorted(self.t_end, tt, side="right"), 0, len(self.R) - 1)
        moving = (tt >= self.t_move0[i]) & self.has_move[i]
        dur = np.maximum(self.t_end[i] - self.t_move0[i], 1e-9)
        tau = np.where(moving, np.clip((tt - self.t_move0[i]) / dur, 0, 1), 0.0)
        return i, moving, dur, tau

    def tremor(self, t: np.ndarray, max_hz: Optional[float] = None):
        """Hand tremor at times t (n,): (angle rad (n, 3), rate deg/s (n, 3), angular
        acceleration rad/s^2 (n, 3)), body frame; zeros without tremor."""
        t = np.atleast_1d(np.asarray(t, float))
        if self._tremor is None:
            z = np.zeros((len(t), 3))
            return z, z, z
        ang, rate, acc = self._tremor.unit(t, max_hz)
        env = self.tremor_env_dps
        if np.all(env == env[0]):
            return env[0] * ang, env[0] * rate, env[0] * acc
        i, moving, dur, tau = self._segments(t)
        e0 = env[i]
        # per-pose amplitude: smoothstep from pose i's to pose i+1's during the move after i
        de = np.where(moving, env[(i + 1) % len(self.R)] - e0, 0.0)
        e = (e0 + de * (3 * tau ** 2 - 2 * tau ** 3))[:, None]
        e1 = (de * 6 * tau * (1 - tau) / dur)[:, None]                # d envelope / dt
        e2 = (de * (6 - 12 * tau) / dur ** 2)[:, None]                # d2 envelope / dt2
        return (e * ang, e * rate + e1 * np.degrees(ang),
                e * acc + 2 * e1 * np.radians(rate) + e2 * ang)

    def sample(self, t: np.ndarray, max_hz: Optional[float] = None) -> Dict[str, np.ndarray]:
        """Motion at times t (n,): keys f (g), w (deg/s), h (gauss), temp (degC), R, still.
        ``max_hz``: the tremor's components above it left out (a logger's Nyquist band)."""
        t = np.atleast_1d(np.asarray(t, float))
        i, moving, dur, tau = self._segments(t)
        s = 3 * tau ** 2 - 2 * tau ** 3
        sdot = np.where(moving, 6 * tau * (1 - tau) / dur, 0.0)
        R = self.R[i] @ _rodrigues_batch(self.axis[i], self.angle[i] * s)
        w = np.degrees(self.axis[i] * (self.angle[i] * sdot)[:, None])
        a_world = (self.bump_amp[i] * np.sin(2 * np.pi * tau) * moving)[:, None] * self.bump_dir[i]
        if self._tremor is not None or self._sway is not None:
            ang, rate, alpha = self.tremor(t, max_hz)
            if self._sway is not None:
                ang, rate, alpha = (x + self._sway_k * y for x, y in zip((ang, rate, alpha),
                                                                         self._sway.unit(t, max_hz)))
            R, w, a_world = _compose(R, w, a_world, ang, rate, alpha, self.tremor_lever_m)
        temp = temperature_profile(t, self.temp_kind, self.temp0_c, self.temp_rise_c,
                                   span_s=self.period, tau_s=self.temp_tau_s)
        return _motion(R, w, a_world, self.B_world, temp, ~moving)


class Tumble:
    """A board turned slowly by hand without ever stopping: the body rate's direction wanders
    smoothly (8 sinusoids per axis at 0.02-0.3 Hz) and its magnitude stays within
    ``speed_dps`` (a slow sinusoid), with a small hand-like linear acceleration
    (``move_accel_g``, 0.5 Hz).  The attitude is integrated on a ``fine_hz`` grid with the
    rate held over each step, so :meth:`sample` is exact for that piecewise-constant rate at
    any time.  Temperature constant at ``temp0_c``; ``still`` is always False."""

    def __init__(self, rng: RngLike = None, duration_s: float = 120.0,
                 speed_dps: Tuple[float, float] = (15.0, 60.0), move_accel_g: float = 0.05,
                 fine_hz: float = 200.0, field_gauss: float = 0.5, dip_deg: float = 60.0,
                 temp0_c: float = 22.0):
        from .orientations import axis_angle
        rng = as_rng(rng)
        self.fine_hz = fine_hz
        nf = int(round(duration_s * fine_hz))
        tf = np.arange(nf) / fine_hz
        nk = 8
        fr = rng.uniform(0.02, 0.3, size=(nk, 3))
        ph = rng.uniform(0, 2 * np.pi, size=(nk, 3))
        amp = rng.normal(size=(nk, 3))
        d = (amp[None] * np.sin(2 * np.pi * fr[None] * tf[:, None, None] + ph[None])).sum(1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)             # direction (never 0 speed)
        sp_hz = rng.uniform(0.01, 0.05)
        sp = np.interp(np.sin(2 * np.pi * sp_hz * tf + rng.uniform(0, 6.3)), [-1, 1], list(speed_dps))
        self.w_grid_dps = d * sp[:, None]
        R = np.empty((nf, 3, 3))
        Rc = axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
        for k in range(nf):
            R[k] = Rc
            wv = np.radians(self.w_grid_dps[k]) / fine_hz
            ang = np.linalg.norm(wv)
            if ang > 0:
                Rc = Rc @ axis_angle(wv / ang, ang)
        self.R_grid = R
        self.acc_phase_rad = rng.uniform(0, 6.3, 3)
        self.move_accel_g = move_accel_g
        self.period = nf / fine_hz
        self._span_s = float(duration_s)
        self.B_world = field_world_gauss(field_gauss, dip_deg)
        self.temp0_c = temp0_c

    @property
    def duration_s(self) -> float:
        return self.period

    def holds(self):
        return []

    def sample_times(self, rate_hz: float) -> np.ndarray:
        """A logger's sample times, s, whose nearest grid step lies inside the tumble."""
        t = np.arange(0.0, self._span_s, 1.0 / rate_hz)
        return t[np.round(t * self.fine_hz) < len(self.R_grid)]

    def sample(self, t: np.ndarray, max_hz: Optional[float] = None) -> Dict[str, np.ndarray]:
        """Motion at times t (n,) within the tumble: keys f, w, h, temp, R, still."""
        t = np.atleast_1d(np.asarray(t, float))
        x = t * self.fine_hz
        k = np.clip(np.floor(x + 1e-6).astype(int), 0, len(self.R_grid) - 1)
        w = self.w_grid_dps[k]
        R = self.R_grid[k] @ _rotvec_batch(np.radians(w) * ((x - k) / self.fine_hz)[:, None])
        a_world = self.move_accel_g * np.sin(2 * np.pi * 0.5 * t[:, None] + self.acc_phase_rad[None])
        return _motion(R, w, a_world, self.B_world, np.full(len(t), self.temp0_c),
                       np.zeros(len(t), bool))
