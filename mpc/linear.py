"""The linear MPC problem every solver path solves, defined once.

In deviation coordinates x̃ = x − xe, ũ = u − ue about the operating point of
an exact zero-order-hold model x̃⁺ = A x̃ + B (ũ + d), with d the estimated
input disturbance, the problem at each sample is

    minimize    Σ_{k=0}^{N-1} ‖x_k − x_s‖²_Q + ‖u_k − u_s‖²_R + ‖x_N − x_s‖²_P
                + Σ_{k=1}^{N} wᵀ s_k + s_kᵀ diag(ρ) s_k
    subject to  x_0 = x̂,   x_{k+1} = A x_k + B (u_k + d)          k = 0..N-1
                u_lo ≤ u_k ≤ u_hi                                  (hard)
                |u_k − u_{k-1}| ≤ Δ,  u_{-1} = previous input       (hard, optional)
                g_lo − s_k ≤ G x_k ≤ g_hi + s_k,  s_k ≥ 0           k = 1..N (soft)

with P the discrete Riccati solution for (A, B, Q, R), so that when no
constraint is active the first move is the LQR law u_s − K (x̂ − x_s). The
slack penalty w is linear (an exact penalty: with w above the constraint's
multiplier the soft solution equals the hard one whenever the hard problem is
feasible) plus a small quadratic ρ that keeps the QP strictly convex.

`MPCProblem` holds the matrices (built once); `QPParameters` are the vectors
that change every sample. `mpc.qp_fast`, `mpc.qp_osqp` and
`mpc.reference_cvxpy` solve the same problem.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from models import LinearModel, Plant
from models.checks import integer, real_array, weight_matrix
from models.lqr import dlqr

#: Stand-in for an infinite bound in solvers that want finite numbers.
INFINITY = 1e30


# The checks below have the contract of models.checks.integer, real and real_array (TypeError
# for a string, a bool or a list where a number belongs; ValueError for a bad value).
@dataclass(frozen=True)
class SoftBound:
    """A softened bound lower ≤ row·x ≤ upper on the absolute state.

    Attributes
    ----------
    name : str
        What is bounded, for reports ("theta", "panel deflection").
    row : ndarray, (nx,)
        Coefficients of the bounded combination of states.
    lower, upper : float
        Bounds in the combination's unit; ±inf for a one-sided bound.
    linear_weight : float
        Exact-penalty weight w per unit of violation per stage (cost units per
        bound unit); must exceed the bound's Lagrange multiplier for the soft
        problem to equal the hard one when that is feasible.
    quadratic_weight : float
        ρ > 0 per unit² of violation, keeping the QP strictly convex.
    """

    name: str
    row: np.ndarray
    lower: float
    upper: float
    linear_weight: float
    quadratic_weight: float

    @classmethod
    def on(
        cls,
        plant: Plant,
        combination: dict,
        lower: float,
        upper: float,
        *,
        scale: float | None = None,
        linear_weight: float = 1e3,
        quadratic_weight: float = 1e1,
        name: str | None = None,
    ) -> SoftBound:
        """A bound on a linear combination of named states, e.g. ``{"phi": 1, "theta": -1}``.

        Parameters
        ----------
        plant : Plant whose `state_names` the combination refers to
        combination : mapping state name -> coefficient
        lower, upper : bounds (±inf allowed, not both)
        scale : size of a meaningful violation in the bound's unit (default:
            the half-width of the bound, or ``|finite bound|`` when one-sided, or 1).
            The weights are given per violation of one `scale`:
            w = linear_weight / scale, ρ = quadratic_weight / scale².
        """
        if not isinstance(combination, Mapping):
            raise TypeError(
                f"soft bound {name!r}: combination must be a mapping state name -> coefficient, "
                f"got {type(combination).__name__} {combination!r}"
            )
        if not combination:
            raise ValueError(f"soft bound {name!r}: combination is empty; give state name -> coefficient")
        label = name or " ".join(_term(coef, state) for state, coef in combination.items())
        row = np.zeros(plant.nx)
        for state, coef in combination.items():
            if state not in plant.state_names:
                raise ValueError(f"{plant.name} has no state {state!r}; states are {', '.join(plant.state_names)}")
            row[plant.state_names.index(state)] = real_array(coef, f"soft bound {label!r}: coefficient of {state}")
        if not np.any(row) or not np.all(np.isfinite(row)):
            raise ValueError(
                f"soft bound {label!r}: the combination {combination!r} needs finite coefficients, not all zero"
            )
        lower = float(real_array(lower, f"soft bound {label!r}: lower"))
        upper = float(real_array(upper, f"soft bound {label!r}: upper"))
        if np.isnan(lower) or np.isnan(upper):
            raise ValueError(f"soft bound {label!r}: bounds must not be NaN, got lower {lower}, upper {upper}")
        if lower > upper:
            raise ValueError(f"soft bound {label!r}: lower {lower} > upper {upper}; need lower <= upper")
        if not (np.isfinite(lower) or np.isfinite(upper)):
            raise ValueError(f"soft bound {label!r} has no finite side (lower {lower}, upper {upper})")
        for weight, value, strict in (
            ("linear_weight", linear_weight, False),
            ("quadratic_weight", quadratic_weight, True),
        ):
            value = float(real_array(value, f"soft bound {label!r}: {weight}"))
            if not np.isfinite(value) or value < 0 or (strict and value == 0):
                raise ValueError(
                    f"soft bound {label!r}: {weight} must be finite and {'> 0' if strict else '>= 0'}, got {value}"
                )
        if scale is None:
            finite = [b for b in (lower, upper) if np.isfinite(b)]
            scale = (upper - lower) / 2 if len(finite) == 2 else (abs(finite[0]) if finite and finite[0] else 1.0)
            if scale == 0:
                raise ValueError(
                    f"soft bound {label!r}: lower = upper = {lower}; need lower < upper, or give scale= (> 0)"
                )
        scale = float(real_array(scale, f"soft bound {label!r}: scale"))
        if not np.isfinite(scale) or scale <= 0:
            raise ValueError(f"soft bound {label!r}: scale must be finite and > 0, got {scale}")
        return cls(label, row, lower, upper, linear_weight / scale, quadratic_weight / scale**2)


def _term(coefficient, state: str) -> str:
    """'+1 theta' for a label; the coefficient as given when it is not a number (checked later)."""
    try:
        return f"{coefficient:+g} {state}"
    except (TypeError, ValueError):
        return f"{coefficient!r} {state}"


class QPParameters(NamedTuple):
    """The vectors that change every sample, in deviation coordinates.

    x0 : (nx,) state estimate;  disturbance : (nu,) input-disturbance estimate d
    x_target, u_target : (nx,), (nu,) steady state to track
    u_previous : (nu,) input applied at the previous sample (for rate limits)
    """

    x0: np.ndarray
    disturbance: np.ndarray
    x_target: np.ndarray
    u_target: np.ndarray
    u_previous: np.ndarray


@dataclass
class QPSolution:
    """One solve: the input plan, slacks and the solver's report.

    Attributes
    ----------
    inputs : (N, nu) planned ũ_0..ũ_{N-1} (deviation from ue); NaN when no answer
    slacks : (N, ns) soft-bound slacks s_1..s_N, in each bound's unit
    success : bool, the solver reports an optimal solution
    status : str, the solver's own status text
    iterations : int
    solve_time : float, s (wall clock of the solver call and the vector update)
    extra : dict, what a solver reports beyond these fields (its own names and values), empty by default
    """

    inputs: np.ndarray
    slacks: np.ndarray
    success: bool
    status: str
    iterations: int = 0
    solve_time: float = 0.0
    extra: dict = field(default_factory=dict)


def riccati_terminal_cost(A, B, Q, R) -> tuple[np.ndarray, np.ndarray]:
    """Discrete algebraic Riccati solution P and the LQR gain K = (R + BᵀPB)⁻¹ BᵀPA.

    `models.lqr.dlqr`, returned in the order the terminal cost uses them.

    Returns
    -------
    P : (nx, nx), K : (nu, nx)

    Raises
    ------
    ValueError
        When (A, B) is not stabilizable or (A, Q) has unobservable modes on the
        unit circle, so no stabilizing solution exists.
    """
    K, P = dlqr(A, B, Q, R, "MPC terminal cost")
    return P, K


class MPCProblem:
    """The matrices of the linear MPC problem (see the module docstring), built once.

    Parameters
    ----------
    A, B : (nx, nx), (nx, nu) discrete-time deviation model x̃⁺ = A x̃ + B ũ
    state_weight : Q, scalar, (nx,) diagonal or (nx, nx), positive semidefinite
    input_weight : R, scalar, (nu,) or (nu, nu), positive definite
    horizon : N >= 1 samples
    input_lower, input_upper : (nu,) hard bounds on ũ (the actuator limit minus ue)
    rate_limit : (nu,) bound on ``|ũ_k − ũ_{k-1}|`` per sample, or None
    soft_rows : (ns, nx) G;  soft_lower, soft_upper : (ns,) bounds on G x̃ (±inf allowed)
    soft_linear_weight, soft_quadratic_weight : (ns,) w >= 0 and ρ > 0
    terminal_weight : (nx, nx) P, default the Riccati solution for (A, B, Q, R)
    soft_names : names of the soft bounds, for reports

    Raises
    ------
    ValueError
        Naming the culprit: non-finite or wrongly shaped data, horizon < 1, Q
        not PSD, R not PD, empty input bounds (lower > upper), a rate limit
        <= 0, soft bounds with lower > upper, or no stabilizing Riccati solution.
    """

    def __init__(
        self,
        A,
        B,
        state_weight,
        input_weight,
        horizon: int,
        input_lower,
        input_upper,
        *,
        rate_limit=None,
        soft_rows=None,
        soft_lower=None,
        soft_upper=None,
        soft_linear_weight=None,
        soft_quadratic_weight=None,
        terminal_weight=None,
        soft_names=None,
    ):
        A = np.atleast_2d(np.asarray(A, dtype=float))
        B = np.asarray(B, dtype=float)
        B = B.reshape(-1, 1) if B.ndim == 1 else B
        nx = A.shape[0]
        if A.shape != (nx, nx) or B.shape[0] != nx:
            raise ValueError(f"A must be square and B have as many rows: got A {A.shape}, B {B.shape}")
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
            raise ValueError("A and B must be finite")
        nu = B.shape[1]
        self.A, self.B = A, B
        self.nx, self.nu, self.horizon = nx, nu, integer(horizon, "horizon", minimum=1)
        self.Q = weight_matrix(state_weight, nx, "state_weight Q")
        self.R = weight_matrix(input_weight, nu, "input_weight R", definite=True)
        self.input_lower = self._vector(input_lower, nu, "input_lower")
        self.input_upper = self._vector(input_upper, nu, "input_upper")
        if np.any(self.input_lower > self.input_upper):
            raise ValueError(
                f"the hard input bounds are infeasible: input_lower {self.input_lower} > "
                f"input_upper {self.input_upper} (is the operating point's input beyond the limit?)"
            )
        if rate_limit is None:
            self.rate_limit = None
        else:
            self.rate_limit = self._vector(rate_limit, nu, "rate_limit")
            if np.any(self.rate_limit <= 0):
                raise ValueError(f"rate_limit must be > 0 per sample, got {self.rate_limit}")
        self._set_soft(soft_rows, soft_lower, soft_upper, soft_linear_weight, soft_quadratic_weight, soft_names)
        if terminal_weight is None:
            self.P, self.lqr_gain = riccati_terminal_cost(A, B, self.Q, self.R)
        else:
            self.P = weight_matrix(terminal_weight, nx, "terminal_weight P")
            self.lqr_gain = np.linalg.solve(self.R + B.T @ self.P @ B, B.T @ self.P @ A)

    @staticmethod
    def _vector(value, n, what) -> np.ndarray:
        arr = real_array(value, what)
        if arr.size not in (1, n) or arr.ndim > 1:
            raise ValueError(f"{what} must be a number or {n} numbers, got shape {arr.shape}")
        arr = np.broadcast_to(arr.reshape(-1) if arr.ndim else arr, (n,)).copy()
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{what} must be finite, got {arr}")
        return arr

    def _set_soft(self, rows, lower, upper, linear, quadratic, names) -> None:
        nx = self.nx
        if rows is None:
            rows = np.zeros((0, nx))
        rows = np.atleast_2d(np.asarray(rows, dtype=float)).reshape(-1, nx)
        ns = rows.shape[0]
        if not np.all(np.isfinite(rows)):
            raise ValueError("soft_rows must be finite")

        def vec(value, default, what):
            arr = np.broadcast_to(np.asarray(default if value is None else value, dtype=float), (ns,)).copy()
            if np.any(np.isnan(arr)):
                raise ValueError(f"{what} has NaN entries: {arr}")
            return arr

        self.soft_rows = rows
        self.soft_lower = vec(lower, -np.inf, "soft_lower")
        self.soft_upper = vec(upper, np.inf, "soft_upper")
        self.soft_linear_weight = vec(linear, 1e3, "soft_linear_weight")
        self.soft_quadratic_weight = vec(quadratic, 1.0, "soft_quadratic_weight")
        self.soft_names = tuple(names) if names is not None else tuple(f"soft bound {i}" for i in range(ns))
        if len(self.soft_names) != ns:
            raise ValueError(f"need {ns} soft_names, got {len(self.soft_names)}")
        for i, name in enumerate(self.soft_names):
            if self.soft_lower[i] > self.soft_upper[i]:
                raise ValueError(f"soft bound {name!r}: lower {self.soft_lower[i]} > upper {self.soft_upper[i]}")
            if self.soft_lower[i] == -np.inf and self.soft_upper[i] == np.inf:
                raise ValueError(f"soft bound {name!r} has no finite side")
            if not np.isfinite(self.soft_linear_weight[i]) or self.soft_linear_weight[i] < 0:
                raise ValueError(
                    f"soft bound {name!r}: linear weight must be finite and >= 0, got {self.soft_linear_weight[i]}"
                )
            if not np.isfinite(self.soft_quadratic_weight[i]) or self.soft_quadratic_weight[i] <= 0:
                raise ValueError(
                    f"soft bound {name!r}: quadratic weight must be finite and > 0, got {self.soft_quadratic_weight[i]}"
                )

    @property
    def n_soft(self) -> int:
        """ns, the number of soft bounds (rows of `soft_rows`)."""
        return self.soft_rows.shape[0]

    # ----------------------------------------------------------- prediction
    def prediction_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Φ (N nx, nx) and Γ (N nx, N nu) with [x_1; ..; x_N] = Φ x_0 + Γ [u_0 + d; ..; u_{N-1} + d]."""
        nx, nu, N = self.nx, self.nu, self.horizon
        powers = [np.eye(nx)]
        for _ in range(N):
            powers.append(self.A @ powers[-1])
        Phi = np.vstack(powers[1:])
        Gamma = np.zeros((N * nx, N * nu))
        impulse = [p @ self.B for p in powers[:N]]  # A^i B
        for k in range(1, N + 1):
            for j in range(k):
                Gamma[(k - 1) * nx : k * nx, j * nu : (j + 1) * nu] = impulse[k - 1 - j]
        return Phi, Gamma

    def simulate(self, x0, inputs, disturbance) -> np.ndarray:
        """States x_0..x_N (N+1, nx) of the model under the plan `inputs` (N, nu) and disturbance d.

        Parameters
        ----------
        x0 : (nx,) initial deviation state x̃_0
        inputs : (N, nu) or (N nu,) planned deviation inputs ũ_0..ũ_{N-1}
        disturbance : (nu,) input disturbance d added to every input

        Returns
        -------
        (N+1, nx) the deviation states x̃_0..x̃_N
        """
        x = [np.asarray(x0, dtype=float)]
        for u in np.asarray(inputs, dtype=float).reshape(self.horizon, self.nu):
            x.append(self.A @ x[-1] + self.B @ (u + disturbance))
        return np.array(x)

    def cost(self, params: QPParameters, inputs, slacks=None) -> float:
        """The objective of the module docstring at a plan and its slacks.

        Parameters
        ----------
        params : QPParameters, the sample's initial state, disturbance and targets
        inputs : (N, nu) planned deviation inputs ũ_0..ũ_{N-1}
        slacks : (N, ns) soft-bound slacks, in each bound's unit; None for zero

        Returns
        -------
        float, the objective's value (dimensionless, as weighted)
        """
        x = self.simulate(params.x0, inputs, params.disturbance)
        ex = x - params.x_target
        eu = np.asarray(inputs).reshape(self.horizon, self.nu) - params.u_target
        total = np.einsum("ki,ij,kj->", ex[:-1], self.Q, ex[:-1]) + ex[-1] @ self.P @ ex[-1]
        total += np.einsum("ki,ij,kj->", eu, self.R, eu)
        if self.n_soft:
            s = np.zeros((self.horizon, self.n_soft)) if slacks is None else np.asarray(slacks)
            total += np.sum(s @ self.soft_linear_weight) + np.sum(s**2 @ self.soft_quadratic_weight)
        return float(total)

    def soft_violation(self, params: QPParameters, inputs) -> np.ndarray:
        """Violation of each soft bound at x_1..x_N under a plan, zero where respected.

        Parameters
        ----------
        params : QPParameters, the sample's initial state and disturbance
        inputs : (N, nu) planned deviation inputs ũ_0..ũ_{N-1}

        Returns
        -------
        (N, ns) how far G x̃_k lies outside [soft_lower, soft_upper], in each bound's unit
        """
        x = self.simulate(params.x0, inputs, params.disturbance)[1:]
        g = x @ self.soft_rows.T
        return np.maximum(0.0, np.maximum(self.soft_lower - g, g - self.soft_upper))


def check_holding_input(name: str, needed, limit) -> None:
    """Refuse an operating point whose holding input `needed` (nu,) is beyond the actuator limit
    |u| <= `limit` (nu,): a ValueError naming the plant `name`, the input needed and the limit."""
    needed = np.asarray(needed, dtype=float)
    if np.any(np.abs(needed) > limit):
        raise ValueError(
            f"{name}: holding the operating point needs the input {needed}, beyond the actuator limit "
            f"{np.asarray(limit, dtype=float)}; no admissible input holds it"
        )


def problem_from_model(
    model: LinearModel,
    state_weight,
    input_weight,
    horizon: int,
    input_limit,
    *,
    rate_limit=None,
    soft_bounds=(),
    terminal_weight=None,
) -> MPCProblem:
    """The MPC problem of a discrete `LinearModel` (from `Plant.linearize(...).discretize(Ts)`).

    Parameters
    ----------
    model : discrete LinearModel; its operating point (xe, ue) defines the deviations
    state_weight : Q, scalar, (nx,) diagonal or (nx, nx), positive semidefinite (as `MPCProblem`)
    input_weight : R, scalar, (nu,) or (nu, nu), positive definite
    horizon : N >= 1 samples
    input_limit : (nu,) symmetric limit ``|u|`` <= limit on the TOTAL input u = ue + ũ
    rate_limit : (nu,) bound on ``|u_k − u_{k-1}|`` per sample, or None
    soft_bounds : sequence of SoftBound on the absolute state
    terminal_weight : (nx, nx) P, default the Riccati solution for (A, B, Q, R)

    Returns
    -------
    MPCProblem, in deviations from the operating point, input bounds -limit - ue and limit - ue

    Raises
    ------
    ValueError
        When the model is continuous-time, or the operating point's input is
        beyond the limit (no input in the box holds it).
    """
    if model.sample_period is None:
        raise ValueError(f"{model.name}: the MPC model must be discrete; call .discretize(Ts) first")
    limit = np.broadcast_to(np.asarray(input_limit, dtype=float), (model.nu,))
    if np.any(~np.isfinite(limit)) or np.any(limit <= 0):
        raise ValueError(f"input_limit must be finite and > 0, got {limit}")
    check_holding_input(model.name, model.ue, limit)
    soft = tuple(soft_bounds)
    rows = np.array([b.row for b in soft]).reshape(len(soft), model.nx)
    offset = rows @ model.xe
    return MPCProblem(
        model.A,
        model.B,
        state_weight,
        input_weight,
        horizon,
        -limit - model.ue,
        limit - model.ue,
        rate_limit=rate_limit,
        soft_rows=rows,
        soft_lower=np.array([b.lower for b in soft]) - offset,
        soft_upper=np.array([b.upper for b in soft]) - offset,
        soft_linear_weight=[b.linear_weight for b in soft],
        soft_quadratic_weight=[b.quadratic_weight for b in soft],
        terminal_weight=terminal_weight,
        soft_names=[b.name for b in soft],
    )
