"""State-space design as linear algebra: controllability, pole placement, observers, LQR, Kalman.

Everything here takes and returns numpy arrays and prints nothing; the
controller blocks that run these gains on the nonlinear plants are in
`designs.statespace_blocks`, the case studies' numbers in
`designs.statespace_cases`.

Conventions
-----------
- State feedback is u = −K x (K of shape (nu, nx)); the observer gain L
  (nx, ny) gives error dynamics A − L C.
- The integrator state of `augment_integrator` is x_I' = r − C_r x, and the
  augmented gain splits as u = −K x + k_i x_I (so k_i > 0 for a plant whose
  tracked output rises with the input at low frequency).
- The disturbance of `augment_disturbance` enters at the input: x' = A x + B (u + d).
- Continuous time unless a function's name starts with ``d`` (`dlqr`, `dkalman`,
  `discrete_observer_gain`).
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.signal

__all__ = [
    "controllability_matrix", "observability_matrix", "uncontrollable_modes", "unobservable_modes",
    "require_controllable", "require_observable", "require_stabilizable", "require_detectable",
    "second_order_poles", "second_order_from_specs", "normalized_rise_time", "place",
    "pole_mismatch", "reference_gain", "reference_steady_state", "augment_integrator",
    "split_integral_gain", "augment_disturbance", "observer_gain", "discrete_observer_gain",
    "current_estimator_gain", "bryson_weights", "lqr", "dlqr", "kalman", "dkalman",
    "riccati_residual",
]


# ------------------------------------------------------------------ checks
def _matrix(value, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.size == 0:
        raise ValueError(f"{what} must be a non-empty 2-D matrix, got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} has non-finite entries")
    return arr


def _square(A, what: str = "A") -> np.ndarray:
    A = _matrix(A, what)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"{what} must be square, got shape {A.shape}")
    return A


def _pair_AB(A, B) -> tuple[np.ndarray, np.ndarray]:
    A = _square(A)
    B = np.asarray(B, dtype=float)
    if B.ndim == 1:
        B = B[:, None]
    B = _matrix(B, "B")
    if B.shape[0] != A.shape[0]:
        raise ValueError(f"B must have {A.shape[0]} rows (one per state), got shape {B.shape}")
    return A, B


def _pair_AC(A, C) -> tuple[np.ndarray, np.ndarray]:
    A = _square(A)
    C = _matrix(C, "C")
    if C.shape[1] != A.shape[0]:
        raise ValueError(f"C must have {A.shape[0]} columns (one per state), got shape {C.shape}")
    return A, C


def _prefix(what: str) -> str:
    return f"{what}: " if what else ""


def _fmt(values) -> str:
    """Poles for messages; parts below 1e-7 (roundoff about a repeated root) print as 0."""
    out = []
    for v in np.atleast_1d(np.asarray(values, dtype=complex)):
        re = 0.0 if abs(v.real) < 1e-7 else v.real
        out.append(f"{re:.4g}" if abs(v.imag) < 1e-7 else f"{re:.4g}{v.imag:+.4g}j")
    return ", ".join(out)


# ------------------------------------------------------ controllability
def controllability_matrix(A, B) -> np.ndarray:
    """[B, A B, ..., A^(n−1) B], shape (nx, nx·nu)."""
    A, B = _pair_AB(A, B)
    blocks = [B]
    for _ in range(A.shape[0] - 1):
        blocks.append(A @ blocks[-1])
    return np.hstack(blocks)


def observability_matrix(A, C) -> np.ndarray:
    """[C; C A; ...; C A^(n−1)], shape (nx·ny, nx)."""
    A, C = _pair_AC(A, C)
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
    A, B = _pair_AB(A, B)
    return _pbh_rank_deficient(A, B, tol)


def unobservable_modes(A, C, tol: float = 1e-9) -> np.ndarray:
    """Eigenvalues of A invisible in the output C x (PBH test on the dual), complex array."""
    A, C = _pair_AC(A, C)
    return _pbh_rank_deficient(A.T, C.T, tol)


def require_controllable(A, B, what: str = "") -> int:
    """Raise ValueError naming `what` and the uncontrollable modes unless (A, B) is controllable.

    Returns
    -------
    int : rank of the controllability matrix (= nx).
    """
    A, B = _pair_AB(A, B)
    modes = uncontrollable_modes(A, B)
    rank = int(np.linalg.matrix_rank(controllability_matrix(A, B)))
    if modes.size:
        raise ValueError(f"{_prefix(what)}(A, B) is not controllable: the input cannot move the "
                         f"mode(s) at s = {_fmt(modes)} (controllability matrix rank {rank} < {A.shape[0]})")
    return A.shape[0]


def require_observable(A, C, what: str = "") -> int:
    """Raise ValueError naming `what` and the unobservable modes unless (A, C) is observable.

    Returns
    -------
    int : rank of the observability matrix (= nx).
    """
    A, C = _pair_AC(A, C)
    modes = unobservable_modes(A, C)
    rank = int(np.linalg.matrix_rank(observability_matrix(A, C)))
    if modes.size:
        raise ValueError(f"{_prefix(what)}(A, C) is not observable: the output does not see the "
                         f"mode(s) at s = {_fmt(modes)} (observability matrix rank {rank} < {A.shape[0]})")
    return A.shape[0]


def _unstable(modes, discrete: bool, margin: float = 1e-9) -> np.ndarray:
    modes = np.asarray(modes, dtype=complex)
    return modes[np.abs(modes) >= 1 - margin] if discrete else modes[modes.real >= -margin]


def require_stabilizable(A, B, what: str = "", discrete: bool = False) -> None:
    """Raise ValueError unless every uncontrollable mode of (A, B) is stable.

    Checked before any Riccati solve: a solver asked for an unstabilizable
    pair can return a gain that leaves a mode at s = 0 without saying so.
    """
    A, B = _pair_AB(A, B)
    bad = _unstable(uncontrollable_modes(A, B), discrete)
    if bad.size:
        where = "|z| >= 1" if discrete else "Re s >= 0"
        raise ValueError(f"{_prefix(what)}(A, B) is not stabilizable: uncontrollable mode(s) with "
                         f"{where} at {_fmt(bad)}")


def require_detectable(A, C, what: str = "", discrete: bool = False) -> None:
    """Raise ValueError unless every unobservable mode of (A, C) is stable."""
    A, C = _pair_AC(A, C)
    bad = _unstable(unobservable_modes(A, C), discrete)
    if bad.size:
        where = "|z| >= 1" if discrete else "Re s >= 0"
        raise ValueError(f"{_prefix(what)}(A, C) is not detectable: unobservable mode(s) with "
                         f"{where} at {_fmt(bad)}")


# ------------------------------------------------------------ pole specs
def second_order_poles(natural_frequency: float, damping_ratio: float) -> np.ndarray:
    """Roots of s² + 2 ζ ωₙ s + ωₙ², complex array (2,) (rad/s).

    Raises
    ------
    ValueError
        Unless ωₙ > 0 and ζ > 0 are finite.
    """
    wn, zeta = float(natural_frequency), float(damping_ratio)
    if not (np.isfinite(wn) and wn > 0 and np.isfinite(zeta) and zeta > 0):
        raise ValueError(f"need natural_frequency > 0 and damping_ratio > 0, got {wn} rad/s, {zeta}")
    root = np.sqrt(complex(zeta**2 - 1))
    return np.array([wn * (-zeta + root), wn * (-zeta - root)])


def _step_response_normalized(tau: float, zeta: float) -> float:
    """Unit step response of ωₙ²/(s² + 2ζωₙ s + ωₙ²) at normalized time τ = ωₙ t, 0 < ζ < 1."""
    wd = np.sqrt(1 - zeta**2)
    return 1 - np.exp(-zeta * tau) * (np.cos(wd * tau) + zeta / wd * np.sin(wd * tau))


def normalized_rise_time(damping_ratio: float) -> float:
    """ωₙ · t_r of the standard second-order system, t_r the 10–90 % rise time, 0 < ζ < 1."""
    zeta = float(damping_ratio)
    if not 0 < zeta < 1:
        raise ValueError(f"damping_ratio must be in (0, 1), got {zeta}")
    peak = np.pi / np.sqrt(1 - zeta**2)  # the response rises monotonically up to its first peak
    crossing = [scipy.optimize.brentq(lambda tau: _step_response_normalized(tau, zeta) - level,
                                      0.0, peak, xtol=1e-14) for level in (0.1, 0.9)]
    return crossing[1] - crossing[0]


def second_order_from_specs(rise_time: float, overshoot: float) -> tuple[float, float]:
    """(ωₙ rad/s, ζ) of the second-order system with exactly this step response.

    Parameters
    ----------
    rise_time : float, s
        10–90 % rise time.
    overshoot : float
        Fractional overshoot in (0, 1), e.g. 0.05 for 5 %.

    Returns
    -------
    natural_frequency : float, rad/s
    damping_ratio : float
        From the exact M_p = exp(−π ζ / √(1 − ζ²)).
    """
    if not (np.isfinite(rise_time) and rise_time > 0):
        raise ValueError(f"rise_time must be > 0 s, got {rise_time}")
    if not (np.isfinite(overshoot) and 0 < overshoot < 1):
        raise ValueError(f"overshoot must be a fraction in (0, 1), got {overshoot}")
    log = np.log(overshoot)
    zeta = -log / np.sqrt(np.pi**2 + log**2)
    return normalized_rise_time(zeta) / rise_time, zeta


# --------------------------------------------------------- pole placement
def _checked_poles(poles, n: int, n_inputs: int, what: str) -> np.ndarray:
    poles = np.atleast_1d(np.asarray(poles, dtype=complex)).ravel()
    if poles.size != n:
        raise ValueError(f"{_prefix(what)}need {n} poles (one per state), got {poles.size}")
    if not np.all(np.isfinite(poles)):
        raise ValueError(f"{_prefix(what)}the requested poles are not finite: {_fmt(poles)}")
    complex_ones = poles[np.abs(poles.imag) > 0]
    if not np.allclose(np.sort_complex(complex_ones), np.sort_complex(complex_ones.conj()),
                       rtol=1e-12, atol=1e-12):
        raise ValueError(f"{_prefix(what)}complex poles must come in conjugate pairs, got {_fmt(poles)}")
    for p in poles:
        count = int(np.sum(np.abs(poles - p) <= 1e-9 * max(1.0, abs(p))))
        if count > n_inputs:
            raise ValueError(f"{_prefix(what)}the pole {_fmt([p])} is requested {count} times but the "
                             f"system has {n_inputs} independent input(s); a pole can be placed at most "
                             f"rank(B) times: spread the repeated poles slightly")
    return poles


def pole_mismatch(actual, requested) -> float:
    """Largest distance between two pole sets after the best one-to-one matching."""
    actual = np.atleast_1d(np.asarray(actual, dtype=complex))
    requested = np.atleast_1d(np.asarray(requested, dtype=complex))
    if actual.size != requested.size:
        raise ValueError(f"pole sets differ in size: {actual.size} and {requested.size}")
    cost = np.abs(actual[:, None] - requested[None, :])
    rows, cols = scipy.optimize.linear_sum_assignment(cost)
    return float(np.max(cost[rows, cols]))


def place(A, B, poles, what: str = "") -> np.ndarray:
    """State-feedback gain K with eig(A − B K) = poles.

    Parameters
    ----------
    A : (nx, nx);  B : (nx, nu)
    poles : sequence of nx complex, conjugate pairs; each at most rank(B) times
    what : name used in error messages (e.g. "satellite")

    Returns
    -------
    K : ndarray (nu, nx), for u = −K x.

    Raises
    ------
    ValueError
        Uncontrollable pair (naming the modes), wrong number of poles,
        unpaired complex poles, a pole repeated more often than there are
        inputs, or a placement whose eigenvalues miss the request (an
        ill-conditioned problem).
    """
    A, B = _pair_AB(A, B)
    require_controllable(A, B, what)
    n_inputs = int(np.linalg.matrix_rank(B))
    poles = _checked_poles(poles, A.shape[0], n_inputs, what)
    with warnings.catch_warnings():
        # YT's iterations only improve robustness for several inputs; accuracy is checked below.
        warnings.filterwarnings("ignore", message="Convergence was not reached", category=UserWarning)
        result = scipy.signal.place_poles(A, B, poles, method="YT")
    K = np.real_if_close(result.gain_matrix, tol=1e6)
    if np.iscomplexobj(K):
        raise ValueError(f"{_prefix(what)}placement returned a complex gain")
    K = np.asarray(K, dtype=float).reshape(B.shape[1], A.shape[0])
    miss = pole_mismatch(np.linalg.eigvals(A - B @ K), poles)
    if miss > 1e-6 * max(1.0, float(np.max(np.abs(poles)))):
        raise ValueError(f"{_prefix(what)}pole placement is ill-conditioned: eig(A − B K) misses the "
                         f"requested poles by {miss:.3g}")
    return K


def reference_steady_state(A, B, C_r) -> tuple[np.ndarray, np.ndarray]:
    """(N_x, N_u): the rest state and input with C_r x = 1, from [A B; C_r 0][N_x; N_u] = [0; 1].

    For a single tracked output and input. Any gain K then gives the reference
    gain k_r = N_u + K N_x, the same number as `reference_gain` when A − B K
    is invertible, and the reference enters as u = N_u r − K (x − N_x r).

    Raises
    ------
    ValueError
        When the tracked output has a zero at s = 0 (no rest state reaches it).
    """
    A, B = _pair_AB(A, B)
    C_r = _matrix(C_r, "C_r")
    n = A.shape[0]
    if B.shape[1] != 1 or C_r.shape != (1, n):
        raise ValueError(f"reference_steady_state needs one input and one tracked output row C_r of "
                         f"{n} entries; got B {B.shape}, C_r {C_r.shape}")
    system = np.block([[A, B], [C_r, np.zeros((1, 1))]])
    if np.linalg.cond(system) > 1e12:
        raise ValueError("the tracked output has a transmission zero at s = 0: no rest state holds "
                         "it at a nonzero reference")
    sol = np.linalg.solve(system, np.concatenate([np.zeros(n), [1.0]]))
    return sol[:n], sol[n:]


def reference_gain(A, B, K, C_r) -> np.ndarray:
    """k_r = −1 / (C_r (A − B K)⁻¹ B): unit DC gain from r to C_r x under u = −K x + k_r r.

    Parameters
    ----------
    A (nx, nx), B (nx, 1), K (1, nx), C_r (1, nx): the row of the output that
    tracks the reference (the satellite's φ: (0, 1, 0, 0)).

    Returns
    -------
    kr : ndarray (1,)

    Raises
    ------
    ValueError
        When A − B K is singular or the DC gain C_r (A − B K)⁻¹ B is zero.
    """
    A, B = _pair_AB(A, B)
    K = _matrix(K, "K")
    C_r = _matrix(C_r, "C_r")
    if K.shape != (B.shape[1], A.shape[0]) or C_r.shape != (1, A.shape[0]) or B.shape[1] != 1:
        raise ValueError(f"reference_gain needs B (nx, 1), K (1, nx), C_r (1, nx); got {B.shape}, "
                         f"{K.shape}, {C_r.shape}")
    closed = A - B @ K
    if np.linalg.cond(closed) > 1e12:
        raise ValueError("A − B K is singular (a closed-loop pole at s = 0): no reference gain")
    dc = (C_r @ np.linalg.solve(closed, B)).item()
    if abs(dc) < 1e-12 * max(1.0, np.linalg.norm(B)):
        raise ValueError("the closed loop has zero DC gain from u to the tracked output")
    return np.array([-1.0 / dc])


def augment_integrator(A, B, C_r) -> tuple[np.ndarray, np.ndarray]:
    """System with the integral of the tracking error appended: x_I' = r − C_r x.

    Returns
    -------
    A_I : (nx+1, nx+1) = [[A, 0], [−C_r, 0]]
    B_I : (nx+1, nu) = [B; 0]
    """
    A, B = _pair_AB(A, B)
    C_r = _matrix(C_r, "C_r")
    n = A.shape[0]
    if C_r.shape != (1, n):
        raise ValueError(f"C_r must be one row of {n} entries, got shape {C_r.shape}")
    A_I = np.block([[A, np.zeros((n, 1))], [-C_r, np.zeros((1, 1))]])
    return A_I, np.vstack([B, np.zeros((1, B.shape[1]))])


def split_integral_gain(K_augmented, n_states: int) -> tuple[np.ndarray, np.ndarray]:
    """(K (nu, nx), k_i (nu,)) from the gain of the integrator-augmented system, u = −K x + k_i x_I."""
    K_augmented = _matrix(K_augmented, "K_augmented")
    if K_augmented.shape[1] != n_states + 1:
        raise ValueError(f"K_augmented must have {n_states + 1} columns, got {K_augmented.shape}")
    return K_augmented[:, :n_states].copy(), -K_augmented[:, n_states].copy()


def augment_disturbance(A, B, C) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous model with a constant input disturbance d as a state: x' = A x + B (u + d), d' = 0.

    The ZOH-discrete counterpart has the identity in the lower-right block
    (d_{k+1} = d_k); `designs.statespace_blocks.ObserverFeedback` builds it.

    Returns
    -------
    A_d (nx+nu, nx+nu) = [[A, B], [0, 0]];  B_d = [B; 0];  C_d = [C, 0]
    """
    A, B = _pair_AB(A, B)
    A, C = _pair_AC(A, C)
    n, m = B.shape
    A_d = np.block([[A, B], [np.zeros((m, n + m))]])
    return A_d, np.vstack([B, np.zeros((m, m))]), np.hstack([C, np.zeros((C.shape[0], m))])


def observer_gain(A, C, poles, what: str = "") -> np.ndarray:
    """Observer gain L (nx, ny) with eig(A − L C) = poles, by placement on the dual (Aᵀ, Cᵀ).

    Raises
    ------
    ValueError
        An unobservable pair (naming the modes) and every error of `place`.
    """
    A, C = _pair_AC(A, C)
    require_observable(A, C, what)
    return place(A.T, C.T, poles, what).T


def discrete_observer_gain(A_d, C, poles_z, what: str = "") -> np.ndarray:
    """Predictor gain L (nx, ny) of x̂_{k+1} = A_d x̂_k + B_d u_k + L (y_k − C x̂_k): eig(A_d − L C) = poles_z.

    Poles in the z-plane; exp(p Ts) maps continuous observer poles p.
    """
    poles_z = np.atleast_1d(np.asarray(poles_z, dtype=complex))
    if np.any(np.abs(poles_z) >= 1):
        raise ValueError(f"{_prefix(what)}discrete observer poles must lie inside the unit circle, "
                         f"got {_fmt(poles_z)}")
    return observer_gain(A_d, C, poles_z, what)


def current_estimator_gain(A_d, L_predictor) -> np.ndarray:
    """Gain M = A_d⁻¹ L of the current estimator x̂_k = x̄_k + M (y_k − C x̄_k), x̄_{k+1} = A_d x̂_k + B_d u_k.

    Its prior error x − x̄ has the same dynamics A_d − L C as the predictor;
    the controller uses y_k in the same sample instead of one sample late.
    A ZOH model's A_d = exp(A Ts) is always invertible.
    """
    A_d = _square(A_d, "A_d")
    return np.linalg.solve(A_d, _matrix(L_predictor, "L_predictor"))


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
    n, m = B.shape
    Q = np.eye(n) if Q is None else np.asarray(Q, dtype=float)
    R = np.eye(m) if R is None else np.asarray(R, dtype=float)
    R = R.reshape(1, 1) if R.size == 1 and m == 1 else R
    for name, W, size in (("Q", Q, n), ("R", R, m)):
        if W.shape != (size, size):
            raise ValueError(f"{_prefix(what)}{name} must have shape ({size}, {size}), got {W.shape}")
        if not np.all(np.isfinite(W)):
            raise ValueError(f"{_prefix(what)}weight {name} has non-finite entries")
        if not np.allclose(W, W.T, rtol=1e-10, atol=1e-14 * np.abs(W).max(initial=0)):
            raise ValueError(f"{_prefix(what)}weight {name} must be symmetric")
    if np.min(np.linalg.eigvalsh(Q)) < -1e-12 * max(1.0, np.abs(Q).max()):
        raise ValueError(f"{_prefix(what)}Q must be positive semidefinite")
    if np.min(np.linalg.eigvalsh(R)) <= 0:
        raise ValueError(f"{_prefix(what)}R must be positive definite")
    return Q, R


def _weight_root(Q) -> np.ndarray:
    vals, vecs = np.linalg.eigh(Q)
    return (vecs * np.sqrt(np.clip(vals, 0, None))).T


def riccati_residual(A, B, Q, R, P, discrete: bool = False) -> float:
    """Relative residual of the algebraic Riccati equation at P.

    Continuous: Aᵀ P + P A − P B R⁻¹ Bᵀ P + Q; discrete:
    Aᵀ P A − P − Aᵀ P B (R + Bᵀ P B)⁻¹ Bᵀ P A + Q. The Frobenius norm is
    divided by the sum of the norms of the terms.
    """
    A, B = _pair_AB(A, B)
    if discrete:
        gain_term = A.T @ P @ B @ np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        terms = [A.T @ P @ A, -P, -gain_term, Q]
    else:
        terms = [A.T @ P, P @ A, -P @ B @ np.linalg.solve(R, B.T @ P), Q]
    scale = sum(np.linalg.norm(t) for t in terms)
    return float(np.linalg.norm(sum(terms)) / max(scale, 1e-300))


def _riccati_checked(A, B, Q, R, P, K, discrete: bool, what: str) -> None:
    res = riccati_residual(A, B, Q, R, P, discrete)
    closed = np.linalg.eigvals(A - B @ K)
    stable = np.all(np.abs(closed) < 1) if discrete else np.all(closed.real < 0)
    if not (np.all(np.isfinite(P)) and res < 1e-8 and stable):
        raise ValueError(f"{_prefix(what)}the Riccati solve failed: relative residual {res:.3g}, "
                         f"closed-loop poles {_fmt(closed)}")


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
    A, B = _pair_AB(A, B)
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
    A, B = _pair_AB(A, B)
    Q, R = _weights(A, B, Q, R, what)
    require_stabilizable(A, B, what, discrete=True)
    require_detectable(A, _weight_root(Q), f"{what} with the weight Q" if what else "weight Q",
                       discrete=True)
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    P = (P + P.T) / 2
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    _riccati_checked(A, B, Q, R, P, K, True, what)
    return K, P


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
    A, C = _pair_AC(A, C)
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
    A, C = _pair_AC(A, C)
    K, P = dlqr(A.T, C.T, W, V, what)
    return K.T, P
