"""Case studies: every controller on every plant, in tables, plots and animations.

>>> import studies
>>> table = studies.run("arm", scenarios=["step"], mc=0)      # a pandas DataFrame
>>> result = studies.run_study("arm", mc=50, out="results")   # everything, files written

Each case study is one file, ``studies/cases/<name>.py``, defining ``CASE =
CaseStudy(...)``: its numbers, scenarios, designs, drawing and errata.
`studies.cases` is the registry (`names()`, `get`, `register`);
`studies.runner` runs every controller on the nonlinear plant,
`models.metrics` computes every column and `studies.writers` writes the
tables. ``python -m studies`` runs every registered case.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

if TYPE_CHECKING:
    import pandas as pd

    from .case import CaseStudy
    from .runner import Options, StudyResult

#: The scenarios a study can run, as named on the command line.
SCENARIO_NAMES = ("step", "steps", "disturbance", "noise", "mc")

__all__ = ["CaseStudy", "Options", "SCENARIO_NAMES", "StudyResult", "get", "names", "register", "run",
           "run_study", "unregister"]


def __getattr__(name: str):
    # The runner imports pandas; `python -m studies` with bad arguments should not wait for it.
    if name in ("Options", "StudyResult"):
        from . import runner

        return getattr(runner, name)
    if name == "CaseStudy":
        from .case import CaseStudy

        return CaseStudy
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def names() -> tuple[str, ...]:
    """Names of the registered case studies, in the text's order (see `studies.cases`)."""
    from . import cases

    return cases.names()


def get(name: str) -> "CaseStudy":
    """The case study `name` (ValueError listing the registered ones otherwise)."""
    from . import cases

    return cases.get(name)


def register(case: "CaseStudy", replace: bool = False) -> "CaseStudy":
    """Add a user's case study to the registry (see `studies.cases.register`)."""
    from . import cases

    return cases.register(case, replace)


def unregister(name: str) -> None:
    """Remove a case study from the registry."""
    from . import cases

    cases.unregister(name)


def run_study(name: "str | CaseStudy", *, scenarios: Sequence[str] | None = None, mc: int = 200, mc_python: int = 10,
              mc_python_steps: int = 12_000, python_scenarios: Sequence[str] | None = None,
              python_budget: float | None = None,
              seed: int = 0, quick: bool = False, out: str | os.PathLike | None = None,
              providers: Sequence[str] | None = None, controllers: Mapping | None = None, strict: bool = False,
              threads: int = 2, jit: bool | str = "auto", progress: Callable | None = None,
              executor=None) -> "StudyResult":
    """Run one study; with `out`, write its tables, answers, plots and animation into out/<plant>/.

    Parameters
    ----------
    name : name of a registered case study, or a `CaseStudy`
    scenarios : names among "step", "steps", "disturbance", "noise", "mc" (default all)
    mc : Monte Carlo samples for block controllers (0 skips it)
    mc_python, mc_python_steps : most samples, and most simulated steps in all, of the Monte Carlo of
        controllers simulated step by step (MPC)
    python_scenarios : scenarios run for those controllers (default all)
    python_budget : seconds of compute time each of them may spend on the plant (default unlimited)
    seed : seed of the parameter samples and of the noise
    quick : fewer animation frames and lighter plots
    out : output folder; nothing is written without it
    providers : replace the case's ``module:function`` controller providers
    controllers : extra {label: controller} to compare
    strict : raise on provider or controller errors instead of noting them
    progress : progress(done, total, text) after each simulation
    executor : a `dask.distributed.Client` (or a `studies.distributed` executor) to run the Monte Carlo
        of Block controllers on; default this process. The numbers do not depend on it.

    Returns
    -------
    StudyResult (its `.table` is the DataFrame `run` returns)
    """
    from . import runner, writers
    from .case import CaseStudy

    study = name if isinstance(name, CaseStudy) else get(name)
    options = runner.Options(scenarios=tuple(scenarios) if scenarios else None, mc=mc, mc_python=mc_python,
                      mc_python_steps=mc_python_steps,
                      python_scenarios=tuple(python_scenarios) if python_scenarios else None,
                      python_budget=python_budget, seed=seed,
                      threads=threads, jit=jit, strict=strict, quick=quick)
    result = runner.run_study(study, options, providers=providers, controllers=controllers, progress=progress,
                              executor=executor)
    if out is not None:
        writers.write_study(result, out)
    return result


def run(name: "str | CaseStudy", **kwargs) -> "pd.DataFrame":
    """Run one study and return its table: one row per (controller, scenario).

    Takes the keyword arguments of `run_study`. Every row is a simulation of
    the nonlinear plant; ``table.attrs["notes"]`` lists skipped providers and
    failures, ``table.attrs["timing"]`` the seconds spent.
    """
    result = run_study(name, **kwargs)
    table = result.table.copy()
    table.attrs["notes"] = list(result.notes)
    table.attrs["timing"] = dict(result.timing)
    return table
