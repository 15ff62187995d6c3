"""The smoothing continuation of one solve, as named steps: build a level, run a stage, judge a stage.

A stage is one IPOPT solve of the smoothed problem at one width, warm-started from the last; a level is
the whole problem at one integration fidelity (an optional coarse level first, then the problem's own).
The continuation stops at the first converged stage whose exact and smoothed objectives agree to
`AGREEMENT` with the same specs violated, and whose answer no longer moves the exact objective (or has
every switch outside its band, gap 0).

A stage that makes the exact problem worse than the best point seen so far (the start, or an earlier
stage's answer; judged on the exact loop: a higher cost that bought no smaller excess of the specs,
`Continuation.worse`) is stopped and undone, its start kept: at its end, or during it, once the objective
IPOPT sees has stayed `WATCH_MARGIN` above the best exact cost for `PATIENCE` iterations and the exact
loop confirms it (IPOPT then returns `STOPPED`). The next width starts from the kept point; the verdict is the kept
point's (converged only if it is a converged stage's answer). Every
stage's record says why it ended (`stop`) and IPOPT's stationarity measure at its last iterate (the
scaled dual infeasibility, `stationarity`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

import models

from .iterations import IterationLog, IterationRecorder
from .options import SolveOptions
from .phase_one import PhaseOne, decision_scale
from .problem import TuningProblem
from .result import TuningResult, answer_note, continuation_note, pick_answer
from .settings import (
    AGGREGATED_IPOPT_OPTIONS,
    AGREEMENT,
    CAPPED,
    COARSE_AGREEMENT,
    INFEASIBLE,
    IPOPT_OPTIONS,
    PATIENCE,
    RETRIED,
    SLACK,
    STAGE_TOL_FACTOR,
    STOPPED,
    TUNING_FLAGS,
    WARM_START,
    WATCH_MARGIN,
    converged,
)
from .spectral import missed_specs


def total_objective(
    problem: TuningProblem, plant_cost: Callable[[ca.MX], ca.MX] | None, cost_weight: float
) -> ca.Function:
    """Function decision -> cost_weight × the exact objective + plant_cost(decision): what a solve minimizes."""
    extra = ca.MX(0) if plant_cost is None else plant_cost(problem.decision)
    return ca.Function("total", [problem.decision], [cost_weight * problem.objective + extra])


@dataclass
class Level:
    """One level of fidelity, built: its problem, IPOPT solvers by (warm, loose), the bounds of its NLP's
    constraints, and Functions of the decision (and width) for its exact total, smoothed total and
    smoothed spec rows."""

    problem: TuningProblem
    solvers: dict[tuple[bool, bool], Any]
    lbg: np.ndarray
    ubg: np.ndarray
    exact_total: ca.Function
    smoothed_total: ca.Function
    smoothed_g: ca.Function


@dataclass
class Kept:
    """The best point seen so far: its merit (`Continuation.merit`), IPOPT's scaled point and multipliers
    there, and the verdict (status, gap, settled) of the stage that ended there (None: the start)."""

    merit: tuple[float, float]
    z: np.ndarray
    verdict: tuple[str, float, bool] | None


@dataclass
class Judgement:
    """A stage's answer judged: exact and smoothed objectives, their relative gap, and whether the exact and
    the smoothed constraints miss the same specs."""

    exact: float
    smoothed: float
    gap: float
    same: bool


class Continuation:
    """IPOPT on cost_weight × the problem's objective (+ plant_cost(decision)), smoothed by continuation.

    Parameters
    ----------
    problem : TuningProblem;  lbx, ubx : decision bounds (n_decision,)
    begin : the decision the first stage starts from (n_decision,), inside the bounds
    options : SolveOptions
    plant_cost : optional callable MX decision -> MX scalar added to the objective
    cost_weight : >= 0, the closed-loop objective's weight
    started : time.perf_counter() of the `solve` call (iterate times count from it)

    IPOPT works on the decision scaled by `decision_scale(begin)` (with the epigraph variable τ appended
    for robust="worst"); `z` is its current point and `multipliers` the last solve's, for a warm start.
    """

    def __init__(
        self,
        problem: TuningProblem,
        lbx: np.ndarray,
        ubx: np.ndarray,
        begin: np.ndarray,
        options: SolveOptions,
        *,
        plant_cost: Callable[[ca.MX], ca.MX] | None = None,
        cost_weight: float = 1.0,
        started: float | None = None,
    ):
        self.problem, self.options = problem, options
        self.lbx, self.ubx, self.begin = lbx, ubx, begin
        self.plant_cost, self.cost_weight = plant_cost, cost_weight
        self.n = problem.decision.numel()
        self.smooth, self.widths = options.smooth, tuple(options.widths)
        self.worst = problem.robust == "worst"
        self.width = problem.width if self.smooth else ca.MX.sym("unused", 0)
        self.log = IterationLog(options.progress, started)
        self.levels = self.fidelity_levels()
        scale = decision_scale(begin)
        if self.worst:
            totals = ca.Function(
                "c", [problem.decision, self.width], [problem.smoothed()[0] if self.smooth else problem.costs]
            )
            tau0 = float(ca.mmax(totals(begin, self.widths[0] if self.smooth else [])))
            self.start_z = np.concatenate([begin, [tau0]])
            self.scale = np.concatenate([scale, [max(abs(tau0), 1e-12)]])
            self.lbz, self.ubz = np.concatenate([lbx, [-np.inf]]), np.concatenate([ubx, [np.inf]])
        else:
            self.start_z, self.scale, self.lbz, self.ubz = begin, scale, lbx, ubx
        self.continuation = self.smooth and len(self.widths) > 1
        self.ipopt: dict[str, Any] = (
            IPOPT_OPTIONS
            | (AGGREGATED_IPOPT_OPTIONS if self.smooth and problem.paths == "aggregated" else {})
            | {"max_iter": int(options.max_iter), "tol": options.tol, "acceptable_tol": 100 * options.tol}
            | {"hessian_approximation": options.hessian}
            | dict(options.ipopt_options or {})
        )
        self.loose: dict[str, float] = {}
        self.variants = self._variants()
        self.solver_options = {
            name: {"ipopt": ipopt, "print_time": False, "error_on_fail": False}
            for name, ipopt in self.variants.values()
        }
        self.z = self.start_z / self.scale
        self.multipliers: dict[str, ca.DM] = {}
        self.stages: list[dict[str, Any]] = []
        self.iterations = 0
        self.status, self.gap, self.settled = "not solved", 0.0, not self.continuation
        self.total = total_objective(problem, plant_cost, cost_weight)
        self.best: Kept | None = None
        self.above, self.stationarity = 0, np.nan

    # ------------------------------------------------------------ setting up
    def fidelity_levels(self) -> list[TuningProblem]:
        """The problems solved in turn: a coarser integration first (`SolveOptions.coarse_substeps`) on a
        problem without specs, where its objective at `begin` agrees with the problem's to
        `COARSE_AGREEMENT`; then the problem itself."""
        problem, coarse = self.problem, self.options.coarse_substeps
        levels = [problem]
        if self.smooth and coarse is not None and coarse < problem.substeps and not problem.g.numel():
            lower = problem.with_substeps(coarse)
            fine_value, coarse_value = problem.values(self.begin)[0], lower.values(self.begin)[0]
            if abs(coarse_value - fine_value) <= COARSE_AGREEMENT * abs(fine_value):
                levels.insert(0, lower)
        return levels

    def _variants(self) -> dict[tuple[bool, bool], tuple[str, dict]]:
        """IPOPT's options by (warm, loose), each with its solver's name. Later stages start at the last
        answer and its multipliers, with the barrier already small; intermediate stages are solved loosely
        (`STAGE_TOL_FACTOR` times the tolerances)."""
        ipopt = self.ipopt
        variants = {(False, False): ("tuning", ipopt)}
        if self.continuation:
            self.loose = {
                "tol": STAGE_TOL_FACTOR * ipopt["tol"],
                "acceptable_tol": STAGE_TOL_FACTOR * ipopt["acceptable_tol"],
            }
            for warm, tight, name in (
                (False, False, "tuning_loose"),
                (True, True, "tuning_warm"),
                (True, False, "tuning_warm_loose"),
            ):
                variants[warm, not tight] = (name, ipopt | (WARM_START if warm else {}) | ({} if tight else self.loose))
        elif len(self.levels) > 1:  # one width: the problem's own level starts warm from the coarse level's answer
            variants[True, False] = ("tuning_warm", ipopt | WARM_START)
        return variants

    def build(self, level: TuningProblem) -> Level:
        """The level's solvers by (warm, loose), its bounds on g, and its total, smoothed total and smoothed g.

        The solvers are built once per problem and options (`TuningProblem.cached`): the decision's scale is
        a parameter of the NLP, not a constant in it, so the problem solved again from another start (each
        evaluation of a nested co-design) reuses them.
        """
        smooth, worst, cost_weight, plant_cost = self.smooth, self.worst, self.cost_weight, self.plant_cost
        xl = level.decision
        per_sample, g = level.smoothed() if smooth else (level.costs, level.g)
        if smooth:
            assert level.smooth_bounds is not None, "set by smoothed()"
            lbg, ubg, _ = level.smooth_bounds
        else:
            lbg, ubg = level.lbg, level.ubg
        extra = ca.MX(0) if plant_cost is None else plant_cost(xl)
        if worst:
            # Epigraph: minimize τ subject to every sample's total <= τ (max is not smooth).
            m = level.samples.shape[0]
            tau = ca.MX.sym("tau")
            variables, objective = ca.vertcat(xl, tau), cost_weight * tau + extra
            g = ca.vertcat(g, per_sample - tau)
            lbg, ubg = np.concatenate([lbg, np.full(m, -np.inf)]), np.concatenate([ubg, np.zeros(m)])
        else:
            variables, objective = xl, cost_weight * level.aggregate(per_sample) + extra
        size, width, options = self.start_z.size, self.width, self.solver_options

        def make() -> tuple[IterationRecorder, dict[str, Any]]:
            f_of = ca.Function("objective", [variables, level.width], [objective])
            g_of = ca.Function("constraints", [variables, level.width], [g])
            z, scaling = ca.MX.sym("z", size), ca.MX.sym("scale", size)
            decision = scaling * z
            nlp: dict[str, Any] = {
                "x": z,
                "p": ca.vertcat(width, scaling),
                "f": f_of(decision, width),
                "g": g_of(decision, width),
            }
            recorder = IterationRecorder(size, g.numel(), width.numel() + size)
            with_recorder: dict[str, Any] = {name: o | {"iteration_callback": recorder} for name, o in options.items()}
            # Compiled once without a shell and cached (models.compile); CasADi's virtual machine when impossible.
            if self.options.jit:
                return recorder, models.compile.jit_nlpsols("ipopt", nlp, with_recorder, TUNING_FLAGS)
            return recorder, {name: ca.nlpsol(name, "ipopt", nlp, o) for name, o in with_recorder.items()}

        key = ("tuning", smooth, worst, cost_weight, plant_cost, self.options.jit, options)
        recorder, built = level.cached(key, make)
        recorder.log = self.log
        total = cost_weight * level.aggregate(per_sample) + extra
        spec_rows = level.smoothed()[1] if smooth else level.g
        return Level(
            problem=level,
            solvers={key: built[name] for key, (name, _) in self.variants.items()},
            lbg=lbg,
            ubg=ubg,
            exact_total=ca.Function("total", [xl], [cost_weight * level.objective + extra]),
            smoothed_total=ca.Function("smoothed_total", [xl, level.width], [total]),
            smoothed_g=ca.Function("smoothed_constraints", [xl, level.width], [spec_rows]),
        )

    # ------------------------------------------------------------ the worsening rule
    def merit(self, decision: np.ndarray) -> tuple[float, float]:
        """(the exact specs' largest relative excess, 0 where every spec holds; the exact total) at a decision;
        a run that is not finite has an infinite total."""
        value = float(self.total(decision))
        excess = self.problem.largest_excess(decision)
        return (max(float(excess), 0.0), value if np.isfinite(value) else np.inf)

    @staticmethod
    def worse(now: tuple[float, float], best: tuple[float, float]) -> bool:
        """Whether merit `now` is worse than `best`. Meeting the specs means an excess within `AGREEMENT`.
        From a best that meets them: a higher exact total (by `AGREEMENT` relative) that still meets them,
        or one that misses them by more than `SLACK` (a smoothed stage may miss them by its width on the
        way). From a best that misses them: a higher total with a larger excess (by `AGREEMENT`)."""
        higher = not now[1] <= best[1] + AGREEMENT * abs(best[1])
        if best[0] <= AGREEMENT:
            return higher and (now[0] <= AGREEMENT or now[0] > SLACK)
        return higher and now[0] > best[0] + AGREEMENT

    @staticmethod
    def better(now: tuple[float, float], best: tuple[float, float]) -> bool:
        """Whether merit `now` replaces `best` as the best point: meeting the specs (excess within
        `AGREEMENT`) first, then the lower total; among points missing them, the smaller excess."""
        if now[0] <= AGREEMENT:
            return best[0] > AGREEMENT or now[1] < best[1]
        return best[0] > AGREEMENT and now[0] < best[0]

    def watch(self, x: np.ndarray, objective: float) -> bool:
        """IPOPT's iteration callback: True (stop) once the objective IPOPT sees has stayed more than
        `WATCH_MARGIN` above the best exact total for a multiple of `PATIENCE` iterations in a row and the
        exact loop at this iterate x (IPOPT's scaled point) is worse than the best point (`worse`) by as
        much."""
        best = self.best
        if best is None or not np.isfinite(best.merit[1]):
            return False
        ceiling = best.merit[1] + WATCH_MARGIN * abs(best.merit[1])
        if np.isfinite(objective) and objective <= ceiling:
            self.above = 0
            return False
        self.above += 1
        if self.above % PATIENCE:
            return False
        merit = self.merit(np.clip(self.scale[: self.n] * x[: self.n], self.lbx, self.ubx))
        return self.worse(merit, best.merit) and not merit[1] <= ceiling

    # ------------------------------------------------------------ one stage
    def decision(self) -> np.ndarray:
        """The decision at the current point `z` (n_decision,), within the bounds (IPOPT relaxes them ~1e-8)."""
        return np.clip(self.scale[: self.n] * self.z[: self.n], self.lbx, self.ubx)

    def run_stage(self, level: Level, w: float | None, tight: bool, warm: bool) -> tuple[str, int]:
        """One IPOPT solve at width w (None: the exact loop) from `z`; (status, iterations).

        warm : start with the last solve's multipliers and a small barrier;  tight : to the tolerance
        (else `STAGE_TOL_FACTOR` times it). A numerical failure (not an iteration cap) is retried once from
        its last point, cold, to the stage's own tolerance: a fresh quasi-Newton memory often gets past it.
        A verdict of local infeasibility that one of the solve's own iterates contradicts (it meets the
        specs on the exact loop) is retried once from the last such iterate, cold.
        """
        done, status = 0, "not solved"
        n, scale = self.n, self.scale
        self.above = 0
        for attempt in range(2):
            warm_now = warm and attempt == 0
            mark = len(self.log.iterates)
            this = level.solvers[warm_now, not tight]
            sol = this(
                x0=self.z,
                lbx=self.lbz / scale,
                ubx=self.ubz / scale,
                lbg=level.lbg,
                ubg=level.ubg,
                p=np.concatenate([[] if w is None else [w], scale]),
                **(self.multipliers if warm_now else {}),
            )
            stats = this.stats()
            status = stats["return_status"]
            done += int(stats.get("iter_count", 0))
            dual = stats.get("iterations", {}).get("inf_du", [])
            self.stationarity = float(dual[-1]) if len(dual) else np.nan
            self.z = np.asarray(sol["x"]).ravel()
            self.multipliers = {"lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]}
            if status == INFEASIBLE and attempt == 0:
                at = level.problem
                met = (
                    zz
                    for zz, _, _ in reversed(self.log.iterates[mark:])
                    if not at.values(np.clip(scale[:n] * zz[:n], self.lbx, self.ubx))[2]
                )
                witness = next(met, None)
                if witness is None:
                    break
                self.z = witness
                continue
            if status not in RETRIED:
                break
        return status, done

    def judge_stage(self, level: Level, w: float | None) -> Judgement:
        """The current point judged: its exact and smoothed (width w) objectives, their relative gap
        (inf when either is not finite), and whether both loops miss the same specs."""
        decision = self.decision()
        exact = float(level.exact_total(decision))
        seen = float(level.smoothed_total(decision, [] if w is None else w))
        gap = abs(exact - seen) / max(abs(exact), 1e-300) if np.isfinite(exact) and np.isfinite(seen) else np.inf
        same = True
        at = level.problem
        if self.smooth and at.g.numel():
            g_exact = np.asarray(at.evaluate(decision)[1]).ravel()
            g_smooth = np.asarray(level.smoothed_g(decision, [] if w is None else w)).ravel()
            same = at.violated_names(g_exact) == at.violated_names(g_smooth, smoothed=True)
        return Judgement(exact, seen, gap, same)

    def stage(self, level: Level, w: float | None, last: bool, previous: dict | None) -> tuple[dict, bool]:
        """Run and judge the stage at width w; (its record for `TuningResult.stages`, whether it ends the
        continuation). previous : the same level's last stage record, None for its first.

        Intermediate stages only start the next one: solved loosely; the stage that ends the continuation
        is then finished at the tolerance from where it stopped (a coarser level's never: it only gives
        the next level its start), started as the stage was: warm from a loose answer centred for a large
        barrier, IPOPT can creep where a cold start converges.
        """
        tight, warm = not self.continuation, bool(self.multipliers)
        status, iterations = self.run_stage(level, w, tight, warm)
        while True:
            judged = self.judge_stage(level, w)
            exact = judged.exact
            # Settled: the exact objective no longer moved from the previous stage's answer, or gap exactly
            # 0: every switch at the answer lies outside its band, so near it the smoothed problem is the
            # exact one and IPOPT's convergence on it is convergence on the exact problem.
            moved = abs(previous["exact"] - exact) if previous is not None and np.isfinite(exact) else np.inf
            self.settled = not self.continuation or judged.gap == 0.0 or moved <= AGREEMENT * abs(exact)
            ends = judged.gap <= AGREEMENT and judged.same and self.settled
            if (
                tight
                or not last
                or not (np.isfinite(exact) and converged(status))
                or not (ends or w == self.widths[-1])
            ):
                break
            tight = True
            status, more = self.run_stage(level, w, tight, warm)
            iterations += more
        self.status, self.gap = status, judged.gap
        self.iterations += iterations
        record = {
            "width": w,
            "substeps": level.problem.substeps,
            "status": status,
            "tol": self.ipopt["tol"] if tight else self.loose["tol"],
            "iterations": iterations,
            "smoothed": judged.smoothed,
            "exact": exact,
            "gap": judged.gap,
            "settled": self.settled,
            "stationarity": self.stationarity,
            "stop": _stop_reason(status, tight),
        }
        return record, ends

    # ------------------------------------------------------------ the whole continuation
    def run_level(self, level: Level, first: int, last: bool) -> list[dict]:
        """The level's stages from width index `first`: a stage stopped at IPOPT's iteration cap hands its
        last point on, cold (the verdict rests on the last stage alone, which must converge); two capped
        stages in a row, a numerical failure or a non-finite run end the level, reported, not hidden. A
        stage that ends worse than the best point seen so far (`worse`), or that `watch` stopped, is undone
        (`undone`): the next width starts from the best point, cold; at the last width the level ends there."""
        own: list[dict] = []
        for w in self.widths[first:] if self.smooth else (None,):
            mark = len(self.log.iterates)
            record, ends = self.stage(level, w, last, own[-1] if own else None)
            own.append(record)
            ends = ends and converged(record["status"])
            undone = self.undone(record, mark, ends)
            if undone and ends:
                break  # converged, at a worse point than the one kept
            if undone and (record["status"] == STOPPED or converged(record["status"])):
                continue  # the next width, from the kept point
            if not undone and not np.isfinite(record["exact"]):
                break  # no closed-loop run to go on from
            if not converged(record["status"]):
                if (
                    record["status"] == CAPPED
                    and w != self.widths[-1]
                    and not (len(own) > 1 and own[-2]["status"] == CAPPED)
                ):
                    self.multipliers = {}
                    continue
                break
            if ends:
                break
        return own

    def undone(self, record: dict, mark: int, ends: bool) -> bool:
        """The worsening rule on the stage just run (its `record`; its iterates are those logged from index
        `mark` on; `ends`: it passed the continuation's test): True when its answer is worse than the best
        point seen so far, or `watch` stopped it. Then its lowest iterate (by the objective IPOPT saw) is
        judged on the exact loop too, the best point seen so far is kept (the stage's start, unless that
        iterate beat it) and the stage's record says so. The verdict stays the stage's when it passed the
        test (a converged stage whose answer is worse than a point kept); otherwise it is the kept point's
        (not converged unless that is a converged stage's answer). When not undone, the best point is
        updated with the stage's answer."""
        assert self.best is not None, "run() sets the start as the best point"
        now = self.merit(self.decision())
        if record["status"] != STOPPED and not self.worse(now, self.best.merit):
            if self.better(now, self.best.merit):
                self.best = Kept(now, self.z.copy(), (self.status, self.gap, self.settled))
            return False
        worst_seen = self.best.merit
        seen = [(f, zz) for zz, f, _ in self.log.iterates[mark:] if np.isfinite(f)]
        if seen:
            z = min(seen, key=lambda item: item[0])[1]
            merit = self.merit(np.clip(self.scale[: self.n] * z[: self.n], self.lbx, self.ubx))
            if self.better(merit, self.best.merit):
                self.best = Kept(merit, z.copy(), None)
        record["undone"] = True
        record["stop"] = (
            f"worse than the best point so far (exact total {now[1]:.6g} against {worst_seen[1]:.6g}, specs' "
            f"excess {now[0]:.3g} against {worst_seen[0]:.3g}): undone, "
            + ("its start kept" if self.best.merit == worst_seen else "its best iterate kept")
        )
        self.z, self.multipliers = self.best.z.copy(), {}
        if ends:
            return True
        verdict = self.best.verdict
        self.status, self.gap, self.settled = verdict or (
            f"{STOPPED}: kept a point no stage converged at",
            np.inf,
            False,
        )
        return True

    def run(self) -> None:
        """Every level in turn, each from where the coarser one settled (from the start again when it
        failed); the stages, status, gap and point are left in `stages`, `status`, `gap` and `z`."""
        first = 0  # the width a level starts at: where the coarser one settled
        self.best = Kept(self.merit(self.decision()), self.z.copy(), None)
        self.log.watch = self.watch
        for number, at in enumerate(self.levels):
            last = number == len(self.levels) - 1
            own = self.run_level(self.build(at), first, last)
            self.stages += own
            if not last:
                if not (np.isfinite(own[-1]["exact"]) and converged(own[-1]["status"])):
                    self.z, self.multipliers = self.start_z / self.scale, {}  # the next level starts afresh
                else:
                    first = self.widths.index(own[-1]["width"])
        self.log.watch = None

    @property
    def converged(self) -> bool:
        """The last stage converged, its objectives agree to `AGREEMENT`, and the continuation settled."""
        return converged(self.status) and self.gap <= AGREEMENT and self.settled

    # ------------------------------------------------------------ the answer
    def result(self, start: np.ndarray, found: PhaseOne | None, prefix: str, started: float) -> TuningResult:
        """The `TuningResult` after `run`: IPOPT's final point, or a better feasible point met on the way.

        start : the decision the solve was asked to start from (the initial cost's, a fallback)
        found : the phase one run first (its answer a fallback when it met the specs), or None
        prefix : the message of the solves run before this one
        """
        problem, lbx, ubx, n = self.problem, self.lbx, self.ubx, self.n
        total = total_objective(problem, self.plant_cost, self.cost_weight)

        def judge(decision):
            return float(total(decision)), missed_specs(problem, decision)

        initial_cost, _ = judge(start)
        message = f"IPOPT: {self.status}"
        if found is not None:
            message = (
                f"started outside the specs; phase one (IPOPT: {found.status}, {found.iterations} iterations) "
                f"met them; {message}"
            )
        message = prefix + message  # in the order the solves ran
        if self.smooth:
            message += continuation_note(self.stages, self.gap, self.settled)
        iterates = [(f, self.scale[:n] * zz[:n]) for zz, f, _ in self.log.iterates]
        fallbacks = [(initial_cost, start, "start")]
        if found is not None and found.excess <= AGREEMENT:
            fallbacks.append((float(total(found.decision)), found.decision, "phase one's answer"))
        chosen = pick_answer(judge, self.decision(), iterates, fallbacks, lbx, ubx)
        message += answer_note(chosen)
        if chosen is None:
            value, violations, decision, label = np.inf, ["no finite closed-loop run"], start, "start"
        else:
            value, violations, decision, label = chosen.value, chosen.violations, chosen.decision, chosen.label
        block = problem.block_at(decision)
        return TuningResult(
            block=block,
            gains={k: v.copy() for k, v in block.gains.items()},
            initial_gains={k: v.copy() for k, v in problem.block.gains.items()},
            cost=float(value),
            initial_cost=initial_cost,
            improvement=1 - float(value) / initial_cost if initial_cost else 0.0,
            feasible=not violations,
            success=self.converged and label == "final" and not violations,
            status=self.status,
            message=message,
            violations=list(violations),
            iterations=self.iterations,
            wall_time=time.perf_counter() - started,
            decision=np.array(decision),
            history=[(stamp - started, f) for _, f, stamp in self.log.iterates],
            iterates=[np.clip(self.scale[:n] * zz[:n], lbx, ubx) for zz, _, _ in self.log.iterates],
            converged=self.converged,
            stages=self.stages,
            smoothing_gap=float(self.gap),
            method=self.options.method,
            phase_one=found,
        )


def _stop_reason(status: str, tight: bool) -> str:
    """Why a stage ended, from IPOPT's status: its convergence test (to which tolerance), its iteration cap,
    the worsening rule's stop, or a failure; `stationarity` in the stage's record gives the measure."""
    if converged(status):
        return f"IPOPT's convergence test ({'the tolerance' if tight else 'the loose stage tolerance'})"
    if status == CAPPED:
        return "IPOPT's iteration cap"
    if status == STOPPED:
        return "stopped: worse than the best point so far"
    return f"IPOPT: {status}"
