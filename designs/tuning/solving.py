"""The entry points: `tune` a setup, or `solve` a built problem within bounds.

`solve` runs, in order and as its options ask: the problem without its specs first (`relaxed`), a phase
one when the start misses a spec (`phase`), and the smoothing continuation (`Continuation`) from the
phase one's answer or the start.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import casadi as ca
import numpy as np

from models.checks import as_vector, real

from .continuation import Continuation, total_objective
from .options import SolveOptions, TuningSetup
from .phase_one import phase_one
from .problem import TuningProblem, gain_bounds
from .result import TuningResult, feasible_answer
from .settings import AGREEMENT
from .spectral import missed_specs


def checked_options(options) -> SolveOptions:
    """`options`, or the defaults for None; TypeError for anything but a `SolveOptions`."""
    if options is None:
        return SolveOptions()
    if not isinstance(options, SolveOptions):
        raise TypeError(f"options must be a designs.tuning.SolveOptions, got {type(options).__name__}")
    return options


def tune(setup: TuningSetup, options: SolveOptions | None = None) -> TuningResult:
    """Tune `setup.block`'s gains on the nonlinear closed loop with IPOPT, from its current gains.

    Parameters
    ----------
    setup : TuningSetup, what is tuned (its problem is built and checked first, then its bounds)
    options : SolveOptions, how (default `SolveOptions()`)

    Returns
    -------
    TuningResult
        When IPOPT fails or the closed loop diverges on the way, the best
        feasible iterate (or the start, if it is feasible and better) is
        returned and `message` says so; an infeasible spec set is reported
        with the violated specs named.
    """
    if not isinstance(setup, TuningSetup):
        raise TypeError(f"setup must be a designs.tuning.TuningSetup, got {type(setup).__name__}")
    options = checked_options(options)
    problem = setup.problem()
    lbx, ubx = gain_bounds(problem, setup.bounds)
    return solve(problem, lbx, ubx, options)


def solve(
    problem: TuningProblem,
    lbx,
    ubx,
    options: SolveOptions | None = None,
    *,
    start=None,
    plant_cost: Callable[[ca.MX], ca.MX] | None = None,
    cost_weight: float = 1.0,
) -> TuningResult:
    """IPOPT on cost_weight × the problem's objective (+ plant_cost(decision)), smoothed by continuation.

    Parameters
    ----------
    problem : TuningProblem
    lbx, ubx : decision bounds (n_decision,)
    options : SolveOptions (default `SolveOptions()`). With `phase`, a start that misses a spec is
        first moved by `phase_one`; if the phase one ends outside the specs, the problem is tuned from
        its answer and from the start and the better kept (feasible first, then converged, then cost).
        With `until_feasible`, the start itself when it meets the specs (no solve), or the phase one's
        answer when it does, is returned as converged. With `relaxed`, a problem with specs is first
        solved without them; a converged answer meeting every spec on the exact loop is returned.
    start : decision vector to start from (default `problem.start()`), clipped to the bounds
    plant_cost : optional callable MX decision -> MX scalar added to the objective
    cost_weight : >= 0, the closed-loop objective's weight (0: the plant cost alone, under the specs)
    """
    options = checked_options(options)
    started = time.perf_counter()
    n = problem.decision.numel()
    lbx, ubx = np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float)
    start = np.clip(problem.start() if start is None else as_vector(start, n, "start"), lbx, ubx)
    cost_weight = real(cost_weight, "cost_weight")
    if cost_weight < 0:
        raise ValueError(f"cost_weight must be >= 0, got {cost_weight}")
    # What a further solve from another start (of this problem, or of it without its specs) runs with.
    again = replace(options, phase=False, until_feasible=False, relaxed=False)
    prefix = ""
    if options.relaxed and not options.until_feasible and problem.g.numel():
        free = solve(
            problem.without_specs(), lbx, ubx, again, start=start, plant_cost=plant_cost, cost_weight=cost_weight
        )
        kept, prefix = _kept_without_specs(problem, free, started)
        if kept is not None:
            return kept
    found, begin = None, start
    if options.phase and problem.largest_excess(start) > AGREEMENT:
        found = phase_one(problem, lbx, ubx, start, options)
    if options.until_feasible and (found is None or found.excess <= AGREEMENT):
        total = total_objective(problem, plant_cost, cost_weight)
        return feasible_answer(problem, start, found, total, started, options.method)
    if found is not None:
        if found.excess > AGREEMENT:
            # A local verdict only: IPOPT's own restoration from the start may still find the specs, or not
            # where the phase one's answer leads it on. Both starts; the better answer is kept.
            tries = [
                solve(problem, lbx, ubx, again, start=point, plant_cost=plant_cost, cost_weight=cost_weight)
                for point in (found.decision, start)
            ]
            best = max(tries, key=lambda r: (r.feasible, r.converged, -r.cost if np.isfinite(r.cost) else -np.inf))
            initial = tries[1].initial_cost
            return replace(
                best,
                phase_one=found,
                initial_cost=initial,
                initial_gains=tries[1].initial_gains,
                improvement=1 - best.cost / initial if initial else 0.0,
                iterations=sum(r.iterations for r in tries),
                wall_time=time.perf_counter() - started,
                message=f"{prefix}started outside the specs; phase one (IPOPT: {found.status}, {found.iterations} "
                f"iterations) ended {found.excess:.3g} relative outside them; tuned from its answer and from "
                f"the start, kept the one from {'its answer' if best is tries[0] else 'the start'}: {best.message}",
            )
        begin = found.decision
    continuation = Continuation(
        problem, lbx, ubx, begin, options, plant_cost=plant_cost, cost_weight=cost_weight, started=started
    )
    continuation.run()
    return continuation.result(start, found, prefix, started)


def _kept_without_specs(problem: TuningProblem, free: TuningResult, started: float) -> tuple[TuningResult | None, str]:
    """(the answer solved without the specs when it converged and meets them, else None; the message of
    that first solve to put before the next one's)."""
    assert free.decision is not None, "solve always returns its decision vector"
    missed = missed_specs(problem, free.decision)
    if free.converged and np.isfinite(free.cost) and not missed:
        worst_excess = problem.largest_excess(free.decision)
        kept = replace(
            free,
            wall_time=time.perf_counter() - started,
            message=f"solved without the specs: the answer meets them (largest relative excess "
            f"{worst_excess:.3g}), so it is a local minimum under them too; {free.message}",
        )
        return kept, ""
    prefix = (
        f"without the specs: {free.status}, {'converged' if free.converged else 'not converged'}"
        f"{', missing ' + '; '.join(missed) if missed else ''}; then with them: "
    )
    return None, prefix
