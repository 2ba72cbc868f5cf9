"""Sim-to-real gap diagnosis: where real data leaves the sensor model, which
unmodelled effect causes it, and how far the gap shrinks once it is modelled.

Method (../shared/reference/error-models.md sections 3-5):

1. **Twin.**  Still poses are segmented with the calibration's detector; the
   baseline model is fitted by weighted least squares; the noise is measured in
   the data: per-pose within-pose variance, combined robustly (median over
   poses; a pose whose own variance is far above it is flagged as disturbed and
   left out), inflated by the Allan deviation at the pose length when a long
   still stretch shows coloured noise.  The twin re-simulates the same poses
   ``sims`` times with that noise and refits (linearised), giving the held-out
   residual the model predicts.
2. **Gap.**  Held-out residuals (leave-one-pose-out, by leverage) of the real
   data over the twin's median: ``ratio`` is about 1 when the model is adequate;
   a chi-square test on the normalised residuals gives the p-value.
3. **Where.**  Excess residual by orientation region, temperature and time bins;
   trend tests against temperature, time, each axis squared, and the previous pose.
4. **Which effect.**  Every candidate's signature (its Jacobian columns,
   projected off what the baseline absorbs) is score-tested from the single
   baseline fit; significant candidates are refitted (nested test), judged by
   the held-out ratio; on the norm paths a forward and backward search over
   combinations (the random walk a member too) names every member whose
   coefficients and held-out shrink are both significant (:mod:`.search`);
   candidates whose projected signatures coincide are reported as one class,
   with the recording that would separate them.
5. **Shrink**: ratio before and after, the effect's parameters and uncertainty.
6. **Verdict** per sensor (:mod:`.verdict`, one rule): ``none``, the effect(s),
   ``partially_explained`` or ``unexplained``.  Fewer than 10 poses or 6 orientations:
   the time-series path (:mod:`.single`, :mod:`.series`).

Modules: ``candidates`` (the effects), :mod:`imucald.fitting.judging.heldout` (fitting kernels,
twin), ``posenoise`` (the pose means' noise, disturbed poses), ``signif`` and
:mod:`imucald.numerics.tails` (tests and distributions), :mod:`imucald.fitting.judging.levels`
(the significance levels), ``verdict`` (one verdict for every path), ``norm`` and ``linear`` (the
accelerometer/magnetometer and gyro paths), ``where``, ``saturation``; this module only
segments the recording, measures the noise and calls them (:func:`pose_setup`, then one
step per sensor).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..fitting.judging.coverage import cube_coverage
from ..fitting.fit import accel_prior
from ..fitting.models.accel import Triangular9
from ..fitting.noise.colour import MIN_STRETCH_S, allan_model, colour_inflation
from ..fitting.solvers.lsq import Problem, lm
from ..fitting.stillness.poses import PoseSet, detect_static, poses_from_slices
from ..fitting.inputs import stuck_columns, stuck_message
from ..errors import UserError
from ..files.recording import Recording
from ..specs import BOARDS, MAG, recording_chips
from .candidates import ACCEL_CANDIDATES, GYRO_CANDIDATES, MAG_CANDIDATES, hat_columns
from .gyrostill import split_at_time_gaps, trim_turns
from .linear import gyro_diag
from .magpath import diagnosable, mag_model, mag_points, mag_still_slices, quiet_noise
from .norm import norm_diag
from .posenoise import flag_disturbed, flicker_between_poses, pose_mean_variance
from ..fitting.noise.posefloor import (
    estimate_lsb, pose_quantisation_floor, radial_series, run_effective_counts, sway_rotation_variance,
    tilt_wander_test
)
from .saturation import saturated
from .search import PAIR_ENTRY_MIN_DOF
from ..fitting.judging.coverage import orientation_groups
from .series import within_pose_inflation
from .single import diagnose_single

__all__ = ["diagnose", "GapError", "ACCEL_CANDIDATES", "GYRO_CANDIDATES", "MAG_CANDIDATES"]

MIN_POSES = 10          #: below, the time-series path (or an error)
FULL_POSES = 15         #: below, the reduced power is stated
#: below, the richest accelerometer pair the search can name, a nonlinearity in its general
#: form and a linear thermal bias, cannot enter beside the 9 baseline parameters (it must
#: leave PAIR_ENTRY_MIN_DOF residual degrees of freedom): said, with what it costs
_NL_TERMS = max(c.q for c in ACCEL_CANDIDATES if c.name == "nonlinearity")
_TB_TERMS = min(c.q for c in ACCEL_CANDIDATES if c.name == "thermal_bias")
PAIR_POSES = Triangular9().k + _NL_TERMS + _TB_TERMS + PAIR_ENTRY_MIN_DOF
MIN_ORIENTATIONS = 6    #: distinct gravity directions (20 deg apart) the 9-parameter fit needs
#: a temperature span below this (degC) is flat: no thermal candidate is tested over it, and a
#: still stretch that flat gives the noise's colour (noise_stretch)
FLAT_TEMP_C = 0.5


class GapError(UserError):
    pass


def _series_path(rec, sl, ps, sensors, sims, rng, name, n_orient) -> Dict[str, object]:
    """Few poses or few orientations: gyro and accelerometer from still stretches split in time."""
    N = len(ps)
    have = {"accel": rec.acc, "gyro": rec.gyro}
    res = diagnose_single(rec.t, sl, ps.acc, {s: have[s] for s in sensors if s in have and have[s] is not None},
                          rec.temp, sims, rng) if N else {}
    ok = {k: v for k, v in res.items() if v.get("verdict") is not None}
    why = "; ".join([f"{k}: {v['error']}" for k, v in res.items() if v.get("verdict") is None]
                    + [f"{k}: not diagnosed: no still stretch" for k in sensors
                       if k in have and have[k] is not None and k not in res])
    notes = [f"{N} still pose(s) in {n_orient} orientation(s): diagnosed from still stretches split in time "
             f"(the pose diagnosis needs {MIN_POSES} poses in {MIN_ORIENTATIONS}+ orientations)" if N else
             "no still pose: only what needs none (the magnetometer's rotation) is diagnosed"]
    if why:
        notes.append(why)
    # the magnetometer from its rotation points needs no still pose: diagnosed before the
    # error for too few poses (gap --sensor mag on a hand tumble logged with the
    # accelerometer was refused for its "0 still poses")
    if "mag" in sensors and rec.mag is not None:
        use_temp = rec.temp is not None and np.all(np.isfinite(rec.temp)) and np.ptp(rec.temp) >= 0.5
        skip = {} if use_temp else {"thermal_bias": "no temperature", "thermal_scale": "no temperature"}
        m = _mag(rec, sl, None, None, [], None, skip, sims, rng, _chip_mag_noise(rec))
        if m.get("verdict") is None:
            notes.append(f"mag: not diagnosed: {m['error']}")
            why = "; ".join(w for w in (why, f"mag: {m['error']}") if w)
        else:
            ok["mag"] = m
    if not ok:
        norm = np.linalg.norm(ps.acc, axis=1)
        up = ps.acc[(norm > 0.5) & (norm < 1.5)]             # poses under 1 g (raw)
        miss = cube_coverage(up / np.linalg.norm(up, axis=1, keepdims=True))["missing"][:6]
        more = (f"{MIN_POSES - N} more" if N < MIN_POSES else
                f"{max(MIN_ORIENTATIONS - n_orient, 1)} more orientation(s)")
        raise GapError(f"{name}: {N} still poses found in {n_orient} orientation(s); the diagnosis needs at "
                       f"least {MIN_POSES} in {MIN_ORIENTATIONS} or more orientations (25-30 recommended): "
                       f"{more}, e.g. {', '.join(miss)}; or one still stretch of "
                       f"several minutes for the time-series diagnosis" + (f" ({why})" if why else ""))
    return {"sensors": ok, "poses_found": N, "orientations": n_orient, "mode": "time_series",
            "poses_left_out": [], "notes": notes}


def _allan_compare(r, x_still, rate, unit) -> None:
    """A random-walk wandering bias's intensity beside the Allan figures of the longest still
    stretch (rate random walk: AVAR = q tau / 3, IEEE Std 952-1997 annex C), when it is long
    enough (fitting.noise.colour.MIN_STRETCH_S)."""
    ent = next((e for e in r.get("effects", []) if e.get("stochastic")), None)
    if ent is None:
        return
    if x_still is None or len(x_still) / rate < MIN_STRETCH_S:
        ent["random_walk"]["allan"] = (f"no still stretch of {MIN_STRETCH_S:.0f} s: the chip's random-walk "
                                       f"term is not measured here")
        return
    c = allan_model(x_still, rate)[:, 2]
    q_allan = (3 * c).tolist()
    q = ent["params"][next(iter(ent["params"]))][0]
    ent["random_walk"]["allan"] = {f"still_stretch_intensity_{unit}^2/s": q_allan,
                                   "stretch_s": round(len(x_still) / rate, 1),
                                   "walk_over_allan": (q / max(float(np.mean(q_allan)), 1e-300))}


def _chip_mag_noise(rec) -> Optional[float]:
    """The magnetometer's datasheet per-sample noise, gauss (None for an unknown chip)."""
    chip = recording_chips(rec.meta).get("mag")
    return MAG[chip].noise_gauss if chip in MAG else None


def _mag_only(rec, sims, rng, name) -> Dict[str, object]:
    """A magnetometer-only recording (issue 20): still stretches found from the magnetometer
    itself, its noise from the quiet windows (free of the motion), the rotation points and
    the still means against the deployed hard + soft iron model; no orientation regressor."""
    chip_noise = _chip_mag_noise(rec)
    m = rec.mag
    qn = quiet_noise(m, rec.rate_hz, chip_noise)
    sl = mag_still_slices(rec.t, m, rec.rate_hz, qn["sigma"])
    notes = ["no accelerometer: still stretches found from the magnetometer; orientation "
             "interference is not tested (it needs the specific force)"]
    skip: Dict[str, str] = {"orientation_interference": "no accelerometer"}
    use_temp = rec.temp is not None and np.all(np.isfinite(rec.temp)) and np.ptp(rec.temp) >= 0.5
    if not use_temp:
        skip.update({"thermal_bias": "no temperature", "thermal_scale": "no temperature"})
        notes.append("no temperature column (or flat): temperature effects were skipped")
    pm = np.array([m[s].mean(0) for s in sl]) if sl else None
    n = np.array([s.stop - s.start for s in sl], float)
    pv = float(np.mean(qn["sigma"] ** 2)) / n if sl else None
    r = _mag(rec, sl, pm, pv, list(range(len(sl))), None, skip, sims, rng, chip_noise)
    if r.get("verdict") is None:
        raise GapError(f"{name}: magnetometer-only recording not diagnosable: {r['error']}")
    r["points"]["quiet_noise"] = {k: v for k, v in qn.items() if k != "quiet_slices"}
    r["points"]["quiet_noise"]["sigma"] = np.round(qn["sigma"], 6).tolist()
    if "measured_sigma" in qn:
        r["points"]["quiet_noise"]["measured_sigma"] = np.round(qn["measured_sigma"], 6).tolist()
    return {"sensors": {"mag": r}, "poses_found": len(sl), "mode": "magnetometer_only",
            "poses_left_out": [], "notes": notes}


def _mag(rec, sl, pose_mag, pose_var, pose_idx, acc_theta, skip, sims, rng,
         chip_noise=None) -> Dict[str, object]:
    """The magnetometer against the deployed hard + soft iron model (gap/magpath.py)."""
    x, var, ctx, info = mag_points(rec, sl, pose_mag, pose_var, pose_idx, acc_theta, "thermal_bias" not in skip,
                                   chip_noise)
    why = diagnosable(x, var)
    if why:
        return {"verdict": None, "error": why, **info}
    r = norm_diag(x, ctx, var, mag_model(), MAG_CANDIDATES, sims, rng, skip, "gauss", scale=info["field_gauss"])
    r["points"] = info
    if info.get("rails_left_out"):
        r["note"] = "; ".join(x for x in (r.get("note"), "samples on a rail left out (clipping or an overflow "
                                          "code: " + ", ".join(f"{x['axis']} at {x['value']:+.6g} ({x['samples']})"
                                                               for x in info["rails_left_out"]) + ")") if x)
    r["baseline"] = ("the deployed hard + soft iron model (mag_sym, as the daemon and calibrate fit it) on "
                     "the still poses' means and the rotation thinned over the sphere")
    return r


def distinct_samples(rec: Recording) -> Recording:
    """The recording without its repeated rows (sample-and-hold, duplicated rows: issue 20,
    :mod:`imucald.fitting.stillness.repeats`), at the effective rate: noise and block statistics need
    distinct samples.  Unchanged when none is repeated."""
    from ..fitting.stillness.repeats import find_repeats
    ref = rec.acc if rec.acc is not None else rec.mag
    if ref is None or len(rec.t) < 4:
        return rec
    rep = find_repeats(rec.t, ref, rec.rate_hz)
    if not rep.repeated:
        return rec
    k = rep.keep
    pick = lambda a: None if a is None else np.asarray(a)[k]
    return Recording(t=rec.t[k], acc=pick(rec.acc), gyro=pick(rec.gyro), mag=pick(rec.mag),
                     temp=pick(rec.temp), meta=dict(rec.meta, rate_hz=f"{rep.rate_hz:.6g}"))


def _dead_columns(rec: Recording, sensors: Sequence[str], name: str, notes: List[str]) -> List[str]:
    """The sensors left to diagnose once those with a column that holds one value in every
    sample (fitting/inputs.stuck_columns: a dead or stuck axis, a column mapped to nothing) are
    set aside, each with a note naming its column; a GapError when none is left.  Such a
    column has no noise to build a twin from (its pose means' variance is 0: the fit's weights
    divided by zero raised a bare LinAlgError) and no calibration to diagnose."""
    left, why = [], []
    for s in sensors:
        dead = stuck_columns({"accel": rec.acc, "gyro": rec.gyro, "mag": rec.mag}[s], s)
        if dead:
            msg = f"{s}: {stuck_message(dead)}"
            why.append(msg)
            notes.append(msg + f"; {s} not diagnosed")
        else:
            left.append(s)
    if not left:
        raise GapError(f"{name}: {'; '.join(why)}: nothing left to diagnose")
    return left


def _sensors_asked(rec: Recording, sensors: Optional[Sequence[str]], name: str) -> List[str]:
    """The sensors to diagnose: the ones asked for (each must be in the recording) or all present."""
    avail = [s for s, a in (("accel", rec.acc), ("gyro", rec.gyro), ("mag", rec.mag)) if a is not None]
    sensors = list(sensors or avail)
    for s in sensors:
        if s not in avail:
            raise GapError(f"{name}: --sensor {s}: the recording has no {s} columns")
    return sensors


@dataclass
class PoseSetup:
    """The still poses of a recording with enough of them, and what every sensor's step shares."""
    sl: List[slice]                #: still stretches (sample slices)
    ps: PoseSet                    #: their pose averages
    keep: np.ndarray               #: poses used (not disturbed, not saturated)
    bad: np.ndarray                #: poses flagged disturbed or saturated
    sat: np.ndarray                #: poses with saturated samples
    skip: Dict[str, str]           #: candidates skipped, with the reason
    ctx_all: Dict[str, np.ndarray]  #: regressors per pose (time, temperature...)
    T_pose: float                  #: median pose length, s
    longest: Optional[slice]       #: the longest still stretch
    notes: List[str]
    _acc_theta: Optional[np.ndarray] = None

    def accel_theta(self) -> np.ndarray:
        """triangular9 fitted (LM, no prior) to the kept poses' accelerometer means: what the
        gyro step's g-sensitivity regressor and the magnetometer step's pairing calibrate the
        accelerometer with; fitted once for both (each step fitted it again before)."""
        if self._acc_theta is None:
            self._acc_theta = lm(Problem(Triangular9(), self.ps.acc[self.keep])).theta
        return self._acc_theta

    @property
    def ctx(self) -> Dict[str, np.ndarray]:
        """The regressors of the poses kept."""
        return {k: v[self.keep] for k, v in self.ctx_all.items()}

    def kept(self, slices: Sequence[slice]) -> List[slice]:
        return [s_ for s_, k_ in zip(slices, self.keep) if k_]


def _pair_note(u: PoseSetup, verdict: str) -> None:
    """A gap on the accelerometer found on fewer than PAIR_POSES kept poses with temperature,
    and not named as a nonlinearity with a thermal bias: say that this pair in its general form
    could not enter the search together there (its simpler variants could, step by step).  The
    figures were measured on tests/blindgen2.py pair_nl_thermal, seeds 0-59, with
    PAIR_ENTRY_MIN_DOF = 6 (docs/methods/gap.md)."""
    n_kept = int(u.keep.sum())
    named = set(verdict.split("+"))
    if n_kept >= PAIR_POSES or "thermal_bias" in u.skip or verdict == "none" \
            or {"nonlinearity", "thermal_bias"} <= named:
        return
    u.notes.append(f"accel: {n_kept} poses: a nonlinearity in its general form ({_NL_TERMS} terms) and a "
                   f"thermal bias cannot enter the search together below {PAIR_POSES} poses (they must "
                   f"leave {PAIR_ENTRY_MIN_DOF} residual degrees of freedom beside the baseline's "
                   f"{Triangular9().k}); their simpler forms can, one at a time, and a wandering bias named "
                   f"beside one of them may stand for the other (such pairs were named in 26 of 30 blind "
                   f"recordings of 22-27 poses, 30 of 30 of 28-35)")


def pose_setup(rec: Recording, sl: List[slice], ps: PoseSet) -> PoseSetup:
    """Disturbed and saturated poses, the temperature candidates' fate and the regressors."""
    N, rate = len(ps), rec.rate_hz
    notes: List[str] = []
    if N < FULL_POSES:
        notes.append(f"{N} still poses: the diagnosis runs from {MIN_POSES}, with less power than with "
                     f"{FULL_POSES} or more (25-30 recommended); a small effect may go unseen")
    # saturation (E10: not a model term): samples at the range limit bias a pose mean
    sat = saturated(rec, sl)
    # robust noise and disturbed poses (accelerometer)
    s2 = np.einsum("nii->n", ps.acc_sample_cov) / 3
    bad = flag_disturbed(s2, ps.n) | sat
    keep = ~bad
    if keep.sum() < MIN_POSES:
        keep = np.ones(N, bool)
        notes.append("many poses look disturbed; none were left out")
    temp = ps.temp
    skip: Dict[str, str] = {}
    if temp is None or not np.all(np.isfinite(temp)):
        skip = {"thermal_bias": "no temperature", "thermal_scale": "no temperature"}
        notes.append("no temperature column: temperature effects were skipped")
    elif np.ptp(temp) < FLAT_TEMP_C:
        skip = {"thermal_bias": "flat temperature", "thermal_scale": "flat temperature"}
        notes.append(f"temperature varied by only {np.ptp(temp):.2f} C: temperature effects were skipped")
    tmid = 0.5 * (ps.t0 + ps.t1)
    # hold_s: each pose's hold, over which its mean averages a wandering bias (gap/wander.py)
    ctx_all = {"t": tmid - tmid.min(), "dt": tmid - tmid.mean(), **hat_columns(tmid), "hold_s": ps.t1 - ps.t0}
    if not skip:
        ctx_all["temp"] = temp
        ctx_all["dT"] = temp - temp.mean()
    T_pose = float(np.median(ps.n[keep]) / rate)
    return PoseSetup(sl, ps, keep, bad, sat, skip, ctx_all, T_pose, noise_stretch(rec, sl), notes)


def noise_stretch(rec: Recording, sl: List[slice]) -> Optional[slice]:
    """The still stretch the noise's colour (Allan deviation) is read from: the longest over
    which the temperature held within FLAT_TEMP_C, else the longest.  A warm-up's stretch
    drifts with the temperature, the effect under diagnosis: 10 minutes warming on the table
    before a tour made every hold's gyro variance 4-9x and hid the gyro's thermal drift (an
    independent probe's warm-up tours: "none" in 6 of 8, ratio 0.09-0.16)."""
    if not sl:
        return None
    span = lambda s: s.stop - s.start
    if rec.temp is not None:
        held = lambda s: np.isfinite(rec.temp[s]).any() and \
            np.nanmax(rec.temp[s]) - np.nanmin(rec.temp[s]) < FLAT_TEMP_C
        flat = [s for s in sl if held(s)]
        if flat:
            return max(flat, key=span)
    return max(sl, key=span)


def _accel_pose_noise(rec: Recording, u: PoseSetup, kept, x_a: np.ndarray, tilt) -> Tuple[np.ndarray, dict]:
    """The variance of each accelerometer pose mean along its direction (what the norm
    model sees), and the noise-colour report: ``x_a`` the samples (per axis, or the radial
    series under tilt wander), ``kept`` the poses' still rows."""
    rate, ps, keep, longest = rec.rate_hz, u.ps, u.keep, u.longest
    xl = None if longest is None else rec.acc[longest]
    if tilt["wander"] and xl is not None:
        xl = radial_series(xl, [slice(0, len(xl))])
    kap, colour = colour_inflation(xl, rate, u.T_pose)
    # colour measured inside the poses too (short holds have no long stretch), on the radial
    # component whatever the tilt test says: the norm model sees that one, and a sway too
    # small for the test is slow and tangential; read per axis it was colour (inflation
    # 2.6-3.9, twin ratio 0.28-0.39 on 5 of 10 simulated swaying hand-held nulls; radial
    # 1.0 and 0.53-0.68).  One column scatters more than the mean of three (the cost:
    # docs/methods/gap.md).  The longest stretch is one direction, and its three axes stand
    # for all the poses' directions: kap below is the larger of that per-axis figure and
    # this radial one
    x_r = x_a if tilt["wander"] else radial_series(rec.acc, kept)
    wp = within_pose_inflation(x_r, kept)
    kap = max(kap, wp["inflation"])
    colour = dict(colour or {}, within_pose=wp)
    # the pose means' variance from within-pose statistics (gap/posenoise.py): below the
    # white figure under hand tremor; the colour inflation applies to the white axes
    # under tilt wander x_a is the radial series itself: one two-sided reading serves both
    # (its "below white" is the one-sided reading's; "above white" is used below)
    pmv, pinfo = pose_mean_variance(x_a, kept, two_sided=tilt["wander"])
    rv, rinfo = pmv, pinfo
    white_ax = ~np.asarray(pinfo.get("axes_below_white", [False] * x_a.shape[1]))
    if tilt["wander"]:
        # the radial component holds no rotation tremor (tangential): its pose means keep the
        # white figure (the structure function's bounded part, from one column, read white
        # radial noise as half of it on simulated swaying nulls: 5 of 40 called a gap)
        white_ax[:] = True
        n_k = np.asarray(ps.n[keep], float)
        s2r = np.median([x_a[s_, 0].var(ddof=1) for s_ in kept if s_.stop - s_.start > 1])
        pmv = (s2r / n_k)[:, None]
        pinfo["radial_white"] = "the radial pose means keep the white figure"
    pv = np.mean(pmv * np.where(white_ax, kap, 1.0)[None, :], axis=1)
    # colour clearly above the white figure, read on the radial series too (its structure
    # function, two-sided): slow-correlated noise (an AR(1) of 0.1-2 s, 1/f) that the
    # within-pose inflation under-reads in short holds (a cold review's 300 coloured nulls:
    # 118 false alarms, now 68; its 30 white ones none either way); read per axis, a sway
    # passed for such colour (simulated swaying hand-held nulls: twin ratio 0.68 -> 0.35)
    if not tilt["wander"]:
        rv, rinfo = pose_mean_variance(x_r, kept, two_sided=True)
    if rinfo.get("axes_above_white", [False])[0]:
        pv = np.maximum(pv, rv[:, 0])
        pinfo["radial_above_white"] = {"ratio_to_white": rinfo["ratio_to_white"][0],
                                       "ratio_stderr": rinfo["ratio_stderr"][0]}
    pinfo["tilt_wander"] = tilt
    # the quantisation floor of each pose mean (does not average down without dither)
    qf, qinfo = pose_quantisation_floor(rec.acc, kept)
    up = ps.acc[keep] / np.linalg.norm(ps.acc[keep], axis=1, keepdims=True)
    pv = pv + up ** 2 @ qf
    pinfo["quantisation"] = qinfo
    colour["pose_mean_variance"] = pinfo
    return pv, colour


def _accel_step(rec: Recording, u: PoseSetup, sims, rng) -> Dict[str, object]:
    """The accelerometer against the deployed triangular9 MAP fit (gap/norm.py)."""
    rate, ps, keep, longest = rec.rate_hz, u.ps, u.keep, u.longest
    # the noise the norm model |a| = 1 g sees is radial (along each pose's mean direction): a
    # swaying hand's tilt wander is tangential and inflates the per-axis figure (twin ratio
    # 0.48 on simulated swaying nulls); without wander the three axes estimate the same
    # noise with less scatter (the radial figure alone: 3 of 20 hand-held nulls called a
    # gap against 1 of 20).  The radial figure is used when the tangential per-sample
    # variance exceeds the radial one beyond 2 standard errors over poses (fitting/noise/posefloor.py)
    kept = u.kept(u.sl)
    tilt = tilt_wander_test(rec.acc, kept)
    x_a = rec.acc
    if tilt["wander"]:
        # the radial noise from the poses without their turning ends (the gyro's cut,
        # gap/gyrostill.py), as the gyro's: a turn's last degrees are not noise
        if rec.gyro is not None:
            kept = u.kept(trim_turns(rec.gyro, u.sl, rate)[0])
        x_a = radial_series(rec.acc, kept)
    pv, colour = _accel_pose_noise(rec, u, kept, x_a, tilt)
    # the deployed fit: triangular9 with the datasheet prior (MAP), as `calibrate` fits it
    chip = BOARDS.get(rec.meta.get("board", ""), (None,))[0]
    r = norm_diag(ps.acc[keep], u.ctx, pv, Triangular9(), ACCEL_CANDIDATES, sims, rng,
                  u.skip, "g", prior=accel_prior(Triangular9(), chip))
    r["baseline"] = ("triangular9, MAP with the datasheet prior "
                     + (f"({chip})" if chip else "(generic chip)") + ", as calibrate fits it")
    if colour:
        r["noise_colour"] = colour
    r["not_detectable"] = ("a local |g| different from 1 g and a rotation of the sensor frame leave no "
                           "trace in norm-only data: not detectable without an external reference")
    if u.bad.any():
        r["where"]["disturbed_poses"] = {"indices": np.flatnonzero(u.bad).tolist(),
                                         "t0_s": np.round(ps.t0[u.bad], 2).tolist()}
    if u.sat.any():
        idx = np.flatnonzero(u.sat).tolist()
        r["effects"].insert(0, {"name": "saturation", "significant": True, "poses": idx,
                                "ratio_after": r["ratio_after"], "params": {},
                                "note": "samples at the range limit (clipping, e.g. vibration peaks) "
                                        "bias these poses' means; they were left out of the fit: "
                                        "reduce vibration or raise the range"})
        r["verdict"] = "saturation" if r["verdict"] in ("none",) else f"saturation+{r['verdict']}"
    _allan_compare(r, None if longest is None else rec.acc[longest], rate, "g")
    return r


def _detrended_var(x: np.ndarray) -> float:
    """The mean over axes of the variance of ``x`` (n, C) about its straight line in sample
    order: a bias drifting through a warm-up hold is the thermal signal, not a disturbance."""
    k = np.arange(len(x), dtype=float)
    k -= k.mean()
    xc = x - x.mean(0)
    slope = (k @ xc) / (k @ k)
    return float(np.mean((xc - np.outer(k, slope)) ** 2))


def _gyro_disturbed(gyro: np.ndarray, gsl: List[slice], u: PoseSetup):
    """(the setup the gyro step uses, the poses it leaves out (N,) bool): a hold whose gyro
    varies far more than the others' (the accelerometer's rule, gap/posenoise.py
    flag_disturbed, on the within-pose gyro variance about a straight line in time) turned
    during it, e.g. a hand hold among table holds, turning about gravity, which moves the
    gyro's pose mean tens of the pooled standard errors while the accelerometer's screen sees
    nothing; left out when MIN_POSES remain, and only beyond one LSB^2 (quantisation is no
    turn)."""
    n = np.array([s_.stop - s_.start for s_ in gsl])
    s2 = np.array([_detrended_var(gyro[s_]) if k > 2 else 0.0 for s_, k in zip(gsl, n)])
    # a gyro held at one value inside most holds (noise below its LSB) has a median of ~0: a
    # hold that flips between two values is not a turn (their variance is at most LSB^2 / 4)
    lsb = estimate_lsb(np.asarray(gyro, float), [slice(0, len(gyro))])
    moved = flag_disturbed(s2, n) & (s2 > np.mean(lsb ** 2)) & u.keep
    if not moved.any() or (u.keep & ~moved).sum() < MIN_POSES:
        return u, np.zeros(len(n), bool)
    return replace(u, keep=u.keep & ~moved, bad=u.bad | moved), moved


def _gyro_step(rec: Recording, u: PoseSetup, sims, rng) -> Dict[str, object]:
    """The gyro against a bias per axis and Earth's vertical rate (gap/linear.py)."""
    rate, ps, keep, longest = rec.rate_hz, u.ps, u.keep, u.longest
    # the gyro's own still stretch: the slow ends of turns the accelerometer-led
    # detector keeps inside a pose are cut (gap/gyrostill.py)
    gsl, trim = trim_turns(rec.gyro, u.sl, rate)
    gm = np.array([rec.gyro[s_].mean(0) for s_ in gsl])
    # the gyro's own disturbed holds leave this step only (gm holds every pose; keep picks)
    u, moved = _gyro_disturbed(rec.gyro, gsl, u)
    keep = u.keep
    kap_g, colour_g = colour_inflation(None if longest is None else rec.gyro[longest], rate, u.T_pose)
    wp = within_pose_inflation(rec.gyro, u.kept(gsl))
    kap_g = max(kap_g, wp["inflation"])
    colour_g = dict(colour_g or {}, within_pose=wp)
    gvar, pinfo = pose_mean_variance(rec.gyro, u.kept(gsl))
    white_ax = ~np.asarray(pinfo.get("axes_below_white", [False] * 3))
    gvar = gvar * np.where(white_ax, kap_g, 1.0)[None, :]
    # a swaying hand's net rotation over each hold, and the quantisation floor (fitting/noise/posefloor.py)
    sway, pinfo["sway"] = sway_rotation_variance(rec.acc, rec.gyro, u.kept(gsl), rate)
    qf, pinfo["quantisation"] = pose_quantisation_floor(rec.gyro, u.kept(gsl))
    gvar = np.maximum(gvar, sway[:, None]) + qf[None, :]
    # flicker (bias instability) slower than a hold scatters the pose means too (gap/posenoise.py)
    # (not on the axes a hand's tremor fills, which the structure function read below white,
    # nor under a hand's sway clear of its standard error by 3 (one-sided 0.1 %): its slow
    # turning inside the holds reads as flicker there; the twin's own rule, 1 SE, is met by
    # chance on a sixth of bench recordings)
    sw = pinfo["sway"]
    swaying = sw.get("net_rotation_variance_deg2", 0.0) > 3 * sw.get("stderr_deg2", np.inf)
    read = white_ax & (not swaying)
    fl, colour_g["flicker_between_poses"] = flicker_between_poses(rec.gyro, u.kept(gsl), rate, read)
    gvar = gvar + fl
    colour_g["pose_mean_variance"] = pinfo
    ctx = u.ctx
    # specific force in g from the calibrated accelerometer (raw directions carry the
    # accelerometer's own scale and bias errors into the g-sensitivity regressor)
    ctx["acc_dir"] = Triangular9().forward(u.accel_theta(), ps.acc[keep])
    r = gyro_diag(gm[keep], gvar, ctx, sims, rng, u.skip)
    r["turn_ends_trimmed_s"] = float(np.sum(trim["trimmed_s"]))
    if moved.any():
        idx = np.flatnonzero(moved).tolist()
        r["where"]["gyro_disturbed_poses"] = {"indices": idx, "t0_s": np.round(ps.t0[moved], 2).tolist()}
        r.setdefault("notes", []).append(
            f"poses {idx} left out of the gyro's diagnosis: their gyro scatters far more than the "
            f"other holds' (the board turned or settled during the hold)")
    if colour_g:
        r["noise_colour"] = colour_g
    return r


def _mag_step(rec: Recording, u: PoseSetup, sims, rng) -> Dict[str, object]:
    """The magnetometer's still pose means and rotation points (gap/magpath.py)."""
    ps, keep = u.ps, u.keep
    mv = np.einsum("nii->n", ps.mag_cov) / 3 if ps.mag_cov is not None else None
    # a magnetometer held at its own rate inside a faster log: its distinct readings count
    # (fitting/noise/posefloor.py run_effective_counts), not the rows (mag_cov is over the rows / n)
    n_eff = ps.n[keep]
    from ..fitting.stillness.repeats import find_repeats
    if len(rec.t) > 3 and find_repeats(rec.t, rec.mag, rec.rate_hz).held:
        n_eff = run_effective_counts(rec.mag, u.kept(u.sl))
    mvar = np.median(mv[keep] * ps.n[keep]) / n_eff
    return _mag(rec, u.sl, ps.mag[keep], mvar, np.flatnonzero(keep), u.accel_theta(), u.skip, sims, rng,
                _chip_mag_noise(rec))


def diagnose(rec: Recording, sensors: Optional[Sequence[str]] = None, sims: int = 200,
             seed: int = 0, name: str = "recording") -> Dict[str, object]:
    """Diagnose every sensor present (or the ones asked for); returns the JSON object.

    Steps: segment the still poses; too few (or too few orientations): the time-series
    path; else :func:`pose_setup` and one step per sensor (accelerometer, gyro, magnetometer)."""
    rng = np.random.default_rng(seed)
    rec = distinct_samples(rec)
    if rec.acc is None:
        if rec.mag is None:
            raise GapError(f"{name}: no accelerometer or magnetometer columns: nothing to diagnose")
        for s in sensors or ["mag"]:
            if s != "mag":
                raise GapError(f"{name}: --sensor {s}: the recording has no {s} columns")
        _dead_columns(rec, ["mag"], name, [])     # for its GapError: nothing else is left to diagnose
        return _mag_only(rec, sims, rng, name)
    sensors = _sensors_asked(rec, sensors, name)
    dead_notes: List[str] = []
    sensors = _dead_columns(rec, sensors, name, dead_notes)
    rate = rec.rate_hz
    sl = split_at_time_gaps(rec.t, rec.acc, detect_static(rec.t, rec.acc, rec.gyro, rate_hz=rate), rate)
    ps = poses_from_slices(rec, sl)
    N = len(ps)
    n_orient = int(orientation_groups(ps.acc).max()) + 1 if N else 0
    if N < MIN_POSES or n_orient < MIN_ORIENTATIONS:
        res = _series_path(rec, sl, ps, sensors, sims, rng, name, n_orient)
        if dead_notes:
            res["notes"] = dead_notes + list(res.get("notes", []))
        return res
    u = pose_setup(rec, sl, ps)
    u.notes[:0] = dead_notes
    result: Dict[str, object] = {"sensors": {}, "poses_found": N,
                                 "poses_left_out": np.flatnonzero(u.bad).tolist() if u.keep.sum() < N else []}
    if "accel" in sensors:
        result["sensors"]["accel"] = _accel_step(rec, u, sims, rng)
        _pair_note(u, result["sensors"]["accel"]["verdict"])
    if "gyro" in sensors:
        result["sensors"]["gyro"] = _gyro_step(rec, u, sims, rng)
    if "mag" in sensors:
        m = _mag_step(rec, u, sims, rng)
        if m.get("verdict") is None:
            u.notes.append(f"mag: not diagnosed: {m['error']}")
        else:
            result["sensors"]["mag"] = m
    result["notes"] = u.notes
    return result
