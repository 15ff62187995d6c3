"""Robust MPC on the pendulum and the crane, over a Monte Carlo of the ±5 % box and the text's disturbance.

    python benchmarks/robust_mpc.py --json PATH [--samples 200] [--plants pendulum,crane] [--dompc-steps 30]

Per plant, the same runs for every controller: the truth is the nonlinear plant with parameters
drawn uniformly from the ±5 % box about the text's values (`models.uncertainty.sample_params`,
seed 0), the text's constant input disturbance acting (pendulum 0.5 N, II.16(c); crane 500 N, the
case's 10 % of 5 kN), reference 0. The pendulum starts with the cart 0.35 m out moving outwards at
0.255 m/s (3 s runs; a start from which the nominal NMPC leaves the travel limit, see `PLANTS`), the
crane at rest at the origin (20 s runs). Violations are counted by
`models.state_limits` (pendulum: the cart travel of the tube's region, ±0.5 m, SWING_UP_TRAVEL; crane:
the case's STATE_LIMITS, the swing angles ±0.2 rad).

- nominal MPC: `mpc.nonlinear_mpc` designed on the case's known model (nominal·1.05) with the
  case's MPC settings, those limits added as soft bounds at the limit itself (no back-off,
  `studies.robust_rows.with_limits`), so that what the model error does shows;
- scenario-tree NMPC: `mpc.ScenarioTreeMPC` with the same settings; branches chosen corners of the
  ±5 % box, the other parameters nominal (pendulum: the 4 corners of the rod's mass and length m2,
  ell; crane: the 4 corners of the cable lengths ell1, ell2), equal weights, robust horizon 1
  (first move shared, later moves per branch), one real-time iteration a sample. The full boxes'
  16 and 64 corners cost too much per step here: the QP has N·S inputs;
- tube MPC (`mpc.TubeMPC`, linear, regulating to the operating point) and its nominal twin on the
  same QP (`nominal_sets`, the untightened sets, `nominal_linear_*`), with the case's MPC horizon:
  W covers the input disturbance on the known model's linearization (the crane's Z is F(α, s) as a
  zonotope, the pendulum's a certified polytope); the tube with the box's parametric error in W as
  well is attempted and its refusal, which names each constraint and the margin it lacks, reported
  (`parametric_tube_refused`). When the disturbance tube itself is refused, `tube_refused` gives
  the message.

Costs are the runs' Σ (x − x_s)ᵀ Q (x − x_s) + R u² with the case's MPC weights, compared sample by
sample (the median of the ratios). Per-step times are medians over one closed loop on the nominal
truth; the Monte Carlo runs each MPC's samples through its exported C closed loop
(`models.exported_loop`, the studies' path, equal to the Python step's commands to 1e-9; two
threads), or where it does not export (the tube MPC) through `models.simulate_closed_loop_many`
(`<controller>_runs_by` says which).

do-mpc: its multi-stage MPC (n_robust = 1, IPOPT) on the pendulum's tree problem (the same 4 corners,
the case's Q and R, a terminal xᵀ P x, |F| ≤ 5 N, no state bounds), run in its own virtual
environment benchmarks/.venv-dompc by `benchmarks/dompc_multistage.py` (skipped, saying so, when the
environment is missing). Our tree solves the same problem to convergence (``iteration="sqp"``) and
the first moves are compared (`first_move_difference`). do-mpc's per-step time in a closed loop of
`--dompc-steps` samples from `DOMPC_START` on the nominal pendulum is compared with our tree's on the
same problem and loop, right before it in the same run: the exported C (`robust_c_step_median_ms`,
`ratio_robust_vs_do_mpc`, do-mpc's over ours; `robust_step_source` says so) and the Python step
(`robust_python_step_median_ms`, `ratio_robust_python_vs_do_mpc`), both one real-time iteration a
sample, where do-mpc iterates IPOPT to convergence.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _path import HERE as _HERE  # noqa: F401  (drops this folder from sys.path, see _path.py)

import models
import studies
from models.exported_loop import simulate_exported_many
from models.state_limits import StateLimit, check_state_limits, summarize_limit_violations
from models.uncertainty import corner_params, sample_params
from mpc import nonlinear_mpc, riccati_terminal_cost, scenario_tree_mpc
from mpc.export_nmpc import export_nonlinear_mpc
from mpc.scenario_tree import ScenarioTreeProblem
from mpc.sets import Polytope, Zonotope
from mpc.tube import TubeOptions, ancillary_feedback, build_tube, disturbance_set, vertex_models
from mpc.tube_mpc import TubeMPC, nominal_sets
from studies.cases import crane as crane_case
from studies.cases.pendulum import SWING_UP_TRAVEL
from studies.exported_runs import exported_loop, wanted
from studies.robust_rows import with_limits

#: RK4 sub-steps of the truth per controller sample (models.simulate_closed_loop_many's default).
SUBSTEPS = 10
FOLDER = Path(__file__).resolve().parent
DOMPC_PYTHON = FOLDER / ".venv-dompc" / "bin" / "python"
#: The pendulum's limit here: the cart travel of the tube's region, ±0.5 m (the case's physical track is ±2.5 m,
#: which none of these regulation runs comes near).
PENDULUM_LIMITS = (
    StateLimit("cart travel", "z", -SWING_UP_TRAVEL, SWING_UP_TRAVEL, source="SWING_UP_TRAVEL", unit="m"),
)
#: Per plant: the limits the violations are counted against, the start, the run's length (s), the parameters
#: whose ±5 % corners are the tree's branches (the others nominal), the tube's region (deviations, every state),
#: its ancillary LQR weights and how its Z is computed (the crane's six states: F(α, s) as a zonotope, as the
#: polytope template's LP grows with its core's rows squared and did not finish in 20 minutes).
#: The pendulum's start, 0.35 m out at 0.255 m/s towards the 0.5 m limit: 10- and 20-sample runs here had the
#: nominal NMPC leave it (at 0.25 m/s none did, at 0.26 m/s the tree did too, at 0.28 m/s both by about 2 cm).
PLANTS = {
    "pendulum": dict(
        limits=PENDULUM_LIMITS,
        start=np.array([0.35, 0.0, 0.255, 0.0]),
        duration=3.0,
        branch_names=("m2", "ell"),
        region=np.array([0.5, 0.2, 2.0, 2.0]),
        ancillary=(np.diag([100.0, 100.0, 1.0, 1.0]), 1e-2),
        tube_options=TubeOptions(facet_limit=0),
    ),
    "crane": dict(
        limits=crane_case.STATE_LIMITS,
        start=np.zeros(6),
        duration=20.0,
        branch_names=("ell1", "ell2"),
        region=np.array([5.0, 0.2, 0.2, 2.0, 1.0, 1.0]),
        ancillary=(np.diag([1.0, 100.0, 100.0, 1.0, 1000.0, 1000.0]), 1 / 5000**2),
        tube_options=TubeOptions(zonotope=True),
    ),
}
#: do-mpc's and our converged solve start here, (z, θ, ż, θ̇): near enough upright that the first move is
#: inside the 5 N limit (a saturated first move would agree trivially).
DOMPC_START = np.array([0.1, 0.0, 0.0, 0.0])
#: What `ratio_robust_vs_do_mpc` compares.
RATIO_SOURCE = (
    "our tree's exported C (mpc.export_nmpc: one real-time iteration a sample) against do-mpc's IPOPT solve "
    "(to convergence), each a median over the same closed loop on do-mpc's problem; "
    "ratio_robust_python_vs_do_mpc uses our Python step instead"
)
#: A box added to W so that 0 is in its interior (B·[−d, d] alone is flat), in the states' units.
INTERIOR = 1e-6


def tube_sets(name: str, case, known):
    """The known model's discrete linearization, the disturbance-only tube (or the refusal's message), its
    build time, the parametric attempt's refusal and the nominal twin's sets."""
    spec, plant = PLANTS[name], models.get(name)
    xe, ue = known.equilibrium()
    model = known.linearize(xe, ue).discretize(case.mpc.sample_period)
    A, B, umax = model.A, model.B, plant.input_limit
    K = ancillary_feedback(A, B, *spec["ancillary"])
    region = spec["region"]
    X = Polytope.box(-region, region)
    names = [f"{s} upper" for s in plant.state_names] + [f"{s} lower" for s in plant.state_names]
    options = spec["tube_options"]
    interior = Zonotope.box(-INTERIOR * np.ones(plant.nx), INTERIOR * np.ones(plant.nx))
    corners, offsets = vertex_models(plant, corner_params(plant), xe, ue, case.mpc.sample_period)
    refused = None
    try:
        W_box = disturbance_set(
            A,
            B,
            input_bound=case.input_disturbance,
            vertex_models=corners,
            offsets=offsets,
            state_lower=-region,
            state_upper=region,
            input_lower=-umax,
            input_upper=umax,
        ).plus(interior)
        build_tube(A, B, W_box, X, -umax, umax, feedback=K, state_constraint_names=names, options=options)
    except ValueError as error:
        refused = str(error)
    begin = time.perf_counter()
    tube, tube_refused = None, None
    try:
        W = disturbance_set(A, B, input_bound=case.input_disturbance).plus(interior)
        tube = build_tube(A, B, W, X, -umax, umax, feedback=K, state_constraint_names=names, options=options)
    except ValueError as error:
        tube_refused = str(error)
    built = time.perf_counter() - begin
    nominal = nominal_sets(A, B, K, X, -umax, umax, names)
    return model, tube, tube_refused, built, refused, nominal


def cost_matrices(case):
    """The case's MPC weights Q (nx, nx) and R (scalar)."""
    return np.diag(case.mpc.state_weight), float(case.mpc.input_weight)


def monte_carlo(name: str, case, controller, samples: int) -> dict:
    """Per-sample limit checks and quadratic costs over the ±5 % box (stepped together where the controller
    can), and the median step time of one closed loop on the nominal truth."""
    spec, plant = PLANTS[name], models.get(name)
    Q, R = cost_matrices(case)
    xs = plant.equilibrium(**{case.tracked: 0.0})[0]
    params = sample_params(plant, samples, seed=0)
    common = dict(x0=spec["start"], input_disturbance=case.input_disturbance)
    notes: list = []
    loop = (
        exported_loop(name, controller, plant, [(0.0, spec["duration"])], SUBSTEPS, notes)
        if wanted("auto", controller)
        else None
    )
    if loop is not None:
        runs = simulate_exported_many(
            plant, controller, loop, 0.0, spec["duration"], params, substeps=SUBSTEPS, threads=2, **common
        )
    elif getattr(controller, "lockstep", False):
        runs = models.simulate_closed_loop_many(plant, controller, 0.0, spec["duration"], params, **common)
    else:
        runs = (
            models.simulate_closed_loop(plant, controller, 0.0, spec["duration"], params=p, **common) for p in params
        )
    checks, costs, closest = [], [], np.inf
    for result in runs:
        checks.append(check_state_limits(result.t, result.x, plant.state_names, spec["limits"]))
        for limit in spec["limits"]:
            column = result.x[:, plant.state_names.index(limit.state)]
            closest = min(closest, float(limit.upper - np.nanmax(column)), float(np.nanmin(column) - limit.lower))
        e = result.x[:-1] - xs
        costs.append(float(np.einsum("ki,ij,kj->", e, Q, e) + R * np.sum(result.u**2)))
    alone = models.simulate_closed_loop(plant, controller, 0.0, spec["duration"], **common)
    return {
        "runs_by": "exported C" if loop is not None else "Python" + "".join(f" ({n})" for n in notes),
        "violations": summarize_limit_violations(checks),
        "closest": closest,
        "costs": np.array(costs),
        "step_median_ms": 1e3 * float(np.median(alone.step_time)),
        "step_max_ms": 1e3 * float(np.max(alone.step_time)),
    }


def nmpc_controllers(name: str, case, known):
    """(nominal NMPC, scenario-tree NMPC, the tree's branches, its build time s) on `case`'s settings with
    its STATE_LIMITS as soft bounds."""
    spec, plant = PLANTS[name], models.get(name)
    settings = with_limits(case.mpc, spec["limits"], backoff=0.0)
    nominal = nonlinear_mpc(known, settings, tracked=case.tracked)
    branches = corner_params(plant, names=spec["branch_names"])
    begin = time.perf_counter()
    tree = scenario_tree_mpc(known, settings, branches, tracked=case.tracked)
    return nominal, tree, branches, time.perf_counter() - begin


def progress(text: str) -> None:
    """One line of progress on stderr."""
    print(f"{time.strftime('%H:%M:%S')} {text}", file=sys.stderr, flush=True)


def run_plant(name: str, samples: int, save=lambda partial: None) -> dict:
    """Every controller's Monte Carlo on plant `name` (see the module docstring); `save(partial)` after each
    controller's, with the results so far."""
    case, plant = studies.get(name), models.get(name)
    known = case.known_plant(plant)
    spec = PLANTS[name]
    out: dict = {"samples": samples, "duration_s": spec["duration"], "start": spec["start"].tolist()}
    nominal, tree, branches, tree_build_s = nmpc_controllers(name, case, known)
    out["branches"] = len(branches)
    out["tree_build_s"] = tree_build_s
    progress(f"{name}: tree of {len(branches)} branches built in {tree_build_s:.1f} s")
    results = {"nominal": monte_carlo(name, case, nominal, samples)}
    progress(f"{name}: nominal NMPC done")
    results["robust"] = monte_carlo(name, case, tree, samples)
    progress(f"{name}: scenario tree done")
    save(out | {f"{k}_violations": r["violations"] for k, r in results.items()})
    model, tube, tube_refused, tube_build_s, parametric_refused, twin = tube_sets(name, case, known)
    progress(f"{name}: tube {'refused' if tube is None else 'built'} ({tube_build_s:.1f} s)")
    out["tube_build_s"], out["parametric_tube_refused"], out["tube_refused"] = (
        tube_build_s,
        parametric_refused,
        tube_refused,
    )
    if tube is not None:
        Q, R = cost_matrices(case)
        for key, sets in (("nominal_linear", twin), ("tube", tube)):
            controller = TubeMPC(
                model,
                sets,
                horizon=case.mpc.horizon,
                record_error=not isinstance(sets.error_set, Zonotope),
                state_weight=Q,
                input_weight=R,
                initial_state=spec["start"],
                replan=key == "nominal_linear",
                name=key,
            )
            results[key] = monte_carlo(name, case, controller, samples)
        out["tube_state_margins"] = dict(zip(tube.state_constraint_names, tube.state_margins.tolist()))
        out["tube_W"] = "the input disturbance on the known model's linearization (B·[-d, d])"
    else:
        out["tube_violations"] = None
    for key, result in results.items():
        out[f"{key}_runs_by"] = result["runs_by"]
        out[f"{key}_violations"] = result["violations"]
        out[f"{key}_closest_to_a_limit"] = result["closest"]
        out[f"{key}_step_median_ms"] = result["step_median_ms"]
        out[f"{key}_step_max_ms"] = result["step_max_ms"]
    ratio = lambda a, b: float(np.median(results[a]["costs"] / results[b]["costs"]))
    out["cost_ratio_robust_vs_nominal"] = ratio("robust", "nominal")
    if tube is not None:
        out["cost_ratio_tube_vs_nominal_linear"] = ratio("tube", "nominal_linear")
    return out


def dompc_problem(known, case, branches, folder: Path, steps: int) -> tuple[dict, np.ndarray]:
    """The pendulum's tree problem for do-mpc (written into `folder`) and our converged first move on it."""
    plant = models.get(case.plant)
    settings = case.mpc
    Ts, N, nx = settings.sample_period, settings.horizon, known.nx
    Q, R = cost_matrices(case)
    step = known.step_function(Ts, settings.substeps)
    step.save(str(folder / "step.casadi"))
    lin = known.linearize().discretize(Ts)
    P, _ = riccati_terminal_cost(lin.A, lin.B, Q, R)
    uncertain = {
        n: sorted({float(row[list(plant.params).index(n)]) for row in branches}) for n in plant.uncertain_params
    }
    x0 = DOMPC_START
    spec = {
        "model": str(folder / "step.casadi"),
        "parameter_names": list(known.params),
        "parameter_values": known.param_vector().tolist(),
        "nominal_parameters": plant.param_vector().tolist(),
        "uncertain": uncertain,
        "Q": Q.tolist(),
        "R": [[R]],
        "P": P.tolist(),
        "horizon": N,
        "sample_period": Ts,
        "input_limit": float(known.input_limit[0]),
        "x0": x0.tolist(),
        "steps": steps,
        "tolerance": 1e-10,
    }
    S = len(branches)
    problem = ScenarioTreeProblem(
        known,
        branches,
        None,
        1,
        Ts,
        N,
        Q,
        R,
        substeps=settings.substeps,
        iteration="sqp",
        tolerance=1e-10,
        compiled=False,
    )
    terminal = np.kron(np.eye(S) / S, P)
    solution = problem.solve(x0, np.zeros(1), np.zeros(S * nx), np.zeros(S), terminal, np.zeros(1), np.zeros((N, 1)))
    if not solution.success:
        raise RuntimeError(f"our converged tree solve failed: {solution.status}")
    return spec, solution.inputs[0]


def our_steps(case, known, branches, steps: int) -> dict:
    """Per-step times (ms, median and max) of our tree on do-mpc's problem (the same branches, weights and
    input limit, no state bounds) in a closed loop from `DOMPC_START` on the nominal pendulum for `steps`
    samples, as Python (`ScenarioTreeMPC`, one real-time iteration a sample) and as its exported C
    (`mpc.export_nmpc`; its export and compilation time too); the C's commands against Python's."""
    plant = models.get(case.plant)
    tree = scenario_tree_mpc(known, dataclasses.replace(case.mpc, soft=()), branches, tracked=case.tracked)
    begin = time.perf_counter()
    compiled = export_nonlinear_mpc(tree, "robust_tree", [0.0]).load()
    built = time.perf_counter() - begin
    duration = steps * tree.sample_period
    runs = {
        key: models.simulate_closed_loop(plant, controller, 0.0, duration, x0=DOMPC_START)
        for key, controller in (("python", tree), ("c", compiled))
    }
    out = {
        "robust_c_build_s": built,
        "robust_c_vs_python_max_input_difference": float(np.max(np.abs(runs["c"].u - runs["python"].u))),
    }
    for key, run in runs.items():
        out[f"robust_{key}_step_median_ms"] = 1e3 * float(np.median(run.step_time))
        out[f"robust_{key}_step_max_ms"] = 1e3 * float(np.max(run.step_time))
    return out


def compare_dompc(steps: int) -> dict:
    """do-mpc's multi-stage MPC on the pendulum's tree problem against ours (see the module docstring)."""
    if not DOMPC_PYTHON.exists():
        return {
            "do_mpc_skipped": f"no {DOMPC_PYTHON}: python3 -m venv benchmarks/.venv-dompc && "
            "benchmarks/.venv-dompc/bin/pip install do-mpc"
        }
    case, plant = studies.get("pendulum"), models.get("pendulum")
    known = case.known_plant(plant)
    branches = corner_params(plant, names=PLANTS["pendulum"]["branch_names"])
    ours = our_steps(case, known, branches, steps)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        spec, first = dompc_problem(known, case, branches, folder, steps)
        (folder / "problem.json").write_text(json.dumps(spec))
        done = subprocess.run(
            [str(DOMPC_PYTHON), str(FOLDER / "dompc_multistage.py"), str(folder / "problem.json")],
            capture_output=True,
            text=True,
            check=False,
        )
    if done.returncode != 0:
        return ours | {"do_mpc_failed": done.stderr.strip().splitlines()[-5:]}
    theirs = json.loads(done.stdout.strip().splitlines()[-1])
    median = 1e3 * float(np.median(theirs["step_s"]))
    return ours | {
        "do_mpc_version": theirs["do_mpc_version"],
        "do_mpc_scenarios": theirs["scenarios"],
        "do_mpc_first_solve": f"{theirs['first_solve_status']} in {theirs['first_solve_iterations']} iterations",
        "do_mpc_robust_step_median_ms": median,
        "do_mpc_steps": len(theirs["step_s"]),
        "robust_step_median_ms": ours["robust_c_step_median_ms"],
        "robust_step_source": RATIO_SOURCE,
        "ratio_robust_vs_do_mpc": median / ours["robust_c_step_median_ms"],
        "ratio_robust_python_vs_do_mpc": median / ours["robust_python_step_median_ms"],
        "first_move_ours": float(first[0]),
        "first_move_do_mpc": float(theirs["first_move"][0]),
        "first_move_difference": float(abs(first[0] - theirs["first_move"][0])),
        "first_move_saturated": bool(abs(first[0]) >= known.input_limit[0] - 1e-6),
        "do_mpc_start": DOMPC_START.tolist(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", required=True, help="where to write the results")
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--plants", default="pendulum,crane", help="comma-separated, of " + ", ".join(PLANTS))
    parser.add_argument("--dompc-steps", type=int, default=30, help="do-mpc's and our closed-loop steps timed")
    args = parser.parse_args()
    out: dict = {}

    def save(results: dict) -> None:
        with open(args.json, "w") as handle:
            json.dump(results, handle, indent=2)

    for name in args.plants.split(","):
        out[name] = run_plant(name, args.samples, lambda partial, name=name: save(out | {name: partial}))
        save(out)  # each plant's results as soon as they are in
        progress(f"{name}: done")
    if "pendulum" in out:
        pendulum = out["pendulum"]
        for key in ("nominal_violations", "robust_violations", "tube_violations"):
            out[key] = pendulum.get(key)
        out |= compare_dompc(args.dompc_steps)
    out["load_average"] = os.getloadavg()
    with open(args.json, "w") as handle:
        json.dump(out, handle, indent=2)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
