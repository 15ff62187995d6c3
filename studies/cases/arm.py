"""Case study I: the single link robot arm, θ from level, torque limited to 1 N m.

Everything chapter I decides: the text's numbers, the study table, the
classical homework (I.8–I.14) and its controllers, the state-space choices
(I.15–I.17), the MPC settings, the actuator-sizing co-design problem, the
drawing and the errata. The plant itself is declared in `models.catalog`.
"""

from __future__ import annotations

import math

import numpy as np

import models
import models.specs
from designs import analysis as an
from designs import statespace as ss
from designs.analysis import Loop, dc_gain, pid_tf, steady_state_errors
from designs.filters import TransferFunctionBlock
from designs.pid import PID, linearized_input_bound, pd_saturation
from models.specs import Specs
from mpc import Collocation, FreeTime, MPCSettings, OptimalControlProblem
from studies import drawing as d
from studies import providers
from studies.case import CaseStudy, LoopSpec, standard_scenarios
from studies.codesign_problems import ActuatorSizing, pid_at
from studies.codesign_problems import actuator_sizing as size_actuator
from studies.errata import Erratum
from studies.homework import (
    ZETA,
    ClassicalDesign,
    StateSpaceChoices,
    classical_design,
    error_record,
    loopshaped,
    loopshaping_record,
    margin_record,
    poles_record,
    record,
    root_locus_record,
    single_loop,
    single_loop_blocks,
    statespace_items_15_to_17,
    tf_record,
)
from studies.trajectories import TrajectoryProblem, TrajectorySetup

#: I.14(c): 10x better tracking and disturbance rejection below 0.007 rad/s, 10x better noise
#: attenuation above 200 rad/s, relative to the PD loop.
LOOPSHAPING = LoopSpec("I.14", "input", low_frequency=0.007, high_frequency=200.0, factor=10.0)
#: I.11: the controller sample period, s. `CASE.sample_period`: every block and the MPC of the arm.
SAMPLE_PERIOD = 0.01


# ----------------------------------------------------------------- classical homework (I.8-I.14)
def classical(known: models.Plant) -> ClassicalDesign:
    """I.8 PD by the saturation rule, I.10 integrator, I.13 frequency answers, I.14 loopshaping."""
    G = known.linearize().tf("theta", "tau")
    bound = linearized_input_bound(known, {"theta": (-np.pi, np.pi)})
    pd = pd_saturation(G, input_bound=bound["bound"], step=CASE.design_step, zeta=ZETA)
    rl, loops = single_loop(G, pd, ZETA, CASE.derivative_time_constant)
    ki = rl["ki"]
    a = {}
    a["I.8(a)"] = record(**tf_record(G, "plant_"), **tf_record(pd.closed_loop, "closed_loop_"))
    a["I.8(b)"] = record(
        max_equilibrium_input=bound["max_equilibrium_input"], bound=bound["bound"], input_limit=bound["input_limit"]
    )
    a["I.8(c)"] = record(kp=pd.kp, step=CASE.design_step)
    a["I.8(d)"] = record(wn=pd.wn, kd=pd.kd, zeta=pd.zeta)
    a["I.8(e)"] = record(poles=poles_record(pd.poles))
    a["I.10(a)"] = record(**error_record(loops["PD"]), **error_record(loops["PID"], "_pid"))
    a["I.10(b)"] = record(
        ess_input_disturbance=dc_gain(loops["PD"].input_disturbance_to_output()),
        ess_input_disturbance_pid=dc_gain(loops["PID"].input_disturbance_to_output()),
    )
    a["I.10(c)"] = record(**tf_record(loops["PID"].reference_to_output(), "closed_loop_"), ki=ki)
    a["I.10(d)"] = root_locus_record(G, pd.kp, pd.kd, rl)
    pid_impl, pd_impl = loops["PID (implemented)"], loops["PD (implemented)"]
    a["I.13"] = record(**margin_record(pd_impl.loop_gain(), "_pd"), **margin_record(pid_impl.loop_gain(), "_pid"))
    a["I.13(a)"] = record(omega=0.4, tracking_error_percent=an.percent_tracking_error_below(pid_impl, 0.4))
    a["I.13(b)"] = record(slope=5.0, ess_ramp=5.0 * steady_state_errors(pid_impl)["ess_ramp"])
    a["I.13(c)"] = record(omega=0.01, input_disturbance_percent=an.percent_input_disturbance_below(pid_impl, 0.01))
    a["I.13(d)"] = record(
        omega=100.0,
        noise_percent=an.percent_noise_above(pid_impl, 100.0),
        noise_percent_ideal_derivative=an.percent_noise_above(loops["PID"], 100.0),
    )
    # I.14: lag + low-pass + lead on the implemented PD loop, then a prefilter.
    C_pd = pid_tf(pd.kp, 0.0, pd.kd, CASE.derivative_time_constant)
    shaped, pre, T_new = loopshaped(G * C_pd, LOOPSHAPING)
    a["I.14"] = loopshaping_record(shaped, pre, T_new)
    blocks = single_loop_blocks(
        known, "theta", pd, ki, feedforward=True, sample_period=CASE.sample_period, sigma=CASE.derivative_time_constant
    )
    blocks["loopshaped"] = TransferFunctionBlock(
        known,
        "theta",
        shaped.controller * C_pd,
        prefilter=pre["prefilter"],
        sample_period=CASE.sample_period,
        output_limit=float(known.input_limit[0]),
        feedforward=True,
        name="loopshaped (I.14)",
    )
    loops["loopshaped"] = Loop(G, shaped.controller * C_pd, pre["prefilter"] * shaped.controller * C_pd, "loopshaped")
    notes = [
        f"ζ = {ZETA} (I.8(d) leaves it to the student)",
        "feedforward τ_e = m g ℓ/2 cos θ at the measured θ (I.9), from the known plant",
    ]
    return ClassicalDesign(a, blocks, loops, notes)


# ----------------------------------------------------------------- state space (I.15-I.17)
def statespace_poles(known: models.Plant, damping_ratio: float = ZETA) -> np.ndarray:
    """I.8 / I.15(c): ωₙ from k_p = (τ_max − τ_e,max) / A_θ with A_θ the 50° step; ζ = 0.707.

    Then K = (k_p, k_d) exactly (I.15(f)); ωₙ = √(k_p / J) with 1/J from the model's B.
    """
    linear = known.linearize()
    limit = float(known.input_limit[0])
    kp = (limit - abs(linear.ue[0])) / CASE.design_step
    if kp <= 0:
        raise ValueError(
            f"arm: the equilibrium torque {linear.ue[0]:.3g} N m leaves no room under the limit {limit} N m"
        )
    return ss.second_order_poles(np.sqrt(linear.B[1, 0] * kp), damping_ratio)


STATESPACE = StateSpaceChoices(
    poles=statespace_poles,
    bryson_maxima={"theta": np.deg2rad(50)},
    items=statespace_items_15_to_17("I"),
    observer_uses_integrator=True,
)


# ----------------------------------------------------------------- MPC
MPC = MPCSettings(SAMPLE_PERIOD, 50, (100.0, 0.1), 1.0, notes="50 samples = 0.5 s, several closed-loop time constants")


# ----------------------------------------------------------------- co-design: the smallest motor
def sizing_hand_design(known: models.Plant) -> PID:
    """I.8's saturation-rule PD re-derived for `known`'s torque limit (needs it above the 0.735 N m gravity torque)."""
    block = classical_design(CASE, known).controllers["PD"]
    assert isinstance(block, PID)  # `classical` builds the arm's PD as one PID block
    return block


def sizing_start(known: models.Plant) -> models.Block:
    """The hand PD at the text's 1 N m, saturating at `known`'s limit (the re-tuning start)."""
    text = known.with_input_limit(1.0)
    return pid_at(sizing_hand_design(text), known, float(known.input_limit[0]))


#: The arm's motor requirement (the text gives no time-domain spec for the arm): the 50° step 90 % done
#: by 0.6 s and staying there, overshoot at most 5 %; judged on a 3 s run.
SIZING_SPECS = Specs(max_rise_time_s=0.6, max_overshoot_pct=5.0)
SIZING = ActuatorSizing(
    text_limit=1.0,
    high=1.2,
    hand_range=(0.75, 1.2),
    duration=3.0,
    parameter="torque limit",
    hand_design=sizing_hand_design,
    retune_start=sizing_start,
    specs=SIZING_SPECS,
    specs_origin="a stated requirement (the text gives none for the arm): 90 % of the 50° "
    "step by 0.6 s and staying, overshoot ≤ 5 %",
)


def actuator_sizing(**options):
    """The smallest torque limit meeting `SIZING_SPECS`, three ways; `options` are the keywords of
    `studies.codesign_problems.actuator_sizing` (rel_tol, methods, the tunings' SolveOptions)."""
    return size_actuator(CASE, SIZING, **options)


# ----------------------------------------------------------------- trajectory optimization: point to point
def point_to_point_time(plant: models.Plant, quick: bool, solved: dict) -> TrajectorySetup:
    """The text's 50° step from level, rest to rest, in the least time T (free in [0.05, 5] s) within 1 N m."""
    ocp = OptimalControlProblem(plant, FreeTime(0.05, 5.0, 1.0))
    ocp.minimize(ocp.final_time)
    ocp.subject_to(ocp.at_start(ocp.state) == [0.0, 0.0])
    ocp.subject_to(ocp.at_end(ocp.state) == [CASE.step, 0.0])
    return TrajectorySetup(
        ocp,
        Collocation(intervals=20 if quick else 40),
        {},
        "T (s)",
        f"From level at rest to θ = {np.degrees(CASE.step):g} deg at rest (the text's step), |τ| ≤ 1 N m, in the "
        "least time; the gravity torque m g ℓ/2 cos θ (0.735 N m at level) leaves 0.26 N m to accelerate and "
        "1.7 N m to brake. Bang-bang with one switch; the held input puts the switch on a mesh point, so T is "
        "within about one interval of the continuous-time answer.",
    )


TRAJECTORIES = (
    TrajectoryProblem(
        "point_to_point_time",
        "50° point to point, minimum time",
        point_to_point_time,
        report={"dtheta": "rate"},
        compare_step=True,
    ),
)


# ----------------------------------------------------------------- drawing
def draw(p: dict, s: dict, r: float) -> list:
    """The rod from its pivot at angle θ, the reference angle dashed."""
    ell, th = p["ell"], s["theta"]
    tip = (ell * math.cos(th), ell * math.sin(th))
    return [
        d.polygon([(-0.15 * ell, -0.3 * ell), (0.15 * ell, -0.3 * ell), (0, 0)], fill=d.GROUND, stroke=d.GROUND),
        d.line([(0, 0), (ell * 1.1 * math.cos(r), ell * 1.1 * math.sin(r))], d.REFERENCE, 1.5, True),
        d.line([(0, 0), tip], d.BODY, 8),
        d.circle((0, 0), 0.04 * ell, d.ACCENT),
    ]


# ----------------------------------------------------------------- errata
ERRATA = (
    Erratum(
        "hint",
        "I.15 (arm)",
        (
            "A = [[0, 1], [0, −0.667]], B = (0, 66.667)",
            "the same (−0.6667, 66.667)",
            "agrees to the printed digits",
            "—",
        ),
    ),
    Erratum(
        "text",
        "I.15(c)",
        (
            "roots of s² + 2ζωₙ + ωₙ²",
            "s² + 2ζωₙ s + ωₙ²",
        ),
    ),
    Erratum(
        "text",
        "I.11(c), II.11, III.11, IV.12, V.12, VI.11",
        (
            '"dirty derivative gain τ = 0.05"',
            "0.05 s is the bandwidth time constant σ of the dirty derivative s/(σ s + 1), not a gain",
        ),
        also=("pendulum", "satellite", "uuv", "ballbeam", "crane"),
    ),
    Erratum(
        "design",
        "I.15 hint",
        (
            "feed forward τ_e = (m g ℓ / 2) cos θᵈ with I.8's K = (k_p, k_d)",
            "about the 50° reference the gravity stiffness (m g ℓ / 2) sin 50° = 0.563 N m/rad exceeds k_p = 0.304 "
            "N m/rad, so the rest point at θᵈ is unstable and the arm stalls near 0°. The equilibrium torque must "
            "be cancelled at the measured angle (what our blocks do).",
        ),
    ),
)


#: Specs of every scenario. The text gives the arm none: the I.8 design's second-order target (ζ = 0.707,
#: ω_n = 4.5 rad/s, I.8(d)) settles in 4/(ζ ω_n) = 1.3 s with 4.3 % overshoot. We ask 1.5 times that
#: settling time for the saturating 50° step (2 s), 10 % overshoot, and a steady-state error within the
#: 2 % settling band.
SPECS = {
    "*": models.specs.Specs(
        max_settling_time_s=2.0,
        max_overshoot_pct=10.0,
        max_ss_error_pct=2.0,
        source="stated: 1.5 x the I.8(d) design's settling time, 10 % overshoot, 2 % error",
    )
}

CASE = CaseStudy(
    plant="arm",
    numeral="I",
    tracked="theta",
    design_step=np.deg2rad(50),
    step=np.deg2rad(50),
    input_disturbance=0.2,
    sample_period=SAMPLE_PERIOD,
    duration=5.0,
    source="I.8(c) step 50 deg; I.17(e) disturbance 0.2 N m; I.11 Ts = 0.01 s",
    tracked_unit="rad",
    input_unit="N m",
    # I.8(c): 50 deg, sized so that the PD just saturates; I.17(e): 0.2 N m; noise in rad, the text gives no
    # sensor: an encoder-scale 0.06 deg; I.11(a): m and ell known to 5 %.
    scenarios=standard_scenarios({"theta": 1e-3}),
    providers=providers.STANDARD,
    answer_providers=providers.STANDARD_ANSWERS,
    loops=(LOOPSHAPING,),
    classical=classical,
    statespace=STATESPACE,
    mpc=MPC,
    codesign={"arm": actuator_sizing},
    specs=SPECS,
    drawing=draw,
    errata=ERRATA,
    trajectories=TRAJECTORIES,
)
