"""designs.statespace against closed forms derived by hand, python-control and brute force."""

import control
import numpy as np
import pytest
import scipy.linalg

import models
from designs import statespace as ss

DOUBLE_INTEGRATOR = (np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]]))


@pytest.fixture(scope="module")
def satellite():
    return models.get("satellite").linearize()


# ------------------------------------------------------------ rank tests
def test_controllability_and_observability_matrices_match_python_control(satellite):
    np.testing.assert_allclose(ss.controllability_matrix(satellite.A, satellite.B),
                               control.ctrb(satellite.A, satellite.B), atol=1e-14)
    np.testing.assert_allclose(ss.observability_matrix(satellite.A, satellite.C),
                               control.obsv(satellite.A, satellite.C), atol=1e-14)
    assert ss.require_controllable(satellite.A, satellite.B) == 4
    assert ss.require_observable(satellite.A, satellite.C) == 4


def test_uncontrollable_pair_names_the_case_and_the_mode():
    A = np.diag([-1.0, 2.0])
    B = np.array([[1.0], [0.0]])
    np.testing.assert_allclose(ss.uncontrollable_modes(A, B), [2.0])
    with pytest.raises(ValueError, match=r"toy: \(A, B\) is not controllable.*s = 2.*rank 1 < 2"):
        ss.require_controllable(A, B, "toy")
    with pytest.raises(ValueError, match="not controllable"):
        ss.place(A, B, [-1, -3], "toy")


def test_satellite_measuring_only_the_twist_cannot_see_the_rigid_body_mode(satellite):
    # y = phi - theta is blind to the common rotation theta = phi: the double pole at s = 0
    # (a Jordan block, so its computed eigenvalues scatter by about sqrt(eps)).
    twist = satellite.C[[1]]
    np.testing.assert_allclose(ss.unobservable_modes(satellite.A, twist), [0.0, 0.0], atol=1e-7)
    with pytest.raises(ValueError, match=r"satellite twist: \(A, C\) is not observable.*s = 0"):
        ss.require_observable(satellite.A, twist, "satellite twist")
    with pytest.raises(ValueError, match="not observable"):
        ss.observer_gain(satellite.A, twist, [-1, -2, -3, -4])


def test_riccati_solves_refuse_an_unstabilizable_pair():
    # The mode at s = 0 cannot be moved; a Riccati solver could leave it there silently.
    A = np.diag([0.0, -1.0])
    B = np.array([[0.0], [1.0]])
    with pytest.raises(ValueError, match=r"not stabilizable.*Re s >= 0 at 0"):
        ss.lqr(A, B)
    with pytest.raises(ValueError, match=r"not stabilizable.*\|z\| >= 1"):
        ss.dlqr(np.diag([1.0, 0.5]), B)
    # Stable but uncontrollable is fine: stabilizable.
    K, _ = ss.lqr(np.diag([-2.0, -1.0]), B)
    assert np.all(np.linalg.eigvals(np.diag([-2.0, -1.0]) - B @ K).real < 0)


def test_lqr_refuses_a_weight_that_hides_an_unstable_mode():
    A = np.array([[1.0, 0.0], [0.0, -1.0]])
    B = np.array([[1.0], [1.0]])
    with pytest.raises(ValueError, match="not detectable"):
        ss.lqr(A, B, Q=np.diag([0.0, 1.0]))


# --------------------------------------------------------- pole placement
@pytest.mark.parametrize("poles", [(-1.0, -2.0), (-3 + 4j, -3 - 4j), (-0.5, -7.0)])
def test_double_integrator_placement_matches_the_characteristic_polynomial(poles):
    # det(sI - A + BK) = s^2 + k2 s + k1 = (s - p1)(s - p2)  =>  k1 = p1 p2, k2 = -(p1 + p2).
    p1, p2 = poles
    K = ss.place(*DOUBLE_INTEGRATOR, poles)
    np.testing.assert_allclose(K, [[(p1 * p2).real, -(p1 + p2).real]], rtol=1e-12)


@pytest.mark.parametrize("name", ["arm", "pendulum", "satellite", "uuv", "ballbeam", "crane1", "crane"])
def test_place_equals_ackermann_and_puts_the_poles_where_asked(name):
    lin = models.get(name).linearize()
    n = lin.nx
    poles = np.concatenate([[-0.7 + 0.5j, -0.7 - 0.5j], -0.7 * np.arange(2, n)])
    K = ss.place(lin.A, lin.B, poles, name)
    assert ss.pole_mismatch(np.linalg.eigvals(lin.A - lin.B @ K), poles) < 1e-8
    np.testing.assert_allclose(K.ravel(), np.ravel(control.acker(lin.A, lin.B, poles)), rtol=1e-7)


def test_bad_pole_requests_name_what_is_wrong():
    A, B = DOUBLE_INTEGRATOR
    with pytest.raises(ValueError, match=r"the pole -1 is requested 2 times but the system has 1"):
        ss.place(A, B, [-1.0, -1.0])
    with pytest.raises(ValueError, match="need 2 poles"):
        ss.place(A, B, [-1.0])
    with pytest.raises(ValueError, match="conjugate pairs"):
        ss.place(A, B, [-1 + 1j, -2])
    with pytest.raises(ValueError, match="not finite"):
        ss.place(A, B, [-1, np.nan])
    with pytest.raises(ValueError, match="B must have 2 rows"):
        ss.place(A, np.ones((3, 1)), [-1, -2])
    # Two inputs may repeat a pole twice.
    K = ss.place(np.zeros((2, 2)), np.eye(2), [-1.0, -1.0])
    np.testing.assert_allclose(np.linalg.eigvals(-K), [-1, -1], atol=1e-12)


def test_second_order_specs_give_that_step_response():
    wn, zeta = ss.second_order_from_specs(1.0, 0.05)
    t = np.linspace(0, 10, 100001)
    info = control.step_info(control.tf([wn**2], [1, 2 * zeta * wn, wn**2]), T=t)
    assert info["RiseTime"] == pytest.approx(1.0, abs=t[1])
    assert info["Overshoot"] == pytest.approx(5.0, rel=1e-4)
    # Overshoot alone fixes zeta by M_p = exp(-pi zeta / sqrt(1 - zeta^2)).
    assert np.exp(-np.pi * zeta / np.sqrt(1 - zeta**2)) == pytest.approx(0.05, rel=1e-12)
    np.testing.assert_allclose(np.poly(ss.second_order_poles(wn, zeta)), [1, 2 * zeta * wn, wn**2])
    with pytest.raises(ValueError, match="overshoot must be a fraction"):
        ss.second_order_from_specs(1.0, 5)


# --------------------------------------------------------- reference gain
def test_reference_gain_gives_unit_dc_gain_on_the_tracked_output(satellite):
    K = ss.place(satellite.A, satellite.B, [-1 + 1j, -1 - 1j, -0.3 + 0.3j, -0.3 - 0.3j])
    C_phi = np.array([[0.0, 1.0, 0.0, 0.0]])
    kr = ss.reference_gain(satellite.A, satellite.B, K, C_phi)
    closed = control.ss(satellite.A - satellite.B @ K, satellite.B * kr, C_phi, 0)
    assert control.dcgain(closed) == pytest.approx(1.0, rel=1e-12)
    N_x, N_u = ss.reference_steady_state(satellite.A, satellite.B, C_phi)
    assert kr[0] == pytest.approx((N_u + K @ N_x)[0], rel=1e-12)
    # The rest state holding phi = 1: the spring relaxed, theta = phi, no torque.
    np.testing.assert_allclose(N_x, [1, 1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(N_u, [0], atol=1e-12)


def test_reference_gain_refuses_a_closed_loop_pole_at_zero():
    A, B = DOUBLE_INTEGRATOR
    with pytest.raises(ValueError, match="singular"):
        ss.reference_gain(A, B, [[0.0, 1.0]], [[1.0, 0.0]])
    with pytest.raises(ValueError, match="transmission zero at s = 0"):
        ss.reference_steady_state(A, B, [[0.0, 1.0]])  # a velocity cannot rest at 1


def test_integrator_augmentation_sign_and_poles():
    # Double integrator + integral of r - x1: characteristic polynomial
    # s^3 + k2 s^2 + k1 s - ki with u = -k1 x1 - k2 x2 + ki xI.
    A_I, B_I = ss.augment_integrator(*DOUBLE_INTEGRATOR, [[1.0, 0.0]])
    poles = [-1.0, -2.0, -3.0]
    K, ki = ss.split_integral_gain(ss.place(A_I, B_I, poles), 2)
    coeffs = np.poly(poles)  # s^3 + 6 s^2 + 11 s + 6
    np.testing.assert_allclose(K, [[coeffs[2], coeffs[1]]], rtol=1e-12)
    assert ki[0] == pytest.approx(coeffs[3], rel=1e-12)  # ki = 6 > 0: positive for this plant


def test_disturbance_augmentation_and_its_observer(satellite):
    A_d, B_d, C_d = ss.augment_disturbance(satellite.A, satellite.B, satellite.C)
    assert A_d.shape == (5, 5) and B_d.shape == (5, 1) and C_d.shape == (2, 5)
    np.testing.assert_allclose(A_d[:4, 4:], satellite.B)  # d enters where u does
    np.testing.assert_allclose(A_d[4], 0)
    poles = [-2, -3, -4 + 1j, -4 - 1j, -1.5]
    L = ss.observer_gain(A_d, C_d, poles)
    assert ss.pole_mismatch(np.linalg.eigvals(A_d - L @ C_d), poles) < 1e-8


# ---------------------------------------------------------------- observers
def test_discrete_observer_and_current_estimator(satellite):
    disc = satellite.discretize(0.01)
    poles_z = np.exp(0.01 * np.array([-5, -6, -7 + 2j, -7 - 2j]))
    L = ss.discrete_observer_gain(disc.A, disc.C, poles_z)
    assert ss.pole_mismatch(np.linalg.eigvals(disc.A - L @ disc.C), poles_z) < 1e-10
    M = ss.current_estimator_gain(disc.A, L)
    # Prior error of the current estimator: e+ = A (I - M C) e = (A - L C) e.
    np.testing.assert_allclose(disc.A @ (np.eye(4) - M @ disc.C), disc.A - L @ disc.C, atol=1e-12)
    with pytest.raises(ValueError, match="inside the unit circle"):
        ss.discrete_observer_gain(disc.A, disc.C, [0.5, 0.6, 0.7, 1.2])


# --------------------------------------------------------------------- LQR
@pytest.mark.parametrize("a, b, q, r", [(0.0, 1.0, 1.0, 1.0), (2.0, 0.5, 3.0, 0.1), (-1.0, 2.0, 0.5, 4.0)])
def test_scalar_lqr_closed_form(a, b, q, r):
    # 2 a P - P^2 b^2 / r + q = 0  =>  P = r (a + sqrt(a^2 + b^2 q / r)) / b^2,  K = b P / r.
    P_hand = r * (a + np.sqrt(a**2 + b**2 * q / r)) / b**2
    K, P = ss.lqr([[a]], [[b]], [[q]], [[r]])
    assert P[0, 0] == pytest.approx(P_hand, rel=1e-12)
    assert K[0, 0] == pytest.approx(b * P_hand / r, rel=1e-12)
    # Kalman-Bucy by duality: x' = a x + w, y = b x + v.
    L, S = ss.kalman([[a]], [[b]], [[q]], [[r]])
    assert S[0, 0] == pytest.approx(P_hand, rel=1e-12)


def test_double_integrator_lqr_closed_form():
    # Q = diag(q, 0), R = 1: K = (sqrt(q), sqrt(2 sqrt(q))) (poles of a Butterworth pair).
    q = 9.0
    K, P = ss.lqr(*DOUBLE_INTEGRATOR, np.diag([q, 0.0]), [[1.0]])
    np.testing.assert_allclose(K, [[np.sqrt(q), np.sqrt(2 * np.sqrt(q))]], rtol=1e-12)


@pytest.mark.parametrize("name", ["arm", "pendulum", "satellite", "uuv", "ballbeam", "crane1", "crane"])
def test_lqr_solves_the_riccati_equation_of_every_plant(name):
    lin = models.get(name).linearize()
    Q = np.diag(np.arange(1.0, lin.nx + 1))
    R = np.array([[0.3]])
    K, P = ss.lqr(lin.A, lin.B, Q, R, name)
    residual = lin.A.T @ P + P @ lin.A - P @ lin.B @ np.linalg.solve(R, lin.B.T @ P) + Q
    scale = np.linalg.norm(lin.A.T @ P) * 2 + np.linalg.norm(P @ lin.B @ np.linalg.solve(R, lin.B.T @ P)) \
        + np.linalg.norm(Q)
    assert np.linalg.norm(residual) / scale < 1e-9
    assert ss.riccati_residual(lin.A, lin.B, Q, R, P) < 1e-9
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
    K, P = ss.dlqr(disc.A, disc.B, Q, R, name)
    K_rec, P_rec = _riccati_recursion(disc.A, disc.B, Q, R)
    np.testing.assert_allclose(P, P_rec, rtol=1e-8)
    np.testing.assert_allclose(K, K_rec, rtol=1e-8)
    assert ss.riccati_residual(disc.A, disc.B, Q, R, P, discrete=True) < 1e-9


def test_dkalman_equals_the_converged_covariance_recursion(satellite):
    disc = satellite.discretize(0.05)
    W = disc.B @ disc.B.T + 1e-4 * np.eye(4)
    V = 1e-2 * np.eye(2)
    L, P = ss.dkalman(disc.A, disc.C, W, V)
    # Prediction covariance: P+ = A P A' - A P C' (C P C' + V)^-1 C P A' + W, the dual recursion.
    _, P_rec = _riccati_recursion(disc.A.T, disc.C.T, W, V)
    np.testing.assert_allclose(P, P_rec, rtol=1e-8)
    np.testing.assert_allclose(L, disc.A @ P_rec @ disc.C.T @ np.linalg.inv(disc.C @ P_rec @ disc.C.T + V),
                               rtol=1e-8)


def test_bryson_weights_and_bad_weights():
    Q, R = ss.bryson_weights([0.5, np.inf], [2.0])
    np.testing.assert_allclose(Q, np.diag([4.0, 0.0]))
    np.testing.assert_allclose(R, [[0.25]])
    A, B = DOUBLE_INTEGRATOR
    with pytest.raises(ValueError, match="weight Q has non-finite entries"):
        ss.lqr(A, B, Q=np.diag([np.nan, 1.0]))
    with pytest.raises(ValueError, match="weight R has non-finite entries"):
        ss.dlqr(np.eye(2), B, R=[[np.inf]])
    with pytest.raises(ValueError, match="R must be positive definite"):
        ss.lqr(A, B, R=[[0.0]])
    with pytest.raises(ValueError, match="Q must be positive semidefinite"):
        ss.lqr(A, B, Q=np.diag([1.0, -1.0]))
    with pytest.raises(ValueError, match="must be symmetric"):
        ss.lqr(A, B, Q=[[1.0, 1.0], [0.0, 1.0]])
    with pytest.raises(ValueError, match="Q must have shape"):
        ss.lqr(A, B, Q=np.eye(3))
    with pytest.raises(ValueError, match="state_max entries must be > 0"):
        ss.bryson_weights([0.0, 1.0], [1.0])
    with pytest.raises(ValueError, match="A has non-finite entries"):
        ss.lqr([[np.nan, 0], [0, 0]], B)


def test_continuous_and_discrete_lqr_agree_as_the_sample_period_shrinks():
    # dlqr on the ZOH model with weights Q Ts, R Ts converges to the continuous gain.
    lin = models.get("uuv").linearize()
    Q, R = np.diag([10.0, 1.0]), np.array([[1e-3]])
    K_c, _ = ss.lqr(lin.A, lin.B, Q, R)
    errors = []
    for Ts in (0.01, 0.001):
        disc = lin.discretize(Ts)
        K_d, _ = ss.dlqr(disc.A, disc.B, Q * Ts, R * Ts)
        errors.append(np.max(np.abs(K_d - K_c) / np.abs(K_c)))
    assert errors[1] < errors[0] / 5 and errors[1] < 0.01


def test_riccati_residual_flags_a_wrong_solution():
    A, B = DOUBLE_INTEGRATOR
    Q, R = np.eye(2), np.eye(1)
    _, P = ss.lqr(A, B, Q, R)
    assert ss.riccati_residual(A, B, Q, R, P) < 1e-12
    assert ss.riccati_residual(A, B, Q, R, 1.01 * P) > 1e-3
    P_scipy = scipy.linalg.solve_continuous_are(A, B, Q, R)
    np.testing.assert_allclose(P, P_scipy, rtol=1e-12)
