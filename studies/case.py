"""A case study as one record: the text's numbers, the study table it asks for, and what its chapter decides.

A case file (``studies/cases/<name>.py``) defines ``CASE = CaseStudy(...)``;
`studies.cases` discovers it. Everything the engine needs from a case is a
field here: the plant's registry name, the tracked coordinate and the text's
step, disturbance and sample periods; the scenarios and controllers of its
table and the providers they come from; and its designs (classical homework,
state-space choices, MPC settings, co-design problems), its animation drawing
and its errata. Nothing in the library packages (`designs`, `mpc`) names a case.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import models
from models import signals
from models.scenario import Scenario
from models.specs import Specs

#: The scenarios a study can run, as named on the command line (`TableScenario.name`).
SCENARIO_NAMES = ("step", "steps", "disturbance", "noise", "mc")

#: The text's parameter error: the controller knows each uncertain parameter to ±5 % (I.11(a), II.11(a), ...).
KNOWN_ERROR = 0.05

#: Controller labels in table order; a provider's other labels follow these.
CONTROLLERS = (
    "PD",
    "PID",
    "PID (no anti-windup)",
    "loopshaped",
    "pole placement",
    "pole placement + integrator",
    "observer-based",
    "disturbance observer",
    "LQR",
    "LQR + Kalman",
    "linear MPC",
    "nonlinear MPC",
    "tuned",
)


# ---------------------------------------------------------------------------- scenarios
@dataclass(frozen=True)
class TableScenario:
    """One column block of a study table: what the closed loop is asked to do, relative to a case.

    `run` turns it into the one run record, `models.scenario.Scenario`, that the study simulates.

    Attributes
    ----------
    name : short name used on the command line ("step", "steps", "disturbance", "noise", "mc")
    title : one line for captions
    levels : reference levels as multiples of the case's step, added to the equilibrium value
    segment_fraction : each level lasts this fraction of the case's duration
    input_disturbance : add the case's constant input disturbance from t = 0
    noise : standard deviation of the measurement noise per plant output (SI units)
    monte_carlo : run on parameter samples (the text's ±5 %) instead of the nominal plant
    rel : half-width of the uniform parameter spread of the Monte Carlo
    """

    name: str
    title: str
    levels: tuple = (1.0,)
    segment_fraction: float = 1.0
    input_disturbance: bool = False
    noise: Mapping[str, float] = field(default_factory=dict)
    monte_carlo: bool = False
    rel: float = KNOWN_ERROR

    def duration(self, case: CaseStudy) -> float:
        """Length of the run, s."""
        return case.duration * self.segment_fraction * len(self.levels)

    def reference(self, case: CaseStudy, equilibrium_value: float):
        """The reference signal: the equilibrium value plus the levels times the case's step."""
        if len(self.levels) == 1:
            return signals.step(self.levels[0] * case.step, 0.0, equilibrium_value)
        return signals.steps(
            [level * case.step for level in self.levels], case.duration * self.segment_fraction, equilibrium_value
        )

    def run(self, case: CaseStudy, equilibrium_value: float, noise_std=0.0) -> Scenario:
        """This scenario of `case` as a `models.scenario.Scenario`: the reference signal from the tracked
        coordinate's `equilibrium_value`, the duration, the case's input disturbance when asked, the tracked
        coordinate; `noise_std` the measurement noise's std per measurement (units of the measurements,
        `studies.runner.measurement_noise_std`, which needs the controller)."""
        return Scenario(
            self.reference(case, equilibrium_value),
            self.duration(case),
            input_disturbance=case.input_disturbance if self.input_disturbance else 0.0,
            tracked=case.tracked,
            noise_std=noise_std,
            name=self.name,
        )


def step() -> TableScenario:
    """The text's step on the tracked coordinate, from the standard equilibrium, sized to saturate."""
    return TableScenario("step", "the text's step from the equilibrium (sized to saturate the actuator)")


def series_of_steps(levels=(1.0, 0.0, -1.0, 0.0), segment_fraction: float = 0.5) -> TableScenario:
    """Steps through `levels` (multiples of the case's step), each held `segment_fraction` of the duration."""
    text = ", ".join(f"{level:+g}" for level in levels)
    return TableScenario("steps", f"a series of steps ({text} times the text's step)", tuple(levels), segment_fraction)


def input_disturbance() -> TableScenario:
    """The step with the case's constant input disturbance acting from t = 0 (the text's .16/.17)."""
    return TableScenario(
        "disturbance", "the step with the case's constant input disturbance from t = 0", input_disturbance=True
    )


def measurement_noise(noise: Mapping[str, float]) -> TableScenario:
    """The step with seeded Gaussian measurement noise of the given standard deviation per output (SI)."""
    text = ", ".join(f"{k}: {v:g}" for k, v in noise.items())
    return TableScenario("noise", f"the step with seeded measurement noise (std {text}, SI)", noise=dict(noise))


def parameter_monte_carlo(rel: float = KNOWN_ERROR) -> TableScenario:
    """The step on plants whose uncertain parameters are uniform within ±rel of nominal."""
    return TableScenario(
        "mc", f"the step on ±{100 * rel:g} % parameter samples (Monte Carlo)", monte_carlo=True, rel=rel
    )


def standard_scenarios(noise: Mapping[str, float]) -> tuple:
    """The five scenarios every case study runs: step, series of steps, disturbance, noise, Monte Carlo."""
    return (step(), series_of_steps(), input_disturbance(), measurement_noise(noise), parameter_monte_carlo())


@dataclass(frozen=True)
class LoopSpec:
    """Frequency-domain specs of a loopshaping homework, drawn on its Bode plot (and designed to).

    Attributes
    ----------
    item : homework item the specs come from ("I.14")
    loop : where the loop is broken: "input" (plant input), "outer" or "inner" (of a `models.Cascade`)
    design : label of the loopshaped controller
    baseline : label of the controller the relative specs refer to (the PD of .9)
    low_frequency : rad/s; below it |L| must be `factor` times the baseline's
    high_frequency : rad/s; above it |L| must be 1/`factor` times the baseline's
    factor : improvement factor
    crossover : rad/s, target crossover (bandwidth) frequency
    phase_margin : deg, least phase margin
    """

    item: str
    loop: str = "input"
    design: str = "loopshaped"
    baseline: str | None = "PD"
    low_frequency: float | None = None
    high_frequency: float | None = None
    factor: float = 10.0
    crossover: float | None = None
    phase_margin: float | None = None


# ---------------------------------------------------------------------------- the case
@dataclass(frozen=True)
class CaseStudy:
    """Everything one case study decides (SI units, angles in rad).

    The text's numbers
    ------------------
    plant : registry name of the plant in `models`
    numeral : the case study's Roman numeral, prefix of its homework items ("I"); orders the registry
    tracked : the coordinate that follows the reference
    design_step : step on the tracked coordinate used by the saturation rules (.8)
    step : step commanded in the comparisons, from the standard equilibrium
    input_disturbance : constant input disturbance of the .16/.17 problems (units of u)
    sample_period : controller sample period (.11), s: the one source of every block's and MPC's sample
        period in the case (an MPC whose horizon needs seconds samples at a multiple of it)
    derivative_time_constant : σ of the dirty derivative s/(σ s + 1) of the case's PID blocks and their
        .13 loops (.11: the text's "dirty derivative gain τ = 0.05"), s; also the σ with which the runner
        turns position noise into the velocity noise of a controller that reads the full state
    observer_sample_period : sample period of the observer problems (.15), where different, s
    duration : length of a step scenario, s
    source : where each number comes from

    The study table
    ---------------
    tracked_unit, input_unit : units of the tracked coordinate and of the input, for labels
    scenarios : the scenarios, in table order
    controllers : labels in table order (providers' other labels are appended)
    providers : callables ``provider(case, known) -> {label: controller}``, asked in order for the table's
        controllers (keyword only; `studies.providers.STANDARD` are the case's own designs by kind)
    answer_providers : callables ``provider(case) -> {item: {name: value}}`` of the homework answers
        (keyword only; `studies.providers.STANDARD_ANSWERS` are the case's own)
    bounds : params dict -> {state name: (low, high)}, counted as constraint violation and judged as a spec
    state_limits : the plant's physical limits (`models.state_limits.StateLimit`, with their source), judged
        on every scenario and Monte Carlo sample (`specs_for`)
    specs : scenario name -> `models.specs.Specs` the rows of that scenario are judged by; "*" for the
        scenarios not named (default: no step specs, only the actuator limit, the bounds and no limit cycle)
    loops : the loopshaping specs (`LoopSpec`), one Bode plot each
    cascade : (inner output, outer output) of the .6 transfer-function cascade
    cascade_model : (plant name, parameter overrides) of the .6 model when it is not the plant itself
    known_rel : controllers are designed from the plant with its uncertain parameters scaled by 1 + known_rel
    input_limits : controller label -> actuator limit of the plant that controller runs on, where the
        text gives that design its own actuator (IV.11: 250 N m thrusters)
    substeps : RK4 sub-steps of the plant per controller sample. Two (5 ms at Ts = 10 ms) resolve every
        case's open-loop dynamics (at most a few rad/s) to about 1e-7 relative in the table's metrics,
        checked against 10 by tests/studies/test_runner.py, at a third of the cost.

    What the chapter designs
    ------------------------
    classical : known Plant -> `studies.homework.ClassicalDesign` (the .8-.14 answers and controllers)
    statespace : `studies.homework.StateSpaceChoices` (.15-.17: poles, observers, LQR weights)
    mpc : `mpc.MPCSettings` of its linear and nonlinear MPC
    design_models : other plants the designs accept as the known plant (the crane's one-load crane1)
    codesign : key -> function returning a `studies.codesign_report.CaseResult` (its co-design problems)
    drawing : (params dict, state dict, reference) -> animation primitives (`studies.animation`)
    errata : `studies.errata.Erratum` rows and remarks this case found in the text
    trajectories : `studies.trajectories.TrajectoryProblem`s, its optimal motions (solved, tracked and
        drawn by `studies.trajectories`)
    open_loop_codesign : `studies.codesign_open_loop.OpenLoopCodesign`s, plant parameters decided with
        an input history (reported by `studies.codesign_open_loop`)
    """

    plant: str
    numeral: str
    tracked: str
    design_step: float
    step: float
    input_disturbance: float
    tracked_unit: str
    input_unit: str
    scenarios: tuple
    sample_period: float = 0.01
    derivative_time_constant: float = 0.05
    observer_sample_period: float = 0.01
    duration: float = 10.0
    source: str = ""
    controllers: tuple = CONTROLLERS
    # Keyword-only and required: a case says where its controllers and answers come from.
    providers: tuple = field(kw_only=True)
    answer_providers: tuple = field(kw_only=True)
    bounds: Callable[[dict], dict] | None = None
    state_limits: tuple = ()
    specs: Mapping[str, Specs] = field(default_factory=dict)
    loops: tuple = ()
    cascade: tuple | None = None
    cascade_model: tuple | None = None
    known_rel: float = KNOWN_ERROR
    input_limits: Mapping[str, float] = field(default_factory=dict)
    substeps: int = 2
    classical: Callable[[models.Plant], Any] | None = None
    statespace: Any = None
    mpc: Any = None
    design_models: tuple = ()
    codesign: Mapping[str, Callable[[], Any]] = field(default_factory=dict)
    drawing: Callable[[dict, dict, float], list] | None = None
    errata: tuple = ()
    trajectories: tuple = ()
    open_loop_codesign: tuple = ()

    @property
    def name(self) -> str:
        """The case's registry name (its plant's)."""
        return self.plant

    def truth(self, plant: models.Plant, label: str) -> models.Plant:
        """The simulated plant of controller `label`: `plant`, with its own actuator if the text gives one."""
        return plant.with_input_limit(self.input_limits[label]) if label in self.input_limits else plant

    def state_bounds(self, params: Mapping[str, float]) -> dict:
        """{state name: (low, high)} of the plant with `params` (`bounds`; none without it), SI units."""
        return dict(self.bounds(dict(params))) if self.bounds else {}

    def specs_for(self, scenario: str, params: Mapping[str, float]) -> Specs:
        """The specs of `scenario` on the plant with `params`: the case's, with its state bounds and its
        physical limits (`state_limits`, at `params`) added."""
        chosen = self.specs.get(scenario, self.specs.get("*", Specs()))
        return chosen.with_state_bounds(self.state_bounds(params)).with_limits(self.state_limits, params)

    def known_plant(self, plant: models.Plant | None = None) -> models.Plant:
        """The model the controllers are designed from: the uncertain parameters of `plant` (default the
        case's plant with the text's parameters) scaled by 1 + known_rel."""
        plant = models.get(self.plant) if plant is None else plant
        return models.perturbed(plant, self.known_rel, 1.0) if self.known_rel else plant


ROMAN = {"I": 1, "V": 5, "X": 10, "L": 50, "C": 100}


def numeral_value(numeral: str) -> int:
    """The integer of a Roman numeral ("VI" -> 6); ValueError for anything else."""
    if not numeral or any(c not in ROMAN for c in numeral):
        raise ValueError(f"numeral must be a Roman numeral such as 'VII', got {numeral!r}")
    values = [ROMAN[c] for c in numeral]
    return sum(-v if i + 1 < len(values) and v < values[i + 1] else v for i, v in enumerate(values))
