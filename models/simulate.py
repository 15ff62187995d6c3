"""Open-loop simulation of a plant under a zero-order-held input sequence.

Three methods, one result type:

- ``"rk4"``: fixed-step RK4 with sub-steps, the whole run one CasADi mapaccum.
- ``"adaptive"``: CVODES (BDF, variable step), restarted at every input
  change; one integrator call per constant-input segment.
- ``"collocation"``: Legendre-Gauss-Radau (Radau IIA) collocation on every
  sample interval, the whole horizon solved as one Newton rootfinding problem.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .checks import (
    SimulationError,
    as_matrix,
    as_vector,
    boolean,
    check_memory,
    first_divergence,
    integer,
    positive,
)
from .compile import NumpyCall
from .compile import jit as compile_jit
from .plant import Plant

METHODS = ("rk4", "adaptive", "collocation")

#: Longest trajectory whose output map `output_call` expands into one SX Function.
EXPANDED_OUTPUT_POINTS = 100_000

#: Collocation degrees CasADi's Radau points are tabulated for.
COLLOCATION_DEGREES = range(1, 10)

#: States beyond this magnitude (m or rad, SI) count as a diverged simulation.
DIVERGENCE_BOUND = 1e6


@dataclass(frozen=True)
class Trajectory:
    """An open-loop run.

    Attributes
    ----------
    t : ndarray, (N+1,)  sample times k * Ts in s
    x : ndarray, (N+1, nx)  states at the sample times
    u : ndarray, (N, nu)  input held on [t[k], t[k+1])
    state_names, input_names : tuple of str
    method : str
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    state_names: tuple
    input_names: tuple
    method: str

    def state(self, name: str) -> np.ndarray:
        """The trajectory of the state called `name`, (N+1,)."""
        return self.x[:, self.state_names.index(name)]


def simulate(
    plant: Plant,
    x0,
    u,
    sample_period: float,
    *,
    method: str = "rk4",
    params=None,
    substeps: int = 10,
    degree: int = 3,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    jit: bool = False,
) -> Trajectory:
    """Simulate `plant` from `x0` under the input sequence `u` held for `sample_period` s each.

    Parameters
    ----------
    x0 : array, (nx,)
    u : array, (N, nu), or (N,) for a single input
    sample_period : float, s
    method : "rk4", "adaptive" or "collocation"
    params : dict of overrides, full vector, or None for the plant's values
    substeps : RK4 steps per sample (``"rk4"``)
    degree : collocation points per sample (``"collocation"``)
    rtol, atol : CVODES tolerances (``"adaptive"``) and Newton tolerance (``"collocation"``)
    jit : compile the RK4 run to machine code first (``"rk4"``; see `models.compile`)

    Raises
    ------
    SimulationError
        When the state diverges or a solver fails, with the time it happened.
    ResourceLimitError
        Before any work, when the run would need more than `models.checks.MEMORY_LIMIT_BYTES`.
    """
    if not isinstance(plant, Plant):
        raise TypeError(f"plant must be a models.Plant, got {type(plant).__name__} {plant!r}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    x0 = as_vector(x0, plant.nx, f"{plant.name} initial state {plant.state_names}")
    u = as_matrix(u, plant.nu, f"{plant.name} input sequence")
    if u.shape[0] == 0:
        raise ValueError("the input sequence is empty")
    sample_period = positive(sample_period, "sample_period (s)")
    substeps = integer(substeps, "substeps", minimum=1)
    if method == "collocation":
        degree = len(radau_matrices(degree)[0]) - 1  # checks the degree
    if method in ("adaptive", "collocation"):
        rtol, atol = positive(rtol, "rtol"), positive(atol, "atol")
    jit = boolean(jit, "jit")
    p = plant.param_vector(params)
    n = u.shape[0]
    check_memory(
        _simulation_bytes(plant.nx, n, method, degree),
        f"simulate ({method}) of {plant.name} over {n} samples",
        "simulate a shorter input sequence",
    )
    if method == "rk4":
        x = _rk4_run(plant, sample_period, substeps, n, jit)(x0, u.T, p)[0].T
    elif method == "adaptive":
        x = _adaptive(plant, x0, u, p, sample_period, rtol, atol)
    else:
        x = _collocation(plant, x0, u, p, sample_period, degree, substeps, atol)
    x = np.vstack([x0, x])
    t = sample_period * np.arange(n + 1)
    check_trajectory(plant.name, t, x)
    return Trajectory(t, x, u, plant.state_names, plant.input_names, method)


def _simulation_bytes(nx: int, n: int, method: str, degree: int) -> float:
    """Estimated bytes a simulation allocates beyond its input: the states (result, CasADi's output
    and a copy), and for collocation the Newton system of n·nx·degree unknowns, whose sparse
    Jacobian and factors hold about 3·nx·(degree + 1) entries per unknown."""
    states = 3.0 * (n + 1) * nx
    if method != "collocation":
        return 8.0 * states
    unknowns = n * nx * degree
    return 8.0 * (states + unknowns * (4 + 3 * nx * (degree + 1)))


def output_call(plant: Plant, points: int) -> NumpyCall:
    """Noise-free outputs along one trajectory, in one call; cached on the plant.

    ``(X (nx, points), p (n_params,)) -> [Y (ny, points)]``. Expanded to one SX
    Function up to `EXPANDED_OUTPUT_POINTS` points: a mapped call of a tiny h
    costs about 1 µs per point in CasADi's virtual machine, the expanded one a
    few ns.
    """
    key = ("outputs", points)
    cache = plant.function_cache
    if key not in cache:
        X, p = ca.MX.sym("X", plant.nx, points), ca.MX.sym("p", plant.n_params)
        fun = ca.Function("outputs", [X, p], [plant.casadi_h.map(points)(X, p)], ["X", "p"], ["Y"])
        cache[key] = NumpyCall(fun.expand() if points <= EXPANDED_OUTPUT_POINTS else fun)
    return cache[key]


def check_trajectory(name: str, t: np.ndarray, x: np.ndarray) -> None:
    """Raise SimulationError naming the time at which `x` stopped being finite and bounded."""
    k = first_divergence(x, DIVERGENCE_BOUND)
    if k is not None:
        raise SimulationError(
            f"{name}: simulation diverged at t = {t[k]:.4g} s "
            f"(state left |x| <= {DIVERGENCE_BOUND:g} or became non-finite)"
        )


def _rk4_run(plant: Plant, sample_period: float, substeps: int, n: int, jit: bool = False) -> NumpyCall:
    """(x0 (nx,), U (nu, N), p) -> [X (nx, N)]: the states after each sample."""
    key = ("rk4_run", float(sample_period), int(substeps), n, jit)
    cache = plant.function_cache
    if key not in cache:
        accum = plant.step_function(sample_period, substeps).mapaccum("rk4_run", n)
        x0, U, p = ca.MX.sym("x0", plant.nx), ca.MX.sym("U", plant.nu, n), ca.MX.sym("p", plant.n_params)
        run = ca.Function("rk4_run", [x0, U, p], [accum(x0, U, p)], ["x0", "U", "p"], ["X"])
        cache[key] = NumpyCall(compile_jit(run) if jit else run)
    return cache[key]


def _adaptive(plant, x0, u, p, sample_period, rtol, atol) -> np.ndarray:
    """CVODES over each sample with its input held: the states after each sample, (N, nx).

    SimulationError naming the segment where CVODES fails or the state diverges.
    """
    key = ("cvodes", float(sample_period), rtol, atol)
    cache = plant.function_cache
    if key not in cache:
        x = ca.SX.sym("x", plant.nx)
        up = ca.SX.sym("up", plant.nu + plant.n_params)
        ode = plant.casadi_f(x, up[: plant.nu], up[plant.nu :])
        cache[key] = ca.integrator(
            "cvodes",
            "cvodes",
            {"x": x, "p": up, "ode": ode},
            0.0,
            sample_period,
            {"abstol": atol, "reltol": rtol, "max_num_steps": 100000, "error_on_fail": True},
        )
    integrator = cache[key]
    out = np.empty((u.shape[0], plant.nx))
    xk = x0
    for k, uk in enumerate(u):
        try:
            xk = np.asarray(integrator(x0=xk, p=np.concatenate([uk, p]))["xf"]).ravel()
        except RuntimeError as err:
            raise SimulationError(
                f"{plant.name}: CVODES failed on the segment starting at "
                f"t = {k * sample_period:.4g} s: {str(err).splitlines()[-1]}"
            ) from err
        out[k] = xk
        if first_divergence(xk[None], DIVERGENCE_BOUND) is not None:
            check_trajectory(plant.name, sample_period * np.arange(k + 2), np.vstack([out[: k + 1], xk]))
    return out


def lagrange_basis(nodes, s) -> tuple[np.ndarray, np.ndarray]:
    """Values and derivatives of the Lagrange polynomials through `nodes` at `s`, each (len(s), len(nodes)).

    The one construction of collocation polynomials: the Radau simulator here, and the
    transcriptions, dense output and mesh refinement of `mpc`.
    """
    nodes, s = np.asarray(nodes, dtype=float), np.atleast_1d(np.asarray(s, dtype=float))
    values, derivs = np.empty((s.size, nodes.size)), np.empty((s.size, nodes.size))
    for r in range(nodes.size):
        others = np.delete(nodes, r)
        poly = np.poly1d(np.poly(others)) / np.prod(nodes[r] - others)
        values[:, r], derivs[:, r] = poly(s), np.polyder(poly)(s)
    return values, derivs


def radau_matrices(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Collocation nodes and differentiation matrix of Radau IIA of `degree` points.

    Returns
    -------
    tau : ndarray, (degree + 1,)  0 followed by the Legendre-Gauss-Radau nodes on (0, 1]
    deriv : ndarray, (degree + 1, degree)  deriv[l, j] is the derivative at tau[j+1] of
        the Lagrange polynomial through tau that is one at tau[l]
    """
    degree = integer(degree, "degree", minimum=1)
    if degree not in COLLOCATION_DEGREES:
        raise ValueError(f"degree must be an integer from 1 to {COLLOCATION_DEGREES[-1]} (Radau points), got {degree}")
    tau = np.array([0.0] + ca.collocation_points(degree, "radau"))
    _, deriv = lagrange_basis(tau, tau[1:])
    return tau, deriv.T.copy()


def _collocation(plant, x0, u, p, sample_period, degree, substeps, tol) -> np.ndarray:
    """Radau IIA collocation of `degree` points per sample, the whole horizon one Newton solve from an
    RK4 start: the states after each sample, (N, nx)."""
    n, nx = u.shape[0], plant.nx
    key = ("radau", float(sample_period), degree, n)
    cache = plant.function_cache
    if key not in cache:
        _, deriv = radau_matrices(degree)
        h = sample_period
        start = ca.SX.sym("start", nx)
        states = ca.SX.sym("states", nx, degree)
        uk = ca.SX.sym("u", plant.nu)
        pk = ca.SX.sym("p", plant.n_params)
        nodes = ca.horzcat(start, states)
        residual = ca.vertcat(*[nodes @ deriv[:, j] - h * plant.casadi_f(states[:, j], uk, pk) for j in range(degree)])
        interval = ca.Function("radau_interval", [start, states, uk, pk], [residual])
        unknowns = ca.MX.sym("X", nx * degree * n)
        x0_mx = ca.MX.sym("x0", nx)
        u_mx = ca.MX.sym("U", plant.nu, n)
        p_mx = ca.MX.sym("p", plant.n_params)
        blocks = ca.reshape(unknowns, nx, degree * n)
        ends = blocks[:, degree - 1 :: degree]
        starts = ca.horzcat(x0_mx, ends[:, : n - 1])
        res = interval.map(n)(starts, blocks, u_mx, p_mx)
        g = ca.Function("radau_residual", [unknowns, ca.vertcat(x0_mx, ca.vec(u_mx), p_mx)], [ca.vec(res)])
        cache[key] = ca.rootfinder("radau", "newton", g, {"abstol": tol, "max_iter": 50, "error_on_fail": True})
    solver = cache[key]
    # Newton starts from an RK4 run held constant over each interval; the
    # answer is the collocation solution whatever the start, once converged.
    guess = _rk4_run(plant, sample_period, substeps, n)(x0, u.T, p)[0]
    guess = np.repeat(guess, degree, axis=1)
    if first_divergence(guess.T, DIVERGENCE_BOUND) is not None:
        check_trajectory(plant.name, sample_period * np.arange(n + 1), np.vstack([x0, guess[:, ::degree].T]))
    try:
        sol = solver(ca.vec(guess), np.concatenate([x0, u.ravel(), p]))
    except RuntimeError as err:
        raise SimulationError(
            f"{plant.name}: the collocation Newton solve over {n * sample_period:.4g} s did not converge"
        ) from err
    solved = np.asarray(sol).reshape(nx, degree * n, order="F")
    return solved[:, degree - 1 :: degree].T
