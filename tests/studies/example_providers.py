"""Controller providers for testing the studies apart from the case studies' own designs.

`controllers(case, known)` returns, for any case (registered or not), linear-quadratic
state feedback with reference feedforward in three speeds (blocks), a
dirty-derivative PD on the tracked output for the one-coordinate plants, and
the same state feedback as a Python controller with per-step solver records
(standing in for MPC). These are fixtures with the providers' interface
(``provider(case, known) -> {label: controller}``, `studies.providers`), not
designs of the case studies. Each takes the case, or a registered case's name.
"""

from __future__ import annotations

import os
import time

import casadi as ca
import control
import numpy as np

import models
import studies
from designs.discrete import dirty_derivative


def _case(case) -> studies.CaseStudy:
    """`case`, or the registered case of that name."""
    return studies.get(case) if isinstance(case, str) else case


def _plant(case: studies.CaseStudy, known: models.Plant | None) -> models.Plant:
    return known or models.get(case.plant)


def _tracking_gains(plant: models.Plant, case: studies.CaseStudy, weight: float):
    """LQR gain K and feedforward (Nx, Nu) so that x → xe + Nx Δr, u → ue + Nu Δr."""
    xe, ue = plant.equilibrium()
    lin = plant.linearize(xe, ue)
    i = plant.state_names.index(case.tracked)
    q = np.ones(plant.nx)
    q[i] = 1.0 / case.step**2
    K, _, _ = control.lqr(lin.A, lin.B, np.diag(q), np.eye(1) * weight / plant.input_limit[0] ** 2)
    row = np.eye(plant.nx)[i : i + 1]
    big = np.block([[lin.A, lin.B], [row, np.zeros((1, 1))]])
    solution = np.linalg.solve(big, np.concatenate([np.zeros(plant.nx), [1.0]]))
    return np.asarray(K)[0], solution[: plant.nx], solution[plant.nx :], xe, ue, float(xe[i])


class StateFeedback(models.Block):
    """u = ue + Nu (r − re) − K (x − xe − Nx (r − re)), reading the state."""

    def __init__(self, K, Nx, Nu, xe, ue, re, sample_period=0.01, name="state feedback"):
        self.xe, self.ue, self.re = np.asarray(xe), np.asarray(ue), float(re)
        super().__init__(
            sample_period=sample_period,
            n_state=0,
            n_measured=len(K),
            n_reference=1,
            n_input=1,
            gains={"K": K, "Nx": Nx, "Nu": Nu},
            measures="state",
            name=name,
        )

    def expr(self, xc, y, r, g):
        dr = r[0] - self.re
        return xc, self.ue[0] + g["Nu"][0] * dr - ca.dot(g["K"], y - self.xe - g["Nx"] * dr)


class DirtyPD(models.Block):
    """u = ue + kp (r − y) − kd ẏ with ẏ from the dirty derivative (σ = 0.05 s); state (y_prev, ẏ)."""

    def __init__(self, kp, kd, ue, sample_period=0.01):
        self.ue = float(ue)
        super().__init__(
            sample_period=sample_period,
            n_state=2,
            n_measured=1,
            n_reference=1,
            n_input=1,
            gains={"kp": kp, "kd": kd},
            name="PD",
        )

    def expr(self, xc, y, r, g):
        rate = dirty_derivative(xc[1], xc[0], y[0], 0.05, self.sample_period)
        return ca.vertcat(y[0], rate), self.ue + g["kp"] * (r[0] - y[0]) - g["kd"] * rate

    def initial_state(self, y0, r0):
        return np.array([float(np.asarray(y0).ravel()[0]), 0.0])


class PythonStateFeedback:
    """The same state feedback as a Python controller, clipped to the limit, with solver records."""

    measures = "state"
    n_reference = 1

    def __init__(self, block: StateFeedback, limit: float, fail_after: int | None = None):
        self.block, self.limit, self.fail_after = block, limit, fail_after
        self.sample_period = block.sample_period
        self.name = "python state feedback"
        self._info = {}

    def initial_state(self, y0, r0):
        return np.zeros(1)

    def step(self, xc, y, r):
        start = time.perf_counter()
        _, u = self.block.step(np.zeros(0), y, r)
        u = np.clip(u, -self.limit, self.limit)
        count = int(xc[0])
        if self.fail_after is not None and count >= self.fail_after:
            u = np.full(1, np.nan)
        self._info = {
            "status": "solved" if count % 50 else "max_iter_reached",
            "solve_time": time.perf_counter() - start,
        }
        return np.array([count + 1.0]), u

    def step_info(self):
        return dict(self._info)


def controllers(case, known: models.Plant | None = None) -> dict:
    """Example controllers for `case`, designed from `known` (default: nominal)."""
    case = _case(case)
    plant = _plant(case, known)
    out = {}
    for label, weight in (("LQR", 1.0), ("LQR fast", 0.25), ("LQR slow", 4.0)):
        K, Nx, Nu, xe, ue, re = _tracking_gains(plant, case, weight)
        out[label] = StateFeedback(K, Nx, Nu, xe, ue, re, name=label)
    if plant.nq == 1:
        K, _, _, xe, ue, _ = _tracking_gains(plant, case, 1.0)
        out["PD"] = DirtyPD(K[0], K[1], ue[0])
    out["linear MPC"] = PythonStateFeedback(out["LQR"], float(plant.input_limit[0]))
    return out


def failing(case, known: models.Plant | None = None) -> dict:
    """A provider that raises, as a provider with a bug would."""
    raise RuntimeError(f"no design for {_case(case).plant}")


def diverging(case, known: models.Plant | None = None) -> dict:
    """A controller whose command becomes NaN after 1 s: the run must be reported as diverged."""
    case = _case(case)
    plant = _plant(case, known)
    K, Nx, Nu, xe, ue, re = _tracking_gains(plant, case, 1.0)
    return {
        "broken": PythonStateFeedback(StateFeedback(K, Nx, Nu, xe, ue, re), float(plant.input_limit[0]), fail_after=100)
    }


def lqr_only(case, known: models.Plant | None = None) -> dict:
    """Just the LQR state feedback of `controllers`."""
    return {"LQR": controllers(case, known)["LQR"]}


def with_own_actuator(case, known: models.Plant | None = None) -> dict:
    """The LQR twice, once under the label the UUV study gives its own 250 N m actuator."""
    lqr = controllers(case, known)["LQR"]
    return {"LQR": lqr, "lead-lag (IV.11)": lqr}


def killing_the_worker(case, known: models.Plant | None = None) -> dict:
    """Kills the process it runs in when that is a Dask worker (a worker lost mid-run); else `controllers`."""
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        return controllers(case, known)
    os._exit(1)
