"""Constrained linear and nonlinear model predictive control."""

from .controller import LinearMPC, NonlinearMPC
from .estimator import DisturbanceObserver, SteadyStateTarget
from .linear import MPCProblem, QPParameters, QPSolution, SoftBound, problem_from_model, riccati_terminal_cost
from .mesh_refinement import collocation_defects
from .nonlinear import NonlinearMPCProblem
from .ocp import FreeTime, OptimalControlProblem, UnknownNameError
from .ocp_codesign import NestedCodesignResult, solve_nested
from .ocp_solution import OCPSolution, Verification, resimulate, verify_trajectory
from .ocp_solver import OCPSolver, WarmStart
from .qp_fast import CondensedDaqpSolver
from .qp_osqp import OsqpSolver
from .reference_cvxpy import CvxpySolver
from .scenario_tree import ScenarioTreeMPC, scenario_tree_mpc
from .settings import MPCSettings, SoftSpec, linear_mpc, nonlinear_mpc, physical_soft_bounds
from .transcription import Collocation, MultipleShooting, Transcription
from .tube_mpc import TubeMPC

__all__ = [
    "CondensedDaqpSolver",
    "CvxpySolver",
    "DisturbanceObserver",
    "LinearMPC",
    "MPCProblem",
    "MPCSettings",
    "NonlinearMPC",
    "NonlinearMPCProblem",
    "OsqpSolver",
    "QPParameters",
    "QPSolution",
    "SoftBound",
    "SoftSpec",
    "SteadyStateTarget",
    "ScenarioTreeMPC",
    "TubeMPC",
    "linear_mpc",
    "nonlinear_mpc",
    "physical_soft_bounds",
    "scenario_tree_mpc",
    "problem_from_model",
    "riccati_terminal_cost",
    # optimal control problems
    "Collocation",
    "FreeTime",
    "MultipleShooting",
    "NestedCodesignResult",
    "OCPSolution",
    "OCPSolver",
    "OptimalControlProblem",
    "Transcription",
    "UnknownNameError",
    "Verification",
    "WarmStart",
    "collocation_defects",
    "resimulate",
    "solve_nested",
    "verify_trajectory",
]
