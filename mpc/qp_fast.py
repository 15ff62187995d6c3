"""The fast path: the condensed QP solved by DAQP's dual active-set method, warm-started.

Eliminating the states with [x_1; ..; x_N] = Φ x_0 + Γ (U + 1⊗d) leaves a
dense QP in the N·nu inputs U and the N·ns slacks S:

    minimize  ½ zᵀ H z + fᵀ z,   z = (U, S)
    subject to  u_lo ≤ U ≤ u_hi,  S ≥ 0                      (simple bounds)
                g_lo − Ḡ(Φ x_0 + Γ 1⊗d) ≤ ḠΓ U + S          (soft, lower side)
                ḠΓ U − S ≤ g_hi − Ḡ(Φ x_0 + Γ 1⊗d)          (soft, upper side)
                −Δ ≤ u_k − u_{k−1} ≤ Δ                        (rate, optional)

The variables are scaled so that H has a unit diagonal (z = D z̄), which makes
a crane's newtons and an arm's newton-metres alike to DAQP's tolerances.
H and the constraint matrix never change, so DAQP factors them once; each
sample only f (affine in x_0, d, x_s, u_s) and the constraint bounds change.
DAQP keeps the previous active set, so a solve where the saturation pattern
is unchanged costs a few microseconds. Without soft bounds or rate limits the
only constraints are the input box.
"""

from __future__ import annotations

import time

import daqp
import numpy as np
import scipy.linalg

from .linear import INFINITY, MPCProblem, QPParameters, QPSolution, integer

#: DAQP exit flags (daqp/include/constants.h).
DAQP_STATUS = {1: "optimal", 2: "soft optimal", -1: "primal infeasible", -2: "cycling detected",
               -3: "unbounded", -4: "iteration limit", -5: "nonconvex problem", -6: "overdetermined initial active set",
               -7: "time limit"}

#: Constraint violation DAQP accepts, in the scaled variables.
PRIMAL_TOLERANCE = 1e-10


class CondensedDaqpSolver:
    """Condensed MPC QP with DAQP; the matrices are set up once at construction.

    Parameters
    ----------
    problem : MPCProblem
    iteration_limit : int, DAQP's bound on active-set changes per solve
    """

    name = "daqp"

    def __init__(self, problem: MPCProblem, iteration_limit: int = 1000):
        self.problem = problem
        N, nx, nu, ns = problem.horizon, problem.nx, problem.nu, problem.n_soft
        self.n_inputs, self.n_slacks = N * nu, N * ns
        Phi, Gamma = problem.prediction_matrices()
        Q_bar = scipy.linalg.block_diag(*([problem.Q] * (N - 1) + [problem.P]))
        R_bar = np.kron(np.eye(N), problem.R)
        stack_u = np.kron(np.ones((N, 1)), np.eye(nu))  # d or u_s repeated over the horizon
        stack_x = np.kron(np.ones((N, 1)), np.eye(nx))
        GtQ = Gamma.T @ Q_bar
        H_inputs = 2 * (GtQ @ Gamma + R_bar)
        H_slacks = 2 * np.diag(np.tile(problem.soft_quadratic_weight, N))
        self.H = scipy.linalg.block_diag(H_inputs, H_slacks)
        self.H = (self.H + self.H.T) / 2
        # f = F_theta @ (x0, d, x_s, u_s) for the inputs; the slacks' gradient is the constant w.
        self.F_theta = 2 * np.hstack([GtQ @ Phi, GtQ @ Gamma @ stack_u, -GtQ @ stack_x, -R_bar @ stack_u])
        self.f_slacks = np.tile(problem.soft_linear_weight, N)

        rows = []
        G_bar = np.kron(np.eye(N), problem.soft_rows)
        G_Gamma = G_bar @ Gamma
        # Soft-row bounds are g_bound − (Ḡ Φ x0 + Ḡ Γ 1⊗d): affine in (x0, d).
        self.soft_offset = np.hstack([G_bar @ Phi, G_Gamma @ stack_u])
        lower_all = np.tile(problem.soft_lower, N)
        upper_all = np.tile(problem.soft_upper, N)
        self.lower_rows = np.flatnonzero(np.isfinite(lower_all))
        self.upper_rows = np.flatnonzero(np.isfinite(upper_all))
        slack_identity = np.eye(self.n_slacks)
        if self.lower_rows.size:
            rows.append(np.hstack([G_Gamma, slack_identity])[self.lower_rows])
        if self.upper_rows.size:
            rows.append(np.hstack([G_Gamma, -slack_identity])[self.upper_rows])
        self.soft_lower_bound = lower_all[self.lower_rows]
        self.soft_upper_bound = upper_all[self.upper_rows]
        if problem.rate_limit is not None:
            difference = np.eye(N * nu) - np.eye(N * nu, k=-nu)  # row k: u_k − u_{k−1}, row 0: u_0
            rows.append(np.hstack([difference, np.zeros((N * nu, self.n_slacks))]))
            self.rate_bound = np.tile(problem.rate_limit, N)
        n = self.n_inputs + self.n_slacks
        A = np.vstack(rows) if rows else np.zeros((0, n))
        # Jacobi scaling z = D z̄: unit diagonal of the Hessian DAQP sees.
        self.scale = 1 / np.sqrt(np.diag(self.H))
        self.H_scaled = self.H * np.outer(self.scale, self.scale)
        self.A = A * self.scale
        self.bupper = np.concatenate([np.tile(problem.input_upper, N) / self.scale[:self.n_inputs],
                                      np.full(self.n_slacks, INFINITY), np.full(self.A.shape[0], INFINITY)])
        self.blower = np.concatenate([np.tile(problem.input_lower, N) / self.scale[:self.n_inputs],
                                      np.zeros(self.n_slacks), np.full(self.A.shape[0], -INFINITY)])
        self._n_lower, self._n_upper = self.lower_rows.size, self.upper_rows.size
        self.iteration_limit = integer(iteration_limit, "iteration_limit")
        self._f = np.concatenate([np.zeros(self.n_inputs), self.f_slacks * self.scale[self.n_inputs:]])
        self._f_per_theta = self.F_theta * self.scale[:self.n_inputs, None]  # f of the scaled inputs
        self._bounds_vary = bool(self._n_lower or self._n_upper or problem.rate_limit is not None)
        # Buffers the hot path writes into: theta = (x0, d, x_s, u_s) and the inputs' part of f.
        self._theta = np.zeros(2 * (nx + nu))
        self._theta_parts = (slice(0, nx), slice(nx, nx + nu), slice(nx + nu, 2 * nx + nu), slice(2 * nx + nu, None))
        self._f_inputs = self._f[:self.n_inputs]
        self._shapes = ((N, nu), (N, ns))
        self.reset()

    def _update_vectors(self, params: QPParameters) -> None:
        theta, (x0, d, xs, us) = self._theta, self._theta_parts
        theta[x0], theta[d], theta[xs], theta[us] = params.x0, params.disturbance, params.x_target, params.u_target
        np.dot(self._f_per_theta, theta, out=self._f_inputs)
        if self._bounds_vary:
            self._update_bounds(theta, params.u_previous)

    def _update_bounds(self, theta: np.ndarray, u_previous: np.ndarray) -> None:
        start = self.n_inputs + self.n_slacks
        if self._n_lower or self._n_upper:
            offset = self.soft_offset @ theta[:self.problem.nx + self.problem.nu]
            self.blower[start:start + self._n_lower] = self.soft_lower_bound - offset[self.lower_rows]
            start += self._n_lower
            self.bupper[start:start + self._n_upper] = self.soft_upper_bound - offset[self.upper_rows]
            start += self._n_upper
        if self.problem.rate_limit is not None:
            nu = self.problem.nu
            self.bupper[start:] = self.rate_bound
            self.blower[start:] = -self.rate_bound
            self.bupper[start:start + nu] += u_previous
            self.blower[start:start + nu] += u_previous

    def solve(self, params: QPParameters) -> QPSolution:
        """Update f and the bounds for `params`, solve warm-started, return the plan.

        The hot path of linear MPC: the matrices are fixed, the vectors are written into
        buffers in place, and DAQP keeps its factorization and active set between calls.
        """
        start = time.perf_counter()
        self._update_vectors(params)
        model = self._model
        if not self._set_up:
            flag, _ = model.setup(self.H_scaled, self._f, self.A, self.bupper, self.blower)
            self._set_up = True
            if flag < 0:
                return self._failure(f"setup failed ({DAQP_STATUS.get(flag, flag)})", start)
        elif self._bounds_vary:
            model.update(f=self._f, bupper=self.bupper, blower=self.blower)
        else:
            model.update(f=self._f)
        z, _, flag, info = model.solve()
        z *= self.scale  # DAQP returns a fresh array
        success = flag > 0 and bool(np.isfinite(z).all())
        n, (inputs, slacks) = self.n_inputs, self._shapes
        return QPSolution(z[:n].reshape(inputs), z[n:].reshape(slacks), success,
                          DAQP_STATUS.get(flag, f"exit flag {flag}"), info["iterations"],
                          time.perf_counter() - start)

    def _failure(self, status: str, start: float) -> QPSolution:
        N, nu, ns = self.problem.horizon, self.problem.nu, self.problem.n_soft
        return QPSolution(np.full((N, nu), np.nan), np.full((N, ns), np.nan), False, status, 0,
                          time.perf_counter() - start)

    def reset(self) -> None:
        """Forget the warm start (the next solve sets DAQP up from scratch)."""
        self._model = daqp.Model()
        # DAQP's default primal tolerance (1e-6) lets a soft bound be crossed by 1e-6 with zero
        # slack; on the pendulum's |theta| bound that moves the first input by 1e-3.
        self._model.settings = {"iter_limit": self.iteration_limit, "primal_tol": PRIMAL_TOLERANCE}
        self._set_up = False
