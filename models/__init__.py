"""Plants declared once by their energies; linearizations, simulators, the controller block.

>>> import models
>>> arm = models.get("arm")
>>> xe, ue = arm.equilibrium(theta=0.5)
>>> lin = arm.linearize(xe, ue)
"""

from . import catalog as _catalog  # noqa: F401  (registers the case studies' plants)
from . import signals
from .block import Block, Cascade, Controller, saturate
from .checks import ResourceLimitError, SimulationError
from .closed_loop import ClosedLoopResult, closed_loop_function, simulate_closed_loop
from .linear import LinearModel
from .lockstep import simulate_closed_loop_many
from .monte_carlo_batch import MonteCarloResult, monte_carlo, monte_carlo_chunks
from .plant import Param, Physics, Plant, declare, get, names
from .simulate import Trajectory, simulate
from .uncertainty import corner_params, perturbed, sample_params

__all__ = [
    "Block",
    "Cascade",
    "ClosedLoopResult",
    "Controller",
    "LinearModel",
    "MonteCarloResult",
    "Param",
    "Physics",
    "Plant",
    "ResourceLimitError",
    "SimulationError",
    "Trajectory",
    "closed_loop_function",
    "corner_params",
    "declare",
    "get",
    "monte_carlo",
    "monte_carlo_chunks",
    "names",
    "perturbed",
    "sample_params",
    "saturate",
    "signals",
    "simulate",
    "simulate_closed_loop",
    "simulate_closed_loop_many",
]
