"""The case studies' state-space homework (.15–.17, IV.14–15, V.14–15, VI.14–15) and LQR.

`design(name, known)` makes every state-space design of one plant from the
linearization of the known plant and returns a `StateSpaceDesign` record;
`answers` lists its numbers by homework item; `controllers` builds the
blocks. Nothing here types a matrix: A, B, C come from
`Plant.linearize()`.

Poles the text leaves open are chosen by the rules below, each a named
default argument of the plant's pole function:

- arm (I.15(c)): the I.8 design. k_p makes the linearized torque just
  saturate on the 50° step, k_p = (τ_max − m g ℓ / 2) / A_θ; ωₙ = √(k_p / J)
  (J from the model's B); ζ = 0.707. Then K = (k_p, k_d) exactly (I.15(f)).
- pendulum (II.15(c)) and satellite (III.15(c)): the .8 successive-loop
  rule. The inner loop's ωₙ makes the input just saturate when its
  reference steps by A_θ (the text names A_θ without a value: 10° for the
  pendulum, which keeps the pendulum in its linear range; 30° for the
  satellite body, the size of the panel step A_φ); the outer loop is
  M = 5 times slower (bandwidth separation); ζ = 0.707 in both.
- uuv (IV.14(b)): t_r = 1 s (10–90 %) and 5 % overshoot give ζ = 0.690,
  ωₙ = 2.096 rad/s exactly (`second_order_from_specs`).
- ballbeam (V.14(c)) and crane1 (VI.14(c)): the text's poles.
- crane, two loads: VI.14's poles plus a pair −0.35 ± 0.5j for the second
  load's swing (open loop 0.665 rad/s; ζ = 0.57 like VI.14's pair). The
  state-space method designs on the full 6-state model directly, with the
  three outputs of VI.7 measured.
- Integrator (.16): pole at −min|pᵢ| of the state-feedback poles (the
  slowest mode's natural frequency); crane and crane1 −0.5 rad/s, because
  −0.6 is already a placed pole. The reference enters through the
  integrator only (k_r = 0), as in the text's augmented design: with the
  feedforward k_r on top the integrator designs overshoot 25–40 %
  (measured on arm, UUV, ball on beam).
- Observers (.17(c), IV.15, V.15, VI.15): 5 times the state-feedback poles,
  3 times for crane1: measuring the cart position only (VI.15), 5 times puts
  a pair of eig(A − B K − L C) at +0.19 ± 12j, which VI.15(c) forbids; 2–4
  times keeps them in the left half plane. V.15 and VI.15 measure the
  position only (z, x), as the text says; the others use every output.
- Disturbance observer (.17(e)): the observer's poles plus a real pole at
  half the slowest observer pole's magnitude for d̂. Its compensator always
  has a pole at s = 0 (d̂ integrates the output error: the integral action
  that removes steady-state error) besides eig(A − B K − L_x C).
- LQR: Bryson's rule from the maxima in `BRYSON_MAXIMA`, with the
  integrator state (limit: the design step held for `INTEGRAL_HORIZON`,
  0.25 s; 1 s for the crane, whose 10 m move then overshoots 8 % instead of
  14 % and settles in 14 s (crane1) and 21 s (crane)) and the input's room
  above the equilibrium input. The "LQR" blocks run this continuous gain;
  the record also keeps `dlqr` of the ZOH model (integrator by forward
  Euler, weights Q Ts and R Ts) for comparison. The steady-state Kalman
  filter assumes measurement noise `MEASUREMENT_NOISE` (σ_y = 1 mm or
  1 mrad per sample) and white generalized acceleration noise on every
  coordinate with σ_a = σ_y ω_K², ω_K = 5 max|pᵢ|: a measured coordinate
  then behaves as a double integrator whose filter has bandwidth ω_K. (An
  input-noise-only model drives the crane's swing estimate to the
  lightly damped zeros of x/F, −0.0005 ± 0.99j.) The Kalman filter reads
  every output of the plant (V.7's and VI.7's y), not V.15's and VI.15's
  position alone: from z alone the beam-angle estimate cannot be faster
  than −2.2 ± 2.2j, slower than the LQR's own poles, and the ball on beam
  then leaves the beam under the 1.5 N disturbance.

Sampling: the gains K, k_r, k_i are continuous designs run at Ts = 0.01 s
(the homework's numbers, e.g. I.15(f)'s K = (k_p, k_d)). This is acceptable
because |p| Ts ≤ 0.08 for every state-feedback and LQR pole here: the
record keeps the sampled-data poles eig(A_d − B_d K), `design` raises if
any leaves the unit circle, and they lie within 0.011 of exp(p Ts). Read
back in the s-plane, the ball on beam's −6 ± 1.5j moves to −6.75 ± 0.71j
and −4.5 ± 4.5j to −4.46 ± 4.21j (its unstable plant makes the half-sample
delay of the hold count most); every other plant's poles move by less
than 3.2 % of their magnitude. Observers are designed in discrete time on
the exact ZOH model (poles exp(p Ts)), since 5 times faster poles would
not tolerate forward Euler at 0.01 s; the continuous L of the homework is
reported too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

import models
from designs import statespace as ss
from designs.statespace_blocks import ObserverFeedback, StateFeedback, TrackingModel

__all__ = ["StateSpaceDesign", "design", "answers", "controllers", "nominal_poles", "default_integrator_pole",
           "kalman_noise", "BRYSON_MAXIMA", "LABELS"]

#: Controller labels of `controllers`, the same for every plant.
LABELS = ("pole placement", "pole placement + integrator", "observer-based", "disturbance observer",
          "LQR", "LQR + Kalman")

DAMPING = 0.707
BANDWIDTH_SEPARATION = 5.0
OBSERVER_SPEEDUP = {"crane1": 3.0}  # others: DEFAULT_OBSERVER_SPEEDUP
DEFAULT_OBSERVER_SPEEDUP = 5.0
#: Bryson maximum of the integrator state = design step × this horizon (s); crane: slower.
INTEGRAL_HORIZON = {"crane": 1.0, "crane1": 1.0}
DEFAULT_INTEGRAL_HORIZON = 0.25
MEASUREMENT_NOISE = 1e-3  # m or rad, standard deviation per sample

#: Bryson's rule maxima per state (SI; np.inf leaves a velocity unweighted).
BRYSON_MAXIMA = {
    "arm": {"theta": np.deg2rad(50)},
    "pendulum": {"z": 2.0, "theta": np.deg2rad(10)},
    "satellite": {"theta": np.deg2rad(30), "phi": np.deg2rad(30)},
    "uuv": {"phi": np.deg2rad(30)},
    "ballbeam": {"z": 0.25, "theta": np.deg2rad(10)},
    "crane": {"x": 10.0, "theta1": np.deg2rad(10), "theta2": np.deg2rad(10)},
    "crane1": {"x": 10.0, "theta": np.deg2rad(10)},
}

#: Outputs the observer reads where the text restricts them (V.15, VI.15).
OBSERVER_OUTPUTS = {"ballbeam": ("z",), "crane1": ("x",)}

#: The text's integrator items (.16/.17); IV–VI have none, so their observer design has no integrator.
OBSERVER_HAS_INTEGRATOR = {"arm": True, "pendulum": True, "satellite": True}

VI14_POLES = (-0.6, -1.5, -0.55 + 0.75j, -0.55 - 0.75j)
V14_POLES = (-4.5 + 4.5j, -4.5 - 4.5j, -6 + 1.5j, -6 - 1.5j)
SECOND_LOAD_POLES = (-0.35 + 0.5j, -0.35 - 0.5j)


# --------------------------------------------------------------- pole rules
def arm_poles(linear: models.LinearModel, input_limit: float, *, step: float | None = None,
              damping_ratio: float = DAMPING) -> np.ndarray:
    """I.8 / I.15(c): ωₙ from k_p = (τ_max − τ_e,max) / A_θ with A_θ the 50° step."""
    step = models.case("arm").design_step if step is None else step
    kp = (input_limit - abs(linear.ue[0])) / step
    if kp <= 0:
        raise ValueError(f"arm: the equilibrium torque {linear.ue[0]:.3g} N m leaves no room under "
                         f"the limit {input_limit} N m")
    return ss.second_order_poles(np.sqrt(linear.B[1, 0] * kp), damping_ratio)


def _inner_outer(linear, inner_row: int, inner_state: int, input_room: float, angle_step: float,
                 damping_ratio: float, separation: float, what: str) -> np.ndarray:
    """.8 rule: inner ωₙ² = |b| u_max / A − a from q̈ = a q + b u; outer ωₙ = inner / M."""
    a, b = linear.A[inner_row, inner_state], linear.B[inner_row, 0]
    wn_sq = abs(b) * input_room / angle_step - a
    if wn_sq <= 0:
        raise ValueError(f"{what}: a step of {angle_step:.3g} rad saturating the input cannot "
                         f"stabilize the inner loop (ωₙ² = {wn_sq:.3g}); choose a smaller angle step")
    wn = np.sqrt(wn_sq)
    return np.concatenate([ss.second_order_poles(wn, damping_ratio),
                           ss.second_order_poles(wn / separation, damping_ratio)])


def pendulum_poles(linear: models.LinearModel, input_limit: float, *, angle_step: float = np.deg2rad(10),
                   damping_ratio: float = DAMPING, separation: float = BANDWIDTH_SEPARATION) -> np.ndarray:
    """II.8 / II.15(c): θ̈ = a θ + b F ⇒ ω_θ² = |b| F_max / A_θ − a; ω_z = ω_θ / M."""
    return _inner_outer(linear, 3, 1, input_limit, angle_step, damping_ratio, separation, "pendulum")


def satellite_poles(linear: models.LinearModel, input_limit: float, *, angle_step: float = np.deg2rad(30),
                    damping_ratio: float = DAMPING, separation: float = BANDWIDTH_SEPARATION) -> np.ndarray:
    """III.8 / III.15(c): J_s θ̈ = τ − k θ + … ⇒ ω_θ² = (k + τ_max / A_θ) / J_s; ω_φ = ω_θ / M."""
    return _inner_outer(linear, 2, 0, input_limit, angle_step, damping_ratio, separation, "satellite")


def uuv_poles(linear: models.LinearModel, input_limit: float, *, rise_time: float = 1.0,
              overshoot: float = 0.05) -> np.ndarray:
    """IV.14(b): the second-order poles with exactly this 10–90 % rise time and overshoot."""
    return ss.second_order_poles(*ss.second_order_from_specs(rise_time, overshoot))


def nominal_poles(name: str, known: models.Plant | None = None) -> np.ndarray:
    """The state-feedback poles of plant `name` by the rules of the module docstring (rad/s)."""
    known = models.get(name) if known is None else known
    linear, limit = known.linearize(), float(known.input_limit[0])
    rules = {"arm": arm_poles, "pendulum": pendulum_poles, "satellite": satellite_poles, "uuv": uuv_poles}
    if name in rules:
        return np.asarray(rules[name](linear, limit), dtype=complex)
    fixed = {"ballbeam": V14_POLES, "crane1": VI14_POLES, "crane": VI14_POLES + SECOND_LOAD_POLES}
    if name not in fixed:
        raise ValueError(f"no state-space design for {name!r}; valid: {', '.join(models.names())}")
    return np.asarray(fixed[name], dtype=complex)


def default_integrator_pole(name: str, poles) -> float:
    """The .16 integrator pole: −min|pᵢ|, or −0.5 rad/s for the crane (−0.6 is already placed)."""
    if name in ("crane", "crane1"):
        return -0.5
    return -float(np.min(np.abs(poles)))


# ------------------------------------------------------------------ record
@dataclass(frozen=True)
class StateSpaceDesign:
    """Every state-space design of one plant, from the known plant's linearization.

    Gains follow u = u_e + u_nl(q) − K x̃ + k_r r̃ + k_i x_I − d̂ (see
    `designs.statespace_blocks`), SI units; poles in rad/s, or in the z-plane
    for fields ending in ``_z``.

    Attributes
    ----------
    model : TrackingModel (known plant, linearization, tracked coordinate)
    sample_period, observer_sample_period : s
    controllability_rank, observability_rank : int (= nx); the latter for `observer_outputs`
    poles, K (1, nx), kr : .15 state feedback with reference gain
    poles_sampled_z : eig(A_d − B_d K) of K held over `sample_period`
    integrator_pole, K_integral (1, nx), ki : .16, reference through the integrator only
    observer_outputs : outputs the observers read (n_used of them)
    observer_uses_integrator : the observer-based design is .17 (K_integral, ki) or IV–VI.15 (K, kr)
    observer_poles, L (nx, n_used) : continuous observer; L_discrete, observer_poles_z its
        ZOH predictor gain and poles at `observer_sample_period`
    controller_poles : eig(A − B K − L C), the compensator's own poles (.17(c))
    disturbance_observer_poles (nx + 1), L_disturbance (nx + 1, n_used), their discrete
        counterparts at `sample_period`, disturbance_controller_poles
    Q, R, K_lqr (1, nx), ki_lqr, P_lqr, lqr_poles : integrator-augmented LQR
    K_lqr_plain, kr_lqr_plain : LQR on the states only, with its reference gain
    K_dlqr (1, nx + 1), dlqr_poles_z : discrete LQR of the ZOH model at `sample_period`
    kalman_W, kalman_V, L_kalman (nx, ny), kalman_poles_z : steady-state Kalman predictor
        reading every output
    """

    plant: str
    model: TrackingModel
    sample_period: float
    observer_sample_period: float
    controllability_rank: int
    observability_rank: int
    # .15: state feedback with reference gain
    poles: np.ndarray
    K: np.ndarray
    kr: float
    poles_sampled_z: np.ndarray
    # .16: integrator
    integrator_pole: float
    K_integral: np.ndarray
    ki: float
    # .17(c): observer
    observer_outputs: tuple
    observer_uses_integrator: bool
    observer_poles: np.ndarray
    L: np.ndarray
    observer_poles_z: np.ndarray
    L_discrete: np.ndarray
    controller_poles: np.ndarray
    # .17(e): disturbance observer
    disturbance_observer_poles: np.ndarray
    L_disturbance: np.ndarray
    disturbance_observer_poles_z: np.ndarray
    L_disturbance_discrete: np.ndarray
    disturbance_controller_poles: np.ndarray
    # LQR (integrator-augmented; _plain: states only, with k_r) and Kalman filter
    Q: np.ndarray
    R: np.ndarray
    K_lqr: np.ndarray
    ki_lqr: float
    P_lqr: np.ndarray
    lqr_poles: np.ndarray
    K_lqr_plain: np.ndarray
    kr_lqr_plain: float
    K_dlqr: np.ndarray
    dlqr_poles_z: np.ndarray
    kalman_W: np.ndarray
    kalman_V: np.ndarray
    L_kalman: np.ndarray
    kalman_poles_z: np.ndarray

    @property
    def observer_rows(self) -> list[int]:
        return self.model.output_rows(self.observer_outputs)


def _used_C(model: TrackingModel, outputs) -> np.ndarray:
    return model.linear.C[model.output_rows(outputs)]


def _sampled_poles(model: TrackingModel, K, Ts, what) -> np.ndarray:
    disc = model.discrete(Ts)
    z = np.linalg.eigvals(disc.A - disc.B @ np.atleast_2d(K))
    if np.any(np.abs(z) >= 1):
        raise ValueError(f"{what}: the continuous gain is unstable when sampled at Ts = {Ts} s "
                         f"(|z| up to {np.max(np.abs(z)):.4g}); slow the poles or sample faster")
    return z


def _discrete_observer(model, outputs, poles, Ts, disturbance: bool, what):
    """(predictor L_d on the ZOH model, its z-poles) for the observer with these continuous poles."""
    disc = model.discrete(Ts)
    C = _used_C(model, outputs)
    A, B = disc.A, disc.B
    if disturbance:
        A = np.block([[A, B], [np.zeros((1, model.nx)), np.eye(1)]])
        C = np.hstack([C, np.zeros((C.shape[0], 1))])
    poles_z = np.exp(np.asarray(poles, dtype=complex) * Ts)
    return ss.discrete_observer_gain(A, C, poles_z, what), poles_z


def design(name: str, known: models.Plant | None = None, *, poles=None, integrator_pole: float | None = None,
           observer_poles=None, disturbance_pole: float | None = None, Q=None, R=None) -> StateSpaceDesign:
    """All state-space designs of plant `name` made on `known` (default: the nominal plant).

    Parameters
    ----------
    name : plant name (`models.names()`)
    known : the plant the controller believes in (e.g. ``models.perturbed(plant, 0.05)``)
    poles : nx state-feedback poles (rad/s); default `nominal_poles`
    integrator_pole : rad/s; default `default_integrator_pole`
    observer_poles : nx observer poles; default the speed-up rule times `poles`
    disturbance_pole : pole of the disturbance estimate; default half the slowest observer pole
    Q, R : LQR weights of the integrator-augmented state (nx + 1) and input;
        default Bryson's rule (`BRYSON_MAXIMA`)

    Raises
    ------
    ValueError
        For an unknown plant, or a design check that fails (controllability,
        observability, pole requests, weights, stability when sampled).
    """
    plant = models.get(name)
    known = plant if known is None else known
    if known.name != name:
        raise ValueError(f"known plant {known.name!r} does not match {name!r}")
    case = models.case(name)
    model = TrackingModel.from_plant(known)
    lin = model.linear
    A, B, nx = lin.A, lin.B, lin.nx
    Ts, Ts_obs = case.sample_period, case.observer_sample_period
    outputs = OBSERVER_OUTPUTS.get(name, lin.output_names)
    C_used = _used_C(model, outputs)
    rank_c = ss.require_controllable(A, B, name)
    rank_o = ss.require_observable(A, C_used, f"{name} measuring {', '.join(outputs)}")

    poles = nominal_poles(name, known) if poles is None else np.asarray(poles, dtype=complex)
    K = ss.place(A, B, poles, name)
    kr = float(ss.reference_gain(A, B, K, model.C_r)[0])
    sampled = _sampled_poles(model, K, Ts, name)

    p_int = default_integrator_pole(name, poles) if integrator_pole is None else float(integrator_pole)
    A_I, B_I = ss.augment_integrator(A, B, model.C_r)
    K_int, ki = ss.split_integral_gain(ss.place(A_I, B_I, np.append(poles, p_int), name), nx)
    _sampled_poles(model, K_int, Ts, f"{name} (state feedback part of the integrator design)")

    uses_integrator = OBSERVER_HAS_INTEGRATOR.get(name, False)
    obs_poles = (OBSERVER_SPEEDUP.get(name, DEFAULT_OBSERVER_SPEEDUP) * poles if observer_poles is None
                 else np.asarray(observer_poles, dtype=complex))
    L = ss.observer_gain(A, C_used, obs_poles, name)
    L_d, obs_z = _discrete_observer(model, outputs, obs_poles, Ts_obs, False, name)
    K_obs = K_int if uses_integrator else K
    controller_poles = np.linalg.eigvals(A - B @ K_obs - L @ C_used)

    p_dist = -0.5 * np.min(np.abs(obs_poles)) if disturbance_pole is None else float(disturbance_pole)
    dob_poles = np.append(obs_poles, p_dist)
    A_d, B_d, C_d = ss.augment_disturbance(A, B, C_used)
    L_dob = ss.observer_gain(A_d, C_d, dob_poles, f"{name} with a disturbance state")
    L_dob_d, dob_z = _discrete_observer(model, outputs, dob_poles, Ts, True, name)
    # u = −K x̂ + k_r r − d̂ cancels d̂ in the model: x̂' = (A − B K − L_x C) x̂ + …, d̂' = L_d (y − C x̂).
    dob_controller = np.linalg.eigvals(np.block([[A - B @ K, np.zeros((nx, 1))], [np.zeros((1, nx + 1))]])
                                       - L_dob @ C_d)

    Q_default, R_default = _bryson(name, known, model, case)
    Q = Q_default if Q is None else np.asarray(Q, dtype=float)
    R = R_default if R is None else np.atleast_2d(np.asarray(R, dtype=float))
    K_aug, P = ss.lqr(A_I, B_I, Q, R, f"{name} (integrator-augmented)")
    K_lqr, ki_lqr = ss.split_integral_gain(K_aug, nx)
    lqr_poles = np.linalg.eigvals(A_I - B_I @ K_aug)
    _sampled_poles(model, K_lqr, Ts, f"{name} LQR")
    K_lqr_plain, _ = ss.lqr(A, B, Q[:nx, :nx], R, name)
    kr_lqr_plain = float(ss.reference_gain(A, B, K_lqr_plain, model.C_r)[0])
    disc = model.discrete(Ts)
    A_Id = np.block([[disc.A, np.zeros((nx, 1))], [-Ts * model.C_r, np.eye(1)]])
    B_Id = np.vstack([disc.B, np.zeros((1, 1))])
    K_dlqr, _ = ss.dlqr(A_Id, B_Id, Q * Ts, R * Ts, name)
    dlqr_z = np.linalg.eigvals(A_Id - B_Id @ K_dlqr)

    W, V = kalman_noise(model, Ts, lin.ny, DEFAULT_OBSERVER_SPEEDUP * np.max(np.abs(poles)))
    L_kf, _ = ss.dkalman(disc.A, lin.C, W, V, name)
    kalman_z = np.linalg.eigvals(disc.A - L_kf @ lin.C)

    return StateSpaceDesign(
        plant=name, model=model, sample_period=Ts, observer_sample_period=Ts_obs,
        controllability_rank=rank_c, observability_rank=rank_o,
        poles=poles, K=K, kr=kr, poles_sampled_z=sampled,
        integrator_pole=p_int, K_integral=K_int, ki=float(ki[0]),
        observer_outputs=tuple(outputs), observer_uses_integrator=uses_integrator,
        observer_poles=obs_poles, L=L, observer_poles_z=obs_z, L_discrete=L_d,
        controller_poles=controller_poles,
        disturbance_observer_poles=dob_poles, L_disturbance=L_dob, disturbance_observer_poles_z=dob_z,
        L_disturbance_discrete=L_dob_d, disturbance_controller_poles=dob_controller,
        Q=Q, R=R, K_lqr=K_lqr, ki_lqr=float(ki_lqr[0]), P_lqr=P, lqr_poles=lqr_poles,
        K_lqr_plain=K_lqr_plain, kr_lqr_plain=kr_lqr_plain,
        K_dlqr=K_dlqr, dlqr_poles_z=dlqr_z, kalman_W=W, kalman_V=V, L_kalman=L_kf,
        kalman_poles_z=kalman_z,
    )


def kalman_noise(model: TrackingModel, sample_period: float, n_outputs: int,
                 bandwidth: float) -> tuple[np.ndarray, np.ndarray]:
    """Covariances (W (nx, nx), V (ny, ny)) of the Kalman filter's noise model per sample.

    Measurement noise σ_y = `MEASUREMENT_NOISE` on each output; generalized
    acceleration noise σ_a = σ_y · bandwidth² (rad/s) on every coordinate,
    held over each sample (its ZOH input matrix G_a gives W = σ_a² G_a G_aᵀ).
    """
    nq, nx = model.plant.nq, model.nx
    acceleration = np.vstack([np.zeros((nq, nq)), np.eye(nq)])
    block = np.zeros((nx + nq, nx + nq))
    block[:nx, :nx] = model.linear.A
    block[:nx, nx:] = acceleration
    G_a = scipy.linalg.expm(block * sample_period)[:nx, nx:]
    sigma_a = MEASUREMENT_NOISE * bandwidth**2
    return sigma_a**2 * G_a @ G_a.T, MEASUREMENT_NOISE**2 * np.eye(n_outputs)


def _bryson(name, known, model, case) -> tuple[np.ndarray, np.ndarray]:
    maxima = BRYSON_MAXIMA[name]
    state_max = [maxima.get(s, np.inf) for s in known.state_names]
    state_max.append(case.design_step * INTEGRAL_HORIZON.get(name, DEFAULT_INTEGRAL_HORIZON))
    room = float(known.input_limit[0] - abs(model.linear.ue[0]))
    return ss.bryson_weights(state_max, [room])


# ----------------------------------------------------------------- outputs
def _plain(value):
    """numpy -> floats, complex and nested lists for the studies' writer."""
    arr = np.asarray(value)
    if np.iscomplexobj(arr) and np.all(arr.imag == 0):
        arr = arr.real
    return arr.item() if arr.ndim == 0 else arr.tolist()


def _rule_values(name: str, known: models.Plant) -> dict:
    """The numbers behind the pole choice (ωₙ, ζ per loop), for the .15(c) / IV.14(b) entries."""
    poles = nominal_poles(name, known)
    pairs = poles[poles.imag > 0]
    out = {"natural_frequencies": _plain(np.abs(pairs)), "damping_ratios": _plain(-pairs.real / np.abs(pairs))}
    if name == "uuv":
        out |= {"rise_time": 1.0, "overshoot": 0.05}
    return out


def answers(name: str, known: models.Plant | None = None, **overrides) -> dict:
    """Homework item -> dict of named values (SI units, rad/s; lists; complex allowed).

    Items: I–III .15(c), .15(e), .15(f), .16, .17(b), .17(c), .17(e);
    IV.14(b)–(f) and IV.15; V.14(b)–(c) and V.15; VI.14(b)–(e) and VI.15 (on
    crane1's single-load model, or on the full two-load crane for
    ``name="crane"``); plus "LQR" for every plant, and "integrator" and
    "disturbance observer" for IV–VI, where the text has no such item.
    `overrides` go to `design` (poles, integrator_pole, observer_poles,
    disturbance_pole, Q, R).
    """
    d = design(name, known, **overrides)
    N = models.case(name).numeral
    A, B = d.model.linear.A, d.model.linear.B
    A_I, B_I = ss.augment_integrator(A, B, d.model.C_r)
    feedback = {"K": _plain(d.K), "kr": d.kr, "poles": _plain(np.linalg.eigvals(A - B @ d.K)),
                "poles_sampled_z": _plain(d.poles_sampled_z), "sample_period": d.sample_period}
    integrator = {"K": _plain(d.K_integral), "ki": d.ki, "kr": 0.0, "integrator_pole": d.integrator_pole,
                  "poles": _plain(np.linalg.eigvals(A_I - B_I @ np.hstack([d.K_integral, [[-d.ki]]])))}
    controllable = {"controllability_rank": d.controllability_rank, "n_states": d.model.nx}
    observable = {"observability_rank": d.observability_rank, "n_states": d.model.nx,
                  "measured_outputs": list(d.observer_outputs)}
    observer = {"L": _plain(d.L), "observer_poles": _plain(d.observer_poles),
                "controller_poles": _plain(d.controller_poles), "L_discrete": _plain(d.L_discrete),
                "observer_poles_z": _plain(d.observer_poles_z), "sample_period": d.observer_sample_period,
                "measured_outputs": list(d.observer_outputs), "with_integrator": d.observer_uses_integrator}
    if not d.observer_uses_integrator:
        observer["kr"] = d.kr
    dob = {"L": _plain(d.L_disturbance), "observer_poles": _plain(d.disturbance_observer_poles),
           "controller_poles": _plain(d.disturbance_controller_poles),
           "L_discrete": _plain(d.L_disturbance_discrete),
           "observer_poles_z": _plain(d.disturbance_observer_poles_z), "sample_period": d.sample_period,
           "K": _plain(d.K), "kr": d.kr, "input_disturbance": models.case(name).input_disturbance}
    lqr = {"K": _plain(d.K_lqr), "ki": d.ki_lqr, "Q": _plain(d.Q), "R": _plain(d.R),
           "poles": _plain(d.lqr_poles), "K_without_integrator": _plain(d.K_lqr_plain),
           "kr_without_integrator": d.kr_lqr_plain, "K_discrete": _plain(d.K_dlqr),
           "poles_discrete_z": _plain(d.dlqr_poles_z),
           "kalman_L": _plain(d.L_kalman), "kalman_poles_z": _plain(d.kalman_poles_z),
           "kalman_W": _plain(d.kalman_W), "kalman_V": _plain(d.kalman_V)}
    rule = _rule_values(name, d.model.plant) | {"poles": _plain(d.poles)}
    if N in ("I", "II", "III"):
        return {f"{N}.15(c)": rule, f"{N}.15(e)": controllable, f"{N}.15(f)": feedback,
                f"{N}.16": integrator, f"{N}.17(b)": observable, f"{N}.17(c)": observer,
                f"{N}.17(e)": dob, "LQR": lqr}
    extra = {"integrator": integrator, "disturbance observer": dob, "LQR": lqr}
    if N == "IV":
        return {"IV.14(b)": rule, "IV.14(c)": controllable, "IV.14(d)": feedback,
                "IV.14(f)": {"kr": d.kr}, "IV.15(b)": observable, "IV.15(c)": observer} | extra
    if N == "V":
        return {"V.14(b)": controllable, "V.14(c)": feedback, "V.15(b)": observable,
                "V.15(c)": observer} | extra
    model = {"model": f"{name}: {d.model.nx} states ({', '.join(d.model.plant.state_names)})"}
    return {"VI.14(b)": controllable | model, "VI.14(c)": feedback | model, "VI.14(e)": {"kr": d.kr},
            "VI.15(b)": observable, "VI.15(c)": observer} | extra


def controllers(name: str, known: models.Plant | None = None, **overrides) -> dict:
    """Label -> `models.Block` designed on `known` (default nominal); labels in `LABELS`.

    Every block takes the absolute tracked coordinate as its reference and
    saturates its total command at the known plant's limit. Sample period:
    the case's (0.01 s); "observer-based" runs at the observer problem's
    (0.001 s for V.15 and VI.15). `overrides` go to `design`.
    """
    d = design(name, known, **overrides)
    model, Ts = d.model, d.sample_period

    def current(L_predictor, Ts_, disturbance):
        disc = model.discrete(Ts_)
        A = disc.A
        if disturbance:
            A = np.block([[A, disc.B], [np.zeros((1, model.nx)), np.eye(1)]])
        return ss.current_estimator_gain(A, L_predictor)

    K_obs = d.K_integral if d.observer_uses_integrator else d.K
    kr_obs = 0.0 if d.observer_uses_integrator else d.kr
    ki_obs = d.ki if d.observer_uses_integrator else None
    outputs = d.observer_outputs
    return {
        "pole placement": StateFeedback(model, d.K, d.kr, sample_period=Ts, name="pole placement"),
        "pole placement + integrator": StateFeedback(model, d.K_integral, 0.0, d.ki, sample_period=Ts,
                                                     name="pole placement + integrator"),
        "observer-based": ObserverFeedback(model, K_obs, kr_obs, current(d.L_discrete, d.observer_sample_period, False),
                                           ki_obs, sample_period=d.observer_sample_period,
                                           measured_outputs=outputs, name="observer-based"),
        "disturbance observer": ObserverFeedback(model, d.K, d.kr, current(d.L_disturbance_discrete, Ts, True),
                                                 sample_period=Ts, measured_outputs=outputs,
                                                 disturbance_observer=True, name="disturbance observer"),
        "LQR": StateFeedback(model, d.K_lqr, 0.0, d.ki_lqr, sample_period=Ts, name="LQR"),
        "LQR + Kalman": ObserverFeedback(model, d.K_lqr, 0.0, current(d.L_kalman, Ts, False), d.ki_lqr,
                                         sample_period=Ts, name="LQR + Kalman"),
    }
