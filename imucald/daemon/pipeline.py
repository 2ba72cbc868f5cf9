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

from .accumulator import PoseAccumulator
from .calibrator import Applied, MagReservoir, calibration_job
from .outputs import encode_samples, event
from .stillness import StillnessDetector

__all__ = ["Pipeline", "InlineExecutor", "applied_from_doc"]

log = logging.getLogger("imucald")
#: fewest poses a forced calibration may use (9 parameters plus one degree of freedom)
MIN_FIT_POSES = 10
#: fresh magnetometer readings kept for the per-sample noise (second differences)
MAG_NOISE_SAMPLES = 2000
#: boards without an accelerometer: fewest reservoir points for a fit, and seconds of new
#: readings between calibrations
MIN_MAG_POINTS = 30
MAG_RECAL_S = 20.0


class InlineExecutor(Executor):
    """Runs jobs at submit time (replay: deterministic, as fast as possible)."""

    def submit(self, fn, *args, **kwargs):
        f: Future = Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except BaseException as e:          # reported through the future, like a pool
            f.set_exception(e)
        return f


def applied_from_doc(doc: Dict[str, Any]) -> Applied:
    a = doc.get("accel") or {}
    g = doc.get("gyro") or {}
    m = doc.get("mag") or {}
    return Applied(id=int(doc.get("id", 0)),
                   accel_theta=np.array(a["theta"], float) if a.get("theta") else None,
                   gyro_bias_dps=np.array(g["params"]["bias_dps"], float) if g.get("params") else None,
                   mag_theta=np.array(m["theta"], float) if m.get("theta") else None,
                   info={"created": doc.get("created")})


class Pipeline:
    def __init__(self, cfg: Dict[str, Dict[str, Any]], board: str, rate_hz: float, has_mag: bool,
                 executor: Optional[Executor] = None, persist: Optional[Callable] = None,
                 chips: Optional[Dict[str, str]] = None, has_acc: bool = True):
        self.cfg, self.board, self.rate_hz, self.has_mag = cfg, board, rate_hz, has_mag
        # without an accelerometer (gy273) there are no still poses: the magnetometer is
        # calibrated from its rotation cloud alone, as `imucald calibrate` does
        self.has_acc = has_acc
        self.mag_recent: Deque[np.ndarray] = deque(maxlen=MAG_NOISE_SAMPLES)
        self._next_mag_seen = 0
        st = cfg["stillness"]
        self.det = StillnessDetector(rate_hz, st["window_s"], st["k"], st["min_still_s"],
                                     st["max_pose_s"], st["trim_s"])
        self.acc = PoseAccumulator(cfg["poses"]["merge_angle_deg"], cfg["poses"]["max_poses"])
        self.applied = Applied()
        self.reservoir = MagReservoir() if has_mag else None
        self.executor = executor or InlineExecutor()
        self.persist = persist or (lambda kind, obj: None)
        self.chips = chips or {}
        self.fmt = cfg["output"]["format"]
        self.pending: Optional[Future] = None
        self.next_cal_added = 0
        self.force = False
        self.samples = 0
        self.last_still = False
        # bounded: a daemon runs for months and adds an event per pose
        self.history: Deque[Dict[str, Any]] = deque(maxlen=100)
        self.events: Deque[str] = deque(maxlen=100)     # human log lines for status
        self.cal_doc: Optional[Dict[str, Any]] = None
        self.t_last = 0.0
        self.temp_range = [np.inf, -np.inf]

    # -- the hot path -------------------------------------------------------------------
    def process(self, b) -> bytes:
        out: List[bytes] = []
        for s0, k in b.gaps:
            out.append(event("GAP", self.fmt, seq=int(s0), missing=int(k)))
        n = len(b.t)
        if n:
            still, intervals = self.det.update(b.t, b.acc, b.gyro, b.temp, b.mag, b.mag_fresh)
            self.samples += n
            self.t_last = float(b.t[-1])
            self.last_still = bool(still[-1])
            for iv in intervals:
                self._pose(iv)
            if self.reservoir is not None and b.mag_fresh is not None and b.mag_fresh.any():
                self.reservoir.add(b.mag[b.mag_fresh])
                self.mag_recent.extend(b.mag[b.mag_fresh])
            ap = self.applied
            mag = ap.mag(b.mag) if b.mag is not None else None
            dec = self.cfg["output"]["decimate"]
            if dec > 1:
                keep = (b.seq % dec) == 0
                out.append(encode_samples(self.fmt, b.seq[keep], b.t[keep], ap.accel(b.acc[keep]),
                                          ap.gyro(b.gyro[keep]), b.temp[keep],
                                          None if mag is None else mag[keep], still[keep], ap.id))
            else:
                out.append(encode_samples(self.fmt, b.seq, b.t, ap.accel(b.acc), ap.gyro(b.gyro),
                                          b.temp, mag, still, ap.id))
        out.append(self.poll_calibration())
        self.maybe_calibrate()
        out.append(self.poll_calibration())
        return b"".join(out)

    # -- poses ------------------------------------------------------------------------
    def _pose(self, iv) -> None:
        what = self.acc.add(iv)
        if what == "rejected":
            return
        if np.isfinite(iv.temp):
            self.temp_range = [min(self.temp_range[0], iv.temp), max(self.temp_range[1], iv.temp)]
        cov = self.acc.coverage()
        need = self.cfg["calibration"]["min_poses"]
        nxt = f"; next: try {cov['missing'][0]}" if cov["missing"] else ""
        msg = (f"pose {len(self.acc)}/{need} ({what}, {iv.t1 - iv.t0:.1f} s still): coverage "
               f"{cov['covered']}/{cov['targets']}{nxt}")
        log.info(msg)
        self.events.append(msg)
        self.persist("poses", self.acc.pose_set())

    # -- calibration ----------------------------------------------------------------------
    def ready_to_calibrate(self) -> Dict[str, Any]:
        c = self.cfg["calibration"]
        sd = self.acc.predicted_std(self.applied.accel_theta)
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
        from ..calib.magcal import sample_noise
        return sample_noise(np.array(self.mag_recent)) if len(self.mag_recent) >= 20 else None

    def _maybe_calibrate_mag_only(self) -> None:
        c = self.cfg["calibration"]
        r = self.reservoir
        if not self.force:
            if r.coverage() < c["mag_min_coverage"] or r.seen < self._next_mag_seen:
                return
        if len(r.points()) < MIN_MAG_POINTS:
            return
        noise = self._mag_noise()
        if not self.force and noise is not None:
            from ..calib.magcal import flat_axis
            flat = flat_axis(r.points(), noise)
            if flat is not None:       # not turned in 3-D yet: wait, and say so once
                self._next_mag_seen = r.seen + int(MAG_RECAL_S * self.rate_hz)
                msg = ("magnetometer: the rotation so far stays in one plane; tilt the sensor onto "
                       "another face and keep turning it" if flat["rank"] == 2 else
                       "magnetometer: waiting for rotation (the readings hardly change)")
                if not self.events or self.events[-1] != msg:
                    log.info(msg)
                    self.events.append(msg)
                return
        self.force = False
        self._next_mag_seen = r.seen + int(MAG_RECAL_S * self.rate_hz)
        ap = self.applied
        job = {"acc": None, "mag_points": r.points(), "mag_noise": noise,
               "holdout_fraction": c["holdout_fraction"], "seed": int(r.seen),
               "current": {"mag_theta": ap.mag_theta}}
        self._job_poses = self.acc.pose_set()
        msg = (f"calibrating the magnetometer in the background on {len(job['mag_points'])} "
               f"points ({r.coverage():.0%} of the sphere)")
        log.info(msg)
        self.events.append(msg)
        self.pending = self.executor.submit(calibration_job, job)

    def maybe_calibrate(self) -> None:
        if self.pending is not None:
            return
        if not self.has_acc:
            if self.reservoir is not None:
                self._maybe_calibrate_mag_only()
            return
        # the readiness check (a CRLB) only changes when the pose set does
        key = (self.acc.added, len(self.acc), self.applied.id)
        if not self.force and key == getattr(self, "_checked", None):
            return
        self._checked = key
        if self.force:                      # asked for (control socket): any fit-able pose set
            if len(self.acc) < MIN_FIT_POSES:
                return
        else:
            r = self.ready_to_calibrate()
            if not (r["poses"] and r["uncertainty"] and self.acc.added >= self.next_cal_added):
                return
        c = self.cfg["calibration"]
        ps = self.acc.pose_set()
        mag_pts = None
        if self.reservoir is not None and self.reservoir.coverage() >= c["mag_min_coverage"]:
            mag_pts = self.reservoir.points()
        ap = self.applied
        job = {"acc": ps.acc, "acc_cov": ps.acc_cov, "t0": ps.t0, "n": ps.n, "temp": ps.temp,
               "gyro": ps.gyro, "mag_points": mag_pts, "mag_noise": self._mag_noise(), "method": c["method"],
               "holdout_fraction": c["holdout_fraction"], "seed": int(self.acc.added),
               "current": {"accel_theta": ap.accel_theta, "gyro_bias_dps": ap.gyro_bias_dps,
                           "mag_theta": ap.mag_theta}}
        self.force = False
        self.next_cal_added = self.acc.added + c["recalibrate_every_poses"]
        self._job_poses = ps
        msg = f"calibrating in the background on {len(ps)} poses ({c['method']})"
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

    def _apply(self, res: Dict[str, Any], ps) -> bytes:
        ap = self.applied
        a, g, m = res.get("accel"), res.get("gyro"), res.get("mag")
        take_a = bool(a and a["accept"])
        take_g = bool(g and g["accept"])
        take_m = bool(m and m["accept"])
        parts = []
        if a:
            parts.append(f"accel held-out {a['heldout_rms_g'] * 1e3:.3f} mg vs "
                         f"{a['heldout_rms_before_g'] * 1e3:.3f} mg {'(applied)' if take_a else '(kept the current one)'}")
        if m and not m.get("determined", True):
            from ..calib.magcal import flat_message
            parts.append("mag not determined: " + flat_message(m))
        elif m:
            parts.append(f"mag held-out {m['heldout_rel_rms'] * 100:.2f} % vs "
                         f"{m['heldout_rel_rms_before'] * 100:.2f} % {'(applied)' if take_m else '(kept)'}")
        if not (take_a or take_g or take_m):
            msg = "calibration not applied: it validates no better than the current one: " + "; ".join(parts)
            log.info(msg)
            self.events.append(msg)
            self.history.append({"applied": False, **_summary(res)})
            return event("CAL", self.fmt, id=ap.id, applied=False)
        new = Applied(id=ap.id + 1,
                      accel_theta=np.array(a["theta"]) if take_a else ap.accel_theta,
                      gyro_bias_dps=np.array(g["bias_dps"]) if take_g else ap.gyro_bias_dps,
                      mag_theta=np.array(m["theta"]) if take_m else ap.mag_theta)
        now = datetime.now(timezone.utc).isoformat(timespec="seconds")
        new.info = {"created": now, "created_t_s": self.t_last}
        self.applied = new
        doc = self.calibration_doc(res, ps, take_a, take_g, take_m, now)
        self.cal_doc = doc
        self.persist("calibration", doc)
        msg = f"calibration #{new.id} applied: " + "; ".join(parts)
        log.info(msg)
        self.events.append(msg)
        self.history.append({"applied": True, "id": new.id, **_summary(res)})
        return event("CAL", self.fmt, id=new.id, applied=True,
                     accel_heldout_rms_g=a["heldout_rms_g"] if a else None,
                     accel_heldout_rms_before_g=a["heldout_rms_before_g"] if a else None,
                     accel_predicted_heldout_rms_g=a["predicted_heldout_rms_g"] if a else None,
                     mag_heldout_rel_rms=m.get("heldout_rel_rms") if m else None)

    def calibration_doc(self, res, ps, take_a, take_g, take_m, now) -> Dict[str, Any]:
        """The persisted calibration (YAML): parameters under the names `imucald
        calibrate --json` uses, with units, identity, temperature range and quality."""
        prev = self.cal_doc or {}
        doc: Dict[str, Any] = {
            "id": self.applied.id, "created": now, "board": self.board, "chips": self.chips,
            "units": {"accel": "g", "gyro": "deg/s", "mag": "gauss", "temperature": "degC",
                      "time": "s"},
            "temperature_range_c": None if not np.isfinite(self.temp_range[0]) else
            [round(self.temp_range[0], 2), round(self.temp_range[1], 2)],
        }
        a, g, m = res.get("accel"), res.get("gyro"), res.get("mag")
        if take_a:
            doc["accel"] = {"model": "triangular9", "method": self.cfg["calibration"]["method"],
                            "params": a["params"], "stderr": a["stderr"], "theta": a["theta"],
                            "fitness": a["fitness"], "rms_g": a["rms_g"], "loo_rms_g": a["loo_rms_g"],
                            "heldout_rms_g": a["heldout_rms_g"],
                            "heldout_rms_before_g": a["heldout_rms_before_g"],
                            "predicted_heldout_rms_g": a["predicted_heldout_rms_g"],
                            "crlb_std": a["crlb_std"], "poses": a["train_poses"] + a["heldout_poses"],
                            "heldout_poses": a["heldout_poses"], "noise_g": a["noise_g"]}
        elif "accel" in prev:
            doc["accel"] = prev["accel"]
        if take_g:
            doc["gyro"] = {"model": "bias", "params": {"bias_dps": g["bias_dps"]},
                           "stderr": {"bias_dps": g["stderr_dps"]}, "heldout_rms_dps": g["heldout_rms_dps"]}
        elif "gyro" in prev:
            doc["gyro"] = prev["gyro"]
        if take_m:
            doc["mag"] = {"model": "mag_sym", "params": m["params"], "stderr": m["stderr"],
                          "theta": m["theta"], "points": m["points"], "coverage": m["coverage"],
                          "heldout_rel_rms": m["heldout_rel_rms"]}
        elif "mag" in prev:
            doc["mag"] = prev["mag"]
        doc["poses_used"] = {"columns": ["ax_g", "ay_g", "az_g", "n", "temp_c", "t0_s", "t1_s"],
                             "rows": np.column_stack([ps.acc, ps.n, ps.temp, ps.t0, ps.t1]).round(7).tolist()}
        return doc

    # -- status ---------------------------------------------------------------------------
    def status(self) -> Dict[str, Any]:
        cov = self.acc.coverage()
        ap = self.applied
        d = {"poses": len(self.acc), "poses_needed": self.cfg["calibration"]["min_poses"],
             "coverage": cov["fraction"], "next_orientation": cov["missing"][0] if cov["missing"] else None,
             "calibration_id": ap.id, "calibrating": self.pending is not None,
             "ready": self.ready_to_calibrate(), "samples": self.samples, "still": self.last_still}
        if ap.id:
            d["calibration_created"] = ap.info.get("created")
        if self.reservoir is not None:
            d["mag_coverage"] = self.reservoir.coverage()
        if self.events:
            d["last_event"] = self.events[-1]
        return d


def _summary(res):
    a = res.get("accel") or {}
    return {"accel_heldout_rms_g": a.get("heldout_rms_g"),
            "accel_heldout_rms_before_g": a.get("heldout_rms_before_g")}
