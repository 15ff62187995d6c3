"""A linear MPC parameterized by its weights: Q, R and the soft-bound penalties from log-weights.

The decision of a weight-tuned MPC is θ = (log Q₁₁, …, log Q_nn, log R[, log ρ₁, log ρ₂]): the
diagonal state weight and the input weight of `mpc.MPCSettings`, and, when the settings have soft
bounds, the linear and quadratic price ρ₁, ρ₂ of their violation. Every finite θ gives positive
weights. `settings` writes θ into a copy of the case's settings; the horizon, the sample period, the
bounds themselves and the estimator's tuning stay as the case states them.

Why the weights are searched without derivatives (`designs.weight_search`), not with the exact
sensitivities of the MPC's QP: the closed-loop cost of a constrained MPC is only piecewise smooth in
its weights. The QP's solution is differentiable in θ only while its active set stays the same, and a
closed-loop run solves one QP per sample; each change of the active set anywhere in a run, and each
sample that crosses a settling band of the verdict, is a kink or a jump of the objective. Sensitivities
of the QP are exact within one piece and say nothing across it, so a gradient method needs the
continuation the PID tuner uses, while a poll search on the table's own verdict needs only closed-loop
runs. Measured on the arm and the numbers behind this choice: docs/notes/tuned_rows.md.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mpc import MPCSettings


def size(base: MPCSettings) -> int:
    """Length of θ for `base`: nx + 1, plus 2 when it has soft bounds."""
    return len(base.state_weight) + 1 + (2 if base.soft else 0)


def log_weights(base: MPCSettings) -> np.ndarray:
    """θ of `base`'s own weights (see the module docstring); ValueError for a weight that is not > 0."""
    values = [*base.state_weight, base.input_weight]
    if base.soft:
        values += [base.soft_linear_weight, base.soft_quadratic_weight]
    values_array = np.asarray(values, dtype=float)
    if np.any(~np.isfinite(values_array)) or np.any(values_array <= 0):
        raise ValueError(f"every MPC weight must be finite and > 0 to be log-parameterized, got {values}")
    return np.log(values_array)


def settings(base: MPCSettings, log_weights) -> MPCSettings:
    """`base` with the weights of θ (length `size(base)`): Q's diagonal, R, and the soft-bound prices."""
    theta = np.asarray(log_weights, dtype=float).ravel()
    if theta.size != size(base):
        raise ValueError(f"log_weights must have {size(base)} entries for these settings, got {theta.size}")
    if not np.all(np.isfinite(theta)):
        raise ValueError(f"log_weights must be finite, got {theta.tolist()}")
    weights = np.exp(theta)
    nx = len(base.state_weight)
    fields: dict = {"state_weight": tuple(float(w) for w in weights[:nx]), "input_weight": float(weights[nx])}
    if base.soft:
        fields |= {"soft_linear_weight": float(weights[nx + 1]), "soft_quadratic_weight": float(weights[nx + 2])}
    return replace(base, **fields)
