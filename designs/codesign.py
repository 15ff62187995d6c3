"""Plant/controller co-design: plant parameters and gains decided together, against fair baselines.

The closed loop of `designs.tuning` already takes the plant parameters as a
symbolic input, so co-design adds the chosen parameters to the decision
vector and a plant cost to the objective:

    minimize   closed-loop cost(gains, p) + plant_cost(p)
    subject to the specs on the nonlinear closed loop, p_low <= p <= p_high

`codesign` answers it three ways, each solved to convergence (`Codesign`, one
method a step):

- sequential (control-blind, as the co-design literature defines it): the
  plant parameters minimize a plant-only objective (default `plant_cost`)
  within their ranges, then the best controller for that plant is tuned;
- nested: an outer optimizer on the plant parameters (bounded Brent for one
  parameter, Powell for several), each of its evaluations a converged inner
  tuning of the gains at those parameters;
- simultaneous: gains and parameters in one IPOPT problem, started from a
  neutral point (the middle of each range, the starting controller's gains)
  and from the sequential answer.

Actuator sizing (`size_actuator`, the smallest symmetric limit meeting the
specs of a `SizingProblem`) is the same comparison for a limit: the nested
method bisects on the limit with the gains re-tuned at each, the simultaneous
one decides the limit as one more decision (`ActuatorLimit`, a saturation
whose level is a gain).

Every solve here runs with `SolveOptions.phase` on: a start outside the specs
is first moved by a phase one. The measurements behind the constants are in
docs/notes/tuning.md.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

import models
from models import Block, Plant, deferred
from models.checks import boolean, positive, real

from .tuning import (
    MAX_ITER,
    Cost,
    Scenario,
    SolveOptions,
    Specs,
    TuningProblem,
    TuningResult,
    TuningSetup,
    checked_options,
    gain_bounds,
    solve,
    tune,
)

scipy = deferred.module("scipy")

METHODS = ("sequential", "nested", "simultaneous", "simultaneous from sequential")
#: Where the nested method's inner tunings start (`codesign`'s `nested_start`).
NESTED_STARTS = ("nearest", "neutral")
#: Statuses of an IPOPT solve that stopped on a convergence test (local infeasibility included).
STOPPED_BY_TEST = ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Infeasible_Problem_Detected")
#: The simultaneous sizing's regularizing tie-break weight (`size_actuator_simultaneous` solves with it
#: first, then at its own smaller `cost_weight` from that answer): with a weak tie-break alone the gains
#: are nearly free at the answer and IPOPT creeps.
SIZING_COST_WEIGHT = 0.03
#: The simultaneous sizing's own tie-break weight (the default `cost_weight`), reached from the above.
SIZING_TIE_BREAK = 1e-3
#: Most limits `size_actuator` may try (a bisection of 2^-60 relative resolution needs fewer).
MAX_BISECTIONS = 60


@dataclass
class CodesignResult:
    """One co-design answer.

    method : one of `METHODS`
    params : the chosen values of the designed plant parameters (SI)
    plant : the plant with those values;  block : the controller with its gains
    objective : closed_loop_cost + plant_cost (exact closed loop)
    feasible, violations : as in `TuningResult`
    converged : every optimizer this answer rests on stopped on its convergence test
    status : the solvers' statuses in words (IPOPT's return status, the outer optimizer's)
    message : what happened
    evaluations : inner tunings (nested) or IPOPT solves made
    wall_time : s
    history : the last solve's (seconds, objective) per iteration, or the nested method's
        (parameter values, inner objective) per evaluation
    """

    method: str
    params: dict
    plant: Plant
    block: Block
    objective: float
    closed_loop_cost: float
    plant_cost: float
    feasible: bool
    success: bool
    message: str
    violations: list
    wall_time: float
    converged: bool = False
    status: str = ""
    evaluations: int = 1
    history: list = field(default_factory=list)


def _plant_cost_function(names, plant_cost) -> ca.Function:
    """Function p (len(names),) -> plant_cost({name: p_i}) (zero without a plant cost)."""
    p = ca.MX.sym("p", len(names))
    value = plant_cost({n: p[i] for i, n in enumerate(names)}) if plant_cost else ca.MX(0)
    return ca.Function("plant_cost", [p], [value])


def check_ranges(plant: Plant, design_params) -> dict:
    """{name: (low, high)} checked: known parameters, finite low < high, the current value inside."""
    if not isinstance(design_params, Mapping):
        raise TypeError(f"design_params must be a dict name -> (low, high), got {design_params!r}")
    if not design_params:
        raise ValueError("design_params is empty: name the plant parameters to co-design")
    ranges = {}
    for name, pair in design_params.items():
        if name not in plant.params:
            raise ValueError(f"{plant.name} has no parameter {name!r}; its parameters are {', '.join(plant.params)}")
        if isinstance(pair, (str, bytes)) or not isinstance(pair, Sequence) or len(pair) != 2:
            raise ValueError(f"design_params[{name!r}] must be a pair (low, high), got {pair!r}")
        low, high = (real(v, f"design_params[{name!r}] bound", finite=False) for v in pair)
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ValueError(f"range of {name} must be finite with low < high, got ({low}, {high})")
        plant.with_params(**{name: low})
        plant.with_params(**{name: high})
        if not low <= plant.params[name] <= high:
            raise ValueError(f"{name} = {plant.params[name]} starts outside its range ({low}, {high})")
        ranges[name] = (low, high)
    return ranges


def check_methods(methods) -> None:
    """Raise unless `methods` is a non-empty sequence of `METHODS` whose start from the sequential
    answer comes with "sequential"."""
    if isinstance(methods, str) or not isinstance(methods, Sequence) or not methods:
        raise TypeError(f"methods must be a non-empty sequence of {METHODS}, got {methods!r}")
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise ValueError(f"unknown co-design method {bad}; choose from {', '.join(METHODS)}")
    if "simultaneous from sequential" in methods and "sequential" not in methods:
        raise ValueError("'simultaneous from sequential' needs 'sequential' among the methods")


def codesign(
    setup: TuningSetup,
    design_params: dict,
    *,
    plant_cost: Callable | None = None,
    plant_objective: Callable | None = None,
    options: SolveOptions | None = None,
    methods: Sequence[str] = METHODS,
    nested_tol: float = 1e-3,
    nested_start: str = "nearest",
    progress: Callable[[CodesignResult], None] | None = None,
) -> dict[str, CodesignResult]:
    """Co-design the named plant parameters with the block's gains: sequential, nested, simultaneous.

    Parameters
    ----------
    setup : TuningSetup, its plant's current values the plant the controller starts on, its block the
        starting controller (usually the hand design), its bounds holding in every method; parameters
        listed in `setup.samples` rows are overwritten by the decision for the designed names
    design_params : dict name -> (low, high), the parameters to decide and their ranges (SI)
    plant_cost : callable dict name -> MX symbol -> MX scalar, the price of the plant in the
        objective (for example ``lambda p: 0.1 * p["k"]``); default zero
    plant_objective : the sequential method's plant-only objective, same form (default
        `plant_cost`; one of the two must be given)
    options : SolveOptions of every solve (phase one always on; default `SolveOptions()`)
    methods : which of `METHODS` to run (the simultaneous start from the sequential
        answer needs "sequential")
    nested_tol : the nested outer optimizer's tolerance on each parameter, a fraction of its range
    nested_start : where each inner tuning of the nested method starts: "nearest" (the gains of the
        nearest parameters tuned so far, the block's for the first) or "neutral" (always the block's)
    progress : called with each method's answer as soon as it is found (the methods can take hours)

    Returns
    -------
    dict method -> CodesignResult for each method run, in the order of `METHODS`.
    """
    if not isinstance(setup, TuningSetup):
        raise TypeError(f"setup must be a designs.tuning.TuningSetup, got {type(setup).__name__}")
    ranges = check_ranges(setup.plant, design_params)
    for what, fn in (("plant_cost", plant_cost), ("plant_objective", plant_objective)):
        if fn is not None and not callable(fn):
            raise TypeError(f"{what} must be callable dict name -> CasADi symbol -> scalar, got {fn!r}")
    options = checked_options(options)
    check_methods(methods)
    nested_tol = positive(nested_tol, "nested_tol")
    if nested_tol >= 1:
        raise ValueError(f"nested_tol must be a fraction of the range below 1, got {nested_tol}")
    if nested_start not in NESTED_STARTS:
        raise ValueError(f"nested_start must be one of {NESTED_STARTS}, got {nested_start!r}")
    if plant_objective is None and plant_cost is None and "sequential" in methods:
        raise ValueError("the sequential method needs a plant-only objective: give plant_objective or plant_cost")
    # Validated once, before any solve: the joint problem and its bounds.
    problem = Codesign(setup, ranges, plant_cost, plant_objective or plant_cost, options)
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be callable with a CodesignResult, got {progress!r}")
    answers: dict[str, CodesignResult] = {}
    steps = {
        "sequential": problem.sequential,
        "nested": lambda: problem.nested(nested_tol, from_nearest=nested_start == "nearest"),
        "simultaneous": problem.simultaneous,
        "simultaneous from sequential": lambda: problem.simultaneous_from(answers["sequential"]),
    }
    for method in METHODS:
        if method in methods:
            answers[method] = answer = steps[method]()
            if progress is not None:
                progress(answer)
    return answers


class Codesign:
    """One co-design problem, each of its methods a step (`sequential`, `nested`, `simultaneous`,
    `simultaneous_from`), each returning its `CodesignResult`.

    Built from checked arguments (see `codesign`): the joint problem (the free gains, then the designed
    parameters in the order of `ranges`) and its bounds, and the plant cost as a Function of the
    parameters. Every solve runs with `options` and the phase one on.
    """

    def __init__(
        self,
        setup: TuningSetup,
        ranges: dict,
        plant_cost: Callable | None,
        plant_only: Callable | None,
        options: SolveOptions,
    ):
        self.setup, self.ranges, self.plant_only = setup, ranges, plant_only
        self.names = tuple(ranges)
        self.options = replace(options, phase=True)
        self.joint = setup.problem(self.names)
        self.lbx, self.ubx = self.joint_bounds(self.joint)
        self.cost_fn = _plant_cost_function(self.names, plant_cost)

    def __getstate__(self) -> dict:
        """Everything but the joint problem (CasADi MX, not picklable), which `__setstate__` builds again
        from the setup: the problem travels to other processes (`designs.codesign_global`'s sweep)."""
        state = dict(self.__dict__)
        state.pop("joint")
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.joint = self.setup.problem(self.names)

    def joint_bounds(self, problem: TuningProblem) -> tuple[np.ndarray, np.ndarray]:
        """(lbx, ubx) of a joint problem: the setup's gain bounds, then each designed parameter's range."""
        lbx, ubx = gain_bounds(problem, self.setup.bounds)
        lbx[problem.n_gains :] = [self.ranges[n][0] for n in self.names]
        ubx[problem.n_gains :] = [self.ranges[n][1] for n in self.names]
        return lbx, ubx

    def _answer(self, method, problem: TuningProblem, result: TuningResult, started, where: str) -> CodesignResult:
        """The `CodesignResult` of one joint solve: its parameters, plant and costs split."""
        assert result.decision is not None, "tuning.solve always returns its decision vector"
        values = dict(zip(self.names, (float(v) for v in result.decision[problem.n_gains :])))
        plant_cost_value = float(self.cost_fn(result.decision[problem.n_gains :]))
        return CodesignResult(
            method=method,
            params=values,
            plant=problem.plant.with_params(**values),
            block=result.block,
            objective=result.cost,
            closed_loop_cost=result.cost - plant_cost_value,
            plant_cost=plant_cost_value,
            feasible=result.feasible,
            success=result.converged and result.feasible,
            message=where + result.message,
            violations=result.violations,
            wall_time=time.perf_counter() - started,
            converged=result.converged,
            status=f"IPOPT: {result.status}",
            evaluations=len(result.stages),
            history=result.history,
        )

    def sequential(self) -> CodesignResult:
        """Control-blind: the parameters from the plant-only objective, then the best controller for them."""
        started = time.perf_counter()
        names, setup = self.names, self.setup
        p = ca.MX.sym("p", len(names))
        assert self.plant_only is not None, "codesign checks that the sequential method has its objective"
        objective = self.plant_only({n: p[i] for i, n in enumerate(names)})
        low, high = np.array([self.ranges[n] for n in names]).T
        start = np.array([setup.plant.params[n] for n in names])
        plant_solver = ca.nlpsol(
            "plant_only",
            "ipopt",
            {"x": p, "f": objective},
            {
                "ipopt": {"print_level": 0, "sb": "yes", "tol": self.options.tol, "max_iter": MAX_ITER},
                "print_time": False,
                "error_on_fail": False,
            },
        )
        sol = plant_solver(x0=start, lbx=low, ubx=high)
        plant_status = plant_solver.stats()["return_status"]
        values = dict(zip(names, np.clip(np.asarray(sol["x"]).ravel(), low, high)))
        designed = setup.plant.with_params(**values)
        problem = replace(setup, plant=designed).problem()
        lbx, ubx = gain_bounds(problem, setup.bounds)
        tuned = solve(problem, lbx, ubx, self.options)
        plant_cost_value = float(self.cost_fn(list(values.values())))
        converged = plant_status in STOPPED_BY_TEST[:2] and tuned.stopped_on_test
        return CodesignResult(
            method="sequential",
            params={k: float(v) for k, v in values.items()},
            plant=designed,
            block=tuned.block,
            objective=tuned.cost + plant_cost_value,
            closed_loop_cost=tuned.cost,
            plant_cost=plant_cost_value,
            feasible=tuned.feasible,
            success=converged and tuned.feasible,
            message=f"plant-only objective: IPOPT {plant_status}; controller: {tuned.message}",
            violations=tuned.violations,
            wall_time=time.perf_counter() - started,
            converged=converged,
            status=f"plant: IPOPT: {plant_status}; controller: IPOPT: {tuned.status}",
            evaluations=2,
            history=tuned.history,
        )

    def inner(self, values: np.ndarray, tried: list, from_nearest: bool) -> tuple[TuningResult, float]:
        """One evaluation of the nested method at parameter `values`: a converged tuning of the gains, from
        the gains of the nearest evaluation in `tried` (`from_nearest`) or from the block's; (its result,
        the value the outer optimizer sees), the evaluation appended to `tried`.

        Each tuning is the joint problem with the parameters fixed by their bounds (IPOPT takes them as
        constants), so one compiled NLP serves every evaluation. Infeasible answers lose to every feasible
        one, and the least infeasible wins.
        """
        joint, n = self.joint, self.joint.n_gains
        low, high = self.lbx[n:], self.ubx[n:]
        values = np.clip(values, low, high)
        start = joint.start()
        if tried and from_nearest:
            nearest = min(tried, key=lambda item: float(np.max(np.abs(item[0] - values) / (high - low))))[1].decision
            assert nearest is not None, "tuning.solve always returns its decision vector"
            start[:n] = nearest[:n]
        start[n:] = values
        fixed_low, fixed_high = self.lbx.copy(), self.ubx.copy()
        fixed_low[n:] = fixed_high[n:] = values
        result = solve(joint, fixed_low, fixed_high, self.options, start=start)
        value = result.cost + float(self.cost_fn(values))
        if not result.feasible or not np.isfinite(value):
            assert result.decision is not None, "tuning.solve always returns its decision vector"
            excess = (
                joint.excess(np.asarray(joint.evaluate(result.decision)[1]).ravel())
                if np.isfinite(result.cost)
                else np.array([np.inf])
            )
            worst = float(np.max(excess, initial=0.0))
            value = 1e6 * (1.0 + abs(result.initial_cost)) * (1.0 + min(worst, 1e6))
        tried.append((values, result, value))
        return result, value

    def nested(self, nested_tol: float, from_nearest: bool = True, bracket=None) -> CodesignResult:
        """Outer optimizer on the parameters (bounded Brent for one, Powell for several, to `nested_tol` of
        each range), each evaluation an `inner` tuning; the best evaluation is the answer.

        bracket : None (the whole ranges, Powell from their middle) or (low, high) arrays inside them: the
            search is kept to that box, Powell started at its middle (the global layer's refinement)
        """
        started = time.perf_counter()
        n, names = self.joint.n_gains, self.names
        low, high = self.lbx[n:], self.ubx[n:]
        if bracket is not None:
            low, high = (np.clip(np.asarray(b, dtype=float), self.lbx[n:], self.ubx[n:]) for b in bracket)
        tried: list[tuple[np.ndarray, TuningResult, float]] = []
        if len(names) == 1:
            outer = scipy.optimize.minimize_scalar(
                lambda v: self.inner(np.atleast_1d(v), tried, from_nearest)[1],
                bounds=(low[0], high[0]),
                method="bounded",
                options={"xatol": nested_tol * (self.ubx[n:] - self.lbx[n:])[0], "maxiter": 500},
            )
            outer_ok, outer_text = bool(outer.success), f"bounded Brent: {outer.message}"
        else:
            outer = scipy.optimize.minimize(
                lambda v: self.inner(v, tried, from_nearest)[1],
                (low + high) / 2,
                method="Powell",
                bounds=list(zip(low, high)),
                options={"xtol": nested_tol, "ftol": 1e-9, "maxiter": 500},
            )
            outer_ok, outer_text = bool(outer.success), f"Powell: {outer.message}"
        values, result, _ = min(tried, key=lambda item: item[2])
        plant_cost_value = float(self.cost_fn(values))
        converged = outer_ok and result.converged
        return CodesignResult(
            method="nested",
            params={n: float(v) for n, v in zip(names, values)},
            plant=self.setup.plant.with_params(**dict(zip(names, values))),
            block=result.block,
            objective=result.cost + plant_cost_value,
            closed_loop_cost=result.cost,
            plant_cost=plant_cost_value,
            feasible=result.feasible,
            success=converged and result.feasible,
            message=f"{outer_text} after {len(tried)} inner tunings; at the answer: {result.message}",
            violations=result.violations,
            wall_time=time.perf_counter() - started,
            converged=converged,
            status=f"outer: {outer_text}; inner: IPOPT: {result.status}",
            evaluations=len(tried),
            history=[(float(v[0]) if len(v) == 1 else v.tolist(), float(f)) for v, _, f in tried],
        )

    def solve_joint(self, method: str, problem: TuningProblem, start, where: str) -> CodesignResult:
        """One IPOPT problem on gains and parameters together, from `start` (None: the problem's own)."""
        started = time.perf_counter()
        lbx, ubx = (self.lbx, self.ubx) if problem is self.joint else self.joint_bounds(problem)
        result = solve(
            problem, lbx, ubx, self.options, plant_cost=lambda x: self.cost_fn(x[problem.n_gains :]), start=start
        )
        return self._answer(method, problem, result, started, where)

    def simultaneous(self) -> CodesignResult:
        """Simultaneous from a neutral start: the middle of each range, the block's gains."""
        neutral = self.joint.start()
        neutral[self.joint.n_gains :] = [(low + high) / 2 for low, high in self.ranges.values()]
        return self.solve_joint("simultaneous", self.joint, neutral, "from the middle of the ranges: ")

    def simultaneous_from(self, sequential: CodesignResult) -> CodesignResult:
        """Simultaneous from the sequential answer (its plant and controller)."""
        problem = replace(self.setup, plant=sequential.plant, block=sequential.block).problem(self.names)
        return self.solve_joint("simultaneous from sequential", problem, None, "from the sequential answer: ")


# ----------------------------------------------------------------- actuator sizing
class ActuatorLimit(Block):
    """`block`, its command then saturated at ±"actuator_limit", a gain: the limit becomes a decision.

    Used on a plant whose own limit is at least any value the gain takes, the
    plant receives exactly sat(u, actuator_limit). Equivalent to `block` built
    for that limit when `block`'s state does not depend on its own saturation
    (no back-calculation or observer anti-windup): saturating twice is
    saturating once at the smaller limit.
    """

    def __init__(self, block: Block, limit: float):
        if not isinstance(block, Block):
            raise TypeError(f"ActuatorLimit needs a models.Block, got {type(block).__name__}")
        if "actuator_limit" in block.gains:
            raise ValueError(f"{block.name} already has a gain named 'actuator_limit'")
        self.block = block
        limit = positive(limit, "limit")
        super().__init__(
            sample_period=block.sample_period,
            n_state=block.n_state,
            n_measured=block.n_measured,
            n_reference=block.n_reference,
            n_input=block.n_input,
            gains=dict(block.gains) | {"actuator_limit": limit},
            measures=block.measures,
            name=f"{block.name} (limit decided)",
        )

    def expr(self, xc, y, r, gains):
        xc_next, u = self.block.expr(xc, y, r, {k: v for k, v in gains.items() if k != "actuator_limit"})
        return xc_next, models.saturate(ca.vertcat(u), gains["actuator_limit"])

    def initial_state(self, y0, r0):
        return self.block.initial_state(y0, r0)

    def with_gains(self, **gains) -> ActuatorLimit:
        new = super().with_gains(**gains)
        new.block = self.block.with_gains(**{k: v for k, v in new.gains.items() if k != "actuator_limit"})
        return new


@dataclass(frozen=True, eq=False)
class SizingProblem:
    """The smallest symmetric actuator limit in [low, high] at which `design`'s loop meets the specs.

    plant : the plant, its limit replaced by each limit tried (units of u)
    design : callable Plant -> Block, the design at the plant's limit (for example a saturation-rule PD
        whose gains depend on the limit)
    scenario : a `models.scenario.Scenario` or several
    specs : the `models.specs.Specs` every limit is judged on
    low, high : the range searched, 0 < low < high (units of u)
    free, bounds, substeps, paths : of every tuning, as in `TuningSetup` (the gains to tune, default all)

    Checked when made.
    """

    plant: Plant
    design: Callable[[Plant], Block]
    scenario: Scenario | Sequence[Scenario]
    specs: Specs
    low: float
    high: float
    free: Sequence[str] | None = None
    bounds: Mapping | None = None
    substeps: int = 10
    paths: str = "pointwise"

    def __post_init__(self):
        low = real(self.low, "low", finite=False)
        high = real(self.high, "high", finite=False)
        if not (np.isfinite(low) and np.isfinite(high) and 0 < low < high):
            raise ValueError(f"need finite 0 < low < high, got low={low}, high={high}")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        if not callable(self.design):
            raise TypeError(f"design must be callable Plant -> Block, got {self.design!r}")
        if not isinstance(self.specs, Specs):
            raise TypeError(f"specs must be a models.specs.Specs, got {type(self.specs).__name__}")

    def setup(self, plant: Plant, block: Block, cost: Cost | None = None) -> TuningSetup:
        """The `TuningSetup` of `block` on `plant` (the plant at some limit), judged by the specs."""
        return TuningSetup(
            plant,
            block,
            self.scenario,
            specs=self.specs,
            cost=cost,
            free=self.free,
            bounds=self.bounds,
            substeps=self.substeps,
            paths=self.paths,
        )


def _check_rel_tol(problem: SizingProblem, rel_tol) -> float:
    """`rel_tol`, a fraction in (0, 1) that bisects [low, high] in at most `MAX_BISECTIONS` limits."""
    rel_tol = real(rel_tol, "rel_tol", finite=False)
    if not (np.isfinite(rel_tol) and 0 < rel_tol < 1):
        raise ValueError(f"rel_tol must be a fraction in (0, 1), got {rel_tol}")
    low, high = problem.low, problem.high
    needed = math.ceil(math.log2(max(math.log(high / low) / math.log1p(rel_tol), 1.0))) + 1
    if needed > MAX_BISECTIONS:
        raise ValueError(
            f"rel_tol = {rel_tol:g} over [{low:g}, {high:g}] needs {needed} limits, more than "
            f"{MAX_BISECTIONS}; give a larger rel_tol"
        )
    return rel_tol


class _Bisection:
    """The limits `size_actuator` tried: each one's verdict, the tunings' statuses and retries."""

    def __init__(self, problem: SizingProblem, retune: bool, options: SolveOptions):
        self.problem, self.retune = problem, retune
        self.options = replace(options, phase=True)
        self.history: list[tuple[float, bool]] = []
        self.statuses: list[str] = []
        self.decided: list[bool] = []
        self.best_block: Block | None = None
        self.retries = 0

    def attempt(self, limit: float) -> tuple[bool, Block, list]:
        """(feasible, the block, its violations) at `limit`: the design as designed, or (retune) gains meeting
        the specs searched from it (`SolveOptions.until_feasible`: only the verdict matters here)."""
        problem = self.problem
        sized = problem.plant.with_input_limit(limit)
        block = problem.design(sized)
        if self.retune:
            verdict = replace(self.options, until_feasible=True)
            result = tune(problem.setup(sized, block), verdict)
            if not result.stopped_on_test and self.best_block is not None:
                # A numerical stop decides nothing about this limit: once more from the gains that met the
                # specs at the smallest feasible limit so far.
                self.retries += 1
                known = {k: v for k, v in self.best_block.gains.items() if k in block.gains}
                again = tune(problem.setup(sized, block.with_gains(**known)), verdict)
                # A feasible design decides the limit whatever the other start claims; then a stop on the test.
                if (again.feasible, again.stopped_on_test) > (result.feasible, result.stopped_on_test):
                    result = again
            ok, block, violations = result.feasible, result.block, result.violations
            self.statuses.append(result.status)
            self.decided.append(result.feasible or result.stopped_on_test)
        else:
            check = problem.setup(sized, block).problem()
            violations = check.values(check.start())[2]
            ok = not violations
        self.history.append((float(limit), bool(ok)))
        return ok, block, violations


def size_actuator(
    problem: SizingProblem, *, retune: bool, rel_tol: float = 0.01, options: SolveOptions | None = None
) -> dict:
    """Smallest symmetric actuator limit in [problem.low, problem.high] for which the specs hold (bisection).

    Parameters
    ----------
    problem : SizingProblem
    retune : False checks `problem.design` as designed (the hand rule at each limit); True also decides
        each limit by searching the gains with `designs.tuning.tune` and a phase one stopped at the first
        gains meeting the specs (the nested co-design: an outer bisection on the limit, an inner converged
        feasibility problem), then tunes the gains for the cost at the limit found
    rel_tol : fraction in (0, 1); bisection stops when high / low - 1 < rel_tol (at most
        `MAX_BISECTIONS` limits)
    options : SolveOptions of the tunings when retuning (phase one always on)

    Returns
    -------
    dict: limit (the smallest feasible limit found), block (the design at that limit; retuned: with
    the gains tuned for the cost there when that tuning stays feasible), evaluations (number of
    limits tried), history [(limit, feasible)], statuses [status per searched limit], final (the
    `TuningResult` of the cost tuning at the limit; None without retune), retries (searches that
    stopped neither converged nor infeasible, repeated from the gains of the smallest feasible
    limit so far; the repeat is kept when it alone is feasible, or is as feasible and alone
    stopped on its test),
    converged (every limit's verdict is decided: gains meeting the specs were found there, or
    the tuning proved it infeasible, `TuningResult.stopped_on_test`; the sizing's objective is
    the limit, so a feasible limit needs no converged cost).

    Raises
    ------
    ValueError
        When even `high` does not meet the specs (naming the violated specs).
    """
    if not isinstance(problem, SizingProblem):
        raise TypeError(f"problem must be a designs.codesign.SizingProblem, got {type(problem).__name__}")
    rel_tol = _check_rel_tol(problem, rel_tol)
    retune = boolean(retune, "retune")
    bisection = _Bisection(problem, retune, checked_options(options))
    low, high = problem.low, problem.high
    ok, bisection.best_block, violations = bisection.attempt(high)
    if not ok:
        raise ValueError(f"even the largest limit {high:g} misses the specs: " + "; ".join(violations))
    best = high
    for _ in range(MAX_BISECTIONS):
        if high / low - 1 <= rel_tol:
            break
        mid = np.sqrt(low * high)
        ok, block, _ = bisection.attempt(mid)
        if ok:
            high, best, bisection.best_block = mid, mid, block
        else:
            low = mid
    best_block, final = bisection.best_block, None
    if retune:
        # The gains at the limit found, tuned for the cost from the feasible ones the verdict found there.
        sized = problem.plant.with_input_limit(best)
        final = tune(problem.setup(sized, best_block), bisection.options)
        if final.feasible:
            best_block = final.block
    return {
        "limit": best,
        "block": best_block,
        "evaluations": len(bisection.history),
        "history": bisection.history,
        "statuses": bisection.statuses,
        "retries": bisection.retries,
        "converged": all(bisection.decided),
        "final": final,
    }


def size_actuator_simultaneous(
    problem: SizingProblem,
    *,
    start_limit: float,
    start_block: Block | None = None,
    cost_weight: float = SIZING_TIE_BREAK,
    options: SolveOptions | None = None,
) -> dict:
    """Smallest limit and its gains in one IPOPT problem: minimize the limit subject to the specs.

    The decision is (the free gains, the limit λ in [low, high]) on `ActuatorLimit(design(plant at high))`;
    the objective is λ + cost_weight · λ₀ · J / J₀ (J the closed-loop ITAE, a tie-break among
    gains that all meet the specs at the same λ; J₀, λ₀ its and the limit's start values).
    The answer is re-built as `design(plant at λ)` with the found gains and judged on
    that block by a fresh `TuningProblem`, so what is reported is a design at the limit.

    Parameters
    ----------
    problem : SizingProblem; its design's state must not depend on its own saturation (see `ActuatorLimit`)
    start_limit : the limit to start from, in [low, high]
    start_block : the gains to start from (default ``design(plant at start_limit)``)
    cost_weight : >= 0, weight of the closed-loop cost relative to the limit; below
        `SIZING_COST_WEIGHT` the problem is solved at that weight first, then at this one from its
        answer, and the last converged feasible answer kept (its weight in "cost_weight")
    options : SolveOptions of the solves (phase one always on)

    Returns
    -------
    dict: limit, block (the design at the limit with the found gains), feasible, violations,
    converged (the solve converged, or proved the specs locally out of reach), status, message,
    result (the `TuningResult`), cost_weight.
    """
    if not isinstance(problem, SizingProblem):
        raise TypeError(f"problem must be a designs.codesign.SizingProblem, got {type(problem).__name__}")
    low, high = problem.low, problem.high
    start_limit = real(start_limit, "start_limit")
    if not low <= start_limit <= high:
        raise ValueError(f"start_limit = {start_limit:g} is outside [{low:g}, {high:g}]")
    cost_weight = real(cost_weight, "cost_weight")
    if cost_weight < 0:
        raise ValueError(f"cost_weight must be >= 0, got {cost_weight}")
    options = replace(checked_options(options), phase=True)
    top = problem.plant.with_input_limit(high)
    base = problem.design(top)
    if start_block is not None:
        base = base.with_gains(**{k: v for k, v in start_block.gains.items() if k in base.gains})
    wrapped = ActuatorLimit(base, start_limit)
    free = tuple(base.gain_names if problem.free is None else problem.free) + ("actuator_limit",)
    joint = replace(problem.setup(top, wrapped, Cost("itae")), free=free, bounds=None).problem()
    lbx, ubx = gain_bounds(joint, dict(problem.bounds or {}) | {"actuator_limit": (low, high)})
    index = list(joint.free).index("actuator_limit")
    offset = sum(np.asarray(wrapped.gains[g]).size for g in joint.free[:index])
    j0 = joint.values(joint.start())[0]
    scaled = start_limit / j0 if np.isfinite(j0) and j0 > 0 else 0.0
    # First with the regularizing weight, then at `cost_weight` from that answer; the last converged,
    # feasible answer is kept (the first one when the second creeps or fails).
    weights = (SIZING_COST_WEIGHT, cost_weight) if cost_weight < SIZING_COST_WEIGHT else (cost_weight,)
    result, point, used = None, None, cost_weight
    for w in weights:
        trial = solve(joint, lbx, ubx, options, cost_weight=w * scaled, start=point, plant_cost=lambda x: x[offset])
        if result is None or (trial.converged and trial.feasible):
            result, used = trial, w
        point = trial.decision
    assert result is not None
    assert result.decision is not None, "tuning.solve always returns its decision vector"
    limit = float(result.decision[offset])
    sized = problem.plant.with_input_limit(limit)
    gains = {k: v for k, v in result.gains.items() if k != "actuator_limit"}
    block = problem.design(sized).with_gains(**gains)
    check = TuningProblem(sized, block, problem.scenario, specs=problem.specs, substeps=problem.substeps)
    _, _, violations = check.values(check.start())
    return {
        "limit": limit,
        "block": block,
        "feasible": not violations,
        "violations": violations,
        # A proof that no limit and gains near the solve's path meet the specs (IPOPT's restoration or the
        # phase one converged outside them) is a stop on a convergence test, as for a tuning.
        "converged": result.stopped_on_test,
        "status": f"IPOPT: {result.status}",
        "message": f"tie-break weight {used:g}: {result.message}",
        "result": result,
        "cost_weight": used,
    }
