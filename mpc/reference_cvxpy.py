"""The readable reference: the MPC problem of `mpc.linear` written in cvxpy as it reads on paper.

Slow (cvxpy canonicalizes the problem; with Parameters it does so once and
maps the parameter values to solver data each solve). Every fast path is
tested against it: same first input to 1e-5.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from models import deferred

from .linear import MPCProblem, QPParameters, QPSolution

cp = deferred.module("cvxpy")


def _square_root(weight: np.ndarray) -> np.ndarray:
    """L with L Lᵀ = weight for a symmetric PSD weight, so ‖Lᵀ e‖² = eᵀ weight e."""
    values, vectors = np.linalg.eigh(weight)
    return vectors * np.sqrt(np.clip(values, 0.0, None))


def mpc_problem(problem: MPCProblem, x0, disturbance, x_target, u_target, u_previous):
    """The cvxpy Problem and its input variable, for numbers or cvxpy Parameters.

    Parameters
    ----------
    problem : MPCProblem
    x0, disturbance, x_target, u_target, u_previous : arrays or cp.Parameter of sizes nx, nu, nx, nu, nu

    Returns
    -------
    cp.Problem, the input variable u (N, nu) and the slack variable s (N, ns)
    """
    N, nx, nu, ns = problem.horizon, problem.nx, problem.nu, problem.n_soft
    A, B, G = problem.A, problem.B, problem.soft_rows
    x = cp.Variable((N + 1, nx), name="x")
    # The inputs relative to their bounds: kilonewtons and newton-metres alike for the solver.
    input_scale = np.maximum(np.abs(problem.input_lower), np.abs(problem.input_upper))
    u = cp.Variable((N, nu), name="u_relative") @ np.diag(input_scale)
    s = cp.Variable((N, max(ns, 1)), nonneg=True, name="s")
    Q_root, R_root, P_root = (_square_root(W) for W in (problem.Q, problem.R, problem.P))

    cost = (
        cp.sum_squares((x[:N] - x_target) @ Q_root)
        + cp.sum_squares((u - u_target) @ R_root)
        + cp.sum_squares((x[N] - x_target) @ P_root)
    )
    constraints = [
        x[0] == x0,
        x[1:] == x[:N] @ A.T + (u + disturbance) @ B.T,
        u >= problem.input_lower,
        u <= problem.input_upper,
    ]
    if problem.rate_limit is not None:
        constraints += [
            cp.abs(u[0] - u_previous) <= problem.rate_limit,
            cp.abs(cp.diff(u, axis=0)) <= problem.rate_limit,
        ]
    if ns:
        cost += cp.sum(s @ problem.soft_linear_weight) + cp.sum_squares(
            s @ np.diag(np.sqrt(problem.soft_quadratic_weight))
        )
        g = x[1:] @ G.T
        lower, upper = np.isfinite(problem.soft_lower), np.isfinite(problem.soft_upper)
        if lower.any():
            constraints.append(g[:, lower] + s[:, lower] >= problem.soft_lower[lower])
        if upper.any():
            constraints.append(g[:, upper] - s[:, upper] <= problem.soft_upper[upper])
    else:
        constraints.append(s == 0)
    return cp.Problem(cp.Minimize(cost), constraints), u, s


class CvxpySolver:
    """The cvxpy formulation as a solver path.

    Parameters
    ----------
    problem : MPCProblem
    parametrized : bool
        True: build once with cvxpy Parameters and only set their values per
        solve. False: rebuild the problem from numbers every solve (the way
        a first MPC script is often written).
    solver : str, a cvxpy solver name; CLARABEL (interior point) by default
    solver_options : dict passed to `Problem.solve`; for CLARABEL the default
        tightens its gaps and feasibility tolerances to 1e-10 so the whole plan,
        not just the first input, is a reference
    """

    name = "cvxpy"

    def __init__(
        self,
        problem: MPCProblem,
        parametrized: bool = True,
        solver: str = "CLARABEL",
        solver_options: dict | None = None,
    ):
        if solver not in cp.installed_solvers():
            raise ValueError(
                f"solver {solver!r} is not an installed cvxpy solver; installed: {', '.join(cp.installed_solvers())}"
            )
        self.problem = problem
        self.parametrized = parametrized
        self.solver = solver
        tight: dict[str, Any] = dict(
            tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12, tol_ktratio=1e-10, max_iter=500
        )
        self.solver_options: dict[str, Any] = (tight if solver == "CLARABEL" else {}) | dict(solver_options or {})
        # cvxpy's C++ canonicalization does not take every expression here; choose the
        # SciPy one up front instead of a warning on each solve.
        self.solver_options.setdefault("canon_backend", cp.SCIPY_CANON_BACKEND)
        if parametrized:
            nx, nu = problem.nx, problem.nu
            # In the order of QPParameters' fields.
            self.parameters = (
                cp.Parameter(nx, name="x0"),
                cp.Parameter(nu, name="d"),
                cp.Parameter(nx, name="x_s"),
                cp.Parameter(nu, name="u_s"),
                cp.Parameter(nu, name="u_prev"),
            )
            self._cvx, self._u, self._s = mpc_problem(problem, *self.parameters)

    def solve(self, params: QPParameters) -> QPSolution:
        """Solve for `params`; the returned plan is NaN unless cvxpy reports an optimum."""
        start = time.perf_counter()
        if self.parametrized:
            for parameter, value in zip(self.parameters, params):
                parameter.value = np.asarray(value, dtype=float)
            cvx, u, s = self._cvx, self._u, self._s
        else:
            cvx, u, s = mpc_problem(self.problem, *params)
        try:
            cvx.solve(solver=self.solver, **self.solver_options)
            status = cvx.status
        except cp.error.SolverError as err:
            status = f"solver error: {err}"
        elapsed = time.perf_counter() - start
        N, nu, ns = self.problem.horizon, self.problem.nu, self.problem.n_soft
        success = status == cp.OPTIMAL and u.value is not None
        inputs = np.asarray(u.value) if success else np.full((N, nu), np.nan)
        slacks = np.asarray(s.value)[:, :ns] if success else np.full((N, ns), np.nan)
        iterations = int(getattr(cvx.solver_stats, "num_iters", 0) or 0) if success else 0
        return QPSolution(inputs, slacks, success, status, iterations, elapsed)

    def reset(self) -> None:
        """Nothing to forget: cvxpy solves from scratch."""
