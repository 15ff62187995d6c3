"""Frequency answers of a loop: the largest gain over a band, the .13 percentages, Bode data.

Frequencies in rad/s; "percent" values are 100·|G(jω)| of the named
transfer function (for a disturbance in N or N m reaching an angle, that is
rad per 100 N m, as the text's questions count it).
"""

from __future__ import annotations

import numpy as np

from models import deferred

from .loop import Loop
from .polynomials import as_polynomials, limit_at_zero

scipy = deferred.module("scipy")

__all__ = [
    "band_max",
    "percent_tracking_error_below",
    "percent_input_disturbance_below",
    "percent_output_disturbance_below",
    "percent_noise_above",
    "bode_data",
]


def _magnitude(G, omega) -> np.ndarray:
    """|G(jω)| at omega (F,) rad/s."""
    num, den = as_polynomials(G)
    s = 1j * np.asarray(omega, dtype=float)
    return np.abs(np.polyval(num, s) / np.polyval(den, s))


def band_max(G, low: float, high: float, points_per_decade: int = 400) -> tuple[float, float]:
    """Largest |G(jω)| for low ≤ ω ≤ high and the frequency where it occurs.

    `low` may be 0 (the DC limit is included) and `high` may be inf (the
    limit at infinity is included). Between, a logarithmic grid of
    `points_per_decade` points per decade, an interior peak refined by a
    bounded scalar search; an open end extends six decades beyond the
    slowest (fastest) pole or zero.
    """
    if not (0 <= low < high):
        raise ValueError(f"need 0 <= low < high, got low = {low}, high = {high}")
    num, den = as_polynomials(G)
    corners = np.abs(np.concatenate([np.roots(num), np.roots(den)]))
    corners = corners[corners > 0]
    slowest = corners.min() if corners.size else 1.0
    fastest = corners.max() if corners.size else 1.0
    lo = low if low > 0 else min(slowest, high) * 1e-6
    hi = high if np.isfinite(high) else max(fastest, lo) * 1e6
    decades = max(np.log10(hi / lo), 1e-3)
    grid = np.logspace(np.log10(lo), np.log10(hi), int(np.ceil(decades * points_per_decade)) + 1)
    mags = _magnitude(G, grid)
    best = int(np.argmax(mags))
    value, where = float(mags[best]), float(grid[best])
    if 0 < best < grid.size - 1:
        # Refine an interior peak between its grid neighbours.
        res = scipy.optimize.minimize_scalar(
            lambda lw: -_magnitude(G, 10.0**lw),
            method="bounded",
            bounds=(np.log10(grid[best - 1]), np.log10(grid[best + 1])),
            options={"xatol": 1e-12},
        )
        if -res.fun > value:
            value, where = float(-res.fun), float(10.0**res.x)
    if low == 0:
        at_zero = abs(limit_at_zero(num, den))
        if at_zero > value:
            value, where = at_zero, 0.0
    if not np.isfinite(high):
        at_inf = 0.0 if num.size < den.size else (np.inf if num.size > den.size else abs(num[0] / den[0]))
        if at_inf > value:
            value, where = float(at_inf), float(np.inf)
    return value, where


def percent_tracking_error_below(loop: Loop, omega: float) -> float:
    """100·max |E/R(jw)| for references with all frequency content below `omega` rad/s."""
    loop.require_stable("a tracking error")
    return 100.0 * band_max(loop.reference_to_error(), 0.0, omega)[0]


def percent_input_disturbance_below(loop: Loop, omega: float) -> float:
    """100·max |Y/D_i(jw)| below `omega`: the part of an input disturbance seen at the output."""
    loop.require_stable("a disturbance response")
    return 100.0 * band_max(loop.input_disturbance_to_output(), 0.0, omega)[0]


def percent_output_disturbance_below(loop: Loop, omega: float) -> float:
    """100·max |S(jw)| below `omega`: the part of an output disturbance left in the output."""
    loop.require_stable("a disturbance response")
    return 100.0 * band_max(loop.output_disturbance_to_output(), 0.0, omega)[0]


def percent_noise_above(loop: Loop, omega: float) -> float:
    """100·max |T(jw)| above `omega`: the part of measurement noise that reaches the output."""
    loop.require_stable("a noise response")
    return 100.0 * band_max(loop.noise_to_output(), omega, np.inf)[0]


def bode_data(G, omega) -> dict:
    """Magnitude (absolute) and unwrapped phase (deg) of G at the frequencies `omega` (rad/s)."""
    omega = np.asarray(omega, dtype=float)
    num, den = as_polynomials(G)
    resp = np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega)
    return {"omega": omega, "magnitude": np.abs(resp), "phase_deg": np.degrees(np.unwrap(np.angle(resp)))}
