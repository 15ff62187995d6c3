"""Mesh refinement for collocation: halve the intervals whose collocation defect is too large.

On interval k the collocated state is a polynomial x̃(t) that satisfies the
dynamics only at the collocation points. Between them, the residual
r(t) = dx̃/dt - f(x̃(t), u_k, p) is not zero; the interval's defect is

    e_k = h_k max_{s in S} max_i |r_i(t_k + s h_k)| / scale_i

with S the midpoints between consecutive nodes 0, τ_1, ..., τ_d, 1 and
scale_i the state's scale (`OptimalControlProblem.scale`, default 1): about
the state error the interval adds, in scaled state units.

`solve_refined` solves on the given mesh, splits every interval with
e_k > tolerance in two, re-solves starting from the previous answer
interpolated onto the new mesh, and repeats until every e_k <= tolerance or
`max_refinements` rounds have been made (the status then says so).
"""

from __future__ import annotations

import numpy as np

from models.simulate import lagrange_basis

from .ocp_solution import OCPSolution
from .transcription import Collocation


def collocation_defects(solution: OCPSolution) -> np.ndarray:
    """The defect e_k of every interval of a collocation solution, (N,); see the module docstring."""
    tr = solution.transcription
    if tr.coefficients is None or solution.collocation_states is None:
        raise ValueError("collocation defects need a Collocation transcription, not multiple shooting")
    tau = tr.coefficients.tau
    nodes = np.concatenate([tau, [1.0]]) if tau[-1] < 1 else tau
    samples = (nodes[:-1] + nodes[1:]) / 2
    values, derivs = lagrange_basis(tau, samples)
    plant, p = solution.plant, solution.param_values()
    f = plant.casadi_f.map(samples.size)
    h = np.diff(solution.t)
    defects = np.empty(h.size)
    for k in range(h.size):
        poly = np.vstack([solution.states[k], solution.collocation_states[k]])  # (d+1, nx)
        x = values @ poly
        rate = derivs @ poly / h[k]
        f_values = np.asarray(f(x.T, np.tile(solution.plant_inputs[k][:, None], (1, samples.size)), p)).T
        defects[k] = h[k] * np.max(np.abs(rate - f_values) / tr.state_scale)
    return defects


def solve_refined(
    ocp, transcription, tolerance: float, max_refinements: int, solver_options: dict, solve_options: dict
) -> OCPSolution:
    """Solve `ocp`, halving intervals with a collocation defect above `tolerance`; see the module docstring.

    The returned solution's `refinement` lists (intervals, largest defect) per round.
    """
    tolerance = float(tolerance)
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise ValueError(f"refine_tolerance must be > 0, got {tolerance}")
    if int(max_refinements) != max_refinements or max_refinements < 0:
        raise ValueError(f"max_refinements must be an integer >= 0, got {max_refinements}")
    method = Collocation() if transcription is None else transcription
    if not isinstance(method, Collocation):
        raise ValueError("mesh refinement needs a Collocation transcription, not multiple shooting")
    history = []
    solution = ocp.solver(method, **solver_options).solve(**solve_options)
    warm = {k: v for k, v in solve_options.items() if k not in ("guess", "guess_input", "warm_start")}
    for _ in range(int(max_refinements) + 1):
        defects = collocation_defects(solution)
        history.append((method.intervals, float(defects.max())))
        solution.refinement = list(history)
        if not solution.success or defects.max() <= tolerance or len(history) > max_refinements:
            break
        mesh = method.fractions
        split = defects > tolerance
        middles = (mesh[:-1] + mesh[1:]) / 2
        method = method.with_mesh(np.sort(np.concatenate([mesh, middles[split]])))
        solution = ocp.solver(method, **solver_options).solve(guess=solution, **warm)
    if solution.success and history[-1][1] > tolerance:
        solution.status += (
            f"; mesh refinement stopped after {len(history) - 1} rounds with a defect of "
            f"{history[-1][1]:.3g} > {tolerance:g}"
        )
    return solution
