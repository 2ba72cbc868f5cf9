"""Gyro and accelerometer diagnosis of single-orientation / few-pose recordings,
from still stretches split in time (the analysis is in :mod:`imucald.gap.series`)."""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence

import numpy as np

from ..fitting.judging.coverage import orientation_groups
from .series import between_block_var, block_noise_var, make_blocks, series_diagnose

__all__ = ["diagnose_single", "MIN_BLOCKS"]

MIN_BLOCKS = 12


def run_groups(slices: Sequence[slice]) -> np.ndarray:
    """The baseline's constant for each still slice: its own.  Two still runs shared one
    constant when their orientations were within 20 deg: a board set down again, or held
    again, rests a fraction of a degree to degrees away (1 deg moves 17 mg across gravity),
    and that step read as a "wandering bias" (an independent probe's null with 8 holds in 6
    orientations: ratio 17, wandering_bias named).  A sensor's drift is still seen inside
    each run; what it does between two runs only is not, nor across a run split by a bump or
    a logger's gap with a move in it (the cost: power on recordings of short rests; and each
    run spends one block on its constant, so runs of one block leave nothing to compare)."""
    return np.arange(len(slices))


def choose_block_s(slices: Sequence[slice], t_s: np.ndarray) -> float:
    """Block length: about 40 blocks over the still time, kept within 4..60 s."""
    still = sum(float(t_s[s.stop - 1] - t_s[s.start]) for s in slices if s.stop - s.start > 1)
    return float(np.clip(still / 40.0, 4.0, 60.0))


def diagnose_single(t_s: np.ndarray, slices: Sequence[slice], acc_means_g: np.ndarray,
                    sensors: Dict[str, np.ndarray], temp_c: Optional[np.ndarray], sims: int,
                    rng) -> Dict[str, Dict[str, object]]:
    """Per sensor ("accel" in g, "gyro" in deg/s), the time-series diagnosis over the still
    ``slices`` (each one still run: the board moved between two of them); ``acc_means_g``
    (one row per slice) counts the orientations.  Each still run has its own constant
    (:func:`run_groups`)."""
    group = run_groups(slices)
    n_orient = int(orientation_groups(acc_means_g).max()) + 1
    block_s = choose_block_s(slices, t_s)
    use_temp = temp_c is not None and np.all(np.isfinite(temp_c))
    res: Dict[str, Dict[str, object]] = {}
    for name, x in sensors.items():
        blk = make_blocks(t_s, x, temp_c if use_temp else None, slices, group, block_s)
        K = len(blk["n"])
        G = len(np.unique(blk["group"])) if K else 0
        if K - G < MIN_BLOCKS - 1:
            # each still stretch spends one block on its constant: what is left is compared
            res[name] = {"verdict": None, "error": f"{K} still blocks of {block_s:.0f} s in {G} still "
                                                     f"stretches leave {K - G} to compare; the time-series "
                                                     f"diagnosis needs {MIN_BLOCKS - 1}: record longer still "
                                                     f"stretches"}
            continue
        ut = use_temp and np.ptp(blk["temp"]) >= 0.5
        noise = block_noise_var(blk)
        # colour beyond a block's length (flicker with time constants of minutes), from the
        # block means themselves; the larger of the two is the twin's block noise
        vb = between_block_var(blk)
        if vb is not None:
            rel = np.median(blk["n"]) / blk["n"]
            noise["var"] = np.maximum(noise["var"], vb[None, :] * rel[:, None])
            noise["adev_block_between"] = np.sqrt(vb)
        unit = "g" if name == "accel" else "dps"
        r = series_diagnose(blk, noise, sims, rng, unit, ut)
        r["block_s"] = round(block_s, 1)
        notes: List[str] = []
        if use_temp and not ut:
            notes.append(f"temperature varied by only {np.ptp(blk['temp']):.2f} C: thermal effects not tested")
        notes.append(f"{n_orient} orientation(s): power reduced against a full pose set; "
                     "effects that need orientation diversity (scale, non-orthogonality, nonlinearity, "
                     "g-sensitivity) are absorbed by one constant per still stretch")
        if name == "accel":
            _accel_classes(r, acc_means_g, n_orient)
        r["notes"] = notes
        res[name] = r
    return res


def _accel_classes(r: Dict[str, object], acc_means_g: np.ndarray, n_orient: int) -> None:
    """In a fixed orientation a change along gravity is a bias or a scale change of that axis
    (g times the scale change); across gravity a bias change or a tilt of the mount."""
    if n_orient != 1:
        return
    u = acc_means_g.mean(0)
    j = int(np.argmax(np.abs(u)))
    ax = "xyz"[j]
    r["along_gravity_axis"] = f"{'+' if u[j] > 0 else '-'}{ax}"
    chosen = r.get("chosen") or []
    if any(c in ("thermal_bias", "bias_drift", "wandering_bias") for c in chosen):
        conf = r.setdefault("confusable", [])
        for c in chosen:
            kind = c.replace("_bias", "").replace("bias_", "")
            conf.append({"effects": [c, c.replace("bias", "scale") + f"_{ax}"],
                         "axis": ax,
                         "why": f"along gravity ({ax}) a {kind} change of the bias and of the {ax} scale "
                                f"factor read the same (1 g x scale change)",
                         "to_separate": f"the same profile with {ax} pointing down (or sideways): a bias "
                                        f"keeps its sign, a scale change flips it"})
        conf.append({"effects": ["bias change", "tilt of the mount"], "axis": "".join(a for a in "xyz" if a != ax),
                     "why": "across gravity a bias change and a small tilt of the board read the same",
                     "to_separate": "a second orientation at each temperature (or the gyro's integrated rate, "
                                    "which a tilt changes)"})
        # the scale-change reading along gravity, for the user's comparison
        for e in r.get("effects", []):
            if e["name"] == "thermal_bias" and e.get("params"):
                k = next(iter(e["params"]))
                c = e["params"][k][j]
                e["as_scale_along_gravity_ppm_per_degC"] = round(float(c / abs(u[j]) * 1e6), 1)
