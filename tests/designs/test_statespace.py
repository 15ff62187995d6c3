"""designs.statespace against closed forms derived by hand, python-control and brute force."""

import control
import numpy as np
import pytest

import models
from designs import statespace as ss

DOUBLE_INTEGRATOR = (np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]]))


@pytest.fixture(scope="module")
def satellite():
    return models.get("satellite").linearize()


# ------------------------------------------------------------ rank tests
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


def test_placement_refuses_uncontrollable_and_unobservable_pairs(satellite):
    with pytest.raises(ValueError, match=r"toy: \(A, B\) is not controllable.*s = 2"):
        ss.place(np.diag([-1.0, 2.0]), np.array([[1.0], [0.0]]), [-1, -3], "toy")
    # y = phi - theta is blind to the common rotation of body and panel.
    with pytest.raises(ValueError, match="not observable"):
        ss.observer_gain(satellite.A, satellite.C[[1]], [-1, -2, -3, -4])
