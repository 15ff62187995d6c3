"""Tube MPC: robust linear MPC by constraint tightening, on the condensed DAQP path, regulating or tracking.

The controller plans with the nominal model z⁺ = A z + B v in the tightened sets of a
`mpc.tube.TubeSets` and applies the ancillary law u = v_0 + K (x − z), K the tube's feedback.
The nominal state z is the controller's state: it starts at the measured deviation x_0 − xe
(error 0 ∈ Z) and moves with z⁺ = A z + B v_0, so only the QP's vectors change from sample to
sample. Regulating (to the operating point), the condensed QP over V = (v_0, ..., v_{N−1}) is

    minimize    Σ_{k<N} ‖z_k‖²_Q + ‖v_k‖²_R + ‖z_N‖²_P
    subject to  v_lo ≤ v_k ≤ v_hi          (U ⊖ K Z, simple bounds)
                Ḡ z_k ≤ ḡ, k = 1..N−1      (X ⊖ Z)
                H_f z_N ≤ h_f               (the terminal set X_f)

with z_k = A^k z_0 + Σ_{j<k} A^{k−1−j} B v_j and P the terminal law's Lyapunov matrix,
P = A_Kᵀ P A_K + Q + Kᵀ R K (the Riccati solution when K is the LQR of the same Q, R).

Tracking (``tracked_rows`` H given), the plan aims at an artificial steady state θ, a decision of
the QP beside V (MPC for tracking, Limon, Alamo, Álvarez & Camacho 2008, Automatica 44(9)
2382–2387; its tube form Limon, Alvarado, Alamo & Camacho 2010, J. Process Control 20(3) 248–260):
θ (nu,) is the tracked coordinates' deviation, (x_s, u_s) = (S_x θ, S_v θ) its steady state of the
nominal model (`mpc.estimator.SteadyStateTarget`), and with the reference's deviation r̃ = r − H xe

    minimize    Σ_{k<N} ‖z_k − S_x θ‖²_Q + ‖v_k − S_v θ‖²_R + ‖z_N − S_x θ‖²_P + ‖θ − r̃‖²_T
    subject to  the same bounds on v_k and z_k, and (z_N, θ) ∈ Ω_t

where Ω_t (`tracking_terminal_set`) is positively invariant for (z, θ)⁺ = (A z + B v, θ) under
v = K (z − S_x θ) + S_v θ inside X̄ and Ū, with the steady state itself kept in λ (X̄ × Ū). The
reference enters only the cost. The variables are scaled to a unit Hessian diagonal as in
`mpc.qp_fast`; DAQP factors H once.

Guarantee (Mayne, Seron & Raković 2005; `mpc.tube.TubeSets`; for tracking, Limon et al. 2010):
if the true deviation obeys x⁺ = A x + B u + w with w_k ∈ W (the tube's disturbance set) at every
sample and the full state is measured, and the problem is feasible at the first sample (checked
at construction for the given initial state and again in `initial_state`), then

- it is feasible at every later sample (recursive feasibility: the shifted plan with the terminal
  move, and the same θ, is feasible), whatever the reference does: a reference change, of any size,
  changes the cost, never the constraints;
- every state x_k satisfies the physical constraints X and every input u_k the bounds U, for every
  disturbance sequence in W and every reference sequence;
- tracking, once the reference stays at r: the nominal state converges to the steady state
  x_s(θ*), θ* = argmin ‖θ − r̃‖²_T over the steady states in λ (X̄ × Ū), which is r̃ itself when r̃
  is such a steady state; the true state converges to x_s(θ*) ⊕ Z (with w ≡ 0 and e_0 = 0, to
  x_s(θ*) itself). This needs P to be the terminal law's Lyapunov matrix, as it is here.

Not guaranteed: how fast θ* is reached; that the tracked coordinate reaches r under a disturbance
(no integral action: a constant w leaves the error at its steady state (I − A_K)⁻¹ w, inside Z, so
the offset is at most Z's support in the tracked direction); a reference that no admissible steady
state meets (the plan stops at θ*, the closest). Nothing is guaranteed for a deviation outside W
(for a nonlinear plant: the linearization remainder, parameters outside the hull W was built on,
estimation error, measurement noise); the controller then reports what it saw (`step_info`'s
error_in_tube) and never falls back silently.
"""

from __future__ import annotations

import time

import daqp
import numpy as np

from models import deferred
from models.checks import as_matrix, as_vector, integer, positive, real, weight_matrix

from .estimator import SteadyStateTarget
from .linear import INFINITY
from .qp_fast import DAQP_STATUS, PRIMAL_TOLERANCE, CondensedQP
from .sets import HIGHS_OPTIONS, Polytope, maximal_invariant_set
from .tube import TubeSets

scipy = deferred.module("scipy")

__all__ = ["TubeMPC", "condensed_prediction", "nominal_sets", "tracking_terminal_set"]

#: λ of the tracking terminal set: the steady states a plan may aim at lie in λ (X̄ × Ū).
STEADY_STATE_SCALE = 0.99


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


def tracking_terminal_set(
    A, B, tube: TubeSets, target: SteadyStateTarget, scale: float = STEADY_STATE_SCALE, iterations: int = 200
) -> Polytope:
    """Ω_t over w = (z, θ) (nx + nu): the maximal positively invariant set of the tracking terminal law.

    With the steady state (x_s, u_s) = (S_x θ, S_v θ) of `target` and v = K (z − x_s) + u_s,
    w⁺ = [[A_K, B (S_v − K S_x)], [0, I]] w (θ held; A_K = A + B K, and z⁺ − x_s = A_K (z − x_s)).
    Ω_t is the largest set of w whose successors all keep z ∈ X̄ and v ∈ Ū (the tube's tightened
    sets) while x_s ∈ λ X̄ and u_s ∈ λ Ū (λ = `scale` < 1 makes it finitely determined; Limon et al.
    2008, after Gilbert & Tan 1991), computed by `mpc.sets.maximal_invariant_set`.

    Raises
    ------
    ValueError
        For λ outside (0, 1); EmptySetError (a ValueError) or the iteration cap's error, said of Ω_t.
    """
    lam = real(scale, "steady-state scale λ")
    if not 0 < lam < 1:
        raise ValueError(f"the steady-state scale λ must be in (0, 1), got {lam}")
    n, m = np.shape(B)
    K, Sx, Sv = tube.feedback, target.state_per_reference, target.input_per_reference
    L = Sv - K @ Sx
    closed = np.block([[A + B @ K, B @ L], [np.zeros((m, n)), np.eye(m)]])
    G, g = tube.state_constraints.H, tube.state_constraints.h
    u_rows, u_bound = np.vstack([np.eye(m), -np.eye(m)]), np.concatenate([tube.input_upper, -tube.input_lower])
    rows = np.vstack(
        [
            np.hstack([G, np.zeros((len(g), m))]),
            u_rows @ np.hstack([K, L]),
            np.hstack([np.zeros((len(g), n)), G @ Sx]),
            np.hstack([np.zeros((2 * m, n)), u_rows @ Sv]),
        ]
    )
    bounds = np.concatenate([g, u_bound, lam * g, lam * u_bound])
    # A steady state's velocity rows are zero but for round-off (1e-16): drop them, as a unit-scaled row
    # with a bound of 1e15 would swamp the LPs' scaling of the others.
    lengths = np.linalg.norm(rows, axis=1)
    keep = lengths > 1e-12 * np.max(lengths)
    try:
        return maximal_invariant_set(closed, Polytope(rows[keep], bounds[keep]), iterations)
    except ValueError as error:  # EmptySetError or the iteration cap, said of Ω_t
        raise type(error)(f"the tracking terminal set is refused: {error}") from None


def lyapunov_terminal_weight(closed_loop, feedback, Q, R) -> np.ndarray:
    """P = A_Kᵀ P A_K + Q + Kᵀ R K: the terminal law's cost to go (the Riccati P when K is the LQR of Q, R)."""
    P = scipy.linalg.solve_discrete_lyapunov(closed_loop.T, Q + feedback.T @ R @ feedback)
    return (P + P.T) / 2


class TubeMPC:
    """Tube MPC for x⁺ = A x + B u + w, w ∈ W, with the full state measured, regulating to the
    operating point or tracking a reference (see the module docstring for the QP and for what it
    guarantees).

    Parameters
    ----------
    model : a discrete `models.LinearModel` (A, B, xe, ue, sample_period), the prediction model
    tube : `mpc.tube.TubeSets` built for model.A, model.B (its K, X ⊖ Z, U ⊖ K Z, X_f)
    horizon : N samples
    state_weight, input_weight : Q (nx,) or (nx, nx), R (nu,) or (nu, nu) of the nominal cost
    tracked_rows : (nu, nx) H, the tracked combinations of the state (the reference r is H x's
        absolute value); None regulates to the operating point and takes no reference
    offset_weight : T (nu,) or (nu, nu) of ‖θ − r̃‖²_T; default 100 S_xᵀ P S_x, so that a plan stopping
        short of an admissible reference costs a hundred times its terminal cost
    steady_state_scale : λ of `tracking_terminal_set`
    initial_state : (nx,) absolute state the problem must be feasible at; checked at construction
    replan : plan from the measured state at every sample (z := x − xe, so u = v_0): the nominal MPC,
        for comparison; it keeps none of the guarantee under W
    record_error : check x − z ∈ Z at every step for `step_info` (an LP per step for a zonotope Z)
    iteration_limit : DAQP's bound on active-set changes per solve
    name : str

    Attributes
    ----------
    qp : the scaled condensed QP as an `mpc.qp_fast.CondensedQP` whose parameter vector is p = z_0
        (nx,), or p = (z_0, r̃) (nx + nu,) tracking; its decisions V, then θ tracking: the data DAQP
        solves here and in the C export (`mpc.export.export_linear_mpc`)
    terminal_set : X_f, or Ω_t over (z, θ) tracking
    target : the `SteadyStateTarget` (S_x, S_v) tracking, else None
    reference_offset : (nu,) H xe, the tracked coordinates at the operating point (tracking)

    Raises
    ------
    ValueError
        When the tightened problem is infeasible at `initial_state`: the message names the
        constraints and the margin they lack (the smallest uniform relaxation that makes it feasible);
        when the tracked coordinates cannot be held at a steady state; when Ω_t is empty.
    """

    measures = "state"

    def __init__(
        self,
        model,
        tube: TubeSets,
        *,
        horizon: int,
        state_weight,
        input_weight,
        tracked_rows=None,
        offset_weight=None,
        steady_state_scale: float = STEADY_STATE_SCALE,
        initial_state=None,
        replan: bool = False,
        record_error: bool = True,
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
        self.horizon = integer(horizon, "horizon", minimum=1)
        self.name, self.model, self.tube = name, model, tube
        self.replan, self.record_error = bool(replan), bool(record_error)
        self.iteration_limit = integer(iteration_limit, "iteration_limit", minimum=1)
        self._A, self._B, self._K = A, B, tube.feedback
        self._xe, self._ue = np.asarray(model.xe, dtype=float), np.asarray(model.ue, dtype=float)
        Q = weight_matrix(state_weight, n, "state_weight")
        R = weight_matrix(input_weight, m, "input_weight")
        P = lyapunov_terminal_weight(A + B @ self._K, self._K, Q, R)
        if tracked_rows is None:
            self.target, self.n_reference, self.reference_offset = None, 1, np.zeros(0)
            Sx, Sv, T = np.zeros((n, 0)), np.zeros((m, 0)), np.zeros((0, 0))
            self.terminal_set = tube.terminal_set
        else:
            H = as_matrix(tracked_rows, n, "tracked_rows", rows=m)
            self.target = SteadyStateTarget(A, B, H)
            Sx, Sv = self.target.state_per_reference, self.target.input_per_reference
            T = 100 * Sx.T @ P @ Sx if offset_weight is None else weight_matrix(offset_weight, m, "offset_weight")
            self.n_reference, self.reference_offset = m, H @ self._xe
            self.terminal_set = tracking_terminal_set(A, B, tube, self.target, steady_state_scale, 200)
        self.qp = self._condensed(Q, R, P, Sx, Sv, T)
        self.last_target = np.zeros(Sx.shape[1])
        self._shape = (self.horizon, m)
        self._info: dict = {}
        self.reset()
        if initial_state is not None:
            self.check_feasible(as_vector(initial_state, n, "initial_state") - self._xe)

    def _condensed(self, Q, R, P, Sx, Sv, T) -> CondensedQP:
        """The scaled condensed QP over (V, θ) (θ empty when regulating) and its rows' data for
        `check_feasible`: the cost of the module docstring, p = (z_0, r̃)."""
        A, B, N, tube = self._A, self._B, self.horizon, self.tube
        n, m = B.shape
        t = Sx.shape[1]  # θ's size: nu tracking, 0 regulating
        Phi, Gamma = condensed_prediction(A, B, N)
        Qbar = np.kron(np.eye(N), Q)
        Qbar[-n:, -n:] = P
        E_z = np.hstack([Gamma, -np.kron(np.ones((N, 1)), Sx)])  # z_k − x_s, k = 1..N
        E_v = np.hstack([np.eye(N * m), -np.kron(np.ones((N, 1)), Sv)])  # v_k − u_s
        E_0 = np.hstack([np.zeros((n, N * m)), -Sx])  # z_0 − x_s (its z_0 part is constant)
        E_t = np.hstack([np.zeros((t, N * m)), np.eye(t)])  # θ
        H = E_z.T @ Qbar @ E_z + E_v.T @ np.kron(np.eye(N), R) @ E_v + E_0.T @ Q @ E_0 + E_t.T @ T @ E_t
        F = np.hstack([E_z.T @ Qbar @ Phi + E_0.T @ Q, -E_t.T @ T])  # f = F p, p = (z_0, r̃)
        G, g = tube.state_constraints.H, tube.state_constraints.h
        Ht, ht = self.terminal_set.H, self.terminal_set.h
        zero = np.zeros((len(g), t))
        blocks = [np.hstack([G @ Gamma[k * n : (k + 1) * n], zero]) for k in range(N - 1)]
        blocks.append(np.hstack([Ht[:, :n] @ Gamma[-n:], Ht[:, n:]]))
        shifts = [G @ Phi[k * n : (k + 1) * n] for k in range(N - 1)] + [Ht[:, :n] @ Phi[-n:]]
        self._rows, self._row_shift = np.vstack(blocks), np.vstack(shifts)
        self._row_bound = np.concatenate([*[g] * (N - 1), ht])
        names = tube.state_constraint_names
        self._row_names = [f"{names[i]} at step {k + 1}" for k in range(N - 1) for i in range(len(g))]
        kind = "terminal set" if not t else "tracking terminal set"
        self._row_names += [f"{kind} row {i}" for i in range(len(ht))]
        self._v_lower, self._v_upper = np.tile(tube.input_lower, N), np.tile(tube.input_upper, N)
        scale = 1 / np.sqrt(np.diag(H))
        n_rows = len(self._row_bound)
        return CondensedQP(
            H=H * np.outer(scale, scale),
            scale=scale,
            F=F * scale[:, None],
            f=np.zeros(N * m + t),
            lower=np.concatenate([self._v_lower / scale[: N * m], np.full(t, -INFINITY)]),
            upper=np.concatenate([self._v_upper / scale[: N * m], np.full(t, INFINITY)]),
            rows=self._rows * scale,
            row_lower_constant=np.full(n_rows, -INFINITY),
            row_lower_matrix=np.zeros((n_rows, n + t)),
            row_upper_constant=self._row_bound,
            row_upper_matrix=-np.hstack([self._row_shift, np.zeros((n_rows, t))]),
            n_inputs=N * m,
            n_slacks=t,  # θ, in the slacks' place after the inputs
        )

    @property
    def n_state(self) -> int:
        """Size of the controller state x_c = z, the nominal deviation state."""
        return self._A.shape[0]

    @property
    def tracking(self) -> bool:
        """Whether the controller tracks a reference (`tracked_rows` given)."""
        return self.target is not None

    def reset(self) -> None:
        """Forget DAQP's warm start."""
        self._model = daqp.Model()
        self._model.settings = {"iter_limit": self.iteration_limit, "primal_tol": PRIMAL_TOLERANCE}
        self._set_up = False

    def _parameters(self, z0, reference) -> np.ndarray:
        """p = z_0, or (z_0, r̃) tracking, from the nominal deviation z_0 and the absolute reference."""
        if not self.tracking:
            return np.asarray(z0, dtype=float)
        if reference is None:
            raise ValueError(f"{self.name}: a tracking tube MPC needs the reference r")
        r = as_vector(np.atleast_1d(np.asarray(reference, dtype=float)), self.n_reference, f"{self.name}: reference")
        return np.concatenate([z0, r - self.reference_offset])

    def _vectors(self, p) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        qp = self.qp
        upper = np.concatenate([qp.upper, qp.row_upper_constant + qp.row_upper_matrix @ p])
        lower = np.concatenate([qp.lower, qp.row_lower_constant + qp.row_lower_matrix @ p])
        return qp.F @ p + qp.f, upper, lower

    def solve(self, z0, reference=None) -> tuple[np.ndarray, bool, str, int]:
        """The nominal plan V (N, nu) from z_0 (deviation), success, DAQP's status and iterations;
        tracking, the artificial steady state's θ (deviation) is `last_target`.

        Parameters
        ----------
        z0 : the nominal state's deviation from the operating point, shape (nx,)
        reference : the absolute reference r (nu,), tracking; not used regulating
        """
        f, upper, lower = self._vectors(self._parameters(z0, reference))
        if not self._set_up:
            flag, _ = self._model.setup(self.qp.H, f, self.qp.rows, upper, lower)
            self._set_up = True
            if flag < 0:
                return np.full(self._shape, np.nan), False, f"setup failed ({DAQP_STATUS.get(flag, flag)})", 0
        else:
            self._model.update(f=f, bupper=upper, blower=lower)
        solution, _, flag, info = self._model.solve()
        solution = solution * self.qp.scale
        V = solution[: self.qp.n_inputs]
        self.last_target = solution[self.qp.n_inputs :]
        return (
            V.reshape(self._shape),
            flag > 0 and bool(np.isfinite(solution).all()),
            DAQP_STATUS.get(flag, str(flag)),
            info["iterations"],
        )

    def check_feasible(self, z0) -> None:
        """ValueError unless the tightened problem is feasible from the nominal deviation state z0
        (whatever the reference: it enters only the cost).

        The message gives the smallest uniform relaxation t of every constraint (input bounds in
        the input's unit, state and terminal rows in theirs) that makes it feasible, by one LP, and
        names the constraints that need all of it.
        """
        N, m = self._shape
        nv, t = N * m, self.qp.n_slacks
        X_bar = self.tube.state_constraints  # z_0 itself is fixed: its rows are constant, 0 <= bound + t
        box = np.hstack([np.eye(nv), np.zeros((nv, t))])
        rows = np.vstack([np.zeros((len(X_bar.h), nv + t)), self._rows, box, -box])
        bound = np.concatenate(
            [X_bar.h - X_bar.H @ z0, self._row_bound - self._row_shift @ z0, self._v_upper, -self._v_lower]
        )
        names = [f"{name} at step 0" for name in self.tube.state_constraint_names] + self._row_names
        names += [f"input {j} upper at step {k}" for k in range(N) for j in range(m)]
        names += [f"input {j} lower at step {k}" for k in range(N) for j in range(m)]
        cost = np.zeros(nv + t + 1)
        cost[-1] = 1.0
        result = scipy.optimize.linprog(
            cost,
            A_ub=np.hstack([rows, -np.ones((len(bound), 1))]),
            b_ub=bound,
            bounds=[(None, None)] * (nv + t) + [(0, None)],
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
        r0 : the first reference; not used (the problem's feasibility does not depend on it)
        """
        z0 = as_vector(y0, self.n_state, f"{self.name}: first state") - self._xe
        self.check_feasible(z0)
        self.reset()
        self._info = {}
        return z0

    def step(self, xc, y, r=None) -> tuple[np.ndarray, np.ndarray]:
        """One sample: plan from z = x_c (for reference r, tracking), command u = ue + v_0 + K (x − xe − z),
        advance z with v_0 (with `replan`, z = x − xe).

        A failed solve raises RuntimeError: by recursive feasibility it cannot happen, and no fallback
        hides it.

        Parameters
        ----------
        xc : the controller state, the nominal state's deviation z, shape (nx,)
        y : the measured absolute state, shape (nx,)
        r : the absolute reference (nu,), tracking; not used regulating
        """
        start = time.perf_counter()
        z = np.asarray(y, dtype=float) - self._xe if self.replan else np.asarray(xc, dtype=float)
        V, success, status, iterations = self.solve(z, r)
        if not success:
            raise RuntimeError(
                f"{self.name}: the tightened QP failed ({status}) from z = {z}; the first state was not "
                "checked, or (replanning) the disturbance left W"
            )
        error = np.asarray(y, dtype=float) - self._xe - z
        u = self._ue + V[0] + self._K @ error
        elapsed = time.perf_counter() - start  # the membership check below is a record, not the law
        self._info = {"solver": "daqp", "status": status, "success": success, "iterations": iterations}
        self._info["solve_time"] = elapsed
        if self.record_error:
            self._info["error_in_tube"] = bool(self.tube.error_set.contains(error[None, :], tolerance=1e-9)[0])
        if self.tracking:
            self._info["target"] = self.last_target + self.reference_offset
        return self._A @ z + self._B @ V[0], u

    def step_info(self) -> dict:
        """The last step's record: solver, status, success, iterations, solve_time (s), error_in_tube
        (whether x − z was in Z, which the guarantee needs; with `record_error`) and, tracking, target
        (the artificial steady state's tracked value H x_s, absolute)."""
        return dict(self._info)
