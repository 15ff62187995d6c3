"""The robust controllers' rows of a study, beside nominal MPC: the providers `scenario_tree` and `tube`.

They are not among a case's own providers (`studies.providers.STANDARD`): a tree's step costs a few
times the nominal NMPC's (docs/robust_mpc.md has the measurement), more than a quick run has room
for. A run adds them by name::

    python -m studies pendulum --provider studies.robust_rows:scenario_tree --provider studies.robust_rows:tube

`scenario_tree` gives "scenario-tree NMPC": `mpc.ScenarioTreeMPC` with the case's own MPC settings
(those of its "nonlinear MPC" row) over `branches`, the two opposite corners of the text's ±5 % box
around the case's plant (every uncertain parameter 5 % low, every one 5 % high; the known model,
nominal·(1 + known_rel), is the high one), with equal weights and robust horizon 1. Two branches,
not the box's 2^k corners, because a row runs every scenario and the Monte Carlo of the study at the
controller's sample rate, and the cost of a step grows with the branches (`benchmarks/robust_mpc.py`
runs the full corner trees and measures that).

`tube` has no row to give: `mpc.TubeMPC` regulates to its design point and takes no reference, so in
a study of reference steps it would not be the controller the table compares; it raises `NotProvided`
saying so (the run notes it). `benchmarks/robust_mpc.py` runs it on the regulation problem it is built
for.
"""

from __future__ import annotations

import dataclasses

import numpy as np

import models
from models.state_limits import StateLimit
from mpc import MPCSettings, ScenarioTreeMPC, SoftSpec, scenario_tree_mpc

from .case import CaseStudy
from .provider_calls import NotProvided

#: The relative half-width of the text's box of parameters.
BOX = 0.05
#: The tree's label in the tables.
LABEL = "scenario-tree NMPC"


def branches(plant: models.Plant, rel: float = BOX) -> np.ndarray:
    """The two opposite corners of `plant`'s ±rel box in its uncertain parameters, (2, n_params):
    every one at (1 − rel), then every one at (1 + rel)."""
    low = models.perturbed(plant, rel, -1.0).param_vector()
    high = models.perturbed(plant, rel, 1.0).param_vector()
    return np.array([low, high])


def with_limits(settings: MPCSettings, limits, backoff: float = 0.1) -> MPCSettings:
    """`settings` with each `models.state_limits.StateLimit` of `limits` added as a soft bound (tightened by
    `backoff` of its half-width, as the case's own soft bounds): on x[state] − x[relative_to] for a
    deflection, up to the known plant's parameter for an `upper_parameter` limit. The bounds the settings
    already have stay, and a limit on a state they already bound within it adds nothing."""
    extra = []
    for limit in limits:
        if not isinstance(limit, StateLimit):
            raise TypeError(f"limits must be models.state_limits.StateLimit records, got {limit!r}")
        if any(_inside(spec, limit) for spec in settings.soft):
            continue  # the settings already bound that state within the limit
        combination = {limit.state: 1.0} | ({} if limit.relative_to is None else {limit.relative_to: -1.0})
        upper = limit.upper if limit.upper_parameter is None else _parameter(limit.upper_parameter)
        extra.append(SoftSpec(limit.name, combination, limit.lower, upper, backoff=backoff))
    return dataclasses.replace(settings, soft=tuple(settings.soft) + tuple(extra))


def _parameter(name: str):
    """The known plant's parameter `name`, as a SoftSpec bound (a callable of the known Plant)."""
    return lambda plant: plant.params[name]


def _inside(spec: SoftSpec, limit: StateLimit) -> bool:
    """Whether the soft bound `spec` is on `limit`'s state alone, with constant bounds within the limit."""
    lower, upper = spec.lower, spec.upper
    if not isinstance(lower, (int, float)) or not isinstance(upper, (int, float)):
        return False
    if limit.relative_to is not None or limit.upper_parameter is not None or spec.combination != {limit.state: 1.0}:
        return False
    return limit.lower <= lower and upper <= limit.upper


def scenario_tree(case: CaseStudy, known: models.Plant | None = None) -> dict:
    """The case's "scenario-tree NMPC" (see the module docstring), designed from `known` (default nominal)."""
    if case.mpc is None:
        raise NotProvided(f"the {case.plant} case has no MPC settings for a scenario-tree NMPC")
    known = models.get(case.plant) if known is None else known
    controller: ScenarioTreeMPC = scenario_tree_mpc(
        known, case.mpc, branches(models.get(case.plant)), tracked=case.tracked, name=LABEL
    )
    return {LABEL: controller}


def tube(case: CaseStudy, known: models.Plant | None = None) -> dict:
    """No "tube MPC" row: `NotProvided` naming why (see the module docstring)."""
    raise NotProvided(
        f"no tube MPC row for {case.plant}: mpc.TubeMPC regulates to its design point and takes no "
        "reference, and the study's scenarios step the reference; benchmarks/robust_mpc.py runs it"
    )
