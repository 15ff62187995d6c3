"""mpc.tube_mpc: the tube MPC's QP against cvxpy and the LQR, its refusals, and its guarantee on the
double integrator with an additive disturbance in W (where the guarantee is exact), beside a nominal
MPC of the same structure that does leave the constraints."""

from types import SimpleNamespace

import cvxpy as cp
import numpy as np
import pytest

from models.lqr import dlqr
from mpc.sets import Polytope, Zonotope
from mpc.tube import build_tube
from mpc.tube_mpc import TubeMPC, condensed_prediction, nominal_sets

SAMPLE_PERIOD = 0.1
A = np.array([[1.0, SAMPLE_PERIOD], [0.0, 1.0]])
B = np.array([[SAMPLE_PERIOD**2 / 2], [SAMPLE_PERIOD]])
W_BOX = Zonotope.box([-0.01, -0.02], [0.01, 0.02])
LIMITS = Polytope.box([-1.0, -1.0], [1.0, 1.0])
MODEL = SimpleNamespace(A=A, B=B, xe=np.zeros(2), ue=np.zeros(1), sample_period=SAMPLE_PERIOD)
HORIZON = 15
START = np.array([0.3, 0.6])  # heading for the position limit: the nominal plan rides it


@pytest.fixture(scope="module")
def tube():
    return build_tube(A, B, W_BOX, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0)


def controller(sets, **kwargs):
    return TubeMPC(MODEL, sets, horizon=HORIZON, state_weight=np.eye(2), input_weight=1.0, **kwargs)


#: A velocity limit the nominal plan rides when the position weight is large: |velocity| <= 0.5.
RIDDEN = Polytope.box([-1.0, -0.5], [1.0, 0.5])
EAGER = {"state_weight": np.diag([100.0, 1e-2]), "input_weight": 1e-2}


def worst_excess(mpc, start, seeds) -> float:
    """Largest excess over RIDDEN and |u| <= 1 across closed loops x⁺ = A x + B u + w with w from W:
    half the runs at W's corners (its extreme points), half uniform inside it."""
    corners, half, limit = W_BOX.corners(), np.array([0.01, 0.02]), np.array([1.0, 0.5])
    worst = -np.inf
    for seed in seeds:
        rng, x = np.random.default_rng(seed), np.array(start, dtype=float)
        z = mpc.initial_state(x)
        for _ in range(60):
            z, u = mpc.step(z, x)
            w = corners[rng.integers(len(corners))] if seed % 2 else rng.uniform(-half, half)
            x = A @ x + B @ u + w
            worst = max(worst, float(np.max(np.abs(x) - limit)), float(np.max(np.abs(u))) - 1.0)
    return worst


def test_tube_mpc_keeps_every_constraint_under_disturbances_in_w_and_nominal_mpc_does_not():
    """From 0.6 m the eager cost drives the nominal plan along the velocity limit; a disturbance at W's
    velocity side then crosses it by up to 0.02 m/s, which the tube's tightening leaves room for."""
    sets = build_tube(A, B, W_BOX, RIDDEN, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0)
    start, seeds = [0.6, 0.0], range(40)
    robust = TubeMPC(MODEL, sets, horizon=HORIZON, initial_state=start, **EAGER)
    assert worst_excess(robust, start, seeds) <= 0.0
    untightened = nominal_sets(A, B, sets.feedback, RIDDEN, [-1.0], [1.0])
    nominal = TubeMPC(MODEL, untightened, horizon=HORIZON, initial_state=start, replan=True, **EAGER)
    assert worst_excess(nominal, start, seeds) > 1e-2  # the same check fails without the tightening


def test_plan_equals_cvxpy_on_the_tightened_problem(tube):
    """The condensed, scaled DAQP plan against the uncondensed problem written out in cvxpy."""
    mpc, z0 = controller(tube), np.array([0.4, 0.3])
    plan, success, _, _ = mpc.solve(z0)
    assert success
    _, P = dlqr(A, B, np.eye(2), np.eye(1), "test")
    z, v = cp.Variable((HORIZON + 1, 2)), cp.Variable((HORIZON, 1))
    G, g = tube.state_constraints.H, tube.state_constraints.h
    cons = [z[0] == z0, tube.terminal_set.H @ z[HORIZON] <= tube.terminal_set.h]
    cons += [z[k + 1] == A @ z[k] + B @ v[k] for k in range(HORIZON)]
    cons += [G @ z[k] <= g for k in range(1, HORIZON)]
    cons += [v >= tube.input_lower[0], v <= tube.input_upper[0]]
    cost = sum(cp.sum_squares(z[k]) + cp.sum_squares(v[k]) for k in range(HORIZON)) + cp.quad_form(z[HORIZON], P)
    cp.Problem(cp.Minimize(cost), cons).solve(solver=cp.CLARABEL)
    np.testing.assert_allclose(plan, v.value, atol=1e-6)
    assert np.max(np.abs(plan)) >= tube.input_upper[0] - 1e-9  # an input bound is active: not the LQR


def test_unconstrained_first_move_is_the_lqr_law(tube):
    mpc, z0 = controller(tube), np.array([0.02, -0.01])
    plan, success, _, _ = mpc.solve(z0)
    gain, _ = dlqr(A, B, np.eye(2), np.eye(1), "test")
    assert success
    np.testing.assert_allclose(plan[0], -gain @ z0, rtol=1e-9, atol=1e-12)


def test_command_is_the_ancillary_law_and_z_moves_with_the_nominal_model(tube):
    mpc = controller(tube)
    z = mpc.initial_state(START)
    x = START + np.array([0.005, -0.01])
    plan, _, _, _ = mpc.solve(z)
    z_next, u = mpc.step(z, x)
    np.testing.assert_allclose(u, plan[0] + tube.feedback @ (x - z), rtol=1e-12)
    np.testing.assert_allclose(z_next, A @ z + B @ plan[0], rtol=1e-12)
    assert mpc.step_info()["error_in_tube"]


def test_condensed_prediction_matches_the_recursion():
    rng = np.random.default_rng(1)
    Phi, Gamma = condensed_prediction(A, B, 5)
    z0, V = rng.normal(size=2), rng.normal(size=5)
    z, stacked = z0, []
    for v in V:
        z = A @ z + B[:, 0] * v
        stacked.append(z)
    np.testing.assert_allclose(Phi @ z0 + Gamma @ V, np.concatenate(stacked), rtol=1e-12)


def test_replanning_plans_from_the_measured_state(tube):
    mpc = controller(tube, replan=True)
    x = START + np.array([0.005, -0.01])
    plan, _, _, _ = mpc.solve(x)
    z_next, u = mpc.step(mpc.initial_state(START), x)
    np.testing.assert_allclose(u, plan[0], rtol=1e-12)
    np.testing.assert_allclose(z_next, A @ x + B @ plan[0], rtol=1e-12)


def test_refuses_an_initial_state_the_tightened_problem_cannot_start_from(tube):
    """(0.95, 0.9): the position bound tightened by h_Z leaves no room to brake."""
    with pytest.raises(ValueError, match=r"infeasible at the initial state.*lack a margin of"):
        controller(tube, initial_state=[0.95, 0.9])
    with pytest.raises(ValueError, match="lack a margin"):
        controller(tube).initial_state([0.95, 0.9])


def test_refuses_an_initial_state_outside_the_tightened_state_constraints(tube):
    """Position 0.9 > 1 − h_Z: no plan helps, the first state itself lacks the margin."""
    margin = 0.9 - tube.state_constraints.h[0]
    with pytest.raises(ValueError, match=rf"row 0 at step 0.*lack a margin of {margin:.6g}"):
        controller(tube, initial_state=[0.9, 0.0])


def test_refuses_an_error_set_the_constraints_cannot_hold():
    big = Zonotope.box([-0.2, -0.4], [0.2, 0.4])
    with pytest.raises(ValueError, match="larger than the constraints can hold"):
        build_tube(A, B, big, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0)
