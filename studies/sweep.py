"""Robustness beyond the ±5 % box: every controller over a grid of one parameter of the true plant.

``python -m studies PLANT --sweep PARAM=LOW:HIGH:N`` (or `run_sweep`) designs
the study's controllers once, from the model known to them, then simulates
each of them on the nonlinear plant with PARAM set to each of N values from
LOW to HIGH (the other parameters nominal), in one scenario (the step by
default). Every point gets the table's metrics and its verdict against the
case's specs. Blocks run the grid as one batched `models.monte_carlo` (on Dask
when given an executor); other controllers (MPC) one point at a time here.
`write_sweep` leaves ``sweep.csv`` and ``sweep.png`` (cost and verdict against
the parameter) in ``OUT/<plant>/``.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

import models
from models import Block, checks, deferred, interrupts, metrics, specs
from models.files import write_csv, write_text

from . import batch, distributed, judging, plots, runner, style
from .case import CaseStudy
from .designing import leave_out

if TYPE_CHECKING:
    import pandas as pd
else:
    pd = deferred.module("pandas")


#: Bytes one grid point holds before any work: its value as a float in an array and in the tuple
#: (8 + 8 + a 24-byte Python float); `grid_params` adds a row of the plant's parameters.
POINT_BYTES = 40
#: A sweep whose estimated time (`estimate_seconds`) exceeds this many seconds is refused unless accepted
#: (`check_time`; ``python -m studies --sweep ... --long``); read at every call.
TIME_LIMIT_S = 1800.0


@dataclass(frozen=True)
class Grid:
    """The swept parameter and its values."""

    param: str
    values: tuple

    @classmethod
    def parse(cls, text: str) -> Grid:
        """The grid of ``PARAM=LOW:HIGH:N``: "m1=0.2:0.4:5" -> m1 at 0.2, 0.25, ..., 0.4 (N >= 2, LOW < HIGH).

        A grid whose values alone would hold more than `models.checks.MEMORY_LIMIT_BYTES` is refused
        before it is made (`models.checks.ResourceLimitError`, a ValueError, naming the points, the
        size and the limit)."""
        match = re.fullmatch(r"\s*([A-Za-z_]\w*)\s*=\s*([^:]+):([^:]+):(\d+)\s*", str(text))
        if not match:
            raise ValueError(f"a sweep is PARAM=LOW:HIGH:N (e.g. m1=0.2:0.4:5), got {text!r}")
        name, low, high, count = match.groups()
        try:
            low, high = float(low), float(high)
        except ValueError:
            raise ValueError(f"the sweep's LOW and HIGH must be numbers, got {text!r}") from None
        count = int(count)
        if not (math.isfinite(low) and math.isfinite(high) and low < high) or count < 2:
            raise ValueError(f"a sweep needs finite LOW < HIGH and N >= 2 points, got {text!r}")
        checks.check_memory(count * POINT_BYTES, f"a sweep of {count} points", "sweep fewer points")
        return cls(name, tuple(float(v) for v in np.linspace(low, high, count)))


def grid_params(plant: models.Plant, grid: Grid) -> np.ndarray:
    """(N, n_params) parameter vectors: nominal, with `grid.param` at each value (checked by the plant)."""
    if grid.param not in plant.params:
        raise ValueError(f"{plant.name} has no parameter {grid.param!r}; its parameters are {', '.join(plant.params)}")
    index = list(plant.params).index(grid.param)
    checks.check_memory(
        len(grid.values) * 8 * len(plant.params), f"a sweep of {len(grid.values)} points of {plant.name}"
    )
    rows = np.tile(plant.param_vector(), (len(grid.values), 1))
    rows[:, index] = grid.values
    for row, value in zip(rows, grid.values):
        try:
            plant.param_vector(row)
        except ValueError as err:
            raise ValueError(f"sweep of {grid.param} at {value:g}: {err}") from None
    return rows


def estimate_seconds(study: CaseStudy, grid: Grid, scenario: str = "step", labels: Sequence[str] | None = None):
    """The expected wall time (s) of `run_sweep` over `grid`: {label: s} per controller, and their sum.

    From the recorded cost of one run (`studies.batch.run_weights`, measured on ``python -m studies arm
    --quick``): a Block's N points are one batched Monte Carlo of N samples (the fixed cost of a row and of
    the batch's compilation once, then N times the simulated samples); any other controller's points run one
    at a time (N whole runs). The designs made before the points are not counted.

    labels : the controllers (default the study's declared ones)
    """
    labels = list(study.controllers if labels is None else labels)
    count = len(grid.values)
    per_run = batch.run_weights(study, [scenario], 0, labels)
    seconds = {}
    for label, ms in zip(labels, per_run):
        if batch.controller_kind(label) == "block":
            ms = batch.ROW_MS + batch.FIRST_MONTE_CARLO_MS + (ms - batch.ROW_MS) * count
        else:
            ms *= count
        seconds[label] = ms / 1000.0
    return seconds, sum(seconds.values())


def check_time(study: CaseStudy, grid: Grid, scenario: str = "step", accept: bool = False) -> float:
    """The sweep's estimated seconds (`estimate_seconds`); raises `models.checks.ResourceLimitError` (a
    ValueError naming the points, the estimate and the limit) above `TIME_LIMIT_S` unless `accept`."""
    _, seconds = estimate_seconds(study, grid, scenario)
    if seconds > TIME_LIMIT_S and not accept:
        raise checks.ResourceLimitError(
            f"a sweep of {len(grid.values)} points of {grid.param} on {study.plant} is estimated at "
            f"{format_duration(seconds)}, above the limit of {format_duration(TIME_LIMIT_S)} "
            "(studies.sweep.TIME_LIMIT_S); "
            "sweep fewer points, or accept the time (--long)"
        )
    return seconds


def format_duration(seconds: float) -> str:
    """ "42 s", "12 min", "3.5 h" """
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


def run_sweep(
    study: CaseStudy,
    grid: Grid,
    *,
    scenario: str = "step",
    options: runner.Options | None = None,
    providers: Sequence | None = None,
    controllers: Mapping | None = None,
    executor=None,
    progress: Callable[[int, int, str], None] | None = None,
):
    """Every controller of `study` on the true plant at each grid value; one row per (controller, value).

    Parameters
    ----------
    grid : the parameter of the true plant and its values (`Grid.parse("m1=0.2:0.4:5")`)
    scenario : a scenario of the study that is not the Monte Carlo
    options : seed, threads, jit, strict (see `runner.Options`)
    providers : replace the study's providers: callables ``provider(case, known)``, or ``module:function``
        strings naming them (see `studies.providers`)
    controllers : extra {label: controller} to sweep as well
    executor : None, a `dask.distributed.Client` or a `studies.distributed` executor for the Blocks' grids

    Returns
    -------
    (DataFrame with controller, the parameter's column, status, verdict, verdict_detail and the metrics;
    notes: list of str)
    """
    options = options or runner.Options()
    executor = distributed.executor_of(executor)
    chosen = next((s for s in study.scenarios if s.name == scenario and not s.monte_carlo), None)
    if chosen is None:
        names = [s.name for s in study.scenarios if not s.monte_carlo]
        raise ValueError(
            f"a sweep runs one scenario of the study other than the Monte Carlo ({', '.join(names)}); got {scenario!r}"
        )
    plant = models.get(study.plant)
    samples = grid_params(plant, grid)
    designed, notes = runner.design_controllers(study, study.known_plant(plant), providers, options.strict)
    designed |= dict(controllers or {})
    notes += leave_out(designed, options.without)[1]
    _, base = runner.tracked_equilibrium(plant, study)
    reference, duration = chosen.reference(study, base), chosen.duration(study)
    names = list(plant.params)
    rows = []
    for done, (label, controller) in enumerate(designed.items(), start=1):
        truth = study.truth(plant, label)
        started = time.perf_counter()
        try:
            if isinstance(controller, Block):
                noise = (
                    runner.measurement_noise_std(truth, controller, chosen.noise, sigma=study.derivative_time_constant)
                    if chosen.noise
                    else 0.0
                )
                steps = int(round(duration / controller.sample_period))
                results = list(
                    distributed.monte_carlo(
                        executor,
                        truth,
                        controller,
                        reference,
                        duration,
                        samples,
                        seed=options.seed,
                        threads=options.threads,
                        substeps=study.substeps,
                        noise_std=noise,
                        input_disturbance=study.input_disturbance if chosen.input_disturbance else 0.0,
                        jit=runner.use_jit(options, truth, controller, len(samples), steps, study.substeps),
                    )
                )
            else:
                results = [
                    runner.simulate_scenario(
                        truth, controller, chosen, study, options, base, study.substeps, params=row
                    )
                    for row in samples
                ]
            for value, row, result in zip(grid.values, samples, results):
                judged = judging.judge_run(study, chosen.name, result, dict(zip(names, row)))
                rows.append({"controller": label, grid.param: value, **judged.row()})
        except distributed.RunFailed:
            raise
        except Exception as err:  # one controller's failure leaves the others' points
            if interrupts.is_interrupt(err):  # Ctrl-C, which CasADi may report as an error
                raise KeyboardInterrupt from err
            if options.strict:
                raise
            status = f"failed: {type(err).__name__}: {err}".splitlines()[0]
            rows += [
                {
                    "controller": label,
                    grid.param: value,
                    "status": status[:200],
                    **judging.verdict_columns(specs.Verdict(specs.FAILED, (), status[:200])),
                    **dict.fromkeys(metrics.METRIC_COLUMNS, math.nan),
                }
                for value in grid.values
            ]
            notes.append(f"{label}: {status[:200]}")
        if progress:
            progress(
                done,
                len(designed),
                f"{study.plant} sweep of {grid.param}: {label} ({time.perf_counter() - started:.1f} s)",
            )
    frame = pd.DataFrame(rows)
    columns = ["controller", grid.param, "status", "verdict", "verdict_detail", *metrics.METRIC_COLUMNS]
    return frame.reindex(columns=columns), notes


def write_sweep(study: CaseStudy, grid: Grid, table, out, notes: Sequence[str] = (), scenario: str = "step") -> dict:
    """``OUT/<plant>/sweep.csv``, ``sweep.png`` and ``sweep.md``: cost and verdict of every controller
    against the parameter; returns {kind: file name}."""
    folder = Path(out) / study.plant
    write_csv(folder / "sweep.csv", table)
    plant = models.get(study.plant)
    nominal = plant.params[grid.param]
    unit = next((p.unit for p in plant.param_info if p.name == grid.param), "")
    fig = plots.figure(10, 7.5)
    cost, strip = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    labels = list(dict.fromkeys(table.controller))
    for label in labels:
        mine = table[table.controller == label]
        look = style.of(label)
        itae = mine.itae.astype(float).to_numpy()
        cost.plot(mine[grid.param], itae, label=label, **look.line())
        meets = (mine.verdict == specs.MEETS).to_numpy()
        cost.plot(mine[grid.param][meets], itae[meets], linestyle="none", marker=look.marker, color=look.color)
        cost.plot(
            mine[grid.param][~meets],
            itae[~meets],
            linestyle="none",
            marker=look.marker,
            markerfacecolor="none",
            markeredgecolor=look.color,
        )
    if np.nanmin(table.itae.astype(float).replace(0, np.nan)) > 0:
        cost.set_yscale("log")
    for i, label in enumerate(labels):
        mine = table[table.controller == label]
        strip.scatter(
            mine[grid.param], np.full(len(mine), i), marker="s", s=90, c=[style.verdict_color(v) for v in mine.verdict]
        )
    strip.set_yticks(range(len(labels)), labels, fontsize=7)
    strip.invert_yaxis()
    for ax in (cost, strip):
        ax.axvline(nominal, color="#555", linestyle=":", linewidth=1)
        ax.grid(True, alpha=0.3)
    cost.set_ylabel(f"ITAE ({'rad' if study.tracked_unit == 'rad' else study.tracked_unit} s²)")
    strip.set_xlabel(
        f"{grid.param} of the true plant ({unit}); dotted: nominal {nominal:g}; "
        "controllers designed from the known model"
    )
    legend = "  ".join(f"{symbol} {label}" for label, (symbol, _) in style.VERDICTS.items())
    strip.set_title(f"verdict against the specs (colour): {legend}", fontsize=8)
    cost.set_title(f"{plant.title}: {scenario} as {grid.param} varies (filled: meets its specs)", fontsize=10)
    handles, names = cost.get_legend_handles_labels()
    plots.legend_below(fig, handles, names, top=0.95, hspace=0.15, left=0.2)
    plots.save(fig, folder / "sweep.png", 100)
    lines = [
        f"# {plant.title}: sweep of {grid.param}",
        "",
        f"Every controller, designed from the known model, on the nonlinear plant with {grid.param} from "
        f"{grid.values[0]:g} to {grid.values[-1]:g} {unit} ({len(grid.values)} values; nominal {nominal:g}), "
        f"scenario {scenario}. Rows in sweep.csv; picture in sweep.png.",
        "",
        *sweep_summary(table, grid),
        *([""] + [f"- note: {n}" for n in notes] if notes else []),
        "",
    ]
    write_text(folder / "sweep.md", "\n".join(lines))
    return {"sweep.csv": "sweep.csv", "sweep.png": "sweep.png", "sweep.md": "sweep.md"}


def sweep_summary(table, grid: Grid) -> list:
    """One line per controller: where along the grid it meets its specs."""
    lines = []
    for label in dict.fromkeys(table.controller):
        mine = table[table.controller == label]
        good = mine[mine.verdict == specs.MEETS][grid.param].to_numpy()
        if len(good) == len(mine):
            where = "meets its specs at every value"
        elif len(good) == 0:
            worst = mine.verdict.value_counts().index[0]
            where = f"meets its specs nowhere (mostly: {worst})"
        else:
            where = f"meets its specs at {len(good)} of {len(mine)} values, {good.min():g} to {good.max():g}"
        lines.append(f"- {label}: {where}")
    return lines
