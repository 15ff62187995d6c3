"""The interactive control designer: move a gain, see the nonlinear response, the verdict and the loop.

>>> from studies import designer
>>> session = designer.Designer.for_case("arm", "PD")
>>> update = session.update({"kp": 0.3})      # nonlinear run, verdict, Bode, margins, root locus
>>> update.status, str(update.verdict)

``python -m studies.designer [PLANT] [CONTROLLER]`` serves it as a page in the
browser (`studies.designer.app`). This module is the part without a page:
`Designer.update` takes gain values and returns everything the page draws, so
the benchmark (``benchmarks/designer.py``) and the tests call exactly what a
gain change on the page calls.

What an update computes, with the project's one mechanism for each:

* the run of the chosen scenario on the nonlinear plant (the truth, the text's
  parameters): `studies.runner.simulate_scenario`, that is
  `models.simulate_closed_loop`, compiled and cached per controller structure,
  so a new gain value costs one call of the cached closed loop;
* the verdict against the case's specs: `studies.judging.judge_run`, the one rule
  the study tables use (metrics, status, verdict);
* the loop gain about the end of the run (`studies.loops.loop`, exact
  Jacobians of the block and the plant): its Bode plot, its gain and phase
  margins (`studies.loops.LoopGain.margins`), the case's loopshaping specs
  (`studies.case.LoopSpec`) and the root locus: the closed-loop poles
  eig(A - k B C) of the loop gain scaled by k (`LOCUS_GAINS`), in the s-plane
  (s = ln z / Ts), with the current poles (k = 1).

Each gain element of the block gets a `GainControl`: its range is
`RANGE` times the designed value either way, sign kept, on a log scale; an
element the design sets to zero (a padded coefficient, a feedforward the
design leaves out) stays zero and gets no control. A typed value is checked by
`GainControl.parse`, which refuses a non-number, a non-finite value or a value
outside the range with a one-line message. A pole-placement design also gets
controls of its desired poles (`pole_controls`); `Designer.place` redesigns
its gains from them. Beside the update: `Designer.envelope` (the ±5 % Monte
Carlo of the same gains, one batched `models.monte_carlo`), `Designer.tune`
(`designs.tuning.tune` from the gains in force) and `Designer.export` (the
gains, and the C step of `models.export.export_block`).
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

# One OpenBLAS thread: the update's small matrix exponential is far slower spread over threads on a loaded
# machine (measured in docs/designer.md). It takes effect only where numpy is not imported yet (as under
# ``python -m studies.designer`` and ``benchmarks/designer.py``).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import models  # noqa: E402
from designs import tuning  # noqa: E402
from models import Block, Cascade, export, specs  # noqa: E402

from .. import cases, homework, judging, loops, providers, runner, tuner  # noqa: E402
from ..case import KNOWN_ERROR, CaseStudy, LoopSpec, TableScenario  # noqa: E402

#: Each gain element ranges over [value / RANGE, value * RANGE] (sign kept).
RANGE = 10.0
#: Points of the Bode plot (and of the margins computed from it), log-spaced up to the Nyquist frequency.
FREQUENCIES = 240
#: Lowest frequency of the Bode plot, rad/s.
LOWEST_FREQUENCY = 1e-3
#: Frequencies of each band of a loopshaping spec check (`studies.loops.spec_check`).
SPEC_POINTS = 120
#: Loop gain multipliers k of the root locus (k = 1 is the design).
LOCUS_GAINS = np.logspace(-2, 2, 121)
#: Providers the designer does not ask: their controllers are not Blocks (an MPC has no gains to move).
SKIPPED_PROVIDERS = (providers.mpc,)
#: Plants of the optional Monte Carlo envelope, and the quantiles it draws.
ENVELOPE_SAMPLES = 20
ENVELOPE_QUANTILES = (0.0, 0.05, 0.5, 0.95, 1.0)
#: The state-space designs whose gains come from the desired poles (`studies.homework.StateSpaceChoices.poles`);
#: the LQR designs come from weights instead.
POLE_LABELS = ("pole placement", "pole placement + integrator", "observer-based", "disturbance observer")
#: Scenarios the designer offers: the case's, without the Monte Carlo.
SCENARIOS = ("step", "steps", "disturbance", "noise")


# ---------------------------------------------------------------------------- gains
@dataclass(frozen=True)
class GainControl:
    """One scalar of a block's gains, as the page controls it.

    Attributes
    ----------
    key : "kp", "K[0,2]" or "outer.num[3]": the gain's name and, for an array, the element's index
    gain : the gain's name in `models.Block.gains`;  index : the element's index in that array (() for a scalar)
    design : the designed value (never zero)
    low, high : the allowed range, low < high, both of the design's sign
    """

    key: str
    gain: str
    index: tuple
    design: float
    low: float
    high: float

    @property
    def log_low(self) -> float:
        """log10 |value| at the range's end nearer zero (the slider moves on log10 |value|)."""
        return math.log10(min(abs(self.low), abs(self.high)))

    @property
    def log_high(self) -> float:
        """log10 |value| at the range's end farther from zero."""
        return math.log10(max(abs(self.low), abs(self.high)))

    @property
    def sign(self) -> float:
        """+1.0 or -1.0: the design's sign, which every value in the range keeps."""
        return math.copysign(1.0, self.design)

    def from_log(self, exponent: float) -> float:
        """The gain value at slider position log10 |value| = `exponent`."""
        return self.sign * 10.0 ** float(exponent)

    def parse(self, text) -> float:
        """The value `text` asks for, or ValueError with a one-line message naming the gain.

        Refused: anything that is not a number, a non-finite number, a number outside [low, high].
        """
        try:
            value = float(str(text).strip()) if not isinstance(text, (int, float)) else float(text)
        except ValueError:
            raise ValueError(
                f"{self.key}: {str(text)!r} is not a number; give a value in [{self.low:.4g}, {self.high:.4g}]"
            ) from None
        if not math.isfinite(value):
            raise ValueError(f"{self.key}: {value} is not finite; give a value in [{self.low:.4g}, {self.high:.4g}]")
        if not self.low <= value <= self.high:
            raise ValueError(
                f"{self.key}: {value:.6g} is outside the allowed range [{self.low:.4g}, {self.high:.4g}] "
                f"({RANGE:g} x the design's {self.design:.4g} either way, sign kept)"
            )
        return value


def gain_controls(block: Block, spread: float = RANGE) -> tuple[GainControl, ...]:
    """A `GainControl` for every non-zero element of `block`'s gains, in `block.gain_names` order."""
    out = []
    for name, value in block.gains.items():
        value = np.asarray(value, dtype=float)
        for index in np.ndindex(value.shape):
            design = float(value[index])
            if design == 0.0:
                continue
            key = name if value.ndim == 0 else f"{name}[{','.join(str(i) for i in index)}]"
            low, high = sorted((design / spread, design * spread))
            out.append(GainControl(key, name, tuple(index), design, low, high))
    return tuple(out)


def with_values(block: Block, controls, values: Mapping[str, float]) -> Block:
    """`block` with the gain elements named in `values` (control key -> value) replaced.

    Raises ValueError naming the key for an unknown control or a value `GainControl.parse` refuses.
    """
    by_key = {c.key: c for c in controls}
    gains = {name: np.array(v, dtype=float) for name, v in block.gains.items()}
    for key, value in values.items():
        if key not in by_key:
            raise ValueError(f"{block.name} has no gain control {key!r}; controls are {', '.join(by_key)}")
        control_ = by_key[key]
        gains[control_.gain][control_.index] = control_.parse(value)
    return block.with_gains(**gains)


# ---------------------------------------------------------------------------- one update
@dataclass
class Update:
    """Everything the page draws after a gain change (SI units; angles in rad).

    Attributes
    ----------
    gains : control key -> value of this update
    scenario : the scenario's name
    t : (N+1,) s;  tracked, reference : (N+1,) the tracked coordinate and its reference
    u : (N,) the commanded input (first input; the plant gets it clipped to `input_limit`)
    input_limit : the actuator limit (first input)
    status : "ok" or "diverged at t = ... s", as in the study tables
    verdict : `models.specs.Verdict` against the case's specs for this scenario
    metrics : the run's metrics (`models.metrics.run_metrics`)
    loop : where the loop is broken ("input", "outer", "inner"), or "" when there is no loop analysis
    omega : (F,) rad/s;  magnitude_db, phase_deg : (F,) of the loop gain L(e^{jωTs})
    margins : gain_margin_db, phase_margin_deg, phase_crossover_rad_s, gain_crossover_rad_s
    locus : (K, n) closed-loop poles in the s-plane for the gains `LOCUS_GAINS` (complex, NaN where z = 0)
    poles : (n,) the closed-loop poles in the s-plane at k = 1
    loop_specs : the loopshaping specs of the loop and whether they hold (`studies.loops.spec_check`),
        with their bounds as curves: {"item", "checks", "low" (omega, |L| bound dB), "high" (...)}
    notes : what could not be computed and why
    seconds : wall time of the update, s
    run : the `models.ClosedLoopResult` itself (for the animation)
    """

    gains: dict
    scenario: str
    t: np.ndarray
    tracked: np.ndarray
    reference: np.ndarray
    u: np.ndarray
    input_limit: float
    status: str
    verdict: specs.Verdict
    metrics: dict
    loop: str = ""
    omega: np.ndarray = field(default_factory=lambda: np.zeros(0))
    magnitude_db: np.ndarray = field(default_factory=lambda: np.zeros(0))
    phase_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    margins: dict = field(default_factory=dict)
    locus: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=complex))
    poles: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    loop_specs: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    seconds: float = 0.0
    run: models.ClosedLoopResult | None = None

    @property
    def diverged(self) -> bool:
        """Whether the run diverged (its status says at what time)."""
        return self.status.startswith("diverged")

    def verdict_text(self) -> str:
        """One line: the status when the run diverged, else the verdict and what it found."""
        return self.status if self.diverged else str(self.verdict)


def loop_spec_curves(
    spec: LoopSpec, design: loops.LoopGain, baseline: loops.LoopGain | None, margins: dict, omega: np.ndarray
) -> dict:
    """The loopshaping `spec`'s checks on `design` and its bounds on |L| in dB over `omega`.

    The band checks are `studies.loops.spec_check`'s; the crossover and phase margin are judged with its
    rules (crossover within a factor 1.5, at least the phase margin) on `margins`, the update's own.
    """
    checks = loops.spec_check(design, replace(spec, crossover=None, phase_margin=None), baseline, points=SPEC_POINTS)
    if spec.crossover is not None:
        wc = margins["gain_crossover_rad_s"]
        checks["crossover"] = bool(np.isfinite(wc) and spec.crossover / 1.5 <= wc <= spec.crossover * 1.5)
    if spec.phase_margin is not None:
        checks["phase_margin"] = bool(margins["phase_margin_deg"] >= spec.phase_margin)
    curves: dict[str, Any] = {
        "item": spec.item,
        "checks": checks,
        "crossover": spec.crossover,
        "phase_margin": spec.phase_margin,
    }
    if baseline is not None:
        base_db = 20 * np.log10(np.abs(baseline.frequency_response(omega)))
        shift = 20 * math.log10(spec.factor)
        if spec.low_frequency is not None:
            below = omega <= spec.low_frequency
            curves["low"] = (omega[below], base_db[below] + shift)
        if spec.high_frequency is not None:
            above = omega >= spec.high_frequency
            curves["high"] = (omega[above], base_db[above] - shift)
    return curves


class Designer:
    """One plant and one controller block under design: the state behind the page.

    Parameters
    ----------
    case : the case study (its scenarios, specs, loopshaping specs, sample period)
    block : the designed controller (a `models.Block`); its gains are the design that Reset returns to
    label : the controller's label (its study label, "PD" ...)
    plant : the simulated plant (default the case's plant with the text's parameters, with the
        controller's own actuator where the case gives it one)
    baseline : the block the case's relative loopshaping specs refer to, or None
    poles, placement : for a pole-placement design, its desired poles (rad/s; conjugate pairs) and the
        function poles -> block that designs it (`pole_placement`); the poles then get controls
        (`pole_controls`) and `place` redesigns the gains from them
    c_prefix : the C name `export` gives the C step (a `models.export.c_name`); default derived from the
        plant's name and `label` (`models.export.c_identifiers`). `catalog` and `for_case` give each of a
        plant's controllers a distinct one.
    """

    def __init__(
        self,
        case: CaseStudy,
        block: Block,
        label: str | None = None,
        *,
        plant: models.Plant | None = None,
        baseline: Block | None = None,
        poles=None,
        placement: Callable[[np.ndarray], Block] | None = None,
        c_prefix: str | None = None,
    ):
        if not isinstance(case, CaseStudy):
            raise TypeError(f"case must be a studies CaseStudy, got {type(case).__name__} {case!r}")
        if not isinstance(block, Block):
            raise TypeError(f"block must be a models.Block (a controller with gains), got {type(block).__name__}")
        self.case = case
        self.block = self.text_block = block
        self.label = label or block.name
        self.c_prefix = (
            export.c_identifiers([f"{case.plant}_{self.label}"])[0] if c_prefix is None else export.c_name(c_prefix)
        )
        if (poles is None) != (placement is None):
            raise ValueError("give both poles and placement (the function that designs from them), or neither")
        self.text_poles = None if poles is None else np.asarray(poles, dtype=complex)
        self.placement = placement
        self.pole_controls = pole_controls(self.text_poles) if poles is not None else ()
        base_plant = models.get(case.plant) if plant is None else plant
        self.plant = case.truth(base_plant, self.label) if plant is None else plant
        self.controls = gain_controls(block)
        # Built once here, the step Function is shared by every block `with_gains` copies from this one, so
        # the compiled closed loop cached on the plant for it serves every update.
        block.casadi_step  # noqa: B018
        self.tracked_index = self.plant.state_names.index(case.tracked)
        self.equilibrium, self.base = runner.tracked_equilibrium(self.plant, case)
        self.options = runner.Options(mc=0)
        self.scenarios = {s.name: s for s in case.scenarios if not s.monte_carlo and s.name in SCENARIOS}
        if not self.scenarios:
            raise ValueError(f"{case.plant} has no scenario the designer runs ({', '.join(SCENARIOS)})")
        self.which = self._which_loop()
        spec = next((s for s in case.loops if s.loop == self.which), None)
        self.loop_spec = spec
        self.baseline_loop = None
        self.notes: list[str] = []
        if spec is not None and spec.baseline is not None and isinstance(baseline, Block):
            try:
                self.baseline_loop = self.loop_gain(baseline, self.simulate(baseline, "step"))
            except Exception as err:  # the relative specs need it; the rest of the page does not
                self.notes.append(f"no baseline loop ({type(err).__name__}: {err})")
        frequencies = np.logspace(
            math.log10(LOWEST_FREQUENCY), math.log10(0.999 * math.pi / block.sample_period), FREQUENCIES
        )
        self.omega = frequencies
        self.lock = threading.Lock()

    # ------------------------------------------------------------- construction from the studies
    @classmethod
    def for_case(cls, name: str | CaseStudy, label: str | None = None) -> Designer:
        """The designer of case `name`'s controller `label` (default its first Block), designed as the
        studies design it: from the model known to the controller (`CaseStudy.known_plant`)."""
        designed = designed_blocks(name)
        case = name if isinstance(name, CaseStudy) else cases.get(name)
        if not designed:
            raise ValueError(f"{case.plant} has no controller with gains to design")
        if label is None:
            label = next(iter(designed))
        if label not in designed:
            raise ValueError(f"{case.plant} has no controller {label!r} with gains; choose from {', '.join(designed)}")
        baseline = next((designed.get(s.baseline) for s in case.loops if s.baseline), None)
        prefix = c_prefixes(case.plant, list(designed))[label]
        return cls(case, designed[label], label, baseline=baseline, c_prefix=prefix, **pole_placement(case, label))

    # ------------------------------------------------------------- pole placement
    def poles_for(self, values: Mapping[str, float] | None = None) -> np.ndarray:
        """The desired poles with `values` (pole control key -> value; the others at the text's), checked."""
        if self.text_poles is None:
            raise ValueError(f"{self.label} is not a pole-placement design: it has no poles to place")
        by_key = {c.key: c for c in self.pole_controls}
        poles = self.text_poles.copy()
        for key, value in (values or {}).items():
            if key not in by_key:
                raise ValueError(f"{self.label} has no pole control {key!r}; controls are {', '.join(by_key)}")
            c = by_key[key]
            j, part = c.index
            v = c.parse(value)
            for i in pole_indices(self.text_poles, j):
                pole = poles[i]
                sign = 1.0 if self.text_poles[i].imag >= 0 else -1.0
                poles[i] = complex(v, pole.imag) if part == 0 else complex(pole.real, sign * v)
        return poles

    def place(self, values: Mapping[str, float] | None = None) -> Block:
        """Redesign from the desired poles `values` (pole control key -> value; None: the text's design).

        The redesigned gains become the design the gain controls range about (`controls`); the block's
        structure, and so its compiled closed loop, stays the same. Returns the new design.
        """
        poles = self.poles_for(values)
        designed = self.placement(poles) if values and self.placement is not None else self.text_block
        with self.lock:
            self.block = self.text_block.with_gains(**designed.gains)
            self.controls = gain_controls(self.block)
        return self.block

    def _which_loop(self) -> str:
        """Where the loop is broken: the loop of the case's loopshaping spec that names this controller (as its
        design or baseline), else "outer" for a cascade and "input" for a single loop."""
        for spec in self.case.loops:
            if spec.loop == "input" or isinstance(self.block, Cascade):
                if spec.design == self.label or spec.baseline == self.label:
                    return spec.loop
        return "outer" if isinstance(self.block, Cascade) else "input"

    # ------------------------------------------------------------- the update
    def design_values(self) -> dict:
        """Control key -> the designed value (what Reset returns to)."""
        return {c.key: c.design for c in self.controls}

    def block_for(self, values: Mapping[str, float] | None = None) -> Block:
        """The block with `values` (control key -> value; others at the design) checked and set."""
        return with_values(self.block, self.controls, values or {})

    def scenario(self, name: str) -> TableScenario:
        """The scenario `name` among those the designer offers (`SCENARIOS`); ValueError naming them otherwise."""
        if name not in self.scenarios:
            raise ValueError(f"scenario must be one of {', '.join(self.scenarios)}, got {name!r}")
        return self.scenarios[name]

    def simulate(self, block: Block, scenario: str):
        """The run of `block` on `scenario` as the study tables run it (a `models.ClosedLoopResult`;
        `diverged_at` set instead of raising)."""
        return runner.simulate_scenario(
            self.plant, block, self.scenario(scenario), self.case, self.options, self.base, self.case.substeps
        )

    def operating_point(self, block: Block, run) -> loops.OperatingPoint:
        """Where the loop is linearized: the end of the run, or the equilibrium at the final reference
        when the run diverged (the locus then shows why)."""
        if run.diverged_at is None:
            return loops.final_point(self.plant, block, run)
        r = run.r[-1]
        x, u = self.plant.equilibrium(**{self.case.tracked: float(r[0])})
        y = self.plant.output(x) if block.measures == "outputs" else x
        return loops.OperatingPoint(x, u, np.asarray(block.initial_state(y, r), dtype=float), r, 0.0)

    def loop_gain(self, block: Block, run) -> loops.LoopGain:
        """The loop gain of `block` about `operating_point`, broken where the case's loopshaping spec says."""
        return loops.loop(self.plant, block, self.operating_point(block, run), self.which, self.label)

    def update(self, values: Mapping[str, float] | None = None, scenario: str = "step") -> Update:
        """Run the nonlinear loop with `values` (control key -> value; the others at the design) on
        `scenario`, judge it and analyse its loop.

        Raises
        ------
        ValueError
            Naming the control, for an unknown key or a refused value (see `GainControl.parse`).
        """
        started = time.perf_counter()
        block = self.block_for(values)
        gains = {c.key: float(np.asarray(block.gains[c.gain])[c.index]) for c in self.controls}
        with self.lock:  # CasADi Functions cached on the plant are not safe to call from two threads
            run = self.simulate(block, scenario)
            judgement = judging.judge_run(self.case, scenario, run, self.plant.params)
            status, measured, verdict = judgement.status, judgement.metrics, judgement.verdict
            out = Update(
                gains,
                scenario,
                run.t,
                run.x[:, self.tracked_index],
                run.r[:, 0],
                run.u[:, 0],
                float(self.plant.input_limit[0]),
                status,
                verdict,
                measured,
                run=run,
            )
            try:
                self._analyse(block, run, out)
            except Exception as err:  # the linear analysis is a plot; the run and the verdict stand
                out.notes.append(f"no loop analysis: {type(err).__name__}: {err}".splitlines()[0])
        out.seconds = time.perf_counter() - started
        return out

    def _analyse(self, block: Block, run, out: Update) -> None:
        """Fill `out`'s loop analysis: the Bode plot over `omega`, the margins, the root locus over `LOCUS_GAINS`
        and the closed-loop poles (s-plane), and the loopshaping spec's checks and bounds."""
        design = self.loop_gain(block, run)
        response = design.frequency_response(self.omega)
        out.loop = self.which
        out.omega = self.omega
        with np.errstate(divide="ignore"):  # |L| = 0 where the block is saturated: -inf dB, not drawn
            out.magnitude_db = 20 * np.log10(np.abs(response))
        out.phase_deg = np.degrees(np.unwrap(np.angle(response)))
        out.margins = design.margins()
        # eig(A - k B C) for every k at once (`studies.loops.LoopGain.closed_loop_poles` one k at a time)
        closed = design.A[None] - LOCUS_GAINS[:, None, None] * (design.B @ design.C)[None]
        out.locus = s_plane(np.linalg.eigvals(closed), design.sample_period)
        out.poles = s_plane(design.closed_loop_poles(1.0), design.sample_period)
        if self.loop_spec is not None:
            out.loop_specs = [loop_spec_curves(self.loop_spec, design, self.baseline_loop, out.margins, self.omega)]

    def envelope(
        self,
        values: Mapping[str, float] | None = None,
        scenario: str = "step",
        samples: int = ENVELOPE_SAMPLES,
        seed: int = 0,
    ) -> dict:
        """The tracked coordinate over `samples` plants with the uncertain parameters uniform within the
        case's Monte Carlo spread (±5 %), as one batched run (`models.monte_carlo`).

        Returns
        -------
        dict: t (N+1,) s; quantiles (0, 0.05, 0.5, 0.95, 1); tracked (5, N+1) over the samples that did not
        diverge (NaN when all did); samples, diverged (counts)
        """
        block = self.block_for(values)
        chosen = self.scenario(scenario)
        spread = next((s.rel for s in self.case.scenarios if s.monte_carlo), KNOWN_ERROR)
        params = models.sample_params(self.plant, samples, rel=spread, seed=seed)
        noise = (
            runner.measurement_noise_std(self.plant, block, chosen.noise, sigma=self.case.derivative_time_constant)
            if chosen.noise
            else 0.0
        )
        with self.lock:
            batch = models.monte_carlo(
                self.plant,
                block,
                chosen.reference(self.case, self.base),
                chosen.duration(self.case),
                params,
                substeps=self.case.substeps,
                input_disturbance=self.case.input_disturbance if chosen.input_disturbance else 0.0,
                noise_std=noise,
                seed=seed,
                threads=2,
            )
        kept = np.isnan(batch.diverged_at)
        tracked = batch.x[kept, :, self.tracked_index]
        quantiles = ENVELOPE_QUANTILES
        bands = (
            np.quantile(tracked, quantiles, axis=0) if len(tracked) else np.full((len(quantiles), len(batch.t)), np.nan)
        )
        return {
            "t": batch.t,
            "quantiles": quantiles,
            "tracked": bands,
            "samples": samples,
            "diverged": int(np.sum(~kept)),
        }

    # ------------------------------------------------------------- tune and export
    def tune(
        self,
        values: Mapping[str, float] | None = None,
        scenario: str = "step",
        *,
        max_iter: int = 100,
        progress: Callable[[int, float, float], None] | None = None,
    ):
        """Tune the gains from `values` with `designs.tuning.tune` on the nominal plant and `scenario`
        ("disturbance" with the case's input disturbance, otherwise the step): ITAE of the tracked
        coordinate, the gains kept within their controls' ranges (the elements the design sets to
        zero stay zero).

        Returns
        -------
        (designs.tuning.TuningResult, {control key: tuned value})
        """
        start = self.block_for(values)
        chosen = tuner.scenario(self.case, "disturbance" if scenario == "disturbance" else "step")
        bounds = {}
        for name, value in start.gains.items():
            value = np.asarray(value, dtype=float)
            low, high = np.zeros(value.shape), np.zeros(value.shape)
            for c in self.controls:
                if c.gain == name:
                    low[c.index], high[c.index] = c.low, c.high
            bounds[name] = (low, high)
        # A copy of the plant, with Function caches of its own: the page's updates go on in the server's thread
        # while this one tunes, and a cached Function must not be called from two threads at once.
        plant = self.plant.with_input_limit(self.plant.input_limit)
        result = tuning.tune(
            tuning.TuningSetup(
                plant, start, [chosen], cost=tuning.Cost("itae"), bounds=bounds, substeps=self.case.substeps
            ),
            tuning.SolveOptions(max_iter=max_iter, progress=progress),
        )
        tuned = {
            c.key: float(np.clip(np.asarray(result.gains[c.gain], dtype=float)[c.index], c.low, c.high))
            for c in self.controls
        }
        return result, tuned

    def export(self, values: Mapping[str, float] | None = None) -> dict:
        """The gains as JSON-ready data, with the C step function (`models.export.export_block`, files
        ``<c_name>.h`` and ``<c_name>.c``, under the C name `c_prefix`) when it exports, or a note saying why not.
        """
        block = self.block_for(values)
        out = {
            "plant": self.case.plant,
            "controller": self.label,
            "sample_period_s": block.sample_period,
            "gains": {k: np.asarray(v, dtype=float).tolist() for k, v in block.gains.items()},
            "c_name": self.c_prefix,
        }
        try:
            out["c"] = export.export_block(block, self.c_prefix).files()
        except export.UnsupportedExport as err:
            out["c_note"] = str(err)
        return out


def export_note(data: dict) -> str:
    """What the Export button says it downloaded (plain text): the C name and files of the step, or why
    there is no C."""
    if "c" in data:
        return f"exported the gains and the C step as {data['c_name']}_step ({', '.join(sorted(data['c']))})"
    return f"exported the gains; no C: {data.get('c_note', 'not exported')}".splitlines()[0]


def pole_controls(poles) -> tuple[GainControl, ...]:
    """Controls of desired poles (rad/s): one per real pole ("p1"), two per conjugate pair ("p2.re" and
    "p2.im", the upper pole's), each over `RANGE` times its value either way, sign kept (so a pole stays
    in the left half plane and a pair stays complex); poles numbered as `pole_indices` groups them."""
    poles = np.asarray(poles, dtype=complex)
    out = []
    for j, group in enumerate(pole_groups(poles)):
        pole = poles[group[0]]
        parts = (
            [(0, pole.real, f"p{j + 1}")]
            if pole.imag == 0
            else [(0, pole.real, f"p{j + 1}.re"), (1, abs(pole.imag), f"p{j + 1}.im")]
        )
        for part, value, key in parts:
            if value == 0:
                continue
            low, high = sorted((float(value) / RANGE, float(value) * RANGE))
            out.append(GainControl(key, "poles", (j, part), float(value), low, high))
    return tuple(out)


def pole_groups(poles) -> list[list[int]]:
    """Indices of `poles` grouped as real poles and conjugate pairs, in order of first appearance."""
    poles = np.asarray(poles, dtype=complex)
    groups, used = [], set()
    for i, pole in enumerate(poles):
        if i in used:
            continue
        group = [i]
        if pole.imag != 0:
            mates = [
                k
                for k in range(len(poles))
                if k not in used and k != i and abs(poles[k] - np.conj(pole)) <= 1e-9 * max(1.0, abs(pole))
            ]
            if not mates:
                raise ValueError(f"pole {pole} has no complex conjugate among {poles}")
            group.append(mates[0])
        used.update(group)
        groups.append(group)
    return groups


def pole_indices(poles, j: int) -> list[int]:
    """Indices of the pole (or conjugate pair) numbered j by `pole_groups`."""
    return pole_groups(poles)[j]


def pole_placement(case: CaseStudy, label: str) -> dict:
    """{"poles", "placement"} for the case's state-space design `label` (its desired poles, and the
    function redesigning it from other poles with `studies.homework.statespace_controllers`, from the
    model known to the controller); {} for any other controller."""
    if case.statespace is None or label not in POLE_LABELS:
        return {}
    known = case.known_plant()

    def placement(poles):
        return homework.statespace_controllers(case, known, poles=np.asarray(poles))[label]

    return {"poles": np.asarray(case.statespace.poles(known), dtype=complex), "placement": placement}


def s_plane(z: np.ndarray, sample_period: float) -> np.ndarray:
    """s = ln(z) / Ts of discrete poles, NaN where z = 0 (no continuous equivalent)."""
    z = np.asarray(z, dtype=complex)
    out = np.full(z.shape, complex(np.nan, np.nan))
    nonzero = np.abs(z) > 1e-12
    out[nonzero] = np.log(z[nonzero]) / sample_period
    return out


_DESIGNED: dict = {}


def catalog(name: str) -> tuple[list[str], Callable[[str], Designer]]:
    """The case `name`'s controllers with gains (designed once per process, `designed_blocks`) and a function
    label -> a new `Designer` of that controller (one per page: placing poles changes a designer's design).

    Raises ValueError when the case has no controller with gains.
    """
    case = cases.get(name)
    if name not in _DESIGNED:
        _DESIGNED[name] = designed_blocks(case)
    blocks = _DESIGNED[name]
    if not blocks:
        raise ValueError(f"{name} has no controller with gains")
    baseline = next((blocks.get(s.baseline) for s in case.loops if s.baseline), None)
    prefixes = c_prefixes(name, list(blocks))

    def make(label: str) -> Designer:
        if label not in blocks:
            raise ValueError(f"{name} has no controller {label!r} with gains; choose from {', '.join(blocks)}")
        return Designer(
            case, blocks[label], label, baseline=baseline, c_prefix=prefixes[label], **pole_placement(case, label)
        )

    return list(blocks), make


def c_prefixes(plant: str, labels: list[str]) -> dict[str, str]:
    """label -> the C name of its exported step: ``<plant>_<label>`` as a C identifier, distinct for each of
    the plant's `labels` (`models.export.c_identifiers`, in the order of `labels`)."""
    return dict(zip(labels, export.c_identifiers(f"{plant}_{label}" for label in labels)))


def designed_blocks(name: str | CaseStudy) -> dict:
    """{label: Block} of the case's controllers with gains, designed as `studies.runner` designs them
    (from `CaseStudy.known_plant`), without the providers in `SKIPPED_PROVIDERS`."""
    case = name if isinstance(name, CaseStudy) else cases.get(name)
    providers = [p for p in case.providers if p not in SKIPPED_PROVIDERS]
    designed, _ = runner.design_controllers(case, case.known_plant(), providers)
    return {label: c for label, c in designed.items() if isinstance(c, Block) and gain_controls(c)}
