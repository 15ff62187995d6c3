"""The co-design report runner: each case's co-design problems, solved three ways, each converged.

Every problem is answered with `designs.codesign` and `designs.tuning` only
(IPOPT through the compiled nonlinear closed loop):

1. sequential (control-blind, as the co-design literature defines it): the
   plant from a plant-only objective (actuator sizing: the smallest limit that
   holds the target at rest; a plant parameter: its price alone), then the best
   controller for that plant (a converged tuning);
2. nested: an outer optimizer on the plant (actuator sizing: bisection on the
   limit, each limit decided by a converged feasibility search, the gains tuned
   once at the answer; a plant parameter: bounded Brent, each evaluation a
   converged tuning);
3. simultaneous: plant and gains in one IPOPT problem, started from a neutral
   point (the middle of the range, the hand design's gains) and from (1).

The report states the gain of the better simultaneous answer over the better
of (1) and (2) among the feasible ones, each answer's solver status, and the
wall times. The text's hand rule re-derived at each limit (the actuator
sizing of the text's procedure) is kept as a note.

The problems live in the case files (``CASE.codesign``: key -> function
returning a `CaseResult`): actuator sizing for the arm, UUV and ball on beam
(`ActuatorSizing` + `actuator_sizing`), the crane's cable length and the
satellite's panel stiffness (`codesign_case`).

``python -m studies.codesign_report [--out FILE] [--only KEY ...]`` runs them
(an hour or more on a shared core, most of it the nested method on the crane
and the satellite) and writes the Markdown report docs/codesign.md. The
document is built from sections (`SECTIONS`: header, table, notes), so other
co-design reports can be appended to it.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

import models
from designs.codesign import (
    METHODS,
    SIZING_COST_WEIGHT,
    SIZING_TIE_BREAK,
    check_methods,
    codesign,
    size_actuator,
    size_actuator_simultaneous,
)
from designs.pid import PID, max_equilibrium_input
from designs.tuning import Cost, Scenario, SolveOptions, Specs, TuningProblem, TuningSetup, tune
from models import files

from . import cases
from .case import CaseStudy

log = logging.getLogger(__name__)
DOC = Path(__file__).resolve().parent.parent / "docs" / "codesign.md"
#: `tune` options of the plant-parameter problems (crane, satellite; `codesign_case`): compiled, each spec
#: aggregated over the run (one constraint per bound, not one per sample) and IPOPT on the exact Hessian.
#: On the satellite's panel stiffness this converged (nested and simultaneous agreeing on the objective to
#: 2e-6) where the pointwise specs with L-BFGS were still in the first method's tuning after 40 minutes.
CODESIGN_TUNE_OPTIONS = {"jit": True, "paths": "aggregated", "hessian": "exact"}


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


# ----------------------------------------------------------------- records on disk
#: The `Design` fields a record keeps: everything but the plant and controller objects.
RECORDED = ("method", "value", "objective", "closed_loop_cost", "plant_cost", "feasible", "violations",
            "measured", "wall_time", "message", "gains", "converged", "status")  # fmt: skip
#: The `CaseResult` fields a record keeps besides its designs.
RECORDED_CASE = ("key", "problem", "plant", "parameter", "unit", "text_value", "objective", "notes")


def to_record(result: CaseResult, run: dict, kept: dict | None = None) -> dict:
    """`result` as JSON-able data (what the report prints), each design with `run`: how, when and from
    which code it was solved. `kept`: an earlier record of the problem whose designs of methods not in
    `result` are kept, each with its own run."""
    designs = dict((kept or {}).get("designs", {}))
    designs |= {
        m: {name: getattr(d, name) for name in RECORDED} | {"run": dict(run)} for m, d in result.designs.items()
    }
    return {
        **{name: getattr(result, name) for name in RECORDED_CASE},
        "designs": {m: designs[m] for m in METHODS if m in designs},
    }


def from_record(record: dict) -> CaseResult:
    """The `CaseResult` of a `to_record` record (plants, controllers and scenario left None), the
    runs its designs come from added to the notes."""
    numbers = ("value", "objective", "closed_loop_cost", "plant_cost", "wall_time")
    designs = {}
    for method, saved in record["designs"].items():
        fields: dict[str, Any] = {name: saved[name] for name in RECORDED}
        fields |= {name: float(saved[name]) for name in numbers}
        fields["measured"] = {k: float(v) for k, v in saved["measured"].items()}
        designs[method] = Design(**fields, plant=None, block=None)
    result = CaseResult(
        **{name: record[name] for name in RECORDED_CASE if name != "notes"},
        scenario=None,
        specs=None,
        cost=None,
        designs=designs,
        notes=list(record["notes"]),
    )
    result.text_value = float(result.text_value)
    runs: dict[tuple, list] = {}
    for method, saved in record["designs"].items():
        runs.setdefault(tuple(saved["run"][k] for k in ("command", "date", "commit")), []).append(method)
    for (command, date, commit), methods in runs.items():
        result.notes.append(f"{', '.join(methods)}: run by `{command}` on {date} (commit {commit})")
    return result


def _provenance(command: str) -> dict:
    """The run's command, UTC date and git commit ("+ changes" when the tree differs from it), now."""

    def git(*args):
        done = subprocess.run(["git", *args], cwd=DOC.parent, capture_output=True, text=True, check=False)
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    if git("status", "--porcelain", "--untracked-files=no"):
        commit += " + changes"
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return {"command": command, "date": date, "commit": commit}


# ----------------------------------------------------------------- fresh evaluation
def step_scenario(plant: models.Plant, tracked: str, step: float, duration: float) -> Scenario:
    """A step of `step` on the tracked coordinate from the plant's standard equilibrium."""
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


def _listed(gains: dict) -> dict:
    return {k: np.asarray(v, dtype=float).tolist() for k, v in gains.items()}


# ----------------------------------------------------------------- actuator sizing
#: Bisection stops when high / low − 1 < this.
SIZING_REL_TOL = 0.01
#: The `tune_options` that the simultaneous sizing (`size_actuator_simultaneous`) also takes.
SIMULTANEOUS_OPTIONS = ("max_iter", "tol", "jit", "widths", "paths", "hessian")


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


def _sizing_design(method, plant, block, scenario, specs, wall_time, message, converged, status) -> Design:
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
        gains=_listed(block.gains),
        plant=plant,
        block=block,
        converged=converged,
        status=status,
    )


def _announce(problem: str, design) -> None:
    """Log one method's answer as soon as it is found (a `Design` or a `CodesignResult`)."""
    value = design.value if isinstance(design, Design) else next(iter(design.params.values()))
    log.info(
        "  %s, %s: %s → objective %s%s; %s; %.0f s",
        problem,
        design.method,
        _number(value),
        _number(design.objective),
        "" if design.feasible else " (infeasible)",
        design.status if design.converged else f"not converged ({design.status})",
        design.wall_time,
    )


def actuator_sizing(
    case: CaseStudy, sizing: ActuatorSizing, *, rel_tol: float = SIZING_REL_TOL, methods=METHODS, tune_options=None
) -> CaseResult:
    """Smallest actuator limit meeting the specs, three ways (see the module docstring).

    The limit is searched in [holding limit, `sizing.high`]: no smaller limit holds the
    target at rest. The objective is the limit itself; the ITAE is reported.

    Parameters
    ----------
    case, sizing : the case and its `ActuatorSizing`
    rel_tol : relative resolution of the bisections on the limit
    methods : which of `METHODS` to run
    tune_options : keyword arguments for every `designs.tuning.tune` call (max_iter, ...)
    """
    check_methods(methods)
    plant = models.get(case.plant)
    scenario = sizing_scenario(case, sizing)
    specs = sizing.specs
    unit = case.input_unit
    floor = holding_limit(case, sizing)
    options: dict[str, Any] = {"free": sizing.free, "phase": True} | dict(tune_options or {})
    result = CaseResult(
        key=case.plant,
        problem=f"actuator sizing: {case.plant}",
        plant=case.plant,
        parameter=sizing.parameter,
        unit=unit,
        text_value=sizing.text_limit,
        objective="smallest limit meeting the specs",
        scenario=scenario,
        specs=specs,
        cost=Cost("itae"),
        notes=[
            f"spec: {sizing.specs_origin}",
            f"step {case.step:.4g} from the standard equilibrium, "
            f"{scenario.duration:g} s run; limits searched in [{floor:.4g}, {sizing.high:g}] {unit}",
            f"plant-only objective of the sequential method: the smallest limit that holds the target at rest "
            f"(the largest equilibrium input along the step, {floor:.4g} {unit})",
        ],
    )
    if "sequential" in methods:
        started = time.perf_counter()
        sized = plant.with_input_limit(floor)
        setup = TuningSetup(sized, sizing.retune_start(sized), scenario, specs=specs, free=sizing.free)
        solved: dict[str, Any] = {"phase": True} | dict(tune_options or {})
        tuned = tune(setup, SolveOptions(**solved))
        result.designs["sequential"] = _sizing_design(
            "sequential",
            sized,
            tuned.block,
            scenario,
            specs,
            time.perf_counter() - started,
            f"the holding limit, then the gains tuned for it: {tuned.message}",
            tuned.stopped_on_test,
            f"IPOPT: {tuned.status}",
        )
        _announce(result.problem, result.designs["sequential"])
    if "nested" in methods:
        started = time.perf_counter()
        try:
            nested = size_actuator(
                plant,
                sizing.retune_start,
                scenario,
                specs,
                low=floor,
                high=sizing.high,
                retune=True,
                rel_tol=rel_tol,
                tune_options=options,
            )
            counts = {s: nested["statuses"].count(s) for s in dict.fromkeys(nested["statuses"])}
            status = "bisection to rel_tol {:g}; each limit decided by a feasibility search, its status: {}".format(
                rel_tol, ", ".join(f"{s} x{c}" for s, c in counts.items())
            )
            if nested["retries"]:
                status += f" ({nested['retries']} after a numerical stop, repeated from the best gains so far)"
            status += f"; the gains at the limit found tuned for ITAE: IPOPT: {nested['final'].status}"
            result.designs["nested"] = _sizing_design(
                "nested",
                plant.with_input_limit(nested["limit"]),
                nested["block"],
                scenario,
                specs,
                time.perf_counter() - started,
                f"bisection over [{floor:.4g}, {sizing.high:g}], {nested['evaluations']} limits decided",
                nested["converged"],
                status,
            )
            _announce(result.problem, result.designs["nested"])
        except ValueError as err:
            result.notes.append(f"nested: {err}")
    for method in ("simultaneous", "simultaneous from sequential"):
        if method not in methods:
            continue
        started = time.perf_counter()
        if method == "simultaneous":
            start_limit, start_block = (floor + sizing.high) / 2, None
        else:
            seq = result.designs["sequential"]
            start_limit, start_block = seq.value, seq.block
        sim = size_actuator_simultaneous(
            plant,
            sizing.retune_start,
            scenario,
            specs,
            low=floor,
            high=sizing.high,
            start_limit=start_limit,
            start_block=start_block,
            free=sizing.free,
            **{k: v for k, v in (tune_options or {}).items() if k in SIMULTANEOUS_OPTIONS},
        )
        where = (
            "from the middle of the range and the hand gains" if start_block is None else "from the sequential answer"
        )
        design = _sizing_design(
            method,
            plant.with_input_limit(sim["limit"]),
            sim["block"],
            scenario,
            specs,
            time.perf_counter() - started,
            f"{where}: {sim['message']}",
            sim["converged"],
            sim["status"],
        )
        if not design.converged and design.feasible and design.value <= floor * (1 + rel_tol):
            # The bisection's own test: the smallest limit lies in [floor, limit], narrower than rel_tol.
            design = replace(
                design,
                converged=True,
                status=f"{design.status}; settled: feasible within rel_tol {rel_tol:g} of the holding limit "
                f"{floor:.4g} {unit}, below which no limit holds the target at rest",
            )
        result.designs[method] = design
        _announce(result.problem, result.designs[method])
    result.notes.append(_hand_rule_note(case, sizing, plant, scenario, specs, rel_tol))
    return result


def _hand_rule_note(case, sizing, plant, scenario, specs, rel_tol) -> str:
    """The text's procedure for comparison: the hand rule re-derived at each limit, bisection."""
    text_plant = plant.with_input_limit(sizing.text_limit)
    hand = measure(text_plant, sizing.hand_design(text_plant), scenario, specs)
    low, high = sizing.hand_range
    try:
        rule = size_actuator(
            plant, sizing.hand_design, scenario, specs, low=low, high=high, retune=False, rel_tol=rel_tol
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
        gains=_listed(res.block.gains),
        plant=res.plant,
        block=res.block,
        converged=res.converged,
        status=res.status,
    )


def codesign_case(
    result: CaseResult, plant, block, name, low, high, plant_cost, *, methods=METHODS, tune_options=None
) -> CaseResult:
    """Fill `result` with `designs.codesign.codesign`'s answers (its own numbers, plus a fresh `measure`).

    `name` is the plant parameter decided within [low, high], `plant_cost` its price
    (dict name -> value or CasADi symbol -> objective units), which is also the
    sequential method's plant-only objective. `tune_options` go to every solve
    (max_iter, jit, tol, ...).
    """
    answers = codesign(
        plant,
        block,
        result.scenario,
        {name: (low, high)},
        plant_cost=plant_cost,
        specs=result.specs,
        cost=result.cost,
        methods=tuple(methods),
        progress=lambda answer: _announce(result.problem, answer),
        **(tune_options or {}),
    )
    for method, answer in answers.items():
        result.designs[method] = _codesign_design(answer, name, result)
    result.notes.append(
        f"plant-only objective of the sequential method: the plant's price alone, minimized over [{low:g}, {high:g}]"
    )
    return result


def problems() -> dict[str, Callable[[], CaseResult]]:
    """CLI key -> function running the problem, over the registered cases in their order."""
    found: dict[str, Callable[[], CaseResult]] = {}
    for name in cases.names():
        found |= dict(cases.get(name).codesign)
    return found


# ----------------------------------------------------------------- report
COLUMNS = (
    "problem",
    "designed parameter",
    "text",
    "(1) sequential",
    "(2) nested",
    "(3) simultaneous",
    "(3) from (1)",
    "gain of (3) over (1), (2)",
    "wall time (1) / (2) / (3) / (3) from (1) (s)",
    "all converged",
)

HEADER = """# Co-design: sequential, nested and simultaneous

Generated by `{command}` (do not edit by hand).

Each problem is solved with `designs.codesign` / `designs.tuning`, every method to
convergence (see each case's co-design problem in `studies/cases/<name>.py`):

1. **sequential**, control-blind as the co-design literature defines it: the plant from a
   plant-only objective (actuator sizing: the smallest limit that holds the target at rest;
   a plant parameter: its price alone), then the best controller for that plant;
2. **nested**: an outer optimizer on the plant (bisection on the limit; bounded Brent on a
   parameter), each of its evaluations a converged inner problem: a tuning of the gains
   (Brent), or, since actuator sizing minimizes the limit and only each limit's verdict
   matters, a feasibility search (gains meeting the specs found there, or a proof that none
   near the search's path do), the gains then tuned for ITAE once at the limit found;
3. **simultaneous**: plant and gains in one IPOPT problem, from a neutral start (the middle
   of the range, the hand design's gains) and, in "(3) from (1)", from the sequential answer
   (actuator sizing: the limit plus a tie-break of {tie_break:g} times the ITAE, scaled, as the objective,
   solved first with a tie-break of {weight:g} and then from that answer).

A solve that starts outside the specs first runs a phase one (minimize the largest relative
spec excess); one that converges with the specs still missed is a local proof of infeasibility.
A case may solve each tuning without its specs first (`relaxed`, the satellite's): an answer
that converges and meets them is a local minimum under them too, and is kept.

Columns:

- **designed parameter**: the plant parameter decided, with its unit; **text**: its value in the text.
- **(1) ... (3) from (1)**: each method's value of the parameter and, after "→", its objective.
  Actuator sizing: the smallest limit meeting the specs (the value itself); crane and
  satellite: ITAE of the tracked coordinate plus the plant's price (m s² for the crane, rad s²
  for the satellite). "(infeasible)" marks an answer that misses a spec (judged on a fresh
  evaluation of the exact loop).
- **gain of (3) over (1), (2)**: 1 − (better feasible simultaneous objective) / (better feasible
  objective of (1) and (2)); positive: simultaneous better.
- **wall time**: seconds per method on the machine that ran the command.
- **all converged**: every optimizer behind every answer stopped on its convergence test
  (IPOPT's tolerance with the smoothing continuation settled, or a proof that a limit, or the
  limits and gains near a simultaneous solve's path, cannot meet the specs: IPOPT's or the
  phase one's, the answer then marked "(infeasible)"; the bisection's or Brent's resolution),
  none at an iteration cap; a sizing's limit where gains meeting the specs were found is
  settled even when the ITAE tuning there stopped short (its status is still listed), and a
  simultaneous sizing's feasible limit within the bisection's resolution of the holding limit
  is settled by the bisection's own test (the smallest limit lies between the two); each
  answer's statuses are listed under Notes.
"""


def _number(value: float) -> str:
    return f"{value:.4g}"


def _percent(fraction: float) -> str:
    """One decimal, or two significant digits below 0.1 % (a tie shows its size, not "-0.0 %")."""
    return f"{100 * fraction:.1f} %" if abs(fraction) >= 1e-3 else f"{100 * fraction:.2g} %"


def _cell(design: Design | None) -> str:
    if design is None:
        return "—"
    return f"{_number(design.value)} → {_number(design.objective)}" + ("" if design.feasible else " (infeasible)")


def table(results: list[CaseResult]) -> str:
    """The Markdown table of `COLUMNS`, one row per result."""
    rows = []
    for r in results:
        d = r.designs
        gain = r.gain
        times = " / ".join(f"{d[m].wall_time:.0f}" if m in d else "—" for m in METHODS)
        cells = [
            r.problem,
            f"{r.parameter} ({r.unit})",
            _number(r.text_value),
            *(_cell(d.get(m)) for m in METHODS),
            "—" if gain is None else _percent(gain),
            times,
            "yes" if r.converged else "no",
        ]
        rows.append(dict(zip(COLUMNS, cells)))
    return files.markdown_table(rows, [(c, c, str) for c in COLUMNS], literal=False)


def notes(results: list[CaseResult]) -> str:
    """Each problem's notes, then one line per answer: its numbers, statuses and message."""
    parts = ["## Notes\n"]
    for r in results:
        parts.append(f"\n**{r.problem}** ({r.objective}):\n")
        for note in r.notes:
            parts.append(f"- {note}\n")
        for method in METHODS:
            d = r.designs.get(method)
            if d is None:
                continue
            m = d.measured
            extra = "".join(f", {k} {v:.3g}" for k, v in m.items() if k.startswith("max_abs_"))
            violated = "" if d.feasible else f"; violates {'; '.join(d.violations)}"
            parts.append(
                f"- {method}: {r.parameter} = {_number(d.value)} {r.unit}, "
                f"ITAE {_number(d.closed_loop_cost)}, rise time {m['rise_time_s']:.3g} s, "
                f"overshoot {100 * m['overshoot']:.2g} %, "
                f"peak |u| {_number(m['peak_input'])}{extra}{violated}; status: {d.status}; "
                f"{d.message}\n"
            )
    return "".join(parts)


#: The document's sections in order: each a callable (results, command) -> Markdown.
SECTIONS = (
    lambda results, command: HEADER.format(command=command, weight=SIZING_COST_WEIGHT, tie_break=SIZING_TIE_BREAK),
    lambda results, command: "\n" + table(results) + "\n",
    lambda results, command: notes(results),
)


def report(results: list[CaseResult], command: str, sections=SECTIONS) -> str:
    """The whole Markdown document: the `sections` in order (header, table, notes by default)."""
    return "".join(section(results, command) for section in sections)


def _listed_methods(methods) -> str:
    return "" if methods is None else " --methods " + " ".join(f"'{m}'" if " " in m else m for m in methods)


def main(argv=None) -> int:
    found = problems()
    parser = argparse.ArgumentParser(prog="python -m studies.codesign_report", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=DOC, help=f"Markdown file to write (default {DOC})")
    parser.add_argument("--only", nargs="+", choices=list(found), help="run only these problems")
    parser.add_argument(
        "--records",
        type=Path,
        help="folder of each problem's record, KEY.json, written as soon as the problem is solved "
        "(default: beside the document, its name without .md: docs/codesign/)",
    )
    parser.add_argument(
        "--reuse", action="store_true", help="read the problems that have a record instead of solving them again"
    )
    parser.add_argument(
        "--methods",
        nargs="+",
        choices=METHODS,
        help="solve only these methods; the problem's record keeps its other methods' designs",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout)
    keys = args.only or list(found)
    records = args.records or args.out.with_suffix("")
    command = "python -m studies.codesign_report" + ("" if args.only is None else " --only " + " ".join(keys))
    results = []
    for i, key in enumerate(keys, 1):
        saved = records / f"{key}.json"
        earlier = json.loads(saved.read_text()) if saved.exists() else None
        if args.reuse and earlier is not None:
            results.append(from_record(earlier))
            print(f"[{i}/{len(keys)}] {key}: read {saved}", flush=True)
            continue
        print(f"[{i}/{len(keys)}] {key} ...", flush=True)
        # Taken before solving: the code that runs is the one checked out now.
        run = _provenance(f"python -m studies.codesign_report --only {key}" + _listed_methods(args.methods))
        started = time.perf_counter()
        r = found[key](**({} if args.methods is None else {"methods": tuple(args.methods)}))
        values = ", ".join(f"{m} {_number(d.value)}" for m, d in r.designs.items())
        print(f"{values} {r.unit} ({time.perf_counter() - started:.0f} s; record {saved})", flush=True)
        record = to_record(r, run, earlier if args.methods else None)
        files.write_json(saved, record)
        results.append(from_record(record) if args.methods else r)
    text = report(results, command + (" --reuse" if args.reuse else ""))
    print(table(results))
    files.write_text(args.out, text)
    print(f"wrote {args.out}")
    return 0 if all(r.converged for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
