"""A global layer over co-design: a coarse sweep of the plant parameters, then local refinement.

Co-design landscapes J*(p) often have several local optima in the plant parameters
(a stiffness against a fixed manoeuvre time, a cable length against a swing
period), and every local method (the simultaneous transcription, the nested outer
optimizer) stops on the first. `search` wraps any of them:

1. **sweep**: J*(p) with p fixed at the points of a coarse design over the ranges,
   each point solved from the same start, so the points are independent and their
   order does not matter: a grid of `samples` points per parameter for one or two
   parameters, a seeded scrambled Sobol design of `samples` points for more;
2. **basins**: the sweep's local minima (`basins`: converged points no worse than
   their converged neighbours), the best `keep` of them;
3. **refine**: the local method started at each kept point;
4. **merge**: two local answers closer than `tolerance` in the scaled parameters are
   one optimum (the better objective kept); the global answer is the converged
   optimum of least objective (any optimum when none converged, and then the answer
   is not converged). "Converged" means converged at the best of them: the best
   converged and no unconverged refinement ended below it.

Steps 1 and 3 go through `map(function, items) -> list` when one is given (a
`studies.distributed` executor's ``map``, a Dask client's, or one built on
``dask.compute``): the functions and items are picklable records, and no answer
depends on where it ran. Without `map` everything runs in this process.

`codesign` applies it to the open-loop methods of this package (`OptimalControlProblem.choose`
solved simultaneously, or `solve_nested`); `designs.codesign_global` to the closed loop.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from models import checks, deferred

from .ocp_codesign import solve_nested

#: Held while a thread builds its solver (`solver` of the work's evaluations).
_BUILDING = threading.Lock()

qmc = deferred.module("scipy.stats.qmc")

#: The sweep's default density: points per parameter for one or two parameters, points in all for more.
DEFAULT_SAMPLES = 12
#: Distinct basins refined by default (`keep`).
DEFAULT_KEEP = 3
#: Default distinctness: the largest coordinate difference of two answers, each parameter scaled to its range.
DEFAULT_TOLERANCE = 0.02
#: Default budget of the whole search, estimated before the sweep from one timed solve (s) and memory (bytes).
MAX_SECONDS, MAX_MEMORY = 1800.0, 2.0e9
#: A refinement's cost, in solves of one sweep point (the estimate's assumption).
REFINE_COST = 10.0
METHODS = ("simultaneous", "nested")


@dataclass(frozen=True)
class LocalOptimum:
    """One local answer: its parameters (SI, by name), objective, convergence, status and the sweep point it
    was started from."""

    params: dict
    objective: float
    success: bool
    status: str
    start: dict


@dataclass
class GlobalResult:
    """The answer of `search`.

    best : the global answer (a `LocalOptimum`);  optima : every distinct local optimum found, best first
    converged : the best one converged;  how : how the best was chosen, in words
    design : the sweep's design in words (kind, points, seed);  sweep : (params, objective, success) per point
    wall_time : s;  answer : the local method's full answer at the best (an `OCPSolution`, ...) or None
    """

    best: LocalOptimum
    optima: list
    converged: bool
    how: str
    design: str
    sweep: list
    wall_time: float
    answer: object = None
    extra: dict = field(default_factory=dict)


def sweep_points(ranges: dict, samples: int, seed: int) -> tuple[np.ndarray, str]:
    """The sweep's points (n, len(ranges)) in SI, and the design in words.

    One or two parameters: a grid of `samples` points per parameter, ends included; more: a scrambled
    Sobol design of `samples` points seeded by `seed`.
    """
    low, high = (np.array([r[i] for r in ranges.values()], dtype=float) for i in (0, 1))
    d = len(ranges)
    if d <= 2:
        axes = [np.linspace(lo, hi, samples) for lo, hi in zip(low, high)]
        grid = np.array(np.meshgrid(*axes, indexing="ij")).reshape(d, -1).T
        return grid, f"grid of {samples}" + (f" × {samples}" if d == 2 else "") + " points, ends included"
    unit = qmc.Sobol(d, scramble=True, seed=seed).random(samples)
    return low + unit * (high - low), f"scrambled Sobol design of {samples} points, seed {seed}"


def distinct(points: Sequence[np.ndarray], candidate: np.ndarray, span: np.ndarray, tolerance: float) -> bool:
    """True when `candidate` lies farther than `tolerance` (scaled by `span`, largest coordinate) from all."""
    return all(float(np.max(np.abs(candidate - p) / span)) > tolerance for p in points)


def basins(points: np.ndarray, values: list, span: np.ndarray, grid: bool) -> list[int]:
    """Indices of the sweep's local minima, best first: converged points no worse than any converged neighbour.

    Neighbours: on a grid, the points one step away along each axis (and diagonally); on a scattered design,
    the 2·d nearest points (distance scaled by `span`). Ties go to the earlier point.
    """
    scaled = (points - points.min(axis=0)) / span
    n, d = points.shape
    ok = [bool(v[1]) and math.isfinite(v[0]) for v in values]
    distance = np.max(np.abs(scaled[:, None, :] - scaled[None, :, :]), axis=2)
    minima = []
    for i in range(n):
        if not ok[i]:
            continue
        if grid:
            step = np.min(distance[i][distance[i] > 0]) if n > 1 else 1.0
            near = np.flatnonzero((distance[i] > 0) & (distance[i] <= step * (1 + 1e-9)))
        else:
            near = np.argsort(distance[i], kind="stable")[1 : 2 * d + 1]
        if all(not ok[j] or (values[i][0], i) < (values[j][0], j) for j in near):
            minima.append(i)
    return sorted(minima, key=lambda i: (values[i][0], i))


def check_budget(samples: int, n_params: int, keep: int, seconds_per_solve: float, bytes_per_solve: float, **limits):
    """Raise ValueError naming `samples` when the sweep's estimated time or memory exceeds the limits.

    seconds_per_solve : one timed solve (s);  bytes_per_solve : what one point's answer holds
    limits : max_seconds, max_memory, workers
    """
    points = samples ** min(n_params, 2) if n_params <= 2 else samples
    workers = max(1, int(limits.get("workers", 1)))
    seconds = (points + REFINE_COST * keep) * seconds_per_solve / workers
    memory = points * bytes_per_solve
    if seconds > limits.get("max_seconds", MAX_SECONDS):
        raise ValueError(
            f"samples = {samples} makes {points} sweep points, estimated {seconds:.0f} s from one solve of "
            f"{seconds_per_solve:.3g} s (max_seconds = {limits.get('max_seconds', MAX_SECONDS):g}): lower samples"
        )
    if memory > limits.get("max_memory", MAX_MEMORY):
        raise ValueError(
            f"samples = {samples} makes {points} sweep points, estimated {memory:.3g} bytes "
            f"(max_memory = {limits.get('max_memory', MAX_MEMORY):.3g}): lower samples"
        )


def search(
    evaluate: Callable,
    refine: Callable,
    ranges: dict,
    *,
    samples: int = DEFAULT_SAMPLES,
    keep: int = DEFAULT_KEEP,
    tolerance: float = DEFAULT_TOLERANCE,
    seed: int = 0,
    map: Callable | None = None,
) -> GlobalResult:
    """Sweep, pick distinct basins, refine, merge; see the module docstring.

    evaluate : picklable callable values (tuple of floats, SI) -> (objective, success), J*(p) with p fixed
    refine : picklable callable values -> LocalOptimum, the local method started at `values`
    ranges : dict name -> (low, high), SI;  samples, keep, tolerance, seed : the design, see the module
    map : callable (function, items) -> list of results in the items' order, or None (this process)
    """
    checks.integer(samples, "samples", minimum=2)
    checks.integer(keep, "keep", minimum=1)
    tolerance = checks.positive(tolerance, "tolerance")
    started = time.perf_counter()
    points, design = sweep_points(ranges, samples, seed)
    run = map or (lambda function, items: [function(item) for item in items])
    items = [tuple(float(v) for v in point) for point in points]
    values = run(evaluate, items)
    span = np.array([hi - lo for lo, hi in ranges.values()], dtype=float)
    names = list(ranges)
    kept = [points[i] for i in basins(points, values, span, len(ranges) <= 2)[:keep]]
    if not kept:  # no point of the sweep converged: refine from its least bad one
        least = min(range(len(items)), key=lambda i: (values[i][0] if math.isfinite(values[i][0]) else math.inf, i))
        kept = [points[least]]
    answers = run(refine, [tuple(float(v) for v in p) for p in kept])
    optima: list[LocalOptimum] = []
    for answer in sorted(answers, key=lambda a: (not a.success, a.objective)):
        at = np.array([answer.params[n] for n in names])
        if distinct([np.array([o.params[n] for n in names]) for o in optima], at, span, tolerance):
            optima.append(answer)
    best = optima[0]
    below = [o for o in optima if not o.success and o.objective < best.objective]
    converged = best.success and not below
    how = (
        f"least objective among the {sum(o.success for o in optima)} converged of {len(optima)} distinct local "
        f"optima, refined from the best {len(kept)} local minima of the sweep (distinct: parameters farther "
        f"apart than {tolerance:g} of their range)"
        + (
            f"; not converged: {len(below)} refinement(s) that did not converge ended below it"
            if below
            else ("" if best.success else "; not converged: no refinement converged")
        )
    )
    sweep = [(dict(zip(names, item)), float(v[0]), bool(v[1])) for item, v in zip(items, values)]
    return GlobalResult(best, optima, converged, how, design, sweep, time.perf_counter() - started)


# ----------------------------------------------------------------- the open-loop methods
class OpenLoopWork:
    """The sweep's and the refinement's work on one `OptimalControlProblem` with chosen parameters.

    problem : an `OptimalControlProblem`, or a picklable callable () -> one (a function of an importable
    module), which each process calls once: then the work travels to other processes. The solvers it builds
    are kept per thread and never pickled. Each sweep
    point and each refinement starts from the same start: the problem's own initial guess with
    `solve_options` (``guess``, ``guess_input``, ...). A refinement first solves its point with p fixed and
    starts the local method from that trajectory at that p.
    """

    def __init__(self, problem, transcription, method: str, solver_options: dict | None, solve_options: dict):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self.build = problem if callable(problem) else None
        self.ocp = problem() if callable(problem) else problem
        self.transcription, self.method = transcription, method
        self.solver_options = {"tolerance": 1e-10} | dict(solver_options or {})
        self.solve_options = dict(solve_options)
        self.names = list(self.ocp.chosen)
        self._local = threading.local()

    def __getstate__(self):
        state = dict(self.__dict__)
        state.pop("_local")
        if self.build is not None:
            state.pop("ocp")
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self.build is not None:
            self.ocp = self.build()
        self._local = threading.local()

    def solver(self, fixed: bool):
        """This thread's OCPSolver: with the chosen parameters as NLP parameters (`fixed`) or as decisions."""
        key = "fixed" if fixed else "free"
        if not hasattr(self._local, key):
            options = self.solver_options
            # Built one thread at a time: the solvers share the problem's CasADi expressions, whose reference
            # counts are not atomic (two threads building at once crashed the Dask threads test).
            with _BUILDING:
                solver = self.ocp.solver(self.transcription, chosen_as_parameters=fixed, **options)
            setattr(self._local, key, solver)
        return getattr(self._local, key)

    def at(self, values: tuple):
        """The OCPSolution with the chosen parameters fixed at `values`."""
        options = dict(self.solve_options)
        fixed = dict(options.pop("plant_params", None) or {}) | dict(zip(self.names, values))
        return self.solver(True).solve(plant_params=fixed, **options)

    def evaluate(self, values: tuple) -> tuple[float, bool]:
        """(J*(values), converged) with the parameters fixed."""
        solution = self.at(values)
        return float(solution.objective), bool(solution.success)

    def refine_answer(self, values: tuple):
        """The local method from `values`: its LocalOptimum and its full answer."""
        start = dict(zip(self.names, values))
        point = self.at(values)
        options = {k: v for k, v in self.solve_options.items() if k not in ("guess", "guess_input")}
        if self.method == "nested":
            result = solve_nested(
                self.ocp, self.transcription, start=start, solver_options=self.solver_options, guess=point, **options
            )
            return LocalOptimum(result.params, result.objective, result.success, result.outer_status, start), result
        solution = self.solver(False).solve(guess=replace(point, chosen=start), **options)
        params = {n: float(solution.chosen[n]) for n in self.names}
        return LocalOptimum(params, float(solution.objective), solution.success, solution.status, start), solution

    def refine(self, values: tuple) -> LocalOptimum:
        """The local method from `values` (its numbers only, to travel back from a worker)."""
        return self.refine_answer(values)[0]


def codesign(
    problem,
    transcription=None,
    *,
    method: str = "simultaneous",
    samples: int = DEFAULT_SAMPLES,
    keep: int = DEFAULT_KEEP,
    tolerance: float = DEFAULT_TOLERANCE,
    seed: int = 0,
    map: Callable | None = None,
    workers: int = 1,
    max_seconds: float = MAX_SECONDS,
    max_memory: float = MAX_MEMORY,
    solver_options: dict | None = None,
    **solve_options,
) -> GlobalResult:
    """Global open-loop co-design of the parameters in `ocp.choose(...)`: `search` around `method`.

    problem : the `OptimalControlProblem`, or a picklable callable () -> one (so that `map` may send the
        work to other processes; see `OpenLoopWork`)
    method : "simultaneous" (the parameters decisions of the transcription) or "nested" (`solve_nested`)
    samples : the sweep's density (`sweep_points`; default `DEFAULT_SAMPLES`); refused (ValueError) when
        one timed solve makes the whole search exceed `max_seconds` (s, on `workers` workers) or the sweep
        `max_memory` (bytes)
    keep, tolerance, seed, map : see `search`;  solver_options : to `OCPSolver` (tolerance 1e-10 by default)
    solve_options : to every solve (the common start: guess, guess_input, plant_params of the fixed ones)

    Returns the `GlobalResult`, its `answer` the best's full answer (`OCPSolution` or
    `NestedCodesignResult`), solved again here from its start when `map` ran the refinements elsewhere.
    """
    checks.integer(samples, "samples", minimum=2)
    checks.integer(workers, "workers", minimum=1)
    work = OpenLoopWork(problem, transcription, method, solver_options, solve_options)
    ocp = work.ocp
    if not ocp.chosen:
        raise ValueError("global co-design needs parameters to choose: call ocp.choose(name, lower, upper)")
    ranges = {n: (ocp.chosen[n].lower, ocp.chosen[n].upper) for n in work.names}
    timed = time.perf_counter()
    trial = work.at(tuple(ocp.chosen[n].guess for n in work.names))
    seconds = time.perf_counter() - timed
    check_budget(
        samples,
        len(ranges),
        keep,
        seconds,
        8.0 * 4 * trial.decision.size,
        max_seconds=max_seconds,
        max_memory=max_memory,
        workers=workers,
    )
    result = search(
        work.evaluate, work.refine, ranges, samples=samples, keep=keep, tolerance=tolerance, seed=seed, map=map
    )
    best = result.best
    result.answer = work.refine_answer(tuple(best.start[n] for n in work.names))[1]
    result.extra["method"] = method
    return result
