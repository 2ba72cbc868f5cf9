"""Error rates of the magnetometer's determination rule (imucald/fitting/magcal.py: a hard-
iron component or soft-iron term counts as determined when its standard error is within
2 % of the field, resp. 0.02) on simulated rotations with partial coverage.

Each case: a board's true hard and soft iron and local field (imucald.sim.sensor's
draw_truth, HMC5883L noise and LSB), a 90 s field-direction path at 50 Hz in the sensor
frame, `calibrate_rotation` as `imucald calibrate --sensor mag` runs it.  Paths:
  full         a free tumble over the whole sphere
  capNN        the field direction wandering within NN degrees of one sensor direction
               (tilted about, never rolled over)
  planar       turned round on a table (about the sensor's vertical), 2 deg tilt wobble
  planar10     the same with a 10 deg wobble
  translate    carried about without turning (1 deg wobble) through indoor field
               changes of 3 % of the field (what BROAD's translation trials show)

Figures per path: fits that say "determined" (every term), and per term:
  false determined   declared determined but its error is beyond 3x the rule's limit
                     (6 % of the field, 0.06): the rule let a wrong term through
  z RMS              error / standard error over the declared-determined terms
and, on full tumbles, false undetermined: a term declared undetermined; "before": the
same figure when every term of a cloud that is not flat counts as determined (the code
before the rule).

  nice -n 10 python bench/mag_determination.py --seeds 20
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from imucald.fitting.magcal import (HARD_IRON_SE_MAX, HARD_NAMES, SOFT_IRON_SE_MAX,  # noqa: E402
                                  SOFT_NAMES, calibrate_rotation)
from imucald.sim.sensor import draw_truth                      # noqa: E402
from imucald.specs import MAG                                  # noqa: E402

RATE, DUR = 50.0, 90.0
PATHS = ("full", "cap20", "cap45", "cap60", "cap70", "cap90", "planar", "planar10", "translate")
_IDX = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _smooth(n, rng, k=8, fmax=0.3):
    """(n, 3) sum of k slow sinusoids per axis (0.01-fmax Hz), unit RMS."""
    t = np.arange(n) / RATE
    f = rng.uniform(0.01, fmax, size=(k, 3))
    ph = rng.uniform(0, 2 * np.pi, size=(k, 3))
    a = rng.normal(size=(k, 3))
    x = (a[None] * np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None])).sum(1)
    return x / x.std(0)


def _rotate(d, axis_angle):
    """Rotate unit vectors d (n, 3) by small rotation vectors (n, 3), rad (Rodrigues)."""
    th = np.linalg.norm(axis_angle, axis=1, keepdims=True)
    k = np.where(th > 0, axis_angle / np.maximum(th, 1e-300), 0.0)
    return (d * np.cos(th) + np.cross(k, d) * np.sin(th)
            + k * np.sum(k * d, axis=1, keepdims=True) * (1 - np.cos(th)))


def directions(path, n, rng):
    """Field directions in the sensor frame (n, 3) for a path, and an added field (n, 3)
    in units of the field (indoor changes while carried about)."""
    extra = np.zeros((n, 3))
    if path == "full" or path.startswith("cap"):
        # a random walk of the direction with a smooth turning rate (15-40 deg/s)
        w = _smooth(n, rng) * np.radians(rng.uniform(15, 40)) / RATE
        d = np.empty((n, 3))
        axis = _unit(rng.normal(size=3))
        cap = np.radians(float(path[3:])) if path.startswith("cap") else None
        cur = axis if cap is not None else _unit(rng.normal(size=3))
        for i in range(n):
            nxt = _rotate(cur[None], w[i][None])[0]
            if cap is not None and np.arccos(np.clip(nxt @ axis, -1, 1)) > cap:
                w[i:] *= -1                              # turn back at the cap's rim
                nxt = _rotate(cur[None], w[i][None])[0]
            d[i] = cur = nxt
        return d, extra
    up = _unit(rng.normal(size=3))
    e1 = _unit(np.cross(up, rng.normal(size=3)))
    e2 = np.cross(up, e1)
    dip = np.radians(rng.uniform(30, 70))
    if path.startswith("planar"):
        psi = 2 * np.pi * np.arange(n) / n * rng.uniform(1.5, 3.0)
        d = np.cos(dip) * (np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2) - np.sin(dip) * up
        wob = np.radians(10.0 if path == "planar10" else 2.0)
        return _rotate(d, _smooth(n, rng) * wob / np.sqrt(3)), extra
    d0 = np.cos(dip) * e1 - np.sin(dip) * up                       # translate: one direction
    d = _rotate(np.repeat(d0[None], n, 0), _smooth(n, rng) * np.radians(1.0) / np.sqrt(3))
    return d, 0.03 * _smooth(n, rng, fmax=0.5) / np.sqrt(3)


def case(path, seed, board="9dof"):
    rng = np.random.default_rng(seed)
    tr = draw_truth(board, rng)
    spec = MAG["hmc5883l"]
    n = int(RATE * DUR)
    d, extra = directions(path, n, rng)
    h = tr.field_gauss * (d + extra)
    raw = tr.mag_raw(h) + rng.normal(scale=spec.noise_gauss, size=h.shape)
    raw = np.round(raw / spec.lsb_gauss) * spec.lsb_gauss
    res = calibrate_rotation(raw, "mag_sym", "lm", rng=seed)
    W = tr.mag_soft_iron
    c = np.cbrt(np.linalg.det(W))
    F = tr.field_gauss / c
    true = np.concatenate([tr.mag_hard_iron_gauss, [(W / c)[i, j] for i, j in _IDX]])
    names = list(HARD_NAMES) + list(SOFT_NAMES)
    lim = np.array([HARD_IRON_SE_MAX * F] * 3 + [SOFT_IRON_SE_MAX] * 6)
    cal = res.get("calibration") or res.get("rejected_fit")
    if cal is None:                                  # flat: nothing fitted, nothing determined
        return {"determined": False, "decl": np.zeros(9, bool), "err": np.full(9, np.nan),
                "se": np.full(9, np.nan), "lim": lim, "flat": True}
    est = np.concatenate([cal.params["hard_iron_gauss"], cal.params["soft_iron"]])
    se = np.concatenate([cal.stderr["hard_iron_gauss"], cal.stderr["soft_iron"]])
    und = {u["name"] for u in res.get("undetermined", [])}
    # a field that is not one field (the one-field rule) declares no term determined
    decl = np.array([nm not in und and "inconsistent" not in res for nm in names])
    return {"determined": bool(res["determined"]), "decl": decl, "err": est - true, "se": se, "lim": lim,
            "flat": False}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--paths", default=",".join(PATHS))
    a = ap.parse_args(argv)
    print(f"{'path':10s} {'fits':>4s} {'determined':>10s} {'flat':>4s} {'terms decl. det.':>16s} "
          f"{'false det.':>10s} {'z RMS det.':>10s} {'false undet.':>12s} {'before: false det.':>18s}")
    for path in a.paths.split(","):
        R = [case(path, 5000 + s) for s in range(a.seeds)]
        decl = np.concatenate([r["decl"] for r in R])
        err = np.concatenate([r["err"] for r in R])
        se = np.concatenate([r["se"] for r in R])
        lim = np.concatenate([r["lim"] for r in R])
        bad = decl & (np.abs(err) > 3 * lim)
        z = err[decl] / se[decl]
        fu = f"{np.mean(~decl):.3f}" if path == "full" else "-"
        old = np.concatenate([np.full(9, not r["flat"]) for r in R])       # before the rule
        obad = old & (np.abs(err) > 3 * lim)
        print(f"{path:10s} {len(R):4d} {sum(r['determined'] for r in R):10d} {sum(r['flat'] for r in R):4d} "
              f"{decl.sum():7d} of {len(decl):5d} {bad.sum():6d} ({bad.sum() / max(decl.sum(), 1):.3f}) "
              f"{np.sqrt(np.mean(z * z)) if len(z) else float('nan'):10.2f} {fu:>12s} "
              f"{obad.sum():4d} of {old.sum():4d} ({obad.sum() / max(old.sum(), 1):.2f})", flush=True)


if __name__ == "__main__":
    main()
