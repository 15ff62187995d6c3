"""The global layer over closed-loop co-design: `mpc.global_search.search` around `designs.codesign`'s methods.

The nested method's bounded Brent search and the simultaneous IPOPT solve each stop on the first local
optimum of the plant parameters. `codesign_globally` sweeps the parameters first (each point a converged
tuning of the gains from the block's own gains, the same start for every point: `Codesign.inner`), then
refines the sweep's best local minima with the chosen method:

- nested: the outer search kept to the sweep cell around the point (the box one grid step either side,
  `Codesign.nested`'s ``bracket``);
- simultaneous: one IPOPT solve of gains and parameters from the point's tuned gains at the point.

Every answer is a `designs.codesign.CodesignResult`; the global one (`GlobalResult.answer`) is the best
converged and feasible of them (infeasible answers lose, as in the nested method).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from models import checks
from mpc.global_search import (
    DEFAULT_KEEP,
    DEFAULT_SAMPLES,
    DEFAULT_TOLERANCE,
    MAX_MEMORY,
    MAX_SECONDS,
    GlobalResult,
    LocalOptimum,
    check_budget,
    search,
)

from .codesign import Codesign, CodesignResult, check_ranges
from .tuning import SolveOptions, TuningSetup, checked_options

#: The closed-loop methods the layer refines with.
GLOBAL_METHODS = ("nested", "simultaneous")


class ClosedLoopWork:
    """The sweep's and the refinement's work on one `Codesign` problem (see the module docstring).

    step : the sweep's grid step per parameter (SI), the half-width of a nested refinement's box.
    Answers are kept by start (`answers`) so that the global one is returned whole in this process.
    """

    def __init__(self, problem: Codesign, method: str, nested_tol: float, step: np.ndarray):
        if method not in GLOBAL_METHODS:
            raise ValueError(f"method must be one of {GLOBAL_METHODS}, got {method!r}")
        self.problem, self.method, self.nested_tol, self.step = problem, method, nested_tol, step
        self.answers: dict = {}

    def __getstate__(self) -> dict:
        """The work without the answers kept here (only the sweep travels to other processes)."""
        return dict(self.__dict__) | {"answers": {}}

    def evaluate(self, values: tuple) -> tuple[float, bool]:
        """(objective the nested method sees, converged and feasible) with the parameters fixed at `values`."""
        result, value = self.problem.inner(np.array(values, dtype=float), [], from_nearest=False)
        return float(value), bool(result.converged and result.feasible)

    def refine(self, values: tuple) -> LocalOptimum:
        """The method from the sweep point `values`; its `CodesignResult` kept in `answers`."""
        problem, point = self.problem, np.array(values, dtype=float)
        if self.method == "nested":
            answer = problem.nested(self.nested_tol, from_nearest=True, bracket=(point - self.step, point + self.step))
        else:
            tuned, _ = problem.inner(point, [], from_nearest=False)
            initial = problem.joint.start()
            assert tuned.decision is not None, "tuning.solve always returns its decision vector"
            initial[: problem.joint.n_gains] = tuned.decision[: problem.joint.n_gains]
            initial[problem.joint.n_gains :] = point
            answer = problem.solve_joint("simultaneous", problem.joint, initial, f"from the sweep point {values}: ")
        self.answers[values] = answer
        began = dict(zip(problem.names, (float(v) for v in values)))
        return LocalOptimum(dict(answer.params), float(answer.objective), bool(answer.success), answer.status, began)


def codesign_globally(
    setup: TuningSetup,
    design_params: dict,
    *,
    method: str = "nested",
    plant_cost: Callable | None = None,
    options: SolveOptions | None = None,
    samples: int = DEFAULT_SAMPLES,
    keep: int = DEFAULT_KEEP,
    tolerance: float = DEFAULT_TOLERANCE,
    seed: int = 0,
    nested_tol: float = 1e-3,
    max_seconds: float = MAX_SECONDS,
    max_memory: float = MAX_MEMORY,
    map: Callable | None = None,
) -> GlobalResult:
    """Closed-loop co-design of `design_params` with the block's gains, under the global layer.

    setup, design_params, plant_cost, options, nested_tol : as in `designs.codesign.codesign`
    method : "nested" or "simultaneous", the local method the sweep's best local minima are refined with
    samples, keep, tolerance, seed : the sweep (`mpc.global_search.search`; default `DEFAULT_SAMPLES` per
        parameter), refused (ValueError naming `samples`) when one timed tuning makes the search exceed
        `max_seconds` (s) or `max_memory` (bytes)
    map : ``map(function, items) -> list`` for the sweep's tunings (a `studies.distributed` executor's
        ``map``: the work is pickled with its problem, and the numbers are those of this process), or None

    The refinements run in this process (their answers are kept whole). Returns the `GlobalResult`: every
    distinct local optimum, the best, and its `CodesignResult` as ``answer``.
    """
    if not isinstance(setup, TuningSetup):
        raise TypeError(f"setup must be a designs.tuning.TuningSetup, got {type(setup).__name__}")
    ranges = check_ranges(setup.plant, design_params)
    checks.integer(samples, "samples", minimum=2)
    nested_tol = checks.positive(nested_tol, "nested_tol")
    problem = Codesign(setup, ranges, plant_cost, plant_cost, checked_options(options))
    low, high = (np.array([r[i] for r in ranges.values()]) for i in (0, 1))
    step = (high - low) / (samples - 1)
    work = ClosedLoopWork(problem, method, nested_tol, step)
    trial = problem.joint.start()
    timed = time.perf_counter()
    work.evaluate(tuple((low + high) / 2))
    seconds = time.perf_counter() - timed
    check_budget(
        samples, len(ranges), keep, seconds, 8.0 * 4 * trial.size, max_seconds=max_seconds, max_memory=max_memory
    )
    spread = None
    if map is not None:
        elsewhere = map

        def spread(function, items):  # the sweep elsewhere, the refinements here (`work.answers` keeps them)
            return elsewhere(function, items) if function == work.evaluate else [function(item) for item in items]

    result = search(
        work.evaluate, work.refine, ranges, samples=samples, keep=keep, tolerance=tolerance, seed=seed, map=spread
    )
    chosen: CodesignResult = work.answers[tuple(result.best.start[n] for n in problem.names)]
    result.answer = chosen
    result.extra["method"] = method
    return result
