"""Plant/controller co-design: plant parameters and gains decided together.

The closed loop of `designs.tuning` already takes the plant parameters as a
symbolic input, so co-design adds the chosen parameters to the decision
vector and a plant cost to the objective:

    minimize   closed-loop cost(gains, p) + plant_cost(p)
    subject to the specs on the nonlinear closed loop, p_low <= p <= p_high

- simultaneous: gains and parameters in one IPOPT problem;
- sequential: the parameters first (with the starting controller fixed), then
  the gains (with those parameters fixed).

The simultaneous problem starts from the sequential answer, so on the same
problem it is never worse. `size_actuator` finds the smallest actuator limit
that still meets the specs, with the hand design re-derived for each limit
(sequential) or with the gains re-tuned for each limit (simultaneous).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import casadi as ca
import numpy as np

from models import Block, Plant

from .tuning import Cost, Scenario, Specs, TuningProblem, TuningResult, gain_bounds, solve


@dataclass
class CodesignResult:
    """One co-design answer.

    method : "sequential" or "simultaneous"
    params : the chosen values of the designed plant parameters (SI)
    plant : the plant with those values;  block : the controller with its gains
    objective : closed_loop_cost + plant_cost
    feasible, success, message, violations : as in `TuningResult`
    """

    method: str
    params: dict
    plant: Plant
    block: Block
    objective: float
    closed_loop_cost: float
    plant_cost: float
    feasible: bool
    success: bool
    message: str
    violations: list
    wall_time: float


def _plant_cost_function(names, plant_cost):
    p = ca.MX.sym("p", len(names))
    value = plant_cost({n: p[i] for i, n in enumerate(names)}) if plant_cost else ca.MX(0)
    return ca.Function("plant_cost", [p], [value])


def _check_ranges(plant: Plant, design_params: dict) -> None:
    if not design_params:
        raise ValueError("design_params is empty: name the plant parameters to co-design")
    for name, (low, high) in design_params.items():
        if name not in plant.params:
            raise ValueError(f"{plant.name} has no parameter {name!r}; its parameters are {', '.join(plant.params)}")
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ValueError(f"range of {name} must be finite with low < high, got ({low}, {high})")
        plant.with_params(**{name: low})
        if not low <= plant.params[name] <= high:
            raise ValueError(f"{name} = {plant.params[name]} starts outside its range ({low}, {high})")


def _run(plant, block, scenario, names, ranges, plant_cost, free, options, method, start_time):
    """One IPOPT solve over (free gains, the named parameters)."""
    problem = TuningProblem(plant, block, scenario, free=free, extra_params=names, **options["problem"])
    lbx, ubx = gain_bounds(problem, options["bounds"] if free else None)
    lbx[problem.n_gains:] = [ranges[n][0] for n in names]
    ubx[problem.n_gains:] = [ranges[n][1] for n in names]
    cost_fn = _plant_cost_function(names, plant_cost)
    result: TuningResult = solve(problem, lbx, ubx, options["max_iter"], options["jit"],
                                  plant_cost=lambda x: cost_fn(x[problem.n_gains:]), tol=options["tol"])
    values = dict(zip(names, result.decision[problem.n_gains:]))
    plant_cost_value = float(cost_fn(result.decision[problem.n_gains:]))
    return CodesignResult(method=method, params=values, plant=plant.with_params(**values), block=result.block,
                          objective=result.cost, closed_loop_cost=result.cost - plant_cost_value,
                          plant_cost=plant_cost_value, feasible=result.feasible, success=result.success,
                          message=result.message, violations=result.violations,
                          wall_time=time.perf_counter() - start_time)


def codesign(plant: Plant, block: Block, scenario: Scenario, design_params: dict, *,
             plant_cost: Callable | None = None, specs: Specs | None = None, cost: Cost | None = None,
             free=None, bounds=None, samples=None, robust: str = "mean",
             max_iter: int = 200, tol: float = 1e-8, jit: bool = False) -> dict[str, CodesignResult]:
    """Co-design the named plant parameters with the block's gains, both ways.

    Parameters
    ----------
    plant : Plant, its current values are the starting point
    block : Block, the starting controller (usually the hand design)
    scenario : Scenario
    design_params : dict name -> (low, high), the parameters to decide and their ranges (SI)
    plant_cost : callable dict name -> MX symbol -> MX scalar, the price of the plant
        (for example ``lambda p: 0.1 * p["k"]``); default zero
    specs, cost, free, bounds, samples, robust, max_iter, tol, jit
        As in `designs.tuning.tune`. Parameters listed in `samples` rows are
        overwritten by the decision for the designed names.

    Returns
    -------
    dict with "sequential" and "simultaneous" CodesignResult. The simultaneous
    solve starts from the sequential answer.
    """
    _check_ranges(plant, design_params)
    names = tuple(design_params)
    options = {"problem": {"specs": specs, "cost": cost, "samples": samples, "robust": robust},
               "bounds": bounds, "max_iter": max_iter, "tol": tol, "jit": jit}
    start_time = time.perf_counter()
    plant_first = _run(plant, block, scenario, names, design_params, plant_cost, (), options,
                       "sequential", start_time)
    # Second sequential stage: the gains with the chosen plant fixed (a plain tuning problem).
    problem = TuningProblem(plant_first.plant, block, scenario, free=free, **options["problem"])
    lbx, ubx = gain_bounds(problem, bounds)
    tuned = solve(problem, lbx, ubx, max_iter, jit, tol=tol)
    cost_fn = _plant_cost_function(names, plant_cost)
    fixed_cost = float(cost_fn([plant_first.params[n] for n in names]))
    sequential = CodesignResult(
        method="sequential", params=plant_first.params, plant=plant_first.plant, block=tuned.block,
        objective=tuned.cost + fixed_cost, closed_loop_cost=tuned.cost, plant_cost=fixed_cost,
        feasible=tuned.feasible, success=plant_first.success and tuned.success,
        message=f"plant: {plant_first.message}; controller: {tuned.message}", violations=tuned.violations,
        wall_time=time.perf_counter() - start_time)
    start_time = time.perf_counter()
    simultaneous = _run(sequential.plant, sequential.block, scenario, names, design_params, plant_cost, free,
                        options, "simultaneous", start_time)
    return {"sequential": sequential, "simultaneous": simultaneous}


def size_actuator(plant: Plant, design: Callable[[Plant], Block], scenario: Scenario, specs: Specs, *,
                  low: float, high: float, retune: bool, rel_tol: float = 0.01, tune_options=None) -> dict:
    """Smallest symmetric actuator limit in [low, high] for which the specs hold (bisection).

    Parameters
    ----------
    design : callable Plant -> Block, the hand design re-derived for the plant's limit
        (for example a saturation-rule PD whose gains depend on the limit)
    retune : False checks the hand design as designed (sequential: plant first,
        controller by its rule); True also tunes the gains for each limit with
        `designs.tuning.tune` (simultaneous: limit and gains decided together)
    rel_tol : bisection stops when high / low - 1 < rel_tol
    tune_options : keyword arguments for `tune` when retuning (cost, bounds, ...)

    Returns
    -------
    dict: limit (the smallest feasible limit found), block (the design at that
    limit), evaluations (number of limits tried), history [(limit, feasible)].

    Raises
    ------
    ValueError
        When even `high` does not meet the specs (naming the violated specs).
    """
    from .tuning import tune

    if not (0 < low < high and np.isfinite(high)):
        raise ValueError(f"need 0 < low < high, got low={low}, high={high}")
    history = []

    def attempt(limit):
        sized = plant.with_input_limit(limit)
        block = design(sized)
        if retune:
            result = tune(sized, block, scenario, specs=specs, **(tune_options or {}))
            ok, block, violations = result.feasible, result.block, result.violations
        else:
            problem = TuningProblem(sized, block, scenario, specs=specs)
            violations = problem.values(problem.start())[2]
            ok = not violations
        history.append((float(limit), bool(ok)))
        return ok, block, violations

    ok, best_block, violations = attempt(high)
    if not ok:
        raise ValueError(f"even the largest limit {high:g} misses the specs: " + "; ".join(violations))
    best = high
    while high / low - 1 > rel_tol:
        mid = np.sqrt(low * high)
        ok, block, _ = attempt(mid)
        if ok:
            high, best, best_block = mid, mid, block
        else:
            low = mid
    return {"limit": best, "block": best_block, "evaluations": len(history), "history": history}
