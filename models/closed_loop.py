"""The closed-loop simulator: plant (actual parameters) + controller, sampled and held.

Every sample k (t_k = k * Ts, Ts the controller's sample period):

    y_k   = h(x_k) + n_k           (or x_k + n_k for controllers that measure the state)
    x_c,k+1, u_k = controller.step(x_c,k, y_k, r_k)
    x_k+1 = RK4 over Ts of the plant with input clip(u_k, ±input_limit) + d_k

n_k is seeded Gaussian measurement noise, d_k an input disturbance. For a
`Block` the whole run is one CasADi mapaccum (and a Monte Carlo one map of
it); other controllers (MPC) run the same step in a Python loop.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .block import Block, Controller
from .checks import SimulationError, as_matrix, as_vector, first_divergence
from .compile import NumpyCall, jit as compile_jit
from .plant import Plant
from .signals import sample
from .simulate import DIVERGENCE_BOUND


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
    diverged_at : time in s at which the state diverged, or None
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
    params: np.ndarray = field(default=None, repr=False)

    def output(self, name: str) -> np.ndarray:
        """The named (noise-free) output over time, (N+1,)."""
        return self.y[:, self.output_names.index(name)]

    def state(self, name: str) -> np.ndarray:
        return self.x[:, self.state_names.index(name)]


def closed_loop_function(plant: Plant, controller: Block, n_steps: int, substeps: int = 10,
                         jit: bool = False) -> ca.Function:
    """The whole run as one CasADi Function, differentiable in the gains and parameters.

    Signature ``(x0, xc0, R, noise, D, p, gains) -> (X, XC, U, measured)`` with
    R (n_reference, N), noise (n_measured, N), D (nu, N); X (nx, N) and XC
    (n_state, N) the states after each sample, U (nu, N) the commands.
    Cached on the plant per (controller, N, substeps, jit); `jit` compiles it
    to machine code (see `models.compile`).
    """
    key = ("closed_loop", id(controller.casadi_step), controller.sample_period, n_steps, substeps, jit)
    cache = plant.function_cache
    if key in cache:
        return cache[key][1]
    if not isinstance(controller, Block):
        raise TypeError("closed_loop_function needs a Block (a controller written in CasADi)")
    _check_sizes(plant, controller)
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
    x_next = rk4(x, ca.fmin(ca.fmax(u, -plant.input_limit), plant.input_limit) + d, p)
    one = ca.Function("closed_loop_step", [s, r, noise, d, p, g], [ca.vertcat(x_next, xc_next), u, meas])
    run = one.mapaccum("closed_loop_run", n_steps)
    x0, xc0 = ca.MX.sym("x0", nx), ca.MX.sym("xc0", nc)
    R = ca.MX.sym("R", controller.n_reference, n_steps)
    Nz = ca.MX.sym("noise", controller.n_measured, n_steps)
    D = ca.MX.sym("D", plant.nu, n_steps)
    P, G = ca.MX.sym("p", plant.n_params), ca.MX.sym("gains", g.numel())
    S, U, M = run(ca.vertcat(x0, xc0), R, Nz, D, P, G)
    fun = ca.Function("closed_loop", [x0, xc0, R, Nz, D, P, G], [S[:nx, :], S[nx:, :], U, M],
                      ["x0", "xc0", "R", "noise", "D", "p", "gains"], ["X", "XC", "U", "measured"])
    # Holding the step Function keeps its id from being reused while cached.
    if jit:
        fun = compile_jit(fun)
    cache[key] = (controller.casadi_step, fun, NumpyCall(fun))
    return fun


def _numpy_run(plant: Plant, controller: Block, n_steps: int, substeps: int, jit: bool) -> NumpyCall:
    """The cached `closed_loop_function` wrapped for fast numpy evaluation."""
    closed_loop_function(plant, controller, n_steps, substeps, jit)
    key = ("closed_loop", id(controller.casadi_step), controller.sample_period, n_steps, substeps, jit)
    return plant.function_cache[key][2]


def _check_sizes(plant: Plant, controller) -> None:
    n_meas = plant.ny if controller.measures == "outputs" else plant.nx
    if isinstance(controller, Block):
        if controller.n_measured != n_meas:
            raise ValueError(f"{controller.name} reads {controller.n_measured} measurements but "
                             f"{plant.name} provides {n_meas} ({controller.measures})")
        if controller.n_input != plant.nu:
            raise ValueError(f"{controller.name} gives {controller.n_input} inputs, {plant.name} takes {plant.nu}")


@dataclass(frozen=True)
class _Setup:
    t: np.ndarray
    x0: np.ndarray
    r: np.ndarray
    d: np.ndarray
    noise_std: np.ndarray
    n_meas: int


def _setup(plant, controller, reference, duration, x0, input_disturbance, noise_std) -> _Setup:
    if not isinstance(controller, Controller):
        raise TypeError(f"{controller!r} is not a controller: it needs sample_period, measures, "
                        "n_reference, initial_state and step")
    _check_sizes(plant, controller)
    ts = controller.sample_period
    if not np.isfinite(duration) or duration <= 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    n = int(round(duration / ts))
    if n < 1:
        raise ValueError(f"duration {duration} s is shorter than one sample ({ts} s)")
    t = ts * np.arange(n + 1)
    x0 = plant.equilibrium()[0] if x0 is None else as_vector(x0, plant.nx, f"{plant.name} initial state")
    r = sample(reference, t, controller.n_reference, "reference")
    d = sample(input_disturbance, t[:-1], plant.nu, "input disturbance")
    n_meas = plant.ny if controller.measures == "outputs" else plant.nx
    std = np.broadcast_to(np.asarray(noise_std, dtype=float), (n_meas,))
    if not np.all(np.isfinite(std)) or np.any(std < 0):
        raise ValueError(f"noise_std must be finite and >= 0, got {noise_std}")
    return _Setup(t, x0, r, d, np.array(std), n_meas)


def _noise(setup: _Setup, seed: int | None) -> np.ndarray:
    n = len(setup.t) - 1
    if not np.any(setup.noise_std):
        return np.zeros((n, setup.n_meas))
    return np.random.default_rng(seed).standard_normal((n, setup.n_meas)) * setup.noise_std


def simulate_closed_loop(plant: Plant, controller, reference, duration: float, *, x0=None,
                         params=None, substeps: int = 10, input_disturbance=0.0, noise_std=0.0,
                         seed: int | None = 0, xc0=None, compiled: bool | None = None,
                         allow_divergence: bool = False, jit: bool = False) -> ClosedLoopResult:
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
    seed : seed of the noise generator
    compiled : force (True) or refuse (False) the compiled path; default: compiled for Blocks
    allow_divergence : return a result with `diverged_at` set instead of raising
    jit : compile the run to machine code first (Blocks only; pays off for long or repeated runs)

    Raises
    ------
    SimulationError
        When the state diverges, naming the time.
    """
    setup = _setup(plant, controller, reference, duration, x0, input_disturbance, noise_std)
    p = plant.param_vector(params)
    noise = _noise(setup, seed)
    n = len(setup.t) - 1
    y0 = (plant.output(setup.x0, p) if controller.measures == "outputs" else setup.x0) + \
        (noise[0] if n else 0.0)
    xc_init = controller.initial_state(y0, setup.r[0]) if xc0 is None else np.asarray(xc0, dtype=float)
    use_compiled = isinstance(controller, Block) if compiled is None else compiled
    if use_compiled and not isinstance(controller, Block):
        raise TypeError("only a Block can run compiled")
    if use_compiled:
        run = _numpy_run(plant, controller, n, substeps, jit)
        X, XC, U, M = run(setup.x0, xc_init, setup.r[:-1].T, noise.T, setup.d.T, p, controller.gain_vector())
        x = np.vstack([setup.x0, X.T])
        xc = np.vstack([xc_init, XC.T]) if controller.n_state else np.zeros((n + 1, 0))
        u, measured = U.T, M.T
        step_time = _time_block(controller, xc[:-1], measured, setup.r[:-1])
        status = None
    else:
        x, u, measured, step_time, status, xc = _python_loop(plant, controller, setup, p, noise,
                                                              xc_init, substeps)
    y = np.asarray(plant.casadi_h.map(n + 1)(x.T, p)).T
    k = first_divergence(x, DIVERGENCE_BOUND)
    diverged_at = None if k is None else float(setup.t[k])
    if diverged_at is not None and not allow_divergence:
        raise SimulationError(f"{plant.name} under {getattr(controller, 'name', 'controller')}: closed loop "
                              f"diverged at t = {diverged_at:.4g} s")
    return ClosedLoopResult(t=setup.t, x=x, y=y, r=setup.r, u=u, d=setup.d, measured=measured, xc=xc,
                            step_time=step_time, status=status, input_limit=plant.input_limit.copy(),
                            state_names=plant.state_names, output_names=plant.output_names,
                            input_names=plant.input_names, controller=getattr(controller, "name", ""),
                            diverged_at=diverged_at, params=p)


def _time_block(controller: Block, xc, measured, r) -> np.ndarray:
    """Controller-only compute time per sample: the step mapped over the recorded inputs."""
    n = len(measured)
    mapped = controller.casadi_step.map(n)
    args = (xc.T if controller.n_state else np.zeros((0, n)), measured.T, r.T, controller.gain_vector())
    start = time.perf_counter()
    mapped(*args)
    return np.full(n, (time.perf_counter() - start) / n)


def _python_loop(plant, controller, setup, p, noise, xc, substeps):
    n = len(setup.t) - 1
    rk4 = plant.step_function(controller.sample_period, substeps)
    x = np.empty((n + 1, plant.nx))
    x[0] = setup.x0
    u = np.empty((n, plant.nu))
    measured = np.empty((n, setup.n_meas))
    step_time = np.empty(n)
    states = [np.asarray(xc, dtype=float)]
    status = [] if hasattr(controller, "step_info") else None
    limit = plant.input_limit
    for k in range(n):
        meas = (np.asarray(plant.casadi_h(x[k], p)).ravel() if controller.measures == "outputs" else x[k]) + noise[k]
        start = time.perf_counter()
        xc, uk = controller.step(xc, meas, setup.r[k])
        step_time[k] = time.perf_counter() - start
        if status is not None:
            status.append(controller.step_info())
        u[k], measured[k] = uk, meas
        x[k + 1] = np.asarray(rk4(x[k], np.clip(uk, -limit, limit) + setup.d[k], p)).ravel()
        states.append(np.asarray(xc, dtype=float))
        if first_divergence(x[k + 1:k + 2], DIVERGENCE_BOUND) is not None:
            x[k + 2:] = np.nan
            u[k + 1:] = np.nan
            measured[k + 1:] = np.nan
            step_time[k + 1:] = np.nan
            break
    xc_hist = np.array(states) if isinstance(controller, Block) else None
    if xc_hist is not None and len(xc_hist) < n + 1:
        xc_hist = np.vstack([xc_hist, np.full((n + 1 - len(xc_hist), xc_hist.shape[1]), np.nan)])
    return x, u, measured, step_time, status, xc_hist


def monte_carlo(plant: Plant, controller: Block, reference, duration: float, param_samples, *,
                x0=None, substeps: int = 10, input_disturbance=0.0, noise_std=0.0, seed: int = 0,
                threads: int = 2, jit: bool = False) -> list[ClosedLoopResult]:
    """Run `controller` on every parameter sample in one batched CasADi map.

    Parameters
    ----------
    param_samples : array (M, n_params) of actual parameter vectors (see `models.uncertainty`)
    seed : noise of sample i is drawn from the generator seeded with (seed, i)

    Returns
    -------
    list of ClosedLoopResult, one per sample; a diverged sample has `diverged_at` set.
    """
    if not isinstance(controller, Block):
        raise TypeError("monte_carlo batches Blocks; run other controllers with simulate_closed_loop")
    samples = as_matrix(param_samples, plant.n_params, "param_samples")
    for row in samples:
        plant.param_vector(row)
    setup = _setup(plant, controller, reference, duration, x0, input_disturbance, noise_std)
    n, m = len(setup.t) - 1, samples.shape[0]
    noises = [_noise(setup, np.random.SeedSequence([seed, i])) for i in range(m)]
    xc0 = []
    for i in range(m):
        y0 = plant.output(setup.x0, samples[i]) if controller.measures == "outputs" else setup.x0
        xc0.append(controller.initial_state(y0 + (noises[i][0] if n else 0), setup.r[0]))
    run = closed_loop_function(plant, controller, n, substeps, jit)
    batch = run.map(m, "thread", max(1, int(threads)))
    noise_cols = np.hstack([z.T for z in noises]) if np.any(setup.noise_std) else np.zeros((setup.n_meas, n))
    X, XC, U, M = (np.asarray(v) for v in batch(setup.x0, np.array(xc0).T if controller.n_state else
                                                  np.zeros((0, m)), setup.r[:-1].T, noise_cols,
                                                  setup.d.T, samples.T, controller.gain_vector()))
    results = []
    nc = controller.n_state
    for i in range(m):
        x = np.vstack([setup.x0, X[:, i * n:(i + 1) * n].T])
        xc = np.vstack([xc0[i], XC[:, i * n:(i + 1) * n].T]) if nc else np.zeros((n + 1, 0))
        y = np.asarray(plant.casadi_h.map(n + 1)(x.T, samples[i])).T
        k = first_divergence(x, DIVERGENCE_BOUND)
        results.append(ClosedLoopResult(
            t=setup.t, x=x, y=y, r=setup.r, u=U[:, i * n:(i + 1) * n].T, d=setup.d,
            measured=M[:, i * n:(i + 1) * n].T, xc=xc, step_time=np.full(n, np.nan), status=None,
            input_limit=plant.input_limit.copy(), state_names=plant.state_names,
            output_names=plant.output_names, input_names=plant.input_names, controller=controller.name,
            diverged_at=None if k is None else float(setup.t[k]), params=samples[i]))
    return results
