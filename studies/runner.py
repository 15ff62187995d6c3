"""The one runner: every controller of a case study through every scenario, on the nonlinear plant.

A case (`studies.case.CaseStudy`, declared in ``studies/cases/<name>.py``) names
its plant, the controllers it compares, where they come from (provider
functions ``module:function`` returning ``{label: controller}``) and its scenarios. The
runner designs the controllers from the model known to them (the text's
+5 % parameter error), simulates each scenario with `models.simulate_closed_loop`
(every row comes from the nonlinear plant, never from a linear model), runs
the parameter Monte Carlo of a `models.Block` as one batched CasADi map
(`models.monte_carlo`) and of any other controller (MPC) as a loop over
fewer samples, and computes every column with `models.metrics`.

A provider that is not importable yet, or has no such function yet, is
skipped with a note; the notes travel with the results into the tables.
"""

from __future__ import annotations

import importlib
import math
import shutil
import time
import traceback
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

import models
from designs.pid import SIGMA
from models import Block, metrics, specs

from . import SCENARIO_NAMES, distributed
from .case import CaseStudy, Scenario

#: Work (samples x steps x instructions of the plant's RK4 step and the controller's step) from which
#: a Monte Carlo map is JIT-compiled with jit="auto": compiling costs 0.5-2 s per controller, CasADi's
#: virtual machine about 35 ns per instruction; measured break-even about 1e8 (pendulum, 20 samples).
JIT_THRESHOLD = 1.5e8

@dataclass(frozen=True)
class Options:
    """How much to run.

    Attributes
    ----------
    scenarios : names of the scenarios to run (default: all of the study's)
    mc : Monte Carlo samples for Block controllers (one batched map); 0 skips the Monte Carlo
    mc_python : most samples for controllers that are not Blocks (MPC), simulated one by one
    mc_python_steps : and at most this many simulated samples in all, so the Monte Carlo of an
        optimizing controller costs about as much on every plant (at least one sample)
    python_scenarios : scenarios run for controllers that are not Blocks (default all); the others
        get a row saying they were skipped
    python_budget : seconds of its own compute time a controller that is not a Block may spend on
        one plant (default unlimited); past it, its remaining rows say so instead of holding numbers
    seed : seed of the parameter samples and of the measurement noise
    threads : threads of the batched Monte Carlo map
    jit : True, False or "auto" (compile the Monte Carlo map when it has >= JIT_THRESHOLD steps)
    strict : raise on a provider or controller error instead of noting it
    quick : smaller defaults for plots and animations (the CLI also lowers mc)
    """

    scenarios: tuple | None = None
    mc: int = 200
    mc_python: int = 10
    mc_python_steps: int = 12_000
    python_scenarios: tuple | None = None
    python_budget: float | None = None
    seed: int = 0
    threads: int = 2
    jit: bool | str = "auto"
    strict: bool = False
    quick: bool = False

    def __post_init__(self):
        for name in ("mc", "mc_python", "mc_python_steps"):
            value = getattr(self, name)
            if int(value) != value or value < 0:
                raise ValueError(f"{name} (Monte Carlo samples) must be an integer >= 0, got {value}")
        for chosen in (self.scenarios, self.python_scenarios):
            unknown = [s for s in chosen or () if s not in SCENARIO_NAMES]
            if unknown:
                raise ValueError(f"unknown scenario {unknown[0]!r}; valid scenarios: {', '.join(SCENARIO_NAMES)}")
        if self.jit not in (True, False, "auto"):
            raise ValueError(f"jit must be True, False or 'auto', got {self.jit!r}")


# ---------------------------------------------------------------------------- results
@dataclass
class Envelope:
    """Monte Carlo envelope of one controller: quantiles over the samples that did not diverge.

    Attributes
    ----------
    t : (N+1,) s
    quantiles : the levels of the rows below (0, 0.05, 0.5, 0.95, 1)
    tracked : (5, N+1) tracked coordinate;  u : (5, N) commanded input (first input)
    reference : (N+1,)
    samples, diverged : counts
    """

    t: np.ndarray
    quantiles: tuple
    tracked: np.ndarray
    u: np.ndarray
    reference: np.ndarray
    samples: int
    diverged: int


@dataclass
class StudyResult:
    """Everything a study produced; `table` is what `studies.run` returns.

    Attributes
    ----------
    study : CaseStudy;  options : Options
    plant : the truth (nominal parameters);  known : the model the controllers were designed from
    truths : controller label -> its simulated plant (`plant` unless the study gives it its own actuator)
    table : DataFrame, one row per (controller, scenario)
    runs : (controller, scenario) -> ClosedLoopResult of the non-Monte-Carlo scenarios
    envelopes : controller -> Envelope of its Monte Carlo
    samples : DataFrame of per-sample Monte Carlo metrics
    controllers : label -> controller object
    notes : skipped providers, failures and other remarks, in order
    timing : seconds spent per phase
    answers : homework item -> answers (see `studies.answers`), with "errata"
    """

    study: CaseStudy
    options: Options
    plant: models.Plant
    known: models.Plant
    table: pd.DataFrame
    runs: dict
    envelopes: dict
    samples: pd.DataFrame
    controllers: dict
    notes: list
    timing: dict
    answers: dict = field(default_factory=dict)
    truths: dict = field(default_factory=dict)

    def best(self, scenario: str = "step") -> str | None:
        """The controller with the lowest ITAE in `scenario` among runs that did not diverge or fail."""
        rows = self.table[(self.table.scenario == scenario) & (self.table.status == "ok")]
        rows = rows[np.isfinite(rows.itae.astype(float))]
        return None if rows.empty else str(rows.loc[rows.itae.astype(float).idxmin(), "controller"])


# ---------------------------------------------------------------------------- providers
class NotProvided(LookupError):
    """Raised by a provider that has nothing for this case (no design of its kind): noted, not a failure."""


def call_providers(specs: Sequence[str], *args, strict: bool = False, **kwargs) -> tuple[list, list]:
    """Call each ``module:function`` provider; skip the ones that do not exist yet.

    Returns
    -------
    results : list of (spec, returned value) for the providers that answered
    notes : one line per provider skipped or failed
    """
    results, notes = [], []
    for spec in specs:
        module_name, _, function_name = spec.partition(":")
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as err:
            if err.name and (module_name == err.name or module_name.startswith(err.name + ".")):
                notes.append(f"{spec}: skipped, module {module_name} is not importable yet")
                continue
            if strict:
                raise
            notes.append(f"{spec}: skipped, importing {module_name} failed: {err}")
            continue
        except Exception as err:  # a provider that fails to import must not stop the other studies
            if strict:
                raise
            notes.append(f"{spec}: skipped, importing {module_name} failed: {type(err).__name__}: {err}")
            continue
        function = getattr(module, function_name, None)
        if function is None:
            notes.append(f"{spec}: skipped, {module_name} has no {function_name}() yet")
            continue
        try:
            results.append((spec, function(*args, **kwargs)))
        except NotProvided as err:
            notes.append(f"{spec}: skipped, {err}")
        except Exception as err:
            if strict:
                raise
            where = traceback.extract_tb(err.__traceback__)[-1]
            notes.append(f"{spec}: failed ({type(err).__name__}: {err}; at {where.filename}:{where.lineno})")
    return results, notes


def design_controllers(study: CaseStudy, known: models.Plant, providers: Sequence[str] | None = None,
                       strict: bool = False) -> tuple[dict, list]:
    """The study's controllers designed from `known`, in table order, and notes on what is missing."""
    found, notes = call_providers(study.providers if providers is None else providers, study.plant,
                                  strict=strict, known=known)
    collected: dict = {}
    for spec, returned in found:
        if not isinstance(returned, Mapping):
            notes.append(f"{spec}: returned {type(returned).__name__}, not a dict of controllers; skipped")
            continue
        for label, controller in returned.items():
            if label in collected:
                notes.append(f"{spec}: controller {label!r} already provided; the first one is kept")
            elif not isinstance(controller, models.Controller):
                notes.append(f"{spec}: {label!r} is a {type(controller).__name__}, not a controller; skipped")
            elif controller.n_reference != 1:
                notes.append(f"{spec}: {label!r} takes {controller.n_reference} references; the studies "
                             "command the tracked coordinate only; skipped")
            else:
                collected[str(label)] = controller
    ordered = {label: collected[label] for label in study.controllers if label in collected}
    ordered |= {label: c for label, c in collected.items() if label not in ordered}
    missing = [label for label in study.controllers if label not in collected]
    if missing and found:
        notes.append("not provided yet: " + ", ".join(missing))
    return ordered, notes


# ---------------------------------------------------------------------------- time budget
class BudgetExceeded(RuntimeError):
    """A controller simulated step by step used up its time budget."""


class Budgeted:
    """A controller (not a Block) that raises `BudgetExceeded` once its steps took `seconds` in all.

    Everything else is the wrapped controller's: sample period, measurement,
    initial state, solver records (`step_info`), name.
    """

    def __init__(self, controller, seconds: float):
        self.controller, self.seconds, self.spent, self.steps = controller, float(seconds), 0.0, 0
        self.sample_period = controller.sample_period
        self.measures = controller.measures
        self.n_reference = controller.n_reference

    def initial_state(self, y0, r0):
        self.steps = 0
        return self.controller.initial_state(y0, r0)

    def step(self, xc, y, r):
        if self.spent > self.seconds:
            raise BudgetExceeded(f"over its budget of {self.seconds:g} s of compute time")
        start = time.perf_counter()
        out = self.controller.step(xc, y, r)
        self.spent += time.perf_counter() - start
        self.steps += 1
        if self.spent > self.seconds:
            raise BudgetExceeded(f"over its budget of {self.seconds:g} s of compute time at t = "
                                 f"{self.steps * self.sample_period:.3g} s")
        return out

    def __getattr__(self, name):
        return getattr(self.controller, name)


# ---------------------------------------------------------------------------- noise
def measurement_noise_std(plant: models.Plant, controller, noise: Mapping[str, float]) -> np.ndarray:
    """Noise standard deviation of each measurement the controller reads.

    Output noise is given per output. A controller that reads the full state
    gets on each coordinate the noise its outputs carry (through q = P y, the
    outputs being linear in q: std_q = sqrt(diag(P Σ Pᵀ))), and on each
    velocity the noise a dirty derivative (σ = 0.05 s, Tustin at the
    controller's Ts) would make of it: std_q (1 − β)/Ts · sqrt(2 / (1 + β)).

    Returns
    -------
    ndarray, (n_measured,), SI units
    """
    unknown = set(noise) - set(plant.output_names)
    if unknown:
        raise ValueError(f"{plant.name} has no output {sorted(unknown)}; outputs are {plant.output_names}")
    per_output = np.array([float(noise.get(name, 0.0)) for name in plant.output_names])
    if controller.measures == "outputs":
        return per_output
    import casadi as ca

    y = ca.SX.sym("y", plant.ny)
    jac = ca.Function("dq_dy", [y], [ca.jacobian(plant.casadi_configuration(y, plant.param_vector()), y)])
    P = np.asarray(jac(np.zeros(plant.ny)))
    std_q = np.sqrt(np.diag(P @ np.diag(per_output**2) @ P.T))
    ts = controller.sample_period
    beta = (2 * SIGMA - ts) / (2 * SIGMA + ts)
    gain = (1 - beta) / ts * math.sqrt(2 / (1 + beta))
    return np.concatenate([std_q, gain * std_q])


# ---------------------------------------------------------------------------- running
def tracked_equilibrium(plant: models.Plant, case: CaseStudy) -> tuple[np.ndarray, float]:
    """The standard equilibrium state and the tracked coordinate's value there."""
    xe, _ = plant.equilibrium()
    return xe, float(xe[plant.state_names.index(case.tracked)])


def _status(result) -> str:
    return "ok" if result.diverged_at is None else f"diverged at t = {result.diverged_at:.3g} s"


def _solver_issues(result) -> float:
    """Steps whose solver record does not report success (NaN when there are no records)."""
    if not result.status:
        return math.nan
    bad = 0
    for record in result.status:
        if not isinstance(record, Mapping):
            continue
        if "success" in record:
            bad += not bool(record["success"])
        elif "status" in record:
            text = str(record["status"]).lower().replace(" ", "_")
            bad += not any(word in text for word in ("solved", "optimal", "succeeded", "success"))
    return float(bad)


def python_samples(options: Options, steps_per_run: int) -> int:
    """Monte Carlo samples of a controller simulated step by step: at most `mc_python`, at most
    `mc_python_steps` simulated steps in all, at least one (none when mc or mc_python is 0)."""
    if options.mc == 0 or options.mc_python == 0:
        return 0
    return max(1, min(options.mc, options.mc_python, options.mc_python_steps // max(steps_per_run, 1)))


def use_jit(options: Options, plant: models.Plant, controller: Block, samples: int, steps: int,
            substeps: int = 10) -> bool:
    """Whether to JIT-compile a Monte Carlo map of `samples` runs of `steps` (`Options.jit`, `JIT_THRESHOLD`)."""
    if options.jit != "auto":
        return bool(options.jit)
    instructions = (plant.step_function(controller.sample_period, substeps).n_instructions()
                    + controller.casadi_step.n_instructions())
    compiler = shutil.which("cc") or shutil.which("gcc")
    return samples * steps * instructions >= JIT_THRESHOLD and compiler is not None


def _envelope(results, tracked_index: int) -> Envelope:
    quantiles = (0.0, 0.05, 0.5, 0.95, 1.0)
    kept = [r for r in results if r.diverged_at is None]
    t = results[0].t
    if kept:
        y = np.array([r.x[:, tracked_index] for r in kept])
        u = np.array([r.u[:, 0] for r in kept])
        tracked, inputs = np.quantile(y, quantiles, axis=0), np.quantile(u, quantiles, axis=0)
    else:
        tracked = np.full((len(quantiles), len(t)), np.nan)
        inputs = np.full((len(quantiles), len(t) - 1), np.nan)
    return Envelope(t, quantiles, tracked, inputs, results[0].r[:, 0], len(results), len(results) - len(kept))


def run_study(study: CaseStudy, options: Options | None = None, *, providers: Sequence[str] | None = None,
              controllers: Mapping | None = None, progress: Callable[[int, int, str], None] | None = None,
              executor=None) -> StudyResult:
    """Run every controller of `study` through its scenarios on the nonlinear plant.

    Parameters
    ----------
    study : CaseStudy
    options : Options (defaults: all scenarios, 200 Monte Carlo samples, seed 0)
    providers : replace the study's provider list (``module:function`` strings)
    controllers : extra {label: controller} added after the providers' (for example your own design)
    progress : called as progress(done, total, text) after each simulation
    executor : where the Monte Carlo of Block controllers runs: None (this process), a
        `dask.distributed.Client` or a `studies.distributed` executor; the numbers are the same

    Returns
    -------
    StudyResult

    Raises
    ------
    studies.distributed.RunFailed
        When work sent to a Dask cluster could not complete (never noted as a failed row).
    """
    options = options or Options()
    executor = distributed.executor_of(executor)
    started = time.perf_counter()
    case = study
    plant = models.get(study.plant)
    known = study.known_plant(plant)
    designed, notes = design_controllers(study, known, providers, options.strict)
    for label, controller in (controllers or {}).items():
        if label in designed:
            notes.append(f"controller {label!r} given twice; the provider's is replaced")
        designed[label] = controller
    timing = {"design_s": time.perf_counter() - started}
    if not designed:
        notes.append("no controllers: nothing to simulate")

    scenarios = [s for s in study.scenarios if options.scenarios is None or s.name in options.scenarios]
    if options.mc == 0 and any(s.monte_carlo for s in scenarios):
        notes.append("Monte Carlo skipped (0 samples requested)")
        scenarios = [s for s in scenarios if not s.monte_carlo]
    xe, base = tracked_equilibrium(plant, case)
    tracked_index = plant.state_names.index(case.tracked)

    rows, sample_rows, runs, envelopes = [], [], {}, {}
    total, done = len(designed) * len(scenarios), 0
    sim_time = mc_time = 0.0
    truths = {}
    for label, controller in designed.items():
        truth = truths[label] = study.truth(plant, label)
        if options.python_budget is not None and not isinstance(controller, Block):
            controller = Budgeted(controller, options.python_budget)
        for scenario in scenarios:
            tick = time.perf_counter()
            row = {"controller": label, "scenario": scenario.name, "kind": "block" if isinstance(controller, Block)
                   else "python"}
            try:
                if (not isinstance(controller, Block) and options.python_scenarios is not None
                        and scenario.name not in options.python_scenarios):
                    row |= dict.fromkeys(metrics.METRIC_COLUMNS, math.nan)
                    row |= {"status": "skipped: controllers that optimize each step run only "
                                      + ", ".join(options.python_scenarios) + " here", "samples": 0}
                    row |= verdict_columns(specs.Verdict(specs.SKIPPED, (), row["status"]))
                elif scenario.monte_carlo:
                    row |= _monte_carlo(study, truth, controller, scenario, options, base, tracked_index,
                                        sample_rows, envelopes, label, executor)
                else:
                    result = simulate_scenario(truth, controller, scenario, case, options, base, study.substeps)
                    runs[(label, scenario.name)] = result
                    judged = study.specs_for(scenario.name, truth.params)
                    row |= metrics.run_metrics(result, case.tracked, judged.state_bounds)
                    row |= {"status": _status(result), "diverged_at_s": result.diverged_at, "samples": 1,
                            "solver_issues": _solver_issues(result)}
                    row |= verdict_columns(specs.judge(judged, result, case.tracked, case.step, row["status"],
                                                       measured=row))
            except distributed.RunFailed:
                raise
            except BudgetExceeded as err:
                row |= dict.fromkeys(metrics.METRIC_COLUMNS, math.nan)
                row |= {"status": f"skipped: {err}", "samples": 0}
                row |= verdict_columns(specs.Verdict(specs.SKIPPED, (), row["status"]))
            except Exception as err:
                if options.strict:
                    raise
                row |= dict.fromkeys(metrics.METRIC_COLUMNS, math.nan)
                row |= {"status": f"failed: {type(err).__name__}: {err}".splitlines()[0][:200]}
                row |= verdict_columns(specs.Verdict(specs.FAILED, (), row["status"]))
                notes.append(f"{label} / {scenario.name}: {row['status']}")
            elapsed = time.perf_counter() - tick
            row["wall_s"] = elapsed
            if scenario.monte_carlo:
                mc_time += elapsed
            else:
                sim_time += elapsed
            rows.append(row)
            done += 1
            if progress:
                progress(done, total, f"{study.plant}: {label} / {scenario.name}")
    table = _frame(rows, study, case)
    timing |= {"simulate_s": sim_time, "monte_carlo_s": mc_time, "total_s": time.perf_counter() - started}
    samples = pd.DataFrame(sample_rows)
    from .answers import collect

    answers, answer_notes = collect(study, options.strict)
    notes += answer_notes
    return StudyResult(study, options, plant, known, table, runs, envelopes, samples, designed, notes, timing,
                       answers, truths)


def simulate_scenario(plant, controller, scenario: Scenario, case, options: Options, base: float, substeps: int,
                      params=None):
    """One run of `scenario` on `plant` (parameters `params`, default its own): noise, disturbance, seed."""
    noise = measurement_noise_std(plant, controller, scenario.noise) if scenario.noise else 0.0
    return models.simulate_closed_loop(
        plant, controller, scenario.reference(case, base), scenario.duration(case), params=params,
        substeps=substeps,
        input_disturbance=case.input_disturbance if scenario.input_disturbance else 0.0,
        noise_std=noise, seed=options.seed, allow_divergence=True)


def _monte_carlo(study, plant, controller, scenario, options, base, tracked_index, sample_rows, envelopes,
                 label, executor=None) -> dict:
    case = study
    batched = isinstance(controller, Block)
    duration = scenario.duration(case)
    steps = int(round(duration / controller.sample_period))
    count = options.mc if batched else python_samples(options, steps)
    if count == 0:
        raise ValueError("no Monte Carlo samples for a controller that is not a Block (mc_python = 0)")
    # The same seeded samples for every controller; a Python controller gets their first `count`.
    samples = models.sample_params(plant, options.mc, rel=scenario.rel, seed=options.seed)[:count]
    if batched:
        results = distributed.monte_carlo(executor, plant, controller, scenario.reference(case, base), duration,
                                          samples, seed=options.seed, threads=options.threads,
                                          substeps=study.substeps,
                                          jit=use_jit(options, plant, controller, count, steps, study.substeps))
    else:
        results = [simulate_scenario(plant, controller, scenario, case, options, base, study.substeps, params=row)
                   for row in samples]
    per_sample, verdicts = [], []
    names = list(plant.params)
    for i, (result, row) in enumerate(zip(results, samples)):
        judged = study.specs_for(scenario.name, dict(zip(names, row)))
        values = metrics.run_metrics(result, case.tracked, judged.state_bounds)
        per_sample.append(values)
        verdicts.append(specs.judge(judged, result, case.tracked, case.step, measured=values))
        sample_rows.append({"controller": label, "sample": i, **dict(zip(names, row)), **values,
                            "diverged_at_s": result.diverged_at, **verdict_columns(verdicts[-1])})
    envelopes[label] = _envelope(results, tracked_index)
    out = metrics.aggregate(per_sample)
    diverged = [r.diverged_at for r in results if r.diverged_at is not None]
    status = "ok" if not diverged else (f"{len(diverged)} of {count} diverged (first at t = "
                                        f"{min(diverged):.3g} s)")
    out |= {"status": status, "samples": count, "diverged_samples": len(diverged),
            "diverged_at_s": min(diverged) if diverged else None}
    out |= verdict_columns(specs.combine(verdicts))
    if not batched:
        out["step_ms"] = 1e3 * float(np.nanmean(np.concatenate([r.step_time for r in results])))
        out["step_ms_max"] = 1e3 * float(np.nanmax(np.concatenate([r.step_time for r in results])))
        issues = [_solver_issues(r) for r in results]
        out["solver_issues"] = float(np.nansum(issues)) if not all(np.isnan(issues)) else math.nan
    return out


def verdict_columns(verdict: specs.Verdict) -> dict:
    """The table's verdict columns of a `models.specs.Verdict`: its label and what it found."""
    return {"verdict": verdict.label, "verdict_detail": verdict.detail}


TABLE_COLUMNS = ("controller", "scenario", "status", "verdict", "verdict_detail", *metrics.METRIC_COLUMNS,
                 "solver_issues", "samples", "diverged_samples", "diverged_at_s",
                 *(f"{k}_std" for k in metrics.SPREAD_COLUMNS), "kind",
                 "tracked", "tracked_unit", "input_unit", "wall_s")


def _frame(rows: list, study: CaseStudy, case) -> pd.DataFrame:
    frame = pd.DataFrame(rows)
    for column in TABLE_COLUMNS:
        if column not in frame:
            frame[column] = np.nan
    frame["tracked"] = case.tracked
    frame["tracked_unit"] = study.tracked_unit
    frame["input_unit"] = study.input_unit
    if len(frame):
        frame["samples"] = frame["samples"].fillna(1).astype(int)
        frame["diverged_samples"] = frame["diverged_samples"].fillna(0).astype(int)
    return frame[list(TABLE_COLUMNS)]
