"""The steps of designs.statespace_design.design, each against a second method (python-control, SciPy, eigenvalues)."""

import control
import numpy as np
import pytest
import scipy.linalg

import models
from designs import statespace as ss
from designs import statespace_design as ssd
from designs.statespace_blocks import TrackingModel

TS = 0.01
POLES = np.array([-1.5 + 1j, -1.5 - 1j, -0.4 + 0.3j, -0.4 - 0.3j])


@pytest.fixture(scope="module")
def model():
    """The pendulum on a cart, tracking the cart position z (an unstable plant of four states)."""
    return TrackingModel.from_plant(models.get("pendulum"), "z")


def _sorted(values):
    values = np.asarray(values, dtype=complex)
    return values[np.lexsort((values.imag.round(9), values.real.round(9)))]


def test_feedback_places_the_poles_with_unit_dc_gain(model):
    A, B = model.linear.A, model.linear.B
    out = ssd.feedback_design(model, POLES, TS, "pendulum")
    np.testing.assert_allclose(_sorted(np.linalg.eigvals(A - B @ out["K"])), _sorted(POLES), atol=1e-8)
    closed = control.ss(A - B @ out["K"], B * out["kr"], model.C_r, 0)
    assert control.dcgain(closed) == pytest.approx(1.0, rel=1e-10)
    # The sampled-data poles: python-control's zero-order hold of the plant, the gain held over Ts.
    sampled = control.c2d(control.ss(A, B, np.eye(model.nx), 0), TS)
    expected = np.linalg.eigvals(sampled.A - sampled.B @ out["K"])
    np.testing.assert_allclose(_sorted(out["poles_sampled_z"]), _sorted(expected), atol=1e-10)


def test_feedback_too_fast_for_the_sample_period_is_refused(model):
    with pytest.raises(ValueError, match="unstable when sampled at Ts = 0.5 s"):
        ssd.feedback_design(model, 10 * POLES, 0.5, "pendulum")


def test_integrator_places_the_augmented_poles(model):
    A, B = model.linear.A, model.linear.B
    out = ssd.integrator_design(model, POLES, None, TS, "pendulum")
    assert out["integrator_pole"] == pytest.approx(-np.min(np.abs(POLES)))
    # x_I' = r − C_r x̃ and u = −K x̃ + k_i x_I, written out by hand.
    closed = np.block([[A - B @ out["K_integral"], B * out["ki"]], [-model.C_r, np.zeros((1, 1))]])
    wanted = np.append(POLES, out["integrator_pole"])
    np.testing.assert_allclose(_sorted(np.linalg.eigvals(closed)), _sorted(wanted), atol=1e-8)


def test_observer_gains_place_the_continuous_and_the_sampled_poles(model):
    A, B = model.linear.A, model.linear.B
    rows = model.output_rows(("z",))
    C = model.linear.C[rows]
    K = ss.place(A, B, POLES)
    out = ssd.observer_design(model, rows, 5 * POLES, TS, K, "pendulum")
    np.testing.assert_allclose(_sorted(np.linalg.eigvals(A - out["L"] @ C)), _sorted(5 * POLES), atol=1e-7)
    sampled = control.c2d(control.ss(A, B, C, 0), TS)
    observer_z = np.linalg.eigvals(sampled.A - out["L_discrete"] @ sampled.C)
    np.testing.assert_allclose(_sorted(observer_z), _sorted(np.exp(5 * POLES * TS)), atol=1e-9)
    compensator = np.linalg.eigvals(A - B @ K - out["L"] @ C)
    np.testing.assert_allclose(_sorted(out["controller_poles"]), _sorted(compensator), atol=1e-9)


def test_disturbance_observer_estimates_a_constant_input(model):
    A, B, nx = model.linear.A, model.linear.B, model.nx
    rows = model.output_rows(("z", "theta"))
    C = model.linear.C[rows]
    out = ssd.disturbance_observer_design(model, rows, 5 * POLES, None, TS, ss.place(A, B, POLES), "pendulum")
    assert out["disturbance_observer_poles"][-1] == pytest.approx(-0.5 * np.min(np.abs(5 * POLES)))
    # (x, d)' = [[A, B], [0, 0]] (x, d), y = C x: the estimate's error dynamics, by hand.
    A_d = np.block([[A, B], [np.zeros((1, nx + 1))]])
    C_d = np.hstack([C, np.zeros((len(rows), 1))])
    error = np.linalg.eigvals(A_d - out["L_disturbance"] @ C_d)
    np.testing.assert_allclose(_sorted(error), _sorted(out["disturbance_observer_poles"]), atol=1e-7)


def test_lqr_gains_against_python_control(model):
    A, B, nx = model.linear.A, model.linear.B, model.nx
    Q = np.diag([1.0, 10.0, 0.1, 0.1, 4.0])
    R = np.array([[0.04]])
    out = ssd.lqr_design(model, Q, R, TS, "pendulum")
    A_I = np.block([[A, np.zeros((nx, 1))], [-model.C_r, np.zeros((1, 1))]])
    B_I = np.vstack([B, np.zeros((1, 1))])
    K, _, _ = control.lqr(A_I, B_I, Q, R)
    # u = −K_lqr x̃ + k_i x_I: the integral's column carries the minus sign.
    np.testing.assert_allclose(np.hstack([out["K_lqr"], [[-out["ki_lqr"]]]]), K, rtol=1e-6)
    K_plain, _, _ = control.lqr(A, B, Q[:nx, :nx], R)
    np.testing.assert_allclose(out["K_lqr_plain"], K_plain, rtol=1e-6)
    disc = control.c2d(control.ss(A, B, np.eye(nx), 0), TS)
    A_Id = np.block([[disc.A, np.zeros((nx, 1))], [-TS * model.C_r, np.eye(1)]])
    B_Id = np.vstack([disc.B, np.zeros((1, 1))])
    K_d, _, _ = control.dlqr(A_Id, B_Id, Q * TS, R * TS)
    np.testing.assert_allclose(out["K_dlqr"], K_d, rtol=1e-6)


def test_kalman_predictor_solves_the_filter_riccati_equation(model):
    out = ssd.kalman_design(model, TS, 10.0, 1e-3, "pendulum")
    disc = model.discrete(TS)
    W, V = out["kalman_W"], out["kalman_V"]
    P = scipy.linalg.solve_discrete_are(disc.A.T, disc.C.T, W, V)
    L = disc.A @ P @ disc.C.T @ np.linalg.inv(disc.C @ P @ disc.C.T + V)
    np.testing.assert_allclose(out["L_kalman"], L, rtol=1e-6, atol=1e-12)
    assert np.all(np.abs(out["kalman_poles_z"]) < 1)
    np.testing.assert_allclose(V, 1e-6 * np.eye(model.linear.ny))
