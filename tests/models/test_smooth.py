"""Smoothed switches: equal to the exact Function outside their bands, smooth and bounded inside."""

import casadi as ca
import numpy as np
import pytest

import models
from models.smooth import smooth_step, smoothed


def _saturation():
    u, limit = ca.SX.sym("u"), ca.SX.sym("limit")
    return ca.Function("sat", [u, limit], [models.saturate(u, limit)])


def test_smooth_step_is_the_quintic_with_flat_ends():
    z = ca.SX.sym("z")
    f = ca.Function("s", [z], [smooth_step(z), ca.jacobian(smooth_step(z), z)])
    for value in (-2.0, -0.5, 0.5, 3.0):
        s, ds = (float(v) for v in f(value))
        assert s == (0.0 if value < 0 else 1.0) and ds == 0.0
    for value in (-0.3, 0.0, 0.2):
        t = value + 0.5
        assert float(f(value)[0]) == pytest.approx(t**3 * (10 - 15 * t + 6 * t**2), rel=1e-15)


def test_smoothed_saturation_is_exact_outside_its_band_and_between_inside():
    exact = _saturation()
    smooth = smoothed(exact)
    assert smooth.name_in() == ["i0", "i1", "width"]
    width, limit = 0.01, 2.0
    for u in (-5.0, -2.02, -1.5, 0.0, 1.0, 1.98, 2.011, 7.0):  # all outside |u ∓ L| <= width L / 2 (about 0.01)
        assert float(smooth(u, limit, width)) == float(exact(u, limit))
    for u in np.linspace(limit - 0.009, limit + 0.009, 19):
        value = float(smooth(u, limit, width))
        assert min(u, limit) - 1e-12 <= value <= max(u, limit) + 1e-12 and abs(value - limit) <= 0.01
    assert np.isnan(float(smooth(np.nan, limit, width)))


def test_smoothed_saturation_has_a_continuous_derivative_matching_finite_differences():
    u = ca.SX.sym("u")
    smooth = smoothed(_saturation())
    w = ca.SX.sym("w")
    value = smooth(u, 1.0, w)
    d = ca.Function("d", [u, w], [value, ca.jacobian(value, u)])
    width = 0.1
    grid = np.linspace(0.9, 1.1, 2001)
    slopes = np.array([float(d(x, width)[1]) for x in grid])
    assert slopes[0] == 1.0 and slopes[-1] == 0.0
    assert np.max(np.abs(np.diff(slopes))) < 0.02  # no jump: C¹ across the band
    for x in (0.96, 0.99, 1.0, 1.03):
        h = 1e-7
        fd = (float(d(x + h, width)[0]) - float(d(x - h, width)[0])) / (2 * h)
        assert float(d(x, width)[1]) == pytest.approx(fd, rel=1e-6, abs=1e-9)


def test_logic_and_fmin_fmax_are_blended_and_equalities_kept():
    x, k = ca.SX.sym("x"), ca.SX.sym("k")
    exact = ca.Function(
        "f",
        [x, k],
        [
            ca.if_else(ca.logic_and(x > 0, ca.logic_not(x > 1)), x**2, -x),
            ca.fmin(x, 1.0),
            ca.fmax(x, 1.0),
            ca.if_else(k == 0, 1.0, 1 / k),
        ],
    )
    smooth = smoothed(exact)
    for value in (-1.0, 0.5, 0.8, 1.5):
        for a, b in zip(exact(value, 0.0), smooth(value, 0.0, 1e-3)):
            assert float(a) == float(b)
    assert float(smooth(0.3, 0.0, 0.1)[3]) == 1.0  # k == 0 stays an exact test


def test_only_sx_functions_are_smoothed():
    x = ca.MX.sym("x")
    with pytest.raises(TypeError, match="smoothed needs an SX casadi.Function"):
        smoothed(ca.Function("f", [x], [ca.fmin(x, 1)]))
    with pytest.raises(TypeError, match="smoothed needs an SX casadi.Function"):
        smoothed(lambda v: v)


def test_smoothed_closed_loop_equals_the_exact_one_away_from_the_limits():
    """The arm's saturating PD: widths too small to reach any sample give the exact run bit for bit."""
    from tests.designs.test_tuning import ArmPD

    arm = models.get("arm")
    block = ArmPD(arm, kp=1.0, kd=0.1)
    n = 300
    exact = models.closed_loop_function(arm, block, n, 10)
    smooth = models.closed_loop_function(arm, block, n, 10, smooth=True)
    assert smooth.name_in()[-1] == "width"
    args = (
        np.zeros(2),
        np.zeros(0),
        np.full((1, n), np.deg2rad(50)),
        np.zeros((2, n)),
        np.zeros((1, n)),
        arm.param_vector(),
        block.gain_vector(),
    )
    X, _, U, _ = (np.asarray(v) for v in exact(*args))
    assert np.max(np.abs(U)) == 1.0  # the run saturates
    Xs, _, Us, _ = (np.asarray(v) for v in smooth(*args, 1e-8))
    np.testing.assert_array_equal(Xs, X)
    np.testing.assert_array_equal(Us, U)
    Xw, _, _, _ = (np.asarray(v) for v in smooth(*args, 0.1))
    assert 0 < np.max(np.abs(Xw - X)) < 0.01
