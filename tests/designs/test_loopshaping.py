"""Loopshaping against python-control's margins, bandwidth and frequency responses."""

import control
import numpy as np
import pytest

from designs.analysis import pid_tf, tf
from designs.loopshaping import (
    crossover_for_bandwidth,
    damping_for_phase_margin,
    flattening_prefilter,
    improve_loop,
    lag_ratio_for_tracking,
    lead_for_crossover,
    lowpass_corner_for_noise,
    prototype_bandwidth,
    prototype_crossover,
    prototype_phase_margin,
)

ARM = control.tf([66.667], [1, 0.6667, 0])
ARM_PD = ARM * pid_tf(0.3037, 0.0, 0.0854, 0.05)


@pytest.mark.parametrize("zeta", [0.25, 0.4, 0.7, 0.9])
def test_prototype_relations(zeta):
    wn = 3.0
    L = control.tf([wn**2], [1, 2 * zeta * wn, 0])
    gm, pm, _, _, wc, _ = control.stability_margins(L)
    assert prototype_crossover(wn, zeta) == pytest.approx(wc, rel=1e-6)
    assert prototype_phase_margin(zeta) == pytest.approx(pm, rel=1e-6)
    half_power_db = 20 * np.log10(1 / np.sqrt(2))  # the closed form is the 1/√2 crossing
    assert prototype_bandwidth(wn, zeta) == pytest.approx(
        control.bandwidth(control.feedback(L, 1), half_power_db), rel=1e-6
    )
    assert damping_for_phase_margin(pm) == pytest.approx(zeta, rel=1e-9)
    assert crossover_for_bandwidth(prototype_bandwidth(wn, zeta), zeta) == pytest.approx(wc, rel=1e-9)


@pytest.mark.parametrize("plant", [tf([2.652], [1, 0, 0]), tf([-9.8], [1, 0, 0]), tf([-6.667e-5], [1, 0, 1.308])])
def test_lead_for_crossover_meets_its_margin(plant):
    design = lead_for_crossover(plant, 2.0, 55.0)
    L = plant * design.controller
    _, pm, _, _, wc, _ = control.stability_margins(L)
    assert wc == pytest.approx(2.0, rel=1e-6) and pm == pytest.approx(55.0, rel=1e-6)
    assert np.all(control.poles(control.feedback(L, 1)).real < 0)


def test_lead_refuses_an_unstable_loop():
    with pytest.raises(ValueError, match="right-half-plane poles"):
        lead_for_crossover(tf([-2.0], [1, 0, -24.5]), 5.0, 60.0)


def _closed(L):
    return control.feedback(L, 1), control.feedback(1, L)


def test_arm_loopshaping_meets_I14_independently():
    shaped = improve_loop(
        ARM_PD, low_frequency=0.007, low_factor=10, high_frequency=200, high_factor=10, phase_margin_deg=60
    )
    assert shaped.all_met, [s for s in shaped.specs if not s.met]
    T_old, S_old = _closed(ARM_PD)
    T_new, S_new = _closed(ARM_PD * shaped.controller)
    low = np.logspace(-6, np.log10(0.007), 400)
    high = np.logspace(np.log10(200), 5, 400)
    mag = lambda G, w: np.abs(control.frequency_response(G, w).magnitude).ravel()
    assert np.all(mag(S_new, low) <= mag(S_old, low) / 10 * (1 + 1e-9))
    assert np.all(mag(T_new, high) <= mag(T_old, high) / 10 * (1 + 1e-9))
    _, pm, _, _, wc, _ = control.stability_margins(ARM_PD * shaped.controller)
    _, _, _, _, wc_old, _ = control.stability_margins(ARM_PD)
    assert pm == pytest.approx(60.0, abs=0.5) and wc == pytest.approx(wc_old, rel=0.01)


def test_flattening_prefilter_keeps_the_closed_loop_below_one():
    shaped = improve_loop(ARM_PD, low_frequency=0.007, low_factor=10, high_frequency=200, high_factor=10)
    T = control.feedback(ARM_PD * shaped.controller, 1)
    out = flattening_prefilter(T)
    w = np.logspace(-4, 4, 4000)
    assert out["peak_before"] > 1.01
    assert np.max(np.abs(control.frequency_response(out["prefilter"] * T, w).magnitude)) <= 1.01 + 1e-9


def test_a_spec_that_cannot_be_met_is_reported():
    # Noise attenuation 10x just above crossover cannot coexist with a 60 deg phase margin there.
    shaped = improve_loop(ARM_PD, low_frequency=0.007, low_factor=10, high_frequency=9.0, high_factor=10)
    failed = [s.spec for s in shaped.specs if not s.met]
    assert not shaped.all_met and failed
    assert any("phase margin" in f or "noise" in f or "stable" in f for f in failed)
    with pytest.raises(ValueError, match="low_frequency < crossover < high_frequency"):
        improve_loop(ARM_PD, low_frequency=10.0, low_factor=10, high_frequency=200, high_factor=10)


def _on(G, omega):
    return np.asarray(control.frequency_response(G, omega).complex).ravel()


def test_lowpass_corner_gives_the_noise_ratio_asked_for():
    """The corner found on a grid, against python-control's closed loops: |T_new/T_old| above 200 rad/s."""
    omega = np.logspace(np.log10(200), np.log10(200) + 6, 1201)
    corner = lowpass_corner_for_noise(_on(ARM_PD, omega), np.ones(omega.size), omega, 2, 0.1, 1e-3, 2e5)
    T_old = control.feedback(ARM_PD, 1)
    T_new = control.feedback(ARM_PD * (corner / control.tf([1, corner], [1])) ** 2, 1)
    dense = np.logspace(np.log10(200), 6, 20001)
    ratio = np.abs(_on(T_new, dense) / _on(T_old, dense))
    assert np.max(ratio) == pytest.approx(0.1, rel=1e-6)
    # An interval that cannot reach the ratio, and one whose top end already does.
    assert lowpass_corner_for_noise(_on(ARM_PD, omega), np.ones(omega.size), omega, 2, 0.1, 1e4, 2e5) == 1e4
    assert lowpass_corner_for_noise(_on(ARM_PD, omega), np.ones(omega.size), omega, 2, 0.1, 1e-3, 1.0) == 1.0


def test_lag_ratio_gives_the_tracking_improvement_asked_for():
    """The lag ratio M against python-control's sensitivities: |S_old/S_new| below 0.007 rad/s is 10."""
    omega = np.logspace(np.log10(0.007) - 6, np.log10(0.007), 1201)
    zero = 0.2
    ratio, reached = lag_ratio_for_tracking(_on(ARM_PD, omega), np.ones(omega.size), omega, zero, 10.0)
    assert reached and ratio > 1
    S_old = control.feedback(1, ARM_PD)
    S_new = control.feedback(1, ARM_PD * control.tf([1, zero], [1, zero / ratio]))
    dense = np.logspace(np.log10(0.007) - 6, np.log10(0.007), 20001)
    assert np.min(np.abs(_on(S_old, dense) / _on(S_new, dense))) == pytest.approx(10.0, rel=1e-6)
    # No lag is needed for an improvement of 1; none up to 4^20 reaches 10 with a zero far below the band.
    assert lag_ratio_for_tracking(_on(ARM_PD, omega), np.ones(omega.size), omega, zero, 1.0) == (1.0 + 1e-9, True)
    assert lag_ratio_for_tracking(_on(ARM_PD, omega), np.ones(omega.size), omega, 1e-12, 10.0) == (4.0**20, False)
