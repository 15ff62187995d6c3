"""Cascade transfer functions and successive loop closure against hand-derived closed forms."""

import casadi as ca
import control
import numpy as np
import pytest

import models
from designs.analysis import as_polynomials, tf
from designs.loops import (
    FilteredBlock,
    cascade_blocks,
    cascade_plants,
    cascade_poles,
    low_frequency_model,
    place_pair,
    successive_loop_closure,
    zero_cancelling_design,
    zero_cancelling_filter,
)
from designs.pid import PID, pd_design


def _same(G, num, den):
    n, d = as_polynomials(G)
    n, d = n / d[0], d / d[0]
    num, den = np.asarray(num, float) / den[0], np.asarray(den, float) / den[0]
    np.testing.assert_allclose(np.pad(n, (len(num) - len(n), 0)), num, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(d, den, rtol=1e-9, atol=1e-12)


def test_pendulum_cascade():
    # (m1+m2) z̈ + m1 ℓ θ̈ = F − b ż, ℓ θ̈ + z̈ = g θ: θ/F = −1/(m2 ℓ)/(s² − (m1+m2) g/(m2 ℓ)), z/θ = (g − ℓ s²)/s².
    p = models.get("pendulum")
    m1, m2, ell, g, b = (p.params[k] for k in ("m1", "m2", "ell", "g", "b"))
    c = cascade_plants(p, "theta", "z")
    _same(c.inner, [-1 / (m2 * ell)], [1, 0, -(m1 + m2) * g / (m2 * ell)])
    _same(c.outer, [-ell, 0, g], [1, 0, 0])
    assert c.dropped == {"dz": pytest.approx(b / (m2 * ell))}


def test_satellite_cascade():
    # J_s θ̈ = τ − b(θ̇ − φ̇) − k(θ − φ), J_p φ̈ = −b(φ̇ − θ̇) − k(φ − θ).
    p = models.get("satellite")
    Js, Jp, k, b = (p.params[n] for n in ("Js", "Jp", "k", "b"))
    c = cascade_plants(p, "theta", "phi")
    _same(c.inner, [1 / Js], [1, b / Js, k / Js])
    _same(c.outer, [b / Jp, k / Jp], [1, b / Jp, k / Jp])
    assert c.dropped == {"phi": pytest.approx(k / Js), "dphi": pytest.approx(b / Js)}


def test_ball_on_beam_and_crane_cascades():
    bb = models.get("ballbeam")
    m1, m2, ell, g = (bb.params[k] for k in ("m1", "m2", "ell", "g"))
    c = cascade_plants(bb, "theta", "z")
    # V.6(c): θ/F = ℓ/(m2 ℓ²/3 + m1 z_e²)/s² with z_e = ℓ/2; z/θ = −g/s².
    _same(c.inner, [ell / (m2 * ell**2 / 3 + m1 * (ell / 2) ** 2)], [1, 0, 0])
    _same(c.outer, [-g], [1, 0, 0])
    cr = models.get("crane1")
    mc, m, ell, g = (cr.params[k] for k in ("mc", "m", "ell", "g"))
    c = cascade_plants(cr, "theta", "x")
    _same(c.inner, [-1 / (mc * ell)], [1, 0, (mc + m) * g / (mc * ell)])
    _same(c.outer, [-ell, 0, -g], [1, 0, 0])


def test_place_pair_on_a_double_integrator():
    # 1 + b/s² (k_p + k_d s) = 0  ->  k_p = ω_n²/b, k_d = 2ζω_n/b.
    b, wn, zeta = 2.5, 1.3, 0.4
    out = place_pair(tf([b], [1, 0, 0]), wn, zeta)
    assert out["kp"] == pytest.approx(wn**2 / b) and out["kd"] == pytest.approx(2 * zeta * wn / b)
    np.testing.assert_allclose(np.sort_complex(out["poles"]), np.sort_complex(np.roots([1, 2 * zeta * wn, wn**2])))


def test_zero_cancelling_filter_makes_the_pendulum_outer_loop_second_order():
    p = models.get("pendulum")
    ell, g = p.params["ell"], p.params["g"]
    c, K = cascade_plants(p, "theta", "z"), 1.35
    F = zero_cancelling_filter(c.outer, K)
    root = np.sqrt(g / ell)
    _same(F, [root / K], [1, root])
    # K F (g − ℓ s²)/s² = (root/(s + root)) (−ℓ)(s − root)(s + root)/s²: (s + root) divides out exactly,
    # leaving (g − √(g ℓ) s)/s², on which a PD matches a second-order loop with DC gain 1.
    num, den = as_polynomials(K * F * c.outer)
    num, num_rest = np.polydiv(num, [1, root])
    den, den_rest = np.polydiv(den, [1, root])
    assert np.max(np.abs(num_rest)) < 1e-9 and np.max(np.abs(den_rest)) < 1e-9
    _same(tf(num, den), [-np.sqrt(g * ell), g], [1, 0, 0])
    design = pd_design(tf(num, den), zeta=0.7, wn=0.8)
    assert design.dc_gain == pytest.approx(1.0)
    np.testing.assert_allclose(np.sort_complex(design.poles), np.sort_complex(np.roots([1, 1.12, 0.64])), rtol=1e-9)


def test_ball_on_beam_cascade_poles_equal_the_hand_derived_polynomial():
    bb = models.get("ballbeam")
    lin = bb.linearize()
    b, g = 2.651934, 9.8
    kpi, kdi, kpo, kdo = 51.0, 6.2, -0.14, -0.17
    q = ca.SX.sym("q", 2)
    jac = ca.Function("j", [q], [ca.jacobian(bb.casadi_equilibrium_input(q, bb.param_vector()), q)])
    grad = np.asarray(jac(lin.xe[:2])).ravel()
    # With the feedforward cancelling the ball's weight: s²(s² + b k_di s + b k_pi) − g b k_pi (k_po + k_do s) = 0.
    char = np.polysub(np.polymul([1, 0, 0], [1, b * kdi, b * kpi]), np.polymul([g * b * kpi], [kdo, kpo]))
    np.testing.assert_allclose(
        np.sort_complex(cascade_poles(lin, "theta", "z", (kpi, kdi), (kpo, kdo), feedforward_gradient=grad)),
        np.sort_complex(np.roots(char)),
        rtol=1e-5,
    )


def test_successive_loop_closure_meets_its_rules():
    p = models.get("pendulum")
    slc = successive_loop_closure(
        p, "theta", "z", inner_bound=5.0, outer_step=2.0, separation=10.0, outer_model="low_frequency"
    )
    a_th = slc.inner_limit
    assert slc.inner.kp == pytest.approx(-5.0 / a_th)  # F̃ just saturates on a step A_θ
    assert slc.outer.kp == pytest.approx(a_th / 2.0)  # θ_d just saturates on a 2 m step
    assert slc.inner.wn / slc.outer.wn == pytest.approx(10.0)  # bandwidth separation
    K = 2 * abs(slc.inner.kp) / (2 * abs(slc.inner.kp) - 24.5)  # −2 k_p/(−24.5 − 2 k_p)
    assert slc.inner_dc_gain == pytest.approx(K)
    assert slc.outer.wn == pytest.approx(np.sqrt(K * 9.8 * slc.outer.kp))
    assert np.all(slc.full_poles.real < 0)
    _same(low_frequency_model(slc.plants.outer), [9.8], [1, 0, 0])
    with pytest.raises(ValueError, match="bandwidth separation of 1e\\+06"):
        successive_loop_closure(
            p, "theta", "z", inner_bound=5.0, outer_step=2.0, separation=1e6, outer_model="low_frequency"
        )
    with pytest.raises(ValueError, match="no coordinate 'x'"):
        cascade_plants(p, "theta", "x")


def test_zero_cancelling_design_tracks_on_the_nonlinear_pendulum():
    p = models.get("pendulum")
    slc = successive_loop_closure(p, "theta", "z", inner_bound=5.0, outer_step=2.0, outer_model="low_frequency")
    zc = zero_cancelling_design(slc)
    assert zc.outer_dc_gain == pytest.approx(1.0) and zc.separation == pytest.approx(10.0)
    assert np.all(zc.full_poles.real < 0) and zc.full_poles.size == 5  # the filter adds one state
    res = models.simulate_closed_loop(
        p, cascade_blocks(p, zc, sample_period=0.01, sigma=0.05), models.signals.step(2.0, 0.5), 30.0
    )
    assert res.state("z")[-1] == pytest.approx(2.0, abs=1e-4)
    assert np.max(np.abs(res.u)) <= 5.0


def test_filtered_block_equals_tustin_of_the_filter_after_the_block():
    arm = models.get("arm")
    inner = PID(arm, "theta", kp=2.0, kd=0.0, derivative_on="error", sample_period=0.01, sigma=0.05)
    F = tf([3.0], [1.0, 3.0])
    block = FilteredBlock(inner, F)
    n, xc, out = 200, np.zeros(block.n_state), []
    for _ in range(n):
        xc, u = block.step(xc, [0.0], [1.0])
        out.append(u[0])
    ref = control.forced_response(control.c2d(2.0 * F, 0.01, "tustin"), np.arange(n) * 0.01, np.ones(n)).outputs
    np.testing.assert_allclose(out, ref, atol=1e-9)
    assert set(block.gains) == {"kp", "kd", "filter_num", "filter_den"}
