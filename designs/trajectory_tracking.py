"""Tracking a planned trajectory: time-varying LQR along it, then the LQR at its end.

A trajectory (x_ref,k, u_ff,k) sampled at the controller's instants t_k = k Ts
(an optimal control solution, say) is tracked on the known plant by

    u_k = sat( u_ff,k − K_k (x_k − x_ref,k) )            k < K   (along the trajectory)
    u_k = sat( u_e − K_∞ (x_k − x_ref,K) )               k >= K  (caught and held at its end)

with A_k, B_k the Jacobians of the known plant's sample-and-hold step (RK4 over
Ts, `models.Plant.step_function`) at (x_ref,k, u_ff,k), the gains K_k from the
backward Riccati recursion (`models.lqr.dlqr_time_varying`) whose final weight
is the infinite-horizon discrete LQR's cost at the end state, and u_e the input
holding the known plant at rest there: the gains run into K_∞ without a jump.

The schedule (x_ref,k, u_ff,k, K_k) is the block's reference signal, one row per
sample (`TrajectoryTracking.reference`), so a closed-loop run and a Monte Carlo
of it stay one compiled CasADi loop (`models.simulate_closed_loop`,
`models.monte_carlo`). Nothing here knows a particular plant.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

import models
from models.checks import positive
from models.lqr import dlqr, dlqr_time_varying

__all__ = ["TrajectoryTracker", "TrajectoryTracking", "linearize_along", "tvlqr_tracking"]

#: Largest |f(x_end, u_e)| (SI units per second) for the trajectory's end to count as a rest point.
REST_TOLERANCE = 1e-6


def linearize_along(
    plant: models.Plant, sample_period: float, states, inputs, substeps: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of the plant's RK4 step over `sample_period` s along a trajectory.

    Parameters
    ----------
    states : (K, nx) or (K+1, nx), the points (the first K are used);  inputs : (K, nu) held over each step
    substeps : RK4 sub-steps of the step (as the closed-loop simulator's)

    Returns
    -------
    As : (K, nx, nx) = ∂x_{k+1}/∂x_k;  Bs : (K, nx, nu) = ∂x_{k+1}/∂u_k
    """
    inputs = np.asarray(inputs, dtype=float).reshape(-1, plant.nu)
    states = np.asarray(states, dtype=float).reshape(-1, plant.nx)
    if states.shape[0] < inputs.shape[0]:
        raise ValueError(f"states: need at least {inputs.shape[0]} rows (one per input), got {states.shape[0]}")
    step = plant.step_function(positive(sample_period, "sample_period (s)"), substeps)
    x, u = ca.SX.sym("x", plant.nx), ca.SX.sym("u", plant.nu)
    x_next = step(x, u, plant.param_vector())
    jacobians = ca.Function("step_jacobians", [x, u], [ca.jacobian(x_next, x), ca.jacobian(x_next, u)])
    batch = jacobians.map(inputs.shape[0])
    A, B = batch(states[: inputs.shape[0]].T, inputs.T)
    nx, nu = plant.nx, plant.nu
    As = np.asarray(A, dtype=float).reshape(nx, -1, nx).transpose(1, 0, 2)  # [A_0 | A_1 | ...]
    Bs = np.asarray(B, dtype=float).reshape(nx, -1, nu).transpose(1, 0, 2)
    return As, Bs


class TrajectoryTracker(models.Block):
    """u = sat(u_ff − K (x − x_ref)) with (x_ref, u_ff, K) read from the reference signal each sample.

    The reference is (x_ref (nx), u_ff (nu), K (nu·nx, row by row)); the block measures the
    full state and has neither state nor gains of its own (the schedule is the design).
    """

    def __init__(self, plant: models.Plant, sample_period: float, name: str = "time-varying LQR"):
        self.limit = np.asarray(plant.input_limit, dtype=float)
        self.nx, self.nu = plant.nx, plant.nu
        super().__init__(
            sample_period=sample_period,
            n_state=0,
            n_measured=plant.nx,
            n_reference=plant.nx + plant.nu + plant.nu * plant.nx,
            n_input=plant.nu,
            gains={},
            measures="state",
            name=name,
        )

    def expr(self, xc, y, r, gains):
        """One sample: u = u_ff + K (x_ref − x), saturated; r = (x_ref (nx), u_ff (nu), K row by row (nu·nx))."""
        nx, nu = self.nx, self.nu
        x_ref, u_ff = r[:nx], r[nx : nx + nu]
        gain = ca.reshape(r[nx + nu :], nx, nu).T  # row by row
        u = u_ff - gain @ (y - x_ref)
        return ca.SX(0, 1), models.saturate(u, ca.DM(self.limit))


@dataclass(frozen=True)
class TrajectoryTracking:
    """A time-varying LQR design along a sampled trajectory (see the module docstring).

    Attributes
    ----------
    plant : the known plant it was designed on;  sample_period : Ts, s
    states : (K+1, nx) x_ref at t_k = k Ts;  inputs : (K, nu) u_ff
    gains : (K, nu, nx) K_k;  cost_to_go : (K+1, nx, nx) P_k
    final_gain : (nu, nx) K_∞;  final_input : (nu,) u_e at the end state
    block : the `TrajectoryTracker` that runs it
    """

    plant: models.Plant
    sample_period: float
    states: np.ndarray
    inputs: np.ndarray
    gains: np.ndarray
    cost_to_go: np.ndarray
    final_gain: np.ndarray
    final_input: np.ndarray
    block: TrajectoryTracker

    @property
    def duration(self) -> float:
        """Length of the trajectory, s."""
        return self.sample_period * len(self.inputs)

    def reference(self, duration: float) -> np.ndarray:
        """The block's reference over a run of `duration` s (>= the trajectory's): (M+1, nx + nu + nu·nx).

        Rows k < K follow the trajectory; from K on, the end state, u_e and K_∞ (the catch).
        """
        duration = positive(duration, "duration (s)")
        steps = int(round(duration / self.sample_period))
        K = len(self.inputs)
        if steps < K:
            raise ValueError(f"duration must cover the trajectory's {self.duration:g} s, got {duration:g} s")
        nu, nx = self.final_gain.shape
        out = np.empty((steps + 1, nx + nu + nu * nx))
        out[:K, :nx] = self.states[:K]
        out[:K, nx : nx + nu] = self.inputs
        out[:K, nx + nu :] = self.gains.reshape(K, nu * nx)
        out[K:, :nx] = self.states[K]
        out[K:, nx : nx + nu] = self.final_input
        out[K:, nx + nu :] = self.final_gain.reshape(nu * nx)
        return out


def tvlqr_tracking(
    known: models.Plant,
    sample_period: float,
    states,
    inputs,
    Q,
    R,
    *,
    substeps: int = 2,
    name: str = "time-varying LQR",
) -> TrajectoryTracking:
    """Design the time-varying LQR along (states, inputs) on the known plant.

    Parameters
    ----------
    known : the plant the controller believes (its parameters and actuator limit)
    sample_period : Ts, s; the trajectory is sampled at t_k = k Ts
    states : (K+1, nx) the reference states; the last must be a rest point of `known`
    inputs : (K, nu) the feedforward, held over each sample
    Q, R : weights on the state and input deviations (`models.lqr.bryson_weights`)
    substeps : RK4 sub-steps of the design model's step

    Raises
    ------
    ValueError
        When the trajectory does not end at rest (|f(x_K, u_e)| > `REST_TOLERANCE`), or the
        Riccati solve at the end fails (see `models.lqr.dlqr`).
    """
    sample_period = positive(sample_period, "sample_period (s)")
    inputs = np.asarray(inputs, dtype=float).reshape(-1, known.nu)
    states = np.asarray(states, dtype=float).reshape(-1, known.nx)
    if states.shape[0] != inputs.shape[0] + 1:
        raise ValueError(f"states: need one row more than inputs ({inputs.shape[0] + 1}), got {states.shape[0]}")
    end = states[-1]
    final_input = known.equilibrium_input(end[: known.nq])
    drift = np.asarray(known.casadi_f(end, final_input, known.param_vector()), dtype=float).ravel()
    if np.max(np.abs(drift)) > REST_TOLERANCE:
        raise ValueError(
            f"states: the trajectory must end at rest for the LQR to hold it; at its end "
            f"|f(x, u_e)| = {np.max(np.abs(drift)):.3g} > {REST_TOLERANCE:g}"
        )
    As, Bs = linearize_along(known, sample_period, np.vstack([states, end]), np.vstack([inputs, final_input]), substeps)
    final_gain, final_weight = dlqr(As[-1], Bs[-1], Q, R, f"{name} at the trajectory's end")
    gains, costs = dlqr_time_varying(As[:-1], Bs[:-1], Q, R, final_weight, name)
    block = TrajectoryTracker(known, sample_period, name)
    return TrajectoryTracking(known, sample_period, states, inputs, gains, costs, final_gain, final_input, block)
