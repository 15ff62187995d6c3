"""What a tuning returns (`TuningResult`), and how the answer is chosen among IPOPT's points."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from models import Block

from .phase_one import PhaseOne
from .problem import TuningProblem
from .settings import AGREEMENT, INFEASIBLE


@dataclass
class TuningResult:
    """What `tune` found.

    block : the block with the tuned gains (or the best feasible point found)
    cost, initial_cost : the objective on the exact (nonsmooth) closed loop
    improvement : 1 − cost / initial_cost
    feasible : every spec holds at `block`'s gains (exact loop)
    converged : the last IPOPT solve met its tolerance (`CONVERGED`) and, with smoothing,
        the exact and smoothed objectives agree to `AGREEMENT` at its answer
    success : converged, feasible, and the answer is IPOPT's (not a fallback)
    status : IPOPT's return status of the last solve
    message : one line saying what happened, including any fallback
    violations : the specs violated at the returned gains, by name
    iterations : IPOPT iterations over every solve;  wall_time : s
    decision : the returned decision vector (n_decision,)
    phase_one : the `PhaseOne` run first when the start missed a spec (None otherwise)
    stages : one dict per solve: width (None for the exact loop), substeps, status, tol, iterations,
        smoothed (the objective IPOPT saw), exact objective and their relative gap at its answer, settled,
        stop (why it ended: IPOPT's convergence test, its cap, a failure, or the worsening rule's stop,
        its start kept) and stationarity (IPOPT's scaled dual infeasibility at its last iterate)
    smoothing_gap : |exact − smoothed| / |exact| at the last stage's answer (0 for "exact")
    history : [(seconds since the call began, the objective IPOPT saw)] per IPOPT iteration
        (smoothed at that stage's width)
    iterates : the decision vector of each `history` entry (evaluate the exact objective
        there with `TuningProblem.values`)
    """

    block: Block
    gains: dict
    initial_gains: dict
    cost: float
    initial_cost: float
    improvement: float
    feasible: bool
    success: bool
    status: str
    message: str
    violations: list = field(default_factory=list)
    iterations: int = 0
    wall_time: float = 0.0
    decision: np.ndarray | None = None
    history: list = field(default_factory=list)
    converged: bool = False
    stages: list = field(default_factory=list)
    smoothing_gap: float = 0.0
    method: str = "smooth"
    iterates: list = field(default_factory=list)
    phase_one: PhaseOne | None = None

    @property
    def stopped_on_test(self) -> bool:
        """Converged, or the specs were proved locally infeasible (IPOPT's restoration converged, or the
        phase one converged outside them) and no point returned meets them: not a cap, and not a claim of
        infeasibility a feasible answer contradicts."""
        proved = self.status == INFEASIBLE or (self.phase_one is not None and self.phase_one.infeasible)
        return self.converged or (proved and not self.feasible)


@dataclass
class Answer:
    """A candidate answer: its exact objective, the specs it misses, its decision and where it came from."""

    value: float
    violations: list
    decision: np.ndarray
    label: str


def pick_answer(
    judge: Callable[[np.ndarray], tuple[float, list]],
    final: np.ndarray,
    iterates: Sequence[tuple[float, np.ndarray]],
    fallbacks: Sequence[tuple[float, np.ndarray, str]],
    lbx: np.ndarray,
    ubx: np.ndarray,
) -> Answer | None:
    """The answer a solve returns: IPOPT's `final` point, unless another point is feasible and clearly better.

    judge : decision -> (exact objective, missed specs)
    iterates : (objective IPOPT saw, decision) of each iteration; only those IPOPT saw below the final
        point's objective (by 1e-6 relative, or any when the final point is infeasible) are judged,
        lowest first, then the `fallbacks` (value, decision, label) in order (the start, ...)
    Returns the first feasible candidate with a finite objective below that threshold, else the final
    point when its objective is finite (feasible or not), else None.
    """
    chosen = None
    value, violations = judge(final)
    if np.isfinite(value):
        chosen = Answer(value, violations, final, "final")
    # Other points matter only when clearly better than IPOPT's answer, or when that answer is infeasible:
    # judged lazily, lowest objective IPOPT saw first.
    threshold = value - 1e-6 * abs(value) if chosen and not violations else np.inf
    others = sorted(
        ((f, decision, "iterate") for f, decision in iterates if np.isfinite(f) and f < threshold),
        key=lambda item: item[0],
    )
    others.extend(fallbacks)
    for _, candidate, label in others:
        candidate = np.clip(candidate, lbx, ubx)
        candidate_value, candidate_violations = judge(candidate)
        if np.isfinite(candidate_value) and not candidate_violations and candidate_value < threshold:
            return Answer(candidate_value, candidate_violations, candidate, label)
    return chosen


def answer_note(answer: Answer | None) -> str:
    """What the message adds about the answer chosen: no finite run, infeasible, or a fallback point."""
    if answer is None:
        return "; no iterate gave a finite closed-loop run"
    if answer.violations:
        return "; infeasible: " + "; ".join(answer.violations)
    if answer.label != "final":
        return f"; returning the best feasible point found (the {answer.label})"
    return ""


def continuation_note(stages: list[dict], gap: float, settled: bool) -> str:
    """What the message says about a smoothing continuation: its stages, last width and final gap."""
    note = (
        f"; smoothing continuation in {len(stages)} stage{'s' if len(stages) > 1 else ''} down to "
        f"width {stages[-1]['width']:g}, exact and smoothed objectives agree to {gap:.1e}"
    )
    if gap > AGREEMENT:
        note += f" (not within {AGREEMENT:g})"
    if not settled:
        note += "; the exact objective still changed at the last width"
    undone = [stage for stage in stages if str(stage.get("stop", "")).startswith("worse")]
    if undone:
        note += f"; the stage at width {undone[-1]['width']:g} was {undone[-1]['stop']}"
    return note


def feasible_answer(
    problem: TuningProblem, start, found: PhaseOne | None, total, started: float, method: str
) -> TuningResult:
    """`solve`'s answer with `until_feasible`: the start, or the phase one's answer, meeting the specs.

    total : Function decision -> the exact objective;  started : time.perf_counter() of the call
    """
    decision = start if found is None else np.asarray(found.decision)
    start_value = float(total(start))
    value = start_value if found is None else float(total(decision))
    block = problem.block_at(decision)
    where = "the start meets the specs" if found is None else (
        f"phase one (IPOPT: {found.status}, {found.iterations} iterations) met the specs"
    )  # fmt: skip
    return TuningResult(
        block=block,
        gains={k: v.copy() for k, v in block.gains.items()},
        initial_gains={k: v.copy() for k, v in problem.block.gains.items()},
        cost=value,
        initial_cost=start_value,
        improvement=1 - value / start_value if start_value else 0.0,
        feasible=True,
        success=True,
        status=found.status if found is not None else "not solved: the start meets the specs",
        message=f"{where}; stopped there (until_feasible: a verdict on the specs, the cost not tuned)",
        iterations=0 if found is None else found.iterations,
        wall_time=time.perf_counter() - started,
        decision=np.array(decision),
        converged=True,
        method=method,
        phase_one=found,
    )
