"""Error models: round trips, analytic Jacobians, unobservable directions."""
import numpy as np
import pytest

from imucald.fitting.models.registry import (
    MODEL_NAMES, get_model, gyro_bias_eq6_fitness, gyro_bias_mean
)
from imucald.fitting.models.accel import Cosine, Full12, Triangular9
from imucald.fitting.models.mag import MagModel, mag_report
from imucald.fitting.judging.uncertainty import crlb


def _theta(model, rng, s=0.05):
    th = model.nominal + rng.normal(scale=s, size=model.k)
    return th


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_forward_inverse_round_trip(name):
    rng = np.random.default_rng(1)
    m = get_model(name)
    th = _theta(m, rng)
    x = rng.normal(size=(40, 3))
    y = m.forward(th, x)
    assert np.allclose(m.inverse(th, y), x, atol=1e-12)
    assert np.allclose(m.forward(th, m.inverse(th, x)), x, atol=1e-12)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_population_vectorisation_matches_loop(name):
    rng = np.random.default_rng(2)
    m = get_model(name)
    P = np.array([_theta(m, rng) for _ in range(7)]).reshape(7, m.k)
    x = rng.normal(size=(12, 3))
    f = m.fitness(P, x)
    for i in range(7):
        r = 1 - np.linalg.norm(m.forward(P[i], x), axis=1)
        assert f[i] == pytest.approx(float(r @ r), rel=1e-12)
    assert m.forward(P.reshape(7, 1, m.k), x).shape == (7, 1, 12, 3)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_analytic_jacobian_matches_central_differences(name):
    rng = np.random.default_rng(3)
    m = get_model(name)
    th = _theta(m, rng)
    x = rng.normal(size=(15, 3))
    _, J = m.jacobian(th, x)
    for k in range(m.k):
        d = np.zeros(m.k)
        d[k] = 1e-6
        num = (m.residual(th + d, x) - m.residual(th - d, x)) / 2e-6
        assert np.allclose(J[:, k], num, atol=1e-8)


def test_triangular9_is_paper000_equation_1():
    th = np.array([0.01, -0.02, 0.03, 1.01, 0.98, 1.02, 0.05, -0.04, 0.08])
    T = np.array([[1, 0.01, -0.02], [0, 1, 0.03], [0, 0, 1]])
    K = np.diag([1.01, 0.98, 1.02])
    am = np.array([[0.3, -0.5, 0.8]])
    expect = T @ K @ (am[0] - th[6:])
    assert np.allclose(Triangular9().forward(th, am)[0], expect, atol=1e-15)


def test_cosine_is_paper002_equations_1_to_4():
    o, s, a = np.array([0.1, -0.2, 0.05]), np.array([1.1, 0.9, 1.05]), np.array([0.02, 0.03, -0.01])
    th = np.concatenate([o, s, a])
    X1, Y1, Z1 = 0.4, -0.3, 0.85
    X = (X1 + o[0]) * s[0]
    Y = (Y1 * np.cos(a[0]) + o[1]) * s[1]
    Z = (Z1 * np.cos(a[1]) * np.cos(a[2]) + o[2]) * s[2]
    assert np.allclose(Cosine().forward(th, [[X1, Y1, Z1]])[0], [X, Y, Z], atol=1e-15)


def test_full12_reports_three_unobservable_directions():
    rng = np.random.default_rng(4)
    m = Full12()
    th = _theta(m, rng, 0.02)
    x = rng.normal(size=(30, 3))
    U = m.unobservable_directions(th)
    assert U.shape == (3, 12)
    _, J = m.jacobian(th, x)
    # the norm residual does not change along them ...
    assert np.abs(J @ U.T).max() < 1e-12
    # ... they are independent, and they are exactly the numerical null space
    assert np.linalg.matrix_rank(U) == 3
    unc = crlb(m, th, x, np.full(30, 1e-8))
    assert unc.rank == 9
    P_null = unc.null_directions.T @ np.linalg.pinv(unc.null_directions.T)
    assert np.allclose(P_null @ U.T, U.T, atol=1e-8)
    # a small step along one leaves the fitness unchanged to first order, while a
    # step of the same size along an observable direction does not
    f0 = m.fitness(th, x)
    for u in U:
        assert abs(m.fitness(th + 1e-6 * u, x) - f0) < 1e-9
    e_bias = np.zeros(12)
    e_bias[9] = 1.0
    assert abs(m.fitness(th + 1e-6 * e_bias, x) - f0) > 1e-7


def test_triangular9_has_no_unobservable_direction():
    rng = np.random.default_rng(5)
    m = Triangular9()
    x = rng.normal(size=(25, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    unc = crlb(m, m.nominal, x, np.full(25, 1e-8))
    assert unc.rank == 9 and not unc.unobservable


def test_cosine_angles_have_no_information_at_zero():
    # cos'(0) = 0: at zero angle the misalignment columns vanish (the paper's
    # "misalignment ... almost do not have any effect").
    rng = np.random.default_rng(6)
    m = Cosine("osm")
    x = rng.normal(size=(25, 3))
    unc = crlb(m, m.nominal, x, np.full(25, 1e-8))
    assert set(unc.unobservable) == {"angle_zy_rad", "angle_xz_rad", "angle_yz_rad"}
    assert np.all(np.isinf(unc.std[6:9]))


def test_mag_report_normalises_soft_iron_and_recovers_field():
    rng = np.random.default_rng(7)
    m = MagModel("sym")
    W = np.eye(3) + 0.05 * rng.normal(size=(3, 3))
    W = (W + W.T) / 2
    v = np.array([0.2, -0.1, 0.3])
    F = 0.48
    th = np.array([W[0, 0], W[1, 1], W[2, 2], W[0, 1], W[0, 2], W[1, 2], *v]) / np.array(
        [F] * 6 + [1] * 3)
    p, _ = mag_report(m, th)
    Wn = np.zeros((3, 3))
    for k, (i, j) in enumerate([(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]):
        Wn[i, j] = Wn[j, i] = p["soft_iron"][k]
    assert np.linalg.det(Wn) == pytest.approx(1.0, rel=1e-12)
    assert p["field_gauss"] == pytest.approx(F / np.linalg.det(W) ** (1 / 3), rel=1e-12)
    assert np.allclose(p["hard_iron_gauss"], v)


def test_gyro_bias_mean_and_eq6():
    rng = np.random.default_rng(8)
    b = np.array([1.5, -0.7, 0.2])
    s = b + rng.normal(scale=0.05, size=(5000, 3))
    assert np.allclose(gyro_bias_mean(s.reshape(50, 100, 3).mean(1)), b, atol=4 * 0.05 / np.sqrt(5000))
    # eq. 6 is minimised near the true bias, and is larger away from it
    f0 = gyro_bias_eq6_fitness(b, s)
    assert gyro_bias_eq6_fitness(b + [0.05, 0, 0], s) > f0
    assert gyro_bias_eq6_fitness(np.stack([b, b + 0.1]), s).shape == (2,)


def test_unknown_model_names_allowed_values():
    with pytest.raises(ValueError, match="allowed"):
        get_model("nine")


def test_full12_canonical_gauge_keeps_the_norms():
    rng = np.random.default_rng(9)
    m = Full12()
    th = _theta(m, rng, 0.02)
    c = m.canonical(th)
    assert np.allclose(c[[2, 4, 5]], 0)                        # lower terms gauged away
    x = rng.normal(size=(20, 3))
    assert np.allclose(m.norms(c, x), m.norms(th, x), atol=1e-12)
    assert np.allclose(m.canonical(np.stack([th, th]))[1], c)
    # ga-paper averages its runs in this gauge: solutions that differ only by a frame
    # rotation average to a solution, whereas their raw average does not
    from imucald.sim.orientations import small_rotation
    sols = []
    for _ in range(5):
        M = small_rotation(rng, 0.05) @ m.matrix(th)
        S = np.diag(M).copy()
        off = [M[0, 1] / S[1], M[0, 2] / S[2], M[1, 0] / S[0], M[1, 2] / S[2], M[2, 0] / S[0],
               M[2, 1] / S[1]]
        sols.append(np.array([*off, *S, *th[9:12]]))
    sols = np.array(sols)
    assert np.allclose(m.norms(sols, x), m.norms(th, x), atol=1e-12)
    assert np.allclose(m.norms(m.canonical(sols).mean(0), x), m.norms(th, x), atol=1e-12)
    assert np.abs(m.norms(sols.mean(0), x) - m.norms(th, x)).max() > 1e-5


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_affine_rows_fast_path_matches_affine(name):
    rng = np.random.default_rng(10)
    m = get_model(name)
    P = np.array([_theta(m, rng) for _ in range(5)])
    A, c = m.affine(P)
    rows = m.affine_rows(P)
    assert rows.shape == (3, 5, 4)
    assert np.allclose(rows[..., :3].transpose(1, 0, 2), A) and np.allclose(rows[..., 3].T, c)
