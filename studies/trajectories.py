"""Trajectory optimization in the studies: each case's optimal control problems, solved, checked, tracked, drawn.

A case declares its problems as data, ``CaseStudy(trajectories=(TrajectoryProblem(...), ...))``:
a key, a title and a builder that poses the problem on a plant and says how to solve it
(`TrajectorySetup`: an `mpc.OptimalControlProblem`, its transcription, solve options). A problem
may also ask for

- `Tracking`: a time-varying LQR along the trajectory, then the LQR at its end
  (`designs.trajectory_tracking`), designed on the model the controllers know (the case's
  +known_rel parameters, the trajectory re-optimized on it with headroom in the actuator)
  and run on the nominal nonlinear plant and on Monte Carlo samples of it;
- `open_loop` commands to compare with (input shaping, say), simulated on the plant the same
  way as the optimal input: the command, then the input holding the end state at rest (zero
  without gravity) for as long again;
- `compare_step`: the problem is the text's step, so the study's step responses are listed
  beside it (when the study ran).

`solve_case` solves, verifies (`OCPSolution.verify`: the input re-simulated with CVODES),
tracks and compares; `write` leaves OUT/<plant>/trajectories.md and .csv, a figure per
problem and the animation of each optimized motion (`studies.animation`).
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import models

from .style import display_unit

#: Largest state defect per interval (SI units of the state) for a solution to count as verified: the
#: optimal input held on each interval and re-simulated with CVODES from the optimized state there.
DEFECT_TOLERANCE = 1e-3

#: Seconds over which a tracked run must have settled (the last of the run) to count as held.
SETTLE_WINDOW = 1.0


# ---------------------------------------------------------------------------- what a case declares
@dataclass(frozen=True)
class TrajectorySetup:
    """A posed problem and how to solve it: what a `TrajectoryProblem`'s builder returns.

    problem : mpc.OptimalControlProblem
    transcription : mpc.Collocation or mpc.MultipleShooting
    solve_options : keyword arguments of `OptimalControlProblem.solve` (guess, guess_input,
        solver_options, refine_tolerance, ...)
    objective : what the objective measures, with its unit ("T (s)", "∫F² dt (N² s)")
    description : the problem in one or two sentences (constraints, bounds and why)
    """

    problem: Any
    transcription: Any
    solve_options: Mapping = field(default_factory=dict)
    objective: str = ""
    description: str = ""


@dataclass(frozen=True)
class Tracking:
    """Track the trajectory with a time-varying LQR on the nonlinear plant with the parameter error.

    state_max : Bryson maxima of the state deviations by name (SI); states not named are unweighted
    input_max : Bryson maximum of the input deviation (units of u), one number per input
    headroom : the tracked trajectory is re-optimized on the known model with |u| <= (1 − headroom) × limit,
        leaving the rest of the actuator to the feedback
    hold : s of LQR after the trajectory (the catch)
    samples : Monte Carlo samples of the plant (uniform ±known_rel on the case's uncertain parameters)
    settled : state name -> bound (SI) on |x − x_end| over the run's last `SETTLE_WINDOW` s: "held"
    """

    state_max: Mapping[str, float]
    input_max: tuple
    headroom: float = 0.2
    hold: float = 4.0
    samples: int = 5
    settled: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class OpenLoopCommand:
    """An input sequence held for `sample_period` s each, (M, nu), to compare with the optimal one."""

    sample_period: float
    inputs: np.ndarray
    description: str = ""


@dataclass(frozen=True)
class TrajectoryProblem:
    """One optimal control problem of a case study (see the module docstring).

    key : short file-safe name ("swing_up_effort")
    title : one line ("swing-up, minimum effort")
    build : (plant, quick, solved) -> TrajectorySetup; `solved` maps the keys in `depends` to their
        `mpc.OCPSolution`s (for starting points); `quick` asks for a coarser mesh
    depends : keys of earlier problems of the case whose solutions `build` uses
    report : state name -> what its largest |value| along the motion means ("cart travel"), reported
    compare_step : the problem is the case's step from its standard equilibrium: list the study's step runs
    open_loop : label -> (plant) -> OpenLoopCommand, compared on the plant with the optimal input
    tracking : a `Tracking`, or None
    """

    key: str
    title: str
    build: Callable[..., TrajectorySetup]
    depends: tuple = ()
    report: Mapping[str, str] = field(default_factory=dict)
    compare_step: bool = False
    open_loop: Mapping[str, Callable[[models.Plant], OpenLoopCommand]] = field(default_factory=dict)
    tracking: Tracking | None = None

    def __post_init__(self):
        if not self.key.isidentifier():
            raise ValueError(f"TrajectoryProblem key must be an identifier (file-safe), got {self.key!r}")
        if not 0 <= (self.tracking.headroom if self.tracking else 0) < 1:
            raise ValueError(f"{self.key}: tracking headroom must be in [0, 1), got {self.tracking.headroom}")


# ---------------------------------------------------------------------------- results
@dataclass
class Motion:
    """A motion sampled for plots and the animation: t (M+1,), x (M+1, nx), r (M+1, 1) the marked target,
    u (M, nu) the input held on [t_k, t_k+1), input_limit (nu,) the actuator's (the page draws both)."""

    t: np.ndarray
    x: np.ndarray
    r: np.ndarray
    u: np.ndarray
    input_limit: np.ndarray


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


# ---------------------------------------------------------------------------- solving
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


def motion(solution, target: float, input_limit, step: float = 0.01) -> Motion:
    """The optimized motion every `step` s (the collocation polynomial or the shooting interpolant)."""
    count = max(2, int(math.ceil(solution.final_time / step)))
    t = np.linspace(0.0, solution.final_time, count + 1)
    return Motion(
        t,
        solution.state_at(t),
        np.full((t.size, 1), float(target)),
        solution.input_at(t[:-1]),
        np.asarray(input_limit, dtype=float),
    )


def _bryson(plant: models.Plant, tracking: Tracking) -> tuple[np.ndarray, np.ndarray]:
    from models.lqr import bryson_weights

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
    plants with the uncertain parameters uniform within ±known_rel (seeded).
    """
    from designs.trajectory_tracking import tvlqr_tracking

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
    """The optimal input and each open-loop command, simulated alike (see the module docstring)."""
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
    """Solve, verify, track and compare every trajectory problem of `case` (a `CaseStudy`).

    study_result : the case's `studies.runner.StudyResult`, for the step comparison (optional)
    strict : raise on a failing problem instead of noting it
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


# ---------------------------------------------------------------------------- files
def _figure(width: float, height: float, rows: int):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]


def _margins(fig) -> None:
    """Room for the two-line title and the time axis, in inches whatever the figure's height."""
    height = fig.get_figheight()
    fig.subplots_adjust(left=0.11, right=0.98, top=1 - 0.6 / height, bottom=0.5 / height, hspace=0.15)


def _held(ax, t, u, **style):
    """A held input, u[k] on [t_k, t_k+1)."""
    return ax.step(t, np.append(u, u[-1]), where="post", **style)


def plot_problem(result: CaseTrajectories, solved: SolvedTrajectory, path: Path, dpi: int) -> Path:
    """Each coordinate of the optimized motion (the interpolant, mesh points marked) and the held input."""
    from . import plots

    plant, s = result.plant, solved.solution
    fig, axes = _figure(8, 1.7 * (plant.nq + 1) + 0.8, plant.nq + 1)
    dense = motion(s, 0.0, plant.input_limit, step=s.final_time / 600)
    for ax, name in zip(axes, plant.coordinate_names):
        scale, unit = display_unit(name)
        index = plant.state_names.index(name)
        ax.plot(dense.t, scale * dense.x[:, index], color="C0", linewidth=1.4, label="optimized (interpolant)")
        ax.plot(s.t, scale * s.states[:, index], ".", color="C0", markersize=3, label="mesh points")
        ax.plot(
            s.t,
            scale * solved.verification.simulated[:, index],
            "--",
            color="C3",
            linewidth=1.0,
            label="input re-simulated (CVODES, from x(0))",
        )
        ax.set_ylabel(f"{name} ({unit})")
        ax.grid(True, alpha=0.3)
    limit = float(plant.input_limit[0])
    for i, name in enumerate(plant.input_names):
        _held(axes[-1], s.t, s.inputs[:, i], color="C2", linewidth=1.3, label=f"{name}")
    axes[-1].axhline(limit, color="k", linestyle=":", linewidth=0.8)
    axes[-1].axhline(-limit, color="k", linestyle=":", linewidth=0.8, label="actuator limit")
    axes[-1].set_ylabel(f"{plant.input_names[0]} ({result.case.input_unit})")
    axes[-1].set_xlabel("t (s)")
    axes[-1].grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    axes[-1].legend(fontsize=7, loc="best")
    fig.suptitle(f"{plant.title}:\n{solved.problem.title}, T = {s.final_time:.4g} s", fontsize=9)
    _margins(fig)
    return plots.save(fig, path, dpi)


def plot_tracking(
    result: CaseTrajectories, problem: TrajectoryProblem, tracked: TrackingRun, path: Path, dpi: int
) -> Path:
    """The tracked runs (nominal plant and Monte Carlo samples) against the trajectory planned on the known model."""
    from . import plots

    plant = result.plant
    fig, axes = _figure(8, 1.7 * (plant.nq + 1) + 0.8, plant.nq + 1)
    planned = tracked.planned
    dense = motion(planned, 0.0, plant.input_limit, step=planned.final_time / 600)
    runs = list(tracked.samples) if tracked.samples is not None else []
    for ax, name in zip(axes, plant.coordinate_names):
        scale, unit = display_unit(name)
        index = plant.state_names.index(name)
        for j, run in enumerate(runs):
            ax.plot(
                run.t,
                scale * run.x[:, index],
                color="0.6",
                linewidth=0.7,
                label="Monte Carlo samples (±5 %)" if j == 0 else None,
            )
        ax.plot(
            tracked.nominal.t, scale * tracked.nominal.x[:, index], color="C0", linewidth=1.4, label="nominal plant"
        )
        ax.plot(dense.t, scale * dense.x[:, index], "--", color="C1", linewidth=1.2, label="planned on the known model")
        ax.axvline(planned.final_time, color="k", linestyle=":", linewidth=0.8)
        ax.set_ylabel(f"{name} ({unit})")
        ax.grid(True, alpha=0.3)
    for run in runs:
        _held(axes[-1], run.t, run.u[:, 0], color="0.6", linewidth=0.7)
    _held(axes[-1], tracked.nominal.t, tracked.nominal.u[:, 0], color="C0", linewidth=1.2)
    _held(axes[-1], planned.t, planned.inputs[:, 0], color="C1", linewidth=1.0, linestyle="--")
    limit = float(plant.input_limit[0])
    for sign in (-1, 1):
        axes[-1].axhline(sign * limit, color="k", linestyle=":", linewidth=0.8)
    axes[-1].set_ylabel(f"{plant.input_names[0]} ({result.case.input_unit})")
    axes[-1].set_xlabel("t (s); dotted: end of the trajectory, the LQR holds from there")
    axes[-1].grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(
        f"{plant.title}: {problem.title},\ntracked by a time-varying LQR designed on the "
        f"{100 * result.case.known_rel:+g} % model; the truth nominal and ±{100 * result.case.known_rel:g} % "
        "samples",
        fontsize=9,
    )
    _margins(fig)
    return plots.save(fig, path, dpi)


def plot_comparison(
    result: CaseTrajectories, problem: TrajectoryProblem, runs: list, path: Path, dpi: int, closed_loop=None
) -> Path:
    """The optimal input and the open-loop commands on the plant: coordinates and input.

    closed_loop : (label, settling time s, run) of a study's step run to draw too (dashed), or None
    """
    from . import plots

    plant = result.plant
    fig, axes = _figure(8, 1.7 * (plant.nq + 1) + 0.8, plant.nq + 1)
    curves = [(c.label, c.run, dict(color=f"C{j}", linewidth=1.3 if j == 0 else 1.0)) for j, c in enumerate(runs)]
    end = max(c.run.t[-1] for c in runs)
    if closed_loop is not None:
        label, settling, run = closed_loop
        curves.append(
            (
                f"closed loop: {label} (settles first, {settling:.3g} s)",
                run,
                dict(color="0.3", linewidth=1.0, linestyle="--"),
            )
        )
        end = max(end, 1.2 * settling)
    for label, run, style in curves:
        for ax, name in zip(axes, plant.coordinate_names):
            scale, _ = display_unit(name)
            ax.plot(run.t, scale * run.state(name), label=label, **style)
        _held(axes[-1], run.t, run.u[:, 0], **style)
    axes[-1].set_xlim(0, end)
    for ax, name in zip(axes, plant.coordinate_names):
        ax.set_ylabel(f"{name} ({display_unit(name)[1]})")
        ax.grid(True, alpha=0.3)
    limit = float(plant.input_limit[0])
    for sign in (-1, 1):
        axes[-1].axhline(sign * limit, color="k", linestyle=":", linewidth=0.8)
    axes[-1].set_ylabel(f"{plant.input_names[0]} ({result.case.input_unit})")
    axes[-1].set_xlabel("t (s)")
    axes[-1].grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(
        f"{plant.title}: {problem.title}\nagainst open-loop commands (each then the input holding the end)"
        + ("" if closed_loop is None else ",\nand the study's first step response to settle"),
        fontsize=9,
    )
    _margins(fig)
    return plots.save(fig, path, dpi)


def _target(result: CaseTrajectories, solution) -> float:
    return float(solution.states[-1][result.plant.state_names.index(result.case.tracked)])


def write(result: CaseTrajectories, out) -> dict:
    """Write OUT/<plant>/trajectories.md and .csv, the figures and the animations; returns {kind: file name}."""
    folder = Path(out) / result.case.plant
    folder.mkdir(parents=True, exist_ok=True)
    return write_files(result, folder)


def write_files(result: CaseTrajectories, folder: Path) -> dict:
    """Write trajectories.md and .csv, the figures and the animations into `folder`; returns {kind: file name}."""
    import pandas as pd

    from models.files import write_csv, write_text

    from . import animation

    quick = result.quick
    dpi = 72 if quick else 100
    files: dict = {}
    notes = list(result.notes)
    for key, solved in result.solved.items():
        if not solved.solution.success:
            continue
        name = f"trajectory_{key}.png"
        files[name] = plot_problem(result, solved, folder / name, dpi).name
        if result.case.drawing is not None:
            run = motion(solved.solution, _target(result, solved.solution), result.plant.input_limit)
            label = solved.problem.title
            caption = (
                f"{label}: the optimized motion (collocation interpolant, nonlinear model), "
                f"T = {solved.solution.final_time:.4g} s."
            )
            gif, page = f"trajectory_{key}.gif", f"trajectory_{key}.html"
            animation.write_gif(
                folder / gif,
                result.case,
                result.plant,
                run,
                label,
                max_frames=30 if quick else 100,
                dpi=64 if quick else 80,
            )
            animation.write_html(
                folder / page, result.case, result.plant, {label: run}, label, caption, max_frames=300 if quick else 600
            )
            files |= {gif: gif, page: page}
    for key, tracked in result.tracking.items():
        problem = result.solved[key].problem
        name = f"trajectory_{key}_tracking.png"
        files[name] = plot_tracking(result, problem, tracked, folder / name, dpi).name
        if result.case.drawing is not None:
            name = f"trajectory_{key}_tracking.gif"
            animation.write_gif(
                folder / name,
                result.case,
                result.plant,
                tracked.nominal,
                f"{problem.title}, tracked",
                max_frames=30 if quick else 100,
                dpi=64 if quick else 80,
            )
            files[name] = name
        write_csv(folder / f"trajectory_{key}_tracking.csv", pd.DataFrame(tracked.rows))
        files[f"trajectory_{key}_tracking.csv"] = f"trajectory_{key}_tracking.csv"
    for key, runs in result.compared.items():
        name = f"trajectory_{key}_comparison.png"
        files[name] = plot_comparison(
            result, result.solved[key].problem, runs, folder / name, dpi, result.step_runs.get(key)
        ).name
        rows = [c.row for c in runs] + [
            {"command": f"closed loop: {r['controller']}", **r} for r in result.step_rows.get(key, [])
        ]
        write_csv(folder / f"trajectory_{key}_comparison.csv", pd.DataFrame(rows))
        files[f"trajectory_{key}_comparison.csv"] = f"trajectory_{key}_comparison.csv"
    rows = result.rows()
    if rows:
        write_csv(folder / "trajectories.csv", pd.DataFrame(rows))
        files["trajectories.csv"] = "trajectories.csv"
    write_text(folder / "trajectories.md", markdown(result, files, notes))
    files["trajectories.md"] = "trajectories.md"
    return files


# ---------------------------------------------------------------------------- Markdown
def _cell(value, name: str | None = None) -> str:
    from models.files import format_number

    if name is not None and isinstance(value, (int, float, np.floating)):
        scale, unit = display_unit(name)
        return f"{format_number(scale * value)} {unit}"
    return format_number(value)


def _report_text(row: dict, problem: TrajectoryProblem, prefix: str = "max_abs_") -> str:
    return "; ".join(
        f"{what} {_cell(row[prefix + name], name)}" for name, what in problem.report.items() if prefix + name in row
    )


def markdown(result: CaseTrajectories, files: Mapping, notes: list) -> str:
    """trajectories.md: the problems' table, then per problem its description, tracking and comparisons."""
    from models.files import format_number, markdown_table

    case, plant = result.case, result.plant
    unit = case.input_unit
    parts = [
        f"# {plant.title}: optimized trajectories",
        "",
        "Each problem is an `mpc.OptimalControlProblem` on the nonlinear plant (nominal parameters), "
        "transcribed as stated and solved by IPOPT; the wall time runs from posing the problem to the "
        "verified answer. *Defect* is `OCPSolution.verify()`: the optimal input, held on each interval, "
        "re-simulated with CVODES, largest state difference at the mesh points (SI units of that state), "
        "from x(0) over the whole horizon (an unstable plant amplifies it) and restarted from the "
        f"optimized state on every interval (the transcription's own error; verified below "
        f"{DEFECT_TOLERANCE:g}). Angles in degrees here, radians in the CSV files."
        + (" Run with --quick: coarser meshes." if result.quick else ""),
        "",
    ]
    rows = []
    for solved in result.solved.values():
        row = problem_row(plant, solved)
        row["extremes"] = _report_text(row, solved.problem)
        rows.append(row)
    columns = [
        ("problem", "problem", format_number),
        ("status", "status", format_number),
        ("final_time_s", "T (s)", format_number),
        ("objective", "objective", format_number),
        ("objective_is", "objective is", format_number),
        ("peak_u", f"peak |u| ({unit})", format_number),
        ("extremes", "largest along the motion", format_number),
        ("transcription", "transcription", format_number),
        ("iterations", "IPOPT iterations", format_number),
        ("wall_s", "wall (s)", format_number),
        ("defect_whole", "defect, whole horizon", format_number),
        ("defect_interval", "defect per interval", format_number),
        ("verified", "verified", format_number),
    ]
    parts += [markdown_table(rows, columns)]
    for key, solved in result.solved.items():
        problem, s = solved.problem, solved.solution
        parts += [f"## {problem.title}", "", solved.setup.description, ""]
        if f"trajectory_{key}.png" in files:
            parts += [f"![{problem.title}](trajectory_{key}.png)", ""]
        if f"trajectory_{key}.gif" in files:
            parts += [
                f"Animation: [trajectory_{key}.gif](trajectory_{key}.gif), "
                f"[trajectory_{key}.html](trajectory_{key}.html) (play and slider).",
                "",
            ]
        if key in result.tracking:
            parts += _tracking_section(result, problem, result.tracking[key], files)
        if key in result.compared:
            parts += _comparison_section(result, problem, result.compared[key], result.step_rows.get(key), files)
        if s.success and key in result.timing:
            parts += [
                f"Wall time of this problem including its tracking and comparisons: {result.timing[key]:.3g} s.",
                "",
            ]
    if notes:
        parts += ["## Notes", ""] + [f"- {note}" for note in notes] + [""]
    return "\n".join(parts)


def _tracking_section(
    result: CaseTrajectories, problem: TrajectoryProblem, tracked: TrackingRun, files: Mapping
) -> list:
    from models.files import format_number, markdown_table

    case, spec, unit = result.case, problem.tracking, result.case.input_unit
    assert spec is not None
    planned = tracked.planned
    held = sum(bool(r["held"]) for r in tracked.rows)
    settled = ", ".join(f"|{name} − end| ≤ {_cell(bound, name)}" for name, bound in spec.settled.items())
    maxima = ", ".join(
        [f"{name} {_cell(value, name)}" for name, value in spec.state_max.items()]
        + [f"{name} {value:g} {unit}" for name, value in zip(result.plant.input_names, np.atleast_1d(spec.input_max))]
    )
    text = (
        f"**Tracking.** The controller knows the model with {', '.join(result.plant.uncertain_params)} "
        f"{100 * case.known_rel:+g} %: the trajectory is re-optimized on it with |u| ≤ "
        f"{100 * (1 - spec.headroom):g} % of the limit (objective {planned.objective:.5g}, T = "
        f"{planned.final_time:.4g} s, {planned.status}), leaving {100 * spec.headroom:g} % of the actuator to "
        f"the feedback. A time-varying LQR along it (Bryson maxima {maxima}; `designs.trajectory_tracking`) "
        f"runs at Ts = {case.sample_period:g} s, then the LQR "
        f"at the upright end holds it for {spec.hold:g} s. The truth is the nominal plant, then "
        f"{spec.samples} samples with those parameters uniform within ±{100 * case.known_rel:g} % (seed 0). "
        f"*Held*: {settled} over the last {SETTLE_WINDOW:g} s. **{held} of {len(tracked.rows)} runs held**."
    )
    rows = []
    for r in tracked.rows:
        rows.append(
            {
                **r,
                "extremes": _report_text(r, problem),
                "final": "; ".join(f"{name} {_cell(r['final_dev_' + name], name)}" for name in spec.settled),
            }
        )
    columns = [
        ("run", "plant", format_number),
        ("held", "held at the end", format_number),
        ("peak_u", f"peak |u| ({unit})", format_number),
        ("extremes", "largest along the run", format_number),
        ("final", "largest |x − end| in the last second", format_number),
        ("params", "parameters", format_number),
    ]
    out = [text, "", markdown_table(rows, columns)]
    key = problem.key
    if f"trajectory_{key}_tracking.png" in files:
        out += [f"![tracking](trajectory_{key}_tracking.png)", ""]
    if f"trajectory_{key}_tracking.gif" in files:
        out += [
            f"Animation of the nominal run: [trajectory_{key}_tracking.gif](trajectory_{key}_tracking.gif) "
            "(the marker is the planned cart position).",
            "",
        ]
    return out


def _comparison_section(result: CaseTrajectories, problem: TrajectoryProblem, runs: list, steps, files) -> list:
    from models.files import format_number, markdown_table

    unit = result.case.input_unit
    text = (
        "**Against open-loop commands.** Each command (and the optimal input) runs on the nonlinear plant "
        "(CVODES) from the same start, then the input that holds the end state at rest, for as long as the "
        "optimal move again. *Move* is the "
        "command's length; *residual* the largest |x − end| after it."
    )
    rows = []
    for compared in runs:
        r = compared.row
        rows.append(
            {
                **r,
                "extremes": _report_text(r, problem),
                "residual": _report_text(r, problem, "residual_"),
                "end": _cell(r["end_error"], result.case.tracked),
            }
        )
    columns = [
        ("command", "command", format_number),
        ("move_time_s", "move (s)", format_number),
        ("peak_u", f"peak |u| ({unit})", format_number),
        ("extremes", "largest along the run", format_number),
        ("end", f"|{result.case.tracked} − end| when the command ends", format_number),
        ("residual", "residual after the command", format_number),
        ("description", "what it is", format_number),
    ]
    out = [text, "", markdown_table(rows, columns)]
    if f"trajectory_{problem.key}_comparison.png" in files:
        out += [f"![comparison](trajectory_{problem.key}_comparison.png)", ""]
    if problem.compare_step:
        if steps:
            step_text = (
                "**Against the study's step responses** (the same move by each controller in closed loop, "
                "from `table.md`; settling: within 2 % of the step for good)."
            )
            step_table = [{**r, "extremes": _report_text(r, problem)} for r in steps]
            step_columns = [
                ("controller", "controller", format_number),
                ("status", "status", format_number),
                ("settling_time_s", "settling 2 % (s)", format_number),
                ("peak_u", f"peak |u| ({unit})", format_number),
                ("extremes", "largest along the run", format_number),
            ]
            out += [step_text, "", markdown_table(step_table, step_columns)]
        else:
            out += ["The study's step responses were not run with these trajectories (run the whole study).", ""]
    return out
