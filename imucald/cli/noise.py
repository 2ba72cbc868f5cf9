"""``imucald noise RECORDING``: Allan deviation and noise figures of a still stretch."""
from __future__ import annotations

import os

from ..errors import UserError
from ._common import eprint, print_json, window_rows

__all__ = ["cmd_noise", "still_stretch"]

_AXES = {"accel": ("acc", "xyz"), "gyro": ("gyro", "xyz"), "mag": ("mag", "xyz")}


def still_stretch(t, start_s=None, end_s=None, max_gap_s: float = 1.0):
    """(i0, i1, rate_hz): the longest run of samples within [start_s, end_s] with no time
    step above ``max_gap_s``; the rate is the run's mean rate (bursty timestamps, e.g.
    reception times, average out; the Allan deviation is taken over the sample index)."""
    import numpy as np
    t = np.asarray(t, float)
    lo, hi = window_rows(t, start_s, end_s)
    cut = np.flatnonzero(np.diff(t[lo:hi]) > max_gap_s) + 1
    edges = np.concatenate([[0], cut, [hi - lo]])
    k = int(np.argmax(np.diff(edges)))
    i0, i1 = lo + int(edges[k]), lo + int(edges[k + 1])
    if i1 - i0 < 2 or t[i1 - 1] <= t[i0]:
        raise UserError("no stretch of samples without a gap: check the t column")
    return i0, i1, (i1 - i0 - 1) / (t[i1 - 1] - t[i0])


def cmd_noise(args) -> int:
    import numpy as np
    import yaml
    from ..files.atomic import atomic_write_text
    from ..fitting.noise.allan import characterise, figures_document, kalibr_text
    from ..fitting.inputs import stuck_columns, stuck_message
    from ._common import read_input
    kind, rec = read_input(args, args.recording, applied=("--rate-hz",))     # a recording's rate too
    if kind != "recording":
        raise UserError(f"{args.recording}: noise needs samples (a recording), not pose averages")
    i0, i1, rate = still_stretch(rec.t, args.start_s, args.end_s, args.max_gap_s)
    if args.rate_hz:
        rate = float(args.rate_hz)
    keep = slice(None)
    ref = next((getattr(rec, a) for a in ("acc", "gyro", "mag") if getattr(rec, a) is not None), None)
    if ref is not None and i1 - i0 > 3:
        # repeated rows (sample-and-hold, duplicated rows) are not samples: the figures come
        # from the distinct ones at their effective rate (README: repeated samples)
        from ..fitting.stillness.repeats import find_repeats
        rep = find_repeats(rec.t[i0:i1], np.asarray(ref[i0:i1], float), rate)
        if rep.repeated:
            keep = rep.keep
            rate = rate * float(keep.mean()) if args.rate_hz else rep.rate_hz
            eprint(f"imucald: warning: {args.recording}: {rep.summary()}")
    figs = {}
    for sensor, (attr, axes) in _AXES.items():
        x = getattr(rec, attr)
        if x is None or (args.sensor and sensor not in args.sensor):
            continue
        x = np.asarray(x[i0:i1], float)[keep]
        if not np.all(np.isfinite(x)):
            raise UserError(f"{args.recording}: {sensor} has non-finite values in the stretch used")
        stuck = stuck_columns(x, sensor)
        if stuck:
            # no sample-to-sample change: an Allan deviation of zero, and a fit that divides
            # by it (a noise below half an LSB reads so too: the figures need a finer range)
            raise UserError(f"{args.recording}: {sensor}: {stuck_message(stuck)}; or a noise below "
                            f"half an LSB, which no figure can be read from")
        figs[sensor] = characterise(x, rate, axes, args.confidence, args.tau_min_s, args.tau_max_s)
    if not figs:
        raise UserError(f"{args.recording}: no accel, gyro or mag columns to characterise")
    moved = motion_in_stretch(rec, i0, i1, rate)
    if moved:
        eprint(f"imucald: warning: {args.recording}: {moved}")
    dur = float(rec.t[i1 - 1] - rec.t[i0]) if isinstance(keep, np.ndarray) else (i1 - i0) / rate
    span = f"samples {i0}..{i1 - 1} ({dur:.0f} s at {rate:.2f} Hz)"
    doc = figures_document(figs, rate, os.path.basename(args.recording), dur)
    doc["stretch"] = {"first_sample": int(i0), "samples": int(i1 - i0),
                      "t_start_s": float(rec.t[i0]), "t_end_s": float(rec.t[i1 - 1])}
    from ..errors import write_failure
    for path, flag, text in ((args.output, "-o", lambda: "# imucald noise figures "
                              "(docs/guide/noise.md)\n" + yaml.safe_dump(doc, sort_keys=False,
                                                            default_flow_style=None, width=110)),
                             (args.kalibr, "--kalibr", lambda: kalibr_text(doc["kalibr"]))):
        if path:
            try:
                atomic_write_text(path, text(), flag=flag)
            except OSError as e:
                raise write_failure(e, flag, path) from None
    if args.plot:
        _plot(figs, args.plot, args.recording)
    if args.json:
        print_json({**doc, "allan": figs})
        return 0
    print(summary(figs, span, args.confidence))
    if args.output or args.kalibr:
        eprint("imucald: wrote " + " and ".join(p for p in (args.output, args.kalibr) if p))
    return 0


#: motion shorter than this between two still stretches is the detector's own edge (its trim
#: before a detected start of motion), not a move
MOTION_MIN_S = 1.0


def motion_in_stretch(rec, i0: int, i1: int, rate_hz: float) -> str:
    """What moved in the stretch ``i0:i1`` that noise figures need still, or '': the still
    detector (calibrate's, with its defaults) over the stretch, and the gaps of more than
    MOTION_MIN_S between its still intervals, before the first and after the last (the
    detector marks a still start from its first samples on); no still stretch at all is said only where the
    accelerometer reads ~1 g (else its units are the question).  A board lifted now and then inflated the Allan
    deviation near its period and the fit read a white density of 0 and a bias instability
    of 5.6 mg, with no word (a newcomer's walk on the noise guide's own example)."""
    import numpy as np
    if rec.acc is None or i1 - i0 < 8 * rate_hz:
        return ""
    from ..fitting.stillness.poses import detect, merge_cut
    t = np.asarray(rec.t[i0:i1], float)
    ivs, _, det = detect(t, rec.acc[i0:i1], None if rec.gyro is None else rec.gyro[i0:i1], rate_hz)
    spans = [(float(t[s.start]), float(t[s.stop - 1])) for s in merge_cut(ivs)]
    if not spans:
        g = float(np.median(np.linalg.norm(np.asarray(rec.acc[i0:i1], float), axis=1)))
        if not 0.65 <= g <= 1.35:
            return ""               # not in g (its own warning says so), or in free fall
        return (f"no still stretch in samples {i0}..{i1 - 1} by calibrate's detector: noise figures "
                f"need the board left still (a moving board's figures are its motion's)")
    gaps = [(a, b) for (_, a), (b, _) in zip(spans, spans[1:]) if b - a > MOTION_MIN_S]
    if spans[0][0] > t[0] + MOTION_MIN_S:           # the hand leaving the board
        gaps.insert(0, (float(t[0]), spans[0][0]))
    if spans[-1][1] < t[-1] - MOTION_MIN_S - 1.0:
        gaps.append((spans[-1][1], float(t[-1])))
    if not gaps:
        return ""
    what = ", ".join(f"{a - t[0]:.1f}-{b - t[0]:.1f} s" for a, b in gaps[:4]) + (", ..." if len(gaps) > 4 else "")
    return (f"the board moved in the stretch ({len(gaps)} time(s): {what} after its start, by calibrate's "
            f"detector): the figures include that motion; record the board left still, or choose a still "
            f"part with --start-s/--end-s")


def summary(figs, span: str, conf: float) -> str:
    """Human summary: per axis the figures with their interval and reading tau."""
    u = {"accel": ("ug/rtHz", 1e6, "ug", 1e6, "ug/rts", 1e6),
         "gyro": ("deg/h/rtHz", 3600.0, "deg/h", 3600.0, "deg/h/rts", 3600.0),
         "mag": ("mG/rtHz", 1e3, "mG", 1e3, "mG/rts", 1e3)}
    out = [f"noise figures of {span}; {conf:.0%} intervals; fit over tau "
           f"{figs[next(iter(figs))][0]['fit_tau_s'][0]:.3g}..{figs[next(iter(figs))][0]['fit_tau_s'][1]:.3g} s"]
    for s, axes in figs.items():
        un = u[s]
        for a in axes:
            parts = []
            for j, key in enumerate(("white_density", "bias_instability", "rate_random_walk")):
                name, k = un[2 * j], un[2 * j + 1]
                lo, hi = a[key + "_ci"]
                val = f"{a[key] * k:.3g}" if a[key + "_resolved"] else "<"
                parts.append(f"{key.replace('_', ' ')} {val} [{lo * k:.3g}, {hi * k:.3g}] {name} "
                             f"@{a[key + '_tau_s']:.3g} s")
            out.append(f"  {s} {a['axis']}: " + "; ".join(parts))
        if s == "gyro":
            arw = [a["white_density"] * 60 for a in axes]
            out.append("  gyro angle random walk (deg/sqrt(h)): " + ", ".join(f"{v:.3g}" for v in arw))
        if s == "accel":
            vrw = [a["white_density"] * 9.80665 * 60 for a in axes]
            out.append("  accel velocity random walk ((m/s)/sqrt(h)): " + ", ".join(f"{v:.3g}" for v in vrw))
    return "\n".join(out)


def _plot(figs, directory: str, name: str) -> None:
    from ..plots._mpl import pyplot
    plt = pyplot("--plot")
    import numpy as np
    os.makedirs(directory, exist_ok=True)
    for s, axes in figs.items():
        fig, ax = plt.subplots(figsize=(7, 5))
        for a in axes:
            t = np.array(a["taus_s"])
            y = np.array(a["adev"])
            line = ax.loglog(t, y, label=f"{a['axis']}")[0]
            ax.fill_between(t, a["adev_low"], a["adev_high"], color=line.get_color(), alpha=0.25)
            c = a["avar_coef"]
            ax.loglog(t, np.sqrt(c[0] / t + c[1] + c[2] * t), "--", color=line.get_color(), lw=0.8)
        lo, hi = axes[0]["fit_tau_s"]
        ax.axvspan(lo, hi, color="0.9", zorder=0, label="fit range")
        ax.set_xlabel("tau (s)")
        ax.set_ylabel(f"Allan deviation ({ {'accel': 'g', 'gyro': 'deg/s', 'mag': 'gauss'}[s] })")
        ax.set_title(f"{os.path.basename(name)}: {s}")
        ax.grid(True, which="both", lw=0.3)
        ax.legend()
        fig.savefig(os.path.join(directory, f"allan_{s}.png"), dpi=100)
        plt.close(fig)
