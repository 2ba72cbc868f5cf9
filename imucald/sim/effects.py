"""Unmodelled effects the simulator can inject (``imucald simulate --effect``).

Each effect is a parametric perturbation of the raw measurement, applied before
noise and quantisation, with a default magnitude taken from datasheets
(../shared/reference/error-models.md section 2):

accel.thermal_bias   g/degC    MPU-6050 zero-g change: +-35 mg over 0..70 C ~ 0.5 mg/degC
accel.thermal_scale  1/degC    sensitivity change +-0.02 %/degC
accel.nonlinearity   g/g^2     0.5 % of full scale (+-2 g): 10 mg at 2 g ~ 2.5 mg/g^2
accel.bias_drift     g/s       1 mg over 10 minutes (the upper end of the MPU-6050 class's wander)
gyro.thermal_bias    dps/degC  0.03 dps/degC (ITG-class ZRO tempco)
gyro.g_sensitivity   dps/g     0.1 dps/g (MPU-6050 linear-acceleration sensitivity)
gyro.bias_drift      dps/s     0.02 dps over 10 minutes
mag.thermal_bias     gauss/degC 0.5 mG/degC of hard-iron change

Signs and axis weights are drawn per effect from the generator, so the same
name gives a different (but equally large) effect on each seed.
"""
from __future__ import annotations

from typing import Dict, Optional

import numpy as np

from ..fitting.models import effect_forms as ef
from ..specs import ACCEL, GYRO

__all__ = ["EFFECTS", "DEFAULT_MAGNITUDE", "make_effect", "parse_effect_name"]

_A, _G = ACCEL["mpu6050"], GYRO["mpu6050"]
#: default magnitude per effect: the datasheet figures of imucald.specs where a datasheet
#: gives one (the MPU-6050's accelerometer, the ITG-3200's ZRO tempco, the MPU-6050's
#: g-sensitivity), the error-model notes' magnitudes for the drifts and the hard iron
DEFAULT_MAGNITUDE = {
    "accel.thermal_bias": _A.bias_tempco_g_per_c[0],
    "accel.thermal_scale": _A.scale_tempco_per_c,
    "accel.nonlinearity": _A.nonlinearity_fs * _A.range_g / _A.range_g ** 2,
    "accel.bias_drift": 1e-3 / 600,
    "gyro.thermal_bias": GYRO["itg3200"].bias_tempco_dps_per_c,
    "gyro.g_sensitivity": _G.g_sensitivity_dps_per_g,
    "gyro.bias_drift": 0.02 / 600,
    "mag.thermal_bias": 0.5e-3,
}
EFFECTS = tuple(DEFAULT_MAGNITUDE)
_SENSOR_OF = {"g_sensitivity": "gyro"}


def parse_effect_name(name: str) -> str:
    """'thermal_bias' -> 'accel.thermal_bias'; 'gyro.bias_drift' stays."""
    if "." not in name:
        name = f"{_SENSOR_OF.get(name, 'accel')}.{name}"
    if name not in DEFAULT_MAGNITUDE:
        raise ValueError(f"unknown effect {name!r}: allowed {', '.join(EFFECTS)}")
    return name


def _signs(rng, scale=1.0):
    """A random direction with every axis carrying a good share of the magnitude."""
    return scale * rng.choice([-1.0, 1.0], 3) * rng.uniform(0.6, 1.0, 3)


def make_effect(name: str, magnitude: Optional[float], rng) -> Dict[str, object]:
    """Returns {"name", "magnitude", "params", "apply"(sensor, raw, ctx)}."""
    name = parse_effect_name(name)
    mag = DEFAULT_MAGNITUDE[name] if magnitude is None else float(magnitude)
    sensor, kind = name.split(".")
    p: Dict[str, object] = {}
    if kind in ("thermal_bias", "bias_drift", "thermal_scale", "nonlinearity"):
        p["coef"] = _signs(rng, mag)
    elif kind == "g_sensitivity":
        G = rng.normal(scale=mag / np.sqrt(3), size=(3, 3))
        p["G"] = G * (mag / max(np.abs(G).max(), 1e-12))

    def apply(s: str, raw: np.ndarray, ctx: Dict[str, np.ndarray]) -> None:
        if s != sensor:
            return
        dT = ctx["temp"] - ctx["temp"][0]
        dt = ctx["t"] - ctx["t"][0]
        if kind == "thermal_bias":
            raw += ef.thermal_bias(p["coef"], dT)
        elif kind == "bias_drift":
            raw += ef.bias_drift(p["coef"], dt)
        elif kind == "thermal_scale":
            raw += ef.thermal_scale(p["coef"], ctx["f"], dT)   # scale (1 + d dT) on the true input
        elif kind == "nonlinearity":
            raw += ef.nonlinearity(p["coef"], ctx["f"])
        elif kind == "g_sensitivity":
            raw += ef.g_sensitivity(p["G"], ctx["f"])

    return {"name": name, "magnitude": mag, "params": {k: np.asarray(v).tolist() for k, v in p.items()},
            "apply": apply}


def effect_session(board: str, rotations, rng, effects, rate_hz: float = 100.0,
                   hold_s=(8.0, 12.0), move_s=(2.1, 3.9), temp_kind: str = "warmup",
                   temp_rise_c: float = 6.0, tremor_dps: float = 0.0, sway_deg: float = 0.0):
    """A simulated session with the deployed model's truth (the magnetometer with ordinary
    hard and soft iron, as drawn for every board) plus the given effects
    [(name, magnitude or None), ...].

    Returns (session, [effect dicts without the apply function])."""
    from .sensor import draw_truth, simulate_session
    truth = draw_truth(board, rng)
    made = [make_effect(n, m, rng) for n, m in effects]
    s = simulate_session(board, rotations, rng, rate_hz=rate_hz, hold_s=hold_s, move_s=move_s,
                         truth=truth, temp_kind=temp_kind, temp_rise_c=temp_rise_c,
                         effects=[e["apply"] for e in made], tremor_dps=tremor_dps, sway_deg=sway_deg)
    if made:
        s.recording.meta["effects"] = ",".join(e["name"] for e in made)
    return s, [{k: v for k, v in e.items() if k != "apply"} for e in made]
