"""Per-plant MPC defaults and `controllers(name, known)`, the entry point other packages call.

Weights are diagonal, Bryson-style (1 / acceptable excursion²), in SI units.
Soft bounds are stated on the physical quantity and tightened inside the MPC
by a back-off fraction of their half-width, so that the true plant — whose
parameters differ by ±5 % from the known ones and which sees the input
disturbance — still respects the physical bound.

Sample periods: the text's Ts = 0.01 s for the fast plants (arm, pendulum,
ball on beam). The satellite (panel mode 0.42 rad/s, period 15 s), the UUV
(1.1 rad/s) and the crane (pendulum modes 0.67 and 1.15 rad/s, a 10 m move
taking 10-20 s) need prediction horizons of seconds to tens of seconds; at
0.01 s that would be thousands of stages, so their MPCs run at 0.05-0.1 s,
still 50-150 samples per period of their fastest mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import models
from models import Plant

from .controller import LinearMPC, NonlinearMPC
from .linear import SoftBound


@dataclass(frozen=True)
class SoftSpec:
    """A physical bound lower <= Σ coefficient·state <= upper, softened in the MPC.

    `upper` / `lower` may be callables of the known Plant (the beam's length).
    `backoff` tightens both sides by that fraction of the half-width inside the MPC.
    """

    name: str
    combination: dict
    lower: object
    upper: object
    backoff: float = 0.0

    def bounds(self, plant: Plant) -> tuple[float, float]:
        """The physical (lower, upper) for `plant`."""
        value = lambda b: float(b(plant)) if callable(b) else float(b)
        return value(self.lower), value(self.upper)

    def soft_bound(self, known: Plant, linear_weight: float, quadratic_weight: float) -> SoftBound:
        """The tightened SoftBound the MPC designed on `known` uses."""
        lower, upper = self.bounds(known)
        margin = self.backoff * (upper - lower) / 2
        return SoftBound.on(known, self.combination, lower + margin, upper - margin, scale=(upper - lower) / 2,
                            linear_weight=linear_weight, quadratic_weight=quadratic_weight, name=self.name)


@dataclass(frozen=True)
class MPCDefaults:
    """One plant's MPC design choices (see the module docstring for the reasoning).

    Attributes
    ----------
    sample_period : s;  horizon : N samples (linear and nonlinear MPC alike)
    state_weight : diagonal of Q, (nx,);  input_weight : R (scalar, the plants have one input)
    soft : tuple of SoftSpec
    disturbance_step_std : estimator's random-walk std of d per sample, as a fraction of the input limit
    input_noise_std : estimator's input-noise std, fraction of the input limit
    measurement_std : estimator's measurement-noise std (output units)
    soft_linear_weight, soft_quadratic_weight : penalty per half-width of violation (see SoftBound.on)
    substeps : RK4 steps per sample in the nonlinear MPC's prediction model
    notes : why the horizon and bounds are what they are
    """

    sample_period: float
    horizon: int
    state_weight: tuple
    input_weight: float
    soft: tuple = ()
    disturbance_step_std: float = 0.01
    input_noise_std: float = 0.01
    measurement_std: float = 1e-3
    soft_linear_weight: float = 1e3
    soft_quadratic_weight: float = 1e2
    substeps: int = 1
    notes: str = ""


DEFAULTS: dict[str, MPCDefaults] = {
    "arm": MPCDefaults(0.01, 50, (100.0, 0.1), 1.0, notes="50 samples = 0.5 s, several closed-loop time constants"),
    "pendulum": MPCDefaults(
        0.01, 50, (1.0, 10.0, 0.1, 0.1), 1e-2,
        soft=(SoftSpec("theta", {"theta": 1.0}, -0.2, 0.2, backoff=0.1),),
        notes="|theta| <= 0.2 rad (11.5 deg): from about 0.3 rad on, 5 N no longer catches the pendulum "
              "once the 0.5 N disturbance acts; N = 50 at 0.01 s covers the 0.2 s unstable time constant "
              "2.5 times"),
    "satellite": MPCDefaults(
        0.1, 60, (1.0, 10.0, 0.1, 0.1), 1 / 25,
        soft=(SoftSpec("panel deflection", {"phi": 1.0, "theta": -1.0}, -0.2, 0.2, backoff=0.1),),
        notes="|phi - theta| <= 0.2 rad; 6 s horizon, 0.4 of the panel period"),
    "uuv": MPCDefaults(0.05, 40, (100.0, 1.0), 1 / 50**2, notes="2 s horizon, 0.36 of the roll period"),
    "ballbeam": MPCDefaults(
        0.01, 60, (100.0, 10.0, 1.0, 1.0), 1 / 15**2,
        soft=(SoftSpec("ball on beam", {"z": 1.0}, 0.0, lambda p: p.params["ell"], backoff=0.1),),
        notes="0 <= z <= ell; 0.6 s horizon, two unstable time constants (0.27 s)"),
    "crane": MPCDefaults(
        0.1, 80, (1.0, 100.0, 100.0, 1.0, 1000.0, 1000.0), 1 / 5000**2,
        soft=(SoftSpec("swing 1", {"theta1": 1.0}, -0.1, 0.1, backoff=0.1),
              SoftSpec("swing 2", {"theta2": 1.0}, -0.1, 0.1, backoff=0.1)),
        disturbance_step_std=0.05,
        notes="|theta_i| <= 0.1 rad; 8 s horizon, 0.85 of the slow swing period; the heavy swing-rate "
              "weights damp the 24 m cable mode (time constant 6 s, the best a cart force achieves)"),
    "crane1": MPCDefaults(
        0.1, 80, (1.0, 100.0, 1.0, 100.0), 1 / 5000**2,
        soft=(SoftSpec("swing", {"theta": 1.0}, -0.1, 0.1, backoff=0.1),),
        disturbance_step_std=0.05,
        notes="|theta| <= 0.1 rad; 8 s horizon, 1.5 swing periods"),
}


def defaults(name: str) -> MPCDefaults:
    """The MPC defaults of plant `name` (ValueError listing the plants otherwise)."""
    if name not in DEFAULTS:
        raise ValueError(f"no MPC defaults for {name!r}; plants with defaults: {', '.join(DEFAULTS)}")
    return DEFAULTS[name]


def _design_arguments(known: Plant, spec: MPCDefaults) -> dict:
    soft = tuple(s.soft_bound(known, spec.soft_linear_weight, spec.soft_quadratic_weight) for s in spec.soft)
    limit = known.input_limit
    return dict(sample_period=spec.sample_period, horizon=spec.horizon, state_weight=np.array(spec.state_weight),
                input_weight=spec.input_weight, soft_bounds=soft,
                disturbance_step_std=spec.disturbance_step_std * limit, input_noise_std=spec.input_noise_std * limit,
                measurement_std=spec.measurement_std)


def linear_mpc(name: str, known: Plant | None = None, solver: str = "daqp", **overrides) -> LinearMPC:
    """The linear MPC of plant `name` with its defaults; keyword arguments override them."""
    known = models.get(name) if known is None else known
    if known.name != name:
        raise ValueError(f"the known plant is {known.name!r}, not {name!r}")
    return LinearMPC(known, solver=solver, **(_design_arguments(known, defaults(name)) | overrides))


def nonlinear_mpc(name: str, known: Plant | None = None, **overrides) -> NonlinearMPC:
    """The nonlinear MPC of plant `name` with its defaults; keyword arguments override them."""
    known = models.get(name) if known is None else known
    if known.name != name:
        raise ValueError(f"the known plant is {known.name!r}, not {name!r}")
    spec = defaults(name)
    return NonlinearMPC(known, substeps=spec.substeps, **(_design_arguments(known, spec) | overrides))


def controllers(name: str, known: Plant | None = None) -> dict:
    """{"linear MPC": ..., "nonlinear MPC": ...} for plant `name`, designed on `known`.

    Parameters
    ----------
    name : a plant with MPC defaults (every `models.names()` entry)
    known : the Plant the controllers are designed from (default: the nominal plant);
        for the text's mismatch pass ``models.perturbed(models.get(name), 0.05)``.

    Returns
    -------
    dict of two controllers following `models.Controller`: they measure the
    plant's outputs, take the absolute value of the case's tracked coordinate
    as reference, expose `step_info()`, and `initial_state` resets them for a rerun.
    """
    return {"linear MPC": linear_mpc(name, known), "nonlinear MPC": nonlinear_mpc(name, known)}


def physical_soft_bounds(name: str, plant: Plant) -> list[tuple[str, np.ndarray, float, float]]:
    """(name, row, lower, upper) of the physical (untightened) soft bounds on `plant`'s state."""
    out = []
    for spec in defaults(name).soft:
        bound = SoftBound.on(plant, spec.combination, *spec.bounds(plant), name=spec.name)
        out.append((spec.name, bound.row, bound.lower, bound.upper))
    return out
