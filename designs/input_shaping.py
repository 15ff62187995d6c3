"""Input shaping: impulse sequences that move a lightly damped mode without leaving it swinging.

A shaper is a sequence of impulses A_i at times t_i with Σ A_i = 1. A command
convolved with it, u_s(t) = Σ A_i u(t − t_i), moves a linear plant's rigid-body
part as the command would (the move is delayed by the shaper's duration) and
stays within the command's bound (|u_s| <= max |u| since the A_i are positive).
The zero-vibration (ZV) shaper of a mode with natural frequency ω_n and damping
ratio ζ (Singer and Seering, 1990) cancels that mode's residual vibration:

    K = exp(−ζ π / √(1 − ζ²)),   A = (1/(1 + K), K/(1 + K)),   t = (0, π/ω_d),   ω_d = ω_n √(1 − ζ²)

For two modes, the convolution of their ZV shapers (ZV-ZV) cancels both.
`Shaper.residual_vibration` is the closed-form residual of any shaper on any
mode, in fractions of an unshaped impulse's. Units: s, rad/s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from models import deferred
from models.checks import positive, real

scipy = deferred.module("scipy")

__all__ = ["Shaper", "bang_bang", "oscillatory_modes", "rest_to_rest_bang_bang", "zero_vibration"]


@dataclass(frozen=True)
class Shaper:
    """Impulses `amplitudes` (positive, summing to 1) at `times` (s, increasing from 0)."""

    times: np.ndarray
    amplitudes: np.ndarray

    def __post_init__(self):
        """Store the impulses as float arrays: as many times (s, from 0, not decreasing) as amplitudes (> 0, sum 1)."""
        times = np.asarray(self.times, dtype=float).reshape(-1)
        amplitudes = np.asarray(self.amplitudes, dtype=float).reshape(-1)
        if times.size != amplitudes.size or times.size == 0:
            raise ValueError(
                f"times and amplitudes must have the same number (>= 1) of entries, got "
                f"{times.size} and {amplitudes.size}"
            )
        if not (np.all(np.isfinite(times)) and times[0] == 0 and np.all(np.diff(times) >= 0)):
            raise ValueError(f"times must be finite, start at 0 s and not decrease, got {times}")
        if not (np.all(amplitudes > 0) and abs(amplitudes.sum() - 1) < 1e-12):
            raise ValueError(f"amplitudes must be positive and sum to 1, got {amplitudes}")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "amplitudes", amplitudes)

    @property
    def duration(self) -> float:
        """The time of the last impulse, s: how much the shaper delays the move."""
        return float(self.times[-1])

    def convolve(self, other: Shaper) -> Shaper:
        """The shaper of both in series (its impulses: every pair's product, at the sum of their times)."""
        times = np.add.outer(self.times, other.times).ravel()
        amplitudes = np.multiply.outer(self.amplitudes, other.amplitudes).ravel()
        order = np.argsort(times, kind="stable")
        return Shaper(times[order], amplitudes[order] / amplitudes.sum())

    def apply(self, command: Callable[[np.ndarray], np.ndarray], t) -> np.ndarray:
        """The shaped command Σ A_i command(t − t_i) at the times `t` (s); command(s) is taken as 0 for s < 0.

        command : a function of an array of times returning an array of the same length (one input)
        """
        t = np.asarray(t, dtype=float).reshape(-1)
        out = np.zeros_like(t)
        for time, amplitude in zip(self.times, self.amplitudes):
            shifted = t - time
            values = np.asarray(command(np.maximum(shifted, 0.0)), dtype=float).reshape(-1)
            out += amplitude * np.where(shifted >= 0, values, 0.0)
        return out

    def residual_vibration(self, natural_frequency: float, damping_ratio: float) -> float:
        """Residual vibration of the mode (ω_n, ζ) after the last impulse, relative to one unit impulse's.

        V = exp(−ζ ω_n t_last) √(C² + S²), C = Σ A_i exp(ζ ω_n t_i) cos(ω_d t_i), S the same with sin.
        """
        omega = positive(natural_frequency, "natural_frequency (rad/s)")
        zeta = _damping_ratio(damping_ratio)
        damped = omega * np.sqrt(1 - zeta**2)
        weights = self.amplitudes * np.exp(zeta * omega * self.times)
        c, s = np.sum(weights * np.cos(damped * self.times)), np.sum(weights * np.sin(damped * self.times))
        return float(np.exp(-zeta * omega * self.times[-1]) * np.hypot(c, s))


def _damping_ratio(value) -> float:
    """`value` as a damping ratio of an oscillatory mode, 0 <= ζ < 1 (ValueError otherwise)."""
    zeta = real(value, "damping_ratio")
    if not 0 <= zeta < 1:
        raise ValueError(f"damping_ratio must be in [0, 1) (an oscillatory mode), got {zeta}")
    return zeta


def zero_vibration(natural_frequency: float, damping_ratio: float = 0.0) -> Shaper:
    """The ZV shaper of the mode (ω_n rad/s, ζ): two impulses half a damped period apart."""
    omega = positive(natural_frequency, "natural_frequency (rad/s)")
    zeta = _damping_ratio(damping_ratio)
    K = np.exp(-zeta * np.pi / np.sqrt(1 - zeta**2))
    return Shaper(np.array([0.0, np.pi / (omega * np.sqrt(1 - zeta**2))]), np.array([1.0, K]) / (1 + K))


def oscillatory_modes(A) -> list[tuple[float, float]]:
    """(ω_n rad/s, ζ) of every complex eigenvalue pair of the state matrix A, slowest first."""
    A = np.asarray(A, dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or not np.all(np.isfinite(A)):
        raise ValueError(f"A must be a finite square matrix, got shape {A.shape}")
    modes = []
    for value in np.linalg.eigvals(A):
        if value.imag > 1e-9 * max(1.0, abs(value)):
            modes.append((float(abs(value)), float(-value.real / abs(value))))
    return sorted(modes)


def rest_to_rest_bang_bang(mass: float, damping: float, force: float, distance: float) -> tuple[float, float]:
    """Durations (s) of +force then −force that move m v̇ = F − b v by `distance` from rest to rest.

    With b = 0 both are √(m d / F) (the double integrator's bang-bang); with b > 0,
    accelerating for t₁ gives v₁ = V (1 − e^{−t₁/τ}) (V = F/b, τ = m/b) and braking stops
    after t₂ = τ ln(1 + v₁/V); t₁ is found so that the distance covered is d.
    """
    mass = positive(mass, "mass (kg)")
    force = positive(force, "force (N)")
    distance = positive(distance, "distance (m)")
    damping = real(damping, "damping (N s/m)")
    if damping < 0:
        raise ValueError(f"damping (N s/m) must be >= 0, got {damping}")
    if damping == 0:
        half = float(np.sqrt(mass * distance / force))
        return half, half
    speed, tau = force / damping, mass / damping

    def phases(t1):
        v1 = speed * -np.expm1(-t1 / tau)
        x1 = speed * t1 - speed * tau * -np.expm1(-t1 / tau)
        t2 = tau * np.log1p(v1 / speed)
        x2 = -speed * t2 + tau * (v1 + speed) * -np.expm1(-t2 / tau)
        return x1 + x2, t2

    upper = np.sqrt(mass * distance / force)
    while phases(upper)[0] < distance:
        upper *= 2
    t1 = scipy.optimize.brentq(lambda t: phases(t)[0] - distance, 0.0, upper, xtol=1e-14, rtol=1e-14)
    return float(t1), float(phases(t1)[1])


def bang_bang(accelerate: float, decelerate: float, force: float) -> Callable[[np.ndarray], np.ndarray]:
    """The command +force on [0, accelerate), −force on [accelerate, accelerate + decelerate), then 0."""
    accelerate, decelerate = positive(accelerate, "accelerate (s)"), positive(decelerate, "decelerate (s)")
    force = positive(force, "force")

    def command(t):
        t = np.asarray(t, dtype=float)
        return np.where(t < accelerate, force, np.where(t < accelerate + decelerate, -force, 0.0))

    return command
