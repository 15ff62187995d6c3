"""Constrained linear and nonlinear model predictive control."""

from .controller import LinearMPC, NonlinearMPC
from .estimator import DisturbanceObserver, SteadyStateTarget
from .linear import MPCProblem, QPParameters, QPSolution, SoftBound, problem_from_model, riccati_terminal_cost
from .nonlinear import NonlinearMPCProblem
from .qp_fast import CondensedDaqpSolver
from .qp_osqp import OsqpSolver
from .reference_cvxpy import CvxpySolver
from .settings import MPCSettings, SoftSpec, linear_mpc, nonlinear_mpc, physical_soft_bounds

__all__ = [
    "CondensedDaqpSolver", "CvxpySolver", "DisturbanceObserver", "LinearMPC", "MPCProblem", "MPCSettings",
    "NonlinearMPC", "NonlinearMPCProblem", "OsqpSolver", "QPParameters", "QPSolution", "SoftBound", "SoftSpec",
    "SteadyStateTarget", "linear_mpc", "nonlinear_mpc", "physical_soft_bounds", "problem_from_model",
    "riccati_terminal_cost",
]
