"""Case studies: every controller on every plant, in tables, plots and animations.

>>> import studies
>>> table = studies.run("arm", scenarios=["step"], mc=0)      # a pandas DataFrame
>>> result = studies.run_study("arm", mc=50, out="results")   # everything, files written

Each case study is one file, ``studies/cases/<name>.py``, defining ``CASE =
CaseStudy(...)``: its numbers, scenarios, providers, designs, drawing and
errata. `studies.cases` is the registry (`names()`, `get`, `register`);
`studies.runner` runs every controller on the nonlinear plant,
`models.metrics` computes every column and `studies.writers` writes the
tables. ``python -m studies`` runs every registered case.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

from . import runner, trajectories, writers
from .case import SCENARIO_NAMES, CaseStudy
from .cases import get, names, register, unregister
from .runner import Options, StudyResult

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "CaseStudy",
    "Options",
    "SCENARIO_NAMES",
    "StudyResult",
    "get",
    "names",
    "register",
    "run",
    "run_study",
    "unregister",
]


def run_study(
    name: str | CaseStudy,
    *,
    scenarios: Sequence[str] | None = None,
    mc: int = 200,
    seed: int = 0,
    quick: bool = False,
    out: str | os.PathLike | None = None,
    providers: Sequence | None = None,
    controllers: Mapping | None = None,
    strict: bool = False,
    threads: int = 2,
    jit: bool | str = "auto",
    progress: Callable | None = None,
    run_id: str | None = None,
    executor=None,
    without: str | Sequence[str] = (),
) -> StudyResult:
    """Run one study; with `out`, write its tables, answers, plots and animation into out/<plant>/.

    Parameters
    ----------
    name : name of a registered case study, or a `CaseStudy` (registered or not)
    scenarios : names among "step", "steps", "disturbance", "noise", "mc" (default all)
    mc : Monte Carlo samples of every controller, MPC included (0 skips it)
    seed : seed (integer >= 0) of the parameter samples and of the noise
    quick : fewer animation frames and lighter plots
    out : output folder; nothing is written without it. out/<plant> is written aside and replaces
        the previous folder whole when complete (see `studies.writers.write_study`)
    providers : replace the case's controller providers: callables ``provider(case, known)``, or
        ``module:function`` strings naming them (see `studies.providers`)
    controllers : extra {label: controller} to compare
    strict : raise on provider or controller errors instead of noting them
    threads : threads of the batched Monte Carlo map (integer >= 1)
    jit : True, False or "auto" (compile the Monte Carlo map when it is long enough to pay off)
    progress : progress(done, total, text) after each simulation
    run_id : the id recorded in out/<plant>/run.json (default a new one)
    executor : a `dask.distributed.Client` (or a `studies.distributed` executor) to run the Monte Carlo
        of Block controllers on; default this process. The numbers do not depend on it.
    without : labels of controllers to leave out (a label, or a list of them); each is noted

    Returns
    -------
    StudyResult (its `.table` is the DataFrame `run` returns)

    Raises
    ------
    TypeError, ValueError
        Naming the argument, before any work, when one is not what is allowed.
    models.checks.ResourceLimitError
        Before any work, when the Monte Carlo would need more memory than allowed.
    """
    if not isinstance(name, (str, CaseStudy)):
        raise TypeError(f"name must be a plant name or a CaseStudy, got {type(name).__name__} {name!r}")
    if out is not None and (not isinstance(out, (str, os.PathLike)) or not str(os.fspath(out)).strip()):
        raise ValueError(f"out must name a folder (or be None to write nothing), got {out!r}")
    study = name if isinstance(name, CaseStudy) else get(name)
    options = Options(
        scenarios=scenarios, mc=mc, seed=seed, threads=threads, jit=jit, strict=strict, quick=quick, without=without
    )
    result = runner.run_study(
        study, options, providers=providers, controllers=controllers, progress=progress, executor=executor
    )
    if out is not None:
        if study.trajectories:
            solve_trajectories(result)
        writers.write_study(result, out, run_id)
    return result


def solve_trajectories(result: StudyResult) -> None:
    """Solve, track and compare the study's optimal trajectories (`studies.trajectories`) into
    ``result.trajectories`` (written with the study's files); the wall time goes to
    ``result.timing["trajectories_s"]``, failures to its notes."""
    started = time.perf_counter()
    options = result.options
    solved = trajectories.solve_case(
        result.study, quick=options.quick, study_result=result, strict=options.strict, seed=options.seed
    )
    result.trajectories = solved
    result.notes += [f"trajectories: {note}" for note in solved.notes]
    result.timing["trajectories_s"] = time.perf_counter() - started


def run(name: str | CaseStudy, **kwargs) -> pd.DataFrame:
    """Run one study and return its table: one row per (controller, scenario).

    `name` is a registered case study's name or a `CaseStudy`; takes the keyword arguments of `run_study`.
    Every row is a simulation of the nonlinear plant; ``table.attrs["notes"]`` lists skipped providers and
    failures, ``table.attrs["timing"]`` the seconds spent.
    """
    result = run_study(name, **kwargs)
    table = result.table.copy()
    table.attrs["notes"] = list(result.notes)
    table.attrs["timing"] = dict(result.timing)
    return table
