"""The calibration value: one type for the daemon, the worker, ``calibrate``, ``replay``
and the state file.

A :class:`Calibration` holds the board/chip identity, the temperature range it was
made over and up to three :class:`SensorCal` parts (accelerometer, gyro,
magnetometer).  Each part is a model name, its parameters under unit-carrying
names, their standard errors, optional per-parameter flags (``determined``,
``undetermined``, ``at_bound``) and quality figures (held-out RMS, poses...).
Every part is an affine correction in the sensor frame, ``corrected = A raw + c``:

- accel (``g``): a norm model of :mod:`imucald.fitting.models.registry` (``triangular9``,
  ``full12``, ``cosine*``), parameters as that model reports them;
- gyro (``deg/s``): ``bias``: ``bias_dps`` (3), optionally ``matrix`` (9, row-major
  scale/misalignment M: corrected = M (raw - bias(T) - G a), fitting/gyro/rotations.py fits it from
  the rotations between poses; each entry of M - I within +-0.5), ``g_sens_dps_per_g``
  (9, row-major G, deg/s per g of calibrated specific force a; within +-10); its thermal
  terms are a ``thermal`` block like every part's (below).  The older form, params
  ``bias_temp_poly_dps`` (K rows of 3, coefficient of (T - temp_ref_c)^k, k = 1..K) with
  ``temp_ref_c``, is still read: it becomes a ``thermal`` block when the part is made
  (:func:`_legacy_gyro_thermal`), with the same corrections, and is saved in that form;
- mag (``gauss``): ``mag_sym``/``mag_diag``/``mag_sphere``: ``hard_iron_gauss`` (3),
  ``soft_iron`` (upper triangle xx yy zz xy xz yz of W, det 1) and ``field_gauss``;
  corrected = W (raw - hard_iron), so a clean field has norm ``field_gauss``.

Any part may carry a ``thermal`` block (fitting/thermal/terms.py fits it): a bias polynomial
``bias_poly_<unit>`` (rows k = 1..order of the coefficients of (T - t_ref_c)^k), for the
accelerometer optionally ``scale_poly`` (1/degC, on the raw reading minus its bias), the
range ``t_min_c``..``t_max_c`` it was fitted on and a ``note`` (what was chosen and why).
The raw reading is corrected first, raw' = raw - b(T) - (raw - b0) s(T), with T clamped
to the fitted range (held at the edge value outside it; unknown T: t_ref_c), and then
by the part's own model; the part's parameters are those at t_ref_c.

:meth:`Calibration.from_dict` checks every field (type, shape, finiteness, model
name, units) and raises a one-line :class:`CalibrationError` naming the key path
and the fix.  :func:`load` / :func:`save` read and write the YAML atomically.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Dict, Mapping, Optional, Tuple

import numpy as np

from .files.calibration_checks import (
    FLAGS, PARAM_LIMIT, THERMAL_UNIT, CalibrationError, check_array, fail_check, check_flags, check_keys,
    check_provisional, check_table, check_thermal
)

__all__ = ["Calibration", "SensorCal", "CalibrationError", "FORMAT_VERSION", "MAX_ID", "next_id", "UNITS",
           "FLAGS", "load", "save", "apply"]

FORMAT_VERSION = 2
#: the largest calibration id: the binary stream holds it in 4 bytes (daemon/outputs.py)
MAX_ID = 2 ** 32 - 1
UNITS = {"accel": "g", "gyro": "deg/s", "mag": "gauss", "temperature": "degC", "time": "s"}
SENSORS = ("accel", "gyro", "mag")
_MAG_PARAMS = {"hard_iron_gauss": 3, "soft_iron": 6, "field_gauss": 0}
_GYRO_REQUIRED = {"bias_dps": 3}
#: -3: (K, 3); bias_temp_poly_dps and temp_ref_c: the older thermal form, read and migrated
_GYRO_OPTIONAL = {"matrix": 9, "g_sens_dps_per_g": 9, "bias_temp_poly_dps": -3, "temp_ref_c": 0}
_LEGACY_GYRO_THERMAL = ("bias_temp_poly_dps", "temp_ref_c")
#: the temperature range of a migrated gyro thermal block: the older form recorded none and
#: never clamped, so the block spans every temperature a file may hold (PARAM_LIMIT) and its
#: corrections are the older form's at every temperature
LEGACY_GYRO_RANGE_C = (-PARAM_LIMIT, PARAM_LIMIT)
#: the ``note`` of a migrated block (imucald status and calibrate show it)
LEGACY_GYRO_NOTE = "migrated from params.bias_temp_poly_dps (no fitted range recorded: not clamped)"
#: plausible bounds: |M - I| (a gyro scale/misalignment matrix), |G| deg/s per g
_GYRO_BOUNDS = {"matrix": (0.5, "scale and misalignment within 50 %"), "g_sens_dps_per_g": (10.0, "|G| <= 10 deg/s per g")}
#: plausible bounds of an accelerometer part's correction (corrected = A raw + c): |A - I| and
#: |c| in g.  Datasheets give scale and cross-axis within a few % and zero-g within 0.08-0.25 g
#: (specs.ACCEL); the fit searches 3x that (fitting/fit.accel_bounds: at its corners |A - I|
#: reaches 0.30 and |c| 1.07 g for the ADXL345, tests/test_calibration.py checks every chip and
#: model inside these), so whatever the daemon or calibrate writes loads again, while a scale
#: of -1 or 5, or an offset of 3 g, is a sign, unit or typing error
_ACCEL_BOUNDS = (0.5, 1.5)
_SYM = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
#: largest condition number of a part's correction matrix A: a sensor's scale and
#: misalignment errors are percents (A near I, condition ~1.1); a singular A maps a whole
#: axis onto zero (and made applying the thermal terms raise)
MAX_CONDITION = 1e3


def next_id(current: int) -> int:
    """The id after ``current``: one more, back to 1 after MAX_ID (a daemon that has applied
    four billion calibrations numbers on rather than stopping)."""
    return current + 1 if current < MAX_ID else 1


def param_shapes(sensor: str, model: str) -> Tuple[Dict[str, int], Dict[str, int]]:
    """(required, optional) parameter names -> length (0 scalar, -3 rows of 3) of a model."""
    if sensor == "accel":
        from .fitting.models.registry import MODEL_NAMES, get_model
        if model not in MODEL_NAMES or model.startswith("mag_"):
            raise ValueError("allowed: " + ", ".join(m for m in MODEL_NAMES if not m.startswith("mag_")))
        return {g: len(i) for g, i in get_model(model).groups.items()}, {}
    if sensor == "gyro":
        if model != "bias":
            raise ValueError("allowed: bias")
        return dict(_GYRO_REQUIRED), dict(_GYRO_OPTIONAL)
    if model not in ("mag_sym", "mag_diag", "mag_sphere"):
        raise ValueError("allowed: mag_sym, mag_diag, mag_sphere")
    return dict(_MAG_PARAMS), {}


@dataclass(frozen=True, eq=False)
class SensorCal:
    """One sensor's correction.  params/stderr: name -> float array (stderr NaN = unknown)."""

    sensor: str
    model: str
    params: Mapping[str, np.ndarray]
    stderr: Mapping[str, np.ndarray] = field(default_factory=dict)
    flags: Mapping[str, Tuple[str, ...]] = field(default_factory=dict)
    method: str = ""
    quality: Mapping[str, float] = field(default_factory=dict)
    #: None, or the temperature terms: order, t_ref_c, t_min_c, t_max_c, bias_poly_<unit>
    #: ((order, 3) array), bias_poly_stderr_<unit>, scale_poly (accel, (1, 3)), note
    thermal: Optional[Mapping[str, Any]] = None

    def __post_init__(self):
        if self.sensor == "gyro" and any(k in self.params for k in _LEGACY_GYRO_THERMAL):
            params, stderr, flags, thermal = _legacy_gyro_thermal(self.params, self.stderr, self.flags,
                                                                  self.thermal, self.sensor)
            for k, v in (("params", params), ("stderr", stderr), ("flags", flags), ("thermal", thermal)):
                object.__setattr__(self, k, v)

    # -- construction ----------------------------------------------------------------
    @classmethod
    def accel(cls, model: str, theta, stderr_flat=None, method: str = "", quality=None,
              flags=None) -> "SensorCal":
        """From a norm model's flat parameter vector (and flat standard errors)."""
        from .fitting.models.registry import get_model
        m = get_model(model)
        th = np.asarray(theta, float)
        se = np.full(m.k, np.nan) if stderr_flat is None else np.asarray(stderr_flat, float)
        return cls("accel", model, {g: th[i].copy() for g, i in m.groups.items()},
                   {g: se[i].copy() for g, i in m.groups.items()}, dict(flags or {}), method,
                   dict(quality or {}))

    @classmethod
    def from_fit(cls, fit, quality=None) -> "SensorCal":
        """From a :class:`imucald.fitting.fit.FitResult` (its reported params and stderr)."""
        unit = {"accel": "g", "gyro": "dps", "mag": "gauss"}[fit.sensor]
        q = {"poses": int(fit.poses), f"rms_{unit}": float(fit.rms),
             f"loo_rms_{unit}": float(fit.heldout_rms), f"noise_{unit}": float(fit.noise)}
        q = {k: v for k, v in q.items() if math.isfinite(v)}
        arr = lambda v: np.array(np.nan if v is None else v, float) if not isinstance(v, list) \
            else np.array([np.nan if x is None else x for x in v], float)
        return cls(fit.sensor, fit.model, {k: arr(v) for k, v in fit.params.items()},
                   {k: arr(v) for k, v in fit.stderr.items()}, _fit_flags(fit),
                   fit.method, {**q, **(quality or {})})

    @property
    def theta(self) -> np.ndarray:
        """accel: the model's flat parameter vector."""
        from .fitting.models.registry import get_model
        m = get_model(self.model)
        th = m.nominal.copy()
        for g, i in m.groups.items():
            th[i] = self.params[g]
        return th

    # -- correction ------------------------------------------------------------------
    @cached_property
    def affine(self) -> Tuple[np.ndarray, np.ndarray]:
        """(A, c): corrected = raw @ A.T + c (thermal gyro terms excluded)."""
        p = self.params
        if self.sensor == "accel":
            from .fitting.models.registry import get_model
            A, c = get_model(self.model).affine(self.theta)
            return np.asarray(A, float), np.asarray(c, float)
        if self.sensor == "gyro":
            M = p["matrix"].reshape(3, 3) if "matrix" in p else np.eye(3)
            return M, -M @ p["bias_dps"]
        W = np.zeros((3, 3))
        for k, (i, j) in enumerate(_SYM):
            W[i, j] = W[j, i] = p["soft_iron"][k]
        return W, -W @ p["hard_iron_gauss"]

    @cached_property
    def _thermal_terms(self):
        """(t_min, t_ref, t_max, bias rows (K, 3), scale rows (L, 3), b0 (3,), powers
        1..max(K, L)) or None: worked out once per calibration, not per batch."""
        th = self.thermal
        if not th:
            return None
        P = np.asarray(th.get(f"bias_poly_{THERMAL_UNIT[self.sensor]}", np.zeros((0, 3))), float)
        S = np.asarray(th.get("scale_poly", np.zeros((0, 3))), float)
        if not len(P) and not len(S):
            return None
        A, c = self.affine
        b0 = -np.linalg.solve(A, c) if len(S) else np.zeros(3)
        k = np.arange(1, max(len(P), len(S)) + 1)
        return float(th["t_min_c"]), float(th["t_ref_c"]), float(th["t_max_c"]), P, S, b0, k

    @cached_property
    def _g_sens(self):
        """G (3, 3) transposed, deg/s per g, or None: the g-sensitivity term's matrix."""
        G = self.params.get("g_sens_dps_per_g")
        return None if G is None else G.reshape(3, 3).T

    def g_offset(self, raw, acc_g):
        """raw minus the g-sensitivity term G a (deg/s; acc_g (N, 3): the calibrated specific
        force in g); raw when the part has no such term."""
        G = self._g_sens
        return raw if G is None else raw - np.asarray(acc_g, float) @ G

    def thermal_offset(self, raw, temp_c):
        """raw minus the thermal terms at temp_c (degC: a scalar, e.g. a batch's mean, or
        (N,)); clamped to the fitted range, unknown (NaN/None) = t_ref_c."""
        tt = self._thermal_terms
        if tt is None or temp_c is None:
            return raw
        lo, ref, hi, P, S, b0, k = tt
        if np.ndim(temp_c) == 0:            # a batch's temperature: scalar arithmetic
            T = float(temp_c)
            dT = np.float64(min(max(T, lo), hi) - ref if math.isfinite(T) else 0.0)
        else:
            T = np.asarray(temp_c, float)
            dT = np.where(np.isfinite(T), np.clip(T, lo, hi) - ref, 0.0)
        pw = dT[..., None] ** k                              # (K,) or (N, K)
        out = raw - pw[..., :len(P)] @ P if len(P) else raw
        if len(S):
            out = out - (raw - b0) * (pw[..., :len(S)] @ S)
        return out

    def apply(self, raw, temp_c=None, acc_g=None) -> np.ndarray:
        """Correct raw readings (N, 3) in this sensor's unit; temp_c (N,) or a scalar degC
        (a batch's temperature) feeds the thermal terms (unknown = NaN: those at t_ref_c);
        acc_g (N, 3) calibrated specific force feeds the gyro's g-sensitivity term (required
        when the part has one: leaving G a out would be a silent error of up to |G| deg/s)."""
        x = np.asarray(raw, float)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"{self.sensor}: raw readings must have shape (N, 3), got {x.shape}")
        if acc_g is None and "g_sens_dps_per_g" in self.params:
            raise ValueError("gyro: this calibration has a g-sensitivity term (g_sens_dps_per_g): "
                             "give acc_g, the calibrated accelerometer readings (N, 3) in g")
        A, c = self.affine
        if self.thermal is not None:
            x = self.thermal_offset(x, temp_c)
        if acc_g is not None:
            x = self.g_offset(x, acc_g)
        return x @ A.T + c

    # -- serialisation ---------------------------------------------------------------
    def to_dict(self) -> Dict[str, Any]:
        d: Dict[str, Any] = {"model": self.model}
        if self.method:
            d["method"] = self.method
        d["params"] = {k: _out(v) for k, v in self.params.items()}
        if self.stderr:
            d["stderr"] = {k: _out(v) for k, v in self.stderr.items()}
        if self.flags:
            d["flags"] = {k: list(v) for k, v in self.flags.items()}
        if self.quality:
            d["quality"] = {k: (int(v) if isinstance(v, (int, np.integer)) else float(v))
                            for k, v in self.quality.items()}
        if self.thermal is not None:
            d["thermal"] = {k: (v if isinstance(v, str) else int(v) if k == "order"
                                else _out(v)) for k, v in self.thermal.items()}
        return d

    @classmethod
    def from_dict(cls, sensor: str, d: Any, path: str = "") -> "SensorCal":
        path = path or sensor
        if not isinstance(d, Mapping):
            fail_check(path, f"expected a mapping, got {type(d).__name__}", "see docs/reference/calibration-file.md")
        check_keys(d, path, {"model", "params"}, {"method", "stderr", "flags", "quality", "thermal"})
        model = d["model"]
        try:
            req, opt = param_shapes(sensor, model if isinstance(model, str) else "")
        except ValueError as e:
            fail_check(f"{path}.model", f"{model!r} is not a {sensor} model", str(e))
        method = d.get("method", "")
        if not isinstance(method, str):
            fail_check(f"{path}.method", f"expected text, got {type(method).__name__}", "e.g. method: ga")
        pd = d["params"]
        if not isinstance(pd, Mapping):
            fail_check(f"{path}.params", f"expected a mapping, got {type(pd).__name__}",
                  "give " + ", ".join(req))
        check_keys(pd, f"{path}.params", set(req), set(opt))
        params = {k: check_array(pd[k], f"{path}.params.{k}", {**req, **opt}[k], limit=PARAM_LIMIT) for k in pd}
        for k, (lim, what) in (_GYRO_BOUNDS.items() if sensor == "gyro" else ()):
            if k in params and np.max(np.abs(params[k] - (np.eye(3).ravel() if k == "matrix" else 0))) > lim:
                fail_check(f"{path}.params.{k}", f"{params[k].tolist()} is not plausible ({what})",
                      "check the row-major order and units, or remove it")
        sd = d.get("stderr", {})
        if not isinstance(sd, Mapping):
            fail_check(f"{path}.stderr", f"expected a mapping, got {type(sd).__name__}", "or leave it out")
        check_keys(sd, f"{path}.stderr", set(), set(params))
        stderr = {k: check_array(sd[k], f"{path}.stderr.{k}", params[k].shape, nullable=True,
                            nonneg=True) for k in sd}
        fl = d.get("flags", {})
        if not isinstance(fl, Mapping):
            fail_check(f"{path}.flags", f"expected a mapping, got {type(fl).__name__}", "or leave it out")
        check_keys(fl, f"{path}.flags", set(), set(params))
        flags = {k: check_flags(fl[k], f"{path}.flags.{k}", params[k].size) for k in fl}
        q = d.get("quality", {})
        if not isinstance(q, Mapping):
            fail_check(f"{path}.quality", f"expected a mapping, got {type(q).__name__}", "or leave it out")
        quality = {}
        for k, v in q.items():
            if not isinstance(k, str) or isinstance(v, bool) or not isinstance(v, (int, float)) \
                    or not math.isfinite(v):
                fail_check(f"{path}.quality.{k}", f"{v!r} is not a finite number", "fix or remove it")
            quality[k] = v
        thermal = None if d.get("thermal") is None else check_thermal(d["thermal"], f"{path}.thermal", sensor)
        part = cls(sensor, model, params, stderr, flags, method, quality, thermal)    # migrates an older form
        A = part.affine[0]
        cond = np.linalg.cond(A) if np.isfinite(A).all() else math.inf
        if not cond <= MAX_CONDITION:
            fail_check(f"{path}.params", f"the correction matrix is singular or nearly so (condition "
                  f"number {cond:.3g} > {MAX_CONDITION:g}): it would lose an axis",
                  "a scale of 0 or a degenerate soft iron is not a calibration: recalibrate")
        if sensor == "accel":
            dev, off = float(np.max(np.abs(A - np.eye(3)))), float(np.max(np.abs(part.affine[1])))
            lim, off_lim = _ACCEL_BOUNDS
            if not (dev <= lim and off <= off_lim):
                fail_check(f"{path}.params", f"not plausible: the correction changes a scale or an "
                      f"axis by {100 * dev:.3g} % and offsets by {off:.3g} g (at most "
                      f"{100 * lim:g} % and {off_lim:g} g)", "check the file (a sign, a unit) or recalibrate")
        return part


#: highest order of a thermal block (calibration_checks.check_thermal)
_MAX_THERMAL_ORDER = 3


def _legacy_gyro_thermal(params, stderr, flags, thermal, path: str):
    """A gyro part's older thermal form -- params ``bias_temp_poly_dps`` (K rows of 3, the
    coefficients of (T - temp_ref_c)^k, k = 1..K, deg/s) with ``temp_ref_c`` -- as a
    ``thermal`` block of order K about t_ref_c = temp_ref_c over LEGACY_GYRO_RANGE_C:
    (params, stderr, flags, thermal) without the older keys.  The correction is the same:
    raw - sum_k poly_k (T - temp_ref_c)^k, an unknown (NaN) temperature giving the bias at
    temp_ref_c.  One difference: without any temperature (temp_c None) the older form raised;
    a thermal block corrects as at t_ref_c."""
    if ("bias_temp_poly_dps" in params) != ("temp_ref_c" in params):
        fail_check(f"{path}.params.temp_ref_c", "bias_temp_poly_dps and temp_ref_c go together",
              "give both or neither")
    if thermal is not None:
        fail_check(f"{path}.thermal", "given together with params.bias_temp_poly_dps",
              "keep one of the two thermal terms (thermal: supersedes the older one)")
    poly = np.asarray(params["bias_temp_poly_dps"], float).reshape(-1, 3)
    if len(poly) > _MAX_THERMAL_ORDER:
        fail_check(f"{path}.params.bias_temp_poly_dps", f"{len(poly)} rows; a thermal bias polynomial "
              f"has at most {_MAX_THERMAL_ORDER}", "keep the first 3 rows, or refit the thermal terms")
    ref = float(params["temp_ref_c"])
    th: Dict[str, Any] = {"order": len(poly), "t_ref_c": ref, "t_min_c": min(LEGACY_GYRO_RANGE_C[0], ref),
                          "t_max_c": max(LEGACY_GYRO_RANGE_C[1], ref), "bias_poly_dps": poly}
    if "bias_temp_poly_dps" in stderr:
        th["bias_poly_stderr_dps"] = np.asarray(stderr["bias_temp_poly_dps"], float).reshape(-1, 3)
    th["note"] = LEGACY_GYRO_NOTE
    drop = lambda d: {k: v for k, v in d.items() if k not in _LEGACY_GYRO_THERMAL}
    return drop(params), drop(stderr), drop(flags), th


def _fit_flags(fit) -> Dict[str, Tuple[str, ...]]:
    """Per-parameter flags of an accelerometer fit (``determined`` unless the fit
    flagged it), grouped like its params; {} when the fit reports none."""
    u = fit.uncertainty
    if fit.sensor != "accel" or u is None or getattr(u, "posterior_std", None) is None:
        return {}                       # no determination reported (e.g. ga-paper)
    from .fitting.models.registry import get_model
    m = get_model(fit.model)
    why = {f["name"]: f["reason"] for f in u.flags}
    return {g: tuple(why.get(m.param_names[i], "determined") for i in idx) for g, idx in m.groups.items()}


@dataclass(frozen=True, eq=False)
class Calibration:
    """The calibration of one board.  id 0 with no parts = uncalibrated."""

    board: str = "unknown"
    chips: Mapping[str, str] = field(default_factory=dict)   #: accel/gyro/mag -> chip name
    id: int = 0
    created: str = ""                                         #: ISO 8601 UTC
    temperature_range_c: Optional[Tuple[float, float]] = None
    accel: Optional[SensorCal] = None
    gyro: Optional[SensorCal] = None
    mag: Optional[SensorCal] = None
    poses_used: Optional[Mapping[str, Any]] = None           #: {columns: [...], rows: [[...]]}
    #: None, or {poses, poses_for_final, missing_orientations}: applied before the pose set
    #: met the readiness targets (README: provisional calibrations)
    provisional: Optional[Mapping[str, Any]] = None
    sensor: str = ""       #: fingerprint id of the physical sensor (daemon/sensors.py); "" unknown

    def part(self, sensor: str) -> Optional[SensorCal]:
        return getattr(self, sensor)

    def replace(self, **kw) -> "Calibration":
        return replace(self, **kw)

    # -- correction (identity for a sensor without a part) ----------------------------
    def apply_accel(self, acc_g, temp_c=None):
        return np.asarray(acc_g, float) if self.accel is None else self.accel.apply(acc_g, temp_c)

    def apply_gyro(self, gyro_dps, temp_c=None, acc_g=None):
        """acc_g (N, 3): the calibrated specific force in g, required when the gyro part has
        a g-sensitivity term (g_sens_dps_per_g; ValueError without it)."""
        return np.asarray(gyro_dps, float) if self.gyro is None else self.gyro.apply(gyro_dps, temp_c, acc_g)

    def apply_mag(self, mag_gauss, temp_c=None):
        return np.asarray(mag_gauss, float) if self.mag is None else self.mag.apply(mag_gauss, temp_c)

    # -- identity ----------------------------------------------------------------------
    def mismatch(self, board: str, chips: Optional[Mapping[str, str]] = None,
                 sensor: str = "") -> Optional[str]:
        """Why this calibration does not belong to the running board (None: it does)."""
        if self.sensor and sensor and self.sensor != sensor:
            return f"made on sensor {self.sensor}, this is sensor {sensor}"
        if self.board == "unknown" and board != "unknown":
            return (f"its file names no board ('unknown': from a raw table read without --board); this "
                    f"is {board!r}: calibrate it again with --board {board}")
        if board == "unknown" and self.board != "unknown":
            return (f"made for board {self.board!r}, and this input names none (a raw table: give "
                    f"--board {self.board} if it was logged from one)")
        if self.board != board:
            return f"made for board {self.board!r}, this is {board!r}"
        for k, v in (chips or {}).items():
            if k in self.chips and self.chips[k] != v:
                return f"made for {k} chip {self.chips[k]!r}, this board has {v!r}"
        return None

    # -- serialisation -----------------------------------------------------------------
    def to_dict(self) -> Dict[str, Any]:
        d: Dict[str, Any] = {"format_version": FORMAT_VERSION, "id": int(self.id),
                             "created": self.created, "board": self.board, "chips": dict(self.chips),
                             "units": dict(UNITS)}
        if self.sensor:
            d["sensor"] = self.sensor
        if self.temperature_range_c is not None:
            d["temperature_range_c"] = [float(x) for x in self.temperature_range_c]
        for s in SENSORS:
            p = self.part(s)
            if p is not None:
                d[s] = p.to_dict()
        if self.poses_used is not None:
            d["poses_used"] = {"columns": list(self.poses_used["columns"]),
                               "rows": [[_num(x) for x in r] for r in self.poses_used["rows"]]}
        if self.provisional is not None:
            d["provisional"] = check_provisional(self.provisional, "provisional")
        return d

    @classmethod
    def from_dict(cls, d: Any) -> "Calibration":
        if not isinstance(d, Mapping):
            fail_check("(top level)", f"expected a mapping, got {type(d).__name__}",
                  "see docs/reference/calibration-file.md")
        if d.get("format_version") == 1:
            d = _from_v1(d)
        check_keys(d, "", {"format_version", "id", "board", "units"},
              {"created", "chips", "temperature_range_c", "poses_used", "provisional", "sensor", *SENSORS})
        if d["format_version"] != FORMAT_VERSION:
            fail_check("format_version", f"{d['format_version']!r} is not supported",
                  f"this imucald reads 1 and {FORMAT_VERSION}")
        if isinstance(d["id"], bool) or not isinstance(d["id"], int) or not 0 <= d["id"] <= MAX_ID:
            # the stream carries it in 4 bytes (daemon/outputs.py BINARY_DTYPE "cal" <u4): a
            # larger one passed here and crashed the daemon at its first binary record
            fail_check("id", f"{d['id']!r} is not an integer from 0 to {MAX_ID}", "e.g. id: 1")
        for k in ("board", "created", "sensor"):
            if not isinstance(d.get(k, ""), str):
                fail_check(k, f"expected text, got {type(d[k]).__name__}", "quote it")
        chips = d.get("chips", {})
        if not isinstance(chips, Mapping):
            fail_check("chips", "expected a mapping of sensor -> chip name", "e.g. {accel: mpu6050}")
        for k, v in chips.items():
            if k not in SENSORS or not isinstance(v, str):
                fail_check(f"chips.{k}", f"{v!r} is not a chip name of a sensor",
                      "keys accel, gyro, mag; values e.g. mpu6050")
        if d["units"] != UNITS:
            u = d["units"] if isinstance(d["units"], Mapping) else {}
            bad = next((k for k in UNITS if u.get(k) != UNITS[k]), "units")
            fail_check(f"units.{bad}" if bad != "units" else "units", f"{u.get(bad)!r} is not the stored unit",
                  "imucald stores " + ", ".join(f"{k}: {v}" for k, v in UNITS.items()))
        tr = d.get("temperature_range_c")
        if tr is not None:
            tr = check_array(tr, "temperature_range_c", 2)
            if tr[0] > tr[1]:
                fail_check("temperature_range_c", f"{tr.tolist()} is not [low, high]", "swap them")
            tr = (float(tr[0]), float(tr[1]))
        parts = {s: SensorCal.from_dict(s, d[s]) for s in SENSORS if d.get(s) is not None}
        pu = d.get("poses_used")
        if pu is not None:
            pu = check_table(pu, "poses_used")
        pv = d.get("provisional")
        return cls(d["board"], dict(chips), d["id"], d.get("created", ""), tr, parts.get("accel"),
                   parts.get("gyro"), parts.get("mag"), pu,
                   None if pv is None else check_provisional(pv, "provisional"), d.get("sensor", ""))


def build_calibration(parts: Mapping[str, Optional["SensorCal"]], board: Optional[str] = None,
                      chips: Optional[Mapping[str, str]] = None, meta: Optional[Mapping[str, Any]] = None,
                      id: int = 1, created: Optional[str] = None,
                      temperature_range_c: Optional[Tuple[float, float]] = None) -> Calibration:
    """The one builder of a :class:`Calibration` (the API, ``calibrate -o`` and the daemon's
    job all call it).  ``parts``: sensor -> SensorCal (None entries are left out).  Board
    and chips: given, else from a recording's ``meta`` (its board; its recorded chips, else
    the board's usual ones, specs.recording_chips), else "unknown" and {}.  ``created``:
    ISO 8601 UTC, now unless given ("" for a candidate not yet in force)."""
    if meta is not None:
        board = board or meta.get("board", "unknown")
        if chips is None:
            from .specs import recording_chips
            chips = recording_chips(meta)
    if created is None:
        from datetime import datetime, timezone
        created = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return Calibration(board or "unknown", dict(chips or {}), id=id, created=created,
                       temperature_range_c=temperature_range_c,
                       **{s: p for s, p in parts.items() if p is not None})


# --- files ----------------------------------------------------------------------------

def save(cal: Calibration, path) -> None:
    """Write ``cal`` as YAML, atomically (temp file, fsync, rename).  The text is PyYAML's
    ``safe_dump``; files/yamlout.py writes it without importing PyYAML (7-10 ms of a
    ``calibrate -o``) when the document is one it knows, byte for byte the same."""
    from .files.atomic import atomic_write_text
    from .files.yamlout import WIDTH, dump
    doc = cal.to_dict()
    body = dump(doc)
    if body is None:
        import yaml
        body = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=WIDTH)
    text = "# imucald calibration (see docs/reference/calibration-file.md)\n" + body
    atomic_write_text(os.fspath(path), text)


def load(path, data: Optional[bytes] = None) -> Calibration:
    """Read and validate a calibration file (or its bytes ``data``, already read); the
    hardened YAML loader (yamlsafe: size, depth, no aliases); CalibrationError names the
    file and key."""
    from .files.yamlsafe import load as load_yaml, load_file
    p = os.fspath(path)
    if data is None:
        doc = load_file(p, CalibrationError, max_bytes=MAX_CALIBRATION_BYTES)
    else:
        doc = load_yaml(data, p, CalibrationError, max_bytes=MAX_CALIBRATION_BYTES)
    try:
        return Calibration.from_dict(doc)
    except CalibrationError as e:
        raise CalibrationError(f"{p}: {e}") from None


#: the largest calibration file read: one with every sensor, thermal terms and quality
#: figures is ~5 KB
MAX_CALIBRATION_BYTES = 1 << 20


def apply(cal: Calibration, accel_g=None, gyro_dps=None, mag_gauss=None, temp_c=None
          ) -> Dict[str, np.ndarray]:
    """Correct whichever arrays are given ((N, 3) each); returns them by name."""
    out = {}
    if accel_g is not None:
        out["accel_g"] = cal.apply_accel(accel_g, temp_c)
    if gyro_dps is not None:
        out["gyro_dps"] = cal.apply_gyro(gyro_dps, temp_c, out.get("accel_g"))
    if mag_gauss is not None:
        out["mag_gauss"] = cal.apply_mag(mag_gauss, temp_c)
    return out


def _num(x):
    return None if x is None or not math.isfinite(x) else float(x)


def _out(v: np.ndarray):
    a = np.asarray(v, float)
    return _num(float(a)) if a.ndim == 0 else [(_out(x) if a.ndim > 1 else _num(float(x))) for x in a]


# --- format_version 1 (imucald 0.1 state files) -----------------------------------------

_V1_QUALITY = {"accel": ("fitness", "rms_g", "loo_rms_g", "heldout_rms_g", "heldout_rms_before_g",
                         "predicted_heldout_rms_g", "poses", "heldout_poses", "noise_g"),
               "gyro": ("heldout_rms_dps",), "mag": ("points", "heldout_rel_rms")}


def _from_v1(d: Mapping) -> Dict[str, Any]:
    """A v1 document in the v2 layout: quality figures move under ``quality``; the
    redundant ``theta`` and ``crlb_std``, the mag ``coverage`` report and the board
    and bus names under ``chips`` are dropped."""
    out = {k: v for k, v in d.items() if k not in (*SENSORS, "chips")}
    out["format_version"] = FORMAT_VERSION
    chips = d.get("chips")
    if isinstance(chips, Mapping):          # v1 also kept board and bus names there
        out["chips"] = {k: v for k, v in chips.items() if k in SENSORS}
    for s in SENSORS:
        p = d.get(s)
        if p is None:
            continue
        if not isinstance(p, Mapping):
            fail_check(s, f"expected a mapping, got {type(p).__name__}", "see docs/reference/calibration-file.md")
        q = {k: p[k] for k in _V1_QUALITY[s] if p.get(k) is not None}
        rest = {k: v for k, v in p.items()
                if k not in (*_V1_QUALITY[s], "theta", "crlb_std", "coverage")}
        out[s] = {**rest, **({"quality": q} if q else {})}
    return out
