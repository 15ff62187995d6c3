"""MPC settings as one record, and the builders of the two controllers from it.

`MPCSettings` holds every design choice of an MPC (sample period, horizon,
weights, soft bounds, estimator tuning); `linear_mpc(known, settings,
tracked=...)` and `nonlinear_mpc(...)` build the controllers from it. A case
study states its own settings (weights diagonal, Bryson-style: 1 / acceptable
excursion², SI units).

Soft bounds are stated on the physical quantity and tightened inside the MPC
by a back-off fraction of their half-width, so that the true plant, whose
parameters differ from the known ones and which sees input disturbances,
still respects the physical bound.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models import Plant

from .controller import LinearMPC, NonlinearMPC
from .linear import SoftBound


@dataclass(frozen=True)
class SoftSpec:
    """A physical bound lower <= Σ coefficient·state <= upper, softened in the MPC.

    `name` labels the bound; `combination` maps state names to their coefficients.
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
        """The tightened SoftBound the MPC designed on `known` uses, its violation priced by linear_weight
        and quadratic_weight."""
        lower, upper = self.bounds(known)
        margin = self.backoff * (upper - lower) / 2
        return SoftBound.on(
            known,
            self.combination,
            lower + margin,
            upper - margin,
            scale=(upper - lower) / 2,
            linear_weight=linear_weight,
            quadratic_weight=quadratic_weight,
            name=self.name,
        )


@dataclass(frozen=True)
class MPCSettings:
    """The design choices of one MPC (see the module docstring).

    Attributes
    ----------
    sample_period : s, no default: the case's sample period, or a multiple of it where the horizon
        needs seconds;  horizon : N samples (linear and nonlinear MPC alike)
    state_weight : diagonal of Q, (nx,);  input_weight : R (scalar, the plants have one input)
    soft : tuple of SoftSpec
    disturbance_step_std : estimator's random-walk std of d per sample, as a fraction of the input limit
    input_noise_std : estimator's input-noise std, fraction of the input limit
    measurement_std : estimator's measurement-noise std (output units)
    soft_linear_weight, soft_quadratic_weight : penalty per half-width of violation (see SoftBound.on)
    substeps : RK4 steps per sample in the nonlinear MPC's prediction model
    notes : why the horizon and bounds are what they are, in words
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


def design_arguments(known: Plant, settings: MPCSettings) -> dict:
    """Keyword arguments of `LinearMPC` / `NonlinearMPC` from `settings` on the known plant."""
    soft = tuple(
        s.soft_bound(known, settings.soft_linear_weight, settings.soft_quadratic_weight) for s in settings.soft
    )
    limit = known.input_limit
    return dict(
        sample_period=settings.sample_period,
        horizon=settings.horizon,
        state_weight=np.array(settings.state_weight),
        input_weight=settings.input_weight,
        soft_bounds=soft,
        disturbance_step_std=settings.disturbance_step_std * limit,
        input_noise_std=settings.input_noise_std * limit,
        measurement_std=settings.measurement_std,
    )


def linear_mpc(known: Plant, settings: MPCSettings, *, tracked: str, solver: str = "daqp", **overrides) -> LinearMPC:
    """The linear MPC designed on `known` with `settings`; keyword arguments override them.

    Parameters
    ----------
    known : the Plant the controller is designed from (its model of the plant)
    settings : MPCSettings
    tracked : coordinate whose absolute value the reference gives
    solver : see `LinearMPC`
    """
    return LinearMPC(known, solver=solver, tracked=tracked, **(design_arguments(known, settings) | overrides))


def nonlinear_mpc(known: Plant, settings: MPCSettings, *, tracked: str, **overrides) -> NonlinearMPC:
    """The nonlinear MPC designed on `known` with `settings`, tracking the coordinate `tracked`; keyword
    arguments override the settings."""
    arguments = {"substeps": settings.substeps} | design_arguments(known, settings) | overrides
    return NonlinearMPC(known, tracked=tracked, **arguments)


def physical_soft_bounds(settings: MPCSettings, plant: Plant) -> list[tuple[str, np.ndarray, float, float]]:
    """(name, row, lower, upper) of the physical (untightened) soft bounds of `settings` on `plant`'s state."""
    out = []
    for spec in settings.soft:
        bound = SoftBound.on(plant, spec.combination, *spec.bounds(plant), name=spec.name)
        out.append((spec.name, bound.row, bound.lower, bound.upper))
    return out
