"""The weight-parameterized LQR: its gain is python-control's LQR of the augmented linearization."""

import control
import numpy as np
import pytest

import models
from designs import tuned_lqr
from designs.statespace_blocks import TrackingModel


def test_weights_and_log_weights_are_inverse_and_positive():
    theta = np.array([0.3, -2.0, 1.5, -0.7])
    Q, R = tuned_lqr.weights(theta, 2)
    assert np.all(np.linalg.eigvalsh(Q) > 0) and R[0, 0] > 0
    np.testing.assert_allclose(tuned_lqr.log_weights(Q, R), theta, rtol=0, atol=1e-14)


def test_a_zero_weight_gets_the_floor_and_bad_weights_are_refused():
    theta = tuned_lqr.log_weights(np.diag([4.0, 0.0, 2.0]), 1.0, zero_floor=1e-3)
    np.testing.assert_allclose(np.exp(theta), [4.0, 2e-3, 2.0, 1.0])
    with pytest.raises(ValueError, match="diagonal"):
        tuned_lqr.log_weights(np.array([[1.0, 0.1], [0.1, 1.0]]), 1.0)
    with pytest.raises(ValueError, match="R must be"):
        tuned_lqr.log_weights(np.eye(2), 0.0)
    with pytest.raises(ValueError, match="entries"):
        tuned_lqr.weights([0.0, 0.0], 2)
    with pytest.raises(ValueError, match="finite"):
        tuned_lqr.weights([0.0, np.nan, 0.0, 0.0], 2)


@pytest.mark.parametrize("plant", ["arm", "uuv"])
def test_gain_is_python_controls_lqr_of_the_augmented_linearization(plant):
    known = models.get(plant)
    tracked = {"arm": "theta", "uuv": known.state_names[0]}[plant]
    model = TrackingModel.from_plant(known, tracked)
    theta = np.random.default_rng(3).normal(0.0, 1.5, model.nx + 2)
    K, ki, K_aug = tuned_lqr.gains(model, theta)
    lin = known.linearize()
    index = known.state_names.index(tracked)
    # The augmentation written out by hand: x_I' = r − x_tracked.
    A_I = np.block([[lin.A, np.zeros((model.nx, 1))], [-np.eye(model.nx)[[index]], np.zeros((1, 1))]])
    B_I = np.vstack([lin.B, [[0.0]]])
    K_ref, _, _ = control.lqr(A_I, B_I, np.diag(np.exp(theta[:-1])), np.exp(theta[-1]))
    np.testing.assert_allclose(K_aug, K_ref, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(K, K_ref[0, :-1], rtol=1e-8, atol=1e-10)
    assert ki == pytest.approx(-K_ref[0, -1], rel=1e-8)
    block = tuned_lqr.block(known, tracked, theta, 0.01)
    np.testing.assert_allclose(np.ravel(block.gains["K"]), K_ref[0, :-1], rtol=1e-8, atol=1e-10)
    assert float(np.ravel(block.gains["ki"])[0]) == pytest.approx(-K_ref[0, -1], rel=1e-8)
