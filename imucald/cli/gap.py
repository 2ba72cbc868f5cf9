"""``imucald gap``: the sim-to-real gap diagnosis and its text summary."""
from __future__ import annotations

import json

import numpy as np

from ..errors import CannotCreate, UserError
from ._common import print_json


def _values(pv, se=None) -> str:
    """A coefficient vector as text: a+-se each, or one figure when every axis shares it;
    a scalar (e.g. a spline's knot count) or anything else as it is."""
    if isinstance(pv, (int, float)):
        return f"{pv:.3g}" if isinstance(pv, float) else str(pv)
    if not isinstance(pv, (list, tuple)) or not all(isinstance(a, (int, float)) for a in pv):
        return str(pv)
    pv = list(pv)
    if se is not None and not (isinstance(se, (list, tuple)) and len(se) == len(pv)):
        se = None
    if se is None:
        return f"{pv[0]:.3g}" if len(set(pv)) == 1 else f"[{', '.join(f'{a:.3g}' for a in pv)}]"
    return f"[{', '.join(f'{a:.3g}+-{b:.2g}' for a, b in zip(pv, se))}]"


def _param_text(params, stderr) -> str:
    return "; ".join(f"{k} = {_values(v, (stderr or {}).get(k))}" for k, v in params.items())


def _effect_lines(r) -> list:
    """The named members of the verdict (the combination search's joint fit, both tests' p-values),
    then any other effect significant when fitted alone; without members, the fits as made."""
    members = (r.get("search") or {}).get("members") or []
    lines, named = [], {m["name"] for m in members}
    for m in members:
        tests = (f"coefficient p = {m['coefficient_p_value']:.2g}, held-out p = "
                 f"{m['heldout_p_value']:.2g}")
        txt = _param_text(m.get("params", {}), m.get("stderr"))
        ci = (m.get("random_walk") or {}).get("q_ci95")
        if ci:
            txt += f" (95 % interval {ci[0]:.3g} .. {ci[1]:.3g})"
        lines.append(f"  {m['name']} ({'joint fit; ' if len(members) > 1 else ''}{tests}): {txt}")
    alone = [ef for ef in r["effects"] if ef.get("significant") and ef["name"] not in named]
    for ef in alone:        # without members (the time-series path), the fits as they were made
        what = " (also significant alone)" if members else ""
        if ef.get("step", 1) > 1:   # the time-series path's second step: beside the first's effect
            what += f" (beside {'+'.join(r.get('chosen', [])[:ef['step'] - 1])})"
        lines.append(f"  {ef['name']}{what}: ratio after {ef['ratio_after']:.2f}, "
                     f"{_param_text(ef['params'], ef.get('stderr'))}")
    return lines


def gap_summary(res) -> str:
    mode = res.get("mode")
    lines = [f"{res['poses_found']} still poses"
             + (" (found from the magnetometer: no accelerometer)" if mode == "magnetometer_only" else
                f" in {res['orientations']} orientation(s): time-series diagnosis" if mode else "")
             + (f"; left out as disturbed: {res['poses_left_out']}" if res.get("poses_left_out") else "")]
    for s, r in res["sensors"].items():
        u = r.get("unit", "")
        k = 1e3 if u == "g" else 1.0
        uu = "mg" if u == "g" else u
        v = r["verdict"]
        if v == "partially_explained":
            v += f" (by {r['partially_explained_by']}: shrink {r['shrink']:.2f})"
        elif r.get("explained"):
            v += f" ({r['explained']}: shrink {r['shrink']:.2f})"
        if "points" in r:       # points of unequal noise (pose means and rotation samples)
            rms = (f"; {r['points']['still_pose_means']} pose means and {r['points']['rotation_points']} "
                   f"rotation points, held-out residual {r['heldout_rms_normalised']:.3g} noise sd vs "
                   f"the twin's {r['twin_heldout_rms_normalised']:.3g}")
        elif "heldout_rms" in r:
            rms = (f"; held-out residual {r['heldout_rms'] * k:.4g} {uu} vs the twin's "
                   f"{r['twin_heldout_rms'] * k:.4g} {uu}")
        else:
            rms = f"; {r['blocks']} blocks of {r['block_s']} s"
        lines.append(f"{s}: verdict {v}{rms}: ratio {r['ratio_before']:.2f} -> "
                     f"{r['ratio_after']:.2f}; chi-square p = {r['p_value']:.3g}"
                     + (f" (log10 p = {r['log10_p_value']})" if r['p_value'] == 0 else ""))
        lines += _effect_lines(r)
        qn = r.get("points", {}).get("quiet_noise")
        if qn:
            lines.append(f"  magnetometer noise {np.round(np.asarray(qn['sigma']) * 1e3, 2).tolist()} mG per sample, "
                         f"from {qn['source']}")
        for c in r.get("confusable", []):
            why = (f"correlation {c['canonical_correlation']}" if "canonical_correlation" in c
                   else c.get("why", ""))
            lines.append(f"  cannot tell {' from '.join(c['effects'])} apart here ({why}); "
                         f"to separate them: {c['to_separate']}")
        w = r.get("where", {})
        # the excess (normalised residual^2 - 1) by orientation says where a gap lies: only
        # when there is one (with no gap, or nothing above the noise, the shares are all 0 %)
        if w.get("region_share") and r["verdict"] != "none" and max(w["region_share"].values()) > 0:
            top = [kv for kv in sorted(w["region_share"].items(), key=lambda kv: -kv[1])[:3] if kv[1] > 0]
            lines.append("  excess by orientation: " + ", ".join(f"{a} {b:.0%}" for a, b in top))
        if r.get("note"):
            lines.append(f"  note: {r['note']}")
        for n in r.get("notes", []):
            lines.append(f"  note: {n}")
    for n in res.get("notes", []):
        lines.append(f"note: {n}")
    return "\n".join(lines)


def cmd_gap(args) -> int:
    from ..gap.diagnose import diagnose
    from ._common import read_input
    kind, rec = read_input(args, args.recording)
    if kind != "recording":
        raise UserError(f"{args.recording}: gap needs samples (a recording), not pose averages")
    if args.report:         # created before the diagnosis, so a bad place fails at once
        import os
        try:
            os.makedirs(args.report, exist_ok=True)
        except OSError as e:
            raise CannotCreate(f"--report {args.report}: cannot create the directory: {e.strerror}") from None
    try:
        res = diagnose(rec, args.sensor, sims=args.sims, seed=args.seed, name=args.recording)
    except UserError as e:
        if not args.json:
            raise
        # under --json the answer is one JSON object, an error included (exit status kept)
        print(json.dumps({"error": str(e), "exit_code": e.exit_code}))
        return e.exit_code
    if args.report:
        from ..gap.report import write_report
        try:
            write_report(res, args.report)
        except OSError as e:
            raise CannotCreate(f"--report {args.report}: cannot write: {e.strerror}") from None
    for r in res["sensors"].values():
        r.pop("_plot", None)
    if args.json:
        print_json(res)
    else:
        print(gap_summary(res))
    return 0

