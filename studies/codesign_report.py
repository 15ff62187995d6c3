"""The co-design report runner: every case's co-design problems, solved three ways, in one document.

Every problem is answered with `designs.codesign` and `designs.tuning` only
(IPOPT through the compiled nonlinear closed loop):

1. sequential (control-blind, as the co-design literature defines it): the
   plant from a plant-only objective (actuator sizing: the smallest limit that
   holds the target at rest; a plant parameter: its price alone), then the best
   controller for that plant (a converged tuning);
2. nested: an outer optimizer on the plant (actuator sizing: bisection on the
   limit, each limit decided by a converged feasibility search, the gains tuned
   once at the answer; a plant parameter: bounded Brent, each evaluation a
   converged tuning);
3. simultaneous: plant and gains in one IPOPT problem, started from a neutral
   point (the middle of the range, the hand design's gains) and from (1).

The report states the gain of the better simultaneous answer over the better
of (1) and (2) among the feasible ones, each answer's solver status, and the
wall times. The text's hand rule re-derived at each limit (the actuator
sizing of the text's procedure) is kept as a note.

The problems live in the case files (``CASE.codesign``: key -> function
returning a `CaseResult`), stated with `studies.codesign_problems`: actuator
sizing for the arm, UUV and ball on beam (`ActuatorSizing` + `actuator_sizing`),
the crane's cable length and the satellite's panel stiffness (`codesign_case`).
This module collects them from the case registry (`problems`).

``python -m studies.codesign_report [--out FILE | --write-docs] [--only KEY ...]`` runs them
(an hour or more on a shared core, most of it the nested method on the crane
and the satellite) and prints the Markdown report, or writes it to FILE, or with
--write-docs into docs/codesign.md and its records (never by default). The
document is built from sections (`SECTIONS`: header, table, notes), so other
co-design reports can be appended to it.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from designs.codesign import METHODS, SIZING_COST_WEIGHT, SIZING_TIE_BREAK
from models import files

from . import cases, distributed
from .codesign_problems import GLOBAL, CaseResult, Design, sweep_on

DOC = Path(__file__).resolve().parent.parent / "docs" / "codesign.md"


# ----------------------------------------------------------------- records on disk
#: The `Design` fields a record keeps: everything but the plant and controller objects.
RECORDED = ("method", "value", "objective", "closed_loop_cost", "plant_cost", "feasible", "violations",
            "measured", "wall_time", "message", "gains", "converged", "status")  # fmt: skip
#: The `CaseResult` fields a record keeps besides its designs.
RECORDED_CASE = ("key", "problem", "plant", "parameter", "unit", "text_value", "objective", "notes")


def to_record(result: CaseResult, run: dict, kept: dict | None = None) -> dict:
    """`result` as JSON-able data (what the report prints), each design with `run`: how, when and from
    which code it was solved. `kept`: an earlier record of the problem whose designs of methods not in
    `result` are kept, each with its own run."""
    designs = dict((kept or {}).get("designs", {}))
    designs |= {
        m: {name: getattr(d, name) for name in RECORDED} | {"run": dict(run)} for m, d in result.designs.items()
    }
    layer = (kept or {}).get("global_layer")
    if result.global_layer is not None:
        layer = result.global_layer | {"run": dict(run)}
    return {
        **{name: getattr(result, name) for name in RECORDED_CASE},
        "designs": {m: designs[m] for m in METHODS if m in designs},
        **({"global_layer": layer} if layer is not None else {}),
    }


def from_record(record: dict) -> CaseResult:
    """The `CaseResult` of a `to_record` record (plants, controllers and scenario left None), the
    runs its designs come from added to the notes."""
    numbers = ("value", "objective", "closed_loop_cost", "plant_cost", "wall_time")
    designs = {}
    for method, saved in record["designs"].items():
        fields: dict[str, Any] = {name: saved[name] for name in RECORDED}
        fields |= {name: float(saved[name]) for name in numbers}
        fields["measured"] = {k: float(v) for k, v in saved["measured"].items()}
        designs[method] = Design(**fields, plant=None, block=None)
    result = CaseResult(
        **{name: record[name] for name in RECORDED_CASE if name != "notes"},
        scenario=None,
        specs=None,
        cost=None,
        designs=designs,
        notes=list(record["notes"]),
        global_layer=record.get("global_layer"),
    )
    result.text_value = float(result.text_value)
    runs: dict[tuple, list] = {}
    for method, saved in record["designs"].items():
        runs.setdefault(tuple(saved["run"][k] for k in ("command", "date", "commit")), []).append(method)
    for (command, date, commit), methods in runs.items():
        result.notes.append(f"{', '.join(methods)}: run by `{command}` on {date} (commit {commit})")
    return result


def _provenance(command: str) -> dict:
    """The run's command, UTC date and git commit ("+ changes" when the tree differs from it), now."""

    def git(*args):
        done = subprocess.run(["git", *args], cwd=DOC.parent, capture_output=True, text=True, check=False)
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    if git("status", "--porcelain", "--untracked-files=no"):
        commit += " + changes"
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return {"command": command, "date": date, "commit": commit}


def problems() -> dict[str, Callable[[], CaseResult]]:
    """CLI key -> function running the problem, over the registered cases in their order."""
    found: dict[str, Callable[[], CaseResult]] = {}
    for name in cases.names():
        found |= dict(cases.get(name).codesign)
    return found


# ----------------------------------------------------------------- report
COLUMNS = (
    "problem",
    "designed parameter",
    "text",
    "(1) sequential",
    "(2) nested",
    "(3) simultaneous",
    "(3) from (1)",
    "gain of (3) over (1), (2)",
    "wall time (1) / (2) / (3) / (3) from (1) (s)",
    "all converged",
)

HEADER = """# Co-design: sequential, nested and simultaneous

Generated by `{command}` (do not edit by hand).

Each problem is solved with `designs.codesign` / `designs.tuning`, every method to
convergence (see each case's co-design problem in `studies/cases/<name>.py`):

1. **sequential**, control-blind as the co-design literature defines it: the plant from a
   plant-only objective (actuator sizing: the smallest limit that holds the target at rest;
   a plant parameter: its price alone), then the best controller for that plant;
2. **nested**: an outer optimizer on the plant (bisection on the limit; bounded Brent on a
   parameter), each of its evaluations a converged inner problem: a tuning of the gains
   (Brent), or, since actuator sizing minimizes the limit and only each limit's verdict
   matters, a feasibility search (gains meeting the specs found there, or a proof that none
   near the search's path do), the gains then tuned for ITAE once at the limit found;
3. **simultaneous**: plant and gains in one IPOPT problem, from a neutral start (the middle
   of the range, the hand design's gains) and, in "(3) from (1)", from the sequential answer
   (actuator sizing: the limit plus a tie-break of {tie_break:g} times the ITAE, scaled, as the objective,
   solved first with a tie-break of {weight:g} and then from that answer).

A solve that starts outside the specs first runs a phase one (minimize the largest relative
spec excess); one that converges with the specs still missed is a local proof of infeasibility.
A case may solve each tuning without its specs first (`relaxed`, the satellite's): an answer
that converges and meets them is a local minimum under them too, and is kept.

Columns:

- **designed parameter**: the plant parameter decided, with its unit; **text**: its value in the text.
- **(1) ... (3) from (1)**: each method's value of the parameter and, after "→", its objective.
  Actuator sizing: the smallest limit meeting the specs (the value itself); crane and
  satellite: ITAE of the tracked coordinate plus the plant's price (m s² for the crane, rad s²
  for the satellite). "(infeasible)" marks an answer that misses a spec (judged on a fresh
  evaluation of the exact loop).
- **gain of (3) over (1), (2)**: 1 − (better feasible simultaneous objective) / (better feasible
  objective of (1) and (2)); positive: simultaneous better.
- **wall time**: seconds per method on the machine that ran the command.
- **all converged**: every optimizer behind every answer stopped on its convergence test
  (IPOPT's tolerance with the smoothing continuation settled, or a proof that a limit, or the
  limits and gains near a simultaneous solve's path, cannot meet the specs: IPOPT's or the
  phase one's, the answer then marked "(infeasible)"; the bisection's or Brent's resolution),
  none at an iteration cap; a sizing's limit where gains meeting the specs were found is
  settled even when the ITAE tuning there stopped short (its status is still listed), and a
  simultaneous sizing's feasible limit within the bisection's resolution of the holding limit
  is settled by the bisection's own test (the smallest limit lies between the two); each
  answer's statuses are listed under Notes.
"""


def _number(value: float) -> str:
    return f"{value:.4g}"


def _percent(fraction: float) -> str:
    """One decimal, or two significant digits below 0.1 % (a tie shows its size, not "-0.0 %")."""
    return f"{100 * fraction:.1f} %" if abs(fraction) >= 1e-3 else f"{100 * fraction:.2g} %"


def _cell(design: Design | None) -> str:
    if design is None:
        return "—"
    return f"{_number(design.value)} → {_number(design.objective)}" + ("" if design.feasible else " (infeasible)")


def table(results: list[CaseResult]) -> str:
    """The Markdown table of `COLUMNS`, one row per result."""
    rows = []
    for r in results:
        d = r.designs
        gain = r.gain
        times = " / ".join(f"{d[m].wall_time:.0f}" if m in d else "—" for m in METHODS)
        cells = [
            r.problem,
            f"{r.parameter} ({r.unit})",
            _number(r.text_value),
            *(_cell(d.get(m)) for m in METHODS),
            "—" if gain is None else _percent(gain),
            times,
            "yes" if r.converged else "no",
        ]
        rows.append(dict(zip(COLUMNS, cells)))
    return files.markdown_table(rows, [(c, c, str) for c in COLUMNS], literal=False)


def notes(results: list[CaseResult]) -> str:
    """Each problem's notes, then one line per answer: its numbers, statuses and message."""
    parts = ["## Notes\n"]
    for r in results:
        parts.append(f"\n**{r.problem}** ({r.objective}):\n")
        for note in r.notes:
            parts.append(f"- {note}\n")
        for method in METHODS:
            d = r.designs.get(method)
            if d is None:
                continue
            m = d.measured
            extra = "".join(f", {k} {v:.3g}" for k, v in m.items() if k.startswith("max_abs_"))
            violated = "" if d.feasible else f"; violates {'; '.join(d.violations)}"
            parts.append(
                f"- {method}: {r.parameter} = {_number(d.value)} {r.unit}, "
                f"ITAE {_number(d.closed_loop_cost)}, rise time {m['rise_time_s']:.3g} s, "
                f"overshoot {100 * m['overshoot']:.2g} %, "
                f"peak |u| {_number(m['peak_input'])}{extra}{violated}; status: {d.status}; "
                f"{d.message}\n"
            )
    return "".join(parts)


#: A local answer whose objective is within this fraction of the global layer's best is that optimum.
SAME_OPTIMUM = 1e-6

GLOBAL_LAYER = """
## Local optima: the global layer

Every method above is local: the nested method's bounded Brent search and the simultaneous IPOPT solve
stop on the first local optimum of the plant parameter. `designs.codesign_global.codesign_globally` (over
`mpc.global_search.search`) sweeps the parameter first (a grid over its range, ends included, each point a
converged tuning from the block's own gains), then refines the sweep's best local minima with the
simultaneous method; its answer lists every distinct local optimum (parameter, objective, status), and
says converged only when the best of them converged. It is tested on a first-order loop with four known
local optima (tests/designs/test_codesign_global.py). `--methods global` runs it on the plant-parameter
problems (`studies.codesign_problems.GLOBAL_SAMPLES` points, the best `GLOBAL_KEEP` refined; `--workers N`
spreads the sweep over a Dask LocalCluster of N processes, with the same numbers), keeping the record's
local answers. The actuator sizings are bisections on a monotone feasibility, to which a sweep adds
nothing: they are not swept.

For each plant-parameter problem: the local optima the sweep found, the best, and how far each method's
feasible local answer is above it (relative objective; "already global" below {same:g}); a record whose
answers were already global keeps them.

{table}

A problem without a layer record has not been run under it. The crane's: its one timed tuning (the
layer's estimate) took 732 s on the shared 2-core machine at load 12, which puts the default sweep (12
points, 2 refinements) at an estimated 6.5 h, refused by `GLOBAL_MAX_SECONDS` (4 h); its local answers
agree on the range's end (ℓ = 5 m by nested, simultaneous and the start from (1)), and its open-loop
counterpart below is global.

The open-loop problems (docs/codesign_open_loop.md, `python -m studies.codesign_open_loop`) run under
the layer by default; for each, local optima found by the sweep (simultaneous / nested) and the plain
local answer's gap to the best:

| problem | local optima | plain answer's gap to the best | plain answer |
|---|---|---|---|
| spring-mass, largest displacement | 1 / 1 | < 1e-5 relative | already global |
| spring-mass, minimum-energy transfer (from k = 20 N/m) | 3 / 3 | 871 % / 871 % (k = 21.81, not 2.067 N/m) | local |
| UUV roll, centre-of-gravity offset | 1 / 1 | < 1e-6 relative | already global |
| crane, cable length | 1 / 1 | < 1e-7 relative | already global (the range's end) |
"""


def gap_text(objective: float, best: float) -> str:
    """A local answer's distance above the global layer's best: "already global", or a percentage."""
    gap = (objective - best) / abs(best)
    return "already global" if gap <= SAME_OPTIMUM else f"{_percent(gap)} above"


def global_table(results: list[CaseResult]) -> str:
    """One row per plant-parameter problem: the layer's sweep, its local optima, its best, each method's gap."""
    rows = []
    for r in results:
        layer = r.global_layer
        if layer is None:
            if not r.parameter.endswith(" limit"):  # an actuator sizing (a bisection) is not swept
                rows.append({"problem": r.problem, "sweep": "not run under the global layer (see below)"})
            continue
        best = layer["best"]
        optima = "; ".join(
            f"{_number(o['value'])} → {_number(o['objective'])}{'' if o['success'] else ' (not converged)'}"
            for o in layer["optima"]
        )
        gaps = "; ".join(
            f"{m}: {gap_text(d.objective, best['objective']) if d.feasible else 'infeasible'}"
            for m, d in r.designs.items()
        )
        rows.append(
            {
                "problem": f"{r.problem} ({r.parameter}, {r.unit})",
                "sweep": f"{layer['design']}; {layer['wall_time']:.0f} s",
                "local optima": f"{len(layer['optima'])}: {optima}",
                "best": f"{_number(best['value'])} → {_number(best['objective'])}"
                + ("" if layer["converged"] else " (not converged)"),
                "each method's answer": gaps or "—",
            }
        )
    columns = ("problem", "sweep", "local optima", "best", "each method's answer")
    cell = lambda value: "" if value is None else str(value)
    return files.markdown_table(rows, [(c, c, cell) for c in columns], literal=False) if rows else "(none)"


#: The document's sections in order: each a callable (results, command) -> Markdown.
SECTIONS = (
    lambda results, command: HEADER.format(command=command, weight=SIZING_COST_WEIGHT, tie_break=SIZING_TIE_BREAK),
    lambda results, command: "\n" + table(results) + "\n",
    lambda results, command: GLOBAL_LAYER.format(same=SAME_OPTIMUM, table=global_table(results)) + "\n",
    lambda results, command: notes(results),
)


def report(results: list[CaseResult], command: str, sections=SECTIONS) -> str:
    """The whole Markdown document: the `sections` in order (header, table, notes by default)."""
    return "".join(section(results, command) for section in sections)


def _listed_methods(methods) -> str:
    return "" if methods is None else " --methods " + " ".join(f"'{m}'" if " " in m else m for m in methods)


def _solve(args, found: dict, keys: list, records: Path | None) -> list[CaseResult]:
    """Each problem of `keys` solved (or, with --reuse, read), its record written as soon as it is solved."""
    results = []
    for i, key in enumerate(keys, 1):
        saved = records / f"{key}.json" if records is not None else None
        earlier = json.loads(saved.read_text()) if saved is not None and saved.exists() else None
        if args.reuse and earlier is not None:
            results.append(from_record(earlier))
            print(f"[{i}/{len(keys)}] {key}: read {saved}", flush=True)
            continue
        print(f"[{i}/{len(keys)}] {key} ...", flush=True)
        # Taken before solving: the code that runs is the one checked out now.
        run = _provenance(f"python -m studies.codesign_report --only {key}" + _listed_methods(args.methods))
        started = time.perf_counter()
        r = found[key](**({} if args.methods is None else {"methods": tuple(args.methods)}))
        values = ", ".join(f"{m} {_number(d.value)}" for m, d in r.designs.items())
        print(f"{values} {r.unit} ({time.perf_counter() - started:.0f} s; record {saved})", flush=True)
        record = to_record(r, run, earlier if args.methods else None)
        if saved is not None:
            files.write_json(saved, record)
        results.append(from_record(record) if args.methods else r)
    return results


def main(argv=None) -> int:
    """``python -m studies.codesign_report``: solve (or read) each problem, save its record, write the document;
    1 unless every problem converged."""
    found = problems()
    parser = argparse.ArgumentParser(prog="python -m studies.codesign_report", description=__doc__.split("\n")[0])
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--out", type=Path, help="Markdown file to write (default: the report on stdout)")
    where.add_argument("--write-docs", action="store_true", help=f"write the report and records into {DOC}")
    parser.add_argument("--only", nargs="+", choices=list(found), help="run only these problems")
    parser.add_argument(
        "--records",
        type=Path,
        help="folder of each problem's record, KEY.json, written as soon as the problem is solved "
        "(default: beside the document, its name without .md; with neither --out nor --write-docs none is written)",
    )
    parser.add_argument(
        "--reuse", action="store_true", help="read the problems that have a record instead of solving them again"
    )
    parser.add_argument(
        "--methods",
        nargs="+",
        choices=(*METHODS, GLOBAL),
        help="solve only these methods; the problem's record keeps its other methods' designs",
    )
    parser.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="run the global layer's sweep (--methods global) on a Dask LocalCluster of N worker processes "
        "(studies.distributed; the same numbers as in one process)",
    )
    args = parser.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        parser.error(f"--workers must be a whole number >= 1, got {args.workers}")
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout)
    keys = args.only or list(found)
    out = DOC if args.write_docs else args.out
    records = args.records or (out.with_suffix("") if out is not None else None)
    command = "python -m studies.codesign_report" + ("" if args.only is None else " --only " + " ".join(keys))
    if args.workers is None:
        results = _solve(args, found, keys, records)
    else:
        with distributed.connect(None, args.workers) as executor, sweep_on(executor.map):
            results = _solve(args, found, keys, records)
    text = report(results, command + (" --reuse" if args.reuse else ""))
    if out is None:
        print(text)
    else:
        print(table(results))
        files.write_text(out, text)
        print(f"wrote {out}")
    return 0 if all(r.converged for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
