"""Offset-free tracking: a disturbance-augmented Kalman filter and the steady-state target.

The model is augmented with a constant input disturbance d,

    x⁺ = A x + B (u + d),   d⁺ = d,   y = C x,

and a steady-state (current-form) Kalman filter estimates (x, d) from the
measured outputs. The target (x_s, u_s) solves

    (A − I) x_s + B (u_s + d̂) = 0,   H x_s = r,

so the MPC drives the model to a point where the tracked coordinate equals
r *given* the estimated disturbance. Because the filter's innovation vanishes
at any closed-loop steady state (as many disturbances as tracked outputs, and
the plants' output steady states lie on the one-parameter family the model
has), a constant input disturbance or a parameter error leaves no offset
(Pannocchia & Rawlings, AIChE J. 49(2), 2003).
"""

from __future__ import annotations

import numpy as np

from models import deferred
from models.checks import real_array
from models.lqr import augment_disturbance, dkalman, unobservable_modes

scipy = deferred.module("scipy")


class DisturbanceObserver:
    """Steady-state Kalman filter for the disturbance-augmented discrete model.

    Parameters
    ----------
    A, B, C : (nx, nx), (nx, nu), (ny, nx), discrete deviation model
    input_noise_std : (nu,) std of white noise added to the input per sample (models unmodelled forces)
    disturbance_step_std : (nu,) std of the random-walk increment of d per sample; larger = faster d̂
    measurement_std : (ny,) std of the measurement noise

    Attributes
    ----------
    gain : (nx + nu, ny) filter gain L: (x̂, d̂)_{k|k} = (x̂, d̂)_{k|k−1} + L (ỹ_k − C x̂_{k|k−1})
    A_aug, B_aug, C_aug : the augmented model

    Raises
    ------
    ValueError
        When the disturbance is not observable from the outputs (the plant has
        a zero at z = 1 from input to outputs) or a noise level is not > 0.
    """

    def __init__(self, A, B, C, input_noise_std, disturbance_step_std, measurement_std):
        A, B, C = (np.atleast_2d(real_array(m, what)) for m, what in ((A, "A"), (B, "B"), (C, "C")))
        nx, nu, ny = A.shape[0], B.shape[1], C.shape[0]
        if A.shape != (nx, nx) or B.shape[0] != nx or C.shape[1] != nx:
            raise ValueError(f"A must be square with B and C fitting it: got A {A.shape}, B {B.shape}, C {C.shape}")
        if not all(np.all(np.isfinite(m)) for m in (A, B, C)):
            raise ValueError("A, B and C must be finite")
        stds = {}
        for name, value, n in (
            ("input_noise_std", input_noise_std, nu),
            ("disturbance_step_std", disturbance_step_std, nu),
            ("measurement_std", measurement_std, ny),
        ):
            arr = real_array(value, name)
            if arr.size not in (1, n):
                raise ValueError(f"{name} must be a number or {n} numbers, got shape {arr.shape}")
            arr = np.broadcast_to(arr.reshape(-1), (n,)).copy()
            if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
                raise ValueError(f"{name} must be finite and > 0, got {arr}")
            stds[name] = arr
        self.A_aug, self.B_aug, self.C_aug = augment_disturbance(A, B, C, discrete=True)
        hidden = [z for z in unobservable_modes(self.A_aug, self.C_aug) if abs(z) >= 1 - 1e-9]
        if hidden:
            raise ValueError(
                f"the input disturbance (or a mode at z = {hidden[0]:.4g}) is not observable from the "
                "outputs; offset-free estimation needs rank [[A − I, B], [C, 0]] = nx + nu"
            )
        Bw = B * stds["input_noise_std"]
        process = scipy.linalg.block_diag(Bw @ Bw.T, np.diag(stds["disturbance_step_std"] ** 2))
        # A floor on every state keeps the Riccati equation's solution unique and stabilizing.
        process += 1e-12 * max(1.0, np.max(np.abs(process))) * np.eye(nx + nu)
        measurement = np.diag(stds["measurement_std"] ** 2)
        _, covariance = dkalman(self.A_aug, self.C_aug, process, measurement, "offset-free estimator")
        innovation = self.C_aug @ covariance @ self.C_aug.T + measurement
        self.gain = np.linalg.solve(innovation, self.C_aug @ covariance).T
        self.nx, self.nu, self.ny = nx, nu, ny

    def correct(self, x_pred, d_pred, innovation) -> tuple[np.ndarray, np.ndarray]:
        """Measurement update of the predictions x_pred = x̂_{k|k−1} (nx,) and d_pred = d̂_{k|k−1} (nu,)
        from the innovation ỹ − C x̂_{k|k−1}: (x̂_{k|k}, d̂_{k|k})."""
        step = self.gain @ innovation
        return x_pred + step[: self.nx], d_pred + step[self.nx :]

    def update(self, predicted, measured) -> np.ndarray:
        """`correct` on the stacked estimate: (x̂, d̂)_{k|k} (nx + nu,) from `predicted`, (x̂, d̂)_{k|k−1}
        (nx + nu,), and `measured`, ỹ_k."""
        return predicted + self.gain @ (measured - self.C_aug @ predicted)

    def error_dynamics(self) -> np.ndarray:
        """(I − L C) A_aug: the estimation error's transition matrix; Schur stable by construction."""
        return (np.eye(self.nx + self.nu) - self.gain @ self.C_aug) @ self.A_aug


class SteadyStateTarget:
    """Steady states (x_s, v_s) of x⁺ = A x + B v with H x_s = r, v = u + d.

    Parameters
    ----------
    A, B : discrete deviation model
    tracked_rows : (nu, nx) H, the tracked combinations of states (as many as inputs)

    Raises
    ------
    ValueError
        When the tracked coordinates cannot be held at arbitrary values (the
        plant has a zero at z = 1 from the inputs to them).
    """

    def __init__(self, A, B, tracked_rows):
        A, B = np.atleast_2d(A), np.atleast_2d(B)
        H = np.atleast_2d(np.asarray(tracked_rows, dtype=float))
        nx, nu = A.shape[0], B.shape[1]
        if H.shape != (nu, nx):
            raise ValueError(f"need as many tracked coordinates as inputs: H must be ({nu}, {nx}), got {H.shape}")
        system = np.block([[A - np.eye(nx), B], [H, np.zeros((nu, nu))]])
        if np.linalg.cond(system) > 1e12:
            raise ValueError(
                "the tracked coordinates cannot be held at a steady state: "
                "[[A − I, B], [H, 0]] is singular (a zero at z = 1)"
            )
        solution = np.linalg.solve(system, np.vstack([np.zeros((nx, nu)), np.eye(nu)]))
        self.state_per_reference = solution[:nx]  # x_s = S_x r
        self.input_per_reference = solution[nx:]  # v_s = S_v r
        self.nx, self.nu = nx, nu

    def __call__(self, reference, disturbance) -> tuple[np.ndarray, np.ndarray]:
        """(x_s, u_s) for the deviation reference r̃ (nu,) and disturbance estimate d̂ (nu,)."""
        return self.state_per_reference @ reference, self.input_per_reference @ reference - disturbance
