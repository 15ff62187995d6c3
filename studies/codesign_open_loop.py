"""Open-loop co-design: plant parameters decided together with the input history, simultaneous and nested.

Each problem is an `mpc.OptimalControlProblem` with chosen plant parameters
(`ocp.choose`), declared as data (`OpenLoopCodesign`, `studies.trajectories`): the
spring-mass problems of `studies.codesign_problems` (a user's plant, no case study) and each case's own
(``CaseStudy.open_loop_codesign``: the crane's cable length, the UUV's
centre-of-gravity offset). `solve` decides every problem twice, to convergence:

* simultaneous: the parameters in the decision vector of the same transcription,
  one IPOPT solve;
* nested: `mpc.solve_nested`, SciPy's L-BFGS-B on the parameters around the OCP
  (re-solved warm; gradient by the envelope theorem);

then tabulates the optimal value J*(p) at a few parameter values with the
parameter fixed (`sweep`), verifies the answers (`OCPSolution.verify`), and
`report` returns the Markdown of docs/codesign_open_loop.md:

    python -m studies.codesign_open_loop [--quick] [--samples N] [--out FILE | --write-docs]

Every problem is also decided under the global layer (`mpc.global_search.codesign`: a coarse sweep of the
parameter, then local refinement from the sweep's best local minima), and the report lists every distinct
local optimum it found and how far each method's plain local answer is from the best.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from models import files
from models.files import format_number, markdown_table
from mpc import global_search, solve_nested

from . import cases
from .codesign_problems import (
    SPRING_MASS_PROBLEM,
    SPRING_TRANSFER_PROBLEM,
)
from .trajectories import OpenLoopCodesign, TrajectorySetup, describe

DOC = Path(__file__).resolve().parent.parent / "docs" / "codesign_open_loop.md"


def problems() -> list[OpenLoopCodesign]:
    """The spring-mass problems, then every registered case's, in the text's order."""
    found = [SPRING_MASS_PROBLEM, SPRING_TRANSFER_PROBLEM]
    for name in cases.names():
        found += list(cases.get(name).open_loop_codesign)
    return found


# ---------------------------------------------------------------------------- solving
@dataclass
class Decision:
    """One method's answer: the parameter, the objective as reported (the value when maximized), convergence."""

    method: str
    parameter: float
    objective: float
    success: bool
    status: str
    iterations: str
    wall_time: float
    defect: float
    final_time: float
    gradient: float = math.nan


@dataclass
class CodesignResult:
    """A problem decided both ways, with its sweep of J*(p) and the independent answer if any."""

    problem: OpenLoopCodesign
    setup: TrajectorySetup
    simultaneous: Decision
    nested: Decision
    sweep: list = field(default_factory=list)
    reference: dict | None = None
    at_text: dict | None = None
    global_answers: dict = field(default_factory=dict)

    @property
    def agree(self) -> tuple[float, float]:
        """(|Δp|, |ΔJ| / max(1, |J|)) between the two methods."""
        s, n = self.simultaneous, self.nested
        return abs(s.parameter - n.parameter), abs(s.objective - n.objective) / max(1.0, abs(s.objective))

    def global_gap(self, method: str) -> tuple[float, float]:
        """(|ΔJ|, relative |ΔJ|) of `method`'s plain local answer from its global layer's best (as reported)."""
        local = self.simultaneous if method == "simultaneous" else self.nested
        best = (-1.0 if self.problem.maximized else 1.0) * self.global_answers[method].best.objective
        difference = abs(local.objective - best)
        return difference, difference / max(abs(best), 1e-300)


def envelope_gradient(solution, name: str) -> float:
    """dJ*/dp of a solve with p as an NLP parameter (`chosen_as_parameters`): −λ_p, the envelope theorem."""
    tr = solution.transcription
    position = tr.parameter_slices["plant"].start + tr.fixed_param_names.index(name)
    return float(-solution.lam_p[position])


def decide_simultaneous(problem: OpenLoopCodesign, setup: TrajectorySetup, sign: float) -> Decision:
    """The parameter a decision of the transcription itself: one IPOPT solve of `setup`, then `verify()`.

    sign : −1 when the problem maximizes (its OCP objective is the negative of the reported value), else 1
    """
    options = dict(setup.solve_options)
    started = time.perf_counter()
    solution = setup.problem.solve(setup.transcription, **options)
    verification = solution.verify() if solution.success else None
    return Decision(
        "simultaneous",
        solution.chosen.get(problem.parameter, math.nan),
        sign * solution.objective,
        solution.success,
        solution.status,
        f"{solution.iterations} IPOPT",
        time.perf_counter() - started,
        verification.max_interval_defect if verification else math.nan,
        solution.final_time,
    )


def decide_nested(problem: OpenLoopCodesign, setup: TrajectorySetup, sign: float) -> tuple[Decision, Any]:
    """`mpc.solve_nested` on `setup`: L-BFGS-B on the parameter around the OCP with it fixed.

    Returns the decision (with dJ*/dp by the envelope theorem at the answer) and the last inner
    `OCPSolution`, the starting point of the sweep.
    """
    started = time.perf_counter()
    nested_result = solve_nested(setup.problem, setup.transcription, **dict(setup.solve_options))
    inner = nested_result.solution
    verification = inner.verify() if nested_result.success else None
    decision = Decision(
        "nested",
        nested_result.params[problem.parameter],
        sign * nested_result.objective,
        nested_result.success,
        nested_result.outer_status,
        f"{nested_result.outer_iterations} L-BFGS-B, {nested_result.inner_solves} IPOPT solves",
        time.perf_counter() - started,
        verification.max_interval_defect if verification else math.nan,
        inner.final_time,
        sign * envelope_gradient(inner, problem.parameter),
    )
    return decision, inner


def sweep_optimum(
    problem: OpenLoopCodesign, setup: TrajectorySetup, guess, sign: float
) -> tuple[list[dict], dict | None]:
    """J*(p) with p fixed at each of `problem.sweep` and at the text's value, solved warm from `guess`.

    Returns (the sweep's rows, the row at the text's value or None); a row is {"parameter", "objective"
    (as reported), "success", "final_time" (s), "gradient" (dJ*/dp, per unit of p)}.
    """
    rows, at_text = [], None
    values = list(problem.sweep) + ([problem.text_value] if problem.text_value is not None else [])
    if values:
        solver = setup.problem.solver(setup.transcription, chosen_as_parameters=True, tolerance=1e-10)
        for value in dict.fromkeys(values):
            point = solver.solve(plant_params={problem.parameter: value}, guess=guess)
            row = {
                "parameter": float(value),
                "objective": sign * point.objective,
                "success": point.success,
                "final_time": point.final_time,
                "gradient": sign * envelope_gradient(point, problem.parameter) if point.success else math.nan,
            }
            if value in problem.sweep:
                rows.append(row)
            if value == problem.text_value:
                at_text = row
    return rows, at_text


def decide_globally(problem: OpenLoopCodesign, quick: bool, samples: int) -> dict:
    """method -> `mpc.global_search.GlobalResult` of both methods on fresh builds of `problem`, `samples` points."""
    found = {}
    for method in global_search.METHODS:
        setup = problem.build(quick)
        found[method] = global_search.codesign(
            setup.problem, setup.transcription, method=method, samples=samples, **dict(setup.solve_options)
        )
    return found


def solve(
    problem: OpenLoopCodesign, quick: bool = False, samples: int = global_search.DEFAULT_SAMPLES
) -> CodesignResult:
    """Decide `problem` simultaneously and nested (each on a fresh build), then sweep J*(p) with p fixed, then
    both methods under the global layer (`mpc.global_search.codesign` with `samples` sweep points; 0: not).

    quick : coarser meshes. The problem must choose exactly its `parameter` (ValueError otherwise).
    """
    sign = -1.0 if problem.maximized else 1.0
    setup = problem.build(quick)
    if list(setup.problem.chosen) != [problem.parameter]:
        raise ValueError(
            f"{problem.key}: the problem must choose exactly {problem.parameter!r}, chooses "
            f"{list(setup.problem.chosen)}"
        )
    simultaneous = decide_simultaneous(problem, setup, sign)
    fresh = problem.build(quick)
    nested, inner = decide_nested(problem, fresh, sign)
    rows, at_text = sweep_optimum(problem, fresh, inner, sign)
    reference = problem.reference() if problem.reference else None
    found = decide_globally(problem, quick, samples) if samples else {}
    return CodesignResult(problem, setup, simultaneous, nested, rows, reference, at_text, found)


# ---------------------------------------------------------------------------- report
HEADER = """# Open-loop co-design: simultaneous versus nested

Generated by `{command}` (do not edit by hand); {machine}.

A plant parameter and the input history are decided together in one optimal control problem
(`mpc.OptimalControlProblem` with `ocp.choose`, docs/ocp.md). Each problem is solved twice, each to
convergence:

- **simultaneous**: the parameter is a decision of the same transcription as the trajectory; one
  IPOPT solve decides both;
- **nested**: `mpc.solve_nested`, SciPy's L-BFGS-B on the parameter (scaled to [0, 1]) around the
  optimal control problem with the parameter fixed, re-solved warm from its previous answer; the
  outer gradient is dJ*/dp = −λ_p, the envelope theorem at each converged inner solve.

*Wall time* runs from posing the problem to the answer (transcription and IPOPT set-up included);
*defect* is `OCPSolution.verify()` at the answer: the optimal input, held on each interval,
re-simulated with CVODES from the optimized state on every interval, largest state difference
(SI units). *dJ*/dp* is the envelope derivative −λ_p of the problem with p fixed: at a bound it is
what the bound costs, per unit of the parameter. The sweep tables give J*(p) with p fixed, and the
text's value of the parameter is compared with the co-designed one.

**Global layer** (`mpc.global_search.codesign`): each method is also run over a coarse sweep of the
parameter (a grid over its range, each point solved with the parameter fixed from the same start),
refined from the sweep's best local minima; the answers closer than 2 % of the range are one optimum.
Each section lists every distinct local optimum found and how far the method's plain local answer is
from the best; "converged" there means converged at the best of them.
"""


def _number(value, digits: int = 6) -> str:
    """A number as the report prints it: `digits` significant digits (`models.files.format_number`)."""
    return format_number(value, digits)


def section(result: CodesignResult) -> str:
    """One problem: its statement, both decisions, their agreement, the sweep and the independent answer."""
    p = result.problem
    what = result.setup.objective
    lines = [
        f"## {p.title}",
        "",
        result.setup.description,
        "",
        f"Plant: {p.plant}. Transcription: {describe(result.setup.transcription)}. Objective: {what}."
        + (f" The text's value: {p.parameter} = {_number(p.text_value)} {p.unit}." if p.text_value is not None else ""),
        "",
    ]
    rows = []
    for d in (result.simultaneous, result.nested):
        rows.append(
            {
                "method": d.method,
                "value": f"{_number(d.parameter)} {p.unit}",
                "objective": _number(d.objective),
                "T": _number(d.final_time),
                "converged": "yes" if d.success else "no",
                "status": d.status,
                "iterations": d.iterations,
                "wall": f"{d.wall_time:.2f}",
                "defect": _number(d.defect, 3),
            }
        )
    columns = [
        ("method", "method", str),
        ("value", p.parameter, str),
        ("objective", "objective", str),
        ("T", "T (s)", str),
        ("converged", "converged", str),
        ("iterations", "iterations", str),
        ("wall", "wall time (s)", str),
        ("defect", "defect", str),
        ("status", "status", str),
    ]
    lines += [markdown_table(rows, columns)]
    dp, dj = result.agree
    lines += [
        f"Simultaneous and nested agree to |Δ{p.parameter}| = {dp:.2g} {p.unit} and a relative "
        f"|ΔJ| = {dj:.2g}. Wall time: simultaneous {result.simultaneous.wall_time:.2f} s, nested "
        f"{result.nested.wall_time:.2f} s.",
        "",
    ]
    lines += [_where(result), ""]
    if result.at_text is not None and result.at_text["success"]:
        best, text = result.nested.objective, result.at_text["objective"]
        worse = "less" if p.maximized else "more"
        lines += [
            f"At the text's {p.parameter} = {_number(p.text_value)} {p.unit} the optimum is "
            f"{_number(text)}: {_number(abs(text - best), 4)} ({100 * abs(text - best) / abs(best):.2g} %) "
            f"{worse} than with the co-designed {p.parameter}.",
            "",
        ]
    if result.reference:
        ref = result.reference
        lines += [
            f"Independent answer ({ref['how']}): {p.parameter} = {_number(ref['parameter'])} {p.unit}, "
            f"objective {_number(ref['objective'])}.",
            "",
        ]
    lines += global_lines(result)
    if result.sweep:
        sweep_rows = [
            {
                "p": f"{_number(r['parameter'])} {p.unit}",
                "J": _number(r["objective"]),
                "T": _number(r["final_time"]),
                "g": _number(r["gradient"], 4),
                "ok": "yes" if r["success"] else "no",
            }
            for r in result.sweep
        ]
        lines += [
            f"The optimal value with {p.parameter} fixed (the nested problem's inner solve):",
            "",
            markdown_table(
                sweep_rows,
                [
                    ("p", p.parameter, str),
                    ("J", "J*", str),
                    ("T", "T (s)", str),
                    ("g", f"dJ*/d{p.parameter}", str),
                    ("ok", "converged", str),
                ],
            ),
        ]
    return "\n".join(lines)


def global_lines(result: CodesignResult) -> list[str]:
    """The global layer's paragraph and table: its sweep, every distinct local optimum, the gap it closes."""
    if not result.global_answers:
        return []
    p, sign = result.problem, -1.0 if result.problem.maximized else 1.0
    lines = []
    for method, found in result.global_answers.items():
        best = sign * found.best.objective
        difference, relative = result.global_gap(method)
        optima = f"{len(found.optima)} distinct local optim{'um' if len(found.optima) == 1 else 'a'}"
        rows = [
            {
                "p": f"{_number(o.params[p.parameter])} {p.unit}",
                "J": _number(sign * o.objective),
                "start": f"{_number(o.start[p.parameter])} {p.unit}",
                "ok": "yes" if o.success else "no",
                "status": o.status,
            }
            for o in found.optima
        ]
        lines += [
            f"Global layer over the {method} method ({found.design}, each from the same start; "
            f"{found.wall_time:.2f} s): {optima}, "
            f"the best {p.parameter} = {_number(found.best.params[p.parameter])} {p.unit}, objective {_number(best)} "
            f"({'converged' if found.converged else 'not converged'}; chosen as the {found.how}). The plain "
            f"{method} answer is {_number(difference, 4)} ({100 * relative:.3g} %) "
            + ("from it: already the global one." if relative < 1e-4 else "worse."),
            "",
            markdown_table(
                rows,
                [
                    ("p", p.parameter, str),
                    ("J", "objective", str),
                    ("start", "refined from", str),
                    ("ok", "converged", str),
                    ("status", "status", str),
                ],
            ),
        ]
    return lines


def _where(result: CodesignResult) -> str:
    """Where the answer lies and what dJ*/dp says there."""
    p, d = result.problem, result.nested
    chosen = result.setup.problem.chosen[p.parameter]
    gradient = f"dJ*/d{p.parameter} = {_number(d.gradient, 4)} per {p.unit}"
    for end, value in (("lower", chosen.lower), ("upper", chosen.upper)):
        if abs(d.parameter - value) <= 1e-6 * max(1.0, abs(value)):
            return (
                f"The answer lies at the {end} end of the range, {_number(value)} {p.unit}: {gradient} there "
                f"(the envelope derivative at the nested answer) is what each {p.unit} "
                f"{'more' if end == 'lower' else 'less'} costs."
            )
    return (
        f"The answer lies inside the range; {gradient} at the nested answer. It is not zero because the "
        "held input makes J*(p) piecewise smooth: where the switch of the bang-bang input moves from one "
        "interval to the next, J*(p) has a kink, and both methods stop on the same kink."
    )


def report(results: list[CodesignResult], command: str, machine: str = "") -> str:
    """The whole Markdown document (a function of the results, so it can be joined into another report).

    command : the command line that made it, named in the header;  machine : what the timings are of
    """
    summary = [
        {
            "problem": r.problem.title,
            "parameter": f"{r.problem.parameter} ({r.problem.unit})",
            "text": _number(r.problem.text_value) if r.problem.text_value is not None else "—",
            "sim": _number(r.simultaneous.parameter),
            "nested": _number(r.nested.parameter),
            "J": f"{_number(r.simultaneous.objective)} / {_number(r.nested.objective)}",
            "converged": f"{'yes' if r.simultaneous.success else 'no'} / {'yes' if r.nested.success else 'no'}",
            "wall": f"{r.simultaneous.wall_time:.2f} / {r.nested.wall_time:.2f}",
            "optima": " / ".join(str(len(g.optima)) for g in r.global_answers.values()) or "—",
            "gap": " / ".join(f"{100 * r.global_gap(m)[1]:.3g} %" for m in r.global_answers) or "—",
        }
        for r in results
    ]
    columns = [
        ("problem", "problem", str),
        ("parameter", "chosen parameter", str),
        ("text", "text", str),
        ("sim", "simultaneous", str),
        ("nested", "nested", str),
        ("J", "objective sim / nested", str),
        ("converged", "converged sim / nested", str),
        ("wall", "wall time sim / nested (s)", str),
        ("optima", "local optima found sim / nested", str),
        ("gap", "local answer's gap to the global sim / nested", str),
    ]
    parts = [HEADER.format(command=command, machine=machine or "timings of one run"), markdown_table(summary, columns)]
    parts += [section(r) for r in results]
    return "\n".join(parts)


def main(argv=None) -> int:
    """The command line: decide the problems (all, or --only KEY ...), print each answer, give the report.

    The report goes to stdout, to --out PATH, or with --write-docs into docs/codesign_open_loop.md (the
    committed one is never overwritten by default); progress goes to stderr. Returns 0 when every problem
    converged both ways (and under the global layer), 1 otherwise; an unknown key is a usage error.
    """
    parser = argparse.ArgumentParser(prog="python -m studies.codesign_open_loop", description=__doc__.split("\n")[0])
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--out", type=Path, help="Markdown file to write (default: the report on stdout)")
    where.add_argument("--write-docs", action="store_true", help=f"write the report into {DOC}")
    parser.add_argument("--quick", action="store_true", help="coarser meshes (seconds instead of a minute)")
    parser.add_argument("--only", nargs="+", metavar="KEY", help="run only these problems")
    parser.add_argument(
        "--samples",
        type=int,
        default=global_search.DEFAULT_SAMPLES,
        help=f"the global layer's sweep points per parameter (default {global_search.DEFAULT_SAMPLES}; 0: none)",
    )
    args = parser.parse_args(argv)
    found = {p.key: p for p in problems()}
    unknown = [key for key in args.only or () if key not in found]
    if unknown:
        parser.error(f"unknown problem {unknown[0]!r}; problems: {', '.join(found)}")
    if args.samples and args.samples < 2:
        parser.error(f"--samples must be 0 or at least 2, got {args.samples}")
    out = DOC if args.write_docs else args.out
    if out is not None:
        files.check_writable(out.parent)
    results = []
    for i, key in enumerate(args.only or list(found), 1):
        print(f"[{i}/{len(args.only or found)}] {key} ...", end=" ", flush=True, file=sys.stderr)
        result = solve(found[key], args.quick, args.samples)
        results.append(result)
        print(
            f"simultaneous {_number(result.simultaneous.parameter)}, nested {_number(result.nested.parameter)} "
            f"{found[key].unit} ({result.simultaneous.wall_time:.1f} s / {result.nested.wall_time:.1f} s)",
            flush=True,
            file=sys.stderr,
        )
    command = (
        "python -m studies.codesign_open_loop"
        + (" --quick" if args.quick else "")
        + ("" if args.only is None else " --only " + " ".join(args.only))
        + ("" if args.samples == global_search.DEFAULT_SAMPLES else f" --samples {args.samples}")
    )
    total = sum(r.simultaneous.wall_time + r.nested.wall_time for r in results)
    layer = sum(g.wall_time for r in results for g in r.global_answers.values())
    text = report(
        results, command, f"{len(results)} problems, {total:.0f} s of local solves and {layer:.0f} s of global layer"
    )
    if out is None:
        sys.stdout.write(text + "\n")
    else:
        files.write_text(out, text)
        print(f"wrote {out}", file=sys.stderr)
    converged = all(r.simultaneous.success and r.nested.success for r in results)
    return 0 if converged and all(g.converged for r in results for g in r.global_answers.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
