"""Loop algebra, steady-state errors and frequency answers against closed forms derived by hand."""

import control
import numpy as np
import pytest

from designs.analysis import (
    Loop,
    UnstableLoopError,
    band_max,
    check_band_ratio,
    check_bandwidth,
    check_damping,
    dc_gain,
    limit_at_zero,
    margins,
    percent_input_disturbance_below,
    percent_noise_above,
    percent_output_disturbance_below,
    percent_tracking_error_below,
    pid_tf,
    steady_state_errors,
    step_info,
    step_response,
    tf,
)
from designs.analysis.polynomials import pid_polynomials
from designs.analysis.stability_margins import sampled_loop_response

# The arm about θ = 0: θ/τ = b0/(s² + a1 s), b0 = 3/(m ℓ²), a1 = 3 b/(m ℓ²).
B0, A1 = 3 / (0.5 * 0.3**2), 3 * 0.01 / (0.5 * 0.3**2)
ARM = control.tf([B0], [1, A1, 0])
KP, KD, KI = 0.3, 0.085, 0.2


def test_pd_with_derivative_on_the_measurement():
    # E/R = (s² + (a1 + b0 kd) s)/(s² + (a1 + b0 kd) s + b0 kp): type 1.
    out = steady_state_errors(Loop.pid(ARM, KP, 0.0, KD))
    assert out["type"] == 1 and out["ess_step"] == 0.0 and out["ess_parabola"] == np.inf
    assert out["ess_ramp"] == pytest.approx((A1 + B0 * KD) / (B0 * KP), rel=1e-12)


def test_pd_with_derivative_on_the_error():
    # Unity feedback: E/R = s(s + a1)/(s² + (a1 + b0 kd) s + b0 kp): ramp error a1/(b0 kp) = 1/K_v.
    out = steady_state_errors(Loop.pid(ARM, KP, 0.0, KD, derivative_on="error"))
    assert out["type"] == 1 and out["ess_ramp"] == pytest.approx(A1 / (B0 * KP), rel=1e-12)


@pytest.mark.parametrize("derivative_on,numerator", [("measurement", A1 + B0 * KD), ("error", A1)])
def test_pid_is_type_two(derivative_on, numerator):
    # E/R = s² (s + a1 [+ b0 kd]) / (s³ + (a1 + b0 kd) s² + b0 kp s + b0 ki): parabola error numerator/(b0 ki).
    out = steady_state_errors(Loop.pid(ARM, KP, KI, KD, derivative_on=derivative_on))
    assert out["type"] == 2 and out["ess_step"] == 0.0 and out["ess_ramp"] == 0.0
    assert out["ess_parabola"] == pytest.approx(numerator / (B0 * KI), rel=1e-12)


def test_type_zero_plant_and_disturbances():
    k, a = 3.0, 2.0
    loop = Loop.unity(control.tf([k], [1, a]), 1.0)
    out = steady_state_errors(loop)
    assert out["type"] == 0 and out["ess_step"] == pytest.approx(1 / (1 + k / a)) and out["ess_ramp"] == np.inf
    # Arm under PD: θ/d_i at DC = b0/(b0 kp) = 1/kp; an integrator removes it exactly.
    assert dc_gain(Loop.pid(ARM, KP, 0, KD).input_disturbance_to_output()) == pytest.approx(1 / KP)
    assert dc_gain(Loop.pid(ARM, KP, KI, KD).input_disturbance_to_output()) == 0.0


def test_dirty_derivative_keeps_the_exact_type():
    out = steady_state_errors(Loop.pid(ARM, KP, KI, KD, sigma=0.05))
    assert out["type"] == 2 and out["ess_ramp"] == 0.0


def test_pid_tf_evaluates_to_its_formula():
    s, sigma = 2.0j, 0.05
    num, den = (np.ravel(v) for v in (pid_tf(KP, KI, KD, sigma).num[0][0], pid_tf(KP, KI, KD, sigma).den[0][0]))
    assert np.polyval(num, s) / np.polyval(den, s) == pytest.approx(KP + KI / s + KD * s / (sigma * s + 1))


def test_limits_keep_their_sign_and_infinity():
    assert limit_at_zero([1.0], [1.0, 0.0]) == np.inf
    assert limit_at_zero([-2.0], [1.0, 0.0]) == -np.inf
    assert limit_at_zero([1.0, 0.0], [1.0, 1.0]) == 0.0
    assert limit_at_zero([3.0, 0.0], [1.0, 2.0, 0.0]) == pytest.approx(1.5)
    assert dc_gain(tf([1.0], [1.0, 0.0])) == np.inf


def test_unstable_loop_has_no_steady_state():
    loop = Loop.unity(control.tf([1.0], [1.0, -1.0]), 0.5, name="unstable")
    assert not loop.is_stable()
    with pytest.raises(UnstableLoopError, match="unstable is not stable.*steady-state error"):
        steady_state_errors(loop)
    with pytest.raises(UnstableLoopError, match="tracking error"):
        percent_tracking_error_below(loop, 1.0)


def test_band_answers_of_an_integrator_loop():
    # L = k/s: T = k/(s + k), S = s/(s + k); both monotone, so the band maxima sit at ω.
    k, w = 4.0, 1.5
    loop = Loop.unity(control.tf([1.0], [1.0, 0.0]), k)
    assert percent_noise_above(loop, w) == pytest.approx(100 * k / np.hypot(w, k), rel=1e-9)
    assert percent_tracking_error_below(loop, w) == pytest.approx(100 * w / np.hypot(w, k), rel=1e-9)
    assert percent_output_disturbance_below(loop, w) == pytest.approx(100 * w / np.hypot(w, k), rel=1e-9)
    # Y/D_i = 1/(s + k): largest at DC.
    assert percent_input_disturbance_below(loop, w) == pytest.approx(100 / k, rel=1e-9)


def test_band_max_finds_a_resonance_peak():
    zeta, wn = 0.1, 2.0
    G = tf([wn**2], [1.0, 2 * zeta * wn, wn**2])
    peak, where = band_max(G, 0.0, np.inf)
    assert peak == pytest.approx(1 / (2 * zeta * np.sqrt(1 - zeta**2)), rel=1e-5)
    assert where == pytest.approx(wn * np.sqrt(1 - 2 * zeta**2), rel=1e-2)


def test_margins_of_a_type_one_loop():
    # L = k/(s (s + a)): ω_c² = (−a² + √(a⁴ + 4k²))/2, PM = 90° − atan(ω_c/a), GM infinite.
    k, a = 10.0, 2.0
    m = margins(tf([k], [1.0, a, 0.0]))
    wc = np.sqrt((-(a**2) + np.sqrt(a**4 + 4 * k**2)) / 2)
    assert m["gain_crossover"] == pytest.approx(wc, rel=1e-6)
    assert m["pm_deg"] == pytest.approx(90 - np.degrees(np.arctan(wc / a)), rel=1e-6)
    assert m["gm"] == np.inf


def test_margins_of_a_sampled_type_one_loop_in_closed_form():
    # L(z) = k Ts / (z − 1): |L| = k Ts / (2 sin(ω Ts / 2)), ∠L = −90° − ω Ts / 2, so
    # ω_c = (2 / Ts) asin(k Ts / 2), PM = 90° − ω_c Ts / 2; L(−1) = −k Ts / 2, GM = 2 / (k Ts) at π/Ts,
    # the grid's end (0.999 π/Ts), so none is found.
    k, ts = 20.0, 0.01
    m = margins(control.tf([k * ts], [1.0, -1.0], ts))
    wc = 2 / ts * np.arcsin(k * ts / 2)
    assert m["gain_crossover"] == pytest.approx(wc, rel=1e-10)
    assert m["pm_deg"] == pytest.approx(90 - np.degrees(wc * ts / 2), rel=1e-10)
    assert m["gm"] == np.inf
    # Its state space gives the same.
    assert margins(control.ss(control.tf([k * ts], [1.0, -1.0], ts)))["pm_deg"] == pytest.approx(m["pm_deg"], rel=1e-12)


def _scan_margins(L, ts, points=100_001):
    """(phase margin, gain margin) of a sampled loop by a linear scan of L(e^{jωTs}) over [0, π/Ts),
    each crossing refined with brentq: the second method the margins are held to."""
    from scipy.optimize import brentq

    def at(w):
        return complex(np.squeeze(L(np.exp(1j * w * ts))))

    w = np.linspace(0, np.pi / ts, points)[:-1]
    values = np.squeeze(L(np.exp(1j * w * ts)))
    gains = [
        brentq(lambda x: abs(at(x)) - 1, w[k], w[k + 1], xtol=1e-14)
        for k in np.flatnonzero(np.diff(np.sign(np.abs(values) - 1)))
    ]
    phases = [
        brentq(lambda x: at(x).imag, w[k], w[k + 1], xtol=1e-14) for k in np.flatnonzero(np.diff(np.sign(values.imag)))
    ]
    pms = np.array([np.remainder(np.angle(at(x), deg=True), 360) - 180 for x in gains])
    gms = [1 / abs(at(x)) for x in phases if at(x).real < 0]
    if values[0].real < 0:
        gms.insert(0, 1 / abs(values[0]))
    gms = np.array(gms)
    pm = pms[np.argmin(np.abs(pms))] if pms.size else np.inf
    gm = gms[np.argmin(np.abs(np.log(gms)))] if gms.size else np.inf
    return pm, gm


@pytest.mark.parametrize("zeta", [1e-2, 1e-3, 1e-4])
def test_sampled_margins_resolve_a_lightly_damped_resonance(zeta):
    """A rigid body with a flexible mode (a satellite-like loop): |L| crosses one twice within the
    resonance, far closer together than a logarithmic grid's step; the margins equal the scan's."""
    ts, w = 0.01, 3.0
    plant = control.tf([w**2], [1, 2 * zeta * w, w**2]) * control.tf([1.0], [1.0, 0.0, 0.0])
    controller = control.tf([4.0, 1.0], [0.02, 1.0])  # lead: k (τ s + 1) / (σ s + 1)
    L = control.c2d(plant * controller * 0.05, ts)
    ours = margins(L)
    pm, gm = _scan_margins(L, ts)
    # To 1e-5: the transfer function's polynomials near z = 1 carry rounding of about 1e-8 of L.
    assert ours["pm_deg"] == pytest.approx(pm, abs=1e-5)
    assert ours["gm"] == pytest.approx(gm, rel=1e-5)


@pytest.mark.parametrize("seed", range(8))
def test_sampled_margins_against_a_dense_scan_and_python_control(seed):
    """Random stable sampled loops: the margins against a 100,000-point linear scan of L(e^{jωTs}),
    crossings refined (a second method), and against python-control's spline-based 'frd' method where it finds the same
    crossing."""
    ts = 0.01
    rng = np.random.default_rng(seed)
    np.random.seed(seed)  # control.drss draws from numpy's global generator
    G = control.drss(int(rng.integers(2, 9)), 1, 1, dt=ts)
    L = control.ss(G.A, G.B, G.C, G.D, ts) * float(10 ** rng.uniform(-1, 2))
    ours = margins(L)
    scan_pm, scan_gm = _scan_margins(L, ts)
    assert ours["pm_deg"] == pytest.approx(scan_pm, rel=1e-5, abs=1e-5)
    assert ours["gm"] == pytest.approx(scan_gm, rel=1e-5)
    if np.isfinite(ours["gain_crossover"]):
        at = L(np.exp(1j * ours["gain_crossover"] * ts))
        assert abs(at) == pytest.approx(1.0, rel=1e-10)
    if np.isfinite(ours["phase_crossover"]) and ours["phase_crossover"] > 0:
        at = complex(L(np.exp(1j * ours["phase_crossover"] * ts)))
        assert at.real < 0 and abs(at.imag) < 1e-10 * abs(at)
    gm, pm, _, _, wgc, _ = control.stability_margins(L, method="frd")
    if np.isfinite(wgc) and np.isclose(wgc, ours["gain_crossover"], rtol=1e-3):
        assert ours["pm_deg"] == pytest.approx(pm, rel=1e-5, abs=1e-5)


def test_sampled_loop_response_of_a_transfer_function_and_of_its_state_space():
    """L(e^{jωTs}) as python-control evaluates it, for a discrete transfer function and its realization;
    the poles and zeros are the transfer function's roots."""
    ts = 0.01
    L = control.c2d(control.tf([2.0, 1.0], [1.0, 0.5, 4.0, 0.0]), ts)
    omega = np.array([0.1, 1.0, 2.0, 10.0, 100.0])
    expected = np.array([complex(L(np.exp(1j * w * ts))) for w in omega])
    num, den = np.ravel(L.num[0][0]), np.ravel(L.den[0][0])
    for system in (L, control.tf2ss(L)):
        response, poles, features = sampled_loop_response(system)
        np.testing.assert_allclose(response(omega), expected, rtol=1e-8)
        np.testing.assert_allclose(np.sort_complex(poles), np.sort_complex(np.roots(den)), atol=1e-9)
        found = np.sort_complex(features[~np.isin(features, poles)])
        np.testing.assert_allclose(found, np.sort_complex(np.roots(num)), atol=1e-7)


def test_pid_polynomials_share_the_denominator_of_their_flags():
    # k_p + k_i/s + k_d s/(σ s + 1) over s (σ s + 1): (k_p σ + k_d) s² + (k_p + k_i σ) s + k_i.
    num, den = pid_polynomials(KP, KI, KD, 0.05, True, True)
    np.testing.assert_allclose(den, [0.05, 1.0, 0.0])
    np.testing.assert_allclose(num, [KP * 0.05 + KD, KP + KI * 0.05, KI])
    _, den_reference = pid_polynomials(KP, KI, 0.0, 0.05, True, True)
    np.testing.assert_array_equal(den_reference, den)


def test_step_response_and_overshoot_of_a_second_order_loop():
    zeta, wn = 0.4, 3.0
    T = tf([wn**2], [1.0, 2 * zeta * wn, wn**2])
    times = np.linspace(0, 8, 801)
    np.testing.assert_allclose(step_response(T, times), control.step_response(T, times).outputs, atol=1e-10)
    overshoot = 100 * np.exp(-zeta * np.pi / np.sqrt(1 - zeta**2))
    assert step_info(T)["Overshoot"] == pytest.approx(overshoot, rel=1e-3)


def test_band_ratio_check_says_met_or_not():
    old = tf([1.0], [1.0, 1.0])
    assert check_band_ratio(old * 0.05, old, 0.0, 1.0, 10.0, "tracking").met
    check = check_band_ratio(old * 0.2, old, 0.0, 1.0, 10.0, "tracking")
    assert not check.met and check.value == pytest.approx(5.0) and "below 1 rad/s" in check.spec


def test_bad_transfer_functions_are_named():
    with pytest.raises(ValueError, match="continuous-time"):
        steady_state_errors(Loop.unity(control.tf([1], [1, 1], 0.1), 1.0))
    with pytest.raises(ValueError, match="SISO"):
        Loop.unity(control.tf([[[1], [1]]], [[[1, 1], [1, 2]]]), 1.0)
    with pytest.raises(ValueError, match="sigma must be > 0"):
        pid_tf(1.0, 0.0, 1.0, sigma=-0.05)


def test_damping_and_bandwidth_checks_of_a_second_order_loop():
    # L = ω_n²/(s (s + 2ζω_n)): closed loop ω_n²/(s² + 2ζω_n s + ω_n²), bandwidth ω_n √(1 − 2ζ² + √(2 − 4ζ² + 4ζ⁴)).
    zeta, wn = 0.3, 2.0
    loop = Loop.unity(tf([wn**2], [1, 2 * zeta * wn, 0]), 1.0)
    assert check_damping(loop, 0.2).met and check_damping(loop, 0.2).value == pytest.approx(zeta)
    assert not check_damping(loop, 0.5).met
    bw = wn * np.sqrt(1 - 2 * zeta**2 + np.sqrt(2 - 4 * zeta**2 + 4 * zeta**4))
    check = check_bandwidth(loop.reference_to_output(), bw)
    assert check.met and check.value == pytest.approx(bw, rel=1e-6)
