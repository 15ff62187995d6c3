"""Many parameter samples of a Python-stepped controller (MPC), stepped in lockstep.

Each sample k the plants of all running samples take one mapped RK4 step and
the controller one ``step_many`` for all of them, so the Python work of a
sample is shared; every run gets the numbers `simulate_closed_loop` gives it
alone (see `models.closed_loop` for the loop and the divergence rule).
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import casadi as ca
import numpy as np

from . import interrupts
from .block import Block, saturate
from .checks import as_matrix, integer
from .closed_loop import ClosedLoopResult, batch_outputs, first_faults
from .compile import NumpyCall
from .plant import Plant
from .run_setup import RunSetup
from .simulate import DIVERGENCE_BOUND

#: Samples stepped together by `simulate_closed_loop_many`: enough to spread the per-step Python work,
#: few enough that the runs' step records (one dict per sample and step) stay small.
LOCKSTEP_SAMPLES = 50


class _MappedCalls:
    """`fun` mapped over m samples, as a NumpyCall built once per m (m changes only when runs stop)."""

    def __init__(self, fun: ca.Function):
        self.fun = fun
        self._calls: dict[int, NumpyCall] = {}

    def __call__(self, m: int, *args) -> list[np.ndarray]:
        """`fun` mapped over m samples on `args` (each input's columns the samples)."""
        call = self._calls.get(m)
        if call is None:
            call = self._calls[m] = NumpyCall(self.fun.map(m))
        return call(*args)


def simulate_closed_loop_many(
    plant: Plant,
    controller,
    reference,
    duration: float,
    param_samples,
    *,
    x0=None,
    substeps: int = 10,
    input_disturbance=0.0,
    noise_std=0.0,
    seed: int | None = 0,
    chunk: int = LOCKSTEP_SAMPLES,
) -> Iterator[ClosedLoopResult]:
    """`simulate_closed_loop(..., allow_divergence=True)` of a non-Block controller on many parameter
    samples, stepped in lockstep: each sample's run, in order, with the same numbers.

    Every sample k the plants of all running samples take one mapped RK4 step and the controller
    one `step_many` for all of them, so the Python work per sample is shared. A run stops at its
    first fault (as in `simulate_closed_loop`); the others go on.

    Parameters
    ----------
    controller : a controller with ``lockstep`` True,
        ``initial_states(Y0 (m, n_measured), r0) -> XC (m, n_state)``
        (forgetting every warm start) and ``step_many(XC, Y, r, index) -> (XC_next, U (m, nu), records)``,
        the step of the samples `index` (rows of the `initial_states` batch), one record per sample
        as `step_info()` gives it
    param_samples : (M, n_params) actual parameters of each run
    chunk : samples stepped together (the results do not depend on it)
    plant, reference, duration, x0, substeps, input_disturbance, noise_std, seed : as
        `simulate_closed_loop`; every run gets the same noise (`seed`)

    Yields
    ------
    ClosedLoopResult per sample, in the order of `param_samples` (xc None, as for any non-Block)
    """
    if isinstance(controller, Block) or not getattr(controller, "lockstep", False):
        raise TypeError(
            f"{getattr(controller, 'name', controller)!r} cannot step many samples at once "
            "(it needs lockstep True, initial_states and step_many); use simulate_closed_loop, or "
            "monte_carlo for a Block"
        )
    setup = RunSetup.build(
        plant,
        controller,
        reference,
        duration,
        x0=x0,
        substeps=substeps,
        input_disturbance=input_disturbance,
        noise_std=noise_std,
        seed=seed,
    )
    chunk = integer(chunk, "chunk", minimum=1)
    samples = as_matrix(param_samples, plant.n_params, "param_samples")
    noise = setup.noise()
    rk4 = _MappedCalls(plant.step_function(controller.sample_period, setup.substeps))
    measure = _MappedCalls(plant.casadi_h)
    for first in range(0, len(samples), chunk):
        params = samples[first : first + chunk]
        yield from _lockstep(plant, controller, setup, params, noise, rk4, measure)


def _lockstep(
    plant: Plant,
    controller,
    setup: RunSetup,
    params: np.ndarray,
    noise: np.ndarray,
    rk4: _MappedCalls,
    measure: _MappedCalls,
) -> list[ClosedLoopResult]:
    """The runs of the samples `params` (m, n_params) stepped together; see `simulate_closed_loop_many`.

    noise : (N, n_measured), every run's;  rk4, measure : the plant's RK4 step and output map, mapped
    over the samples still running
    """
    m, n, nx = len(params), setup.n_steps, plant.nx
    outputs = controller.measures == "outputs"
    y0 = np.array([plant.output(setup.x0, p) if outputs else setup.x0 for p in params]) + (noise[0] if n else 0.0)
    xc = np.asarray(controller.initial_states(y0, setup.r[0]), dtype=float).reshape(m, -1)
    x = np.full((m, n + 1, nx), np.nan)
    x[:, 0] = setup.x0
    u = np.full((m, n, plant.nu), np.nan)
    measured = np.full((m, n, setup.n_measured), np.nan)
    step_time = np.full((m, n), np.nan)
    # The controller state's history is only checked for being finite: keep that alone (its runs' full
    # histories would take hundreds of MB).
    xc_fault = np.zeros((m, n + 1, 1))
    xc_fault[:, 0, 0] = np.where(np.all(np.isfinite(xc), axis=1), 0.0, np.nan)
    records: list[list] = [[] for _ in range(m)]
    limit = plant.input_limit
    active = np.flatnonzero(np.all(np.isfinite(xc), axis=1))
    for k in range(n):
        if not active.size:
            break
        interrupts.check()  # a Ctrl-C the previous step's CasADi calls swallowed
        count = len(active)
        now = x[active, k]
        meas = (measure(count, now.T, params[active].T)[0].T if outputs else now) + noise[k]
        start = time.perf_counter()
        xc_next, uk, infos = controller.step_many(xc[active], meas, setup.r[k], active)
        step_time[active, k] = (time.perf_counter() - start) / count
        uk = np.asarray(uk, dtype=float).reshape(count, -1)
        if uk.shape[1] != plant.nu:
            raise ValueError(f"{controller.name} returned {uk.shape[1]} inputs, {plant.name} takes {plant.nu}")
        for j, info in zip(active, infos):
            records[j].append(info)
        u[active, k], measured[active, k], xc[active] = uk, meas, xc_next
        xc_fault[active, k + 1, 0] = np.where(np.all(np.isfinite(xc_next), axis=1), 0.0, np.nan)
        command_ok = np.all(np.isfinite(uk), axis=1)
        moving = active[command_ok]  # a NaN command leaves the plant's input undefined: its state stays NaN
        if moving.size:
            x[moving, k + 1] = rk4(
                moving.size, x[moving, k].T, (saturate(u[moving, k], limit) + setup.d[k]).T, params[moving].T
            )[0].T
        nxt = x[active, k + 1]
        with np.errstate(invalid="ignore"):
            going = command_ok & np.all(np.isfinite(xc_next), axis=1) & np.all(np.abs(nxt) <= DIVERGENCE_BOUND, axis=1)
        active = active[going]
    first = first_faults(x, u, xc_fault)
    y = batch_outputs(plant, x, params)
    return [
        ClosedLoopResult.of_run(
            plant,
            controller,
            setup,
            x=x[i],
            y=y[i],
            u=u[i],
            measured=measured[i],
            xc=None,
            step_time=step_time[i],
            status=records[i],
            diverged_at=None if first[i] < 0 else float(setup.t[first[i]]),
            params=params[i],
        )
        for i in range(m)
    ]
