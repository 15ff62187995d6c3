"""State-space design as linear algebra: controllability, pole placement, observers, LQR, Kalman.

Controllability, observability and the Riccati gains live in `models.lqr`
(MPC needs them too) and are re-exported here, so one import serves a design.
Everything here takes and returns numpy arrays and prints nothing; the
controller blocks that run these gains on the nonlinear plants are in
`designs.statespace_blocks`, and `designs.statespace_design` makes every
design of a plant (pole placement, integrator, observers, LQR, Kalman) from
the choices a case study passes it.

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

from models import deferred
from models.lqr import (
    augment_disturbance,
    bryson_weights,
    controllability_matrix,
    dkalman,
    dlqr,
    finite_matrix,
    format_values,
    kalman,
    lqr,
    message_prefix,
    observability_matrix,
    require_controllable,
    require_detectable,
    require_observable,
    require_stabilizable,
    riccati_residual,
    square_matrix,
    state_input_pair,
    state_output_pair,
    uncontrollable_modes,
    unobservable_modes,
)

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
    "second_order_poles",
    "second_order_from_specs",
    "normalized_rise_time",
    "place",
    "pole_mismatch",
    "reference_gain",
    "reference_steady_state",
    "augment_integrator",
    "split_integral_gain",
    "augment_disturbance",
    "inner_outer_poles",
    "bryson_tracking_weights",
    "observer_gain",
    "discrete_observer_gain",
    "current_estimator_gain",
    "bryson_weights",
    "lqr",
    "dlqr",
    "kalman",
    "dkalman",
    "riccati_residual",
]


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
    crossing = [
        scipy.optimize.brentq(
            lambda tau, level=level: _step_response_normalized(tau, zeta) - level, 0.0, peak, xtol=1e-14
        )
        for level in (0.1, 0.9)
    ]
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
    """The requested poles as a complex (n,) array: n of them, finite, in conjugate pairs, each repeated
    at most `n_inputs` times (ValueError naming `what` otherwise)."""
    poles = np.atleast_1d(np.asarray(poles, dtype=complex)).ravel()
    if poles.size != n:
        raise ValueError(f"{message_prefix(what)}need {n} poles (one per state), got {poles.size}")
    if not np.all(np.isfinite(poles)):
        raise ValueError(f"{message_prefix(what)}the requested poles are not finite: {format_values(poles)}")
    complex_ones = poles[np.abs(poles.imag) > 0]
    if not np.allclose(np.sort_complex(complex_ones), np.sort_complex(complex_ones.conj()), rtol=1e-12, atol=1e-12):
        raise ValueError(
            f"{message_prefix(what)}complex poles must come in conjugate pairs, got {format_values(poles)}"
        )
    for p in poles:
        count = int(np.sum(np.abs(poles - p) <= 1e-9 * max(1.0, abs(p))))
        if count > n_inputs:
            raise ValueError(
                f"{message_prefix(what)}the pole {format_values([p])} is requested {count} times but the "
                f"system has {n_inputs} independent input(s); a pole can be placed at most "
                f"rank(B) times: spread the repeated poles slightly"
            )
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
    A, B = state_input_pair(A, B)
    require_controllable(A, B, what)
    n_inputs = int(np.linalg.matrix_rank(B))
    poles = _checked_poles(poles, A.shape[0], n_inputs, what)
    with warnings.catch_warnings():
        # YT's iterations only improve robustness for several inputs; accuracy is checked below.
        warnings.filterwarnings("ignore", message="Convergence was not reached", category=UserWarning)
        result = scipy.signal.place_poles(A, B, poles, method="YT")
    K = np.real_if_close(result.gain_matrix, tol=1e6)
    if np.iscomplexobj(K):
        raise ValueError(f"{message_prefix(what)}placement returned a complex gain")
    K = np.asarray(K, dtype=float).reshape(B.shape[1], A.shape[0])
    miss = pole_mismatch(np.linalg.eigvals(A - B @ K), poles)
    if miss > 1e-6 * max(1.0, float(np.max(np.abs(poles)))):
        raise ValueError(
            f"{message_prefix(what)}pole placement is ill-conditioned: eig(A − B K) misses the "
            f"requested poles by {miss:.3g}"
        )
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
    A, B = state_input_pair(A, B)
    C_r = finite_matrix(C_r, "C_r")
    n = A.shape[0]
    if B.shape[1] != 1 or C_r.shape != (1, n):
        raise ValueError(
            f"reference_steady_state needs one input and one tracked output row C_r of "
            f"{n} entries; got B {B.shape}, C_r {C_r.shape}"
        )
    system = np.block([[A, B], [C_r, np.zeros((1, 1))]])
    if np.linalg.cond(system) > 1e12:
        raise ValueError(
            "the tracked output has a transmission zero at s = 0: no rest state holds it at a nonzero reference"
        )
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
    A, B = state_input_pair(A, B)
    K = finite_matrix(K, "K")
    C_r = finite_matrix(C_r, "C_r")
    if K.shape != (B.shape[1], A.shape[0]) or C_r.shape != (1, A.shape[0]) or B.shape[1] != 1:
        raise ValueError(
            f"reference_gain needs B (nx, 1), K (1, nx), C_r (1, nx); got {B.shape}, {K.shape}, {C_r.shape}"
        )
    closed = A - B @ K
    if np.linalg.cond(closed) > 1e12:
        raise ValueError("A − B K is singular (a closed-loop pole at s = 0): no reference gain")
    dc = (C_r @ np.linalg.solve(closed, B)).item()
    if abs(dc) < 1e-12 * max(1.0, float(np.linalg.norm(B))):
        raise ValueError("the closed loop has zero DC gain from u to the tracked output")
    return np.array([-1.0 / dc])


def augment_integrator(A, B, C_r) -> tuple[np.ndarray, np.ndarray]:
    """System with the integral of the tracking error appended: x_I' = r − C_r x.

    Returns
    -------
    A_I : (nx+1, nx+1) = [[A, 0], [−C_r, 0]]
    B_I : (nx+1, nu) = [B; 0]
    """
    A, B = state_input_pair(A, B)
    C_r = finite_matrix(C_r, "C_r")
    n = A.shape[0]
    if C_r.shape != (1, n):
        raise ValueError(f"C_r must be one row of {n} entries, got shape {C_r.shape}")
    A_I = np.block([[A, np.zeros((n, 1))], [-C_r, np.zeros((1, 1))]])
    return A_I, np.vstack([B, np.zeros((1, B.shape[1]))])


def split_integral_gain(K_augmented, n_states: int) -> tuple[np.ndarray, np.ndarray]:
    """(K (nu, nx), k_i (nu,)) from the gain of the integrator-augmented system, u = −K x + k_i x_I."""
    K_augmented = finite_matrix(K_augmented, "K_augmented")
    if K_augmented.shape[1] != n_states + 1:
        raise ValueError(f"K_augmented must have {n_states + 1} columns, got {K_augmented.shape}")
    return K_augmented[:, :n_states].copy(), -K_augmented[:, n_states].copy()


def inner_outer_poles(
    linear,
    inner_state: int,
    input_room: float,
    angle_step: float,
    damping_ratio: float,
    separation: float,
    what: str = "",
) -> np.ndarray:
    """The .8 successive-loop rule as state-feedback poles (rad/s), (4,).

    From the inner coordinate's row q̈_i = a q_i + b u + … of the linearization:
    inner ωₙ² = |b| u_room / A − a, so the input just saturates when the inner
    reference steps by `angle_step` A; the outer pair is `separation` times
    slower; both with `damping_ratio`.

    Parameters
    ----------
    linear : models.LinearModel (states (q, q̇))
    inner_state : index of the inner coordinate in q
    input_room : the input left for feedback (units of u)

    Raises
    ------
    ValueError
        When no ωₙ > 0 comes out (the step is too large to stabilize the inner loop).
    """
    nq = linear.nx // 2
    a, b = linear.A[nq + inner_state, inner_state], linear.B[nq + inner_state, 0]
    wn_sq = abs(b) * input_room / angle_step - a
    if wn_sq <= 0:
        raise ValueError(
            f"{message_prefix(what)}a step of {angle_step:.3g} rad saturating the input cannot "
            f"stabilize the inner loop (ωₙ² = {wn_sq:.3g}); choose a smaller angle step"
        )
    wn = np.sqrt(wn_sq)
    return np.concatenate([second_order_poles(wn, damping_ratio), second_order_poles(wn / separation, damping_ratio)])


def bryson_tracking_weights(
    state_names, maxima: dict, integral_max: float, input_room: float
) -> tuple[np.ndarray, np.ndarray]:
    """Bryson's rule for the integrator-augmented state (x, x_I) and one input.

    `maxima` gives the largest acceptable excursion per state name (SI; states not
    named are unweighted), `integral_max` that of the integrator state, `input_room`
    the input's room above the equilibrium input.
    """
    unknown = set(maxima) - set(state_names)
    if unknown:
        raise ValueError(f"Bryson maxima for unknown states {sorted(unknown)}; states are {tuple(state_names)}")
    state_max = [maxima.get(s, np.inf) for s in state_names] + [integral_max]
    return bryson_weights(state_max, [input_room])


def observer_gain(A, C, poles, what: str = "") -> np.ndarray:
    """Observer gain L (nx, ny) with eig(A − L C) = poles, by placement on the dual (Aᵀ, Cᵀ).

    Raises
    ------
    ValueError
        An unobservable pair (naming the modes) and every error of `place`.
    """
    A, C = state_output_pair(A, C)
    require_observable(A, C, what)
    return place(A.T, C.T, poles, what).T


def discrete_observer_gain(A_d, C, poles_z, what: str = "") -> np.ndarray:
    """Predictor gain L (nx, ny) of x̂_{k+1} = A_d x̂_k + B_d u_k + L (y_k − C x̂_k): eig(A_d − L C) = poles_z.

    Poles in the z-plane; exp(p Ts) maps continuous observer poles p.
    """
    poles_z = np.atleast_1d(np.asarray(poles_z, dtype=complex))
    if np.any(np.abs(poles_z) >= 1):
        raise ValueError(
            f"{message_prefix(what)}discrete observer poles must lie inside the unit circle, "
            f"got {format_values(poles_z)}"
        )
    return observer_gain(A_d, C, poles_z, what)


def current_estimator_gain(A_d, L_predictor) -> np.ndarray:
    """Gain M = A_d⁻¹ L of the current estimator x̂_k = x̄_k + M (y_k − C x̄_k), x̄_{k+1} = A_d x̂_k + B_d u_k.

    Its prior error x − x̄ has the same dynamics A_d − L C as the predictor;
    the controller uses y_k in the same sample instead of one sample late.
    A ZOH model's A_d = exp(A Ts) is always invertible.
    """
    A_d = square_matrix(A_d, "A_d")
    return np.linalg.solve(A_d, finite_matrix(L_predictor, "L_predictor"))
