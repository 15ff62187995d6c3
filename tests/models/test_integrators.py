"""models.integrators.rk4 against its closed forms: the fourth-order Taylor factor on ẋ = λx, and Simpson's
rule (exact for cubics) on a rate of t alone; the plant's step function and the shooting interval use it."""

import casadi as ca
import numpy as np
import pytest

import models
from models.integrators import rk4


@pytest.mark.parametrize("substeps", [1, 3])
def test_a_step_on_a_linear_rate_is_the_fourth_order_taylor_factor(substeps):
    lam, h = -1.7, 0.3
    z = lam * h / substeps
    factor = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
    x = rk4(lambda x, t: lam * x, np.array([2.0]), h, substeps)
    assert x[0] == pytest.approx(2.0 * factor**substeps, rel=1e-15)


def test_a_rate_of_time_alone_is_integrated_by_simpsons_rule():
    # ∫ t³ dt from 0.5 to 0.5 + h: Simpson's rule is exact for cubics.
    t0, h = 0.5, 0.4
    x = rk4(lambda x, t: np.array([t**3]), np.array([0.0]), h, 1, t0)
    assert x[0] == pytest.approx(((t0 + h) ** 4 - t0**4) / 4, rel=1e-14)


def test_the_plant_step_function_is_rk4_of_its_dynamics():
    plant = models.get("pendulum")
    x0, u, p = np.array([0.1, 0.3, -0.2, 0.5]), np.array([1.5]), plant.param_vector()
    step = plant.step_function(0.01, substeps=4)
    f = lambda x, t: np.asarray(plant.f(x, u)).ravel()
    np.testing.assert_allclose(np.asarray(step(x0, u, p)).ravel(), rk4(f, x0, 0.01, 4), rtol=1e-14, atol=1e-15)
    assert isinstance(rk4(lambda x, t: -x, ca.SX.sym("x", 2), 0.1), ca.SX)
