"""The exact problem's end game: a poll search on the exact loop where the smoothed stages do not converge.

The continuation's stages minimize smoothed specs. Where a spec jumps (a settling time moves by a sample
when the last sample to leave the band changes), IPOPT's iterates can wander without meeting its test,
with L-BFGS or the exact Hessian (measured cases: docs/notes/tuning.md). `polish` starts from the point
the continuation kept and runs `designs.weight_search.poll_search` on the exact problem itself. The score
of a decision is its exact objective relative to the start's where every exact spec holds (largest
relative excess within `AGREEMENT`); otherwise it is `BARRIER` plus that excess, so the search first meets
the specs (a phase one) and then lowers the cost. The coordinates are each entry's log-magnitude relative
to the start, with its sign kept (the tuner's gain bounds keep it too): a poll step h changes one gain by
the factor e^h.

It converges when no gain changed by a factor e^{±h} lowers the score by more than c h², with h below
`MIN_STEP` (the poll's stationarity measure on the nonsmooth problem, the test a derivative-free method
has; Kolda, Lewis & Torczon, SIAM Review 45(3), 2003). That is weaker than IPOPT's KKT test, and the
record names which test ended a tuning.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..weight_search import Evaluation, SearchResult, poll_search
from .problem import TuningProblem
from .settings import AGREEMENT

#: Score of a decision that misses a spec, before its largest relative excess is added: above any cost
#: (costs are relative to the start's, near 1).
BARRIER = 1e3
#: The first poll step (each gain × or ÷ e^0.1) and the one below which the search has converged (1 %).
FIRST_STEP, MIN_STEP = 0.1, 0.01
#: The sufficient decrease c: a point is taken when it lowers the score by more than c h².
DECREASE = 1e-3
MAX_EVALUATIONS = 3000


@dataclass(frozen=True)
class Polished:
    """What `polish` found: the decision, its exact objective and largest relative excess, and the search."""

    decision: np.ndarray
    objective: float
    excess: float
    search: SearchResult

    @property
    def converged(self) -> bool:
        """The poll step fell below `MIN_STEP` (not the evaluation cap)."""
        return self.search.converged

    @property
    def feasible(self) -> bool:
        """Every exact spec holds at the decision (within `AGREEMENT`)."""
        return self.excess <= AGREEMENT


class _Coordinates:
    """decision = sign × |start| × e^θ for the start's non-zero entries, decision = θ for its zeros."""

    def __init__(self, start: np.ndarray, lbx: np.ndarray, ubx: np.ndarray):
        start = np.asarray(start, dtype=float)
        self.logged = start != 0
        magnitude = np.where(self.logged, np.abs(start), 1.0)
        sign = np.sign(np.where(self.logged, start, 1.0))
        self.scale = sign * magnitude
        # |decision| bounds on each entry's side of zero (a bound across zero does not bound its magnitude)
        low = np.where(sign > 0, lbx, -ubx) / magnitude
        high = np.where(sign > 0, ubx, -lbx) / magnitude
        with np.errstate(divide="ignore"):
            self.lower = np.where(self.logged, np.log(np.maximum(low, 0.0)), lbx)
            self.upper = np.where(self.logged, np.log(np.maximum(high, 0.0)), ubx)

    def decision(self, theta: np.ndarray) -> np.ndarray:
        return np.where(self.logged, self.scale * np.exp(theta), theta)

    def theta(self, decision: np.ndarray) -> np.ndarray:
        return np.where(self.logged, np.log(np.asarray(decision, dtype=float) / self.scale), decision)


def polish(
    problem: TuningProblem,
    lbx: np.ndarray,
    ubx: np.ndarray,
    start: np.ndarray,
    *,
    max_evaluations: int = MAX_EVALUATIONS,
    progress: Callable[[int, float, float], None] | None = None,
) -> Polished:
    """Poll-search the exact problem from `start` (a decision within [lbx, ubx]); see the module docstring.

    progress : `poll_search`'s, called as progress(evaluations, best score, poll step) after every poll
    """
    coordinates = _Coordinates(start, lbx, ubx)
    reference, _ = problem.merit(start)
    if not (math.isfinite(reference) and reference > 0):
        reference = 1.0

    def score(theta: np.ndarray, bound: float) -> Evaluation:
        objective, excess = problem.merit(coordinates.decision(theta))
        if not math.isfinite(objective) or math.isnan(excess):
            return Evaluation(math.inf, info={"objective": objective, "excess": excess})
        value = objective / reference if excess <= AGREEMENT else BARRIER + excess
        return Evaluation(value, info={"objective": objective, "excess": excess})

    theta0 = np.clip(coordinates.theta(start), coordinates.lower, coordinates.upper)
    found = poll_search(
        score,
        theta0,
        step=FIRST_STEP,
        min_step=MIN_STEP,
        max_evaluations=max_evaluations,
        progress=progress,
        bounds=(coordinates.lower, coordinates.upper),
        decrease=DECREASE,
    )
    return Polished(coordinates.decision(found.x), float(found.info["objective"]), float(found.info["excess"]), found)
