"""Gain and phase margins of continuous and sampled loop gains.

`margins` is the one margins computation of the project: python-control's
`stability_margins` for a continuous loop, and for a sampled loop the
crossings of the exact L(e^{jωTs}) on a grid that resolves lightly damped
modes (`discrete_grid`), refined by root finding (`crossover_margins`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from models import deferred

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")
scipy = deferred.module("scipy")

__all__ = ["SLOWEST", "crossover_margins", "sampled_response", "discrete_grid", "sampled_loop_response", "margins"]


def crossover_margins(response, omega, values=None) -> dict:
    """Gain and phase margins from a loop's frequency response, crossings found on a grid and refined.

    The algorithm of python-control's `stability_margins` for frequency data, applied to the exact
    response instead of a spline through samples of it: the phase crossovers are the sign changes of
    Im L on the grid where Re L < 0 (and ω = 0 when the grid starts there and L(0) < 0), the gain
    crossovers those of |L| − 1, each refined by `scipy.optimize.brentq` on `response`; of several,
    the gain margin nearest 1 and the phase margin smallest in magnitude. A pair of crossings
    between two grid points (a resonance narrower than the grid) is missed, as in python-control.

    response : callable, omega (F,) rad/s -> L at omega, complex (F,)
    omega : (F,) rad/s, increasing
    values : response(omega) when already computed

    Returns the dict of `margins`.
    """
    omega = np.asarray(omega, dtype=float)
    values = response(omega) if values is None else np.asarray(values)

    def at(w):
        return complex(response(np.array([w]))[0])

    def crossings(f, keep=lambda w: True):
        signs = np.sign(f(values))
        found = []
        for i in np.flatnonzero(signs[:-1] * signs[1:] < 0):
            w = scipy.optimize.brentq(lambda w: f(np.array([at(w)]))[0], omega[i], omega[i + 1], xtol=1e-14)
            if keep(w):
                found.append(w)
        found.extend(float(omega[i]) for i in np.flatnonzero(signs == 0) if keep(omega[i]))
        return np.sort(np.array(found, dtype=float))

    w_180 = crossings(np.imag, keep=lambda w: at(w).real < 0)
    if omega[0] == 0 and values[0].real < 0 and 0.0 not in w_180:
        w_180 = np.concatenate([[0.0], w_180])  # negative at DC: the phase is -180 there
    w_c = crossings(lambda v: np.abs(v) - 1.0)
    out = {"gm": np.inf, "gm_db": np.inf, "pm_deg": np.inf, "phase_crossover": np.nan, "gain_crossover": np.nan}
    if w_180.size:
        with np.errstate(divide="ignore"):
            gm = 1.0 / np.abs([at(w) for w in w_180])
            i = int(np.argmin(np.abs(np.log(gm))))
        if np.isfinite(gm[i]):
            out.update(gm=float(gm[i]), gm_db=float(20 * np.log10(gm[i])), phase_crossover=float(w_180[i]))
    if w_c.size:
        pm = np.remainder(np.angle([at(w) for w in w_c], deg=True), 360.0) - 180.0
        i = int(np.argmin(np.abs(pm)))
        out.update(pm_deg=float(pm[i]), gain_crossover=float(w_c[i]))
    return out


#: Poles and zeros with |ln z| below this fraction of π (a time constant over 3e5 samples) count as at
#: z = 1 in sampled margins: an integrator computed to rounding, not a feature of the loop to resolve.
SLOWEST = 1e-6


def sampled_response(A, B, C, D, sample_period: float, omega) -> np.ndarray:
    """C (zI − A)⁻¹ B + D at z = e^{jωTs} of a SISO sampled state space: complex (F,) at omega (F,) rad/s."""
    omega = np.asarray(omega, dtype=float)
    z = np.exp(1j * omega * sample_period)
    rhs = np.broadcast_to(np.asarray(B, dtype=complex), (len(z), *np.shape(B)))
    return (C @ np.linalg.solve(z[:, None, None] * np.eye(np.shape(A)[0]) - A, rhs))[:, 0, 0] + np.asarray(D)[0, 0]


def discrete_grid(poles_zeros, sample_period: float, points_per_decade: int = 200) -> np.ndarray:
    """A grid (rad/s) below the Nyquist frequency for a sampled loop's crossings.

    0; a logarithmic grid from a decade below the slowest pole or zero (|ln z| / Ts; those below
    `SLOWEST` of the Nyquist frequency count as at z = 1 and are left out) to 0.999 of the Nyquist
    frequency π/Ts; and around each pole or zero, at both |ln z| / Ts and |∠z| / Ts (where e^{jωTs}
    passes nearest to it), offsets from 1e-6 to 0.5 of that frequency on either side, log-spaced:
    a lightly damped mode's resonance, with its pair of crossings far narrower than the
    logarithmic grid's step, is resolved.
    """
    nyquist = np.pi / sample_period
    z = np.asarray(poles_zeros, dtype=complex)
    z = z[np.abs(z) > 1e-300]
    features = np.concatenate([np.abs(np.log(z)), np.abs(np.angle(z))]) / sample_period
    features = features[features > SLOWEST * nyquist]
    slowest = min(features.min(), nyquist) if features.size else 1e-3 * nyquist
    lo, hi = min(slowest, 1e-3 * nyquist) / 10, 0.999 * nyquist
    grid = np.logspace(np.log10(lo), np.log10(hi), int(np.ceil(np.log10(hi / lo) * points_per_decade)) + 1)
    offsets = np.geomspace(1e-6, 0.5, 60)
    local = (features[:, None] * (1 + np.concatenate([-offsets, [0.0], offsets]))[None]).ravel()
    local = local[(local > lo) & (local < hi)]
    return np.concatenate([[0.0], np.unique(np.concatenate([grid, local]))])


def sampled_loop_response(L) -> tuple[Callable, np.ndarray, np.ndarray]:
    """The exact frequency response of a sampled SISO loop gain, with its poles and its poles and zeros.

    L : a discrete SISO `control.TransferFunction` or `control.StateSpace` (sample period L.dt, s).

    Returns
    -------
    (response, poles, features) : response maps omega (F,) rad/s to L(e^{jωTs}), complex (F,);
    poles (n,) and features (poles and finite transmission zeros) are complex z-plane points.
    """
    ts = float(L.dt)
    if isinstance(L, control.TransferFunction):
        num, den = np.asarray(L.num[0][0], dtype=float), np.asarray(L.den[0][0], dtype=float)

        def response(w):
            z = np.exp(1j * w * ts)
            return np.polyval(num, z) / np.polyval(den, z)

        poles = np.roots(den)
        return response, poles, np.concatenate([np.roots(num), poles])
    A, B, C, D = (np.asarray(m, dtype=float) for m in (L.A, L.B, L.C, L.D))

    def state_space_response(w):
        return sampled_response(A, B, C, D, ts, w)

    poles = np.linalg.eigvals(A)
    # Transmission zeros: the finite generalized eigenvalues of ([[A, B], [C, D]], diag(I, 0)).
    n = A.shape[0]
    pencil = np.zeros((n + 1, n + 1))
    pencil[:n, :n] = np.eye(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        zeros = scipy.linalg.eigvals(np.block([[A, B], [C, D]]), pencil)
    return state_space_response, poles, np.concatenate([poles, zeros[np.isfinite(zeros)]])


def margins(L) -> dict:
    """Gain and phase margins of a loop gain, the one margins computation.

    L : a continuous or discrete SISO transfer function or state-space system (closed loop 1 + L = 0).
    Continuous loops: python-control's `stability_margins` (its exact polynomial method). Sampled
    loops: `crossover_margins` of the exact L(e^{jωTs}) on `discrete_grid`, because python-control's
    spline through frequency samples is slow there and misses or invents crossings of lightly
    damped loops (docs/notes/designs.md has the measurements).

    Returns
    -------
    dict with gm (ratio, inf when the phase never crosses −180°), gm_db,
    pm_deg, phase_crossover and gain_crossover (rad/s; nan when absent).
    """
    if L.isdtime(strict=True):
        if L.ninputs != 1 or L.noutputs != 1:
            raise ValueError(f"margins need a SISO loop gain, got {L.noutputs}x{L.ninputs}")
        response, poles, features = sampled_loop_response(L)
        grid = discrete_grid(features, float(L.dt))
        near_one = np.abs(poles - 1) < SLOWEST * np.pi  # |ln z| ≈ |z − 1| there; ln 0 is not asked for
        if np.any(near_one):
            grid = grid[1:]  # a pole at z = 1 (an integrator): L(1) is infinite, not a phase crossover
        return crossover_margins(response, grid)
    gm, pm, _, w_pc, w_gc, _ = control.stability_margins(L)
    gm = float(gm)
    return {
        "gm": gm,
        "gm_db": float(20 * np.log10(gm)) if np.isfinite(gm) and gm > 0 else float(np.inf),
        "pm_deg": float(pm),
        "phase_crossover": float(w_pc),
        "gain_crossover": float(w_gc),
    }
