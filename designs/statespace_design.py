"""Every state-space design of one plant from its linearization: the .15–.17 family and LQR.

`design(known, tracked, poles=..., Q=..., R=..., ...)` places the state
feedback, the integrator, the observers and the disturbance observer, solves
the integrator-augmented LQR and the steady-state Kalman filter, and returns
a `StateSpaceDesign` record; `controllers(design)` builds the blocks that run
those gains on the nonlinear plant (`designs.statespace_blocks`). Nothing
here types a matrix: A, B, C come from `Plant.linearize()`; every choice (poles,
observer speed, outputs read, weights, sample periods) is an argument.

Sampling: the gains K, k_r, k_i are continuous designs run at the sample
period; the record keeps the sampled-data poles eig(A_d − B_d K) and
`design` raises if any leaves the unit circle. Observers are designed in
discrete time on the exact ZOH model (poles exp(p Ts)), since fast observer
poles would not tolerate forward Euler; the continuous L is reported too.
The LQR blocks run the continuous gain; the record also keeps `dlqr` of the
ZOH model (integrator by forward Euler, weights Q Ts and R Ts).

The steady-state Kalman filter assumes measurement noise σ_y on every output
and white generalized acceleration noise on every coordinate with
σ_a = σ_y ω_K², ω_K the filter's bandwidth: a measured coordinate then
behaves as a double integrator whose filter has bandwidth ω_K.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import models
from designs import statespace as ss
from designs.statespace_blocks import ObserverFeedback, StateFeedback, TrackingModel
from models import deferred

scipy = deferred.module("scipy")

__all__ = [
    "StateSpaceDesign",
    "design",
    "feedback_design",
    "integrator_design",
    "observer_design",
    "disturbance_observer_design",
    "lqr_design",
    "kalman_design",
    "controllers",
    "kalman_noise",
    "LABELS",
    "MEASUREMENT_NOISE",
]

#: Controller labels of `controllers`.
LABELS = (
    "pole placement",
    "pole placement + integrator",
    "observer-based",
    "disturbance observer",
    "LQR",
    "LQR + Kalman",
)

#: Measurement noise of the Kalman filter's model, m or rad, standard deviation per sample.
MEASUREMENT_NOISE = 1e-3


@dataclass(frozen=True)
class StateSpaceDesign:
    """Every state-space design of one plant, from the known plant's linearization.

    Gains follow u = u_e + u_nl(q) − K x̃ + k_r r̃ + k_i x_I − d̂ (see
    `designs.statespace_blocks`), SI units; poles in rad/s, or in the z-plane
    for fields ending in ``_z``.

    Attributes
    ----------
    plant : name of the known plant
    model : TrackingModel (known plant, linearization, tracked coordinate)
    sample_period, observer_sample_period : s
    controllability_rank, observability_rank : int (= nx); the latter for `observer_outputs`
    poles, K (1, nx), kr : state feedback with reference gain
    poles_sampled_z : eig(A_d − B_d K) of K held over `sample_period`
    integrator_pole, K_integral (1, nx), ki : integrator design, reference through the integrator only
    observer_outputs : outputs the observers read (n_used of them)
    observer_uses_integrator : the observer-based design runs (K_integral, ki) or (K, kr)
    observer_poles, L (nx, n_used) : continuous observer; L_discrete, observer_poles_z its
        ZOH predictor gain and poles at `observer_sample_period`
    controller_poles : eig(A − B K − L C), the compensator's own poles
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
    poles: np.ndarray
    K: np.ndarray
    kr: float
    poles_sampled_z: np.ndarray
    integrator_pole: float
    K_integral: np.ndarray
    ki: float
    observer_outputs: tuple
    observer_uses_integrator: bool
    observer_poles: np.ndarray
    L: np.ndarray
    observer_poles_z: np.ndarray
    L_discrete: np.ndarray
    controller_poles: np.ndarray
    disturbance_observer_poles: np.ndarray
    L_disturbance: np.ndarray
    disturbance_observer_poles_z: np.ndarray
    L_disturbance_discrete: np.ndarray
    disturbance_controller_poles: np.ndarray
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
        """Row indices in the plant's outputs of `observer_outputs`."""
        return self.model.output_rows(self.observer_outputs)


def _sampled_poles(model: TrackingModel, K, Ts, what) -> np.ndarray:
    """eig(A_d − B_d K) of the gain K (1, nx) held over Ts s on the ZOH model; ValueError naming `what`
    when one leaves the unit circle."""
    disc = model.discrete(Ts)
    z = np.linalg.eigvals(disc.A - disc.B @ np.atleast_2d(K))
    if np.any(np.abs(z) >= 1):
        raise ValueError(
            f"{what}: the continuous gain is unstable when sampled at Ts = {Ts} s "
            f"(|z| up to {np.max(np.abs(z)):.4g}); slow the poles or sample faster"
        )
    return z


def _estimator_model(model: TrackingModel, Ts: float, disturbance: bool, rows=None):
    """(A, C) of the ZOH model the discrete observers run at Ts, with a disturbance state if asked."""
    disc = model.discrete(Ts)
    C = disc.C if rows is None else disc.C[rows]
    if disturbance:
        A, _, C = ss.augment_disturbance(disc.A, disc.B, C, discrete=True)
        return A, C
    return disc.A, C


def _discrete_observer(model, rows, poles, Ts, disturbance: bool, what):
    """(predictor L_d on the ZOH model, its z-poles) for the observer with these continuous poles."""
    A, C = _estimator_model(model, Ts, disturbance, rows)
    poles_z = np.exp(np.asarray(poles, dtype=complex) * Ts)
    return ss.discrete_observer_gain(A, C, poles_z, what), poles_z


def feedback_design(model: TrackingModel, poles, sample_period: float, name: str) -> dict:
    """Pole placement with its reference gain (.15): K (1, nx) with eig(A − B K) = `poles`, k_r for unit DC gain.

    Parameters
    ----------
    model : the tracking model of the known plant
    poles : nx state-feedback poles, rad/s
    sample_period : s; the sampled-data poles eig(A_d − B_d K) must stay inside the unit circle
    name : names the plant in errors

    Returns
    -------
    dict of the `StateSpaceDesign` fields poles, K, kr, poles_sampled_z
    """
    A, B = model.linear.A, model.linear.B
    poles = np.asarray(poles, dtype=complex)
    K = ss.place(A, B, poles, name)
    kr = float(ss.reference_gain(A, B, K, model.C_r)[0])
    return {"poles": poles, "K": K, "kr": kr, "poles_sampled_z": _sampled_poles(model, K, sample_period, name)}


def integrator_design(
    model: TrackingModel, poles, integrator_pole: float | None, sample_period: float, name: str
) -> dict:
    """The integrator design (.16): the state feedback and k_i placing `poles` and the integrator's pole.

    u = −K x̃ + k_i x_I with x_I the integral of the tracking error; the reference acts through the
    integrator only. `integrator_pole` (rad/s) defaults to −min |pᵢ|.

    Returns
    -------
    dict of the `StateSpaceDesign` fields integrator_pole, K_integral (1, nx), ki
    """
    A, B, nx = model.linear.A, model.linear.B, model.linear.nx
    p_int = -float(np.min(np.abs(poles))) if integrator_pole is None else float(integrator_pole)
    A_I, B_I = ss.augment_integrator(A, B, model.C_r)
    K_int, ki = ss.split_integral_gain(ss.place(A_I, B_I, np.append(poles, p_int), name), nx)
    _sampled_poles(model, K_int, sample_period, f"{name} (state feedback part of the integrator design)")
    return {"integrator_pole": p_int, "K_integral": K_int, "ki": float(ki[0])}


def observer_design(model: TrackingModel, rows, observer_poles, sample_period: float, K_feedback, name: str) -> dict:
    """The observer (.17): continuous L (nx, n_used) and its ZOH predictor gain at `sample_period`.

    Parameters
    ----------
    rows : indices of the outputs the observer reads
    observer_poles : nx observer poles, rad/s (z-plane poles exp(p Ts) for the discrete gain)
    K_feedback : the state feedback the observer-based block runs, for the compensator's poles
        eig(A − B K − L C)

    Returns
    -------
    dict of the `StateSpaceDesign` fields observer_poles, L, observer_poles_z, L_discrete, controller_poles
    """
    A, B, C_used = model.linear.A, model.linear.B, model.linear.C[rows]
    L = ss.observer_gain(A, C_used, observer_poles, name)
    L_d, obs_z = _discrete_observer(model, rows, observer_poles, sample_period, False, name)
    return {
        "observer_poles": observer_poles,
        "L": L,
        "observer_poles_z": obs_z,
        "L_discrete": L_d,
        "controller_poles": np.linalg.eigvals(A - B @ K_feedback - L @ C_used),
    }


def disturbance_observer_design(
    model: TrackingModel, rows, observer_poles, disturbance_pole: float | None, sample_period: float, K, name: str
) -> dict:
    """The disturbance observer: the state and an input disturbance d estimated, d̂ cancelled in u.

    The observer's poles are `observer_poles` and `disturbance_pole` (rad/s; default half the slowest
    observer pole); L_disturbance is (nx + 1, n_used), its ZOH predictor gain at `sample_period`.

    Returns
    -------
    dict of the `StateSpaceDesign` fields disturbance_observer_poles, L_disturbance,
    disturbance_observer_poles_z, L_disturbance_discrete, disturbance_controller_poles
    """
    A, B, nx = model.linear.A, model.linear.B, model.linear.nx
    p_dist = -0.5 * np.min(np.abs(observer_poles)) if disturbance_pole is None else float(disturbance_pole)
    dob_poles = np.append(observer_poles, p_dist)
    A_d, _, C_d = ss.augment_disturbance(A, B, model.linear.C[rows])
    L_dob = ss.observer_gain(A_d, C_d, dob_poles, f"{name} with a disturbance state")
    L_dob_d, dob_z = _discrete_observer(model, rows, dob_poles, sample_period, True, name)
    # u = −K x̂ + k_r r − d̂ cancels d̂ in the model: x̂' = (A − B K − L_x C) x̂ + …, d̂' = L_d (y − C x̂).
    dob_controller = np.linalg.eigvals(
        np.block([[A - B @ K, np.zeros((nx, 1))], [np.zeros((1, nx + 1))]]) - L_dob @ C_d
    )
    return {
        "disturbance_observer_poles": dob_poles,
        "L_disturbance": L_dob,
        "disturbance_observer_poles_z": dob_z,
        "L_disturbance_discrete": L_dob_d,
        "disturbance_controller_poles": dob_controller,
    }


def lqr_design(model: TrackingModel, Q, R, sample_period: float, name: str) -> dict:
    """The integrator-augmented LQR, the LQR on the states alone, and the discrete LQR of the ZOH model.

    Parameters
    ----------
    Q : (nx + 1, nx + 1) weight of (x̃, x_I);  R : (1, 1) weight of the input
    sample_period : s; the continuous gain must stay stable when sampled, and the discrete LQR
        runs the ZOH model with the integrator by forward Euler and weights Q Ts, R Ts

    Returns
    -------
    dict of the `StateSpaceDesign` fields Q, R, K_lqr, ki_lqr, P_lqr, lqr_poles, K_lqr_plain,
    kr_lqr_plain, K_dlqr, dlqr_poles_z
    """
    A, B, nx = model.linear.A, model.linear.B, model.linear.nx
    Ts = sample_period
    Q = np.asarray(Q, dtype=float)
    R = np.atleast_2d(np.asarray(R, dtype=float))
    A_I, B_I = ss.augment_integrator(A, B, model.C_r)
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
    return {
        "Q": Q,
        "R": R,
        "K_lqr": K_lqr,
        "ki_lqr": float(ki_lqr[0]),
        "P_lqr": P,
        "lqr_poles": lqr_poles,
        "K_lqr_plain": K_lqr_plain,
        "kr_lqr_plain": kr_lqr_plain,
        "K_dlqr": K_dlqr,
        "dlqr_poles_z": np.linalg.eigvals(A_Id - B_Id @ K_dlqr),
    }


def kalman_design(
    model: TrackingModel, sample_period: float, bandwidth: float, measurement_noise: float, name: str
) -> dict:
    """The steady-state Kalman predictor of the ZOH model reading every output (noise model: `kalman_noise`).

    bandwidth : the filter's ω_K, rad/s;  measurement_noise : σ_y per output (m or rad per sample)

    Returns
    -------
    dict of the `StateSpaceDesign` fields kalman_W, kalman_V, L_kalman (nx, ny), kalman_poles_z
    """
    lin = model.linear
    disc = model.discrete(sample_period)
    W, V = kalman_noise(model, sample_period, lin.ny, bandwidth, measurement_noise)
    L_kf, _ = ss.dkalman(disc.A, lin.C, W, V, name)
    return {"kalman_W": W, "kalman_V": V, "L_kalman": L_kf, "kalman_poles_z": np.linalg.eigvals(disc.A - L_kf @ lin.C)}


def design(
    known: models.Plant,
    tracked: str,
    *,
    poles,
    Q,
    R,
    sample_period: float,
    observer_sample_period: float | None = None,
    integrator_pole: float | None = None,
    observer_poles=None,
    observer_speedup: float = 5.0,
    observer_outputs=None,
    observer_uses_integrator: bool = False,
    disturbance_pole: float | None = None,
    kalman_speedup: float = 5.0,
    measurement_noise: float = MEASUREMENT_NOISE,
) -> StateSpaceDesign:
    """All state-space designs of `known` (the plant the controller believes) about its standard equilibrium.

    The steps, each a function of this module: `feedback_design`, `integrator_design`,
    `observer_design`, `disturbance_observer_design`, `lqr_design`, `kalman_design`.

    Parameters
    ----------
    known : models.Plant
    tracked : coordinate that follows the reference
    poles : nx state-feedback poles (rad/s)
    Q, R : LQR weights of the integrator-augmented state (nx + 1) and the input
    sample_period : s, of the state-feedback, disturbance-observer and LQR blocks
    observer_sample_period : s, of the observer-based block (default `sample_period`)
    integrator_pole : rad/s; default −min |pᵢ| (the slowest mode's natural frequency)
    observer_poles : nx observer poles; default `observer_speedup` times `poles`
    observer_outputs : outputs the observers read (default all)
    observer_uses_integrator : the observer-based block runs the integrator design
    disturbance_pole : pole of the disturbance estimate; default half the slowest observer pole
    kalman_speedup : the Kalman filter's bandwidth ω_K = this times max |pᵢ|
    measurement_noise : σ_y of the Kalman filter's model (m or rad per sample)

    Raises
    ------
    ValueError
        For a design check that fails (controllability, observability, pole
        requests, weights, stability when sampled), naming the plant.
    """
    name = known.name
    model = TrackingModel.from_plant(known, tracked)
    lin = model.linear
    Ts = float(sample_period)
    Ts_obs = Ts if observer_sample_period is None else float(observer_sample_period)
    outputs = tuple(lin.output_names if observer_outputs is None else observer_outputs)
    rows = model.output_rows(outputs)
    rank_c = ss.require_controllable(lin.A, lin.B, name)
    rank_o = ss.require_observable(lin.A, lin.C[rows], f"{name} measuring {', '.join(outputs)}")
    feedback = feedback_design(model, poles, Ts, name)
    poles = feedback["poles"]
    integral = integrator_design(model, poles, integrator_pole, Ts, name)
    obs_poles = observer_speedup * poles if observer_poles is None else np.asarray(observer_poles, dtype=complex)
    K_obs = integral["K_integral"] if observer_uses_integrator else feedback["K"]
    return StateSpaceDesign(
        plant=name,
        model=model,
        sample_period=Ts,
        observer_sample_period=Ts_obs,
        controllability_rank=rank_c,
        observability_rank=rank_o,
        observer_outputs=outputs,
        observer_uses_integrator=bool(observer_uses_integrator),
        **feedback,
        **integral,
        **observer_design(model, rows, obs_poles, Ts_obs, K_obs, name),
        **disturbance_observer_design(model, rows, obs_poles, disturbance_pole, Ts, feedback["K"], name),
        **lqr_design(model, Q, R, Ts, name),
        **kalman_design(model, Ts, kalman_speedup * np.max(np.abs(poles)), measurement_noise, name),
    )


def kalman_noise(
    model: TrackingModel,
    sample_period: float,
    n_outputs: int,
    bandwidth: float,
    measurement_noise: float = MEASUREMENT_NOISE,
) -> tuple[np.ndarray, np.ndarray]:
    """Covariances (W (nx, nx), V (ny, ny)) of the Kalman filter's noise model per sample.

    Measurement noise σ_y = `measurement_noise` on each output; generalized
    acceleration noise σ_a = σ_y · bandwidth² (rad/s) on every coordinate,
    held over each sample (its ZOH input matrix G_a gives W = σ_a² G_a G_aᵀ).
    """
    nq, nx = model.plant.nq, model.nx
    acceleration = np.vstack([np.zeros((nq, nq)), np.eye(nq)])
    block = np.zeros((nx + nq, nx + nq))
    block[:nx, :nx] = model.linear.A
    block[:nx, nx:] = acceleration
    G_a = scipy.linalg.expm(block * sample_period)[:nx, nx:]
    sigma_a = measurement_noise * bandwidth**2
    return sigma_a**2 * G_a @ G_a.T, measurement_noise**2 * np.eye(n_outputs)


def controllers(d: StateSpaceDesign) -> dict:
    """Label -> `models.Block` running the gains of `d` (labels in `LABELS`).

    Every block takes the absolute tracked coordinate as its reference and
    saturates its total command at the known plant's limit. "observer-based"
    runs at `d.observer_sample_period`, the others at `d.sample_period`.
    """
    model, Ts = d.model, d.sample_period

    def current(L_predictor, Ts_, disturbance):
        A, _ = _estimator_model(model, Ts_, disturbance)
        return ss.current_estimator_gain(A, L_predictor)

    K_obs = d.K_integral if d.observer_uses_integrator else d.K
    kr_obs = 0.0 if d.observer_uses_integrator else d.kr
    ki_obs = d.ki if d.observer_uses_integrator else None
    outputs = d.observer_outputs
    return {
        "pole placement": StateFeedback(model, d.K, d.kr, sample_period=Ts, name="pole placement"),
        "pole placement + integrator": StateFeedback(
            model, d.K_integral, 0.0, d.ki, sample_period=Ts, name="pole placement + integrator"
        ),
        "observer-based": ObserverFeedback(
            model,
            K_obs,
            kr_obs,
            current(d.L_discrete, d.observer_sample_period, False),
            ki_obs,
            sample_period=d.observer_sample_period,
            measured_outputs=outputs,
            name="observer-based",
        ),
        "disturbance observer": ObserverFeedback(
            model,
            d.K,
            d.kr,
            current(d.L_disturbance_discrete, Ts, True),
            sample_period=Ts,
            measured_outputs=outputs,
            disturbance_observer=True,
            name="disturbance observer",
        ),
        "LQR": StateFeedback(model, d.K_lqr, 0.0, d.ki_lqr, sample_period=Ts, name="LQR"),
        "LQR + Kalman": ObserverFeedback(
            model, d.K_lqr, 0.0, current(d.L_kalman, Ts, False), d.ki_lqr, sample_period=Ts, name="LQR + Kalman"
        ),
    }
