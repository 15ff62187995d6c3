"""An LQR parameterized by its weights: Q and R from a log-diagonal, the gain from the linearization.

The decision of a weight-tuned LQR is the vector θ = (log q₁, …, log q_{n+1}, log r) of the
diagonal of Q, the weight of the integrator-augmented state (x̃, x_I), and of R. Q = diag(e^θ) and
R = e^{θ_r} are positive definite for every finite θ, so no search over θ can leave the set of valid
weights. The gain is the LQR of the known plant's linearization about its standard equilibrium,
augmented with the tracked coordinate's integrator (the same design as `designs.statespace_design`'s
"LQR" row): K_aug = lqr(A_I, B_I, Q, R), split into the state gain K and the integral gain k_i, run
by a `designs.statespace_blocks.StateFeedback` block that saturates its command.

Why the weights are searched without derivatives (`designs.weight_search`), not by exact gradients
of the closed loop: the map θ → K passes through the algebraic Riccati equation, whose derivative
CasADi's closed-loop function does not provide, and the table's verdict (`models.specs`) counts rise
and settling times that jump when a sample crosses a band; with at most seven weights a poll search
on the verdict itself costs a few hundred closed-loop runs of milliseconds each. The measured costs
are in docs/notes/tuned_rows.md.
"""

from __future__ import annotations

import numpy as np

import models
from models.lqr import lqr

from . import statespace as ss
from .statespace_blocks import StateFeedback, TrackingModel


def weights(log_weights, n_states: int) -> tuple[np.ndarray, np.ndarray]:
    """(Q (n_states + 1, n_states + 1), R (1, 1)) of θ = (log diag Q, log R), length n_states + 2."""
    theta = np.asarray(log_weights, dtype=float).ravel()
    if theta.size != n_states + 2:
        raise ValueError(f"log_weights must have n_states + 2 = {n_states + 2} entries, got {theta.size}")
    if not np.all(np.isfinite(theta)):
        raise ValueError(f"log_weights must be finite, got {theta.tolist()}")
    return np.diag(np.exp(theta[:-1])), np.array([[np.exp(theta[-1])]])


def log_weights(Q, R, zero_floor: float = 1e-3) -> np.ndarray:
    """θ = (log diag Q, log R) of diagonal weights Q (n + 1, n + 1) ≥ 0 and R (1, 1) or scalar > 0.

    A zero on Q's diagonal (a state Bryson's rule leaves free) becomes `zero_floor` times the smallest
    positive entry, so that it has a logarithm and the search can still raise it.
    """
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    if R.shape != (1, 1) or not R[0, 0] > 0:
        raise ValueError(f"R must be one positive number (the plants have one input), got {R.tolist()}")
    diagonal = np.diag(Q).copy()
    if not np.array_equal(Q, np.diag(diagonal)) or np.any(diagonal < 0) or not np.any(diagonal > 0):
        raise ValueError(f"Q must be diagonal, >= 0 and not zero to be log-parameterized, got {Q.tolist()}")
    diagonal[diagonal == 0] = zero_floor * np.min(diagonal[diagonal > 0])
    return np.log(np.concatenate([diagonal, R.ravel()]))


def augmented_model(model: TrackingModel) -> tuple[np.ndarray, np.ndarray]:
    """(A_I, B_I): the linearization of `model` augmented with the integrator of the tracked coordinate."""
    return ss.augment_integrator(model.linear.A, model.linear.B, model.C_r)


def gains(model: TrackingModel, log_weights) -> tuple[np.ndarray, float, np.ndarray]:
    """(K (nx,), k_i, K_aug (1, nx + 1)) of the integrator-augmented LQR with the weights of θ.

    K_aug = R⁻¹ B_Iᵀ P with P the stabilizing solution of the Riccati equation of (A_I, B_I, Q, R);
    u = −K x̃ + k_i ∫(r − y_r) (`designs.statespace.split_integral_gain`).
    """
    A_I, B_I = augmented_model(model)
    Q, R = weights(log_weights, model.nx)
    K_aug, _ = lqr(A_I, B_I, Q, R, f"{model.plant.name} (weight-tuned LQR)")
    K, ki = ss.split_integral_gain(K_aug, model.nx)
    return np.asarray(K, dtype=float).ravel(), float(np.ravel(ki)[0]), K_aug


def block(known: models.Plant, tracked: str, log_weights, sample_period: float, name: str = "tuned LQR"):
    """The `StateFeedback` block of the weight-tuned LQR designed on `known`, tracking `tracked`.

    Parameters
    ----------
    known : the plant the controller is designed from
    tracked : the coordinate that follows the reference
    log_weights : θ, (nx + 2,): log of Q's diagonal (x̃ then x_I), then log R
    sample_period : s
    """
    model = TrackingModel.from_plant(known, tracked)
    K, ki, _ = gains(model, log_weights)
    return StateFeedback(model, K, 0.0, ki, sample_period=sample_period, name=name)
