"""Gain tuning speed: exact-gradient IPOPT versus derivative-free Nelder-Mead, same problems.

The problems: the pendulum's pole-placement-plus-integrator block (K, k_r,
k_i: six gains) on the nonlinear cart-pendulum over 10 s, ITAE plus a small
control-energy weight, each gain boxed within a factor of three of the hand
design; once for the text's 2 m step, which holds the 5 N actuator in
saturation for seconds, and once for a 0.2 m step that stays in the linear
range. Both methods minimize the same CasADi objective, evaluated in CasADi's
virtual machine, from the same start within the same box, in one process:

- nelder_mead: scipy.optimize.minimize(method="Nelder-Mead") on the objective's values;
- gradient: `designs.tuning.tune` (IPOPT, exact gradients by CasADi).

Nelder-Mead runs first; `gradient_s` is IPOPT's wall time until its
objective first reached Nelder-Mead's final cost ("faster to an equal or
better cost"), `gradient_total_s` its whole run. Saturation makes the
objective's gradient jump wherever a sample enters or leaves the limit, which
slows any gradient method; the two problems show how much.

Usage: python benchmarks/tuning.py [--json PATH] [--max-evaluations 20000] [--problems saturating linear]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

# Run as a script, this file's folder is sys.path[0], where benchmarks/mpc.py would shadow the mpc
# package the case studies import; drop the folder.
_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [entry for entry in sys.path if os.path.abspath(entry or os.curdir) != _HERE]

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402

import models  # noqa: E402
import studies  # noqa: E402
from designs.tuning import Cost, Scenario, TuningProblem, tune  # noqa: E402
from studies.homework import statespace_controllers  # noqa: E402

PLANT, LABEL, DURATION = "pendulum", "pole placement + integrator", 10.0
COST = Cost("itae", energy_weight=1e-3)
STEPS = {"saturating": studies.get(PLANT).step, "linear": 0.2}  # m


def problem_data(step):
    plant = models.get(PLANT)
    block = statespace_controllers(studies.get(PLANT))[LABEL]
    scenario = Scenario(reference=step, duration=DURATION, tracked=studies.get(PLANT).tracked)
    start = block.gain_vector()
    # A box of a factor of three around each hand gain (k_r = 0 gets ±1).
    low = np.where(start > 0, start / 3, 3 * start)
    high = np.where(start > 0, 3 * start, start / 3)
    low[start == 0], high[start == 0] = -1.0, 1.0
    bounds = {name: (low[sl].reshape(block.gains[name].shape), high[sl].reshape(block.gains[name].shape))
              for name, sl in _slices(block).items()}
    return plant, block, scenario, bounds, low, high


def _slices(block):
    out, i = {}, 0
    for name, g in block.gains.items():
        out[name] = slice(i, i + g.size)
        i += g.size
    return out


def run_gradient(plant, block, scenario, bounds):
    start = time.perf_counter()
    result = tune(plant, block, scenario, cost=COST, bounds=bounds)
    return time.perf_counter() - start, result


def time_to_reach(result, target):
    """Seconds until IPOPT's objective first reached `target`, or None if it never did."""
    reached = [t for t, value in result.history if value <= target * (1 + 1e-9)]
    return reached[0] if reached else None


def run_nelder_mead(plant, block, scenario, low, high, max_evaluations):
    start = time.perf_counter()
    problem = TuningProblem(plant, block, scenario, cost=COST)
    objective = ca.Function("objective", [problem.decision], [problem.objective])
    evaluations = [0]

    def value(x):
        evaluations[0] += 1
        return float(objective(x))

    result = scipy.optimize.minimize(value, problem.start(), method="Nelder-Mead",
                                     bounds=list(zip(low, high)),
                                     options={"maxfev": max_evaluations, "xatol": 1e-8, "fatol": 1e-10,
                                              "adaptive": True})
    return time.perf_counter() - start, result, evaluations[0]


def compare(step, max_evaluations):
    plant, block, scenario, bounds, low, high = problem_data(step)
    nm_s, nm, nm_evals = run_nelder_mead(plant, block, scenario, low, high, max_evaluations)
    grad_total_s, grad = run_gradient(plant, block, scenario, bounds)
    reached = time_to_reach(grad, float(nm.fun))
    # IPOPT's iterate times count from its solve; add the problem's construction, which Nelder-Mead's time includes.
    grad_s = reached + (grad_total_s - grad.wall_time) if reached is not None else grad_total_s
    return {
        "step_m": step, "initial_cost": grad.initial_cost,
        "gradient_s": grad_s, "gradient_total_s": grad_total_s, "gradient_cost": grad.cost,
        "gradient_iterations": grad.iterations, "gradient_status": grad.status,
        "gradient_reached_nelder_mead_cost": reached is not None,
        "nelder_mead_s": nm_s, "nelder_mead_cost": float(nm.fun), "nelder_mead_evaluations": nm_evals,
        "nelder_mead_message": str(nm.message), "speedup": nm_s / grad_s,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", metavar="PATH", help="write gradient_s, gradient_cost, nelder_mead_s, "
                        "nelder_mead_cost, speedup (of the first problem) and every problem's figures")
    parser.add_argument("--max-evaluations", type=int, default=20000, help="Nelder-Mead's evaluation budget")
    parser.add_argument("--problems", nargs="+", default=list(STEPS), choices=list(STEPS))
    args = parser.parse_args(argv)
    if args.max_evaluations < 1:
        parser.error("--max-evaluations must be >= 1")
    block = statespace_controllers(studies.get(PLANT))[LABEL]
    print(f"{PLANT} '{LABEL}', {block.gain_vector().size} gains, {DURATION:g} s, "
          f"ITAE + {COST.energy_weight:g} energy")
    print(f"{'problem':11s} {'method':12s} {'wall s':>8s} {'cost':>10s}  notes")
    problems = {}
    for name in args.problems:
        r = problems[name] = compare(STEPS[name], args.max_evaluations)
        label = f"{name} ({r['step_m']:g} m)"
        print(f"{label:11s} {'nelder-mead':12s} {r['nelder_mead_s']:8.2f} {r['nelder_mead_cost']:10.6g}  "
              f"{r['nelder_mead_evaluations']} evaluations: {r['nelder_mead_message']}")
        print(f"{'':11s} {'gradient':12s} {r['gradient_s']:8.2f} {r['gradient_cost']:10.6g}  IPOPT "
              f"{r['gradient_status']}, {r['gradient_iterations']} iterations, {r['gradient_total_s']:.2f} s in "
              f"all; reached Nelder-Mead's cost: {r['gradient_reached_nelder_mead_cost']}")
        print(f"{'':11s} speedup to an equal or better cost: {r['speedup']:.1f}x")
    first = problems[args.problems[0]]
    figures = {k: first[k] for k in ("gradient_s", "gradient_cost", "nelder_mead_s", "nelder_mead_cost",
                                     "speedup")} | {"problem": args.problems[0], "problems": problems}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(figures, fh, indent=2)
    return figures


if __name__ == "__main__":
    main()
