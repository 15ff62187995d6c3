"""The named steps of the case files' classical designs, each called on its own and checked with
python-control's own interconnections (feedback, margins, step_info, poles)."""

import control
import numpy as np
import pytest

import models
from designs.loops import cascade_plants, successive_loop_closure
from designs.pid import linearized_input_bound
from studies.cases import ballbeam, crane, pendulum, satellite, uuv


def _damping(poles):
    return -np.real(poles) / np.abs(poles)


def test_crane_successive_loops_meet_VI8_rules():
    plants = cascade_plants(crane.one_load_model(models.get("crane1")), "theta", "x")
    slc, answers = crane.successive_loops(plants, 5000.0)
    assert sorted(answers) == [f"VI.8({c})" for c in "bcdefgh"]
    # Inner loop: 50 % overshoot and an exact 1 s rise time, the PD on θ (derivative on the measurement).
    kp, kd = slc.inner.kp, slc.inner.kd
    inner = control.feedback(plants.inner * kp, control.tf([kd / kp, 1.0], [1]))  # u = kp (r − θ) − kd θ̇
    t = np.linspace(0, 20, 200001)
    info = control.step_info(inner, T=t)
    assert info["Overshoot"] == pytest.approx(50.0, rel=1e-6)
    # To 1e-3 s: the design reads the normalized rise time off `designs.analysis.step_info`'s 20 001-point grid.
    assert info["RiseTime"] == pytest.approx(1.0, abs=1e-3)
    # Outer loop: its pair at ω_n = 0.45 rad/s, ζ = 0.35 on K_DC·G_x, the derivative on the error.
    outer = control.feedback(slc.outer_model * control.tf([slc.outer.kd, slc.outer.kp], [1]), 1)
    pair = [p for p in control.poles(outer) if p.imag > 1e-9]
    assert any(abs(abs(p) - 0.45) < 1e-6 and abs(_damping(p) - 0.35) < 1e-6 for p in pair)
    assert slc.inner_limit == pytest.approx(5000.0 / abs(slc.inner.kp))


def test_ballbeam_inner_lead_lag_holds_the_angle_under_the_disturbance():
    known = models.get("ballbeam")
    G_in = cascade_plants(known, "theta", "z").inner
    C_in, loop, answers = ballbeam.inner_lead_lag(G_in)
    assert set(answers) == {"V.13(a)", "V.13(b)"} and loop.is_stable()
    # θ per newton of input disturbance at DC: G/(1 + G C).
    angle = 13.2 * abs(control.dcgain(control.feedback(G_in, C_in)))
    assert angle == pytest.approx(answers["V.13(b)"]["angle_error_lead_lag"], rel=1e-9)
    assert angle < 0.0175


def test_uuv_loopshaping_crosses_at_2_rad_s_with_its_phase_margin():
    known = models.get("uuv")
    G = known.linearize().tf("phi", "tau")
    C_e, loop, answers = uuv.loopshaping(known, G)
    assert sorted(answers) == [f"IV.13({c})" for c in "abcde"]
    _, pm, _, _, wc, _ = control.stability_margins(G * C_e)
    assert wc == pytest.approx(2.0, rel=0.05) and pm >= 60.0 - 1e-6
    assert np.all(np.real(control.poles(control.feedback(G * C_e, 1))) < 0)


def test_satellite_integrators_place_the_outer_pd_a_decade_below_the_inner_loop():
    known = models.get("satellite")
    slc = successive_loop_closure(
        known,
        "theta",
        "phi",
        inner_bound=linearized_input_bound(known, {})["bound"],
        outer_step=satellite.CASE.design_step,
        separation=10.0,
        zeta_inner=0.707,
        outer_derivative=False,
    )
    outer_pd, rl_in, rl_out, answers = satellite.integrators(slc)
    assert sorted(answers) == [f"III.10({c})" for c in "abcde"]
    G_out = slc.inner_dc_gain * slc.plants.outer
    closed = control.feedback(G_out * control.tf([outer_pd.kd, outer_pd.kp], [1]), 1)
    poles = control.poles(closed)
    assert np.allclose(np.abs(poles), slc.inner.wn / 10, rtol=1e-9)
    assert np.allclose(_damping(poles), 0.707, rtol=1e-9)
    assert rl_in["ki"] > 0 and rl_out["ki"] > 0


def test_pendulum_outer_plant_is_the_inner_closed_loop_times_the_outer_plant():
    known = models.get("pendulum")
    slc = successive_loop_closure(
        known,
        "theta",
        "z",
        inner_bound=linearized_input_bound(known, {"z": (-1.0, 1.0), "theta": (-0.5, 0.5)})["bound"],
        outer_step=pendulum.CASE.design_step,
        separation=10.0,
        zeta_inner=0.707,
        zeta_outer=0.707,
        outer_model="low_frequency",
    )
    loops, exact_outer, answers = pendulum.implemented_loops(slc, 0.0)
    assert list(loops) == ["inner PD", "inner PID", "outer PD"] and "II.13(e)" in answers
    # Reference to θ of the implemented inner PD (derivative on the measurement, σ the case's), then θ -> z.
    s, sigma = control.tf([1, 0], [1]), pendulum.CASE.derivative_time_constant
    kp, kd = slc.inner.kp, slc.inner.kd
    inner = control.feedback(slc.plants.inner * kp, 1 + kd * s / (sigma * s + 1) / kp)
    omega = np.logspace(-2, 3, 50)
    expected = control.frequency_response(inner * slc.plants.outer, omega).complex.ravel()
    found = control.frequency_response(exact_outer, omega).complex.ravel()
    np.testing.assert_allclose(found, expected, rtol=1e-8)
