"""Blind-test recordings for ``imucald gap``, written apart from the simulator and the
candidate library (imucald.sim, imucald.gap): own motion, noise and effect code, with
other parametrisations:

* sensor errors as a full 3x3 gain matrix (not the library's triangular model);
* thermal effects as a polynomial in absolute temperature (K);
* nonlinearity as a cross-coupled quadratic form per axis;
* drifts as random walks (integrated white noise), not straight lines;
* forms outside the library: per-axis cubic, the triple product f_x f_y f_z,
  orientation hysteresis (a bias set by the previous pose's gravity direction);
* noise: white plus flicker (a sum of first-order Gauss-Markov processes with
  log-spaced time constants), quantised to the LSB;
* motion: uniformly random orientations (quaternions), raised-cosine turns, optional
  hand tremor (a few-hundredths-of-a-degree wobble at 6-10 Hz) and short holds;
* Earth's rotation in the gyro (latitude 48 deg), a tilted Earth field for the
  magnetometer with ordinary soft iron (a few per cent) and hard iron, and (class
  mag_thermal) a hard iron moving with the absolute temperature.

Every case returns (Recording, label) with label = {"class", "sensor", "expect"}:
``expect`` is the set of verdicts that count as a hit (confusable classes merged as in
../shared/reference/error-models.md section 5).
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Tuple

import numpy as np
from scipy.signal import lfilter

from imucald.files.recording import Recording

T_REF_K = 298.15
EARTH_RATE_DPS = math.degrees(7.2921e-5)
LAT = math.radians(48.0)


def _quat_to_R(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _axis_angle(R):
    c = np.clip((np.trace(R) - 1) / 2, -1, 1)
    th = math.acos(c)
    if th < 1e-9:
        return np.array([1.0, 0, 0]), 0.0
    a = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2 * math.sin(th))
    if np.linalg.norm(a) < 1e-6:                      # ~180 deg: axis from R + I
        M = R + np.eye(3)
        a = M[:, int(np.argmax(np.linalg.norm(M, axis=0)))]
    return a / np.linalg.norm(a), th


def _rodrigues(a, th):
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def motion(rng, n_poses: int, rate_hz: float, hold_s=(12.0, 20.0), move_s=(2.0, 3.5),
           single: bool = False, tremor: bool = False, duration_s: Optional[float] = None):
    """Body-to-world rotations R (n, 3, 3), body rates (n, 3) dps, time (n,), pose index per sample
    (-1 while moving)."""
    if single:
        q = rng.normal(size=4) * np.array([1, 0.03, 0.03, 1])       # near level, any heading
        Rs = [_quat_to_R(q)]
        holds = [duration_s]
    else:
        Rs = [_quat_to_R(rng.normal(size=4)) for _ in range(n_poses)]
        holds = rng.uniform(*hold_s, n_poses)
    dt = 1 / rate_hz
    R_all, w_all, pid = [], [], []
    for k, R in enumerate(Rs):
        m = int(holds[k] * rate_hz)
        R_all.append(np.repeat(R[None], m, 0))
        w_all.append(np.zeros((m, 3)))
        pid.append(np.full(m, k))
        if k + 1 < len(Rs):
            a, th = _axis_angle(R.T @ Rs[k + 1])         # body-frame axis
            T = rng.uniform(*move_s)
            mm = int(T * rate_hz)
            u = np.arange(mm) / mm
            ang = th * (u - np.sin(2 * np.pi * u) / (2 * np.pi))        # smooth start and stop
            rate = th * (1 - np.cos(2 * np.pi * u)) / T
            R_all.append(np.stack([R @ _rodrigues(a, x) for x in ang]))
            w_all.append(np.degrees(np.outer(rate, a)))
            pid.append(np.full(mm, -1))
    R_all = np.concatenate(R_all)
    w = np.concatenate(w_all)
    if tremor:
        n = len(w)
        t = np.arange(n) * dt
        f = rng.uniform(6, 10, 3)
        amp = np.radians(rng.uniform(0.02, 0.05, 3))            # small wobble of a resting hand
        ph = rng.uniform(0, 2 * np.pi, 3)
        ang = amp * np.sin(2 * np.pi * f * t[:, None] + ph)
        w = w + np.degrees(amp * 2 * np.pi * f * np.cos(2 * np.pi * f * t[:, None] + ph))
        R_all = np.einsum("nij,njk->nik", R_all, np.stack([_rodrigues(np.array([1.0, 0, 0]), a[0])
                                                          @ _rodrigues(np.array([0, 1.0, 0]), a[1])
                                                          for a in ang]))
    return R_all, w, np.arange(len(w)) * dt, np.concatenate(pid)


def temperature_k(rng, t, kind: str, rise_c: float):
    T0 = T_REF_K + rng.uniform(-5, 5)
    if kind == "flat":
        return T0 + 0.0 * t
    if kind == "warmup":
        tau = rng.uniform(0.15, 0.35) * t[-1]
        return T0 + rise_c * (1 - np.exp(-t / tau))
    # heat then cool
    return T0 + rise_c * np.sin(np.pi * t / t[-1])


def coloured_noise(rng, n, rate_hz, white_psd, flicker_sigma, dims=3):
    """White (density white_psd per sqrt(Hz)) plus flicker-like noise of std ``flicker_sigma``:
    five first-order Gauss-Markov processes, time constants 1..300 s, equal variances."""
    x = rng.normal(size=(n, dims)) * white_psd * math.sqrt(rate_hz)
    if flicker_sigma > 0:
        for tau in np.logspace(0, math.log10(300), 5):
            phi = math.exp(-1 / (rate_hz * tau))
            e = rng.normal(size=(n, dims)) * flicker_sigma / math.sqrt(5) * math.sqrt(1 - phi ** 2)
            y0 = rng.normal(size=dims) * flicker_sigma / math.sqrt(5)
            y = lfilter([1.0], [1.0, -phi], e, axis=0, zi=(phi * y0)[None, :])[0]
            x += y
    return x


def _gain(rng, scale_pct, mis_mrad):
    return np.diag(1 + rng.normal(0, scale_pct / 100, 3)) @ (np.eye(3) + rng.normal(0, mis_mrad / 1000, (3, 3))
                                                             * (1 - np.eye(3)))


def _random_walk(rng, n, rate_hz, end_sigma):
    """A random walk whose standard deviation at the end of the record is end_sigma (per axis)."""
    steps = rng.normal(size=(n, 3)) * end_sigma / math.sqrt(n)
    return np.cumsum(steps, axis=0)


def make_case(kind: str, seed: int, rate_hz: float = 50.0) -> Tuple[Recording, Dict[str, object]]:
    """One blind recording.  kinds: null, null_flicker, thermal_bias, thermal_scale, quadratic,
    random_walk, cubic, triple_product, hysteresis, tremor_null, short_holds_null, mag_null,
    single_warmup_null, single_warmup_thermal, mag_thermal."""
    rng = np.random.default_rng(seed)
    single = kind.startswith("single")
    tremor = kind == "tremor_null"
    short = kind == "short_holds_null"
    n_poses = int(rng.integers(24, 31)) if not short else int(rng.integers(40, 50))
    hold = (2.5, 4.0) if short else (12.0, 20.0)
    R, w_true, t, pid = motion(rng, n_poses, rate_hz, hold_s=hold, single=single, tremor=tremor,
                               duration_s=float(rng.uniform(900, 1200)) if single else None)
    n = len(t)
    tk = "heatcool" if kind in ("thermal_scale",) else ("warmup" if single or rng.random() < 0.5 else "heatcool")
    TK = temperature_k(rng, t, tk, rise_c=float(rng.uniform(8, 14)) if single else float(rng.uniform(5, 9)))
    dTK = TK - T_REF_K
    f = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, 1.0]))      # specific force, body frame, g
    # accelerometer: full gain matrix and bias; MPU-6050-like noise, 1/16384 g LSB
    Ga = _gain(rng, 1.5, 8.0)
    ba = rng.normal(0, 0.03, 3)
    flick_a = 40e-6 if kind != "null" else 0.0
    acc = f @ Ga.T + ba + coloured_noise(rng, n, rate_hz, 400e-6, flick_a)
    # gyro: gain, bias, Earth's rate, noise 0.005 dps/sqrt(Hz), 1/131 dps LSB
    Gg = _gain(rng, 2.0, 10.0)
    bg = rng.normal(0, 1.5, 3)
    earth_w = EARTH_RATE_DPS * np.array([math.cos(LAT), 0.0, math.sin(LAT)])
    w_earth_body = np.einsum("nji,j->ni", R, earth_w)
    gyro = (w_true + w_earth_body) @ Gg.T + bg + coloured_noise(rng, n, rate_hz, 0.005, 0.0005)
    label: Dict[str, object] = {"class": kind, "sensor": "accel", "expect": {"none"}, "truth": {}}
    if kind == "thermal_bias":
        p1 = rng.choice([-1, 1], 3) * rng.uniform(0.15, 0.6, 3) * 1e-3           # g/K
        acc += dTK[:, None] * p1
        label.update(expect={"thermal_bias", "bias_drift"} if tk == "warmup" else {"thermal_bias"},
                     truth={"thermal_bias_g/degC": p1.tolist()})
    elif kind == "thermal_scale":
        s1 = rng.choice([-1, 1], 3) * rng.uniform(1.5e-4, 3e-4, 3)              # 1/K
        acc += (f @ Ga.T) * (s1 * dTK[:, None])
        label.update(expect={"thermal_scale"})
    elif kind == "quadratic":
        # cross-coupled quadratic form per axis: a_k += f^T N_k f, N_k with its own-axis
        # square and the other two axes' product (reference E3 + E4), 1.5-4 mg/g^2
        N = np.zeros((3, 3, 3))
        for k in range(3):
            i, j = [a for a in range(3) if a != k]
            N[k, k, k] = rng.choice([-1, 1]) * rng.uniform(1.5e-3, 4e-3)
            N[k, i, j] = N[k, j, i] = rng.choice([-1, 1]) * rng.uniform(1.5e-3, 4e-3) / 2
        acc += np.einsum("ni,kij,nj->nk", f, N, f)
        label.update(expect={"nonlinearity"})
    elif kind == "random_walk":
        acc += _random_walk(rng, n, rate_hz, float(rng.uniform(0.6e-3, 1.2e-3)))
        label.update(expect={"wandering_bias", "bias_drift"})
    elif kind == "cubic":
        acc += rng.choice([-1, 1], 3) * rng.uniform(3e-3, 5e-3, 3) * f ** 3
        label.update(expect={"unexplained", "partially_explained"})
    elif kind == "triple_product":
        acc += rng.choice([-1, 1], 3) * rng.uniform(8e-3, 12e-3, 3) * (f[:, 0] * f[:, 1] * f[:, 2])[:, None]
        label.update(expect={"unexplained", "partially_explained"})
    elif kind == "hysteresis":
        prev = np.zeros((n, 3))
        last = np.zeros(3)
        cur = -2
        for i in range(n):
            if pid[i] != cur and pid[i] >= 0:
                if cur >= 0:
                    last = f[i - 1].copy()
                cur = pid[i]
            prev[i] = last
        acc += 1.5e-3 * prev
        label.update(expect={"unexplained", "partially_explained"})
    elif kind == "single_warmup_thermal":
        p1 = rng.choice([-1, 1], 3) * rng.uniform(0.3, 1.0, 3) * 1e-3
        c1 = rng.choice([-1, 1], 3) * rng.uniform(0.01, 0.03, 3)                  # dps/K
        acc += dTK[:, None] * p1
        gyro += dTK[:, None] * c1
        label.update(expect={"thermal_bias"}, truth={"thermal_bias_g/degC": p1.tolist(),
                                                     "gyro_thermal_bias_dps/degC": c1.tolist()})
    mag = None
    if kind in ("mag_null", "mag_thermal"):
        h_world = np.array([0.21, 0.0, -0.43])                 # gauss, dip ~64 deg
        W = np.eye(3) + (lambda E: (E + E.T) / 2)(rng.normal(0, 0.02, (3, 3)))
        W = W @ np.diag(1 + rng.normal(0, 0.03, 3))
        hard = rng.normal(0, 0.15, 3) + np.zeros((n, 3))
        label.update(sensor="mag")
        if kind == "mag_thermal":
            # hard iron that moves with the absolute temperature (a board's own magnetised
            # parts and traces), 0.3-0.8 mG/K per axis
            m1 = rng.choice([-1, 1], 3) * rng.uniform(0.3e-3, 0.8e-3, 3)
            hard = hard + dTK[:, None] * m1
            label.update(expect={"thermal_bias", "bias_drift"} if tk == "warmup" else {"thermal_bias"},
                         truth={"mag_thermal_bias_gauss/degC": m1.tolist()})
        mag = np.einsum("nji,j->ni", R, h_world) @ W.T + hard + rng.normal(0, 2e-3, (n, 3))
        mag = np.round(mag * 1090) / 1090
    acc = np.round(acc * 16384) / 16384
    gyro = np.round(gyro * 131) / 131
    temp_c = np.round((TK - 273.15) * 340) / 340
    meta = {"board": "blind-9dof" if mag is not None else "blind-6dof", "rate_hz": f"{rate_hz:g}",
            "accel_range_g": "2"}
    return Recording(t=t, acc=acc, gyro=gyro, mag=mag, temp=temp_c, meta=meta), label


CLASSES = ["null", "null_flicker", "thermal_bias", "thermal_scale", "quadratic", "random_walk", "cubic",
           "triple_product", "hysteresis", "tremor_null", "short_holds_null", "mag_null",
           "single_warmup_null", "single_warmup_thermal", "mag_thermal"]


def hit(verdict: str, expect) -> bool:
    """A verdict hits when its effect set lies within the expected class (names joined by +)."""
    if verdict in expect:
        return True
    parts = set(str(verdict).split("+"))
    return bool(parts) and parts <= set(expect) - {"none", "unexplained"}
