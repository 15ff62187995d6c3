"""Linear and nonlinear MPC as controllers of the project's `models.Controller` protocol.

Both read the plant's outputs y, estimate the state and a constant input
disturbance, compute the steady-state target for the reference (the absolute
value of the tracked coordinate), solve their optimization and command the
first input of the plan. The controller state passed through the simulator is

    x_c = (x̂ (nx,), d̂ (nu,), plan (N·nu,))

with x̂, d̂ the one-step predictions for the next sample and `plan` the input
sequence being followed, clipped to the actuator limit; its first entry is the
input applied last. Solver warm starts live inside the solver objects and are
reset by `initial_state`, so a controller can be rerun.

Every sample: if the solver reports failure (or an iteration limit, or a
non-finite answer), the plan shifted by one sample is applied instead. The
command is clipped to ±input_limit *after* solving, so |u| <= limit holds
exactly; the excess clipped away is reported in `step_info()`.

Nothing non-finite passes silently. A non-finite measurement is not used
(the estimate is the model's prediction) and the step is a failure with
status "non-finite measurement"; a non-finite estimate skips the solve
("non-finite estimate"); a solver answer with non-finite entries is a
failure ("non-finite solution"); and if the command itself is non-finite
(the plan to fall back on is) the status says "non-finite command". Such
steps have success False and fallback True. Sizes that do not match and a
non-finite reference are errors (ValueError).
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from models import Plant, interrupts
from models.checks import integer, positive, real_array, weight_matrix
from models.compile import NumpyCall
from models.linear_plant import LinearPlant

from .estimator import DisturbanceObserver, SteadyStateTarget
from .linear import (
    MPCProblem,
    QPParameters,
    QPSolution,
    SoftBound,
    problem_from_model,
    riccati_terminal_cost,
)
from .nonlinear import NLPSolution, NonlinearMPCProblem
from .qp_fast import CondensedDaqpSolver
from .qp_osqp import OsqpSolver
from .reference_cvxpy import CvxpySolver

SOLVERS = {"daqp": CondensedDaqpSolver, "osqp": OsqpSolver, "cvxpy": CvxpySolver}


def make_solver(solver, problem: MPCProblem):
    """The QP solver object for `solver`: a name in `SOLVERS` or a callable problem -> solver."""
    if isinstance(solver, str):
        if solver not in SOLVERS:
            raise ValueError(
                f"solver must be one of {', '.join(map(repr, SOLVERS))} or a callable problem -> solver, got {solver!r}"
            )
        return SOLVERS[solver](problem)
    if not callable(solver):
        raise ValueError(
            f"solver must be one of {', '.join(map(repr, SOLVERS))} or a callable problem -> solver, got {solver!r}"
        )
    made = solver(problem)
    missing = [m for m in ("solve", "reset") if not callable(getattr(made, m, None))]
    if missing:
        raise ValueError(f"solver {solver!r} made {type(made).__name__}, which has no {' or '.join(missing)} method")
    return made


def solver_name(solver) -> str:
    """The name a QP solver object reports in step records: its ``name`` (a str) if it has one, else its
    class's name (a custom solver needs only ``solve`` and ``reset``)."""
    name = getattr(solver, "name", None)
    return name if isinstance(name, str) and name else type(solver).__name__


def _vector(value, size: int, what: str) -> np.ndarray:
    arr = real_array(value, what).reshape(-1)
    if arr.size != size:
        raise ValueError(f"{what} must have {size} entries, got {value!r}")
    return arr


def _finite_vector(value, size: int, what: str) -> np.ndarray:
    arr = _vector(value, size, what)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be {size} finite values, got {value!r}")
    return arr


def _soft_bounds(bounds) -> tuple[SoftBound, ...]:
    bounds = tuple(bounds)
    wrong = [b for b in bounds if not isinstance(b, SoftBound)]
    if wrong:
        raise TypeError(f"soft_bounds must be SoftBound objects (mpc.SoftBound.on(plant, ...)), got {wrong[0]!r}")
    return bounds


def _finite(arr: np.ndarray) -> bool:
    return bool(np.isfinite(arr).all())


class _PlanFollower:
    """What both MPCs share: settings checks, the controller-state layout, the start from the
    first measurement, the fallback to the shifted plan, exact clipping and `step_info`.

    Subclasses call `_setup_common`, set `_rate_per_sample` (or None) and write
    `initial_state` and `step`.
    """

    measures = "outputs"
    n_reference = 1
    _rate_per_sample: np.ndarray | None  # (nu,) largest input change per sample, None when unlimited

    def _setup_common(self, known: Plant, sample_period: float, horizon: int, tracked: str, name: str):
        if not isinstance(known, (Plant, LinearPlant)):  # LinearPlant: a python-control model with limits
            raise TypeError(f"known must be a models.Plant, got {type(known).__name__} {known!r}")
        sample_period = positive(sample_period, "sample_period (s)")
        horizon = integer(horizon, "horizon", minimum=1)
        if known.nu != 1:
            raise ValueError(
                f"{known.name} has {known.nu} inputs; these controllers track one coordinate with one input"
            )
        self.plant = known
        self.sample_period = float(sample_period)
        self.horizon = int(horizon)
        self.name = name
        self.tracked = tracked
        if self.tracked not in known.coordinate_names:
            raise ValueError(
                f"{known.name} has no coordinate {self.tracked!r} to track; coordinates are "
                f"{', '.join(known.coordinate_names)}"
            )
        self.tracked_index = known.state_names.index(self.tracked)
        self.input_limit = known.input_limit.copy()
        self._known_params = known.param_vector()
        self._info: dict = {}
        nx, nu = known.nx, known.nu
        self._slices = (slice(0, nx), slice(nx, nx + nu), slice(nx + nu, nx + nu + self.horizon * nu))
        self._state_shape = (nx + nu + self.horizon * nu,)
        self._measurement_shape = (known.ny,)
        self._plan_shape = (self.horizon, nu)

    @property
    def n_state(self) -> int:
        """Size of the controller state x_c = (x̂, d̂, plan)."""
        return self.plant.nx + self.plant.nu + self.horizon * self.plant.nu

    def _start(self, y0, r0) -> tuple[np.ndarray, np.ndarray]:
        """Absolute state at rest at the measured configuration, and the input holding it (clipped)."""
        y0 = _finite_vector(y0, self.plant.ny, f"{self.name}: first measurement {self.plant.output_names}")
        _finite_vector(r0, 1, f"{self.name}: first reference")
        q0 = np.asarray(self.plant.casadi_configuration(y0, self._known_params)).ravel()
        x0 = np.concatenate([q0, np.zeros(self.plant.nx - self.plant.nq)])  # at rest (velocities, other states 0)
        u0 = np.clip(self.plant.equilibrium_input(q0, self._known_params), -self.input_limit, self.input_limit)
        return x0, u0

    def _read(self, xc, y, r) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(x_c, y, r) of one step with their sizes checked, and the stored input plan, (horizon, nu).

        x_c and y may hold non-finite values (the step reports them); r must be finite.
        """
        # Arrays of the right kind pass without copies (the simulator's case); anything else is converted.
        if not (type(xc) is np.ndarray and xc.dtype == np.float64 and xc.shape == self._state_shape):
            xc = real_array(xc, f"{self.name}: controller state")
            if xc.shape != self._state_shape:
                raise ValueError(f"{self.name}: controller state must have {self.n_state} entries, got {xc.shape}")
        if not (type(y) is np.ndarray and y.dtype == np.float64 and y.shape == self._measurement_shape):
            y = _vector(y, self.plant.ny, f"{self.name}: measurement {self.plant.output_names}")
        if not (type(r) is np.ndarray and r.dtype == np.float64 and r.shape == (1,) and math.isfinite(r[0])):
            r = _finite_vector(r, 1, f"{self.name}: reference")
        return xc, y, r, xc[self._slices[2]].reshape(self._plan_shape)

    def _follow(
        self, solution_inputs, success: bool, status: str, plan: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, bool, float, bool, str]:
        """The plan to follow (clipped), the command, whether the fallback was used, the clipped
        excess, and the step's success and status.

        The solver's plan when it succeeded with finite values, else the previous plan shifted by
        one sample. Clipping happens here, after solving, so the command is within ±input_limit
        exactly (and within the rate limit of the previous command, which is itself within the
        limit). A non-finite command (the plan fallen back on was non-finite) is reported.
        """
        if success and not _finite(solution_inputs):
            success, status = False, f"non-finite solution (solver: {status})"
        fallback = not success
        candidate = np.vstack([plan[1:], plan[-1:]]) if fallback else solution_inputs
        limit = self.input_limit
        excess = max(0.0, float((np.abs(candidate[0]) - limit).max()))
        new_plan = np.minimum(np.maximum(candidate, -limit), limit)
        if self._rate_per_sample is not None:
            rate = self._rate_per_sample
            new_plan[0] = np.minimum(np.maximum(new_plan[0], plan[0] - rate), plan[0] + rate)
            new_plan[0] = np.minimum(np.maximum(new_plan[0], -limit), limit)
        command = new_plan[0].copy()
        if fallback and not _finite(command):  # a solution was checked finite above
            success, status = False, f"non-finite command ({status})"
        return new_plan, command, fallback, excess, success, status

    def step_info(self) -> dict:
        """The last step's record: solver, status, success, iterations, solve_time (s), fallback,
        input_excess (what clipping removed from the solver's first input), soft_violation
        (largest predicted soft-bound violation over the horizon, in the bound's unit) and
        soft_violation_now (the estimate's current violation). The nonlinear MPC adds
        preparation_time and feedback_time (s, the real-time iteration's two phases) and qp_status."""
        return dict(self._info)


class LinearMPC(_PlanFollower):
    """Offset-free linear MPC on the exact zero-order-hold linearization at the operating point.

    Parameters
    ----------
    known : Plant
        The model the controller is designed from (the text's ±5 % known parameters).
    sample_period : float, s
    horizon : int, N samples
    state_weight, input_weight : Q (nx,) diagonal or (nx, nx); R (nu,) or (nu, nu), absolute units
    soft_bounds : sequence of SoftBound on the absolute state
    rate_limit : (nu,) bound on the input's rate of change in input units per second, or None
    solver : "daqp" (condensed, fastest), "osqp" (sparse) or "cvxpy" (the readable reference),
        or a callable problem -> solver object with solve(QPParameters) -> QPSolution and reset()
        (and optionally a ``name``, reported in step records; by default its class's name)
    tracked : coordinate whose absolute value the reference gives
    operating_point : (xe, ue) to linearize about (default: the plant's standard equilibrium)
    input_noise_std, disturbance_step_std, measurement_std : the estimator's tuning, see
        `mpc.estimator.DisturbanceObserver`
    name : str
    """

    def __init__(
        self,
        known: Plant,
        *,
        sample_period: float,
        horizon: int,
        state_weight,
        input_weight,
        soft_bounds=(),
        rate_limit=None,
        solver="daqp",
        tracked: str,
        operating_point=None,
        input_noise_std=None,
        disturbance_step_std=None,
        measurement_std=1e-3,
        name: str = "linear MPC",
    ):
        self._setup_common(known, sample_period, horizon, tracked, name)
        xe, ue = known.equilibrium() if operating_point is None else operating_point
        self.model = known.linearize(xe, ue).discretize(self.sample_period)
        per_sample_rate = None if rate_limit is None else real_array(rate_limit, "rate_limit") * self.sample_period
        self._rate_per_sample = per_sample_rate
        self.soft_bounds = _soft_bounds(soft_bounds)
        self.problem: MPCProblem = problem_from_model(
            self.model,
            state_weight,
            input_weight,
            self.horizon,
            self.input_limit,
            rate_limit=per_sample_rate,
            soft_bounds=self.soft_bounds,
        )
        self.solver = make_solver(solver, self.problem)
        nu = known.nu
        self.observer = DisturbanceObserver(
            self.model.A,
            self.model.B,
            self.model.C,
            self.input_limit * 1e-2 if input_noise_std is None else input_noise_std,
            self.input_limit * 1e-3 if disturbance_step_std is None else disturbance_step_std,
            measurement_std,
        )
        tracked_row = np.zeros((nu, known.nx))
        tracked_row[0, self.tracked_index] = 1.0
        self.target = SteadyStateTarget(self.model.A, self.model.B, tracked_row)
        self._xe, self._ue, self._ye = self.model.xe, self.model.ue, self.model.ye
        self._reference_offset = self.model.xe[self.tracked_index]
        # The stacked estimate (x̂, d̂) moves one sample with (A_aug, B_aug) under the command ũ.
        self._estimate = slice(0, known.nx + nu)
        self._A_aug, self._B_aug = self.observer.A_aug, np.vstack([self.model.B, np.zeros((nu, nu))])

    def initial_state(self, y0, r0) -> np.ndarray:
        """x_c at the first sample from the first measurement y0 and reference r0: at rest at the measured
        configuration, d̂ = 0, holding input as plan."""
        x0, u0 = self._start(y0, r0)
        self.solver.reset()
        self._info = {}
        return np.concatenate([x0 - self._xe, np.zeros(self.plant.nu), np.tile(u0, self.horizon)])

    def step(self, xc, y, r) -> tuple[np.ndarray, np.ndarray]:
        """One sample from the state xc: correct the estimate with y, solve the QP for reference r, command
        the first input."""
        sx, sd, _ = self._slices
        xc, y, r, plan = self._read(xc, y, r)
        estimate = xc[self._estimate]
        fault = None
        if not _finite(y):  # a lost measurement: the prediction stands as the estimate
            fault = "non-finite measurement"
        elif not _finite(estimate):
            fault = "non-finite estimate"
        else:
            estimate = self.observer.update(estimate, y - self._ye)
            if not _finite(estimate):
                fault = "non-finite estimate"
        x_hat, d_hat = estimate[sx], estimate[sd]
        solution = None
        if fault is None:
            x_target, u_target = self.target(r - self._reference_offset, d_hat)
            params = QPParameters(x_hat, d_hat, x_target, u_target, plan[0] - self._ue)
            try:
                solution = self.solver.solve(params)
            except Exception as err:  # a crashing solver is a failed solve: reported, never raised mid-run
                if interrupts.is_interrupt(err):
                    raise KeyboardInterrupt from err
                fault = f"solver raised {type(err).__name__}: {err}"
        if solution is None:
            assert fault is not None  # the solve was skipped or raised
            solution = QPSolution(
                np.full_like(plan, np.nan), np.zeros((self.horizon, self.problem.n_soft)), False, fault
            )
        new_plan, u, fallback, excess, success, status = self._follow(
            solution.inputs + self._ue, solution.success, solution.status, plan
        )
        ns = self.problem.n_soft
        self._info = {
            "solver": solver_name(self.solver),
            "status": status,
            "success": success,
            "iterations": solution.iterations,
            "solve_time": solution.solve_time,
            "fallback": fallback,
            "input_excess": excess,
            "soft_violation": float(solution.slacks.max()) if ns and success else 0.0,
            "soft_violation_now": self._violation_now(x_hat) if ns else 0.0,
        }
        # (x̂, d̂) one sample on: x̂⁺ = A x̂ + B (ũ + d̂), d̂⁺ = d̂ (non-finite after a fault, reported above).
        with np.errstate(invalid="ignore", over="ignore") if not success else contextlib.nullcontext():
            predicted = self._A_aug @ estimate + self._B_aug @ (u - self._ue)
        return np.concatenate((predicted, new_plan.ravel())), u

    @property
    def lockstep(self) -> bool:
        """Whether `step_many` can run (the solver's warm start can be saved and restored)."""
        return hasattr(self.solver, "warm_start")

    def initial_states(self, y0, r0) -> np.ndarray:
        """`initial_state` of m samples stepped together by `step_many`: y0 (m, ny) -> x_c (m, n_state),
        all with the reference r0."""
        if not self.lockstep:
            raise TypeError(
                f"{self.name}: the {solver_name(self.solver)} solver's warm start cannot be kept per sample "
                "(no warm_start attribute); step the samples one by one"
            )
        y0 = real_array(y0, f"{self.name}: first measurements").reshape(-1, self.plant.ny)
        rows, self._warm_starts = [], []
        for y in y0:
            rows.append(self.initial_state(y, r0))
            self._warm_starts.append(self.solver.warm_start)  # a fresh one each (initial_state resets)
        self.solver.reset()
        return np.array(rows)

    def step_many(self, xc, y, r, index) -> tuple[np.ndarray, np.ndarray, list[dict]]:
        """`step` of the samples `index` (rows of the `initial_states` batch), each from its own warm start.

        xc (m, n_state), y (m, ny) and r: the states, measurements and reference of those samples.
        Returns (x_c next (m, n_state), commands (m, nu), step records (m dicts, as `step_info()`)).
        """
        xc_next, commands, records = [], [], []
        for row, measured, i in zip(xc, y, index):
            self.solver.warm_start = self._warm_starts[i]
            state, command = self.step(row, measured, r)
            self._warm_starts[i] = self.solver.warm_start
            xc_next.append(state)
            commands.append(command)
            records.append(self.step_info())
        return np.array(xc_next), np.array(commands), records

    def _violation_now(self, x_hat) -> float:
        """Violation of the MPC's (backed-off) soft bounds by the current estimate."""
        if not self.problem.n_soft:
            return 0.0
        g = self.problem.soft_rows @ x_hat
        return float(np.max(np.maximum(0.0, np.maximum(self.problem.soft_lower - g, g - self.problem.soft_upper))))


class NonlinearMPC(_PlanFollower):
    """Offset-free nonlinear MPC on the known plant's equations (see `mpc.nonlinear`).

    The estimator is the disturbance-augmented Kalman gain of the linearization
    applied to the nonlinear model: predict x̂⁺ = F(x̂, u + d̂), correct with
    y − h(x̂). The target is the plant's exact equilibrium with the tracked
    coordinate at r (cached per reference value), and the terminal weight is
    the Riccati solution of the linearization there.

    Each sample runs one real-time iteration (`mpc.rti`): the preparation
    (linearization at the previous plan shifted by a sample, condensing) and the
    feedback (the QP for the corrected estimate); `step_info()` reports both
    times, the iterations and the QP's status. The first sample, and the first
    after a failed one, iterates to convergence from the plan rolled out
    through the model.

    Parameters
    ----------
    known : Plant
    sample_period, horizon, state_weight, input_weight, soft_bounds, tracked, name : as `LinearMPC`
    rate_limit : (nu,) input units per second, or None
    substeps : RK4 steps per sample in the prediction model
    iteration : "rti" (one SQP iteration per sample, the default) or "sqp" (iterated to convergence)
    max_iterations : SQP iterations where iterating to convergence
    tolerance : the SQP's convergence test, max ``|Δw|`` (inputs scaled by their limit)
    compiled : compile the iteration to machine code (`models.compile`); False runs CasADi's virtual machine
    input_noise_std, disturbance_step_std, measurement_std : estimator tuning, as `LinearMPC`
    """

    def __init__(
        self,
        known: Plant,
        *,
        sample_period: float,
        horizon: int,
        state_weight,
        input_weight,
        soft_bounds=(),
        rate_limit=None,
        tracked: str,
        substeps: int = 1,
        iteration: str = "rti",
        max_iterations: int = 50,
        tolerance: float = 1e-8,
        compiled: bool = True,
        input_noise_std=None,
        disturbance_step_std=None,
        measurement_std=1e-3,
        name: str = "nonlinear MPC",
    ):
        interrupts.watch()  # Ctrl-C stops a run even where CasADi swallows it (see models.interrupts)
        self._setup_common(known, sample_period, horizon, tracked, name)
        nx = known.nx
        self.Q = weight_matrix(state_weight, nx, "state_weight Q")
        self.R = weight_matrix(input_weight, known.nu, "input_weight R", definite=True)
        per_sample_rate = None if rate_limit is None else real_array(rate_limit, "rate_limit") * self.sample_period
        self._rate_per_sample = per_sample_rate
        self.soft_bounds = _soft_bounds(soft_bounds)
        self.nlp = self._problem(
            known,
            self.sample_period,
            self.horizon,
            self.Q,
            self.R,
            soft_bounds=self.soft_bounds,
            rate_limit=per_sample_rate,
            substeps=substeps,
            iteration=iteration,
            max_iterations=max_iterations,
            tolerance=tolerance,
            compiled=compiled,
        )
        self.step_model = known.step_function(self.sample_period, substeps)
        # Numeric calls without CasADi's DM conversions (half the cost of these small calls).
        self._predict, self._output = NumpyCall(self.step_model), NumpyCall(known.casadi_h)
        linear = known.linearize().discretize(self.sample_period)
        self.observer = DisturbanceObserver(
            linear.A,
            linear.B,
            linear.C,
            self.input_limit * 1e-2 if input_noise_std is None else input_noise_std,
            self.input_limit * 1e-3 if disturbance_step_std is None else disturbance_step_std,
            measurement_std,
        )
        self._targets: dict = {}
        self._soft_rows = np.array([b.row for b in self.soft_bounds]).reshape(-1, nx)
        self._soft_lower = np.array([b.lower for b in self.soft_bounds])
        self._soft_upper = np.array([b.upper for b in self.soft_bounds])

    def _problem(self, known: Plant, *arguments, **options):
        """The NLP this controller solves each sample (`NonlinearMPCProblem`; a subclass may solve another)."""
        return NonlinearMPCProblem(known, *arguments, **options)

    def target(self, reference: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_s, input holding it without disturbance, terminal weight P) for an absolute reference."""
        key = float(reference)
        if key not in self._targets:
            xs, vs = self.plant.equilibrium(**{self.tracked: key})
            lin = self.plant.linearize(xs, vs).discretize(self.sample_period)
            P, _ = riccati_terminal_cost(lin.A, lin.B, self.Q, self.R)
            if len(self._targets) > 64:
                self._targets.clear()
            self._targets[key] = (xs, vs, P)
        return self._targets[key]

    def initial_state(self, y0, r0) -> np.ndarray:
        """x_c at the first sample from the first measurement y0 and reference r0: at rest at the measured
        configuration, d̂ = 0, holding input as plan."""
        interrupts.watch()
        interrupts.clear()
        x0, u0 = self._start(y0, r0)
        self.nlp.reset()
        self._info = {}
        return np.concatenate([x0, np.zeros(self.plant.nu), np.tile(u0, self.horizon)])

    def step(self, xc, y, r) -> tuple[np.ndarray, np.ndarray]:
        """One sample from the state xc: correct the estimate with y, solve the NLP for reference r, command
        the first input.

        Raises KeyboardInterrupt at the end of the step when a Ctrl-C arrived during it, and at the
        start when one arrived since the last step and was swallowed (see `models.interrupts`).
        """
        interrupts.check()
        try:
            with interrupts.deferred():  # no CasADi call sees the interrupt: raised when the step ends
                return self._step(xc, y, r)
        except KeyboardInterrupt:
            interrupts.clear()  # delivered
            raise
        except Exception as err:
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            raise

    #: `step_many` can run (see `models.simulate_closed_loop_many`)
    lockstep = True

    def initial_states(self, y0, r0) -> np.ndarray:
        """`initial_state` of m samples stepped together by `step_many`: y0 (m, ny) -> x_c (m, n_state),
        all with the reference r0.

        Forgets every warm start, that of `step` included."""
        interrupts.watch()
        interrupts.clear()
        y0 = real_array(y0, f"{self.name}: first measurements").reshape(-1, self.plant.ny)
        rows = []
        for y in y0:
            x0, u0 = self._start(y, r0)
            rows.append(np.concatenate([x0, np.zeros(self.plant.nu), np.tile(u0, self.horizon)]))
        self.nlp.reset_many(len(rows))
        self._info = {}
        self._many_calls: dict = {}
        return np.array(rows)

    def _record(
        self, solver: str, status: str, success: bool, solution, fallback: bool, excess: float, x_hat: np.ndarray
    ) -> dict:
        """One step's solver record (see `step_info`); x_hat (nx,) the estimate the soft rows are read at."""
        g = self._soft_rows @ x_hat
        now = np.maximum(0.0, np.maximum(self._soft_lower - g, g - self._soft_upper))
        return {
            "solver": solver,
            "status": status,
            "success": success,
            "iterations": solution.iterations,
            "solve_time": solution.solve_time,
            "preparation_time": solution.preparation_time,
            "feedback_time": solution.feedback_time,
            "qp_status": solution.qp_status,
            "fallback": fallback,
            "input_excess": excess,
            "soft_violation": float(np.max(solution.slacks)) if solution.slacks.size and success else 0.0,
            "soft_violation_now": float(np.max(now)) if now.size else 0.0,
        }

    def step_many(self, xc, y, r, index) -> tuple[np.ndarray, np.ndarray, list[dict]]:
        """`step` of the samples `index` (rows of the `initial_states` batch), all at once.

        Each sample's numbers are those `step` gives it alone, from its own warm start; the
        real-time iterations of the samples run mapped over them (`NonlinearMPCProblem.solve_many`).

        Parameters
        ----------
        xc : (m, n_state);  y : (m, ny) measurements;  r : (1,) reference, shared;  index : (m,) int

        Returns
        -------
        (x_c next (m, n_state), commands (m, nu), step records (m dicts, as `step_info()`))
        """
        interrupts.check()
        try:
            with interrupts.deferred():
                return self._step_many(xc, y, r, index)
        except KeyboardInterrupt:
            interrupts.clear()
            raise
        except Exception as err:
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            raise

    def _mapped_call(self, fun, m: int) -> NumpyCall:
        key = (fun.name(), m)
        if key not in self._many_calls:
            self._many_calls[key] = NumpyCall(fun.map(m))
        return self._many_calls[key]

    def _step_many(self, xc, y, r, index):
        sx, sd, splan = self._slices
        xc, y = np.asarray(xc, dtype=float), np.asarray(y, dtype=float)
        index = np.asarray(index, dtype=int)
        m, N, nu, nx = len(index), self.horizon, self.plant.nu, self.plant.nx
        if xc.shape != (m, self.n_state) or y.shape != (m, self.plant.ny):
            raise ValueError(
                f"{self.name}: step_many takes x_c ({m}, {self.n_state}) and y ({m}, {self.plant.ny}) "
                f"for {m} samples, got {xc.shape} and {y.shape}"
            )
        r = _finite_vector(r, 1, f"{self.name}: reference")
        p = self._known_params
        plans = xc[:, splan].reshape(m, N, nu)
        x_hat, d_hat = xc[:, sx].copy(), xc[:, sd].copy()
        faults: list = [None] * m
        measured = np.all(np.isfinite(y), axis=1)
        for j in np.flatnonzero(~measured):  # a lost measurement: the prediction stands as the estimate
            faults[j] = "non-finite measurement"
        rows = np.flatnonzero(measured)
        if rows.size:
            known = np.tile(p[:, None], rows.size)
            predicted = self._mapped_call(self.plant.casadi_h, rows.size)(x_hat[rows].T, known)[0].T
            for j, h in zip(rows, predicted):
                x_hat[j], d_hat[j] = self.observer.correct(x_hat[j], d_hat[j], y[j] - h)
                if not (_finite(x_hat[j]) and _finite(d_hat[j])):
                    faults[j] = "non-finite estimate"
        solutions: list = [None] * m
        good = np.array([f is None for f in faults], dtype=bool)
        if good.any():
            x_target, v_target, P = self.target(r[0])
            g = np.flatnonzero(good)
            for j, solution in zip(
                g,
                self.nlp.solve_many(
                    index[g], x_hat[g], d_hat[g], x_target, v_target - d_hat[g], P, plans[g, 0], plans[g]
                ),
            ):
                solutions[j] = solution
        xc_next, commands, records = np.empty_like(xc), np.empty((m, nu)), []
        followed = []
        for j in range(m):
            solution = solutions[j]
            if solution is None:
                solution = NLPSolution(
                    np.full((N, nu), np.nan),
                    np.full((N + 1, nx), np.nan),
                    np.zeros((N, len(self.soft_bounds))),
                    False,
                    faults[j],
                    0,
                    0.0,
                )
                solutions[j] = solution
            followed.append(self._follow(solution.inputs, solution.success, solution.status, plans[j]))
            commands[j] = followed[-1][1]
        with np.errstate(invalid="ignore", over="ignore"):
            x_next = self._mapped_call(self.step_model, m)(x_hat.T, (commands + d_hat).T, np.tile(p[:, None], m))[0].T
        solver = f"{self.nlp.iteration}/{self.nlp.qp_solver}"
        for j in range(m):
            new_plan, u, fallback, excess, success, status = followed[j]
            solution = solutions[j]
            if not _finite(x_next[j]) and _finite(x_hat[j]) and _finite(u):
                x_next[j] = x_hat[j]
                status += "; non-finite model prediction, estimate held"
            records.append(self._record(solver, status, success, solution, fallback, excess, x_hat[j]))
            xc_next[j, sx], xc_next[j, sd], xc_next[j, splan] = x_next[j], d_hat[j], new_plan.ravel()
        self._info = dict(records[-1]) if records else {}
        return xc_next, commands, records

    def _step(self, xc, y, r) -> tuple[np.ndarray, np.ndarray]:
        sx, sd, _ = self._slices
        xc, y, r, plan = self._read(xc, y, r)
        p = self._known_params
        x_hat, d_hat = xc[sx], xc[sd]
        fault = None
        if not _finite(y):  # a lost measurement: the prediction stands as the estimate
            fault = "non-finite measurement"
        else:
            innovation = y - self._output(x_hat, p)[0].ravel()
            x_hat, d_hat = self.observer.correct(x_hat, d_hat, innovation)
            if not (_finite(x_hat) and _finite(d_hat)):
                fault = "non-finite estimate"
        if fault is None:
            x_target, v_target, P = self.target(r[0])
            solution = self.nlp.solve(x_hat, d_hat, x_target, v_target - d_hat, P, plan[0], plan)
        else:
            N, nu = self.horizon, self.plant.nu
            solution = NLPSolution(
                np.full((N, nu), np.nan),
                np.full((N + 1, self.plant.nx), np.nan),
                np.zeros((N, len(self.soft_bounds))),
                False,
                fault,
                0,
                0.0,
            )
        new_plan, u, fallback, excess, success, status = self._follow(
            solution.inputs, solution.success, solution.status, plan
        )
        x_next = self._predict(x_hat, u + d_hat, p)[0].ravel()
        if not _finite(x_next) and _finite(x_hat) and _finite(u):
            # The model's prediction blew up from a finite estimate: hold the estimate, say so.
            x_next = x_hat
            status += "; non-finite model prediction, estimate held"
        solver = f"{self.nlp.iteration}/{self.nlp.qp_solver}"
        self._info = self._record(solver, status, success, solution, fallback, excess, x_hat)
        return np.concatenate([x_next, d_hat, new_plan.ravel()]), u
