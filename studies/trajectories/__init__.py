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

The package is three modules: `problem` (what a case declares), `solve` (solving, tracking,
comparing, and the records of the results) and `report` (figures, animations and Markdown);
their public names are re-exported here.
"""

from .problem import SETTLE_WINDOW, OpenLoopCodesign, OpenLoopCommand, Tracking, TrajectoryProblem, TrajectorySetup
from .report import Motion, markdown, motion, plot_comparison, plot_problem, plot_tracking, write, write_files
from .solve import (
    DEFECT_TOLERANCE,
    CaseTrajectories,
    ComparedRun,
    SolvedTrajectory,
    TrackingRun,
    compare,
    comparison_row,
    describe,
    fastest_step,
    problem_row,
    simulate_command,
    solve_case,
    solve_problem,
    step_rows,
    track,
    tracking_row,
)

__all__ = [
    "DEFECT_TOLERANCE",
    "SETTLE_WINDOW",
    "CaseTrajectories",
    "ComparedRun",
    "Motion",
    "OpenLoopCodesign",
    "OpenLoopCommand",
    "SolvedTrajectory",
    "Tracking",
    "TrackingRun",
    "TrajectoryProblem",
    "TrajectorySetup",
    "compare",
    "comparison_row",
    "describe",
    "fastest_step",
    "markdown",
    "motion",
    "plot_comparison",
    "plot_problem",
    "plot_tracking",
    "problem_row",
    "simulate_command",
    "solve_case",
    "solve_problem",
    "step_rows",
    "track",
    "tracking_row",
    "write",
    "write_files",
]
