"""The offline tuner of the case studies' stored gains: each case's PID, tuned through the nonlinear loop
against the specs its own study table judges it by.

For each case the start is its classical design's "PID" (the text's PID, or
its successive loop closure with a PID outer loop), designed from the model
known to the controller (the case's known parameter error, +5 %). Its gains
are tuned by `designs.tuning` on every scenario the table judges
(`SCENARIOS`: the step, the series of steps, the input disturbance and the
measurement noise, each the table's own run, `studies.case.TableScenario.run`),
robustly over the ±known_rel box (`tuning_samples`: its corners, or samples
where there are more than `MAX_CORNERS`, plus `N_SEEDED` seeded samples):

* specs: the case's own (`CaseStudy.specs_for`, the table's `models.specs.Specs`) on
  every scenario and every sample, the step specs on each step of a series; the
  state bounds are those of every sample at once, the physical limits
  (`CaseStudy.state_limits`: cart travel, beam length, swing, panel deflection)
  each sample's own; the frequency fields (margins, bandwidth) are set by no
  case, and a tuning problem refuses them (`designs.tuning.TuningProblem`); tuning enforces overshoot,
  settling, rise time and steady-state error with a margin (`MARGIN` times the
  bounds), so that the plants between the samples meet them too (``--margin``;
  1 enforces the case's own bounds, the record stores which);
* cost: per scenario, ITAE of the tracked coordinate plus control energy (weighted
  so that energy makes `ENERGY_SHARE` of the hand design's cost), summed over the
  scenarios; the worst sample's total is minimized (an epigraph);
* each gain stays within a factor `GAIN_RANGE` of the hand design's, with its sign.

A hand design that misses the specs is first moved by a minimal-violation
phase one (`designs.tuning.phase_one`); if that converges with the specs still
missed, the structure cannot meet them near it, and the record says so with
the phase one's numbers (`infeasible_text`: the case's step specs missed, and the
physical limits and state bounds left, with their excess): the row "tuned" then carries it as
its remark ("infeasible for this structure: overshoot at best 14 % > 10 %",
first in every verdict detail of the row), its gains the phase one's answer.
Otherwise the smoothing continuation tunes from there; a
stage that makes the exact cost worse than the best point seen is stopped and
its start kept (`designs.tuning.Continuation`).

``python -m studies.tuner [case ...]`` tunes (a setting not given on the command
line is the stored record's, `run_settings`), validates the result with the
table's own rule (`table_verdicts`, on the nominal plant and on `N_VALIDATION`
fresh samples, seed `VALIDATION_SEED`), says whether it reproduced the stored
record's cost (`REPRODUCED`, relative) and why not, and stores gains, costs,
statuses and provenance in ``<case>_tuned_gains.json`` (package data beside the
case files with ``--install``, read with `importlib.resources`).
`controllers(case, known)` rebuilds the hand design and returns it with the
stored gains; it refuses when the hand design no longer matches the one the
gains were tuned from. A case without stored gains has no "tuned" row.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import replace
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np

import models
import models.compile
from designs.tuning import (
    AGREEMENT,
    CONVERGED,
    HESSIANS,
    MAX_ITER,
    PATHS,
    WIDTHS,
    Cost,
    Scenario,
    SolveOptions,
    TuningProblem,
    TuningSetup,
    phase_one,
    solve,
)
from designs.tuning import gain_bounds as decision_bounds
from designs.tuning.polish import Polished, polish
from designs.weight_search import CONVERGED as POLL_CONVERGED
from designs.weight_search import reporter
from models import files
from models import specs as specs_module
from models.specs import Specs

from . import cases, judging, runner
from .case import CaseStudy
from .homework import classical_design
from .tuner_settings import (
    MARGIN,
    PATHS_DEFAULT,
    STORED_SETTINGS,
    TUNE_OPTIONS,
    check_margin,
    check_settings,
    run_settings,
    widths_option,
)

START = "PID"
LABEL = "tuned"
#: The table's scenarios the tuned design is tuned on and judged by (every one but the Monte Carlo).
SCENARIOS = ("step", "steps", "disturbance", "noise")
MAX_CORNERS, N_TUNING, N_SEEDED, TUNING_SEED = 16, 8, 2, 1
N_VALIDATION, VALIDATION_SEED = 20, 2
ENERGY_SHARE = 0.1
GAIN_RANGE = 100.0
#: Statuses of a tuning that ended on its test: IPOPT's convergence, or the poll search's (`designs.tuning.polish`).
ENDED_ON_TEST = (*CONVERGED, POLL_CONVERGED)
#: A re-tuning reproduces a stored record when its cost agrees to this, relative.
REPRODUCED = 1e-6
#: Folder of the stored gains when writing them (beside the case files).
STORE_DIR = Path(cases.__file__).resolve().parent
#: What the infeasibility text calls each step spec, its metric column and unit.
SPEC_WORDS = {
    "max_overshoot_pct": ("overshoot", "overshoot_pct", "%"),
    "max_settling_time_s": ("settling time", "settling_time_s", "s"),
    "max_rise_time_s": ("rise time", "rise_time_s", "s"),
    "max_ss_error_pct": ("steady-state error", "ss_error", "%"),
}


def store_name(case: CaseStudy) -> str:
    """File name of the case's stored gains, beside the case files."""
    return f"{case.plant}_tuned_gains.json"


def table_scenarios(case: CaseStudy) -> dict:
    """{name: studies.case.TableScenario} of the case's `SCENARIOS`."""
    chosen = {s.name: s for s in case.scenarios}
    missing = [name for name in SCENARIOS if name not in chosen]
    if missing:
        raise ValueError(f"the {case.plant} case has no scenario {missing}; the tuner needs {', '.join(SCENARIOS)}")
    return {name: chosen[name] for name in SCENARIOS}


def scenario(case: CaseStudy, name: str = "disturbance", block=None, specs: Specs | None = None) -> Scenario:
    """One of the `SCENARIOS` as the table runs it (`TableScenario.run`), with `specs` when given; the noise
    scenario's noise is that of the measurements `block` reads (`studies.runner.measurement_noise_std`)."""
    tables = table_scenarios(case)
    if name not in tables:
        raise ValueError(f"unknown tuning scenario {name!r}; choose from {', '.join(SCENARIOS)}")
    table, plant = tables[name], models.get(case.plant)
    if table.noise and block is None:
        raise ValueError(f"the {name!r} scenario's noise depends on what the controller reads: give the block")
    _, base = runner.tracked_equilibrium(plant, case)
    noise = (
        runner.measurement_noise_std(plant, block, table.noise, sigma=case.derivative_time_constant)
        if table.noise
        else 0.0
    )
    return replace(table.run(case, base, noise), specs=specs)


def scenarios(case: CaseStudy, block, specs: dict | None = None) -> list[Scenario]:
    """The `SCENARIOS` (`scenario`), each with its specs from `specs` (scenario name -> Specs) when given."""
    return [scenario(case, name, block, (specs or {}).get(name)) for name in SCENARIOS]


def hand_design(case: CaseStudy, known: models.Plant | None = None):
    """The start: the case's classical "PID" block designed from `known` (default the case's known plant)."""
    return classical_design(case, known if known is not None else case.known_plant()).controllers[START]


def samples(case: CaseStudy, n: int, seed: int) -> np.ndarray:
    """(n, n_params) actual plants, uniform ±known_rel on the case's uncertain parameters."""
    return models.sample_params(models.get(case.plant), n, case.known_rel, seed)


def tuning_samples(case: CaseStudy) -> tuple[np.ndarray, str]:
    """The parameter rows tuning sees, and how they were chosen: the 2^k corners of the ±known_rel box
    where there are at most `MAX_CORNERS` (otherwise `N_TUNING` uniform samples), and `N_SEEDED` uniform
    samples (seed `TUNING_SEED`) inside it."""
    corners = models.corner_params(models.get(case.plant), case.known_rel)
    box = f"±{100 * case.known_rel:g} % box"
    if len(corners) <= MAX_CORNERS:
        rows = np.vstack([corners, samples(case, N_SEEDED, TUNING_SEED)])
        return rows, f"the {len(corners)} corners of the {box} and {N_SEEDED} uniform samples (seed {TUNING_SEED})"
    return samples(case, N_TUNING, TUNING_SEED), f"{N_TUNING} uniform samples of the {box} (seed {TUNING_SEED})"


def case_specs(case: CaseStudy, params: np.ndarray) -> dict:
    """{scenario: Specs}: the case's specs of each of the `SCENARIOS`, with the state bounds of every row of
    `params` (n, n_params) at once (the largest low, the smallest high) and the case's physical limits
    (`CaseStudy.state_limits`) as declared, a bound that is a parameter read by the tuning problem from each
    sample's own row (as the table reads it from the plant it simulated)."""
    names = list(models.get(case.plant).params)
    out = {}
    for name in SCENARIOS:
        each = [case.specs_for(name, dict(zip(names, row))) for row in params]
        bounds = {
            state: (max(s.state_bounds[state][0] for s in each), min(s.state_bounds[state][1] for s in each))
            for state in each[0].state_bounds
        }
        out[name] = replace(each[0].with_limits(case.state_limits), state_bounds=bounds)
    return out


def with_margin(specs: Specs, margin: float = MARGIN) -> Specs:
    """The specs tuning enforces: the step specs' bounds times `margin` (0 < margin <= 1; the others as
    they are)."""
    check_margin(margin)
    scaled: dict = {k: None if getattr(specs, k) is None else margin * getattr(specs, k) for k in SPEC_WORDS}
    return replace(specs, **scaled)


def gain_bounds(block) -> dict:
    """Each gain within a factor `GAIN_RANGE` of the hand design's, keeping its sign (zero gains: ±1)."""
    bounds = {}
    for key, g in block.gains.items():
        g = np.asarray(g, dtype=float)
        low = np.where(g > 0, g / GAIN_RANGE, g * GAIN_RANGE)
        high = np.where(g > 0, g * GAIN_RANGE, g / GAIN_RANGE)
        bounds[key] = (np.where(g == 0, -1.0, low), np.where(g == 0, 1.0, high))
    return bounds


def energy_weight(case: CaseStudy, block, params) -> float:
    """The energy weight that makes control energy `ENERGY_SHARE` of the hand design's mean cost over the
    `SCENARIOS` on the rows of `params` (0 when it uses none)."""
    problem = TuningProblem(
        models.get(case.plant), block, scenarios(case, block), cost=Cost("itae"), samples=params, substeps=case.substeps
    )
    costs, _, u, _ = (np.asarray(v) for v in problem.evaluate(problem.start()))
    itae, energy = float(np.mean(costs)), float(block.sample_period * np.sum(u**2) / len(params))
    return ENERGY_SHARE / (1 - ENERGY_SHARE) * itae / energy if energy > 0 else 0.0


def tuning_setup(case: CaseStudy, margin: float = MARGIN) -> tuple[TuningSetup, dict, str, np.ndarray]:
    """(the tuner's setup of the case, enforcing its step specs times `margin` (`with_margin`); its specs by
    scenario (the case's, without margin); how the samples were chosen; the samples (n, n_params))."""
    block = hand_design(case)
    train, chosen = tuning_samples(case)
    specs = case_specs(case, train)
    setup = TuningSetup(
        models.get(case.plant),
        block,
        scenarios(case, block, {name: with_margin(s, margin) for name, s in specs.items()}),
        cost=Cost("itae", energy_weight=energy_weight(case, block, train)),
        samples=train,
        robust="worst",
        bounds=gain_bounds(block),
        substeps=case.substeps,
    )
    return setup, specs, chosen, train


def worst_metrics(case: CaseStudy, block, params: np.ndarray) -> dict:
    """{scenario: {metric column: worst value}} of `block` over the rows of `params` in each of the
    `SCENARIOS`, each run measured by the table's rule (`studies.judging.judge_run`)."""
    return _worst(_judged(case, block, params))


def _worst(runs: dict) -> dict:
    """`worst_metrics` of judged runs ({scenario: [Judgement]})."""
    return {
        name: {column: max(j.metrics[column] for j in judged) for _, column, _ in SPEC_WORDS.values()}
        for name, judged in runs.items()
    }


def departures(runs: dict) -> dict:
    """{what is left ("leaves panel deflection by"): (largest excess, unit, scenario)} over judged runs
    ({scenario: [studies.judging.Judgement]}): the physical limits and state bounds their verdicts find
    left (`models.specs.Violation.left`), the largest excess over the samples and scenarios. Other
    verdicts the tuning does not constrain (a run that drifts at its end) are no part of a certificate."""
    out: dict = {}
    for name, judged in runs.items():
        for j in judged:
            for v in j.verdict.violations:
                if v.left and v.value > out.get(v.spec, (0.0,))[0]:
                    out[v.spec] = (float(v.value), v.unit, name)
    return out


def certificate(case: CaseStudy, specs: dict, block, params: np.ndarray) -> str | None:
    """`infeasible_text` of `block` on the tuning's rows `params` (n, n_params): the tuning's own runs
    (row j's measurement noise is the tuning problem's draw for sample j), judged by the table's rule."""
    runs = _judged(case, block, params, tuning_noise=True)
    return infeasible_text(case, specs, _worst(runs), departures(runs))


def infeasible_text(case: CaseStudy, specs: dict, worst: dict, left: dict | None = None) -> str | None:
    """The row's text "infeasible for this structure: overshoot at best 14 % > 10 % (steps); ...": each
    step spec of `specs` ({scenario: Specs}) that the worst measured value (`worst_metrics`) misses, in
    the scenario where it misses most, then each limit or bound `left` (`departures`) with its excess
    ("leaves panel deflection by 0.0013 rad at best (disturbance)"); None when none is (a phase one
    that failed only the margin `with_margin` adds)."""
    missed = []
    for field_name, (words, column, unit) in SPEC_WORDS.items():
        found = []  # (value / bound, value, bound, scenario) where the spec is missed
        for name, s in specs.items():
            bound = getattr(s, field_name)
            if bound is None or name not in worst:
                continue
            value = worst[name][column]
            if field_name == "max_ss_error_pct":
                value = 100 * value / abs(case.step)
            if value > bound:
                found.append((value / bound if bound > 0 else np.inf, value, bound, name))
        if found:
            _, value, bound, name = max(found, key=lambda f: f[0])
            missed.append(f"{words} at best {value:.3g} {unit} > {bound:g} {unit} ({name})")
    for spec, (excess, unit, scenario_name) in (left or {}).items():
        missed.append(f"{spec} {excess:.3g}{f' {unit}' if unit else ''} at best ({scenario_name})")
    return "infeasible for this structure: " + "; ".join(missed) if missed else None


def tune_case(
    case: CaseStudy, options: SolveOptions = TUNE_OPTIONS, paths: str = PATHS_DEFAULT, log=None, margin: float = MARGIN
) -> dict:
    """Tune the case's hand design against its specs, validate it; the record its stored-gains file keeps.

    options : how the tuning is solved (default `TUNE_OPTIONS`); its tol, widths, Hessian and jit are stored
        in the record
    paths : the specs' form on the smoothed stages (`designs.tuning.TuningSetup`), stored in the record
    log : optional callable(text) told what each step found as it ends
    margin : the step specs' factor tuning enforces (`with_margin`), stored in the record
    """
    started = time.perf_counter()
    say = log or (lambda text: None)
    setup, specs, chosen, train = tuning_setup(case, margin)
    setup = replace(setup, paths=paths)
    problem = setup.problem()
    lbx, ubx = decision_bounds(problem, setup.bounds)
    start = problem.start()
    found = None
    say(f"  {chosen}; {problem.g.numel()} spec inequalities; the hand design's cost {problem.values(start)[0]:.6g}")
    if problem.largest_excess(start) > AGREEMENT:
        found = phase_one(problem, lbx, ubx, start, options)
        say(
            f"  phase one: IPOPT {found.status}, {found.iterations} iterations, largest excess {found.excess:.3g} "
            f"({time.perf_counter() - started:.0f} s); gains {_listed(problem.block_at(found.decision).gains)}"
        )
    block, result, infeasible = setup.block, None, None
    if found is not None and found.infeasible:
        infeasible = certificate(case, specs, problem.block_at(found.decision), train)
    if found is not None and (infeasible or not found.converged):
        decision = found.decision
        tuned = {"cost": float(problem.values(decision)[0]), "status": found.status, "converged": found.converged}
        tuned |= {
            "message": f"phase one (IPOPT: {found.status}, {found.iterations} iterations) ended "
            + ("farther outside the specs than its start (kept): no certificate; " if found.uphill else "")
            + f"{found.excess:.3g} relative outside the specs"
            + (f": {infeasible}" if infeasible else "")
        }
        tuned |= {"iterations": found.iterations, "stages": [], "feasible": False, "method": "phase one"}
    else:
        result = solve(problem, lbx, ubx, options, start=start if found is None else found.decision)
        assert result.decision is not None, "solve always returns its decision vector"
        decision = result.decision
        tuned = {
            "cost": result.cost,
            "status": result.status,
            "converged": result.converged and result.feasible,
            "message": ("phase one met the specs; " if found is not None else "") + result.message,
            "iterations": result.iterations + (found.iterations if found is not None else 0),
            "stages": result.stages,
            "feasible": result.feasible,
            "method": result.method,
        }
    if not tuned["converged"] and not infeasible:
        say(f"  not converged ({tuned['status']}): a poll search on the exact loop from there")
        polished = polish(problem, lbx, ubx, decision, progress=reporter(50, say))
        decision, tuned = polished.decision, _polished(tuned, polished)
        search = polished.search
        say(f"  poll search: {search.status}, {search.evaluations} evaluations, cost {polished.objective:.6g}")
        if polished.converged and not polished.feasible:
            infeasible = certificate(case, specs, problem.block_at(decision), train)
    gains = problem.block_at(decision).gains
    record = {
        "plant": case.plant,
        "start": START,
        "start_gains": _listed(block.gains),
        "gains": _listed(gains),
        "known": f"uncertain parameters +{100 * case.known_rel:g} % (models.perturbed)",
        "scenarios": {name: table.title for name, table in table_scenarios(case).items()},
        "cost": {"kind": "itae", "energy_weight": problem.cost.energy_weight, "robust": "worst"},
        "tuning_margin": margin,
        "gain_range": GAIN_RANGE,
        "specs": {name: _spec_record(s) for name, s in specs.items()},
        "infeasible": infeasible,
        "tuning": tuned
        | {
            "samples": len(train),
            "chosen": chosen,
            "seed": TUNING_SEED,
            "rel": case.known_rel,
            "initial_cost": float(problem.values(start)[0]),
            "phase_one": None if found is None else {"status": found.status, "excess": found.excess},
            "tol": options.tol,
            "max_iter": options.max_iter,
            "phase_max_iter": options.phase_iterations,
            "widths": [float(w) for w in options.widths],
            "paths": paths,
            "hessian": options.hessian,
            "phase_hessian": options.phase_hessian,
            "jit": options.jit,
            "wall_time_s": time.perf_counter() - started,
        },
        "provenance": provenance(problem),
    }
    return record | {"validation": validate(case, record)}


def _polished(tuned: dict, polished: Polished) -> dict:
    """The tuning record `tuned` (IPOPT's, not converged) after `designs.tuning.polish` ran from its answer:
    its decision's cost, the poll's status and whether it converged inside the specs."""
    search = polished.search
    return tuned | {
        "cost": polished.objective,
        "status": search.status,
        "converged": polished.converged and polished.feasible,
        "message": f"{tuned['message']}; then a poll search on the exact loop ({search.evaluations} evaluations, "
        f"poll step {search.step:.3g}): {search.status}",
        "feasible": polished.feasible,
        "method": f"{tuned['method']}, then a poll search on the exact loop",
        "polish": {"evaluations": search.evaluations, "step": search.step, "status": search.status},
    }


def provenance(problem: TuningProblem) -> dict:
    """What a re-tuning must share to reproduce a record: the samples, the specs enforced, the cost weight,
    and the versions of Python, NumPy and CasADi."""
    return {
        "samples": problem.samples.tolist(),
        "enforced": {run.scenario.name: _spec_record(run.specs) for run in problem.runs},
        "energy_weight": problem.cost.energy_weight,
        "versions": {"python": platform.python_version(), "numpy": np.__version__, "casadi": _casadi_version()},
    }


def _casadi_version() -> str:
    """CasADi's version text."""
    return str(getattr(ca, "__version__", "unknown"))


def _spec_record(specs: Specs) -> dict:
    """The stored form of a scenario's specs (the `models.specs.Specs` fields, SI units and %)."""
    return {
        "max_overshoot_pct": specs.max_overshoot_pct,
        "max_settling_time_s": specs.max_settling_time_s,
        "max_rise_time_s": specs.max_rise_time_s,
        "max_ss_error_pct": specs.max_ss_error_pct,
        "settling_band_pct": specs.settling_band_pct,
        "state_bounds": {k: list(v) for k, v in specs.state_bounds.items()},
        "state_limits": [limit.describe() for limit in specs.state_limits],
    }


def reproduction(record: dict, stored_record: dict | None) -> tuple[bool, str]:
    """(whether `record`'s cost reproduces `stored_record`'s to `REPRODUCED` relative, and a sentence
    saying so, or why not: what differs between the two problems and the versions they were solved with)."""
    if stored_record is None:
        return False, "no stored record to reproduce"
    cost, before = record["tuning"]["cost"], stored_record["tuning"]["cost"]
    relative = abs(cost - before) / max(abs(before), 1e-300)
    if relative <= REPRODUCED:
        return True, f"reproduced the stored record's cost {before:.10g} (relative difference {relative:.1e})"
    text = f"did not reproduce the stored record's cost {before:.10g}: got {cost:.10g} (relative {relative:.1e})"
    then, now = stored_record.get("provenance"), record.get("provenance") or {}
    if then is None:
        return False, text + "; the stored record predates tuning against the case's specs (no provenance)"
    reasons = [f"{key} differ" for key in ("samples", "enforced", "energy_weight") if then.get(key) != now.get(key)]
    if record.get("start_gains") != stored_record.get("start_gains"):
        reasons.append("the hand design differs")
    then_margin, margin = stored_record.get("tuning_margin"), record.get("tuning_margin")
    if then_margin != margin:
        reasons.append(f"tuning margin {then_margin} -> {margin} (--margin)")
    reasons += [
        f"{name} {then.get('versions', {}).get(name)} -> {version}"
        for name, version in now.get("versions", {}).items()
        if then.get("versions", {}).get(name) != version
    ]
    if not reasons:
        reasons.append("same problem and versions: IPOPT took another path (compare the stages)")
    return False, text + "; " + ", ".join(reasons)


def validate(case: CaseStudy, record: dict) -> dict:
    """The tuned design of `record` judged by the table's own rule (`table_verdicts`) on the nominal plant
    (the table's rows) and on `N_VALIDATION` fresh samples (seed `VALIDATION_SEED`), with its worst
    metrics there."""
    block = hand_design(case)
    tuned = block.with_gains(**{k: np.asarray(v) for k, v in record["gains"].items()})
    fresh = samples(case, N_VALIDATION, VALIDATION_SEED)
    nominal = models.get(case.plant).param_vector()[None, :]
    return {
        "samples": N_VALIDATION,
        "seed": VALIDATION_SEED,
        "nominal_table_verdicts": table_verdicts(case, tuned, nominal),
        "tuned_table_verdicts": table_verdicts(case, tuned, fresh),
        "tuned_worst": worst_metrics(case, tuned, fresh),
    }


def _judged(case: CaseStudy, block, params: np.ndarray, tuning_noise: bool = False) -> dict:
    """{scenario: [studies.judging.Judgement per row of params]}: the table's own runs and rule; with
    `tuning_noise`, row j's measurement noise is the one the tuning problem draws for its sample j
    (`runner.simulate_scenario`'s noise_sample), so that the runs are the tuning's own."""
    plant = models.get(case.plant)
    _, base = runner.tracked_equilibrium(plant, case)
    options, out = runner.Options(), {}
    for name, table in table_scenarios(case).items():
        out[name] = [
            judging.judge_run(
                case,
                name,
                runner.simulate_scenario(
                    plant,
                    block,
                    table,
                    case,
                    options,
                    base,
                    case.substeps,
                    row,
                    noise_sample=j if tuning_noise else None,
                ),
                dict(zip(plant.params, row)),
            )
            for j, row in enumerate(params)
        ]
    return out


def table_verdicts(case: CaseStudy, block, params: np.ndarray) -> dict:
    """{scenario: verdict text} of `block` on the rows of `params` (n, n_params) in each of the `SCENARIOS`:
    the study table's own rule against the case's specs (`studies.judging.judge_run` on the study's run of
    that scenario), the samples combined as the table's Monte Carlo combines them (`models.specs.combine`)."""
    return {
        name: str(specs_module.combine([j.verdict for j in judged]))
        for name, judged in _judged(case, block, params).items()
    }


def _listed(gains: dict) -> dict:
    return {k: np.asarray(v, dtype=float).tolist() for k, v in gains.items()}


def stored(case: CaseStudy, name: str | None = None, folder: Path | None = None) -> dict | None:
    """The case's stored tuning record (package data beside the case files, or file `name` (default
    `store_name`) in `folder`), or None when there is none."""
    name = store_name(case) if name is None else name
    data = resources.files(cases.__name__).joinpath(name) if folder is None else Path(folder) / name
    if not data.is_file():
        return None
    return json.loads(data.read_text(encoding="utf-8"))


def remark(record: dict) -> str | None:
    """The tuned row's remark (the runner's ``controller.remark``): "infeasible for this structure: ..."
    when the record's phase one proved the case's specs out of reach (`infeasible_text`), else None."""
    return record.get("infeasible") or None


def controllers(case: CaseStudy, known: models.Plant | None = None) -> dict:
    """{"tuned": block}: the hand design built from `known` with the stored tuned gains; the block's
    ``remark`` says when the record proved the specs out of reach (`remark`).

    Raises ValueError when no gains are stored for the case, or when the hand design
    built from `known` differs from the one the gains were tuned from (rerun
    ``python -m studies.tuner NAME`` after changing a design).
    """
    record = stored(case)
    if record is None:
        raise ValueError(f"no tuned gains stored for {case.plant!r}; run `python -m studies.tuner {case.plant}`")
    block = hand_design(case, known)
    for key, value in record["start_gains"].items():
        now = np.asarray(block.gains[key], dtype=float)
        if now.shape != np.shape(value) or not np.allclose(now, value, rtol=1e-9, atol=1e-12):
            raise ValueError(
                f"{case.plant}: the stored tuned gains start from a different {START!r} design "
                f"(gain {key} is now {now.tolist()}, was {value}); "
                f"rerun `python -m studies.tuner {case.plant}`"
            )
    tuned = block.with_gains(**{k: np.asarray(v) for k, v in record["gains"].items()})
    tuned.remark = remark(record)
    return {LABEL: tuned}


def _report_every(n: int):
    def report(iteration, objective, seconds):
        if iteration % n == 0:
            # IPOPT's objective: the largest relative spec excess in the phase one, the worst sample's cost after
            print(f"    iteration {iteration:3d}: objective {objective:.6g} ({seconds:.0f} s)", flush=True)

    return report


def write(case: CaseStudy, record: dict, folder: Path = STORE_DIR, name: str | None = None) -> Path:
    """Store `record` as the case's tuned gains (file `name`, default `store_name`) in `folder` (default
    beside the case files)."""
    return files.write_json(Path(folder) / (store_name(case) if name is None else name), record)


def main(argv=None) -> int:
    """``python -m studies.tuner``: tune (or re-validate) each case's gains and write its record when the tuning
    converged (or with ``--force``) into ``--out`` (default the user cache's tuned/; ``--install`` writes into
    studies/cases, the records the study reads); 1 if one did not converge. A setting not given takes the
    stored record's (`run_settings`), so that a plain run reproduces it."""
    names = [n for n in cases.names() if cases.get(n).classical is not None]
    stored_note = "; default: the stored record's, else "
    parser = argparse.ArgumentParser(prog="python -m studies.tuner", description=__doc__.split("\n")[0])
    parser.add_argument("plants", nargs="*", default=names, help=f"cases to tune (default all: {', '.join(names)})")
    parser.add_argument(
        "--max-iter",
        type=int,
        default=None,
        help=f"IPOPT iteration cap per solve (a stop there is reported{stored_note}{MAX_ITER})",
    )
    parser.add_argument(
        "--phase-max-iter",
        type=int,
        default=None,
        help=f"the phase one's IPOPT iteration cap per solve ({stored_note.lstrip('; ')}--max-iter)",
    )
    parser.add_argument(
        "--margin",
        type=float,
        default=None,
        help=f"the step specs' factor tuning enforces (1: the case's own specs{stored_note}{MARGIN:g}, for the "
        "plants between the samples)",
    )
    parser.add_argument(
        "--validate", action="store_true", help="re-validate the stored gains on the fresh samples, without tuning"
    )
    parser.add_argument("--no-jit", action="store_true", help="evaluate with CasADi's virtual machine")
    parser.add_argument(
        "--widths",
        type=widths_option,
        default=None,
        help="the smoothing continuation's widths, comma-separated, strictly decreasing (a start far from the "
        f"answer may need 0.1 first{stored_note}{','.join(f'{w:g}' for w in WIDTHS)})",
    )
    parser.add_argument(
        "--paths",
        choices=PATHS,
        default=None,
        help="on the smoothed stages, each spec as one soft maximum per run or one inequality per sample (the "
        f"exact specs judge every sample either way{stored_note}{PATHS_DEFAULT})",
    )
    parser.add_argument(
        "--hessian",
        choices=HESSIANS,
        default=None,
        help="IPOPT's Hessian: L-BFGS or CasADi's exact second derivatives (few gains, hard problems"
        f"{stored_note}limited-memory)",
    )
    parser.add_argument(
        "--phase-hessian",
        choices=HESSIANS,
        default=None,
        help=f"the phase one's Hessian (exact where L-BFGS wanders{stored_note}{TUNE_OPTIONS.phase_hessian})",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder for the records (default: tuned/ in the user cache, models.compile.cache_directory())",
    )
    parser.add_argument("--install", action="store_true", help=f"write the records into {STORE_DIR} instead")
    parser.add_argument("--force", action="store_true", help="write a record also when its tuning did not converge")
    args = parser.parse_args(argv)
    folder = STORE_DIR if args.install else (args.out or models.compile.cache_directory() / "tuned")
    unknown = [p for p in args.plants if p not in names]
    if unknown:
        parser.error(f"unknown plant {unknown}; valid: {', '.join(names)}")
    try:  # the command line's own values (a stored record's are checked per plant below, by run_settings)
        check_settings(
            {key: default for key, (_, _, default) in STORED_SETTINGS.items()}
            | {key: value for key in STORED_SETTINGS if (value := getattr(args, key)) is not None}
        )
    except ValueError as err:
        parser.error(str(err))
    failed = []
    for name in args.plants:
        case = cases.get(name)
        before = stored(case)
        if args.validate:
            if before is None:
                parser.error(f"no tuned gains stored for {name!r} to validate")
            print(f"validating {name} ...", flush=True)
            record = before | {"validation": validate(case, before)}
        else:
            print(f"tuning {name} ...", flush=True)
            try:
                chosen, from_record = run_settings(args, before)
            except ValueError as err:
                parser.error(f"the stored record of {name} ({store_name(case)}): {err}")
            if from_record:
                print(f"  as the stored record: {' '.join(from_record)}", flush=True)
            options = SolveOptions(
                max_iter=int(chosen["max_iter"]),
                phase_max_iter=None if chosen["phase_max_iter"] is None else int(chosen["phase_max_iter"]),
                jit=not args.no_jit,
                progress=_report_every(10),
                widths=chosen["widths"],
                hessian=chosen["hessian"],
                phase_hessian=chosen["phase_hessian"],
            )
            record = tune_case(
                case,
                options,
                paths=chosen["paths"],
                log=lambda text: print(text, flush=True),
                margin=float(chosen["margin"]),
            )
        if not _report(case, record, before, args, folder):
            failed.append(name)
    if failed:
        print(f"not converged: {', '.join(failed)}", flush=True)
        return 1
    return 0


def finished(record: dict) -> bool:
    """The tuning of `record` ended on a test: converged inside the specs, or its phase one converged
    outside them (the infeasibility certificate)."""
    t = record["tuning"]
    if record.get("infeasible"):
        return t["status"] in ENDED_ON_TEST
    return t["status"] in ENDED_ON_TEST and t["converged"]


def _report(case: CaseStudy, record: dict, before: dict | None, args, folder: Path) -> bool:
    """Print what the tuning (or validation) of `record` found and write it when it finished (or with
    --force); whether it finished."""
    t, v = record["tuning"], record["validation"]
    done = finished(record)
    if not args.validate:
        if done or args.force:
            print(f"  record written: {write(case, record, folder)}", flush=True)
        else:
            print("  not converged: no record written (--force writes it)", flush=True)
        print(f"  {reproduction(record, before)[1]}", flush=True)
    print(
        f"  {t['message']}; {t['iterations']} iterations, {t['wall_time_s']:.1f} s; "
        f"cost {t['initial_cost']:.6g} -> {t['cost']:.6g}",
        flush=True,
    )
    if record.get("infeasible"):
        print(f"  {record['infeasible']}", flush=True)
    for where in ("nominal", "tuned"):
        for scenario_name, verdict in v.get(f"{where}_table_verdicts", {}).items():
            on = "the nominal plant" if where == "nominal" else f"{v['samples']} fresh samples"
            print(f"  table's verdict on {on}, {scenario_name}: {verdict}", flush=True)
    return done


if __name__ == "__main__":
    sys.exit(main())
