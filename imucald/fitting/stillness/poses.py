"""Static-pose extraction from sample streams, and the pose-average file format.

Still intervals come from the one stillness detector,
:mod:`imucald.fitting.stillness.detector` (criterion, noise floor and defaults are documented
there): the batch call here runs the daemon's streaming detector over the whole
file, so ``calibrate``, ``replay``, the daemon and ``gap`` find the same poses.

Each pose carries its mean, sample covariance, covariance of the mean, count,
mean temperature and start/end time.  The covariance of the mean is the sample
covariance over n (white noise) for single slices; the whole-recording calls
(:func:`poses_and_pieces`, what calibrate fits) rescale it per axis by the
structure-function estimate of :mod:`imucald.fitting.noise.posecov`, so that hand tremor (which
averages out of a pose mean) and short-correlated colour (which does not) are counted as
they are.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from ...errors import UserError
from ...numerics.npstats import median
from ...files.recording import Recording
from .detector import StillnessDetector

__all__ = ["PoseSet", "detect_static", "detect_intervals", "detect", "poses_from_recording",
           "poses_and_pieces", "still_report", "no_still_message",
           "read_poses", "write_poses", "NoPoses", "POSES_MAGIC"]

POSES_MAGIC = "# imucald poses v1"
#: rows fed to the stillness detector at a time by the whole-file calls
DETECT_CHUNK = 1 << 14


@dataclass(eq=False)
class PoseSet:
    """Averages of static intervals.  All arrays have N rows."""

    acc: np.ndarray                              #: mean specific force, g (N, 3)
    acc_cov: np.ndarray                          #: covariance of that mean, g^2 (N, 3, 3)
    n: np.ndarray                                #: samples per pose (N,)
    t0: np.ndarray                               #: start, s (N,)
    t1: np.ndarray                               #: end, s (N,)
    acc_sample_cov: Optional[np.ndarray] = None  #: within-pose sample covariance, g^2
    gyro: Optional[np.ndarray] = None            #: mean rate, deg/s (N, 3)
    gyro_cov: Optional[np.ndarray] = None        #: covariance of the mean, (deg/s)^2
    mag: Optional[np.ndarray] = None             #: mean field, gauss (N, 3)
    mag_cov: Optional[np.ndarray] = None
    temp: Optional[np.ndarray] = None            #: mean temperature, degC (N,)
    meta: Dict[str, str] = field(default_factory=dict)
    #: the whole-file detector that found the poses (repeats, rejected stretches), or None
    detector: object = field(default=None, repr=False, compare=False)
    #: how the covariances of the means were formed ({"accel": summary, "gyro": ...} of
    #: fitting/noise/posecov.py), or None (sample covariance over n)
    noise: Optional[dict] = field(default=None, repr=False, compare=False)
    #: each pose's sample slice of the recording (its distinct rows: ``detector.repeats.keep``),
    #: or None
    slices: Optional[list] = field(default=None, repr=False, compare=False)

    def __len__(self):
        return len(self.acc)

    def subset(self, idx) -> "PoseSet":
        """The poses ``idx`` (indices or a mask), with the detector and the noise summary that
        found them and their sample slices (dropped before: calibrate's --model eq6 then had
        no slices, --sensor all no stillness object)."""
        f = lambda a: None if a is None else a[idx]
        sl = None if self.slices is None else [self.slices[i] for i in np.arange(len(self.acc))[idx]]
        return PoseSet(self.acc[idx], self.acc_cov[idx], self.n[idx], self.t0[idx], self.t1[idx],
                       f(self.acc_sample_cov), f(self.gyro), f(self.gyro_cov), f(self.mag),
                       f(self.mag_cov), f(self.temp), dict(self.meta), self.detector, self.noise, sl)


def detect_static(t: np.ndarray, acc: np.ndarray, gyro: Optional[np.ndarray] = None,
                  rate_hz: Optional[float] = None, **params) -> List[slice]:
    """Index slices of the still intervals: the streaming detector
    (:class:`imucald.fitting.stillness.detector.StillnessDetector`, whose docstring gives the
    criterion and the defaults) run over the whole file, then flushed.  ``params`` are
    its keyword arguments (window_s, k, min_still_s, max_pose_s, trim_s, max_turn_deg,
    chip).  The pieces the streaming detector cuts from one long still run (every
    ``max_pose_s``, so that a daemon reports a resting board) are joined again here.
    A slice covers the repeated rows inside it too (:mod:`imucald.fitting.stillness.repeats`)."""
    ivs, _, _ = detect(t, acc, gyro, rate_hz, **params)
    return merge_cut(ivs)


def merge_cut(intervals) -> List[slice]:
    """Slices of intervals, the pieces of one still run (cut at max_pose_s: an interval that
    ``continues`` the one before it) joined; a joined slice covers any repeated rows between
    its pieces."""
    out: List[slice] = []
    for iv in intervals:
        if out and iv.continues:
            out[-1] = slice(out[-1].start, iv.i1)
        else:
            out.append(slice(iv.i0, iv.i1))
    return out


def detect_intervals(t, acc, gyro=None, rate_hz=None, temp=None, **params):
    """(intervals, samples dropped as non-finite or absurd) for a whole file."""
    ivs, dropped, _ = detect(t, acc, gyro, rate_hz, temp, **params)
    return ivs, dropped


def detect(t, acc, gyro=None, rate_hz=None, temp=None, mag=None, **params):
    """(intervals, samples dropped as non-finite or absurd, the detector) for a whole file:
    its repeated samples found first (:func:`imucald.fitting.stillness.repeats.find_repeats`), the
    detector run on the distinct ones at their effective rate (``det.repeats``; the
    stretches it rejected: ``det.rejected``, ``det.rejected_counts``).  The detector is
    None for fewer than 4 rows."""
    from .repeats import find_repeats
    t = np.asarray(t, float)
    if len(t) < 4:
        return [], 0, None
    rep = find_repeats(t, acc, rate_hz)
    det = StillnessDetector(rep.nominal_hz, repeats=rep, **params)
    out = []
    # the streaming detector over consecutive chunks: its decisions do not depend on how the
    # stream is cut, and its working arrays (~300 bytes a row) stay those of one chunk
    for i in range(0, len(t), DETECT_CHUNK):
        sl = slice(i, i + DETECT_CHUNK)
        out += det.update(t[sl], acc[sl], None if gyro is None else gyro[sl],
                          None if temp is None else temp[sl], None if mag is None else mag[sl])[1]
    out += det.flush()
    return out, det.dropped, det


def _mean_cov(x: np.ndarray):
    """(mean, sample covariance, deviations from the mean) of x (n, C)."""
    m = x.sum(0) / len(x)        # x.mean(0) bit for bit (the same sum, / the count) without its wrapper
    d = x - m
    c = d.T @ d / max(len(x) - 1, 1)
    return m, c, d


def poses_from_recording(rec: Recording, **kw) -> PoseSet:
    """Detect still intervals in a recording and average each one."""
    return poses_and_pieces(rec, **kw)[0]


def poses_and_pieces(rec: Recording, **kw) -> Tuple[PoseSet, PoseSet]:
    """(poses, pieces): the still intervals of a recording averaged, contiguous pieces
    joined (one pose per placement, what a constant fit wants), and the same averaged
    piece by piece as the detector cut them (every ``max_pose_s``), so that a long still
    stretch through a warm-up gives one point per piece at its own temperature: what
    the thermal fit wants, as the daemon's thermal log keeps them."""
    if rec.acc is None:
        raise UserError("the recording has no accelerometer columns (ax, ay, az): "
                        "poses are detected from the accelerometer")
    if "chip" not in kw:
        from ...specs import recording_chips
        kw = dict(kw, chip=recording_chips(rec.meta).get("accel"))
    ivs, dropped, det = detect(rec.t, rec.acc, rec.gyro, rec.rate_hz, mag=rec.mag, **kw)
    keep = None if det is None else det.repeats.keep
    cuts = [slice(iv.i0, iv.i1) for iv in ivs]
    pieces, _, centred = _averaged(rec, cuts, keep)
    joined = merge_cut(ivs)
    ps = _joined(rec, joined, cuts, pieces, keep, centred)
    ps.slices, pieces.slices = joined, cuts
    if dropped:
        ps.meta["dropped_samples"] = pieces.meta["dropped_samples"] = str(dropped)
    if det is not None:
        ps.detector = pieces.detector = det
    return ps, pieces


def _joined(rec: Recording, slices: List[slice], cuts: List[slice], pieces: PoseSet,
            keep: Optional[np.ndarray], centred: Dict[str, list]) -> PoseSet:
    """``poses_from_slices(rec, slices, keep, structure=True)``, the rows of a slice that is
    also one of the pieces (``cuts``: most poses are one piece) copied from ``pieces``
    instead of averaged again (the same rows of the same samples, so the same numbers),
    then the structure-function scaling as there (from the pieces' own centring,
    ``centred``: :func:`_averaged`'s)."""
    at = {(s.start, s.stop): i for i, s in enumerate(cuts)}
    new = [s for s in slices if (s.start, s.stop) not in at]
    if len(new) == len(slices):
        return poses_from_slices(rec, slices, keep, structure=True)
    more, _, more_centred = _averaged(rec, new, keep)
    src, j = [], len(cuts)
    for s in slices:
        i = at.get((s.start, s.stop))
        if i is None:
            i, j = j, j + 1
        src.append(i)
    idx = np.array(src, dtype=np.intp)
    rows = lambda a, b: None if a is None else np.concatenate([a, b])[idx]
    ps = PoseSet(rows(pieces.acc, more.acc), rows(pieces.acc_cov, more.acc_cov), rows(pieces.n, more.n),
                 rows(pieces.t0, more.t0), rows(pieces.t1, more.t1),
                 rows(pieces.acc_sample_cov, more.acc_sample_cov), rows(pieces.gyro, more.gyro),
                 rows(pieces.gyro_cov, more.gyro_cov), rows(pieces.mag, more.mag),
                 rows(pieces.mag_cov, more.mag_cov), rows(pieces.temp, more.temp), dict(rec.meta))
    both = {k: centred[k] + more_centred[k] for k in centred}
    return _structure(ps, rec, [_distinct(s, keep) for s in slices],
                      {k: [v[i] for i in src] if v else [] for k, v in both.items()})


def still_report(det) -> List[str]:
    """Lines for the user about a whole-file detection: repeated samples and the effective
    rate (one line, when any), and the quiet stretches rejected, by reason."""
    out = []
    if det is None:
        return out
    s = det.repeats.summary()
    if s:
        out.append(s)
    rc = det.rejected_counts
    if rc:
        names = {"short": "shorter than the minimum", "few": "too few distinct samples",
                 "noise": "noisier than the chip can be at rest", "norm": "|mean| not ~1 g",
                 "turn": "turning (magnetometer)"}
        ex = {}
        for r in det.rejected:
            ex.setdefault(r["kind"], r)
        out.append("quiet stretches not counted as poses: " + "; ".join(
            f"{rc[k]} {names.get(k, k)} (e.g. {ex[k]['t0_s']:.1f}-{ex[k]['t1_s']:.1f} s: {ex[k]['reason']})"
            if k in ex else f"{rc[k]} {names.get(k, k)}" for k in rc))
    return out


def no_still_message(path: str, det, n_found: int = 0, acc_g: Optional[np.ndarray] = None) -> str:
    """One line: the recording has no still moment (or too few), and why (``path`` heads it;
    '' for a line that names the file already).  ``acc_g``: the recording's accelerometer
    samples; a median |a| beyond 0.5-2 g says the unit is wrong (m/s^2 read as g scatters
    9.8x, so no window is quiet enough: the line told such a file to hold the board still,
    under a warning that named the unit)."""
    head = f"{path}: " if path else ""
    if det is None:
        return f"{head}no still moment: only 0 still poses found (too few samples)"
    cap = det.floor_cap
    fl = det._core.floor_a if det._core is not None else None
    what = "no still moment: only 0 still poses" if n_found == 0 else f"only {n_found} still poses"
    why = ""
    units = False           # the numbers are not in g: the scale, not the hands, is to fix
    rc = det.rejected_counts
    if rc:
        k = max(rc, key=rc.get)
        r = next(x for x in reversed(det.rejected) if x["kind"] == k)
        why = f"; {sum(rc.values())} quiet stretches rejected, e.g. at {r['t0_s']:.1f} s: {r['reason']}"
        units = k == "norm"
    elif cap is not None and fl is not None and det._core._hist_a.size:
        q = float(np.percentile(det._core._hist_a, 5))
        kc = det._core.k * cap
        why = (f"; the quietest 1 s windows scatter {np.sqrt(q / 3) * 1e3:.3g} mg per axis, "
               f"{np.sqrt(q / kc):.3g}x the most a still {det.chip or 'accelerometer'} can "
               f"({np.sqrt(kc / 3) * 1e3:.3g} mg at {det.rate:.3g} Hz)")
        units = np.sqrt(q / 3) > 0.1        # a tenth of a g in the quietest second: not in g
    if acc_g is not None and len(acc_g):
        x = np.asarray(acc_g, float)[::max(1, len(acc_g) // 5000)]
        norm = float(median(np.sqrt(np.einsum("ij,ij->i", x, x))))
        units = units or not 0.5 <= norm <= 2.0
    fix = ("check --nominal-scale first (is the file in g? counts or m/s^2 read as g fail every "
           "test), then hold the board still for a few seconds in each orientation" if units else
           "hold the board still for a few seconds in each orientation")
    return f"{head}{what} found{why}: {fix}"


def poses_from_slices(rec: Recording, slices: List[slice], keep: Optional[np.ndarray] = None,
                      structure: bool = False) -> PoseSet:
    """Each slice's rows averaged; with ``keep`` only the distinct ones (repeated samples
    are not measurements: counted, they would shrink the standard errors).  With
    ``structure`` the accelerometer's and gyro's covariances of the means are rescaled
    per axis by the within-pose structure function (fitting/noise/posecov.py; ``ps.noise`` says
    what it found); else each is the pose's sample covariance over n."""
    ps, rows, centred = _averaged(rec, slices, keep)
    return _structure(ps, rec, rows, centred) if structure else ps


def _averaged(rec: Recording, slices: List[slice], keep: Optional[np.ndarray]):
    """(PoseSet, each slice's rows, {"acc": [(mean, deviations)], "gyro": [...]}): the
    averages of :func:`poses_from_slices` and the centred samples they were formed from, which
    the structure-function scaling (:func:`_structure`) takes as they are instead of centring
    the same rows again (the same numbers)."""
    N = len(slices)
    acc = np.zeros((N, 3))
    acov = np.zeros((N, 3, 3))
    scov = np.zeros((N, 3, 3))
    n = np.zeros(N, int)
    t0 = np.zeros(N)
    t1 = np.zeros(N)
    gy = np.zeros((N, 3)) if rec.gyro is not None else None
    gcov = np.zeros((N, 3, 3)) if rec.gyro is not None else None
    mg = np.zeros((N, 3)) if rec.mag is not None else None
    mcov = np.zeros((N, 3, 3)) if rec.mag is not None else None
    tp = np.zeros(N) if rec.temp is not None else None
    rows = []
    centred: Dict[str, list] = {"acc": [], "gyro": []}
    for i, s in enumerate(slices):
        s = _distinct(s, keep)
        rows.append(s)
        a = rec.acc[s]
        n[i] = len(a)
        m, scov[i], d = _mean_cov(a)
        acc[i] = m
        centred["acc"].append((m, d))
        acov[i] = scov[i] / n[i]
        t0[i], t1[i] = rec.t[s][0], rec.t[s][-1]
        if gy is not None:
            m, c, d = _mean_cov(rec.gyro[s])
            gy[i] = m
            centred["gyro"].append((m, d))
            gcov[i] = c / n[i]
        if mg is not None:
            mg[i], c, _ = _mean_cov(rec.mag[s])
            mcov[i] = c / n[i]
        if tp is not None:
            tp[i] = rec.temp[s].mean()
    ps = PoseSet(acc, acov, n, t0, t1, scov, gy, gcov, mg, mcov, tp, dict(rec.meta))
    return ps, rows, centred


def _distinct(s: slice, keep: Optional[np.ndarray]):
    """The slice, or the indices of its distinct rows when ``keep`` drops some."""
    if keep is not None and not keep[s].all():
        return s.start + np.flatnonzero(keep[s])
    return s


def _structure(ps: PoseSet, rec: Recording, rows, centred: Dict[str, list]) -> PoseSet:
    """The accelerometer's and gyro's covariances of the means rescaled per axis by the
    within-pose structure function (fitting/noise/posecov.py), the accelerometer's along
    its mean direction by the radial series' own; ``rows``: each pose's rows, ``centred``
    their means and deviations (:func:`_averaged`)."""
    if len(rows):
        from ..noise.posecov import radial_pose_cov, scale_pose_cov
        from ..noise.posefloor import tilt_wander_test_parts
        ps.noise = {}
        parts = [rec.acc[s] for s in rows]
        # the averaging's means and deviations are reused only where they are float64: those of
        # float32 samples (an API caller's) are the samples' own precision, and these
        # functions centre in float64 themselves
        f64 = rec.acc.dtype == np.float64
        ps.acc_cov, ps.noise["accel"] = scale_pose_cov(parts, ps.acc_cov,
                                                       [d for _, d in centred["acc"]] if f64 else None)
        # along each pose's direction from the radial series where the direction wanders
        # within the poses (a hand's sway, which the norm model does not see: radial_pose_cov;
        # the test is gap's, fitting/noise/posefloor.py, one-sided ~2 %)
        tilt = tilt_wander_test_parts(parts, means=[m for m, _ in centred["acc"]] if f64 else None)
        if tilt["wander"]:
            ps.acc_cov, ps.noise["accel_radial"] = radial_pose_cov(parts, ps.acc, ps.acc_cov)
            ps.noise["accel_radial"]["tilt_wander"] = tilt
        if ps.gyro_cov is not None:
            ps.gyro_cov, ps.noise["gyro"] = scale_pose_cov(
                [rec.gyro[s] for s in rows], ps.gyro_cov,
                [d for _, d in centred["gyro"]] if rec.gyro.dtype == np.float64 else None)
    return ps


# --- pose-average file ----------------------------------------------------------------

_POSE_COLS = ["t0", "t1", "n", "ax", "ay", "az", "sax", "say", "saz"]


def write_poses(ps: PoseSet, path: str) -> None:
    """CSV: magic line, '# key: value' header, columns t0,t1,n,ax,ay,az,sax,say,saz
    [,gx,gy,gz[,sgx,sgy,sgz]][,mx,my,mz][,temp]; s* are within-pose sample standard
    deviations (g; sg*: deg/s, written when the gyro means carry their covariance)."""
    from ...files.atomic import atomic_write_text
    cols = list(_POSE_COLS)
    sd = np.sqrt(np.einsum("nii->ni", ps.acc_sample_cov)) if ps.acc_sample_cov is not None \
        else np.sqrt(np.einsum("nii->ni", ps.acc_cov) * ps.n[:, None])
    parts = [ps.t0[:, None], ps.t1[:, None], ps.n[:, None], ps.acc, sd]
    if ps.gyro is not None:
        cols += ["gx", "gy", "gz"]
        parts.append(ps.gyro)
        if ps.gyro_cov is not None:
            cols += ["sgx", "sgy", "sgz"]
            parts.append(np.sqrt(np.einsum("nii->ni", ps.gyro_cov) * ps.n[:, None]))
    if ps.mag is not None:
        cols += ["mx", "my", "mz"]
        parts.append(ps.mag)
    if ps.temp is not None:
        cols.append("temp")
        parts.append(ps.temp[:, None])
    data = np.hstack(parts)
    lines = [POSES_MAGIC] + [f"# {k}: {v}" for k, v in ps.meta.items()] + [",".join(cols)]
    lines += [",".join(f"{v:.9g}" for v in row) for row in data]
    atomic_write_text(path, "\n".join(lines) + "\n")


def _cut_last_line(path: str, lines, n: int):
    """A last line without a newline that is not a whole pose row is dropped, with a warning."""
    from ...files.tables import warn
    last = lines[-1].split(",")
    try:
        [float(p) for p in last]
        if n > 2 and len(last) == len(lines[-2].split(",")):
            return lines
    except ValueError:
        pass
    if n > 2 and not lines[-1].startswith("#"):
        warn(f"{path}:{n}: the last line is cut short (no newline at the end of the file) and is ignored")
        return lines[:-1]
    return lines


class NoPoses(UserError):
    """A pose file with its header and no pose: what the daemon saves before its first pose
    or after a reset (daemon/state.py reads it as no poses, not as damage)."""


def read_poses(path: str) -> PoseSet:
    """Read a pose file written by :func:`write_poses`.  Errors name file and line.

    Every value must be a finite number within :data:`imucald.files.recording.PLAUSIBLE_LIMIT`
    (``temp`` may be ``nan``: unknown), ``n`` a positive integer and the deviations
    ``s*`` >= 0."""
    from ...files.recording import PLAUSIBLE_LIMIT, read_small
    from ...files.tables import decode_line
    raw = read_small(path, UserError, "a pose file")
    lines = decode_line(path, raw, 1, 0).splitlines()
    if lines and not raw.endswith(b"\n"):
        lines = _cut_last_line(path, lines, len(lines))
    if not lines or lines[0].strip() != POSES_MAGIC:
        raise UserError(f"{path}:1: not an imucald pose file (expected {POSES_MAGIC!r})")
    meta = {}
    i = 1
    while i < len(lines) and lines[i].startswith("#"):
        body = lines[i][1:]
        if ":" in body:
            k, v = body.split(":", 1)
            meta[k.strip()] = v.strip()
        i += 1
    if i >= len(lines):
        raise UserError(f"{path}:{i + 1}: no column header")
    cols = [c.strip() for c in lines[i].split(",")]
    need = ["ax", "ay", "az"]
    if not all(c in cols for c in need):
        raise UserError(f"{path}:{i + 1}: the column header must include ax, ay, az")
    dup = next((c for c in cols if cols.count(c) > 1), None)
    if dup is not None:
        raise UserError(f"{path}:{i + 1}: column {dup} is given twice; keep one")
    _check_pose_columns(path, i + 1, cols)
    i01 = (cols.index("t0"), cols.index("t1")) if "t0" in cols and "t1" in cols else None
    rows = []
    for j in range(i + 1, len(lines)):
        s = lines[j].strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split(",")
        if len(parts) != len(cols):
            raise UserError(f"{path}:{j + 1}: expected {len(cols)} values, found {len(parts)}")
        try:
            row = [float(p) for p in parts]
        except ValueError:
            raise UserError(f"{path}:{j + 1}: a value is not a number") from None
        for name, v in zip(cols, row):
            _check_pose_value(path, j + 1, name, v, PLAUSIBLE_LIMIT)
        if i01 and row[i01[0]] > row[i01[1]]:
            # a pose ends after it starts (a cold review's saved poses had t0 > t1, accepted)
            raise UserError(f"{path}:{j + 1}: t0 {row[i01[0]]:g} s is after t1 {row[i01[1]]:g} s: "
                            f"a pose's start comes before its end (repair or delete this line)")
        rows.append(row)
    if not rows:
        raise NoPoses(f"{path}: no poses")
    d = np.array(rows)
    c = {k: d[:, cols.index(k)] for k in cols}
    N = len(d)
    acc = np.column_stack([c["ax"], c["ay"], c["az"]])
    n = c["n"].astype(np.int64) if "n" in c else np.ones(N, np.int64)
    if all(k in c for k in ("sax", "say", "saz")):
        scov = np.zeros((N, 3, 3))
        for a, k in enumerate(("sax", "say", "saz")):
            scov[:, a, a] = c[k] ** 2
        acov = scov / np.maximum(n, 1)[:, None, None]
    else:
        scov = None
        acov = np.full((N, 3, 3), np.nan)
    g3 = lambda ks: np.column_stack([c[k] for k in ks]) if all(k in c for k in ks) else None
    gy, sg = g3(["gx", "gy", "gz"]), g3(["sgx", "sgy", "sgz"])
    gcov = None if gy is None or sg is None else \
        np.einsum("ni,ij->nij", sg ** 2 / np.maximum(n, 1)[:, None], np.eye(3))
    return PoseSet(acc, acov, n, c.get("t0", np.arange(N, dtype=float)),
                   c.get("t1", np.arange(N, dtype=float)), scov,
                   gy, gcov, g3(["mx", "my", "mz"]), None,
                   c.get("temp"), meta)


#: the columns write_poses writes; each group's axes come together
_POSE_ALL = _POSE_COLS + ["gx", "gy", "gz", "sgx", "sgy", "sgz", "mx", "my", "mz", "temp"]
_POSE_GROUPS = (("ax", "ay", "az"), ("sax", "say", "saz"), ("gx", "gy", "gz"), ("sgx", "sgy", "sgz"),
                ("mx", "my", "mz"))


def _check_pose_columns(path: str, lineno: int, cols: List[str]) -> None:
    """Every column one the reader uses: a misspelt or half-given one would be read as
    nothing, without a word (a 'tmp' column: no thermal fit; gx,gy without gz: no gyro)."""
    bad = next((c for c in cols if c not in _POSE_ALL), None)
    if bad is not None:
        raise UserError(f"{path}:{lineno}: unknown column {bad[:40]!r}; allowed: {', '.join(_POSE_ALL)}")
    for g in _POSE_GROUPS:
        if sum(c in cols for c in g) not in (0, 3):
            raise UserError(f"{path}:{lineno}: columns {','.join(g)} must come together")
    if "sgx" in cols and "gx" not in cols:
        raise UserError(f"{path}:{lineno}: columns sgx,sgy,sgz need gx,gy,gz (the gyro means they "
                        f"are the deviations of)")


def _check_pose_value(path: str, lineno: int, name: str, v: float, limit: float) -> None:
    """One value of a pose file: finite (temp may be nan: unknown) and physically possible."""
    if name == "temp" and v != v:
        return
    if not (abs(v) <= limit):
        what = "is not a finite number" if not np.isfinite(v) else f"is beyond {limit:g}"
        raise UserError(f"{path}:{lineno}: column {name}: {v!r} {what} (repair or delete this line)")
    if name == "n" and (v < 1 or not v.is_integer()):
        raise UserError(f"{path}:{lineno}: column n: {v!r} is not a sample count (a whole number >= 1)")
    if name in ("sax", "say", "saz") and v < 0:
        raise UserError(f"{path}:{lineno}: column {name}: {v!r} is a negative standard deviation")
