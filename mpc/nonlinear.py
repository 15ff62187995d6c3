"""Nonlinear MPC on the plant's own equations: an optimal control problem solved by real-time iteration.

With F the plant's RK4 map over one sample and the known parameters, the
problem at each sample is

    minimize    Σ_{k=0}^{N-1} ‖x_k − x_s‖²_Q + ‖u_k − u_s‖²_R + wᵀ s_k + s_kᵀ diag(ρ) s_k
                + ‖x_N − x_s‖²_P
    subject to  x_0 = x̂,   x_{k+1} = F(x_k, u_k + d̂)                 k = 0..N-1
                −u_max ≤ u_k ≤ u_max                                 (hard, total input)
                |u_k − u_{k-1}| ≤ Δ,  u_{-1} = previous input          (hard, optional)
                g_lo − s_k ≤ G x_{k+1} ≤ g_hi + s_k,  s_k ≥ 0         k = 0..N-1 (soft)

on absolute states and inputs: the linear MPC's problem with the exact
dynamics. It is written once as an `mpc.OptimalControlProblem` (the soft
bounds on `x_next` paired with the slack of the same interval, the rate limit
on `u_previous`), transcribed by `mpc.MultipleShooting` and solved by
`mpc.rti.RealTimeIteration`: per sample one Gauss-Newton SQP iteration
(preparation: linearize at the previous solution shifted by one sample and
condense; feedback: the QP for the new estimate), or with ``iteration="sqp"``
iterated to convergence. The first sample, and any after a failure, has no
previous solution: it starts from the plan rolled out through the model and
iterates to convergence.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from models import Plant, checks, interrupts
from models.checks import integer, positive, real_array, weight_matrix

from .linear import check_holding_input
from .ocp import OptimalControlProblem
from .rti import RealTimeIteration
from .transcription import MultipleShooting, Transcription

#: How each sample is solved: one real-time iteration, or SQP iterations to convergence.
ITERATIONS = ("rti", "sqp")

log = logging.getLogger(__name__)

#: A build estimated (`build_estimate`) to take longer than this (s) is refused; read at every call, and
#: overridden per problem by ``build_time_limit`` (math.inf accepts any).
BUILD_TIME_LIMIT_S = 600.0
#: The build's cost model, fitted to builds of the arm and the pendulum at N = 10 to 160 with an empty
#: compile cache on an idle core (docs/reliability.md): a fixed part, one per instruction of the plant's
#: sample map, and the compilation of the linearization at -O3, which grows as (N (nx + nu + ns))².
BUILD_FIXED_S, BUILD_S_PER_INSTRUCTION, BUILD_S_QUADRATIC = 0.3, 2e-3, 4.5e-5
#: The construction without compilation (``compiled=False``): seconds per interval and stage variable.
BUILD_S_PER_STAGE_VARIABLE = 5e-4
#: Dense matrices of the condensed QP (Hessian, the states' sensitivities, their copies) the build holds.
BUILD_MATRIX_COPIES = 4


@dataclass(frozen=True)
class BuildEstimate:
    """What building a `NonlinearMPCProblem` is expected to take, before any of it is built.

    seconds : wall time of a build not in the compile cache (s), on an idle core;  nbytes : memory of
    its dense condensed matrices (bytes);  horizon, stage : N and the variables per interval (nx + nu + ns)
    """

    seconds: float
    nbytes: float
    horizon: int
    stage: int


def build_estimate(plant: Plant, horizon: int, *, n_soft: int = 0, compiled: bool = True) -> BuildEstimate:
    """The time and memory a `NonlinearMPCProblem` of `horizon` intervals on `plant` with `n_soft` soft
    bounds will take to build (`BUILD_FIXED_S` ...: within a factor of 2 on the arm and the pendulum for N
    from 20 to 160; the crane's linearization, compiled at -O1, builds several times faster than estimated)."""
    N = integer(horizon, "horizon", minimum=1)
    stage = plant.nx + plant.nu + int(n_soft)
    nbytes = 8.0 * BUILD_MATRIX_COPIES * (N * plant.nu) * (N * stage)
    if not compiled:
        return BuildEstimate(BUILD_FIXED_S + BUILD_S_PER_STAGE_VARIABLE * N * stage, nbytes, N, stage)
    code = plant.step_function(1.0, 1).n_instructions()
    seconds = BUILD_FIXED_S + BUILD_S_PER_INSTRUCTION * code + BUILD_S_QUADRATIC * (N * stage) ** 2
    return BuildEstimate(seconds, nbytes, N, stage)


def check_build(estimate: BuildEstimate, plant: Plant, limit: float | None = None) -> None:
    """Refuse (`models.checks.ResourceLimitError`, a ValueError naming the horizon) a build whose estimate
    exceeds `limit` seconds (default `BUILD_TIME_LIMIT_S`) or `models.checks.MEMORY_LIMIT_BYTES`."""
    limit = BUILD_TIME_LIMIT_S if limit is None else float(limit)
    what = f"a nonlinear MPC on {plant.name} with horizon = {estimate.horizon}"
    checks.check_memory(estimate.nbytes, what, "give a shorter horizon (or a longer sample period)")
    if estimate.seconds > limit:
        raise checks.ResourceLimitError(
            f"{what} is estimated to build in {estimate.seconds:.0f} s, above the limit of {limit:g} s "
            "(mpc.nonlinear.BUILD_TIME_LIMIT_S, or build_time_limit): give a shorter horizon (or a longer "
            "sample period), or raise the limit (math.inf accepts any)"
        )


@dataclass
class NLPSolution:
    """One NMPC solve.

    inputs : (N, nu) planned total inputs; states : (N+1, nx) predicted states;
    slacks : (N, ns); success, status, iterations, solve_time (s) as reported by the solver;
    preparation_time, feedback_time : s, the two phases of the iterations (their sum is solve_time
    less the Python bookkeeping); qp_status : the last QP's status.
    """

    inputs: np.ndarray
    states: np.ndarray
    slacks: np.ndarray
    success: bool
    status: str
    iterations: int
    solve_time: float
    preparation_time: float = 0.0
    feedback_time: float = 0.0
    qp_status: str = ""


def mpc_problem(
    plant: Plant, sample_period: float, horizon: int, state_weight, input_weight, *, soft_bounds=(), rate_limit=None
) -> OptimalControlProblem:
    """The NMPC's optimal control problem (see the module docstring) on `plant`.

    Parameters ``x0`` (start_from), ``d_hat`` (nu), ``x_s`` (nx), ``u_s`` (nu), ``P`` (nx², column-major)
    and ``u_prev`` (nu); one control ``slack_i`` per soft bound. Weights as in `NonlinearMPCProblem`.
    """
    nx, nu = plant.nx, plant.nu
    Q = weight_matrix(state_weight, nx, "state_weight Q")
    R = weight_matrix(input_weight, nu, "input_weight R", definite=True)
    ocp = OptimalControlProblem(plant, horizon * sample_period)
    ocp.start_from()
    d_hat, x_s = ocp.parameter("d_hat", nu, 0.0), ocp.parameter("x_s", nx, 0.0)
    u_s, terminal = ocp.parameter("u_s", nu, 0.0), ocp.parameter("P", nx * nx, 0.0)
    u_prev = ocp.parameter("u_prev", nu, 0.0)
    ocp.plant_input(ocp.input + d_hat)
    stage = ca.bilin(ca.DM(Q), ocp.state - x_s) + ca.bilin(ca.DM(R), ocp.input - u_s)
    for i, bound in enumerate(soft_bounds):
        slack = ocp.control(f"slack_{i + 1}", 0.0, np.inf)
        value = ca.dot(ca.DM(bound.row), ocp.state_next)
        label = f"soft bound {bound.name or i + 1}"
        if np.isfinite(bound.lower):
            ocp.subject_to(value + slack >= bound.lower, label=f"{label} (lower)")
        if np.isfinite(bound.upper):
            ocp.subject_to(value - slack <= bound.upper, label=f"{label} (upper)")
        stage += bound.linear_weight * slack + bound.quadratic_weight * slack**2
    if rate_limit is not None:
        ocp.input_before(u_prev)
        ocp.subject_to(
            ocp.bounded(-ca.DM(rate_limit), ocp.input - ocp.input_previous, ca.DM(rate_limit)), label="input rate limit"
        )
    ocp.minimize(ocp.sum(stage) + ocp.at_end(ca.bilin(ca.reshape(terminal, nx, nx), ocp.state - x_s)))
    return ocp


class NonlinearMPCProblem:
    """The NMPC's optimal control problem, transcribed and prepared for real-time iteration once.

    Parameters
    ----------
    plant : Plant with the parameters known to the controller
    sample_period : s, the shooting interval and the controller's period
    horizon : N >= 1
    state_weight, input_weight : Q (nx, nx) and R (nu, nu) as in `mpc.linear`
    soft_bounds : sequence of SoftBound on the absolute state
    rate_limit : (nu,) bound on ``|u_k − u_{k−1}|`` per sample, or None
    substeps : RK4 steps per shooting interval
    iteration : "rti" (one SQP iteration per sample) or "sqp" (iterate to convergence)
    max_iterations : SQP iteration limit where iterating to convergence (hitting it is a failure)
    tolerance : convergence test of the SQP, max ``|Δw|`` in scaled units (inputs / limit)
    compiled : compile the iteration to machine code (`models.compile`, cached); False runs
        CasADi's virtual machine
    build_time_limit : s, refuse a build estimated longer (`build_estimate`; default `BUILD_TIME_LIMIT_S`)
    progress : called as progress(phase, seconds since the build began) after each phase of the build
        (each phase is also logged at INFO on ``mpc.nonlinear``)
    constrain : callable ocp -> None adding constraints to the `mpc_problem` before it is transcribed
        (a scenario tree's non-anticipativity), or None

    Raises
    ------
    ValueError
        For a horizon < 1, non-finite or indefinite weights, substeps < 1, an unknown iteration, or a
        plant whose operating point (`Plant.equilibrium()`) needs more input than its limit; a
        `models.checks.ResourceLimitError` naming the horizon for a build estimated beyond its limits.
    """

    def __init__(
        self,
        plant: Plant,
        sample_period: float,
        horizon: int,
        state_weight,
        input_weight,
        *,
        soft_bounds=(),
        rate_limit=None,
        substeps: int = 1,
        iteration: str = "rti",
        max_iterations: int = 50,
        tolerance: float = 1e-8,
        compiled: bool = True,
        build_time_limit: float | None = None,
        progress: Callable[[str, float], None] | None = None,
        constrain=None,
    ):
        N = integer(horizon, "horizon", minimum=1)
        self.max_iterations = integer(max_iterations, "max_iterations", minimum=1)
        substeps = integer(substeps, "substeps", minimum=1)
        if iteration not in ITERATIONS:
            raise ValueError(f"iteration must be one of {', '.join(map(repr, ITERATIONS))}, got {iteration!r}")
        self.iteration = iteration
        self.tolerance = positive(tolerance, "tolerance")
        sample_period = positive(sample_period, "sample_period (s)")
        nx, nu = plant.nx, plant.nu
        soft = tuple(soft_bounds)
        ns = len(soft)
        self.plant, self.nx, self.nu, self.horizon, self.n_soft = plant, nx, nu, N, ns
        self.sample_period, self.input_limit, self.soft_bounds = float(sample_period), plant.input_limit.copy(), soft
        self.rate_limit = (
            None if rate_limit is None else np.broadcast_to(real_array(rate_limit, "rate_limit"), (nu,)).copy()
        )
        if self.rate_limit is not None and (not np.all(np.isfinite(self.rate_limit)) or np.any(self.rate_limit <= 0)):
            raise ValueError(f"rate_limit must be finite and > 0 per sample, got {self.rate_limit}")
        check_holding_input(plant.name, plant.equilibrium()[1], self.input_limit)  # as the linear MPC
        self.build_estimate = build_estimate(plant, N, n_soft=ns, compiled=compiled)
        check_build(self.build_estimate, plant, build_time_limit)
        began = time.perf_counter()

        def phase(text: str) -> None:
            elapsed = time.perf_counter() - began
            log.info("nonlinear MPC on %s, horizon %d: %s (%.1f s)", plant.name, N, text, elapsed)
            if progress is not None:
                progress(text, elapsed)

        phase(f"building, estimated {self.build_estimate.seconds:.0f} s unless cached")
        self.ocp = mpc_problem(
            plant, self.sample_period, N, state_weight, input_weight, soft_bounds=soft, rate_limit=self.rate_limit
        )
        if constrain is not None:
            constrain(self.ocp)
        transcription = Transcription(self.ocp, MultipleShooting(intervals=N, substeps=substeps))
        phase("problem stated and transcribed")
        self.rti = RealTimeIteration(transcription, compiled=compiled, progress=phase)
        phase("built")
        tr = self.transcription = self.rti.transcription
        self.qp_solver = "daqp (condensed)"
        self._slices = tr.parameter_slices
        self._parameters = tr.parameter_values(np.zeros(nx))  # defaults, the known plant's parameters included
        layout = tr.layout
        self._states, self._inputs = layout.states, layout.inputs
        self._slacks = layout.controls
        self._input_scale = tr.scale[layout.inputs[0]]
        self._rollout = plant.step_function(self.sample_period, substeps).mapaccum("rollout", N)
        self._known = plant.param_vector()
        self.reset()

    def reset(self) -> None:
        """Forget the warm start (of `solve`; `reset_many` forgets those of `solve_many`)."""
        self._guess: np.ndarray | None = None

    def reset_many(self, count: int) -> None:
        """Forget every warm start and keep one per sample for `solve_many` on `count` samples."""
        self.reset()
        count = integer(count, "count", minimum=1)
        self._guesses = np.zeros((count, self.transcription.layout.size))
        self._has_guess = np.zeros(count, dtype=bool)

    def solve_many(
        self, index, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous, plans
    ) -> list[NLPSolution]:
        """`solve` for the samples `index` of the `reset_many` batch at once, each from its own warm start.

        The samples with a warm start take their real-time iteration together (the compiled
        preparation and feedback mapped over them); the others (first samples, after a failure,
        or with ``iteration="sqp"``) are solved one by one by `solve`. Every sample's numbers are
        those `solve` gives it alone; solve_time, preparation_time and feedback_time are the
        batch's shared by its samples.

        Parameters
        ----------
        index : (m,) int, rows of the batch
        x_hat, d_hat : (m, nx), (m, nu);  u_target, u_previous : (m, nu);  plans : (m, N, nu)
        x_target : (nx,), terminal_weight : (nx, nx), shared by the samples
        """
        index = np.asarray(index, dtype=int)
        m = len(index)
        out: list = [None] * m
        warm = self._has_guess[index] & (self.iteration == "rti")
        for j in np.flatnonzero(~warm):  # as alone: the SQP from the rolled-out plan
            self._guess = None
            out[j] = self.solve(x_hat[j], d_hat[j], x_target, u_target[j], terminal_weight, u_previous[j], plans[j])
            i = index[j]
            self._has_guess[i] = self._guess is not None
            if self._has_guess[i]:
                self._guesses[i] = self._guess
        self._guess = None
        hot = np.flatnonzero(warm)
        if hot.size:
            for j, solution in zip(
                hot,
                self._iterate_many(
                    index[hot], x_hat[hot], d_hat[hot], x_target, u_target[hot], terminal_weight, u_previous[hot]
                ),
            ):
                out[j] = solution
        return out

    def _iterate_many(self, rows, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous) -> list:
        """One real-time iteration of the batch rows `rows` from their warm starts, mapped over them."""
        start = time.perf_counter()
        m, s = len(rows), self._slices
        P = np.tile(self._parameters, (m, 1))
        P[:, s["x0"]], P[:, s["d_hat"]], P[:, s["x_s"]], P[:, s["u_s"]] = x_hat, d_hat, x_target, u_target
        P[:, s["P"]] = np.asarray(terminal_weight, dtype=float).T.ravel()
        P[:, s["u_prev"]] = u_previous
        guesses = self._guesses[rows]
        try:
            began = time.perf_counter()
            data = self.rti.prepare_many(guesses, P)
            prepared = time.perf_counter()
            W, residuals = self.rti.feedback_many(data, x_hat)
            fed = time.perf_counter()
        except Exception as err:  # CasADi raises on NaN in a function evaluation: each sample alone, as solve
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            return self._each_alone(rows, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous)
        share = 1.0 / m
        preparation, feedback = (prepared - began) * share, (fed - prepared) * share
        # The batch's bookkeeping at once (gathers and elementwise products: each row's numbers are
        # those of the sample alone).
        reports = [self.rti.report(r) for r in residuals]
        success = np.array([qp.success for qp in reports], dtype=bool) & np.all(np.isfinite(W), axis=1)
        self._guesses[rows[success]] = self.rti.shift(W[success])
        self._has_guess[rows] = success
        states = W[:, self._states] * self.rti.state_scale
        inputs = W[:, self._inputs] * self._input_scale
        slacks = (
            W[:, self._slacks] * self.transcription.scale[self._slacks]
            if self.n_soft
            else np.zeros((m, self.horizon, 0))
        )
        solve_time = (time.perf_counter() - start) * share
        return [
            NLPSolution(
                inputs[j],
                states[j],
                slacks[j],
                bool(success[j]),
                "solved" if success[j] else (qp.status if not qp.success else "non-finite iterate"),
                1,
                solve_time,
                preparation,
                feedback,
                qp.status,
            )
            for j, qp in enumerate(reports)
        ]

    def _each_alone(self, rows, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous) -> list:
        """The real-time iteration of each row by `solve`, from its warm start (after a batch raised)."""
        out = []
        for j, i in enumerate(rows):
            self._guess = self._guesses[i]
            out.append(
                self.solve(
                    x_hat[j],
                    d_hat[j],
                    x_target,
                    u_target[j],
                    terminal_weight,
                    u_previous[j],
                    np.zeros((self.horizon, self.nu)),
                )
            )
            self._has_guess[i] = self._guess is not None
            if self._has_guess[i]:
                self._guesses[i] = self._guess
        self._guess = None
        return out

    def parameters(self, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous) -> np.ndarray:
        """The NLP parameter vector for these values (see `mpc_problem`): the estimates x_hat (nx,) and
        d_hat (nu,), the targets x_target (nx,) and u_target (nu,), the terminal_weight (nx, nx) and
        the input applied last, u_previous (nu,)."""
        P = self._parameters.copy()
        s = self._slices
        P[s["x0"]], P[s["d_hat"]], P[s["x_s"]], P[s["u_s"]] = x_hat, d_hat, x_target, u_target
        P[s["P"]] = np.asarray(terminal_weight, dtype=float).T.ravel()
        P[s["u_prev"]] = u_previous
        return P

    def initial_guess(self, x_hat, d_hat, plan) -> np.ndarray:
        """A starting point from scratch (scaled decisions): the plan (N, nu) rolled out from the estimate
        x_hat (nx,) with the disturbance estimate d_hat (nu,) through the model."""
        plan = np.clip(
            np.asarray(plan, dtype=float).reshape(self.horizon, self.nu), -self.input_limit, self.input_limit
        )
        X = np.asarray(self._rollout(x_hat, (plan + d_hat).T, self._known))
        X = np.hstack([np.asarray(x_hat, dtype=float).reshape(-1, 1), X])
        if not np.all(np.isfinite(X)):
            X = np.tile(np.asarray(x_hat, dtype=float).reshape(-1, 1), (1, self.horizon + 1))
        w = np.zeros(self.transcription.layout.size)
        w[self._states] = X.T / self.rti.state_scale
        w[self._inputs] = plan / self._input_scale
        return w

    def solve(self, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous, plan) -> NLPSolution:
        """One sample: a real-time iteration from the shifted previous solution (or SQP to convergence).

        Parameters
        ----------
        x_hat : (nx,) state estimate;  d_hat : (nu,) input-disturbance estimate
        x_target, u_target : (nx,), (nu,) steady state to track (u_target excludes d̂)
        terminal_weight : (nx, nx) P
        u_previous : (nu,) input applied at the previous sample
        plan : (N, nu) the previous plan, used for the first guess
        """
        start = time.perf_counter()
        x_hat = np.asarray(x_hat, dtype=float)
        P = self.parameters(x_hat, d_hat, x_target, u_target, terminal_weight, u_previous)
        try:
            if self._guess is None or self.iteration == "sqp":
                guess = self.initial_guess(x_hat, d_hat, plan) if self._guess is None else self._guess
                result = self.rti.solve(guess, P, x_hat, tolerance=self.tolerance, max_iterations=self.max_iterations)
            else:
                result = self.rti.iterate(self._guess, P, x_hat)
        except Exception as err:  # CasADi raises on NaN in a function evaluation, for example
            if interrupts.is_interrupt(err):  # Ctrl-C, which CasADi reports as an error
                raise KeyboardInterrupt from err
            self.reset()
            status = f"solver error: {err}".splitlines()[0]
            return NLPSolution(
                np.full((self.horizon, self.nu), np.nan),
                np.full((self.horizon + 1, self.nx), np.nan),
                np.zeros((self.horizon, self.n_soft)),
                False,
                status,
                0,
                time.perf_counter() - start,
            )
        w = result.decision
        success = result.qp.success and result.converged and bool(np.all(np.isfinite(w)))
        if success:
            status = "solved" if result.iterations == 1 else f"converged in {result.iterations} iterations"
            self._guess = self.rti.shift(w)
        else:
            status = (
                result.qp.status
                if not result.qp.success
                else "non-finite iterate"
                if not np.all(np.isfinite(w))
                else f"not converged in {result.iterations} iterations (step {result.step:.1e})"
            )
            self.reset()  # next time start over from the plan the controller actually follows
        states = w[self._states] * self.rti.state_scale
        inputs = w[self._inputs] * self._input_scale
        slacks = (
            w[self._slacks] * self.transcription.scale[self._slacks] if self.n_soft else np.zeros((self.horizon, 0))
        )
        return NLPSolution(
            inputs,
            states,
            slacks,
            success,
            status,
            result.iterations,
            time.perf_counter() - start,
            result.preparation_time,
            result.feedback_time,
            result.qp.status,
        )
