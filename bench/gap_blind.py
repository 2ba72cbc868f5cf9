"""Blind test of `imucald gap`, blind in model space (tests/blindgen2.py: effect forms that
are not the library's, magnitudes log-uniform over 0.5x-5x the datasheet figures, random
sample rates, LSBs, latitudes).  Prints a per-class table (hits on the judged sensor, and
for out-of-library classes what they were called), the null false-alarm rate with its 95 %
Clopper-Pearson bound, the gyro's verdicts on the nulls, how often a named coefficient lies
within 3 standard errors of the truth (the injected effect projected onto the named
library form: see truth_check), and the issue-25 acceptance figures in one line each.

Usage: python bench/gap_blind.py [--per-class N] [--nulls M] [--old]
(--old: the previous generator, tests/blindgen.py; no truth column)"""
import argparse
import math
import os
import sys
import time
from collections import Counter, defaultdict

from _common import np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from imucald.errors import UserError  # noqa: E402
from imucald.gap.diagnose import diagnose  # noqa: E402

OMEGA_E_DPS = math.degrees(7.2921e-5)        # IERS Earth rate


def clopper_upper(k, n, conf=0.95):
    """One-sided upper bound of a binomial rate (bisection on the binomial tail)."""
    from math import comb
    if n == 0:
        return 1.0
    lo, hi = k / n, 1.0
    for _ in range(60):
        p = 0.5 * (lo + hi)
        tail = sum(comb(n, i) * p ** i * (1 - p) ** (n - i) for i in range(k + 1))
        lo, hi = (p, hi) if tail > 1 - conf else (lo, p)
    return hi


# --- truth within 3 SE: the injected effect projected onto the named library form ----------
#
# The generator's forms are not the library's, so no coefficient is "the truth" one to one.
# The truth a named coefficient is judged against is the coefficient the library's own form
# takes when fitted, with the diagnosis's weighting, to the NOISE-FREE signal over the
# recording's own poses and temperatures (the projection of the injected effect onto the
# named form; whatever the form cannot follow is misfit in both fits, so the two differ by
# the noise alone, which the standard error describes):
#
# * accelerometer (norm path): the triangular9 baseline plus the named candidate(s) (the
#   variant with the reported parameter count), MAP with the datasheet prior as the
#   diagnosis fits it, on the noise-free pose means (the generator's holds), weights
#   n_k / sigma^2 (the diagnosis's pose-mean variance: a common per-sample variance over
#   n; the flicker's slow part left out);
# * gyro (linear path): bias + Earth's vertical rate + the candidate's columns, weighted
#   least squares on the pose means of the injected effect alone (linear: the rest is the
#   baseline's or noise), weights 1 / (sigma^2 / n_k + the horizontal Earth rate's
#   scatter at the generator's latitude, (Omega cos lat)^2 (1 - u_j^2) / 2, as the twin holds it);
# * magnetometer (norm path): the deployed hard + soft iron model plus the candidate, no
#   prior, on the noise-free still pose means (weights n_k / sigma^2) and the turns (the
#   diagnosis's rotation points stood for by every moving sample, at their total weight),
#   temperature centred where the diagnosis centres it (its points' mean; a curved variant's
#   slope depends on the centre);
# * not projected: the random walk (a stochastic form: its intensity is judged by the
#   reported 95 % interval instead), out-of-library classes (nothing is the truth there).


def _pose_stats(lab, rec_t):
    pid = lab["pose_id"]
    K = int(pid.max()) + 1
    masks = [pid == k for k in range(K)]
    n = np.array([m.sum() for m in masks], float)
    mean = lambda a: np.array([np.asarray(a)[m].mean(0) for m in masks])
    tmid = mean(rec_t)
    temp = mean(lab["temp_true_c"])
    return masks, n, mean, tmid, temp


def _ctx(tmid, temp):
    from imucald.gap.candidates import hat_columns
    return {"t": tmid - tmid.min(), "dt": tmid - tmid.mean(), **hat_columns(tmid), "temp": temp,
            "dT": temp - temp.mean()}


def _named(r, verdict):
    """[(name, q)] of the named parametric effect(s) and their coefficients and standard errors
    as flat arrays; None (with the reason) when they cannot be compared."""
    names = verdict.split("+")
    if len(names) == 1:
        e = next((e for e in r.get("effects", []) if e["name"] == names[0]), None)
        if e is None or e.get("stochastic") or not e.get("stderr"):
            return None, ("named the random-walk form (no coefficient)" if e is not None and e.get("stochastic")
                         else "no coefficients")
        keys = list(e["params"])
        return ([(names[0], int(e["q"]))], np.concatenate([e["params"][k] for k in keys]),
                np.concatenate([e["stderr"][k] for k in keys])), None
    j = r.get("joint")
    if not j or list(j["effects"]) != names:
        return None, "pair without its joint fit"
    return ([(names[0], None), (names[1], None)], np.asarray(j["params"], float),
            np.asarray(j["stderr"], float)), None


def _bases(r, verdict):
    """Each named member's visible basis (q, k) where the search fitted only the combinations
    of its coefficients the data see (gap/search.py VisiblePart), else None."""
    b = (r.get("joint") or {}).get("visible_bases") if "+" in verdict else None
    return [None if v is None else np.asarray(v, float) for v in b] if b else None


def _variants(cands, named, q_total):
    """The candidate objects of ``named`` [(name, q or None)]; None when the parameter count
    leaves the variants ambiguous (a pair reports only its total)."""
    import itertools
    opts = [[c for c in cands if c.name == nm and (q is None or c.q == q)] for nm, q in named]
    combos = [cs for cs in itertools.product(*opts) if sum(c.q for c in cs) == q_total]
    return combos[0] if len(combos) == 1 else None


def project_accel(cs, lab, rec_t, bases=None):
    """Coefficients of candidates ``cs`` (with the triangular9 baseline, MAP) fitted to the
    noise-free accelerometer pose means (see above); with ``bases`` (a (q, k) matrix or None
    per candidate) each fitted in the combinations V xi the diagnosis fitted, and mapped back."""
    from scipy.optimize import least_squares
    from imucald.fitting.fit import accel_prior
    from imucald.fitting.models.accel import Triangular9
    from imucald.fitting.solvers.lsq import Problem, lm
    masks, n, mean, tmid, temp = _pose_stats(lab, rec_t)
    x = mean(lab["noise_free"]["acc"])
    ctx = _ctx(tmid, temp)
    model = Triangular9()
    pm, ps = accel_prior(model, None)      # the board is not a known chip: the generic prior
    sw = np.sqrt(n) / lab["noise_sd"]["acc"]
    Vs = [np.eye(c.q) if V is None else V for c, V in zip(cs, bases or [None] * len(cs))]
    qs = [V.shape[1] for V in Vs]

    def fun(z):
        th, xx, o = z[:9], x.copy(), 9
        for c, V, q in zip(cs, Vs, qs):
            xx = xx - c.delta(V @ z[o:o + q], x, th, ctx)
            o += q
        return np.concatenate([(1.0 - model.norms(th, xx)) * sw, (th - pm) / ps])
    z0 = np.concatenate([lm(Problem(model, x)).theta] + [np.zeros(q) for q in qs])
    xi = least_squares(fun, z0, method="lm", xtol=1e-14, ftol=1e-14).x[9:]
    return np.concatenate([V @ xi[o:o + q] for V, q, o in zip(Vs, qs, np.cumsum([0] + qs[:-1]))])


def project_mag(cs, lab, rec_t, n_rot, centre_c=None):
    """Coefficients of candidates ``cs`` (with the deployed hard + soft iron model, no prior,
    as the diagnosis fits the magnetometer) fitted to the noise-free still pose means and
    the turns: the diagnosis's ``n_rot`` rotation points (single samples thinned over the
    sphere, weight 1 / sigma^2 each) stand here as every moving sample at weight
    n_rot / (moving samples) / sigma^2, and temperature is centred as the diagnosis centres
    it (the plain mean over its points, pose means and rotation points alike)."""
    from scipy.optimize import least_squares
    from imucald.fitting.models.mag import MagModel
    from imucald.fitting.solvers.lsq import sphere_fit
    from imucald.gap.candidates import hat_columns
    masks, n, mean, tmid, temp = _pose_stats(lab, rec_t)
    mov = lab["pose_id"] < 0
    M = int(mov.sum())
    x = np.vstack([mean(lab["noise_free"]["mag"]), lab["noise_free"]["mag"][mov]])
    T = np.concatenate([temp, lab["temp_true_c"][mov]])
    tt = np.concatenate([tmid, np.asarray(rec_t)[mov]])
    wpt = np.concatenate([np.ones(len(n)), np.full(M, n_rot / max(M, 1))])    # points' share
    centre = float(np.sum(wpt * T) / np.sum(wpt)) if centre_c is None else centre_c
    ctx = {"t": tt - tt.min(), "dt": tt - np.sum(wpt * tt) / np.sum(wpt), **hat_columns(tt),
           "temp": T, "dT": T - centre}
    model = MagModel("sym")
    sw = np.sqrt(np.concatenate([n, np.full(M, n_rot / max(M, 1))])) / lab["noise_sd"]["mag"]
    qs = [c.q for c in cs]
    p0 = model.k

    def fun(z):
        th, xx, o = z[:p0], x.copy(), p0
        for c, q in zip(cs, qs):
            xx = xx - c.delta(z[o:o + q], x, th, ctx)
            o += q
        return (1.0 - model.norms(th, xx)) * sw
    c0, rad = sphere_fit(x)
    kd = min(model.kw, 3)
    th0 = np.concatenate([[1.0 / rad] * kd, np.zeros(model.kw - kd), c0])
    z0 = np.concatenate([th0] + [np.zeros(q) for q in qs])
    return least_squares(fun, z0, method="lm", xtol=1e-14, ftol=1e-14).x[p0:]


def project_gyro(cs, lab, rec_t):
    """Coefficients of candidates ``cs`` (bias + Earth's vertical rate baseline) fitted by
    weighted least squares to the pose means of the injected gyro effect (see above)."""
    from imucald.fitting.models.accel import Triangular9
    from imucald.fitting.solvers.lsq import Problem, lm
    from imucald.gap.candidates import kron_cols
    masks, n, mean, tmid, temp = _pose_stats(lab, rec_t)
    xa = mean(lab["noise_free"]["acc"])
    t9 = Triangular9()
    ctx = _ctx(tmid, temp)
    ctx["acc_dir"] = t9.forward(lm(Problem(t9, xa)).theta, xa)
    u = ctx["acc_dir"] / np.linalg.norm(ctx["acc_dir"], axis=1, keepdims=True)
    y = mean(lab["effect"]["gyro"]).reshape(-1)
    N = len(n)
    X = np.hstack([kron_cols(np.ones(N)), u.reshape(-1, 1)] + [c.columns(ctx) for c in cs])
    h2 = (OMEGA_E_DPS * math.cos(math.radians(lab["latitude_deg"]))) ** 2
    var = (lab["noise_sd"]["gyro"] ** 2 / n)[:, None] + h2 * (1 - u ** 2) / 2
    sw = 1 / np.sqrt(var.reshape(-1))
    return np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)[0][4:]


def _centre(r):
    """The diagnosis's own temperature centre (mean over its points' temperatures, from the
    plotting data it returns), or None when the result does not carry them."""
    T = (r.get("_plot") or {}).get("temp")
    return None if T is None else float(np.mean(T))


def truth_check(res, lab, rec_t):
    """{"z": z-scores of the named coefficients against the projected truth} or {"skip": why};
    for a named random walk {"ci_hit": truth inside the reported 95 % interval}."""
    sensor = lab["sensor"]
    r = res["sensors"][sensor]
    v = r["verdict"]
    if lab["class"] == "random_walk":
        e = next((e for e in r.get("effects", []) if e.get("stochastic")), None)
        if v != "wandering_bias" or e is None:
            return {"skip": "random walk not named as one"}
        lo, hi = e["random_walk"]["intensity_ci95"]
        q = lab["truth"]["random_walk_intensity_g^2/s"]
        est = e["params"][next(iter(e["params"]))][0]
        return {"ci_hit": (lo is None or lo <= q) and (hi is None or q <= hi), "ratio": est / q}
    named, why = _named(r, v) if v not in ("none", "unexplained", "partially_explained") else (None, "nothing named")
    if named is None:
        return {"skip": why}
    names, coef, se = named
    from imucald.gap.candidates import ACCEL_CANDIDATES, GYRO_CANDIDATES, MAG_CANDIDATES
    if sensor in ("accel", "mag"):
        cs = _variants(ACCEL_CANDIDATES if sensor == "accel" else MAG_CANDIDATES, names, len(coef))
        if cs is None:
            return {"skip": "variant ambiguous"}
        if sensor == "mag" and _bases(r, v):
            return {"skip": "magnetometer pair fitted in visible parts (no projection written)"}
        proj = (project_accel(cs, lab, rec_t, _bases(r, v)) if sensor == "accel" else
                project_mag(cs, lab, rec_t, int(r.get("points", {}).get("rotation_points", 0)), _centre(r)))
    else:
        # one variant per gyro class; g-sensitivity is reported as the 9 elements of its
        # traceless matrix (the 8 coefficients on the TRACELESS basis mapped back)
        from imucald.gap.candidates import TRACELESS
        cs = [next(c for c in GYRO_CANDIDATES if c.name == nm) for nm, _ in names]
        beta, proj, o = project_gyro(cs, lab, rec_t), [], 0
        for c in cs:
            proj.append(TRACELESS @ beta[o:o + c.q] if c.name == "g_sensitivity" else beta[o:o + c.q])
            o += c.q
        proj = np.concatenate(proj)
        if len(proj) != len(coef):
            return {"skip": "parameter count differs"}
    return {"z": (coef - proj) / np.maximum(se, 1e-300), "coef": coef, "proj": proj, "se": se}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-class", type=int, default=10)
    ap.add_argument("--nulls", type=int, default=200, help="null recordings over the null classes")
    ap.add_argument("--old", action="store_true", help="the previous generator (tests/blindgen.py)")
    args = ap.parse_args()
    if args.old:
        from tests import blindgen as G
        nulls = [c for c in G.CLASSES if c.endswith("null")]
        library = [c for c in G.CLASSES if c not in nulls and c not in ("cubic", "triple_product", "hysteresis")]
        outside = ["cubic", "triple_product", "hysteresis"]
    else:
        from tests import blindgen2 as G
        nulls, library, outside = G.NULLS, G.LIBRARY, G.OUTSIDE
    hits = defaultdict(lambda: [0, 0])
    called = defaultdict(Counter)
    gyro_none = [0, 0]
    false_alarm = [0, 0]
    below_white = {False: [0, 0], True: [0, 0]}   # accel nulls: an axis's pose variance "below white"
    zs = defaultdict(list)            # class -> z-scores of every named coefficient
    rec_ok = defaultdict(lambda: [0, 0])   # class -> recordings with every |z| <= 3, compared
    ci = defaultdict(lambda: [0, 0])  # random walk: truth inside the reported 95 % interval
    ci_ratio = defaultdict(list)      # random walk: estimated over injected intensity
    skipped = defaultdict(Counter)
    times = []
    plan = [(k, s) for k in library + outside for s in range(args.per_class)]
    plan += [(nulls[i % len(nulls)], 1000 + i) for i in range(args.nulls)]
    for kind, seed in plan:
        t = time.perf_counter()
        rec, lab = G.make_case(kind, seed)
        try:
            res = diagnose(rec, sims=100, seed=seed)
            v = res["sensors"][lab["sensor"]]["verdict"]
        except UserError as e:
            res, v = None, f"error: {str(e)[:60]}"
        times.append(time.perf_counter() - t)
        h = G.hit(v, lab["expect"])
        hits[kind][0] += h
        hits[kind][1] += 1
        called[kind][v] += 1
        if kind in nulls:
            false_alarm[0] += v != "none"
            false_alarm[1] += 1
            if res and lab["sensor"] == "accel":
                pmv = res["sensors"]["accel"].get("noise_colour", {}).get("pose_mean_variance", {})
                bw = bool(np.any(pmv.get("axes_below_white", [False])))
                below_white[v != "none"][0] += bw
                below_white[v != "none"][1] += 1
            if res and "gyro" in res["sensors"]:
                gyro_none[0] += res["sensors"]["gyro"]["verdict"] != "none"
                gyro_none[1] += 1
        if kind in library and res is not None and "pose_id" in lab:
            tc = truth_check(res, lab, rec.t)
            if "z" in tc:
                zs[kind].extend(np.abs(tc["z"]).tolist())
                rec_ok[kind][0] += bool(np.all(np.abs(tc["z"]) <= 3))
                rec_ok[kind][1] += 1
            elif "ci_hit" in tc:
                ci[kind][0] += bool(tc["ci_hit"])
                ci[kind][1] += 1
                ci_ratio[kind].append(tc["ratio"])
            else:
                skipped[kind][tc["skip"]] += 1
        if not h and kind not in outside:
            print(f"  miss: {kind} seed {seed}: {lab['sensor']} verdict {v!r}, expected {sorted(lab['expect'])}",
                  flush=True)
    print(f"{'class':26s}{'kind':10s}{'hits':>8s}   what it was called")
    for group, ks in (("null", nulls), ("library", library), ("outside", outside)):
        for k in ks:
            if hits[k][1]:
                calls = ", ".join(f"{v} {c}" for v, c in called[k].most_common())
                print(f"{k:26s}{group:10s}{hits[k][0]:4d}/{hits[k][1]:<3d}   {calls}")
    k, n = false_alarm
    print(f"null false alarms (judged sensor): {k}/{n} = {k / max(n, 1):.1%} "
          f"(95 % upper bound {clopper_upper(k, n):.1%})")
    print(f"gyro false alarms on the nulls: {gyro_none[0]}/{gyro_none[1]}")
    (a0, n0), (a1, n1) = below_white[False], below_white[True]
    if n0 + n1:
        print(f"accelerometer nulls whose pose-mean variance was estimated below the white figure on "
              f"some axis (gap/posenoise.py): {a1}/{n1} of the false alarms, {a0}/{n0} of the others")
    if not args.old:
        print()
        print("truth within 3 SE: each named coefficient against the injected effect projected onto the")
        print("named form (noise-free fit, the diagnosis's weighting: see truth_check); by chance |z| > 3")
        print("for 0.27 % of Gaussian coefficients (fewer: the standard errors are scaled up by any misfit)")
        print(f"{'class':26s}{'coefs |z|<=3':>14s}{'recordings':>12s}{'median |z|':>12s}{'max |z|':>9s}   not compared")
        for kd in library:
            z = np.array(zs[kd])
            rest = ", ".join(f"{why} {c}" for why, c in skipped[kd].most_common()) or "-"
            if ci[kd][1]:
                rr = np.array(ci_ratio[kd])
                print(f"{kd:26s}{'':14s}{'':12s}{'':12s}{'':9s}   " + ("" if rest == "-" else rest + "; ")
                      + "no coefficient (a stochastic form): "
                      f"the injected intensity inside the reported 95 % interval {ci[kd][0]}/{ci[kd][1]}, "
                      f"estimate / injected median {np.median(rr):.2f} (range {rr.min():.2f}-{rr.max():.2f})")
            elif len(z):
                print(f"{kd:26s}{int(np.sum(z <= 3)):>8d}/{len(z):<5d}{rec_ok[kd][0]:>6d}/{rec_ok[kd][1]:<5d}"
                      f"{np.median(z):>12.2f}{z.max():>9.2f}   {rest}")
            else:
                print(f"{kd:26s}{'-':>14s}{'-':>12s}{'':12s}{'':9s}   {rest}")
        print("out-of-library classes: no truth to project onto (their forms are not the library's)")
        allz = np.concatenate([np.array(zs[kd]) for kd in library if zs[kd]] or [np.zeros(0)])
        if len(allz):
            qs = np.quantile(allz, [0.5, 0.9, 0.99])
            print(f"all named coefficients: {int(np.sum(allz <= 3))}/{len(allz)} within 3 SE; |z| quantiles "
                  f"50/90/99 %: {qs[0]:.2f} / {qs[1]:.2f} / {qs[2]:.2f} (Gaussian: 0.67 / 1.64 / 2.58)")
    print()
    print("acceptance (issue 25):")
    low = [f"{kd} {hits[kd][0]}/{hits[kd][1]}" for kd in library if hits[kd][0] < 0.9 * hits[kd][1]]
    print(f"  library classes named >= 9/10: {len(library) - len(low)} of {len(library)}"
          + (f" (below: {', '.join(low)})" if low else ""))
    print(f"  out-of-library classes reported with what they are called: {len(outside)} (table above)")
    k, n = false_alarm
    print(f"  null false alarms <= 2 % on >= 200 nulls: {k}/{n} = {k / max(n, 1):.1%}, 95 % upper bound "
          f"{clopper_upper(k, n):.1%} (" + ("fewer than 200 nulls" if n < 200 else
                                            f"{'met' if k / n <= 0.02 else 'not met'} as a point figure; "
                                            f"{'shown' if clopper_upper(k, n) <= 0.02 else 'not shown'} "
                                            f"at 95 % confidence") + ")")
    if not args.old:
        allz = np.concatenate([np.array(zs[kd]) for kd in library if zs[kd]] or [np.zeros(0)])
        nr = sum(v[1] for v in rec_ok.values())
        print(f"  truth within 3 SE for named coefficients: {int(np.sum(allz <= 3))}/{len(allz)} coefficients, "
              f"{sum(v[0] for v in rec_ok.values())}/{nr} recordings with every coefficient inside")
    print(f"per recording: median {np.median(times):.2f} s over {len(times)}")

if __name__ == "__main__":
    main()
