"""The phase one: gains meeting the specs, or a converged local certificate that none near the start do."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

import models
from models.checks import as_vector

from .excess import relative_excess
from .iterations import IterationLog, IterationRecorder
from .options import SolveOptions
from .problem import TuningProblem
from .settings import (
    AGREEMENT,
    IPOPT_OPTIONS,
    PHASE_ONE_FLAGS,
    PHASE_ONE_MARGIN,
    RETRIED,
    WARM_START,
    converged,
)


@dataclass
class PhaseOne:
    """What `phase_one` found.

    decision : the decision vector it ended at (n_decision,)
    excess : the largest relative excess of the exact specs there (<= 0: every spec holds)
    status : IPOPT's return status of its last solve;  converged : that status is in `CONVERGED`
    iterations : IPOPT iterations over its stages
    uphill : a stage ended farther outside the exact specs than the start: the start is returned, not
        `converged` (a smoothed stage's local minimum that the exact loop contradicts is no certificate)
    """

    decision: np.ndarray
    excess: float
    status: str
    converged: bool
    iterations: int
    uphill: bool = False

    @property
    def infeasible(self) -> bool:
        """Converged with the specs still missed: a local certificate that no decision near it meets them."""
        return self.converged and self.excess > AGREEMENT


def decision_scale(start: np.ndarray) -> np.ndarray:
    """The scale of each decision (shape of `start`): IPOPT works on z = x / scale, each decision scaled by
    its own start, so gains of different magnitudes (a crane cascade's 0.2 outer and 8000 inner) all move on
    the order of one; a zero start takes 1e-3 of the largest."""
    magnitude = np.abs(start)
    floor = 1e-3 * np.max(magnitude) if np.any(magnitude > 0) else 1.0
    return np.where(magnitude > 0, magnitude, floor)


def phase_one(problem: TuningProblem, lbx, ubx, start, options: SolveOptions | None = None) -> PhaseOne:
    """Gains meeting the specs, or a converged local certificate that none near `start` do.

    minimize s over (decision, s >= -`PHASE_ONE_MARGIN`) subject to every spec's relative
    excess (as `TuningProblem.excess` measures it) <= s, on the smoothed loop through the
    continuation's widths, each stage from the last one's answer; it stops at the first
    stage whose answer meets the exact specs. The problem is feasible for every decision
    (s large), so IPOPT usually stops on its convergence test (a local minimum of the largest
    excess), where the tuning problem itself, started outside its specs, can end in
    Restoration_Failed; a failed stage (not `converged`) is no certificate.

    Parameters
    ----------
    problem : TuningProblem;  lbx, ubx : decision bounds (n_decision,);  start : (n_decision,)
    options : its method, widths, tol, phase_iterations, phase_hessian, jit and ipopt_options are used
    """
    options = options or SolveOptions()
    lbx, ubx = np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float)
    start = np.clip(as_vector(start, problem.decision.numel(), "start"), lbx, ubx)
    smooth = options.smooth
    if smooth:
        g = problem.smoothed()[1]
        assert problem.smooth_bounds is not None, "set by smoothed()"
        lbg, ubg, _ = problem.smooth_bounds
    else:
        g, lbg, ubg = problem.g, problem.lbg, problem.ubg
    width = problem.width if smooth else ca.MX.sym("unused", 0)
    excess = relative_excess(g, lbg, ubg)
    scale = decision_scale(start)
    n = start.size
    z, s, scaling = ca.MX.sym("z", n), ca.MX.sym("s"), ca.MX.sym("scale", n)  # a parameter, as in `solve`
    excess_of = ca.Function("excess", [problem.decision, width], [excess])
    rows = excess_of(scaling * z, width) - s
    tol = options.tol
    ipopt = (
        IPOPT_OPTIONS
        | {
            "max_iter": options.phase_iterations,
            "tol": tol,
            "acceptable_tol": 100 * tol,
            "hessian_approximation": options.phase_hessian,
        }
        | dict(options.ipopt_options or {})
    )
    settings: dict[str, Any] = {"ipopt": ipopt, "print_time": False, "error_on_fail": False}
    nlp: dict[str, Any] = {"x": ca.vertcat(z, s), "p": ca.vertcat(width, scaling), "f": s, "g": rows}
    variants = {"phase_one": settings, "phase_one_warm": settings | {"ipopt": ipopt | WARM_START}}

    def make() -> tuple[IterationRecorder, dict[str, Any]]:
        # The iterates go to `options.progress` (the recorder is no part of the compiled code).
        recorder = IterationRecorder(n + 1, rows.numel(), width.numel() + n)
        recorded = {name: o | {"iteration_callback": recorder} for name, o in variants.items()}
        if options.jit:
            return recorder, models.compile.jit_nlpsols("ipopt", nlp, recorded, PHASE_ONE_FLAGS)
        return recorder, {name: ca.nlpsol(name, "ipopt", nlp, o) for name, o in recorded.items()}

    recorder, solvers = problem.cached(("phase one", smooth, options.jit, settings), make)
    recorder.log = IterationLog(options.progress)

    decision, worst = start, np.inf  # widths is never empty: the loop sets both
    at_start = problem.largest_excess(start)
    status, iterations = "not solved", 0
    z_now, s_now, multipliers = start / scale, 0.0, None
    for w in options.widths if smooth else (None,):
        for _ in range(2):
            # With L-BFGS a later stage starts at the last answer and its multipliers with the barrier
            # already small (as the continuation's): cold, a fresh memory's first steps left the answer (the
            # UUV's: from 0.11 to 3). A numerical failure is retried once from where it stopped, cold, as the
            # tuning's stages are.
            s0 = float(ca.mmax(excess_of(scale * z_now, [] if w is None else w)))
            solver = solvers["phase_one" if multipliers is None else "phase_one_warm"]
            sol = solver(
                x0=np.concatenate([z_now, [max(s0, 0.0)] if multipliers is None else [max(s0, s_now)]]),
                lbx=np.concatenate([lbx / scale, [-PHASE_ONE_MARGIN]]),
                ubx=np.concatenate([ubx / scale, [np.inf]]),
                lbg=-np.inf,
                ubg=0.0,
                p=np.concatenate([[] if w is None else [w], scale]),
                **(multipliers or {}),
            )
            stats = solver.stats()
            status, iterations = stats["return_status"], iterations + int(stats.get("iter_count", 0))
            x_now = np.asarray(sol["x"]).ravel()
            z_now, s_now = x_now[:n], float(x_now[n])
            warm = options.phase_hessian == "limited-memory" and status not in RETRIED
            multipliers = {"lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]} if warm else None
            if status not in RETRIED:
                break
        decision = np.clip(scale * z_now, lbx, ubx)
        worst = problem.largest_excess(decision)
        if not converged(status):  # a failed or capped stage may have passed a better point than its last
            decision, worst = _better_logged(problem, recorder.log, scale, lbx, ubx, (decision, worst))
        if worst > at_start:
            return PhaseOne(start, at_start, status, False, iterations, uphill=True)
        if worst <= 0 or not converged(status):
            break
    return PhaseOne(decision, worst, status, converged(status), iterations)


def _better_logged(problem: TuningProblem, log: IterationLog, scale, lbx, ubx, last: tuple) -> tuple:
    """(decision, exact largest excess): the logged iterate of smallest smoothed largest excess (s plus its
    largest row, rows = excess - s: IPOPT's iterates need not satisfy them), where the exact loop finds it
    further inside the specs than `last` (decision, excess), else `last`. Wandering L-BFGS phase ones pass
    such points (measured cases: docs/notes/tuning.md)."""
    n = scale.size
    if not log.iterates:
        return last
    i = int(np.argmin([x[n] + g for (x, _, _), g in zip(log.iterates, log.largest_g)]))
    x = log.iterates[i][0]
    decision = np.clip(scale * x[:n], lbx, ubx)
    excess = problem.largest_excess(decision)
    return (decision, excess) if excess < last[1] else last
