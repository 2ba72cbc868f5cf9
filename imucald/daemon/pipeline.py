"""One pipeline, one direction: sample batches -> stillness -> poses -> calibrator
-> correction -> encoded stream.

The pipeline owns no I/O: the daemon feeds it batches from the board and writes
what it returns to the sinks; replay feeds it a recording.  Calibration jobs go
to an executor (a worker process in the daemon, inline in replay) and are
polled without waiting.
"""
from __future__ import annotations

import logging
from concurrent.futures import Executor, Future
from datetime import datetime, timezone
from collections import deque
from typing import Any, Callable, Deque, Dict, List, Optional

import numpy as np

from ..fitting.gate import fitted_poses, in_force_check
from ..fitting.judging.levels import IN_FORCE_CHALLENGE_LEVEL
from ..fitting.judging.outliers import OUTLIER_CAUSE
from ..fitting.judging.coverage import next_orientation
from ..fitting.stillness.detector import StillnessDetector
from ..fitting.stillness.repeats import duplicated_rows
from ..calibration import Calibration, next_id
from .accumulator import PoseAccumulator
from .fitjob import JobResult, MagReservoir, calibration_job
from .config import accel_poses_needed
from .outputs import encode_samples, event
from .thermallog import ThermalLog, thermal_status

__all__ = ["Pipeline", "InlineExecutor", "POSE_COLUMNS", "batch_period_s"]

log = logging.getLogger("imucald")
#: fewest poses any accelerometer calibration uses: the 9 parameters of triangular9 and
#: leave-one-pose-out scoring (each refit keeps 9 poses); the first, provisional one is
#: tried from here on
MIN_FIT_POSES = accel_poses_needed()
#: columns of a calibration's ``poses_used`` table
POSE_COLUMNS = ["ax_g", "ay_g", "az_g", "n", "temp_c", "t0_s", "t1_s"]
#: fresh magnetometer readings kept for the per-sample noise (second differences)
MAG_NOISE_SAMPLES = 2000
#: boards without an accelerometer: fewest reservoir points for a fit, and seconds of new
#: readings between calibrations
MIN_MAG_POINTS = 30
MAG_RECAL_S = 20.0
#: fewest samples the daemon hands the pipeline at once: a batch costs a fixed ~60 us here
#: (numpy calls of the stillness detector, encoder, socket write) plus ~5 us a sample
#: (bench/pipeline.py), so a 9DOF board polled at 100 Hz with 20 ms batches (2 samples)
#: would spend most of its time on the fixed part
MIN_BATCH_SAMPLES = 4
#: the thermal terms are refitted each time the thermal log's temperature span has grown by
#: this much since the last thermal fit (and first when it reaches thermal_min_span_c)
THERMAL_REFIT_GROWTH_C = 1.0


def batch_period_s(batch_s: float, rate_hz: float) -> float:
    """How often the daemon drains the board: ``sensor.batch_s``, lengthened to hold at least
    MIN_BATCH_SAMPLES samples (a 100 Hz board: 40 ms; 1 kHz boards keep 20 ms)."""
    return max(float(batch_s), MIN_BATCH_SAMPLES / float(rate_hz))


class InlineExecutor(Executor):
    """Runs jobs at submit time (replay: deterministic, as fast as possible)."""

    def submit(self, fn, *args, **kwargs):
        f: Future = Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except BaseException as e:          # reported through the future, like a pool
            f.set_exception(e)
        return f


class Pipeline:
    def __init__(self, cfg: Dict[str, Dict[str, Any]], board: str, rate_hz: float, has_mag: bool,
                 executor: Optional[Executor] = None, persist: Optional[Callable] = None,
                 chips: Optional[Dict[str, str]] = None, has_acc: bool = True):
        self.cfg, self.board, self.rate_hz, self.has_mag = cfg, board, rate_hz, has_mag
        self.chips = dict(chips or {})
        # without an accelerometer (gy273) there are no still poses: the magnetometer is
        # calibrated from its rotation cloud alone, as `imucald calibrate` does
        self.has_acc = has_acc
        self.mag_recent: Deque[np.ndarray] = deque(maxlen=MAG_NOISE_SAMPLES)
        self._next_mag_seen = 0
        st = cfg["stillness"]
        self.det = StillnessDetector(rate_hz, st["window_s"], st["k"], st["min_still_s"],
                                     st["max_pose_s"], st["trim_s"], chip=(chips or {}).get("accel"),
                                     keep_structure=True)
        self.acc = PoseAccumulator(cfg["poses"]["merge_angle_deg"], cfg["poses"]["max_poses"])
        self.next_hint: Optional[str] = None          # the orientation the log asked for last
        self._hinted: Dict[str, int] = {}             # orientation -> times asked for
        #: every still interval with its temperature, for the thermal terms (daemon/thermallog.py)
        self.thermal_log = ThermalLog()
        self._thermal_span_at = -np.inf        #: the log's span when thermal terms were last fitted
        self.thermal_notes: Dict[str, Dict[str, Any]] = {}   #: the last thermal fit, per sensor
        #: the calibration in force (id 0, no parts: uncalibrated)
        self.applied = Calibration(board, dict(chips or {}))
        self.applied_t_s: Optional[float] = None      #: stream time it was applied at
        self.reservoir = MagReservoir() if has_mag else None
        self.executor = executor or InlineExecutor()
        self.persist = persist or (lambda kind, obj: None)
        self.fmt = cfg["output"]["format"]
        self.pending: Optional[Future] = None
        self.next_cal_added = 0
        self.force = False
        self.samples = 0
        self.last_still = False
        self._repeats_said = None        #: the detector whose repeated-samples decision was logged
        # bounded: a daemon runs for months and adds an event per pose
        self.events: Deque[str] = deque(maxlen=100)     # human log lines for status
        self.t_last = 0.0
        self.temp_range = [np.inf, -np.inf]
        self._tried_raw_at = 0           #: acc.added at the last attempt on the raw sensor
        self._ready_tried = False        #: a fit has run with the poses needed reached
        self._said_nothing_new = False   #: the log has said why revisits start no refit
        self._job_ready = True           #: the pending job's pose set met the readiness targets
        self._job_missing: List[str] = []
        #: noise figures (fitting.noise.allan.read_figures of noise.file), or None
        self.noise: Optional[Dict[str, Dict[str, np.ndarray]]] = None
        self._cov_key = None
        self._cov_text = ""
        #: the orientation filter (issue 26; use_orientation), None when off, and why it is off
        self.orient = None
        self.orientation_off: Optional[str] = "not asked for"

    def reconfigure(self, cfg: Dict[str, Dict[str, Any]], changed) -> None:
        """A reload: ``changed`` keys of ``cfg`` take effect from the next batch (new
        stillness settings restart a still interval in progress)."""
        self.cfg = cfg
        if any(k.startswith("stillness.") for k in changed):
            st = cfg["stillness"]
            self.det = StillnessDetector(self.rate_hz, st["window_s"], st["k"], st["min_still_s"],
                                         st["max_pose_s"], st["trim_s"], chip=self.applied.chips.get("accel"),
                                         keep_structure=True)
        if any(k.startswith("poses.") for k in changed):
            self.acc.merge_cos = np.cos(np.radians(cfg["poses"]["merge_angle_deg"]))
            self.acc.max_poses = cfg["poses"]["max_poses"]
        self.fmt = cfg["output"]["format"]
        self._checked = None            # readiness targets may have changed

    # -- the hot path -------------------------------------------------------------------
    def process(self, b) -> bytes:
        out: List[bytes] = []
        n = len(b.t)
        # a GAP before the batch's first sample leads it; one inside it (merged polls) goes
        # where its samples are missing (_gaps_in_place)
        inside = [g for g in b.gaps if n and g[0] > b.seq[0]] if b.gaps else []
        out += [event("GAP", self.fmt, seq=int(s0), missing=int(k)) for s0, k in b.gaps
                if (s0, k) not in inside]
        if n:
            still, intervals = self.det.update(b.t, b.acc, b.gyro, b.temp, b.mag, b.mag_fresh)
            if self.det.repeats is not None and self._repeats_said is not self.det:
                self._repeats_said = self.det       # said once per detector (issue 20)
                msg = self.det.repeats.summary()
                if msg:                             # counted over the stream's first seconds
                    msg = f"input, first {len(self.det.repeats.keep)} rows: {msg}"
                    log.warning("%s", msg)
                    self.events.append(msg)
            self.samples += n
            self.t_last = float(b.t[-1])
            self.last_still = bool(still[-1])
            for iv in intervals:
                self._pose(iv)
            if self.reservoir is not None and b.mag_fresh is not None and b.mag_fresh.any():
                fresh = b.mag[b.mag_fresh]
                # each point's tag: its temperature in centi-kelvin (-1 unknown), for the hard
                # iron's thermal terms (daemon/thermaljob.py)
                tf = None if b.temp is None else b.temp[b.mag_fresh]
                self.reservoir.add(fresh, None if tf is None else
                                   np.where(np.isfinite(tf), np.round((tf + 273.15) * 100), -1))
                self.mag_recent.extend(fresh)
            ap = self.applied
            dec = self.cfg["output"]["decimate"]
            keep = (b.seq % dec) == 0 if dec > 1 else slice(None)
            temp = None if b.temp is None else b.temp[keep]
            # thermal terms: evaluated once per batch, at its mean temperature (NaN: t_ref)
            tb = None if temp is None or not len(temp) else float(temp.mean())
            acc = ap.apply_accel(b.acc[keep], tb)
            gyro = None if b.gyro is None else ap.apply_gyro(b.gyro[keep], tb, acc)
            mag = None if b.mag is None else ap.apply_mag(b.mag[keep], tb)
            pieces = self.det.take_pieces()     # as cut: a long rest's bias does not wait for its end
            ori = None if self.orient is None else self._orientation(b, keep, tb, acc, gyro, mag, pieces)
            enc = encode_samples(self.fmt, b.seq[keep], b.t[keep], acc,
                                 gyro, temp, mag, still[keep], ap.id, self._covariance(), ori)
            out.append(self._gaps_in_place(enc, b.seq[keep], inside) if inside else enc)
        out.append(self.poll_calibration())
        self.maybe_calibrate()
        out.append(self.poll_calibration())
        return b"".join(out)

    def _gaps_in_place(self, enc: bytes, seq, gaps) -> bytes:
        """The batch's lines with each GAP object inside it where its samples are missing (a
        cold review: on a gy273 a GAP came before IMU lines of earlier seq); binary streams
        carry no GAP objects (their records hold seq)."""
        if self.fmt == "binary":
            return enc
        lines = enc.split(b"\n")[:-1]      # one line a sample (ndjson, csv)
        out, at = [], 0
        for s0, k in gaps:
            i = int(np.searchsorted(seq, s0))
            out += [ln + b"\n" for ln in lines[at:i]]
            out.append(event("GAP", self.fmt, seq=int(s0), missing=int(k)))
            at = max(at, i)
        out += [ln + b"\n" for ln in lines[at:]]
        return b"".join(out)

    def end_of_stream(self) -> bytes:
        """A recording ended (replay): the detector judges what waits and closes the
        still run, so replay finds the poses ``calibrate`` finds in the same file."""
        for iv in self.det.flush():
            self._pose(iv)
        self.maybe_calibrate()
        return self.poll_calibration()

    def use_noise_file(self, path: Optional[str]) -> None:
        """Load noise.file (``imucald noise -o``); a bad file is a configuration error."""
        if not path:
            return
        from ..fitting.noise.allan import read_figures
        from ..errors import UserError
        from .config import ConfigError
        try:
            self.noise = read_figures(path)
        except UserError as e:
            msg = str(e)
            raise ConfigError(msg if msg.startswith("noise.file") else f"noise.file: {msg}") from None
        log.info("noise figures from %s (%s)", path, ", ".join(self.noise))

    def _covariance(self) -> str:
        """',"acc_var_g2":[..],"gyro_var_dps2":[..]' for output.covariance, else "".

        The variance of one sample per axis: the noise file's white density squared times
        the sample rate (kalibr's discrete-time convention, as in its ROS export), plus for
        the gyro the squared standard error of the applied bias.  Diagonal: the axes' noises
        are independent; the calibration's scale and misalignment errors are not included."""
        if not self.cfg["output"]["covariance"] or self.noise is None:
            return ""
        key = self.applied.id
        if key != self._cov_key:
            parts = []
            for s, name in (("accel", "acc_var_g2"), ("gyro", "gyro_var_dps2")):
                if s not in self.noise:
                    continue
                v = self.noise[s]["white"] ** 2 * self.rate_hz
                g = self.applied.gyro
                if s == "gyro" and g is not None and "bias_dps" in g.stderr:
                    se = np.asarray(g.stderr["bias_dps"], float)
                    v = v + np.where(np.isfinite(se), se, 0.0) ** 2
                parts.append(f',"{name}":[{v[0]:.4g},{v[1]:.4g},{v[2]:.4g}]')
            self._cov_key, self._cov_text = key, "".join(parts)
        return self._cov_text

    # -- orientation (issue 26): one hook, off unless use_orientation() turns it on ----------
    def use_orientation(self, mode: str, has_gyro: bool = True,
                        gyro_range_dps: Optional[float] = None) -> None:
        """output.orientation: "yes" (the extra missing is a configuration error, one line),
        "auto" (on when the extra is installed and the board has a gyro and an accelerometer;
        else off, and ``orientation_off`` says why), "no".  ``gyro_range_dps``: the gyro's
        full scale (the board's, or a recording's header; None: its chip's datasheet default),
        beyond which the filter re-converges fast (OrientationFilter.use_gyro_range)."""
        from ..orientation import OrientationFilter, unavailable_reason
        from ..specs import ACCEL, GYRO
        self.orient = None
        if mode == "no":
            self.orientation_off = "output.orientation: no"
            return
        why = None if (self.has_acc and has_gyro) else "the board has no gyroscope and accelerometer pair"
        why = why or unavailable_reason()
        if why is not None:
            if mode == "yes":
                from .config import ConfigError
                raise ConfigError(f"output.orientation: yes: {why}")
            self.orientation_off = why
            return
        spec = ACCEL.get(self.chips.get("accel", ""))
        noise = None
        if self.noise is not None and "accel" in self.noise:
            noise = float(np.mean(self.noise["accel"]["white"])) * self.rate_hz ** 0.5
        elif spec is not None:
            noise = spec.noise_density_g_rthz * self.rate_hz ** 0.5
        self._acc_tol = None if spec is None else spec.bias_tol_g
        gspec = GYRO.get(self.chips.get("gyro", ""))
        self._gyro_tol = None if gspec is None else gspec.bias_tol_dps
        self._gain_tol = None if gspec is None else (gspec.scale_tol, gspec.cross_axis_tol)
        self.orient = OrientationFilter(self.rate_hz, self.has_mag, noise)
        self.orient.use_gyro_range(gyro_range_dps or (None if gspec is None else gspec.range_dps),
                                   self._gyro_tol)
        self._orient_prev = {}              #: the last row the filter saw (duplicated_rows)
        self._orient_cal = None
        self.orientation_off = None

    def orientation_rate_from(self, t_s, rows=None) -> None:
        """Replay: the filter integrates at the rate the recording's timestamps show (their
        median step) when it differs from its header's rate_hz by more than 1 %; called with
        the first block's times, before any sample reached the filter.  ``rows``: the block's
        sensor arrays (acc, gyro, mag or None), whose duplicated rows are left out."""
        if self.orient is None or len(t_s) < 3 or self.samples:
            return
        t_s = np.asarray(t_s, float)
        if rows is not None:                    # a logger's duplicated rows are not samples
            t_s = t_s[~duplicated_rows(t_s, rows)]
            if len(t_s) < 3:
                return
        dt = float(np.median(np.diff(t_s)))
        if dt > 0 and abs(1.0 / dt / self.rate_hz - 1.0) > 0.01:
            log.info("orientation: the timestamps step %.6g s (%.6g Hz), the header says %.6g Hz: "
                     "the filter integrates at %.6g Hz", dt, 1.0 / dt, self.rate_hz, 1.0 / dt)
            self.orient.set_rate(1.0 / dt)

    def _orientation(self, b, keep, tb, acc, gyro, mag, intervals):
        """Feed the filter this batch's calibrated samples, every one of them (decimation thins
        the stream only); returns its output for the kept rows, or None without a gyro."""
        f, ap = self.orient, self.applied
        if ap is not self._orient_cal:          # a new calibration: reset what depends on it
            what = f.use_calibration(ap, self._acc_tol, self._gyro_tol, self._gain_tol)
            self._orient_cal = ap
            if what:
                log.info("orientation: reset the %s (calibration #%d)", what, ap.id)
        if b.gyro is None:
            return None
        for iv in intervals:                    # imucald's still interval: the residual bias
            if iv.gyro is not None and iv.gyro_cov is not None:
                ti = float(iv.temp) if np.isfinite(iv.temp) else None
                g = ap.apply_gyro(iv.gyro[None], ti, ap.apply_accel(iv.acc[None], ti))[0]
                f.still_interval(g, np.sqrt(np.diag(iv.gyro_cov)))
        rep = duplicated_rows(b.t, [b.acc, b.gyro, b.mag], self._orient_prev)   # replay: a logger's
        if isinstance(keep, slice):                                              # rows written twice
            return f.update(acc, gyro, mag, rep)
        A = ap.apply_accel(b.acc, tb)
        o = f.update(A, ap.apply_gyro(b.gyro, tb, A), None if b.mag is None else ap.apply_mag(b.mag, tb), rep)
        o["q"], o["lin_acc_g"] = o["q"][keep], o["lin_acc_g"][keep]
        if o["mag_disturbed"] is not None:
            o["mag_disturbed"] = o["mag_disturbed"][keep]
        return o

    # -- poses ------------------------------------------------------------------------
    def _pose(self, iv) -> None:
        if self.thermal_log.add(iv):
            self.persist("thermal", self.thermal_log.pose_set())
        what = self.acc.add(iv)
        if what == "rejected":
            return
        if np.isfinite(iv.temp):
            self.temp_range = [min(self.temp_range[0], iv.temp), max(self.temp_range[1], iv.temp)]
        if iv.continues and what == "refined":
            # the next piece of a rest already reported (cut at max_pose_s): its pose is refined
            # without a line (and a new hint) every max_pose_s while the board rests
            log.debug("the rest goes on: its pose refined by %.1f s more", iv.t1 - iv.t0)
        else:
            self._pose_line(iv, what)
        self.persist("poses", self.acc.pose_set())

    def _pose_line(self, iv, what: str) -> None:
        """The log line (and event) of a pose: its count, coverage and the next hint."""
        cov = self.acc.coverage()
        need = self.cfg["calibration"]["min_poses"]
        # the hint moves through the missing orientations (fitting/judging/coverage.py)
        self.next_hint = next_orientation(cov["missing"], self._hinted, iv.acc)
        if self.next_hint is not None:
            self._hinted[self.next_hint] = self._hinted.get(self.next_hint, 0) + 1
        nxt = f"; next: try {self.next_hint}" if self.next_hint else ""
        n = len(self.acc)
        count = f"{n}/{need}" if n <= need else f"{n} ({need} needed, reached)"
        msg = (f"pose {count} ({what}, {iv.t1 - iv.t0:.1f} s still): coverage "
               f"{cov['covered']}/{cov['targets']}{nxt}")
        log.info(msg)
        self.events.append(msg)

    # -- calibration ----------------------------------------------------------------------
    def ready_to_calibrate(self) -> Dict[str, Any]:
        c = self.cfg["calibration"]
        a = self.applied.accel
        sd = self.acc.predicted_std(a.theta if a is not None and a.model == "triangular9" else None)
        ok_n = len(self.acc) >= c["min_poses"]
        ok_u = sd is not None and bool(np.all(sd[6:9] <= c["target_bias_g"])) and \
            bool(np.all(sd[3:6] <= c["target_scale"]))
        return {"poses": ok_n, "uncertainty": ok_u,
                "predicted_bias_std_g": None if sd is None else sd[6:9].tolist(),
                "predicted_scale_std": None if sd is None else sd[3:6].tolist()}

    def request_calibration(self) -> bool:
        """Calibrate now with the poses there are (at least MIN_FIT_POSES; a board without
        an accelerometer: MIN_MAG_POINTS magnetometer points); True if started."""
        if not self.has_acc:
            if self.reservoir is None or len(self.reservoir.points()) < MIN_MAG_POINTS:
                return False
        elif len(self.acc) < MIN_FIT_POSES:
            return False
        self.force = True
        self.maybe_calibrate()
        return self.pending is not None

    def _mag_noise(self):
        """(per-sample noise (3,) or None under 20 readings, the latest readings (K, 3) in time
        order): a job's magnetometer noise and what fitting/magcal.py rotation_noise re-estimates
        it from when the turning inflated it."""
        from ..fitting.magcal import sample_noise
        series = np.array(self.mag_recent)
        return (sample_noise(series) if len(series) >= 20 else None), series

    def _maybe_calibrate_mag_only(self) -> None:
        c = self.cfg["calibration"]
        r = self.reservoir
        if not self.force:
            if r.coverage() < c["mag_min_coverage"] or r.seen < self._next_mag_seen:
                return
        if len(r.points()) < MIN_MAG_POINTS:
            return
        noise, series = self._mag_noise()
        if not self.force and noise is not None:
            from ..fitting.magcal import flat_axis
            flat = flat_axis(r.points(), noise)
            # not turned yet: wait, and say so once (a cloud that looks like one plane goes to
            # the job, whose noise the turning has not inflated: fitting/magcal.py rotation_noise)
            if flat is not None and flat["rank"] < 2:
                self._next_mag_seen = r.seen + int(MAG_RECAL_S * self.rate_hz)
                msg = "magnetometer: waiting for rotation (the readings hardly change)"
                if not self.events or self.events[-1] != msg:
                    log.info(msg)
                    self.events.append(msg)
                return
        self.force = False
        self._next_mag_seen = r.seen + int(MAG_RECAL_S * self.rate_hz)
        job = {"acc": None, "mag_points": r.points(), "mag_noise": noise, "mag_series": series,
               "holdout_fraction": c["holdout_fraction"], "alpha": c["false_accept_rate"],
               "seed": int(r.seen),
               "current": self.applied}
        self._job_poses = self.acc.pose_set()
        msg = (f"calibrating the magnetometer in the background on {len(job['mag_points'])} "
               f"points ({r.coverage():.0%} of the sphere)")
        log.info(msg)
        self.events.append(msg)
        self.pending = self.executor.submit(calibration_job, job)

    def _just_ready(self, r) -> bool:
        """A provisional calibration is in force and the pose set has just reached the poses
        needed (``r``: :meth:`ready_to_calibrate`), not fitted since: fit now, once, not at the
        next recalibrate_every_poses mark (the log has just said the poses needed are reached;
        a user may stop there).  Later fits keep that mark."""
        return self.applied.provisional is not None and bool(r["poses"]) and not self._ready_tried

    def _nothing_to_score(self, ready: bool) -> bool:
        """A periodic refit would have nothing to be judged on: every pose is one the
        calibration in force was fitted on (a tour back at its orientations refines its
        poses and adds none), so the gate could only say "not applied: no pose the current
        one was not fitted on".  Still refitted: a provisional calibration once the pose set
        is ready (refined poses can make it so; the fit confirms it), a gyro with no part in
        force (its gate scores against the raw readings on every pose, refined ones
        included), and a board with a magnetometer (its points may be new).  Says so in the
        log once."""
        if self.reservoir is not None or (self.applied.provisional is not None and ready):
            return False
        ps = self.acc.pose_set()
        if self.applied.gyro is None and ps.gyro is not None:
            return False
        fitted, _ = fitted_poses(ps.acc, ps.t0, ps.t1, self.applied.poses_used)
        if not (len(fitted) and fitted.all()):
            return False
        if not self._said_nothing_new:
            self._said_nothing_new = True
            msg = (f"no refit: all {len(ps)} poses are ones the calibration in force was fitted "
                   f"on (revisits refine them); the next new orientation starts one")
            log.info(msg)
            self.events.append(msg)
        return True

    def _fit_due(self, r, ready: bool, thermal_due: bool) -> bool:
        """Whether a fit starts now (``r``: :meth:`ready_to_calibrate`): when asked for
        (control socket) or the thermal span grew; on the raw sensor at every new pose until
        a calibration beats the raw readings significantly (applied as provisional while the
        pose set is not ready); else at each recalibrate_every_poses mark, or once at the
        poses needed, unless no pose is new to the calibration in force."""
        if self.force or thermal_due:
            return True
        if self.applied.accel is None:
            return self.acc.added > self._tried_raw_at
        if not ((ready or self.applied.provisional is not None) and
                self.acc.added >= self.next_cal_added) and not self._just_ready(r):
            return self._challenged()
        return not self._nothing_to_score(ready)

    def _challenged(self) -> bool:
        """A final calibration in force (loaded at start, or from an earlier session) that the
        poses it was not fitted on reject: fit now, before the pose set is ready, and let the
        gate judge.  It waited for the poses needed (25) while a calibration 28-120 mg off (the
        wrong board's file in the state directory) corrected every sample, and a shorter session
        saved it back untouched (a cold review: 20 of 20).  The test: the chi-square of those
        poses' |a| - 1 g under it, each over its pose mean's radial variance plus the calibration's
        own held-out RMS squared (its quality figure; conservative), at IN_FORCE_CHALLENGE_LEVEL.
        At most once per recalibrate_every_poses new poses, so a refused fit is not retried at
        every pose."""
        if self.applied.provisional is not None or len(self.acc) < MIN_FIT_POSES or \
                self.acc.added < getattr(self, "_challenge_at", 0):
            return False
        ps = self.acc.pose_set()
        fitted, _ = fitted_poses(ps.acc, ps.t0, ps.t1, self.applied.poses_used)
        new = ~fitted if len(fitted) else np.ones(len(ps), bool)
        if new.sum() < 3:
            return False
        p, rms_g, expected_g = in_force_check(self.applied, ps.acc[new], ps.acc_cov[new],
                                              None if _temps(ps.temp) is None else ps.temp[new])
        if not p < IN_FORCE_CHALLENGE_LEVEL:
            return False
        self._challenge_at = self.acc.added + self.cfg["calibration"]["recalibrate_every_poses"]
        need = self.cfg["calibration"]["min_poses"]
        when = f"before the {need} poses needed" if len(self.acc) < need else "before the next refit"
        msg = (f"the calibration in force disagrees with the {int(new.sum())} poses it was not fitted "
               f"on (|a| - 1 g RMS {rms_g * 1e3:.3g} mg where {expected_g * 1e3:.2g} mg is expected, "
               f"p = {p:.2g}): fitting now, {when}")
        log.info(msg)
        self.events.append(msg)
        return True

    def maybe_calibrate(self) -> None:
        if self.pending is not None:
            return
        if not self.has_acc:
            if self.reservoir is not None:
                self._maybe_calibrate_mag_only()
            return
        c = self.cfg["calibration"]
        span = self.thermal_log.span_c()
        thermal_due = (self.applied.accel is not None and span >= c["thermal_min_span_c"]
                       and span >= self._thermal_span_at + THERMAL_REFIT_GROWTH_C)
        # the readiness check (a CRLB) only changes when the pose set does (or a thermal
        # refit falls due: once, not at every batch while too few poses hold it back)
        key = (self.acc.added, len(self.acc), self.applied.id,
               self.thermal_log.seen if thermal_due else None)
        if not self.force and key == getattr(self, "_checked", None):
            return
        self._checked = key
        r = self.ready_to_calibrate()
        ready = r["poses"] and r["uncertainty"]
        if len(self.acc) < MIN_FIT_POSES or not self._fit_due(r, bool(ready), thermal_due):
            return
        self._said_nothing_new = False
        self._tried_raw_at = self.acc.added
        self._job_ready = bool(ready)
        if r["poses"]:
            self._ready_tried = True
        self._job_missing = self.acc.coverage()["missing"]
        ps = self.acc.pose_set()
        mag_noise, mag_series = self._mag_noise()
        mag_pts = mag_temp = None
        if self.reservoir is not None and self.reservoir.coverage() >= c["mag_min_coverage"]:
            mag_pts = self.reservoir.points()
            tg = self.reservoir.tags()
            mag_temp = None if np.any(tg < 0) else tg / 100.0 - 273.15
        k = None
        if self.noise is not None and "accel" in self.noise:
            # coloured noise: a pose mean over T s varies k(T) times more than white noise
            # says (fitting/noise/colour.py), k from the noise file's Allan coefficients; the
            # worker applies it where the holds' structure functions decide nothing
            from ..fitting.noise.colour import inflation_of
            k = np.array([inflation_of(self.noise["accel"]["avar_coef"], n / self.rate_hz)[0]
                          for n in ps.n])
        # tremor averages out of a pose mean, sway does not change its norm: the worker forms
        # the covariances from the holds' structure functions as calibrate does from its
        # samples (daemon/fitjob.py _pose_cov, fitting/noise/posecov.py)
        job = {"acc": ps.acc, "acc_cov": ps.acc_cov, "acc_colour_k": k,
               "acc_sf": [p.acc_sf or [] for p in self.acc.poses],
               "acc_radial_sf": [p.acc_radial_sf or [] for p in self.acc.poses],
               "acc_sample_cov": ps.acc_sample_cov,
               "t0": ps.t0, "t1": ps.t1, "n": ps.n,
               "temp": _temps(ps.temp),
               "gyro": ps.gyro, "mag_points": mag_pts, "mag_temp": mag_temp, "mag_noise": mag_noise,
               "mag_series": mag_series,
               "method": c["method"],
               "holdout_fraction": c["holdout_fraction"], "alpha": c["false_accept_rate"],
               "seed": int(self.acc.added),
               "current": self.applied,
               "thermal": self.thermal_log.arrays() if thermal_due else None,
               "thermal_min_span_c": c["thermal_min_span_c"]}
        if thermal_due:
            self._thermal_span_at = span
        self.force = False
        self.next_cal_added = self.acc.added + c["recalibrate_every_poses"]
        self._job_poses = ps
        msg = f"calibrating in the background on {len(ps)} poses ({c['method']})" + (
            f"; thermal terms on {len(self.thermal_log)} still intervals over {span:.1f} degC"
            if thermal_due else "")
        log.info(msg)
        self.events.append(msg)
        self.pending = self.executor.submit(calibration_job, job)

    def poll_calibration(self) -> bytes:
        f = self.pending
        if f is None or not f.done():
            return b""
        self.pending = None
        try:
            res = f.result()
        except Exception as e:          # a failed fit never takes the sampler down
            log.warning("calibration failed: %s", e)
            self.events.append(f"calibration failed: {e}")
            return b""
        return self._apply(res, self._job_poses)

    def _apply(self, res: JobResult, ps) -> bytes:
        """A finished job: the parts its gate accepted replace those in force (one new
        calibration, persisted), or nothing does; the CAL event says which and why."""
        cand = res.candidate
        take = {k: v for k, v in res.accept.items() if v}
        gates = res.notes.get("gate", {})
        undet = _undetermined(cand.accel) if "accel" in take else None
        blind = undet is not None and len(undet) == len(cand.accel.theta)
        if blind:
            # no parameter determined by the poses (one orientation, its means drifting with
            # the temperature: the real FreeIMU warm-up counted 25 'poses'): the gate's
            # held-out poses lie where the fit was made, so 'better' there says nothing
            del take["accel"]
        parts = self._outcome_texts(res, take, gates, undet)
        if blind:
            parts.insert(0, "accel not applied: the poses determine none of its parameters (too few "
                            "orientations): turn the board as the log says")
        # the gate's figures and reasons (fitting/gate.py Decision), in the CAL event too
        gate_ev = {k: d.to_dict() for k, d in gates.items()} or None
        if not take:
            return self._keep_applied(cand, gates, parts, gate_ev)
        out = [o["t0_s"] for o in res.notes.get("outlier_poses") or [] if "t0_s" in o]
        if out and ps is not None:       # poses the fit left out are none it was fitted on
            ps = ps.subset(~np.isin(np.round(ps.t0, 9), np.round(out, 9)))
        return self._take_parts(cand, take, gates, parts, gate_ev, undet, ps)

    def _outcome_texts(self, res: JobResult, take, gates, undet) -> List[str]:
        """One phrase per part of the job's outcome (the log line and the CAL reason); notes
        the thermal fits for status."""
        a, m = res.candidate.accel, res.candidate.mag
        parts = []
        out = res.notes.get("outlier_poses")
        if out:
            parts.append(f"{len(out)} pose(s) left out, |a| far from what the others' calibration predicts "
                         f"(" + ", ".join(f"{o['residual_g'] * 1e3:+.3g} mg" + (f" at {o['t0_s']:.1f} s" if "t0_s" in o
                                                                                    else "") for o in out[:4])
                         + f"): {OUTLIER_CAUSE}")
        if res.notes.get("stuck"):
            from ..fitting.inputs import stuck_message
            parts += [f"{s} not fitted: {stuck_message(c, 'pose')}" for s, c in res.notes["stuck"].items()]
        if a:
            parts.append(f"accel {gates['accel'].text(1e3, 'mg')} "
                         f"{'(applied)' if 'accel' in take else '(kept the current one)'}")
            if undet:
                parts.append("not determined by these poses, held near the datasheet prior: " +
                             ", ".join(f"{k} ({v})" for k, v in undet.items()))
        if "gyro" in gates:
            parts.append(f"gyro bias {'applied' if 'gyro' in take else 'kept'} "
                         f"({gates['gyro'].text(1.0, 'dps')})")
        for s, ent in res.notes.get("thermal", {}).items():
            self.thermal_notes[s] = ent
            parts.append(f"{s} thermal {ent['note'].split(':')[0]}" + (
                f" {'applied' if ent['accepted'] else 'kept the current one'} (p = {ent['p_value']:.2g})"
                if "p_value" in ent else ""))
        if "mag_flat" in res.notes:
            from ..fitting.magcal import flat_message
            parts.append("mag not determined: " + flat_message({"flat": res.notes["mag_flat"]}))
        elif "mag_undetermined" in res.notes:
            from ..fitting.magcal import flat_message
            parts.append("mag not determined: " + flat_message(res.notes["mag_undetermined"]))
        elif m:
            parts.append(f"mag held-out {m.quality['heldout_rel_rms'] * 100:.2f} % vs "
                         f"{m.quality['heldout_rel_rms_before'] * 100:.2f} % "
                         f"(p = {gates['mag'].p_value:.2g}) {'(applied)' if 'mag' in take else '(kept)'}")
        return parts

    def _keep_applied(self, cand: Calibration, gates, parts: List[str], gate_ev) -> bytes:
        """Nothing taken: the calibration in force stays."""
        ap = self.applied
        # a fit on a ready pose set did not replace the provisional one though scored
        # out of sample on the poses it was not fitted on: it has been checked against
        # the full set and stays, as final -- unless those poses disagree with it
        confirmed = bool(cand.accel) and self._job_ready and ap.provisional is not None and _confirms(gates)
        if confirmed:
            self.applied = ap.replace(provisional=None)
            self.persist("calibration", self.applied)
        msg = (f"calibration not applied, #{ap.id} stays" +
               (" and is no longer provisional" if confirmed else "") + ": " + "; ".join(parts))
        log.info(msg)
        self.events.append(msg)
        return event("CAL", self.fmt, id=ap.id, applied=False, reason=msg, gate=gate_ev)

    def _provisional_after(self, cand: Calibration, take, gates, parts: List[str], n_poses: int):
        """The new calibration's ``provisional`` entry: the accelerometer part came from a
        pose set short of the readiness targets (min_poses, predicted uncertainty); the
        orientations still missing are named."""
        ap = self.applied
        prov = ap.provisional
        if "accel" in take:
            prov = None if self._job_ready else {
                "poses": n_poses, "poses_for_final": self.cfg["calibration"]["min_poses"],
                "missing_orientations": list(self._job_missing)}
        elif cand.accel and self._job_ready and prov is not None and _confirms(gates):
            # as when nothing is taken: a fit on a ready pose set did no significantly
            # better, so the provisional accelerometer part stays, as final (the gyro or the
            # magnetometer part taken with it does not change that)
            prov = None
            parts.append(f"accel #{ap.id} is no longer provisional")
        return prov

    def _take_parts(self, cand: Calibration, take, gates, parts: List[str], gate_ev, undet, ps) -> bytes:
        """The accepted parts replace those in force: a new calibration, persisted."""
        ap = self.applied
        now = datetime.now(timezone.utc).isoformat(timespec="seconds")
        lo, hi = self.temp_range
        temp = ps.temp if ps.temp is not None else np.full(len(ps), np.nan)
        rows = np.column_stack([ps.acc, ps.n, temp, ps.t0, ps.t1]).round(7).tolist()
        prov = self._provisional_after(cand, take, gates, parts, len(ps))
        new = ap.replace(id=next_id(ap.id), created=now, provisional=prov,
                         temperature_range_c=(round(lo, 2), round(hi, 2)) if np.isfinite(lo) else None,
                         # the poses the accelerometer part in force was fitted on (fitting/gate.py
                         # scores it on the others): kept when only the gyro or mag part changes
                         poses_used=({"columns": POSE_COLUMNS, "rows": rows} if len(ps) else None)
                         if "accel" in take or ap.accel is None else ap.poses_used,
                         **{k: cand.part(k) for k in take})
        self.applied, self.applied_t_s = new, self.t_last
        self.persist("calibration", new)
        msg = (f"calibration #{new.id} applied{_provisional_text(prov, 'accel' in take)}{_partly(cand, take)}: "
               + "; ".join(parts))
        log.info(msg)
        self.events.append(msg)
        return event("CAL", self.fmt, id=new.id, applied=True, provisional=prov is not None,
                     missing_orientations=list(prov["missing_orientations"]) if prov else None,
                     undetermined=undet, **_cal_figures(cand, take), reason=msg, gate=gate_ev)

    # -- status ---------------------------------------------------------------------------
    def thermal_status(self) -> Dict[str, Any]:
        return thermal_status(self.thermal_log, self.applied, self.thermal_notes,
                              self.cfg["calibration"]["thermal_min_span_c"])

    def status(self) -> Dict[str, Any]:
        cov = self.acc.coverage()
        ap = self.applied
        d = {"poses": len(self.acc), "poses_needed": self.cfg["calibration"]["min_poses"],
             "coverage": cov["fraction"], "next_orientation": (self.next_hint if self.next_hint in cov["missing"] else
                                  next_orientation(cov["missing"], self._hinted)),
             "calibration_id": ap.id, "calibrating": self.pending is not None,
             "ready": self.ready_to_calibrate(), "samples": self.samples, "still": self.last_still}
        if ap.id:
            d["calibration_created"] = ap.created
            d["calibration_provisional"] = ap.provisional is not None
            if ap.provisional is not None:
                d["missing_orientations"] = list(ap.provisional["missing_orientations"])
        if self.reservoir is not None:
            d["mag_coverage"] = self.reservoir.coverage()
        d["thermal"] = self.thermal_status()
        d["orientation"] = "on" if self.orient is not None else "off"     # issue 26
        if self.orient is None:
            d["orientation_off"] = self.orientation_off
        else:
            d["orientation_resets"] = self.orient.resets
        # the still-pose detector: the rate it judges at (distinct samples), repeated rows
        # found, and the quiet stretches that did not make a pose, by reason (issue 20)
        det = self.det
        d["stillness"] = {"effective_rate_hz": round(det.rate, 3),
                          "repeats": None if det.repeats is None else (det.repeats.summary() or None),
                          "rejected": dict(det.rejected_counts),
                          "last_rejected": det.rejected[-1]["reason"] if det.rejected else None}
        if self.events:
            d["last_event"] = self.events[-1]
        return d


def _temps(t):
    """Pose temperatures, or None when any is unknown."""
    return None if t is None or not np.all(np.isfinite(t)) else t


def _confirms(gates) -> bool:
    """A refused accelerometer candidate on a ready pose set confirms the provisional part in
    force, unless the gate found the new poses at odds with it (fitting/gate.py rule 1)."""
    d = gates.get("accel")
    return not (d is not None and d.consistency_p is not None and not d.consistent)


def _partly(cand: Calibration, take) -> str:
    """' (gyro part; accel not applied)' when the job's fit had parts the gate kept out, else
    '': the log line's head then says what it applied (its parts' own phrases follow)."""
    out = [k for k in ("accel", "gyro", "mag") if cand.part(k) is not None and k not in take]
    if not out:
        return ""
    taken = [k for k in ("accel", "gyro", "mag") if k in take]
    return f" ({', '.join(taken)} part{'s' if len(taken) > 1 else ''}; {', '.join(out)} not applied)"


def _provisional_text(prov, accel_new: bool = True) -> str:
    """' as provisional (N poses of the M for a final one; missing orientations: ...)'; when
    the accelerometer part is the one in force (a gyro or magnetometer part applied alone),
    its figures are that part's, from when it was fitted, and the line says so (they read as
    poses lost: '15 poses' at pose 20, a newcomer's walk)."""
    if prov is None:
        return ""
    miss = prov["missing_orientations"]
    whose = "" if accel_new else "its accel part fitted on "
    gone = "missing orientations" if accel_new else "missing then"
    return (f" as provisional ({whose}{prov['poses']} poses of the {prov['poses_for_final']} for a final one" +
            (f"; {gone}: {', '.join(miss)})" if miss else ")"))


def _undetermined(part) -> Optional[Dict[str, str]]:
    """Parameter name -> flag (undetermined, at_bound...) for the accelerometer parameters
    the poses did not determine; None when every one is determined or none is flagged."""
    if part is None or not part.flags:
        return None
    from ..fitting.models.registry import get_model
    m = get_model(part.model)
    out = {m.param_names[i]: f for g, idx in m.groups.items()
           for i, f in zip(idx, part.flags.get(g, ())) if f != "determined"}
    return out or None


def _cal_figures(cand: Calibration, take) -> Dict[str, Any]:
    """The CAL event's held-out figures of the parts applied (``take``), None for a part not
    applied (omitted from the event): a gyro-only application reported the refused
    accelerometer candidate's held-out RMS as if it were in force (an independent probe: 10
    CAL events in 9 replays)."""
    q = cand.accel.quality if cand.accel and "accel" in take else {}
    m = cand.mag if "mag" in take else None
    return {"accel_heldout_rms_g": q.get("heldout_rms_g"),
            "accel_heldout_rms_before_g": q.get("heldout_rms_before_g"),
            "accel_predicted_heldout_rms_g": q.get("predicted_heldout_rms_g"),
            "mag_heldout_rel_rms": m.quality.get("heldout_rel_rms") if m else None}
