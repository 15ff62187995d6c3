"""The closed-loop simulator: plant (actual parameters) + controller, sampled and held.

Every sample k (t_k = k * Ts, Ts the controller's sample period):

    y_k   = h(x_k) + n_k           (or x_k + n_k for controllers that measure the state)
    x_c,k+1, u_k = controller.step(x_c,k, y_k, r_k)
    x_k+1 = RK4 over Ts of the plant with input clip(u_k, ±input_limit) + d_k

n_k is seeded Gaussian measurement noise, d_k an input disturbance. For a
`Block` the whole run is one CasADi mapaccum (and a Monte Carlo one map of
it, in chunks of samples); other controllers (MPC) run the same step in a
Python loop.

Divergence, on every path: a run diverges at the first sample t_k at which
the plant state x_k is non-finite or beyond `DIVERGENCE_BOUND`, the command
u_k is non-finite, or a `Block`'s state x_c,k is non-finite. A NaN command is
never clipped into a finite force: the plant's input is undefined from then
on, and the states after it are NaN.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from . import interrupts
from .block import Block, saturate
from .checks import (
    SimulationError,
    as_matrix,
    as_vector,
    boolean,
    check_memory,
    format_bytes,
    integer,
)
from .compile import NumpyCall
from .compile import jit as compile_jit
from .plant import Plant
from .run_setup import RunSetup, check_sizes, doubles_per_step
from .simulate import DIVERGENCE_BOUND, output_call
from .smooth import smoothed

#: Working memory, in bytes, of one chunk of a Monte Carlo batch (CasADi's
#: output buffers and the noise of the chunk's samples). Results do not depend
#: on the chunk size. Override by assignment.
MONTE_CARLO_CHUNK_BYTES = 64 * 2**20

#: Samples x steps per chunk at most. CasADi stores the sparsity of every
#: mapped input and output explicitly, so building the map of a chunk costs
#: time superlinear in its size: 0.6 s for 256 pendulum runs of 2000 steps,
#: 15 ms for 16 (measured); beyond ~64k sample-steps a call's own work
#: (~30 ms) already dwarfs the per-call overhead.
MONTE_CARLO_CHUNK_STEPS = 2**16


@dataclass(frozen=True)
class ClosedLoopResult:
    """One closed-loop run; arrays over samples k = 0..N.

    Attributes
    ----------
    t : (N+1,) s
    x : (N+1, nx) plant state;  y : (N+1, ny) plant outputs, noise-free
    r : (N+1, n_reference) reference
    u : (N, nu) controller command on [t_k, t_k+1) (the plant gets it clipped to the limit)
    d : (N, nu) input disturbance added at the plant input
    measured : (N, n_measured) what the controller read (with noise)
    xc : (N+1, n_state) controller state, or None when the controller is not a Block
    step_time : (N,) s of controller computation per sample
    status : list of per-step solver records (dicts) for optimizing controllers, else None
    input_limit : (nu,)
    diverged_at : s, the first sample time at which the state left the bound or became
        non-finite, or the command or the controller state became non-finite; None if never
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    r: np.ndarray
    u: np.ndarray
    d: np.ndarray
    measured: np.ndarray
    xc: np.ndarray | None
    step_time: np.ndarray
    status: list | None
    input_limit: np.ndarray
    state_names: tuple
    output_names: tuple
    input_names: tuple
    controller: str = ""
    diverged_at: float | None = None
    params: np.ndarray | None = field(default=None, repr=False)

    def output(self, name: str) -> np.ndarray:
        """The named (noise-free) output over time, (N+1,)."""
        return self.y[:, self.output_names.index(name)]

    def state(self, name: str) -> np.ndarray:
        return self.x[:, self.state_names.index(name)]


class MonteCarloResult(Sequence):
    """Closed-loop runs of one controller on M parameter samples, held as arrays.

    Indexing gives one sample as a `ClosedLoopResult` whose arrays are
    read-only views into the batch (no copies); iterating gives every sample.

    Attributes
    ----------
    t : (N+1,) s;  r : (N+1, n_reference);  d : (N, nu)   shared by every sample
    x : (M, N+1, nx) plant states
    xc : (M, N+1, n_state) controller states
    u : (M, N, nu) commands;  measured : (M, N, n_measured)
    params : (M, n_params) the actual parameters of each sample
    diverged_at : (M,) s, NaN where the sample did not diverge (see the module docstring)
    first_sample : index of this batch's first sample in the whole sample set
        (non-zero for the chunks of `monte_carlo_chunks`)
    y : (M, N+1, ny) noise-free outputs, computed on first use
    """

    def __init__(
        self, *, plant: Plant, controller: str, t, r, d, x, xc, u, measured, params, diverged_at, first_sample: int = 0
    ):
        self._plant = plant
        self.controller = controller
        self.t, self.r, self.d = t, r, d
        self.x, self.xc, self.u, self.measured = x, xc, u, measured
        self.params, self.diverged_at = params, diverged_at
        self.first_sample = first_sample
        self.input_limit = plant.input_limit.copy()
        self.state_names, self.output_names, self.input_names = plant.state_names, plant.output_names, plant.input_names
        self._y: np.ndarray | None = None
        self._step_time = np.full(len(t) - 1, np.nan)
        for arr in (
            self.t,
            self.r,
            self.d,
            self.x,
            self.xc,
            self.u,
            self.measured,
            self.params,
            self.diverged_at,
            self.input_limit,
            self._step_time,
        ):
            arr.setflags(write=False)

    @property
    def y(self) -> np.ndarray:
        if self._y is None:
            y = batch_outputs(self._plant, self.x, self.params)
            y.setflags(write=False)
            self._y = y
        return self._y

    def __len__(self) -> int:
        return self.x.shape[0]

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = int(index)
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {index} of a batch of {len(self)}")
        i %= len(self)
        k = self.diverged_at[i]
        return ClosedLoopResult(
            t=self.t,
            x=self.x[i],
            y=self.y[i],
            r=self.r,
            u=self.u[i],
            d=self.d,
            measured=self.measured[i],
            xc=self.xc[i],
            step_time=self._step_time,
            status=None,
            input_limit=self.input_limit,
            state_names=self.state_names,
            output_names=self.output_names,
            input_names=self.input_names,
            controller=self.controller,
            diverged_at=None if np.isnan(k) else float(k),
            params=self.params[i],
        )

    def __iter__(self) -> Iterator[ClosedLoopResult]:
        return (self[i] for i in range(len(self)))

    def __repr__(self) -> str:
        diverged = int(np.sum(~np.isnan(self.diverged_at)))
        return f"MonteCarloResult({self.controller!r}, {len(self)} samples x {len(self.t)} times, {diverged} diverged)"


def batch_outputs(plant: Plant, x: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Noise-free outputs of M trajectories, (M, P, ny), from states x (M, P, nx) and params (M, n_params)."""
    m, points = x.shape[0], x.shape[1]
    call = output_call(plant, points)
    y = np.empty((m, points, plant.ny))
    for i in range(m):
        y[i] = call(x[i].T, params[i])[0].T
    return y


def closed_loop_function(
    plant: Plant, controller: Block, n_steps: int, substeps: int = 10, jit: bool = False, smooth: bool = False
) -> ca.Function:
    """The whole run as one CasADi Function, differentiable in the gains and parameters.

    Signature ``(x0, xc0, R, noise, D, p, gains) -> (X, XC, U, measured)`` with
    R (n_reference, N), noise (n_measured, N), D (nu, N); X (nx, N) and XC
    (n_state, N) the states after each sample, U (nu, N) the commands.
    The plant receives `saturate(U)`, which keeps a NaN command NaN.
    Cached on the plant per (controller, N, substeps, jit, smooth); `jit`
    compiles it to machine code (see `models.compile`). `smooth` blends every
    switch of one closed-loop step (the saturations, the controller's
    conditional integration) over a band set by one more input, "width"
    (relative, > 0), with `models.smooth.smoothed`: a smooth run for
    gradient-based tuning, equal to the exact one wherever no sample falls in
    a band.
    """
    if not isinstance(plant, Plant):
        raise TypeError(f"plant must be a models.Plant, got {type(plant).__name__} {plant!r}")
    n_steps = integer(n_steps, "n_steps", minimum=1)
    substeps = integer(substeps, "substeps", minimum=1)
    jit, smooth = boolean(jit, "jit"), boolean(smooth, "smooth")
    if not isinstance(controller, Block):
        raise TypeError("closed_loop_function needs a Block (a controller written in CasADi)")
    key: tuple = ("closed_loop", id(controller.casadi_step), controller.sample_period, n_steps, substeps, jit)
    key += ("smooth",) if smooth else ()
    cache = plant.function_cache
    if key in cache:
        return cache[key][1]
    check_sizes(plant, controller)
    check_memory(
        8.0 * n_steps * doubles_per_step(plant, controller),
        f"closed_loop_function of {n_steps} steps of {plant.name}",
        "use fewer steps",
    )
    rk4 = plant.step_function(controller.sample_period, substeps)
    nx, nc = plant.nx, controller.n_state
    s = ca.SX.sym("s", nx + nc)
    r = ca.SX.sym("r", controller.n_reference)
    noise = ca.SX.sym("noise", controller.n_measured)
    d = ca.SX.sym("d", plant.nu)
    p = ca.SX.sym("p", plant.n_params)
    g = ca.SX.sym("gains", controller.gain_vector().size)
    x, xc = s[:nx], s[nx:]
    meas = (plant.casadi_h(x, p) if controller.measures == "outputs" else x) + noise
    xc_next, u = controller.casadi_step(xc, meas, r, g)
    x_next = rk4(x, saturate(u, plant.input_limit) + d, p)
    one = ca.Function("closed_loop_step", [s, r, noise, d, p, g], [ca.vertcat(x_next, xc_next), u, meas])
    if smooth:
        one = smoothed(one)
    run = one.mapaccum("closed_loop_run", n_steps)
    x0, xc0 = ca.MX.sym("x0", nx), ca.MX.sym("xc0", nc)
    R = ca.MX.sym("R", controller.n_reference, n_steps)
    Nz = ca.MX.sym("noise", controller.n_measured, n_steps)
    D = ca.MX.sym("D", plant.nu, n_steps)
    P, G = ca.MX.sym("p", plant.n_params), ca.MX.sym("gains", g.numel())
    inputs, names = [x0, xc0, R, Nz, D, P, G], ["x0", "xc0", "R", "noise", "D", "p", "gains"]
    if smooth:
        inputs, names = inputs + [ca.MX.sym("width")], names + ["width"]
    S, U, M = run(ca.vertcat(x0, xc0), *inputs[2:])
    fun = ca.Function("closed_loop", inputs, [S[:nx, :], S[nx:, :], U, M], names, ["X", "XC", "U", "measured"])
    # Holding the step Function keeps its id from being reused while cached.
    if jit:
        fun = compile_jit(fun)
    cache[key] = (controller.casadi_step, fun, NumpyCall(fun))
    return fun


def release(plant: Plant, controller: Block) -> int:
    """Drop the closed-loop Functions of `controller` cached on `plant`, with the work memory and output
    buffers they hold (hundreds of MB for a long run at a short sample period); returns how many.

    The next simulation of that controller builds (and, with jit, compiles) them again: call it when
    the controller's runs on this plant are done.
    """
    step = controller.casadi_step
    keys = [
        key
        for key, value in plant.function_cache.items()
        if isinstance(key, tuple)
        and key[0] in ("closed_loop", "closed_loop_batch")
        and isinstance(value, tuple)
        and value[0] is step
    ]
    for key in keys:
        del plant.function_cache[key]
    return len(keys)


def _numpy_run(plant: Plant, controller: Block, n_steps: int, substeps: int, jit: bool) -> NumpyCall:
    """The cached `closed_loop_function` wrapped for fast numpy evaluation."""
    closed_loop_function(plant, controller, n_steps, substeps, jit)
    key: tuple = ("closed_loop", id(controller.casadi_step), controller.sample_period, n_steps, substeps, jit)
    return plant.function_cache[key][2]


def _batch_run(
    plant: Plant, controller: Block, n_steps: int, substeps: int, jit: bool, size: int, threads: int, noisy: bool
) -> NumpyCall:
    """`size` closed-loop runs in one call, `threads` at a time; cached on the plant.

    ``(x0 (nx,), XC0 (n_state, size), R (n_reference, N), noise, D (nu, N), P (n_params, size), gains)
    -> (X (nx, N size), XC, U, measured)``, noise (n_measured, N size) when `noisy`, else
    (n_measured, N) shared. Output columns are sample-major: sample i owns columns i N .. (i+1) N - 1.
    """
    key = (
        "closed_loop_batch",
        id(controller.casadi_step),
        controller.sample_period,
        n_steps,
        substeps,
        jit,
        size,
        threads,
        noisy,
    )
    cache = plant.function_cache
    if key not in cache:
        run = closed_loop_function(plant, controller, n_steps, substeps, jit)
        mapped = run.map(size, "thread", min(threads, size)) if size > 1 else run
        nx, nc, nm = plant.nx, controller.n_state, controller.n_measured
        args = [
            ca.MX.sym("x0", nx),
            ca.MX.sym("xc0", nc, size),
            ca.MX.sym("R", controller.n_reference, n_steps),
            ca.MX.sym("noise", nm, n_steps * size if noisy else n_steps),
            ca.MX.sym("D", plant.nu, n_steps),
            ca.MX.sym("p", plant.n_params, size),
            ca.MX.sym("gains", controller.gain_vector().size),
        ]
        fun = ca.Function(
            "closed_loop_batch",
            args,
            mapped.call(args),
            ["x0", "xc0", "R", "noise", "D", "p", "gains"],
            ["X", "XC", "U", "measured"],
        )
        cache[key] = (controller.casadi_step, NumpyCall(fun))
    return cache[key][1]


def first_faults(
    x: np.ndarray, u: np.ndarray, xc: np.ndarray | None = None, bound: float = DIVERGENCE_BOUND
) -> np.ndarray:
    """Index k of the first fault of each run, -1 where there is none.

    A fault at sample k: x_k non-finite or beyond `bound`, u_k non-finite, or xc_k non-finite.

    Parameters
    ----------
    x : (M, N+1, nx);  u : (M, N, nu);  xc : (M, N+1, n_state) or None

    Returns
    -------
    ndarray of int, (M,)
    """

    def clean(arr, bound=None) -> np.ndarray:
        # Per run: finite (and within bound); two reductions, no temporary copy. NaN propagates
        # through max and min, so a NaN anywhere makes the run suspect.
        if arr is None or arr.size == 0:
            return np.ones(x.shape[0], dtype=bool)
        high, low = np.max(arr, axis=(1, 2)), np.min(arr, axis=(1, 2))
        ok = np.isfinite(high) & np.isfinite(low)
        return ok if bound is None else ok & (high <= bound) & (low >= -bound)

    first = np.full(x.shape[0], -1)
    suspect = ~(clean(x, bound) & clean(u) & clean(xc))
    for i in np.flatnonzero(suspect):
        with np.errstate(invalid="ignore"):
            bad = ~np.all(np.abs(x[i]) <= bound, axis=1)
        bad[:-1] |= ~np.all(np.isfinite(u[i]), axis=1)
        if xc is not None and xc.shape[2]:
            bad |= ~np.all(np.isfinite(xc[i]), axis=1)
        if np.any(bad):
            first[i] = int(np.argmax(bad))
    return first


def _fault_cause(x, u, xc, k: int) -> str:
    if xc is not None and xc.shape[1] and not np.all(np.isfinite(xc[k])):
        return "the controller's state became non-finite"
    if k < len(u) and not np.all(np.isfinite(u[k])):
        return f"the command u = {u[k]} is not finite"
    return f"the state left |x| <= {DIVERGENCE_BOUND:g} or became non-finite"


def simulate_closed_loop(
    plant: Plant,
    controller,
    reference,
    duration: float,
    *,
    x0=None,
    params=None,
    substeps: int = 10,
    input_disturbance=0.0,
    noise_std=0.0,
    seed: int | None = 0,
    xc0=None,
    compiled: bool | None = None,
    allow_divergence: bool = False,
    jit: bool = False,
) -> ClosedLoopResult:
    """Run `controller` on `plant` for `duration` s.

    Parameters
    ----------
    plant : Plant
        The truth: simulated with `params` (default: the plant's own values).
    controller : Block or any Controller
        Designed from the parameters known to it.
    reference : constant, callable t -> r, or array (N+1, n_reference)
    duration : float, s
    x0 : (nx,), default the plant's standard equilibrium state
    input_disturbance : constant, callable or array (N, nu), added at the plant input
    noise_std : float or (n_measured,), standard deviation of Gaussian measurement noise
    seed : seed of the noise generator (None, an integer >= 0, or a numpy SeedSequence)
    compiled : force (True) or refuse (False) the compiled path; default: compiled for Blocks
    allow_divergence : return a result with `diverged_at` set instead of raising
    jit : compile the run to machine code first (Blocks only; pays off for long or repeated runs)

    Raises
    ------
    SimulationError
        When the run diverges (see the module docstring), naming the time and the cause.
    ResourceLimitError
        Before any work, when the run would need more than `models.checks.MEMORY_LIMIT_BYTES`.
    """
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
    allow_divergence, jit = boolean(allow_divergence, "allow_divergence"), boolean(jit, "jit")
    p = plant.param_vector(params)
    noise = setup.noise()
    n = setup.n_steps
    y0 = (plant.output(setup.x0, p) if controller.measures == "outputs" else setup.x0) + (noise[0] if n else 0.0)
    name = getattr(controller, "name", "controller")
    if xc0 is not None:
        size = controller.n_state if isinstance(controller, Block) else np.size(xc0)
        xc_init = as_vector(xc0, size, f"{name}: initial controller state xc0")
    else:
        xc_init = np.asarray(controller.initial_state(y0, setup.r[0]), dtype=float).ravel()
        if isinstance(controller, Block) and xc_init.size != controller.n_state:
            raise ValueError(f"{name}.initial_state returned {xc_init.size} values, its state has {controller.n_state}")
    use_compiled = isinstance(controller, Block) if compiled is None else boolean(compiled, "compiled")
    if use_compiled and not isinstance(controller, Block):
        raise TypeError("only a Block can run compiled")
    if use_compiled:
        run = _numpy_run(plant, controller, n, setup.substeps, jit)
        X, XC, U, M = run(setup.x0, xc_init, setup.r[:-1].T, noise.T, setup.d.T, p, controller.gain_vector())
        x = np.vstack([setup.x0, X.T])
        xc = np.vstack([xc_init, XC.T]) if controller.n_state else np.zeros((n + 1, 0))
        u, measured = U.T, M.T
        step_time = _time_block(controller, xc[:-1], measured, setup.r[:-1])
        status = None
        xc_check = xc
    else:
        x, u, measured, step_time, status, xc, xc_check = _python_loop(plant, controller, setup, p, noise, xc_init)
    k = int(first_faults(x[None], u[None], None if xc_check is None else xc_check[None])[0])
    diverged_at = None if k < 0 else float(setup.t[k])
    if diverged_at is not None and not allow_divergence:
        raise SimulationError(
            f"{plant.name} under {name}: closed loop diverged at t = {diverged_at:.4g} s "
            f"({_fault_cause(x, u, xc_check, k)})"
        )
    y = batch_outputs(plant, x[None], p[None])[0]
    return ClosedLoopResult(
        t=setup.t,
        x=x,
        y=y,
        r=setup.r,
        u=u,
        d=setup.d,
        measured=measured,
        xc=xc,
        step_time=step_time,
        status=status,
        input_limit=plant.input_limit.copy(),
        state_names=plant.state_names,
        output_names=plant.output_names,
        input_names=plant.input_names,
        controller=getattr(controller, "name", ""),
        diverged_at=diverged_at,
        params=p,
    )


def _time_block(controller: Block, xc, measured, r) -> np.ndarray:
    """Controller-only compute time per sample: the step mapped over the recorded inputs."""
    n = len(measured)
    mapped = controller.casadi_step.map(n)
    args = (xc.T if controller.n_state else np.zeros((0, n)), measured.T, r.T, controller.gain_vector())
    start = time.perf_counter()
    mapped(*args)
    return np.full(n, (time.perf_counter() - start) / n)


def _python_loop(plant, controller, setup: RunSetup, p, noise, xc):
    """Step any controller in Python; stops at the first fault, leaving NaN after it.

    Returns (x, u, measured, step_time, status, xc history of a Block or None,
    controller states as an array for fault detection or None).
    """
    n = setup.n_steps
    # NumpyCall: CasADi's own call converts through DM, about 10 µs a call, as much as the step itself.
    rk4 = NumpyCall(plant.step_function(controller.sample_period, setup.substeps))
    h = NumpyCall(plant.casadi_h)
    x = np.full((n + 1, plant.nx), np.nan)
    x[0] = setup.x0
    u = np.full((n, plant.nu), np.nan)
    measured = np.full((n, setup.n_measured), np.nan)
    step_time = np.full(n, np.nan)
    states = [np.asarray(xc, dtype=float)]
    status: list | None = [] if hasattr(controller, "step_info") else None
    limit = plant.input_limit
    name = getattr(controller, "name", "controller")
    for k in range(n if np.all(np.isfinite(states[0])) else 0):
        interrupts.check()  # a Ctrl-C the previous step's CasADi calls swallowed
        meas = (h(x[k], p)[0].ravel() if controller.measures == "outputs" else x[k]) + noise[k]
        start = time.perf_counter()
        xc, uk = controller.step(xc, meas, setup.r[k])
        step_time[k] = time.perf_counter() - start
        if status is not None:
            status.append(controller.step_info())
        uk = np.asarray(uk, dtype=float).ravel()
        if uk.size != plant.nu:
            raise ValueError(f"{name} returned {uk.size} inputs, {plant.name} takes {plant.nu}")
        u[k], measured[k] = uk, meas
        states.append(np.asarray(xc, dtype=float))
        if not np.all(np.isfinite(uk)):
            break  # the plant's input is undefined: its state stays NaN from here on
        x[k + 1] = rk4(x[k], saturate(uk, limit) + setup.d[k], p)[0].ravel()
        if (
            not np.all(np.isfinite(states[-1]))
            or not np.all(np.isfinite(x[k + 1]))
            or np.any(np.abs(x[k + 1]) > DIVERGENCE_BOUND)
        ):
            break
    padded = None
    try:
        history = np.array(states, dtype=float).reshape(len(states), -1)
        padded = np.vstack([history, np.full((n + 1 - len(history), history.shape[1]), np.nan)])
    except ValueError:  # a controller whose state changes shape: only its commands are checked
        pass
    xc_hist = padded if isinstance(controller, Block) else None
    return x, u, measured, step_time, status, xc_hist, padded


#: Samples stepped together by `simulate_closed_loop_many`: enough to spread the per-step Python work,
#: few enough that the runs' step records (one dict per sample and step) stay small.
LOCKSTEP_SAMPLES = 50


class _MappedCalls:
    """`fun` mapped over m samples, as a NumpyCall built once per m (m changes only when runs stop)."""

    def __init__(self, fun: ca.Function):
        self.fun = fun
        self._calls: dict[int, NumpyCall] = {}

    def __call__(self, m: int, *args) -> list[np.ndarray]:
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
    other arguments : as `simulate_closed_loop`; every run gets the same noise (`seed`)

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


def _lockstep(plant, controller, setup, params, noise, rk4, measure) -> list[ClosedLoopResult]:
    """Runs of `params` (m, n_params) stepped together; see `simulate_closed_loop_many`."""
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
    results = []
    for i in range(m):
        results.append(
            ClosedLoopResult(
                t=setup.t,
                x=x[i],
                y=y[i],
                r=setup.r,
                u=u[i],
                d=setup.d,
                measured=measured[i],
                xc=None,
                step_time=step_time[i],
                status=records[i],
                input_limit=plant.input_limit.copy(),
                state_names=plant.state_names,
                output_names=plant.output_names,
                input_names=plant.input_names,
                controller=getattr(controller, "name", ""),
                diverged_at=None if first[i] < 0 else float(setup.t[first[i]]),
                params=params[i],
            )
        )
    return results


@dataclass(frozen=True)
class MonteCarloPlan:
    """A checked Monte Carlo request: the shared run inputs, the samples and how to batch them.

    Attributes
    ----------
    setup : the run inputs every sample shares (its seed an integer >= 0)
    samples : (M, n_params) actual parameters of each sample
    threads : evaluations run in parallel within a chunk
    jit : compile the closed loop to machine code first
    chunk : samples per batched call
    chunk_bytes : estimated working memory of one chunk's call, bytes
    first_sample : index of the first row of `samples` in the whole sample set (it sets the noise)
    """

    setup: RunSetup
    samples: np.ndarray
    threads: int
    jit: bool
    chunk: int
    chunk_bytes: float
    first_sample: int = 0

    @classmethod
    def build(
        cls,
        plant: Plant,
        controller: Block,
        setup: RunSetup,
        param_samples,
        *,
        threads: int = 2,
        jit: bool = False,
        chunk_size: int | None = None,
        first_sample: int = 0,
    ) -> MonteCarloPlan:
        """Check the Monte Carlo's own arguments and size its chunks.

        Parameters
        ----------
        setup : from `RunSetup.build` for `plant` and `controller`
        param_samples : (M, n_params), M >= 1, every entry a valid value of its parameter
        chunk_size : samples per batched call; default the most that keeps one chunk within
            `MONTE_CARLO_CHUNK_BYTES` and `MONTE_CARLO_CHUNK_STEPS` (at least `threads`)
        """
        samples = as_matrix(param_samples, plant.n_params, "param_samples")
        if samples.shape[0] == 0:
            raise ValueError("param_samples has no rows; give at least one parameter vector")
        must_be_positive = np.array([p.positive for p in plant.param_info], dtype=bool)
        invalid = np.any((samples < 0) | ((samples == 0) & must_be_positive), axis=1)
        if np.any(invalid):
            row = int(np.argmax(invalid))
            try:
                plant.param_vector(samples[row])
            except ValueError as err:
                raise ValueError(f"param_samples row {row}: {err}") from None
        threads = integer(threads, "threads", minimum=1)
        jit = boolean(jit, "jit")
        integer(setup.seed, "seed", minimum=0)  # each sample's noise is seeded with (seed, index)
        n, m, nc = setup.n_steps, samples.shape[0], controller.n_state
        nm = setup.n_measured
        work = 8.0 * n * (3 * (plant.nx + nc) + 2 * plant.nu + (3 if setup.noisy else 2) * nm + controller.n_reference)
        if chunk_size is None:
            by_steps = max(threads, MONTE_CARLO_CHUNK_STEPS // max(n, 1))
            chunk = int(min(m, max(1, min(by_steps, MONTE_CARLO_CHUNK_BYTES // work))))
        else:
            chunk = min(m, integer(chunk_size, "chunk_size", minimum=1))
        first_sample = integer(first_sample, "first_sample", minimum=0)
        return cls(setup, samples, threads, jit, chunk, chunk * work, first_sample)

    def sample_bytes(self, plant: Plant, controller: Block) -> float:
        """Bytes the results of one sample hold: x, xc, y over N+1 samples, u and measured over N."""
        n, nm = self.setup.n_steps, self.setup.n_measured
        return 8.0 * ((n + 1) * (plant.nx + controller.n_state + plant.ny) + n * (plant.nu + nm) + 1)

    def chunks(self) -> Iterator[tuple[int, int]]:
        """(start, stop) of each chunk of samples, in order."""
        m = self.samples.shape[0]
        for start in range(0, m, self.chunk):
            yield start, min(m, start + self.chunk)


def _require_block(controller) -> None:
    if not isinstance(controller, Block):
        raise TypeError("monte_carlo batches Blocks; run other controllers with simulate_closed_loop")


def _run_chunk(plant, controller, plan: MonteCarloPlan, start, stop, out) -> None:
    """Run samples start..stop-1 into the arrays `out` (x, xc, u, measured, diverged_at) of stop - start rows."""
    setup, samples, n = plan.setup, plan.samples, plan.setup.n_steps
    c = stop - start
    nx, nc, nm = plant.nx, controller.n_state, setup.n_measured
    noise = np.zeros((c, n, nm)) if setup.noisy else None
    if noise is not None:
        for j in range(c):
            noise[j] = setup.noise(sample=plan.first_sample + start + j)
    if controller.measures == "outputs":
        y0 = batch_outputs(plant, np.broadcast_to(setup.x0, (c, 1, nx)), samples[start:stop])[:, 0]
    else:
        y0 = np.broadcast_to(setup.x0, (c, nx))
    if noise is not None and n:
        y0 = y0 + noise[:, 0]
    # One initial_state call per distinct first measurement (all samples share it without noise).
    rows, inverse = np.unique(y0, axis=0, return_inverse=True)
    initial = np.array(
        [np.asarray(controller.initial_state(row, setup.r[0]), dtype=float).ravel() for row in rows]
    ).reshape(len(rows), nc)
    xc0 = initial[np.ravel(inverse)]
    call = _batch_run(plant, controller, n, setup.substeps, plan.jit, c, plan.threads, setup.noisy)
    noise_arg = noise.reshape(c * n, nm).T if noise is not None else np.zeros((nm, n))
    X, XC, U, M = call(
        setup.x0, xc0.T, setup.r[:-1].T, noise_arg, setup.d.T, samples[start:stop].T, controller.gain_vector()
    )
    x, xc, u, measured, diverged_at = out
    x[:, 0], x[:, 1:] = setup.x0, X.T.reshape(c, n, nx)
    xc[:, 0], xc[:, 1:] = xc0, XC.T.reshape(c, n, nc)
    u[:] = U.T.reshape(c, n, plant.nu)
    measured[:] = M.T.reshape(c, n, nm)
    first = first_faults(x, u, xc)
    diverged_at[:] = np.where(first >= 0, setup.t[np.maximum(first, 0)], np.nan)


def _allocate(plant, controller, plan: MonteCarloPlan, m) -> tuple:
    n, nm = plan.setup.n_steps, plan.setup.n_measured
    return (
        np.empty((m, n + 1, plant.nx)),
        np.empty((m, n + 1, controller.n_state)),
        np.empty((m, n, plant.nu)),
        np.empty((m, n, nm)),
        np.empty(m),
    )


def monte_carlo(
    plant: Plant,
    controller: Block,
    reference,
    duration: float,
    param_samples,
    *,
    x0=None,
    substeps: int = 10,
    input_disturbance=0.0,
    noise_std=0.0,
    seed: int = 0,
    threads: int = 2,
    jit: bool = False,
    chunk_size: int | None = None,
    first_sample: int = 0,
) -> MonteCarloResult:
    """Run `controller` on every parameter sample, a chunk of samples per batched CasADi map.

    Parameters
    ----------
    param_samples : array (M, n_params) of actual parameter vectors (see `models.uncertainty`)
    seed : integer >= 0; the noise of sample i is drawn from the generator seeded with (seed, i)
    threads : evaluations run in parallel within a chunk
    jit : compile the closed loop to machine code first (see `models.compile`)
    chunk_size : samples per batched call; default from `MONTE_CARLO_CHUNK_BYTES`. Results do not
        depend on it.
    first_sample : index of the first row of `param_samples` in a larger sample set: row j gets the
        noise of sample first_sample + j, so a set split into parts (for other processes) runs as a whole

    Returns
    -------
    MonteCarloResult: the batch as arrays; ``result[i]`` is sample i as a `ClosedLoopResult`, and a
    diverged sample has `diverged_at` set.

    Raises
    ------
    ResourceLimitError
        Before any work, when the results would need more than `models.checks.MEMORY_LIMIT_BYTES`;
        `monte_carlo_chunks` then runs the same samples holding one chunk at a time.
    """
    _require_block(controller)
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
    plan = MonteCarloPlan.build(
        plant,
        controller,
        setup,
        param_samples,
        threads=threads,
        jit=jit,
        chunk_size=chunk_size,
        first_sample=first_sample,
    )
    m, n = plan.samples.shape[0], plan.setup.n_steps
    per_sample = plan.sample_bytes(plant, controller)
    check_memory(
        m * per_sample + plan.chunk_bytes,
        f"monte_carlo of {m} samples x {n} steps ({format_bytes(per_sample)} per sample)",
        "run them with models.monte_carlo_chunks, which holds one chunk at a time",
    )
    out = _allocate(plant, controller, plan, m)
    for start, stop in plan.chunks():
        _run_chunk(plant, controller, plan, start, stop, tuple(a[start:stop] for a in out))
    return _result(plant, controller, plan, out, plan.samples, plan.first_sample)


def monte_carlo_chunks(
    plant: Plant,
    controller: Block,
    reference,
    duration: float,
    param_samples,
    *,
    x0=None,
    substeps: int = 10,
    input_disturbance=0.0,
    noise_std=0.0,
    seed: int = 0,
    threads: int = 2,
    jit: bool = False,
    chunk_size: int | None = None,
) -> Iterator[MonteCarloResult]:
    """`monte_carlo`, one chunk of samples at a time: memory stays bounded by the chunk.

    Arguments as `monte_carlo`; every argument is checked before the first chunk runs. Sample i
    gets the same noise and the same numbers as in `monte_carlo` (each chunk's `first_sample`
    says where it starts).

    Yields
    ------
    MonteCarloResult of samples first_sample .. first_sample + len - 1
    """
    _require_block(controller)
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
    plan = MonteCarloPlan.build(
        plant, controller, setup, param_samples, threads=threads, jit=jit, chunk_size=chunk_size
    )
    check_memory(
        plan.chunk * plan.sample_bytes(plant, controller) + plan.chunk_bytes,
        f"a Monte Carlo chunk of {plan.chunk} samples x {plan.setup.n_steps} steps",
        "give a smaller chunk_size",
    )

    def chunks():
        for start, stop in plan.chunks():
            out = _allocate(plant, controller, plan, stop - start)
            _run_chunk(plant, controller, plan, start, stop, out)
            yield _result(plant, controller, plan, out, plan.samples[start:stop], start)

    return chunks()


def _result(plant, controller, plan: MonteCarloPlan, out, samples, first_sample) -> MonteCarloResult:
    setup = plan.setup
    x, xc, u, measured, diverged_at = out
    return MonteCarloResult(
        plant=plant,
        controller=controller.name,
        t=setup.t,
        r=setup.r,
        d=setup.d,
        x=x,
        xc=xc,
        u=u,
        measured=measured,
        params=np.array(samples),
        diverged_at=diverged_at,
        first_sample=first_sample,
    )
