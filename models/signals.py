"""Reference and disturbance signals sampled at t_k = k * Ts.

Each returns a callable ``signal(t) -> ndarray`` that accepts an array of
times, so the simulator samples it once, exactly at k * Ts. Every number is
checked when the signal is made, so a bad amplitude is named there rather
than as a non-finite sample later.
"""

from __future__ import annotations

import numpy as np

from .checks import positive, real, real_array


def step(amplitude: float, start: float = 0.0, offset: float = 0.0):
    """offset for t < start, offset + amplitude from `start` s on."""
    amplitude, start, offset = real(amplitude, "amplitude"), real(start, "start (s)"), real(offset, "offset")
    return lambda t: np.where(np.asarray(t) >= start, offset + amplitude, offset)


def steps(levels, period: float, offset: float = 0.0):
    """A series of steps: ``offset + levels[i]`` on [i * period, (i + 1) * period), last level held."""
    levels = real_array(levels, "levels")
    if levels.ndim != 1 or levels.size == 0:
        raise ValueError(f"levels must be a non-empty 1-D sequence, got shape {levels.shape}")
    if not np.all(np.isfinite(levels)):
        raise ValueError(f"levels must be finite, got {levels}")
    period, offset = positive(period, "period (s)"), real(offset, "offset")

    def signal(t):
        # The level of the period each time falls in (1e-9: a time k * period on the grid starts level k).
        idx = np.clip(np.floor(np.asarray(t) / period + 1e-9).astype(int), 0, levels.size - 1)
        return offset + levels[idx]

    return signal


def square(amplitude: float, period: float, offset: float = 0.0):
    """Square wave: offset + amplitude for the first half of each period, offset − amplitude after."""
    amplitude, period, offset = real(amplitude, "amplitude"), positive(period, "period (s)"), real(offset, "offset")
    return lambda t: offset + amplitude * np.where((np.asarray(t) % period) < period / 2, 1.0, -1.0)


def ramp(slope: float, start: float = 0.0, offset: float = 0.0):
    """offset + slope * (t − start) after `start`, offset before."""
    slope, start, offset = real(slope, "slope"), real(start, "start (s)"), real(offset, "offset")
    return lambda t: offset + slope * np.maximum(np.asarray(t) - start, 0.0)


def sample(signal, t: np.ndarray, width: int, what: str) -> np.ndarray:
    """Sample a signal given as a constant, a sequence, an array (len(t), width) or a callable.

    Returns ndarray (len(t), width), checked finite.

    Raises
    ------
    TypeError
        Naming `what` when the signal (or what a callable returns) is not numbers: a string is
        refused, not converted.
    ValueError
        When the shape does not fit or a sample is not finite (naming its time).
    """
    values = real_array(signal(t) if callable(signal) else signal, what)
    if values.ndim == 0 or (values.ndim == 1 and values.size == width and len(t) != width):
        values = np.broadcast_to(values, (len(t), width))
    elif values.ndim == 1 and values.size == len(t):
        values = values[:, None]
    if values.shape == (len(t), 1) and width > 1:
        values = np.broadcast_to(values, (len(t), width))
    if values.shape != (len(t), width):
        raise ValueError(
            f"{what} must be a constant, {width} values, or an array of shape "
            f"({len(t)}, {width}); got shape {values.shape}"
        )
    if not np.all(np.isfinite(values)):
        k = int(np.flatnonzero(~np.all(np.isfinite(values), axis=1))[0])
        raise ValueError(f"{what} is not finite at t = {t[k]:.4g} s")
    return np.array(values)
