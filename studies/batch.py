"""Several case studies run into one folder on one executor: the work of ``python -m studies``.

`run_plants` runs the named plants and writes each one's folder into a staging folder that the
command publishes when every plant is done (`studies.writers.publish`). On an executor with more
than one worker (``--jobs N`` with several plants, or Dask) each plant is one task (`plant_task`):
it is studied in a private folder wherever it runs and its files come back as bytes, installed
into the staging folder once every plant has come back; otherwise the plants run here one after
the other, their Monte Carlo on the executor. Either way every plant's files are the same bytes.

What the command prints of a plant comes back as a small report (`plant_report`), so that a
plant run elsewhere sends back no tables or plots.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import textwrap
import uuid
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from models.files import write_bytes

from . import cases, run_study
from .answers import format_answers
from .runner import StudyResult, status_kind
from .writers import not_ok_rows, verdict_counts

#: progress(plant, done, total, text) after each simulation of a plant, or when a plant is done.
PlantProgress = Callable[[str, int, int, str], None]

#: Expected cost of one row (`run_weights`), in ms of the rows of a recorded ``python -m studies arm
#: --quick`` (tests/studies/data/arm_quick_row_seconds.csv): a fixed part (the closed loop built, the
#: metrics) and one part per simulated sample; an MPC's sample costs in proportion to its horizon.
ROW_MS = 5.0
BLOCK_SAMPLE_MS = 6e-4
LINEAR_MPC_SAMPLE_MS_PER_STAGE = 1e-3
NONLINEAR_MPC_SAMPLE_MS_PER_STAGE = 8e-3
#: The plant's first Monte Carlo row also compiles the batched simulation of its samples.
FIRST_MONTE_CARLO_MS = 200.0
#: The nonlinear MPC steps its Monte Carlo samples together: each sample costs this fraction of a run alone.
NONLINEAR_MPC_BATCH = 0.4
#: A plant's work before its first run (the designs, per controller) and after its last (its files, per
#: run), in the same ms: a recorded ``python -m studies arm --quick``'s run.json (timing design_s and
#: files_s, about as long as its rows together; tests/studies/data/quick_run_phases.csv), scaled as its rows.
DESIGN_MS_PER_CONTROLLER = 240.0
FILES_MS_PER_RUN = 53.0


def plant_costs(case, scenarios=None, samples: int = 0, controllers=None) -> tuple[list, float]:
    """The whole expected cost of studying `case`, in `run_weights`' ms: each run's weight, the first one
    carrying the designs made before it (`DESIGN_MS_PER_CONTROLLER`), and the cost of the files written
    after the last run (`FILES_MS_PER_RUN` per run), reached when the plant is done.

    Parameters are those of `run_weights`.

    Returns
    -------
    weights : list of float, one per run;  after : float, the files' cost
    """
    weights = run_weights(case, scenarios, samples, controllers)
    labels = case.controllers if controllers is None else controllers
    if weights:
        weights[0] += DESIGN_MS_PER_CONTROLLER * len(labels)
    return weights, FILES_MS_PER_RUN * len(weights)


def controller_kind(label: str) -> str:
    """ "nonlinear MPC", "linear MPC" or "block", from a controller's label (what its cost follows)."""
    if "MPC" not in label:
        return "block"
    return "nonlinear MPC" if "nonlinear" in label else "linear MPC"


def run_weights(case, scenarios=None, samples: int = 0, controllers=None) -> list:
    """Expected cost of each run of `case` in the order the runner makes them (every controller through
    every scenario), in ms of the recorded timings (`ROW_MS`); their sum is the plant's whole.

    A run costs ROW_MS plus, per simulated sample (the scenario's duration over the controller's
    sample period, times the Monte Carlo `samples`), a block's BLOCK_SAMPLE_MS or an MPC's cost per
    stage times its horizon (the case's `mpc` settings; the nonlinear MPC's stages are dearer, its
    Monte Carlo samples batched: `NONLINEAR_MPC_BATCH`). The first Monte Carlo run adds
    FIRST_MONTE_CARLO_MS.

    Parameters
    ----------
    case : studies.case.CaseStudy
    scenarios : names of the scenarios that run (None: all; "mc" is left out when `samples` is 0)
    samples : Monte Carlo samples per controller
    controllers : labels (default the case's declared ones)
    """
    mpc = case.mpc
    horizon = mpc.horizon if mpc is not None else 1
    mpc_period = mpc.sample_period if mpc is not None else case.sample_period
    per_sample = {
        "block": (case.sample_period, BLOCK_SAMPLE_MS),
        "linear MPC": (mpc_period, LINEAR_MPC_SAMPLE_MS_PER_STAGE * horizon),
        "nonlinear MPC": (mpc_period, NONLINEAR_MPC_SAMPLE_MS_PER_STAGE * horizon),
    }
    chosen = [
        s for s in case.scenarios if (scenarios is None or s.name in scenarios) and not (s.monte_carlo and samples == 0)
    ]
    weights: list[float] = []
    compiled = False
    for label in case.controllers if controllers is None else controllers:
        kind = controller_kind(label)
        period, cost = per_sample[kind]
        for scenario in chosen:
            steps = scenario.duration(case) / period
            extra = 0.0
            if scenario.monte_carlo:
                steps *= samples * (NONLINEAR_MPC_BATCH if kind == "nonlinear MPC" else 1.0)
                extra, compiled = (0.0 if compiled else FIRST_MONTE_CARLO_MS), True
            weights.append(ROW_MS + extra + steps * cost)
    return weights


#: Console lines of one remark at most (a refused construction names every constraint it lacks).
REMARK_LINES = 2


def not_ok_lines(table, width: int = 118) -> list:
    """Every row that is not ok or misses its specs, grouped: "  violates: PD, PID [all]; LQR [steps]".

    Grouped by verdict (or status, for a degraded row that meets its specs), then by the set of
    scenarios, so the list stays short while naming every (controller, scenario). A row that did not
    run as designed says so beside its verdict: "violates (degraded)". Then each controller's remark
    (``controller.remark``, the table's remark column): "  tuned: infeasible for this structure: ...",
    in at most `REMARK_LINES` lines.
    """
    scenarios = list(dict.fromkeys(table.scenario))
    groups: dict = {}
    for row in table.to_dict("records"):
        verdict, status = str(row.get("verdict")), str(row.get("status"))
        if verdict == "meets specs" and status == "ok":
            continue
        kind = status_kind(status)
        if verdict == "meets specs":
            key = kind
        elif kind == "ok" or verdict.startswith(kind):
            key = verdict
        else:
            key = f"{verdict} ({kind})"
        groups.setdefault(key, {}).setdefault(row["controller"], []).append(row["scenario"])
    lines = []
    for key, by_controller in groups.items():
        by_set: dict = {}
        for controller, where in by_controller.items():
            tag = "all" if where == scenarios else ", ".join(where)
            by_set.setdefault(tag, []).append(controller)
        text = "; ".join(f"{', '.join(controllers)} [{tag}]" for tag, controllers in by_set.items())
        lines += textwrap.wrap(f"{key}: {text}", width, initial_indent="  ", subsequent_indent="      ")
    remarks = {} if "remark" not in table else table.dropna(subset=["remark"]).groupby("controller", sort=False)
    for controller, rows in remarks:
        for remark in dict.fromkeys(rows["remark"]):
            if remark:
                lines += textwrap.wrap(
                    f"{controller}: {remark}",
                    width,
                    initial_indent="  ",
                    subsequent_indent="      ",
                    max_lines=REMARK_LINES,
                    placeholder=" ... (whole: table.md)",
                )
    return lines


def plant_report(result: StudyResult, answers: bool) -> dict:
    """What the command prints of one study (picklable): its name, the answers' text (with `answers`,
    else None), counts of controllers and rows, timing, notes, the best step, the verdict counts and
    the lines of the rows that are not ok."""
    table = result.table
    return {
        "name": result.study.plant,
        "answers": format_answers(result.study, result.answers, result.plant.title) if answers else None,
        "controllers": len(result.controllers),
        "rows": len(table),
        "timing": result.timing,
        "notes": list(result.notes),
        "left_out": list(result.left_out),
        "best": result.best("step"),
        "counts": verdict_counts(table),
        "not_ok": not_ok_lines(table),
        "not_ok_rows": len(not_ok_rows(table)),
    }


def run_plant(
    name: str,
    settings: Mapping,
    out: str,
    answers: bool,
    progress: PlantProgress | None = None,
    executor=None,
    run_id: str | None = None,
) -> dict:
    """Study the registered plant `name` with `settings` (keyword arguments of `studies.run_study`) and
    write its folder into `out`; returns its `plant_report`."""
    step = None if progress is None else (lambda done, total, text: progress(name, done, total, text))
    result = run_study(cases.get(name), out=out, progress=step, executor=executor, run_id=run_id, **settings)
    return plant_report(result, answers)


def plant_task(task: tuple) -> tuple:
    """One plant as a task: ``(name, settings, answers, run_id)`` -> (its report, its files as
    {path relative to the output folder: bytes}). It runs in a private folder, so nothing is written
    where the command can see it until every plant has come back (`install`)."""
    name, settings, answers, run_id = task
    with tempfile.TemporaryDirectory(prefix="studies-") as folder:
        report = run_plant(name, settings, folder, answers, run_id=run_id)
        files = {
            str(path.relative_to(folder)): path.read_bytes()
            for path in sorted(Path(folder).rglob("*"))
            if path.is_file()
        }
    return report, files


def install(out: str, files: Mapping[str, bytes]) -> None:
    """Write the plants' folders {relative path: bytes} into `out`, each plant folder replaced as a whole."""
    folder = Path(out)
    staging = folder / f".staging-{uuid.uuid4().hex[:8]}"
    try:
        for relative, data in files.items():
            write_bytes(staging / relative, data)
        for plant in sorted(p for p in staging.iterdir() if p.is_dir()):
            target, old = folder / plant.name, folder / f".old-{plant.name}-{staging.name[9:]}"
            if target.exists():
                target.rename(old)
            plant.rename(target)
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def run_plants(
    plants: Sequence[str],
    settings: Mapping[str, Mapping],
    out: str,
    answers: bool,
    executor,
    progress: PlantProgress,
    run_id: str | None = None,
    longest_first: Mapping[str, float] | None = None,
) -> list:
    """Study every plant of `plants` into `out` on `executor`; returns their reports, as they finished.

    Parameters
    ----------
    settings : plant -> keyword arguments of `studies.run_study` (providers, scenarios, mc, ...)
    executor : a `studies.distributed` executor; with more than one worker (a `Local` pool, or Dask)
        and more than one plant, each plant is a task of its own, else they run here one by one
    progress : progress(plant, done, total, text): after each simulation here, and (1, 1) as each plant
        ends, its files written
    longest_first : plant -> seconds it is expected to take: parallel tasks start with the longest (an
        unknown plant first of all), so that they finish together; every order writes the same files
    """
    reports: list = []
    if len(plants) < 2 or not (executor.distributed or executor.workers > 1):
        for name in plants:
            reports.append(run_plant(name, settings[name], out, answers, progress, executor, run_id))
            progress(name, 1, 1, f"{name} done")  # its files are written too
        return reports
    seconds = longest_first or {}
    order = sorted(plants, key=lambda name: -seconds.get(name, math.inf))
    tasks = [(name, settings[name], answers, run_id) for name in order]
    files: dict = {}
    for report, written in executor.as_completed(plant_task, tasks, labels=[f"plant-{name}" for name in order]):
        reports.append(report)
        files |= written
        progress(report["name"], 1, 1, f"{report['name']} done")
    install(out, files)
    return reports
