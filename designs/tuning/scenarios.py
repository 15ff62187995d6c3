"""What one closed-loop run of a tuning problem costs (`Cost`), and the checks of its bounds.

The run itself is `models.scenario.Scenario` and its specs the study tables' own
record, `models.specs.Specs` (both re-exported here); `TuningProblem` turns the
specs into pointwise constraints that imply the tables' verdict.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.checks import positive, real, real_array
from models.scenario import Scenario as Scenario
from models.specs import Specs as Specs

#: The criteria a `Cost` may take.
COSTS = ("itae", "iae", "ise")


def state_bound(bound, what: str) -> tuple[float, float]:
    """(low, high) from a bound b > 0 (meaning |x| <= b) or a pair low < high (NaN refused)."""
    arr = real_array(bound, what)
    if arr.ndim == 0:
        b = float(arr)
        if not (np.isfinite(b) and b > 0):
            raise ValueError(f"{what} must be a finite bound > 0 or a pair (low, high), got {bound!r}")
        return -b, b
    if arr.shape != (2,) or np.any(np.isnan(arr)) or not arr[0] < arr[1]:
        raise ValueError(f"{what} must be a finite bound > 0 or a pair (low, high) with low < high, got {bound!r}")
    return float(arr[0]), float(arr[1])


def final_value(pair, what: str) -> tuple[float, float]:
    """(value, tolerance) with a finite value and a finite tolerance > 0."""
    arr = real_array(pair, what)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)) or arr[1] <= 0:
        raise ValueError(f"{what} must be a pair (value, tolerance > 0) of finite numbers, got {pair!r}")
    return float(arr[0]), float(arr[1])


@dataclass(frozen=True)
class Cost:
    """A closed-loop cost: a criterion of one signal plus quadratic terms, summed over k = 0..N-1.

        J = Ts Σ_k w(t_k) ρ(s_k) + energy_weight Ts Σ_k |u_k|²
            + Ts Σ_k [(x_k − x*)ᵀ Q (x_k − x*) + (u_k − u*)ᵀ R (u_k − u*) + (y_k − y*)ᵀ Q_y (y_k − y*)]
            + (x_N − x*)ᵀ P (x_N − x*)

    kind : "itae" (w = t, ρ = |s|), "iae" (ρ = |s|), "ise" (ρ = s²), or None for no criterion term
    signal : what the criterion measures: "error" (reference − tracked coordinate), or the
        name of a state, output or input (measured from its target)
    energy_weight : weight (>= 0) on Σ u² Ts
    smoothing, resolution : |s| is evaluated as sqrt(s² + δ²), δ = max(smoothing, resolution × S),
        so the criterion is differentiable with a curvature a quasi-Newton method can follow;
        `smoothing` in units of the signal (> 0), `resolution` relative (>= 0) to the signal's
        scale S (its size at the start, or the reference's largest change for "error"; 0 where
        both are zero). The criterion exceeds the exact Σ w|s| Ts by at most δ Σ w Ts (ITAE:
        δ T² / 2). The default resolution 1e-4 is coarse enough for IPOPT to converge across
        the sign changes of a settled error (each a kink of curvature 1/δ; see
        docs/notes/tuning.md).
    state_weights, output_weights, input_weights, terminal_weights : Q, Q_y, R and P: a
        symmetric positive semidefinite matrix, a vector of its diagonal, or a dict
        name -> weight (diagonal, the others zero); None for no term
    target : x*, a dict state name -> value or a full state vector; default the plant's
        standard equilibrium with the tracked coordinate at the final reference (when the
        scenario has one); y* = h(x*)
    input_target : u*, a dict input name -> value or a vector; default zero
    """

    kind: str | None = "itae"
    energy_weight: float = 0.0
    smoothing: float = 1e-6
    resolution: float = 1e-4
    signal: str = "error"
    state_weights: object = None
    input_weights: object = None
    output_weights: object = None
    terminal_weights: object = None
    target: object = None
    input_target: object = None

    def __post_init__(self):
        if self.kind is not None and self.kind not in COSTS:
            raise ValueError(f"unknown cost {self.kind!r}; choose one of {', '.join(COSTS)} or None")
        weight = real(self.energy_weight, "energy_weight", finite=False)
        if not np.isfinite(weight) or weight < 0:
            raise ValueError(f"energy_weight must be finite and >= 0, got {self.energy_weight}")
        positive(self.smoothing, "smoothing")
        resolution = real(self.resolution, "resolution", finite=False)
        if not np.isfinite(resolution) or resolution < 0:
            raise ValueError(f"resolution must be finite and >= 0, got {self.resolution}")
        if not isinstance(self.signal, str):
            raise TypeError(f"signal must be 'error' or a state, output or input name, got {self.signal!r}")
        terms = (self.kind, self.state_weights, self.input_weights, self.output_weights, self.terminal_weights)
        if all(term is None for term in terms) and weight == 0:
            raise ValueError("the cost has no term: give kind, energy_weight or a weight matrix")
