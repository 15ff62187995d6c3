"""What a case declares about its optimal trajectories: the problems, as data.

A case lists `TrajectoryProblem`s in ``CaseStudy(trajectories=...)``; each builder returns a
`TrajectorySetup` (the posed `mpc.OptimalControlProblem`, its transcription and solve options).
`Tracking` and `OpenLoopCommand` say what else to do with a solved problem: track it in closed
loop, compare it with other open-loop inputs. `OpenLoopCodesign` is an optimal control problem
that also chooses a plant parameter (``CaseStudy(open_loop_codesign=...)``, decided by
`studies.codesign_open_loop`). Solving is `studies.trajectories.solve`, the
figures and pages `studies.trajectories.report`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import models

#: Seconds over which a tracked run must have settled (the last of the run) to count as held.
SETTLE_WINDOW = 1.0


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
    """One optimal control problem of a case study (see `studies.trajectories`).

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
        """Refuse a key that is no identifier (it names files) and a headroom outside [0, 1)."""
        if not self.key.isidentifier():
            raise ValueError(f"TrajectoryProblem key must be an identifier (file-safe), got {self.key!r}")
        if not 0 <= (self.tracking.headroom if self.tracking else 0) < 1:
            raise ValueError(f"{self.key}: tracking headroom must be in [0, 1), got {self.tracking.headroom}")


@dataclass(frozen=True)
class OpenLoopCodesign:
    """One open-loop co-design problem: a plant parameter chosen together with the input history.

    Declared by a case (``CaseStudy(open_loop_codesign=...)``) or by `studies.codesign_open_loop`, which
    decides it simultaneously and nested and reports both. It lives here, with the other records a case
    declares, so that a case file imports no engine that lists the cases.

    key : short name;  title : one line
    plant : the plant's registry name or title, for the table
    build : (quick) -> `TrajectorySetup` whose problem chooses exactly one plant
        parameter (`ocp.choose`); quick asks for a coarser mesh
    parameter, unit : the chosen parameter's name and unit;  text_value : its value in the text, or None
    maximized : the problem maximizes (its OCP objective is the negative; the report shows the value)
    sweep : parameter values at which the optimal value J*(p) is tabulated with p fixed
    reference : () -> {"parameter": value, "objective": value, "how": text}, an independent answer, or None
    """

    key: str
    title: str
    plant: str
    build: Callable[[bool], TrajectorySetup]
    parameter: str
    unit: str
    text_value: float | None = None
    maximized: bool = False
    sweep: tuple = ()
    reference: Callable[[], dict] | None = None
