"""The case studies' co-design problems, each solved three ways with `designs.codesign`, each converged.

What a case file needs to state its co-design problem, and nothing that knows the cases (the report that
collects them is `studies.codesign_report`):

- the records of an answer (`Design`, one method's; `CaseResult`, a problem's), and their fresh
  evaluation (`measure`, `evaluate`);
- actuator sizing (`ActuatorSizing` + `actuator_sizing`): the smallest limit meeting the specs, for the
  arm, UUV and ball on beam; the sequential method sizes for holding the target at rest and then tunes
  the gains, the nested one bisects on the limit with each limit decided by a converged feasibility
  search, the simultaneous one decides the limit as a gain;
- a plant parameter with the controller (`codesign_case`): the crane's cable length and the satellite's
  panel stiffness, by `designs.codesign.codesign`;
- the open-loop problems of a user's plant, the catalog's spring and mass (no case study), which
  `studies.codesign_open_loop` decides with the cases' own: the largest displacement in a fixed time
  (`SPRING_MASS_PROBLEM`) and a minimum-energy transfer priced by the stiffness, whose J*(k) has a local
  minimum below each resonance (`SPRING_TRANSFER_PROBLEM`).
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np

import models
from designs.codesign import (
    METHODS,
    SizingProblem,
    check_methods,
    codesign,
    size_actuator,
    size_actuator_simultaneous,
)
from designs.codesign_global import codesign_globally
from designs.pid import PID, max_equilibrium_input
from designs.tuning import Cost, Scenario, SolveOptions, Specs, TuningProblem, TuningSetup, checked_options, tune
from models import catalog, deferred
from mpc import Collocation, OptimalControlProblem

from .case import CaseStudy
from .trajectories import OpenLoopCodesign, TrajectorySetup

optimize = deferred.module("scipy.optimize")

log = logging.getLogger(__name__)
#: How the plant-parameter problems are solved (crane, satellite; `codesign_case`): compiled, IPOPT on the
#: exact Hessian (few gains, so second derivatives are cheap; see docs/notes/tuning.md).
CODESIGN_SOLVE_OPTIONS = SolveOptions(jit=True, hessian="exact")
#: Their specs' form on the smoothed stages: one soft maximum per spec and run, not one row per sample.
CODESIGN_PATHS = "aggregated"
#: The method name that runs the global layer (`designs.codesign_global.codesign_globally`) on a
#: plant-parameter problem, beside (or, given alone, instead of) the local `METHODS`.
GLOBAL = "global"
#: The global layer's sweep there: a grid of this many points over the range, ends included, the best
#: `GLOBAL_KEEP` local minima refined by the simultaneous method, within `GLOBAL_MAX_SECONDS` (estimated).
GLOBAL_SAMPLES, GLOBAL_KEEP, GLOBAL_MAX_SECONDS = 12, 2, 4 * 3600.0
#: Where the global layer's sweep runs when `codesign_case` is given no ``map``: set by `sweep_on`.
_SWEEP_MAP: contextvars.ContextVar[Callable | None] = contextvars.ContextVar("sweep_map", default=None)


@contextlib.contextmanager
def sweep_on(map: Callable | None) -> Iterator[None]:
    """Within the block, the global layer of every `codesign_case` sweeps through `map(function, items)`
    (a `studies.distributed` executor's ``map``; the case files' problem functions need not pass it)."""
    token = _SWEEP_MAP.set(map)
    try:
        yield
    finally:
        _SWEEP_MAP.reset(token)


# ----------------------------------------------------------------- records
@dataclass
class Design:
    """One method's answer to one problem.

    method : one of `METHODS`
    value : the designed plant value, in the problem's `unit`
    objective : what the problem minimizes: the limit itself (actuator sizing)
        or closed_loop_cost + plant_cost (crane, satellite)
    closed_loop_cost : ITAE of the tracked coordinate on the problem's scenario
        (units of the coordinate × s²); for actuator sizing only reported, not minimized
    plant_cost : the plant's price in the objective's units (actuator sizing: the limit)
    feasible : every spec holds (and |u| stays within the limit) on a fresh evaluation
    violations : the specs violated, by name (empty when feasible)
    measured : numbers of a fresh `models.simulate_closed_loop` run: rise_time_s (the
        time after which the output stays beyond 90 % of the step; inf if never),
        overshoot (fraction of the step), peak_input (units of u), and max_abs_<state>
        for each bounded state (rad)
    wall_time : s spent by this method
    converged : every optimizer the answer rests on stopped on its convergence test
    status : the solvers' statuses (IPOPT's return status, the outer optimizer's)
    message : what the optimizer said
    gains : the controller's gains, name -> list
    plant, block : the designed plant and controller (for re-simulation; not printed; None when
        the design was read from a record)
    """

    method: str
    value: float
    objective: float
    closed_loop_cost: float
    plant_cost: float
    feasible: bool
    violations: list
    measured: dict
    wall_time: float
    message: str
    gains: dict
    plant: models.Plant | None = field(repr=False)
    block: models.Block | None = field(repr=False)
    converged: bool = False
    status: str = ""


@dataclass
class CaseResult:
    """The answers of every method to one co-design problem.

    key : short name used by the CLI ("arm", "crane", ...)
    problem : one line for the table
    plant : registry name of the plant the problem designs (in `models`)
    parameter, unit : the designed plant parameter (for example "input limit", "N m")
    text_value : its value in the text
    objective : what is minimized, in words
    scenario, specs, cost : the closed-loop run every design is judged on (None when read from a record)
    designs : method -> Design, for the `METHODS` run
    notes : choices made, in words
    global_layer : the global layer's answer (`global_summary`), or None where it was not run
    """

    key: str
    problem: str
    plant: str
    parameter: str
    unit: str
    text_value: float
    objective: str
    scenario: Scenario | None = field(repr=False)
    specs: Specs | None = field(repr=False)
    cost: Cost | None = field(repr=False)
    designs: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    global_layer: dict | None = None

    def best(self, methods) -> Design | None:
        """The feasible design of lowest objective among `methods`, None when none is feasible."""
        found = [self.designs[m] for m in methods if m in self.designs and self.designs[m].feasible]
        return min(found, key=lambda d: d.objective) if found else None

    @property
    def gain(self) -> float | None:
        """1 − best simultaneous objective / best of sequential and nested (feasible ones); None if either lacks one."""
        sim = self.best(("simultaneous", "simultaneous from sequential"))
        base = self.best(("sequential", "nested"))
        if sim is None or base is None:
            return None
        return 1.0 - sim.objective / base.objective

    @property
    def converged(self) -> bool:
        """Every method of `METHODS` answered, and each converged (a method not run is not converged)."""
        return set(self.designs) == set(METHODS) and all(d.converged for d in self.designs.values())


# ----------------------------------------------------------------- fresh evaluation
def step_scenario(plant: models.Plant, tracked: str, step: float, duration: float) -> Scenario:
    """A step of `step` on the tracked coordinate from the plant's standard equilibrium, `duration` s."""
    xe, _ = plant.equilibrium()
    k = plant.state_names.index(tracked)
    return Scenario(reference=float(xe[k] + step), duration=duration, x0=xe, tracked=tracked)


def measure(plant: models.Plant, block: models.Block, scenario: Scenario, specs: Specs) -> dict:
    """Rise time, overshoot, peak input and bounded-state peaks of one fresh simulation.

    rise_time_s : first sample time after which the tracked coordinate stays beyond 90 %
        of the step (inf when it ends below); overshoot : fraction of the step;
        peak_input : max |u| (units of u); max_abs_<name> for each state in specs.state_bounds
    """
    k = plant.state_names.index(scenario.tracked)
    reference = scenario.reference
    if not isinstance(reference, (int, float)):
        raise TypeError(f"measure needs a constant step reference, got {reference!r}")
    x0 = plant.equilibrium()[0] if scenario.x0 is None else np.asarray(scenario.x0, dtype=float)
    run = models.simulate_closed_loop(
        plant,
        block,
        scenario.reference,
        scenario.duration,
        x0=x0,
        input_disturbance=scenario.input_disturbance,
        allow_divergence=True,
    )
    step = float(reference) - x0[k]
    y = np.sign(step) * (run.x[1:, k] - x0[k]) / abs(step)  # fraction of the step, samples 1..N
    below = np.flatnonzero(y < 0.9)
    if below.size == 0:
        rise = float(run.t[1])
    elif below[-1] == y.size - 1:
        rise = np.inf
    else:
        rise = float(run.t[1:][below[-1] + 1])
    out = {"rise_time_s": rise, "overshoot": float(np.max(y) - 1.0), "peak_input": float(np.max(np.abs(run.u)))}
    for name in specs.state_bounds:
        out[f"max_abs_{name}"] = float(np.max(np.abs(run.state(name))))
    return out


def evaluate(plant, block, scenario, specs, cost) -> tuple[float, list]:
    """(closed-loop cost, violated specs) of a design, from a fresh `TuningProblem`."""
    problem = TuningProblem(plant, block, scenario, specs=specs, cost=cost)
    value, _, violations = problem.values(problem.start())
    return value, violations


def listed_gains(gains: dict) -> dict:
    """A block's gains as JSON-ready lists, name -> list."""
    return {k: np.asarray(v, dtype=float).tolist() for k, v in gains.items()}


def announce(problem: str, design) -> None:
    """Log one method's answer as soon as it is found (a `Design` or a `designs.codesign.CodesignResult`)."""
    value = design.value if isinstance(design, Design) else next(iter(design.params.values()))
    log.info(
        "  %s, %s: %s → objective %s%s; %s; %.0f s",
        problem,
        design.method,
        format(value, ".4g"),
        format(design.objective, ".4g"),
        "" if design.feasible else " (infeasible)",
        design.status if design.converged else f"not converged ({design.status})",
        design.wall_time,
    )


# ----------------------------------------------------------------- actuator sizing
#: Bisection stops when high / low − 1 < this.
SIZING_REL_TOL = 0.01


@dataclass(frozen=True)
class ActuatorSizing:
    """A case's actuator-sizing problem: the smallest limit meeting its step specs.

    Attributes
    ----------
    text_limit : the actuator limit in the text (units of u)
    high : the largest limit considered (units of u); every method searches up to it
    hand_range : (low, high) where the text's rule still designs (its bisection, a note)
    duration : s of each sizing run (long enough to see the response settle)
    parameter : what is sized, in words ("torque limit")
    hand_design : known Plant -> Block, the text's design re-derived at the plant's limit
        (the text's procedure, reported as a note)
    retune_start : known Plant -> Block, the controller tuned at each limit, starting from
        the hand design's gains at the text's limit; its state must not depend on its own
        saturation (the simultaneous method decides the limit as a gain, see
        `designs.codesign.ActuatorLimit`)
    specs : Specs every limit is judged on, independent of any design (the text's or a stated requirement)
    specs_origin : where `specs` come from, in words
    free : gains re-tuned (default all)
    """

    text_limit: float
    high: float
    hand_range: tuple
    duration: float
    parameter: str
    hand_design: Callable[[models.Plant], models.Block]
    retune_start: Callable[[models.Plant], models.Block]
    specs: Specs
    specs_origin: str
    free: tuple | None = None


def pid_at(pid: PID, known: models.Plant, limit: float | None) -> PID:
    """The same PD block reading `known`, saturating at `limit` (no integrator)."""
    return PID(
        known,
        pid.coordinate,
        kp=float(pid.gains["kp"]),
        kd=float(pid.gains["kd"]),
        sample_period=pid.sample_period,
        sigma=pid.sigma,
        derivative_on=pid.derivative_on,
        output_limit=limit,
        feedforward=pid.has_feedforward,
        name=pid.name,
    )


def sizing_scenario(case: CaseStudy, sizing: ActuatorSizing) -> Scenario:
    """The case's step from the standard equilibrium, no disturbance, over the sizing duration."""
    return step_scenario(models.get(case.plant), case.tracked, case.step, sizing.duration)


def holding_limit(case: CaseStudy, sizing: ActuatorSizing) -> float:
    """Largest equilibrium input along the step, units of u: no smaller limit can hold the target."""
    plant = models.get(case.plant)
    scenario = sizing_scenario(case, sizing)
    assert scenario.x0 is not None, "step_scenario starts at the standard equilibrium"
    start = scenario.x0[plant.state_names.index(case.tracked)]
    value, _ = max_equilibrium_input(plant, {case.tracked: tuple(sorted((start, scenario.reference)))})
    return value


def actuator_sizing(
    case: CaseStudy,
    sizing: ActuatorSizing,
    *,
    rel_tol: float = SIZING_REL_TOL,
    methods=METHODS,
    options: SolveOptions | None = None,
) -> CaseResult:
    """Smallest actuator limit meeting the specs, three ways (see the module docstring).

    The limit is searched in [holding limit, `sizing.high`]: no smaller limit holds the
    target at rest. The objective is the limit itself; the ITAE is reported.

    Parameters
    ----------
    case, sizing : the case and its `ActuatorSizing`
    rel_tol : relative resolution of the bisections on the limit
    methods : which of `METHODS` to run
    options : SolveOptions of every tuning (phase one always on; default `SolveOptions()`)
    """
    methods = tuple(m for m in methods if m != GLOBAL)  # a bisection on a monotone feasibility: one basin
    check_methods(methods)
    run = CaseSizing(case, sizing, rel_tol, checked_options(options))
    for method in METHODS:
        if method in methods:
            run.solve(method)
    run.result.notes.append(run.hand_rule_note())
    return run.result


class CaseSizing:
    """One case's actuator sizing, each method a step (`solve`), filling `result` (a `CaseResult`).

    plant : the case's registered plant;  scenario : `sizing_scenario`;  floor : `holding_limit`
    options : the tunings' SolveOptions, phase one on
    """

    def __init__(self, case: CaseStudy, sizing: ActuatorSizing, rel_tol: float, options: SolveOptions):
        self.case, self.sizing, self.rel_tol = case, sizing, rel_tol
        self.options = replace(options, phase=True)
        self.plant = models.get(case.plant)
        self.scenario = sizing_scenario(case, sizing)
        self.floor = holding_limit(case, sizing)
        unit, floor = case.input_unit, self.floor
        self.result = CaseResult(
            key=case.plant,
            problem=f"actuator sizing: {case.plant}",
            plant=case.plant,
            parameter=sizing.parameter,
            unit=unit,
            text_value=sizing.text_limit,
            objective="smallest limit meeting the specs",
            scenario=self.scenario,
            specs=sizing.specs,
            cost=Cost("itae"),
            notes=[
                f"spec: {sizing.specs_origin}",
                f"step {case.step:.4g} from the standard equilibrium, "
                f"{self.scenario.duration:g} s run; limits searched in [{floor:.4g}, {sizing.high:g}] {unit}",
                f"plant-only objective of the sequential method: the smallest limit that holds the target at rest "
                f"(the largest equilibrium input along the step, {floor:.4g} {unit})",
            ],
        )

    def problem(self) -> SizingProblem:
        """The sizing over [holding limit, sizing.high] of the re-tuned design (ValueError when empty)."""
        sizing = self.sizing
        return SizingProblem(
            self.plant,
            sizing.retune_start,
            self.scenario,
            sizing.specs,
            low=self.floor,
            high=sizing.high,
            free=sizing.free,
        )

    def design(self, method, plant, block, started, message, converged, status) -> Design:
        """The `Design` of `block` on `plant` (the plant at the limit found), judged afresh."""
        wall_time = time.perf_counter() - started
        scenario, specs = self.scenario, self.sizing.specs
        itae, violations = evaluate(plant, block, scenario, specs, Cost("itae"))
        limit = float(plant.input_limit[0])
        return Design(
            method=method,
            value=limit,
            objective=limit,
            closed_loop_cost=itae,
            plant_cost=limit,
            feasible=not violations,
            violations=violations,
            measured=measure(plant, block, scenario, specs),
            wall_time=wall_time,
            message=message,
            gains=listed_gains(block.gains),
            plant=plant,
            block=block,
            converged=converged,
            status=status,
        )

    def solve(self, method: str) -> None:
        """Solve one of `METHODS`, its design added to `result` (a nested search that fails, as a note)."""
        started = time.perf_counter()
        if method == "sequential":
            found = self.sequential(started)
        elif method == "nested":
            try:
                found = self.nested(started)
            except ValueError as err:
                self.result.notes.append(f"nested: {err}")
                return
        else:
            found = self.simultaneous(method, started)
        self.result.designs[method] = found
        announce(self.result.problem, found)

    def sequential(self, started: float) -> Design:
        """Control-blind: the holding limit, then the gains tuned for it."""
        sized = self.plant.with_input_limit(self.floor)
        sizing = self.sizing
        setup = TuningSetup(sized, sizing.retune_start(sized), self.scenario, specs=sizing.specs, free=sizing.free)
        tuned = tune(setup, self.options)
        return self.design(
            "sequential",
            sized,
            tuned.block,
            started,
            f"the holding limit, then the gains tuned for it: {tuned.message}",
            tuned.stopped_on_test,
            f"IPOPT: {tuned.status}",
        )

    def nested(self, started: float) -> Design:
        """A bisection on the limit, each limit decided by a feasibility search, the gains tuned at the end."""
        rel_tol = self.rel_tol
        nested = size_actuator(self.problem(), retune=True, rel_tol=rel_tol, options=self.options)
        counts = {s: nested["statuses"].count(s) for s in dict.fromkeys(nested["statuses"])}
        status = "bisection to rel_tol {:g}; each limit decided by a feasibility search, its status: {}".format(
            rel_tol, ", ".join(f"{s} x{c}" for s, c in counts.items())
        )
        if nested["retries"]:
            status += f" ({nested['retries']} after a numerical stop, repeated from the best gains so far)"
        status += f"; the gains at the limit found tuned for ITAE: IPOPT: {nested['final'].status}"
        return self.design(
            "nested",
            self.plant.with_input_limit(nested["limit"]),
            nested["block"],
            started,
            f"bisection over [{self.floor:.4g}, {self.sizing.high:g}], {nested['evaluations']} limits decided",
            nested["converged"],
            status,
        )

    def simultaneous(self, method: str, started: float) -> Design:
        """The limit decided as a gain, from the middle of the range and the hand gains, or from the
        sequential answer; settled by the bisection's own test when within rel_tol of the holding limit."""
        if method == "simultaneous":
            start_limit, start_block = (self.floor + self.sizing.high) / 2, None
        else:
            seq = self.result.designs["sequential"]
            start_limit, start_block = seq.value, seq.block
        sim = size_actuator_simultaneous(
            self.problem(), start_limit=start_limit, start_block=start_block, options=self.options
        )
        where = (
            "from the middle of the range and the hand gains" if start_block is None else "from the sequential answer"
        )
        design = self.design(
            method,
            self.plant.with_input_limit(sim["limit"]),
            sim["block"],
            started,
            f"{where}: {sim['message']}",
            sim["converged"],
            sim["status"],
        )
        if not design.converged and design.feasible and design.value <= self.floor * (1 + self.rel_tol):
            # The bisection's own test: the smallest limit lies in [floor, limit], narrower than rel_tol.
            design = replace(
                design,
                converged=True,
                status=f"{design.status}; settled: feasible within rel_tol {self.rel_tol:g} of the holding limit "
                f"{self.floor:.4g} {self.case.input_unit}, below which no limit holds the target at rest",
            )
        return design

    def hand_rule_note(self) -> str:
        """The text's procedure for comparison: the hand rule re-derived at each limit, bisection."""
        case, sizing, plant, scenario, specs = self.case, self.sizing, self.plant, self.scenario, self.sizing.specs
        text_plant = plant.with_input_limit(sizing.text_limit)
        hand = measure(text_plant, sizing.hand_design(text_plant), scenario, specs)
        low, high = sizing.hand_range
        try:
            rule = size_actuator(
                SizingProblem(plant, sizing.hand_design, scenario, specs, low=low, high=high),
                retune=False,
                rel_tol=self.rel_tol,
            )
            found = f"the smallest limit at which it meets the specs is {rule['limit']:.4g} {case.input_unit}"
        except ValueError as err:
            found = f"re-derived at each limit up to {high:g} {case.input_unit} it never meets the specs ({err})"
        return (
            f"hand design (the text's rule) at the text's {sizing.text_limit:g} {case.input_unit}: rise time "
            f"{hand['rise_time_s']:.3g} s, overshoot {100 * hand['overshoot']:.2g} %, peak |u| "
            f"{hand['peak_input']:.4g} {case.input_unit}; {found}"
        )


# ----------------------------------------------------------------- plant + controller (codesign)
def _codesign_design(res, name, result: CaseResult) -> Design:
    """The `Design` of one `designs.codesign.CodesignResult` for parameter `name`, measured afresh."""
    assert result.scenario is not None and result.specs is not None, "a solved problem, not a record"
    return Design(
        method=res.method,
        value=float(res.params[name]),
        objective=res.objective,
        closed_loop_cost=res.closed_loop_cost,
        plant_cost=res.plant_cost,
        feasible=res.feasible,
        violations=list(res.violations),
        measured=measure(res.plant, res.block, result.scenario, result.specs),
        wall_time=res.wall_time,
        message=res.message,
        gains=listed_gains(res.block.gains),
        plant=res.plant,
        block=res.block,
        converged=res.converged,
        status=res.status,
    )


def codesign_case(
    result: CaseResult,
    setup: TuningSetup,
    name: str,
    low: float,
    high: float,
    plant_cost,
    *,
    methods=METHODS,
    options: SolveOptions = CODESIGN_SOLVE_OPTIONS,
    nested_start: str = "nearest",
    map: Callable | None = None,
) -> CaseResult:
    """Fill `result` with `designs.codesign.codesign`'s answers (its own numbers, plus a fresh `measure`).

    setup : what is tuned (its scenario, specs and cost those of `result`)
    name : the plant parameter decided within [low, high]
    plant_cost : its price (dict name -> value or CasADi symbol -> objective units), which is also
        the sequential method's plant-only objective
    methods : which of `METHODS` to run, and `GLOBAL` for the global layer (`result.global_layer`)
    options, nested_start : of every solve and of the nested method (`designs.codesign.codesign`)
    map : the global layer's ``map(function, items)`` for its sweep (a `studies.distributed` executor's),
        or None: the one of `sweep_on`, else this process
    """
    local = tuple(m for m in methods if m != GLOBAL)
    if local:
        answers = codesign(
            setup,
            {name: (low, high)},
            plant_cost=plant_cost,
            options=options,
            methods=local,
            nested_start=nested_start,
            progress=lambda answer: announce(result.problem, answer),
        )
        for method, answer in answers.items():
            result.designs[method] = _codesign_design(answer, name, result)
    result.notes.append(
        f"plant-only objective of the sequential method: the plant's price alone, minimized over [{low:g}, {high:g}]"
    )
    if GLOBAL in methods:
        found = codesign_globally(
            setup,
            {name: (low, high)},
            method="simultaneous",
            plant_cost=plant_cost,
            options=options,
            samples=GLOBAL_SAMPLES,
            keep=GLOBAL_KEEP,
            max_seconds=GLOBAL_MAX_SECONDS,
            map=map if map is not None else _SWEEP_MAP.get(),
        )
        result.global_layer = global_summary(found, name)
        log.info("%s: global layer, %s", result.problem, found.how)
    return result


def global_summary(found, name: str) -> dict:
    """JSON-able record of a `mpc.global_search.GlobalResult` on the one parameter `name`: the sweep's
    design, every distinct local optimum (value, objective, converged, status, start), the best, how it was
    chosen, whether it converged, and the wall time (s)."""
    optima = [
        {
            "value": float(o.params[name]),
            "objective": float(o.objective),
            "success": bool(o.success),
            "status": str(o.status),
            "start": float(o.start[name]),
        }
        for o in found.optima
    ]
    return {
        "method": str(found.extra.get("method", "")),
        "design": found.design,
        "sweep": [[float(p[name]), float(v), bool(ok)] for p, v, ok in found.sweep],
        "optima": optima,
        "best": {"value": float(found.best.params[name]), "objective": float(found.best.objective)},
        "converged": bool(found.converged),
        "how": found.how,
        "wall_time": float(found.wall_time),
    }


# ---------------------------------------------------------------------------- the spring-mass
#: The mass (kg, the plant's, `models.catalog.spring_mass`), the fixed final time (s) and the stiffness range (N/m).
SPRING_MASS = next(param.value for param in catalog.spring_mass.params if param.name == "m")
SPRING_TIME, SPRING_RANGE = 2.0, (0.1, 2.0)


def spring_mass_plant() -> models.Plant:
    """m s'' = −k s + u, |u| <= 1 N, m = 1 kg; k (N/m) to be chosen (declared in `models.catalog`)."""
    return models.Plant(catalog.spring_mass)


def spring_mass(quick: bool) -> TrajectorySetup:
    """Maximize s(T) at T = 2 s from rest, with s'(T) = 0 and |u| <= 1, choosing k in [0.1, 2] N/m."""
    ocp = OptimalControlProblem(spring_mass_plant(), SPRING_TIME)
    ocp.choose("k", *SPRING_RANGE)
    ocp.maximize(ocp.at_end(ocp.x.s))
    ocp.subject_to(ocp.at_start(ocp.state) == 0)
    ocp.subject_to(ocp.at_end(ocp.x.ds) == 0)
    return TrajectorySetup(
        ocp,
        Collocation(intervals=40 if quick else 100),
        {},
        "s(T) (m), maximized",
        f"m s'' = −k s + u, m = {SPRING_MASS:g} kg, from rest; maximize the displacement s(T) at T = "
        f"{SPRING_TIME:g} s with s'(T) = 0 and |u| ≤ 1 N, choosing the stiffness k in [{SPRING_RANGE[0]:g}, "
        f"{SPRING_RANGE[1]:g}] N/m and the force history together.",
    )


def spring_mass_semi_analytic() -> dict:
    """One-switch bang-bang (Pontryagin; derived in tests/mpc/test_ocp_codesign.py):

    s*(k) = [2 √(1 − sin²θ / 4) − 1 − cos θ] / k with θ = √(k/m) T, maximized over k by a bounded scalar search.
    Returns {"parameter": k (N/m), "objective": s*(k) (m), "how": text}.
    """

    def best(k):
        """s*(k) (m), the largest displacement with the stiffness k (N/m) fixed."""
        theta = math.sqrt(k / SPRING_MASS) * SPRING_TIME
        return (2 * math.sqrt(1 - math.sin(theta) ** 2 / 4) - 1 - math.cos(theta)) / k

    found = optimize.minimize_scalar(
        lambda k: -best(k), bounds=SPRING_RANGE, method="bounded", options={"xatol": 1e-12}
    )
    return {
        "parameter": float(found.x),
        "objective": float(-found.fun),
        "how": "one-switch bang-bang, s*(k) in closed form, maximized over k",
    }


SPRING_MASS_PROBLEM = OpenLoopCodesign(
    "spring_mass",
    "spring-mass: stiffness and force history (issue 13)",
    "spring and mass (user-declared)",
    spring_mass,
    "k",
    "N/m",
    maximized=True,
    sweep=(0.25, 0.5, 1.0, 1.5, 2.0),
    reference=spring_mass_semi_analytic,
)


# ---------------------------------------------------------------------------- the spring's transfer
#: The minimum-energy transfer: final time (s), half the distance (m, from −d to +d at rest), the stiffness's
#: price (J per N/m) and its range (N/m), wide enough for three resonances (ωT = π, 3π, 5π).
TRANSFER_TIME, TRANSFER_DISTANCE, STIFFNESS_PRICE, TRANSFER_RANGE = 2.0, 0.05, 1e-3, (0.5, 70.0)
#: The transfer's starting stiffness (N/m), from which both local methods stop on the second local optimum.
TRANSFER_GUESS = 20.0


def spring_transfer_ocp(guess: float | None = TRANSFER_GUESS) -> OptimalControlProblem:
    """Move the spring's mass from rest at −d to rest at +d in T with the least ½∫u² dt + c·k, choosing k.

    A function of this module (picklable by name), so that `mpc.global_search.codesign` may send it to other
    processes. guess : the starting stiffness (N/m; None: the plant's).
    """
    ocp = OptimalControlProblem(spring_mass_plant(), TRANSFER_TIME)
    k = ocp.choose("k", *TRANSFER_RANGE, guess=guess)
    ocp.minimize(ocp.integral(ocp.u.u**2 / 2) + STIFFNESS_PRICE * k)
    ocp.subject_to(ocp.at_start(ocp.state) == [-TRANSFER_DISTANCE, 0])
    ocp.subject_to(ocp.at_end(ocp.state) == [TRANSFER_DISTANCE, 0])
    return ocp


def spring_transfer(quick: bool) -> TrajectorySetup:
    """`spring_transfer_ocp` on 40 (quick) or 80 collocation intervals."""
    d, (low, high) = TRANSFER_DISTANCE, TRANSFER_RANGE
    return TrajectorySetup(
        spring_transfer_ocp(),
        Collocation(intervals=40 if quick else 80),
        {},
        "½∫u² dt + c k (J), minimized",
        f"m s'' = −k s + u, m = {SPRING_MASS:g} kg; move from rest at s = −{d:g} m to rest at +{d:g} m in "
        f"T = {TRANSFER_TIME:g} s with the least energy ½∫u² dt plus the stiffness's price {STIFFNESS_PRICE:g} k, "
        f"choosing k in [{low:g}, {high:g}] N/m (started at {TRANSFER_GUESS:g} N/m). The free motion makes the "
        "transfer at no energy where ωT is an odd multiple of π, so J*(k) has a local minimum below each such "
        "stiffness in the range.",
    )


def spring_transfer_reference() -> dict:
    """The global optimum of J*(k) = ½ rᵀ W(T)⁻¹ r + c k (W the controllability Gramian, by Van Loan's
    exponential; r = x_T − e^{AT} x_0): a scan of 2001 stiffnesses, its best local minimum polished by a
    bounded Brent search. Returns {"parameter": k (N/m), "objective": J (J), "how": text, "minima": [(k, J)]}."""
    linalg = deferred.module("scipy.linalg")

    def optimum(k):
        A = np.array([[0.0, 1.0], [-k / SPRING_MASS, 0.0]])
        B = np.array([[0.0], [1.0 / SPRING_MASS]])
        van_loan = np.zeros((4, 4))
        van_loan[:2, :2], van_loan[:2, 2:], van_loan[2:, 2:] = -A, B @ B.T, A.T
        E = linalg.expm(van_loan * TRANSFER_TIME)
        r = np.array([TRANSFER_DISTANCE, 0.0]) - linalg.expm(A * TRANSFER_TIME) @ np.array([-TRANSFER_DISTANCE, 0.0])
        return 0.5 * float(r @ np.linalg.solve(E[2:, 2:].T @ E[:2, 2:], r)) + STIFFNESS_PRICE * k

    ks = np.linspace(*TRANSFER_RANGE, 2001)
    js = np.array([optimum(k) for k in ks])
    minima = []
    for i in np.flatnonzero((js[1:-1] < js[:-2]) & (js[1:-1] < js[2:])) + 1:
        found = optimize.minimize_scalar(optimum, bounds=(ks[i - 1], ks[i + 1]), method="bounded")
        minima.append((float(found.x), float(found.fun)))
    minima.sort(key=lambda m: m[1])
    return {
        "parameter": minima[0][0],
        "objective": minima[0][1],
        "how": f"the controllability Gramian's minimum energy, scanned: {len(minima)} local minima, the best",
        "minima": minima,
    }


SPRING_TRANSFER_PROBLEM = OpenLoopCodesign(
    "spring_transfer",
    "spring-mass: stiffness for a minimum-energy transfer (several local optima)",
    "spring and mass (user-declared)",
    spring_transfer,
    "k",
    "N/m",
    sweep=(2.0, 10.0, 22.0, 40.0, 61.0),
    reference=spring_transfer_reference,
)
