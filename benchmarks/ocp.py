"""Pendulum swing-up by four optimal-control paths: time to solution, objective and verified defect.

The problem (case study II's pendulum on a cart, nominal parameters):

    minimize ∫₀ᵀ F² dt,  T = 4 s,  from hanging at rest x(0) = (z, θ, ż, θ̇) = (0, π, 0, 0)
    to upright at rest x(T) = 0,  |F| <= 5 N (the actuator),  |z| <= 0.5 m (the cart travel)

solved by

    (a) `mpc.OptimalControlProblem` with Radau collocation (degree 3, N intervals),
    (b) the same problem with multiple shooting (the plant's RK4, one step per interval),
    (c) a hand-written CasADi Opti + IPOPT Radau collocation of the same NLP
        (CasADi's direct_collocation example; expanded to SX like ours),
    (d) python-control's `optimal.solve_ocp` with trajectory_method="collocation":
        trapezoidal collocation on its time points, the input linear between them,
        the cost by the trapezoid rule, the constraints at the time points only, solved by
        SciPy's SLSQP with finite-difference derivatives. It takes tens of seconds at
        N = 20 and grows about as N³, so it runs with fewer intervals (--control-intervals);
        (a_d) is (a) with that N, for the ratio at equal N.

Every path starts from the same guess: the plant simulated under F = 2 sin(2πt/T) N
(RK4, `models.simulate`), states interpolated, inputs sampled. Wall time is from the
problem statement to the solution (building the NLP included), the median of --repeat
runs interleaved (a), (b), (c); (d) runs once. "∫F² of its input" is the exact integral of
each answer's input (held for (a)-(c), piecewise linear for (d)); the defect is
`verify()`'s: the input re-simulated with CVODES, over the whole horizon from x(0) (the
upright end is unstable, so this grows with any error) and restarted at every mesh point.

A second problem has several local optima: the spring's minimum-energy transfer priced by its
stiffness (`studies.codesign_problems.spring_transfer_ocp`, three local minima of J*(k) in the range).
The plain local solves (simultaneous and nested, from the problem's start) are timed against the global
layer (`mpc.global_search.codesign`, nested, its default sweep) in this process and on Dask's threads
scheduler with 2 workers (a LocalCluster's spawned processes would re-run this script, which only
runs from its folder); "gap closed" is the
plain nested answer's objective above the global one, relative to the plain one. The two global runs
must agree bit for bit.

Usage: python benchmarks/ocp.py [--intervals 100] [--control-intervals 20] [--repeat 3] [--json PATH]
       [--skip-global]
"""

from __future__ import annotations

import argparse
import time

import _path  # noqa: F401  (before our packages: drops this folder from sys.path)
import casadi as ca
import dask
import numpy as np

import models
import mpc
from models.compile import NumpyCall
from models.files import write_json
from mpc import global_search
from mpc.transcription import collocation_coefficients
from studies import codesign_problems

FINAL_TIME, FORCE_LIMIT, TRAVEL = 4.0, 5.0, 0.5
START = np.array([0.0, np.pi, 0.0, 0.0])
DEGREE = 3
PATHS = {
    "a": "ours, Radau collocation",
    "b": "ours, multiple shooting",
    "c": "hand-written Opti collocation",
    "d": "python-control collocation",
    "a_d": "ours, Radau, (d)'s N",
}


def guess_trajectory(plant, intervals: int) -> models.Trajectory:
    """The common starting point: the plant under F = 2 sin(2πt/T), held per interval (RK4)."""
    t = np.linspace(0, FINAL_TIME, intervals + 1)
    force = 2 * np.sin(2 * np.pi * t[:-1] / FINAL_TIME)
    return models.simulate(plant, START, force[:, None], FINAL_TIME / intervals)


def swing_up(plant) -> mpc.OptimalControlProblem:
    ocp = mpc.OptimalControlProblem(plant, FINAL_TIME)
    x, u = ocp.x, ocp.u
    ocp.minimize(ocp.integral(u.F**2))
    ocp.subject_to(ocp.at_start(ocp.state) == START)
    ocp.subject_to(ocp.at_end(ocp.state) == 0)
    ocp.subject_to(ocp.bounded(-TRAVEL, x.z, TRAVEL))
    return ocp


def ours(plant, method, guess) -> dict:
    started = time.perf_counter()
    solver = swing_up(plant).solver(method)
    built = time.perf_counter()
    solution = solver.solve(guess=guess)
    done = time.perf_counter()
    return {
        "build_s": built - started,
        "solve_s": done - built,
        "total_s": done - started,
        "objective": solution.objective,
        "success": solution.success,
        "status": solution.status,
        "iterations": solution.iterations,
        "t": solution.t,
        "states": solution.states,
        "inputs": solution.inputs,
    }


def hand_written(plant, intervals: int, guess) -> dict:
    """Radau collocation written out with casadi.Opti, as in CasADi's direct_collocation example."""
    started = time.perf_counter()
    coefficients = collocation_coefficients(DEGREE, "radau")
    tau, C, D, B = (coefficients.tau, coefficients.derivative, coefficients.continuity, coefficients.quadrature)
    h = FINAL_TIME / intervals
    p = plant.param_vector()
    f = lambda x, u: plant.casadi_f(x, u, p)
    opti = ca.Opti()
    X = opti.variable(4, intervals + 1)
    U = opti.variable(1, intervals)
    XC = [opti.variable(4, DEGREE) for _ in range(intervals)]
    cost = 0
    for k in range(intervals):
        nodes = ca.horzcat(X[:, k], XC[k])
        for j in range(DEGREE):
            opti.subject_to(h * f(XC[k][:, j], U[:, k]) == nodes @ C[:, j])
            cost += B[j] * U[:, k] ** 2 * h
        opti.subject_to(X[:, k + 1] == nodes @ D)
        opti.subject_to(opti.bounded(-TRAVEL, XC[k][0, :], TRAVEL))
    opti.subject_to(opti.bounded(-TRAVEL, X[0, :], TRAVEL))
    opti.subject_to(opti.bounded(-FORCE_LIMIT, U, FORCE_LIMIT))
    opti.subject_to(X[:, 0] == START)
    opti.subject_to(X[:, intervals] == 0)
    opti.minimize(cost)
    t = np.linspace(0, FINAL_TIME, intervals + 1)
    interpolate = lambda times: np.column_stack([np.interp(times, guess.t, guess.x[:, i]) for i in range(4)])
    opti.set_initial(X, interpolate(t).T)
    for k in range(intervals):
        opti.set_initial(XC[k], interpolate(t[k] + h * tau[1:]).T)
    opti.set_initial(U, guess.u[:, 0])
    opti.solver("ipopt", {"expand": True, "print_time": False}, {"print_level": 0, "sb": "yes"})
    built = time.perf_counter()
    try:
        solution, success = opti.solve(), True
    except RuntimeError:
        solution, success = opti.debug, False
    done = time.perf_counter()
    stats = opti.stats()
    return {
        "build_s": built - started,
        "solve_s": done - built,
        "total_s": done - started,
        "objective": float(solution.value(cost)),
        "success": success,
        "status": stats["return_status"],
        "iterations": int(stats["iter_count"]),
        "t": t,
        "states": np.asarray(solution.value(X)).T,
        "inputs": np.asarray(solution.value(U)).reshape(-1, 1),
    }


def python_control(plant, intervals: int) -> dict:
    import control as ct
    from scipy.optimize import LinearConstraint

    started = time.perf_counter()
    p = plant.param_vector()
    f = NumpyCall(plant.casadi_f)
    system = ct.nlsys(
        lambda t, x, u, params: f(x, u, p)[0].ravel(), None, inputs=1, states=4, outputs=4, name="pendulum"
    )
    t = np.linspace(0, FINAL_TIME, intervals + 1)
    guess = guess_trajectory(plant, intervals)
    guess_force = 2 * np.sin(2 * np.pi * t / FINAL_TIME)
    constraints = [
        ct.optimal.input_range_constraint(system, [-FORCE_LIMIT], [FORCE_LIMIT]),
        ct.optimal.state_range_constraint(
            system, [-TRAVEL, -np.inf, -np.inf, -np.inf], [TRAVEL, np.inf, np.inf, np.inf]
        ),
    ]
    terminal = [(LinearConstraint, np.hstack([np.eye(4), np.zeros((4, 1))]), np.zeros(4), np.zeros(4))]
    result = ct.optimal.solve_ocp(
        system,
        t,
        START,
        lambda x, u: u[0] ** 2,
        constraints,
        terminal_constraints=terminal,
        initial_guess=(guess.x.T, guess_force[None, :]),
        trajectory_method="collocation",
        print_summary=False,
    )
    done = time.perf_counter()
    return {
        "build_s": float("nan"),
        "solve_s": done - started,
        "total_s": done - started,
        "objective": float(result.cost),
        "success": bool(result.success),
        "status": str(result.message),
        "iterations": int(getattr(result, "nit", 0) or 0),
        "t": t,
        "states": np.asarray(result.states).T,
        "inputs": np.asarray(result.inputs).reshape(-1, 1),
        "piecewise_linear": True,
    }


def input_cost(row) -> float:
    """Exact ∫F² dt of the answer's input: held, or linear between the time points."""
    h, u = np.diff(row["t"]), row["inputs"][:, 0]
    if row.get("piecewise_linear"):
        return float(np.sum(h / 3 * (u[:-1] ** 2 + u[:-1] * u[1:] + u[1:] ** 2)))
    return float(np.sum(h * u**2))


def defects(plant, row, substeps: int = 20) -> tuple[float, float]:
    """verify()'s two defects; a piecewise-linear input is held on `substeps` pieces per interval
    at its mean over each (exact to O(h²/substeps²)), compared at the time points."""
    t, states, u = row["t"], row["states"], row["inputs"]
    if not row.get("piecewise_linear"):
        check = mpc.verify_trajectory(plant, t, states, u)
        return check.max_defect, check.max_interval_defect
    fractions = (np.arange(substeps) + 0.5) / substeps
    fine_t = np.concatenate(
        [t[k] + (t[k + 1] - t[k]) * np.arange(substeps) / substeps for k in range(len(t) - 1)] + [t[-1:]]
    )
    held = np.concatenate([u[k, 0] + (u[k + 1, 0] - u[k, 0]) * fractions for k in range(len(t) - 1)])[:, None]
    whole = mpc.resimulate(plant, fine_t, states[0], held)[::substeps]
    local = [
        mpc.resimulate(
            plant, fine_t[k * substeps : (k + 1) * substeps + 1], states[k], held[k * substeps : (k + 1) * substeps]
        )[-1]
        for k in range(len(t) - 1)
    ]
    return float(np.max(np.abs(whole - states))), float(np.max(np.abs(np.array(local) - states[1:])))


def dask_threads(function, items) -> list:
    """`map` on Dask's threads scheduler (its workers set by ``dask.config``), results in the items' order."""
    return list(dask.compute(*[dask.delayed(function)(item) for item in items], scheduler="threads"))


def global_layer(intervals: int = 80) -> dict:
    """The multi-optimum problem: plain local solves against the global layer on 1 and 2 workers."""
    transcription = mpc.Collocation(intervals=intervals)
    build = codesign_problems.spring_transfer_ocp
    started = time.perf_counter()
    simultaneous = build().solve(transcription, solver_options={"tolerance": 1e-10})
    simultaneous_s = time.perf_counter() - started
    started = time.perf_counter()
    nested = mpc.solve_nested(build(), transcription)
    nested_s = time.perf_counter() - started
    started = time.perf_counter()
    here = global_search.codesign(build, transcription, method="nested")
    seconds_1 = time.perf_counter() - started
    with dask.config.set(num_workers=2):
        started = time.perf_counter()
        there = global_search.codesign(build, transcription, method="nested", map=dask_threads, workers=2)
        seconds_2 = time.perf_counter() - started
    local, best = nested.objective, here.best.objective
    return {
        "problem": "spring minimum-energy transfer, stiffness priced, k in "
        f"{list(codesign_problems.TRANSFER_RANGE)} N/m from {codesign_problems.TRANSFER_GUESS} N/m",
        "intervals": intervals,
        "design": here.design,
        "optima": [{"k": o.params["k"], "objective": o.objective, "converged": o.success} for o in here.optima],
        "local_simultaneous": {
            "k": simultaneous.chosen["k"],
            "objective": simultaneous.objective,
            "seconds": simultaneous_s,
        },
        "local_nested": {"k": nested.params["k"], "objective": local, "seconds": nested_s},
        "best": {"k": here.best.params["k"], "objective": best, "converged": here.converged},
        "gap_closed": (local - best) / abs(local),
        "gap_closed_absolute": local - best,
        "seconds_1": seconds_1,
        "seconds_2": seconds_2,
        "identical": here.sweep == there.sweep and here.optima == there.optima,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--intervals", type=int, default=100, help="N for (a), (b), (c)")
    parser.add_argument("--control-intervals", type=int, default=20, help="N for python-control (d)")
    parser.add_argument("--repeat", type=int, default=3, help="runs of (a), (b), (c); the median is reported")
    parser.add_argument("--skip-python-control", action="store_true")
    parser.add_argument("--json", metavar="PATH", help="write the figures as one JSON object")
    parser.add_argument("--skip-global", action="store_true", help="skip the multi-optimum problem")
    args = parser.parse_args(argv)

    plant = models.get("pendulum")
    N = args.intervals
    guess = guess_trajectory(plant, N)
    runs = {key: [] for key in "abc"}
    for _ in range(args.repeat):
        runs["a"].append(ours(plant, mpc.Collocation(intervals=N, degree=DEGREE, points="radau"), guess))
        runs["b"].append(ours(plant, mpc.MultipleShooting(intervals=N), guess))
        runs["c"].append(hand_written(plant, N, guess))
    rows = {}
    for key, results in runs.items():
        row = dict(results[-1])
        for field in ("build_s", "solve_s", "total_s"):
            row[field] = float(np.median([r[field] for r in results]))
        row["intervals"] = N
        rows[key] = row
    if not args.skip_python_control:
        rows["d"] = python_control(plant, args.control_intervals) | {"intervals": args.control_intervals}
        small = guess_trajectory(plant, args.control_intervals)
        same_n = [
            ours(plant, mpc.Collocation(intervals=args.control_intervals, degree=DEGREE), small)
            for _ in range(args.repeat)
        ]
        rows["a_d"] = dict(same_n[-1]) | {
            "intervals": args.control_intervals,
            "total_s": float(np.median([r["total_s"] for r in same_n])),
            "build_s": float(np.median([r["build_s"] for r in same_n])),
            "solve_s": float(np.median([r["solve_s"] for r in same_n])),
        }

    for row in rows.values():
        row["input_cost"] = input_cost(row)
        row["defect"], row["interval_defect"] = defects(plant, row)
        row["peak_force"] = float(np.max(np.abs(row["inputs"])))
        row["max_travel"] = float(np.max(np.abs(row["states"][:, 0])))

    base = rows["a"]["total_s"]
    print(
        f"Pendulum swing-up: minimum ∫F² dt, T = {FINAL_TIME} s, |F| <= {FORCE_LIMIT} N, |z| <= {TRAVEL} m; "
        f"median of {args.repeat} runs for (a)-(c)"
    )
    header = (
        f"{'path':36s} {'N':>4s} {'build s':>8s} {'solve s':>8s} {'total s':>8s} {'/ (a)':>7s} "
        f"{'objective':>10s} {'∫F² input':>10s} {'iter':>5s} {'defect':>9s} {'interval':>9s} status"
    )
    print(header)
    for key, row in rows.items():
        label = f"({key}) {PATHS[key]}"
        print(
            f"{label:36s} {row['intervals']:4d} {row['build_s']:8.3f} {row['solve_s']:8.3f} {row['total_s']:8.3f} "
            f"{row['total_s'] / base:7.2f} {row['objective']:10.4f} {row['input_cost']:10.4f} "
            f"{row['iterations']:5d} {row['defect']:9.2e} {row['interval_defect']:9.2e} {row['status'][:40]}"
        )
    solved = [row["input_cost"] for key, row in rows.items() if row["success"] and key != "a_d"]
    best = min(solved)
    figures = {
        "problem": {
            "final_time_s": FINAL_TIME,
            "force_limit_N": FORCE_LIMIT,
            "travel_m": TRAVEL,
            "start": START.tolist(),
            "degree": DEGREE,
        },
        "repeat": args.repeat,
        "paths": {
            key: {k: v for k, v in row.items() if k not in ("t", "states", "inputs")} | {"label": PATHS[key]}
            for key, row in rows.items()
        },
        "objective_a_over_best": rows["a"]["input_cost"] / best,
        "time_a_over_c": rows["a"]["total_s"] / rows["c"]["total_s"],
    }
    print(
        f"(a) ∫F² / best converged = {figures['objective_a_over_best']:.4f} (target <= 1.01); "
        f"time (a) / (c) = {figures['time_a_over_c']:.2f} (target <= 1.5)",
        end="",
    )
    if "d" in rows:
        figures["time_d_over_a"] = rows["d"]["total_s"] / rows["a"]["total_s"]
        figures["time_d_over_a_same_intervals"] = rows["d"]["total_s"] / rows["a_d"]["total_s"]
        print(
            f"; time (d) / (a) = {figures['time_d_over_a']:.1f} (target >= 10), "
            f"{figures['time_d_over_a_same_intervals']:.1f} at (d)'s N"
        )
    else:
        print()
    if not args.skip_global:
        figures["global"] = g = global_layer()
        print(
            f"Global layer ({g['problem']}; {g['design']}): {len(g['optima'])} local optima; plain nested "
            f"k = {g['local_nested']['k']:.4g} N/m, J = {g['local_nested']['objective']:.5g} "
            f"({g['local_nested']['seconds']:.2f} s); global k = {g['best']['k']:.4g} N/m, J = "
            f"{g['best']['objective']:.5g}; gap closed {100 * g['gap_closed']:.1f} %; 1 worker {g['seconds_1']:.2f} s, "
            f"2 workers {g['seconds_2']:.2f} s (ratio {g['seconds_1'] / g['seconds_2']:.2f}); bit for bit: "
            f"{g['identical']}"
        )
    if args.json:
        write_json(args.json, figures)


if __name__ == "__main__":
    main()
