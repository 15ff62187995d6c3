"""Loop analysis of blocks against python-control's own discretization and interconnection."""

import casadi as ca
import control
import numpy as np
import pytest

import models
from studies import loops

TS = 0.01


class Proportional(models.Block):
    """u = k (r − y[index]) + bias (a test fixture)."""

    def __init__(self, k, index=0, n_measured=1, bias=0.0):
        self.index, self.bias = index, bias
        super().__init__(sample_period=TS, n_state=0, n_measured=n_measured, n_reference=1, n_input=1, gains={"k": k})

    def expr(self, xc, y, r, g):
        return xc, g["k"] * (r[0] - y[self.index]) + self.bias


class StateFeedback(models.Block):
    def __init__(self, K):
        super().__init__(
            sample_period=TS,
            n_state=0,
            n_measured=len(K),
            n_reference=1,
            n_input=1,
            gains={"K": np.asarray(K, dtype=float)},
            measures="state",
        )

    def expr(self, xc, y, r, g):
        return xc, -ca.dot(g["K"], y)


class FilteredPD(models.Block):
    """A block with a state, reading the state: u = k w − kd θ̇ with w+ = a w + (1 − a)(r − θ)."""

    def __init__(self, k, kd, a):
        super().__init__(
            sample_period=TS,
            n_state=1,
            n_measured=2,
            n_reference=1,
            n_input=1,
            gains={"k": k, "kd": kd, "a": a},
            measures="state",
        )

    def expr(self, xc, y, r, g):
        return g["a"] * xc + (1 - g["a"]) * (r[0] - y[0]), g["k"] * xc[0] - g["kd"] * y[1]


OMEGA = np.logspace(-2, 2.4, 25)


def discrete_plant(plant, x, u):
    return control.c2d(plant.linearize(x, u, check=False).ss(), TS, method="zoh")


def test_input_loop_of_a_filtered_pd_equals_controller_times_plant():
    arm = models.get("arm")
    block = FilteredPD(2.0, 0.3, 0.8)
    point = loops.rest_point(arm, block, 0.3, 10.0)
    assert point.residual < 1e-6
    # At rest the filter state equals the error and k e balances gravity: k (r − θ) = m g ℓ / 2 cos θ.
    theta = point.x[0]
    assert 2.0 * (0.3 - theta) == pytest.approx(0.5 * 9.8 * 0.3 / 2 * np.cos(theta), rel=1e-6)
    L = loops.loop(arm, block, point)
    plant = control.c2d(control.ss(*_state_output(arm, point)), TS, method="zoh")  # τ -> (θ, θ̇)
    # Loop broken at τ: L = C_f(z) θ/τ + kd θ̇/τ with C_f = k (1 − a) / (z − a).
    expected = control.tf([2.0 * 0.2], [1.0, -0.8], TS) * plant[0, 0] + 0.3 * plant[1, 0]
    np.testing.assert_allclose(
        L.frequency_response(OMEGA), np.squeeze(expected(np.exp(1j * OMEGA * TS))), rtol=1e-6
    )  # python-control's transfer-function products round off


def _state_output(plant, point):
    lin = plant.linearize(point.x, point.u, check=False)
    return lin.A, lin.B, np.eye(plant.nx), np.zeros((plant.nx, 1))


def test_closed_loop_poles_of_state_feedback_are_those_of_the_discretized_plant():
    sat = models.get("satellite")
    K = np.array([2.0, 1.0, 6.0, 0.5])
    xe, ue = sat.equilibrium()
    point = loops.OperatingPoint(xe, ue, np.zeros(0), np.zeros(1), 0.0)
    L = loops.loop(sat, StateFeedback(K), point)
    plant = discrete_plant(sat, xe, ue)
    expected = np.linalg.eigvals(plant.A - plant.B @ K[None])
    np.testing.assert_allclose(np.sort_complex(L.closed_loop_poles()), np.sort_complex(expected), atol=1e-9)
    s = L.s_plane(expected)
    np.testing.assert_allclose(np.exp(s * TS), expected, rtol=1e-12)


def test_outer_loop_of_a_cascade_matches_python_control_feedback():
    pend = models.get("pendulum")
    inner = Proportional(-40.0, index=1, n_measured=2)
    outer = Proportional(-0.1, index=0, n_measured=2)
    block = models.Cascade(outer, inner)
    xe, ue = pend.equilibrium()
    point = loops.OperatingPoint(xe, ue, np.zeros(0), np.zeros(1), 0.0)
    G = discrete_plant(pend, xe, ue)  # F -> (z, θ)
    # Inner loop: u = k_i (v − θ); outer: v = k_o (r − z); L_outer = k_o · z/v.
    inner_closed = control.feedback(-40.0 * G, np.array([[0.0, 1.0]]))
    expected_outer = -0.1 * inner_closed[0, 0]
    got = loops.loop(pend, block, point, "outer")
    np.testing.assert_allclose(
        got.frequency_response(OMEGA), np.squeeze(expected_outer(np.exp(1j * OMEGA * TS))), rtol=1e-7
    )
    expected_inner = -40.0 * G[1, 0]
    got_inner = loops.loop(pend, block, point, "inner")
    np.testing.assert_allclose(
        got_inner.frequency_response(OMEGA), np.squeeze(expected_inner(np.exp(1j * OMEGA * TS))), rtol=1e-8
    )
    with pytest.raises(ValueError, match="needs a models.Cascade"):
        loops.loop(pend, inner, point, "outer")


def test_margins_of_a_proportional_loop_on_the_uuv():
    uuv = models.get("uuv")
    block = Proportional(100.0)
    xe, ue = uuv.equilibrium()
    point = loops.OperatingPoint(xe, ue, np.zeros(0), np.zeros(1), 0.0)
    m = loops.loop(uuv, block, point).margins()
    wc = m["gain_crossover_rad_s"]
    # |L| = 1 at the crossover, and the phase margin is 180° + ∠L there.
    G = discrete_plant(uuv, xe, ue)
    value = 100.0 * np.squeeze(G(np.exp(1j * wc * TS)))
    assert abs(value) == pytest.approx(1.0, rel=1e-6)
    assert m["phase_margin_deg"] == pytest.approx(180 + np.degrees(np.angle(value)), abs=1e-5)


def test_spec_check_on_a_gain_change():
    """A loop 20x the baseline meets "10x better below ω_low" and fails "10x lower above ω_high"."""
    from studies.case import LoopSpec

    uuv = models.get("uuv")
    xe, ue = uuv.equilibrium()
    point = loops.OperatingPoint(xe, ue, np.zeros(0), np.zeros(1), 0.0)
    base = loops.loop(uuv, Proportional(10.0), point)
    higher = loops.loop(uuv, Proportional(200.0), point)
    lower = loops.loop(uuv, Proportional(0.5), point)
    spec = LoopSpec("test", low_frequency=0.01, high_frequency=100.0, factor=10.0)
    assert loops.spec_check(higher, spec, base) == {"low_frequency": True, "high_frequency": False}
    assert loops.spec_check(lower, spec, base) == {"low_frequency": False, "high_frequency": True}
    assert loops.spec_check(higher, spec, None) == {"low_frequency": None, "high_frequency": None}
    wc = higher.margins()["gain_crossover_rad_s"]
    assert loops.spec_check(higher, LoopSpec("test", crossover=wc * 1.4), base) == {"crossover": True}
    assert loops.spec_check(higher, LoopSpec("test", crossover=wc * 1.6), base) == {"crossover": False}


@pytest.mark.parametrize("plant,gain", [("uuv", 100.0), ("uuv", 5.0), ("arm", 0.5), ("satellite", 3.0)])
def test_margins_hold_on_the_loops_own_frequency_response(plant, gain):
    """The margins (python-control's, on the loop's state space) against the loop's frequency response
    computed here by a second method (z I − A solved per frequency): |L| = 1 at the gain crossover with
    the phase margin 180° + ∠L there; L real and negative at the phase crossover, gm = 1/|L|."""
    model = models.get(plant)
    xe, ue = model.equilibrium()
    point = loops.OperatingPoint(xe, ue, np.zeros(0), np.zeros(1), 0.0)
    lp = loops.loop(model, FilteredPDOutput(gain, 0.6 * gain, model.ny), point)
    ours = lp.margins()
    wgc = ours["gain_crossover_rad_s"]
    if np.isfinite(wgc):
        value = lp.frequency_response([wgc])[0]
        assert abs(value) == pytest.approx(1.0, rel=1e-6)
        assert ours["phase_margin_deg"] == pytest.approx(
            (np.degrees(np.angle(value)) + 180.0 + 180) % 360 - 180, abs=1e-5
        )
    else:  # no gain crossover: |L| stays below one up to the Nyquist frequency
        omega = np.logspace(-4, np.log10(0.999 * np.pi / lp.sample_period), 5000)
        assert np.max(np.abs(lp.frequency_response(omega))) < 1
    gm, wpc = 10 ** (ours["gain_margin_db"] / 20), ours["phase_crossover_rad_s"]
    if np.isfinite(gm):
        at_phase_crossover = lp.frequency_response([wpc])[0]
        assert at_phase_crossover.real < 0 and abs(at_phase_crossover.imag) < 1e-8 * abs(at_phase_crossover)
        assert gm == pytest.approx(1 / abs(at_phase_crossover), rel=1e-8)


class FilteredPDOutput(models.Block):
    """u = kp e + kd (e − e_prev)/Ts on the first output, e = r − y (a test fixture with a state)."""

    def __init__(self, kp, kd, n_measured=1):
        super().__init__(
            sample_period=TS, n_state=1, n_measured=n_measured, n_reference=1, n_input=1, gains={"kp": kp, "kd": kd}
        )

    def expr(self, xc, y, r, g):
        e = r[0] - y[0]
        return ca.vertcat(e), g["kp"] * e + g["kd"] * (e - xc[0]) / TS * 0.05
