"""Homework answers as data: the record helpers and the engines behind every case's answers and controllers.

A case file designs its chapter with the library (`designs`) and states the
answers item by item with the helpers here (`record`, `tf_record`,
`margin_record`, `root_locus_record`, ...), which turn designs into plain
numbers: SI units (rad, rad/s; degrees only where a key ends in ``_deg``),
complex poles as complex, transfer functions as ``{num, den}`` lists.

The engines (`classical_design`, `statespace_design`, ...) run a case's own
choices: its ``classical(known)`` function, or its `StateSpaceChoices`
through `designs.statespace_design`.

Choices the text leaves to the student, made once here for every case:

- ζ = 0.707 wherever ζ is "a design parameter" (`ZETA`).
- Bandwidth separation M = 10 between inner and outer loops (`SEPARATION`).
- k_i (.10) along its root locus: the largest gain keeping every closed-loop
  pole's damping at least `DAMPING_KEPT` ζ and, when the PD loop already has
  unit DC gain, adding at most `OVERSHOOT_ALLOWANCE` percentage points of step
  overshoot to it ("without significantly degrading the transient response").
- PID anti-windup: back-calculation, except where the text asks for
  integrating only while |ẏ| is small; the rate limit is `RATE_FRACTION` of
  (design step × outer ω_n).
- The .13 answers use the implemented controllers, with the dirty
  derivative s/(σ s + 1), σ the case's `derivative_time_constant`; .8 and .10 use the ideal PD/PID.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

import models
from designs import analysis as an
from designs import statespace as ss
from designs import statespace_design as ssd
from designs.analysis import Loop, steady_state_errors
from designs.loops import SuccessiveLoopClosure
from designs.loopshaping import flattening_prefilter, improve_loop
from designs.pid import PID, PDDesign
from designs.rootlocus import integrator_gain
from models.files import to_jsonable

from .case import CaseStudy, LoopSpec

#: ζ where the text leaves it as a design parameter (the controlbook's 0.707).
ZETA = 0.707
#: Bandwidth separation between inner and outer loops.
SEPARATION = 10.0
#: k_i keeps every closed-loop pole's damping at least this fraction of the PD design's ζ.
DAMPING_KEPT = 0.9
#: k_i may add at most this many percentage points of step overshoot to the PD loop's.
OVERSHOOT_ALLOWANCE = 10.0
#: integrate-while-slow threshold as a fraction of (design step × outer ω_n).
RATE_FRACTION = 0.1
#: Bandwidth separation of the state-space pole rules (.15(c)): the outer pair this many times slower.
STATESPACE_SEPARATION = 5.0
#: Controller labels every classical design provides.
LABELS = ("PD", "PID", "PID (no anti-windup)", "loopshaped")


# ----------------------------------------------------------------- records
def record(**values) -> dict:
    """A homework record: numpy values as Python numbers and lists (complex stays complex)."""
    return {k: to_jsonable(v, encode=False) for k, v in values.items()}


def tf_record(G, prefix: str = "") -> dict:
    """{prefix num, prefix den}: descending coefficients of a SISO transfer function."""
    num, den = an.as_polynomials(G)
    return {f"{prefix}num": [float(c) for c in num], f"{prefix}den": [float(c) for c in den]}


def poles_record(poles) -> list:
    """Poles as complex numbers, sorted by real then imaginary part."""
    poles = np.asarray(poles, dtype=complex)
    poles = poles[np.lexsort((poles.imag, poles.real))]
    return [complex(p) for p in poles]


def error_record(loop: Loop, suffix: str = "") -> dict:
    """System type and steady-state errors of `loop`, keys suffixed."""
    return {f"{k}{suffix}": v for k, v in steady_state_errors(loop).items()}


def margin_record(L, suffix: str) -> dict:
    """Phase margin (deg), gain margin (ratio) and gain crossover (rad/s) of the loop gain L."""
    m = an.margins(L)
    return {f"pm_deg{suffix}": m["pm_deg"], f"gm{suffix}": m["gm"], f"crossover{suffix}": m["gain_crossover"]}


def spec_records(checks) -> list:
    """SpecChecks as plain dicts."""
    return [to_jsonable(c.as_dict(), encode=False) for c in checks]


def integrator(G, kp: float, kd: float, zeta: float, derivative_on: str = "measurement") -> dict:
    """The .10 integrator gain along its root locus, by this module's rule."""
    return integrator_gain(G, kp, kd, DAMPING_KEPT * zeta, OVERSHOOT_ALLOWANCE, derivative_on)


def root_locus_record(G, kp: float, kd: float, rl: dict) -> dict:
    """The k_i root-locus answer: gain, damping bound, overshoots, poles, Evans form, closed loop."""
    return record(
        ki=rl["ki"],
        zeta_min=rl["zeta_min"],
        ki_damping=rl["ki_damping"],
        overshoot_pd=rl["overshoot_pd"],
        overshoot_pid=rl["overshoot_pid"],
        poles=poles_record(rl["poles"]),
        **tf_record(rl["evans"], "evans_"),
        closed_loop_pid=tf_record(Loop.pid(G, kp, rl["ki"], kd).reference_to_output()),
    )


def rate_limit(step: float, wn: float) -> float:
    """Integrate-while-slow threshold: `RATE_FRACTION` of (design step × outer ω_n), units of y per s."""
    return RATE_FRACTION * abs(step) * wn


# ----------------------------------------------------------------- designs shared by several chapters
def single_loop(G, pd, zeta: float, sigma: float) -> tuple[dict, dict]:
    """Integrator by the root locus, and the four loops the .10/.13 answers read.

    Parameters
    ----------
    G : the loop's plant, continuous SISO transfer function
    pd : the PD design (k_p, k_d) on G
    zeta : the PD's damping ratio (the integrator keeps `DAMPING_KEPT` of it)
    sigma : the dirty derivative's time constant σ of the implemented loops, s

    Returns
    -------
    (rl, loops) : the root-locus record of `integrator`, and label -> Loop for "PD", "PID" (ideal
    derivative) and "PD (implemented)", "PID (implemented)" (dirty derivative s/(σ s + 1))
    """
    rl = integrator(G, pd.kp, pd.kd, zeta)
    ki = rl["ki"]
    loops = {
        "PD": Loop.pid(G, pd.kp, 0.0, pd.kd, name="PD"),
        "PID": Loop.pid(G, pd.kp, ki, pd.kd, name="PID"),
        "PD (implemented)": Loop.pid(G, pd.kp, 0.0, pd.kd, sigma=sigma, name="PD, dirty derivative"),
        "PID (implemented)": Loop.pid(G, pd.kp, ki, pd.kd, sigma=sigma, name="PID, dirty derivative"),
    }
    return rl, loops


def single_loop_blocks(
    known: models.Plant,
    coordinate: str,
    pd,
    ki: float,
    *,
    feedforward: bool,
    sample_period: float,
    sigma: float,
    anti_windup: str = "back_calculation",
    rate_limit: float | None = None,
) -> dict:
    """The "PD", "PID" and "PID (no anti-windup)" blocks of a single-loop design, saturating at the limit.

    Parameters
    ----------
    known : the plant the blocks know (its outputs, its actuator limit, its equilibrium input)
    coordinate : the controlled coordinate
    pd : the PD design (k_p, k_d);  ki : the integrator gain of the PID blocks
    feedforward : add the known plant's equilibrium input (`designs.pid.PID`)
    sample_period : s;  sigma : the dirty derivative's time constant σ, s (both the case's)
    anti_windup, rate_limit : the "PID" block's anti-windup (see `designs.pid.PID`)
    """
    limit = float(known.input_limit[0])
    common = dict(
        kp=pd.kp, kd=pd.kd, output_limit=limit, feedforward=feedforward, sample_period=sample_period, sigma=sigma
    )
    return {
        "PD": PID(known, coordinate, name="PD", **common),
        "PID": PID(known, coordinate, ki=ki, anti_windup=anti_windup, rate_limit=rate_limit, name="PID", **common),
        "PID (no anti-windup)": PID(
            known, coordinate, ki=ki, anti_windup="none", name="PID (no anti-windup)", **common
        ),
    }


def loopshaped(L0, spec: LoopSpec, phase_margin_deg: float = 60.0):
    """The .14 design on the baseline loop L0 to a case's `LoopSpec`, and its flattening prefilter.

    Returns
    -------
    (shaped, prefilter record, new closed loop T): see `designs.loopshaping`.
    """
    if spec.low_frequency is None or spec.high_frequency is None:
        raise ValueError(
            f"loopshaped needs the bands of {spec.item}: low_frequency and high_frequency, got "
            f"{spec.low_frequency} and {spec.high_frequency}"
        )
    shaped = improve_loop(
        L0,
        low_frequency=spec.low_frequency,
        low_factor=spec.factor,
        high_frequency=spec.high_frequency,
        high_factor=spec.factor,
        phase_margin_deg=phase_margin_deg,
    )
    T_new = Loop.unity(shaped.loop, 1.0).reference_to_output()
    return shaped, flattening_prefilter(T_new), T_new


def loopshaping_record(shaped, pre, T_new) -> dict:
    """The .14 answer: compensator, prefilter, margins before and after, and the specs met."""
    specs = list(shaped.specs)
    peak_after = pre["peak_after"]
    specs.append(
        an.SpecCheck("closed-loop magnitude flat (max |F T| <= 1.01)", peak_after <= 1.01 + 1e-9, peak_after, 1.01)
    )
    step_before = an.step_info(T_new)["Overshoot"]
    step_after = an.step_info(pre["prefilter"] * T_new)["Overshoot"]
    return record(
        **tf_record(shaped.controller, "C_"),
        **tf_record(pre["prefilter"], "F_"),
        lag_zero=shaped.lag_zero,
        lag_gain=shaped.lag_gain,
        lowpass_corner=shaped.lowpass_corner,
        lowpass_order=shaped.lowpass_order,
        lead_phase_deg=shaped.lead_phase_deg,
        **margin_record(shaped.baseline, "_baseline"),
        **margin_record(shaped.loop, ""),
        prefilter_corner=pre["corner"],
        peak_before=pre["peak_before"],
        peak_after=peak_after,
        overshoot_percent_without_prefilter=step_before,
        overshoot_percent_with_prefilter=step_after,
        specs=spec_records(specs),
    )


def cascade_records(prefix: str, slc: SuccessiveLoopClosure[PDDesign], bound: dict, letters: Mapping[str, str]) -> dict:
    """The .8 records of a successive-loop design; `letters` maps each record to its homework letter.

    Keys of `letters`: inner_tf, bound, kp_inner, wn_inner, poles_inner, outer_tf, kp_outer,
    wn_outer, poles_outer.
    """
    plants = slc.plants
    item = lambda key: f"{prefix}.8({letters[key]})"
    return {
        item("inner_tf"): record(
            **tf_record(plants.inner, "plant_"),
            **tf_record(slc.inner.closed_loop, "closed_loop_"),
            dropped_coupling=plants.dropped,
        ),
        item("bound"): record(
            max_equilibrium_input=bound["max_equilibrium_input"], bound=bound["bound"], input_limit=bound["input_limit"]
        ),
        item("kp_inner"): record(kp=slc.inner.kp, step=slc.inner_limit),
        item("wn_inner"): record(wn=slc.inner.wn, kd=slc.inner.kd, zeta=slc.inner.zeta),
        item("poles_inner"): record(poles=poles_record(slc.inner.poles), dc_gain=slc.inner_dc_gain),
        item("outer_tf"): record(
            **tf_record(plants.outer, "plant_"),
            **tf_record(slc.outer_model, "model_"),
            inner_dc_gain=slc.inner_dc_gain,
            **tf_record(slc.outer.closed_loop, "closed_loop_"),
        ),
        item("kp_outer"): record(kp=slc.outer.kp, step=slc.outer.step, inner_step=slc.inner_limit),
        item("wn_outer"): record(wn=slc.outer.wn, kd=slc.outer.kd, zeta=slc.outer.zeta),
        item("poles_outer"): record(
            poles=poles_record(slc.outer.poles), full_poles=poles_record(slc.full_poles), separation=slc.separation
        ),
    }


# ----------------------------------------------------------------- classical engine
@dataclass
class ClassicalDesign:
    """Every classical answer and controller of one case.

    Attributes
    ----------
    answers : homework item -> dict of named values
    controllers : label -> models.Block; each reads the plant's outputs and takes the absolute
        tracked coordinate as its 1-vector reference
    loops : label -> designs.analysis.Loop behind the frequency answers (for Bode data)
    notes : what the design chose or found wrong in the text, in words
    """

    answers: dict
    controllers: dict
    loops: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


_CLASSICAL: dict = {}


def _known(case: CaseStudy, known: models.Plant | None) -> models.Plant:
    """`known` (default the case's nominal plant), checked to be the case's plant or one of its design models."""
    known = models.get(case.plant) if known is None else known
    if known.name not in (case.plant, *case.design_models):
        allowed = ", ".join(repr(n) for n in (case.plant, *case.design_models))
        raise ValueError(f"the known plant is {known.name!r}; the {case.plant} designs take {allowed}")
    return known


def classical_design(case: CaseStudy, known: models.Plant | None = None) -> ClassicalDesign:
    """The case's classical design made on `known` (default: the nominal plant), computed once per plant."""
    if case.classical is None:
        raise ValueError(f"the {case.plant} case has no classical design")
    known = _known(case, known)
    key = (case.plant, id(case.classical), known.name, tuple(known.param_vector()), tuple(known.input_limit))
    if key not in _CLASSICAL:
        if len(_CLASSICAL) > 32:
            _CLASSICAL.clear()
        _CLASSICAL[key] = case.classical(known)
    return _CLASSICAL[key]


def classical_answers(case: CaseStudy, known: models.Plant | None = None) -> dict:
    """Homework item -> dict of named values of the classical design, plus its "notes"."""
    design = classical_design(case, known)
    return {k: to_jsonable(v, encode=False) for k, v in design.answers.items()} | {"notes": list(design.notes)}


def frequency_responses(design: ClassicalDesign, omega=None) -> dict:
    """Bode data of the loops behind the frequency answers: label -> {plant, loop, closed_loop}.

    Each entry is `designs.analysis.bode_data` ({omega, magnitude, phase_deg}) of the
    plant, the loop gain and the closed loop from reference to output.
    """
    omega = np.logspace(-3, 3, 600) if omega is None else np.asarray(omega, dtype=float)
    return {
        label: {
            "plant": an.bode_data(loop.plant, omega),
            "loop": an.bode_data(loop.loop_gain(), omega),
            "closed_loop": an.bode_data(loop.reference_to_output(), omega),
        }
        for label, loop in design.loops.items()
    }


# ----------------------------------------------------------------- state-space engine
@dataclass(frozen=True)
class StateSpaceChoices:
    """What a case chooses for its state-space homework (.15–.17) and LQR.

    Attributes
    ----------
    poles : known Plant -> the nx state-feedback poles (rad/s)
    bryson_maxima : state name -> largest acceptable excursion (SI), Bryson's rule for the LQR
    items : records (see `statespace_records`) -> {homework item: record}
    observer_outputs : outputs the observers read (default every output)
    observer_speedup : observer poles = this times the state-feedback poles
    observer_uses_integrator : the observer-based block runs the integrator design (.17(c))
    integral_horizon : Bryson maximum of the integrator state = design step × this (s)
    integrator_pole : rad/s, or None for −min |pᵢ|
    rule_values : extra numbers behind the pole choice, merged into the "rule" record
    notes : why, in words
    """

    poles: Callable[[models.Plant], np.ndarray]
    bryson_maxima: Mapping[str, float]
    items: Callable[[dict], dict]
    observer_outputs: tuple | None = None
    observer_speedup: float = 5.0
    observer_uses_integrator: bool = False
    integral_horizon: float = 0.25
    integrator_pole: float | None = None
    rule_values: Mapping[str, float] = field(default_factory=dict)
    notes: tuple = ()


def _choices(case: CaseStudy, choices: StateSpaceChoices | None) -> StateSpaceChoices:
    """`choices`, or the case's own; ValueError when the case has no state-space design."""
    choices = case.statespace if choices is None else choices
    if choices is None:
        raise ValueError(f"the {case.plant} case has no state-space design")
    return choices


def statespace_design(
    case: CaseStudy,
    known: models.Plant | None = None,
    choices: StateSpaceChoices | None = None,
    *,
    poles=None,
    integrator_pole: float | None = None,
    observer_poles=None,
    disturbance_pole: float | None = None,
    Q=None,
    R=None,
) -> ssd.StateSpaceDesign:
    """Every state-space design of the case, on `known` (default nominal), by `choices` (default the case's).

    The keywords override the choices: poles (nx, rad/s), integrator_pole, observer_poles,
    disturbance_pole, and the LQR weights Q (nx + 1) and R (default Bryson's rule).
    """
    choices = _choices(case, choices)
    known = _known(case, known)
    poles = choices.poles(known) if poles is None else poles
    if Q is None or R is None:
        room = float(known.input_limit[0] - abs(known.linearize().ue[0]))
        Q_rule, R_rule = ss.bryson_tracking_weights(
            known.state_names, dict(choices.bryson_maxima), case.design_step * choices.integral_horizon, room
        )
        Q = Q_rule if Q is None else Q
        R = R_rule if R is None else R
    return ssd.design(
        known,
        case.tracked,
        poles=poles,
        Q=Q,
        R=R,
        sample_period=case.sample_period,
        observer_sample_period=case.observer_sample_period,
        integrator_pole=choices.integrator_pole if integrator_pole is None else integrator_pole,
        observer_poles=observer_poles,
        observer_speedup=choices.observer_speedup,
        observer_outputs=choices.observer_outputs,
        observer_uses_integrator=choices.observer_uses_integrator,
        disturbance_pole=disturbance_pole,
    )


def plain(value):
    """numpy -> Python numbers and lists, complex arrays with no imaginary part as real ones."""
    arr = np.asarray(value)
    if np.iscomplexobj(arr) and np.all(arr.imag == 0):
        arr = arr.real
    return to_jsonable(arr, encode=False)


def statespace_records(d: ssd.StateSpaceDesign, case: CaseStudy, choices: StateSpaceChoices) -> dict:
    """The design's numbers grouped as the homework asks for them (SI units, rad/s; lists; complex allowed).

    Keys: "rule" (the pole choice), "controllable", "feedback", "integrator",
    "observable", "observer", "disturbance observer", "LQR", and "model" (a line
    naming the design model's states).
    """
    A, B = d.model.linear.A, d.model.linear.B
    A_I, B_I = ss.augment_integrator(A, B, d.model.C_r)
    poles = np.asarray(choices.poles(d.model.plant), dtype=complex)
    pairs = poles[poles.imag > 0]
    rule = {
        "natural_frequencies": plain(np.abs(pairs)),
        "damping_ratios": plain(-pairs.real / np.abs(pairs)),
        **dict(choices.rule_values),
        "poles": plain(d.poles),
    }
    observer = {
        "L": plain(d.L),
        "observer_poles": plain(d.observer_poles),
        "controller_poles": plain(d.controller_poles),
        "L_discrete": plain(d.L_discrete),
        "observer_poles_z": plain(d.observer_poles_z),
        "sample_period": d.observer_sample_period,
        "measured_outputs": list(d.observer_outputs),
        "with_integrator": d.observer_uses_integrator,
    }
    if not d.observer_uses_integrator:
        observer["kr"] = d.kr
    return {
        "rule": rule,
        "controllable": {"controllability_rank": d.controllability_rank, "n_states": d.model.nx},
        "feedback": {
            "K": plain(d.K),
            "kr": d.kr,
            "poles": plain(np.linalg.eigvals(A - B @ d.K)),
            "poles_sampled_z": plain(d.poles_sampled_z),
            "sample_period": d.sample_period,
        },
        "integrator": {
            "K": plain(d.K_integral),
            "ki": d.ki,
            "kr": 0.0,
            "integrator_pole": d.integrator_pole,
            "poles": plain(np.linalg.eigvals(A_I - B_I @ np.hstack([d.K_integral, [[-d.ki]]]))),
        },
        "observable": {
            "observability_rank": d.observability_rank,
            "n_states": d.model.nx,
            "measured_outputs": list(d.observer_outputs),
        },
        "observer": observer,
        "disturbance observer": {
            "L": plain(d.L_disturbance),
            "observer_poles": plain(d.disturbance_observer_poles),
            "controller_poles": plain(d.disturbance_controller_poles),
            "L_discrete": plain(d.L_disturbance_discrete),
            "observer_poles_z": plain(d.disturbance_observer_poles_z),
            "sample_period": d.sample_period,
            "K": plain(d.K),
            "kr": d.kr,
            "input_disturbance": case.input_disturbance,
        },
        "LQR": {
            "K": plain(d.K_lqr),
            "ki": d.ki_lqr,
            "Q": plain(d.Q),
            "R": plain(d.R),
            "poles": plain(d.lqr_poles),
            "K_without_integrator": plain(d.K_lqr_plain),
            "kr_without_integrator": d.kr_lqr_plain,
            "K_discrete": plain(d.K_dlqr),
            "poles_discrete_z": plain(d.dlqr_poles_z),
            "kalman_L": plain(d.L_kalman),
            "kalman_poles_z": plain(d.kalman_poles_z),
            "kalman_W": plain(d.kalman_W),
            "kalman_V": plain(d.kalman_V),
        },
        "model": f"{d.plant}: {d.model.nx} states ({', '.join(d.model.plant.state_names)})",
    }


def statespace_items_15_to_17(numeral: str) -> Callable[[dict], dict]:
    """The records under the item labels of chapters I–III: .15(c), .15(e), .15(f), .16, .17(b), .17(c), .17(e)."""

    def items(r: dict) -> dict:
        return {
            f"{numeral}.15(c)": r["rule"],
            f"{numeral}.15(e)": r["controllable"],
            f"{numeral}.15(f)": r["feedback"],
            f"{numeral}.16": r["integrator"],
            f"{numeral}.17(b)": r["observable"],
            f"{numeral}.17(c)": r["observer"],
            f"{numeral}.17(e)": r["disturbance observer"],
            "LQR": r["LQR"],
        }

    return items


def statespace_answers(
    case: CaseStudy, known: models.Plant | None = None, choices: StateSpaceChoices | None = None, **overrides
) -> dict:
    """Homework item -> record of the state-space design (items as the case's `StateSpaceChoices.items` says)."""
    choices = _choices(case, choices)
    d = statespace_design(case, known, choices, **overrides)
    return choices.items(statespace_records(d, case, choices))


def statespace_controllers(
    case: CaseStudy, known: models.Plant | None = None, choices: StateSpaceChoices | None = None, **overrides
) -> dict:
    """Label -> block of the state-space design (`designs.statespace_design.LABELS`)."""
    return ssd.controllers(statespace_design(case, known, choices, **overrides))
