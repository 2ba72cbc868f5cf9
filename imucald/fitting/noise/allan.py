"""Noise figures of a still recording: overlapping Allan deviation with confidence
intervals, and the three classic terms fitted over a stated tau range.

The Allan deviation itself is :func:`imucald.fitting.noise.colour.allan_deviation` (one
implementation, also used by the pose-noise model and the gap diagnosis), here with
the overlapping estimator on a log-spaced grid of cluster sizes.

Model (IEEE Std 952-1997 annex C), per axis, in the sensor's unit u (g, deg/s):

    AVAR(tau) = N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3

* N, white noise density (u/sqrt(Hz)); angle/velocity random walk ARW = 60 N
  (deg/sqrt(h) for a gyro, (m/s)/sqrt(h) for an accelerometer in m/s^2).
* B, bias instability (u): the flicker floor of the deviation is 0.664 B.
* K, rate random walk (u/s/sqrt(Hz) = u/sqrt(s)).

Fit: non-negative weighted least squares of AVAR on the grid points inside
[tau_min, tau_max] (default 10 samples .. a tenth of the stretch: the shortest
averages are shaped by the chip's low-pass filter, the longest rest on few
clusters), weights sqrt(edf / 2) / AVAR_model (the variance of an AVAR estimate
is 2 AVAR^2 / edf), re-weighted three times.

Confidence intervals: each AVAR point has a chi-square interval with the
equivalent degrees of freedom of the overlapping estimator for the noise type
that dominates the model there (Howe, Allan & Barnes 1981, "Properties of signal
sources and measurement methods", as tabulated in NIST SP 1065 (Riley 2008)
section 5.3: white FM, flicker FM, random-walk FM), the chi-square quantile by
inverting the regularised incomplete gamma function.  A term's interval is read where it carries
the largest share of the model (its reading tau): the term moves by what the
AVAR's interval allows there, the other terms held.  A term the fit set to zero
gets [0, upper bound].  The grid points are correlated, so the least-squares
covariance would understate the spread; the reading-tau interval does not.
"""
from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence

import numpy as np

from .colour import MIN_STRETCH_S, allan_deviation, fit_avar_terms
from ...numerics.tails import chi2_logsf

__all__ = ["FLICKER_FACTOR", "edf_overlapping", "chi2_ppf", "tau_grid", "characterise",
           "kalibr_imu", "kalibr_text", "ros_imu_covariances", "KALIBR_UNITS", "TO_SI",
           "TERM_NAMES"]

#: ADEV flicker floor / B = sqrt(2 ln 2 / pi) (IEEE Std 952-1997, C.1.3)
FLICKER_FACTOR = math.sqrt(2 * math.log(2) / math.pi)
TERM_NAMES = ("white", "bias_instability", "rate_random_walk")
#: the frequency-noise exponent alpha of each term (white FM 0, flicker FM -1, RW FM -2)
_ALPHA = (0, -1, -2)


def edf_overlapping(n: int, m: int, alpha: int) -> float:
    """Equivalent degrees of freedom of the overlapping Allan variance of n rate samples at
    cluster size m for noise exponent alpha (0 white, -1 flicker, -2 random walk FM);
    N = n + 1 phase points (Howe, Allan & Barnes 1981; NIST SP 1065 section 5.3)."""
    N, m = float(n + 1), float(m)
    if alpha == 0:
        e = (3 * (N - 1) / (2 * m) - 2 * (N - 2) / N) * 4 * m * m / (4 * m * m + 5)
    elif alpha == -1:
        e = 2 * (N - 2) / (2.3 * N - 4.9) if m == 1 else 5 * N * N / (4 * m * (N + 3 * m))
    elif alpha == -2:
        e = (N - 2) / (m * (N - 3) ** 2) * ((N - 1) ** 2 - 3 * m * (N - 1) + 4 * m * m)
    else:
        raise ValueError(f"alpha {alpha}: allowed 0, -1, -2")
    return max(float(e), 1.0)


def _chi2_cdf(x: float, nu: float) -> float:
    """P(chi2_nu <= x): one minus numerics.tails' survival function (its regularised incomplete
    gamma, A&S 6.5.29/6.5.31), taken through log Q so a CDF near 0 keeps its digits."""
    return -math.expm1(chi2_logsf(x, nu))


def chi2_ppf(p: float, nu: float) -> float:
    """Quantile of the chi-square distribution with nu degrees of freedom: the CDF
    P(nu/2, x/2) inverted by bisection; above 1000 degrees of freedom the Wilson-Hilferty
    approximation (relative error below 1e-5 there)."""
    if nu > 1000:
        from statistics import NormalDist
        h = 2.0 / (9.0 * nu)
        return nu * (1.0 - h + NormalDist().inv_cdf(p) * math.sqrt(h)) ** 3
    lo, hi = 0.0, max(10.0, 2 * nu)
    while _chi2_cdf(hi, nu) < p:
        hi *= 2
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if _chi2_cdf(mid, nu) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-10 * hi:
            break
    return 0.5 * (lo + hi)


def tau_grid(n: int, rate_hz: float, per_decade: int = 8) -> np.ndarray:
    """Averaging times (s): distinct cluster sizes log-spaced from 1 to n // 4 samples."""
    top = max(n // 4, 1)
    m = np.unique(np.round(np.geomspace(1, top, max(2, int(per_decade * math.log10(top)) + 1))))
    return m.astype(float) / rate_hz


def _model(coef: np.ndarray, taus: np.ndarray) -> np.ndarray:
    return np.column_stack([coef[0] / taus, np.full_like(taus, coef[1]), coef[2] * taus])


def _interval(avar: np.ndarray, edf: np.ndarray, conf: float):
    q = (1 - conf) / 2
    lo = np.array([a * e / chi2_ppf(1 - q, e) for a, e in zip(avar, edf)])
    hi = np.array([a * e / chi2_ppf(q, e) for a, e in zip(avar, edf)])
    return lo, hi


def characterise(x: np.ndarray, rate_hz: float, axes: Sequence[str], conf: float = 0.95,
                 tau_min_s: Optional[float] = None, tau_max_s: Optional[float] = None
                 ) -> List[Dict[str, object]]:
    """Noise figures of a still signal x (n, d) sampled at rate_hz, one dict per axis in
    x's unit u: the Allan deviation (``taus_s``, ``adev``, ``adev_low``, ``adev_high``),
    the fitted ``avar_coef`` [N^2, 2 ln2/pi B^2, K^2/3], the figures ``white_density``
    (u/sqrt(Hz)), ``bias_instability`` (u), ``rate_random_walk`` (u/sqrt(s)) each with
    ``*_ci`` [low, high] and ``*_tau_s`` (its reading tau), and ``fit_tau_s`` [from, to]."""
    x = np.asarray(x, float).reshape(len(x), -1)
    n = len(x)
    dur = n / rate_hz
    taus = tau_grid(n, rate_hz)
    m = np.round(taus * rate_hz).astype(int)
    adev = allan_deviation(x, rate_hz, taus, overlapping=True)
    t0 = 10.0 / rate_hz if tau_min_s is None else float(tau_min_s)
    t1 = dur / 10.0 if tau_max_s is None else float(tau_max_s)
    use = (taus >= t0 * (1 - 1e-9)) & (taus <= t1 * (1 + 1e-9))
    if use.sum() < 4 or dur < MIN_STRETCH_S:
        from ...errors import UserError
        raise UserError(f"{dur:.0f} s of samples give {int(use.sum())} averaging times between "
                        f"{t0:g} and {t1:g} s: record a longer still stretch (at least 100 s; "
                        f"bias instability needs tens of minutes)")
    out = []
    idx = np.flatnonzero(use)
    for d, name in enumerate(axes):
        y = adev[:, d] ** 2
        subsets = ((0, 1, 2), (0, 1), (0, 2), (0,))
        for _ in range(3):
            coef = _fit(y, use, n, m, taus, subsets)
            read = _readings(coef, y, n, m, taus, idx, conf)
            # a term whose interval reaches zero is not resolved: refit without it, so that
            # it does not take from the others (flicker and random walk are confusable)
            weak = {j for j in (1, 2) if coef[j] > 0 and read[j][1] <= 0}
            if not weak:
                break
            subsets = tuple(c for c in subsets if not weak & set(c))
        mod = _model(coef, taus)
        lo, hi = _interval(y, _edf(n, m, mod), conf)
        r: Dict[str, object] = {
            "axis": name, "taus_s": taus.tolist(), "adev": adev[:, d].tolist(),
            "adev_low": np.sqrt(lo).tolist(), "adev_high": np.sqrt(hi).tolist(),
            "avar_coef": coef.tolist(), "fit_tau_s": [float(taus[use][0]), float(taus[use][-1])],
            "confidence": conf}
        to_fig = (math.sqrt, lambda v: math.sqrt(v) / FLICKER_FACTOR, lambda v: math.sqrt(3 * v))
        for j, key in enumerate(("white_density", "bias_instability", "rate_random_walk")):
            c, c_lo, c_hi, k = read[j]
            r[key] = to_fig[j](c)
            r[key + "_ci"] = [to_fig[j](c_lo), to_fig[j](c_hi)]
            r[key + "_tau_s"] = float(taus[k])
            r[key + "_resolved"] = bool(c > 0)
        out.append(r)
    return out


def _fit(y, use, n, m, taus, subsets) -> np.ndarray:
    """Weighted non-negative fit, re-weighted three times by the model's own variance."""
    coef, _ = fit_avar_terms(taus[use], y[use], 1.0 / y[use], subsets)
    for _ in range(3):
        mod = _model(coef, taus)
        w = np.sqrt(_edf(n, m, mod) / 2) / np.maximum(mod.sum(1), 1e-300)
        coef, _ = fit_avar_terms(taus[use], y[use], w[use], subsets)
    return coef


def _readings(coef, y, n, m, taus, idx, conf):
    """Per term (coefficient, low, high, grid index of its reading tau): the observed AVAR
    there less the other fitted terms, and the same for the AVAR's interval."""
    mod = _model(coef, taus)
    tot = mod.sum(1)
    lo, hi = _interval(y, _edf(n, m, mod), conf)
    out = []
    for j in range(3):
        scale = (1.0 / taus, np.ones_like(taus), taus)[j]       # term = coef * scale
        if coef[j] > 0:
            k = idx[int(np.argmax(mod[idx, j] / tot[idx]))]
        else:    # not resolved: an upper bound where such a term would show most
            k = idx[int(np.argmax(scale[idx] / tot[idx]))]
        rest = tot[k] - mod[k, j]
        c = max(0.0, (y[k] - rest) / scale[k]) if coef[j] > 0 else 0.0
        out.append((c, max(0.0, (lo[k] - rest) / scale[k]), max(0.0, (hi[k] - rest) / scale[k]), k))
    return out


def _edf(n: int, m: np.ndarray, mod: np.ndarray) -> np.ndarray:
    """Per-point edf for the noise type that dominates the model at each tau."""
    dom = np.argmax(mod, axis=1)
    return np.array([edf_overlapping(n, int(mm), _ALPHA[int(k)]) if n > 2 * mm else 1.0
                     for mm, k in zip(m, dom)])


# --- exports ------------------------------------------------------------------------------

G_MS2 = 9.80665                   #: standard gravity, m/s^2 per g
RAD_PER_DEG = math.pi / 180.0
#: a sensor's native unit -> SI (kalibr and ROS use m/s^2 and rad/s)
TO_SI = {"accel": G_MS2, "gyro": RAD_PER_DEG}


def kalibr_imu(figs: Dict[str, List[Dict[str, object]]], rate_hz: float,
               rostopic: str = "/imu0") -> Dict[str, object]:
    """kalibr's imu.yaml (continuous-time noise model, SI units): the largest axis of each
    figure; a random walk the recording could not resolve is written as its upper
    confidence bound (kalibr needs a positive value; the recording was too short to see
    it).  Keys: accelerometer_noise_density (m/s^2/sqrt(Hz)), accelerometer_random_walk
    (m/s^3/sqrt(Hz)), gyroscope_noise_density (rad/s/sqrt(Hz)), gyroscope_random_walk
    (rad/s^2/sqrt(Hz)), update_rate (Hz), rostopic."""
    out: Dict[str, object] = {}
    for sensor, pre in (("accel", "accelerometer"), ("gyro", "gyroscope")):
        axes = figs.get(sensor)
        if not axes:
            continue
        k = TO_SI[sensor]
        out[f"{pre}_noise_density"] = max(float(a["white_density"]) for a in axes) * k
        out[f"{pre}_random_walk"] = max(
            float(a["rate_random_walk"] if a["rate_random_walk_resolved"] else a["rate_random_walk_ci"][1])
            for a in axes) * k
    out["rostopic"] = rostopic
    out["update_rate"] = float(rate_hz)
    return out


KALIBR_UNITS = {"accelerometer_noise_density": "m/s^2/sqrt(Hz)", "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
                "gyroscope_noise_density": "rad/s/sqrt(Hz)", "gyroscope_random_walk": "rad/s^2/sqrt(Hz)",
                "update_rate": "Hz", "rostopic": "topic of sensor_msgs/Imu"}


def kalibr_text(d: Dict[str, object]) -> str:
    """The imu.yaml text with each key's unit as a comment."""
    lines = ["# kalibr IMU noise model (continuous time), from `imucald noise`",
             "# discrete per-sample sigma = density * sqrt(update_rate)"]
    for k, v in d.items():
        val = f"{v:.6g}" if isinstance(v, float) else str(v)
        lines.append(f"{k}: {val}  # {KALIBR_UNITS[k]}")
    return "\n".join(lines) + "\n"


def ros_imu_covariances(figs: Dict[str, List[Dict[str, object]]], rate_hz: float
                        ) -> Dict[str, List[float]]:
    """sensor_msgs/Imu covariances (row-major 3x3) of one sample: diag N^2 rate_hz per axis
    in (m/s^2)^2 and (rad/s)^2; orientation_covariance[0] = -1 (no orientation)."""
    out: Dict[str, List[float]] = {"orientation_covariance": [-1.0] + [0.0] * 8}
    for sensor, key in (("accel", "linear_acceleration_covariance"),
                        ("gyro", "angular_velocity_covariance")):
        axes = figs.get(sensor)
        if not axes:
            continue
        var = [(float(a["white_density"]) * TO_SI[sensor]) ** 2 * rate_hz for a in axes]
        out[key] = np.diag(var).ravel().tolist()
    return out


# --- the noise-figures file (``imucald noise -o``; the daemon's ``noise.file``) ------------

FIGURES_FORMAT = "imucald-noise-1"
UNIT = {"accel": "g", "gyro": "dps", "mag": "gauss"}


def figures_document(figs: Dict[str, List[Dict[str, object]]], rate_hz: float, source: str,
                     duration_s: float) -> Dict[str, object]:
    """The YAML document ``imucald noise -o`` writes: per sensor and axis the figures with
    units in the key names (u = g, dps or gauss; rts = sqrt(s), rthz = sqrt(Hz)), the
    fitted AVAR coefficients, and the kalibr and ROS exports."""
    doc: Dict[str, object] = {"format": FIGURES_FORMAT, "source": source, "rate_hz": float(rate_hz),
                              "duration_s": round(float(duration_s), 2)}
    for s, axes in figs.items():
        u = UNIT[s]
        doc[s] = {
            "axes": [a["axis"] for a in axes], "confidence": axes[0]["confidence"],
            "fit_tau_s": axes[0]["fit_tau_s"],
            f"white_density_{u}_rthz": [float(a["white_density"]) for a in axes],
            f"white_density_{u}_rthz_ci": [list(map(float, a["white_density_ci"])) for a in axes],
            f"bias_instability_{u}": [float(a["bias_instability"]) for a in axes],
            f"bias_instability_{u}_ci": [list(map(float, a["bias_instability_ci"])) for a in axes],
            f"rate_random_walk_{u}_rts": [float(a["rate_random_walk"]) for a in axes],
            f"rate_random_walk_{u}_rts_ci": [list(map(float, a["rate_random_walk_ci"])) for a in axes],
            "avar_coef": [list(map(float, a["avar_coef"])) for a in axes]}
    doc["kalibr"] = kalibr_imu(figs, rate_hz)
    doc["ros_sensor_msgs_imu"] = ros_imu_covariances(figs, rate_hz)
    return doc


def read_figures(path: str) -> Dict[str, Dict[str, np.ndarray]]:
    """The white densities (per-sample variance = density^2 rate) and AVAR coefficients of
    a noise-figures file, by sensor: {"accel": {"white": (3,), "avar_coef": (3, 3)}, ...}.
    A bad file raises a one-line UserError naming the file and key."""
    from ...errors import UserError
    from ...files.yamlsafe import load_file
    doc = load_file(path, UserError, max_bytes=1 << 20, what="noise.file: ")
    if not isinstance(doc, dict) or doc.get("format") != FIGURES_FORMAT:
        raise UserError(f"{path}: format: not {FIGURES_FORMAT!r}; write it with `imucald noise REC -o FILE`")
    out: Dict[str, Dict[str, np.ndarray]] = {}
    for s, u in UNIT.items():
        if s not in doc:
            continue
        key = f"white_density_{u}_rthz"
        try:
            w = np.asarray(doc[s][key], float).reshape(3)
            c = np.asarray(doc[s]["avar_coef"], float).reshape(3, 3)
        except (KeyError, TypeError, ValueError):
            raise UserError(f"{path}: {s}.{key} / {s}.avar_coef: expected 3 numbers / 3 rows of 3; "
                            f"rewrite it with `imucald noise`") from None
        if not (np.all(np.isfinite(w)) and np.all(w > 0) and np.all(np.isfinite(c)) and np.all(c >= 0)):
            raise UserError(f"{path}: {s}: noise figures must be finite and positive")
        out[s] = {"white": w, "avar_coef": c}
    if not out:
        raise UserError(f"{path}: no accel or gyro section; rewrite it with `imucald noise`")
    return out
