"""python -m studies: every controller on every plant, in tables, plots and animations.

Runs every registered case study (or the plants named) and writes OUT/<plant>/
(tables with each row's verdict against the case's specs, answers, plots,
animations), OUT/summary.md and OUT/index.html. The console shows one progress
bar, then one line per plant, every row that is not ok or misses its specs,
and the files to open; homework answers go to OUT/<plant>/answers.md (printed
with --answers or -v). ``--sweep PARAM=LOW:HIGH:N`` runs every controller of
one plant over a grid of its true parameter instead. ``--workers N`` or
``--scheduler ADDRESS`` run the work on Dask (the same numbers). Exit status 2
on bad arguments, 1 when a run fails, 0 otherwise.
"""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
import time

from . import SCENARIO_NAMES, listing

#: Defaults of a full run and of --quick: Monte Carlo samples for blocks; for controllers simulated
#: step by step (MPC) the most samples, the most simulated steps of their Monte Carlo, and their scenarios.
FULL = {"mc": 200, "mc_python": 10, "mc_python_steps": 12_000, "python_scenarios": None, "python_budget": 30.0}
QUICK = {"mc": 10, "mc_python": 1, "mc_python_steps": 0, "python_scenarios": ("step",), "python_budget": 5.0}


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of samples, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"the number of samples must be >= 0, got {value}")
    return value


def _known_names() -> list:
    """The plants the command knows: the case files' (read without importing them), or the imported registry."""
    if "studies.cases" in sys.modules:
        from . import names

        return list(names())
    return list(listing.names())


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m studies", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  python -m studies --quick\n  python -m studies arm --scenario step --mc 500 --out DIR\n"
               "  python -m studies pendulum --sweep m2=0.5:2:8 --workers 2\n  python -m studies --list")
    p.add_argument("plants", nargs="*", metavar="PLANT",
                   help=f"plants to study (default all: {', '.join(_known_names())})")
    p.add_argument("--scenario", action="append", metavar="NAME",
                   help=f"run only these scenarios (repeat or comma-separate): {', '.join(SCENARIO_NAMES)}")
    p.add_argument("--mc", type=_count, metavar="N",
                   help=f"Monte Carlo samples for block controllers, one batched map (default {FULL['mc']}, "
                        f"--quick {QUICK['mc']}; 0 skips the Monte Carlo)")
    p.add_argument("--mc-python", type=_count, metavar="N",
                   help=f"Monte Carlo samples for controllers simulated step by step, such as MPC (default "
                        f"{FULL['mc_python']}, --quick {QUICK['mc_python']})")
    p.add_argument("--mpc-budget", type=float, metavar="SECONDS",
                   help="compute time each controller that optimizes every step may spend per plant; past it "
                        f"its remaining rows say so (default {FULL['python_budget']:g}, --quick "
                        f"{QUICK['python_budget']:g})")
    p.add_argument("--seed", type=int, default=0, help="seed of the parameter samples and the noise (default 0)")
    p.add_argument("--out", default="results", metavar="DIR", help="output folder (default results/)")
    p.add_argument("--quick", action="store_true",
                   help=f"{QUICK['mc']} Monte Carlo samples, only the step for controllers that optimize each step "
                        "(MPC), lighter plots and animations")
    p.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="run N plants at once in separate processes (default 2, one per core here; 1 runs "
                        "everything in this process)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="run on a Dask LocalCluster of N worker processes: the plants, or one plant's Monte Carlo "
                        "samples and sweep points (the same numbers as without Dask)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on the Dask cluster of this scheduler (tcp://host:8786); its workers must import "
                        "this package")
    p.add_argument("--sweep", metavar="PARAM=LOW:HIGH:N",
                   help="instead of the study: every controller of one plant on N values of its true parameter "
                        "PARAM from LOW to HIGH (writes OUT/PLANT/sweep.csv, sweep.png, sweep.md)")
    p.add_argument("--list", action="store_true",
                   help="list plants, scenarios and declared controllers (designs nothing, runs nothing)")
    p.add_argument("--provider", action="append", default=[], metavar="MODULE:FUNCTION",
                   help="add a controller provider: FUNCTION(plant, known=Plant) -> {label: controller}")
    p.add_argument("--strict", action="store_true", help="fail on a provider or controller error instead of "
                                                         "noting it in the tables")
    p.add_argument("--answers", action="store_true",
                   help="print the homework answers and errata (always written to OUT/<plant>/answers.md)")
    p.add_argument("-v", "--verbose", action="store_true", help="print the answers and every note as well")
    p.add_argument("--quiet", action="store_true", help="no progress bar: only the closing lines")
    return p


class Progress:
    """One tqdm bar over every plant's runs, its total fixed before the run starts.

    Each plant has a share of the total: its declared controllers times its scenarios (from the
    case files, `studies.listing`). `update(plant, done, total, text)` after each simulation moves
    the bar to the plant's share times done/total, so controllers a provider adds or lacks change
    the pace, never the total.
    """

    def __init__(self, slots: dict, stream=None, disable: bool = False):
        from tqdm import tqdm

        stream = stream or sys.stderr
        tty = stream.isatty()
        self.slots = dict(slots)
        self.done = dict.fromkeys(self.slots, 0.0)
        self.bar = tqdm(total=sum(self.slots.values()), unit="run", file=stream, disable=disable,
                        dynamic_ncols=True, mininterval=0.2 if tty else 20.0, ascii=not tty,
                        bar_format="{desc} {percentage:3.0f}%|{bar}| {n}/{total} runs [{elapsed}<{remaining}]"
                                   "{postfix}", desc=f"{len(self.slots)} plant{'s' * (len(self.slots) > 1)}")

    def update(self, plant: str, done: int, total: int, text: str) -> None:
        self.done[plant] = self.slots.get(plant, 0) * min(done, total) / max(total, 1)
        reached = int(round(sum(self.done.values())))
        self.bar.set_postfix_str(text[:50], refresh=False)
        if reached > self.bar.n:
            self.bar.update(reached - self.bar.n)

    def close(self) -> None:
        self.bar.close()


def progress_slots(plants, scenarios, settings: dict) -> dict:
    """plant -> runs it is expected to make: declared controllers x the scenarios it will run."""
    slots = {}
    for name in plants:
        listed = listing.get(name) if name in listing.names() else None
        declared = listed.scenarios if listed else SCENARIO_NAMES
        chosen = [s for s in declared if (scenarios is None or s in scenarios)
                  and not (s == "mc" and settings.get("mc") == 0)]
        slots[name] = max(1, len(chosen) * len(listed.controllers if listed else (1,)))
    return slots


def _scenarios(values, p: argparse.ArgumentParser):
    if not values:
        return None
    names = [n.strip() for v in values for n in v.split(",") if n.strip()]
    unknown = [n for n in names if n not in SCENARIO_NAMES]
    if unknown:
        p.error(f"unknown scenario {unknown[0]!r}; valid scenarios: {', '.join(SCENARIO_NAMES)}")
    return names


def _list(plants, providers) -> str:
    """Plants, scenarios and declared controllers, read from the case files (nothing designed or imported)."""
    lines = ["plants: " + ", ".join(_known_names()), "scenarios: " + ", ".join(SCENARIO_NAMES), ""]
    for name in plants:
        listed = listing.get(name)
        lines.append(f"{name}: {listed.source}")
        lines.append("  scenarios: " + ", ".join(listed.scenarios))
        lines.append("  controllers: " + ", ".join(listed.controllers))
        lines += [f"  + the controllers of {spec}, named when they are designed" for spec in providers]
    lines += ["", "Controllers are listed as each case declares them; a provider may lack some (the run notes "
                  "which) or add others."]
    return "\n".join(lines)


def _run_plant(name: str, settings: dict, out: str, answers: bool, queue=None, executor=None) -> dict:
    """Run and write one study; returns what the command prints (picklable, for --jobs and Dask)."""
    from . import get, run_study
    from .answers import format_answers
    from .writers import verdict_counts

    study = get(name)
    progress = None if queue is None else (lambda done, total, text: queue.put((name, done, total, text)))
    result = run_study(study, out=out, progress=progress, executor=executor, **settings)
    table = result.table
    return {"name": name, "answers": format_answers(study, result.answers, result.plant.title) if answers else None,
            "controllers": len(result.controllers), "rows": len(table), "timing": result.timing,
            "notes": list(result.notes), "best": result.best("step"), "counts": verdict_counts(table),
            "not_ok": not_ok_lines(table)}


def plant_task(task: tuple) -> tuple:
    """One plant on a Dask worker: run it into a private folder, return its report and its files as bytes.

    Nothing is written where the client can see it until every plant has come back (`install`).
    """
    import tempfile
    from pathlib import Path

    name, settings, answers = task
    with tempfile.TemporaryDirectory(prefix="studies-") as folder:
        report = _run_plant(name, settings, folder, answers)
        files = {str(path.relative_to(folder)): path.read_bytes()
                 for path in sorted(Path(folder).rglob("*")) if path.is_file()}
    return report, files


def install(out: str, files: dict) -> None:
    """Write the plants' folders {relative path: bytes} into `out`, each plant folder replaced as a whole."""
    import shutil
    import uuid
    from pathlib import Path

    from models.files import write_bytes

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


def not_ok_lines(table, width: int = 118) -> list:
    """Every row that is not ok or misses its specs, grouped: "  violates: PD, PID [all]; LQR [steps]".

    Grouped by verdict (or status, for a degraded row that meets its specs), then by the set of
    scenarios, so the list stays short while naming every (controller, scenario).
    """
    scenarios = list(dict.fromkeys(table.scenario))
    groups: dict = {}
    for row in table.to_dict("records"):
        verdict, status = str(row.get("verdict")), str(row.get("status"))
        if verdict == "meets specs" and status == "ok":
            continue
        key = verdict if verdict != "meets specs" else status.split(":")[0]
        groups.setdefault(key, {}).setdefault(row["controller"], []).append(row["scenario"])
    lines = []
    for key, by_controller in groups.items():
        by_set: dict = {}
        for controller, where in by_controller.items():
            tag = "all" if where == scenarios else ", ".join(where)
            by_set.setdefault(tag, []).append(controller)
        text = "; ".join(f"{', '.join(controllers)} [{tag}]" for tag, controllers in by_set.items())
        lines += textwrap.wrap(f"{key}: {text}", width, initial_indent="  ", subsequent_indent="      ")
    return lines


def _plant_line(done: dict) -> str:
    plural = {"meets specs": "meet specs", "violates": "violate"}
    counts = ", ".join(f"{n} {plural.get(label, label) if n > 1 else label}" for label, n in done["counts"].items()
                       if n)
    best = f"; best step ITAE: {done['best']}" if done.get("best") else ""
    return f"{done['name']}: {done['controllers']} controllers, {done['rows']} rows: {counts or 'no verdicts'}{best}"


def closing_lines(finished: list, out: str, verbose: bool = False) -> list:
    """What the run ends with: a line per plant, each followed by its rows that are not ok, and the paths."""
    lines = []
    for done in finished:
        lines.append(_plant_line(done))
        lines += done["not_ok"]
        failures = [n for n in done["notes"] if "failed" in n and not n.startswith("not provided")]
        lines += [f"  note: {n}" for n in (done["notes"] if verbose else failures)]
    lines.append(f"open {os.path.join(out, 'index.html')} (every plant at a glance) or "
                 f"{os.path.join(out, 'summary.md')}; {os.path.join(out, '<plant>', 'table.md')} says what each "
                 "row misses, and by how much")
    return lines


class _Inline:
    """A queue stand-in for running plants in this process: puts go straight to the progress bar."""

    def __init__(self, progress: Progress):
        self.progress = progress

    def put(self, item) -> None:
        self.progress.update(*item)


def _run_all(plants, settings: dict, providers: list, out: str, answers: bool, jobs: int, progress: Progress,
             executor=None) -> list:
    from . import get

    # Parallel jobs take the plants last-registered first (the text's later plants, such as the crane, run
    # longest, so the jobs finish together); every order writes the same tables.
    order = list(reversed(plants))
    per_plant = {name: settings | {"providers": list(get(name).providers) + providers} for name in plants}
    finished = []
    if executor is not None and executor.distributed and len(plants) > 1:
        import uuid

        from distributed import as_completed

        run = uuid.uuid4().hex[:8]
        futures = [executor.client.submit(plant_task, (name, per_plant[name], answers), pure=False,
                                          key=f"plant-{name}-{run}") for name in order]
        reports: list = []
        files: dict = {}
        try:
            for future in as_completed(futures):  # as they finish, so the bar moves
                report, written = _gather(future)
                reports.append(report)
                files |= written
                progress.update(report["name"], 1, 1, f"{report['name']} done")
        finally:
            executor.client.cancel(futures)
        install(out, files)
        return reports
    if jobs == 1 or (executor is not None and executor.distributed):
        for name in plants:
            finished.append(_run_plant(name, per_plant[name], out, answers, _Inline(progress), executor))
        return finished
    import concurrent.futures
    import multiprocessing
    import queue as queue_module

    context = multiprocessing.get_context("spawn")
    with context.Manager() as manager, concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
        messages = manager.Queue()
        pending = {pool.submit(_run_plant, name, per_plant[name], out, answers, messages) for name in order}
        while pending:
            try:
                progress.update(*messages.get(timeout=0.2))
            except queue_module.Empty:
                pass
            done = {f for f in pending if f.done()}
            for future in done:
                finished.append(future.result())
            pending -= done
        while not messages.empty():
            progress.update(*messages.get())
    return finished


def _gather(future):
    """A plant task's result, with a dead worker reported as `studies.distributed.RunFailed`."""
    from distributed import KilledWorker

    from .distributed import RunFailed

    try:
        return future.result()
    except KilledWorker as err:
        raise RunFailed(f"{future.key}: a Dask worker died while running it and the scheduler gave up after "
                        f"retrying ({err}); nothing was written") from None


def _run_sweep(args, p, plants, settings, progress_stream) -> int:
    from . import get, runner
    from .distributed import connect
    from .sweep import Grid, run_sweep, sweep_summary, write_sweep

    if len(plants) != 1:
        p.error(f"--sweep runs one plant; name exactly one, got {len(plants)}")
    try:
        grid = Grid.parse(args.sweep)
    except ValueError as err:
        p.error(str(err))
    scenario = (settings["scenarios"] or ["step"])
    if len(scenario) != 1 or scenario[0] == "mc":
        p.error(f"--sweep runs one scenario other than mc; got {', '.join(scenario)}")
    import models

    name = plants[0]
    plant = models.get(name)
    if grid.param not in plant.params:
        p.error(f"{name} has no parameter {grid.param!r}; its parameters are {', '.join(plant.params)}")
    options = runner.Options(seed=settings["seed"], python_budget=settings["python_budget"], strict=settings["strict"],
                             threads=2)
    study = get(name)
    progress = Progress({name: len(listing.get(name).controllers)}, progress_stream, disable=args.quiet)
    started = time.perf_counter()
    try:
        with connect(args.scheduler, args.workers) as executor:
            table, notes = run_sweep(study, grid, scenario=scenario[0], options=options,
                                     providers=list(study.providers) + args.provider, executor=executor,
                                     progress=lambda done, total, text: progress.update(name, done, total, text))
    except Exception as err:
        progress.close()
        print(f"python -m studies: the sweep failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    progress.close()
    write_sweep(study, grid, table, args.out, notes, scenario[0])
    lines = [f"{name}: {table.controller.nunique()} controllers x {len(grid.values)} values of {grid.param} "
             f"({grid.values[0]:g} to {grid.values[-1]:g}), scenario {scenario[0]}", *sweep_summary(table, grid)]
    lines += [f"  note: {n}" for n in notes if args.verbose or "failed" in n]
    folder = os.path.join(args.out, name)
    lines.append(f"open {os.path.join(folder, 'sweep.png')} (cost and verdict against {grid.param}), "
                 f"{os.path.join(folder, 'sweep.md')} and sweep.csv; {time.perf_counter() - started:.1f} s")
    print("\n".join(lines))
    return 0


def main(argv=None) -> int:
    p = parser()
    args = p.parse_args(argv)
    registered = _known_names()
    plants = args.plants or list(registered)
    unknown = [name for name in plants if name not in registered]
    if unknown:
        p.error(f"unknown plant {unknown[0]!r}; valid plants: {', '.join(registered)}")
    plants = list(dict.fromkeys(plants))
    scenarios = _scenarios(args.scenario, p)
    for spec in args.provider:
        if spec.count(":") != 1 or not all(spec.split(":")):
            p.error(f"--provider needs MODULE:FUNCTION, got {spec!r}")
    if args.jobs < 1:
        p.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.workers is not None and args.workers < 1:
        p.error(f"--workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler:
        p.error("give --workers (a local Dask cluster) or --scheduler (an existing one), not both")
    if args.mpc_budget is not None and not args.mpc_budget > 0:
        p.error(f"--mpc-budget must be > 0 seconds, got {args.mpc_budget}")
    if args.list:
        print(_list(plants, args.provider))
        return 0
    defaults = dict(QUICK if args.quick else FULL)
    dask = args.workers is not None or bool(args.scheduler)
    jobs = 1 if dask else min(args.jobs, len(plants))
    settings = {"scenarios": scenarios, "mc": defaults["mc"] if args.mc is None else args.mc,
                "mc_python": defaults["mc_python"] if args.mc_python is None else args.mc_python,
                "mc_python_steps": defaults["mc_python_steps"], "python_scenarios": defaults["python_scenarios"],
                "python_budget": defaults["python_budget"] if args.mpc_budget is None else args.mpc_budget,
                "seed": args.seed, "quick": args.quick, "strict": args.strict, "threads": max(1, 2 // jobs)}
    if args.mc_python is not None:
        settings["mc_python_steps"] = 10**9  # an explicit --mc-python is not capped by simulated steps

    from models import files

    try:
        files.check_writable(args.out)
    except OSError as err:
        p.error(str(err))
    if args.sweep:
        return _run_sweep(args, p, plants, settings, sys.stderr)

    from . import writers
    from .distributed import connect

    answers = args.answers or args.verbose
    started = time.perf_counter()
    progress = Progress(progress_slots(plants, scenarios, settings), disable=args.quiet)
    try:
        with connect(args.scheduler, args.workers) as executor:
            finished = _run_all(plants, settings, args.provider, args.out, answers, jobs, progress, executor)
    except Exception as err:
        progress.close()
        print(f"python -m studies: failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    progress.close()
    finished = sorted(finished, key=lambda d: registered.index(d["name"]))
    for done in finished:
        if done["answers"]:
            print(done["answers"], flush=True)
    writers.write_summary(args.out, registered)
    writers.write_index(args.out, registered)
    where = (f"on Dask ({args.scheduler or f'{args.workers} local workers'})" if dask
             else f"with {jobs} job{'s' if jobs > 1 else ''}")
    lines = closing_lines(finished, args.out, args.verbose)
    lines.append(f"total {time.perf_counter() - started:.1f} s {where}")
    print("\n".join(lines), flush=True)
    return 0
