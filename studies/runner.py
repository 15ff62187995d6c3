"""The one runner: every controller of a case study through every scenario, on the nonlinear plant.

A case (`studies.case.CaseStudy`, declared in ``studies/cases/<name>.py`` or
anywhere) names its plant, the controllers it compares, where they come from
(providers, ``provider(case, known) -> {label: controller}``, called through
`studies.provider_calls`) and its scenarios. The runner designs the controllers
from the model known to them (the text's +5 % parameter error), simulates
each scenario with `models.simulate_closed_loop` (every row comes from the
nonlinear plant, never from a linear model), runs
the parameter Monte Carlo of a `models.Block` as one batched CasADi map
(`models.monte_carlo`) and of any other controller (MPC) as a loop over the
same samples, and computes every column with `models.metrics`. Every
controller runs every scenario on the same samples: there is no time budget,
so the same command gives the same table on any machine.

A provider that has nothing for the case, or fails, is skipped with a note;
the notes travel with the results into the tables. A controller may carry a
``remark`` (text): every row of it then says it first in its verdict detail,
and in its ``remark`` column (a tuned design's certificate that its structure
cannot meet the case's specs).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

import models
import models.closed_loop
from models import Block, checks, deferred, exported_loop, interrupts, metrics, specs
from models.compile import compiler

from . import distributed, exported_runs
from .answers import collect
from .case import SCENARIO_NAMES, CaseStudy, TableScenario
from .designing import add_controllers, design_controllers, leave_out, without_labels
from .judging import check_specs, judge_run, meets_everywhere, remarked, verdict_columns
from .judging import degraded_status as degraded_status
from .judging import run_status as run_status
from .judging import solver_counts as solver_counts
from .provider_calls import NotProvided as NotProvided  # raised by providers; callers catch it from here too
from .provider_calls import name_of, resolve

if TYPE_CHECKING:
    import pandas as pd
else:
    pd = deferred.module("pandas")

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
    mc : Monte Carlo samples of every controller (a Block's as one batched map, any other's one by
        one on the same samples); 0 skips the Monte Carlo
    seed : seed of the parameter samples and of the measurement noise;  threads : of the batched map
    jit : True, False or "auto" (compile the Monte Carlo map when it has >= JIT_THRESHOLD steps)
    strict : raise on a provider or controller error instead of noting it (but for an error the
        controller's remark states: a refused construction's row fails, and --strict exits 1 on it)
    quick : smaller defaults for plots and animations (the CLI also lowers mc)
    without : labels of controllers to leave out (each noted; a label no provider gives is noted too)
    """

    scenarios: Sequence[str] | None = None
    mc: int = 200
    seed: int = 0
    threads: int = 2
    jit: bool | str = "auto"
    strict: bool = False
    quick: bool = False
    without: Sequence[str] = ()

    def __post_init__(self):
        """Check every field (TypeError or ValueError naming it); `scenarios` becomes a tuple."""
        checks.integer(self.mc, "mc (Monte Carlo samples)", minimum=0)
        object.__setattr__(self, "scenarios", scenario_names(self.scenarios, "scenarios"))
        checks.integer(self.seed, "seed", minimum=0)
        checks.integer(self.threads, "threads", minimum=1)
        if not (isinstance(self.jit, bool) or (isinstance(self.jit, str) and self.jit == "auto")):
            raise ValueError(f"jit must be True, False or 'auto', got {self.jit!r}")
        checks.boolean(self.strict, "strict")
        checks.boolean(self.quick, "quick")
        object.__setattr__(self, "without", without_labels(self.without))


def scenario_names(value, what: str = "scenarios") -> tuple | None:
    """`value` (None, or a list or tuple of scenario names) as a tuple of known names.

    Raises
    ------
    TypeError
        Naming `what` when `value` is a single string or not a sequence of strings.
    ValueError
        For an unknown name or an empty selection.
    """
    if value is None:
        return None
    if isinstance(value, str) or not isinstance(value, (list, tuple)):
        raise TypeError(
            f"{what} must be a list of scenario names such as ['step'], got {type(value).__name__} {value!r}"
        )
    if not value:
        raise ValueError(f"{what} is empty; give None for every scenario or some of: {', '.join(SCENARIO_NAMES)}")
    unknown = [s for s in value if s not in SCENARIO_NAMES]
    if unknown:
        raise ValueError(f"unknown scenario {unknown[0]!r} in {what}; valid scenarios: {', '.join(SCENARIO_NAMES)}")
    return tuple(value)


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
    providers : the names (``module:function``) of the providers asked for controllers
    trajectories : the case's solved optimal trajectories (`studies.trajectories.CaseTrajectories`), when
        `studies.solve_trajectories` ran
    left_out : the labels of `Options.without` that were provided here, and so left out
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
    providers: tuple = ()
    trajectories: object = None
    left_out: tuple = ()

    def best(self, scenario: str = "step", meeting: bool = True) -> str | None:
        """The controller with the lowest ITAE in `scenario` among those whose every row is "ok" and meets
        its specs (`judging.meets_everywhere`); None when none does: a controller violating its specs in
        any scenario, or degraded, is never the best. ``meeting=False``: the lowest ITAE among "ok" rows."""
        rows = self.table[(self.table.scenario == scenario) & (self.table.status == "ok")]
        if meeting:
            rows = rows[meets_everywhere(self.table).loc[rows.controller].to_numpy()]
        rows = rows[np.isfinite(rows.itae.astype(float))]
        return None if rows.empty else str(rows.loc[rows.itae.astype(float).idxmin(), "controller"])


# ---------------------------------------------------------------------------- noise
def measurement_noise_std(plant: models.Plant, controller, noise: Mapping[str, float], *, sigma: float) -> np.ndarray:
    """Noise standard deviation of each measurement the controller reads.

    Output noise is given per output. A controller that reads the full state
    gets on each coordinate the noise its outputs carry (through q = P y, the
    outputs being linear in q: std_q = sqrt(diag(P Σ Pᵀ))), and on each
    velocity the noise a dirty derivative s/(σ s + 1) (σ = `sigma`,
    the case's `derivative_time_constant`, in s; Tustin at the controller's Ts) would make of it:
    std_q (1 − β)/Ts · sqrt(2 / (1 + β)), β = (2σ − Ts)/(2σ + Ts).

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
    beta = (2 * sigma - ts) / (2 * sigma + ts)
    gain = (1 - beta) / ts * math.sqrt(2 / (1 + beta))
    return np.concatenate([std_q, gain * std_q])


# ---------------------------------------------------------------------------- running
def tracked_equilibrium(plant: models.Plant, case: CaseStudy) -> tuple[np.ndarray, float]:
    """The standard equilibrium state and the tracked coordinate's value there."""
    xe, _ = plant.equilibrium()
    return xe, float(xe[plant.state_names.index(case.tracked)])


#: What a row's status says first: how its simulation went, not whether it meets its specs. "ok": every
#: step ran as designed; "degraded": it ran, but some steps' solver failed or fell back on its previous
#: plan (the count follows); "diverged": the state left its bound or a value became non-finite;
#: "failed": an error stopped the row; "skipped": not run (the reason follows).
STATUS_KINDS = ("ok", "degraded", "diverged", "failed", "skipped")


def status_kind(status) -> str:
    """The kind a row's status starts with, one of `STATUS_KINDS` ("failed" for anything else,
    such as a missing status)."""
    words = str(status).replace(":", " ").split()
    return words[0] if words and words[0] in STATUS_KINDS else "failed"


def use_jit(
    options: Options, plant: models.Plant, controller: Block, samples: int, steps: int, substeps: int = 10
) -> bool:
    """Whether to JIT-compile a Monte Carlo map of `samples` runs of `steps` (`Options.jit`, `JIT_THRESHOLD`)."""
    if options.jit != "auto":
        return bool(options.jit)
    instructions = (
        plant.step_function(controller.sample_period, substeps).n_instructions()
        + controller.casadi_step.n_instructions()
    )
    return samples * steps * instructions >= JIT_THRESHOLD and compiler() is not None


def _envelope(t: np.ndarray, reference: np.ndarray, tracked: list, inputs: list, samples: int) -> Envelope:
    """Quantiles over samples of the tracked coordinate `tracked` and first input `inputs` of the
    samples that did not diverge (lists of (N+1,) and (N,) arrays)."""
    quantiles = (0.0, 0.05, 0.5, 0.95, 1.0)
    if tracked:
        y = np.quantile(np.array(tracked), quantiles, axis=0)
        u = np.quantile(np.array(inputs), quantiles, axis=0)
    else:
        y = np.full((len(quantiles), len(t)), np.nan)
        u = np.full((len(quantiles), len(t) - 1), np.nan)
    return Envelope(t, quantiles, y, u, reference, samples, samples - len(tracked))


def monte_carlo_bytes(study: CaseStudy, options: Options, n_params: int, sample_period: float | None = None) -> float:
    """Estimated bytes the runner holds for the Monte Carlo of one controller on `study`.

    Per sample: the tracked coordinate and the first input over the run, kept for the envelope (and
    copied once by its quantiles), and the sample's row of parameters and metrics. The simulator's
    own working memory is bounded separately (`models.closed_loop.MONTE_CARLO_CHUNK_BYTES`).

    Parameters
    ----------
    n_params : the plant's parameter count
    sample_period : s, the controller's (default: the case's)
    """
    scenario = next((s for s in study.scenarios if s.monte_carlo), None)
    if scenario is None or options.mc == 0:
        return 0.0
    steps = scenario.duration(study) / (sample_period or study.sample_period)
    row = n_params + len(metrics.METRIC_COLUMNS) + 4
    return options.mc * 8.0 * (2 * 2 * (steps + 1) + row)


def check_resources(study: CaseStudy, options: Options, n_params: int) -> None:
    """Refuse, before any work, a study whose Monte Carlo would hold more than
    `models.checks.MEMORY_LIMIT_BYTES` (ResourceLimitError naming the samples and the limit)."""
    needed = monte_carlo_bytes(study, options, n_params, min(study.sample_period, study.observer_sample_period))
    if needed:
        checks.check_memory(
            needed, f"a Monte Carlo of {options.mc} samples on {study.plant}", "give fewer samples (mc)"
        )


def run_study(
    study: CaseStudy,
    options: Options | None = None,
    *,
    providers: Sequence | None = None,
    controllers: Mapping | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    executor=None,
) -> StudyResult:
    """Run every controller of `study` through its scenarios on the nonlinear plant.

    `study` need not be registered: its providers receive it.

    Parameters
    ----------
    study : CaseStudy
    options : Options (defaults: all scenarios, 200 Monte Carlo samples, seed 0)
    providers : replace the study's providers: callables ``provider(case, known)``, or ``module:function``
        strings naming them (found before any work; one not found is noted, or with `Options.strict` raised)
    controllers : extra {label: controller} added after the providers' (for example your own design)
    progress : called as progress(done, total, text) after each simulation
    executor : where the Monte Carlo of Block controllers runs: None (this process), a
        `dask.distributed.Client` or a `studies.distributed` executor; the numbers are the same

    Returns
    -------
    StudyResult

    Raises
    ------
    TypeError, ValueError
        Naming the argument, before any work, when one is not what is allowed.
    studies.provider_calls.ProviderNotFound
        With `Options.strict`, before any work, for a provider string that names no provider.
    studies.distributed.RunFailed
        When work sent to a Dask cluster could not complete (never noted as a failed row).
    """
    options, chosen, executor = _checked_arguments(study, options, providers, controllers, progress, executor)
    plant = models.get(study.plant)
    check_specs(study, plant)  # specs its scenarios or plant cannot judge are refused before any work
    check_resources(study, options, plant.n_params)
    interrupts.watch()  # Ctrl-C stops the study even where CasADi swallows it
    interrupts.clear()
    started = time.perf_counter()
    known = study.known_plant(plant)
    designed, notes = design_controllers(study, known, chosen, options.strict)
    notes += add_controllers(designed, controllers or {})
    left_out, dropped = leave_out(designed, options.without)
    notes += dropped
    timing = {"design_s": time.perf_counter() - started}
    if not designed:
        notes.append("no controllers: nothing to simulate")
    scenarios = chosen_scenarios(study, options, notes)
    simulation = Simulation(study, options, plant, executor, notes)
    simulation.run_all(designed, scenarios, progress)
    table = _frame(simulation.rows, study)
    timing |= simulation.seconds | {"total_s": time.perf_counter() - started}
    samples = pd.concat(simulation.samples, ignore_index=True) if simulation.samples else pd.DataFrame()
    answers, answer_notes = collect(study, options.strict)
    notes += answer_notes
    return StudyResult(
        study,
        options,
        plant,
        known,
        table,
        simulation.runs,
        simulation.envelopes,
        samples,
        designed,
        notes,
        timing,
        answers,
        simulation.truths,
        tuple(name_of(p) for p in (study.providers if chosen is None else chosen)),
        left_out=tuple(left_out),
    )


def _checked_arguments(study, options, providers, controllers, progress, executor) -> tuple:
    """(options, providers found or None, executor) of `run_study`'s arguments, or the error naming one."""
    if not isinstance(study, CaseStudy):
        raise TypeError(f"study must be a CaseStudy, got {type(study).__name__} {study!r}")
    options = Options() if options is None else options
    if not isinstance(options, Options):
        raise TypeError(f"options must be a studies.Options, got {type(options).__name__} {options!r}")
    chosen = None if providers is None else resolve(providers, strict=options.strict)
    if controllers is not None and not isinstance(controllers, Mapping):
        raise TypeError(f"controllers must be a dict {{label: controller}}, got {type(controllers).__name__}")
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be a function progress(done, total, text), got {progress!r}")
    return options, chosen, distributed.executor_of(executor)


def chosen_scenarios(study: CaseStudy, options: Options, notes: list) -> list[TableScenario]:
    """The study's scenarios that `options` asks for, in the study's order; without samples (mc = 0)
    the Monte Carlo is left out and a note says so (appended to `notes`)."""
    scenarios = [s for s in study.scenarios if options.scenarios is None or s.name in options.scenarios]
    if options.mc == 0 and any(s.monte_carlo for s in scenarios):
        notes.append("Monte Carlo skipped (0 samples requested)")
        scenarios = [s for s in scenarios if not s.monte_carlo]
    return scenarios


def failed_row(err: Exception) -> dict:
    """The columns of a row an error stopped: NaN metrics, status "failed: <error>" (one line, at most
    200 characters) and the failed verdict."""
    status = f"failed: {type(err).__name__}: {err}".splitlines()[0][:200]
    row: dict = dict.fromkeys(metrics.METRIC_COLUMNS, math.nan)
    return row | {"status": status} | verdict_columns(specs.Verdict(specs.FAILED, (), status))


class Simulation:
    """The rows of one study, made controller by controller and scenario by scenario.

    Holds what the runs leave for the `StudyResult`: `rows` (one dict per table row), `runs`
    ((label, scenario) -> ClosedLoopResult of the scenarios that are not the Monte Carlo), `envelopes`
    (label -> Envelope), `samples` (one DataFrame of per-sample rows per Monte Carlo), `truths`
    (label -> simulated plant), `seconds` (simulate_s, monte_carlo_s) and `notes` (failed rows appended).
    """

    def __init__(self, study: CaseStudy, options: Options, plant: models.Plant, executor, notes: list | None = None):
        self.study, self.options, self.plant, self.executor = study, options, plant, executor
        self.notes = [] if notes is None else notes
        _, self.base = tracked_equilibrium(plant, study)
        self.tracked_index = plant.state_names.index(study.tracked)
        self.rows: list[dict] = []
        self.runs: dict = {}
        self.envelopes: dict[str, Envelope] = {}
        self.samples: list[pd.DataFrame] = []
        self.truths: dict = {}
        self.seconds = {"simulate_s": 0.0, "monte_carlo_s": 0.0}
        self.loops: dict = {}
        self.failures: dict = {}  # (label, status) -> (index in notes, scenarios)

    def run_all(self, designed: Mapping, scenarios: Sequence[TableScenario], progress=None) -> None:
        """Every controller of `designed` through every scenario, in that order; `progress(done, total,
        text)` after each row."""
        total, done = len(designed) * len(scenarios), 0
        for label, controller in designed.items():
            truth = self.truths[label] = self.study.truth(self.plant, label)
            for scenario in scenarios:
                self.rows.append(self.row(label, controller, truth, scenario))
                done += 1
                if progress:
                    progress(done, total, f"{self.study.plant}: {label} / {scenario.name}")

    def note_failure(self, label: str, scenario: str, status: str) -> None:
        """Note "label / scenario: status", or add `scenario` to the note of the same label and status
        ("tube MPC / step, steps: failed: ..."), so that a controller failing alike everywhere is one note."""
        key = (label, status)
        if key in self.failures:
            index, names = self.failures[key]
            names.append(scenario)
            self.notes[index] = f"{label} / {', '.join(names)}: {status}"
        else:
            self.failures[key] = (len(self.notes), [scenario])
            self.notes.append(f"{label} / {scenario}: {status}")

    def row(self, label: str, controller, truth: models.Plant, scenario: TableScenario) -> dict:
        """The table row of `controller` in `scenario` on `truth`: a failed row (noted) when an error
        stops it, unless the options are strict; Ctrl-C and a lost cluster stop the study."""
        tick = time.perf_counter()
        python = not isinstance(controller, Block)
        row: dict = {"controller": label, "scenario": scenario.name, "kind": "python" if python else "block"}
        remark = getattr(controller, "remark", None) or ""
        try:
            if scenario.monte_carlo:
                row |= self.monte_carlo_row(label, controller, truth, scenario)
            else:
                row |= self.scenario_row(label, controller, truth, scenario)
        except distributed.RunFailed:
            raise
        except Exception as err:
            if interrupts.is_interrupt(err):  # Ctrl-C, which CasADi may report as an error
                raise KeyboardInterrupt from err
            explained = bool(str(err)) and str(err) in remark  # a refused construction's stand-in
            if self.options.strict and not explained:
                raise
            row |= failed_row(err)
            if not explained:
                self.note_failure(label, scenario.name, row["status"])
        if remark:
            row["verdict_detail"] = remarked(row.get("verdict_detail"), remark)
            row["remark"] = remark
        elapsed = time.perf_counter() - tick
        row["wall_s"] = elapsed
        self.seconds["monte_carlo_s" if scenario.monte_carlo else "simulate_s"] += elapsed
        if not python:
            # A closed loop of 60000 steps holds hundreds of MB of work memory; rows of the same length
            # are rare (step and noise), so free it now rather than hold every row's at once.
            try:
                models.closed_loop.release(truth, controller)
            except Exception:  # a Block whose expression raised has nothing cached; its row says why
                if not row["status"].startswith("failed"):
                    raise
        interrupts.check()
        return row

    def exported(self, label: str, controller, truth: models.Plant):
        """The C closed loop of an MPC row (`studies.exported_runs`), compiled once for all its runs (the
        references of every scenario of the study); None where it steps in Python."""
        if label not in self.loops:
            self.loops[label] = None
            if exported_runs.wanted(self.options.jit, controller):
                study = self.study
                runs = [(s.reference(study, self.base), s.duration(study)) for s in study.scenarios]
                self.loops[label] = exported_runs.exported_loop(
                    label, controller, truth, runs, study.substeps, self.notes
                )
        return self.loops[label]

    def scenario_row(self, label: str, controller, truth: models.Plant, scenario: TableScenario) -> dict:
        """The columns of one run of `scenario` (not the Monte Carlo): metrics, status and verdict."""
        study = self.study
        result = simulate_scenario(
            truth,
            controller,
            scenario,
            study,
            self.options,
            self.base,
            study.substeps,
            loop=self.exported(label, controller, truth),
        )
        self.runs[(label, scenario.name)] = result
        return judge_run(study, scenario.name, result, truth.params, controller=controller, plant=truth).row()

    def monte_carlo_runs(
        self, label: str, truth: models.Plant, controller, scenario: TableScenario, samples: np.ndarray
    ) -> Iterable:
        """The runs of `controller` on `truth` with each row of `samples` (parameters), yielded as they are
        simulated: a Block's as one batched map (a chunk at a time here, in parts on a Dask executor), an
        MPC's by its exported C (`studies.exported_runs`) or else stepped together in Python, any other's
        one by one."""
        study, options, base = self.study, self.options, self.base
        duration = scenario.duration(study)
        steps = int(round(duration / controller.sample_period))
        if isinstance(controller, Block):
            jit = use_jit(options, truth, controller, len(samples), steps, study.substeps)
            if isinstance(self.executor, distributed.Local):
                chunks = models.monte_carlo_chunks(
                    truth,
                    controller,
                    scenario.reference(study, base),
                    duration,
                    samples,
                    seed=options.seed,
                    threads=options.threads,
                    substeps=study.substeps,
                    jit=jit,
                )
                return (run for chunk in chunks for run in chunk)
            return distributed.monte_carlo(
                self.executor,
                truth,
                controller,
                scenario.reference(study, base),
                duration,
                samples,
                seed=options.seed,
                threads=options.threads,
                substeps=study.substeps,
                jit=jit,
            )
        if getattr(controller, "lockstep", False):  # the samples stepped together: the same runs, faster
            noise = (
                measurement_noise_std(truth, controller, scenario.noise, sigma=study.derivative_time_constant)
                if scenario.noise
                else 0.0
            )
            reference = scenario.reference(study, base)
            common: dict[str, Any] = dict(
                substeps=study.substeps,
                input_disturbance=study.input_disturbance if scenario.input_disturbance else 0.0,
                noise_std=noise,
                seed=options.seed,
            )
            loop = self.exported(label, controller, truth)
            if loop is not None:
                return exported_loop.simulate_exported_many(
                    truth, controller, loop, reference, duration, samples, threads=options.threads, **common
                )
            return models.simulate_closed_loop_many(truth, controller, reference, duration, samples, **common)
        return (
            simulate_scenario(truth, controller, scenario, study, options, base, study.substeps, params=row)
            for row in samples
        )

    def monte_carlo_row(self, label: str, controller, truth: models.Plant, scenario: TableScenario) -> dict:
        """The Monte Carlo row of one controller: the worst sample's metrics (`models.metrics.aggregate`),
        the status over the samples and the combined verdict. Its per-sample rows go to `samples` (one
        DataFrame) and its envelope to `envelopes`. Samples are consumed as they are simulated: only the
        tracked coordinate and the first input of each stay."""
        study, count = self.study, self.options.mc
        batched = isinstance(controller, Block)
        steps = int(round(scenario.duration(study) / controller.sample_period))
        checks.check_memory(
            monte_carlo_bytes(study, self.options, truth.n_params, controller.sample_period),
            f"the Monte Carlo of {label} ({count} samples of {steps} steps)",
            "give fewer samples (mc)",
        )
        # The same seeded samples for every controller.
        samples = models.sample_params(truth, count, rel=scenario.rel, seed=self.options.seed)
        names = list(truth.params)
        per_sample, verdicts, diverged_at, tracked, inputs, step_times = [], [], [], [], [], []
        counts = np.zeros(3, dtype=int)
        t: np.ndarray | None = None
        reference: np.ndarray | None = None
        for result, row in zip(self.monte_carlo_runs(label, truth, controller, scenario, samples), samples):
            judgement = judge_run(study, scenario.name, result, dict(zip(names, row)))
            per_sample.append(judgement.metrics)
            verdicts.append(judgement.verdict)
            if t is None:
                t, reference = np.array(result.t), np.array(result.r[:, 0])
            diverged_at.append(math.nan if result.diverged_at is None else float(result.diverged_at))
            if result.diverged_at is None:
                tracked.append(np.array(result.x[:, self.tracked_index]))
                inputs.append(np.array(result.u[:, 0]))
            if not batched:
                step_times.append(result.step_time)
                counts += solver_counts(result.status)
        self.samples.append(_sample_frame(label, names, samples, per_sample, diverged_at, verdicts))
        if t is None or reference is None:
            raise ValueError(f"the Monte Carlo of {label} ran no sample")
        self.envelopes[label] = _envelope(t, reference, tracked, inputs, count)
        out = metrics.aggregate(per_sample) | _monte_carlo_status(diverged_at, counts, count)
        out |= verdict_columns(specs.combine(verdicts))
        if not batched:
            out["step_ms"] = 1e3 * float(np.nanmean(np.concatenate(step_times)))
            out["step_ms_max"] = 1e3 * float(np.nanmax(np.concatenate(step_times)))
            out["solver_issues"] = float(counts[1]) if counts[0] else math.nan
        return out


def _sample_frame(label: str, names: list, samples: np.ndarray, per_sample: list, diverged_at: list, verdicts: list):
    """The per-sample rows of one controller's Monte Carlo: controller, sample index, the sample's
    parameters (columns `names`), its metrics, divergence time (NaN if none) and verdict."""
    frame = pd.DataFrame(per_sample)
    frame.insert(0, "controller", label)
    frame.insert(1, "sample", np.arange(len(samples)))
    for j, name in enumerate(names):
        frame.insert(2 + j, name, samples[:, j])
    frame["diverged_at_s"] = diverged_at
    for key in ("verdict", "verdict_detail"):
        frame[key] = [verdict_columns(v)[key] for v in verdicts]
    return frame


def _monte_carlo_status(diverged_at: list, counts: np.ndarray, count: int) -> dict:
    """The status columns of a Monte Carlo row from each sample's divergence time (s, NaN if none) and
    the (steps, failed solves, fallbacks) summed over the samples."""
    diverged = [t for t in diverged_at if not math.isnan(t)]
    if diverged:
        status = f"diverged: {len(diverged)} of {count} samples, first at t = {min(diverged):.3g} s"
    else:
        steps_run, failed, fallback = (int(c) for c in counts)
        status = degraded_status(steps_run, failed, fallback, what=f"steps of {count} samples") or "ok"
    return {
        "status": status,
        "samples": count,
        "diverged_samples": len(diverged),
        "diverged_at_s": min(diverged) if diverged else None,
    }


def simulate_scenario(
    plant,
    controller,
    scenario: TableScenario,
    case,
    options: Options,
    base: float,
    substeps: int,
    params=None,
    loop=None,
    noise_sample: int | None = None,
):
    """One run of `scenario` on `plant` (parameters `params`, default its own): noise, disturbance, seed;
    the run as `scenario.run` describes it (`models.scenario.Scenario`); by `controller`'s exported C
    closed loop `loop` (`models.exported_loop`) where given, the same run to 1e-9. The noise is drawn from
    `options.seed`, or with `noise_sample` j as Monte Carlo sample j's (`designs.tuning`'s sample j's)."""
    seed = options.seed if noise_sample is None else np.random.SeedSequence([options.seed, noise_sample])
    sigma = case.derivative_time_constant
    noise = measurement_noise_std(plant, controller, scenario.noise, sigma=sigma) if scenario.noise else 0.0
    run = scenario.run(case, base, noise)
    if loop is not None:
        runs = exported_loop.simulate_exported_many(
            plant,
            controller,
            loop,
            run.reference,
            run.duration,
            plant.param_vector(params)[None],
            substeps=substeps,
            input_disturbance=run.input_disturbance,
            noise_std=run.noise_std,
            seed=seed,
        )
        return next(iter(runs))
    return models.simulate_closed_loop(
        plant,
        controller,
        run.reference,
        run.duration,
        params=params,
        substeps=substeps,
        input_disturbance=run.input_disturbance,
        noise_std=run.noise_std,
        seed=seed,
        allow_divergence=True,
    )


TABLE_COLUMNS = (
    "controller",
    "scenario",
    "status",
    "verdict",
    "verdict_detail",
    "remark",
    *metrics.METRIC_COLUMNS,
    "solver_issues",
    "samples",
    "diverged_samples",
    "diverged_at_s",
    *(f"{k}_std" for k in metrics.SPREAD_COLUMNS),
    "kind",
    "tracked",
    "tracked_unit",
    "input_unit",
    "wall_s",
)


def _frame(rows: list, study: CaseStudy) -> pd.DataFrame:
    """The study table of `rows` (dicts): the columns of `TABLE_COLUMNS` in that order, absent ones NaN."""
    frame = pd.DataFrame(rows)
    for column in TABLE_COLUMNS:
        if column not in frame:
            frame[column] = np.nan
    frame["tracked"] = study.tracked
    frame["tracked_unit"] = study.tracked_unit
    frame["input_unit"] = study.input_unit
    if len(frame):
        frame["samples"] = frame["samples"].fillna(1).astype(int)
        frame["diverged_samples"] = frame["diverged_samples"].fillna(0).astype(int)
    return frame[list(TABLE_COLUMNS)]
