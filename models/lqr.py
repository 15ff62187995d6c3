"""Linear-system checks and Riccati gains: controllability, observability, LQR and Kalman.

The linear algebra both the state-space designs and MPC stand on, with
errors that name the uncontrollable or unobservable modes. Stabilizability
and detectability are checked before every Riccati solve, and the residual
and closed-loop stability after it: a solver asked for an unstabilizable
pair can otherwise return a gain that leaves a mode at s = 0 without saying so.
"""

from __future__ import annotations

import numpy as np

from . import deferred
from .checks import weight_matrix

scipy = deferred.module("scipy")

__all__ = [
    "controllability_matrix",
    "observability_matrix",
    "uncontrollable_modes",
    "unobservable_modes",
    "require_controllable",
    "require_observable",
    "require_stabilizable",
    "require_detectable",
    "bryson_weights",
    "riccati_residual",
    "lqr",
    "dlqr",
    "dlqr_time_varying",
    "kalman",
    "dkalman",
]


# ------------------------------------------------------------------ checks
def finite_matrix(value, what: str) -> np.ndarray:
    """`value` as a finite 2-D float array (a vector becomes one row); ValueError naming `what`."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.size == 0:
        raise ValueError(f"{what} must be a non-empty 2-D matrix, got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} has non-finite entries")
    return arr


def square_matrix(A, what: str = "A") -> np.ndarray:
    """`A` as a finite square matrix; ValueError naming `what` otherwise."""
    A = finite_matrix(A, what)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"{what} must be square, got shape {A.shape}")
    return A


def state_input_pair(A, B) -> tuple[np.ndarray, np.ndarray]:
    """(A (n, n), B (n, m)) checked to fit together."""
    A = square_matrix(A)
    B = np.asarray(B, dtype=float)
    if B.ndim == 1:
        B = B[:, None]
    B = finite_matrix(B, "B")
    if B.shape[0] != A.shape[0]:
        raise ValueError(f"B must have {A.shape[0]} rows (one per state), got shape {B.shape}")
    return A, B


def state_output_pair(A, C) -> tuple[np.ndarray, np.ndarray]:
    """(A (n, n), C (p, n)) checked to fit together."""
    A = square_matrix(A)
    C = finite_matrix(C, "C")
    if C.shape[1] != A.shape[0]:
        raise ValueError(f"C must have {A.shape[0]} columns (one per state), got shape {C.shape}")
    return A, C


def message_prefix(what: str) -> str:
    """ "what: " for error messages, or nothing."""
    return f"{what}: " if what else ""


def format_values(values) -> str:
    """Poles for messages; parts below 1e-7 (roundoff about a repeated root) print as 0."""
    out = []
    for v in np.atleast_1d(np.asarray(values, dtype=complex)):
        re = 0.0 if abs(v.real) < 1e-7 else v.real
        out.append(f"{re:.4g}" if abs(v.imag) < 1e-7 else f"{re:.4g}{v.imag:+.4g}j")
    return ", ".join(out)


# ------------------------------------------------------ controllability
def augment_disturbance(A, B, C, discrete: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Model with a constant input disturbance d as a state: x' = A x + B (u + d), d' = 0.

    Continuous time by default; with ``discrete=True`` (A, B) is a ZOH model and
    d_{k+1} = d_k, exact for a disturbance held like the input.

    Returns
    -------
    A_d (nx+nu, nx+nu) = [[A, B], [0, 0]] (discrete: [[A, B], [0, I]]);  B_d = [B; 0];  C_d = [C, 0]
    """
    A, B = state_input_pair(A, B)
    A, C = state_output_pair(A, C)
    n, m = B.shape
    lower = np.hstack([np.zeros((m, n)), np.eye(m) if discrete else np.zeros((m, m))])
    A_d = np.vstack([np.hstack([A, B]), lower])
    return A_d, np.vstack([B, np.zeros((m, m))]), np.hstack([C, np.zeros((C.shape[0], m))])


def controllability_matrix(A, B) -> np.ndarray:
    """[B, A B, ..., A^(n−1) B], shape (nx, nx·nu)."""
    A, B = state_input_pair(A, B)
    blocks = [B]
    for _ in range(A.shape[0] - 1):
        blocks.append(A @ blocks[-1])
    return np.hstack(blocks)


def observability_matrix(A, C) -> np.ndarray:
    """[C; C A; ...; C A^(n−1)], shape (nx·ny, nx)."""
    A, C = state_output_pair(A, C)
    return controllability_matrix(A.T, C.T).T


def _pbh_rank_deficient(A, B, tol: float) -> np.ndarray:
    """Eigenvalues λ of A with rank [A − λI, B] < n (Popov–Belevitch–Hautus test)."""
    n = A.shape[0]
    scale = max(np.linalg.norm(A, 2), np.linalg.norm(B, 2), 1e-300)
    bad = []
    for lam in np.linalg.eigvals(A):
        pencil = np.hstack([A - lam * np.eye(n), B]) / scale
        sv = np.linalg.svd(pencil, compute_uv=False)
        if sv[n - 1] < tol:
            bad.append(lam)
    return np.array(bad, dtype=complex)


def uncontrollable_modes(A, B, tol: float = 1e-9) -> np.ndarray:
    """Eigenvalues of A that the input cannot move (PBH test), complex array (may be empty).

    `tol` is relative to the larger of ‖A‖ and ‖B‖: a mode counts as
    uncontrollable when the smallest singular value of [A − λI, B] is below it.
    """
    A, B = state_input_pair(A, B)
    return _pbh_rank_deficient(A, B, tol)


def unobservable_modes(A, C, tol: float = 1e-9) -> np.ndarray:
    """Eigenvalues of A invisible in the output C x (PBH test on the dual), complex array."""
    A, C = state_output_pair(A, C)
    return _pbh_rank_deficient(A.T, C.T, tol)


def require_controllable(A, B, what: str = "") -> int:
    """Raise ValueError naming `what` and the uncontrollable modes unless (A, B) is controllable.

    Returns
    -------
    int : rank of the controllability matrix (= nx).
    """
    A, B = state_input_pair(A, B)
    modes = uncontrollable_modes(A, B)
    rank = int(np.linalg.matrix_rank(controllability_matrix(A, B)))
    if modes.size:
        raise ValueError(
            f"{message_prefix(what)}(A, B) is not controllable: the input cannot move the "
            f"mode(s) at s = {format_values(modes)} (controllability matrix rank {rank} < {A.shape[0]})"
        )
    return A.shape[0]


def require_observable(A, C, what: str = "") -> int:
    """Raise ValueError naming `what` and the unobservable modes unless (A, C) is observable.

    Returns
    -------
    int : rank of the observability matrix (= nx).
    """
    A, C = state_output_pair(A, C)
    modes = unobservable_modes(A, C)
    rank = int(np.linalg.matrix_rank(observability_matrix(A, C)))
    if modes.size:
        raise ValueError(
            f"{message_prefix(what)}(A, C) is not observable: the output does not see the "
            f"mode(s) at s = {format_values(modes)} (observability matrix rank {rank} < {A.shape[0]})"
        )
    return A.shape[0]


def _unstable(modes, discrete: bool, margin: float = 1e-9) -> np.ndarray:
    """The modes with |z| >= 1 − margin (discrete) or Re s >= −margin (continuous)."""
    modes = np.asarray(modes, dtype=complex)
    return modes[np.abs(modes) >= 1 - margin] if discrete else modes[modes.real >= -margin]


def require_stabilizable(A, B, what: str = "", discrete: bool = False) -> None:
    """Raise ValueError unless every uncontrollable mode of (A, B) is stable.

    Checked before any Riccati solve: a solver asked for an unstabilizable
    pair can return a gain that leaves a mode at s = 0 without saying so.
    """
    A, B = state_input_pair(A, B)
    bad = _unstable(uncontrollable_modes(A, B), discrete)
    if bad.size:
        where = "|z| >= 1" if discrete else "Re s >= 0"
        raise ValueError(
            f"{message_prefix(what)}(A, B) is not stabilizable: uncontrollable mode(s) with "
            f"{where} at {format_values(bad)}"
        )


def require_detectable(A, C, what: str = "", discrete: bool = False) -> None:
    """Raise ValueError unless every unobservable mode of (A, C) is stable."""
    A, C = state_output_pair(A, C)
    bad = _unstable(unobservable_modes(A, C), discrete)
    if bad.size:
        where = "|z| >= 1" if discrete else "Re s >= 0"
        raise ValueError(
            f"{message_prefix(what)}(A, C) is not detectable: unobservable mode(s) with {where} at {format_values(bad)}"
        )


# ------------------------------------------------------------------- LQR
def bryson_weights(state_max, input_max) -> tuple[np.ndarray, np.ndarray]:
    """Bryson's rule: Q = diag(1 / x_max²), R = diag(1 / u_max²).

    Parameters
    ----------
    state_max : (nx,), largest acceptable |x_i| in the state's units; np.inf
        leaves a state unweighted.
    input_max : (nu,), largest acceptable |u_j|.
    """
    xmax = np.atleast_1d(np.asarray(state_max, dtype=float))
    umax = np.atleast_1d(np.asarray(input_max, dtype=float))
    for name, v in (("state_max", xmax), ("input_max", umax)):
        if np.any(np.isnan(v)) or np.any(v <= 0):
            raise ValueError(f"{name} entries must be > 0 (np.inf to leave a state unweighted), got {v}")
    if not np.all(np.isfinite(umax)):
        raise ValueError(f"input_max must be finite, got {umax}")
    return np.diag(1.0 / xmax**2), np.diag(1.0 / umax**2)


def _weights(A, B, Q, R, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Q (n, n) >= 0 and R (m, m) > 0 for B (n, m), identity when None (`models.checks.weight_matrix`)."""
    n, m = B.shape
    prefix = message_prefix(what)
    Q = np.eye(n) if Q is None else weight_matrix(Q, n, f"{prefix}weight Q")
    R = np.eye(m) if R is None else weight_matrix(R, m, f"{prefix}weight R", definite=True)
    return Q, R


def _weight_root(Q) -> np.ndarray:
    """A factor Q^½ with (Q^½)ᵀ Q^½ = Q (for Q >= 0), the output whose detectability the LQR needs."""
    vals, vecs = np.linalg.eigh(Q)
    return (vecs * np.sqrt(np.clip(vals, 0, None))).T


def riccati_residual(A, B, Q, R, P, discrete: bool = False) -> float:
    """Relative residual of the algebraic Riccati equation at P.

    Continuous: Aᵀ P + P A − P B R⁻¹ Bᵀ P + Q; discrete:
    Aᵀ P A − P − Aᵀ P B (R + Bᵀ P B)⁻¹ Bᵀ P A + Q. The Frobenius norm is
    divided by the sum of the norms of the terms.
    """
    A, B = state_input_pair(A, B)
    if discrete:
        gain_term = A.T @ P @ B @ np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        terms = [A.T @ P @ A, -P, -gain_term, Q]
    else:
        terms = [A.T @ P, P @ A, -P @ B @ np.linalg.solve(R, B.T @ P), Q]
    scale = sum(np.linalg.norm(t) for t in terms)
    return float(np.linalg.norm(sum(terms)) / max(scale, 1e-300))


def _riccati_checked(A, B, Q, R, P, K, discrete: bool, what: str) -> None:
    """Refuse a Riccati solution P that is not finite, leaves a relative residual >= 1e-8, or whose gain K
    does not stabilize A − B K (ValueError naming the residual and the closed-loop poles)."""
    res = riccati_residual(A, B, Q, R, P, discrete)
    closed = np.linalg.eigvals(A - B @ K)
    stable = np.all(np.abs(closed) < 1) if discrete else np.all(closed.real < 0)
    if not (np.all(np.isfinite(P)) and res < 1e-8 and stable):
        raise ValueError(
            f"{message_prefix(what)}the Riccati solve failed: relative residual {res:.3g}, "
            f"closed-loop poles {format_values(closed)}"
        )


def lqr(A, B, Q=None, R=None, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Continuous LQR: K minimizing ∫ xᵀ Q x + uᵀ R u dt under u = −K x.

    Parameters
    ----------
    A (nx, nx), B (nx, nu)
    Q : (nx, nx) symmetric ≥ 0; default identity (Bryson's rule with unit
        maxima; use `bryson_weights` for physical maxima)
    R : (nu, nu) symmetric > 0; default identity

    Returns
    -------
    K : (nu, nx) = R⁻¹ Bᵀ P
    P : (nx, nx), the stabilizing solution of Aᵀ P + P A − P B R⁻¹ Bᵀ P + Q = 0

    Raises
    ------
    ValueError
        Non-finite or indefinite weights, (A, B) not stabilizable, (A, Q^½)
        not detectable, or a solve whose residual or closed loop is wrong.
    """
    A, B = state_input_pair(A, B)
    Q, R = _weights(A, B, Q, R, what)
    require_stabilizable(A, B, what)
    require_detectable(A, _weight_root(Q), f"{what} with the weight Q" if what else "weight Q")
    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    P = (P + P.T) / 2
    K = np.linalg.solve(R, B.T @ P)
    _riccati_checked(A, B, Q, R, P, K, False, what)
    return K, P


def dlqr(A, B, Q=None, R=None, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Discrete LQR: K minimizing Σ x_kᵀ Q x_k + u_kᵀ R u_k under u_k = −K x_k, x_{k+1} = A x_k + B u_k.

    Parameters
    ----------
    A (nx, nx), B (nx, nu): a discrete model, e.g. the ZOH
        `LinearModel.discretize(Ts)`.
    Q, R : weights as in `lqr` (defaults identity).

    Returns
    -------
    K : (nu, nx) = (R + Bᵀ P B)⁻¹ Bᵀ P A
    P : (nx, nx), the stabilizing solution of the discrete Riccati equation;
        xᵀ P x is the optimal cost-to-go (an MPC terminal cost).

    Raises
    ------
    ValueError
        As `lqr`, with stability meaning |z| < 1.
    """
    A, B = state_input_pair(A, B)
    Q, R = _weights(A, B, Q, R, what)
    require_stabilizable(A, B, what, discrete=True)
    require_detectable(A, _weight_root(Q), f"{what} with the weight Q" if what else "weight Q", discrete=True)
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    P = (P + P.T) / 2
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    _riccati_checked(A, B, Q, R, P, K, True, what)
    return K, P


def dlqr_time_varying(As, Bs, Q, R, final_weight, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Finite-horizon discrete LQR along a time-varying model: the backward Riccati recursion.

    Minimizes Σₖ₌₀ᴺ⁻¹ (x_kᵀ Q x_k + u_kᵀ R u_k) + x_Nᵀ P_N x_N subject to
    x_{k+1} = A_k x_k + B_k u_k, with u_k = −K_k x_k:

        K_k = (R + B_kᵀ P_{k+1} B_k)⁻¹ B_kᵀ P_{k+1} A_k,
        P_k = Q + A_kᵀ P_{k+1} (A_k − B_k K_k),         P_N = final_weight.

    Used for tracking a trajectory with the deviation model linearized along
    it (time-varying LQR); with `final_weight` the `dlqr` cost of the last
    point, the gains join the infinite-horizon LQR there without a jump.

    Parameters
    ----------
    As : (N, nx, nx);  Bs : (N, nx, nu)
    Q : (nx, nx) symmetric >= 0;  R : (nu, nu) symmetric > 0
    final_weight : (nx, nx) symmetric >= 0, P_N

    Returns
    -------
    K : (N, nu, nx) the gains;  P : (N + 1, nx, nx) the cost-to-go matrices, x₀ᵀ P₀ x₀ the optimal cost
    """
    As = np.asarray(As, dtype=float)
    Bs = np.asarray(Bs, dtype=float)
    if As.ndim != 3 or As.shape[1] != As.shape[2] or As.shape[0] < 1:
        raise ValueError(f"{message_prefix(what)}As must have shape (N, nx, nx) with N >= 1, got {As.shape}")
    steps, n = As.shape[0], As.shape[1]
    if Bs.ndim != 3 or Bs.shape[:2] != (steps, n):
        raise ValueError(f"{message_prefix(what)}Bs must have shape ({steps}, {n}, nu), got {Bs.shape}")
    if not (np.all(np.isfinite(As)) and np.all(np.isfinite(Bs))):
        raise ValueError(f"{message_prefix(what)}As and Bs must be finite")
    Q, R = _weights(As[0], Bs[0], Q, R, what)
    final = finite_matrix(final_weight, "final_weight")
    if final.shape != (n, n) or not np.allclose(final, final.T, rtol=1e-10, atol=1e-14 * np.abs(final).max(initial=0)):
        raise ValueError(
            f"{message_prefix(what)}final_weight must be a symmetric ({n}, {n}) matrix, got shape {final.shape}"
        )
    if np.min(np.linalg.eigvalsh(final)) < -1e-12 * max(1.0, np.abs(final).max()):
        raise ValueError(f"{message_prefix(what)}final_weight must be positive semidefinite")
    gains = np.empty((steps, Bs.shape[2], n))
    costs = np.empty((steps + 1, n, n))
    costs[steps] = final
    for k in range(steps - 1, -1, -1):
        A, B, P = As[k], Bs[k], costs[k + 1]
        gains[k] = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ (A - B @ gains[k])
        costs[k] = (P + P.T) / 2
    return gains, costs


def kalman(A, C, W, V, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Steady-state Kalman–Bucy gain for x' = A x + w, y = C x + v (dual of `lqr`).

    Parameters
    ----------
    W : (nx, nx) process-noise intensity ≥ 0;  V : (ny, ny) measurement-noise intensity > 0

    Returns
    -------
    L : (nx, ny) = P Cᵀ V⁻¹, error dynamics A − L C
    P : (nx, nx) steady-state error covariance
    """
    A, C = state_output_pair(A, C)
    K, P = lqr(A.T, C.T, W, V, what)
    return K.T, P


def dkalman(A, C, W, V, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Steady-state discrete Kalman predictor gain for x_{k+1} = A x_k + w_k, y_k = C x_k + v_k.

    Parameters
    ----------
    W : (nx, nx) covariance of w_k ≥ 0;  V : (ny, ny) covariance of v_k > 0

    Returns
    -------
    L : (nx, ny) = A P Cᵀ (C P Cᵀ + V)⁻¹, predictor error dynamics A − L C;
        `current_estimator_gain(A, L)` = P Cᵀ (C P Cᵀ + V)⁻¹ is the filter's
        measurement-update gain.
    P : (nx, nx) steady-state prior (one-step prediction) error covariance
    """
    A, C = state_output_pair(A, C)
    K, P = dlqr(A.T, C.T, W, V, what)
    return K.T, P
