"""The gyro's combination search (imucald/gap/gyrosearch.py, issue 25 items 3-4): forward and
backward steps over the gyro candidates, each member named only when its Wald test and its
held-out shrink test both pass.

Pose means are drawn directly from the linear model the diagnosis fits (a bias per axis,
Earth's rate with its vertical part along the accelerometer's up and its horizontal part of
random azimuth, white pose-mean noise), so the truth of every coefficient is known exactly
and the noise model is the twin's own.
"""
import math

import numpy as np
import pytest

from imucald.gap import gyrosearch
from imucald.gap.candidates import GYRO_CANDIDATES
from imucald.gap.earth import EARTH_RATE_DPS
from imucald.gap.linear import gyro_baseline, gyro_diag
from imucald.gap.search import backward
from imucald.fitting.judging.levels import GAP_HELDOUT_LEVEL

SD_DPS = 0.002          #: pose-mean noise, dps (an MPU-6050 at 0.005 dps/rtHz over ~6 s)


def pose_means(seed, n=30, thermal_dps_c=None, gsens_dps_g=None, drift_dps_s=None, extra=None, quiet=False):
    """(g (N, 3) dps, gvar (N, 3), ctx) for a heat-then-cool session of ``n`` poses (``quiet``:
    without the noise and Earth's horizontal rate)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = np.sort(rng.uniform(0, 900, n))
    temp = 20 + 12 * np.sin(np.pi * t / 900) ** 1.5
    lat = math.radians(rng.uniform(-60, 60))
    h = rng.normal(size=(n, 3))
    h -= np.sum(h * u, 1, keepdims=True) * u                     # horizontal, random azimuth
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    g = rng.normal(0, 0.5, 3) + EARTH_RATE_DPS * (math.sin(lat) * u + (not quiet) * math.cos(lat) * h)
    if thermal_dps_c is not None:
        g = g + (temp - temp.mean())[:, None] * thermal_dps_c
    if gsens_dps_g is not None:
        g = g + u @ np.asarray(gsens_dps_g).T
    if drift_dps_s is not None:
        g = g + (t - t.mean())[:, None] * drift_dps_s
    if extra is not None:
        g = g + extra(u)
    g = g + (not quiet) * rng.normal(0, SD_DPS, (n, 3))
    ctx = {"t": t - t.min(), "dt": t - t.mean(), "temp": temp, "dT": temp - temp.mean(), "acc_dir": u}
    return g, np.full((n, 3), SD_DPS ** 2), ctx


#: with a trace: its isotropic part reads as Earth's vertical rate (beyond Earth's rate, which
#: the twin caps), only the traceless part is the named g-sensitivity
G_TRUE = np.array([[0.02, -0.05, 0.01], [0.04, 0.0, -0.03], [-0.02, 0.05, 0.03]])   # dps/g
C_TRUE = np.array([0.004, -0.006, 0.003])                                          # dps/degC


@pytest.mark.parametrize("seed", range(4))
def test_a_thermal_and_g_sensitivity_pair_is_named_with_both_members(seed):
    """Seen to fail (verdict "g_sensitivity" alone) with the search held to one member
    (gyrosearch.MAX_MEMBERS = 1; before the search the gyro named a single effect), and
    (seed 2: "mostly", ratio 1.33) with Earth's horizontal share in the twin from the fitted
    vertical rate's unscaled standard error (linear.gyro_baseline: the g-sensitivity the
    baseline misses pulled the vertical rate past its cap).
    Each named coefficient lies within 4 standard errors of the truth (the traceless part of
    G: its trace reads as Earth's vertical rate; the thermal slope), the curvature of a curved
    thermal variant within 4 SE of zero (noise model exact: 4 SE over 22 coefficients is
    passed by chance with probability 0.9986)."""
    g, gv, ctx = pose_means(100 + seed, thermal_dps_c=C_TRUE, gsens_dps_g=G_TRUE)
    out = gyro_diag(g, gv, ctx, 200, np.random.default_rng(seed), {})
    assert set(out["verdict"].split("+")) == {"thermal_bias", "g_sensitivity"}, out["search"]["steps"]
    assert out["explained"] == "closed"
    lvl = out["search"]["coefficient_level"]
    truth = {"g_sensitivity_dps/g": (G_TRUE - np.trace(G_TRUE) / 3 * np.eye(3)).ravel(),
             "thermal_bias_dps/degC": C_TRUE, "thermal_bias_curvature_dps/degC^2": np.zeros(3)}
    for m in out["search"]["members"]:
        assert m["coefficient_p_value"] < lvl and m["heldout_p_value"] < GAP_HELDOUT_LEVEL
        for k, v in m["params"].items():
            z = (np.asarray(v) - truth[k.split(" ")[0]]) / np.asarray(m["stderr"][k])
            assert np.all(np.abs(z) < 4), (k, z)


def test_backward_drops_a_member_no_longer_significant_given_the_others():
    """Seen to fail with the backward step removed (search.backward returning the model unchanged):
    a drift fitted beside a g-sensitivity on data without drift stays named."""
    g, gv, ctx = pose_means(7, gsens_dps_g=G_TRUE)
    b = gyro_baseline(g, gv, ctx, 200, np.random.default_rng(0))
    s = gyrosearch.GyroSearch(b, {id(c): c.columns(ctx) for c in GYRO_CANDIDATES}, np.random.default_rng(1),
                              gyrosearch.coef_level({c.name: 1 for c in GYRO_CANDIDATES}))
    gs, dr = (next(c for c in GYRO_CANDIDATES if c.name == k) for k in ("g_sensitivity", "bias_drift"))
    steps = []
    end = backward(s, s.fit((gs, dr)), steps, set())
    assert end.names == ["g_sensitivity"]
    assert [st["step"] for st in steps] == ["drop bias_drift"]


def test_single_effects_name_one_member_and_nulls_none():
    """A single effect (g-sensitivity, thermal bias or drift, 10 datasets each) is named alone
    and 10 nulls name nothing.  The search's rate of a false member is at most
    GAP_ATTRIBUTION_LEVEL (1 %) by its union bound, so all 40 pass with probability >= 0.67 and
    at most one misses with >= 0.94; allowed: 1.  Seen to fail (30 of 30 effects "unexplained")
    with the held-out draws scaled by the variance instead of the standard deviation in
    GyroSearch (the twins then far too small).  With the held-out test skipped and the Wald
    level not split it still passed (0 of 40 wrong): the false-member rate those guard is
    below what 40 datasets show; the held-out test's own level is checked below."""
    wrong = []
    for k in range(10):
        for what, kw in (("g_sensitivity", {"gsens_dps_g": G_TRUE}), ("thermal_bias", {"thermal_dps_c": C_TRUE}),
                         ("bias_drift", {"drift_dps_s": np.array([2e-5, -3e-5, 1e-5])}), ("none", {})):
            g, gv, ctx = pose_means(300 + k, **kw)
            v = gyro_diag(g, gv, ctx, 100, np.random.default_rng(k), {})["verdict"]
            if v != what:
                wrong.append((k, what, v))
    assert len(wrong) <= 1, wrong


def test_heldout_shrink_test_keeps_its_level_on_a_member_that_is_absent():
    """The held-out test of a drift added to a g-sensitivity model, on data with no drift:
    P(p < GAP_HELDOUT_LEVEL) must be at most the level.  1640 datasets: at most 23 (passes with
    probability 0.96 at 1 %, 0.05 at 2 %; measured 13).  Seen to fail (648 of 1640) with the
    draws scaled by the variance instead of the standard deviation in GyroSearch."""
    gs, dr = (next(c for c in GYRO_CANDIDATES if c.name == k) for k in ("g_sensitivity", "bias_drift"))
    g0, gv, ctx = pose_means(11, gsens_dps_g=G_TRUE)
    mean = pose_means(11, gsens_dps_g=G_TRUE, quiet=True)[0].reshape(-1)
    cols = {id(c): c.columns(ctx) for c in (gs, dr)}
    rng = np.random.default_rng(5)
    b = gyro_baseline(g0, gv, ctx, 50, rng)
    hits = 0
    old = gyrosearch.HELDOUT_SIMS
    gyrosearch.HELDOUT_SIMS = 400         # any count keeps a Monte Carlo p-value's level
    try:
        s = gyrosearch.GyroSearch(b, cols, np.random.default_rng(6), 1.0)
        for k in range(1640):
            s.Y[:, 0] = mean + rng.normal(size=g0.size) * np.sqrt(b.var)   # the data, the twin's noise model
            s.cache.clear()
            hits += s.heldout_p(s.fit((gs,)), s.fit((gs, dr))) < GAP_HELDOUT_LEVEL
    finally:
        gyrosearch.HELDOUT_SIMS = old
    assert hits <= 23, hits


def test_an_effect_outside_the_library_is_unexplained_with_where_it_lies():
    """A bias that follows the product of two up components (even in the orientation: no
    linear g-sensitivity, thermal bias or drift follows it) is "unexplained", with its excess
    placed by orientation.  Seen to fail (KeyError 'region_share') with the gyro's "where" as it
    was (linear_where: axis shares and trends only).  Breaking the tests themselves (held-out
    test skipped, covariance not scaled by the excess) still left it "unexplained": no
    candidate lowers the held-out RMS of a form even in the orientation."""
    quad = lambda u: 0.03 * np.stack([u[:, 1] * u[:, 2], u[:, 2] * u[:, 0], u[:, 0] * u[:, 1]], 1)
    g, gv, ctx = pose_means(21, extra=quad)
    out = gyro_diag(g, gv, ctx, 200, np.random.default_rng(0), {})
    assert out["verdict"] == "unexplained" and not out["search"]["members"]
    assert set(out["where"]["region_share"]) <= {f"{s}{a} up" for s in "+-" for a in "XYZ"}
    assert abs(sum(out["where"]["region_share"].values()) - 1) < 0.01


@pytest.mark.parametrize("seed", range(3))
def test_diagnose_names_a_simulated_gyro_pair(seed):
    """End to end (the simulator's MPU-6050 session, 24 poses, heat then cool, a thermal bias of
    0.01 dps/degC and a g-sensitivity of 0.05 dps/g, through diagnose's pose detection, turn
    trimming and pose-mean noise): both members named.  Seen to fail (one member named) with
    the search held to one member (gyrosearch.MAX_MEMBERS = 1)."""
    from imucald.gap.diagnose import diagnose
    from imucald.sim.effects import effect_session
    from imucald.sim.orientations import random_pose_set
    g = np.random.default_rng(seed)
    s, _ = effect_session("mpu6050", random_pose_set(24, g), g,
                          [("gyro.thermal_bias", 0.01), ("gyro.g_sensitivity", 0.05)], rate_hz=50,
                          hold_s=(5, 7), move_s=(1.5, 2.5), temp_kind="heatcool", temp_rise_c=10)
    r = diagnose(s.recording, sensors=["gyro"], sims=100, seed=seed)["sensors"]["gyro"]
    assert set(r["verdict"].split("+")) == {"thermal_bias", "g_sensitivity"}, r["search"]["steps"]
    assert r["joint"]["effects"] == r["verdict"].split("+")


def test_the_search_generator_is_the_one_generator_spawn_makes():
    """The search draws from a child of the diagnosis's generator made as numpy >= 1.25's
    ``Generator.spawn`` makes it, from the seed sequence, so numpy 1.21-1.24 (Raspberry Pi OS
    bookworm's 1.24 has no ``Generator.spawn``) give the same verdicts, and the parent's own
    stream (the magnetometer's twins) is left as it was.  Fails if the child is seeded from
    the parent's draws (the fallback it had), which advances the parent's stream."""
    from imucald.gap.linear import _spawn
    if not hasattr(np.random.Generator, "spawn"):
        pytest.skip(f"numpy {np.__version__} has no Generator.spawn to compare with")
    for seed in range(5):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(2):
            assert np.array_equal(_spawn(a).random(4), b.spawn(1)[0].random(4))
        assert np.array_equal(a.random(4), b.random(4))
