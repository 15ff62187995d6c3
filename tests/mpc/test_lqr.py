"""Unconstrained MPC with the Riccati terminal cost is the infinite-horizon LQR law.

With P the discrete Riccati solution, the cost-to-go beyond the horizon is exact, so
the first move of the finite-horizon QP is u_s − K (x̂ − x_s) for every horizon N.
Checked against a scalar closed form derived by hand and against python-control's
dlqr, through all three solver paths."""

import control
import numpy as np
import pytest

import models
import mpc
from mpc.linear import MPCProblem, QPParameters
from mpc.reference_cvxpy import CvxpySolver

SOLVERS = {"daqp": mpc.CondensedDaqpSolver, "osqp": mpc.OsqpSolver, "cvxpy": CvxpySolver}
FAR = 1e6  # input bounds that never bind


def scalar_riccati(a, b, q, r):
    """P and K of x⁺ = a x + b u with cost Σ q x² + r u², by hand.

    P = q + a²P − (abP)² / (r + b²P)  ⇔  b²P² + (r − q b² − a² r) P − q r = 0;
    the stabilizing root is the positive one; K = a b P / (r + b² P).
    """
    linear = r - q * b**2 - a**2 * r
    P = (-linear + np.sqrt(linear**2 + 4 * b**2 * q * r)) / (2 * b**2)
    return P, a * b * P / (r + b**2 * P)


def first_moves(problem, solver, states, x_target=None, u_target=None):
    """First inputs for each initial state (rows of `states`)."""
    nx, nu = problem.nx, problem.nu
    x_target = np.zeros(nx) if x_target is None else x_target
    u_target = np.zeros(nu) if u_target is None else u_target
    out = []
    for x0 in states:
        solution = solver.solve(QPParameters(x0, np.zeros(nu), x_target, u_target, np.zeros(nu)))
        assert solution.success, solution.status
        out.append(solution.inputs[0])
    return np.array(out)


@pytest.mark.parametrize("horizon", [1, 7, 40])
@pytest.mark.parametrize("path", list(SOLVERS))
def test_scalar_mpc_is_the_closed_form_lqr_law(horizon, path):
    a, b, q, r = 1.2, 0.5, 2.0, 0.3  # unstable open loop
    P, K = scalar_riccati(a, b, q, r)
    problem = MPCProblem([[a]], [[b]], q, r, horizon, -FAR, FAR)
    assert problem.P[0, 0] == pytest.approx(P, rel=1e-12)
    assert problem.lqr_gain[0, 0] == pytest.approx(K, rel=1e-12)
    u = first_moves(problem, SOLVERS[path](problem), np.array([[1.0], [-0.3]]))
    np.testing.assert_allclose(u[:, 0], -K * np.array([1.0, -0.3]), atol=1e-6, rtol=0)


@pytest.mark.parametrize("path", list(SOLVERS))
@pytest.mark.parametrize("horizon", [1, 30])
def test_pendulum_mpc_gain_is_python_control_dlqr(path, horizon):
    plant = models.get("pendulum")
    model = plant.linearize().discretize(0.01)
    Q, R = np.diag([1.0, 10.0, 0.1, 0.1]), np.array([[1e-2]])
    K, _, _ = control.dlqr(model.A, model.B, Q, R)
    problem = MPCProblem(model.A, model.B, Q, R, horizon, -FAR, FAR)
    # Columns of the gain: the first move from each unit initial state.
    gain = -first_moves(problem, SOLVERS[path](problem), np.eye(4)).T
    np.testing.assert_allclose(gain, K, atol=1e-6 * max(1.0, np.max(np.abs(K))), rtol=0)


def test_tracking_first_move_is_lqr_about_the_target():
    plant = models.get("satellite")
    model = plant.linearize().discretize(0.1)
    Q, R = np.diag([1.0, 10.0, 0.1, 0.1]), np.array([[0.04]])
    K, _, _ = control.dlqr(model.A, model.B, Q, R)
    problem = MPCProblem(model.A, model.B, Q, R, 20, -FAR, FAR)
    x_target, u_target = np.array([0.3, 0.3, 0.0, 0.0]), np.array([0.0])
    states = np.array([[0.0, 0.0, 0.0, 0.0], [0.1, -0.2, 0.05, 0.0]])
    u = first_moves(problem, mpc.CondensedDaqpSolver(problem), states, x_target, u_target)
    expected = u_target - (states - x_target) @ K.T
    np.testing.assert_allclose(u, expected, atol=1e-6, rtol=0)
