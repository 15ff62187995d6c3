"""The co-design report runner: each case's co-design problems, sequential versus simultaneous.

Each problem is solved twice, both times only with `designs.codesign` and
`designs.tuning` (IPOPT through the compiled nonlinear closed loop):

* sequential: the plant first, then the controller (for actuator sizing, the
  text's hand rule re-derived at each limit; for a plant parameter,
  `codesign`'s plant-then-gains answer);
* simultaneous: plant and gains decided together (for actuator sizing, the
  gains re-tuned at each limit; for a plant parameter, `codesign`'s joint
  answer, which starts from the sequential one).

The problems live in the case files (``CASE.codesign``: key -> function
returning a `CaseResult`): actuator sizing for the arm, UUV and ball on beam
(`ActuatorSizing` + `actuator_sizing`), the crane's cable length and the
satellite's panel stiffness (`codesign_case`).

``python -m studies.codesign_report [--out FILE] [--only KEY ...]`` runs them
(5–7 minutes on one shared core, two thirds of it the crane and the satellite)
and writes the Markdown report docs/codesign.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import models
from designs.codesign import codesign, size_actuator
from designs.pid import PID, max_equilibrium_input
from designs.tuning import Cost, Scenario, Specs, TuningProblem, tune
from models import files

from . import cases
from .case import CaseStudy

DOC = Path(__file__).resolve().parent.parent / "docs" / "codesign.md"


# ----------------------------------------------------------------- records
@dataclass
class Design:
    """One method's answer to one problem.

    method : "sequential" or "simultaneous"
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
    message : what the optimizer said
    gains : the controller's gains, name -> list
    plant, block : the designed plant and controller (for re-simulation; not printed)
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
    plant: models.Plant = field(repr=False)
    block: models.Block = field(repr=False)


@dataclass
class CaseResult:
    """Sequential versus simultaneous answers to one co-design problem.

    key : short name used by the CLI ("arm", "crane", ...)
    problem : one line for the table
    plant : registry name of the plant the problem designs (in `models`)
    parameter, unit : the designed plant parameter (for example "input limit", "N m")
    text_value : its value in the text
    objective : what is minimized, in words
    scenario, specs, cost : the closed-loop run every design is judged on
    sequential, simultaneous : Design
    sequential_retuned : Design or None; crane and satellite only: the sequential plant with
        its gains tuned for as many more iterations as the simultaneous solve gets
    notes : choices made, in words
    """

    key: str
    problem: str
    plant: str
    parameter: str
    unit: str
    text_value: float
    objective: str
    scenario: Scenario = field(repr=False)
    specs: Specs = field(repr=False)
    cost: Cost = field(repr=False)
    sequential: Design = None
    simultaneous: Design = None
    sequential_retuned: Design | None = None
    notes: list = field(default_factory=list)

    @property
    def improvement(self) -> float:
        """1 − simultaneous objective / sequential objective (positive: simultaneous better)."""
        return 1.0 - self.simultaneous.objective / self.sequential.objective

    @property
    def improvement_over_retuned(self) -> float | None:
        """1 − simultaneous objective / sequential re-tuned objective, None without a re-tune."""
        if self.sequential_retuned is None:
            return None
        return 1.0 - self.simultaneous.objective / self.sequential_retuned.objective


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
    x0 = plant.equilibrium()[0] if scenario.x0 is None else np.asarray(scenario.x0, dtype=float)
    run = models.simulate_closed_loop(plant, block, scenario.reference, scenario.duration, x0=x0,
                                      input_disturbance=scenario.input_disturbance, allow_divergence=True)
    step = float(scenario.reference) - x0[k]
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
#: Overshoot allowed where the text gives none (arm I.8, ball on beam V.8): about that of ζ = 0.707.
SIZING_OVERSHOOT = 0.05
#: IPOPT iterations per limit when re-tuning.
SIZING_MAX_ITER = 40
#: Bisection stops when high / low − 1 < this.
SIZING_REL_TOL = 0.01


@dataclass(frozen=True)
class ActuatorSizing:
    """A case's actuator-sizing problem: the smallest limit meeting its step specs.

    Attributes
    ----------
    text_limit : the actuator limit in the text (units of u)
    search_range : (low, high) of the sequential bisection: low where the hand rule still designs,
        high where it meets the spec
    duration : s of each sizing run (long enough to see the response settle)
    parameter : what is sized, in words ("torque limit")
    hand_design : known Plant -> Block, the text's design re-derived at the plant's limit (sequential)
    retune_start : known Plant -> Block, the start of the gains re-tuned at each limit (simultaneous)
    specs : Specs every limit is judged on; None measures the hand design at the text's limit (its rise
        time, and at least `SIZING_OVERSHOOT` overshoot)
    specs_origin : where `specs` come from, in words
    free : gains re-tuned (default all)
    """

    text_limit: float
    search_range: tuple
    duration: float
    parameter: str
    hand_design: Callable[[models.Plant], models.Block]
    retune_start: Callable[[models.Plant], models.Block]
    specs: Specs | None = None
    specs_origin: str = ""
    free: tuple | None = None


def pid_at(pid: PID, known: models.Plant, limit: float | None) -> PID:
    """The same PD block reading `known`, saturating at `limit` (no integrator)."""
    return PID(known, pid.coordinate, kp=float(pid.gains["kp"]), kd=float(pid.gains["kd"]),
               sample_period=pid.sample_period, sigma=pid.sigma, derivative_on=pid.derivative_on,
               output_limit=limit, feedforward=pid.has_feedforward, name=pid.name)


def sizing_scenario(case: CaseStudy, sizing: ActuatorSizing) -> Scenario:
    """The case's step from the standard equilibrium, no disturbance, over the sizing duration."""
    return step_scenario(models.get(case.plant), case.tracked, case.step, sizing.duration)


def sizing_specs(case: CaseStudy, sizing: ActuatorSizing) -> tuple[Specs, str]:
    """The spec every limit is judged on, and how it was obtained.

    The sizing's own specs, or: rise time = what the hand design reaches at the
    text's limit (first sample after which it stays beyond 90 % of the step),
    overshoot ≤ `SIZING_OVERSHOOT` (or the hand design's, if larger).
    """
    if sizing.specs is not None:
        return sizing.specs, sizing.specs_origin
    plant = models.get(case.plant).with_input_limit(sizing.text_limit)
    got = measure(plant, sizing.hand_design(plant), sizing_scenario(case, sizing), Specs())
    specs = Specs(rise_time=got["rise_time_s"], max_overshoot=max(SIZING_OVERSHOOT, got["overshoot"]))
    return specs, (f"the hand PD at the text's {sizing.text_limit:g} {case.input_unit}: "
                   f"rise time {got['rise_time_s']:.3g} s, overshoot {100 * got['overshoot']:.2g} % "
                   f"(allowed {100 * specs.max_overshoot:g} %)")


def holding_limit(case: CaseStudy, sizing: ActuatorSizing) -> float:
    """Largest equilibrium input along the step, units of u: no smaller limit can hold the target."""
    plant = models.get(case.plant)
    scenario = sizing_scenario(case, sizing)
    start = scenario.x0[plant.state_names.index(case.tracked)]
    value, _ = max_equilibrium_input(plant, {case.tracked: tuple(sorted((start, scenario.reference)))})
    return value


def _sizing_design(method, plant, block, scenario, specs, wall_time, message) -> Design:
    itae, violations = evaluate(plant, block, scenario, specs, Cost("itae"))
    limit = float(plant.input_limit[0])
    return Design(method=method, value=limit, objective=limit, closed_loop_cost=itae, plant_cost=limit,
                  feasible=not violations, violations=violations, measured=measure(plant, block, scenario, specs),
                  wall_time=wall_time, message=message, gains=_listed(block.gains), plant=plant, block=block)


def actuator_sizing(case: CaseStudy, sizing: ActuatorSizing, *, max_iter: int = SIZING_MAX_ITER,
                    rel_tol: float = SIZING_REL_TOL) -> CaseResult:
    """Smallest actuator limit meeting the spec: hand rule (sequential) versus re-tuned gains (simultaneous).

    Sequential: bisection over `sizing.search_range` with the hand design re-derived
    at each limit. Simultaneous: bisection between `holding_limit` (no lower limit
    can hold the target) and the sequential answer, with the re-tuning start's gains
    tuned at each limit (ITAE, `designs.tuning.tune`). The objective is the limit itself.

    Parameters
    ----------
    case, sizing : the case and its `ActuatorSizing`
    max_iter : IPOPT iterations per limit when re-tuning
    rel_tol : relative resolution of the bisection on the limit
    """
    plant = models.get(case.plant)
    scenario = sizing_scenario(case, sizing)
    specs, origin = sizing_specs(case, sizing)
    unit = case.input_unit
    result = CaseResult(
        key=case.plant, problem=f"actuator sizing: {case.plant}", plant=case.plant, parameter=sizing.parameter,
        unit=unit, text_value=sizing.text_limit, objective="smallest limit meeting the specs", scenario=scenario,
        specs=specs, cost=Cost("itae"),
        notes=[f"spec: {origin}", f"step {case.step:.4g} from the standard equilibrium, "
               f"{scenario.duration:g} s run"])
    low, high = sizing.search_range
    started = time.perf_counter()
    seq = size_actuator(plant, sizing.hand_design, scenario, specs, low=low, high=high, retune=False,
                        rel_tol=rel_tol)
    seq_time = time.perf_counter() - started
    seq_plant = plant.with_input_limit(seq["limit"])
    result.sequential = _sizing_design("sequential", seq_plant, seq["block"], scenario, specs, seq_time,
                                       f"bisection over [{low:g}, {high:g}], {seq['evaluations']} limits tried")
    floor = holding_limit(case, sizing)
    started = time.perf_counter()
    try:
        sim = size_actuator(plant, sizing.retune_start, scenario, specs, low=floor, high=seq["limit"], retune=True,
                            rel_tol=rel_tol, tune_options={"max_iter": max_iter, "free": sizing.free})
        sim_plant, sim_block = plant.with_input_limit(sim["limit"]), sim["block"]
        message = (f"bisection over [{floor:.4g}, {seq['limit']:.4g}] (holding limit, sequential answer), "
                   f"{sim['evaluations']} limits tuned")
    except ValueError as err:  # even the sequential limit was not met after re-tuning
        sim_plant, sim_block = seq_plant, seq["block"]
        message = f"re-tuning failed at the sequential limit: {err}"
    result.simultaneous = _sizing_design("simultaneous", sim_plant, sim_block, scenario, specs,
                                         time.perf_counter() - started, message)
    text_plant = plant.with_input_limit(sizing.text_limit)
    hand = measure(text_plant, sizing.hand_design(text_plant), scenario, specs)
    result.notes += [f"holding limit (largest equilibrium input along the step): {floor:.4g} {unit}",
                     f"hand design at the text's {sizing.text_limit:g} {unit}: rise time "
                     f"{hand['rise_time_s']:.3g} s, peak |u| {hand['peak_input']:.4g} {unit}"]
    return result


# ----------------------------------------------------------------- plant + controller (codesign)
#: IPOPT iterations per solve (codesign makes three: plant, gains, both).
CODESIGN_MAX_ITER = 40


def _codesign_design(method, res, name, result: CaseResult) -> Design:
    return Design(method=method, value=float(res.params[name]), objective=res.objective,
                  closed_loop_cost=res.closed_loop_cost, plant_cost=res.plant_cost, feasible=res.feasible,
                  violations=list(res.violations),
                  measured=measure(res.plant, res.block, result.scenario, result.specs), wall_time=res.wall_time,
                  message=res.message, gains=_listed(res.block.gains), plant=res.plant, block=res.block)


def codesign_case(result: CaseResult, plant, block, name, low, high, plant_cost, max_iter, jit) -> CaseResult:
    """Fill `result` with `codesign`'s two answers (its own numbers, plus a fresh `measure`).

    `name` is the plant parameter decided within [low, high], `plant_cost` its price
    (dict name -> value or CasADi symbol -> objective units).

    Also fills `sequential_retuned`: the sequential plant with its gains tuned
    for another `max_iter` iterations, from the sequential gains and from the
    simultaneous gains, whichever ends better. The simultaneous solve continues
    from the sequential answer, so this separates what deciding the plant too
    brings from what more iterations (or a better start for the gains) bring.
    """
    answers = codesign(plant, block, result.scenario, {name: (low, high)}, plant_cost=plant_cost,
                       specs=result.specs, cost=result.cost, max_iter=max_iter, jit=jit)
    result.sequential = _codesign_design("sequential", answers["sequential"], name, result)
    result.simultaneous = _codesign_design("simultaneous", answers["simultaneous"], name, result)
    seq = result.sequential
    started = time.perf_counter()
    tries = []
    for label, start in (("sequential", seq.block), ("simultaneous", result.simultaneous.block)):
        more = tune(seq.plant, start, result.scenario, specs=result.specs, cost=result.cost, max_iter=max_iter,
                    jit=jit)
        tries.append((not more.feasible, more.cost, label, more))
    _, _, label, more = min(tries, key=lambda item: item[:2])
    others = "; ".join(f"from the {lab} gains: {_number(m.cost)}{'' if m.feasible else ' (infeasible)'}"
                       for _, _, lab, m in tries)
    result.sequential_retuned = Design(
        method="sequential, re-tuned", value=seq.value, objective=more.cost + seq.plant_cost,
        closed_loop_cost=more.cost, plant_cost=seq.plant_cost, feasible=more.feasible,
        violations=list(more.violations), measured=measure(seq.plant, more.block, result.scenario, result.specs),
        wall_time=time.perf_counter() - started,
        message=f"best of two re-tunes ({others}), from the {label} gains: {more.message}",
        gains=_listed(more.block.gains), plant=seq.plant, block=more.block)
    return result


def problems() -> dict[str, Callable[[], CaseResult]]:
    """CLI key -> function running the problem, over the registered cases in their order."""
    found = {}
    for name in cases.names():
        found |= dict(cases.get(name).codesign)
    return found


# ----------------------------------------------------------------- report
COLUMNS = ("problem", "designed parameter", "text", "sequential value", "sequential objective",
           "simultaneous value", "simultaneous objective", "improvement", "sequential re-tuned objective",
           "improvement over re-tuned", "wall time seq / sim (s)")

HEADER = """# Co-design: sequential versus simultaneous

Generated by `{command}` (do not edit by hand).

Each problem is solved twice with `designs.codesign` / `designs.tuning`:
*sequential* decides the plant first and the controller after it, *simultaneous*
decides both together (see each case's co-design problems in `studies/cases/<name>.py`).

Columns:

- **designed parameter**: the plant parameter decided, with its unit; **text**: its value in the text.
- **sequential / simultaneous value**: the value each method chose.
- **sequential / simultaneous objective**: what the problem minimizes. Actuator sizing: the
  smallest limit meeting the specs (the value itself); the sequential method re-derives the
  text's hand design at each limit, the simultaneous one re-tunes the gains at each limit.
  Crane and satellite: ITAE of the tracked coordinate plus the plant's price (m s² for the
  crane, rad s² for the satellite); `codesign`'s plant-then-gains versus joint answer.
  "(infeasible)" marks an answer that misses a spec.
- **improvement**: 1 − simultaneous objective / sequential objective.
- **sequential re-tuned objective**: crane and satellite only, the sequential plant with its gains
  tuned for as many more IPOPT iterations as the simultaneous solve gets (it starts from the
  sequential answer), from the sequential and from the simultaneous gains, the better of the two;
  **improvement over re-tuned**: 1 − simultaneous / re-tuned objective, what choosing the plant
  together with the gains brings beyond more tuning.
- **wall time**: seconds per method on the machine that ran the command.
"""


def _number(value: float) -> str:
    return f"{value:.4g}"


def _objective(design: Design | None) -> str:
    if design is None:
        return "—"
    return _number(design.objective) + ("" if design.feasible else " (infeasible)")


def table(results: list[CaseResult]) -> str:
    """The Markdown table of `COLUMNS`, one row per result."""
    rows = []
    for r in results:
        seq, sim = r.sequential, r.simultaneous
        over = r.improvement_over_retuned
        cells = [r.problem, f"{r.parameter} ({r.unit})", _number(r.text_value), _number(seq.value), _objective(seq),
                 _number(sim.value), _objective(sim), f"{100 * r.improvement:.1f} %", _objective(r.sequential_retuned),
                 "—" if over is None else f"{100 * over:.1f} %", f"{seq.wall_time:.1f} / {sim.wall_time:.1f}"]
        rows.append(dict(zip(COLUMNS, cells)))
    return files.markdown_table(rows, [(c, c, str) for c in COLUMNS], literal=False)


def report(results: list[CaseResult], command: str) -> str:
    """The whole Markdown document: header, table, and each problem's notes and specs."""
    parts = [HEADER.format(command=command), "\n", table(results), "\n## Notes\n"]
    for r in results:
        parts.append(f"\n**{r.problem}** ({r.objective}):\n")
        for note in r.notes:
            parts.append(f"- {note}\n")
        for d in (r.sequential, r.simultaneous, r.sequential_retuned):
            if d is None:
                continue
            m = d.measured
            extra = "".join(f", {k} {v:.3g}" for k, v in m.items() if k.startswith("max_abs_"))
            parts.append(f"- {d.method}: {r.parameter} = {_number(d.value)} {r.unit}, "
                         f"ITAE {_number(d.closed_loop_cost)}, rise time {m['rise_time_s']:.3g} s, "
                         f"overshoot {100 * m['overshoot']:.2g} %, "
                         f"peak |u| {_number(m['peak_input'])}{extra}; {d.message}\n")
    return "".join(parts)


def main(argv=None) -> int:
    found = problems()
    parser = argparse.ArgumentParser(prog="python -m studies.codesign_report", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=DOC, help=f"Markdown file to write (default {DOC})")
    parser.add_argument("--only", nargs="+", choices=list(found), help="run only these problems")
    args = parser.parse_args(argv)
    keys = args.only or list(found)
    results = []
    for i, key in enumerate(keys, 1):
        print(f"[{i}/{len(keys)}] {key} ...", end=" ", flush=True)
        started = time.perf_counter()
        r = found[key]()
        results.append(r)
        print(f"sequential {_number(r.sequential.value)}, simultaneous {_number(r.simultaneous.value)} {r.unit} "
              f"({time.perf_counter() - started:.0f} s)", flush=True)
    command = "python -m studies.codesign_report" + ("" if args.only is None else " --only " + " ".join(keys))
    text = report(results, command)
    print(table(results))
    files.write_text(args.out, text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
