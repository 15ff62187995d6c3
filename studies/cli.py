"""python -m studies: every controller on every plant, in tables, plots and animations.

Runs every registered case study (or the plants named), prints each study's homework
answers and errata, and writes OUT/<plant>/ (tables, answers, plots,
animations), OUT/summary.md and OUT/index.html. Exit status 2 on bad
arguments, 1 when a run fails, 0 otherwise.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from . import SCENARIO_NAMES, get, names

#: Defaults of a full run and of --quick: Monte Carlo samples of every controller (MPC included).
FULL = {"mc": 200}
QUICK = {"mc": 10}


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of samples, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"the number of samples must be >= 0, got {value}")
    return value


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m studies", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  python -m studies --quick\n  python -m studies arm --scenario step --mc 500 --out DIR\n"
               "  python -m studies --list")
    p.add_argument("plants", nargs="*", metavar="PLANT", help=f"plants to study (default all: {', '.join(names())})")
    p.add_argument("--scenario", action="append", metavar="NAME",
                   help=f"run only these scenarios (repeat or comma-separate): {', '.join(SCENARIO_NAMES)}")
    p.add_argument("--mc", type=_count, metavar="N",
                   help=f"Monte Carlo samples of every controller, MPC included (default {FULL['mc']}, "
                        f"--quick {QUICK['mc']}; 0 skips the Monte Carlo)")
    p.add_argument("--seed", type=int, default=0, help="seed of the parameter samples and the noise (default 0)")
    p.add_argument("--out", default="results", metavar="DIR", help="output folder (default results/)")
    p.add_argument("--quick", action="store_true",
                   help=f"{QUICK['mc']} Monte Carlo samples, lighter plots and animations")
    p.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="run N plants at once in separate processes (default 2, one per core here; 1 runs "
                        "everything in this process)")
    p.add_argument("--list", action="store_true", help="list plants, scenarios and controllers, run nothing")
    p.add_argument("--provider", action="append", default=[], metavar="MODULE:FUNCTION",
                   help="add a controller provider: FUNCTION(plant, known=Plant) -> {label: controller}")
    p.add_argument("--strict", action="store_true", help="fail on a provider or controller error instead of "
                                                         "noting it in the tables")
    p.add_argument("--quiet", action="store_true", help="do not print the homework answers (still written)")
    return p


class Progress:
    """One progress bar over every plant's simulations on a terminal; occasional lines otherwise (logs, CI).

    `update(plant, done, total, text)` is called after each simulation of a plant;
    the bar counts the simulations of the plants started so far.
    """

    def __init__(self, plants, stream=sys.stderr, width: int = 28, every: float = 10.0):
        self.plants, self.stream, self.width, self.every = list(plants), stream, width, every
        self.tty = stream.isatty()
        self.started = time.perf_counter()
        self.last = -float("inf")
        self.counts: dict = {}

    def update(self, plant: str, done: int, total: int, text: str) -> None:
        self.counts[plant] = (done, total)
        done_all = sum(d for d, _ in self.counts.values())
        total_all = sum(t for _, t in self.counts.values())
        finished = sum(d == t for d, t in self.counts.values())
        elapsed = time.perf_counter() - self.started
        head = f"{finished}/{len(self.plants)} plants, {done_all}/{total_all} runs, {elapsed:6.1f} s"
        if self.tty:
            filled = int(self.width * done_all / max(total_all, 1))
            line = f"\r[{'#' * filled}{'-' * (self.width - filled)}] {head}  {text}"
            self.stream.write(line[:150].ljust(110))
            self.stream.flush()
        elif elapsed - self.last >= self.every or done == total:
            self.last = elapsed
            self.stream.write(f"{head}: {text}\n")
            self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _scenarios(values, p: argparse.ArgumentParser):
    if not values:
        return None
    names = [n.strip() for v in values for n in v.split(",") if n.strip()]
    unknown = [n for n in names if n not in SCENARIO_NAMES]
    if unknown:
        p.error(f"unknown scenario {unknown[0]!r}; valid scenarios: {', '.join(SCENARIO_NAMES)}")
    return names


def _list(plants, providers) -> str:
    from .runner import design_controllers

    lines = ["plants: " + ", ".join(names()), "scenarios: " + ", ".join(SCENARIO_NAMES), ""]
    for name in plants:
        study = get(name)
        found, notes = design_controllers(study, study.known_plant(), list(study.providers) + providers)
        lines.append(f"{name}: {study.source}")
        lines.append("  scenarios: " + ", ".join(f"{s.name} ({s.title})" for s in study.scenarios))
        lines.append("  controllers: " + (", ".join(found) if found else "none available yet"))
        lines += [f"  note: {n}" for n in notes]
    return "\n".join(lines)


def _run_plant(name: str, settings: dict, out: str, quiet: bool, queue=None) -> dict:
    """Run and write one study; returns what the command prints (picklable, for --jobs)."""
    from . import run_study
    from .answers import format_answers

    study = get(name)
    progress = None if queue is None else (lambda done, total, text: queue.put((name, done, total, text)))
    result = run_study(study, out=out, progress=progress, **settings)
    return {"name": name, "answers": None if quiet else format_answers(study, result.answers, result.plant.title),
            "controllers": len(result.controllers), "rows": len(result.table), "timing": result.timing,
            "notes": list(result.notes)}


def _report(done: dict, out: str) -> None:
    timing = done["timing"]
    print(f"{done['name']}: {done['controllers']} controllers, {done['rows']} rows; simulations "
          f"{timing['total_s']:.1f} s, files {timing.get('files_s', float('nan')):.1f} s "
          f"-> {os.path.join(out, done['name'], 'table.md')}", file=sys.stderr)
    for note in done["notes"]:
        if not ("not importable yet" in note or "() yet" in note):
            print(f"  note: {note}", file=sys.stderr)


class _Inline:
    """A queue stand-in for running plants in this process: puts go straight to the progress bar."""

    def __init__(self, progress: Progress):
        self.progress = progress

    def put(self, item) -> None:
        self.progress.update(*item)


def _run_all(plants, settings: dict, providers: list, out: str, quiet: bool, jobs: int) -> list:
    progress = Progress(plants)
    # Parallel jobs take the plants last-registered first (the text's later plants, such as the crane, run
    # longest, so the jobs finish together); every order writes the same tables.
    order = list(reversed(plants))
    per_plant = {name: settings | {"providers": list(get(name).providers) + providers} for name in plants}
    finished = []
    try:
        if jobs == 1:
            for name in plants:
                finished.append(_run_plant(name, per_plant[name], out, quiet, _Inline(progress)))
            return finished
        import concurrent.futures
        import multiprocessing
        import queue as queue_module

        context = multiprocessing.get_context("spawn")
        with context.Manager() as manager, \
                concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
            messages = manager.Queue()
            pending = {pool.submit(_run_plant, name, per_plant[name], out, quiet, messages) for name in order}
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
    finally:
        progress.close()


def main(argv=None) -> int:
    p = parser()
    args = p.parse_args(argv)
    registered = names()
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
    if args.list:
        print(_list(plants, args.provider))
        return 0
    defaults = dict(QUICK if args.quick else FULL)
    jobs = min(args.jobs, len(plants))
    settings = {"scenarios": scenarios, "mc": defaults["mc"] if args.mc is None else args.mc,
                "seed": args.seed, "quick": args.quick, "strict": args.strict, "threads": max(1, 2 // jobs)}

    from models import files

    from . import writers

    try:
        files.check_writable(args.out)
    except OSError as err:
        p.error(str(err))
    started = time.perf_counter()
    try:
        finished = _run_all(plants, settings, args.provider, args.out, args.quiet, jobs)
    except Exception as err:
        print(f"python -m studies: failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    for done in sorted(finished, key=lambda d: registered.index(d["name"])):
        if done["answers"]:
            print(done["answers"], flush=True)
        _report(done, args.out)
    writers.write_summary(args.out, registered)
    writers.write_index(args.out, registered)
    elapsed = time.perf_counter() - started
    print(f"wrote {os.path.join(args.out, 'index.html')} and {os.path.join(args.out, 'summary.md')}; "
          f"total {elapsed:.1f} s with {jobs} job{'s' if jobs > 1 else ''}", file=sys.stderr)
    return 0
