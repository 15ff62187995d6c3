"""Discrete-time pieces every controller block is built from, as CasADi expressions.

All follow the textbook's controller details: trapezoidal (Tustin) integration,
the dirty derivative s / (σ s + 1) discretized by Tustin, saturation last, and
two anti-windup schemes. They work on CasADi SX/MX (and on floats).
"""

from __future__ import annotations

import casadi as ca

from models import saturate

__all__ = [
    "saturate",
    "trapezoid",
    "dirty_derivative_coefficient",
    "dirty_derivative",
    "back_calculation",
    "integrate_while_slow",
]


def trapezoid(integral, error_prev, error, sample_period: float):
    """Integral after one sample of trapezoidal integration (Tustin of 1/s)."""
    return integral + sample_period / 2 * (error + error_prev)


def dirty_derivative_coefficient(sigma: float, sample_period: float) -> float:
    """β = (2σ − Ts) / (2σ + Ts), the pole of the Tustin-discretized s / (σ s + 1)."""
    if sigma <= 0 or sample_period <= 0:
        raise ValueError(f"sigma and sample_period must be > 0 s, got {sigma} and {sample_period}")
    return (2 * sigma - sample_period) / (2 * sigma + sample_period)


def dirty_derivative(derivative_prev, signal_prev, signal, sigma: float, sample_period: float):
    """Band-limited derivative s / (σ s + 1) of a sampled signal, one Tustin step.

    Parameters
    ----------
    derivative_prev, signal_prev : the previous sample's derivative estimate and signal
    signal : the current sample
    sigma : s, time constant of the roll-off (the text's 0.05 s)
    """
    beta = dirty_derivative_coefficient(sigma, sample_period)
    return beta * derivative_prev + (1 - beta) / sample_period * (signal - signal_prev)


def back_calculation(integral, u_unsaturated, u_saturated, ki, sample_period: float):
    """Anti-windup by back-calculation: bleed the integral by what saturation removed.

    integral + Ts / ki · (u_sat − u_unsat); unchanged when ki = 0.
    """
    safe_ki = ca.if_else(ki == 0, 1.0, ki)
    return ca.if_else(ki == 0, integral, integral + sample_period / safe_ki * (u_saturated - u_unsaturated))


def integrate_while_slow(integral_prev, integral_next, rate, rate_limit: float):
    """Anti-windup for any sign of ki: keep the update only while |rate| < rate_limit.

    The textbook's scheme for loops whose integrator gain is negative,
    where back-calculation would wind the integral the wrong way.
    """
    return ca.if_else(ca.fabs(rate) < rate_limit, integral_next, integral_prev)
