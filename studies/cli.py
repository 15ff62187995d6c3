"""python -m studies: every controller on every plant, in tables, plots and animations.

Runs every registered case study (or the plants named) and writes OUT/<plant>/
(tables with each row's verdict against the case's specs, answers, plots,
animations), OUT/summary.md and OUT/index.html. The console shows one progress
bar, then one line per plant, every row that is not ok or misses its specs,
and the files to open; homework answers go to OUT/<plant>/answers.md (printed
with --answers or -v). ``--sweep PARAM=LOW:HIGH:N`` runs every controller of
one plant over a grid of its true parameter instead. ``--workers N`` or
``--scheduler ADDRESS`` run the work on Dask (the same numbers). Every plant
folder is written aside and moved into OUT when the whole run succeeded: an
interrupted or failed run leaves OUT as it was. Exit status 2 on bad
arguments, 1 when a run fails (or, with --strict, when a provider is missing
or a row is not ok), 130 when interrupted (Ctrl-C), 143 on SIGTERM, 129 on SIGHUP (a closed
terminal), 0 otherwise. The pool's workers (``--jobs``) end with this process, whatever ends it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import models
from models import checks, deferred, files, interrupts

from . import batch, cases, distributed, runner, sweep, writers
from .case import SCENARIO_NAMES
from .designing import without_labels
from .provider_calls import ProviderNotFound, find, unavailable

if TYPE_CHECKING:
    import tqdm
else:  # 0.03 s to import (-X importtime): the bar is made once the command line is checked
    tqdm = deferred.module("tqdm")

#: Defaults of a full run and of --quick: Monte Carlo samples of every controller (MPC included).
FULL = {"mc": 200}
QUICK = {"mc": 10}
#: Seconds each plant's study took in a --quick run here (its run.json: timing total_s + files_s), used
#: only to hand the longest plants to the --jobs workers first, so that they finish together.
RUN_SECONDS = {"crane": 63.0, "pendulum": 40.0, "ballbeam": 28.0, "satellite": 22.0, "arm": 9.0, "uuv": 6.0}


def _count(text: str) -> int:
    """--mc: a whole number of samples >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of samples, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"the number of samples must be >= 0, got {value}")
    return value


def _seed(text: str) -> int:
    """--seed: a whole number >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"the seed must be a whole number >= 0, got {value}")
    return value


def _folder(text: str) -> str:
    """--out: a folder name, not blank and without a NUL character."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a folder name, got {text!r} (use . for this folder)")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"a folder name cannot contain a NUL character, got {text!r}")
    return text


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m studies`` (its help lists the registered plants)."""
    p = argparse.ArgumentParser(
        prog="python -m studies",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  python -m studies --quick\n  python -m studies arm --scenario step --mc 500 --out DIR\n"
        "  python -m studies pendulum --sweep m2=0.5:2:8 --workers 2\n  python -m studies --list",
    )
    p.add_argument(
        "plants", nargs="*", metavar="PLANT", help=f"plants to study (default all: {', '.join(cases.names())})"
    )
    p.add_argument(
        "--scenario",
        action="append",
        metavar="NAME",
        help=f"run only these scenarios (repeat or comma-separate): {', '.join(SCENARIO_NAMES)}",
    )
    p.add_argument(
        "--mc",
        type=_count,
        metavar="N",
        help=f"Monte Carlo samples of every controller, MPC included (default {FULL['mc']}, "
        f"--quick {QUICK['mc']}; 0 skips the Monte Carlo)",
    )
    p.add_argument(
        "--seed",
        type=_seed,
        default=0,
        help="seed of the parameter samples and the noise, a whole number >= 0 (default 0)",
    )
    p.add_argument("--out", type=_folder, default="results", metavar="DIR", help="output folder (default results/)")
    p.add_argument(
        "--quick", action="store_true", help=f"{QUICK['mc']} Monte Carlo samples, lighter plots and animations"
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=2,
        metavar="N",
        help="run N plants at once in separate processes (default 2, one per core here; 1 runs "
        "everything in this process)",
    )
    p.add_argument(
        "--without",
        action="append",
        default=[],
        metavar="LABEL",
        help='leave out the controller LABEL on every plant (repeat for more; e.g. --without "scenario-tree '
        "NMPC\", most of a default run's time); each study notes it",
    )
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="run on a Dask LocalCluster of N worker processes: the plants, or one plant's Monte Carlo "
        "samples and sweep points (the same numbers as without Dask)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the Dask cluster of this scheduler (tcp://host:8786); its workers must import this package",
    )
    p.add_argument(
        "--sweep",
        metavar="PARAM=LOW:HIGH:N",
        help="instead of the study: every controller of one plant on N values of its true parameter "
        "PARAM from LOW to HIGH (writes OUT/PLANT/sweep.csv, sweep.png, sweep.md)",
    )
    p.add_argument("--long", action="store_true", help="run a --sweep estimated beyond studies.sweep.TIME_LIMIT_S")
    p.add_argument(
        "--list",
        action="store_true",
        help="list plants, scenarios and declared controllers (designs nothing, runs nothing)",
    )
    p.add_argument(
        "--provider",
        action="append",
        default=[],
        metavar="MODULE:FUNCTION",
        help="add a controller provider: FUNCTION(case, known) -> {label: controller}",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="exit 1 on a missing or failing provider (before running), on a controller error, and "
        "when any row is not ok (degraded, diverged, failed or skipped)",
    )
    p.add_argument(
        "--answers",
        action="store_true",
        help="print the homework answers and errata (always written to OUT/<plant>/answers.md)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="print the answers and every note as well")
    p.add_argument("--quiet", action="store_true", help="no progress bar: only the closing lines")
    return p


class Progress:
    """One tqdm bar over every plant's runs, its total fixed before the run starts.

    Each plant has a share of the total: the expected costs of its declared controllers' runs, the
    first carrying its designs, and of its files (`progress_slots`, `studies.batch.plant_costs`: a
    pair (weights, after)), or a number of equal runs. `update(plant, done, total, text)` after each
    simulation, and (1, 1) once the plant is done (its files written), moves the bar to the cost of
    the plant's first `done` runs (or its share times done/total when a provider added or
    lacked controllers), so the remaining time follows the work left, not the count of runs. The
    estimate is the run's average rate (no smoothing): elapsed x whole / done.
    """

    def __init__(self, slots: dict, stream=None, disable: bool = False):
        stream = stream or sys.stderr
        tty = stream.isatty()
        after = {plant: float(w[1]) if isinstance(w, tuple) else 0.0 for plant, w in slots.items()}
        slots = {plant: w[0] if isinstance(w, tuple) else w for plant, w in slots.items()}
        self.weights = {
            plant: [1.0] * int(w) if isinstance(w, (int, float)) else [float(x) for x in w]
            for plant, w in slots.items()
        }
        self.slots = {plant: sum(w) + after[plant] for plant, w in self.weights.items()}
        self.done = dict.fromkeys(self.slots, 0.0)
        self.runs = dict.fromkeys(self.slots, 0)
        self.bar = tqdm.tqdm(
            total=sum(self.slots.values()),
            file=stream,
            disable=disable,
            dynamic_ncols=True,
            mininterval=0.2 if tty else 20.0,
            smoothing=0.0,
            ascii=not tty,
            bar_format="{desc} {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]{postfix}",
            desc=f"{len(self.slots)} plant{'s' * (len(self.slots) > 1)}",
        )

    def update(self, plant: str, done: int, total: int, text: str) -> None:
        """`plant` has made `done` of its `total` runs; the runs made and `text` (its first 50 characters)
        follow the bar."""
        weights = self.weights.get(plant, [])
        done = min(done, total)
        if total == len(weights):
            self.done[plant] = sum(weights[:done])
        else:
            self.done[plant] = self.slots.get(plant, 0) * done / max(total, 1)
        self.runs[plant] = done if total == len(weights) else round(len(weights) * done / max(total, 1))
        runs = sum(len(w) for w in self.weights.values())
        self.bar.set_postfix_str(f"{sum(self.runs.values())}/{runs} runs, {text[:50]}", refresh=False)
        reached = sum(self.done.values())
        if reached > self.bar.n:
            self.bar.update(reached - self.bar.n)

    def close(self) -> None:
        """End the bar (its last state stays on the stream)."""
        self.bar.close()


def progress_slots(plants, scenarios, settings: dict) -> dict:
    """plant -> (expected cost of each run it will make, of its files) (`studies.batch.plant_costs`): its
    declared controllers (but those left out, ``--without``) through the scenarios it will run."""
    slots = {}
    without = settings.get("without") or ()
    for name in plants:
        case = cases.get(name)
        labels = [label for label in case.controllers if label not in without]
        weights, after = batch.plant_costs(case, scenarios, int(settings.get("mc") or 0), labels)
        slots[name] = (weights or [1.0], after)
    return slots


def _scenarios(values, p: argparse.ArgumentParser):
    """The --scenario names (repeated or comma-separated; None for all), each checked."""
    if not values:
        return None
    names = [n.strip() for v in values for n in v.split(",") if n.strip()]
    if not names:
        p.error(f"--scenario names no scenario; valid scenarios: {', '.join(SCENARIO_NAMES)}")
    unknown = [n for n in names if n not in SCENARIO_NAMES]
    if unknown:
        p.error(f"unknown scenario {unknown[0]!r}; valid scenarios: {', '.join(SCENARIO_NAMES)}")
    return names


def _list(plants, providers) -> str:
    """Plants, scenarios and declared controllers, as the registered cases declare them (nothing designed)."""
    lines = ["plants: " + ", ".join(cases.names()), "scenarios: " + ", ".join(SCENARIO_NAMES), ""]
    for name in plants:
        case = cases.get(name)
        lines.append(f"{name}: {case.source}")
        lines.append("  scenarios: " + ", ".join(s.name for s in case.scenarios))
        lines.append("  controllers: " + ", ".join(case.controllers))
        lines += [f"  + the controllers of {spec}, named when they are designed" for spec in providers]
    lines += [
        "",
        "Controllers are listed as each case declares them; a provider may lack some (the run notes "
        "which) or add others.",
    ]
    return "\n".join(lines)


def _plant_line(done: dict) -> str:
    """A plant's closing line: "arm: 12 controllers, 60 rows: 50 meet specs, 10 violate; best step ITAE: LQR".

    The best is the lowest step ITAE among the controllers whose every row meets its specs
    (`StudyResult.best`); when none does the line says so ("best step ITAE: none, no step row meets the
    specs"), never naming a controller that violates them in any scenario."""
    plural = {"meets specs": "meet specs", "violates": "violate"}
    counts = ", ".join(
        f"{n} {plural.get(label, label) if n > 1 else label}" for label, n in done["counts"].items() if n
    )
    best = f"; best step ITAE: {done['best'] or 'none, no step row meets the specs'}" if "best" in done else ""
    return f"{done['name']}: {done['controllers']} controllers, {done['rows']} rows: {counts or 'no verdicts'}{best}"


def closing_lines(finished: list, out: str, verbose: bool = False) -> list:
    """What the run ends with: a line per plant, each followed by its rows that are not ok, and the paths."""
    lines = []
    for done in finished:
        lines.append(_plant_line(done))
        lines += done["not_ok"]
        failures = [n for n in done["notes"] if "failed" in n and not n.startswith("not provided")]
        lines += [f"  note: {n}" for n in (done["notes"] if verbose else failures)]
    lines.append(
        f"open {os.path.join(out, 'index.html')} (every plant at a glance) or "
        f"{os.path.join(out, 'summary.md')}; {os.path.join(out, '<plant>', 'table.md')} says what each "
        "row misses, and by how much"
    )
    return lines


def command_line_providers(specs: Sequence[str]) -> tuple[list, list]:
    """The ``--provider MODULE:FUNCTION`` providers, found before any work, and one message per provider
    that does not exist or fails to import; such a provider is run as a `studies.provider_calls.Unavailable`
    stand-in, which each study notes."""
    found, problems = [], []
    for spec in specs:
        try:
            found.append(find(spec))
        except ProviderNotFound as err:
            problems.append(f"--provider {spec}: {str(err).split(': ', 1)[1]}")
            found.append(unavailable(spec, err))
        except Exception as err:
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            problems.append(f"--provider {spec}: importing it failed: {type(err).__name__}: {err}")
            found.append(unavailable(spec, err))
    return found, problems


def check_resources(plants, settings: dict) -> None:
    """Refuse, before any work, settings whose Monte Carlo would hold more memory than allowed
    (`models.checks.ResourceLimitError` naming the samples and the limit)."""
    keys = ("scenarios", "mc", "seed")
    chosen: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in settings.items() if k in keys}
    options = runner.Options(**chosen)
    for name in plants:
        study = cases.get(name)
        runner.check_resources(study, options, models.get(study.plant).n_params)


def _run_sweep(args, p: argparse.ArgumentParser, plants, settings: dict, chosen: list, stream) -> int:
    """``--sweep PARAM=LOW:HIGH:N``: every controller of the one plant over the grid, into OUT/PLANT/sweep.*;
    returns the exit status (exit 2 through `p` for a bad sweep)."""
    if len(plants) != 1:
        p.error(f"--sweep runs one plant; name exactly one, got {len(plants)}")
    try:
        grid = sweep.Grid.parse(args.sweep)
    except ValueError as err:  # a ResourceLimitError too: too many points for memory
        p.error(f"--sweep: {err}")
    scenario = settings["scenarios"] or ["step"]
    if len(scenario) != 1 or scenario[0] == "mc":
        p.error(f"--sweep runs one scenario other than mc; got {', '.join(scenario)}")
    name = plants[0]
    plant = models.get(name)
    if grid.param not in plant.params:
        p.error(f"{name} has no parameter {grid.param!r}; its parameters are {', '.join(plant.params)}")
    try:
        sweep.grid_params(plant, grid)  # every value the plant accepts, before the run starts
        estimate = sweep.check_time(cases.get(name), grid, scenario[0], accept=args.long)
    except ValueError as err:
        p.error(f"--sweep: {err}")
    print(
        f"{name}: sweep of {len(grid.values)} points, estimated {sweep.format_duration(estimate)} of runs", file=stream
    )
    options = runner.Options(seed=settings["seed"], strict=settings["strict"], threads=2, without=settings["without"])
    stop_on_signals()
    study = cases.get(name)
    progress = Progress({name: len(study.controllers)}, stream, disable=args.quiet)
    started = time.perf_counter()
    try:
        with distributed.connect(args.scheduler, args.workers) as executor:
            table, notes = sweep.run_sweep(
                study,
                grid,
                scenario=scenario[0],
                options=options,
                providers=list(study.providers) + chosen,
                executor=executor,
                progress=lambda done, total, text: progress.update(name, done, total, text),
            )
    except Exception as err:
        progress.close()
        print(f"python -m studies: the sweep failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    progress.close()
    sweep.write_sweep(study, grid, table, args.out, notes, scenario[0])
    lines = [
        f"{name}: {table.controller.nunique()} controllers x {len(grid.values)} values of {grid.param} "
        f"({grid.values[0]:g} to {grid.values[-1]:g}), scenario {scenario[0]}",
        *sweep.sweep_summary(table, grid),
    ]
    lines += [f"  note: {n}" for n in notes if args.verbose or "failed" in n]
    folder = os.path.join(args.out, name)
    lines.append(
        f"open {os.path.join(folder, 'sweep.png')} (cost and verdict against {grid.param}), "
        f"{os.path.join(folder, 'sweep.md')} and sweep.csv; {time.perf_counter() - started:.1f} s"
    )
    print("\n".join(lines))
    return 0


def _checked_plants(p: argparse.ArgumentParser, args) -> tuple[list, list | None]:
    """(plants, scenarios) the command line asks for (exit 2 through `p` for what is not allowed)."""
    registered = list(cases.names())
    plants = args.plants or list(registered)
    unknown = [name for name in plants if name not in registered]
    if unknown:
        p.error(f"unknown plant {unknown[0]!r}; valid plants: {', '.join(registered)}")
    plants = list(dict.fromkeys(plants))
    scenarios = _scenarios(args.scenario, p)
    for spec in args.provider:
        if spec.count(":") != 1 or not all(part.strip() for part in spec.split(":")):
            p.error(f"--provider needs MODULE:FUNCTION, got {spec!r}")
    if args.jobs < 1:
        p.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.workers is not None and args.workers < 1:
        p.error(f"--workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler:
        p.error("give --workers (a local Dask cluster) or --scheduler (an existing one), not both")
    return plants, scenarios


def main(argv=None) -> int:
    """``python -m studies [PLANT ...] [options]``; returns the exit status (see the module's docstring)."""
    p = parser()
    args = p.parse_args(argv)
    plants, scenarios = _checked_plants(p, args)
    if args.list:
        print(_list(plants, args.provider))
        return 0
    try:  # an empty label is refused here, before any work, as the run's Options would refuse it
        args.without = without_labels(args.without, "--without")
    except ValueError as err:
        p.error(str(err))
    defaults = dict(QUICK if args.quick else FULL)
    dask = args.workers is not None or bool(args.scheduler)
    jobs = 1 if dask else min(args.jobs, len(plants))
    settings = {
        "scenarios": scenarios,
        "mc": defaults["mc"] if args.mc is None else args.mc,
        "seed": args.seed,
        "quick": args.quick,
        "strict": args.strict,
        "threads": max(1, 2 // jobs),
        "without": args.without,
    }
    try:
        check_resources(plants, settings)
    except checks.ResourceLimitError as err:
        p.error(f"--mc {settings['mc']}: {err}")
    chosen, missing = command_line_providers(args.provider)
    for message in missing:
        print(f"python -m studies: {message}" + ("" if args.strict else "; running without it"), file=sys.stderr)
    if missing and args.strict:
        print("python -m studies: --strict: not running with a missing provider", file=sys.stderr)
        return 1
    try:
        files.check_writable(args.out)
        writers.check_output_folder(args.out, plants)  # a plant folder that is not ours: before any work
    except OSError as err:
        p.error(f"{type(err).__name__}: {err}" if isinstance(err, writers.ForeignFolderError) else str(err))
    if args.sweep:
        return _run_sweep(args, p, plants, settings, chosen, sys.stderr)
    where = (
        f"on Dask ({args.scheduler or f'{args.workers} local workers'})"
        if dask
        else f"with {jobs} job{'s' if jobs > 1 else ''}"
    )
    return _run(args, plants, settings, chosen, missing, jobs, where)


_hung_up = False


def _hang_up(signum, frame) -> None:
    """SIGHUP handler: remember it, then do what SIGTERM's handler does (stop as on Ctrl-C)."""
    global _hung_up
    _hung_up = True
    handler = signal.getsignal(signal.SIGTERM)
    if callable(handler):
        handler(signal.SIGTERM, frame)
    else:
        raise KeyboardInterrupt


def stop_on_signals() -> None:
    """SIGTERM (kill, a scheduler) and SIGHUP (a closed terminal) stop a run as Ctrl-C does, workers
    included; `interrupted_status` then tells them apart. Only where SIGHUP has its default action."""
    interrupts.watch()
    if interrupts.terminate_as_interrupt() and signal.getsignal(signal.SIGHUP) in (signal.SIG_DFL, _hang_up):
        signal.signal(signal.SIGHUP, _hang_up)


def interrupted_status() -> int:
    """The exit status of an interrupted run: 129 after a SIGHUP, 143 after a SIGTERM, else 130 (Ctrl-C)."""
    return 129 if _hung_up else 143 if interrupts.terminated() else 130


def _run(args, plants: list, settings: dict, chosen: list, missing: list, jobs: int, where: str) -> int:
    """Run the plants into a staging folder, publish it into OUT when every plant is done, and print the
    closing lines; returns the exit status (1 failed, 129/130/143 interrupted, 1 with --strict and a row not ok)."""
    registered = list(cases.names())
    per_plant = {name: settings | {"providers": list(cases.get(name).providers) + chosen} for name in plants}
    started = time.perf_counter()
    run_id = writers.new_run_id()
    staging = writers.new_staging(args.out, run_id)
    progress = Progress(progress_slots(plants, settings["scenarios"], settings), disable=args.quiet)
    stop_on_signals()
    signals_before = interrupts.received()
    published = False
    try:
        with distributed.connect(args.scheduler, args.workers, jobs) as executor:
            finished = batch.run_plants(
                plants,
                per_plant,
                str(staging),
                args.answers or args.verbose,
                executor,
                progress.update,
                run_id,
                longest_first=RUN_SECONDS,
            )
        progress.close()
        if interrupts.received() > signals_before:  # a KeyboardInterrupt Python ignored in a callback
            raise KeyboardInterrupt
        with interrupts.deferred():  # every plant of the run and its summary, or none: Ctrl-C waits
            writers.publish(staging, args.out, registered, run_id)
            published = True
    except Exception as err:
        progress.close()
        if not interrupts.is_interrupt(err):  # an interrupt CasADi reported as an error is handled below
            print(
                f"python -m studies: failed: {type(err).__name__}: {err}; nothing of this run was written to "
                f"{args.out}",
                file=sys.stderr,
            )
            return 2 if isinstance(err, writers.ForeignFolderError) else 1  # a folder that is not ours: exit 2
        interrupted = True
    except KeyboardInterrupt:
        progress.close()
        interrupted = True
    else:
        interrupted = False
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    if interrupted:
        print(
            "python -m studies: interrupted"
            + (
                f"; run {run_id} was complete and is in {args.out}"
                if published
                else f"; nothing of this run was written to {args.out}"
            ),
            file=sys.stderr,
        )
        return interrupted_status()
    finished = sorted(finished, key=lambda d: registered.index(d["name"]))
    return _closing(args, finished, missing, f"total {time.perf_counter() - started:.1f} s {where}; run {run_id}")


def _closing(args, finished: list, missing: list, total: str) -> int:
    """Print the answers asked for and the closing lines of a finished run; the exit status."""
    for done in finished:
        if done["answers"]:
            print(done["answers"], flush=True)
    lines = closing_lines(finished, args.out, args.verbose)
    lines.append(total)
    if missing:
        lines.append(f"python -m studies: ran without {len(missing)} missing provider(s): " + "; ".join(missing))
    for label in args.without:
        if not any(label in done["left_out"] for done in finished):
            lines.append(f"python -m studies: --without {label!r} matched no controller of the plants run")
    not_ok = sum(done["not_ok_rows"] for done in finished)
    if args.strict and not_ok:
        lines.append(f"python -m studies: --strict: {not_ok} row(s) not ok (listed above)")
    print("\n".join(lines), flush=True)
    return 1 if args.strict and not_ok else 0
