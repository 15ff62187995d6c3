"""models.lqr against closed forms derived by hand, python-control and brute force."""

import control
import numpy as np
import pytest
import scipy.linalg

import models
from models import lqr

DOUBLE_INTEGRATOR = (np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]]))


@pytest.fixture(scope="module")
def satellite():
    return models.get("satellite").linearize()


# ------------------------------------------------------------ rank tests
def test_controllability_and_observability_matrices_match_python_control(satellite):
    np.testing.assert_allclose(
        lqr.controllability_matrix(satellite.A, satellite.B), control.ctrb(satellite.A, satellite.B), atol=1e-14
    )
    np.testing.assert_allclose(
        lqr.observability_matrix(satellite.A, satellite.C), control.obsv(satellite.A, satellite.C), atol=1e-14
    )
    assert lqr.require_controllable(satellite.A, satellite.B) == 4
    assert lqr.require_observable(satellite.A, satellite.C) == 4


def test_uncontrollable_pair_names_the_case_and_the_mode():
    A = np.diag([-1.0, 2.0])
    B = np.array([[1.0], [0.0]])
    np.testing.assert_allclose(lqr.uncontrollable_modes(A, B), [2.0])
    with pytest.raises(ValueError, match=r"toy: \(A, B\) is not controllable.*s = 2.*rank 1 < 2"):
        lqr.require_controllable(A, B, "toy")


def test_satellite_measuring_only_the_twist_cannot_see_the_rigid_body_mode(satellite):
    # y = phi - theta is blind to the common rotation theta = phi: the double pole at s = 0
    # (a Jordan block, so its computed eigenvalues scatter by about sqrt(eps)).
    twist = satellite.C[[1]]
    np.testing.assert_allclose(lqr.unobservable_modes(satellite.A, twist), [0.0, 0.0], atol=1e-7)
    with pytest.raises(ValueError, match=r"satellite twist: \(A, C\) is not observable.*s = 0"):
        lqr.require_observable(satellite.A, twist, "satellite twist")


def test_riccati_solves_refuse_an_unstabilizable_pair():
    # The mode at s = 0 cannot be moved; a Riccati solver could leave it there silently.
    A = np.diag([0.0, -1.0])
    B = np.array([[0.0], [1.0]])
    with pytest.raises(ValueError, match=r"not stabilizable.*Re s >= 0 at 0"):
        lqr.lqr(A, B)
    with pytest.raises(ValueError, match=r"not stabilizable.*\|z\| >= 1"):
        lqr.dlqr(np.diag([1.0, 0.5]), B)
    # Stable but uncontrollable is fine: stabilizable.
    K, _ = lqr.lqr(np.diag([-2.0, -1.0]), B)
    assert np.all(np.linalg.eigvals(np.diag([-2.0, -1.0]) - B @ K).real < 0)


def test_lqr_refuses_a_weight_that_hides_an_unstable_mode():
    A = np.array([[1.0, 0.0], [0.0, -1.0]])
    B = np.array([[1.0], [1.0]])
    with pytest.raises(ValueError, match="not detectable"):
        lqr.lqr(A, B, Q=np.diag([0.0, 1.0]))


# --------------------------------------------------------- pole placement
@pytest.mark.parametrize("a, b, q, r", [(0.0, 1.0, 1.0, 1.0), (2.0, 0.5, 3.0, 0.1), (-1.0, 2.0, 0.5, 4.0)])
def test_scalar_lqr_closed_form(a, b, q, r):
    # 2 a P - P^2 b^2 / r + q = 0  =>  P = r (a + sqrt(a^2 + b^2 q / r)) / b^2,  K = b P / r.
    P_hand = r * (a + np.sqrt(a**2 + b**2 * q / r)) / b**2
    K, P = lqr.lqr([[a]], [[b]], [[q]], [[r]])
    assert P[0, 0] == pytest.approx(P_hand, rel=1e-12)
    assert K[0, 0] == pytest.approx(b * P_hand / r, rel=1e-12)
    # Kalman-Bucy by duality: x' = a x + w, y = b x + v.
    L, S = lqr.kalman([[a]], [[b]], [[q]], [[r]])
    assert S[0, 0] == pytest.approx(P_hand, rel=1e-12)


def test_double_integrator_lqr_closed_form():
    # Q = diag(q, 0), R = 1: K = (sqrt(q), sqrt(2 sqrt(q))) (poles of a Butterworth pair).
    q = 9.0
    K, P = lqr.lqr(*DOUBLE_INTEGRATOR, np.diag([q, 0.0]), [[1.0]])
    np.testing.assert_allclose(K, [[np.sqrt(q), np.sqrt(2 * np.sqrt(q))]], rtol=1e-12)


@pytest.mark.parametrize("name", ["arm", "pendulum", "satellite", "uuv", "ballbeam", "crane1", "crane"])
def test_lqr_solves_the_riccati_equation_of_every_plant(name):
    lin = models.get(name).linearize()
    Q = np.diag(np.arange(1.0, lin.nx + 1))
    R = np.array([[0.3]])
    K, P = lqr.lqr(lin.A, lin.B, Q, R, name)
    residual = lin.A.T @ P + P @ lin.A - P @ lin.B @ np.linalg.solve(R, lin.B.T @ P) + Q
    scale = (
        np.linalg.norm(lin.A.T @ P) * 2
        + np.linalg.norm(P @ lin.B @ np.linalg.solve(R, lin.B.T @ P))
        + np.linalg.norm(Q)
    )
    assert np.linalg.norm(residual) / scale < 1e-9
    assert lqr.riccati_residual(lin.A, lin.B, Q, R, P) < 1e-9
    np.testing.assert_allclose(K, np.linalg.solve(R, lin.B.T @ P), rtol=1e-12)
    assert np.all(np.linalg.eigvals(P) > 0)


def _riccati_recursion(A, B, Q, R, steps=200000, tol=1e-13):
    """Finite-horizon backward recursion P_{k} = Q + A'P A - A'P B (R + B'P B)^-1 B'P A from P = Q."""
    P = Q.copy()
    for _ in range(steps):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P_next = Q + A.T @ P @ (A - B @ K)
        P_next = (P_next + P_next.T) / 2
        if np.max(np.abs(P_next - P)) <= tol * np.max(np.abs(P_next)):
            return K, P_next
        P = P_next
    raise AssertionError("recursion did not converge")


@pytest.mark.parametrize("name", ["arm", "satellite", "uuv", "ballbeam", "crane1"])
def test_dlqr_equals_the_converged_finite_horizon_recursion(name):
    disc = models.get(name).linearize().discretize(0.05)
    Q = np.eye(disc.nx)
    R = np.array([[0.5]])
    K, P = lqr.dlqr(disc.A, disc.B, Q, R, name)
    K_rec, P_rec = _riccati_recursion(disc.A, disc.B, Q, R)
    np.testing.assert_allclose(P, P_rec, rtol=1e-8)
    np.testing.assert_allclose(K, K_rec, rtol=1e-8)
    assert lqr.riccati_residual(disc.A, disc.B, Q, R, P, discrete=True) < 1e-9


def test_dkalman_equals_the_converged_covariance_recursion(satellite):
    disc = satellite.discretize(0.05)
    W = disc.B @ disc.B.T + 1e-4 * np.eye(4)
    V = 1e-2 * np.eye(2)
    L, P = lqr.dkalman(disc.A, disc.C, W, V)
    # Prediction covariance: P+ = A P A' - A P C' (C P C' + V)^-1 C P A' + W, the dual recursion.
    _, P_rec = _riccati_recursion(disc.A.T, disc.C.T, W, V)
    np.testing.assert_allclose(P, P_rec, rtol=1e-8)
    np.testing.assert_allclose(L, disc.A @ P_rec @ disc.C.T @ np.linalg.inv(disc.C @ P_rec @ disc.C.T + V), rtol=1e-8)


def test_bryson_weights_and_bad_weights():
    Q, R = lqr.bryson_weights([0.5, np.inf], [2.0])
    np.testing.assert_allclose(Q, np.diag([4.0, 0.0]))
    np.testing.assert_allclose(R, [[0.25]])
    A, B = DOUBLE_INTEGRATOR
    with pytest.raises(ValueError, match="weight Q has non-finite entries"):
        lqr.lqr(A, B, Q=np.diag([np.nan, 1.0]))
    with pytest.raises(ValueError, match="weight R has non-finite entries"):
        lqr.dlqr(np.eye(2), B, R=[[np.inf]])
    with pytest.raises(ValueError, match="R must be positive definite"):
        lqr.lqr(A, B, R=[[0.0]])
    with pytest.raises(ValueError, match="Q must be positive semidefinite"):
        lqr.lqr(A, B, Q=np.diag([1.0, -1.0]))
    with pytest.raises(ValueError, match="must be symmetric"):
        lqr.lqr(A, B, Q=[[1.0, 1.0], [0.0, 1.0]])
    with pytest.raises(ValueError, match=r"Q must be a scalar, 2 diagonal entries or a \(2, 2\) matrix"):
        lqr.lqr(A, B, Q=np.eye(3))
    with pytest.raises(ValueError, match="state_max entries must be > 0"):
        lqr.bryson_weights([0.0, 1.0], [1.0])
    with pytest.raises(ValueError, match="A has non-finite entries"):
        lqr.lqr([[np.nan, 0], [0, 0]], B)


def test_continuous_and_discrete_lqr_agree_as_the_sample_period_shrinks():
    # dlqr on the ZOH model with weights Q Ts, R Ts converges to the continuous gain.
    lin = models.get("uuv").linearize()
    Q, R = np.diag([10.0, 1.0]), np.array([[1e-3]])
    K_c, _ = lqr.lqr(lin.A, lin.B, Q, R)
    errors = []
    for Ts in (0.01, 0.001):
        disc = lin.discretize(Ts)
        K_d, _ = lqr.dlqr(disc.A, disc.B, Q * Ts, R * Ts)
        errors.append(np.max(np.abs(K_d - K_c) / np.abs(K_c)))
    assert errors[1] < errors[0] / 5 and errors[1] < 0.01


def test_riccati_residual_flags_a_wrong_solution():
    A, B = DOUBLE_INTEGRATOR
    Q, R = np.eye(2), np.eye(1)
    _, P = lqr.lqr(A, B, Q, R)
    assert lqr.riccati_residual(A, B, Q, R, P) < 1e-12
    assert lqr.riccati_residual(A, B, Q, R, 1.01 * P) > 1e-3
    P_scipy = scipy.linalg.solve_continuous_are(A, B, Q, R)
    np.testing.assert_allclose(P, P_scipy, rtol=1e-12)
