"""python -m studies: every controller on every plant, in tables, plots and animations.

Runs every registered case study (or the plants named), prints each study's homework
answers and errata, and writes OUT/<plant>/ (tables, answers, plots,
animations), OUT/summary.md and OUT/index.html. Every plant folder is written
aside and moved into OUT when the whole run succeeded: an interrupted or
failed run leaves OUT as it was. Exit status 2 on bad arguments, 1 when a run
fails (or, with --strict, when a provider is missing or a row is not ok), 130
when interrupted (Ctrl-C), 0 otherwise.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
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


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"the seed must be a whole number >= 0, got {value}")
    return value


def _folder(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a folder name, got {text!r} (use . for this folder)")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"a folder name cannot contain a NUL character, got {text!r}")
    return text


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
    p.add_argument("--seed", type=_seed, default=0,
                   help="seed of the parameter samples and the noise, a whole number >= 0 (default 0)")
    p.add_argument("--out", type=_folder, default="results", metavar="DIR",
                   help="output folder (default results/)")
    p.add_argument("--quick", action="store_true",
                   help=f"{QUICK['mc']} Monte Carlo samples, lighter plots and animations")
    p.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="run N plants at once in separate processes (default 2, one per core here; 1 runs "
                        "everything in this process)")
    p.add_argument("--list", action="store_true", help="list plants, scenarios and controllers, run nothing")
    p.add_argument("--provider", action="append", default=[], metavar="MODULE:FUNCTION",
                   help="add a controller provider: FUNCTION(plant, known=Plant) -> {label: controller}")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 on a missing or failing provider (before running), on a controller error, and "
                        "when any row is not ok (degraded, diverged, failed or skipped)")
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
    if not names:
        p.error(f"--scenario names no scenario; valid scenarios: {', '.join(SCENARIO_NAMES)}")
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


def _run_plant(name: str, settings: dict, out: str, quiet: bool, queue=None, run_id: str | None = None) -> dict:
    """Run and write one study; returns what the command prints (picklable, for --jobs)."""
    from . import run_study
    from .answers import format_answers
    from .writers import not_ok_rows, status_counts

    study = get(name)
    progress = None if queue is None else (lambda done, total, text: queue.put((name, done, total, text)))
    result = run_study(study, out=out, progress=progress, run_id=run_id, **settings)
    return {"name": name, "answers": None if quiet else format_answers(study, result.answers, result.plant.title),
            "controllers": len(result.controllers), "rows": len(result.table), "timing": result.timing,
            "notes": list(result.notes), "status": status_counts(result.table),
            "not_ok": not_ok_rows(result.table)}


def _report(done: dict, out: str) -> None:
    timing = done["timing"]
    print(f"{done['name']}: {done['controllers']} controllers, {done['rows']} rows; simulations "
          f"{timing['total_s']:.1f} s, files {timing.get('files_s', float('nan')):.1f} s "
          f"-> {os.path.join(out, done['name'], 'table.md')}", file=sys.stderr)
    _report_status(done)
    for note in done["notes"]:
        print(f"  note: {note}", file=sys.stderr)


def _report_status(done: dict) -> None:
    """The count of each row status, and every row that is not ok (skipped rows grouped by reason)."""
    print("  rows: " + ", ".join(f"{n} {kind}" for kind, n in done["status"].items() if n), file=sys.stderr)
    skipped: dict = {}
    for controller, scenario, status in done["not_ok"]:
        if status.startswith("skipped"):
            skipped.setdefault(status, []).append(f"{controller} / {scenario}")
        else:
            print(f"  {status.split(':')[0].split()[0].upper()}: {controller} / {scenario}: {status}", file=sys.stderr)
    for status, where in skipped.items():
        print(f"  SKIPPED {len(where)}: {status.partition(': ')[2]} ({', '.join(where)})", file=sys.stderr)


@contextlib.contextmanager
def _stop_workers_on_error():
    """On any exception (Ctrl-C included) end the worker processes now, so leaving the process pool
    does not wait for their plants to finish; their partial files are in the run's staging folder."""
    try:
        yield
    except BaseException:
        import multiprocessing

        children = multiprocessing.active_children()
        for child in children:
            child.terminate()
        for child in children:
            child.join(10)
        raise


def check_providers(specs) -> list:
    """One message per ``module:function`` provider that does not exist or fails to import."""
    from models import interrupts

    from .runner import ProviderNotFound, find_provider

    problems = []
    for spec in specs:
        try:
            find_provider(spec)
        except ProviderNotFound as err:
            problems.append(f"--provider {spec}: {str(err).split(': ', 1)[1]}")
        except Exception as err:
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            problems.append(f"--provider {spec}: importing it failed: {type(err).__name__}: {err}")
    return problems


def check_resources(plants, settings: dict) -> None:
    """Refuse, before any work, settings whose Monte Carlo would hold more memory than allowed
    (`models.checks.ResourceLimitError` naming the samples and the limit)."""
    import models

    from . import runner

    keys = ("scenarios", "mc", "seed")
    options = runner.Options(**{k: tuple(v) if isinstance(v, list) else v for k, v in settings.items() if k in keys})
    for name in plants:
        study = get(name)
        runner.check_resources(study, options, models.get(study.plant).n_params)


class _Inline:
    """A queue stand-in for running plants in this process: puts go straight to the progress bar."""

    def __init__(self, progress: Progress):
        self.progress = progress

    def put(self, item) -> None:
        self.progress.update(*item)


def _run_all(plants, settings: dict, providers: list, out: str, quiet: bool, jobs: int,
             run_id: str | None = None) -> list:
    progress = Progress(plants)
    # Parallel jobs take the plants last-registered first (the text's later plants, such as the crane, run
    # longest, so the jobs finish together); every order writes the same tables.
    order = list(reversed(plants))
    per_plant = {name: settings | {"providers": list(get(name).providers) + providers} for name in plants}
    finished = []
    try:
        if jobs == 1:
            for name in plants:
                finished.append(_run_plant(name, per_plant[name], out, quiet, _Inline(progress), run_id))
            return finished
        import concurrent.futures
        import multiprocessing
        import queue as queue_module

        context = multiprocessing.get_context("spawn")
        with context.Manager() as manager, \
                concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool, _stop_workers_on_error():
            messages = manager.Queue()
            pending = {pool.submit(_run_plant, name, per_plant[name], out, quiet, messages, run_id)
                       for name in order}
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
        if spec.count(":") != 1 or not all(part.strip() for part in spec.split(":")):
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

    from models import checks, files, interrupts

    from . import writers

    try:
        check_resources(plants, settings)
    except checks.ResourceLimitError as err:
        p.error(f"--mc {settings['mc']}: {err}")
    missing = check_providers(args.provider)
    for message in missing:
        print(f"python -m studies: {message}" + ("" if args.strict else "; running without it"), file=sys.stderr)
    if missing and args.strict:
        print("python -m studies: --strict: not running with a missing provider", file=sys.stderr)
        return 1
    try:
        files.check_writable(args.out)
    except OSError as err:
        p.error(str(err))
    started = time.perf_counter()
    run_id = writers.new_run_id()
    staging = writers.new_staging(args.out, run_id)
    interrupts.watch()
    published = False
    try:
        finished = _run_all(plants, settings, args.provider, str(staging), args.quiet, jobs, run_id)
        with interrupts.deferred():  # every plant of the run and its summary, or none: Ctrl-C waits
            writers.publish(staging, args.out, registered, run_id)
            published = True
    except Exception as err:
        if not interrupts.is_interrupt(err):  # an interrupt CasADi reported as an error is handled below
            print(f"python -m studies: failed: {type(err).__name__}: {err}; nothing of this run was written to "
                  f"{args.out}", file=sys.stderr)
            return 1
        interrupted = True
    except KeyboardInterrupt:
        interrupted = True
    else:
        interrupted = False
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    if interrupted:
        print("python -m studies: interrupted" + (f"; run {run_id} was complete and is in {args.out}" if published
              else f"; nothing of this run was written to {args.out}"), file=sys.stderr)
        return 130
    for done in sorted(finished, key=lambda d: registered.index(d["name"])):
        if done["answers"]:
            print(done["answers"], flush=True)
        _report(done, args.out)
    elapsed = time.perf_counter() - started
    print(f"wrote run {run_id}: {os.path.join(args.out, 'index.html')} and {os.path.join(args.out, 'summary.md')}; "
          f"total {elapsed:.1f} s with {jobs} job{'s' if jobs > 1 else ''}", file=sys.stderr)
    not_ok = sum(len(done["not_ok"]) for done in finished)
    if missing:
        print(f"python -m studies: ran without {len(missing)} missing provider(s): "
              + "; ".join(missing), file=sys.stderr)
    if args.strict and not_ok:
        print(f"python -m studies: --strict: {not_ok} row(s) not ok (listed above)", file=sys.stderr)
        return 1
    return 0
