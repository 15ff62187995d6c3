"""Compensator builders against their closed forms; the Tustin block against python-control's c2d."""

import control
import numpy as np
import pytest

import models
from designs.analysis import as_polynomials, tf
from designs.filters import TransferFunctionBlock, lag, lead, low_pass, notch, prefilter, proportional_integral

TS = 0.01


@pytest.fixture(scope="module")
def arm():
    return models.get("arm")


def _at(G, w):
    num, den = as_polynomials(G)
    return np.polyval(num, 1j * w) / np.polyval(den, 1j * w)


def test_lead_has_its_maximum_phase_and_unit_gain_at_omega():
    w, phase = 5.0, 50.0
    C = lead(w, phase)
    assert np.degrees(np.angle(_at(C, w))) == pytest.approx(phase, rel=1e-9)
    assert abs(_at(C, w)) == pytest.approx(1.0, rel=1e-9)
    grid = np.linspace(0.5, 50, 2000)
    assert np.max(np.degrees(np.angle(_at(C, grid)))) <= phase + 1e-9


def test_lag_notch_lowpass_gains():
    assert abs(_at(lag(0.5, 12.0), 0.0)) == pytest.approx(12.0)
    assert abs(_at(lag(0.5, 12.0), 1e6)) == pytest.approx(1.0, rel=1e-6)
    assert abs(_at(notch(1.14, 0.05, 0.7), 1.14)) == pytest.approx(0.05 / 0.7, rel=1e-12)
    assert abs(_at(low_pass(60.0, 2), 60.0)) == pytest.approx(0.5, rel=1e-12)
    assert abs(_at(prefilter(3.0), 0.0)) == 1.0
    assert np.angle(_at(proportional_integral(0.2), 0.2), deg=True) == pytest.approx(-45.0)


def _block_step(block, n, y=0.0, r=1.0):
    xc, out = np.zeros(block.n_state), []
    for _ in range(n):
        xc, u = block.step(xc, [y], [r])
        out.append(u[0])
    return np.array(out)


def _c2d_step(G, n):
    return control.forced_response(control.c2d(G, TS, "tustin"), np.arange(n) * TS, np.ones(n)).outputs


@pytest.mark.parametrize(
    "C",
    [lead(5, 50) * lag(0.5, 12) * low_pass(60, 2), notch(1.14, 0.05, 0.7) * lead(2, 40), tf([2.0, 1.0], [1.0, 0.0])],
)
def test_block_equals_tustin_step_response(arm, C):
    n = 400
    block = TransferFunctionBlock(arm, "theta", C, anti_windup="none", sample_period=TS)
    np.testing.assert_allclose(_block_step(block, n), _c2d_step(C, n), atol=1e-9)


def test_prefilter_path_equals_tustin_of_the_product(arm):
    n, C, F = 400, lead(5, 40), prefilter(2.0)
    block = TransferFunctionBlock(arm, "theta", C, prefilter=F, sample_period=TS)
    np.testing.assert_allclose(_block_step(block, n), _c2d_step(C * F, n), atol=1e-9)
    # Starting at rest at a constant reference, the prefilter passes it unchanged: with C = 2 and the
    # measurement on the reference, the command stays exactly zero.
    gain = TransferFunctionBlock(arm, "theta", tf([2.0], [1.0]), prefilter=prefilter(2.0, order=2), sample_period=TS)
    xc = gain.initial_state([0.7], [0.7])
    for _ in range(50):
        xc, u = gain.step(xc, [0.7], [0.7])
        assert u[0] == pytest.approx(0.0, abs=1e-12)


def test_rebuilt_from_its_gains(arm):
    block = TransferFunctionBlock(arm, "theta", lead(5, 50), anti_windup="none", sample_period=TS)
    C2 = lead(3, 30)
    num, den = as_polynomials(C2)
    rebuilt = block.with_gains(num=np.pad(num, (2 - num.size, 0)), den=den)
    np.testing.assert_allclose(_block_step(rebuilt, 200), _c2d_step(C2, 200), atol=1e-9)


def test_observer_anti_windup_keeps_an_integrator_bounded(arm):
    # PI (s + 1)/s under a constant error with |u| <= 0.5: without anti-windup the state ramps,
    # with it the state settles where the output just saturates.
    pi = proportional_integral(1.0)
    kw = dict(output_limit=0.5, sample_period=TS)
    plain = TransferFunctionBlock(arm, "theta", pi, anti_windup="none", **kw)
    guarded = TransferFunctionBlock(arm, "theta", pi, anti_windup="observer", **kw)
    x_plain, x_guarded = np.zeros(1), np.zeros(1)
    for _ in range(2000):
        x_plain, _ = plain.step(x_plain, [0.0], [1.0])
        x_guarded, u = guarded.step(x_guarded, [0.0], [1.0])
    assert u[0] == 0.5
    assert abs(x_plain[0]) > 10
    assert abs(x_guarded[0]) < 1.0
    # When the error reverses, the guarded controller leaves saturation at the first sample.
    _, u = guarded.step(x_guarded, [2.0], [1.0])
    assert u[0] < 0.5


def test_bad_compensators_are_refused(arm):
    with pytest.raises(TypeError, match="sample_period"):
        TransferFunctionBlock(arm, "theta", lead(5, 50))  # no library default: the case's sample period
    with pytest.raises(ValueError, match="not causal"):
        TransferFunctionBlock(arm, "theta", tf([1.0, 0.0, 0.0], [1.0, 1.0]), sample_period=TS)
    with pytest.raises(ValueError, match="sample_period"):
        TransferFunctionBlock(arm, "theta", lead(5, 50), sample_period=-0.01)
    with pytest.raises(ValueError, match="two in series"):
        lead(5, 95)
    with pytest.raises(ValueError, match="gain > 1"):
        lag(1.0, 0.5)
    with pytest.raises(ValueError, match="zeta_zero < zeta_pole"):
        notch(1.0, 0.8, 0.7)


def test_reference_feedforward_is_the_restoring_torque_at_the_reference():
    uuv = models.get("uuv")
    m, g, L = (uuv.params[k] for k in ("m", "g", "L"))
    block = TransferFunctionBlock(
        uuv, "phi", lead(2, 40), feedforward="reference", output_limit=250.0, sample_period=TS
    )
    phi_d = 0.4
    _, u = block.step(block.initial_state([phi_d], [phi_d]), [phi_d], [phi_d])
    assert u[0] == pytest.approx(m * g * L * np.sin(phi_d), rel=1e-12)
    with pytest.raises(ValueError, match="feedforward must be"):
        TransferFunctionBlock(uuv, "phi", lead(2, 40), feedforward="state", sample_period=TS)
