"""IPOPT's time to its first iterate on a case's stored-gains tuning problem, per MUMPS ordering.

The tuner's problem (`studies.tuner`: the case's hand PID, its tuning samples, the
step and disturbance runs, the specs with their margin) has one inequality per
sample per spec per run, each depending on every gain: a KKT system with a few
dense columns. IPOPT analyses (orders and symbolically factorizes) that system
once per solve, before its first iterate, so the time to iteration 0 measures
the ordering. Compared in one process: MUMPS's automatic choice
(``mumps_pivot_order`` 7) and QAMD (6, `designs.tuning.IPOPT_OPTIONS`), each on
the same problem from the same start, one IPOPT iteration at the continuation's
first width, CasADi's virtual machine.

Usage: python benchmarks/kkt_ordering.py [--case satellite] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import time

import _path  # noqa: F401  (before our packages: drops this folder from sys.path)

import studies
from designs.tuning import SolveOptions, TuningProblem, gain_bounds, solve
from studies import tuner

ORDERINGS = {"auto": 7, "qamd": 6}


def tuner_problem(name: str) -> tuple[TuningProblem, tuple]:
    """The tuner's problem for case `name` and its gain bounds (lbx, ubx)."""
    setup = tuner.tuning_setup(studies.get(name))[0]
    problem = setup.problem()
    return problem, gain_bounds(problem, setup.bounds)


def first_iterate_s(problem: TuningProblem, bounds: tuple, order: int) -> float:
    """Seconds from calling IPOPT to its iteration 0 with MUMPS ordering `order`."""
    seen: list[float] = []
    called = time.perf_counter()
    solve(
        problem,
        *bounds,
        SolveOptions(
            max_iter=1,
            widths=(0.1,),
            ipopt_options={"mumps_pivot_order": order},
            progress=lambda i, f, s: seen.append(time.perf_counter() - called) if i == 0 else None,
        ),
    )
    return seen[0]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="satellite", choices=studies.names())
    parser.add_argument("--json", help="write the figures to this file")
    args = parser.parse_args(argv)
    problem, bounds = tuner_problem(args.case)
    out = {"case": args.case, "constraints": int(problem.g.numel()), "gains": int(problem.decision.numel())}
    print(f"{args.case}: {out['gains']} gains, {out['constraints']} constraints", flush=True)
    for label, order in ORDERINGS.items():
        out[f"{label}_first_iterate_s"] = seconds = first_iterate_s(problem, bounds, order)
        print(f"  mumps_pivot_order {order} ({label}): first iterate after {seconds:.1f} s", flush=True)
    out["ratio_auto_over_qamd"] = out["auto_first_iterate_s"] / out["qamd_first_iterate_s"]
    print(f"  QAMD {out['ratio_auto_over_qamd']:.1f}x faster to the first iterate")
    if args.json:
        with open(args.json, "w") as stream:
            json.dump(out, stream, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
