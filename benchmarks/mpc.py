"""Linear MPC solve time: cvxpy (rebuilt, parametrized), OSQP directly, and the condensed DAQP path.

The pendulum on a cart (4 states, N = 50, Ts = 0.01 s, |F| <= 5 N; the
input bounds are the only constraints, the common case, unless --soft adds
the default soft |theta| bound) runs 500 closed-loop steps on the nonlinear
plant: the 2 m step of the case study with its 0.5 N input disturbance, the
controller designed on the +5 % parameters. The loop is driven by our path
(d); every QP of the run — same estimate, target and previous input — is
also solved by

    (a) cvxpy, rebuilding the problem from numbers (Clarabel),
    (b) cvxpy with Parameters, built once (Clarabel),
    (c) OSQP on the sparse problem, vectors updated, warm-started,
    (d) DAQP on the condensed problem, vectors updated, warm-started,

each timed around its own call (vector update + solve + reading the plan).
The first inputs are compared with the cvxpy reference (a) at every step.

Two timings, both reported. The figures (``median_ms_*``, ``ratio_*_over_d``)
replay the recorded QPs through fresh solvers in blocks of `BLOCK` steps:
each path solves a block in sequence (warm-started along the run as in a
controller, its code and data in the caches as in a real-time loop), then
the next path the same block, so all four still see the same machine load.
The ``interleaved_*`` figures hand each QP to all four paths in turn at every
step, as this benchmark did first: there cvxpy's rebuild between two calls
evicts the caches, which makes a microsecond call 4x slower (measured: the
same DAQP call 24 us after OSQP alone, 99 us after cvxpy) while a millisecond
OSQP call barely changes, so that ratio measures cache misses more than solvers.
``linear_median_ms`` is the whole linear MPC step (estimator, target, DAQP,
clipping) in the closed loop, and ``ratio_c_over_linear_step`` OSQP's solve
alone over it. ``exported_c_step_median_ms`` is the same controller exported
as C (`mpc.export`: its QP by DAQP's C library, set up once and
warm-started), compiled and called through ctypes in the same closed
loop (``exported_c_max_command_diff``: its largest difference from the Python
controller's commands).

The nonlinear MPC (real-time iteration, `mpc.rti`) runs the same pendulum
closed loop (N = 50, Ts = 0.01 s, |F| <= 5 N, input bounds only unless
--soft): ``nmpc_median_ms`` and ``nmpc_p99_ms`` are its per-step preparation
plus feedback times. Every sample's problem (x̂, d̂, x_s, u_s) is recorded and
solved again, in the same run, by

    (f) acados SQP-RTI (Gauss-Newton, partial condensing HPIPM, explicit RK4,
        generated C, Cython wrapper), in a subprocess with the python of the
        environment named by $ACADOS_PYTHON (default
        benchmarks/.venv-acados/bin/python; see benchmarks/acados_pendulum.py
        for how to create it), timed around its set calls and solve:
        ``acados_median_ms``, ``ratio_nmpc_vs_acados`` = acados / ours; where
        acados cannot run, ``acados_unavailable`` says why and the ratio is
        against our converged SQP (``sqp_median_ms``) instead;
    (g) do-mpc's default NMPC (orthogonal collocation, IPOPT) on the same
        problem: ``do_mpc_median_ms`` over the first `--do-mpc-steps` samples.

First moves of both are compared with ours (``*_max_first_move_diff``).

The same nonlinear MPC exported as C (`mpc.export_nmpc`) replays that closed
loop in a C program (`mpc.export_nmpc_replay`: the recorded measurements in,
each step timed inside C with clock_gettime, no Python in the step):
``exported_nmpc_step_median_ms`` and ``exported_nmpc_p99_ms`` (the first,
cold step left out as for ours; the wall clock, which includes the process's
pre-emption on a loaded machine: ``exported_nmpc_cpu_median_ms`` and
``exported_nmpc_cpu_p99_ms`` are the thread's CPU time, without it; the load
average beside them), ``exported_nmpc_max_command_diff`` against
the Python controller's commands, ``exported_nmpc_step_allocations`` the
allocator's calls in the steps (0). acados' generated solver is called from C
on the same recorded samples too (benchmarks/acados_c.py, run with the acados
environment's python: its solver library built without a Python wrapper, a
small C driver timing the set calls, the solve and reading u_0 with
clock_gettime): ``acados_c_step_median_ms``, ``acados_c_p99_ms`` (and its
CPU times) and ``ratio_exported_nmpc_vs_acados_c`` = acados ÷ ours, both from
C; where it cannot run, those are None and ``acados_c_unavailable`` says why.
acados' iterate is shifted by one interval before each sample, as ours is
(its RTI otherwise linearizes at the unshifted solution: first moves up to
0.09 N apart). That both pose the same problem is checked on every 25th
sample solved cold and iterated to convergence by acados and by our SQP:
``acados_converged_first_move_diff``.
Its solve time on other plants is measured on their own closed loops (arm and
pendulum by default, every plant with --all). --settling runs every plant's
step with both MPCs on the ±5 % models with the input disturbance (the slow
tests' scenario) and prints settling times, peak commands and soft-bound margins.

With --soft, OSQP meets instances where theta rides on its bound with zero
slack (the exact penalty's degenerate vertex); there it stops at its
iteration limit or reports "solved inaccurate" with first inputs off by up to
0.1-1 N, so its failures are counted in the table.

Usage: python benchmarks/mpc.py [--steps 500] [--soft] [--all] [--settling] [--do-mpc-steps 100] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
import warnings

import casadi as ca
import numpy as np
from _path import HERE as _HERE  # before our packages: drops this folder from sys.path (see _path.py)

import models
import mpc
import studies
from models.compile import CompilationError
from mpc.export import export_linear_mpc
from mpc.export_nmpc import export_nonlinear_mpc
from mpc.export_nmpc_replay import replay
from mpc.reference_cvxpy import CvxpySolver

PATHS = {
    "a": "cvxpy, rebuilt every step",
    "b": "cvxpy, Parameters reused",
    "c": "OSQP, warm-started",
    "d": "condensed DAQP (ours)",
}


#: Steps a path solves in a row in the replay before the next path takes the same block.
BLOCK = 25


def make_paths(problem) -> dict:
    return {
        "a": CvxpySolver(problem, parametrized=False),
        "b": CvxpySolver(problem, parametrized=True),
        "c": mpc.OsqpSolver(problem),
        "d": mpc.CondensedDaqpSolver(problem),
    }


class Interleaved:
    """Hands every QP to all four paths, timing each call; returns path (d)'s answer."""

    name = "daqp"

    def __init__(self, problem):
        self.paths = make_paths(problem)
        self.times = {key: [] for key in self.paths}
        self.first_moves = {key: [] for key in self.paths}
        self.status = {key: [] for key in self.paths}
        self.params = []

    def reset(self):
        for solver in self.paths.values():
            solver.reset()

    def solve(self, params):
        self.params.append(params)
        answers = {}
        for key in ("a", "b", "c", "d"):
            start = time.perf_counter()
            answers[key] = self.paths[key].solve(params)
            self.times[key].append(time.perf_counter() - start)
            self.first_moves[key].append(answers[key].inputs[0].copy())
            self.status[key].append(answers[key].success)
        return answers["d"]


def case_mpc(kind: str, case, known, **overrides):
    """The case study's linear or nonlinear MPC designed on `known`."""
    build = mpc.linear_mpc if kind == "linear" else mpc.nonlinear_mpc
    return build(known, case.mpc, tracked=case.tracked, **overrides)


def replay_in_blocks(problem, recorded: list) -> tuple[dict, dict, dict]:
    """Times, first moves and successes of fresh solvers of every path over the recorded QPs,
    path after path on each block of `BLOCK` steps."""
    paths = make_paths(problem)
    times = {key: [] for key in paths}
    first_moves = {key: [None] * len(recorded) for key in paths}
    status = {key: [False] * len(recorded) for key in paths}
    for start in range(0, len(recorded), BLOCK):
        for key, solver in paths.items():
            for i in range(start, min(start + BLOCK, len(recorded))):
                begin = time.perf_counter()
                answer = solver.solve(recorded[i])
                times[key].append(time.perf_counter() - begin)
                first_moves[key][i] = answer.inputs[0].copy()
                status[key][i] = answer.success
    return times, first_moves, status


def linear_benchmark(steps: int, soft: bool) -> dict:
    name = "pendulum"
    plant = models.get(name)
    case = studies.get(name)
    known = case.known_plant(plant)
    interleaved = {}

    def factory(problem):
        interleaved["solver"] = Interleaved(problem)
        return interleaved["solver"]

    overrides = {} if soft else {"soft_bounds": ()}
    controller = case_mpc("linear", case, known, solver=factory, **overrides)
    assert controller.horizon == 50 and controller.sample_period == 0.01
    duration = steps * controller.sample_period
    result = models.simulate_closed_loop(
        plant, controller, case.step, duration, input_disturbance=case.input_disturbance
    )
    solver = interleaved["solver"]
    # The whole controller step (estimator, target, QP, clipping) with path (d) alone.
    alone = models.simulate_closed_loop(
        plant,
        case_mpc("linear", case, known, **overrides),
        case.step,
        duration,
        input_disturbance=case.input_disturbance,
    )
    interleaved = {key: 1e3 * float(np.median(solver.times[key])) for key in PATHS}
    times, first_moves, status = replay_in_blocks(controller.problem, solver.params)
    medians = {key: 1e3 * float(np.median(times[key])) for key in PATHS}
    reference = np.array(first_moves["a"])
    diffs = {key: float(np.max(np.abs(np.array(first_moves[key]) - reference))) for key in "bcd"}
    interleaved_reference = np.array(solver.first_moves["a"])
    interleaved_diffs = {
        key: float(np.max(np.abs(np.array(solver.first_moves[key]) - interleaved_reference))) for key in "bcd"
    }
    step_ms = 1e3 * float(np.median(alone.step_time))
    try:
        compiled = export_linear_mpc(case_mpc("linear", case, known, **overrides), "benchmark_mpc").load()
        in_c = models.simulate_closed_loop(
            plant, compiled, case.step, duration, input_disturbance=case.input_disturbance
        )
        exported = {
            "exported_c_step_median_ms": 1e3 * float(np.median(in_c.step_time)),
            "exported_c_max_command_diff": float(np.max(np.abs(in_c.u - alone.u))),
        }
    except CompilationError as err:
        exported = {"exported_c_step_median_ms": None, "exported_c_unavailable": str(err)}
    return {
        "plant": name,
        "steps": steps,
        "soft_bounds": soft,
        "horizon": controller.horizon,
        "sample_period": controller.sample_period,
        "block": BLOCK,
        **{f"median_ms_{key}": medians[key] for key in PATHS},
        "ratio_b_over_d": medians["b"] / medians["d"],
        "ratio_c_over_d": medians["c"] / medians["d"],
        "ratio_a_over_d": medians["a"] / medians["d"],
        "max_first_move_diff": max(diffs.values()),
        **{f"max_first_move_diff_{key}": diffs[key] for key in "bcd"},
        "failures": {key: int(np.sum(~np.array(status[key]))) for key in PATHS},
        **{f"interleaved_median_ms_{key}": interleaved[key] for key in PATHS},
        "interleaved_ratio_c_over_d": interleaved["c"] / interleaved["d"],
        "interleaved_max_first_move_diff": max(interleaved_diffs.values()),
        "interleaved_failures": {key: int(np.sum(~np.array(solver.status[key]))) for key in PATHS},
        "controller_step_median_ms": step_ms,
        "linear_median_ms": step_ms,
        "ratio_c_over_linear_step": medians["c"] / step_ms,
        **exported,
        "saturated_steps": int(np.sum(np.abs(result.u) >= plant.input_limit)),
        "max_abs_u": float(np.max(np.abs(result.u))),
    }


def nonlinear_benchmark(name: str, steps: int) -> dict:
    plant = models.get(name)
    case = studies.get(name)
    controller = case_mpc("nonlinear", case, case.known_plant(plant))
    xe = plant.equilibrium()[0]
    reference = xe[plant.state_names.index(case.tracked)] + case.step
    duration = min(steps * controller.sample_period, case.duration)
    result = models.simulate_closed_loop(
        plant, controller, reference, duration, input_disturbance=case.input_disturbance
    )
    solve = np.array([s["solve_time"] for s in result.status])
    iterations = np.array([s["iterations"] for s in result.status])
    return {
        "plant": name,
        "steps": len(solve),
        "horizon": controller.horizon,
        "sample_period": controller.sample_period,
        "median_ms": 1e3 * float(np.median(solve)),
        "p90_ms": 1e3 * float(np.percentile(solve, 90)),
        "max_ms": 1e3 * float(np.max(solve)),
        "median_iterations": float(np.median(iterations)),
        "failures": int(sum(not s["success"] for s in result.status)),
        "controller_step_median_ms": 1e3 * float(np.median(result.step_time)),
    }


# ---------------------------------------------------------------------------- nonlinear MPC against acados and do-mpc
#: Python templates of the CasADi operations the plants' equations use (for the acados process,
#: whose older CasADi cannot read a Function serialized by ours).
OPERATIONS = {
    ca.OP_ADD: "{0} + {1}",
    ca.OP_SUB: "{0} - {1}",
    ca.OP_MUL: "{0} * {1}",
    ca.OP_DIV: "{0} / {1}",
    ca.OP_NEG: "-{0}",
    ca.OP_SQ: "{0} * {0}",
    ca.OP_TWICE: "2 * {0}",
    ca.OP_SIN: "ca.sin({0})",
    ca.OP_COS: "ca.cos({0})",
    ca.OP_TAN: "ca.tan({0})",
    ca.OP_SQRT: "ca.sqrt({0})",
    ca.OP_EXP: "ca.exp({0})",
    ca.OP_LOG: "ca.log({0})",
    ca.OP_POW: "{0} ** {1}",
    ca.OP_ATAN: "ca.atan({0})",
    ca.OP_FABS: "ca.fabs({0})",
    ca.OP_INV: "1 / {0}",
}


def casadi_to_python(fun: ca.Function) -> str:
    """Source of ``def f(x, u, p, ca)`` returning the outputs of the SX Function ``fun(x, u, p)``
    as a list, instruction by instruction."""
    lines = ["def f(x, u, p, ca):", "    inputs = (x, u, p)", f"    out = [None] * {fun.nnz_out(0)}"]
    for k in range(fun.n_instructions()):
        op, args, result = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
        if op == ca.OP_INPUT:
            lines.append(f"    w{result[0]} = inputs[{args[0]}][{args[1]}]")
        elif op == ca.OP_OUTPUT:
            lines.append(f"    out[{result[1]}] = w{args[0]}")
        elif op == ca.OP_CONST:
            lines.append(f"    w{result[0]} = {float(fun.instruction_constant(k))!r}")
        elif op in OPERATIONS:
            lines.append(f"    w{result[0]} = " + OPERATIONS[op].format(*(f"w{a}" for a in args)))
        else:
            raise ValueError(f"casadi_to_python: operation {op} of {fun.name()} has no template")
    lines.append("    return out")
    return "\n".join(lines)


def acados_python() -> str:
    """The python of the environment holding acados: $ACADOS_PYTHON, else benchmarks/.venv-acados/bin/python."""
    return os.environ.get("ACADOS_PYTHON") or os.path.join(_HERE, ".venv-acados", "bin", "python")


def run_acados(problem: dict, script: str = "acados_pendulum.py") -> dict:
    """benchmarks/`script` (acados_pendulum.py, or acados_c.py: the solver called from C) on `problem`
    in a subprocess with the acados environment's python; its result, or why it could not run."""
    python = acados_python()
    if not os.path.exists(python):
        return {
            "available": False,
            "reason": f"no acados environment at {python} (set ACADOS_PYTHON; see benchmarks/acados_pendulum.py)",
        }
    try:
        where = subprocess.run(
            [python, "-c", "import acados, os; print(os.path.dirname(acados.__file__))"],
            check=True,
            capture_output=True,
            text=True,
            timeout=120,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError) as err:
        return {"available": False, "reason": f"{python} cannot import acados: {err}"}
    environment = dict(os.environ)
    # Its tools (cython) on the PATH, as if the environment were activated.
    environment["PATH"] = os.pathsep.join(filter(None, [os.path.dirname(python), environment.get("PATH", "")]))
    # The generated solver loads acados' shared libraries from the wheel.
    environment["LD_LIBRARY_PATH"] = os.pathsep.join(
        filter(None, [os.path.join(where, "install", "lib"), environment.get("LD_LIBRARY_PATH", "")])
    )
    with tempfile.TemporaryDirectory(prefix="acados-problem-") as folder:
        problem_path, result_path = os.path.join(folder, "problem.json"), os.path.join(folder, "result.json")
        with open(problem_path, "w") as handle:
            json.dump(problem, handle)
        try:
            done = subprocess.run(
                [python, os.path.join(_HERE, script), problem_path, result_path],
                env=environment,
                capture_output=True,
                text=True,
                timeout=1800,
            )
        except subprocess.SubprocessError as err:
            return {"available": False, "reason": f"the acados process did not finish: {err}"}
        if not os.path.exists(result_path):
            tail = " | ".join((done.stderr or done.stdout or "").strip().splitlines()[-3:])
            return {"available": False, "reason": f"the acados process failed (exit {done.returncode}): {tail}"}
        with open(result_path) as handle:
            return json.load(handle)


def do_mpc_run(plant, known, case, settings: dict, recorded: list) -> dict:
    """do-mpc's default NMPC (orthogonal collocation, IPOPT) on the recorded samples' problems."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import do_mpc

    nx, nu = plant.nx, plant.nu
    model = do_mpc.model.Model("continuous")
    x = model.set_variable("_x", "x", (nx, 1))
    u = model.set_variable("_u", "u", (nu, 1))
    d_hat = model.set_variable("_tvp", "d_hat", (nu, 1))
    x_s = model.set_variable("_tvp", "x_s", (nx, 1))
    u_s = model.set_variable("_tvp", "u_s", (nu, 1))
    model.set_rhs("x", known.casadi_f(x, u + d_hat, known.param_vector()))
    model.setup()
    controller = do_mpc.controller.MPC(model)
    controller.set_param(
        n_horizon=settings["horizon"],
        t_step=settings["sample_period"],
        store_full_solution=False,
        nlpsol_opts={"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": 0},
    )
    Q, R, P = (ca.DM(settings[k]) for k in ("Q", "R", "P"))
    error = x - x_s
    controller.set_objective(lterm=ca.bilin(Q, error) + ca.bilin(R, u - u_s), mterm=ca.bilin(P, error))
    controller.set_rterm(u=0.0)
    limit = known.input_limit
    controller.bounds["lower", "_u", "u"] = -limit
    controller.bounds["upper", "_u", "u"] = limit
    template = controller.get_tvp_template()
    current = {key: recorded[0][key] for key in ("d_hat", "x_s", "u_s")}

    def tvp(_):
        for k in range(settings["horizon"] + 1):
            template["_tvp", k, "d_hat"] = current["d_hat"]
            template["_tvp", k, "x_s"] = current["x_s"]
            template["_tvp", k, "u_s"] = current["u_s"]
        return template

    controller.set_tvp_fun(tvp)
    controller.setup()
    times, first = [], []
    for index, step in enumerate(recorded):
        current.update(d_hat=step["d_hat"], x_s=step["x_s"], u_s=step["u_s"])
        x0 = np.array(step["x_hat"]).reshape(-1, 1)
        if index == 0:
            controller.x0 = x0
            controller.set_initial_guess()
        begin = time.perf_counter()
        u0 = controller.make_step(x0)
        elapsed = time.perf_counter() - begin
        if index:
            times.append(elapsed)
        first.append(np.asarray(u0, dtype=float).ravel().tolist())
    return {"step_ms": [1e3 * t for t in times], "first_moves": first}


#: Samples whose problem acados and our SQP solve again cold and tightly converged: the check that both
#: pose the same problem, apart from the real-time iteration's iterates (every 25th sample).
CONVERGED_CHECK = {"every": 25, "tolerance": 1e-10, "max_iterations": 200}


def acados_problem(controller, known, case, recorded: list, settings: dict) -> dict:
    """The NMPC problem of `controller` as benchmarks/acados_pendulum.py reads it: the model as Python
    source, the weights, the soft bounds and the recorded samples."""
    plant = controller.plant
    return {
        "nx": plant.nx,
        "nu": plant.nu,
        "horizon": controller.horizon,
        "sample_period": controller.sample_period,
        "substeps": case.mpc.substeps,
        "params": known.param_vector().tolist(),
        "model_code": casadi_to_python(known.casadi_f),
        "input_limit": known.input_limit.tolist(),
        "Q": settings["Q"],
        "R": settings["R"],
        "P": settings["P"],
        "steps": recorded,
        "soft": [
            {
                "row": b.row.tolist(),
                "lower": b.lower,
                "upper": b.upper,
                "linear_weight": b.linear_weight,
                "quadratic_weight": b.quadratic_weight,
            }
            for b in controller.soft_bounds
        ],
    }


def converged_first_moves(sqp, recorded: list, check: dict) -> list:
    """First moves of our SQP (`sqp`, iteration="sqp") on every check["every"]-th recorded sample, each
    solved cold (from the plan of zeros rolled out) to the step tolerance check["tolerance"]."""
    nlp, moves = sqp.nlp, []
    nlp.tolerance, nlp.max_iterations = check["tolerance"], check["max_iterations"]
    for record in recorded[:: check["every"]]:
        nlp.reset()
        answer = nlp.solve(
            record["x_hat"],
            record["d_hat"],
            record["x_s"],
            record["u_s"],
            np.array(record["P"]),
            np.zeros(sqp.plant.nu),
            np.zeros((sqp.horizon, sqp.plant.nu)),
        )
        moves.append(np.asarray(answer.inputs)[0].tolist() if answer.success else None)
    return moves


def converged_difference(ours: list, theirs: list) -> float | None:
    """The largest difference of the first moves of the converged check; None where a solve failed."""
    if len(ours) != len(theirs) or any(m is None for m in [*ours, *theirs]):
        return None
    return float(np.max(np.abs(np.array(ours) - np.array(theirs))))


def nmpc_pendulum_benchmark(steps: int, soft: bool, do_mpc_steps: int) -> dict:
    """Our NMPC's closed loop on the pendulum, each sample's problem solved again by acados and do-mpc."""
    name = "pendulum"
    plant, case = models.get(name), studies.get(name)
    known = case.known_plant(plant)
    overrides = {} if soft else {"soft_bounds": ()}
    controller = case_mpc("nonlinear", case, known, **overrides)
    assert controller.horizon == 50 and controller.sample_period == 0.01
    recorded = []
    solve = controller.nlp.solve

    def recording(x_hat, d_hat, x_target, u_target, terminal, u_previous, plan):
        recorded.append(
            {
                "x_hat": np.asarray(x_hat).tolist(),
                "d_hat": np.asarray(d_hat).tolist(),
                "x_s": np.asarray(x_target).tolist(),
                "u_s": np.asarray(u_target).tolist(),
                "P": np.asarray(terminal).tolist(),
            }
        )
        return solve(x_hat, d_hat, x_target, u_target, terminal, u_previous, plan)

    controller.nlp.solve = recording
    duration = steps * controller.sample_period
    result = models.simulate_closed_loop(
        plant, controller, case.step, duration, input_disturbance=case.input_disturbance
    )
    info = result.status
    ours = 1e3 * np.array([s["preparation_time"] + s["feedback_time"] for s in info[1:]])  # the first is cold
    feedback = 1e3 * np.array([s["feedback_time"] for s in info[1:]])
    preparation = 1e3 * np.array([s["preparation_time"] for s in info[1:]])
    our_moves = np.asarray(result.u)[:, 0]
    if np.unique([json.dumps(r["P"]) for r in recorded]).size != 1:
        raise RuntimeError("the terminal weight changed along the run; acados is given one")
    settings = {
        "horizon": controller.horizon,
        "sample_period": controller.sample_period,
        "Q": controller.Q.tolist(),
        "R": controller.R.tolist(),
        "P": recorded[0]["P"],
    }
    figures = {
        "nmpc_plant": name,
        "nmpc_steps": len(ours),
        "nmpc_soft_bounds": soft,
        "nmpc_median_ms": float(np.median(ours)),
        "nmpc_p99_ms": float(np.percentile(ours, 99)),
        "nmpc_max_ms": float(np.max(ours)),
        "nmpc_feedback_median_ms": float(np.median(feedback)),
        "nmpc_preparation_median_ms": float(np.median(preparation)),
        "nmpc_controller_step_median_ms": 1e3 * float(np.median(result.step_time)),
        "nmpc_failures": int(sum(not s["success"] for s in info)),
        "nmpc_saturated_steps": int(np.sum(np.abs(our_moves) >= plant.input_limit[0] - 1e-9)),
    }
    figures |= exported_nmpc_figures(controller, result, case.step)
    # The converged SQP on the same samples (the fallback comparison when acados cannot run).
    sqp = case_mpc("nonlinear", case, known, iteration="sqp", **overrides)
    sqp_times = []
    for record in recorded[1:]:
        begin = time.perf_counter()
        sqp.nlp.solve(
            record["x_hat"],
            record["d_hat"],
            record["x_s"],
            record["u_s"],
            np.array(record["P"]),
            np.zeros(plant.nu),
            np.zeros((controller.horizon, plant.nu)),
        )
        sqp_times.append(time.perf_counter() - begin)
    figures["sqp_median_ms"] = 1e3 * float(np.median(sqp_times))

    problem = acados_problem(controller, known, case, recorded, settings)
    problem["converged_check"] = CONVERGED_CHECK
    converged = converged_first_moves(sqp, recorded, CONVERGED_CHECK)
    acados = run_acados(problem)
    if acados.get("available"):
        step_ms = np.array(acados["step_ms"])
        moves = np.array(acados["first_moves"])[:, 0]
        figures |= {
            "acados_median_ms": float(np.median(step_ms)),
            "acados_p99_ms": float(np.percentile(step_ms, 99)),
            "acados_time_tot_median_ms": float(np.median(acados["time_tot_ms"])),
            "acados_wrapper": acados["wrapper"],
            "acados_build_s": acados["build_s"],
            "acados_max_first_move_diff": float(np.max(np.abs(moves - our_moves))),
            "acados_failures": int(sum(code not in (0,) for code in acados["status"])),
            "acados_converged_first_move_diff": converged_difference(converged, acados["converged_first_moves"]),
            "acados_converged_samples": len(converged),
        }
        figures["ratio_nmpc_vs_acados"] = figures["acados_median_ms"] / figures["nmpc_median_ms"]
    else:
        figures |= {
            "acados_median_ms": None,
            "acados_unavailable": acados.get("reason", "unknown"),
            "ratio_nmpc_vs_acados": None,
            "ratio_nmpc_vs_sqp": figures["sqp_median_ms"] / figures["nmpc_median_ms"],
        }
    figures |= acados_c_figures(problem, figures, our_moves)
    subset = recorded[: max(2, do_mpc_steps)]
    try:
        done = do_mpc_run(plant, known, case, settings, subset)
        moves = np.array(done["first_moves"])[:, 0]
        figures |= {
            "do_mpc_median_ms": float(np.median(done["step_ms"])),
            "do_mpc_steps": len(done["step_ms"]),
            "do_mpc_max_first_move_diff": float(np.max(np.abs(moves - our_moves[: len(moves)]))),
            "ratio_do_mpc_over_nmpc": float(np.median(done["step_ms"])) / figures["nmpc_median_ms"],
        }
    except Exception as err:  # do-mpc is an optional extra
        figures |= {"do_mpc_median_ms": None, "do_mpc_unavailable": f"{type(err).__name__}: {err}"[:300]}
    return figures


def acados_c_figures(problem: dict, figures: dict, our_moves) -> dict:
    """acados' generated solver called from C on the recorded samples (benchmarks/acados_c.py): its
    step's median and p99 inside C, and acados ÷ our exported NMPC's median; None and the reason where
    either cannot run."""
    ours = figures.get("exported_nmpc_step_median_ms")
    acados = run_acados(problem, "acados_c.py")
    if not acados.get("available") or ours is None:
        reason = acados.get("reason", "unknown") if not acados.get("available") else "our exported NMPC did not run"
        return {
            "acados_c_step_median_ms": None,
            "ratio_exported_nmpc_vs_acados_c": None,
            "acados_c_unavailable": reason,
        }
    step_ms, cpu_ms = np.array(acados["step_ms"]), np.array(acados["cpu_ms"])
    moves = np.array(acados["first_moves"])[:, 0]
    return {
        "acados_c_step_median_ms": float(np.median(step_ms)),
        "acados_c_p99_ms": float(np.percentile(step_ms, 99)),
        "acados_c_cpu_median_ms": float(np.median(cpu_ms)),
        "acados_c_cpu_p99_ms": float(np.percentile(cpu_ms, 99)),
        "acados_c_load_average": load_average(),
        "acados_c_failures": int(sum(code != 0 for code in acados["status"])),
        "acados_c_max_first_move_diff": float(np.max(np.abs(moves - np.asarray(our_moves)))),
        "ratio_exported_nmpc_vs_acados_c": float(np.median(step_ms)) / ours,
    }


def load_average() -> float:
    """The machine's load average over the last minute (/proc/loadavg; NaN where there is none)."""
    try:
        with open("/proc/loadavg") as handle:
            return float(handle.read().split()[0])
    except OSError:
        return float("nan")


def exported_nmpc_figures(controller, result, reference: float) -> dict:
    """`controller` exported as C and replayed on `result`'s measurements by a C program: its step's
    median and p99 inside C (the first, cold step left out), its largest command difference from
    `result.u`, and the allocator's calls in the steps."""
    try:
        exported = export_nonlinear_mpc(controller, "bench_nmpc", [reference])
        with tempfile.TemporaryDirectory(prefix="exported-nmpc-") as folder:
            replayed = replay(exported, result.measured, result.r[:-1], folder)
    except (CompilationError, subprocess.CalledProcessError, OSError) as err:
        return {
            "exported_nmpc_step_median_ms": None,
            "exported_nmpc_p99_ms": None,
            "exported_nmpc_max_command_diff": None,
            "exported_nmpc_unavailable": f"{type(err).__name__}: {err}"[:300],
        }
    step_ms, cpu_ms = 1e3 * replayed.step_seconds[1:], 1e3 * replayed.cpu_seconds[1:]
    return {
        "exported_nmpc_step_median_ms": float(np.median(step_ms)),
        "exported_nmpc_p99_ms": float(np.percentile(step_ms, 99)),
        "exported_nmpc_cpu_median_ms": float(np.median(cpu_ms)),
        "exported_nmpc_cpu_p99_ms": float(np.percentile(cpu_ms, 99)),
        "exported_nmpc_load_average": load_average(),
        "exported_nmpc_max_ms": float(np.max(step_ms)),
        "exported_nmpc_max_command_diff": float(np.max(np.abs(replayed.commands - np.asarray(result.u)))),
        "exported_nmpc_failures": int(np.sum(replayed.codes != 0)),
        "exported_nmpc_step_allocations": replayed.step_allocations,
    }


def settling_table() -> dict:
    """Both MPCs on every plant's step, known parameters ±5 %, with the input disturbance."""
    rows = {}
    for name in studies.names():
        plant, case = models.get(name), studies.get(name)
        index = plant.state_names.index(case.tracked)
        reference = plant.equilibrium()[0][index] + case.step
        for kind in ("linear", "nonlinear"):
            for sign in (1, -1):
                controller = case_mpc(kind, case, models.perturbed(plant, case.known_rel, sign))
                result = models.simulate_closed_loop(
                    plant, controller, reference, case.duration, input_disturbance=case.input_disturbance
                )
                error = np.abs(result.x[:, index] - reference)
                outside = np.flatnonzero(error >= 1e-3)
                settle = (
                    float(result.t[outside[-1] + 1])
                    if outside.size and outside[-1] + 1 < len(result.t)
                    else (0.0 if not outside.size else float("inf"))
                )
                margins = [
                    min(value.min() - lower, upper - value.max())
                    for _, row, lower, upper in mpc.physical_soft_bounds(case.mpc, plant)
                    for value in [result.x @ row]
                ]
                solve = np.array([s["solve_time"] for s in result.status])
                rows[f"{name} {kind} {sign:+d}"] = {
                    "settling_time_s": settle,
                    "duration_s": case.duration,
                    "final_error": float(error[-1]),
                    "peak_command_over_limit": float(np.max(np.abs(result.u)) / plant.input_limit[0]),
                    "soft_bound_margin": min(margins) if margins else None,
                    "median_solve_ms": 1e3 * float(np.median(solve)),
                    "max_solve_ms": 1e3 * float(np.max(solve)),
                    "failed_steps": int(sum(not s["success"] for s in result.status)),
                }
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--soft", action="store_true", help="keep the soft |theta| bound in the linear MPC")
    parser.add_argument("--all", action="store_true", help="time the nonlinear MPC on every plant")
    parser.add_argument("--settling", action="store_true", help="settling table of both MPCs on every plant")
    parser.add_argument("--do-mpc-steps", type=int, default=100, help="samples do-mpc solves (about 30 ms each)")
    parser.add_argument("--json", metavar="PATH", help="write the figures as one JSON object")
    args = parser.parse_args(argv)

    linear = linear_benchmark(args.steps, args.soft)
    print(
        f"Linear MPC, pendulum: N = {linear['horizon']}, Ts = {linear['sample_period']} s, "
        f"{linear['steps']} closed-loop steps ({linear['saturated_steps']} saturated), "
        f"{'soft |theta| bound' if args.soft else 'input bounds only'}"
    )
    print(
        f"{'path':32s} {'median ms':>10s} {'x slower than (d)':>18s} {'max |u0 - u0(a)|':>18s} {'failed':>7s}"
        f" {'interleaved ms':>15s}"
    )
    for key, label in PATHS.items():
        ms = linear[f"median_ms_{key}"]
        diff = "reference" if key == "a" else f"{linear[f'max_first_move_diff_{key}']:.2e}"
        print(
            f"({key}) {label:28s} {ms:10.4f} {ms / linear['median_ms_d']:18.1f} {diff:>18s} "
            f"{linear['failures'][key]:7d} {linear[f'interleaved_median_ms_{key}']:15.4f}"
        )
    print(
        f"ratio (b)/(d) = {linear['ratio_b_over_d']:.1f}, (c)/(d) = {linear['ratio_c_over_d']:.1f} "
        f"(interleaved every step: {linear['interleaved_ratio_c_over_d']:.1f}); whole linear MPC step with (d): "
        f"median {linear['linear_median_ms']:.4f} ms, OSQP's solve alone / that = "
        f"{linear['ratio_c_over_linear_step']:.1f}"
    )
    if linear["exported_c_step_median_ms"] is not None:
        print(
            f"exported to C (mpc.export), called through ctypes: median step "
            f"{linear['exported_c_step_median_ms']:.4f} ms, commands within "
            f"{linear['exported_c_max_command_diff']:.1e} of the Python controller's"
        )
    else:
        print(f"exported to C: not measured ({linear['exported_c_unavailable']})")

    rti = nmpc_pendulum_benchmark(args.steps, args.soft, args.do_mpc_steps)
    print(
        f"\nNonlinear MPC, pendulum: N = 50, Ts = 0.01 s, {rti['nmpc_steps']} closed-loop steps "
        f"({rti['nmpc_saturated_steps']} saturated), {'soft |theta| bound' if args.soft else 'input bounds only'}"
    )
    print(f"{'path':44s} {'median ms':>10s} {'p99 ms':>8s} {'max |u0 - ours|':>16s}")
    print(
        f"{'(e) ours: real-time iteration (prep + feedback)':44s} {rti['nmpc_median_ms']:10.4f} "
        f"{rti['nmpc_p99_ms']:8.4f} {'-':>16s}"
    )
    print(
        f"{'    preparation / feedback alone':44s} {rti['nmpc_preparation_median_ms']:10.4f} "
        f"{rti['nmpc_feedback_median_ms']:8.4f}"
    )
    print(f"{'    ours: SQP to convergence':44s} {rti['sqp_median_ms']:10.4f}")
    if rti["acados_median_ms"] is not None:
        print(
            f"{'(f) acados SQP-RTI (' + rti['acados_wrapper'][:10] + ')':44s} {rti['acados_median_ms']:10.4f} "
            f"{rti['acados_p99_ms']:8.4f} {rti['acados_max_first_move_diff']:16.2e}"
        )
        print(f"ratio acados / ours = {rti['ratio_nmpc_vs_acados']:.2f}")
        converged = rti["acados_converged_first_move_diff"]
        print(
            f"    same problem: first moves of both solved cold to convergence on {rti['acados_converged_samples']} "
            f"samples differ by at most {'(a solve failed)' if converged is None else f'{converged:.1e}'}"
        )
    else:
        print(
            f"(f) acados: not measured ({rti['acados_unavailable']}); converged SQP / RTI = "
            f"{rti['ratio_nmpc_vs_sqp']:.2f}"
        )
    if rti["do_mpc_median_ms"] is not None:
        print(
            f"{'(g) do-mpc default (collocation, IPOPT)':44s} {rti['do_mpc_median_ms']:10.4f} {'':8s} "
            f"{rti['do_mpc_max_first_move_diff']:16.2e}"
        )
    else:
        print(f"(g) do-mpc: not measured ({rti['do_mpc_unavailable']})")

    if rti["exported_nmpc_step_median_ms"] is not None:
        print(
            f"{'(h) ours exported as C (mpc.export_nmpc), from C':44s} {rti['exported_nmpc_step_median_ms']:10.4f} "
            f"{rti['exported_nmpc_p99_ms']:8.4f} {rti['exported_nmpc_max_command_diff']:16.2e}"
        )
        print(
            f"    CPU time (the thread's clock) median {rti['exported_nmpc_cpu_median_ms']:.4f}, p99 "
            f"{rti['exported_nmpc_cpu_p99_ms']:.4f} ms; {rti['exported_nmpc_step_allocations']} allocations in "
            f"the C steps; load average {rti['exported_nmpc_load_average']}"
        )
    else:
        print(f"(h) exported as C: not measured ({rti['exported_nmpc_unavailable']})")
    if rti["acados_c_step_median_ms"] is not None:
        print(
            f"{'(i) acados SQP-RTI, its generated C from C':44s} {rti['acados_c_step_median_ms']:10.4f} "
            f"{rti['acados_c_p99_ms']:8.4f} {rti['acados_c_max_first_move_diff']:16.2e}"
        )
        print(
            f"    CPU time median {rti['acados_c_cpu_median_ms']:.4f}, p99 {rti['acados_c_cpu_p99_ms']:.4f} ms; "
            f"load average {rti['acados_c_load_average']}"
        )
        print(f"ratio acados / ours, both from C = {rti['ratio_exported_nmpc_vs_acados_c']:.2f}")
    else:
        print(
            "missing: acados_c_step_median_ms, ratio_exported_nmpc_vs_acados_c "
            f"(acados from C did not run: {rti['acados_c_unavailable']})"
        )

    names = studies.names() if args.all else ["arm", "pendulum"]
    nonlinear = {}
    print("\nNonlinear MPC (real-time iteration, condensed DAQP QPs), solve time per sample")
    print(
        f"{'plant':10s} {'N':>4s} {'Ts s':>6s} {'median ms':>10s} {'p90 ms':>8s} {'max ms':>8s} {'SQP it':>7s} "
        f"{'fails':>6s}"
    )
    for name in names:
        row = nonlinear_benchmark(name, args.steps)
        nonlinear[name] = row
        print(
            f"{name:10s} {row['horizon']:4d} {row['sample_period']:6.2f} {row['median_ms']:10.3f} "
            f"{row['p90_ms']:8.3f} {row['max_ms']:8.1f} {row['median_iterations']:7.1f} {row['failures']:6d}"
        )

    settling = settling_table() if args.settling else None
    if settling:
        print("\nStep with known parameters ±5 % and the input disturbance (settled: |e| < 1e-3 from then on)")
        print(
            f"{'run':24s} {'settles s':>10s} {'of s':>5s} {'|u|max/limit':>13s} {'soft margin':>12s} "
            f"{'solve ms':>9s} {'max ms':>8s} {'failed':>7s}"
        )
        for run, row in settling.items():
            margin = "-" if row["soft_bound_margin"] is None else f"{row['soft_bound_margin']:.4f}"
            print(
                f"{run:24s} {row['settling_time_s']:10.2f} {row['duration_s']:5.0f} "
                f"{row['peak_command_over_limit']:13.4f} {margin:>12s} {row['median_solve_ms']:9.3f} "
                f"{row['max_solve_ms']:8.1f} {row['failed_steps']:7d}"
            )

    if args.json:
        figures = dict(linear) | rti
        figures["nonlinear"] = nonlinear
        for name, row in nonlinear.items():
            figures[f"nmpc_median_ms_{name}"] = row["median_ms"]
        if settling:
            figures["settling"] = settling
        with open(args.json, "w") as handle:
            json.dump(figures, handle, indent=2)


if __name__ == "__main__":
    main()
