"""Gain tuning speed: exact-gradient IPOPT versus derivative-free Nelder-Mead, same problems.

The problems: the pendulum's pole-placement-plus-integrator block (K, k_r,
k_i: six gains) on the nonlinear cart-pendulum over 10 s, ITAE plus a small
control-energy weight, each gain boxed within a factor of three of the hand
design; once for the text's 2 m step, which holds the 5 N actuator in
saturation for seconds, and once for a 0.2 m step that stays in the linear
range. Every method minimizes the same CasADi objective of the exact
(nonsmooth) closed loop, evaluated in CasADi's virtual machine, from the same
start within the same box, in one process:

- nelder_mead: scipy.optimize.minimize(method="Nelder-Mead") on the objective's values;
- gradient: `designs.tuning.tune` (IPOPT, exact gradients by CasADi, the smoothing
  continuation through the saturation, first on the coarsely integrated loop and then
  on this one); each iterate's exact objective (on this loop, whatever level it came
  from) is evaluated after the run, and the time it was reached counted;
- with --compare, the alternatives `tune`'s method was chosen against: "exact loop"
  (IPOPT on the exact loop, single shooting: `tune` with `SolveOptions(method="exact")`) and "multiple
  shooting" (IPOPT on the exact loop cut into `SEGMENTS` intervals whose start states
  are decisions, with continuity constraints), each capped at `ALTERNATIVE_MAX_ITER`
  iterations.

Nelder-Mead runs first; `gradient_s` is the gradient method's wall time until
its exact objective first came within 1e-6 (relative) of Nelder-Mead's final
cost ("faster to an equal cost"), `gradient_total_s` its whole run, and
`gradient_status` IPOPT's final status (`gradient_converged`: it stopped on
its convergence test and the continuation settled, not at an iteration cap).

The "mpc" problem tunes the arm's linear MPC weights (`studies.tuned_rows`, the objective its
"tuned MPC" row is tuned on: every run judged by the table's own verdict, `BARRIER` plus the largest
relative excess while a spec (tightened by `tuned_rows.MARGIN`) is missed, else ITAE and energy
relative to the start) twice from the case's own weights, in the same process: the baseline is
Nelder-Mead on complete evaluations, with a first simplex of the same steps as the poll (weights
x 4), capped at `MPC_BASELINE_EVALUATIONS`; ours is `studies.tuned_rows.search` (the poll search with its
early rejection). `speedup` is the baseline's time to the worse of the two final scores over ours;
`status` the poll's stopping test.

Usage: python benchmarks/tuning.py [--json PATH] [--max-evaluations 20000] [--problems saturating linear mpc]
       [--compare]
"""

from __future__ import annotations

import argparse
import json
import time

import _path  # noqa: F401  (before our packages: drops this folder from sys.path)
import casadi as ca
import numpy as np
import scipy.optimize

import models
import studies
from designs.tuning import Cost, Scenario, SolveOptions, TuningProblem, TuningSetup, tune
from studies import tuned_rows
from studies.homework import statespace_controllers

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
    bounds = {
        name: (low[sl].reshape(block.gains[name].shape), high[sl].reshape(block.gains[name].shape))
        for name, sl in _slices(block).items()
    }
    return plant, block, scenario, bounds, low, high


def _slices(block):
    out, i = {}, 0
    for name, g in block.gains.items():
        out[name] = slice(i, i + g.size)
        i += g.size
    return out


#: Relative distance to Nelder-Mead's final cost that counts as reaching it.
REACHED = 1e-6
#: Intervals of the multiple-shooting alternative (1 s each).
SEGMENTS = 10


#: IPOPT iteration cap of the alternatives (`--compare`): the exact loop stops there rather than converging.
ALTERNATIVE_MAX_ITER = 300


def run_gradient(plant, block, scenario, bounds, method="smooth", max_iter=3000):
    start = time.perf_counter()
    result = tune(
        TuningSetup(plant, block, scenario, cost=COST, bounds=bounds), SolveOptions(method=method, max_iter=max_iter)
    )
    return time.perf_counter() - start, result


def time_to_reach(history, target):
    """Seconds until the recorded exact objective first came within `REACHED` of `target`, or None."""
    reached = [t for t, value in history if value <= target + REACHED * abs(target)]
    return reached[0] if reached else None


def exact_time_to_reach(result, problem, target):
    """`time_to_reach` for a `tune` result, its iterates judged on the exact loop (after the run, in order)."""
    for (t, _), decision in zip(result.history, result.iterates):
        if problem.values(decision)[0] <= target + REACHED * abs(target):
            return t
    return None


def run_multiple_shooting(plant, block, scenario, low, high):
    """IPOPT on the exact loop in `SEGMENTS` shooting intervals; (seconds, exact cost, status, iterations, history)."""
    started = time.perf_counter()
    problem = TuningProblem(plant, block, scenario, cost=COST)
    exact = ca.Function("objective", [problem.decision], [problem.objective])
    n = problem.n_steps
    length = n // SEGMENTS
    run = models.closed_loop_function(plant, block, length, 10)
    nx, nc = plant.nx, block.n_state
    gains = ca.MX.sym("gains", problem.n_gains)
    nodes = ca.MX.sym("nodes", nx + nc, SEGMENTS - 1)
    x0 = problem.x0
    xc0 = block.initial_state(plant.output(x0) if block.measures == "outputs" else x0, problem.reference[0])
    r = problem.reference[:-1].T
    states, commands, gaps = [], [], []
    for i in range(SEGMENTS):
        s = ca.DM(np.concatenate([x0, xc0])) if i == 0 else nodes[:, i - 1]
        X, XC, U, _ = run(
            s[:nx],
            s[nx:],
            r[:, i * length : (i + 1) * length],
            np.zeros((block.n_measured, length)),
            np.zeros((plant.nu, length)),
            plant.param_vector(),
            gains,
        )
        states.append(X)
        commands.append(U)
        if i < SEGMENTS - 1:
            gaps.append(ca.vertcat(X[:, -1], XC[:, -1]) - nodes[:, i])
    X, U = ca.horzcat(*states), ca.horzcat(*commands)
    t = block.sample_period * np.arange(n)
    e = ca.DM(r[0]).T - ca.horzcat(x0[problem.runs[0].tracked_index], X[problem.runs[0].tracked_index, : n - 1])
    cost = block.sample_period * (
        ca.sum2(ca.DM(t).T * ca.sqrt(e**2 + COST.smoothing**2)) + COST.energy_weight * ca.sum2(ca.sum1(U**2))
    )
    sim = models.simulate_closed_loop(plant, block, problem.reference, DURATION, x0=x0)
    node0 = np.array(
        [np.concatenate([sim.x[(i + 1) * length], sim.xc[(i + 1) * length]]) for i in range(SEGMENTS - 1)]
    ).T
    start = problem.start()
    scale = np.concatenate(
        [
            np.where(start != 0, np.abs(start), 1.0),
            np.repeat(np.maximum(np.max(np.abs(node0), axis=1), 1e-2), SEGMENTS - 1),
        ]
    )
    z = ca.MX.sym("z", scale.size)
    decision = scale * z
    split = ca.Function("split", [gains, nodes], [cost, ca.vertcat(*gaps)])
    f, g = split(decision[: start.size], ca.reshape(decision[start.size :], nx + nc, SEGMENTS - 1))
    history = []

    class Record(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("record", {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            size = {
                "x": scale.size,
                "lam_x": scale.size,
                "g": g.numel(),
                "lam_g": g.numel(),
                "p": 0,
                "lam_p": 0,
                "f": 1,
            }[ca.nlpsol_out(i)]
            return ca.Sparsity.dense(size, 1)

        def eval(self, arg):
            history.append(
                (
                    time.perf_counter() - started,
                    float(exact(scale[: start.size] * np.asarray(arg[0]).ravel()[: start.size])),
                )
            )
            return [0]

    record = Record()
    solver = ca.nlpsol(
        "multiple_shooting",
        "ipopt",
        {"x": z, "f": f, "g": g},
        {
            "ipopt": {
                "max_iter": ALTERNATIVE_MAX_ITER,
                "print_level": 0,
                "tol": 1e-8,
                "acceptable_tol": 1e-6,
                "acceptable_iter": 10,
                "hessian_approximation": "limited-memory",
                "sb": "yes",
            },
            "print_time": False,
            "error_on_fail": False,
            "iteration_callback": record,
        },
    )
    lb = np.concatenate([low, np.full(node0.size, -np.inf)]) / scale
    ub = np.concatenate([high, np.full(node0.size, np.inf)]) / scale
    z0 = np.concatenate([start, node0.ravel(order="F")]) / scale
    sol = solver(x0=z0, lbx=lb, ubx=ub, lbg=0, ubg=0)
    stats = solver.stats()
    gains_found = np.clip(scale[: start.size] * np.asarray(sol["x"]).ravel()[: start.size], low, high)
    return (
        time.perf_counter() - started,
        float(exact(gains_found)),
        stats["return_status"],
        int(stats["iter_count"]),
        history,
    )


def run_nelder_mead(plant, block, scenario, low, high, max_evaluations):
    start = time.perf_counter()
    problem = TuningProblem(plant, block, scenario, cost=COST)
    objective = ca.Function("objective", [problem.decision], [problem.objective])
    evaluations = [0]

    def value(x):
        evaluations[0] += 1
        return float(objective(x))

    result = scipy.optimize.minimize(
        value,
        problem.start(),
        method="Nelder-Mead",
        bounds=list(zip(low, high)),
        options={"maxfev": max_evaluations, "xatol": 1e-8, "fatol": 1e-10, "adaptive": True},
    )
    return time.perf_counter() - start, result, evaluations[0]


def compare(step, max_evaluations, alternatives=False):
    plant, block, scenario, bounds, low, high = problem_data(step)
    nm_s, nm, nm_evals = run_nelder_mead(plant, block, scenario, low, high, max_evaluations)
    target = float(nm.fun)
    grad_total_s, grad = run_gradient(plant, block, scenario, bounds)
    exact_problem = TuningProblem(plant, block, scenario, cost=COST)
    reached = exact_time_to_reach(grad, exact_problem, target)
    # Iterate times count from the solve; add the problem's construction, which Nelder-Mead's time includes.
    grad_s = reached + (grad_total_s - grad.wall_time) if reached is not None else grad_total_s
    out = {
        "step_m": step,
        "initial_cost": grad.initial_cost,
        "gradient_s": grad_s,
        "gradient_total_s": grad_total_s,
        "gradient_cost": grad.cost,
        "gradient_iterations": grad.iterations,
        "gradient_status": grad.status,
        "gradient_converged": grad.converged,
        "gradient_stages": grad.stages,
        "gradient_reached_nelder_mead_cost": reached is not None,
        "nelder_mead_s": nm_s,
        "nelder_mead_cost": target,
        "nelder_mead_evaluations": nm_evals,
        "nelder_mead_message": str(nm.message),
        "speedup": nm_s / grad_s,
    }
    if alternatives:
        total, exact = run_gradient(plant, block, scenario, bounds, method="exact", max_iter=ALTERNATIVE_MAX_ITER)
        hit = exact_time_to_reach(exact, exact_problem, target)
        out["exact_loop"] = {
            "s": hit + (total - exact.wall_time) if hit is not None else total,
            "total_s": total,
            "cost": exact.cost,
            "status": exact.status,
            "iterations": exact.iterations,
            "reached_nelder_mead_cost": hit is not None,
        }
        total, cost, status, iterations, history = run_multiple_shooting(plant, block, scenario, low, high)
        hit = time_to_reach(history, target)
        out["multiple_shooting"] = {
            "s": hit if hit is not None else total,
            "total_s": total,
            "cost": cost,
            "status": status,
            "iterations": iterations,
            "reached_nelder_mead_cost": hit is not None,
        }
    return out


MPC_PLANT = "arm"
#: Nelder-Mead's evaluation cap on the MPC problem (each evaluation is up to eight closed-loop MPC runs).
MPC_BASELINE_EVALUATIONS = 150


def first_reached(history, target):
    """Seconds at which a (seconds, best score) history first reached `target` (relative `REACHED`), or None."""
    return time_to_reach(history, target)


def compare_mpc(max_evaluations=MPC_BASELINE_EVALUATIONS):
    """The MPC weight problem: Nelder-Mead (complete evaluations) against the poll search, one process."""
    case = studies.get(MPC_PLANT)
    objective = tuned_rows.objective(case, "mpc", margin=tuned_rows.MARGIN)
    theta0 = tuned_rows.start(case, "mpc")
    started, best, nm_history, nm_runs = time.perf_counter(), [np.inf], [], [0]

    def value(x):
        evaluation = objective(x)
        nm_runs[0] += evaluation.runs
        if evaluation.value < best[0]:
            best[0] = evaluation.value
            nm_history.append((time.perf_counter() - started, evaluation.value))
        return evaluation.value

    simplex = np.vstack([theta0, theta0 + np.log(4.0) * np.eye(theta0.size)])
    nm = scipy.optimize.minimize(
        value,
        theta0,
        method="Nelder-Mead",
        options={"maxfev": max_evaluations, "initial_simplex": simplex, "xatol": tuned_rows.MIN_STEP, "fatol": 1e-9},
    )
    nm_s = time.perf_counter() - started
    started = time.perf_counter()
    ours = tuned_rows.search(objective, theta0)
    ours_s = time.perf_counter() - started
    target = max(float(nm.fun), ours.value)
    nm_reached = first_reached(nm_history, target)
    ours_reached = first_reached([(t, v) for t, _, v in ours.history], target)
    return {
        "plant": MPC_PLANT,
        "decisions": int(theta0.size),
        "start_score": ours.history[0][2],
        "nelder_mead_s": nm_s,
        "nelder_mead_score": float(nm.fun),
        "nelder_mead_evaluations": int(nm.nfev),
        "nelder_mead_runs": nm_runs[0],
        "nelder_mead_message": str(nm.message),
        "poll_s": ours_reached if ours_reached is not None else ours_s,
        "poll_total_s": ours_s,
        "poll_score": ours.value,
        "poll_evaluations": ours.evaluations,
        "poll_runs": ours.runs,
        "target_score": target,
        "speedup": (nm_reached if nm_reached is not None else nm_s) / max(ours_reached or ours_s, 1e-9),
        "status": ours.status,
        "converged": ours.converged,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--json",
        metavar="PATH",
        help="write gradient_s, gradient_cost, nelder_mead_s, "
        "nelder_mead_cost, speedup (of the first problem) and every problem's figures",
    )
    parser.add_argument("--max-evaluations", type=int, default=20000, help="Nelder-Mead's evaluation budget")
    parser.add_argument("--problems", nargs="+", default=[*STEPS, "mpc"], choices=[*STEPS, "mpc"])
    parser.add_argument(
        "--compare", action="store_true", help="also time IPOPT on the exact loop, single and multiple shooting"
    )
    args = parser.parse_args(argv)
    if args.max_evaluations < 1:
        parser.error("--max-evaluations must be >= 1")
    block = statespace_controllers(studies.get(PLANT))[LABEL]
    print(f"{PLANT} '{LABEL}', {block.gain_vector().size} gains, {DURATION:g} s, ITAE + {COST.energy_weight:g} energy")
    print(f"{'problem':17s} {'method':18s} {'wall s':>8s} {'cost':>12s}  notes")
    problems = {}
    for name in args.problems:
        if name == "mpc":
            r = problems[name] = compare_mpc()
            print(
                f"{'mpc (' + r['plant'] + ')':17s} {'nelder-mead':18s} {r['nelder_mead_s']:8.2f} "
                f"{r['nelder_mead_score']:12.8g}  {r['nelder_mead_evaluations']} evaluations, "
                f"{r['nelder_mead_runs']} closed-loop runs: {r['nelder_mead_message']}"
            )
            print(
                f"{'':17s} {'poll search':18s} {r['poll_s']:8.2f} {r['poll_score']:12.8g}  {r['status']}; "
                f"{r['poll_evaluations']} evaluations, {r['poll_runs']} runs, {r['poll_total_s']:.2f} s in all"
            )
            print(f"{'':17s} speedup to the worse final score ({r['target_score']:.6g}): {r['speedup']:.1f}x")
            continue
        r = problems[name] = compare(STEPS[name], args.max_evaluations, args.compare)
        label = f"{name} ({r['step_m']:g} m)"
        print(
            f"{label:17s} {'nelder-mead':18s} {r['nelder_mead_s']:8.2f} {r['nelder_mead_cost']:12.8g}  "
            f"{r['nelder_mead_evaluations']} evaluations: {r['nelder_mead_message']}"
        )
        print(
            f"{'':17s} {'gradient':18s} {r['gradient_s']:8.2f} {r['gradient_cost']:12.8g}  IPOPT "
            f"{r['gradient_status']} (converged: {r['gradient_converged']}), {len(r['gradient_stages'])} "
            f"smoothing stages, {r['gradient_iterations']} iterations, {r['gradient_total_s']:.2f} s in all; "
            f"reached Nelder-Mead's cost: {r['gradient_reached_nelder_mead_cost']}"
        )
        for key, title in (("exact_loop", "exact loop"), ("multiple_shooting", "multiple shooting")):
            if key in r:
                a = r[key]
                print(
                    f"{'':17s} {title:18s} {a['s']:8.2f} {a['cost']:12.8g}  IPOPT {a['status']}, "
                    f"{a['iterations']} iterations, {a['total_s']:.2f} s in all; reached Nelder-Mead's cost: "
                    f"{a['reached_nelder_mead_cost']}"
                )
        print(f"{'':17s} speedup to Nelder-Mead's cost: {r['speedup']:.1f}x")
    first = problems[next((p for p in args.problems if p != "mpc"), args.problems[0])]
    figures = {
        k: first[k]
        for k in ("gradient_s", "gradient_cost", "nelder_mead_s", "nelder_mead_cost", "speedup")
        if k in first
    } | {
        "problem": args.problems[0],
        "problems": problems,
    }
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(figures, fh, indent=2)
    return figures


if __name__ == "__main__":
    main()
