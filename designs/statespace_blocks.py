"""State-space controllers as `models.Block`s: full-state feedback, integrator, observers.

Every block runs a design made on the linearization of a *known* plant about
its standard equilibrium (x_e, u_e) on the nonlinear plant at the sample
period Ts. With r̃ = r − y_r,e the reference relative to the operating point,

    u = sat( u_e + u_nl(q) − K x̃ + k_r r̃  [+ k_i x_I]  [− d̂] )

- x̃ = x − x_e is the measured state (`StateFeedback`) or its estimate
  (`ObserverFeedback`), q the measured or estimated configuration.
- u_nl(q) = u_e(q) − u_e − G (q − q_e), G = ∂u_e/∂q at q_e, is the
  nonlinear remainder of the known plant's equilibrium input
  (`Plant.casadi_equilibrium_input`): the arm's (m g ℓ / 2)(cos θ − 1), the
  UUV's m g L (sin φ − φ), zero for the plants without a static input
  nonlinearity. It cancels the gravity nonlinearity the linear design does
  not know about and vanishes to first order, so the linear design is
  unchanged at the operating point. With k_r = N_u + K N_x (equal to the
  text's −1/(C_r (A − B K)⁻¹ B)) every reference is an exact rest point of
  the known plant: u = u_e(q_ref(r)) there.

  Why at q and not at the reference (a textbook hint feeds τ_e(θ^d) forward):
  with the reference's equilibrium torque the loop's stiffness about θ^d is
  k_p − (m g ℓ / 2) sin θ^d, negative for a k_p of 0.304 N m/rad at
  θ^d = 50° (0.56 N m/rad of gravity stiffness), so the arm stalls near
  θ = 0 instead of reaching the reference. Cancelling at the measured
  configuration keeps the designed poles everywhere on the arm.
- x_I is the trapezoidal integral of r − y_r, with back-calculation
  anti-windup (`designs.discrete.back_calculation`, valid for either sign of
  k_i) and optionally the text's "integrate only while |ẏ_r| is small".
- sat is the known plant's actuator limit on the total input.

Observers are discrete: the current estimator on the exact zero-order-hold
model (A_d, B_d) of the linearization at Ts,

    x̂_k = x̄_k + M (ỹ_k − C x̄_k),   x̄_{k+1} = A_d x̂_k + B_d (u_k − u_e − u_nl(q̂_k)),

with ỹ = y − y_e, and u_k the saturated command the plant receives (so the
observer does not wind up). The prior error obeys e_{k+1} = (A_d − L C) e_k
with L = A_d M, which is how the gains are placed. A disturbance observer
appends d_{k+1} = d_k to the model (input disturbance, exact under ZOH) and
subtracts d̂ from the command instead of integrating the error.

Gains K, k_r, k_i are the blocks' symbolic gains (tunable and
differentiable); L, A_d, B_d, x_e and the known parameters are baked in.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

import models
from designs.discrete import back_calculation, integrate_while_slow, saturate, trapezoid
from designs.pid import numbers_repr
from designs.statespace import augment_disturbance, pole_mismatch, reference_steady_state

__all__ = ["TrackingModel", "StateFeedback", "ObserverFeedback"]


@dataclass(frozen=True)
class TrackingModel:
    """What a state-space block knows: the known plant, its linearization and the tracked coordinate.

    Attributes
    ----------
    plant : models.Plant, the known plant (parameters the controller believes)
    linear : models.LinearModel about the plant's standard equilibrium
    tracked : name of the coordinate that follows the reference
    tracked_state : index of that coordinate in the state
    C_r : (1, nx) row selecting the tracked coordinate from x̃
    N_x : (nx,), N_u : (nu,) rest state and input per unit of r̃ (`reference_steady_state`)
    static_input_jacobian : (nu, nq) G = ∂u_e/∂q at the operating point
    """

    plant: models.Plant
    linear: models.LinearModel
    tracked: str
    tracked_state: int
    C_r: np.ndarray
    N_x: np.ndarray
    N_u: np.ndarray
    static_input_jacobian: np.ndarray
    _discrete: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_plant(cls, plant: models.Plant, tracked: str) -> TrackingModel:
        """Linearize `plant` at its standard equilibrium; `tracked` names the coordinate that follows r."""
        if tracked not in plant.coordinate_names:
            raise ValueError(
                f"{plant.name} has no coordinate {tracked!r}; coordinates are {', '.join(plant.coordinate_names)}"
            )
        if plant.nu != 1:
            raise ValueError(f"{plant.name}: the state-space blocks handle one input, got {plant.nu}")
        linear = plant.linearize()
        index = plant.coordinate_names.index(tracked)
        C_r = np.zeros((1, plant.nx))
        C_r[0, index] = 1.0
        N_x, N_u = reference_steady_state(linear.A, linear.B, C_r)
        G = plant.equilibrium_input_jacobian(linear.xe[: plant.nq])
        return cls(plant, linear, tracked, index, C_r, N_x, N_u, G)

    @property
    def name(self) -> str:
        """The known plant's name."""
        return self.plant.name

    @property
    def nx(self) -> int:
        """Number of states of the linearization."""
        return self.linear.nx

    @property
    def tracked_equilibrium(self) -> float:
        """y_r,e: the tracked coordinate at the operating point."""
        return float(self.linear.xe[self.tracked_state])

    def discrete(self, sample_period: float) -> models.LinearModel:
        """Exact ZOH discretization of `linear` at `sample_period` s (cached)."""
        key = float(sample_period)
        if key not in self._discrete:
            self._discrete[key] = self.linear.discretize(key)
        return self._discrete[key]

    def output_rows(self, outputs) -> list[int]:
        """Indices of the named outputs (all outputs when None)."""
        names = self.linear.output_names if outputs is None else tuple(outputs)
        return [self.linear.output_index(n) for n in names]

    def nonlinear_input(self, q) -> ca.SX:
        """u_nl(q) = u_e(q) − u_e − G (q − q_e), symbolic in the configuration q (nq,)."""
        nq = self.plant.nq
        q_tilde = q - self.linear.xe[:nq]
        ue = self.plant.casadi_equilibrium_input(q, self.plant.param_vector())
        return ue - self.linear.ue - ca.mtimes(ca.DM(self.static_input_jacobian), q_tilde)

    def tracked_from_outputs(self, y) -> ca.SX:
        """The tracked coordinate recovered from the plant's outputs y (symbolic)."""
        q = self.plant.casadi_configuration(y, self.plant.param_vector())
        return q[self.tracked_state]


def _row(value, size: int, what: str) -> np.ndarray:
    """`value` as a (1, size) float row; ValueError naming `what` for another size."""
    arr = np.asarray(value, dtype=float)
    if arr.size != size:
        raise ValueError(f"{what} must have {size} entries, got shape {arr.shape}")
    return arr.reshape(1, size)


def _scalar(value, what: str) -> np.ndarray:
    """`value` as a (1,) float array; ValueError naming `what` unless it is one number."""
    arr = np.asarray(value, dtype=float).ravel()
    if arr.size != 1:
        raise ValueError(f"{what} must be one number (one input), got shape {np.shape(value)}")
    return arr


class _TrackingBlock(models.Block):
    """Shared pieces: reference feedforward, integrator with anti-windup, saturation."""

    def _setup(self, model: TrackingModel, K, kr, ki, rate_limit):
        """Store the model, the actuator limit and the integrator's settings; return the gains dict (K, kr, ki)."""
        self.model = model
        self.limit = model.plant.input_limit.copy()
        self.has_integrator = ki is not None
        if rate_limit is not None and (not np.isfinite(rate_limit) or rate_limit <= 0):
            raise ValueError(f"rate_limit must be > 0 (units of the tracked coordinate per s), got {rate_limit}")
        if rate_limit is not None and not self.has_integrator:
            raise ValueError("rate_limit gates the integrator; give ki as well")
        self.rate_limit = rate_limit
        gains = {"K": _row(K, model.nx, f"{model.name}: K"), "kr": _scalar(kr, f"{model.name}: kr")}
        if self.has_integrator:
            gains["ki"] = _scalar(ki, f"{model.name}: ki")
        return gains

    def __repr__(self) -> str:
        fields = dict(self.gains) | {"Ts": self.sample_period, "limit": self.limit}
        if isinstance(self, ObserverFeedback):
            fields |= {"observer_gain": self.M, "measured": ", ".join(self.measured_outputs)}
        return numbers_repr(type(self).__name__, {"name": self.name} | fields)

    @property
    def n_integrator_states(self) -> int:
        """2 (the integral and the previous error) with an integrator, else 0."""
        return 2 if self.has_integrator else 0

    def _command(self, xc_int, x_tilde, y_r, r, gains, extra=0):
        """(integrator state next, u saturated, u_e + u_nl) from the state (estimate) x̃."""
        model = self.model
        r_tilde = r[0] - model.tracked_equilibrium
        u_static = model.linear.ue + model.nonlinear_input(
            x_tilde[: model.plant.nq] + model.linear.xe[: model.plant.nq]
        )
        u_lin = -ca.mtimes(gains["K"], x_tilde) + gains["kr"] * r_tilde - extra
        if not self.has_integrator:
            return ca.SX(0, 1), saturate(u_static + u_lin, self.limit), u_static
        integral, error_prev = xc_int[0], xc_int[1]
        error = r[0] - y_r
        integral_next = trapezoid(integral, error_prev, error, self.sample_period)
        if self.rate_limit is not None:
            rate = x_tilde[model.plant.nq + model.tracked_state]
            integral_next = integrate_while_slow(integral, integral_next, rate, self.rate_limit)
        u_unsat = u_static + u_lin + gains["ki"] * integral_next
        u_sat = saturate(u_unsat, self.limit)
        integral_next = back_calculation(integral_next, u_unsat, u_sat, gains["ki"], self.sample_period)
        return ca.vertcat(integral_next, error), u_sat, u_static

    def _integrator_initial(self, y_r0: float, r0) -> np.ndarray:
        """The integrator's initial state: no integral, the current error (empty without an integrator)."""
        if not self.has_integrator:
            return np.zeros(0)
        return np.array([0.0, float(np.ravel(r0)[0]) - y_r0])


class StateFeedback(_TrackingBlock):
    """u = sat(u_e + u_nl(q) − K x̃ + k_r r̃ [+ k_i x_I]) reading the full plant state.

    Parameters
    ----------
    model : TrackingModel of the known plant
    K : (nx,) state-feedback gain on x̃ = x − x_e
    kr : reference gain (k_r = N_u + K N_x for unit DC gain)
    ki : integrator gain, or None for no integrator; u contains + k_i ∫(r − y_r)
    sample_period : s
    rate_limit : optional, integrate only while |ẏ_r| < rate_limit (tracked units / s)

    State x_c: (x_I, e_prev) with an integrator, else empty.
    """

    def __init__(
        self,
        model: TrackingModel,
        K,
        kr,
        ki=None,
        *,
        sample_period: float,
        rate_limit: float | None = None,
        name: str = "state feedback",
    ):
        gains = self._setup(model, K, kr, ki, rate_limit)
        super().__init__(
            sample_period=sample_period,
            n_state=self.n_integrator_states,
            n_measured=model.nx,
            n_reference=1,
            n_input=1,
            gains=gains,
            measures="state",
            name=name,
        )

    def expr(self, xc, y, r, gains):
        """One sample: u from the measured state x̃ = y − x_e, the reference and the integrator."""
        x_tilde = y - self.model.linear.xe
        xc_next, u, _ = self._command(xc, x_tilde, y[self.model.tracked_state], r, gains)
        return xc_next, u

    def initial_state(self, y0, r0) -> np.ndarray:
        """The integrator's initial state at the measured tracked coordinate (empty without one)."""
        return self._integrator_initial(float(np.ravel(y0)[self.model.tracked_state]), r0)


class ObserverFeedback(_TrackingBlock):
    """State feedback on a discrete observer's estimate, reading the plant outputs.

    Parameters
    ----------
    model : TrackingModel of the known plant
    K, kr, ki, rate_limit : as `StateFeedback`
    observer_gain : (n_est, n_used) current-estimator gain M (see module docstring);
        n_est = nx, or nx + 1 with `disturbance_observer`
    sample_period : s; the observer runs on the ZOH model at this period
    measured_outputs : names of the outputs the observer uses (default all);
        a position measurement alone, for example
    disturbance_observer : estimate a constant input disturbance d and
        subtract d̂ from the command

    State x_c: (x̄ (nx), [d̄ (1)], [x_I, e_prev]); x̄ is the prior estimate of
    x̃ at the current sample (see `state_estimate`).

    Raises
    ------
    ValueError
        When the observer error dynamics A_d − A_d M C are not stable at Ts.
    """

    def __init__(
        self,
        model: TrackingModel,
        K,
        kr,
        observer_gain,
        ki=None,
        *,
        sample_period: float,
        measured_outputs=None,
        disturbance_observer: bool = False,
        rate_limit: float | None = None,
        name: str = "observer-based",
    ):
        gains = self._setup(model, K, kr, ki, rate_limit)
        self.rows = model.output_rows(measured_outputs)
        self.measured_outputs = tuple(model.linear.output_names[i] for i in self.rows)
        self.disturbance_observer = bool(disturbance_observer)
        disc = model.discrete(sample_period)
        nx, nd = model.nx, int(self.disturbance_observer)
        self.n_estimate = nx + nd
        if nd:
            A_o, B_o, C_o = augment_disturbance(disc.A, disc.B, disc.C[self.rows], discrete=True)
        else:
            A_o, B_o, C_o = disc.A, disc.B, disc.C[self.rows]
        M = np.asarray(observer_gain, dtype=float).reshape(nx + nd, len(self.rows))
        error_poles = np.linalg.eigvals(A_o - A_o @ M @ C_o)
        if np.any(np.abs(error_poles) >= 1):
            raise ValueError(
                f"{model.name}: the observer error dynamics are unstable at Ts = "
                f"{sample_period} s (|z| up to {np.max(np.abs(error_poles)):.4g})"
            )
        self.A_o, self.B_o, self.C_o, self.M = A_o, B_o, C_o, M
        self.error_poles = error_poles
        super().__init__(
            sample_period=sample_period,
            n_state=self.n_estimate + self.n_integrator_states,
            n_measured=model.linear.ny,
            n_reference=1,
            n_input=1,
            gains=gains,
            measures="outputs",
            name=name,
        )

    def expr(self, xc, y, r, gains):
        """One sample: the current estimate from the outputs, u from it (minus d̂), then the prediction."""
        model, n = self.model, self.n_estimate
        prior = xc[:n]
        y_tilde = y[self.rows] - model.linear.ye[self.rows]
        estimate = prior + ca.mtimes(ca.DM(self.M), y_tilde - ca.mtimes(ca.DM(self.C_o), prior))
        x_hat = estimate[: model.nx]
        d_hat = estimate[model.nx] if self.disturbance_observer else 0
        y_r = model.tracked_from_outputs(y) if self.has_integrator else 0
        int_next, u, u_static = self._command(xc[n:], x_hat, y_r, r, gains, extra=d_hat)
        prior_next = ca.mtimes(ca.DM(self.A_o), estimate) + ca.mtimes(ca.DM(self.B_o), u - u_static)
        return ca.vertcat(prior_next, int_next), u

    def initial_state(self, y0, r0) -> np.ndarray:
        """Configuration from the first measurement, velocities and disturbance zero."""
        model = self.model
        q0 = np.asarray(model.plant.casadi_configuration(y0, model.plant.param_vector())).ravel()
        prior = np.zeros(self.n_estimate)
        prior[: model.plant.nq] = q0 - model.linear.xe[: model.plant.nq]
        return np.concatenate([prior, self._integrator_initial(float(q0[model.tracked_state]), r0)])

    def state_estimate(self, xc) -> np.ndarray:
        """Absolute state estimates x_e + x̄ from controller states xc (N, n_state) -> (N, nx)."""
        xc = np.atleast_2d(xc)
        return xc[:, : self.model.nx] + self.model.linear.xe

    def disturbance_estimate(self, xc) -> np.ndarray:
        """d̄ over time from controller states xc (N, n_state) -> (N,)."""
        if not self.disturbance_observer:
            raise ValueError(f"{self.name} has no disturbance observer")
        return np.atleast_2d(xc)[:, self.model.nx]

    def error_pole_mismatch(self, poles_z) -> float:
        """Largest distance between the observer's error poles (z-plane) and `poles_z`."""
        return pole_mismatch(self.error_poles, poles_z)
