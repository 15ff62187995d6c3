"""Specs of a closed-loop response and the one verdict rule: does a run meet them?

A `Specs` record says what a step response must do (rise time, settling
time, overshoot, steady-state error), that the command stays within the
actuator limit, which states must stay within bounds and within the plant's
physical limits (`models.state_limits.StateLimit`), where states must end
up, and whether a sustained oscillation is allowed. `verdict` judges the
metrics of one run (`models.metrics.run_metrics`) against them:

- ``diverged`` / ``failed`` / ``skipped`` when the run's status says so;
- ``limit cycle`` when the response oscillates without decaying (see
  `models.metrics.oscillation`), even if nothing else is violated;
- ``violates`` with every violated spec, its value and by how much;
- ``meets specs`` otherwise.

`combine` turns the per-sample verdicts of a Monte Carlo into one (the worst
label, and in how many samples). Step specs are measured as `models.metrics`
defines them (10-90 % rise, the settling band (2 % unless the specs say), overshoot and steady-state
error in % of the step); a series of steps is judged by its worst step. The
frequency fields (margins, disk margin, bandwidth) are judged on measures of the
row's linearized loop that the caller passes (`designs.analysis.robustness`;
models imports no other package of ours). `Specs.validate` refuses, before any
run, specs that the run or the plant cannot judge.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from . import metrics as metrics_module
from .state_limits import StateLimit, check_state_limits

#: The frequency fields of `Specs`, each with the `designs.analysis.robustness.FrequencyMeasures` attribute it
#: bounds, whether it is a least value, its unit and its name in a verdict.
FREQUENCY_SPECS = {
    "min_gain_margin_db": ("gain_margin_db", True, "dB", "gain margin"),
    "min_phase_margin_deg": ("phase_margin_deg", True, "deg", "phase margin"),
    "min_disk_margin": ("disk_margin", True, "", "disk margin"),
    "min_bandwidth_rad_s": ("bandwidth_rad_s", True, "rad/s", "bandwidth"),
    "max_bandwidth_rad_s": ("bandwidth_rad_s", False, "rad/s", "bandwidth"),
}

MEETS, VIOLATES, LIMIT_CYCLE, DIVERGED, FAILED, SKIPPED = (
    "meets specs",
    "violates",
    "limit cycle",
    "diverged",
    "failed",
    "skipped",
)

#: Verdict labels from best to worst; a Monte Carlo takes the worst of its samples'.
LABELS = (MEETS, VIOLATES, LIMIT_CYCLE, DIVERGED, FAILED, SKIPPED)
_SEVERITY = {MEETS: 0, VIOLATES: 1, LIMIT_CYCLE: 2, DIVERGED: 3, FAILED: 4, SKIPPED: -1}


@dataclass(frozen=True)
class Specs:
    """What a closed-loop step response must do. Every field is optional (None: not judged).

    The one spec record: the study tables judge runs with it (`verdict`), and the gain tuner
    (`designs.tuning`) turns it into differentiable pointwise constraints that imply it.

    Attributes
    ----------
    max_rise_time_s : s, 10-90 % rise time of the (worst) step
    max_settling_time_s : s, time from which the output stays within the settling band
    max_overshoot_pct : % of the step
    max_ss_error_pct : steady-state error, % of the step (mean over the last 5 % of the segment)
    input_limit : the command must stay within the actuator limit (to `metrics.SATURATION_TOLERANCE`)
    state_bounds : state name -> (low, high), or a bound b > 0 for (-b, b), SI units, at every sample
        (a crane's swing, a ball on its beam)
    final_values : state name -> (value, tolerance), SI units: the mean over the last 5 % of the run
    state_limits : the plant's physical limits (`models.state_limits.StateLimit`, cart travel, beam
        length), at every sample; a run that leaves one violates the specs by its excess
    limit_cycle : a sustained oscillation (`models.metrics.oscillation`) fails the specs
    settling_band_pct : the settling band, % of the step (default `models.metrics.SETTLING_BAND`)
    min_gain_margin_db, min_phase_margin_deg : dB, deg: least gain and phase margins of the row's
        linearized loop (broken at the plant input, at the run's final rest point)
    min_disk_margin : least balanced disk margin α of that loop (dimensionless, in (0, 2])
    min_bandwidth_rad_s, max_bandwidth_rad_s : rad/s, bounds on that loop's closed-loop −3 dB bandwidth
        (the frequency fields, `FREQUENCY_SPECS`: measured by `designs.analysis.robustness.frequency_measures`,
        judged where the row has a linear loop)
    max_spectral_abscissa : 1/s, bound on the slowest mode of the closed loop's linearization at the
        end of the run; checked by the tuner at its solution, not judged by the tables
    source : where the numbers come from (the text's item, or the stated choice)
    """

    max_rise_time_s: float | None = None
    max_settling_time_s: float | None = None
    max_overshoot_pct: float | None = None
    max_ss_error_pct: float | None = None
    input_limit: bool = True
    state_bounds: Mapping[str, tuple] = field(default_factory=dict)
    final_values: Mapping[str, tuple] = field(default_factory=dict)
    state_limits: tuple = ()
    limit_cycle: bool = True
    settling_band_pct: float = 100 * metrics_module.SETTLING_BAND
    min_gain_margin_db: float | None = None
    min_phase_margin_deg: float | None = None
    min_disk_margin: float | None = None
    min_bandwidth_rad_s: float | None = None
    max_bandwidth_rad_s: float | None = None
    max_spectral_abscissa: float | None = None
    source: str = ""

    def __post_init__(self):
        """Refuse a negative or non-finite bound, a bound with low >= high, a final value's tolerance <= 0,
        a settling band outside (0, 100) %; a bound b > 0 on a state becomes (-b, b)."""
        for name in ("max_rise_time_s", "max_settling_time_s", "max_overshoot_pct", "max_ss_error_pct"):
            value = getattr(self, name)
            if value is not None and not (_number(value) and value >= 0 and math.isfinite(value)):
                raise ValueError(f"Specs.{name} must be a finite number >= 0 or None, got {value!r}")
        band = self.settling_band_pct
        if not (_number(band) and 0 < band < 100):
            raise ValueError(f"Specs.settling_band_pct must be a percentage in (0, 100), got {band!r}")
        for name in FREQUENCY_SPECS:
            value = getattr(self, name)
            if value is not None and not (_number(value) and value > 0 and math.isfinite(value)):
                raise ValueError(f"Specs.{name} must be a finite number > 0 or None, got {value!r}")
        if self.min_disk_margin is not None and self.min_disk_margin > 2:
            raise ValueError(
                f"Specs.min_disk_margin must be at most 2 (a balanced disk margin beyond 2 only adds phase), "
                f"got {self.min_disk_margin!r}"
            )
        low, high = self.min_bandwidth_rad_s, self.max_bandwidth_rad_s
        if low is not None and high is not None and not low < high:
            raise ValueError(
                f"Specs.min_bandwidth_rad_s = {low!r} must be below Specs.max_bandwidth_rad_s = {high!r}: "
                "no loop can meet both"
            )
        abscissa = self.max_spectral_abscissa
        if abscissa is not None and not (_number(abscissa) and math.isfinite(abscissa)):
            raise ValueError(f"Specs.max_spectral_abscissa must be a finite number (1/s) or None, got {abscissa!r}")
        if not isinstance(self.state_bounds, Mapping):
            raise TypeError(f"Specs.state_bounds must be a dict state name -> (low, high), got {self.state_bounds!r}")
        if not isinstance(self.final_values, Mapping):
            raise TypeError(f"Specs.final_values must be a dict state name -> (value, tol), got {self.final_values!r}")
        bounds = {}
        for state, bound in self.state_bounds.items():
            if _number(bound):
                if not (math.isfinite(bound) and bound > 0):
                    raise ValueError(f"Specs.state_bounds[{state!r}] must be a bound > 0 or (low, high), got {bound!r}")
                bound = (-float(bound), float(bound))
            if len(bound) != 2 or not bound[0] < bound[1]:
                raise ValueError(f"Specs.state_bounds[{state!r}] must be (low, high) with low < high, got {bound!r}")
            bounds[state] = (float(bound[0]), float(bound[1]))
        object.__setattr__(self, "state_bounds", bounds)
        limits = tuple(self.state_limits)
        for limit in limits:
            if not isinstance(limit, StateLimit):
                raise TypeError(f"Specs.state_limits must hold models.state_limits.StateLimit records, got {limit!r}")
        names = [limit.name for limit in limits]
        if len(set(names)) != len(names):
            raise ValueError(f"Specs.state_limits must have distinct names, got {names}")
        object.__setattr__(self, "state_limits", limits)
        self._refuse_contradictions()

    def _refuse_contradictions(self) -> None:
        """ValueError for a final value that is not a (value, tolerance > 0) pair, or that cannot lie within its
        state's bound or physical limit."""
        intervals = [
            (f"Specs.state_bounds[{state!r}]", state, low, high) for state, (low, high) in self.state_bounds.items()
        ]
        intervals += [
            (f"Specs.state_limits {limit.name!r}", limit.state, limit.lower, limit.upper)
            for limit in self.state_limits
            if limit.relative_to is None
        ]
        for state, target in self.final_values.items():
            pair = np.asarray(target, dtype=float) if not isinstance(target, str) else np.array(())
            if pair.shape != (2,) or not (np.all(np.isfinite(pair)) and pair[1] > 0):
                raise ValueError(
                    f"Specs.final_values[{state!r}] must be a pair (value, tolerance > 0) of finite numbers, "
                    f"got {target!r}"
                )
        for state, (value, tolerance) in self.final_values.items():
            for what, bounded, low, high in intervals:
                if bounded == state and (value + tolerance < low or value - tolerance > high):
                    raise ValueError(
                        f"Specs.final_values[{state!r}] = ({value:g}, {tolerance:g}) lies outside {what} = "
                        f"({low:g}, {high:g}): no run can meet both"
                    )

    @property
    def settling_band(self) -> float:
        """The settling band as a fraction of the step."""
        return self.settling_band_pct / 100

    @property
    def frequency_specs(self) -> tuple[str, ...]:
        """Names of the frequency fields set here (judged on a row's linearized loop)."""
        return tuple(name for name in FREQUENCY_SPECS if getattr(self, name) is not None)

    @property
    def step_specs(self) -> tuple[str, ...]:
        """Names of the specs set here that need a step (rise, settling, overshoot, steady-state error)."""
        names = ("max_rise_time_s", "max_settling_time_s", "max_overshoot_pct", "max_ss_error_pct")
        return tuple(name for name in names if getattr(self, name) is not None)

    def validate(
        self,
        states: Sequence[str],
        *,
        tracked: str | None = None,
        targets: Sequence[float] = (),
        duration: float | None = None,
        where: str = "",
    ) -> None:
        """Refuse, before any run, specs the run cannot judge or that contradict it: ValueError naming the
        field and its value.

        Parameters
        ----------
        states : the plant's state names; every state a bound, final value or limit names must be one
        tracked : the coordinate that follows the reference (a state), when the run tracks one
        targets : the tracked coordinate's reference values over the run, its initial value first
            (units of the coordinate); a step spec needs one that differs from the first, and every
            one must lie within the tracked coordinate's bounds and limits
        duration : length of the run, s; a rise or settling time after it constrains nothing
        where : how the message names the run (" 'steps' of pendulum")
        """
        states = tuple(states)
        if tracked is not None and tracked not in states:
            raise ValueError(f"tracked = {tracked!r}: the plant has no such state; its states are {states}")
        for what, table in (("state_bounds", self.state_bounds), ("final_values", self.final_values)):
            for name in table:
                if name not in states:
                    raise ValueError(
                        f"Specs.{what}[{name!r}]: the plant has no state {name!r}; its states are {states}"
                    )
        for limit in self.state_limits:
            for name in limit.states:
                if name not in states:
                    raise ValueError(
                        f"Specs.state_limits {limit.name!r} reads the state {name!r}, which the plant does not "
                        f"have; its states are {states}"
                    )
        targets = [float(v) for v in targets]
        stepped = any(v != targets[0] for v in targets[1:])
        if self.step_specs and not stepped:
            name = self.step_specs[0]
            reason = (
                "it tracks no coordinate"
                if tracked is None or not targets
                else f"its reference stays at {tracked} = {targets[0]:g} (a disturbance or regulation run)"
            )
            raise ValueError(
                f"Specs.{name} = {getattr(self, name)!r} needs a step, and the scenario{where} has none: {reason}"
            )
        for name in ("max_rise_time_s", "max_settling_time_s"):
            when = getattr(self, name)
            if when is not None and duration is not None and when > duration:
                raise ValueError(
                    f"Specs.{name} = {when:g} s is after the end of the scenario{where} ({duration:g} s): "
                    "it would constrain nothing"
                )
        if tracked is None:
            return
        intervals = (
            [(f"Specs.state_bounds[{tracked!r}]", *self.state_bounds[tracked])] if tracked in self.state_bounds else []
        )
        intervals += [
            (f"Specs.state_limits {limit.name!r}", limit.lower, limit.upper)
            for limit in self.state_limits
            if limit.state == tracked and limit.relative_to is None
        ]
        for what, low, high in intervals:
            outside = [v for v in targets if not low <= v <= high]
            if outside:
                raise ValueError(
                    f"{what} = ({low:g}, {high:g}) excludes the scenario{where}'s commanded {tracked} = "
                    f"{outside[0]:g}: no run can track it within the bound"
                )

    def with_state_bounds(self, bounds: Mapping[str, tuple]) -> Specs:
        """These specs with more state bounds (added to, and replacing, the ones of the same state)."""
        return replace(self, state_bounds={**self.state_bounds, **dict(bounds)}) if bounds else self

    def with_limits(self, limits, params: Mapping[str, float] | None = None) -> Specs:
        """These specs with the physical `limits` (`StateLimit`s) on the plant with `params` (name -> value,
        for a limit whose bound is a parameter) added, replacing limits of the same name."""
        limits = tuple(limit.at(params) for limit in limits)
        if not limits:
            return self
        named = {limit.name: limit for limit in (*self.state_limits, *limits)}
        return replace(self, state_limits=tuple(named.values()))

    @property
    def bounds_and_limits(self) -> dict:
        """{state: (low, high)}: the state bounds intersected with the limits on a single state (the form
        of a constraint on the states at every sample, e.g. for a tuner)."""
        bounds = dict(self.state_bounds)
        for limit in self.state_limits:
            if limit.relative_to is None:
                low, high = bounds.get(limit.state, (-math.inf, math.inf))
                bounds[limit.state] = (max(low, limit.lower), min(high, limit.upper))
        return bounds

    def implied_bounds(self) -> set:
        """The states whose bound a physical limit on that state implies (the limit's interval within it):
        judged once, by the named limit."""
        return {
            state
            for state, (low, high) in self.state_bounds.items()
            if any(
                limit.relative_to is None and limit.state == state and low <= limit.lower and limit.upper <= high
                for limit in self.state_limits
            )
        }

    def describe(self, unit: str = "", scale: float = 1.0) -> str:
        """The specs in one line, e.g. "rise ≤ 0.9 s, settling ≤ 3 s, overshoot ≤ 10 %"."""
        parts = []
        if self.max_rise_time_s is not None:
            parts.append(f"rise ≤ {self.max_rise_time_s:g} s")
        if self.max_settling_time_s is not None:
            band = (
                ""
                if self.settling_band_pct == 100 * metrics_module.SETTLING_BAND
                else f" (±{self.settling_band_pct:g} %)"
            )
            parts.append(f"settling{band} ≤ {self.max_settling_time_s:g} s")
        if self.max_overshoot_pct is not None:
            parts.append(f"overshoot ≤ {self.max_overshoot_pct:g} %")
        if self.max_ss_error_pct is not None:
            parts.append(f"ss error ≤ {self.max_ss_error_pct:g} % of the step")
        if self.input_limit:
            parts.append("command within the actuator limit")
        implied = self.implied_bounds()
        parts += [
            f"{low:g} ≤ {name} ≤ {high:g}" for name, (low, high) in self.state_bounds.items() if name not in implied
        ]
        parts += [limit.describe() for limit in self.state_limits]
        for name in self.frequency_specs:
            _, least, unit, what = FREQUENCY_SPECS[name]
            parts.append(f"{what} {'≥' if least else '≤'} {getattr(self, name):g}{f' {unit}' if unit else ''}")
        parts += [f"{name} ends at {value:g} ± {tol:g}" for name, (value, tol) in self.final_values.items()]
        if self.limit_cycle:
            parts.append("no sustained oscillation")
        return ", ".join(parts) or "none"


@dataclass(frozen=True)
class Violation:
    """One spec a run misses: its name, the measured value, the bound, and the excess over it. `left`: a
    state bound or physical limit the run leaves (its value the excess, its bound 0)."""

    spec: str
    value: float
    bound: float
    unit: str = ""
    minimum: bool = False
    left: bool = False

    @property
    def excess(self) -> float:
        """By how much the value misses: value − bound (bound − value for a least value, `minimum`), in
        the spec's unit (inf when the value is)."""
        return self.bound - self.value if self.minimum else self.value - self.bound

    def __str__(self) -> str:
        digits = 3 if f"{self.value:.3g}" != f"{self.bound:.3g}" else 5
        if self.minimum:
            unit = f" {self.unit}" if self.unit else ""
            return f"{self.spec} {self.value:.{digits}g}{unit} < {self.bound:.3g}{unit}"
        value = "∞" if math.isinf(self.value) else f"{self.value:.{digits}g}"
        unit = f" {self.unit}" if self.unit else ""
        if self.unit == "%":
            return f"{self.spec} {value} % > {self.bound:.3g} %{self.note}"
        if math.isinf(self.value):
            return f"{self.spec} ∞ > {self.bound:.3g}{unit}"
        if self.bound == 0:
            return f"{self.spec} {value}{unit}"
        relative = f" (+{100 * self.excess / self.bound:.0f} %)" if self.bound > 0 else ""
        return f"{self.spec} {value}{unit} > {self.bound:.3g}{unit}{relative}"

    @property
    def note(self) -> str:
        """What a % spec is a percentage of, when it is not obvious."""
        return " of the step" if self.spec == "ss error" else ""


@dataclass(frozen=True)
class Verdict:
    """The judgement of one run (or of a Monte Carlo's samples).

    Attributes
    ----------
    label : one of `LABELS`
    violations : the specs missed (for "violates" and "limit cycle")
    detail : one line saying what, and by how much
    """

    label: str
    violations: tuple = ()
    detail: str = ""

    @property
    def ok(self) -> bool:
        """Whether the run meets its specs."""
        return self.label == MEETS

    def __str__(self) -> str:
        return f"{self.label}: {self.detail}" if self.detail else self.label


def execution(status: str) -> str:
    """What a run's status says about its execution: "ok", "diverged", "failed", "skipped" or "degraded".

    Statuses read "ok", "degraded (n)", "diverged at t = ... s", "failed: ...", "skipped: ...",
    or for a Monte Carlo "k of n diverged (...)".
    """
    text = str(status).strip().lower()
    for word in ("skipped", "failed", "diverged", "degraded"):
        if text.startswith(word) or (word == "diverged" and " diverged" in text):
            return word
    return "ok"


def check(
    specs: Specs,
    metrics: Mapping,
    step: float,
    *,
    excursions: Mapping[str, float] | None = None,
    finals: Mapping[str, float] | None = None,
    units: Mapping[str, str] | None = None,
    departures: Mapping[str, float] | None = None,
    frequency: Mapping[str, float] | None = None,
) -> list[Violation]:
    """Every spec the metrics miss.

    Parameters
    ----------
    metrics : the columns of `models.metrics.run_metrics` (worst case of a Monte Carlo allowed)
    step : size of the commanded step (units of the tracked coordinate) the % specs refer to
    excursions : state name -> excess beyond its bounds (`models.metrics.bound_excursions`)
    finals : state name -> final value (`models.metrics.final_values`)
    units : state name (or "input") -> unit, written beside the values of the state's bound and final
        value (and of the peak command); a missing one is left out
    departures : limit name -> largest excess beyond that limit of `specs.state_limits` (the limit's
        units, 0 when the run stays inside; `models.state_limits.check_state_limits`)
    frequency : the measures of the row's linearized loop by name
        (`designs.analysis.robustness.FrequencyMeasures.as_dict`); None when the row has no linear loop,
        and the frequency specs are not judged
    """
    units = units or {}
    step = abs(float(step))
    if step == 0:
        raise ValueError("step must be nonzero: the overshoot and steady-state error specs are % of it")
    found = []

    def over(name, value, bound, unit):
        # A violation when a measured value exceeds its bound (unjudged when either is missing or NaN).
        if bound is not None and value is not None and not math.isnan(value) and value > bound:
            found.append(Violation(name, float(value), float(bound), unit))

    over("rise time", metrics.get("rise_time_s"), specs.max_rise_time_s, "s")
    over("settling time", metrics.get("settling_time_s"), specs.max_settling_time_s, "s")
    over("overshoot", metrics.get("overshoot_pct"), specs.max_overshoot_pct, "%")
    ss_error = metrics.get("ss_error")
    over("ss error", None if ss_error is None else 100 * ss_error / step, specs.max_ss_error_pct, "%")
    if specs.input_limit:
        peak, limit = metrics.get("peak_u"), metrics.get("u_limit")
        if peak is not None and limit is not None and limit > 0:
            over("peak command", peak, limit * (1 + metrics_module.SATURATION_TOLERANCE), units.get("input", ""))
    implied = specs.implied_bounds()
    for name, (low, high) in specs.state_bounds.items():
        if name in implied:
            continue
        excess = (excursions or {}).get(name)
        if excess is None:
            raise ValueError(f"the specs bound {name!r}; pass its excursion (models.metrics.bound_excursions)")
        if excess > 0:
            found.append(
                Violation(f"{name} leaves [{low:g}, {high:g}] by", float(excess), 0.0, units.get(name, ""), left=True)
            )
    for limit in specs.state_limits:
        excess = (departures or {}).get(limit.name)
        if excess is None:
            raise ValueError(f"the specs limit {limit.name!r}; pass its excess (state_limits.check_state_limits)")
        if excess > 0:
            found.append(Violation(f"leaves {limit.name} by", float(excess), 0.0, limit.unit, left=True))
    for name in specs.frequency_specs:
        if frequency is None:
            break
        measure, least, unit, what = FREQUENCY_SPECS[name]
        bound, value = float(getattr(specs, name)), float(frequency[measure])
        if math.isnan(value) or (value < bound if least else value > bound):
            found.append(Violation(what, value, bound, unit, minimum=least))
    for name, (value, tolerance) in specs.final_values.items():
        final = (finals or {}).get(name)
        if final is None:
            raise ValueError(f"the specs give {name!r} a final value; pass it (models.metrics.final_values)")
        over(f"final |{name} − {value:g}|", abs(final - value), tolerance, units.get(name, ""))
    return found


def verdict(
    specs: Specs,
    metrics: Mapping,
    step: float,
    status: str = "ok",
    *,
    excursions: Mapping[str, float] | None = None,
    finals: Mapping[str, float] | None = None,
    units: Mapping[str, str] | None = None,
    tracked: str | None = None,
    drift: float | None = None,
    departures: Mapping[str, float] | None = None,
    frequency: Mapping[str, float] | None = None,
) -> Verdict:
    """The one verdict rule (see the module's docstring) for one run's metrics; `units` as in `check`,
    and the unit of the `tracked` coordinate beside a limit cycle's amplitude. `drift`: the rate at which
    the tracked coordinate's mean still moves at the end (`models.metrics.drift`, units per s; None or
    NaN when it does not): with an oscillation the detail says so, without one the run "drifts" (a
    violation, where `limit_cycle` is judged). `departures` and `frequency`: the excess beyond each
    physical limit and the measures of the linearized loop, as in `check`."""
    state = execution(status)
    if state in ("diverged", "failed", "skipped"):
        return Verdict({"diverged": DIVERGED, "failed": FAILED, "skipped": SKIPPED}[state], (), str(status))
    violations = tuple(
        check(
            specs,
            metrics,
            step,
            excursions=excursions,
            finals=finals,
            units=units,
            departures=departures,
            frequency=frequency,
        )
    )
    speed = abs(float(drift)) if specs.limit_cycle and drift is not None and np.isfinite(drift) else None
    moving = speed is not None
    rate = "" if speed is None else f"{speed:.3g}{_unit(units, tracked)}/s"
    amplitude = metrics.get("oscillation_amplitude")
    if specs.limit_cycle and amplitude is not None and np.isfinite(amplitude):
        period = metrics.get("oscillation_period_s", math.nan)
        cycle = f"amplitude {amplitude:.3g}{_unit(units, tracked)}, period {period:.3g} s at the end of the run"
        cycle += f", its mean drifting {rate}" if moving else ""
        rest = "; ".join(str(v) for v in violations)
        return Verdict(LIMIT_CYCLE, violations, cycle + (f"; {rest}" if rest else ""))
    if speed is not None:
        violations += (Violation("drifts", speed, 0.0, f"{(units or {}).get(tracked or '', '')}/s".lstrip()),)
    if violations:
        return Verdict(VIOLATES, violations, "; ".join(str(v) for v in violations))
    return Verdict(MEETS)


def judge(
    specs: Specs,
    result,
    tracked: str,
    step: float,
    status: str | None = None,
    measured: Mapping | None = None,
    units: Mapping[str, str] | None = None,
    frequency: Mapping[str, float] | None = None,
) -> Verdict:
    """The verdict of one closed-loop run (a `models.ClosedLoopResult`) on the tracked coordinate.

    Metrics (unless given as `measured`, from `models.metrics.run_metrics` with the specs' settling
    band), state excursions, the excess beyond each physical limit (`models.state_limits`) and
    final values are computed here with `models.metrics`; a run that diverged
    (`result.diverged_at`) is "diverged" whatever `status` says. `units`: state name (or "input") ->
    unit, written beside the values in the verdict's detail. `frequency`: the measures of the row's
    linearized loop (as in `check`; None: the frequency specs are not judged).
    """
    if result.diverged_at is not None:
        return Verdict(DIVERGED, (), f"diverged at t = {result.diverged_at:.3g} s")
    if measured is None:
        measured = metrics_module.run_metrics(result, tracked, specs.state_bounds, band=specs.settling_band)
    excursions = metrics_module.bound_excursions(result.x, result.state_names, specs.state_bounds)
    finals = metrics_module.final_values(result.t, result.x, result.state_names, list(specs.final_values))
    left = check_state_limits(result.t, result.x, result.state_names, specs.state_limits)
    departures = {outcome.limit.name: outcome.excess for outcome in left}
    y = result.x[:, list(result.state_names).index(tracked)]
    moving = metrics_module.drift(result.t, y, result.r[:, 0], specs.settling_band)
    return verdict(
        specs,
        measured,
        step,
        status or "ok",
        excursions=excursions,
        finals=finals,
        units=units,
        tracked=tracked,
        drift=moving,
        departures=departures,
        frequency=frequency,
    )


def combine(verdicts: Sequence[Verdict]) -> Verdict:
    """One verdict for the samples of a Monte Carlo: the worst label, in how many samples, and the worst sample.

    "meets specs" only when every sample does; otherwise e.g. "violates in 12 of 200 samples
    (worst: settling time 4.1 s > 3 s (+37 %))".
    """
    if not verdicts:
        return Verdict(SKIPPED, (), "no samples")
    judged = [v for v in verdicts if v.label != SKIPPED]
    if not judged:
        return Verdict(SKIPPED, (), verdicts[0].detail)
    worst = max(judged, key=lambda v: (_SEVERITY[v.label], max((_relative(x) for x in v.violations), default=0)))
    if worst.label == MEETS:
        return Verdict(MEETS, (), f"in all {len(verdicts)} samples" if len(verdicts) > 1 else "")
    count = sum(v.label == worst.label for v in verdicts)
    where = f"in {count} of {len(verdicts)} samples" if len(verdicts) > 1 else ""
    detail = f"{where} (worst: {worst.detail})" if where and worst.detail else where or worst.detail
    return Verdict(worst.label, worst.violations, detail)


def _unit(units: Mapping[str, str] | None, name: str | None) -> str:
    """ " <unit>" of `name` in `units` ("" when there is none)."""
    unit = (units or {}).get(name or "", "")
    return f" {unit}" if unit else ""


def _number(value) -> bool:
    """Whether `value` is a real number (not a bool)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _relative(violation: Violation) -> float:
    """How badly a violation misses: excess / bound (the excess itself for a zero bound, inf for an infinite value)."""
    if math.isinf(violation.value):
        return math.inf
    return violation.excess / violation.bound if violation.bound > 0 else violation.excess
