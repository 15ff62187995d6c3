"""Open-loop co-design, nested: an outer optimizer on the chosen plant parameters, the OCP inside.

The simultaneous form needs nothing here: `OptimalControlProblem.choose`
puts the parameters in the transcription's decision vector and one IPOPT
solve decides them with the trajectory. The nested form keeps them out:

    minimize over p in [p_lo, p_hi]   J*(p) = min over trajectories of the OCP with p fixed

The inner problem is built once (`OCPSolver` with the chosen parameters as
NLP parameters) and re-solved warm from the previous inner answer. The
gradient of J* is exact at a converged inner solve: by the envelope theorem
dJ*/dp = ∂L/∂p, the partial derivative of the inner Lagrangian, which IPOPT
returns (CasADi's ``lam_p`` = -dJ*/dp). The outer optimizer is SciPy's
L-BFGS-B on p scaled to [0, 1].
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from models import deferred

from .ocp_solution import OCPSolution

scipy = deferred.module("scipy")


@dataclass
class NestedCodesignResult:
    """The answer of `solve_nested`.

    params : the chosen parameters' values;  objective : J* there
    solution : the inner OCPSolution at those values
    success : outer and every inner solve converged;  outer_status : SciPy's message
    outer_iterations, inner_solves : counts;  inner_statuses : the status of every inner solve
    wall_time : s
    """

    params: dict
    objective: float
    solution: OCPSolution
    success: bool
    outer_status: str
    outer_iterations: int
    inner_solves: int
    inner_statuses: list
    wall_time: float


class _InnerFailure(RuntimeError):
    pass


def solve_nested(
    ocp,
    transcription=None,
    *,
    tolerance: float = 1e-10,
    ftol: float = 1e-12,
    max_outer_iterations: int = 200,
    start: dict | None = None,
    solver_options: dict | None = None,
    **solve_options,
) -> NestedCodesignResult:
    """Nested co-design of the parameters in `ocp.choose(...)`; see the module docstring.

    Parameters
    ----------
    transcription : of the inner problems (default: as `OptimalControlProblem.solver`)
    max_outer_iterations : L-BFGS-B's iteration limit
    start : the outer optimizer's starting values by name (SI; default each chosen parameter's guess)
    tolerance : L-BFGS-B's ftol and gtol (on J* and its gradient in the [0, 1]-scaled parameters)
    solver_options : passed to `OCPSolver` (default tolerance 1e-10: J* must be accurate below the
        outer optimizer's steps); solve_options to every inner `OCPSolver.solve`
    """
    if not ocp.chosen:
        raise ValueError("nested co-design needs parameters to choose: call ocp.choose(name, lower, upper)")
    started = time.perf_counter()
    solver = ocp.solver(transcription, chosen_as_parameters=True, **({"tolerance": 1e-10} | (solver_options or {})))
    tr = solver.transcription
    names = list(ocp.chosen)
    lower = np.array([ocp.chosen[n].lower for n in names])
    upper = np.array([ocp.chosen[n].upper for n in names])
    span = upper - lower
    plant_slice = tr.parameter_slices["plant"]
    position = [plant_slice.start + tr.fixed_param_names.index(n) for n in names]
    fixed_overrides = dict(solve_options.pop("plant_params", None) or {})
    statuses: list[str] = []
    memory: dict = {"solution": None, "z": None}

    def inner(z):
        values = lower + np.clip(z, 0, 1) * span
        options = dict(solve_options)
        if memory["solution"] is not None:
            options.pop("guess_input", None)
            options["guess"] = memory["solution"]
        solution = solver.solve(plant_params=fixed_overrides | dict(zip(names, values)), **options)
        statuses.append(solution.status)
        if not solution.success:
            raise _InnerFailure(f"inner OCP failed at {dict(zip(names, values))}: {solution.status}")
        memory["solution"], memory["z"] = solution, np.array(z, dtype=float)
        gradient = -solution.lam_p[position] * span
        return solution.objective, gradient

    outer_status, success, iterations = "", False, 0
    try:
        begin = {n: ocp.chosen[n].guess for n in names} | dict(start or {})
        unknown = sorted(set(begin) - set(names))
        if unknown:
            raise ValueError(f"start names {unknown}, which the problem does not choose ({names})")
        first = (np.clip(np.array([float(begin[n]) for n in names]), lower, upper) - lower) / span
        result = scipy.optimize.minimize(
            inner,
            first,
            jac=True,
            method="L-BFGS-B",
            bounds=[(0.0, 1.0)] * len(names),
            options={"ftol": ftol, "gtol": tolerance, "maxiter": int(max_outer_iterations)},
        )
        outer_status, success, iterations = str(result.message), bool(result.success), int(result.nit)
        if memory["z"] is None or not np.array_equal(memory["z"], result.x):
            inner(result.x)  # the reported solution at the returned point
    except _InnerFailure as failure:
        outer_status = str(failure)
    solution = memory["solution"]
    if solution is None:
        raise RuntimeError(f"nested co-design: {outer_status}")
    params = {n: float(solution.params[n]) for n in names}
    return NestedCodesignResult(
        params,
        solution.objective,
        solution,
        success and solution.success,
        outer_status,
        iterations,
        len(statuses),
        statuses,
        time.perf_counter() - started,
    )
