"""Discrete primitives against python-control's Tustin discretization."""

import casadi as ca
import control
import numpy as np
import pytest

from designs.discrete import back_calculation, dirty_derivative, integrate_while_slow, saturate, trapezoid

TS, SIGMA = 0.01, 0.05


def _c2d_step(tf, n):
    disc = control.c2d(tf, TS, "tustin")
    return control.forced_response(disc, np.arange(n) * TS, np.ones(n)).outputs


def test_dirty_derivative_equals_tustin_of_s_over_sigma_s_plus_one():
    n = 200
    signal = np.ones(n)  # a unit step at k = 0, from zero before it
    d_prev, s_prev, out = 0.0, 0.0, []
    for s in signal:
        d_prev = float(dirty_derivative(d_prev, s_prev, s, SIGMA, TS))
        s_prev = s
        out.append(d_prev)
    np.testing.assert_allclose(out, _c2d_step(control.tf([1, 0], [SIGMA, 1]), n), atol=1e-9)


def test_trapezoid_equals_tustin_of_one_over_s():
    n = 100
    integral, e_prev, out = 0.0, 0.0, []
    for e in np.ones(n):
        integral = trapezoid(integral, e_prev, e, TS)
        e_prev = e
        out.append(integral)
    np.testing.assert_allclose(out, _c2d_step(control.tf([1], [1, 0]), n), atol=1e-9)


def test_anti_windup_pieces():
    # Back-calculation removes exactly the saturated excess through ki: ki * Δintegral = Ts (u_sat - u).
    assert float(back_calculation(1.0, 3.0, 2.0, 0.5, TS)) == pytest.approx(1.0 + TS / 0.5 * (2.0 - 3.0))
    assert float(back_calculation(1.0, 3.0, 2.0, 0.0, TS)) == 1.0
    assert float(integrate_while_slow(1.0, 1.5, 0.2, 0.1)) == 1.0
    assert float(integrate_while_slow(1.0, 1.5, -0.05, 0.1)) == 1.5
    x = ca.SX.sym("x")
    clip = ca.Function("clip", [x], [saturate(x, 2.0)])
    assert [float(clip(v)) for v in (-5, 1, 5)] == [-2, 1, 2]
    with pytest.raises(ValueError, match="sigma and sample_period must be > 0"):
        dirty_derivative(0, 0, 1, SIGMA, -0.01)
