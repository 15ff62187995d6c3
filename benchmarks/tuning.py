"""Gain tuning speed: exact-gradient IPOPT versus derivative-free Nelder-Mead, same problem.

The problem: the pendulum's pole-placement-plus-integrator block (K, k_r, k_i:
six gains) on the nonlinear cart-pendulum, the text's 2 m step over 10 s,
ITAE plus a small control-energy weight, each gain boxed within a factor of
three of the hand design. Both methods minimize the same compiled CasADi
objective from the same start within the same box, in one process:

- gradient: `designs.tuning.tune` (IPOPT, exact gradients by CasADi);
- nelder_mead: scipy.optimize.minimize(method="Nelder-Mead") on the objective's values.

Both evaluate the objective JIT-compiled (compile time counted). Nelder-Mead
runs first; `gradient_s` is IPOPT's wall time until its objective first
reaches Nelder-Mead's final cost ("faster to an equal or better cost"), and
`gradient_total_s` its whole run.

Usage: python benchmarks/tuning.py [--json PATH] [--max-evaluations 20000]
"""

from __future__ import annotations

import argparse
import json
import time

import casadi as ca
import numpy as np
import scipy.optimize

import models
from designs import statespace_cases
from designs.tuning import Cost, Scenario, TuningProblem, tune
from models.compile import jit

PLANT, LABEL, DURATION = "pendulum", "pole placement + integrator", 10.0
COST = Cost("itae", energy_weight=1e-3)


def problem_data():
    plant = models.get(PLANT)
    block = statespace_cases.controllers(PLANT)[LABEL]
    case = models.case(PLANT)
    scenario = Scenario(reference=case.step, duration=DURATION)
    start = block.gain_vector()
    # A box of a factor of three around each hand gain (k_r = 0 gets ±1).
    low = np.where(start > 0, start / 3, 3 * start)
    high = np.where(start > 0, 3 * start, start / 3)
    low[start == 0], high[start == 0] = -1.0, 1.0
    bounds = {name: (low[sl], high[sl]) for name, sl in _slices(block).items()}
    return plant, block, scenario, bounds, low, high


def _slices(block):
    out, i = {}, 0
    for name, g in block.gains.items():
        out[name] = slice(i, i + g.size)
        i += g.size
    return out


def run_gradient(plant, block, scenario, bounds):
    start = time.perf_counter()
    result = tune(plant, block, scenario, cost=COST, jit=True,
                  bounds={k: (lo.reshape(block.gains[k].shape), hi.reshape(block.gains[k].shape))
                          for k, (lo, hi) in bounds.items()})
    return time.perf_counter() - start, result


def time_to_reach(result, target):
    """Seconds until IPOPT's objective first reached `target`, or None if it never did."""
    reached = [t for t, value in result.history if value <= target * (1 + 1e-9)]
    return reached[0] if reached else None


def run_nelder_mead(plant, block, scenario, low, high, max_evaluations):
    start = time.perf_counter()
    problem = TuningProblem(plant, block, scenario, cost=COST)
    objective = jit(ca.Function("objective", [problem.decision], [problem.objective]))
    evaluations = [0]

    def value(x):
        evaluations[0] += 1
        return float(objective(x))

    result = scipy.optimize.minimize(value, problem.start(), method="Nelder-Mead",
                                     bounds=list(zip(low, high)),
                                     options={"maxfev": max_evaluations, "xatol": 1e-8, "fatol": 1e-10,
                                              "adaptive": True})
    return time.perf_counter() - start, result, evaluations[0]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", metavar="PATH", help="write gradient_s, gradient_cost, nelder_mead_s, "
                                                       "nelder_mead_cost, speedup")
    parser.add_argument("--max-evaluations", type=int, default=20000, help="Nelder-Mead's evaluation budget")
    args = parser.parse_args(argv)
    if args.max_evaluations < 1:
        parser.error("--max-evaluations must be >= 1")
    plant, block, scenario, bounds, low, high = problem_data()
    nm_s, nm, nm_evals = run_nelder_mead(plant, block, scenario, low, high, args.max_evaluations)
    grad_total_s, grad = run_gradient(plant, block, scenario, bounds)
    reached = time_to_reach(grad, float(nm.fun))
    grad_s = reached if reached is not None else grad_total_s
    figures = {
        "gradient_s": grad_s, "gradient_total_s": grad_total_s, "gradient_cost": grad.cost,
        "gradient_iterations": grad.iterations, "gradient_status": grad.status,
        "gradient_reached_nelder_mead_cost": reached is not None,
        "nelder_mead_s": nm_s, "nelder_mead_cost": float(nm.fun), "nelder_mead_evaluations": nm_evals,
        "nelder_mead_message": str(nm.message), "initial_cost": grad.initial_cost, "speedup": nm_s / grad_s,
    }
    print(f"problem: {PLANT} '{LABEL}', {block.gain_vector().size} gains, {DURATION:g} s, "
          f"ITAE + {COST.energy_weight:g} energy; start cost {grad.initial_cost:.6g}")
    print(f"{'method':12s} {'wall s':>8s} {'cost':>12s}  notes")
    print(f"{'nelder-mead':12s} {nm_s:8.2f} {float(nm.fun):12.6g}  {nm_evals} evaluations: {nm.message}")
    print(f"{'gradient':12s} {grad_s:8.2f} {grad.cost:12.6g}  IPOPT {grad.status}, {grad.iterations} iterations, "
          f"{grad_total_s:.2f} s in all; reached Nelder-Mead's cost: {reached is not None}")
    print(f"speedup to an equal or better cost: {figures['speedup']:.1f}x")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(figures, fh, indent=2)
    return figures


if __name__ == "__main__":
    main()
