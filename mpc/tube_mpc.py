"""Tube MPC: robust linear MPC by constraint tightening, on the condensed DAQP path.

The controller plans with the nominal model z⁺ = A z + B v in the tightened sets of a
`mpc.tube.TubeSets` and applies the ancillary law u = v_0 + K (x − z), K the tube's feedback.
The nominal state z is the controller's state: it starts at the measured deviation x_0 − xe
(error 0 ∈ Z) and moves with z⁺ = A z + B v_0, so the QP's initial state is fixed and only its
vectors change from sample to sample. Over V = (v_0, ..., v_{N−1}) the condensed QP is

    minimize    Σ_{k<N} ‖z_k‖²_Q + ‖v_k‖²_R + ‖z_N‖²_P
    subject to  v_lo ≤ v_k ≤ v_hi          (U ⊖ K Z, simple bounds)
                Ḡ z_k ≤ ḡ, k = 1..N−1      (X ⊖ Z)
                H_f z_N ≤ h_f               (the terminal set X_f)

with z_k = A^k z_0 + Σ_{j<k} A^{k−1−j} B v_j and P the Riccati solution of (A, B, Q, R). The
variables are scaled to a unit Hessian diagonal as in `mpc.qp_fast`; DAQP factors H once.

Guarantee (Mayne, Seron & Raković 2005; `mpc.tube.TubeSets`): if the true deviation obeys
x⁺ = A x + B u + w with w_k ∈ W (the tube's disturbance set) at every sample and the full state
is measured, and the problem is feasible at the first sample (checked at construction for the
given initial state and again in `initial_state`), then it is feasible at every later sample
(recursive feasibility: the shifted plan with the terminal move K z_N is feasible) and every
state x_k satisfies the physical constraints X and every input u_k the bounds U, for every
disturbance sequence in W. Nothing is guaranteed for a deviation outside W (for a nonlinear
plant: the linearization remainder, parameters outside the hull W was built on, estimation
error); the controller then reports what it saw and never falls back silently.
"""

from __future__ import annotations

import time

import daqp
import numpy as np

from models import deferred
from models.checks import as_matrix, as_vector, integer, positive, weight_matrix
from models.lqr import dlqr

from .linear import INFINITY
from .qp_fast import DAQP_STATUS, PRIMAL_TOLERANCE, CondensedQP
from .sets import HIGHS_OPTIONS, Polytope, maximal_invariant_set
from .tube import TubeSets

scipy = deferred.module("scipy")

__all__ = ["TubeMPC", "condensed_prediction", "nominal_sets"]


def condensed_prediction(A, B, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Φ (N nx, nx) and Γ (N nx, N nu) with (z_1; ...; z_N) = Φ z_0 + Γ V."""
    n, m = B.shape
    Phi, Gamma = np.zeros((horizon * n, n)), np.zeros((horizon * n, horizon * m))
    power = np.eye(n)
    for k in range(horizon):
        power = A @ power
        Phi[k * n : (k + 1) * n] = power
        for j in range(k + 1):
            Gamma[k * n : (k + 1) * n, j * m : (j + 1) * m] = np.linalg.matrix_power(A, k - j) @ B
    return Phi, Gamma


def nominal_sets(A, B, feedback, state_constraints: Polytope, input_lower, input_upper, names=None, iterations=200):
    """The untightened sets of a nominal MPC with the same structure: X, U and the maximal
    positively invariant set of A + B K in X ∩ {K x ∈ U}, as a `TubeSets` whose Z is {0}.

    For comparison with the tube only: it guarantees nothing under a disturbance.
    """
    n, m = np.shape(B)
    K = as_matrix(feedback, n, "feedback K", rows=m)
    lower, upper = as_vector(input_lower, m, "input_lower"), as_vector(input_upper, m, "input_upper")
    eye = np.eye(m)
    admissible = state_constraints.intersect(
        Polytope(np.vstack([eye, -eye]), np.concatenate([upper, -lower])).preimage(K)
    )
    origin = Polytope(np.vstack([np.eye(n), -np.eye(n)]), np.zeros(2 * n))
    return TubeSets(
        feedback=K,
        closed_loop=A + B @ K,
        disturbance=origin,
        approximation=None,  # type: ignore[arg-type]  # no disturbance, no F(α, s)
        error_set=origin,
        error_set_exact=True,
        state_constraints=state_constraints,
        state_margins=np.zeros(len(state_constraints.h)),
        state_constraint_names=tuple(names or (f"row {i}" for i in range(len(state_constraints.h)))),
        input_lower=lower,
        input_upper=upper,
        input_margins=np.zeros(2 * m),
        terminal_set=maximal_invariant_set(A + B @ K, admissible, iterations),
    )


class TubeMPC:
    """Tube MPC for x⁺ = A x + B u + w, w ∈ W, with the full state measured (see the module docstring
    for the QP and for what it guarantees).

    Parameters
    ----------
    model : a discrete `models.LinearModel` (A, B, xe, ue, sample_period), the prediction model
    tube : `mpc.tube.TubeSets` built for model.A, model.B (its K, X ⊖ Z, U ⊖ K Z, X_f)
    horizon : N samples
    state_weight, input_weight : Q (nx,) or (nx, nx), R (nu,) or (nu, nu) of the nominal cost
    initial_state : (nx,) absolute state the problem must be feasible at; checked at construction
    replan : plan from the measured state at every sample (z := x − xe, so u = v_0): the nominal MPC,
        for comparison; it keeps none of the guarantee under W
    iteration_limit : DAQP's bound on active-set changes per solve
    name : str

    Attributes
    ----------
    qp : the scaled condensed QP as an `mpc.qp_fast.CondensedQP` whose parameter vector is p = z_0
        (nx,): the data DAQP solves here and in the C export (`mpc.export.export_linear_mpc`)

    Raises
    ------
    ValueError
        When the tightened problem is infeasible at `initial_state`: the message names the
        constraints and the margin they lack (the smallest uniform relaxation that makes it feasible).
    """

    measures = "state"
    n_reference = 1

    def __init__(
        self,
        model,
        tube: TubeSets,
        *,
        horizon: int,
        state_weight,
        input_weight,
        initial_state=None,
        replan: bool = False,
        iteration_limit: int = 1000,
        name: str = "tube MPC",
    ):
        A, B = np.asarray(model.A, dtype=float), np.asarray(model.B, dtype=float)
        n, m = B.shape
        if tube.feedback.shape != (m, n):
            raise ValueError(f"the tube's feedback is {tube.feedback.shape}; the model needs ({m}, {n})")
        if model.sample_period is None:
            raise ValueError("tube MPC needs a discrete model (model.sample_period is None)")
        self.sample_period = positive(model.sample_period, "sample_period (s)")
        self.horizon = N = integer(horizon, "horizon", minimum=1)
        self.name, self.model, self.tube, self.replan = name, model, tube, bool(replan)
        self.iteration_limit = integer(iteration_limit, "iteration_limit", minimum=1)
        self._A, self._B, self._K = A, B, tube.feedback
        self._xe, self._ue = np.asarray(model.xe, dtype=float), np.asarray(model.ue, dtype=float)
        Q = weight_matrix(state_weight, n, "state_weight")
        R = weight_matrix(input_weight, m, "input_weight")
        _, P = dlqr(A, B, Q, R, "tube MPC terminal cost")
        Phi, Gamma = condensed_prediction(A, B, N)
        Qbar = np.kron(np.eye(N), Q)
        Qbar[-n:, -n:] = P
        H = Gamma.T @ Qbar @ Gamma + np.kron(np.eye(N), R)
        self._f_per_z = Gamma.T @ Qbar @ Phi  # f = F z_0 (the z_0 term is constant)
        G, g = tube.state_constraints.H, tube.state_constraints.h
        Hf, hf = tube.terminal_set.H, tube.terminal_set.h
        blocks = [G @ Gamma[k * n : (k + 1) * n] for k in range(N - 1)] + [Hf @ Gamma[-n:]]
        shifts = [G @ Phi[k * n : (k + 1) * n] for k in range(N - 1)] + [Hf @ Phi[-n:]]
        self._rows, self._row_shift = np.vstack(blocks), np.vstack(shifts)
        self._row_bound = np.concatenate([*[g] * (N - 1), hf])
        names = tube.state_constraint_names
        self._row_names = [f"{names[i]} at step {k + 1}" for k in range(N - 1) for i in range(len(g))]
        self._row_names += [f"terminal set row {i}" for i in range(len(hf))]
        self._v_lower, self._v_upper = np.tile(tube.input_lower, N), np.tile(tube.input_upper, N)
        scale = 1 / np.sqrt(np.diag(H))
        n_rows = len(self._row_bound)
        self.qp = CondensedQP(
            H=H * np.outer(scale, scale),
            scale=scale,
            F=self._f_per_z * scale[:, None],
            f=np.zeros(N * m),
            lower=self._v_lower / scale,
            upper=self._v_upper / scale,
            rows=self._rows * scale,
            row_lower_constant=np.full(n_rows, -INFINITY),
            row_lower_matrix=np.zeros((n_rows, n)),
            row_upper_constant=self._row_bound,
            row_upper_matrix=-self._row_shift,
            n_inputs=N * m,
            n_slacks=0,
        )
        self._shape = (N, m)
        self._info: dict = {}
        self.reset()
        if initial_state is not None:
            self.check_feasible(as_vector(initial_state, n, "initial_state") - self._xe)

    @property
    def n_state(self) -> int:
        """Size of the controller state x_c = z, the nominal deviation state."""
        return self._A.shape[0]

    def reset(self) -> None:
        """Forget DAQP's warm start."""
        self._model = daqp.Model()
        self._model.settings = {"iter_limit": self.iteration_limit, "primal_tol": PRIMAL_TOLERANCE}
        self._set_up = False

    def _vectors(self, z0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        qp = self.qp  # p = z0
        upper = np.concatenate([qp.upper, qp.row_upper_constant + qp.row_upper_matrix @ z0])
        lower = np.concatenate([qp.lower, qp.row_lower_constant + qp.row_lower_matrix @ z0])
        return qp.F @ z0 + qp.f, upper, lower

    def solve(self, z0) -> tuple[np.ndarray, bool, str, int]:
        """The nominal plan V (N, nu) from z_0 (deviation), success, DAQP's status and iterations.

        Parameters
        ----------
        z0 : the nominal state's deviation from the operating point, shape (nx,)
        """
        f, upper, lower = self._vectors(z0)
        if not self._set_up:
            flag, _ = self._model.setup(self.qp.H, f, self.qp.rows, upper, lower)
            self._set_up = True
            if flag < 0:
                return np.full(self._shape, np.nan), False, f"setup failed ({DAQP_STATUS.get(flag, flag)})", 0
        else:
            self._model.update(f=f, bupper=upper, blower=lower)
        V, _, flag, info = self._model.solve()
        V = V * self.qp.scale
        return (
            V.reshape(self._shape),
            flag > 0 and bool(np.isfinite(V).all()),
            DAQP_STATUS.get(flag, str(flag)),
            info["iterations"],
        )

    def check_feasible(self, z0) -> None:
        """ValueError unless the tightened problem is feasible from the nominal deviation state z0.

        The message gives the smallest uniform relaxation t of every constraint (input bounds in
        the input's unit, state and terminal rows in theirs) that makes it feasible, by one LP, and
        names the constraints that need all of it.
        """
        N, m = self._shape
        X_bar = self.tube.state_constraints  # z_0 itself is fixed: its rows are constant, 0 <= bound + t
        rows = np.vstack([np.zeros((len(X_bar.h), N * m)), self._rows, np.eye(N * m), -np.eye(N * m)])
        bound = np.concatenate(
            [X_bar.h - X_bar.H @ z0, self._row_bound - self._row_shift @ z0, self._v_upper, -self._v_lower]
        )
        names = [f"{name} at step 0" for name in self.tube.state_constraint_names] + self._row_names
        names += [f"input {j} upper at step {k}" for k in range(N) for j in range(m)]
        names += [f"input {j} lower at step {k}" for k in range(N) for j in range(m)]
        cost = np.zeros(N * m + 1)
        cost[-1] = 1.0
        result = scipy.optimize.linprog(
            cost,
            A_ub=np.hstack([rows, -np.ones((len(bound), 1))]),
            b_ub=bound,
            bounds=[(None, None)] * (N * m) + [(0, None)],
            method="highs",
            options=HIGHS_OPTIONS,
        )
        if result.status != 0:
            raise ValueError(f"{self.name}: the feasibility LP failed ({result.message})")
        lack = float(result.x[-1])
        if lack > 1e-9:
            slack = bound + lack - rows @ result.x[:-1]
            tight = [names[i] for i in np.flatnonzero(slack <= 1e-9 * max(1.0, lack))]
            raise ValueError(
                f"{self.name}: the tightened problem is infeasible at the initial state {z0 + self._xe}: "
                f"{', '.join(tight[:6])}{' ...' if len(tight) > 6 else ''} lack a margin of {lack:.6g} "
                "(their bounds would have to be that much looser); start closer to the operating point, "
                "lengthen the horizon or shrink W"
            )

    def initial_state(self, y0, r0=None) -> np.ndarray:
        """x_c = z_0 = x_0 − xe (the error starts at 0 ∈ Z), checked feasible.

        Parameters
        ----------
        y0 : the first measured absolute state, shape (nx,)
        r0 : the first reference; not used (the tube regulates to the operating point)
        """
        z0 = as_vector(y0, self.n_state, f"{self.name}: first state") - self._xe
        self.check_feasible(z0)
        self.reset()
        self._info = {}
        return z0

    def step(self, xc, y, r=None) -> tuple[np.ndarray, np.ndarray]:
        """One sample: plan from z = x_c, command u = ue + v_0 + K (x − xe − z), advance z with v_0
        (with `replan`, z = x − xe).

        A failed solve raises RuntimeError: inside W it cannot happen, and no fallback hides it.

        Parameters
        ----------
        xc : the controller state, the nominal state's deviation z, shape (nx,)
        y : the measured absolute state, shape (nx,)
        r : the reference; not used (the tube regulates to the operating point)
        """
        start = time.perf_counter()
        z = np.asarray(y, dtype=float) - self._xe if self.replan else np.asarray(xc, dtype=float)
        V, success, status, iterations = self.solve(z)
        if not success:
            raise RuntimeError(
                f"{self.name}: the tightened QP failed ({status}) from z = {z}; the disturbance left W "
                "or the first state was not checked"
            )
        error = np.asarray(y, dtype=float) - self._xe - z
        u = self._ue + V[0] + self._K @ error
        elapsed = time.perf_counter() - start  # the membership check below is a record, not the law
        inside = self.tube.error_set.contains(error[None, :], tolerance=1e-9)[0]
        self._info = {
            "solver": "daqp",
            "status": status,
            "success": success,
            "iterations": iterations,
            "solve_time": elapsed,
            "error_in_tube": bool(inside),
        }
        return self._A @ z + self._B @ V[0], u

    def step_info(self) -> dict:
        """The last step's record: solver, status, success, iterations, solve_time (s) and
        error_in_tube (whether x − z was in Z, which the guarantee needs)."""
        return dict(self._info)
