"""The classical homework of every case study, answered as data, and the controllers it designs.

``answers(name)`` returns one record per homework item (.8, .10, .13, .14,
and IV.11, IV.13, V.13, VI.13): ``{"I.8(c)": {"kp": ...}, ...}`` in SI units
(rad, rad/s; degrees only where a key ends in ``_deg``). ``controllers(name)``
returns the blocks those designs define, each reading the plant's outputs
and taking the absolute tracked coordinate as its reference.

Choices the text leaves to the student, made once here:

- ζ = 0.707 wherever ζ is "a design parameter" (I.8, II.8, III.8, V.8);
  IV.8 gives ζ = 0.7, VI.8 gives 50 % overshoot (ζ = 0.2155) and a 1 s rise time.
- Bandwidth separation M = 10 between inner and outer loops; the free
  inner step A_θ of II.8, III.8 and V.8 is the one that gives it.
- k_i (.10) along its root locus: the largest gain keeping every closed-loop
  pole's damping at least 0.9 ζ and, when the PD loop already has unit DC
  gain, adding at most 10 percentage points of step overshoot to it
  ("without significantly degrading the transient response", IV.10(d)).
- PID anti-windup: back-calculation, except where the text asks for
  integrating only while |ẏ| is small (pendulum II.16, ball on beam
  V.12(f): negative integrator gains); the rate limit is 10 % of (design
  step × outer ω_n). Transfer-function blocks use the observer form of
  back-calculation (see `filters.TransferFunctionBlock`).
- The .13 answers use the implemented controllers, with the dirty
  derivative s/(σ s + 1), σ = 0.05 s; .8 and .10 use the ideal PD/PID.
- Each loop of a cascade gets an integrator analysis (.10); the controllers
  integrate in the outer loop, and for the ball on beam in both (see its notes).

Each record's "notes" entry says what was chosen for that plant and what in
the text did not hold. Labels of `controllers`: `LABELS` for every plant,
plus "lead-lag (IV.11)" (UUV, for the 250 N m thrusters) and
"PD (zero-cancelling filter)" (pendulum).
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass, field

import control
import numpy as np

import models

from . import analysis as an
from .analysis import Loop, dc_gain, pid_tf, steady_state_errors
from .filters import TransferFunctionBlock, notch, proportional_integral
from .loops import (SuccessiveLoopClosure, cascade_blocks, cascade_plants, cascade_poles, place_pair,
                    successive_loop_closure, zero_cancelling_design)
from .loopshaping import (crossover_for_bandwidth, damping_for_phase_margin, flattening_prefilter,
                          improve_loop, lead_for_crossover, phase_at, prototype_phase_margin)
from .pid import PID, SIGMA, linearized_input_bound, pd_design, pd_saturation
from .rootlocus import dominant_pair, integrator_gain, lag_for_static_gain, lead_by_angle

__all__ = ["answers", "controllers", "design", "frequency_responses", "PlantDesign", "ZETA", "SEPARATION",
           "DAMPING_KEPT", "LABELS"]

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
#: Controller labels every plant provides (the UUV adds "lead-lag (IV.11)").
LABELS = ("PD", "PID", "PID (no anti-windup)", "loopshaped")


@dataclass
class PlantDesign:
    """Every classical answer and controller of one plant.

    Attributes
    ----------
    answers : homework item -> dict of named values
    controllers : label -> models.Block
    loops : label -> analysis.Loop used by the frequency answers (for Bode plots)
    notes : what the design chose or found wrong in the text, in words
    """

    answers: dict
    controllers: dict
    loops: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


# ----------------------------------------------------------------- records
def _value(v):
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    if isinstance(v, (complex, np.complexfloating)):
        return complex(v)
    if isinstance(v, np.ndarray):
        return [_value(x) for x in v.tolist()]
    if isinstance(v, (list, tuple)):
        return [_value(x) for x in v]
    if isinstance(v, dict):
        return {k: _value(x) for k, x in v.items()}
    return v


def _record(**values) -> dict:
    return {k: _value(v) for k, v in values.items()}


def _tf(G, prefix: str = "") -> dict:
    num, den = an.as_polynomials(G)
    return {f"{prefix}num": [float(c) for c in num], f"{prefix}den": [float(c) for c in den]}


def _poles(poles) -> list:
    poles = np.asarray(poles, dtype=complex)
    poles = poles[np.lexsort((poles.imag, poles.real))]
    return [complex(p) for p in poles]


def _errors(loop: Loop, suffix: str = "") -> dict:
    out = steady_state_errors(loop)
    return {f"{k}{suffix}": v for k, v in out.items()}


def _margins(L, suffix: str) -> dict:
    m = an.margins(L)
    return {f"pm_deg{suffix}": m["pm_deg"], f"gm{suffix}": m["gm"], f"crossover{suffix}": m["gain_crossover"]}


def _pd_record(d) -> dict:
    return _record(kp=d.kp, kd=d.kd, wn=d.wn, zeta=d.zeta, poles=_poles(d.poles), dc_gain=d.dc_gain)


def _specs(checks) -> list:
    return [_value(c.as_dict()) for c in checks]


def _integrator(G, kp, kd, zeta, derivative_on="measurement") -> dict:
    return integrator_gain(G, kp, kd, DAMPING_KEPT * zeta, OVERSHOOT_ALLOWANCE, derivative_on)


def _root_locus_record(G, kp, kd, rl: dict) -> dict:
    return _record(ki=rl["ki"], zeta_min=rl["zeta_min"], ki_damping=rl["ki_damping"], overshoot_pd=rl["overshoot_pd"],
                   overshoot_pid=rl["overshoot_pid"], poles=_poles(rl["poles"]), **_tf(rl["evans"], "evans_"),
                   closed_loop_pid=_tf(Loop.pid(G, kp, rl["ki"], kd).reference_to_output()))


def _step_specs_nonlinear(plant, block, step, *, rise_time=None, settling_time=None, overshoot_percent=None,
                          steady_state_error_percent=None, duration=10.0, start=0.0, threshold=0.02):
    """Step-response specs of the nonlinear closed loop (one compiled run of models.simulate_closed_loop)."""
    x0, _ = plant.equilibrium()
    tracked = models.case(plant.name).tracked
    y0 = x0[plant.coordinate_names.index(tracked)]
    res = models.simulate_closed_loop(plant, block, y0 + step, duration, x0=x0)
    y = (res.state(tracked) - y0) / step
    info = control.step_info(y, T=res.t, yfinal=y[-1], SettlingTimeThreshold=threshold)
    checks = []
    if rise_time is not None:
        checks.append(an.SpecCheck(f"rise time < {rise_time:g} s (nonlinear)", info["RiseTime"] < rise_time,
                                   info["RiseTime"], rise_time))
    if settling_time is not None:
        checks.append(an.SpecCheck(f"settling time ({100 * threshold:g} %) < {settling_time:g} s (nonlinear)",
                                   info["SettlingTime"] < settling_time, info["SettlingTime"], settling_time))
    if overshoot_percent is not None:
        checks.append(an.SpecCheck(f"overshoot < {overshoot_percent:g} % (nonlinear)",
                                   info["Overshoot"] < overshoot_percent, info["Overshoot"], overshoot_percent))
    if steady_state_error_percent is not None:
        err = 100 * abs(1 - y[-1])
        checks.append(an.SpecCheck(f"steady-state error < {steady_state_error_percent:g} % (nonlinear)",
                                   err < steady_state_error_percent, err, steady_state_error_percent))
    peak = float(np.max(np.abs(res.u)))
    checks.append(an.SpecCheck(f"command within the {plant.input_limit[0]:g} actuator limit",
                               peak <= plant.input_limit[0] * (1 + 1e-12), peak, float(plant.input_limit[0])))
    return checks


def _frequency_specs(loop: Loop, crossover: float, pm_deg: float, bandwidth: float) -> list:
    """V.13/VI.13 requirements: stable, crossover and phase margin as designed, bandwidth as asked."""
    L = loop.loop_gain()
    return [an.check_stable(loop), an.check_crossover(L, crossover),
            an.check_phase_margin(L, target_deg=pm_deg, tolerance_deg=1.0),
            an.check_bandwidth(loop.reference_to_output(), bandwidth)]


def _rate_limit(step, wn) -> float:
    return RATE_FRACTION * abs(step) * wn


# ----------------------------------------------------------------- single loops
def _single_loop(G, pd, zeta):
    """Integrator by the root locus, and the four loops the .10/.13 answers read."""
    rl = _integrator(G, pd.kp, pd.kd, zeta)
    ki = rl["ki"]
    loops = {"PD": Loop.pid(G, pd.kp, 0.0, pd.kd, name="PD"),
             "PID": Loop.pid(G, pd.kp, ki, pd.kd, name="PID"),
             "PD (implemented)": Loop.pid(G, pd.kp, 0.0, pd.kd, sigma=SIGMA, name="PD, dirty derivative"),
             "PID (implemented)": Loop.pid(G, pd.kp, ki, pd.kd, sigma=SIGMA, name="PID, dirty derivative")}
    return rl, loops


def _single_loop_blocks(known, coordinate, pd, ki, *, feedforward, anti_windup="back_calculation",
                        rate_limit=None) -> dict:
    limit = float(known.input_limit[0])
    common = dict(kp=pd.kp, kd=pd.kd, output_limit=limit, feedforward=feedforward)
    return {
        "PD": PID(known, coordinate, name="PD", **common),
        "PID": PID(known, coordinate, ki=ki, anti_windup=anti_windup, rate_limit=rate_limit, name="PID", **common),
        "PID (no anti-windup)": PID(known, coordinate, ki=ki, anti_windup="none", name="PID (no anti-windup)",
                                    **common),
    }


# ----------------------------------------------------------------- I: arm
def _arm(known: models.Plant) -> PlantDesign:
    case = models.case("arm")
    G = known.linearize().tf("theta", "tau")
    bound = linearized_input_bound(known, {"theta": (-np.pi, np.pi)})
    pd = pd_saturation(G, input_bound=bound["bound"], step=case.design_step, zeta=ZETA)
    rl, loops = _single_loop(G, pd, ZETA)
    ki = rl["ki"]
    a = {}
    a["I.8(a)"] = _record(**_tf(G, "plant_"), **_tf(pd.closed_loop, "closed_loop_"))
    a["I.8(b)"] = _record(max_equilibrium_input=bound["max_equilibrium_input"], bound=bound["bound"],
                          input_limit=bound["input_limit"])
    a["I.8(c)"] = _record(kp=pd.kp, step=case.design_step)
    a["I.8(d)"] = _record(wn=pd.wn, kd=pd.kd, zeta=pd.zeta)
    a["I.8(e)"] = _record(poles=_poles(pd.poles))
    a["I.10(a)"] = _record(**_errors(loops["PD"]), **_errors(loops["PID"], "_pid"))
    a["I.10(b)"] = _record(ess_input_disturbance=dc_gain(loops["PD"].input_disturbance_to_output()),
                           ess_input_disturbance_pid=dc_gain(loops["PID"].input_disturbance_to_output()))
    a["I.10(c)"] = _record(**_tf(loops["PID"].reference_to_output(), "closed_loop_"), ki=ki)
    a["I.10(d)"] = _root_locus_record(G, pd.kp, pd.kd, rl)
    pid_impl, pd_impl = loops["PID (implemented)"], loops["PD (implemented)"]
    a["I.13"] = _record(**_margins(pd_impl.loop_gain(), "_pd"), **_margins(pid_impl.loop_gain(), "_pid"))
    a["I.13(a)"] = _record(omega=0.4, tracking_error_percent=an.percent_tracking_error_below(pid_impl, 0.4))
    a["I.13(b)"] = _record(slope=5.0, ess_ramp=5.0 * steady_state_errors(pid_impl)["ess_ramp"])
    a["I.13(c)"] = _record(omega=0.01, input_disturbance_percent=an.percent_input_disturbance_below(pid_impl, 0.01))
    a["I.13(d)"] = _record(omega=100.0, noise_percent=an.percent_noise_above(pid_impl, 100.0),
                           noise_percent_ideal_derivative=an.percent_noise_above(loops["PID"], 100.0))
    # I.14: lag + low-pass + lead on the implemented PD loop, then a prefilter.
    C_pd = pid_tf(pd.kp, 0.0, pd.kd, SIGMA)
    shaped = improve_loop(G * C_pd, low_frequency=0.007, low_factor=10.0, high_frequency=200.0, high_factor=10.0,
                          phase_margin_deg=60.0)
    T_new = Loop.unity(shaped.loop, 1.0).reference_to_output()
    pre = flattening_prefilter(T_new)
    a["I.14"] = _loopshaping_record(shaped, pre, T_new)
    blocks = _single_loop_blocks(known, "theta", pd, ki, feedforward=True)
    blocks["loopshaped"] = TransferFunctionBlock(known, "theta", shaped.controller * C_pd, prefilter=pre["prefilter"],
                                                 output_limit=float(known.input_limit[0]), feedforward=True,
                                                 name="loopshaped (I.14)")
    loops["loopshaped"] = Loop(G, shaped.controller * C_pd, pre["prefilter"] * shaped.controller * C_pd,
                               "loopshaped")
    notes = [f"ζ = {ZETA} (I.8(d) leaves it to the student)",
             "feedforward τ_e = m g ℓ/2 cos θ at the measured θ (I.9), from the known plant"]
    return PlantDesign(a, blocks, loops, notes)


def _loopshaping_record(shaped, pre, T_new) -> dict:
    specs = list(shaped.specs)
    peak_after = pre["peak_after"]
    specs.append(an.SpecCheck("closed-loop magnitude flat (max |F T| <= 1.01)", peak_after <= 1.01 + 1e-9,
                              peak_after, 1.01))
    step_before = an.step_info(T_new)["Overshoot"]
    step_after = an.step_info(pre["prefilter"] * T_new)["Overshoot"]
    return _record(**_tf(shaped.controller, "C_"), **_tf(pre["prefilter"], "F_"), lag_zero=shaped.lag_zero,
                   lag_gain=shaped.lag_gain, lowpass_corner=shaped.lowpass_corner,
                   lowpass_order=shaped.lowpass_order, lead_phase_deg=shaped.lead_phase_deg,
                   **_margins(shaped.baseline, "_baseline"), **_margins(shaped.loop, ""),
                   prefilter_corner=pre["corner"], peak_before=pre["peak_before"], peak_after=peak_after,
                   overshoot_percent_without_prefilter=step_before, overshoot_percent_with_prefilter=step_after,
                   specs=_specs(specs))


# ----------------------------------------------------------------- cascades
def _cascade_common(prefix: str, slc: SuccessiveLoopClosure, bound: dict, a: dict, letters: dict) -> None:
    """The .8 records shared by the pendulum and ball on beam (letters map item -> homework letter)."""
    plants = slc.plants
    a[f"{prefix}.8({letters['inner_tf']})"] = _record(**_tf(plants.inner, "plant_"),
                                                      **_tf(slc.inner.closed_loop, "closed_loop_"),
                                                      dropped_coupling=plants.dropped)
    a[f"{prefix}.8({letters['bound']})"] = _record(max_equilibrium_input=bound["max_equilibrium_input"],
                                                   bound=bound["bound"], input_limit=bound["input_limit"])
    a[f"{prefix}.8({letters['kp_inner']})"] = _record(kp=slc.inner.kp, step=slc.inner_limit)
    a[f"{prefix}.8({letters['wn_inner']})"] = _record(wn=slc.inner.wn, kd=slc.inner.kd, zeta=slc.inner.zeta)
    a[f"{prefix}.8({letters['poles_inner']})"] = _record(poles=_poles(slc.inner.poles), dc_gain=slc.inner_dc_gain)
    a[f"{prefix}.8({letters['outer_tf']})"] = _record(**_tf(plants.outer, "plant_"), **_tf(slc.outer_model, "model_"),
                                                      inner_dc_gain=slc.inner_dc_gain,
                                                      **_tf(slc.outer.closed_loop, "closed_loop_"))
    a[f"{prefix}.8({letters['kp_outer']})"] = _record(kp=slc.outer.kp, step=slc.outer.step,
                                                      inner_step=slc.inner_limit)
    a[f"{prefix}.8({letters['wn_outer']})"] = _record(wn=slc.outer.wn, kd=slc.outer.kd, zeta=slc.outer.zeta)
    a[f"{prefix}.8({letters['poles_outer']})"] = _record(poles=_poles(slc.outer.poles),
                                                         full_poles=_poles(slc.full_poles),
                                                         separation=slc.separation)


def _seen_outer(inner_loop: Loop, G_outer) -> control.TransferFunction:
    """The plant an outer controller sees: the inner closed loop θ/θ_d times the outer plant."""
    n_t, d_t = an.as_polynomials(inner_loop.reference_to_output())
    n_o, d_o = an.as_polynomials(G_outer)
    return an.tf(np.polymul(n_t, n_o), np.polymul(d_t, d_o))


def _pendulum(known: models.Plant) -> PlantDesign:
    case = models.case("pendulum")
    bound = linearized_input_bound(known, {"z": (-1.0, 1.0), "theta": (-0.5, 0.5)})
    slc = successive_loop_closure(known, "theta", "z", inner_bound=bound["bound"], outer_step=case.design_step,
                                  separation=SEPARATION, zeta_inner=ZETA, zeta_outer=ZETA,
                                  outer_model="low_frequency")
    a = {}
    _cascade_common("II", slc, bound, a, dict(inner_tf="b", bound="c", kp_inner="d", wn_inner="e", poles_inner="f",
                                              outer_tf="g", kp_outer="h", wn_outer="i", poles_outer="j"))
    # The controlbook's alternative to II.8(g)'s approximation: cancel the zero at −√(g/ℓ) and K_DC.
    zc = zero_cancelling_design(slc, separation=SEPARATION, zeta_outer=ZETA)
    a["II.8 zero-cancelling filter"] = _record(**_tf(zc.outer_filter, "filter_"), **_tf(zc.outer_model, "model_"),
                                               kp=zc.outer.kp, kd=zc.outer.kd, wn=zc.outer.wn, zeta=zc.outer.zeta,
                                               dc_gain=zc.outer_dc_gain, poles=_poles(zc.outer.poles),
                                               full_poles=_poles(zc.full_poles))
    G_in, G_out = slc.plants.inner, slc.outer_model
    rl_in = _integrator(G_in, slc.inner.kp, slc.inner.kd, ZETA)
    rl_out = _integrator(G_out, slc.outer.kp, slc.outer.kd, ZETA)
    inner_pd, inner_pid = Loop.pid(G_in, slc.inner.kp, 0, slc.inner.kd), Loop.pid(G_in, slc.inner.kp, rl_in["ki"],
                                                                                  slc.inner.kd)
    outer_pd, outer_pid = (Loop.pid(G_out, slc.outer.kp, 0, slc.outer.kd),
                           Loop.pid(G_out, slc.outer.kp, rl_out["ki"], slc.outer.kd))
    a["II.10(a)"] = _record(**_errors(inner_pd), **_errors(inner_pid, "_pid"), ki=rl_in["ki"])
    a["II.10(b)"] = _record(**_errors(outer_pd), **_errors(outer_pid, "_pid"), ki=rl_out["ki"])
    # .13 on the implemented loops. The outer loop sees the inner closed loop times the exact outer
    # plant: K_DC (g − ℓ s²)/s² alone has |L| > 1 at high frequency, which the inner loop's roll-off removes.
    in_pd = Loop.pid(G_in, slc.inner.kp, 0, slc.inner.kd, sigma=SIGMA, name="inner PD")
    exact_outer = _seen_outer(in_pd, slc.plants.outer)
    in_pid = Loop.pid(G_in, slc.inner.kp, rl_in["ki"], slc.inner.kd, sigma=SIGMA, name="inner PID")
    out_pd = Loop.pid(exact_outer, slc.outer.kp, 0, slc.outer.kd, sigma=SIGMA, name="outer PD")
    a["II.13"] = _record(**_margins(in_pd.loop_gain(), "_inner_pd"), **_margins(in_pid.loop_gain(), "_inner_pid"),
                         **_margins(out_pd.loop_gain(), "_outer_pd"))
    a["II.13(a)"] = _record(omega=1.0, tracking_error_percent=an.percent_tracking_error_below(in_pid, 1.0))
    a["II.13(b)"] = _record(step=2.0, ess=2.0 * steady_state_errors(in_pd)["ess_step"])
    a["II.13(c)"] = _record(omega=200.0, noise_percent=an.percent_noise_above(in_pid, 200.0),
                            noise_percent_pd=an.percent_noise_above(in_pd, 200.0))
    a["II.13(d)"] = _record(omega=0.1, output_disturbance_percent=an.percent_output_disturbance_below(out_pd, 0.1))
    a["II.13(e)"] = _record(slope=2.0, ess_ramp=2.0 * steady_state_errors(out_pd)["ess_ramp"])
    C_pd = pid_tf(slc.outer.kp, 0.0, slc.outer.kd, SIGMA)
    shaped = improve_loop(exact_outer * C_pd, low_frequency=0.001, low_factor=10.0, high_frequency=20.0,
                          high_factor=10.0, phase_margin_deg=60.0)
    T_new = Loop.unity(shaped.loop, 1.0).reference_to_output()
    pre = flattening_prefilter(T_new)
    a["II.14"] = _loopshaping_record(shaped, pre, T_new)
    rate = _rate_limit(case.design_step, slc.outer.wn)
    blocks = {
        "PD": cascade_blocks(known, slc, name="PD"),
        "PID": cascade_blocks(known, slc, ki=rl_out["ki"], anti_windup="integrate_while_slow", rate_limit=rate,
                              name="PID"),
        "PID (no anti-windup)": cascade_blocks(known, slc, ki=rl_out["ki"], anti_windup="none",
                                               name="PID (no anti-windup)"),
    }
    outer_block = TransferFunctionBlock(known, "z", shaped.controller * C_pd, prefilter=pre["prefilter"],
                                        output_limit=slc.inner_limit, name="loopshaped outer (z)")
    blocks["loopshaped"] = models.Cascade(outer_block, blocks["PD"].inner, name="loopshaped (II.14)")
    blocks["PD (zero-cancelling filter)"] = cascade_blocks(known, zc, name="PD (zero-cancelling filter)")
    loops = {"inner PD": in_pd, "inner PID": in_pid, "outer PD": out_pd,
             "outer loopshaped": Loop.unity(shaped.loop, 1.0, "outer loopshaped")}
    notes = [f"A_θ = {slc.inner_limit:.4g} rad chosen for a bandwidth separation of {SEPARATION:g}",
             "outer PD designed on K_DC·g/s² (the outer plant (g − ℓ s²)/s² below √(g/ℓ)); II.8(g) assumes "
             f"K_DC = 1, the inner loop gives K_DC = {slc.inner_dc_gain:.4g}",
             "integrator on the outer (z) loop only, integrating while |ż| is small (II.16 hint)",
             "'PD (zero-cancelling filter)': the controlbook's outer loop, F(s) = (1/K_DC) √(g/ℓ)/(s + √(g/ℓ)) "
             "after the outer PD, which then matches a second-order loop exactly (our text does not use it)"]
    return PlantDesign(a, blocks, loops, notes)


def _coupling_tf(plants) -> control.TransferFunction:
    """Transfer function from the outer coordinate to the inner one through the dropped terms (III.10(b))."""
    outer = plants.outer_coordinate
    c_q = plants.dropped.get(outer, 0.0)
    c_v = plants.dropped.get("d" + outer, 0.0)
    _, d_in = an.as_polynomials(plants.inner)
    return an.tf([c_v, c_q], d_in / d_in[0])


def _satellite(known: models.Plant) -> PlantDesign:
    case = models.case("satellite")
    # At rest φ = θ (III.5: the system is linear), so no equilibrium input: the bound is τ_max.
    bound = linearized_input_bound(known, {})
    slc = successive_loop_closure(known, "theta", "phi", inner_bound=bound["bound"], outer_step=case.design_step,
                                  separation=SEPARATION, zeta_inner=ZETA, outer_derivative=False)
    plants = slc.plants
    G_in = plants.inner
    K = slc.inner_dc_gain
    G_out = K * plants.outer
    a = {}
    a["III.8(b)"] = _record(kp=slc.inner.kp, step=slc.inner_limit, bound=bound["bound"])
    a["III.8(c)"] = _record(**_tf(G_in, "plant_"), **_tf(slc.inner.closed_loop, "closed_loop_"),
                            dropped_coupling=plants.dropped)
    a["III.8(d)"] = _record(wn=slc.inner.wn, kd=slc.inner.kd, zeta=slc.inner.zeta)
    a["III.8(e)"] = _record(dc_gain=K)
    a["III.8(f)"] = _record(**_tf(plants.outer, "plant_"), **_tf(slc.outer.closed_loop, "closed_loop_"))
    a["III.8(g)"] = _record(kp=slc.outer.kp, step=case.design_step, inner_step=slc.inner_limit)
    a["III.8(h)"] = _record(dc_gain=slc.outer_dc_gain, steady_state_error_fraction=1 - slc.outer_dc_gain)
    a["III.8(i)"] = _record(poles_inner=_poles(slc.inner.poles), poles_outer=_poles(slc.outer.poles),
                            wn_outer=slc.outer.wn, zeta_outer=slc.outer.zeta, full_poles=_poles(slc.full_poles))
    # III.10(d): a PD outer loop (the PID's), placed M below the inner loop.
    outer_pd = pd_design(G_out, wn=slc.inner.wn / SEPARATION, zeta=ZETA)
    rl_in = _integrator(G_in, slc.inner.kp, slc.inner.kd, ZETA)
    rl_out = _integrator(G_out, outer_pd.kp, outer_pd.kd, ZETA)
    inner_pd = Loop.pid(G_in, slc.inner.kp, 0, slc.inner.kd)
    inner_pid = Loop.pid(G_in, slc.inner.kp, rl_in["ki"], slc.inner.kd)
    coupling = _coupling_tf(plants)
    a["III.10(a)"] = _record(**_errors(inner_pd), **_errors(inner_pid, "_pid"))
    a["III.10(b)"] = _record(
        **_tf(coupling, "coupling_"),
        theta_per_psi=dc_gain(inner_pd.output_disturbance_to_output() * coupling),
        theta_per_psi_pid=dc_gain(inner_pid.output_disturbance_to_output() * coupling))
    a["III.10(c)"] = _root_locus_record(G_in, slc.inner.kp, slc.inner.kd, rl_in)
    a["III.10(d)"] = _record(kp=outer_pd.kp, kd=outer_pd.kd, wn=outer_pd.wn, zeta=outer_pd.zeta,
                             **_errors(Loop.pid(G_out, outer_pd.kp, 0, outer_pd.kd)),
                             **_errors(Loop.pid(G_out, outer_pd.kp, rl_out["ki"], outer_pd.kd), "_pid"))
    a["III.10(e)"] = _root_locus_record(G_out, outer_pd.kp, outer_pd.kd, rl_out)
    in_pd = Loop.pid(G_in, slc.inner.kp, 0, slc.inner.kd, sigma=SIGMA, name="inner PD")
    in_pid = Loop.pid(G_in, slc.inner.kp, rl_in["ki"], slc.inner.kd, sigma=SIGMA, name="inner PID")
    out_p = Loop.pid(G_out, slc.outer.kp, name="outer P")
    out_pid = Loop.pid(G_out, outer_pd.kp, rl_out["ki"], outer_pd.kd, sigma=SIGMA, name="outer PID")
    a["III.13"] = _record(**_margins(in_pd.loop_gain(), "_inner_pd"), **_margins(in_pid.loop_gain(), "_inner_pid"),
                          **_margins(out_pid.loop_gain(), "_outer_pid"))
    a["III.13(a)"] = _record(tracking_error_percent=100 * abs(steady_state_errors(in_pd)["ess_step"]))
    a["III.13(b)"] = _record(omega=0.02, input_disturbance_percent=an.percent_input_disturbance_below(in_pd, 0.02),
                             input_disturbance_percent_pid=an.percent_input_disturbance_below(in_pid, 0.02))
    a["III.13(c)"] = _record(omega=0.01, tracking_error_percent=an.percent_tracking_error_below(out_pid, 0.01),
                             tracking_error_percent_p=an.percent_tracking_error_below(out_p, 0.01))
    a["III.13(d)"] = _record(omega=1.0, noise_percent=an.percent_noise_above(out_pid, 1.0))
    C_pd = pid_tf(outer_pd.kp, 0.0, outer_pd.kd, SIGMA)
    baseline_pm = an.margins(G_out * C_pd)["pm_deg"]
    shaped = improve_loop(G_out * C_pd, low_frequency=0.003, low_factor=10.0, high_frequency=10.0, high_factor=10.0,
                          phase_margin_deg=min(baseline_pm, 60.0))
    T_new = Loop.unity(shaped.loop, 1.0).reference_to_output()
    pre = flattening_prefilter(T_new)
    a["III.14"] = _loopshaping_record(shaped, pre, T_new)
    pid_design = SuccessiveLoopClosure(plants=plants, inner=slc.inner, inner_dc_gain=K, outer_model=G_out,
                                       outer=outer_pd, outer_dc_gain=outer_pd.dc_gain,
                                       separation=slc.inner.wn / outer_pd.wn, inner_limit=slc.inner_limit,
                                       full_poles=slc.full_poles)
    blocks = {
        "PD": cascade_blocks(known, slc, outer_limit=None, name="PD"),
        "PID": cascade_blocks(known, pid_design, ki=rl_out["ki"], outer_limit_about="theta", name="PID"),
        "PID (no anti-windup)": cascade_blocks(known, pid_design, ki=rl_out["ki"], outer_limit_about="theta",
                                               anti_windup="none", name="PID (no anti-windup)"),
    }
    # θ_d bounded to θ ± A_θ: the inner loop stays out of saturation and the outer anti-windup sees the bound.
    outer_block = TransferFunctionBlock(known, "phi", shaped.controller * C_pd, prefilter=pre["prefilter"],
                                        output_limit=slc.inner_limit, limit_about="theta",
                                        name="loopshaped outer (phi)")
    blocks["loopshaped"] = models.Cascade(outer_block, blocks["PD"].inner, name="loopshaped (III.14)")
    loops = {"inner PD": in_pd, "inner PID": in_pid, "outer P": out_p, "outer PID": out_pid,
             "outer loopshaped": Loop.unity(shaped.loop, 1.0, "outer loopshaped")}
    notes = [f"A_θ = {slc.inner_limit:.4g} rad chosen for a bandwidth separation of {SEPARATION:g} with III.8's "
             "P outer loop",
             f"III.8's P outer loop leaves a DC gain of {slc.outer_dc_gain:.3g}: the 'PD' controller tracks φ only "
             "partly, as III.8(h) asks the student to notice",
             "the PID's outer loop is III.10(d)'s PD (ω_n = ω_n,θ/M, ζ = 0.707) plus k_i; θ_d must reach φ_d "
             "(the outer plant has DC gain 1, not an integrator), so the integrator carries the reference and "
             "θ_d is bounded about the measured θ (θ ± A_θ), which keeps the inner loop out of saturation and "
             "lets back-calculation see the bound",
             "III.14 starts from that PD outer loop: III.8's P loop has no gain crossover to keep",
             "III.13(d) asks for noise in θ under the outer loop; the outer loop's output is φ, reported for φ"]
    return PlantDesign(a, blocks, loops, notes)


# ----------------------------------------------------------------- IV: UUV
#: IV.11 dominant poles, lead zero and lag (our choices; see `_uuv_lead_lag`).
UUV_LEAD_LAG = {"wn": 5.0, "zeta": 0.85, "lead_zero": 1.5, "lag_zero": 0.5, "static_gain": 19.0,
                "input_limit": 250.0}


def _uuv_lead_lag(G, wn, zeta, lead_zero, lag_zero, static_gain):
    """IV.11: lead placing ζ, ω_n by the angle condition; lag raising K_p to `static_gain`.

    The lag is fixed first and the lead is placed on G·lag, so the lag's
    phase at s* is compensated and the dominant poles stay exactly at s*;
    the lag ratio is iterated until K_p = `static_gain`.
    """
    s_star = dominant_pair(wn, zeta)
    lead_alone = lead_by_angle(G, s_star, lead_zero)
    g0 = dc_gain(G)
    ratio = static_gain / (lead_alone.gain * lead_zero / lead_alone.lead_pole * g0)
    for _ in range(100):
        lag_tf = an.tf([1.0, lag_zero], [1.0, lag_zero / ratio])
        lead = lead_by_angle(G * lag_tf, s_star, lead_zero)
        achieved = lead.gain * lead_zero / lead.lead_pole * ratio * g0
        new_ratio = ratio * static_gain / achieved
        if abs(new_ratio - ratio) <= 1e-12 * ratio:
            break
        ratio = new_ratio
    final = lag_for_static_gain(lead, G, static_gain, lag_zero)
    return lead_alone, final


def _uuv(known: models.Plant) -> PlantDesign:
    case = models.case("uuv")
    G = known.linearize().tf("phi", "tau")
    zeta = 0.7  # IV.8(c)
    bound = float(known.input_limit[0])
    pd = pd_saturation(G, input_bound=bound, step=case.design_step, zeta=zeta)
    rl, loops = _single_loop(G, pd, zeta)
    ki = rl["ki"]
    a = {}
    a["IV.8(a)"] = _record(**_tf(G, "plant_"), **_tf(pd.closed_loop, "closed_loop_"))
    a["IV.8(b)"] = _record(kp=pd.kp, step=case.design_step, bound=bound)
    a["IV.8(c)"] = _record(wn=pd.wn, kd=pd.kd, zeta=pd.zeta)
    a["IV.8(e)"] = _record(poles=_poles(pd.poles), dc_gain=pd.dc_gain)
    a["IV.10(a)"] = _record(**_errors(loops["PD"]), **_errors(loops["PID"], "_pid"))
    a["IV.10(b)"] = _record(ess_input_disturbance=dc_gain(loops["PD"].input_disturbance_to_output()),
                            ess_input_disturbance_pid=dc_gain(loops["PID"].input_disturbance_to_output()))
    a["IV.10(c)"] = _record(**_tf(loops["PID"].reference_to_output(), "closed_loop_"), ki=ki)
    a["IV.10(d)"] = _root_locus_record(G, pd.kp, pd.kd, rl)
    # IV.11: root-locus lead-lag for the 250 N m thrusters.
    p = UUV_LEAD_LAG
    lead_alone, leadlag = _uuv_lead_lag(G, p["wn"], p["zeta"], p["lead_zero"], p["lag_zero"], p["static_gain"])
    turbo = known.with_input_limit(p["input_limit"])
    T_lead = Loop.unity(G, lead_alone.lead_tf()).reference_to_output()
    T_ll = Loop.unity(G, leadlag.transfer_function()).reference_to_output()
    spec_kw = dict(rise_time=0.9, settling_time=3.0, overshoot_percent=10.0, steady_state_error_percent=10.0)
    # No anti-windup: the lead-lag has no integrator, and the saturated lead is what keeps the overshoot
    # low; an anti-windup observer would hold the lead's state at the bound and slow the rise (6.6 s).
    lead_block = TransferFunctionBlock(turbo, "phi", lead_alone.lead_tf(), output_limit=p["input_limit"],
                                       anti_windup="none", name="lead (IV.11)")
    leadlag_block = TransferFunctionBlock(turbo, "phi", leadlag.transfer_function(), output_limit=p["input_limit"],
                                          anti_windup="none", name="lead-lag (IV.11)")
    a["IV.11(a)"] = _record(gain=lead_alone.gain, zero=lead_alone.lead_zero, pole=lead_alone.lead_pole,
                            wn=p["wn"], zeta=p["zeta"], target_pole=lead_alone.target,
                            specs=_specs(an.check_step(T_lead, **spec_kw)))
    a["IV.11(b)"] = _record(ess=1 - dc_gain(T_lead), specs=_specs(_step_specs_nonlinear(
        turbo, lead_block, case.design_step, **spec_kw)))
    a["IV.11(c)"] = _record(gain=leadlag.gain, zero=leadlag.lead_zero, pole=leadlag.lead_pole,
                            lag_zero=leadlag.lag_zero, lag_pole=leadlag.lag_pole, static_gain=p["static_gain"],
                            poles=_poles(Loop.unity(G, leadlag.transfer_function()).poles()),
                            specs=_specs(an.check_step(T_ll, **spec_kw)))
    a["IV.11(d)"] = _record(ess=1 - dc_gain(T_ll), input_limit=p["input_limit"], specs=_specs(
        _step_specs_nonlinear(turbo, leadlag_block, case.design_step, **spec_kw)))
    feedforward_block = TransferFunctionBlock(turbo, "phi", leadlag.transfer_function(),
                                              output_limit=p["input_limit"], anti_windup="none",
                                              feedforward="reference", name="lead-lag + feedforward (IV.11(e))")
    a["IV.11(e)"] = _record(feedforward="m g L sin(phi_d) of the known plant", specs=_specs(
        _step_specs_nonlinear(turbo, feedforward_block, case.design_step, **spec_kw)))
    # IV.13: PI, lead, notch, double lead at 2 rad/s.
    wc = 2.0
    integ = an.tf([1.0], [1.0, 0.0])
    a["IV.13(a)"] = _record(crossover_target=wc, pm_deg=180.0 + phase_at(integ * G, wc))
    pi = proportional_integral(wc / 10)
    a["IV.13(b)"] = _record(crossover_target=wc, pi_zero=wc / 10, pm_deg=180.0 + phase_at(pi * G, wc))
    lead_pi = lead_for_crossover(pi * G, wc, 60.0)
    C_c = lead_pi.controller * pi
    T_c = Loop.unity(G, C_c).reference_to_output()
    a["IV.13(c)"] = _record(lead_zero=lead_pi.zero, lead_pole=lead_pi.pole, gain=lead_pi.gain,
                            lead_count=lead_pi.count, **_margins(G * C_c, ""), **_tf(C_c, "C_"),
                            overshoot_percent=an.step_info(T_c)["Overshoot"],
                            rise_time=an.step_info(T_c)["RiseTime"])
    m, g_, L_, J = (known.params[k] for k in ("m", "g", "L", "J"))
    omega_notch = float(np.sqrt(m * g_ * L_ / J))
    N = notch(omega_notch, 0.05, 0.7)
    a["IV.13(d)"] = _record(notch_frequency=omega_notch, zeta_zero=0.05, zeta_pole=0.7,
                            pm_deg=180.0 + phase_at(N * integ * G, wc))
    lead_n = lead_for_crossover(N * integ * G, wc, 60.0)
    C_e = lead_n.controller * N * integ
    loop_e = Loop.unity(G, C_e)
    T_e = loop_e.reference_to_output()
    # The notch cancels the lightly damped mode instead of damping it: it stays in the closed loop.
    checks = [an.check_stable(loop_e), an.check_crossover(G * C_e, wc), an.check_phase_margin(G * C_e, 60.0),
              an.check_damping(loop_e, 0.1)]
    checks += an.check_step(T_e, overshoot_percent=10.0, steady_state_error_percent=1e-9)
    a["IV.13(e)"] = _record(lead_count=lead_n.count, lead_zero=lead_n.zero, lead_pole=lead_n.pole, gain=lead_n.gain,
                            **_tf(C_e, "C_"), **_margins(G * C_e, ""),
                            rise_time=an.step_info(T_e)["RiseTime"],
                            overshoot_percent=an.step_info(T_e)["Overshoot"], specs=_specs(checks))
    blocks = _single_loop_blocks(known, "phi", pd, ki, feedforward=False)
    # Anti-windup observer at 1 rad/s (z = 0.99): faster tracking starves the integrator while the
    # lightly damped mode keeps the torque saturated.
    blocks["loopshaped"] = TransferFunctionBlock(known, "phi", C_e, output_limit=bound, tracking_pole=0.99,
                                                 name="loopshaped (IV.13)")
    blocks["lead-lag (IV.11)"] = leadlag_block
    loops["loopshaped"] = loop_e
    loops["lead-lag (IV.11)"] = Loop.unity(G, leadlag.transfer_function(), "lead-lag")
    notes = ["IV.11: dominant poles ω_n = 5 rad/s, ζ = 0.85, lead zero at −1.5, lag zero at −0.5 and K_p = 19 "
             "(5 % error); the unsaturated linear loop overshoots because of the slow lead zero, the 250 N m "
             "thrusters' saturation removes it: specs are met on the nonlinear loop",
             "the IV.11 block saturates at 250 N m: simulate it on models.get('uuv', input_limit=250)",
             "IV.13 notch poles damped at ζ_p = 0.7 (the text gives only the zero damping 0.05)"]
    return PlantDesign(a, blocks, loops, notes)


# ----------------------------------------------------------------- V: ball on beam
def _ballbeam(known: models.Plant) -> PlantDesign:
    case = models.case("ballbeam")
    bound = linearized_input_bound(known, {"z": (0.0, known.params["ell"])})
    ff = known.equilibrium_input_jacobian().ravel()
    slc = successive_loop_closure(known, "theta", "z", inner_bound=bound["bound"], outer_step=case.design_step,
                                  separation=SEPARATION, zeta_inner=ZETA, zeta_outer=ZETA, feedforward_gradient=ff)
    a = {}
    _cascade_common("V", slc, bound, a, dict(inner_tf="b", bound="c", kp_inner="d", wn_inner="e", poles_inner="f",
                                             outer_tf="g", kp_outer="h", wn_outer="i", poles_outer="j"))
    G_in, G_out = slc.plants.inner, slc.outer_model
    rl = _integrator(G_out, slc.outer.kp, slc.outer.kd, ZETA)
    rl_in = _integrator(G_in, slc.inner.kp, slc.inner.kd, ZETA)
    outer_pd, outer_pid = (Loop.pid(G_out, slc.outer.kp, 0, slc.outer.kd),
                           Loop.pid(G_out, slc.outer.kp, rl["ki"], slc.outer.kd))
    a["V.10(a)"] = _record(**_errors(outer_pd), **_errors(outer_pid, "_pid"))
    a["V.10(b)"] = _record(**_tf(outer_pid.reference_to_error(), "error_"), type_pid=_errors(outer_pid)["type"])
    a["V.10(c)"] = _record(ess_input_disturbance=dc_gain(outer_pd.input_disturbance_to_output()),
                           ess_input_disturbance_pid=dc_gain(outer_pid.input_disturbance_to_output()))
    a["V.10(d)"] = _root_locus_record(G_out, slc.outer.kp, slc.outer.kd, rl)
    a["V.10(d) inner"] = _root_locus_record(G_in, slc.inner.kp, slc.inner.kd, rl_in)
    # V.13: lead inner loop (bandwidth 20 rad/s, ζ 0.7), lag for the 13.2 N disturbance, lead outer loop.
    zeta_in, bw_in = 0.7, 20.0
    wc_in, pm_in = crossover_for_bandwidth(bw_in, zeta_in), prototype_phase_margin(zeta_in)
    lead_in = lead_for_crossover(G_in, wc_in, pm_in)
    disturbance, max_error = 13.2, 0.0175
    loop_lead = Loop.unity(G_in, lead_in.controller)
    error_lead = abs(disturbance * dc_gain(loop_lead.input_disturbance_to_output()))
    lag_gain = max(error_lead / max_error * 1.2, 1.0 + 1e-9)
    lag_zero = wc_in / 10
    C_in = lead_in.controller * an.tf([1.0, lag_zero], [1.0, lag_zero / lag_gain])
    loop_in = Loop.unity(G_in, C_in, "inner lead-lag")
    error_lag = abs(disturbance * dc_gain(loop_in.input_disturbance_to_output()))
    a["V.13(a)"] = _record(bandwidth=bw_in, zeta=zeta_in, crossover_target=wc_in, pm_target_deg=pm_in,
                           lead_zero=lead_in.zero, lead_pole=lead_in.pole, gain=lead_in.gain,
                           **_margins(G_in * lead_in.controller, ""),
                           bandwidth_achieved=float(control.bandwidth(loop_lead.reference_to_output())),
                           specs=_specs(_frequency_specs(loop_lead, wc_in, pm_in, bw_in)))
    a["V.13(b)"] = _record(disturbance=disturbance, angle_error_lead=error_lead, lag_zero=lag_zero,
                           lag_gain=lag_gain, angle_error_lead_lag=error_lag, **_tf(C_in, "C_"),
                           specs=_specs([an.SpecCheck("angle error < 0.0175 rad under 13.2 N", error_lag < max_error,
                                                      error_lag, max_error), an.check_stable(loop_in)]))
    zeta_out, bw_out = 0.6, 2.0
    wc_out, pm_out = crossover_for_bandwidth(bw_out, zeta_out), prototype_phase_margin(zeta_out)
    lead_out = lead_for_crossover(slc.plants.outer, wc_out, pm_out)
    loop_out = Loop.unity(slc.plants.outer, lead_out.controller, "outer lead")
    a["V.13(c)"] = _record(bandwidth=bw_out, zeta=zeta_out, crossover_target=wc_out, pm_target_deg=pm_out,
                           lead_zero=lead_out.zero, lead_pole=lead_out.pole, gain=lead_out.gain,
                           **_tf(lead_out.controller, "C_"), **_margins(slc.plants.outer * lead_out.controller, ""),
                           bandwidth_achieved=float(control.bandwidth(loop_out.reference_to_output())),
                           specs=_specs(_frequency_specs(loop_out, wc_out, pm_out, bw_out)))
    rate = _rate_limit(case.design_step, slc.outer.wn)
    blocks = {
        "PD": cascade_blocks(known, slc, feedforward=True, name="PD"),
        "PID": cascade_blocks(known, slc, ki=rl["ki"], inner_ki=rl_in["ki"], feedforward=True,
                              anti_windup="integrate_while_slow", rate_limit=rate, name="PID"),
        "PID (no anti-windup)": cascade_blocks(known, slc, ki=rl["ki"], inner_ki=rl_in["ki"], feedforward=True,
                                               anti_windup="none", name="PID (no anti-windup)"),
    }
    inner_block = TransferFunctionBlock(known, "theta", C_in, output_limit=float(known.input_limit[0]),
                                        feedforward=True, name="loopshaped inner (theta)")
    outer_block = TransferFunctionBlock(known, "z", lead_out.controller, output_limit=slc.inner_limit,
                                        name="loopshaped outer (z)")
    blocks["loopshaped"] = models.Cascade(outer_block, inner_block, name="lead-lag (V.13)")
    loops = {"outer PD": Loop.pid(G_out, slc.outer.kp, 0, slc.outer.kd, sigma=SIGMA, name="outer PD"),
             "outer PID": Loop.pid(G_out, slc.outer.kp, rl["ki"], slc.outer.kd, sigma=SIGMA, name="outer PID"),
             "inner lead-lag": loop_in, "outer lead": loop_out}
    notes = [f"A_θ = {slc.inner_limit:.4g} rad chosen for a bandwidth separation of {SEPARATION:g}",
             "feedforward F_e = (m1 z/ℓ + m2/2) g cos θ at the measured (z, θ), from the known plant (V.13(d) hint)",
             "k_i is negative (V.12(f)); the PID integrates only while |ż| is small",
             "the PID integrates in both loops (V.12(e)'s nested PID loops): with θ_d bounded at A_θ the inner PD "
             "holds at most k_p,θ A_θ = F̃_max of unmodelled force, and a 1.5 N disturbance plus the ±5 % "
             "feedforward error exceed it"]
    return PlantDesign(a, blocks, loops, notes)


# ----------------------------------------------------------------- VI: crane
def _crane1_model(known: models.Plant) -> models.Plant:
    """VI.8's design model: one load, no friction (m2 = ℓ2 = b = 0), from the known crane or crane1."""
    if known.name == "crane1":
        return known.with_params(b=0.0)
    if known.name == "crane":
        p = known.params
        return models.get("crane1", mc=p["mc"], m=p["m1"], ell=p["ell1"], b=0.0, g=p["g"],
                          input_limit=known.input_limit)
    raise ValueError(f"the crane design needs the crane or crane1 plant, got {known.name!r}")


#: VI.8(g): outer poles with ω_n in [0.4, 0.5] rad/s and ζ in [0.3, 0.4]: the middles.
CRANE_OUTER = {"wn": 0.45, "zeta": 0.35}


def _crane(known: models.Plant) -> PlantDesign:
    model = _crane1_model(known)
    plants = cascade_plants(model, "theta", "x")
    overshoot, rise_time = 0.5, 1.0  # VI.8(c)
    zeta_in = float(-np.log(overshoot) / np.sqrt(np.pi**2 + np.log(overshoot) ** 2))
    normalized_rise = an.step_info(an.tf([1.0], [1.0, 2 * zeta_in, 1.0]))["RiseTime"]
    inner = pd_design(plants.inner, zeta=zeta_in, wn=normalized_rise / rise_time)
    K = inner.dc_gain
    outer = place_pair(K * plants.outer, CRANE_OUTER["wn"], CRANE_OUTER["zeta"])
    limit_force = float(known.input_limit[0])
    inner_limit = limit_force / abs(inner.kp)
    full = cascade_poles(plants.linearization, "theta", "x", (inner.kp, inner.kd), (outer["kp"], outer["kd"]))
    G_out = K * plants.outer
    outer_pd = Loop.pid(G_out, outer["kp"], 0.0, outer["kd"], derivative_on="error")
    rl = _integrator(G_out, outer["kp"], outer["kd"], CRANE_OUTER["zeta"], derivative_on="error")
    outer_pid = Loop.pid(G_out, outer["kp"], rl["ki"], outer["kd"], derivative_on="error")
    pair = [p for p in outer["poles"] if p.imag > 0][0]
    a = {}
    a["VI.8(b)"] = _record(**_tf(plants.inner, "plant_"), **_tf(inner.closed_loop, "closed_loop_"),
                           dropped_coupling=plants.dropped)
    a["VI.8(c)"] = _record(kp=inner.kp, kd=inner.kd, wn=inner.wn, zeta=inner.zeta, rise_time=rise_time,
                           overshoot_percent=100 * overshoot)
    a["VI.8(d)"] = _record(poles=_poles(inner.poles))
    a["VI.8(e)"] = _record(dc_gain=K)
    a["VI.8(f)"] = _record(**_tf(plants.outer, "plant_"), **_tf(outer_pd.reference_to_output(), "closed_loop_"))
    a["VI.8(g)"] = _record(kp=outer["kp"], kd=outer["kd"], wn=CRANE_OUTER["wn"], zeta=CRANE_OUTER["zeta"])
    a["VI.8(h)"] = _record(poles=_poles(outer["poles"]), wn_pair=abs(pair), zeta_pair=-pair.real / abs(pair),
                           full_poles=_poles(full))
    a["VI.10(a)"] = _record(**_errors(outer_pd), **_errors(outer_pid, "_pid"))
    a["VI.10(b)"] = _record(x_per_rad=dc_gain(outer_pd.input_disturbance_to_output()),
                            x_per_rad_pid=dc_gain(outer_pid.input_disturbance_to_output()))
    a["VI.10(c)"] = _root_locus_record(G_out, outer["kp"], outer["kd"], rl)
    # VI.13: lead inner loop (bandwidth 3 rad/s, PM 25 deg), lead outer loop (bandwidth 0.5 rad/s, ζ 0.4).
    pm_in, bw_in = 25.0, 3.0
    zeta_lead_in = damping_for_phase_margin(pm_in)
    wc_in = crossover_for_bandwidth(bw_in, zeta_lead_in)
    lead_in = lead_for_crossover(plants.inner, wc_in, pm_in)
    loop_in = Loop.unity(plants.inner, lead_in.controller, "inner lead")
    K_lead = dc_gain(loop_in.reference_to_output())
    zeta_out, bw_out = 0.4, 0.5
    wc_out, pm_out = crossover_for_bandwidth(bw_out, zeta_out), prototype_phase_margin(zeta_out)
    lead_out = lead_for_crossover(K_lead * plants.outer, wc_out, pm_out)
    loop_out = Loop.unity(K_lead * plants.outer, lead_out.controller, "outer lead")
    a["VI.13(a)"] = _record(bandwidth=bw_in, pm_target_deg=pm_in, crossover_target=wc_in, lead_zero=lead_in.zero,
                            lead_pole=lead_in.pole, gain=lead_in.gain, lead_count=lead_in.count,
                            **_tf(lead_in.controller, "C_"), **_margins(plants.inner * lead_in.controller, ""),
                            bandwidth_achieved=float(control.bandwidth(loop_in.reference_to_output())),
                            stable=loop_in.is_stable(), specs=_specs(_frequency_specs(loop_in, wc_in, pm_in, bw_in)))
    a["VI.13(b)"] = _record(inner_dc_gain=K_lead, bandwidth=bw_out, zeta=zeta_out, crossover_target=wc_out,
                            pm_target_deg=pm_out, lead_zero=lead_out.zero, lead_pole=lead_out.pole,
                            gain=lead_out.gain, **_tf(lead_out.controller, "C_"),
                            **_margins(K_lead * plants.outer * lead_out.controller, ""),
                            bandwidth_achieved=float(control.bandwidth(loop_out.reference_to_output())),
                            stable=loop_out.is_stable(),
                            specs=_specs(_frequency_specs(loop_out, wc_out, pm_out, bw_out)))
    inner_name = "theta" if known.name == "crane1" else "theta1"
    slc = SuccessiveLoopClosure(plants=plants, inner=inner, inner_dc_gain=K, outer_model=G_out,
                                outer=_PlacedPD(outer["kp"], outer["kd"]), outer_dc_gain=dc_gain(
                                    outer_pd.reference_to_output()), separation=inner.wn / CRANE_OUTER["wn"],
                                inner_limit=inner_limit, full_poles=full)
    kw = dict(inner_coordinate=inner_name, outer_derivative_on="error")
    blocks = {
        "PD": cascade_blocks(known, slc, name="PD", **kw),
        "PID": cascade_blocks(known, slc, ki=rl["ki"], name="PID", **kw),
        "PID (no anti-windup)": cascade_blocks(known, slc, ki=rl["ki"], anti_windup="none",
                                               name="PID (no anti-windup)", **kw),
    }
    inner_block = TransferFunctionBlock(known, inner_name, lead_in.controller, output_limit=limit_force,
                                        name=f"loopshaped inner ({inner_name})")
    outer_block = TransferFunctionBlock(known, "x", lead_out.controller, output_limit=inner_limit,
                                        name="loopshaped outer (x)")
    blocks["loopshaped"] = models.Cascade(outer_block, inner_block, name="lead (VI.13)")
    loops = {"outer PD": outer_pd, "outer PID": outer_pid, "inner lead": loop_in, "outer lead": loop_out}
    notes = ["designed on crane1 with b = 0 (VI.8: m2 = ℓ2 = b = 0)",
             f"VI.8(c): ζ = {zeta_in:.4f} from 50 % overshoot, ω_n from the exact 10–90 % rise time of 1 s",
             f"bound on θ_d: {inner_limit:.4g} rad, the θ error that saturates the {limit_force:g} N force",
             "outer derivative in the forward path (on the error), VI.8"]
    if known.name == "crane":
        notes.append("two-load crane: the controllers read (x, θ1, θ2) and ignore θ2; answers are crane1's")
    return PlantDesign(a, blocks, loops, notes)


@dataclass(frozen=True)
class _PlacedPD:
    """Gains of a PD placed by the root locus (duck-types PDDesign for cascade_blocks)."""

    kp: float
    kd: float


# ----------------------------------------------------------------- public
_DESIGNERS = {"arm": _arm, "pendulum": _pendulum, "satellite": _satellite, "uuv": _uuv, "ballbeam": _ballbeam,
              "crane": _crane, "crane1": _crane}


def _key(known: models.Plant) -> tuple:
    return (known.name, tuple(known.param_vector()), tuple(known.input_limit))


@functools.lru_cache(maxsize=32)
def _design_cached(key: tuple) -> PlantDesign:
    name, params, limit = key
    known = models.get(name, input_limit=np.array(limit), **dict(zip(models.get(name).params, params)))
    return _DESIGNERS[name](known)


def design(name: str, known: models.Plant | None = None) -> PlantDesign:
    """Every classical answer and controller of plant `name`, designed on `known` (default nominal)."""
    if name not in _DESIGNERS:
        raise ValueError(f"no classical design for {name!r}; valid: {', '.join(_DESIGNERS)}")
    known = models.get(name) if known is None else known
    if known.name != name:
        raise ValueError(f"known plant is {known.name!r} but the design asked for is {name!r}")
    return _design_cached(_key(known))


def answers(name: str, known: models.Plant | None = None) -> dict:
    """Homework item -> dict of named values (SI units), for every classical homework of `name`.

    For "crane" the answers are those of the single-load crane of VI.8
    designed from the crane's parameters, plus a "note".
    """
    out = copy.deepcopy(design(name, known).answers)
    out["notes"] = list(design(name, known).notes)
    if name == "crane":
        out["note"] = "VI.8–VI.13 treat the crane with one load (crane1); these are its answers"
    return out


def controllers(name: str, known: models.Plant | None = None) -> dict:
    """Label -> models.Block: "PD", "PID", "PID (no anti-windup)", "loopshaped", plus the UUV's
    "lead-lag (IV.11)" and the pendulum's "PD (zero-cancelling filter)".

    Each block reads the plant's outputs and takes the absolute tracked
    coordinate as its 1-vector reference; it saturates its command at the
    known plant's input limit (the IV.11 block at 250 N m).
    """
    return dict(design(name, known).controllers)


def frequency_responses(name: str, known: models.Plant | None = None, omega=None) -> dict:
    """Bode data of the loop gains behind the .13/.14 answers: label -> {omega, magnitude, phase_deg}.

    Each entry also carries the closed-loop response from reference to output.
    """
    omega = np.logspace(-3, 3, 600) if omega is None else np.asarray(omega, dtype=float)
    out = {}
    for label, loop in design(name, known).loops.items():
        out[label] = {"plant": an.bode_data(loop.plant, omega), "loop": an.bode_data(loop.loop_gain(), omega),
                      "closed_loop": an.bode_data(loop.reference_to_output(), omega)}
    return out
