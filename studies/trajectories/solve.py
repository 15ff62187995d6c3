"""Solving a case's trajectory problems: solve and verify, track in closed loop, compare open-loop inputs.

`solve_case` takes each `TrajectoryProblem` of a case in turn (`studies.trajectories.problem`):
`solve_problem` builds it on the nominal plant, solves it and verifies it (`OCPSolution.verify`, the
optimal input re-simulated with CVODES); `track` re-optimizes it on the model the controllers know and
runs a time-varying LQR along it on the true plant; `compare` simulates the optimal input and the
problem's open-loop commands alike; `step_rows` lists the study's step runs beside it. The results are
the records below, written by `studies.trajectories.report`.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import models
from designs.trajectory_tracking import tvlqr_tracking
from models.lqr import bryson_weights

from .problem import SETTLE_WINDOW, OpenLoopCommand, Tracking, TrajectoryProblem, TrajectorySetup

#: Largest state defect per interval (SI units of the state) for a solution to count as verified: the
#: optimal input held on each interval and re-simulated with CVODES from the optimized state there.
DEFECT_TOLERANCE = 1e-3


# ---------------------------------------------------------------------------- results
@dataclass
class SolvedTrajectory:
    """One problem solved: its setup, solution, verification and wall time (problem to checked answer), s."""

    problem: TrajectoryProblem
    setup: TrajectorySetup
    solution: Any
    verification: Any
    wall_time: float

    @property
    def verified(self) -> bool:
        """Solved, and the defect per interval of `verify()` at most `DEFECT_TOLERANCE`."""
        return bool(self.solution.success and self.verification.max_interval_defect <= DEFECT_TOLERANCE)


@dataclass
class TrackingRun:
    """The tracking of one problem: the re-optimized trajectory, the design and the closed-loop runs."""

    planned: Any
    design: Any
    nominal: models.ClosedLoopResult
    samples: models.MonteCarloResult | None
    rows: list


@dataclass
class ComparedRun:
    """An open-loop command (or the optimal input) simulated on the plant: its run and its row."""

    label: str
    run: models.Trajectory
    command_time: float
    row: dict


@dataclass
class CaseTrajectories:
    """Everything `solve_case` produced for one case."""

    case: Any
    plant: models.Plant
    quick: bool
    solved: dict = field(default_factory=dict)
    tracking: dict = field(default_factory=dict)
    compared: dict = field(default_factory=dict)
    step_rows: dict = field(default_factory=dict)
    step_runs: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    timing: dict = field(default_factory=dict)

    def rows(self) -> list[dict]:
        """One row per solved problem (SI units), the table of trajectories.csv."""
        return [problem_row(self.plant, s) for s in self.solved.values()]


def describe(transcription) -> str:
    """The transcription in words: "Radau collocation, degree 3, N = 100"."""
    if hasattr(transcription, "degree"):
        return (
            f"{transcription.points.capitalize()} collocation, degree {transcription.degree}, "
            f"N = {transcription.intervals}"
        )
    return f"multiple shooting (RK4, {transcription.substeps} step/interval), N = {transcription.intervals}"


def solve_problem(problem: TrajectoryProblem, plant: models.Plant, quick: bool, solved: Mapping) -> SolvedTrajectory:
    """Build, solve and verify one problem on `plant`."""
    started = time.perf_counter()
    setup = problem.build(plant, quick, {key: solved[key].solution for key in problem.depends})
    solution = setup.problem.solve(setup.transcription, **dict(setup.solve_options))
    verification = solution.verify()
    return SolvedTrajectory(problem, setup, solution, verification, time.perf_counter() - started)


def problem_row(plant: models.Plant, solved: SolvedTrajectory) -> dict:
    """One row of trajectories.csv (SI units): status, T (s), objective, peak |u|, transcription, IPOPT
    iterations, wall time (s), the `verify()` defects and the states they occur in, and ``max_abs_<state>``
    for each state the problem reports."""
    s, v = solved.solution, solved.verification
    row = {
        "key": solved.problem.key,
        "problem": solved.problem.title,
        "status": s.status,
        "final_time_s": s.final_time,
        "objective": s.objective,
        "objective_is": solved.setup.objective,
        "peak_u": float(np.max(np.abs(s.inputs))),
        "u_limit": float(np.max(plant.input_limit)),
        "transcription": describe(solved.setup.transcription),
        "iterations": s.iterations,
        "wall_s": solved.wall_time,
        "defect_whole": v.max_defect,
        "defect_whole_state": v.state,
        "defect_interval": v.max_interval_defect,
        "defect_interval_state": v.interval_state,
        "verified": solved.verified,
    }
    for name in solved.problem.report:
        row[f"max_abs_{name}"] = float(np.max(np.abs(s.state(name))))
    return row


def _bryson(plant: models.Plant, tracking: Tracking) -> tuple[np.ndarray, np.ndarray]:
    """The tracking's Bryson weights on `plant`: Q (nx, nx) from `state_max` by state name, R (nu, nu).

    A state `state_max` does not name gets maximum ∞, weight 0; a name that is no state of the plant
    is refused (ValueError naming it).
    """
    unknown = sorted(set(tracking.state_max) - set(plant.state_names))
    if unknown:
        raise ValueError(f"tracking state_max names {unknown}; {plant.name}'s states are {plant.state_names}")
    state_max = [tracking.state_max.get(name, np.inf) for name in plant.state_names]
    return bryson_weights(state_max, np.broadcast_to(np.asarray(tracking.input_max, dtype=float), (plant.nu,)))


def track(
    case, problem: TrajectoryProblem, plant: models.Plant, nominal_solution, quick: bool, solved: Mapping, seed: int = 0
) -> TrackingRun:
    """Re-optimize `problem` on the case's known model with headroom, track it with a time-varying LQR on `plant`.

    The controller knows the +known_rel model; the truth is `plant` (nominal), then `tracking.samples`
    plants with the uncertain parameters uniform within ±known_rel (seeded). The LQR runs at the case's
    sample period, so the re-optimized final time must be a whole number of samples (ValueError otherwise);
    a failed re-optimization raises RuntimeError with its status.
    """
    spec = problem.tracking
    assert spec is not None
    known = case.known_plant(plant)
    setup = problem.build(known, quick, {key: solved[key].solution for key in problem.depends})
    ocp = setup.problem
    derated = (1 - spec.headroom) * np.asarray(known.input_limit, dtype=float)
    for i, name in enumerate(known.input_names):
        ocp.subject_to(ocp.bounded(-derated[i], ocp.u[name], derated[i]), label=f"{name} within the derated limit")
    options = {k: v for k, v in dict(setup.solve_options).items() if k not in ("guess", "guess_input")}
    planned = ocp.solve(setup.transcription, guess=nominal_solution, **options)
    if not planned.success:
        raise RuntimeError(f"the trajectory re-optimized on the known model failed: {planned.status}")
    ts = case.sample_period
    steps = int(round(planned.final_time / ts))
    if abs(steps * ts - planned.final_time) > 1e-9 * max(1.0, planned.final_time):
        raise ValueError(
            f"{problem.key}: tracking needs a final time that is a whole number of samples of "
            f"{ts:g} s, got {planned.final_time:.6g} s"
        )
    times = ts * np.arange(steps + 1)
    states = planned.state_at(times)
    states[-1] = planned.states[-1]
    inputs = planned.input_at(times[:-1] + ts / 2)
    Q, R = _bryson(known, spec)
    design = tvlqr_tracking(known, ts, states, inputs, Q, R, substeps=case.substeps)
    duration = planned.final_time + spec.hold
    reference = design.reference(duration)
    x0 = planned.states[0]
    nominal = models.simulate_closed_loop(
        plant, design.block, reference, duration, x0=x0, substeps=case.substeps, allow_divergence=True
    )
    runs = [("nominal plant", nominal)]
    samples = None
    if spec.samples:
        params = models.sample_params(plant, spec.samples, rel=case.known_rel, seed=seed)
        samples = models.monte_carlo(
            plant, design.block, reference, duration, params, x0=x0, substeps=case.substeps, seed=seed
        )
        runs += [(f"sample {i}", run) for i, run in enumerate(samples)]
    rows = [tracking_row(label, run, problem, spec, planned) for label, run in runs]
    return TrackingRun(planned, design, nominal, samples, rows)


def tracking_row(label: str, run, problem: TrajectoryProblem, spec: Tracking, planned) -> dict:
    """Whether a tracked run held the end state, its peak input and the largest |value| of the reported states."""
    end = planned.states[-1]
    names = list(run.state_names)
    last = run.t >= run.t[-1] - SETTLE_WINDOW - 1e-9
    finite = run.diverged_at is None and bool(np.all(np.isfinite(run.x)))
    worst = (
        {name: float(np.max(np.abs(run.x[last, names.index(name)] - end[names.index(name)]))) for name in spec.settled}
        if finite
        else {name: math.inf for name in spec.settled}
    )
    held = finite and all(worst[name] <= bound for name, bound in spec.settled.items())
    row = {
        "run": label,
        "held": held,
        "diverged_at_s": run.diverged_at,
        "peak_u": float(np.nanmax(np.abs(run.u))) if run.u.size else math.nan,
        "u_limit": float(np.max(run.input_limit)),
    }
    for name in spec.settled:
        row[f"final_dev_{name}"] = worst[name]
    for name in problem.report:
        row[f"max_abs_{name}"] = float(np.nanmax(np.abs(run.x[:, names.index(name)])))
    if run.params is not None:
        row["params"] = ", ".join(f"{k} = {v:.4g}" for k, v in zip(planned.params, np.ravel(run.params)))
    return row


def simulate_command(
    plant: models.Plant, x0, command: OpenLoopCommand, settle: float, hold, method: str = "adaptive"
) -> tuple[models.Trajectory, float]:
    """Run an open-loop command on `plant` from x0, then the input `hold` (nu,) for `settle` s.

    Returns (the run, the command's duration in s).
    """
    inputs = np.asarray(command.inputs, dtype=float).reshape(-1, plant.nu)
    extra = int(math.ceil(settle / command.sample_period))
    padded = np.vstack([inputs, np.tile(np.asarray(hold, dtype=float).reshape(1, plant.nu), (extra, 1))])
    run = models.simulate(plant, x0, padded, command.sample_period, method=method, rtol=1e-8, atol=1e-8)
    return run, command.sample_period * len(inputs)


def comparison_row(
    label: str,
    run: models.Trajectory,
    command_time: float,
    problem: TrajectoryProblem,
    end,
    tracked: str,
    description: str = "",
) -> dict:
    """Move time, peak input, largest reported states, error at the end of the command and residual after it."""
    after = run.t >= command_time - 1e-9
    names = list(run.state_names)
    k_end = int(np.argmax(after))
    row = {
        "command": label,
        "move_time_s": command_time,
        "peak_u": float(np.max(np.abs(run.u))),
        "end_error": float(abs(run.x[k_end, names.index(tracked)] - end[names.index(tracked)])),
        "description": description,
    }
    for name in problem.report:
        row[f"max_abs_{name}"] = float(np.max(np.abs(run.x[:, names.index(name)])))
        row[f"residual_{name}"] = float(np.max(np.abs(run.x[after, names.index(name)] - end[names.index(name)])))
    return row


def compare(case, problem: TrajectoryProblem, plant: models.Plant, solved: SolvedTrajectory) -> list[ComparedRun]:
    """The optimal input and each of the problem's open-loop commands, simulated alike on `plant`.

    Each runs from the solution's start state (CVODES): the command, then the input that holds the end
    state at rest (zero without gravity) for as long as the optimal move again. The optimal input is the
    solution's, held per interval, so its mesh must be uniform (ValueError otherwise). Returns one
    `ComparedRun` per command, the optimal input first.
    """
    solution = solved.solution
    end, x0 = solution.states[-1], solution.states[0]
    settle = solution.final_time
    hold = plant.equilibrium_input(end[: plant.nq])  # what holds the end state at rest (gravity)
    out = []
    steps = np.diff(solution.t)
    if not np.allclose(steps, steps[0], rtol=1e-9):
        raise ValueError(f"{problem.key}: the comparison simulates the optimal input on a uniform mesh only")
    optimal = OpenLoopCommand(float(steps[0]), solution.plant_inputs, "the optimal input, held per interval")
    commands = [(f"optimal ({problem.title})", optimal)]
    commands += [(label, build(plant)) for label, build in problem.open_loop.items()]
    for label, command in commands:
        run, duration = simulate_command(plant, x0, command, settle, hold)
        out.append(
            ComparedRun(
                label,
                run,
                duration,
                comparison_row(label, run, duration, problem, end, case.tracked, command.description),
            )
        )
    return out


def step_rows(study_result, problem: TrajectoryProblem) -> list[dict]:
    """The study's step runs beside the optimal move: settling time, peak input, largest reported states."""
    table = study_result.table
    rows = []
    for (label, scenario), run in study_result.runs.items():
        if scenario != "step":
            continue
        match = table[(table.controller == label) & (table.scenario == "step")]
        names = list(run.state_names)
        row = {
            "controller": label,
            "status": str(match.status.iloc[0]) if len(match) else "",
            "settling_time_s": float(match.settling_time_s.iloc[0]) if len(match) else math.nan,
            "peak_u": float(np.nanmax(np.abs(run.u))),
        }
        for name in problem.report:
            row[f"max_abs_{name}"] = float(np.nanmax(np.abs(run.x[:, names.index(name)])))
        rows.append(row)
    return rows


def fastest_step(study_result, rows: list[dict]):
    """(label, settling time s, run) of the study's step run that settles first, or None if none settles."""
    settled = [r for r in rows if np.isfinite(r["settling_time_s"])]
    if not settled:
        return None
    best = min(settled, key=lambda r: r["settling_time_s"])
    return best["controller"], best["settling_time_s"], study_result.runs[(best["controller"], "step")]


def solve_case(
    case, *, quick: bool = False, study_result=None, strict: bool = False, seed: int = 0
) -> CaseTrajectories:
    """Solve, verify, track and compare every trajectory problem of `case` (a `CaseStudy`), in its order.

    quick : coarser meshes (each builder's own choice)
    study_result : the case's `studies.runner.StudyResult`, for the step comparison (optional)
    strict : raise on a failing problem instead of noting it
    seed : of the tracking's Monte Carlo samples

    A problem whose `depends` did not solve is skipped; a failure (solve, tracking or comparison) goes
    to the result's notes, naming the phase and where it was raised. Keys must be unique (ValueError).
    """
    plant = models.get(case.plant)
    result = CaseTrajectories(case, plant, quick)
    keys = [p.key for p in case.trajectories]
    if len(set(keys)) != len(keys):
        raise ValueError(f"{case.plant}: trajectory problem keys must be unique, got {keys}")
    for problem in case.trajectories:
        missing = [key for key in problem.depends if key not in result.solved]
        if missing:
            result.notes.append(f"{problem.key}: skipped, it depends on {missing}, which must come earlier and solve")
            continue
        phase = "solve"
        try:
            started = time.perf_counter()
            solved = solve_problem(problem, plant, quick, result.solved)
            result.solved[problem.key] = solved
            if not solved.solution.success:
                result.notes.append(f"{problem.key}: {solved.solution.status}")
                continue
            if not solved.verified:
                result.notes.append(
                    f"{problem.key}: verify() defect per interval "
                    f"{solved.verification.max_interval_defect:.3g} above {DEFECT_TOLERANCE:g}"
                )
            if problem.tracking is not None:
                phase = "tracking"
                result.tracking[problem.key] = track(case, problem, plant, solved.solution, quick, result.solved, seed)
            if problem.open_loop or problem.compare_step:
                phase = "comparison"
                result.compared[problem.key] = compare(case, problem, plant, solved)
                if problem.compare_step and study_result is not None:
                    result.step_rows[problem.key] = step_rows(study_result, problem)
                    result.step_runs[problem.key] = fastest_step(study_result, result.step_rows[problem.key])
            result.timing[problem.key] = time.perf_counter() - started
        except Exception as err:
            if strict:
                raise
            where = traceback.extract_tb(err.__traceback__)[-1]
            result.notes.append(
                f"{problem.key}: {phase} failed ({type(err).__name__}: {err}; at {where.filename}:{where.lineno})"
            )
    return result
