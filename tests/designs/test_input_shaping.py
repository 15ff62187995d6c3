"""designs.input_shaping against closed forms: the ZV impulses, the damped oscillator's exact response,
the rigid body with friction integrated by SciPy."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from designs import input_shaping as shaping


def oscillator_step(t, omega, zeta):
    """Unit step response of x'' + 2ζω x' + ω² x = ω² u (closed form), and its rate; 0 for t < 0."""
    t = np.asarray(t, dtype=float)
    damped = omega * np.sqrt(1 - zeta**2)
    decay = np.exp(-zeta * omega * np.maximum(t, 0))
    c, s = np.cos(damped * t), np.sin(damped * t)
    x = 1 - decay * (c + zeta / np.sqrt(1 - zeta**2) * s)
    dx = decay * omega / np.sqrt(1 - zeta**2) * s
    return np.where(t >= 0, x, 0.0), np.where(t >= 0, dx, 0.0)


def oscillator_impulse(t, omega, zeta):
    """Unit impulse response of the same oscillator, divided by ω² (the rate of the step response)."""
    return oscillator_step(t, omega, zeta)[1]


@pytest.mark.parametrize("omega, zeta", [(1.14, 0.0), (0.67, 0.05), (3.0, 0.3)])
def test_zv_impulses_are_the_closed_form(omega, zeta):
    zv = shaping.zero_vibration(omega, zeta)
    K = np.exp(-zeta * np.pi / np.sqrt(1 - zeta**2))
    np.testing.assert_allclose(zv.times, [0.0, np.pi / (omega * np.sqrt(1 - zeta**2))], rtol=1e-15)
    np.testing.assert_allclose(zv.amplitudes, [1 / (1 + K), K / (1 + K)], rtol=1e-15)
    assert zv.duration == zv.times[1]


@pytest.mark.parametrize("omega, zeta", [(1.14, 0.0), (0.67, 0.05), (3.0, 0.3)])
def test_a_zv_shaped_step_leaves_the_oscillator_at_rest(omega, zeta):
    """Superposing the exact step responses: after the second impulse x = 1 and x' = 0 exactly;
    the unshaped step still rings."""
    zv = shaping.zero_vibration(omega, zeta)
    t = np.linspace(zv.duration, zv.duration + 20 / omega, 400)
    x = sum(a * oscillator_step(t - ti, omega, zeta)[0] for ti, a in zip(zv.times, zv.amplitudes))
    dx = sum(a * oscillator_step(t - ti, omega, zeta)[1] for ti, a in zip(zv.times, zv.amplitudes))
    np.testing.assert_allclose(x, 1.0, atol=1e-12)
    np.testing.assert_allclose(dx, 0.0, atol=1e-12)
    unshaped = oscillator_step(t, omega, zeta)[0]
    assert np.max(np.abs(unshaped - 1)) > 1e-3


@pytest.mark.parametrize("mistuning", [0.8, 1.0, 1.3])
def test_residual_vibration_formula_matches_the_simulated_amplitude(mistuning):
    """V of a ZV shaper designed for ω, on a mode at mistuning·ω: the amplitude of the shaped impulse
    response over a unit impulse at the last impulse time, fitted from the exact responses."""
    omega, zeta = 1.0, 0.1
    zv = shaping.zero_vibration(omega, zeta)
    actual = mistuning * omega
    damped = actual * np.sqrt(1 - zeta**2)
    t = np.linspace(zv.duration + 0.1, zv.duration + 15, 300)
    shaped = sum(a * oscillator_impulse(t - ti, actual, zeta) for ti, a in zip(zv.times, zv.amplitudes))
    single = oscillator_impulse(t - zv.duration, actual, zeta)
    basis = np.column_stack([np.sin(damped * t), np.cos(damped * t)])
    growth = np.exp(zeta * actual * t)[:, None]
    amplitude = lambda y: np.linalg.norm(np.linalg.lstsq(basis, y * growth[:, 0], rcond=None)[0])
    assert zv.residual_vibration(actual, zeta) == pytest.approx(
        amplitude(shaped) / amplitude(single), rel=1e-9, abs=1e-12
    )


def test_convolved_shaper_cancels_both_modes():
    modes = [(0.67, 0.02), (1.15, 0.05)]
    both = shaping.zero_vibration(*modes[0]).convolve(shaping.zero_vibration(*modes[1]))
    assert both.amplitudes.sum() == pytest.approx(1.0, abs=1e-15)
    assert len(both.times) == 4 and both.duration == pytest.approx(
        shaping.zero_vibration(*modes[0]).duration + shaping.zero_vibration(*modes[1]).duration
    )
    for omega, zeta in modes:
        assert both.residual_vibration(omega, zeta) < 1e-12
    assert shaping.zero_vibration(*modes[0]).residual_vibration(*modes[1]) > 0.1


def test_apply_sums_delayed_copies_of_the_command():
    zv = shaping.Shaper([0.0, 1.0], [0.25, 0.75])
    t = np.array([-0.5, 0.0, 0.5, 1.0, 2.5])
    shaped = zv.apply(lambda s: 2.0 + s, t)
    np.testing.assert_allclose(shaped, [0.0, 0.5, 0.625, 0.25 * 3.0 + 0.75 * 2.0, 0.25 * 4.5 + 0.75 * 3.5])


def test_oscillatory_modes_of_a_block_diagonal_model():
    def oscillator(omega, zeta):
        return np.array([[0.0, 1.0], [-(omega**2), -2 * zeta * omega]])

    A = np.zeros((5, 5))
    A[:2, :2], A[2:4, 2:4], A[4, 4] = oscillator(2.0, 0.1), oscillator(0.5, 0.3), -1.0
    modes = shaping.oscillatory_modes(A)
    np.testing.assert_allclose(modes, [(0.5, 0.3), (2.0, 0.1)], rtol=1e-12)


@pytest.mark.parametrize("damping", [0.0, 200.0])
def test_rest_to_rest_bang_bang_moves_the_rigid_body_the_distance(damping):
    mass, force, distance = 2200.0, 5000.0, 10.0
    accelerate, decelerate = shaping.rest_to_rest_bang_bang(mass, damping, force, distance)
    if damping == 0:
        assert accelerate == decelerate == pytest.approx(np.sqrt(mass * distance / force), rel=1e-15)
    command = shaping.bang_bang(accelerate, decelerate, force)
    end = accelerate + decelerate
    rhs = lambda t, s: [s[1], (command(t) - damping * s[1]) / mass]
    run = solve_ivp(rhs, (0, end), [0.0, 0.0], rtol=1e-12, atol=1e-12, max_step=0.01)
    assert run.y[0, -1] == pytest.approx(distance, rel=1e-7)
    assert run.y[1, -1] == pytest.approx(0.0, abs=1e-7)


def test_a_shaped_bang_bang_keeps_the_rigid_body_move():
    """Convolution with impulses summing to one: the same distance, at rest, `duration` later."""
    mass, damping, force, distance = 2200.0, 200.0, 5000.0, 10.0
    command = shaping.bang_bang(*shaping.rest_to_rest_bang_bang(mass, damping, force, distance), force)
    zv = shaping.zero_vibration(0.9, 0.02)
    end = sum(shaping.rest_to_rest_bang_bang(mass, damping, force, distance)) + zv.duration
    rhs = lambda t, s: [s[1], (zv.apply(command, [t])[0] - damping * s[1]) / mass]
    run = solve_ivp(rhs, (0, end + 1.0), [0.0, 0.0], rtol=1e-11, atol=1e-11, max_step=0.005)
    assert run.y[0, -1] == pytest.approx(distance, rel=1e-6)
    assert run.y[1, -1] == pytest.approx(0.0, abs=1e-6)
    assert np.max(np.abs(zv.apply(command, np.linspace(0, end, 2001)))) <= force


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="damping_ratio must be in"):
        shaping.zero_vibration(1.0, 1.0)
    with pytest.raises(ValueError, match="natural_frequency"):
        shaping.zero_vibration(-1.0)
    with pytest.raises(ValueError, match="amplitudes must be positive and sum to 1"):
        shaping.Shaper([0.0, 1.0], [0.5, 0.6])
    with pytest.raises(ValueError, match="times must be finite, start at 0"):
        shaping.Shaper([0.5, 1.0], [0.5, 0.5])
    with pytest.raises(ValueError, match="damping"):
        shaping.rest_to_rest_bang_bang(1.0, -1.0, 1.0, 1.0)
