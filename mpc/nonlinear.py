"""Nonlinear MPC on the plant's own equations: multiple shooting, SQP, warm-started.

With F the plant's RK4 map over one sample (`Plant.step_function`) and the
known parameters, the problem at each sample is

    minimize    Σ_{k=0}^{N-1} ‖x_k − x_s‖²_Q + ‖u_k − u_s‖²_R + ‖x_N − x_s‖²_P
                + Σ_{k=1}^{N} wᵀ s_k + s_kᵀ diag(ρ) s_k
    subject to  x_0 = x̂,   x_{k+1} = F(x_k, u_k + d̂)                 k = 0..N-1
                −u_max ≤ u_k ≤ u_max                                 (hard, total input)
                |u_k − u_{k-1}| ≤ Δ,  u_{-1} = previous input          (hard, optional)
                g_lo − s_k ≤ G x_k ≤ g_hi + s_k,  s_k ≥ 0             k = 1..N (soft)

on absolute states and inputs: the linear MPC's problem with the exact
dynamics. CasADi's `sqpmethod` solves it; its QPs go to HPIPM, whose Riccati
recursion exploits the stage structure (variables are ordered stage by stage
for it), or to `qrqp` when a rate limit couples neighbouring stages. The
Hessian is the cost's (Gauss-Newton: the dynamics' curvature is dropped), so
no second derivatives are evaluated. Each sample starts from the previous
solution and multipliers shifted by one stage, which typically converges in
one to three SQP iterations.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

import models
from models import Plant, interrupts
from models.checks import integer, positive, real_array

#: QP solvers of the SQP, with the options each is given (CasADi conic plugins).
QP_SOLVERS = ("hpipm", "qrqp", "ipqp")


@dataclass
class NLPSolution:
    """One NMPC solve.

    inputs : (N, nu) planned total inputs; states : (N+1, nx) predicted states;
    slacks : (N, ns); success, status, iterations, solve_time (s) as reported by the solver.
    """

    inputs: np.ndarray
    states: np.ndarray
    slacks: np.ndarray
    success: bool
    status: str
    iterations: int
    solve_time: float


def _shift(columns: np.ndarray) -> np.ndarray:
    """Drop the first column (stage) and repeat the last: the warm start one sample later."""
    return np.hstack([columns[:, 1:], columns[:, -1:]])


class NonlinearMPCProblem:
    """The NMPC nonlinear program, built once as a CasADi `nlpsol`.

    Parameters
    ----------
    plant : Plant with the parameters known to the controller
    sample_period : s, the shooting interval and the controller's period
    horizon : N >= 1
    state_weight, input_weight : Q (nx, nx) and R (nu, nu) as in `mpc.linear`
    soft_bounds : sequence of SoftBound on the absolute state
    rate_limit : (nu,) bound on |u_k − u_{k−1}| per sample, or None
    substeps : RK4 steps per shooting interval
    max_iterations : SQP iteration limit per sample (hitting it is reported as a failure)
    qp_solver : CasADi conic plugin for the SQP's subproblems: "hpipm" or "qrqp"
    stationarity_tolerance : the SQP's tolerance on the Lagrangian gradient (cost units per
        scaled variable); 1e-4 changes the commands by about 1e-6 of the limit against 1e-6
        and saves a third of the iterations. Feasibility (the shooting gaps) is kept to 1e-6.
    jit : compile the NLP's functions to machine code (tens of seconds once; about 30 % faster solves)

    Raises
    ------
    ValueError
        For a horizon < 1, non-finite or indefinite weights, or substeps < 1.
    """

    def __init__(self, plant: Plant, sample_period: float, horizon: int, state_weight, input_weight, *,
                 soft_bounds=(), rate_limit=None, substeps: int = 1, max_iterations: int = 20,
                 qp_solver: str = "hpipm", stationarity_tolerance: float = 1e-4, jit: bool = False):
        N = integer(horizon, "horizon", minimum=1)
        max_iterations = integer(max_iterations, "max_iterations", minimum=1)
        substeps = integer(substeps, "substeps", minimum=1)
        if qp_solver not in QP_SOLVERS:
            raise ValueError(f"qp_solver must be one of {', '.join(map(repr, QP_SOLVERS))}, got {qp_solver!r}")
        tolerance = positive(stationarity_tolerance, "stationarity_tolerance")
        sample_period = positive(sample_period, "sample_period (s)")
        nx, nu = plant.nx, plant.nu
        Q = _weight(state_weight, nx, "state_weight Q", definite=False)
        R = _weight(input_weight, nu, "input_weight R", definite=True)
        limit = plant.input_limit
        soft = tuple(soft_bounds)
        ns = len(soft)
        self.plant, self.nx, self.nu, self.horizon, self.n_soft = plant, nx, nu, N, ns
        self.sample_period, self.input_limit, self.soft_bounds = float(sample_period), limit.copy(), soft
        self.rate_limit = None if rate_limit is None else \
            np.broadcast_to(real_array(rate_limit, "rate_limit"), (nu,)).copy()
        if self.rate_limit is not None and (not np.all(np.isfinite(self.rate_limit)) or np.any(self.rate_limit <= 0)):
            raise ValueError(f"rate_limit must be finite and > 0 per sample, got {self.rate_limit}")
        step = plant.step_function(sample_period, substeps)
        known = plant.param_vector()

        # Decision variables, stage by stage as structure-exploiting QP solvers want them:
        # w_k = (x_k, v_k, s_k) for k = 0..N-1, then x_N. Inputs are scaled by the actuator
        # limit (u = limit · v, |v| <= 1) so kilonewtons and newton-metres look alike to the
        # QP solver; s_k is the slack of the soft bounds on x_{k+1}.
        stage = nx + nu + ns
        W = ca.MX.sym("w", stage, N)
        x_N = ca.MX.sym("x_N", nx)
        X = ca.horzcat(W[:nx, :], x_N)
        V = W[nx:nx + nu, :]
        S = W[nx + nu:, :]
        U = ca.diag(ca.DM(limit)) @ V
        # Parameters: estimate, disturbance, target, terminal weight, previous input.
        x_hat = ca.MX.sym("x_hat", nx)
        d_hat = ca.MX.sym("d_hat", nu)
        x_s = ca.MX.sym("x_s", nx)
        u_s = ca.MX.sym("u_s", nu)
        P = ca.MX.sym("P", nx, nx)
        u_prev = ca.MX.sym("u_prev", nu)

        cost = 0
        for k in range(N):
            cost += ca.bilin(Q, X[:, k] - x_s) + ca.bilin(R, U[:, k] - u_s)
        cost += ca.bilin(P, X[:, N] - x_s)
        x_next = step.map(N)(X[:, :N], U + ca.repmat(d_hat, 1, N), known)  # F(x_k, u_k + d̂)
        rows, lower, upper = [x_next - X[:, 1:]], [np.zeros(nx)], [np.zeros(nx)]
        if ns:
            G = ca.DM(np.array([b.row for b in soft]))
            w = np.array([b.linear_weight for b in soft])
            rho = np.array([b.quadratic_weight for b in soft])
            cost += ca.sum2(ca.DM(w).T @ S) + ca.sum2(ca.DM(rho).T @ S**2)
            lo = np.array([b.lower for b in soft])
            hi = np.array([b.upper for b in soft])
            # G x_{k+1} + s_k >= lo and G x_{k+1} − s_k <= hi, written on F(x_k, u_k) so each
            # row involves stage k only; an infinite side is an inactive row.
            rows += [G @ x_next + S, G @ x_next - S]
            lower += [lo, np.full(ns, -np.inf)]
            upper += [np.full(ns, np.inf), hi]
        stage_rows = ca.vertcat(*rows)
        g_all, lbg, ubg = [ca.vec(stage_rows)], [np.tile(np.concatenate(lower), N)], [np.tile(np.concatenate(upper), N)]
        if self.rate_limit is not None:
            # Couples neighbouring stages, which HPIPM's stage-wise structure cannot express;
            # qrqp (CasADi's sparse active-set solver) takes it.
            g_all.append(ca.vec(U - ca.horzcat(u_prev, U[:, :N - 1])))
            lbg.append(np.tile(-self.rate_limit, N))
            ubg.append(np.tile(self.rate_limit, N))
            if qp_solver == "hpipm":
                qp_solver = "qrqp"

        decision = ca.vertcat(ca.vec(W), x_N)
        parameters = ca.vertcat(x_hat, d_hat, x_s, u_s, ca.vec(P), u_prev)
        g_all = ca.vertcat(*g_all)
        # Gauss-Newton: the Hessian of the Lagrangian is replaced by the cost's (constant given P).
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", g_all.numel())
        gauss_newton = ca.Function("gauss_newton", [decision, parameters, lam_f, lam_g],
                                   [lam_f * ca.hessian(cost, decision)[0]],
                                   ["x", "p", "lam_f", "lam_g"], ["hess"]).expand()
        options = {
            "expand": True, "hess_lag": gauss_newton, "qpsol": qp_solver, "max_iter": int(max_iterations),
            "tol_du": tolerance, "tol_pr": 1e-6,
            "print_time": False, "print_header": False, "print_iteration": False, "print_status": False,
            "error_on_fail": False,
        }
        if qp_solver == "hpipm":
            options["qpsol_options"] = {"N": N, "nx": [nx] * (N + 1), "nu": [nu + ns] * N + [0],
                                        "ng": [stage_rows.size1() - nx] * N + [0], "error_on_fail": False}
        elif qp_solver in ("qrqp", "ipqp"):
            options["qpsol_options"] = {"print_iter": False, "print_header": False, "error_on_fail": False}
        else:
            options["qpsol_options"] = {"error_on_fail": False}
        self.qp_solver = qp_solver
        nlp = {"x": decision, "p": parameters, "f": cost, "g": g_all}
        # jit: compiled without a shell and cached (models.compile); -O1 keeps compiling short.
        self.solver = (models.compile.jit_nlpsol("nmpc", "sqpmethod", nlp, options, flags=("-O1",)) if jit
                       else ca.nlpsol("nmpc", "sqpmethod", nlp, options))
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._stage, self._stage_rows = stage, stage_rows.size1()
        stage_lower = np.concatenate([np.full(nx, -np.inf), np.full(nu, -1.0), np.zeros(ns)])
        stage_upper = np.concatenate([np.full(nx, np.inf), np.full(nu, 1.0), np.full(ns, np.inf)])
        self.lbx = np.concatenate([np.tile(stage_lower, N), np.full(nx, -np.inf)])
        self.ubx = np.concatenate([np.tile(stage_upper, N), np.full(nx, np.inf)])
        self._rollout = step.mapaccum("rollout", N)
        self._known = known
        self.reset()

    def reset(self) -> None:
        """Forget the warm start."""
        self._guess = None
        self._lam_g = np.zeros(self.lbg.size)
        self._lam_x = np.zeros(self.lbx.size)

    def _split(self, decision: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """States (nx, N+1), scaled inputs (nu, N) and slacks (ns, N) of a decision vector."""
        nx, nu, N = self.nx, self.nu, self.horizon
        W = decision[:-nx].reshape(N, self._stage).T
        return np.hstack([W[:nx], decision[-nx:, None]]), W[nx:nx + nu], W[nx + nu:]

    def _shift_decision(self, vector: np.ndarray) -> np.ndarray:
        """A decision-shaped vector one sample later: stages move up, the last is repeated."""
        nx = self.nx
        W = vector[:-nx].reshape(self.horizon, self._stage)
        last = np.concatenate([vector[-nx:], W[-1, nx:]])
        return np.concatenate([W[1:].ravel(), last, vector[-nx:]])

    def _shift_constraints(self, vector: np.ndarray) -> np.ndarray:
        """A constraint-shaped vector (multipliers) one sample later."""
        N, rows = self.horizon, self._stage_rows
        staged = vector[:N * rows].reshape(N, rows)
        rest = vector[N * rows:].reshape(N, -1) if vector.size > N * rows else np.zeros((N, 0))
        return np.concatenate([_shift(staged.T).T.ravel(), _shift(rest.T).T.ravel()])

    def initial_guess(self, x_hat, d_hat, plan) -> np.ndarray:
        """A warm start from scratch: the plan (N, nu) rolled out from x̂ through the model."""
        plan = np.clip(np.asarray(plan, dtype=float).reshape(self.horizon, self.nu), -self.input_limit,
                       self.input_limit)
        X = np.asarray(self._rollout(x_hat, (plan + d_hat).T, self._known))
        X = np.hstack([np.asarray(x_hat).reshape(-1, 1), X])
        if not np.all(np.isfinite(X)):
            X = np.tile(np.asarray(x_hat).reshape(-1, 1), (1, self.horizon + 1))
        W = np.vstack([X[:, :-1], (plan / self.input_limit).T, np.zeros((self.n_soft, self.horizon))])
        return np.concatenate([W.T.ravel(), X[:, -1]])

    def solve(self, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous, plan) -> NLPSolution:
        """Solve from the shifted previous solution (or a rollout of `plan` the first time).

        Parameters
        ----------
        x_hat : (nx,) state estimate;  d_hat : (nu,) input-disturbance estimate
        x_target, u_target : (nx,), (nu,) steady state to track (u_target excludes d̂)
        terminal_weight : (nx, nx) P
        u_previous : (nu,) input applied at the previous sample
        plan : (N, nu) the previous plan, used for the first guess
        """
        start = time.perf_counter()
        nx = self.nx
        guess = (self.initial_guess(x_hat, d_hat, plan) if self._guess is None else self._guess).copy()
        # x_0 = x̂ as equal bounds on the first state: the cheapest form for the QP.
        lbx, ubx = self.lbx.copy(), self.ubx.copy()
        lbx[:nx] = ubx[:nx] = guess[:nx] = x_hat
        p = np.concatenate([x_hat, d_hat, x_target, u_target, np.asarray(terminal_weight).T.ravel(), u_previous])
        try:
            result = self.solver(x0=guess, p=p, lbx=lbx, ubx=ubx, lbg=self.lbg, ubg=self.ubg,
                                 lam_g0=self._lam_g, lam_x0=self._lam_x)
            stats = self.solver.stats()
            status, success = str(stats.get("return_status", "")), bool(stats.get("success", False))
            iterations = int(stats.get("iter_count", 0))
            decision = np.asarray(result["x"], dtype=float).ravel()
        except Exception as err:  # CasADi raises on NaN in a function evaluation, for example
            if interrupts.is_interrupt(err):  # Ctrl-C, which CasADi reports as an error
                raise KeyboardInterrupt from err
            status, success, iterations = f"solver error: {err}".splitlines()[0], False, 0
            decision = np.full(self.lbx.size, np.nan)
        success = success and bool(np.all(np.isfinite(decision)))
        X, V, S = self._split(decision)
        if success:
            self._guess = self._shift_decision(decision)
            self._lam_g = self._shift_constraints(np.asarray(result["lam_g"], dtype=float).ravel())
            self._lam_x = self._shift_decision(np.asarray(result["lam_x"], dtype=float).ravel())
        else:
            # Next time start over from the plan the controller actually follows.
            self.reset()
        U = (V.T * self.input_limit)
        return NLPSolution(U, X.T, S.T, success, status, iterations, time.perf_counter() - start)


def _weight(value, n, what, definite) -> np.ndarray:
    arr = real_array(value, what)
    arr = arr * np.eye(n) if arr.ndim == 0 else (np.diag(arr) if arr.ndim == 1 else arr)
    if arr.shape != (n, n) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite with shape ({n}, {n}) (or a scalar or diagonal), "
                         f"got {np.shape(value)}")
    arr = (arr + arr.T) / 2
    smallest = np.min(np.linalg.eigvalsh(arr))
    if smallest < 0 or (definite and smallest == 0):
        raise ValueError(f"{what} must be positive {'definite' if definite else 'semidefinite'}")
    return arr

