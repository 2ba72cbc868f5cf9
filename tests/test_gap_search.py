"""The gap diagnosis's combination search (imucald/gap/search.py, issue 25 items 2-4) on
pose means simulated directly (30 poses 20 s apart, heat then cool over 12 C, pose means
with 0.1 mg noise): both members of a pair named, a random walk paired with a fixed form,
and every named member passing its coefficient and held-out tests."""
import numpy as np
import pytest

from imucald.fitting.fit import accel_prior
from imucald.fitting.judging.levels import GAP_ATTRIBUTION_LEVEL, GAP_HELDOUT_LEVEL
from imucald.fitting.models.accel import Triangular9
from imucald.gap.candidates import ACCEL_CANDIDATES, hat_columns
from imucald.gap.norm import norm_diag

SD_G = 1e-4          # pose-mean noise, g


def _poses(seed, n=30):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = np.arange(n) * 20.0
    temp = 20.0 + 12.0 * np.sin(np.pi * t / t[-1])
    ctx = {"t": t - t.min(), "dt": t - t.mean(), **hat_columns(t), "temp": temp, "dT": temp - temp.mean()}
    x = u * (1 + np.array([0.01, -0.008, 0.005])) + np.array([0.02, -0.01, 0.03])
    return rng, u, ctx, x


def _diag(x, ctx, rng, seed):
    n = len(x)
    x = x + rng.normal(size=x.shape) * SD_G
    return norm_diag(x, ctx, np.full(n, SD_G ** 2), Triangular9(), ACCEL_CANDIDATES, 100,
                     np.random.default_rng(seed), {}, "g", prior=accel_prior(Triangular9(), "mpu6050"))


def _disciplined(r):
    """Every named member passes both tests of the search (at the levels it states)."""
    bonf, ho = r["search"]["coefficient_level"], r["search"]["heldout_level"]
    assert ho == GAP_HELDOUT_LEVEL and GAP_ATTRIBUTION_LEVEL / 10 <= bonf <= GAP_ATTRIBUTION_LEVEL / 2, (bonf, ho)
    for m in r["search"]["members"]:
        assert m["coefficient_p_value"] < bonf and m["heldout_p_value"] < ho, m


@pytest.mark.parametrize("seed", [1, 2])
def test_a_pair_of_fixed_forms_names_both(seed):
    """A per-axis quadratic nonlinearity (3 mg/g^2) with a thermal bias (0.3-0.5 mg/C): both
    named.  Seen to fail with the forward step's re-selection of the members' variants
    removed (the 3-coefficient nonlinearity alone beats the others while the thermal bias is
    unmodelled, and the search stops there) and with a single forward step."""
    rng, u, ctx, x = _poses(seed)
    x = x + np.array([3e-3, -2e-3, 2.5e-3]) * u ** 2 + np.outer(ctx["dT"], [4e-4, -3e-4, 5e-4])
    r = _diag(x, ctx, rng, seed)
    assert set(r["verdict"].split("+")) == {"nonlinearity", "thermal_bias"}, (r["verdict"], r["search"]["steps"])
    _disciplined(r)


def test_the_search_level_counts_its_own_members():
    """The search's Bonferroni count is the hypotheses it can test as members: here the 7
    fixed variants (thermal_bias 3 and 6, thermal_scale 3, nonlinearity 3, 6 and 10,
    bias_drift 3; all with a visible signature over 30 poses and 12 C) and the random walk,
    which stands for the three piecewise wandering forms (those stay in the single
    candidates' report, tested at the level over all 10).  Seen to fail with the level over
    every candidate scored (GAP_ATTRIBUTION_LEVEL / 10: it kept blind pair seed 2's general
    nonlinearity out, F p 0.00124)."""
    rng, u, ctx, x = _poses(1)
    x = x + np.array([3e-3, -2e-3, 2.5e-3]) * u ** 2 + np.outer(ctx["dT"], [4e-4, -3e-4, 5e-4])
    r = _diag(x, ctx, rng, 1)
    fixed = [c for c in ACCEL_CANDIDATES if c.name != "wandering_bias"]
    assert len(fixed) == 7 and len(ACCEL_CANDIDATES) == 10
    assert r["search"]["coefficient_level"] == pytest.approx(GAP_ATTRIBUTION_LEVEL / (len(fixed) + 1), rel=1e-12)


@pytest.mark.parametrize("seed", [3, pytest.param(4, marks=pytest.mark.xfail(
    strict=True, reason="known miss: a 6-term thermal bias and a drift soak up the walk and "
                        "close more than the walk in the drift's place (issue 25 report)"))])
def test_a_random_walk_pairs_with_a_thermal_bias(seed):
    """A bias random walk (0.25 mg per pose, ~1.4 mg at the end) with a thermal bias: both
    named, the walk as a random walk.  Seen to fail with the walk kept out of the
    combinations (the search of issue 25 round 2: thermal_bias alone or the walk alone), and
    without the walk in a drift's place (thermal_bias+bias_drift)."""
    rng, u, ctx, x = _poses(seed)
    walk = np.cumsum(rng.normal(size=x.shape) * 2.5e-4, axis=0)
    x = x + walk + np.outer(ctx["dT"], [4e-4, -3e-4, 5e-4])
    r = _diag(x, ctx, rng, seed)
    assert set(r["verdict"].split("+")) == {"thermal_bias", "wandering_bias"}, (r["verdict"], r["search"]["steps"])
    assert any(m.get("stochastic") for m in r["search"]["members"])
    _disciplined(r)


def test_heldout_tests_are_functions_of_the_two_models():
    """A held-out test asked twice, with other tests asked in between and its cache emptied,
    gives the same p-value (one set of draws for the search, common random numbers): the
    p-values reported in ``search.members`` are the ones the decisions used.  Seen to fail with
    fresh draws per call (gap/search.py _heldout_p drawing from the generator: 0.0013, then 0.0002)."""
    from imucald.gap import search as S
    from imucald.gap.norm import norm_baseline, refit_with, score_candidates
    rng, u, ctx, x = _poses(5)
    # a weak thermal bias (its held-out p-value is neither 0 nor 1: 0.04 with every model's
    # twin on the search's common draws; at 2e-5 C^-1 it was 2e-5, below the precondition)
    x = x + np.outer(ctx["dT"], [1.4e-5, -1.05e-5, 1.4e-5]) + rng.normal(size=x.shape) * SD_G
    b = norm_baseline(x, np.full(len(x), SD_G ** 2), Triangular9(), 100, rng, "g",
                      prior=accel_prior(Triangular9(), "mpu6050"))
    tested = score_candidates(b, ACCEL_CANDIDATES, ctx, {})
    variants, vis_q = S._entry_variants(tested, False, 1.0)
    s = S.Search(b, ctx, 100, np.random.default_rng(0), 1.0, vis_q, False, refit_with)
    base = s.fit((), False)
    tb = s.fit((variants["thermal_bias"][-1],), False)
    nl = s.fit((variants["nonlinearity"][0],), False)
    p1 = s.heldout_p(base, tb)
    assert 1e-4 < p1 < 0.9999, p1
    s.heldout_p(base, nl)
    s.ho_cache.clear()
    assert s.heldout_p(base, tb) == p1


def test_a_models_twin_does_not_depend_on_what_was_fitted_before():
    """Every model's twin (its ratio's denominator and its 99th percentile) is re-simulated on
    the search's common draws (Search.model_rng): the same model fitted first, or after
    others, has the same twin.  Seen to fail with one shared stream (model_rng returning the
    search's generator: a vibration-rectification recording was named or 'partially
    explained' depending only on which fits came before)."""
    from imucald.gap import search as S
    from imucald.gap.norm import norm_baseline, refit_with, score_candidates
    rng, u, ctx, x = _poses(6)
    x = x + np.outer(ctx["dT"], [4e-4, -3e-4, 5e-4]) + rng.normal(size=x.shape) * SD_G
    b = norm_baseline(x, np.full(len(x), SD_G ** 2), Triangular9(), 100, rng, "g",
                      prior=accel_prior(Triangular9(), "mpu6050"))
    tested = score_candidates(b, ACCEL_CANDIDATES, ctx, {})
    got = []
    for first in ([], ["nonlinearity", "thermal_scale"]):
        variants, vis_q = S._entry_variants(tested, False, 1.0)
        s = S.Search(b, ctx, 100, np.random.default_rng(0), 1.0, vis_q, False, refit_with)
        for name in first:
            s.fit((variants[name][0],), False)
        m = s.fit((variants["thermal_bias"][0],), False)
        got.append((m.twin, m.q99))
    assert got[0] == got[1], got


def test_search_takes_the_single_fits_it_is_given(monkeypatch):
    """The single candidates and the walk alone fitted by norm_diag are not fitted again by
    the search (each variant refitted alone once, the walk on the baseline's residuals once).
    Seen to fail with stepwise's prefit argument dropped (gap/norm.py decide_search): each
    single that enters the search and the walk alone fitted twice."""
    from imucald.gap import norm as N
    from imucald.gap import search as S
    singles, walks = [], []

    def counting_refit(b, cs, *a, **k):
        if len(cs) == 1:
            singles.append(id(cs[0]))
        return N.refit_with.__wrapped__(b, cs, *a, **k)
    counting_refit.__wrapped__ = N.refit_with

    def counting_walk(r, J, *a, **k):
        walks.append(J.shape[1])
        return S.random_walk_fit.__wrapped__(r, J, *a, **k)
    counting_walk.__wrapped__ = S.random_walk_fit
    monkeypatch.setattr(N, "refit_with", counting_refit)
    monkeypatch.setattr(N, "random_walk_fit", counting_walk)
    monkeypatch.setattr(S, "random_walk_fit", counting_walk)
    rng, u, ctx, x = _poses(3)
    x = x + np.cumsum(rng.normal(size=x.shape) * 2.5e-4, axis=0) + np.outer(ctx["dT"], [4e-4, -3e-4, 5e-4])
    r = _diag(x, ctx, rng, 3)
    assert r["search"]["steps"], r["verdict"]
    assert len(singles) == len(set(singles)), "a single candidate fitted twice"
    p0 = Triangular9().k
    assert walks.count(p0) <= 1, f"the walk alone fitted {walks.count(p0)} times"


@pytest.mark.parametrize("seed,why", [(536, "together"), pytest.param(
    540, "predicts the held-out poses better", marks=pytest.mark.xfail(
        strict=True, reason="known miss since every model below MIN_DOF is judged by F (gap25b): "
                            "23 poses, the 3+3 pair leaves 8 residual dof, the nonlinearity's Wald "
                            "p 2.0e-5 against chi-square, 8.1e-3 against F(3, 8), above the level "
                            "1e-3: 'wandering_bias'")),
                                      (2001, "together")])
def test_blind_pairs_named_with_both_members(seed, why):
    """Two cases of the blind generator's nonlinearity (full symmetric quadratic per axis) with
    a saturating thermal bias, development seeds (not the bench's): both members named.
    Seed 536: each effect fails its tests alone (the other's excess scales its covariance),
    the two enter together; seen to fail without gap/search.py _pair_entries ("unexplained").
    Seed 540: the random walk alone (a strength that absorbs the orientation-dependent misfit
    too) beats the pair by likelihood; the pair predicts the held-out poses better; seen to fail
    without _choose_end's paired held-out test ("wandering_bias").
    Seed 2001 (22 poses): the pair (a 3-term nonlinearity and a 3-term thermal bias) leaves 7
    residual degrees of freedom, below the 10 a first step needs; it enters with its Wald tests
    referred to F; seen to fail with PAIR_ENTRY_MIN_DOF = MIN_DOF ("wandering_bias")."""
    from imucald.gap.diagnose import diagnose
    from .blindgen2 import make_case
    rec, lab = make_case("pair_nl_thermal", seed)
    r = diagnose(rec, sims=100, seed=seed)["sensors"]["accel"]
    assert set(r["verdict"].split("+")) == {"nonlinearity", "thermal_bias"}, (r["verdict"], r["search"]["steps"])
    assert any(why in st["step"] for st in r["search"]["steps"]), r["search"]["steps"]
    _disciplined(r)


@pytest.mark.parametrize("seed,step", [(2035, None), (2027, "thermal_bias: 3 -> 6 coefficients")])
def test_blind_thermal_bias_named_alone(seed, step):
    """The blind generator's saturating thermal bias alone, development seeds (not the
    bench's): "thermal_bias" with no second member.
    Seed 2035 (31 poses): a step adding a 10-term nonlinearity while cutting the thermal bias
    back to 3 terms was judged only against the 3-term thermal bias, not against the 6-term one
    it left; seen to fail without the held-out test against the current model in
    gap/search.py _add_moves ("thermal_bias+nonlinearity").
    Seed 2027 (23 poses): the 6-term thermal bias cannot enter alone (beside the 9 baseline
    parameters it leaves 8 residual degrees of freedom, below the 10 a single effect needs),
    the 3-term one leaves curvature and a walk joined it; seen to fail with
    _variant_moves held to that room (dof_ok without ``refine``: "thermal_bias+wandering_bias")."""
    from imucald.gap.diagnose import diagnose
    from .blindgen2 import make_case
    rec, lab = make_case("thermal_bias", seed)
    r = diagnose(rec, sims=100, seed=seed)["sensors"]["accel"]
    assert r["verdict"] == "thermal_bias", (r["verdict"], r["search"]["steps"])
    if step:
        assert any(st["step"] == step for st in r["search"]["steps"]), r["search"]["steps"]
    _disciplined(r)


@pytest.mark.parametrize("kind,seed", [("nonlinearity", 2004), ("cubic", 2018)])
def test_short_pair_entry_names_no_spurious_pair(kind, seed):
    """A pair entering with fewer than 10 residual degrees of freedom has its members' Wald
    tests referred to F(rank, dof): development seeds (not the bench's) where, with the
    chi-square reference, a thermal pair soaked up a lone nonlinearity's misfit (nonlinearity
    2004, 24 poses: "thermal_bias+thermal_scale") and a cubic's (cubic 2018, 27 poses:
    "thermal_bias+thermal_scale"); seen to fail with gap/signif.py scaled_wald_p returning the
    chi-square figures. No thermal form is named on either (both are "unexplained")."""
    from imucald.gap.diagnose import diagnose
    from .blindgen2 import make_case
    rec, lab = make_case(kind, seed)
    r = diagnose(rec, sims=100, seed=seed)["sensors"]["accel"]
    assert not {"thermal_bias", "thermal_scale"} & set(r["verdict"].split("+")), (r["verdict"], r["search"]["steps"])


def test_every_short_model_is_judged_by_f_not_the_entry_only(monkeypatch):
    """pair_nl_thermal 2001 (22 poses): the 6-term nonlinearity with the thermal bias leaves 4
    residual degrees of freedom and its F p-values (8.9e-3, 3.3e-2) fail the Bonferroni level,
    so that pair cannot enter; the 3-term pair enters at 7. One step later the search took
    "nonlinearity: 3 -> 6 coefficients" on the chi-square p-values (1e-18, 1.2e-5) and named
    the 4-dof model the entry had rejected, reporting those p-values. Every fitted model
    without the walk that leaves fewer than MIN_DOF (N minus all its coefficients) must carry
    its members' F p-values. Seen to fail with gap/search.py Search._fit's F reference
    switched off (short = False: chi-square p-values for every model, as main 346145d had
    them after the entry). Since members are fitted in the directions their score tests see
    (search.VisiblePart), the general nonlinearity (10 terms, 7 visible) replaces the 3-term
    one with F(7, 3) p 3.7e-4 and a held-out p of 6e-30, and closes the gap (ratio after 1.16,
    against 6.44 for the 3+3 pair): the generator's full quadratic form has the general
    form's norm signature."""
    from imucald.gap import search as S
    from imucald.gap.diagnose import diagnose
    from imucald.gap.signif import wald_f_p
    from .blindgen2 import make_case
    fits = []
    orig = S.Search._fit

    def spy(self, cands, walk):
        m = orig(self, cands, walk)
        if m is not None:
            fits.append((self.b.n, m))
        return m
    monkeypatch.setattr(S.Search, "_fit", spy)
    rec, lab = make_case("pair_nl_thermal", 2001)
    r = diagnose(rec, sims=100, seed=2001)["sensors"]["accel"]
    short = 0
    for n, m in fits:
        dof = n - len(m.z)
        if m.walk or not m.cands or dof >= S.MIN_DOF or m.chi2 <= dof:
            continue
        short += 1
        o = len(m.z) - sum(c.q for c in m.cands)
        for c in m.cands:
            f = wald_f_p(m.z[o:o + c.q], m.cov[o:o + c.q, o:o + c.q], dof)
            assert m.member_p[c.name] == pytest.approx(f, rel=1e-12), (c.name, c.q, dof)
            o += c.q
    assert short >= 2, "no model below MIN_DOF met: the case no longer tests the rule"
    assert set(r["verdict"].split("+")) == {"nonlinearity", "thermal_bias"}, r["verdict"]
    assert {m["name"]: m["coefficients"] for m in r["search"]["members"]} == {"nonlinearity": 10, "thermal_bias": 3}
    _disciplined(r)


@pytest.mark.parametrize("kind,seed,said", [("pair_nl_thermal", 10, True), ("pair_nl_thermal", 2004, False),
                                             ("pair_nl_thermal", 2001, False), ("thermal_bias", 2035, False)])
def test_a_short_pose_set_says_which_pair_it_cannot_enter(kind, seed, said):
    """A gap on the accelerometer below gap/diagnose.py PAIR_POSES (28) kept poses, not named
    as the pair itself: a nonlinearity in its general form (10 terms) and a thermal bias
    cannot enter together there (they must leave 6 residual degrees of freedom beside the 9
    baseline parameters), and the result says so, with what it costs (pairs named in 26 of 30
    blind recordings of 22-27 poses, 30 of 30 of 28-35). Seeds: 10 (23 poses,
    "wandering_bias": said); 2004 (24 poses; "wandering_bias" until the members were fitted in
    their visible directions, now the pair with the nonlinearity reached step by step: not
    said); 2001 (22 poses, the pair named: not said); 2035 (31 poses: not said). Seen to fail
    with the note removed, with the threshold at 22 poses (PAIR_POSES computed without the
    room), and with the note on a named pair."""
    from imucald.gap.diagnose import PAIR_POSES, diagnose
    from .blindgen2 import make_case
    rec, _ = make_case(kind, seed)
    r = diagnose(rec, sims=100, seed=seed)
    a = r["sensors"]["accel"]
    notes = [x for x in r["notes"] if "general form" in x]
    assert bool(notes) == said, (a["poses"], a["verdict"], r["notes"])
    if said:
        assert a["poses"] < PAIR_POSES and notes[0].startswith(
            f"accel: {a['poses']} poses: a nonlinearity in its general form (10 terms)"), notes


def test_twenty_poses_name_a_thermal_bias_not_a_wander():
    """20 simulated poses (MPU-6050, heat then cool over 10 degC, the library's default
    thermal bias): a single 3-term effect leaves 20 - 9 - 3 = 8 residual degrees of freedom,
    SINGLE_MIN_DOF, and is named.  Seen to fail with the single-effect floor at MIN_DOF (10):
    the random walk, which no floor held back, took it ("wandering_bias", 5 of 8 seeds; an
    independent probe: 17 of 18 at 20-21 poses).  Its coefficients are checked against the
    truth in tests/test_gap_blind_truth.py; here the name."""
    from imucald.gap.diagnose import diagnose
    from imucald.sim.effects import DEFAULT_MAGNITUDE, effect_session
    from imucald.sim.orientations import random_pose_set
    got = []
    for seed in range(8):
        g = np.random.default_rng(seed)
        s, _ = effect_session("mpu6050", random_pose_set(20, g), g,
                              [("accel.thermal_bias", DEFAULT_MAGNITUDE["accel.thermal_bias"])],
                              rate_hz=100.0, hold_s=(8.0, 12.0), temp_kind="heatcool", temp_rise_c=10.0)
        got.append(diagnose(s.recording, sensors=["accel"], sims=100, seed=seed)["sensors"]["accel"]["verdict"])
    assert got == ["thermal_bias"] * 8, got
