"""The report of a case's trajectories: figures, animations, tables and trajectories.md.

`write` leaves OUT/<plant>/trajectories.md and .csv, a figure per problem (`plot_problem`), per
tracked problem (`plot_tracking`) and per compared problem (`plot_comparison`), their tables, and
the animation of each optimized motion (`studies.animation`) when the case has a drawing. Angles
are drawn and tabulated in degrees (`studies.style.display_unit`), in radians in the CSV files.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models import deferred
from models.files import escape_markdown, format_number, markdown_table, write_csv, write_text

from .. import animation, plots
from ..style import display_unit
from .problem import SETTLE_WINDOW, TrajectoryProblem
from .solve import DEFECT_TOLERANCE, CaseTrajectories, SolvedTrajectory, TrackingRun, problem_row

pd = deferred.module("pandas")


# ---------------------------------------------------------------------------- motions
@dataclass
class Motion:
    """A motion sampled for plots and the animation: t (M+1,), x (M+1, nx), r (M+1, 1) the marked target,
    u (M, nu) the input held on [t_k, t_k+1), input_limit (nu,) the actuator's (the page draws both)."""

    t: np.ndarray
    x: np.ndarray
    r: np.ndarray
    u: np.ndarray
    input_limit: np.ndarray


def motion(solution, target: float, input_limit, step: float = 0.01) -> Motion:
    """The optimized motion every `step` s (the collocation polynomial or the shooting interpolant).

    target : the value (SI) of the tracked state the animation marks;  input_limit : (nu,) the actuator's
    """
    count = max(2, int(math.ceil(solution.final_time / step)))
    t = np.linspace(0.0, solution.final_time, count + 1)
    return Motion(
        t,
        solution.state_at(t),
        np.full((t.size, 1), float(target)),
        solution.input_at(t[:-1]),
        np.asarray(input_limit, dtype=float),
    )


# ---------------------------------------------------------------------------- figures
def _figure(width: float, height: float, rows: int):
    """A `width` × `height` inch figure (Agg canvas) and its `rows` axes, one column sharing the time axis."""
    fig = plots.figure(width, height)
    return fig, fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]


def _margins(fig) -> None:
    """Room for the two-line title and the time axis, in inches whatever the figure's height."""
    height = fig.get_figheight()
    fig.subplots_adjust(left=0.11, right=0.98, top=1 - 0.6 / height, bottom=0.5 / height, hspace=0.15)


def _held(ax, t, u, **style):
    """A held input, u[k] on [t_k, t_k+1)."""
    return ax.step(t, np.append(u, u[-1]), where="post", **style)


def plot_problem(result: CaseTrajectories, solved: SolvedTrajectory, path: Path, dpi: int) -> Path:
    """Each coordinate of the optimized motion (the interpolant, mesh points marked) and the held input.

    Also draws the optimal input re-simulated with CVODES from x(0) (`verify()`) and the actuator limit;
    coordinates in display units (angles in degrees). Saved as PNG at `dpi`; returns `path`.
    """
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
    """The tracked runs (nominal plant and Monte Carlo samples) against the trajectory planned on the known model.

    Coordinates in display units and the commanded input, the end of the planned trajectory dotted (the
    LQR holds from there). Saved as PNG at `dpi`; returns `path`.
    """
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

    runs : the `ComparedRun`s of `solve.compare`, the optimal input first
    closed_loop : (label, settling time s, run) of a study's step run to draw too (dashed), or None

    Saved as PNG at `dpi`; returns `path`.
    """
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
    """The end value of the case's tracked state (SI), the target the animation marks."""
    return float(solution.states[-1][result.plant.state_names.index(result.case.tracked)])


# ---------------------------------------------------------------------------- files
def write(result: CaseTrajectories, out) -> dict:
    """Write OUT/<plant>/trajectories.md and .csv, the figures and the animations; returns {kind: file name}."""
    folder = Path(out) / result.case.plant
    folder.mkdir(parents=True, exist_ok=True)
    return write_files(result, folder)


def write_files(result: CaseTrajectories, folder: Path) -> dict:
    """Write trajectories.md and .csv, the figures and the animations into `folder`; returns {kind: file name}.

    Per solved problem its figure and, when the case has a drawing, the animation (GIF and HTML page) of the
    optimized motion; per tracked problem its figure, table and animation of the nominal run; per compared
    problem its figure and table. Quick runs draw at lower resolution and with fewer frames.
    """
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
                folder / page,
                result.case,
                result.plant,
                {label: run},
                label,
                caption,
                max_frames=300 if quick else 600,
                scenario=label,
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
    """A table cell: a number in the display unit of state `name` with the unit ("12.3 deg"), else as is."""
    if name is not None and isinstance(value, (int, float, np.floating)):
        scale, unit = display_unit(name)
        return f"{format_number(scale * value)} {unit}"
    return format_number(value)


def _report_text(row: dict, problem: TrajectoryProblem, prefix: str = "max_abs_") -> str:
    """The row's ``<prefix><state>`` values of the problem's reported states in words ("cart travel 0.49 m; ...")."""
    return "; ".join(
        f"{what} {_cell(row[prefix + name], name)}" for name, what in problem.report.items() if prefix + name in row
    )


def markdown(result: CaseTrajectories, files: Mapping, notes: list) -> str:
    """trajectories.md: the problems' table, then per problem its description, tracking and comparisons.

    files : the files written ({name: name}), linked where present;  notes : the lines of the Notes section
    """
    case, plant = result.case, result.plant
    unit = case.input_unit
    parts = [
        f"# {escape_markdown(plant.title)}: optimized trajectories",
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
    """The Markdown lines of a tracked problem: what the tracking does, its runs' table, figure and animation."""
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
    """The Markdown lines of a compared problem: the open-loop commands' table and figure, then the study's step
    runs (`steps`, rows of `solve.step_rows`, or None when the study did not run) if the problem compares them."""
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
