"""Co-design of the case studies: actuator sizing, the crane's cable, the satellite's panel.

Each problem is solved twice, both times only with `designs.codesign` and
`designs.tuning` (IPOPT through the compiled nonlinear closed loop):

* sequential: the plant first, then the controller (for actuator sizing, the
  text's hand rule re-derived at each limit; for the crane and the satellite,
  `codesign`'s plant-then-gains answer);
* simultaneous: plant and gains decided together (for actuator sizing, the
  gains re-tuned at each limit; for the crane and the satellite, `codesign`'s
  joint answer, which starts from the sequential one).

Problems (`PROBLEMS`, one function each, each returning a `CaseResult`):

* `actuator_sizing(name)` for "arm", "uuv", "ballbeam": the smallest
  actuator limit meeting the text's rise-time spec;
* `crane_transfer()`: the single-load crane's cable length ℓ with its state
  feedback, for the text's 10 m transfer with a bounded swing;
* `satellite_stiffness()`: the panel stiffness k with the satellite's state
  feedback.

``python -m designs.codesign_cases [--out FILE] [--only KEY ...]`` runs them
(5–7 minutes on one shared core, two thirds of it the crane and the satellite)
and writes the Markdown report docs/codesign.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import control
import numpy as np

import models
from models import files
from designs import classical, statespace_cases
from designs.codesign import codesign, size_actuator
from designs.filters import TransferFunctionBlock
from designs.pid import PID, max_equilibrium_input
from designs.tuning import Cost, Scenario, Specs, TuningProblem, tune

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
    plant : plant name in `models`
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
def _step_scenario(plant: models.Plant, step: float, duration: float) -> Scenario:
    """A step of `step` on the tracked coordinate from the plant's standard equilibrium."""
    xe, _ = plant.equilibrium()
    k = plant.state_names.index(models.case(plant.name).tracked)
    return Scenario(reference=float(xe[k] + step), duration=duration, x0=xe)


def measure(plant: models.Plant, block: models.Block, scenario: Scenario, specs: Specs) -> dict:
    """Rise time, overshoot, peak input and bounded-state peaks of one fresh simulation.

    rise_time_s : first sample time after which the tracked coordinate stays beyond 90 %
        of the step (inf when it ends below); overshoot : fraction of the step;
        peak_input : max |u| (units of u); max_abs_<name> for each state in specs.state_bounds
    """
    tracked = models.case(plant.name).tracked
    k = plant.state_names.index(tracked)
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
#: Text's actuator limit per plant (I.8: 1 N m; IV.11: the 250 N m "turbo charged" thrusters; V.8: 15 N).
TEXT_LIMIT = {"arm": 1.0, "uuv": 250.0, "ballbeam": 15.0}
#: Sequential bisection range per plant (units of u): the low end is where the hand rule still designs
#: (arm: above the 0.735 N m gravity torque; ball on beam: above the 13.23 N equilibrium force with
#: the ball at the beam's end); the high end is where it meets the spec.
SIZING_RANGE = {"arm": (0.75, 1.2), "uuv": (50.0, 250.0), "ballbeam": (13.25, 18.0)}
#: Horizon of the sizing runs, s (long enough to see the response settle).
SIZING_DURATION = {"arm": 3.0, "uuv": 5.0, "ballbeam": 6.0}
#: Overshoot allowed where the text gives none (arm I.8, ball on beam V.8): about that of ζ = 0.707.
SIZING_OVERSHOOT = 0.05
#: Text's IV.11 specs for the UUV (30 deg step): rise time < 0.9 s, overshoot < 10 %.
UUV_SPECS = Specs(rise_time=0.9, max_overshoot=0.10)
#: IPOPT iterations per limit when re-tuning.
SIZING_MAX_ITER = 40
#: Bisection stops when high / low − 1 < this.
SIZING_REL_TOL = 0.01


def hand_design(name: str, known: models.Plant) -> models.Block:
    """Sequential: the text's design re-derived for `known`'s actuator limit.

    arm, ballbeam: `designs.classical`'s saturation-rule "PD" (I.8, V.8), which
    needs a limit above the largest equilibrium input. uuv: the IV.11 root-locus
    lead-lag (its design does not depend on the limit), saturating at the limit.
    """
    if name == "uuv":  # designed once (at the text's limit, like the text) and cached
        turbo = known.with_input_limit(TEXT_LIMIT["uuv"])
        gains = classical.controllers("uuv", turbo)["lead-lag (IV.11)"].gains
        return TransferFunctionBlock(known, "phi", control.tf(gains["num"], gains["den"]),
                                     output_limit=float(known.input_limit[0]), anti_windup="none",
                                     name="lead-lag (IV.11)")
    return classical.controllers(name, known)["PD"]


def _pid_at(pid: PID, known: models.Plant, limit: float | None) -> PID:
    """The same PD block reading `known`, saturating at `limit` (no integrator)."""
    return PID(known, pid.coordinate, kp=float(pid.gains["kp"]), kd=float(pid.gains["kd"]),
               sample_period=pid.sample_period, sigma=pid.sigma, derivative_on=pid.derivative_on,
               output_limit=limit, feedforward=pid.has_feedforward, name=pid.name)


def retune_start(name: str, known: models.Plant) -> models.Block:
    """Simultaneous start: the hand design at the text's limit, saturating at `known`'s limit.

    Its gains are then re-tuned. Starting from the text's design rather than the
    rule at the new limit keeps the ball on beam's bound A_θ on θ_d (a structure
    choice, not a gain) at the text's value: the V.8 rule shrinks it with the
    limit, which would slow every re-tuned design below 15 N.
    """
    text = known.with_input_limit(TEXT_LIMIT[name])
    limit = float(known.input_limit[0])
    if name == "uuv":
        return hand_design("uuv", known)
    block = hand_design(name, text)
    if name == "arm":
        return _pid_at(block, known, limit)
    return models.Cascade(block.outer, _pid_at(block.inner, known, limit), name=block.name)


def sizing_specs(name: str) -> tuple[Specs, str]:
    """The spec every limit is judged on, and how it was obtained.

    arm, ballbeam: rise time = what the hand PD reaches at the text's limit (first
    sample after which it stays beyond 90 % of the step), overshoot ≤ 5 %;
    uuv: the text's IV.11 rise time 0.9 s and overshoot 10 %.
    """
    if name == "uuv":
        return UUV_SPECS, "IV.11: rise time < 0.9 s, overshoot < 10 %"
    plant = models.get(name).with_input_limit(TEXT_LIMIT[name])
    scenario = sizing_scenario(name)
    got = measure(plant, hand_design(name, plant), scenario, Specs())
    specs = Specs(rise_time=got["rise_time_s"], max_overshoot=max(SIZING_OVERSHOOT, got["overshoot"]))
    return specs, (f"the hand PD at the text's {TEXT_LIMIT[name]:g} {_unit(name)}: "
                   f"rise time {got['rise_time_s']:.3g} s, overshoot {100 * got['overshoot']:.2g} % "
                   f"(allowed {100 * specs.max_overshoot:g} %)")


def _unit(name: str) -> str:
    return "N" if name == "ballbeam" else "N m"


def sizing_scenario(name: str) -> Scenario:
    """The case's step (arm 50 deg, UUV 30 deg, ball on beam 0.25 → 0.40 m), no disturbance."""
    return _step_scenario(models.get(name), models.case(name).step, SIZING_DURATION[name])


def holding_limit(name: str) -> float:
    """Largest equilibrium input along the step, units of u: no smaller limit can hold the target."""
    plant = models.get(name)
    scenario = sizing_scenario(name)
    tracked = models.case(name).tracked
    start = scenario.x0[plant.state_names.index(tracked)]
    value, _ = max_equilibrium_input(plant, {tracked: tuple(sorted((start, scenario.reference)))})
    return value


def _sizing_design(method, plant, block, scenario, specs, wall_time, message) -> Design:
    itae, violations = evaluate(plant, block, scenario, specs, Cost("itae"))
    limit = float(plant.input_limit[0])
    return Design(method=method, value=limit, objective=limit, closed_loop_cost=itae, plant_cost=limit,
                  feasible=not violations, violations=violations, measured=measure(plant, block, scenario, specs),
                  wall_time=wall_time, message=message, gains=_listed(block.gains), plant=plant, block=block)


def actuator_sizing(name: str, *, max_iter: int = SIZING_MAX_ITER, rel_tol: float = SIZING_REL_TOL) -> CaseResult:
    """Smallest actuator limit meeting the rise-time spec: hand rule (sequential) versus re-tuned gains.

    Parameters
    ----------
    name : "arm" (torque, N m), "uuv" (torque, N m) or "ballbeam" (force, N)
    max_iter : IPOPT iterations per limit when re-tuning
    rel_tol : relative resolution of the bisection on the limit

    Sequential: bisection over `SIZING_RANGE` with `hand_design` re-derived at each limit.
    Simultaneous: bisection between `holding_limit` (no lower limit can hold the
    target) and the sequential answer, with `retune_start`'s gains tuned at each
    limit (ITAE, `designs.tuning.tune`). The objective is the limit itself.
    """
    if name not in TEXT_LIMIT:
        raise ValueError(f"actuator sizing is defined for {', '.join(TEXT_LIMIT)}, got {name!r}")
    plant = models.get(name)
    scenario = sizing_scenario(name)
    specs, origin = sizing_specs(name)
    unit = _unit(name)
    free = ("num",) if name == "uuv" else None
    result = CaseResult(
        key=name, problem=f"actuator sizing: {name}", plant=name,
        parameter="force limit" if name == "ballbeam" else "torque limit", unit=unit,
        text_value=TEXT_LIMIT[name], objective="smallest limit meeting the specs", scenario=scenario,
        specs=specs, cost=Cost("itae"),
        notes=[f"spec: {origin}", f"step {models.case(name).step:.4g} from the standard equilibrium, "
               f"{scenario.duration:g} s run"])
    low, high = SIZING_RANGE[name]
    started = time.perf_counter()
    seq = size_actuator(plant, lambda known: hand_design(name, known), scenario, specs, low=low, high=high,
                        retune=False, rel_tol=rel_tol)
    seq_time = time.perf_counter() - started
    seq_plant = plant.with_input_limit(seq["limit"])
    result.sequential = _sizing_design("sequential", seq_plant, seq["block"], scenario, specs, seq_time,
                                       f"bisection over [{low:g}, {high:g}], {seq['evaluations']} limits tried")
    floor = holding_limit(name)
    started = time.perf_counter()
    try:
        sim = size_actuator(plant, lambda known: retune_start(name, known), scenario, specs, low=floor,
                            high=seq["limit"], retune=True, rel_tol=rel_tol,
                            tune_options={"max_iter": max_iter, "free": free})
        sim_plant, sim_block = plant.with_input_limit(sim["limit"]), sim["block"]
        message = (f"bisection over [{floor:.4g}, {seq['limit']:.4g}] (holding limit, sequential answer), "
                   f"{sim['evaluations']} limits tuned")
    except ValueError as err:  # even the sequential limit was not met after re-tuning
        sim_plant, sim_block = seq_plant, seq["block"]
        message = f"re-tuning failed at the sequential limit: {err}"
    result.simultaneous = _sizing_design("simultaneous", sim_plant, sim_block, scenario, specs,
                                         time.perf_counter() - started, message)
    text_plant = plant.with_input_limit(TEXT_LIMIT[name])
    hand = measure(text_plant, hand_design(name, text_plant), scenario, specs)
    result.notes += [f"holding limit (largest equilibrium input along the step): {floor:.4g} {unit}",
                     f"hand design at the text's {TEXT_LIMIT[name]:g} {unit}: rise time {hand['rise_time_s']:.3g} s, "
                     f"peak |u| {hand['peak_input']:.4g} {unit}"]
    return result


# ----------------------------------------------------------------- plant + controller (codesign)
#: Crane: cable length range (m), horizon (s) and swing bound (rad).
CRANE_RANGE = (5.0, 20.0)
CRANE_DURATION = 20.0
CRANE_SWING = 0.2
#: ITAE (m s²) one joule of hoisting work is worth: 2e-4 m s²/J, so with the 500 kg load
#: (m g = 4.9 kN) each metre the load hangs higher costs about 1 m s² of ITAE, the same
#: order as the ITAE a metre of cable costs a re-tuned controller (1–3 m s²/m).
HOIST_PRICE = 2e-4
#: Satellite: stiffness range (N m/rad), horizon (s) and specs.
SATELLITE_RANGE = (0.05, 2.0)
SATELLITE_DURATION = 25.0
SATELLITE_SPECS = Specs(max_overshoot=0.05, settling_time=23.0)
#: ITAE (rad s²) one N m/rad of panel stiffness costs: 0.5 rad s² per N m/rad, so the text's
#: k = 0.15 costs 0.075 rad s², small against the hand design's ITAE (about 14 rad s²) but
#: comparable with what a re-tuned controller gains from a stiffer panel (about 1 rad s² per N m/rad).
STIFFNESS_PRICE = 0.5
#: IPOPT iterations per solve (codesign makes three: plant, gains, both).
CODESIGN_MAX_ITER = 40


def _codesign_design(method, res, name, result: CaseResult) -> Design:
    return Design(method=method, value=float(res.params[name]), objective=res.objective,
                  closed_loop_cost=res.closed_loop_cost, plant_cost=res.plant_cost, feasible=res.feasible,
                  violations=list(res.violations),
                  measured=measure(res.plant, res.block, result.scenario, result.specs), wall_time=res.wall_time,
                  message=res.message, gains=_listed(res.block.gains), plant=res.plant, block=res.block)


def _codesign_case(result: CaseResult, plant, block, name, low, high, plant_cost, max_iter, jit) -> CaseResult:
    """Fill `result` with `codesign`'s two answers (its own numbers, plus a fresh `measure`).

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


def crane_plant_cost(params: dict):
    """Hoisting work to lift the load from the longest cable to ℓ, priced: HOIST_PRICE m g (ℓ_max − ℓ).

    params : {"ell": value or CasADi symbol} (m); returns m s² (ITAE units).
    """
    crane = models.get("crane1").params
    return HOIST_PRICE * crane["m"] * crane["g"] * (CRANE_RANGE[1] - params["ell"])


def crane_transfer(*, max_iter: int = CODESIGN_MAX_ITER, jit: bool = True,
                   duration: float = CRANE_DURATION) -> CaseResult:
    """The single-load crane's cable length ℓ (m) with the text's VI.14 state feedback, 10 m transfer.

    Objective: ITAE of the trolley position x (m s²) over `duration` s plus
    `crane_plant_cost` (a shorter cable hangs the load higher, which costs
    hoisting work). Spec: |θ| ≤ `CRANE_SWING` rad all along the transfer; the
    hand design swings 0.15 rad at ℓ = 10 m and 0.18 rad at 5 m, so it is
    feasible over the whole range and the plant-first stage starts feasible.
    Uses crane1: the two-load crane doubles the state and cost of every solve,
    which does not fit this budget.
    """
    plant = models.get("crane1")
    block = statespace_cases.controllers("crane1", plant)["pole placement"]
    result = CaseResult(
        key="crane", problem="crane transfer (crane1)", plant="crane1", parameter="cable length ℓ", unit="m",
        text_value=plant.params["ell"], objective="ITAE(x) + hoisting price",
        scenario=_step_scenario(plant, models.case("crane1").step, duration),
        specs=Specs(state_bounds={"theta": CRANE_SWING}), cost=Cost("itae"),
        notes=[f"start: the text's VI.14 pole placement at ℓ = 10 m; |θ| ≤ {CRANE_SWING:g} rad; "
               f"{duration:g} s run",
               f"plant cost {HOIST_PRICE:g} m s²/J × m g (ℓ_max − ℓ), ℓ in [{CRANE_RANGE[0]:g}, "
               f"{CRANE_RANGE[1]:g}] m"])
    return _codesign_case(result, plant, block, "ell", *CRANE_RANGE, crane_plant_cost, max_iter, jit)


def satellite_plant_cost(params: dict):
    """Price of the panel's stiffness: STIFFNESS_PRICE k; params {"k": N m/rad}, returns rad s²."""
    return STIFFNESS_PRICE * params["k"]


def satellite_stiffness(*, max_iter: int = CODESIGN_MAX_ITER, jit: bool = True,
                        duration: float = SATELLITE_DURATION) -> CaseResult:
    """The satellite's panel stiffness k (N m/rad) with its pole-placement state feedback (III.15).

    Objective: ITAE of the panel angle φ (rad s²) on the text's 30 deg step plus
    `satellite_plant_cost` (a stiffer panel is heavier and dearer). Specs:
    overshoot ≤ 5 % and 2 % settling by 23 s, which the hand design meets at the
    text's k = 0.15 N m/rad (4.4 %, 22 s).
    """
    plant = models.get("satellite")
    block = statespace_cases.controllers("satellite", plant)["pole placement"]
    result = CaseResult(
        key="satellite", problem="satellite panel", plant="satellite", parameter="panel stiffness k",
        unit="N m/rad", text_value=plant.params["k"], objective="ITAE(φ) + stiffness price",
        scenario=_step_scenario(plant, models.case("satellite").step, duration), specs=SATELLITE_SPECS,
        cost=Cost("itae"),
        notes=[f"start: the pole-placement state feedback at k = 0.15; {duration:g} s run",
               f"plant cost {STIFFNESS_PRICE:g} rad s² per N m/rad × k, k in "
               f"[{SATELLITE_RANGE[0]:g}, {SATELLITE_RANGE[1]:g}] N m/rad"])
    return _codesign_case(result, plant, block, "k", *SATELLITE_RANGE, satellite_plant_cost, max_iter, jit)


#: CLI key -> function running the problem.
PROBLEMS: dict[str, Callable[[], CaseResult]] = {
    "arm": lambda: actuator_sizing("arm"),
    "uuv": lambda: actuator_sizing("uuv"),
    "ballbeam": lambda: actuator_sizing("ballbeam"),
    "crane": crane_transfer,
    "satellite": satellite_stiffness,
}


# ----------------------------------------------------------------- report
COLUMNS = ("problem", "designed parameter", "text", "sequential value", "sequential objective",
           "simultaneous value", "simultaneous objective", "improvement", "sequential re-tuned objective",
           "improvement over re-tuned", "wall time seq / sim (s)")

HEADER = """# Co-design: sequential versus simultaneous

Generated by `{command}` (do not edit by hand).

Each problem is solved twice with `designs.codesign` / `designs.tuning`:
*sequential* decides the plant first and the controller after it, *simultaneous*
decides both together (see `designs/codesign_cases.py` for the exact problems).

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
    return files.markdown_table(rows, [(c, c, str) for c in COLUMNS])


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
    parser = argparse.ArgumentParser(prog="python -m designs.codesign_cases", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=DOC, help=f"Markdown file to write (default {DOC})")
    parser.add_argument("--only", nargs="+", choices=list(PROBLEMS), help="run only these problems")
    args = parser.parse_args(argv)
    keys = args.only or list(PROBLEMS)
    results = []
    for i, key in enumerate(keys, 1):
        print(f"[{i}/{len(keys)}] {key} ...", end=" ", flush=True)
        started = time.perf_counter()
        r = PROBLEMS[key]()
        results.append(r)
        print(f"sequential {_number(r.sequential.value)}, simultaneous {_number(r.simultaneous.value)} {r.unit} "
              f"({time.perf_counter() - started:.0f} s)", flush=True)
    command = "python -m designs.codesign_cases" + ("" if args.only is None else " --only " + " ".join(keys))
    text = report(results, command)
    print(table(results))
    files.write_text(args.out, text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
