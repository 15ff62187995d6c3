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
"""

from __future__ import annotations

import numpy as np

from models import Plant

from .estimator import DisturbanceObserver, SteadyStateTarget
from .linear import MPCProblem, QPParameters, QPSolution, problem_from_model, riccati_terminal_cost
from .nonlinear import NonlinearMPCProblem
from .qp_fast import CondensedDaqpSolver
from .qp_osqp import OsqpSolver
from .reference_cvxpy import CvxpySolver

SOLVERS = {"daqp": CondensedDaqpSolver, "osqp": OsqpSolver, "cvxpy": CvxpySolver}


def _finite_vector(value, size: int, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != size or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be {size} finite values, got {value!r}")
    return arr


class _PlanFollower:
    """What both MPCs share: settings checks, the controller-state layout, the start from the
    first measurement, the fallback to the shifted plan, exact clipping and `step_info`.

    Subclasses call `_setup_common`, set `_rate_per_sample` (or None) and write
    `initial_state` and `step`.
    """

    measures = "outputs"
    n_reference = 1

    def _setup_common(self, known: Plant, sample_period: float, horizon: int, tracked: str, name: str):
        if not np.isfinite(sample_period) or sample_period <= 0:
            raise ValueError(f"sample_period must be > 0 s, got {sample_period}")
        if int(horizon) != horizon or horizon < 1:
            raise ValueError(f"horizon must be an integer >= 1, got {horizon}")
        if known.nu != 1:
            raise ValueError(f"{known.name} has {known.nu} inputs; these controllers track one coordinate "
                             "with one input")
        self.plant = known
        self.sample_period = float(sample_period)
        self.horizon = int(horizon)
        self.name = name
        self.tracked = tracked
        if self.tracked not in known.coordinate_names:
            raise ValueError(f"{known.name} has no coordinate {self.tracked!r} to track; coordinates are "
                             f"{', '.join(known.coordinate_names)}")
        self.tracked_index = known.state_names.index(self.tracked)
        self.input_limit = known.input_limit.copy()
        self._known_params = known.param_vector()
        self._info: dict = {}
        nx, nu = known.nx, known.nu
        self._slices = (slice(0, nx), slice(nx, nx + nu), slice(nx + nu, nx + nu + self.horizon * nu))

    @property
    def n_state(self) -> int:
        """Size of the controller state x_c = (x̂, d̂, plan)."""
        return self.plant.nx + self.plant.nu + self.horizon * self.plant.nu

    def _start(self, y0, r0) -> tuple[np.ndarray, np.ndarray]:
        """Absolute state at rest at the measured configuration, and the input holding it (clipped)."""
        y0 = _finite_vector(y0, self.plant.ny, f"{self.name}: first measurement {self.plant.output_names}")
        _finite_vector(r0, 1, f"{self.name}: first reference")
        q0 = np.asarray(self.plant.casadi_configuration(y0, self._known_params)).ravel()
        x0 = np.concatenate([q0, np.zeros(self.plant.nq)])
        u0 = np.clip(self.plant.equilibrium_input(q0, self._known_params), -self.input_limit, self.input_limit)
        return x0, u0

    def _read(self, xc, y, r) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Checked (x_c, y, r) of one step and the stored input plan, (horizon, nu)."""
        xc = np.asarray(xc, dtype=float)
        y = _finite_vector(y, self.plant.ny, f"{self.name}: measurement {self.plant.output_names}")
        r = _finite_vector(r, 1, f"{self.name}: reference")
        if xc.shape != (self.n_state,):
            raise ValueError(f"{self.name}: controller state must have {self.n_state} entries, got {xc.shape}")
        return xc, y, r, xc[self._slices[2]].reshape(self.horizon, self.plant.nu)

    def _follow(self, solution_inputs, success: bool, plan: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, float]:
        """The plan to follow (clipped), the command, whether the fallback was used, the clipped excess.

        The solver's plan when it succeeded, else the previous plan shifted by one sample.
        Clipping happens here, after solving, so the command is within ±input_limit exactly
        (and within the rate limit of the previous command, which is itself within the limit).
        """
        fallback = not (success and bool(np.isfinite(solution_inputs).all()))
        candidate = np.vstack([plan[1:], plan[-1:]]) if fallback else solution_inputs
        excess = max(0.0, float(np.max(np.abs(candidate[0]) - self.input_limit)))
        new_plan = np.clip(candidate, -self.input_limit, self.input_limit)
        if self._rate_per_sample is not None:
            new_plan[0] = np.clip(new_plan[0], plan[0] - self._rate_per_sample, plan[0] + self._rate_per_sample)
            new_plan[0] = np.clip(new_plan[0], -self.input_limit, self.input_limit)
        return new_plan, new_plan[0].copy(), fallback, excess

    def step_info(self) -> dict:
        """The last step's record: solver, status, success, iterations, solve_time (s), fallback,
        input_excess (what clipping removed from the solver's first input), soft_violation
        (largest predicted soft-bound violation over the horizon, in the bound's unit) and
        soft_violation_now (the estimate's current violation)."""
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
    tracked : coordinate whose absolute value the reference gives
    operating_point : (xe, ue) to linearize about (default: the plant's standard equilibrium)
    input_noise_std, disturbance_step_std, measurement_std : the estimator's tuning, see
        `mpc.estimator.DisturbanceObserver`
    name : str
    """

    def __init__(self, known: Plant, *, sample_period: float, horizon: int, state_weight, input_weight,
                 soft_bounds=(), rate_limit=None, solver="daqp", tracked: str,
                 operating_point=None, input_noise_std=None, disturbance_step_std=None,
                 measurement_std=1e-3, name: str = "linear MPC"):
        self._setup_common(known, sample_period, horizon, tracked, name)
        xe, ue = known.equilibrium() if operating_point is None else operating_point
        self.model = known.linearize(xe, ue).discretize(self.sample_period)
        per_sample_rate = None if rate_limit is None else np.asarray(rate_limit, dtype=float) * self.sample_period
        self._rate_per_sample = per_sample_rate
        self.soft_bounds = tuple(soft_bounds)
        self.problem: MPCProblem = problem_from_model(
            self.model, state_weight, input_weight, self.horizon, self.input_limit,
            rate_limit=per_sample_rate, soft_bounds=self.soft_bounds)
        self.solver = SOLVERS[solver](self.problem) if isinstance(solver, str) else solver(self.problem)
        nu = known.nu
        self.observer = DisturbanceObserver(
            self.model.A, self.model.B, self.model.C,
            self.input_limit * 1e-2 if input_noise_std is None else input_noise_std,
            self.input_limit * 1e-3 if disturbance_step_std is None else disturbance_step_std,
            measurement_std)
        tracked_row = np.zeros((nu, known.nx))
        tracked_row[0, self.tracked_index] = 1.0
        self.target = SteadyStateTarget(self.model.A, self.model.B, tracked_row)
        self._xe, self._ue, self._ye = self.model.xe, self.model.ue, self.model.ye
        self._reference_offset = self.model.xe[self.tracked_index]

    def initial_state(self, y0, r0) -> np.ndarray:
        """x_c at the first sample: at rest at the measured configuration, d̂ = 0, holding input as plan."""
        x0, u0 = self._start(y0, r0)
        self.solver.reset()
        self._info = {}
        return np.concatenate([x0 - self._xe, np.zeros(self.plant.nu), np.tile(u0, self.horizon)])

    def step(self, xc, y, r) -> tuple[np.ndarray, np.ndarray]:
        """One sample: correct the estimate with y, solve the QP for reference r, command the first input."""
        sx, sd, _ = self._slices
        xc, y, r, plan = self._read(xc, y, r)
        model = self.model
        x_hat, d_hat = self.observer.correct(xc[sx], xc[sd], y - self._ye - model.C @ xc[sx])
        x_target, u_target = self.target(r - self._reference_offset, d_hat)
        params = QPParameters(x_hat, d_hat, x_target, u_target, plan[0] - self._ue)
        try:
            solution = self.solver.solve(params)
        except Exception as err:  # a crashing solver is a failed solve: reported, never raised mid-run
            solution = QPSolution(np.full_like(plan, np.nan), np.zeros((self.horizon, self.problem.n_soft)), False,
                                  f"solver raised {type(err).__name__}: {err}")
        new_plan, u, fallback, excess = self._follow(solution.inputs + self._ue, solution.success, plan)
        x_next = model.A @ x_hat + model.B @ (u - self._ue + d_hat)
        ns = self.problem.n_soft
        self._info = {
            "solver": self.solver.name, "status": solution.status, "success": solution.success,
            "iterations": solution.iterations, "solve_time": solution.solve_time, "fallback": fallback,
            "input_excess": excess,
            "soft_violation": float(np.max(solution.slacks)) if ns and solution.success else 0.0,
            "soft_violation_now": self._violation_now(x_hat),
        }
        return np.concatenate([x_next, d_hat, new_plan.ravel()]), u

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

    Parameters
    ----------
    known : Plant
    sample_period, horizon, state_weight, input_weight, soft_bounds, tracked, name : as `LinearMPC`
    rate_limit : (nu,) input units per second, or None
    substeps : RK4 steps per sample in the prediction model
    max_iterations : SQP iterations per sample
    qp_solver : CasADi conic plugin for the SQP's QPs: "hpipm" (structure-exploiting interior
        point, the default; "qrqp" when a rate limit couples the stages) or "qrqp"
    input_noise_std, disturbance_step_std, measurement_std : estimator tuning, as `LinearMPC`
    """

    def __init__(self, known: Plant, *, sample_period: float, horizon: int, state_weight, input_weight,
                 soft_bounds=(), rate_limit=None, tracked: str, substeps: int = 1,
                 max_iterations: int = 20, qp_solver: str = "hpipm", input_noise_std=None,
                 disturbance_step_std=None, measurement_std=1e-3, name: str = "nonlinear MPC"):
        self._setup_common(known, sample_period, horizon, tracked, name)
        nx = known.nx
        self.Q = np.diag(state_weight) if np.ndim(state_weight) == 1 else np.asarray(state_weight, dtype=float)
        self.R = np.diag(input_weight) if np.ndim(input_weight) == 1 else np.atleast_2d(input_weight).astype(float)
        per_sample_rate = None if rate_limit is None else np.asarray(rate_limit, dtype=float) * self.sample_period
        self._rate_per_sample = per_sample_rate
        self.soft_bounds = tuple(soft_bounds)
        self.nlp = NonlinearMPCProblem(known, self.sample_period, self.horizon, self.Q, self.R,
                                       soft_bounds=self.soft_bounds, rate_limit=per_sample_rate,
                                       substeps=substeps, max_iterations=max_iterations, qp_solver=qp_solver)
        self.step_model = known.step_function(self.sample_period, substeps)
        linear = known.linearize().discretize(self.sample_period)
        self.observer = DisturbanceObserver(
            linear.A, linear.B, linear.C,
            self.input_limit * 1e-2 if input_noise_std is None else input_noise_std,
            self.input_limit * 1e-3 if disturbance_step_std is None else disturbance_step_std,
            measurement_std)
        self._targets: dict = {}
        self._soft_rows = np.array([b.row for b in self.soft_bounds]).reshape(-1, nx)
        self._soft_lower = np.array([b.lower for b in self.soft_bounds])
        self._soft_upper = np.array([b.upper for b in self.soft_bounds])

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
        """x_c at the first sample: at rest at the measured configuration, d̂ = 0, holding input as plan."""
        x0, u0 = self._start(y0, r0)
        self.nlp.reset()
        self._info = {}
        return np.concatenate([x0, np.zeros(self.plant.nu), np.tile(u0, self.horizon)])

    def step(self, xc, y, r) -> tuple[np.ndarray, np.ndarray]:
        """One sample: correct the estimate with y, solve the NLP for reference r, command the first input."""
        sx, sd, _ = self._slices
        xc, y, r, plan = self._read(xc, y, r)
        p = self._known_params
        innovation = y - np.asarray(self.plant.casadi_h(xc[sx], p)).ravel()
        x_hat, d_hat = self.observer.correct(xc[sx], xc[sd], innovation)
        x_target, v_target, P = self.target(r[0])
        solution = self.nlp.solve(x_hat, d_hat, x_target, v_target - d_hat, P, plan[0], plan)
        new_plan, u, fallback, excess = self._follow(solution.inputs, solution.success, plan)
        x_next = np.asarray(self.step_model(x_hat, u + d_hat, p)).ravel()
        if not np.all(np.isfinite(x_next)):
            x_next = x_hat
        g = self._soft_rows @ x_hat
        now = np.maximum(0.0, np.maximum(self._soft_lower - g, g - self._soft_upper))
        self._info = {
            "solver": f"sqpmethod/{self.nlp.qp_solver}", "status": solution.status, "success": solution.success,
            "iterations": solution.iterations, "solve_time": solution.solve_time, "fallback": fallback,
            "input_excess": excess,
            "soft_violation": float(np.max(solution.slacks)) if solution.slacks.size and solution.success else 0.0,
            "soft_violation_now": float(np.max(now)) if now.size else 0.0,
        }
        return np.concatenate([x_next, d_hat, new_plan.ravel()]), u
