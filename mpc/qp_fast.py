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
from dataclasses import dataclass

import daqp
import numpy as np

from models import deferred
from models.checks import integer

from .linear import INFINITY, MPCProblem, QPParameters, QPSolution

scipy = deferred.module("scipy")

#: DAQP exit flags (daqp/include/constants.h).
DAQP_STATUS = {
    1: "optimal",
    2: "soft optimal",
    -1: "primal infeasible",
    -2: "cycling detected",
    -3: "unbounded",
    -4: "iteration limit",
    -5: "nonconvex problem",
    -6: "overdetermined initial active set",
    -7: "time limit",
}

#: Constraint violation DAQP accepts (in the scaled variables), in linear MPC and in the real-time
#: iteration's QPs: DAQP's default, 1e-6, lets a soft bound be crossed with zero slack and moved the
#: pendulum's first move by 1e-3 N mid-swing, where the cost is flat along an active bound.
PRIMAL_TOLERANCE = 1e-10


@dataclass(frozen=True)
class CondensedQP:
    """The condensed QP of an `MPCProblem` in scaled variables z̄ (z = scale ⊙ z̄ = (U, S)),
    with every changing vector affine in the parameters p = (x0, d, x_s, u_s, u_previous):

        minimize    ½ z̄ᵀ H z̄ + (F p + f)ᵀ z̄
        subject to  lower ≤ z̄ ≤ upper
                    row_lower_constant + row_lower_matrix p ≤ rows z̄ ≤ row_upper_constant + row_upper_matrix p

    An absent side of a bound is ∓`INFINITY` (and its matrix row zero). Built once by
    `condense`; the DAQP path and the C export (`mpc.export`) solve exactly this.

    Attributes
    ----------
    H : (n, n) with unit diagonal;  scale : (n,);  F : (n, n_p);  f : (n,)
    lower, upper : (n,) simple bounds;  rows : (m, n)
    row_lower_constant, row_upper_constant : (m,);  row_lower_matrix, row_upper_matrix : (m, n_p)
    n_inputs, n_slacks : N nu and N ns (n = their sum);  n_parameters : n_p = 2 nx + 3 nu
    """

    H: np.ndarray
    scale: np.ndarray
    F: np.ndarray
    f: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    rows: np.ndarray
    row_lower_constant: np.ndarray
    row_lower_matrix: np.ndarray
    row_upper_constant: np.ndarray
    row_upper_matrix: np.ndarray
    n_inputs: int
    n_slacks: int

    @property
    def n(self) -> int:
        """The QP's variables, N nu + N ns."""
        return self.n_inputs + self.n_slacks

    @property
    def n_parameters(self) -> int:
        """n_p = 2 nx + 3 nu, the size of p."""
        return self.F.shape[1]

    @property
    def rows_vary(self) -> bool:
        """Some row bound changes with p (soft bounds, rate limits)."""
        return bool(np.any(self.row_lower_matrix) or np.any(self.row_upper_matrix))


def parameter_vector(params: QPParameters) -> np.ndarray:
    """p = (x0, d, x_s, u_s, u_previous) of `CondensedQP`."""
    return np.concatenate([params.x0, params.disturbance, params.x_target, params.u_target, params.u_previous])


def condense(problem: MPCProblem) -> CondensedQP:
    """Eliminate the states of `problem` (see the module docstring) and scale to a unit Hessian diagonal."""
    N, nx, nu, ns = problem.horizon, problem.nx, problem.nu, problem.n_soft
    n_inputs, n_slacks = N * nu, N * ns
    n_p = 2 * nx + 3 * nu
    Phi, Gamma = problem.prediction_matrices()
    Q_bar = scipy.linalg.block_diag(*([problem.Q] * (N - 1) + [problem.P]))
    R_bar = np.kron(np.eye(N), problem.R)
    stack_u = np.kron(np.ones((N, 1)), np.eye(nu))  # d or u_s repeated over the horizon
    stack_x = np.kron(np.ones((N, 1)), np.eye(nx))
    GtQ = Gamma.T @ Q_bar
    H_inputs = 2 * (GtQ @ Gamma + R_bar)
    H_slacks = 2 * np.diag(np.tile(problem.soft_quadratic_weight, N))
    H = scipy.linalg.block_diag(H_inputs, H_slacks)
    H = (H + H.T) / 2
    # The inputs' gradient is F_theta @ (x0, d, x_s, u_s); the slacks' is the constant w.
    F_theta = 2 * np.hstack([GtQ @ Phi, GtQ @ Gamma @ stack_u, -GtQ @ stack_x, -R_bar @ stack_u])
    f_slacks = np.tile(problem.soft_linear_weight, N)

    rows, lower_constant, upper_constant, lower_matrix, upper_matrix = [], [], [], [], []
    G_bar = np.kron(np.eye(N), problem.soft_rows)
    G_Gamma = G_bar @ Gamma
    # Soft-row bounds are g_bound − (Ḡ Φ x0 + Ḡ Γ 1⊗d): affine in (x0, d).
    soft_offset = np.hstack([G_bar @ Phi, G_Gamma @ stack_u, np.zeros((n_slacks, nx + 2 * nu))])
    slack_identity = np.eye(n_slacks)
    for side, bound_all in (("lower", np.tile(problem.soft_lower, N)), ("upper", np.tile(problem.soft_upper, N))):
        present = np.flatnonzero(np.isfinite(bound_all))
        if not present.size:
            continue
        sign = 1.0 if side == "lower" else -1.0
        rows.append(np.hstack([G_Gamma, sign * slack_identity])[present])
        varying = -soft_offset[present]
        absent = np.full(present.size, INFINITY)
        lower_constant.append(bound_all[present] if side == "lower" else -absent)
        upper_constant.append(absent if side == "lower" else bound_all[present])
        lower_matrix.append(varying if side == "lower" else np.zeros_like(varying))
        upper_matrix.append(np.zeros_like(varying) if side == "lower" else varying)
    if problem.rate_limit is not None:
        difference = np.eye(n_inputs) - np.eye(n_inputs, k=-nu)  # row k: u_k − u_{k−1}, row 0: u_0
        rows.append(np.hstack([difference, np.zeros((n_inputs, n_slacks))]))
        rate = np.tile(problem.rate_limit, N)
        previous = np.zeros((n_inputs, n_p))
        previous[:nu, n_p - nu :] = np.eye(nu)  # the first row's bounds move with u_{-1}
        lower_constant.append(-rate)
        upper_constant.append(rate)
        lower_matrix.append(previous)
        upper_matrix.append(previous.copy())
    n = n_inputs + n_slacks
    # Jacobi scaling z = D z̄: a unit Hessian diagonal, so newtons and kilonewtons look alike.
    scale = 1 / np.sqrt(np.diag(H))
    F = np.zeros((n, n_p))
    F[:n_inputs, : n_p - nu] = F_theta * scale[:n_inputs, None]
    stack = lambda parts, width: np.vstack(parts) if parts else np.zeros((0, width))
    return CondensedQP(
        H=H * np.outer(scale, scale),
        scale=scale,
        F=F,
        f=np.concatenate([np.zeros(n_inputs), f_slacks * scale[n_inputs:]]),
        lower=np.concatenate([np.tile(problem.input_lower, N) / scale[:n_inputs], np.zeros(n_slacks)]),
        upper=np.concatenate([np.tile(problem.input_upper, N) / scale[:n_inputs], np.full(n_slacks, INFINITY)]),
        rows=stack(rows, n) * scale,
        row_lower_constant=np.concatenate(lower_constant) if lower_constant else np.zeros(0),
        row_lower_matrix=stack(lower_matrix, n_p),
        row_upper_constant=np.concatenate(upper_constant) if upper_constant else np.zeros(0),
        row_upper_matrix=stack(upper_matrix, n_p),
        n_inputs=n_inputs,
        n_slacks=n_slacks,
    )


class CondensedDaqpSolver:
    """Condensed MPC QP with DAQP; the matrices are set up once at construction.

    Parameters
    ----------
    problem : MPCProblem
    iteration_limit : int, DAQP's bound on active-set changes per solve
    """

    name = "daqp"
    _set_up: bool  # DAQP has the matrices (set by `reset` and the first solve)

    def __init__(self, problem: MPCProblem, iteration_limit: int = 1000):
        self.problem = problem
        self.iteration_limit = integer(iteration_limit, "iteration_limit", minimum=1)
        self.qp = qp = condense(problem)
        N, nx, nu, ns = problem.horizon, problem.nx, problem.nu, problem.n_soft
        self.n_inputs, self.n_slacks = qp.n_inputs, qp.n_slacks
        self.scale, self.H_scaled, self.A = qp.scale, qp.H, qp.rows
        self.bupper = np.concatenate([qp.upper, qp.row_upper_constant])
        self.blower = np.concatenate([qp.lower, qp.row_lower_constant])
        self._bounds_vary = qp.rows_vary
        # Buffers the hot path writes into: p = (x0, d, x_s, u_s, u_previous), f, the row bounds.
        self._p = np.zeros(qp.n_parameters)
        self._p_parts = (
            slice(0, nx),
            slice(nx, nx + nu),
            slice(nx + nu, 2 * nx + nu),
            slice(2 * nx + nu, 2 * nx + 2 * nu),
            slice(2 * nx + 2 * nu, None),
        )
        self._f = qp.f.copy()
        self._f_inputs = self._f[: self.n_inputs]
        self._f_per_p = np.ascontiguousarray(qp.F[: self.n_inputs])
        self._row_upper = self.bupper[qp.n :]
        self._row_lower = self.blower[qp.n :]
        self._shapes = ((N, nu), (N, ns))
        self._set_up: bool = False  # whether DAQP holds this QP's matrices (reset() starts over)
        self.reset()

    def _update_vectors(self, params: QPParameters) -> None:
        p, (x0, d, xs, us, previous) = self._p, self._p_parts
        p[x0], p[d], p[xs], p[us], p[previous] = (
            params.x0,
            params.disturbance,
            params.x_target,
            params.u_target,
            params.u_previous,
        )
        np.dot(self._f_per_p, p, out=self._f_inputs)
        if self._bounds_vary:
            qp = self.qp
            np.dot(qp.row_lower_matrix, p, out=self._row_lower)
            self._row_lower += qp.row_lower_constant
            np.dot(qp.row_upper_matrix, p, out=self._row_upper)
            self._row_upper += qp.row_upper_constant

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
        return QPSolution(
            z[:n].reshape(inputs),
            z[n:].reshape(slacks),
            success,
            DAQP_STATUS.get(flag, f"exit flag {flag}"),
            info["iterations"],
            time.perf_counter() - start,
        )

    def _failure(self, status: str, start: float) -> QPSolution:
        N, nu, ns = self.problem.horizon, self.problem.nu, self.problem.n_soft
        return QPSolution(
            np.full((N, nu), np.nan), np.full((N, ns), np.nan), False, status, 0, time.perf_counter() - start
        )

    @property
    def warm_start(self) -> tuple:
        """What the next solve starts from (DAQP's model with its factorization and active set);
        assign a value read here to continue from it, so one solver can serve many runs in turn."""
        return self._model, self._set_up

    @warm_start.setter
    def warm_start(self, value: tuple) -> None:
        self._model, self._set_up = value

    def reset(self) -> None:
        """Forget the warm start (the next solve sets DAQP up from scratch)."""
        self._model = daqp.Model()
        # DAQP's default primal tolerance (1e-6) lets a soft bound be crossed by 1e-6 with zero
        # slack; on the pendulum's |theta| bound that moves the first input by 1e-3.
        self._model.settings = {"iter_limit": self.iteration_limit, "primal_tol": PRIMAL_TOLERANCE}
        self._set_up = False
