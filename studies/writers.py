"""Every file a study leaves: its tables, answers, plots, animation, summary and index.

Files, JSON and Markdown tables go through `models.files` (atomic writes, the
JSON conventions); the HTML pages are Jinja2 templates (`studies.templates`).
This module decides what each study writes.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import math
import os
import secrets
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from models import deferred, specs
from models.files import (
    JSON_CONVENTIONS,
    escape_markdown,
    format_number,
    fresh_folder,
    markdown_table,
    replace_folder,
    scaled,
    write_csv,
    write_json,
    write_text,
)

from . import animation, loops, overview, plots, style, templates, trajectories
from . import output_folder as owned
from . import plain_markdown as plain
from .answers import format_answers
from .case import LoopSpec
from .output_folder import STAGING_OWNER as STAGING_OWNER
from .output_folder import ForeignFolderError as ForeignFolderError
from .output_folder import StagingLeftOver as StagingLeftOver
from .output_folder import check_output_folder
from .runner import STATUS_KINDS, status_kind, tracked_equilibrium

if TYPE_CHECKING:
    import pandas as pd
else:
    pd = deferred.module("pandas")

#: Columns of the study table that measure compute time: they change from run to run, so they go to
#: timings.csv, and table.csv and monte_carlo.csv are the same bytes for the same seed and settings.
TIMING_COLUMNS = ("wall_s", "step_ms", "step_ms_max")


# ---------------------------------------------------------------------------- one run
def new_run_id() -> str:
    """A run's id: its UTC start time and 6 random hex digits, such as '20261201T120338Z-3f2a9c'."""
    now = datetime.datetime.now(datetime.UTC)
    return f"{now:%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}"


# What the output folder may replace, and its staging folders: `studies.output_folder`; its exception,
# warning, owner record's name and up-front check (`check_output_folder`) are offered here too, beside
# the writers that raise them.


def new_staging(out: str | os.PathLike, run_id: str) -> Path:
    """A fresh hidden folder in `out` where a run writes its plant folders before `publish`, with its
    owner record; the staging folders of dead runs are removed first, and one whose owner cannot be told
    is named (`studies.output_folder.new_staging`)."""
    return owned.new_staging(out, run_id)


def publish(staging: str | os.PathLike, out: str | os.PathLike, names, run_id: str) -> None:
    """Move every plant folder a run wrote into `staging` to `out`, each replacing the one there
    (`models.files.replace_folder`), then write out/summary.md and out/index.html over the plants
    `names` found in `out`. Called when the whole run succeeded: an interrupted run publishes nothing.

    Raises
    ------
    ForeignFolderError
        Before anything is moved, when a plant folder in `out` holds entries no run of ours wrote
        (`studies.output_folder.foreign_entries`); `out` is then left as it was.
    """
    staging, out = Path(staging), Path(out)
    plants = sorted(p for p in staging.iterdir() if p.is_dir() and not p.name.startswith("."))
    check_output_folder(out, [folder.name for folder in plants])
    for folder in plants:
        replace_folder(folder, out / folder.name)
    write_summary(out, names, run_id)
    write_index(out, names, run_id)


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_study_folder(folder: str | os.PathLike) -> list[str]:
    """What is wrong with a study folder: missing run.json, or files that are not the ones its run
    wrote (changed, missing or extra, against run.json's SHA-256 manifest). Empty when it holds one
    run's files and nothing else."""
    folder = Path(folder)
    try:
        info = json.loads((folder / "run.json").read_text(encoding="utf-8"))
        manifest = dict(info["sha256"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        return [f"no readable run.json manifest ({type(err).__name__})"]
    problems = []
    for name, digest in manifest.items():
        path = folder / name
        if not path.is_file():
            problems.append(f"{name} is missing")
        elif file_digest(path) != digest:
            problems.append(f"{name} is not the file run {info.get('run_id')} wrote")
    extra = sorted(
        p.name
        for p in folder.iterdir()
        if p.name != "run.json" and p.name not in manifest and not p.name.startswith(".")
    )
    problems += [f"{name} is not from run {info.get('run_id')}" for name in extra]
    return problems


# ---------------------------------------------------------------------------- a study's files
def _unit_columns(tracked_unit: str, input_unit: str) -> list:
    """(column, header, formatter) of the Markdown study table; angles shown in degrees."""
    angle = tracked_unit == "rad"
    scale = 180 / math.pi if angle else 1.0
    unit = "deg" if angle else tracked_unit
    percent = scaled(100.0)
    return [
        ("controller", "controller", format_number),
        ("scenario", "scenario", format_number),
        ("verdict", "verdict", verdict_text),
        ("status", "status", format_number),
        ("rise_time_s", "rise (s)", scaled()),
        ("settling_time_s", "settling 2 % (s)", scaled()),
        ("overshoot_pct", "overshoot (%)", scaled()),
        ("ss_error", f"ss error ({unit})", scaled(scale)),
        ("iae", f"IAE ({unit} s)", scaled(scale)),
        ("itae", f"ITAE ({unit} s²)", scaled(scale)),
        ("peak_u", f"peak |u| ({input_unit})", scaled()),
        ("u_limit", f"limit ({input_unit})", scaled()),
        ("saturated_frac", "time at limit (%)", percent),
        ("energy", f"energy (({input_unit})² s)", scaled()),
        ("violation", "violation (%)", percent),
        ("step_ms", "step (ms)", scaled()),
        ("samples", "runs", format_number),
    ]


def verdict_text(label) -> str:
    """A verdict label with its symbol ("✓ meets specs"); "—" for a missing one."""
    return f"{style.verdict_symbol(label)} {label}" if isinstance(label, str) and label else "—"


def verdict_grid(table) -> tuple[list, list]:
    """Rows (one per controller) and columns (one per scenario) of the verdict grid of a study table."""
    scenarios = list(dict.fromkeys(table.scenario))
    rows = []
    for label in dict.fromkeys(table.controller):
        mine = table[table.controller == label].set_index("scenario")
        rows.append(
            {
                "controller": label,
                **{s: verdict_text(mine.loc[s, "verdict"]) if s in mine.index else "—" for s in scenarios},
            }
        )
    columns = [("controller", "controller", format_number)] + [(s, s, format_number) for s in scenarios]
    return rows, columns


def not_ok(table) -> list:
    """Rows whose status is not "ok" or whose verdict is not "meets specs", as dicts."""
    rows = table.to_dict("records")
    return [r for r in rows if str(r.get("status")) != "ok" or r.get("verdict") != "meets specs"]


def specs_lines(result) -> list:
    """One line per distinct set of specs of the study's scenarios (Markdown bullets)."""
    study, plant = result.study, result.plant
    scenarios = [s.name for s in study.scenarios]
    described: dict = {}
    for name in scenarios:
        chosen = study.specs_for(name, plant.params)
        described.setdefault((chosen.describe(), chosen.source), []).append(name)
    return [
        f"- {', '.join(names)}: {text}" + (f" ({source})" if source else "")
        for (text, source), names in described.items()
    ]


def caption(result) -> str:
    """What every row of a study table is, in words (the honesty statement of the table)."""
    study, plant, options = result.study, result.plant, result.options
    uncertain = ", ".join(plant.uncertain_params)
    mc = next((s for s in study.scenarios if s.monte_carlo), None)
    text = (
        f"Every row is a closed-loop simulation of the nonlinear {escape_markdown(plant.title)} "
        "(`models.simulate_closed_loop`: the equations of motion derived from the plant's energies, "
        f"RK4 with {study.substeps} sub-steps per controller sample, the controller sampled at its own "
        "period, the actuator clipped at its limit), never a linear model alone. "
        "The simulated plant has the text's nominal parameters; "
        f"the controllers are designed from the model known to them, with {uncertain} "
        f"{100 * study.known_rel:+g} %."
    )
    if mc is not None:
        text += (
            f" Monte Carlo rows (scenario `mc`): worst case over the samples (uniform ±{100 * mc.rel:g} % on "
            f"{uncertain}, seed {options.seed}); every controller runs the same {options.mc} samples, block "
            "controllers as one batched CasADi map, controllers that optimize each step (MPC) one by one "
            "(the `runs` column gives the count); spreads are in table.csv (`*_std`)."
        )
    return text


DEFINITIONS = (
    "Definitions (`models.metrics`): rise 10→90 % of the commanded step; settling: time after which the tracked "
    "coordinate stays within 2 % of the step around the command (∞: not settled by the end); overshoot in % of "
    "the step; ss error: |command − mean over the last 5 %|; IAE = ∫|e| dt, ITAE = ∫(t − t_step)|e| dt; a series "
    "of steps reports its worst step; peak |u| of the command, time at limit: commands within 0.1 % of or beyond "
    "the limit; energy ∫u² dt of the delivered input; violation: largest excess of the command over the limit or "
    "of a state bound, in % of the limit or bound range; step: controller compute time per sample. CSV columns "
    "are in SI units (rad, m, N, N m); this Markdown shows angles in degrees."
)


def _loop_rows(loops_found: dict, specs, checks: dict) -> list:
    """The rows of loops.csv: per controller and loop, its margins (`studies.loops.LoopGain.margins`), the
    real part of its slowest closed-loop pole in the s-plane (1/s), whether the discrete closed loop is
    stable, and the verdict of each loopshaping spec of that loop (`checks`: (label, item) -> {check: bool}).
    """
    rows = []
    for label, found in loops_found.items():
        for which, lp in found.items():
            poles = lp.s_plane(lp.closed_loop_poles(1.0))
            row = {
                "controller": label,
                "loop": which,
                **lp.margins(),
                "slowest_pole_real": float(np.max(poles.real)) if poles.size else math.nan,
                "stable": bool(np.all(np.abs(lp.closed_loop_poles(1.0)) < 1)),
            }
            for spec in specs:
                if spec.loop == which:
                    for name, verdict in checks.get((label, spec.item), {}).items():
                        row[f"{spec.item} {name}"] = verdict
            rows.append(row)
    return rows


def write_study(result, out: str | os.PathLike, run_id: str | None = None) -> dict:
    """Write everything a study produced into ``out/<plant>/``; returns {kind: file name}.

    Files: table.csv, table.md, answers.json, answers.md, monte_carlo.csv,
    loops.csv, timings.csv, <scenario>.png, monte_carlo.png, bode_<loop>.png,
    root_locus.png, poles.png, animation.gif, animation.html, run.json.

    The folder is written beside ``out/<plant>`` and replaces it whole when every file is
    written (`models.files.replace_folder`); an interrupted write leaves the previous folder.
    run.json records `run_id` (default a new one, see `new_run_id`), the settings and the
    SHA-256 of every other file (see `check_study_folder`). table.csv and monte_carlo.csv
    hold no timings (those are in timings.csv and run.json): the same seed and settings give
    the same bytes.

    Raises
    ------
    ForeignFolderError
        Before any file is written, when ``out/<plant>`` holds entries no run of ours wrote.
    """
    run_id = new_run_id() if run_id is None else str(run_id)
    out = Path(out)
    check_output_folder(out, [result.study.plant])
    # Every file goes into a fresh hidden sibling first, swapped in by one rename when complete: out/<plant>
    # holds one run's files, whatever interrupts this one.
    folder = fresh_folder(out, f".{result.study.plant}.", ".partial")
    try:
        files = _write_files(result, folder, run_id)
        replace_folder(folder, out / result.study.plant)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return files


def _write_files(result, folder: Path, run_id: str) -> dict:
    """Write every file of `result` into `folder` (a fresh one); {kind: file name}, in the order written.

    The steps: the tables and answers (`write_tables`), the time responses (`write_responses`), the
    linear loop analysis (`write_loop_analysis`), the animation (`write_animation`), the case's
    trajectories, then table.md, which reports the time the files took, and run.json last, since its
    manifest holds the SHA-256 of every other file (`run_record`).
    """
    started = time.perf_counter()
    dpi = 72 if result.options.quick else 100
    files = write_tables(result, folder)
    files |= write_responses(result, folder, dpi)
    loop_files, loop_rows, loop_notes = write_loop_analysis(result, folder, dpi)
    files |= loop_files
    animation_files, animation_notes = write_animation(result, folder)
    files |= animation_files
    notes = [*result.notes, *loop_notes, *animation_notes]
    if result.trajectories is not None:
        files |= trajectories.write_files(result.trajectories, folder)
    result.timing["files_s"] = time.perf_counter() - started
    write_text(folder / "table.md", _study_markdown(result, notes, loop_rows, run_id))
    files["table.md"] = "table.md"
    write_json(folder / "run.json", run_record(result, folder, files, notes, run_id))
    return files


def write_tables(result, folder: Path) -> dict:
    """table.csv and monte_carlo.csv (without their compute times), timings.csv, answers.json and
    answers.md of `result` in `folder`; {kind: file name} of those written (no monte_carlo.csv
    without Monte Carlo samples)."""
    files: dict = {}
    table, samples = result.table, result.samples
    write_csv(folder / "table.csv", table.drop(columns=[c for c in TIMING_COLUMNS if c in table]))
    files["table.csv"] = "table.csv"
    if len(samples):
        write_csv(folder / "monte_carlo.csv", samples.drop(columns=[c for c in TIMING_COLUMNS if c in samples]))
        files["monte_carlo.csv"] = "monte_carlo.csv"
    write_csv(folder / "timings.csv", timings_frame(table, samples))
    files["timings.csv"] = "timings.csv"
    write_json(folder / "answers.json", {"_conventions": JSON_CONVENTIONS, **result.answers})
    # The title goes into answers.md's heading: shown as written, never Markdown or HTML.
    write_text(folder / "answers.md", format_answers(result.study, result.answers, escape_markdown(result.plant.title)))
    return files | {"answers.json": "answers.json", "answers.md": "answers.md"}


def write_responses(result, folder: Path, dpi: int) -> dict:
    """<scenario>.png of every scenario but the Monte Carlo, and monte_carlo.png (its envelopes), at
    `dpi` dots per inch; {kind: file name} of those drawn (a scenario no controller ran has none)."""
    files = {}
    for scenario in result.study.scenarios:
        name = f"{scenario.name}.png"
        if not scenario.monte_carlo and plots.responses(result, scenario.name, folder / name, dpi):
            files[name] = name
    if plots.envelopes(result, folder / "monte_carlo.png", dpi):
        files["monte_carlo.png"] = "monte_carlo.png"
    return files


def write_loop_analysis(result, folder: Path, dpi: int) -> tuple[dict, list, list]:
    """The linear loop analysis of every block controller (`studies.loops`): bode_<loop>.png of each
    loopshaping spec of the case (bode_input.png when none is at the plant input), loops.csv,
    root_locus.png and poles.png.

    Returns
    -------
    ({kind: file name} of the files written, the rows of loops.csv (dicts), notes on the loops not analysed)
    """
    study, quick = result.study, result.options.quick
    _, base = tracked_equilibrium(result.plant, study)
    found, notes = loops.analyse(result.plant, study, result.controllers, base, result.runs, result.truths)
    files = {}
    checks = {}
    for spec in study.loops:
        baseline = found.get(spec.baseline, {}).get(spec.loop) if spec.baseline else None
        for label, loops_of in found.items():
            if spec.loop in loops_of:
                checks[(label, spec.item)] = loops.spec_check(loops_of[spec.loop], spec, baseline)
        verdicts = {label: checks[(label, spec.item)] for label in found if (label, spec.item) in checks}
        name = f"bode_{spec.loop}.png"
        if plots.bode(result, found, spec, folder / name, verdicts, dpi):
            files[name] = name
    if not any(spec.loop == "input" for spec in study.loops):
        plain = LoopSpec("", "input", design="", baseline=None)
        if plots.bode(result, found, plain, folder / "bode_input.png", None, dpi):
            files["bode_input.png"] = "bode_input.png"
    rows = _loop_rows(found, study.loops, checks)
    if rows:
        write_csv(folder / "loops.csv", pd.DataFrame(rows))
        files["loops.csv"] = "loops.csv"
    if plots.root_loci(result, found, folder / "root_locus.png", dpi, gains=100 if quick else 300):
        files["root_locus.png"] = "root_locus.png"
    if plots.pole_map(result, found, folder / "poles.png", dpi):
        files["poles.png"] = "poles.png"
    return files, rows, notes


def write_animation(result, folder: Path) -> tuple[dict, list]:
    """animation.gif of the best controller in the step scenario (lowest ITAE) and animation.html of
    every controller whose step did not diverge, the best shown first.

    Returns
    -------
    ({kind: file name} of the files written, a note saying why there is no animation (or none))
    """
    study, plant, quick = result.study, result.plant, result.options.quick
    best = result.best("step", meeting=False)
    if study.drawing is None:
        return {}, [f"no animation: the {study.plant} case has no drawing"]
    if best is None or (best, "step") not in result.runs:
        return {}, ["no animation: no controller completed the step scenario"]
    run = result.runs[(best, "step")]
    animation.write_gif(
        folder / "animation.gif", study, plant, run, best, max_frames=30 if quick else 100, dpi=64 if quick else 80
    )
    shown = {label: r for (label, name), r in result.runs.items() if name == "step" and r.diverged_at is None}
    left_out = [label for (label, name), r in result.runs.items() if name == "step" and r.diverged_at is not None]
    steps = result.table[result.table.scenario == "step"].set_index("controller")
    step_verdicts = {label: verdict_text(steps.loc[label, "verdict"]) for label in shown if label in steps.index}
    text = (
        f"Nonlinear simulations of the text's step ({study.source}); first shown: {best}, the lowest ITAE. "
        "Pick a controller, and a second one as a faint ghost; the commanded input is beside the drawing "
        "with the actuator limit." + (f" Left out (diverged): {', '.join(left_out)}." if left_out else "")
    )
    animation.write_html(
        folder / "animation.html",
        study,
        plant,
        shown,
        best,
        text,
        max_frames=150 if quick else 300,
        verdicts=step_verdicts,
        scenario="the controllers on the text's step",
    )
    return {"animation.gif": "animation.gif", "animation.html": "animation.html"}, []


def run_record(result, folder: Path, files: dict, notes: list, run_id: str) -> dict:
    """run.json of a study folder: the plant, the run's id, settings, status counts, timing (s), notes,
    files ({kind: file name}) and units, with the SHA-256 of every file in `files` as written in
    `folder` (the manifest `check_study_folder` checks)."""
    study, plant = result.study, result.plant
    return {
        "plant": plant.name,
        "title": plant.title,
        "numeral": study.numeral,
        "best": result.best("step"),
        "run_id": run_id,
        "settings": run_settings(result),
        "status": status_counts(result.table),
        "timing": result.timing,
        "notes": notes,
        "files": files,
        "tracked": study.tracked,
        "tracked_unit": study.tracked_unit,
        "input_unit": study.input_unit,
        "sha256": {name: file_digest(folder / name) for name in sorted(files.values())},
    }


def run_settings(result) -> dict:
    """Everything that decides a study's numbers: the options, the providers and the case's scenarios."""
    options, study = result.options, result.study
    return {
        "mc": options.mc,
        "seed": options.seed,
        "quick": options.quick,
        "strict": options.strict,
        "jit": options.jit,
        "threads": options.threads,
        "providers": list(result.providers),
        "without": list(options.without),
        "scenarios": [s.name for s in study.scenarios if options.scenarios is None or s.name in options.scenarios],
    }


def status_counts(table) -> dict:
    """Rows of each status kind (`studies.runner.STATUS_KINDS`), in that order."""
    kinds = [status_kind(s) for s in table.status] if len(table) else []
    return {kind: kinds.count(kind) for kind in STATUS_KINDS}


def not_ok_rows(table) -> list:
    """(controller, scenario, status) of every row whose status is not "ok", in table order."""
    return [
        (str(r.controller), str(r.scenario), str(r.status)) for r in table.itertuples() if status_kind(r.status) != "ok"
    ]


def timings_frame(table, samples):
    """timings.csv: compute times of each row (and of each Monte Carlo sample that has one)."""
    keep = ["controller", "scenario"]
    rows = table[keep + [c for c in TIMING_COLUMNS if c in table]].assign(sample=pd.NA)
    frames = [rows[keep + ["sample"] + [c for c in TIMING_COLUMNS if c in rows]]]
    if len(samples) and any(c in samples for c in TIMING_COLUMNS):
        per = samples[["controller", "sample"] + [c for c in TIMING_COLUMNS if c in samples]]
        per = per[per.drop(columns=["controller", "sample"]).notna().any(axis=1)].assign(scenario="mc")
        frames.append(per[keep + ["sample"] + [c for c in TIMING_COLUMNS if c in per]])
    return pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]


def status_lines(table, escape=escape_markdown) -> list:
    """Markdown lines saying how the rows ran: the count of each status kind and every row that is
    not "ok" (skipped rows of the same reason counted once); labels and statuses written by `escape`."""
    counts = status_counts(table)
    lines = ["Status of the rows: " + ", ".join(f"{n} {kind}" for kind, n in counts.items() if n) + "."]
    skipped: dict = {}
    for controller, scenario, status in not_ok_rows(table):
        if status.startswith("skipped"):
            skipped.setdefault(status, []).append(f"{controller} / {scenario}")
        else:
            lines.append(f"- **{escape(controller)} / {escape(scenario)}**: {escape(status)}")
    for status, where in skipped.items():
        lines.append(f"- {escape(status)}: {escape(', '.join(where))}")
    return lines


def _remarks(table, shown) -> dict:
    """{controller: its remark} (the table's remark column, e.g. a tuned design's certificate that its
    structure cannot meet the specs over the parameter box) of the controllers not in `shown`, whose
    failing rows already say it first in their details."""
    if "remark" not in table:
        return {}
    out: dict = {}
    for controller, remark in zip(table.controller, table.remark):
        if isinstance(remark, str) and remark and controller not in shown:
            out.setdefault(controller, remark)
    return out


def _study_markdown(result, notes: list, loop_rows: list, run_id: str = "") -> str:
    """table.md: the caption, the verdict grid and what each row misses, how the rows ran, the metrics (angles
    in degrees), the Monte Carlo's worst case and spread, the linear loop analysis, the notes and run time.
    Tables, rows and notes are written by `studies.plain_markdown` (literal once rendered, clean in a terminal)."""
    study, plant = result.study, result.plant
    columns = _unit_columns(study.tracked_unit, study.input_unit)
    rows = result.table.to_dict("records")
    grid_rows, grid_columns = verdict_grid(result.table)
    failing = not_ok(result.table)
    parts = [
        f"# {escape_markdown(plant.title)}: controllers compared",
        "",
        f"Run {run_id}; settings in run.json.",
        "",
        caption(result),
        "",
        "## Verdicts against the specs",
        "",
        "Specs (`models.specs`; a series of steps is judged by its worst step, a Monte Carlo by its worst sample):",
        "",
        *specs_lines(result),
        "",
        plain.markdown_table(grid_rows, grid_columns),
    ]
    if failing:
        parts += ["What the rows that do not meet their specs miss:", ""]
        parts += [
            f"- {plain.markdown_text(r['controller'])} / {plain.markdown_text(r['scenario'])}: "
            f"{verdict_text(r['verdict'])}"
            + (
                f" — {plain.markdown_text(r['verdict_detail'])}"
                if isinstance(r.get("verdict_detail"), str)
                and r["verdict_detail"]
                and not str(r["verdict_detail"]).startswith("skipped")
                else ""
            )
            for r in failing
        ]
        parts.append("")
    shown = {r["controller"] for r in failing}
    remarks = _remarks(result.table, shown)
    if remarks:
        parts += ["Remarks of the controllers whose rows above meet their specs:", ""]
        parts += [f"- {plain.markdown_text(c)}: {plain.markdown_text(text)}" for c, text in remarks.items()]
        parts.append("")
    parts += [
        "## How the rows ran",
        "",
        *status_lines(result.table, plain.markdown_text),
        "",
        "## Metrics",
        "",
        plain.markdown_table(rows, columns),
        DEFINITIONS,
        "",
    ]
    mc_rows = [r for r in rows if r["scenario"] == "mc"]
    if mc_rows:
        angle = study.tracked_unit == "rad"
        scale, unit = (180 / math.pi, "deg") if angle else (1.0, study.tracked_unit)
        parts += [
            "## Monte Carlo: worst case and spread (sample standard deviation)",
            "",
            plain.markdown_table(
                mc_rows,
                [
                    ("controller", "controller", format_number),
                    ("samples", "samples", format_number),
                    ("diverged_samples", "diverged", format_number),
                    ("settling_time_s", "settling worst (s)", scaled()),
                    ("settling_time_s_std", "settling std (s)", scaled()),
                    ("overshoot_pct", "overshoot worst (%)", scaled()),
                    ("overshoot_pct_std", "overshoot std (%)", scaled()),
                    ("iae", f"IAE worst ({unit} s)", scaled(scale)),
                    ("iae_std", f"IAE std ({unit} s)", scaled(scale)),
                    ("peak_u", f"peak |u| worst ({study.input_unit})", scaled()),
                    ("step_ms", "step (ms)", scaled()),
                ],
            ),
        ]
    if loop_rows:
        keys = [k for k in loop_rows[0] if k not in ("controller", "loop")]
        extra = sorted({k for r in loop_rows for k in r} - set(loop_rows[0]))
        parts += [
            "## Linear loop analysis (exact linearization where each block holds the plant at rest)",
            "",
            plain.markdown_table(
                loop_rows,
                [("controller", "controller", format_number), ("loop", "loop", format_number)]
                + [(k, k.replace("_", " "), format_number) for k in keys + extra],
            ),
            "Margins of the discrete loop L(z) (`designs.analysis.margins`: crossings of the exact "
            "L(e^{jωTs}) located on a grid and refined; closed loop 1 + L = 0); "
            "slowest pole: largest real part of s = ln(z)/Ts of the closed loop.",
            "",
        ]
    timing = ", ".join(f"{k[:-2].replace('_', ' ')} {v:.1f} s" for k, v in result.timing.items())
    timing = timing.replace("total", "simulations in all").replace("files", "plots, animations and files")
    parts += ["## Notes", ""] + [f"- {plain.markdown_text(n)}" for n in notes or ["none"]]
    parts += ["", f"Run time: {timing}.", ""]
    return "\n".join(parts)


# ---------------------------------------------------------------------------- across studies
def _read_studies(out: Path, names) -> list:
    """(name, run.json, table with its timings) of every study folder found in `out`; run.json gains
    "problems", what `check_study_folder` found wrong with the folder."""
    found = []
    for name in names:
        folder = out / name
        if (folder / "run.json").exists() and (folder / "table.csv").exists():
            info = json.loads((folder / "run.json").read_text(encoding="utf-8"))
            info["problems"] = check_study_folder(folder)
            table = pd.read_csv(folder / "table.csv", keep_default_na=True)
            if (folder / "timings.csv").exists():
                timings = pd.read_csv(folder / "timings.csv")
                timings = timings[timings["sample"].isna()].drop(columns=["sample"])
                table = table.merge(timings, on=["controller", "scenario"], how="left")
            found.append((name, info, table))
    return found


def _run_of(info: dict, run_id: str | None) -> str:
    """Which run a study folder comes from, and whether it is whole, in words."""
    text = f"run {info.get('run_id', 'unknown')}"
    if run_id is not None and info.get("run_id") != run_id:
        text += f" (an earlier run, not {run_id})"
    if info.get("problems"):
        text += "; folder not as its run wrote it: " + "; ".join(info["problems"])
    return text


def _cell(table, controller: str, scenario: str = "step") -> str:
    """A cell of summary.md: the verdict's symbol, then settling time (s) / overshoot (%), or the status
    (up to its first colon) of a row that is not ok and never settled; "—" when the plant has no such
    controller."""
    rows = table[(table.controller == controller) & (table.scenario == scenario)]
    if rows.empty:
        return "—"
    row = rows.iloc[0]
    mark = verdict_text(row.get("verdict")).split(" ")[0] if isinstance(row.get("verdict"), str) else ""
    if row.status != "ok" and not np.isfinite(float(row.settling_time_s)):
        return f"{mark} {str(row.status).split(':')[0]}".strip()  # the reason is in the plant's table.md
    return f"{mark} {format_number(row.settling_time_s, 3)} s / {format_number(row.overshoot_pct, 2)} %".strip()


#: Verdict counts reported per plant, in this order.
COUNTED = specs.LABELS


def verdict_counts(table) -> dict:
    """Rows of each verdict in `COUNTED` (0 for a table without a verdict column)."""
    verdicts = table.verdict.astype(str) if "verdict" in table else None
    return {k: int((verdicts == k).sum()) if verdicts is not None else 0 for k in COUNTED}


def write_summary(out: str | os.PathLike, names, run_id: str | None = None) -> Path:
    """OUT/summary.md across the studies found in `out` (read back from their table.csv and run.json).

    Each plant says which run wrote it (and, given `run_id`, whether that is this run) and how its
    rows ran (`studies.runner.STATUS_KINDS`), listing every row that is not "ok".
    """

    out = Path(out)
    studies = _read_studies(out, names)
    labels = []
    for _, _, table in studies:
        labels += [c for c in table.controller.unique() if c not in labels]
    legend = ", ".join(f"{symbol} {label}" for label, (symbol, _) in style.VERDICTS.items())
    lines = ["# Summary: every controller on every plant", ""]
    if run_id is not None:
        lines += [f"Run {run_id}. A plant folder written by another run says so below.", ""]
    lines += [
        f"Each cell: the verdict of the text's step against the plant's specs ({legend}), then its 2 % "
        "settling time / overshoot on the nonlinear plant (from OUT/<plant>/table.csv; ∞: not settled by "
        "the end of the run; — : controller not provided for that plant). Each plant's table.md says which "
        "specs a row misses and by how much.",
        "",
    ]
    columns = [("controller", "controller", format_number)] + [(n, n, format_number) for n, _, _ in studies]
    rows = [{"controller": label, **{n: _cell(t, label) for n, _, t in studies}} for label in labels]
    lines += [markdown_table(rows, columns)]
    lines += ["## Per plant", ""]
    per = [
        {
            "plant": n,
            "run": _run_of(info, run_id),
            "best": info.get("best") or "no row meets the specs",
            "controllers": int(t.controller.nunique()),
            **verdict_counts(t),
            "time": f"{info['timing'].get('total_s', math.nan) + info['timing'].get('files_s', 0.0):.1f} s",
            "settings": f"mc {info['settings']['mc']}, seed {info['settings']['seed']}"
            + (", quick" if info["settings"]["quick"] else ""),
        }
        for n, info, t in studies
    ]
    lines += [
        markdown_table(
            per,
            [
                (k, k if k != "best" else "best (lowest step ITAE among rows meeting the specs)", format_number)
                for k in ("plant", "run", "best", "controllers", *COUNTED, "time", "settings")
            ],
        )
    ]
    for n, _, table in studies:
        if not_ok_rows(table):
            lines += ["", f"Rows of {n} that did not run as designed:", ""] + status_lines(table)[1:]
    common = set.intersection(*(set(info["notes"]) for _, info, _ in studies)) if len(studies) > 1 else set()
    if common:
        first = studies[0][1]["notes"]
        lines += ["", "Notes on every plant:", ""] + [f"- {escape_markdown(note)}" for note in first if note in common]
    for n, info, _ in studies:
        own = [note for note in info["notes"] if note not in common]
        if own:
            lines += ["", f"Notes on {n}:", ""] + [f"- {escape_markdown(note)}" for note in own]
    return write_text(out / "summary.md", "\n".join(lines) + "\n")


def write_index(out: str | os.PathLike, names, run_id: str | None = None) -> Path:
    """OUT/index.html linking every table, answer file, plot and animation found in `out`; each plant
    says which run wrote it and lists its rows that are not "ok" (see `write_summary`). The page is the
    template ``index.html.j2``; every title, label and file name in it is escaped."""
    out = Path(out)
    studies = _read_studies(out, names)
    figures = []
    if studies:
        pictures = [("scatter", overview.scatter(studies)), ("boxplots", overview.boxplots(out, studies))]
        figures = [{"id": name, "svg": svg} for name, svg in pictures if svg]
    page = templates.render(
        "index.html.j2",
        run_id=run_id,
        plants=[_index_entry(name, info, table, run_id) for name, info, table in studies],
        heatmap=overview.heat_map(studies) if studies else "",
        figures=figures,
    )
    return write_text(out / "index.html", page)


def _index_entry(name: str, info: dict, table, run_id: str | None) -> dict:
    """What index.html shows of one plant: its files, the run that wrote them, its rows that are not
    ok, its best controller, verdict grid, step metrics and pictures (from its run.json and table)."""
    files = info["files"]
    step_rows = table[table.scenario == "step"].to_dict("records")
    columns = _unit_columns(info["tracked_unit"], info["input_unit"])
    verdicts = None
    if "verdict" in table:
        grid_rows, grid_columns = verdict_grid(table)
        verdicts = {"rows": grid_rows, "columns": grid_columns}
    return {
        "name": name,
        "title": info["title"],
        "links": [f for f in files.values() if not f.endswith(".png") and not f.endswith(".gif")],
        "run": _run_of(info, run_id),
        "counts": ", ".join(f"{n} {kind}" for kind, n in status_counts(table).items() if n),
        "not_ok": not_ok_rows(table),
        "best": info.get("best") or "no row meets the specs",
        "animation": "animation.gif" in files,
        "verdicts": verdicts,
        "step": {"rows": step_rows, "columns": [c for c in columns if c[0] != "scenario"]} if step_rows else None,
        "pictures": [f for f in files.values() if f.endswith(".png")],
    }
