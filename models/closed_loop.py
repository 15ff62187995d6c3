"""The closed-loop simulator: plant (actual parameters) + controller, sampled and held; one run.

Every sample k (t_k = k * Ts, Ts the controller's sample period):

    y_k   = h(x_k) + n_k           (or x_k + n_k for controllers that measure the state)
    x_c,k+1, u_k = controller.step(x_c,k, y_k, r_k)
    x_k+1 = RK4 over Ts of the plant with input clip(u_k, ±input_limit) + d_k

n_k is seeded Gaussian measurement noise, d_k an input disturbance (their
arguments are checked once, into a `models.run_setup.RunSetup`). For a
`Block` the whole run is one CasADi mapaccum (`closed_loop_function`); other
controllers (MPC) run the same step in a Python loop. Many parameter samples:
`models.monte_carlo_batch` (a Block, one CasADi map of the run) and
`models.lockstep` (any controller that steps many samples at once).

Divergence, on every path: a run diverges at the first sample t_k at which
the plant state x_k is non-finite or beyond `DIVERGENCE_BOUND`, the command
u_k is non-finite, or a `Block`'s state x_c,k is non-finite. A NaN command is
never clipped into a finite force: the plant's input is undefined from then
on, and the states after it are NaN.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from . import interrupts
from .block import Block, saturate
from .checks import SimulationError, as_vector, boolean, check_memory, integer
from .compile import NumpyCall
from .compile import jit as compile_jit
from .mc_kernel import KernelUnavailable, closed_loop_step, kernel
from .plant import Plant
from .run_setup import RunSetup, Seed, check_sizes, doubles_per_step
from .simulate import DIVERGENCE_BOUND, output_call
from .smooth import smoothed


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
    state_names, output_names, input_names : the plant's names, for `state` and `output`
    controller : the controller's name
    params : (n_params,) the plant parameters of the run, or None
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
        """The output called `name` (noise-free) over time, (N+1,)."""
        return self.y[:, self.output_names.index(name)]

    def state(self, name: str) -> np.ndarray:
        """The plant state called `name` over time, (N+1,)."""
        return self.x[:, self.state_names.index(name)]

    @classmethod
    def of_run(
        cls,
        plant: Plant,
        controller,
        setup: RunSetup,
        *,
        x: np.ndarray,
        y: np.ndarray,
        u: np.ndarray,
        measured: np.ndarray,
        xc: np.ndarray | None,
        step_time: np.ndarray,
        status: list | None,
        diverged_at: float | None,
        params: np.ndarray,
    ) -> ClosedLoopResult:
        """A run's result: its arrays (shapes as the attributes), with the time grid, reference and
        disturbance of `setup` and the limit and signal names of `plant`."""
        return cls(
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
            params=params,
        )


@dataclass(frozen=True)
class _Trace:
    """What one run recorded, before its outputs and its first fault are worked out.

    x : (N+1, nx);  u : (N, nu);  measured : (N, n_measured);  step_time : (N,) s
    status : the controller's per-step records, or None
    xc : (N+1, n_state) the controller state of a Block, else None
    xc_check : the controller states as an array, for the fault check (None when their shape changed)
    y : (N+1, ny) the noise-free outputs where the run computed them (the C kernel), else None
    """

    x: np.ndarray
    u: np.ndarray
    measured: np.ndarray
    step_time: np.ndarray
    status: list | None
    xc: np.ndarray | None
    xc_check: np.ndarray | None
    y: np.ndarray | None = None


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

    Signature ``(x0, xc0, R, noise, D, p, gains) -> (X, XC, U, measured)`` over N = `n_steps` samples, with
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
    key = _cache_key(controller, n_steps, substeps, jit, smooth)
    cache = plant.function_cache
    if key in cache:
        return cache[key][1]
    check_sizes(plant, controller)
    check_memory(
        8.0 * n_steps * doubles_per_step(plant, controller),
        f"closed_loop_function of {n_steps} steps of {plant.name}",
        "use fewer steps",
    )
    advance = closed_loop_step(plant, controller, substeps)
    nx, nc = plant.nx, controller.n_state
    s = ca.SX.sym("s", nx + nc)
    r = ca.SX.sym("r", controller.n_reference)
    noise = ca.SX.sym("noise", controller.n_measured)
    d = ca.SX.sym("d", plant.nu)
    p = ca.SX.sym("p", plant.n_params)
    g = ca.SX.sym("gains", controller.gain_vector().size)
    x = s[:nx]
    meas = (plant.casadi_h(x, p) if controller.measures == "outputs" else x) + noise
    s_next, u = advance(s, meas, r, d, p, g)
    one = ca.Function("closed_loop_step", [s, r, noise, d, p, g], [s_next, u, meas])
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
        and key[0] in ("closed_loop", "closed_loop_batch", "mc_kernel")
        and isinstance(value, tuple)
        and value[0] is step
    ]
    for key in keys:
        del plant.function_cache[key]
    return len(keys)


def _cache_key(controller: Block, n_steps: int, substeps: int, jit: bool, smooth: bool = False) -> tuple:
    """The key of a `closed_loop_function` in the plant's function cache."""
    key: tuple = ("closed_loop", id(controller.casadi_step), controller.sample_period, n_steps, substeps, jit)
    return key + (("smooth",) if smooth else ())


#: Steps per call of a single run's closed loop: building CasADi's mapaccum of a run costs time that grows
#: with its length (about 0.4 s at 10,000 steps, 20 ms at 1,000), so longer runs call a Function of this
#: many steps once per block. The numbers do not depend on it.
RUN_BLOCK_STEPS = 1024


def _numpy_run(plant: Plant, controller: Block, n_steps: int, substeps: int, jit: bool) -> NumpyCall:
    """The cached `closed_loop_function` wrapped for fast numpy evaluation."""
    closed_loop_function(plant, controller, n_steps, substeps, jit)
    return plant.function_cache[_cache_key(controller, n_steps, substeps, jit)][2]


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
    """Why a run faulted at sample k (x (N+1, nx), u (N, nu), xc (N+1, n_state) or None), for the message."""
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
    seed: Seed = 0,
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
    jit : compile the run to machine code first (Blocks only; pays off for long or repeated runs): the C
        kernel of `models.mc_kernel` as a batch of one, the numbers `monte_carlo(..., jit=True)` gives
        this sample; where there is none, the compiled CasADi run
    substeps : RK4 steps of the plant per controller sample
    xc0 : the controller's initial state; default its `initial_state` from the first measurement and reference

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
    xc_init = _initial_controller_state(plant, controller, setup, p, noise, xc0)
    use_compiled = isinstance(controller, Block) if compiled is None else boolean(compiled, "compiled")
    if use_compiled and not isinstance(controller, Block):
        raise TypeError("only a Block can run compiled")
    if use_compiled:
        trace = _compiled_run(plant, controller, setup, p, noise, xc_init, jit)
    else:
        trace = _python_loop(plant, controller, setup, p, noise, xc_init)
    x, u, xc_check = trace.x, trace.u, trace.xc_check
    k = int(first_faults(x[None], u[None], None if xc_check is None else xc_check[None])[0])
    diverged_at = None if k < 0 else float(setup.t[k])
    if diverged_at is not None and not allow_divergence:
        raise SimulationError(
            f"{plant.name} under {getattr(controller, 'name', 'controller')}: closed loop diverged at "
            f"t = {diverged_at:.4g} s ({_fault_cause(x, u, xc_check, k)})"
        )
    return ClosedLoopResult.of_run(
        plant,
        controller,
        setup,
        x=x,
        y=batch_outputs(plant, x[None], p[None])[0] if trace.y is None else trace.y,
        u=u,
        measured=trace.measured,
        xc=trace.xc,
        step_time=trace.step_time,
        status=trace.status,
        diverged_at=diverged_at,
        params=p,
    )


def _initial_controller_state(plant: Plant, controller, setup: RunSetup, p, noise, xc0) -> np.ndarray:
    """x_c at the first sample: `xc0` checked, or the controller's `initial_state` from y_0 and r_0.

    y_0 is the first measurement (with its noise, noise[0]) at the plant's actual parameters p.
    """
    name = getattr(controller, "name", "controller")
    if xc0 is not None:
        size = controller.n_state if isinstance(controller, Block) else np.size(xc0)
        return as_vector(xc0, size, f"{name}: initial controller state xc0")
    y0 = (plant.output(setup.x0, p) if controller.measures == "outputs" else setup.x0) + (
        noise[0] if setup.n_steps else 0.0
    )
    xc_init = np.asarray(controller.initial_state(y0, setup.r[0]), dtype=float).ravel()
    if isinstance(controller, Block) and xc_init.size != controller.n_state:
        raise ValueError(f"{name}.initial_state returned {xc_init.size} values, its state has {controller.n_state}")
    return xc_init


def _compiled_run(plant: Plant, controller: Block, setup: RunSetup, p, noise, xc_init, jit: bool) -> _Trace:
    """The run of a Block by its cached `closed_loop_function`: one call, or for a run longer than
    `RUN_BLOCK_STEPS` one call per block of that many steps, each from the state the last left (the
    same numbers: the same steps in the same order); noise (N, n_measured)."""
    n = setup.n_steps
    if jit:
        try:
            compiled = kernel(plant, controller, setup.substeps)
        except KernelUnavailable:
            pass  # the compiled CasADi run below
        else:
            out = {
                "x": np.empty((1, n + 1, plant.nx)),
                "xc": np.empty((1, n + 1, controller.n_state)),
                "y": np.empty((1, n + 1, plant.ny)),
                "u": np.empty((1, n, plant.nu)),
                "measured": np.empty((1, n, setup.n_measured)),
            }
            noisy = noise[None] if setup.noisy else None
            compiled.run(setup.x0, xc_init[None], setup.r[:-1], noisy, setup.d, p[None], controller.gain_vector(), out)
            x, xc, u, measured = out["x"][0], out["xc"][0], out["u"][0], out["measured"][0]
            step_time = _time_block(controller, xc[:-1], measured, setup.r[:-1])
            return _Trace(x, u, measured, step_time, None, xc, xc, out["y"][0])
    X, XC, U, M = _blocked_run(plant, controller, setup, p, noise, xc_init, jit)
    x = np.vstack([setup.x0, X.T])
    xc = np.vstack([xc_init, XC.T]) if controller.n_state else np.zeros((n + 1, 0))
    u, measured = U.T, M.T
    step_time = _time_block(controller, xc[:-1], measured, setup.r[:-1])
    return _Trace(x, u, measured, step_time, None, xc, xc)


def _blocked_run(plant: Plant, controller: Block, setup: RunSetup, p, noise, xc_init, jit: bool) -> list:
    """(X, XC, U, M) of `closed_loop_function`'s whole run, computed a block of at most `RUN_BLOCK_STEPS`
    steps at a time (the last block's inputs padded with zeros, its extra steps dropped)."""
    n, gains = setup.n_steps, controller.gain_vector()
    inputs = [setup.r[:-1].T, noise.T, setup.d.T]
    if n <= RUN_BLOCK_STEPS:
        return _numpy_run(plant, controller, n, setup.substeps, jit)(setup.x0, xc_init, *inputs, p, gains)
    run = _numpy_run(plant, controller, RUN_BLOCK_STEPS, setup.substeps, jit)
    blocks = -(-n // RUN_BLOCK_STEPS)
    padded = [np.hstack([a, np.zeros((a.shape[0], blocks * RUN_BLOCK_STEPS - n))]) for a in inputs]
    x, xc, parts = setup.x0, xc_init, []
    for b in range(blocks):
        columns = slice(b * RUN_BLOCK_STEPS, (b + 1) * RUN_BLOCK_STEPS)
        with np.errstate(all="ignore"):  # the padded steps past the run may overflow; they are dropped
            out = run(x, xc, *(a[:, columns] for a in padded), p, gains)
        parts.append(out)
        x, xc = out[0][:, -1], out[1][:, -1]
    return [np.hstack([part[i] for part in parts])[:, :n] for i in range(4)]


def _time_block(controller: Block, xc, measured, r) -> np.ndarray:
    """Controller-only compute time per sample, (N,) s, each the mean: the step mapped over the first
    `RUN_BLOCK_STEPS` recorded inputs (building the map of a longer run costs more than the timing tells)."""
    n = len(measured)
    m = min(n, RUN_BLOCK_STEPS)
    mapped = controller.casadi_step.map(m)
    args = (xc[:m].T if controller.n_state else np.zeros((0, m)), measured[:m].T, r[:m].T, controller.gain_vector())
    start = time.perf_counter()
    mapped(*args)
    return np.full(n, (time.perf_counter() - start) / max(m, 1))


def _python_loop(plant: Plant, controller, setup: RunSetup, p, noise, xc) -> _Trace:
    """Step any controller in Python from its state `xc`; stops at the first fault, leaving NaN after it."""
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
    return _Trace(x, u, measured, step_time, status, xc_hist, padded)
