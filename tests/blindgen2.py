"""A blind test generator blind in model space (issue 25 item 5).

Written apart from imucald.sim and imucald.gap: it imports only ``Recording``; its effect
forms are not the library's (no degree-1 thermal polynomial, no 6-parameter quadratic,
no (1 + c dT) scale), and its magnitudes come from datasheet figures (cited below), drawn
log-uniform over a decade (0.5x to 5x) around them.  Each recording draws its own sample
rate (25-200 Hz), LSBs (the chips' full-scale settings), latitude (any, |lat| < 70 deg),
noise density (0.5x-1.5x the datasheet), flicker, pose count and hold lengths, and
(class by class) hand tremor.

Datasheet figures used (the MPU-6050 Product Specification rev 3.4, tables 6.1 and 6.2;
HMC5883L datasheet): accelerometer noise 400 ug/rtHz, zero-g change 35 mg over 0..70 C
(0.5 mg/C), sensitivity change 0.02 %/C, nonlinearity 0.5 % of 2 g full scale; gyro noise
0.005 dps/rtHz, linear acceleration sensitivity 0.1 dps/g, ZRO change 20 dps over
-40..85 C (0.16 dps/C, the upper bound; 0.03 dps/C typical of the ITG-3200); magnetometer
2 mG noise.

Classes (``LIBRARY`` expect a library name, ``OUTSIDE`` are reported by what they are
called, ``NULLS`` expect "none"):

* thermal_bias: a bias following temperature through a saturating curve
  b (T - T0) / (1 + |T - T0| / 40 C) plus a small curvature;
* thermal_scale: a gain change per axis following temperature through exp(k (T - T0)) - 1;
* nonlinearity: each axis a quadratic form of the true specific force with a full
  symmetric 3x3 matrix (nine cross terms, not the library's six);
* random_walk: a bias random walk (Gaussian increments), its end sd log-uniform;
* pair_nl_thermal: nonlinearity and thermal_bias together;
* gyro_thermal: a gyro bias following temperature (the curve above), tremor-free;
* gyro_gsens_tremor: gyro g-sensitivity (a full 3x3 matrix) under hand tremor;
* mag_thermal: a hard iron following temperature;
* outside: thermal_hysteresis (bias differs heating and cooling), temp_rate (bias
  proportional to dT/dt), cubic (f^3 per axis), cross_product (f_x f_y on z and so on),
  step_bias (a bias jump at a random time), vibration_rectification (a bias proportional
  to each pose's vibration energy), timestamp_jitter (sample times jittered, no sensor
  effect: a verdict other than "none" is reported), piecewise_bias (a bias piecewise linear
  in time through 3-5 knots at random times; appended last, so the other classes' seeds
  and draws are unchanged).

``make_case`` returns the recording and a label: the judged sensor, the accepted verdicts,
and for the bench's truth projection (bench/gap_blind.py ``truth_check``) the noise-free
signal per sample (``noise_free``: unquantised, without the white and flicker noise), the
injected effect alone (``effect``), the generator's pose of each sample (``pose_id``, -1
while moving), the true temperature (``temp_true_c``), the latitude and the white noise's
per-sample standard deviation (``noise_sd``); for the random walk its intensity (``truth``).
"""
from __future__ import annotations

import math
from typing import Dict, Tuple

import numpy as np
from scipy.signal import lfilter

from imucald.files.recording import Recording

OMEGA_E_DPS = math.degrees(7.2921e-5)        # IERS Earth rate
NULLS = ["null", "null_flicker", "tremor_null", "mag_null"]
LIBRARY = ["thermal_bias", "thermal_scale", "nonlinearity", "random_walk", "pair_nl_thermal",
           "gyro_thermal", "gyro_gsens_tremor", "mag_thermal"]
OUTSIDE = ["thermal_hysteresis", "temp_rate", "cubic", "cross_product", "step_bias",
           "vibration_rectification", "timestamp_jitter", "piecewise_bias"]
CLASSES = NULLS + LIBRARY + OUTSIDE

#: which sensor's verdict a class is judged on, and the accepted verdict names
SENSOR = {"gyro_thermal": "gyro", "gyro_gsens_tremor": "gyro", "mag_thermal": "mag", "mag_null": "mag"}


def _loguni(rng, centre, lo=0.5, hi=5.0, size=None):
    return centre * np.exp(rng.uniform(math.log(lo), math.log(hi), size))


def _sign(rng, n=3):
    return rng.choice([-1.0, 1.0], n)


def _rot(q):
    q = q / np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _slerp_path(q0, q1, u):
    """Quaternions along the great arc from q0 to q1 at fractions u (m,)."""
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    th = math.acos(min(d, 1.0))
    if th < 1e-9:
        return np.repeat(q0[None], len(u), 0)
    return (np.sin((1 - u) * th)[:, None] * q0 + np.sin(u * th)[:, None] * q1) / math.sin(th)


def _quat_rate_body(q, dt):
    """Body rates (m, 3) deg/s from consecutive quaternions (finite differences)."""
    dq = np.gradient(q, dt, axis=0)
    w, x, y, z = q.T
    # omega_body = 2 q* dq (vector part)
    wx = 2 * (w * dq[:, 1] - x * dq[:, 0] - y * dq[:, 3] + z * dq[:, 2])
    wy = 2 * (w * dq[:, 2] + x * dq[:, 3] - y * dq[:, 0] - z * dq[:, 1])
    wz = 2 * (w * dq[:, 3] - x * dq[:, 2] + y * dq[:, 1] - z * dq[:, 0])
    return np.degrees(np.stack([wx, wy, wz], 1))


def _trajectory(rng, rate_hz, n_poses, hold, move):
    qs = [rng.normal(size=4) for _ in range(n_poses)]
    qs = [q / np.linalg.norm(q) for q in qs]
    Q, pid = [], []
    for k, q in enumerate(qs):
        m = int(rng.uniform(*hold) * rate_hz)
        Q.append(np.repeat(q[None], m, 0))
        pid.append(np.full(m, k))
        if k + 1 < n_poses:
            mm = max(4, int(rng.uniform(*move) * rate_hz))
            u = np.arange(mm) / mm
            u = 0.5 - 0.5 * np.cos(np.pi * u)                       # eased start and stop
            Q.append(_slerp_path(q, qs[k + 1], u))
            pid.append(np.full(mm, -1))
    Q = np.concatenate(Q)
    for i in range(1, len(Q)):                                       # continuous sign
        if np.dot(Q[i], Q[i - 1]) < 0:
            Q[i] = -Q[i]
    return Q, np.concatenate(pid)


def _tremor(rng, t, rms_dps):
    """Hand tremor: a sum of 12 sinusoids at 5-11 Hz with random phases; (rate dps, angle rad)."""
    f = rng.uniform(5, 11, (12, 3))
    ph = rng.uniform(0, 2 * np.pi, (12, 3))
    a = rng.uniform(0.5, 1.0, (12, 3))
    rate = np.einsum("ka,nka->na", a, np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None]))
    rate *= rms_dps / rate.std(0)
    ang = np.radians(np.cumsum(rate, 0) * float(np.median(np.diff(t))))
    return rate, ang - ang.mean(0)


def _noise(rng, n, rate_hz, density, flicker_sd):
    x = rng.normal(size=(n, 3)) * density * math.sqrt(rate_hz / 2)
    if flicker_sd > 0:
        for tau in (2.0, 20.0, 200.0):
            phi = math.exp(-1.0 / (rate_hz * tau))
            e = rng.normal(size=(n, 3)) * flicker_sd / math.sqrt(3) * math.sqrt(1 - phi * phi)
            y0 = rng.normal(size=3) * flicker_sd / math.sqrt(3)
            x += lfilter([1.0], [1.0, -phi], e, axis=0, zi=(phi * y0)[None, :])[0]
    return x


def _sat_curve(dT):
    return dT / (1 + np.abs(dT) / 40.0) + 0.004 * dT ** 2


def make_case(kind: str, seed: int) -> Tuple[Recording, Dict[str, object]]:
    rng = np.random.default_rng(9_000_000 + seed * 97 + CLASSES.index(kind))
    rate_hz = float(rng.choice([25.0, 50.0, 100.0, 200.0]))
    tremor = kind in ("tremor_null", "gyro_gsens_tremor")
    n_poses = int(rng.integers(22, 36))
    hold = (2.0, 4.0) if tremor else (6.0, 14.0)
    Q, pid = _trajectory(rng, rate_hz, n_poses, hold, (1.5, 3.0))
    n = len(Q)
    t = np.arange(n) / rate_hz
    R = np.stack([_rot(q) for q in Q])                                # body -> world
    w_body = _quat_rate_body(Q, 1 / rate_hz)
    if tremor:
        tr_rate, tr_ang = _tremor(rng, t, float(rng.uniform(0.7, 2.0)))
        w_body = w_body + tr_rate
        # small-angle wobble of the gravity direction in the body frame
    f = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, 1.0]))         # specific force, g
    if tremor:
        f = f - np.cross(tr_ang, f)
    # temperature: heat then cool, or a warm-up; a few degrees to 15 C
    T0 = rng.uniform(15, 30)
    rise = rng.uniform(6, 15)
    profile = "heatcool" if kind in ("thermal_hysteresis", "thermal_scale") else rng.choice(["warmup", "heatcool"])
    if profile == "warmup":
        T = T0 + rise * (1 - np.exp(-t / (rng.uniform(0.2, 0.4) * t[-1])))
    else:
        T = T0 + rise * np.abs(np.sin(np.pi * t / t[-1])) ** 1.5
    dT = T - T.mean()
    lat = math.radians(rng.uniform(-70, 70))
    # accelerometer: gain matrix, bias, noise (MPU-6050: 400 ug/rtHz)
    lsb_a = float(rng.choice([1 / 16384, 1 / 8192, 1 / 4096]))
    Ga = np.diag(1 + rng.normal(0, 0.02, 3)) + rng.normal(0, 0.006, (3, 3)) * (1 - np.eye(3))
    acc = f @ Ga.T + rng.normal(0, 0.04, 3)
    flick = 0.0 if kind == "null" else float(_loguni(rng, 30e-6, 0.5, 2.0))
    dens_a = 400e-6 * rng.uniform(0.5, 1.5)
    acc_noise = _noise(rng, n, rate_hz, dens_a, flick)
    acc += acc_noise
    # gyro: 0.005 dps/rtHz, Earth's rate at the latitude, random heading
    lsb_g = float(rng.choice([1 / 131, 1 / 65.5, 1 / 14.375]))
    head = rng.uniform(0, 2 * np.pi)
    e_world = OMEGA_E_DPS * np.array([math.cos(lat) * math.cos(head), math.cos(lat) * math.sin(head), math.sin(lat)])
    Gg = np.diag(1 + rng.normal(0, 0.02, 3)) + rng.normal(0, 0.01, (3, 3)) * (1 - np.eye(3))
    gyro = (w_body + np.einsum("nji,j->ni", R, e_world)) @ Gg.T + rng.normal(0, 1.0, 3)
    dens_g = 0.005 * rng.uniform(0.5, 1.5)
    gyro_noise = _noise(rng, n, rate_hz, dens_g, 0.0 if kind == "null" else 3e-4)
    gyro += gyro_noise
    label: Dict[str, object] = {"class": kind, "sensor": SENSOR.get(kind, "accel"), "expect": {"none"},
                                "truth": {}, "rate_hz": rate_hz}
    mono = profile == "warmup"
    acc_before, gyro_before = acc.copy(), gyro.copy()        # the injected effect is the difference
    if kind == "thermal_bias":
        b = _sign(rng) * _loguni(rng, 0.5e-3, size=3)                 # g/C, datasheet 0.5 mg/C
        acc += _sat_curve(T - T0)[:, None] * b
        label["expect"] = {"thermal_bias", "bias_drift", "wandering_bias"} if mono else {"thermal_bias"}
    elif kind == "thermal_scale":
        k = _sign(rng) * _loguni(rng, 2e-4, size=3)                   # 1/C, datasheet 0.02 %/C
        acc += (f @ Ga.T) * (np.exp(k * (T - T0)[:, None]) - 1)
        label["expect"] = {"thermal_scale"}
    elif kind in ("nonlinearity", "pair_nl_thermal"):
        lvl = float(_loguni(rng, 2.5e-3))                              # g/g^2, 0.5 % of 2 g FS
        M = rng.normal(size=(3, 3, 3))
        M = (M + M.transpose(0, 2, 1)) / 2
        M *= lvl / np.abs(M).max(axis=(1, 2))[:, None, None]
        acc += np.einsum("ni,kij,nj->nk", f, M, f)
        label["expect"] = {"nonlinearity"}
        if kind == "pair_nl_thermal":
            b = _sign(rng) * _loguni(rng, 0.5e-3, size=3)
            acc += _sat_curve(T - T0)[:, None] * b
            label["expect"] = {"nonlinearity+thermal_bias", "thermal_bias+nonlinearity"}
            label["pair"] = True
            if mono:
                label["expect"] |= {"nonlinearity+bias_drift", "bias_drift+nonlinearity",
                                    "nonlinearity+wandering_bias", "wandering_bias+nonlinearity"}
    elif kind == "random_walk":
        end = float(_loguni(rng, 1e-3))                                # g at the end of the record
        acc += np.cumsum(rng.normal(size=(n, 3)), 0) * end / math.sqrt(n)
        # the walk's intensity (variance growth per second, each axis): (end^2 / n) per sample
        label["truth"] = {"random_walk_intensity_g^2/s": end ** 2 / (n / rate_hz)}
        label["expect"] = {"wandering_bias", "bias_drift"}
    elif kind == "gyro_thermal":
        c = _sign(rng) * _loguni(rng, 0.03, size=3)                   # dps/C
        gyro += _sat_curve(T - T0)[:, None] * c
        label["expect"] = {"thermal_bias", "bias_drift", "wandering_bias"} if mono else {"thermal_bias"}
    elif kind == "gyro_gsens_tremor":
        G = rng.normal(size=(3, 3))
        G *= float(_loguni(rng, 0.1)) / np.abs(G).max()               # dps/g, datasheet 0.1
        gyro += f @ G.T
        label["expect"] = {"g_sensitivity"}
    elif kind == "thermal_hysteresis":
        heating = np.gradient(T) > 0
        acc += np.where(heating, 1.0, -1.0)[:, None] * _sign(rng) * _loguni(rng, 1e-3, size=3) * 0.5
        label["expect"] = {"unexplained", "partially_explained"}
    elif kind == "temp_rate":
        dTdt = np.gradient(T, t) * 60.0                                # C/min
        acc += dTdt[:, None] * _sign(rng) * _loguni(rng, 1e-3, size=3)
        label["expect"] = {"unexplained", "partially_explained"}
    elif kind == "cubic":
        acc += _sign(rng) * _loguni(rng, 3e-3, size=3) * f ** 3
        label["expect"] = {"unexplained", "partially_explained"}
    elif kind == "cross_product":
        acc += _sign(rng) * _loguni(rng, 4e-3, size=3) * np.stack([f[:, 1] * f[:, 2], f[:, 2] * f[:, 0],
                                                                   f[:, 0] * f[:, 1]], 1)[:, [2, 0, 1]]
        label["expect"] = {"unexplained", "partially_explained"}
    elif kind == "step_bias":
        at = rng.uniform(0.3, 0.7) * t[-1]
        acc += (t > at)[:, None] * _sign(rng) * _loguni(rng, 1e-3, size=3)
        label["expect"] = {"unexplained", "partially_explained", "wandering_bias"}
    elif kind == "vibration_rectification":
        energy = np.zeros(n)
        for k in range(n_poses):
            energy[pid == k] = rng.exponential(1.0)
        acc += energy[:, None] * _sign(rng) * _loguni(rng, 0.5e-3, size=3)
        vib = rng.normal(size=(n, 3)) * np.sqrt(energy)[:, None] * 2e-3   # the vibration itself
        acc += vib
        acc_noise = acc_noise + vib
        label["expect"] = {"unexplained", "partially_explained"}
    elif kind == "piecewise_bias":
        # a bias piecewise linear in time through 3-5 knots at random (not equally spaced)
        # times, each knot's value drawn afresh: a bias that changes its drift now and then
        m = int(rng.integers(3, 6))
        knots = np.sort(np.concatenate([[0.0, t[-1]], rng.uniform(0.1, 0.9, m - 2) * t[-1]]))
        vals = rng.normal(size=(m, 3)) * _loguni(rng, 1e-3)
        acc += np.stack([np.interp(t, knots, vals[:, j]) for j in range(3)], 1)
        label["expect"] = {"unexplained", "partially_explained", "wandering_bias", "bias_drift"}
    effect = {"acc": acc - acc_before, "gyro": gyro - gyro_before, "mag": None}
    if kind == "vibration_rectification":
        effect["acc"] = effect["acc"] - vib
    mag = mag_noise = None
    if kind in ("mag_null", "mag_thermal"):
        dip = math.radians(rng.uniform(-70, 70))
        F = float(rng.uniform(0.25, 0.65))
        h_world = F * np.array([math.cos(dip), 0.0, -math.sin(dip)])
        A = np.eye(3) + (lambda E: (E + E.T) / 2)(rng.normal(0, 0.03, (3, 3)))
        hard = rng.normal(0, 0.2, 3) + np.zeros((n, 3))
        if kind == "mag_thermal":
            c = _sign(rng) * _loguni(rng, 0.5e-3, size=3)             # gauss/C
            hard = hard + _sat_curve(T - T0)[:, None] * c
            label["expect"] = {"thermal_bias", "bias_drift"} if mono else {"thermal_bias"}
            effect["mag"] = _sat_curve(T - T0)[:, None] * c
        mag_noise = rng.normal(0, 2e-3, (n, 3))
        mag = np.einsum("nji,j->ni", R, h_world) @ A.T + hard + mag_noise
        effect["mag"] = np.zeros((n, 3)) if effect["mag"] is None else effect["mag"]
        noise_free_mag = mag - mag_noise
        mag = np.round(mag * 1090) / 1090
    acc_pre_q, gyro_pre_q = acc, gyro
    acc = np.round(acc / lsb_a) * lsb_a
    gyro = np.round(gyro / lsb_g) * lsb_g
    tt = t.copy()
    if kind == "timestamp_jitter":
        tt = t + rng.uniform(-0.3, 0.3, n) / rate_hz
        tt = np.maximum.accumulate(tt)
        label["expect"] = {"none"}
    temp = np.round(T * 340) / 340
    meta = {"board": "blind2", "rate_hz": f"{rate_hz:g}", "accel_range_g": f"{32768 * lsb_a:g}"}
    label["profile"] = profile
    # what the bench needs to project the truth onto the library's forms (noise-free,
    # unquantised, per sample): the whole noise-free signal, the injected effect alone, the
    # generator's pose of each sample (-1 while moving), the true temperature, and the
    # white noise's per-sample standard deviation (the flicker's slow part not included)
    label["noise_free"] = {"acc": acc_pre_q - acc_noise, "gyro": gyro_pre_q - gyro_noise,
                           "mag": None if mag is None else noise_free_mag}
    label["effect"] = effect
    label["pose_id"] = pid
    label["temp_true_c"] = T
    label["latitude_deg"] = math.degrees(lat)
    label["noise_sd"] = {"acc": dens_a * math.sqrt(rate_hz / 2), "gyro": dens_g * math.sqrt(rate_hz / 2),
                         "mag": 2e-3}
    return Recording(t=tt, acc=acc, gyro=gyro, mag=mag, temp=temp, meta=meta), label


def hit(verdict: str, expect) -> bool:
    if verdict in expect:
        return True
    parts = set(str(verdict).split("+"))
    allowed = set()
    for e in expect:
        allowed |= set(e.split("+"))
    return bool(parts) and parts <= allowed - {"none", "unexplained", "partially_explained"} and \
        not any("+" in e for e in expect)
