"""A derivative-free poll search over log-weights that stops on its own mesh, with exact early rejection.

`poll_search` minimizes f(θ) over θ ∈ ℝⁿ (a controller's log-weights) by a compass search: from the
incumbent θ* it tries θ* ± h eᵢ; the first point that lowers f by more than c h² (`decrease`, a
sufficient decrease: Kolda, Lewis & Torczon, SIAM Review 45(3), 2003, §3.7) becomes the incumbent
(with a `mapper` that runs several points at once, the best of the whole poll), and a poll without
one halves h. It stops when h falls below `min_step` (the stationarity measure of a poll search: no
coordinate step of size 2 h lowers f by more than c (2h)²), or at `max_evaluations`. The sufficient
decrease ends the crawl along a weight that barely matters, where a simple decrease accepts steps
that lower f by 1e-6 and polls the other 2n − 1 directions again after each. A poll starts with the
direction that made the last improvement (dynamic polling): a search that keeps moving one weight the
same way pays one evaluation a step, not up to 2n.

The objective is called as ``objective(θ, bound)`` and returns an `Evaluation`. Given the
incumbent's value less c h² as `bound`, it may stop early, as soon as a lower bound of f(θ) reaches `bound`
(``complete=False``): the point cannot become the incumbent, so the search takes the same path as with
complete evaluations, only with less work. A closed-loop objective over several runs does this by
summing non-negative terms run by run.

Why a poll search rather than Nelder–Mead or gradients, with the measured numbers: docs/notes/tuned_rows.md.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from models.checks import integer, real

CONVERGED = "converged: poll step below its tolerance"
CAPPED = "stopped at the evaluation cap"


@dataclass(frozen=True)
class Evaluation:
    """f(θ), or a lower bound of it when `complete` is False; `runs` counts the work done (closed-loop
    runs); `info` carries whatever the objective wants kept about the point (its worst violation)."""

    value: float
    complete: bool = True
    runs: int = 1
    info: dict = field(default_factory=dict)


@dataclass
class SearchResult:
    """What `poll_search` found.

    x : (n,) the best point;  value : f(x);  info : its `Evaluation.info`
    evaluations : objective calls;  runs : their summed `Evaluation.runs`
    step : the final poll step;  status : `CONVERGED` or `CAPPED`;  converged : status is CONVERGED
    history : [(seconds since start, runs so far, best value)] at every improvement (and the start)
    """

    x: np.ndarray
    value: float
    info: dict
    evaluations: int
    runs: int
    step: float
    status: str
    history: list

    @property
    def converged(self) -> bool:
        """Whether the search stopped on its mesh (not at the cap)."""
        return self.status == CONVERGED


def _points(x: np.ndarray, step: float, first: int = 0) -> list[tuple[int, np.ndarray]]:
    """The poll (k, θ + step d_k) over the directions d_{2i} = +eᵢ, d_{2i+1} = −eᵢ, in the order d_first,
    d_first+1, …, wrapping around."""
    out = []
    for k in np.roll(np.arange(2 * x.size), -first):
        y = x.copy()
        y[k // 2] += step if k % 2 == 0 else -step
        out.append((int(k), y))
    return out


@dataclass(frozen=True)
class _Bounded:
    """objective(θ, bound) called on one (θ, bound) item: picklable when the objective is."""

    objective: Callable

    def __call__(self, item) -> Evaluation:
        return self.objective(*item)


def reporter(every: int, say: Callable[[str], None]) -> Callable[[int, float, float], None]:
    """A `poll_search` progress callback that says (``say(text)``) the evaluations, best score and poll step
    once per `every` evaluations."""
    said = [0]

    def report(evaluations: int, value: float, step: float) -> None:
        if evaluations >= said[0] + every:
            said[0] = evaluations
            say(f"    {evaluations:4d} evaluations: score {value:.6g}, poll step {step:.3g}")

    return report


def poll_search(
    objective: Callable[[np.ndarray, float], Evaluation],
    x0: Sequence[float] | np.ndarray,
    *,
    step: float = math.log(4.0),
    min_step: float = 0.05,
    max_evaluations: int = 400,
    mapper: Callable[[Callable, list], list] | None = None,
    progress: Callable[[int, float, float], None] | None = None,
    bounds: tuple | None = None,
    decrease: float = 0.0,
) -> SearchResult:
    """Minimize `objective` from `x0` by a compass search (see the module docstring).

    Parameters
    ----------
    objective : (θ (n,), bound) -> Evaluation; may stop early once its value's lower bound reaches bound
    x0 : (n,) the start (log-weights)
    step : the first poll step, in units of θ (log(4): weights × 4 or ÷ 4)
    min_step : the poll step below which the search has converged
    max_evaluations : cap on objective calls
    mapper : ``mapper(function, items) -> results`` running a whole poll at once (a
        `studies.distributed` executor's ``map``); None polls one point at a time, taking the first
        improvement
    progress : called as ``progress(evaluations, best value, step)`` after every poll
    bounds : (lower (n,), upper (n,)) of θ, or None; poll points outside are not evaluated (x0 must be inside)
    decrease : c ≥ 0 of the sufficient decrease: a point is taken only when it lowers f by more than c h²
        (0: any decrease)
    """
    x = np.asarray(x0, dtype=float).ravel().copy()
    h, h_min = real(step, "step"), real(min_step, "min_step")
    if h <= 0 or h_min <= 0:
        raise ValueError(f"step and min_step must be > 0, got {step!r} and {min_step!r}")
    integer(max_evaluations, "max_evaluations", minimum=1)
    c = real(decrease, "decrease")
    if not c >= 0:
        raise ValueError(f"decrease must be >= 0, got {decrease!r}")
    lower, upper = (np.full(x.size, -np.inf), np.full(x.size, np.inf)) if bounds is None else bounds
    lower, upper = (
        np.broadcast_to(np.asarray(lower, float), x.shape),
        np.broadcast_to(np.asarray(upper, float), x.shape),
    )
    if np.any(x < lower) or np.any(x > upper):
        raise ValueError(f"x0 {x.tolist()} is outside its bounds")
    started = time.perf_counter()
    best = objective(x, math.inf)
    evaluations, runs = 1, best.runs
    history = [(time.perf_counter() - started, runs, best.value)]
    first = 0  # the direction of the last improvement, polled first
    while h >= h_min and evaluations < max_evaluations:
        inside = [(k, y) for k, y in _points(x, h, first) if np.all(y >= lower) and np.all(y <= upper)]
        poll = inside[: max_evaluations - evaluations]
        target = best.value - c * h * h  # what a point must beat to be taken
        if mapper is None:
            found = None
            for k, y in poll:
                trial = objective(y, target)
                evaluations, runs = evaluations + 1, runs + trial.runs
                if trial.complete and trial.value < target:
                    found = (k, y, trial)
                    break
        else:
            trials = mapper(_Bounded(objective), [(y, target) for _, y in poll])
            evaluations += len(poll)
            runs += sum(t.runs for t in trials)
            improving = [(t.value, i) for i, t in enumerate(trials) if t.complete and t.value < target]
            found = (*poll[min(improving)[1]], trials[min(improving)[1]]) if improving else None
        if found is None:
            h /= 2
        else:
            first, x, best = found
            history.append((time.perf_counter() - started, runs, best.value))
        if progress is not None:
            progress(evaluations, best.value, h)
    status = CONVERGED if h < h_min else CAPPED
    return SearchResult(x, best.value, dict(best.info), evaluations, runs, h, status, history)
