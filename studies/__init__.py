"""Case studies: every controller on every plant, in tables, plots and animations.

>>> import studies
>>> table = studies.run("arm", scenarios=["step"], mc=0)      # a pandas DataFrame
>>> result = studies.run_study("arm", mc=50, out="results")   # everything, files written

Each study (``studies/arm.py`` ... ``studies/crane.py``) declares its
controllers, where they come from and its scenarios; `studies.runner` runs
them on the nonlinear plant, `models.metrics` computes every column and
`studies.writers` writes the tables. ``python -m studies`` runs all six.
"""

from __future__ import annotations

import importlib
import os
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

if TYPE_CHECKING:
    import pandas as pd

    from .runner import Options, Study, StudyResult

#: The six case studies, in the text's order.
NAMES = ("arm", "pendulum", "satellite", "uuv", "ballbeam", "crane")

#: The scenarios a study can run, as named on the command line.
SCENARIO_NAMES = ("step", "steps", "disturbance", "noise", "mc")

__all__ = ["NAMES", "Options", "SCENARIO_NAMES", "Study", "StudyResult", "get", "run", "run_study"]


def __getattr__(name: str):
    # The runner imports CasADi and pandas; `python -m studies` with bad arguments should not wait for them.
    if name in ("Options", "Study", "StudyResult"):
        from . import runner

        return getattr(runner, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def get(name: str) -> "Study":
    """The declared study of plant `name` (ValueError listing the studies otherwise)."""
    if name not in NAMES:
        raise ValueError(f"unknown plant {name!r}; valid plants: {', '.join(NAMES)}")
    return importlib.import_module(f"{__name__}.{name}").STUDY


def run_study(name: "str | Study", *, scenarios: Sequence[str] | None = None, mc: int = 200, mc_python: int = 10,
              mc_python_steps: int = 12_000, python_scenarios: Sequence[str] | None = None,
              python_budget: float | None = None,
              seed: int = 0, quick: bool = False, out: str | os.PathLike | None = None,
              providers: Sequence[str] | None = None, controllers: Mapping | None = None, strict: bool = False,
              threads: int = 2, jit: bool | str = "auto", progress: Callable | None = None) -> "StudyResult":
    """Run one study; with `out`, write its tables, answers, plots and animation into out/<plant>/.

    Parameters
    ----------
    name : plant name of a declared study, or a `Study`
    scenarios : names among "step", "steps", "disturbance", "noise", "mc" (default all)
    mc : Monte Carlo samples for block controllers (0 skips it)
    mc_python, mc_python_steps : most samples, and most simulated steps in all, of the Monte Carlo of
        controllers simulated step by step (MPC)
    python_scenarios : scenarios run for those controllers (default all)
    python_budget : seconds of compute time each of them may spend on the plant (default unlimited)
    seed : seed of the parameter samples and of the noise
    quick : fewer animation frames and lighter plots
    out : output folder; nothing is written without it
    providers : replace the study's ``module:function`` controller providers
    controllers : extra {label: controller} to compare
    strict : raise on provider or controller errors instead of noting them
    progress : progress(done, total, text) after each simulation

    Returns
    -------
    StudyResult (its `.table` is the DataFrame `run` returns)
    """
    from . import runner, writers

    study = name if isinstance(name, runner.Study) else get(name)
    options = runner.Options(scenarios=tuple(scenarios) if scenarios else None, mc=mc, mc_python=mc_python,
                      mc_python_steps=mc_python_steps,
                      python_scenarios=tuple(python_scenarios) if python_scenarios else None,
                      python_budget=python_budget, seed=seed,
                      threads=threads, jit=jit, strict=strict, quick=quick)
    result = runner.run_study(study, options, providers=providers, controllers=controllers, progress=progress)
    if out is not None:
        writers.write_study(result, out)
    return result


def run(name: "str | Study", **kwargs) -> "pd.DataFrame":
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
