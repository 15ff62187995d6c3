"""Constrained linear and nonlinear model predictive control."""

from .controller import LinearMPC, NonlinearMPC
from .defaults import DEFAULTS, MPCDefaults, SoftSpec, controllers, defaults, linear_mpc, nonlinear_mpc
from .estimator import DisturbanceObserver, SteadyStateTarget
from .linear import MPCProblem, QPParameters, QPSolution, SoftBound, problem_from_model, riccati_terminal_cost
from .nonlinear import NonlinearMPCProblem
from .qp_fast import CondensedDaqpSolver
from .qp_osqp import OsqpSolver
from .reference_cvxpy import CvxpySolver

__all__ = [
    "CondensedDaqpSolver", "CvxpySolver", "DEFAULTS", "DisturbanceObserver", "LinearMPC", "MPCDefaults", "MPCProblem",
    "NonlinearMPC", "NonlinearMPCProblem", "OsqpSolver", "QPParameters", "QPSolution", "SoftBound", "SoftSpec",
    "SteadyStateTarget", "controllers", "defaults", "linear_mpc", "nonlinear_mpc", "problem_from_model",
    "riccati_terminal_cost",
]
