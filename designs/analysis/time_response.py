"""Step responses of a stable SISO closed loop: exact samples and python-control's step_info on them."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from models import deferred

from .loop import UnstableLoopError
from .polynomials import as_polynomials, dc_gain

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

__all__ = ["step_response", "step_info"]


def step_response(T, times) -> np.ndarray:
    """Unit-step response of a stable SISO T at `times` (s), exact by modal decomposition.

    y(t) = D + C V diag((e^{λt} − 1)/λ) V⁻¹ B; falls back to python-control's
    forced_response when the state matrix is not safely diagonalizable.
    """
    times = np.asarray(times, dtype=float)
    sys = control.tf2ss(T)
    A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (sys.A, sys.B, sys.C, sys.D))
    if A.size == 0:
        return np.full(times.shape, float(D[0, 0]))
    lam, V = np.linalg.eig(A)
    if np.linalg.cond(V) > 1e8 or np.any(np.abs(lam) < 1e-14):
        return np.asarray(control.step_response(T, times).outputs, dtype=float).ravel()
    left = (C @ V).ravel()
    right = np.linalg.solve(V, B).ravel()
    modes = np.expm1(np.outer(times, lam)) / lam
    return (modes @ (left * right)).real + D[0, 0]


def step_info(T, settling_threshold: float = 0.02) -> dict:
    """python-control's step_info on a time grid long enough for the slowest pole to settle.

    The grid runs to 10 time constants of the slowest pole (at most 10⁵ s)
    with 20 000 points, the response computed exactly (`step_response`).
    """
    poles = np.roots(as_polynomials(T)[1])
    if poles.size == 0:
        return control.step_info(T, SettlingTimeThreshold=settling_threshold)
    if np.any(poles.real >= 0):
        raise UnstableLoopError(f"step response of an unstable system (poles {poles})")
    end = min(10.0 / np.min(-poles.real), 1e5)
    times = np.linspace(0.0, end, 20001)
    return control.step_info(
        step_response(T, times), T=times, yfinal=dc_gain(T), SettlingTimeThreshold=settling_threshold
    )
