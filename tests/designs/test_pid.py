"""PD design by the saturation rule, and the discrete PID block, against closed forms and Tustin."""

import control
import numpy as np
import pytest

import models
from designs.analysis import pid_tf
from designs.pid import PID, linearized_input_bound, pd_design, pd_saturation

TS, SIGMA = 0.01, 0.05


@pytest.fixture(scope="module")
def arm():
    return models.get("arm")


def test_arm_saturation_rule_closed_form(arm):
    m, ell, g, b = (arm.params[k] for k in ("m", "ell", "g", "b"))
    bound = linearized_input_bound(arm, {"theta": (-np.pi, np.pi)})
    assert bound["max_equilibrium_input"] == pytest.approx(m * g * ell / 2, rel=1e-9)
    assert bound["bound"] == pytest.approx(1.0 - m * g * ell / 2, rel=1e-9)
    step, zeta = np.deg2rad(50), 0.707
    design = pd_saturation(arm.linearize().tf("theta", "tau"), input_bound=bound["bound"], step=step, zeta=zeta)
    # θ/τ = (3/(m ℓ²))/(s² + 3b/(m ℓ²) s): ω_n² = b0 k_p, 2ζω_n = a1 + b0 k_d.
    b0, a1 = 3 / (m * ell**2), 3 * b / (m * ell**2)
    kp = (1.0 - m * g * ell / 2) / step
    wn = np.sqrt(b0 * kp)
    assert design.kp == pytest.approx(kp, rel=1e-9)
    assert design.wn == pytest.approx(wn, rel=1e-9)
    assert design.kd == pytest.approx((2 * zeta * wn - a1) / b0, rel=1e-9)
    expected = np.array([-zeta * wn - 1j * wn * np.sqrt(1 - zeta**2), -zeta * wn + 1j * wn * np.sqrt(1 - zeta**2)])
    np.testing.assert_allclose(design.poles, expected, rtol=1e-9)
    assert design.dc_gain == pytest.approx(1.0)


def test_ball_on_beam_bound_uses_the_ball_at_the_end():
    bb = models.get("ballbeam")
    m1, m2, g, ell = (bb.params[k] for k in ("m1", "m2", "g", "ell"))
    bound = linearized_input_bound(bb, {"z": (0.0, ell)})
    assert bound["max_equilibrium_input"] == pytest.approx((m1 + m2 / 2) * g, rel=1e-9)
    assert bound["at"]["z"] == pytest.approx(ell)


def test_pd_with_a_plant_zero_places_the_poles():
    # G = (n1 s + n0)/(s² + a1 s + a0): closed loop (1 + n1 kd) s² + (a1 + n1 kp + n0 kd) s + (a0 + n0 kp).
    n1, n0, a1, a0 = 0.05, 0.15, 0.05, 0.15
    wn, zeta = 0.4, 0.707
    design = pd_design(control.tf([n1, n0], [1, a1, a0]), zeta=zeta, wn=wn)
    char = [1 + n1 * design.kd, a1 + n1 * design.kp + n0 * design.kd, a0 + n0 * design.kp]
    np.testing.assert_allclose(
        np.sort_complex(np.roots(char)), np.sort_complex(np.roots([1, 2 * zeta * wn, wn**2])), rtol=1e-9
    )


def test_saturation_rule_that_cannot_stabilize_is_refused():
    # Pendulum inner loop −2/(s² − 24.5): |k_p| must exceed 12.25.
    with pytest.raises(ValueError, match="does not stabilize.*kp < -12.25"):
        pd_saturation(control.tf([-2.0], [1, 0, -24.5]), input_bound=5.0, step=1.0, zeta=0.7)
    with pytest.raises(ValueError, match="exactly one of kp"):
        pd_design(control.tf([1.0], [1, 0, 0]), zeta=0.7)
    with pytest.raises(ValueError, match="step must be a finite number > 0"):
        pd_saturation(control.tf([1.0], [1, 0, 0]), input_bound=1.0, step=-1.0, zeta=0.7)


def _run(block, ys, rs, xc0=None):
    xc = np.zeros(block.n_state) if xc0 is None else xc0
    out = []
    for y, r in zip(ys, rs):
        xc, u = block.step(xc, [y], [r])
        out.append(u[0])
    return np.array(out)


def _tustin_step(G, n):
    disc = control.c2d(G, TS, "tustin")
    return control.forced_response(disc, np.arange(n) * TS, np.ones(n)).outputs


def test_pid_on_the_error_equals_tustin_of_its_transfer_function(arm):
    n = 300
    block = PID(
        arm, "theta", kp=0.3, kd=0.08, ki=0.2, derivative_on="error", anti_windup="none", sample_period=TS, sigma=SIGMA
    )
    np.testing.assert_allclose(
        _run(block, np.zeros(n), np.ones(n)), _tustin_step(pid_tf(0.3, 0.2, 0.08, 0.05), n), atol=1e-9
    )


def test_pid_on_the_measurement_equals_tustin_of_the_feedback_path(arm):
    n = 300
    block = PID(arm, "theta", kp=0.3, kd=0.08, ki=0.2, anti_windup="none", sample_period=TS, sigma=SIGMA)
    np.testing.assert_allclose(
        _run(block, np.ones(n), np.zeros(n)), -_tustin_step(pid_tf(0.3, 0.2, 0.08, 0.05), n), atol=1e-9
    )


def test_feedforward_is_the_known_gravity_torque(arm):
    block = PID(arm, "theta", kp=0.3, kd=0.08, feedforward=True, output_limit=1.0, sample_period=TS, sigma=SIGMA)
    theta = 0.4
    _, u = block.step(block.initial_state([theta], [theta]), [theta], [theta])
    m, ell, g = (arm.params[k] for k in ("m", "ell", "g"))
    assert u[0] == pytest.approx(m * g * ell / 2 * np.cos(theta), rel=1e-12)


def test_back_calculation_holds_the_integral_at_the_saturation(arm):
    # PI, kp = ki = 1, limit 0.5, error 1. Trapezoid first, I' = I + Ts; then back-calculation
    # I'' = I' + Ts/ki (0.5 − (1 + I')). At the fixed point I'' = I: 0 = Ts (1 − 0.5 − I − Ts), I = 0.5 − Ts.
    n = 3000
    kw = dict(kp=1.0, kd=0.0, ki=1.0, output_limit=0.5, derivative_on="error", sample_period=TS, sigma=SIGMA)
    with_aw = PID(arm, "theta", anti_windup="back_calculation", **kw)
    plain = PID(arm, "theta", anti_windup="none", **kw)
    x_aw = x_plain = np.array([1.0, 0.0, 0.0, 0.0])
    for _ in range(n):
        x_aw, u_aw = with_aw.step(x_aw, [0.0], [1.0])
        x_plain, _ = plain.step(x_plain, [0.0], [1.0])
    assert u_aw[0] == 0.5
    assert x_aw[3] == pytest.approx(0.5 - TS, abs=1e-9)
    assert x_plain[3] == pytest.approx(n * TS, rel=1e-9)


def test_integrate_while_slow_freezes_during_fast_motion(arm):
    block = PID(
        arm,
        "theta",
        kp=1.0,
        kd=0.0,
        ki=-1.0,
        anti_windup="integrate_while_slow",
        rate_limit=0.1,
        sample_period=TS,
        sigma=SIGMA,
    )
    xc = block.initial_state([0.0], [1.0])
    xc, _ = block.step(xc, [0.5], [1.0])  # |ẏ| ≈ 0.5/(Ts + 2σ)·2 ≫ 0.1: frozen
    assert xc[3] == 0.0
    xc, _ = block.step(np.array([0.5, 0.5, 0.0, 0.0]), [0.5], [1.0])  # at rest: integrates
    assert xc[3] == pytest.approx(TS * 0.5)


def test_limit_about_a_coordinate():
    sat = models.get("satellite")
    block = PID(sat, "phi", kp=10.0, kd=0.0, output_limit=0.1, limit_about="theta", sample_period=TS, sigma=SIGMA)
    # y = (θ, φ − θ) = (0.3, 0.2): φ = 0.5, command 10 (1 − 0.5) = 5 is bounded to θ + 0.1.
    _, u = block.step(block.initial_state([0.3, 0.2], [1.0]), [0.3, 0.2], [1.0])
    assert u[0] == pytest.approx(0.4)


def test_pid_block_rejects_bad_settings(arm):
    with pytest.raises(ValueError, match="sample_period"):
        PID(arm, "theta", kp=1.0, sample_period=-0.01, sigma=SIGMA)
    with pytest.raises(ValueError, match="needs an output_limit"):
        PID(arm, "theta", kp=1.0, ki=1.0, sample_period=TS, sigma=SIGMA)
    with pytest.raises(ValueError, match="needs a rate_limit"):
        PID(arm, "theta", kp=1.0, ki=1.0, anti_windup="integrate_while_slow", sample_period=TS, sigma=SIGMA)
    with pytest.raises(ValueError, match="no coordinate 'phi'"):
        PID(arm, "phi", kp=1.0, sample_period=TS, sigma=SIGMA)


def test_sample_period_and_sigma_have_no_library_default(arm):
    # Each block runs at its case's sample period with its case's σ: neither may be left out.
    with pytest.raises(TypeError, match="sample_period"):
        PID(arm, "theta", kp=1.0, sigma=SIGMA)
    with pytest.raises(TypeError, match="sigma"):
        PID(arm, "theta", kp=1.0, sample_period=TS)


def test_with_gains_equals_a_block_built_with_them(arm):
    base = PID(arm, "theta", kp=0.3, kd=0.08, ki=0.2, output_limit=1.0, feedforward=True, sample_period=TS, sigma=SIGMA)
    fresh = PID(
        arm, "theta", kp=0.6, kd=0.05, ki=0.1, output_limit=1.0, feedforward=True, sample_period=TS, sigma=SIGMA
    )
    changed = base.with_gains(kp=0.6, kd=0.05, ki=0.1)
    xc = base.initial_state([0.1], [0.5])
    for y in (0.1, 0.12, 0.2):
        (xa, ua), (xb, ub) = changed.step(xc, [y], [0.5]), fresh.step(xc, [y], [0.5])
        np.testing.assert_allclose(ua, ub, rtol=1e-14)
        np.testing.assert_allclose(xa, xb, rtol=1e-14)
        xc = xa


def test_closed_loop_cost_gradient_in_the_classical_gains(arm):
    import casadi as ca

    # Gains of the size of the arm's I.8/I.10 design (k_p = 0.304 N m/rad).
    block = PID(
        arm, "theta", kp=0.304, kd=0.0297, ki=0.45, output_limit=1.0, feedforward=True, sample_period=TS, sigma=SIGMA
    )
    n = 150
    run = models.closed_loop_function(arm, block, n)
    gains = ca.MX.sym("g", block.gain_vector().size)
    x0 = np.zeros(2)
    X = run(
        x0,
        block.initial_state(arm.output(x0), [0.3]),
        0.3 * np.ones((1, n)),
        np.zeros((1, n)),
        np.zeros((1, n)),
        arm.param_vector(),
        gains,
    )[0]
    cost = ca.Function("cost", [gains], [ca.sumsqr(X[0, :] - 0.3) * TS])
    grad = ca.Function("grad", [gains], [ca.gradient(cost(gains), gains)])
    g0 = block.gain_vector()
    h = 1e-6
    fd = [(float(cost(g0 + h * e)) - float(cost(g0 - h * e))) / (2 * h) for e in np.eye(g0.size)]
    np.testing.assert_allclose(np.asarray(grad(g0)).ravel(), fd, rtol=1e-4)
