"""The OSQP path: the sparse (uncondensed) MPC QP, set up once, vectors updated, warm-started.

As in OSQP's own MPC example the decision vector is
z = (x_0..x_N, u_0..u_{N-1}, s_1..s_N) and every constraint is a row of one
sparse matrix with bounds l ≤ A_c z ≤ u:

    x_0 = x̂  and  x_{k+1} − A x_k − B u_k = B d         (equalities, l = u)
    u_lo ≤ u_k ≤ u_hi,  s ≥ 0
    G x_k + s_k ≥ g_lo,  G x_k − s_k ≤ g_hi              (soft bounds, k = 1..N)
    −Δ ≤ u_k − u_{k−1} ≤ Δ  (u_{−1} = previous input)     (optional)

Per sample only q (x_s, u_s) and the bounds (x̂, d, u_{−1}) change; OSQP keeps
its factorization and warm-starts from the previous primal-dual pair. The
variables are scaled to a unit Hessian diagonal (z = D z̄) before OSQP's own
equilibration; without it OSQP does not converge on the crane (kilonewton
inputs against metre and radian states) in 20000 iterations.
"""

from __future__ import annotations

import time

import numpy as np

from models import deferred

from .linear import INFINITY, MPCProblem, QPParameters, QPSolution

osqp = deferred.module("osqp")
sparse = deferred.module("scipy.sparse")

#: Tight enough that the first input agrees with the interior-point reference to 1e-5.
DEFAULT_SETTINGS = dict(eps_abs=1e-7, eps_rel=1e-7, polishing=True, max_iter=20000, verbose=False, warm_starting=True)


def _checked_settings(settings) -> dict:
    """`settings` as a dict of numbers and flags, negative numbers refused (OSQP itself reports only a code)."""
    if settings is None:
        return {}
    if not isinstance(settings, dict):
        raise TypeError(f"settings must be a dict of OSQP settings, got {type(settings).__name__} {settings!r}")
    for key, value in settings.items():
        if not isinstance(value, (bool, int, float, np.integer, np.floating)):
            raise TypeError(f"OSQP setting {key} must be a number or True/False, got {type(value).__name__} {value!r}")
        if not isinstance(value, bool) and not value >= 0:
            raise ValueError(f"OSQP setting {key} must be a number >= 0, got {value!r}")
    return dict(settings)


class OsqpSolver:
    """Sparse MPC QP with OSQP.

    Parameters
    ----------
    problem : MPCProblem
    settings : dict, OSQP settings overriding `DEFAULT_SETTINGS`
    """

    name = "osqp"

    def __init__(self, problem: MPCProblem, settings: dict | None = None):
        self.problem = problem
        self.settings = DEFAULT_SETTINGS | _checked_settings(settings)
        N, nx, nu, ns = problem.horizon, problem.nx, problem.nu, problem.n_soft
        self.n_states, self.n_inputs, self.n_slacks = (N + 1) * nx, N * nu, N * ns
        eye = lambda n: sparse.identity(n, format="csc")
        P = sparse.block_diag(
            [
                sparse.kron(eye(N), problem.Q),
                problem.P,
                sparse.kron(eye(N), problem.R),
                sparse.kron(eye(N), sparse.diags(problem.soft_quadratic_weight)),
            ],
            format="csc",
        )
        self.P = 2 * P
        # Dynamics: −x_{k+1} + A x_k + B u_k = −B d;  −x_0 = −x̂.
        dyn_x = sparse.kron(eye(N + 1), -eye(nx)) + sparse.kron(sparse.eye(N + 1, k=-1), problem.A)
        dyn_u = sparse.kron(sparse.vstack([sparse.csc_matrix((1, N)), eye(N)]), problem.B)
        blocks = [[dyn_x, dyn_u, sparse.csc_matrix((self.n_states, self.n_slacks))]]
        # The dynamics' bounds are placeholders here, set per sample.
        lower: list[np.ndarray] = [np.zeros(self.n_states)]
        upper: list[np.ndarray] = [np.zeros(self.n_states)]
        blocks.append([None, eye(self.n_inputs), None])
        lower.append(np.tile(problem.input_lower, N))
        upper.append(np.tile(problem.input_upper, N))
        if ns:
            blocks.append([None, None, eye(self.n_slacks)])
            lower.append(np.zeros(self.n_slacks))
            upper.append(np.full(self.n_slacks, INFINITY))
            soft_x = sparse.hstack([sparse.csc_matrix((N * ns, nx)), sparse.kron(eye(N), problem.soft_rows)])
            blocks.append([soft_x, None, eye(self.n_slacks)])
            lower.append(np.tile(np.where(np.isfinite(problem.soft_lower), problem.soft_lower, -INFINITY), N))
            upper.append(np.full(self.n_slacks, INFINITY))
            blocks.append([soft_x, None, -eye(self.n_slacks)])
            lower.append(np.full(self.n_slacks, -INFINITY))
            upper.append(np.tile(np.where(np.isfinite(problem.soft_upper), problem.soft_upper, INFINITY), N))
        if problem.rate_limit is not None:
            difference = eye(self.n_inputs) - sparse.eye(self.n_inputs, k=-nu)
            blocks.append([None, difference, None])
            lower.append(np.tile(-problem.rate_limit, N))
            upper.append(np.tile(problem.rate_limit, N))
        self.A = sparse.bmat(blocks, format="csc")
        self.lower, self.upper = np.concatenate(lower), np.concatenate(upper)
        self._rate_start = self.A.shape[0] - self.n_inputs if problem.rate_limit is not None else None
        self.q = np.zeros(self.A.shape[1])
        self.q[self.n_states + self.n_inputs :] = np.tile(problem.soft_linear_weight, N)
        self.scale = 1 / np.sqrt(self.P.diagonal())
        D = sparse.diags(self.scale)
        self._P_scaled = (D @ self.P @ D).tocsc()
        self._A_scaled = (self.A @ D).tocsc()
        self.reset()

    def reset(self) -> None:
        """Set OSQP up afresh (forgets the warm start)."""
        self._solver = osqp.OSQP()
        self._solver.setup(self._P_scaled, self.q * self.scale, self._A_scaled, self.lower, self.upper, **self.settings)

    def _update_vectors(self, params: QPParameters) -> None:
        pb, N, nx, nu = self.problem, self.problem.horizon, self.problem.nx, self.problem.nu
        self.q[: N * nx] = np.tile(-2 * pb.Q @ params.x_target, N)
        self.q[N * nx : self.n_states] = -2 * pb.P @ params.x_target
        self.q[self.n_states : self.n_states + self.n_inputs] = np.tile(-2 * pb.R @ params.u_target, N)
        dynamics = np.concatenate([-params.x0, np.tile(-pb.B @ params.disturbance, N)])
        self.lower[: self.n_states] = dynamics
        self.upper[: self.n_states] = dynamics
        if self._rate_start is not None:
            self.lower[self._rate_start : self._rate_start + nu] = params.u_previous - pb.rate_limit
            self.upper[self._rate_start : self._rate_start + nu] = params.u_previous + pb.rate_limit

    def solve(self, params: QPParameters) -> QPSolution:
        """Update q and the bounds for `params`, solve warm-started, return the plan."""
        start = time.perf_counter()
        self._update_vectors(params)
        self._solver.update(q=self.q * self.scale, l=self.lower, u=self.upper)
        result = self._solver.solve(raise_error=False)
        elapsed = time.perf_counter() - start
        N, nu, ns = self.problem.horizon, self.problem.nu, self.problem.n_soft
        status = str(result.info.status)
        z = np.asarray(result.x, dtype=float) * self.scale if result.x is not None else np.full(self.A.shape[1], np.nan)
        success = status == "solved" and np.all(np.isfinite(z))
        inputs = z[self.n_states : self.n_states + self.n_inputs].reshape(N, nu)
        slacks = z[self.n_states + self.n_inputs :].reshape(N, ns)
        return QPSolution(
            inputs,
            slacks,
            bool(success),
            status,
            int(result.info.iter),
            elapsed,
            {"polished": int(result.info.status_polish) == 1},
        )
