"""Offset-free pieces: the disturbance observer recovers a constant input disturbance on
the exact model, and the steady-state target matches hand-derived steady states."""

import numpy as np
import pytest

import models
import studies
from mpc.estimator import DisturbanceObserver, SteadyStateTarget


def test_observer_recovers_a_constant_input_disturbance_on_the_exact_model():
    plant = models.get("satellite")
    model = plant.linearize().discretize(0.1)
    observer = DisturbanceObserver(model.A, model.B, model.C, 0.05, 0.005, 1e-3)
    true_d, x = np.array([0.3]), np.zeros(4)
    x_hat, d_hat = np.zeros(4), np.zeros(1)
    for k in range(4000):
        u = np.array([0.5 * np.sin(0.05 * k)])
        x_hat, d_hat = observer.correct(x_hat, d_hat, model.C @ x - model.C @ x_hat)
        x_hat = model.A @ x_hat + model.B @ (u + d_hat)
        x = model.A @ x + model.B @ (u + true_d)
    assert d_hat[0] == pytest.approx(true_d[0], abs=1e-9)
    np.testing.assert_allclose(x_hat, x, atol=1e-9)


@pytest.mark.parametrize("name", studies.names())
def test_default_estimators_are_stable(name, build_mpc):
    controller = build_mpc("linear", name)
    radius = np.max(np.abs(np.linalg.eigvals(controller.observer.error_dynamics())))
    assert radius < 1


def test_uuv_target_is_the_hand_derived_steady_state():
    """J φ'' = u + d − b φ' − m g L φ near φ = 0: at rest, u = m g L φ − d."""
    plant = models.get("uuv")
    model = plant.linearize().discretize(0.05)
    target = SteadyStateTarget(model.A, model.B, [[1.0, 0.0]])
    reference, disturbance = np.array([0.4]), np.array([3.0])
    x_s, u_s = target(reference, disturbance)
    p = plant.params
    np.testing.assert_allclose(x_s, [0.4, 0.0], atol=1e-12)
    assert u_s[0] == pytest.approx(p["m"] * p["g"] * p["L"] * 0.4 - 3.0, rel=1e-9)


def test_pendulum_target_holds_the_cart_with_the_disturbance_cancelled():
    model = models.get("pendulum").linearize().discretize(0.01)
    target = SteadyStateTarget(model.A, model.B, [[1.0, 0.0, 0.0, 0.0]])
    x_s, u_s = target(np.array([2.0]), np.array([0.5]))
    np.testing.assert_allclose(x_s, [2.0, 0.0, 0.0, 0.0], atol=1e-10)
    assert u_s[0] == pytest.approx(-0.5, abs=1e-10)


def test_unobservable_disturbance_is_refused():
    # The input drives a state the output does not see.
    A, B, C = np.diag([0.5, 0.5]), np.array([[1.0], [0.0]]), np.array([[0.0, 1.0]])
    with pytest.raises(ValueError, match="not observable"):
        DisturbanceObserver(A, B, C, 1.0, 1.0, 1.0)


def test_a_coordinate_the_input_cannot_hold_is_refused():
    # x1 integrates nothing the input drives: no steady state puts x1 at an arbitrary r.
    A, B = np.array([[1.0, 0.0], [0.0, 0.5]]), np.array([[0.0], [1.0]])
    with pytest.raises(ValueError, match="cannot be held"):
        SteadyStateTarget(A, B, [[1.0, 0.0]])


def test_noise_levels_must_be_positive():
    model = models.get("arm").linearize().discretize(0.01)
    with pytest.raises(ValueError, match="measurement_std"):
        DisturbanceObserver(model.A, model.B, model.C, 1.0, 1.0, 0.0)
