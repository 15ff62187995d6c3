"""The classical fourth-order Runge-Kutta step, written once for every fixed-step integration.

`Plant.step_function` (the simulators, closed loops, Monte Carlo, linear MPC's
prediction) and the multiple-shooting transcription of `mpc` (with the cost
integrands carried alongside the state, and a symbolic interval length) both
call `rk4`.
"""

from __future__ import annotations

from collections.abc import Callable


def rk4(rate: Callable, x, h, substeps: int = 1, t0=0.0):
    """`substeps` RK4 steps of ẋ = rate(x, t) over an interval of length `h`, from `x` at time `t0`.

    Parameters
    ----------
    rate : (x, t) -> ẋ, on CasADi expressions or numpy arrays
    x : state at t0, (n,)
    h : interval length, s (a number or a CasADi symbol)
    substeps : equal steps of h / substeps
    t0 : time at the interval's start, s

    Returns
    -------
    The state after h, of the type of `x`.
    """
    dt = h / substeps
    for i in range(substeps):
        t = t0 + i * dt
        k1 = rate(x, t)
        k2 = rate(x + dt / 2 * k1, t + dt / 2)
        k3 = rate(x + dt / 2 * k2, t + dt / 2)
        k4 = rate(x + dt * k3, t + dt)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x
