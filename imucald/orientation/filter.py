"""The orientation filter in the stream: a thin shell around VQF (the ``orientation`` extra).

VQF (D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation estimation with bias
estimation and magnetic disturbance rejection", Information Fusion 91:187-204, 2023; pip
``vqf``, MIT) was chosen over imufusion (x-io's Fusion) by accuracy on the BROAD trials in
../shared (bench/orientation.py): 2.04 deg mean total / 0.59 deg inclination against 5.6 / 3.7.
Its quaternion is [w, x, y, z], sensor frame -> ENU (VQF's earth frame is ENU, and its 9D
heading is referenced to magnetic north), which is the stream's convention unchanged.

One truth about the sensors (what wins, and why):

* The filter is fed imucald's **calibrated** samples (acc in g -> m/s^2, gyro deg/s -> rad/s,
  mag in gauss; VQF normalises acc and mag) at the board's sample rate, every sample
  (output.decimate thins the stream, not the filter's input).
* **Gyro bias**: the calibration's bias (from still poses, accepted only if it validates
  better) is removed before the filter; VQF's rest and motion bias estimation then tracks
  what is left (drift since the calibration, temperature).  Its estimate is *relative to the
  calibration*, so a new gyro calibration resets it to zero with the new calibration's bias
  standard error as its uncertainty (:meth:`OrientationFilter.use_calibration`).  A still
  interval's residual bias is taken off the gyro before VQF (VQF clips its own estimate at
  2 deg/s, beyond which an uncalibrated chip's zero-rate offset lies).
* **Stillness**: imucald's detector (moving variance against the measured noise) decides the
  stream's ``still`` flag and the calibration's poses; VQF's own rest detection (thresholds on
  its low-passed gyro and acc, 2 deg/s and 0.5 m/s^2, over 1.5 s) decides when VQF learns its
  bias at rest.  A still interval imucald closes hands VQF its gyro mean, corrected by the
  calibration in force, with the mean's standard error (:meth:`OrientationFilter.still_interval`):
  it averages the whole interval rather than VQF's 1.5 s window.
* **Magnetic disturbance**: VQF's detector wins (imucald has no per-sample one; its magnetometer
  calibration's held-out error enters the heading standard deviation instead); the stream
  carries VQF's flag as ``mag_disturbed``.
* A new magnetometer or accelerometer calibration resets the filter's state (the magnetic
  reference and the attitude VQF learnt from the old correction are not valid any more); the
  residual gyro bias survives an accelerometer or magnetometer change.  A swapped sensor
  starts a new daemon pipeline, hence a new filter.
"""
from __future__ import annotations

import math
from typing import Any, Dict, Optional

import numpy as np

from ..errors import EX_CONFIG, UserError, install_hint
from . import quality
from .quat import gravity_free_g, qmul

__all__ = ["OrientationFilter", "OrientationUnavailable", "load_vqf", "unavailable_reason",
           "MISSING_EXTRA", "G_MS2"]

#: standard gravity, m/s^2 per g (the unit the accelerometer columns are in)
G_MS2 = 9.80665
#: the one-line message when the extra is missing (the fix named)
MISSING_EXTRA = ("orientation needs the 'orientation' extra (the vqf package), which is not "
                 f"installed: {install_hint('orientation')} (on a Raspberry Pi first "
                 "sudo apt install g++ python3-dev: vqf is built there from source)")


class OrientationUnavailable(UserError):
    """Orientation was asked for and the extra is not installed (a restart cannot fix it)."""

    exit_code = EX_CONFIG


def load_vqf():
    """The vqf module, or OrientationUnavailable with the one-line fix."""
    try:
        import vqf
        vqf.VQF
    except (ImportError, AttributeError):
        raise OrientationUnavailable(MISSING_EXTRA) from None
    return vqf


def unavailable_reason() -> Optional[str]:
    """None when the filter can run here, else why not (the extra is missing)."""
    try:
        load_vqf()
    except OrientationUnavailable as e:
        return str(e)
    return None


def _part_key(p) -> Optional[str]:
    """Identity of a calibration part's correction (its parameters), None when absent."""
    if p is None:
        return None
    return repr(sorted((k, np.asarray(v, float).round(12).tolist()) for k, v in p.params.items()))


#: VQF's accelerometer time constant while the board is quiet after the gyro saturated, s
#: (_after_saturation); measured on simulated MPU-6050 tours with 0.3-0.5-s flips past
#: +-250 deg/s: median tilt error in the holds 6.5 -> 2.1 deg (1.0 s: 2.0 deg, with the stated
#: sd wider)
SATURATED_TAU_ACC_S = 0.4
#: the rate a saturated gyro did not report, as a share of its full scale: taken as N(0,
#: (SATURATED_EXCESS * range)^2) per axis, the same through a run of saturated rows (one flip
#: overshoots one way), so the tilt sd grows with the time spent at the rail; a true peak of
#: twice the range is 2 sd.  Measured on a helper's MPU-6050 / MPU-9250 tours with flips
#: peaking at 400 deg/s on a 250-deg/s range (see the orientation guide)
SATURATED_EXCESS = 0.5
#: the heading errors the magnetometer pulls back (a gyro bias taken off at a still interval, a
#: saturated gyro's unreported turn) fade over this many tau_mag, not one: VQF slows its heading
#: correction while it doubts the field, as it does after a large heading change (measured on a
#: helper's tours: a 157-deg error after a hand-over and 20-38-deg errors after saturated flips
#: faded with time constants of 17-19 s at tau_mag 9 s)
HEADING_PULL_TAUS = 2.0
#: a quiet batch: |a| within this of 1 g in mean, g, and its sd under this, g (a hand's hold:
#: a few mg; a move: tens to hundreds)
QUIET_MEAN_G, QUIET_SD_G = 0.05, 0.02


class OrientationFilter:
    """VQF over batches of calibrated samples; see the module docstring for what wins where.

    ``update`` returns, per batch: ``q`` (n, 4) [w, x, y, z] body -> ENU; ``lin_acc_g`` (n, 3)
    gravity-free specific force, body frame, g; ``mag_disturbed`` (n,) bool or None;
    ``heading`` "magnetic" or "arbitrary"; ``incl_std_deg``, ``heading_std_deg`` (None when
    arbitrary) and ``cov`` (sensor_msgs/Imu orientation_covariance, rad^2)."""

    def __init__(self, rate_hz: float, has_mag: bool, acc_noise_g: Optional[float] = None,
                 params: Optional[Dict[str, Any]] = None):
        vqf = load_vqf()
        self.rate_hz = float(rate_hz)
        self.has_mag = bool(has_mag)
        self.acc_noise_g = acc_noise_g
        #: VQF's defaults unless overridden (its parameter names, e.g. tauAcc)
        self._params = dict(params or {})
        self.f = vqf.VQF(1.0 / self.rate_hz, **self._params)
        p = self.f.params
        self.tau_acc_s, self.tau_mag_s = float(p["tauAcc"]), float(p["tauMag"])
        self._sigma0_rad_s = math.radians(float(p["biasSigmaInit"]))
        self._clip_rad_s = math.radians(float(p["biasClip"]))
        self.acc_bias_se_g: Optional[np.ndarray] = None
        self._acc_var: Optional[float] = None      #: sum of acc_bias_se_g squared, g^2
        self.mag_rel_floor = 0.0
        #: the gyro's datasheet bias prior, rad/s, without a gyro calibration (or None); the
        #: quality figures take it until a still interval or VQF's rest detection (gyro under
        #: 2 deg/s for 1.5 s) has measured the bias (``_bias_seen``)
        self._gyro_prior_rad_s: Optional[float] = None
        self._gyro_tol_dps: Optional[float] = None   #: the chip's zero-rate tolerance, deg/s
        #: variances of the gyro's gain matrix M (reading = M w), its 9 entries row-major,
        #: fraction^2: the datasheet's sensitivity (diagonal) and cross-axis (off) tolerances
        #: as N(0, tol/2) without a gyro calibration that fitted M, else the fit's standard
        #: errors squared; None when neither is known (not in the quality figures)
        self._gain_var: Optional[list] = None
        self._bias_seen = False
        #: the last still interval's residual bias, rad/s, taken off the gyro before VQF: VQF
        #: clips its own estimate to biasClip (2 deg/s), so a larger bias (an uncalibrated
        #: ITG-3200's tens of deg/s) handed to it stayed 2 deg/s and the tilt 60 deg off
        self._offset_rad_s = np.zeros(3)
        self._keys = (None, None, None)
        self.resets = 0
        #: the last output with rows: a batch of repeated rows only repeats its last row
        self._last: Optional[Dict[str, Any]] = None
        #: a calibrated gyro reading beyond this is saturated, deg/s (use_gyro_range), and the
        #: quiet time still to run with the short tauAcc after one, s (_after_saturation)
        self._sat_dps: Optional[float] = None
        self._range_rad_s: Optional[float] = None
        self._fast_left_s = 0.0
        self._tau_now_s = self.tau_acc_s
        self._clear_quality()

    def _clear_quality(self) -> None:
        self._lin_lp = np.zeros(2)           #: tau_acc low-pass of the horizontal gravity-free acc, g
        self._mnorm = None                   #: slow mean of |m|, gauss
        self._mvar = 0.0                     #: tau_mag mean of (|m|/mean - 1)^2
        self._rejected_s = 0.0
        self._mag_seen = False
        self._last_mag: Optional[np.ndarray] = None
        #: sum over the rows so far of R_h[:, i] w_j dt, forgotten over tau_acc: W (2, 3, 3),
        #: rad, flattened to 18 floats (_track_gain: scalar arithmetic, once a batch); a gain
        #: error E_ij turns the tilt by sum_ij E_ij W[:, i, j]
        self._gain_w = [0.0] * 18
        #: sum of R_h[:, i] times the signed seconds axis i spent at the rail, forgotten over
        #: tau_acc: (2, 3) flattened, s (_track_excess); the unreported rate x_i turns the tilt
        #: by sum_i x_i W[:, i]
        self._sat_w = [0.0] * 6
        #: the same with the vertical row of R, forgotten over HEADING_PULL_TAUS tau_mag: the
        #: unreported rate turns the heading by sum_i x_i U[i], which the magnetometer pulls back
        self._sat_wu = [0.0] * 3
        #: the tilt variance a bias left when a still interval measured it, rad^2, fading as
        #: e^{-2 t/tau_acc} (still_interval)
        self._handover_var = 0.0
        #: the heading variance the same bias left, rad^2 (at most |b| tau_mag, or no
        #: information), fading as e^{-2 t/(HEADING_PULL_TAUS tau_mag)} over the rows VQF
        #: stepped with a magnetometer
        self._handover_hvar = 0.0
        #: this batch's seconds at the rail per axis, signed by the reading (_after_saturation),
        #: or None; folded into _sat_w with the batch's attitude (_track_excess)
        self._sat_s: Optional[list] = None

    def set_rate(self, rate_hz: float) -> None:
        """A new sample rate (before the first sample: the state is started afresh)."""
        vqf = load_vqf()
        self.rate_hz = float(rate_hz)
        self.f = vqf.VQF(1.0 / self.rate_hz, **self._params)
        self._keys = (None, None, None)
        self._fast_left_s, self._tau_now_s = 0.0, self.tau_acc_s
        self._bias_seen = False
        self._offset_rad_s = np.zeros(3)
        self._clear_quality()

    # -- the calibration in force ---------------------------------------------------------
    def use_calibration(self, cal, acc_bias_tol_g=None, gyro_bias_tol_dps=None,
                        gyro_gain_tol=None) -> Optional[str]:
        """Take the calibration in force; returns what was reset (None: nothing).

        acc_bias_tol_g: the accelerometer's datasheet zero-g tolerance (g, per axis), used
        (as N(0, tol/2), the simulator's prior) while there is no accelerometer calibration.
        gyro_bias_tol_dps: the gyro's datasheet zero-rate tolerance (deg/s), likewise the
        bias uncertainty the quality figures take while there is neither a gyro calibration
        nor a still interval (:meth:`still_interval`): VQF starts from its own 0.5 deg/s and
        learns at rest only a bias under its 2 deg/s rest threshold, so an ITG-3200's +-40 deg/s
        (a 73 deg median tilt error before the first still interval) read as 45 deg
        through the gravity-free acceleration alone (a daemon helper).
        gyro_gain_tol: the gyro's datasheet (sensitivity, cross-axis) tolerances, fractions,
        likewise taken while no gyro calibration has fitted its gain matrix: a +-3 % gain
        turns a 90-deg flip into a 2.7-deg tilt error, which the stated sd did not hold (a
        black-box helper: 11-12 % of the motion samples beyond 3 sd on every board)."""
        a, g, m = (getattr(cal, k, None) for k in ("accel", "gyro", "mag"))
        keys = (_part_key(a), _part_key(g), _part_key(m))
        se = None
        if a is not None and "bias_g" in a.stderr:
            se = np.asarray(a.stderr["bias_g"], float)
        elif a is None and acc_bias_tol_g is not None:
            se = np.asarray(acc_bias_tol_g, float) / 2.0
        self.acc_bias_se_g = se
        self._acc_var = None if se is None else float(np.sum(se[np.isfinite(se)] ** 2))
        self.mag_rel_floor = float((m.quality or {}).get("heldout_rel_rms", 0.0) or 0.0) if m is not None else 0.0
        old, self._keys = self._keys, keys
        if old[1] != keys[1]:
            self._bias_seen = False             # what VQF learnt was relative to the old gyro part
        self._gyro_prior_rad_s = (math.radians(float(gyro_bias_tol_dps) / 2.0)
                                  if g is None and gyro_bias_tol_dps is not None else None)
        self._gyro_tol_dps = None if gyro_bias_tol_dps is None else float(gyro_bias_tol_dps)
        self._gain_var = _gain_var(g, gyro_gain_tol)
        if old == keys:
            return None
        what = []
        if old[0] != keys[0] or old[2] != keys[2]:
            if old != (None, None, None):
                b, s = self.f.getBiasEstimate()
                self.f.resetState()
                self._clear_quality()
                if old[1] == keys[1]:             # the residual gyro bias is still valid
                    self.f.setBiasEstimate(np.asarray(b, float), float(s))
                what.append("filter state (new accelerometer/magnetometer calibration)")
        if old[1] != keys[1]:
            sg = self._sigma0_rad_s
            if g is not None and "bias_dps" in g.stderr:
                s = np.asarray(g.stderr["bias_dps"], float)
                if np.all(np.isfinite(s)):
                    sg = math.radians(float(np.max(s)))
            self.f.setBiasEstimate(np.zeros(3), max(sg, 1e-6))
            self._offset_rad_s = np.zeros(3)
            what.append("residual gyro bias (new gyro calibration)")
        if not what:
            return None
        self.resets += 1
        return "; ".join(what)

    #: take imucald's still intervals as bias measurements (bench/orientation.py --compare-still)
    use_still_intervals = True

    def still_interval(self, gyro_mean_dps, gyro_se_dps) -> None:
        """A still interval closed: its mean calibrated gyro reading is the residual bias."""
        if not self.use_still_intervals:
            return
        b = np.asarray(gyro_mean_dps, float)
        if not np.all(np.isfinite(b)):
            return
        se = float(np.max(gyro_se_dps)) if gyro_se_dps is not None and np.all(np.isfinite(gyro_se_dps)) else 0.01
        if float(np.max(np.abs(b))) > self._offset_limit_dps():
            # more than a bias can be: a steady turn about gravity reads as still (the detector
            # cannot tell them apart); handed to VQF, which clips it, as before the offset
            self.f.setBiasEstimate(np.radians(b), max(math.radians(se), 1e-6))
            return
        self._bias_seen = True                  # the bias is measured now
        # the tilt the bias left is pulled back over tau_acc, not at once: the sd keeps it
        # (at most |b| tau, both horizontal components) and lets it fade as the error does
        left = np.radians(b) - self._offset_rad_s
        self._handover_var = max(self._handover_var, float(left @ left) * self._tau_now_s ** 2)
        self._handover_hvar = max(self._handover_hvar, min(float(left @ left) * self.tau_mag_s ** 2,
                                                           quality.ARBITRARY_HEADING_VAR_RAD2))
        self._offset_rad_s = np.radians(b)      # taken off before VQF, whose own estimate restarts at 0
        self.f.setBiasEstimate(np.zeros(3), max(math.radians(se), 1e-6))

    def _offset_limit_dps(self) -> float:
        """The largest still-interval mean taken as a bias, deg/s, per axis.  With a gyro
        calibration in force, what is left is drift, and VQF's own 2-deg/s clip bounds it as
        before (a cold review: a 10 deg/s turn about gravity, read as still, tilted the board
        31 deg once it tipped).  Without one, the chip's datasheet zero-rate tolerance
        (use_calibration's gyro_bias_tol_dps), or, the chip unknown, the widest of the
        supported chips' (the ITG-3200's 40 deg/s: BROAD's trials with a drawn MPU-9250-class
        bias of up to 5 deg/s lost session 18's gain, 2.54 -> 4.86 deg, at the clip)."""
        if self._keys[1] is not None:
            return math.degrees(self._clip_rad_s)
        if self._gyro_tol_dps is not None:
            return self._gyro_tol_dps
        from ..specs import GYRO
        return max(g.bias_tol_dps for g in GYRO.values())

    # -- the batch ------------------------------------------------------------------------
    def update(self, acc_g, gyro_dps, mag_gauss=None, repeat=None) -> Dict[str, Any]:
        """The batch's output (see the class).  ``repeat``: (n,) bool, rows that repeat the
        previous row, timestamp and values (a logger that wrote each row twice): not new
        samples, so not stepped (VQF steps 1/rate a row and would turn every rotation twice:
        a replayed MPU-6050 tour with duplicated rows had its tilt 42 deg off at the 90th
        percentile); each takes the output of the row it repeats."""
        if repeat is not None and np.any(repeat):
            return self._update_distinct(acc_g, gyro_dps, mag_gauss, np.asarray(repeat, bool))
        o = self._update(acc_g, gyro_dps, mag_gauss)
        if len(o["q"]):
            self._last = dict(o)                # (a caller may put other arrays in its own)
        return o

    def _update_distinct(self, acc_g, gyro_dps, mag_gauss, repeat) -> Dict[str, Any]:
        new = ~repeat
        before = self._last                     # the output a batch's leading repeats repeat
        if new.any():
            o = self.update(np.asarray(acc_g)[new], np.asarray(gyro_dps)[new],
                            None if mag_gauss is None else np.asarray(mag_gauss)[new])
        elif before is not None:
            o = before
        else:                                   # nothing seen yet: nothing to repeat
            nan = np.full((len(repeat), 3), np.nan)
            return self._update(nan, nan)
        pick = np.cumsum(new)                   # 0: the last batch's last row; i: the i-th new row
        out = dict(o)
        blank = {"q": np.full((1, 4), np.nan), "lin_acc_g": np.full((1, 3), np.nan),
                 "mag_disturbed": np.zeros(1, bool)}
        for k in blank:
            if o[k] is None:
                continue
            had = before is not None and before[k] is not None and len(before[k])
            first = before[k][-1:] if had else blank[k]
            out[k] = np.concatenate([first, o[k] if new.any() else o[k][:0]])[pick]
        return out

    def _update(self, acc_g, gyro_dps, mag_gauss=None) -> Dict[str, Any]:
        acc = np.asarray(acc_g, float)
        gyro = np.asarray(gyro_dps, float)
        n = len(acc)
        self._after_saturation(acc, gyro)
        allok = math.isfinite(float(acc.sum()) + float(gyro.sum()))     # the usual case, cheaply
        ok = None if allok else (np.isfinite(acc).all(1) & np.isfinite(gyro).all(1))
        mag = None
        if self.has_mag and mag_gauss is not None:
            mag = np.asarray(mag_gauss, float)
            good = None if math.isfinite(float(mag.sum())) else np.isfinite(mag).all(1)
            if good is None:
                self._last_mag = mag[-1].copy()
            elif not good.all():                   # sample-and-hold over rows without a reading
                mag = mag.copy()
                idx = np.where(good, np.arange(n), -1)
                np.maximum.accumulate(idx, out=idx)
                have = idx >= 0
                mag[have] = mag[idx[have]]
                if self._last_mag is not None:
                    mag[~have] = self._last_mag
                    have[:] = True
                good = have
            if good is not None and good.any():
                self._last_mag = mag[good][-1].copy()
            if good is not None and not good.all():
                mag = None                         # none seen yet: these rows go without
        sig = self._sigma0_rad_s
        dist = None
        if allok:
            q, lin, dist, sig = self._run(acc, gyro, mag)
        else:
            q, lin = np.full((n, 4), np.nan), np.full((n, 3), np.nan)
            if self.has_mag:
                dist = np.zeros(n, bool)
            if ok.any():
                q[ok], lin[ok], d, sig = self._run(acc[ok], gyro[ok], None if mag is None else mag[ok])
                if d is not None:
                    dist[ok] = d
        if self.has_mag and dist is None:
            dist = np.zeros(n, bool)
        magnetic = self.has_mag and self._mag_seen
        if self._gyro_prior_rad_s is not None and not self._bias_seen:
            sig = max(sig, self._gyro_prior_rad_s)
        if self._handover_var:
            ran = n if allok else int(ok.sum())     # rows VQF stepped: the tilt fades with them
            self._handover_var = _faded(self._handover_var, ran / self.rate_hz, self._tau_now_s)
        tv = quality.tilt_var_rad2(self._acc_var, sig, math.hypot(self._lin_lp[0], self._lin_lp[1]),
                                   self.acc_noise_g, self._tau_now_s, self.rate_hz,
                                   self._gain_var_rad2() + self._excess_var_rad2() + self._handover_var)
        if self._handover_hvar:
            # pulled back by the magnetometer, over the rows VQF stepped with one
            took = 0 if mag is None else (n if allok else int(ok.sum()))
            self._handover_hvar = _faded(self._handover_hvar, took / self.rate_hz,
                                         HEADING_PULL_TAUS * self.tau_mag_s)
        if magnetic:
            rel = max(math.sqrt(self._mvar), self.mag_rel_floor)
            hv = quality.heading_var_rad2(sig, rel, self._dip_rad, self.tau_mag_s, self._rejected_s, tv,
                                          pullback_var=self._handover_hvar + self._excess_hvar_rad2())
        else:
            hv = quality.ARBITRARY_HEADING_VAR_RAD2
        return {"q": q, "lin_acc_g": lin, "mag_disturbed": dist,
                "heading": "magnetic" if magnetic else "arbitrary",
                "incl_std_deg": math.degrees(math.sqrt(tv)),
                "heading_std_deg": math.degrees(math.sqrt(hv)) if magnetic else None,
                "cov": quality.ros_covariance(tv, hv), "bias_sigma_dps": math.degrees(sig)}

    def use_gyro_range(self, range_dps: Optional[float], bias_tol_dps: Optional[float] = None) -> None:
        """The gyro's full scale, deg/s (None: unknown, nothing done).  A calibrated reading
        beyond 95 % of it less the zero-rate tolerance counts as saturated (a clipped raw count,
        after a sensitivity error of a few % and the bias taken off)."""
        ok = range_dps is not None and math.isfinite(float(range_dps)) and float(range_dps) > 0
        self._sat_dps = 0.95 * float(range_dps) - float(bias_tol_dps or 0.0) if ok else None
        self._range_rad_s = math.radians(float(range_dps)) if ok else None

    def _after_saturation(self, acc, gyro) -> None:
        """A saturated gyro reports too small a rotation, so the tilt is off by what it did not
        report (a hand's flip past +-250 deg/s: 5-14 deg in the next hold, decaying over VQF's
        3-s tauAcc).  From then, each quiet batch (|a| within QUIET_MEAN_G of 1 g, sd under
        QUIET_SD_G) runs with tauAcc SATURATED_TAU_ACC_S until 3 of it have passed (the error
        down to e^-3); a batch that moves keeps the usual tauAcc (its |a| is not gravity)."""
        if self._sat_dps is None or not len(acc):
            return
        g = np.abs(gyro[np.isfinite(gyro)])
        if len(g) and float(g.max()) >= self._sat_dps:
            rail = np.abs(gyro) >= self._sat_dps            # NaN: False
            self._sat_s = (np.where(rail, np.sign(gyro), 0.0).sum(0) / self.rate_hz).tolist()
            self._fast_left_s = 3 * SATURATED_TAU_ACC_S
            self._tau(self.tau_acc_s)
            return
        if self._fast_left_s <= 0:
            return
        an = np.linalg.norm(acc, axis=1)
        an = an[np.isfinite(an)]
        quiet = len(an) > 0 and abs(float(an.mean()) - 1.0) < QUIET_MEAN_G and float(an.std()) < QUIET_SD_G
        if quiet:
            self._tau(SATURATED_TAU_ACC_S)
            self._fast_left_s -= len(acc) / self.rate_hz
        if not quiet or self._fast_left_s <= 0:
            self._tau(self.tau_acc_s)

    def _tau(self, tau_s: float) -> None:
        if tau_s != self._tau_now_s:
            self.f.setTauAcc(tau_s)
            self._tau_now_s = tau_s

    def _run(self, acc, gyro, mag):
        """VQF over rows that are all finite: (q, lin_acc_g, mag_disturbed or None, bias sigma)."""
        a = np.ascontiguousarray(acc * G_MS2)        # VQF takes C-ordered m/s^2 and rad/s
        w = np.ascontiguousarray(np.radians(gyro) - self._offset_rad_s)
        if mag is not None:
            o = self.f.updateBatch(w, a, np.ascontiguousarray(mag))
            q, dist = o["quat9D"], o["magDistDetected"]
            self._mag_seen = True
        else:
            o = self.f.updateBatch(w, a)
            q, dist = o["quat6D"] if not self._mag_seen else self._q9_from_6d(o["quat6D"]), None
        if (not self._bias_seen and self._gyro_prior_rad_s is not None
                and self._gyro_prior_rad_s <= self._clip_rad_s and o["restDetected"].any()):
            self._bias_seen = True              # VQF saw rest and can learn a bias this size
        lin = gravity_free_g(q, acc)
        self._track(q, lin, mag, dist)
        if self._gain_var is not None:
            self._track_gain(q, w)
        if self._sat_s is not None or any(self._sat_w) or any(self._sat_wu):
            self._track_excess(q, mag is not None)
        return q, lin, dist, float(o["biasSigma"][-1])

    def _track_gain(self, q, w_rad_s) -> None:
        """W (see _clear_quality) over this batch: the horizontal rows of R (body -> ENU) at the
        batch's middle row times the batch's rotation (mean rate times its duration), the whole
        forgotten by e^{-n dt/tau}: a gain error acts as a bias proportional to the rate, and
        the filter pulls the tilt it leaves back to the accelerometer's over tau_acc (quality
        module).  One attitude a batch, as _track: per row it cost twice the filter's own time
        at 1 kHz, and a batch turns the board by a few degrees (a second-order error in an sd)."""
        n, dt = len(q), 1.0 / self.rate_hz
        rh = _horizontal_rows(q[n // 2].tolist())
        turn = (w_rad_s.sum(0) * dt).tolist()
        k = math.exp(-n * dt / self._tau_now_s)
        self._gain_w = [k * a + r * b for a, (r, b) in zip(self._gain_w, ((r, b) for r in rh for b in turn))]

    def _track_excess(self, q, with_mag: bool) -> None:
        """_sat_w over this batch (see _clear_quality), as _track_gain: the batch's middle
        attitude, its seconds at the rail, the whole forgotten by e^{-n dt/tau}."""
        n = len(q)
        qm = q[n // 2].tolist()
        rh = _horizontal_rows(qm)
        k = math.exp(-n / self.rate_hz / self._tau_now_s)
        s = self._sat_s or (0.0, 0.0, 0.0)
        self._sat_s = None
        self._sat_w = [k * a + r * s[i % 3] for i, (a, r) in enumerate(zip(self._sat_w, rh))]
        if max(map(abs, self._sat_w)) < 1e-6:
            self._sat_w = [0.0] * 6
        # the heading's share is pulled back only by the magnetometer: batches without one keep it
        ku = math.exp(-n / self.rate_hz / (HEADING_PULL_TAUS * self.tau_mag_s)) if with_mag else 1.0
        self._sat_wu = [ku * a + u * si for a, u, si in zip(self._sat_wu, _vertical_row(qm), s)]
        if max(map(abs, self._sat_wu)) < 1e-6:
            self._sat_wu = [0.0] * 3

    def _excess_var_rad2(self, w=None) -> float:
        """The tilt variance the rate a saturated gyro did not report leaves (SATURATED_EXCESS),
        from its tracker ``w`` (_sat_w; the heading's: _sat_wu)."""
        w = self._sat_w if w is None else w
        if self._range_rad_s is None or not any(w):
            return 0.0
        return (SATURATED_EXCESS * self._range_rad_s) ** 2 * sum(a * a for a in w)

    def _excess_hvar_rad2(self) -> float:
        """The heading variance the rate a saturated gyro did not report leaves."""
        return self._excess_var_rad2(self._sat_wu)

    def _gain_var_rad2(self) -> float:
        """The tilt variance the gyro's gain error leaves (quality.tilt_var_rad2's gain term)."""
        if self._gain_var is None:
            return 0.0
        v = self._gain_var
        return sum(v[i % 9] * a * a for i, a in enumerate(self._gain_w))

    def _q9_from_6d(self, q6):
        """Rows fed without a magnetometer reading after one was seen: the 6D attitude turned
        by the filter's current heading offset (VQF's delta, about the vertical)."""
        d = self.f.getDelta()
        dq = np.array([math.cos(d / 2), 0.0, 0.0, math.sin(d / 2)])
        return qmul(dq, q6)

    def _track(self, q, lin, mag, dist) -> None:
        """The filter-state figures the standard deviations use, once per batch (scalar
        arithmetic on the batch's last attitude: a batch turns the board by a few degrees at
        most, a second-order error in a tau_acc low-pass)."""
        n = len(q)
        k = 1.0 - math.exp(-n / (self.rate_hz * self.tau_acc_s))
        e = _rotate1(q[-1].tolist(), lin.mean(0).tolist())
        self._lin_lp[0] += k * (e[0] - self._lin_lp[0])
        self._lin_lp[1] += k * (e[1] - self._lin_lp[1])
        if mag is None:
            return
        ml = mag[-1].tolist()               # one reading a batch (magnetometers run at 10-100 Hz)
        m = math.sqrt(ml[0] * ml[0] + ml[1] * ml[1] + ml[2] * ml[2])
        if self._mnorm is None:
            self._mnorm = m
        self._mnorm += (1.0 - math.exp(-n / (self.rate_hz * 20.0))) * (m - self._mnorm)
        km = 1.0 - math.exp(-n / (self.rate_hz * self.tau_mag_s))
        self._mvar += km * ((m / self._mnorm - 1.0) ** 2 - self._mvar)
        me = _rotate1(q[-1].tolist(), ml)
        self._dip_rad = math.atan2(-me[2], math.hypot(me[0], me[1]))
        self._rejected_s = (self._rejected_s + n / self.rate_hz) if dist[-1] else 0.0

    _dip_rad = 0.0


def _gain_var(g, tol) -> Optional[list]:
    """Variances of the gyro's gain matrix, 9 entries row-major, fraction^2, or None: a gyro
    part with a fitted ``matrix`` takes its standard errors; the datasheet (sensitivity,
    cross-axis) tolerances ``tol`` as N(0, tol/2) where there is no fitted matrix, or its
    standard errors are not stated or not finite (unknown: a cold review found a matrix saved
    without them dropped the term, 2.4 deg off against a stated 0.19); None when neither is
    known."""
    tv = None
    if tol is not None:
        d, c = (float(tol[0]) / 2.0) ** 2, (float(tol[1]) / 2.0) ** 2
        tv = [d if i % 4 == 0 else c for i in range(9)]
    if g is None or "matrix" not in g.params:
        return tv
    se = g.stderr.get("matrix")
    se = np.full(9, np.nan) if se is None else np.asarray(se, float).reshape(9)
    if tv is None and not np.isfinite(se).all():
        return None if not np.isfinite(se).any() else np.where(np.isfinite(se), se * se, 0.0).tolist()
    return [float(x * x) if math.isfinite(x) else tv[i] for i, x in enumerate(se.tolist())]


def _faded(var: float, seconds: float, tau_s: float) -> float:
    """A variance whose error a filter of time constant ``tau_s`` pulls back, ``seconds`` on:
    var e^{-2 t/tau} (0 once under 1e-12 rad^2)."""
    var *= math.exp(-2.0 * seconds / tau_s)
    return var if var >= 1e-12 else 0.0


def _horizontal_rows(q):
    """Rows E and N of the rotation matrix of one quaternion q (list [w, x, y, z], body ->
    ENU), six floats row-major: where each body axis points horizontally."""
    w, x, y, z = q
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x))


def _vertical_row(q):
    """Row U of the rotation matrix of one quaternion q (list [w, x, y, z], body -> ENU), three
    floats: each body axis's vertical component."""
    w, x, y, z = q
    return (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def _rotate1(q, v):
    """One vector v (list) by one quaternion q (list [w, x, y, z]), body -> ENU, in floats."""
    w, x, y, z = q
    a, b, c = v
    return (a * (1 - 2 * (y * y + z * z)) + b * 2 * (x * y - w * z) + c * 2 * (x * z + w * y),
            a * 2 * (x * y + w * z) + b * (1 - 2 * (x * x + z * z)) + c * 2 * (y * z - w * x),
            a * 2 * (x * z - w * y) + b * 2 * (y * z + w * x) + c * (1 - 2 * (x * x + y * y)))
