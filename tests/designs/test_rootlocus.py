"""Root-locus gains against closed forms and python-control's root_locus_map."""

import control
import numpy as np
import pytest

from designs.analysis import Loop, as_polynomials, dc_gain, step_info, tf
from designs.rootlocus import (
    damping_ratios,
    dominant_pair,
    gain_leaving_damping,
    integrator_evans_form,
    integrator_gain,
    lag_for_static_gain,
    lead_by_angle,
    locus,
)

ARM = control.tf([66.667], [1, 0.6667, 0])


def test_damping_boundary_of_a_second_order_locus():
    # 1 + k/(s (s + a)) = 0: poles −a/2 ± j√(k − a²/4), damping (a/2)/√k, so ζ_min is reached at k = a²/(4ζ²).
    a, zeta = 3.0, 0.6
    assert gain_leaving_damping(tf([1.0], [1.0, a, 0.0]), zeta) == pytest.approx(a**2 / (4 * zeta**2), rel=1e-9)


def test_integrator_evans_form_matches_the_pid_loop():
    kp, kd, ki = 0.3, 0.085, 0.2
    L = integrator_evans_form(ARM, kp, kd)
    np.testing.assert_allclose(
        np.sort_complex(locus(L, [ki])[0]), np.sort_complex(Loop.pid(ARM, kp, ki, kd).poles()), rtol=1e-8
    )


def test_integrator_gain_sits_on_the_damping_boundary():
    kp, kd, zeta_min = 0.3037, 0.0854, 0.9 * 0.707
    out = integrator_gain(ARM, kp, kd, zeta_min, overshoot_allowance=None)
    L = integrator_evans_form(ARM, kp, kd)
    # python-control's locus: exactly ζ_min at the gain, more just below it.
    assert damping_ratios(control.root_locus_map(L, [out["ki"]]).loci[0]).min() == pytest.approx(zeta_min, abs=1e-7)
    assert damping_ratios(control.root_locus_map(L, [0.99 * out["ki"]]).loci[0]).min() > zeta_min


def test_integrator_gain_respects_the_overshoot_allowance():
    kp, kd = 0.3037, 0.0854
    out = integrator_gain(ARM, kp, kd, 0.9 * 0.707, overshoot_allowance=10.0)
    pd = control.feedback(ARM * kp, 1 + kd / kp * control.tf([1, 0], [1]))
    pid = control.feedback(ARM * control.tf([kp, out["ki"]], [1, 0]), control.tf([kd, kp, out["ki"]], [kp, out["ki"]]))
    overshoot_pd = control.step_info(pd, T=np.linspace(0, 60, 12001))["Overshoot"]
    overshoot_pid = control.step_info(pid, T=np.linspace(0, 60, 12001))["Overshoot"]
    assert 0 < out["ki"] < out["ki_damping"]
    assert overshoot_pid == pytest.approx(overshoot_pd + 10.0, abs=0.05)


def test_negative_plant_gain_gives_a_negative_integrator():
    # Ball on beam outer loop: z/θ = −g/s², k_p and k_d negative (V.12(f)).
    out = integrator_gain(tf([-9.8], [1, 0, 0]), -0.14, -0.17, 0.6, overshoot_allowance=None)
    assert out["ki"] < 0
    assert Loop.pid(tf([-9.8], [1, 0, 0]), -0.14, out["ki"], -0.17).is_stable()


def test_lead_by_angle_puts_a_pole_at_the_target():
    G = tf([0.0222], [1, 0.1111, 1.308])
    target = dominant_pair(5.0, 0.85)
    design = lead_by_angle(G, target, zero=1.5)
    n_g, d_g = as_polynomials(G)
    n_c, d_c = as_polynomials(design.lead_tf())
    roots = np.roots(np.polyadd(np.polymul(d_g, d_c), np.polymul(n_g, n_c)))
    assert np.min(np.abs(roots - target)) < 1e-8
    with_lag = lag_for_static_gain(design, G, 19.0, 0.5)
    assert dc_gain(with_lag.transfer_function() * G) == pytest.approx(19.0, rel=1e-12)
    assert step_info(Loop.unity(G, with_lag.transfer_function()).reference_to_output())[
        "SteadyStateValue"
    ] == pytest.approx(19.0 / 20.0)


def test_root_locus_bad_input():
    G = tf([1.0], [1, 1, 0])
    with pytest.raises(ValueError, match="left half plane"):
        lead_by_angle(G, dominant_pair(2, 0.7), zero=-1.0)
    with pytest.raises(ValueError, match="upper pole"):
        lead_by_angle(G, complex(-1, -1), zero=1.0)
    with pytest.raises(ValueError, match="zeta_min must be in"):
        gain_leaving_damping(G, 1.5)
    with pytest.raises(ValueError, match="already have damping below"):
        integrator_gain(ARM, 0.3, 0.0, 0.9)
