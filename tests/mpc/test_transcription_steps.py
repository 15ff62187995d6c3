"""Steps of `mpc.Transcription`'s construction alone, against hand-written expectations: the
decision layout and scales of a small problem with every kind of decision, and the simple bounds'
tightening (numbers and parameter values)."""

from __future__ import annotations

import casadi as ca
import numpy as np

import mpc
from mpc.transcription import DecisionBounds

from .test_ocp import point_mass


def small_problem():
    """Point mass (s, ds; force f, |f| <= 3 N), one extra control c, the mass chosen, T free."""
    ocp = mpc.OptimalControlProblem(point_mass(mass=2.0, limit=3.0), mpc.FreeTime(1.0, 4.0, guess=2.5))
    ocp.control("c", -1.0, 1.0)
    ocp.choose("m", 1.0, 3.0, guess=1.5)
    ocp.scale(s=0.5)
    ocp.minimize(ocp.final_time)
    return ocp


def test_layout_orders_decisions_stage_by_stage_then_parameters_then_time():
    """By hand for N = 2, degree 2: (x_0, x_{0,1}, x_{0,2}, u_0, c_0, x_1, ..., x_2, m, T)."""
    tr = mpc.Transcription(small_problem(), mpc.Collocation(intervals=2, degree=2))
    layout = tr.layout
    np.testing.assert_array_equal(layout.states, [[0, 1], [8, 9], [16, 17]])
    np.testing.assert_array_equal(layout.collocation, [[[2, 3], [4, 5]], [[10, 11], [12, 13]]])
    np.testing.assert_array_equal(layout.inputs, [[6], [14]])
    np.testing.assert_array_equal(layout.controls, [[7], [15]])
    assert layout.chosen == {"m": 18} and layout.final_time == 19 and layout.size == 20
    assert tr.decision_labels[3] == "ds at interval 0 collocation point 1"
    assert tr.decision_labels[18:] == ["parameter m", "final time T"]
    # Scales: s by its given 0.5, ds 1, f by the actuator limit, c 1, m and T by their guesses.
    np.testing.assert_array_equal(tr.scale[:8], [0.5, 1.0, 0.5, 1.0, 0.5, 1.0, 3.0, 1.0])
    np.testing.assert_array_equal(tr.scale[18:], [1.5, 2.5])


def test_bounds_keep_the_tightest_in_scaled_units_and_parameter_values_as_expressions():
    bounds = DecisionBounds(np.array([2.0, 4.0, 1.0]))
    bounds.bound([0, 1], -2.0, 3.0)
    bounds.bound(0, -1.0, 10.0)  # tighter below, looser above
    np.testing.assert_array_equal(bounds.lower, [-0.5, -0.5, -np.inf])
    np.testing.assert_array_equal(bounds.upper, [1.5, 0.75, np.inf])
    limit = ca.SX.sym("limit")
    bounds.bound(1, -np.inf, limit)
    bounds.bound(2, limit, np.inf)
    lower, upper = bounds.expressions()
    values = ca.Function("bounds", [limit], [lower, upper])
    for value, expected_upper in ((1.0, 0.25), (8.0, 0.75)):  # limit / 4 against the numeric 0.75
        low, high = (np.asarray(v).ravel() for v in values(value))
        np.testing.assert_array_equal(low, [-0.5, -0.5, value])
        np.testing.assert_array_equal(high, [1.5, expected_upper, np.inf])
