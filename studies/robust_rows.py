"""The robust controllers' rows of a study, beside nominal MPC: the providers `scenario_tree` and `tube`.

Both are among a case's own providers (`studies.providers.STANDARD`) and both read only the case's
record: its MPC settings (`CaseStudy.mpc`), its physical limits (`CaseStudy.state_limits`), its
input disturbance, its references and its Monte Carlo box. A case without MPC settings has neither
row (`NotProvided`, noted). The choices below are the same for every case.

"scenario-tree NMPC" (`scenario_tree`): `mpc.ScenarioTreeMPC` with the case's own MPC settings
(those of its "nonlinear MPC" row: horizon, weights, soft bounds, estimator) over `branches`, the two
opposite corners of the Monte Carlo's ±5 % box around the case's plant (every uncertain parameter
5 % low, every one 5 % high; the known model, nominal·(1 + known_rel), is the high one), with equal
weights and robust horizon 1 (the first move shared, each branch's later moves its own). Two
branches, not the box's 2^k corners, and robust horizon 1: a step of the tree costs about what S
nominal steps cost or more (its QP has N·S inputs, its condensing grows with S²), and a row runs
every scenario and the Monte Carlo at the controller's sample rate. The horizon stays the case's,
so that the tree and the nominal NMPC differ in the branches only. `benchmarks/robust_mpc.py` runs
the fuller 4-corner trees and measures the cost per step.

"tube MPC" (`tube`): `mpc.TubeMPC` tracking the case's tracked coordinate (an artificial steady
state beside the plan, see `mpc.tube_mpc`), on the known model's zero-order-hold linearization at
its standard operating point at the MPC's sample period, with the MPC's weights Q, R, its horizon
N, and the ancillary feedback K the LQR of those weights. Its sets (`tube_design`):

- X, the constraints: every state within `region`: the case's physical limit where it gives one
  for that state alone (a limit on the plant's parameter at the box's smallest value), else the
  excursion its MPC weight accepts, 1/√Q_jj (the cases' weights are Bryson's: 1 / acceptable
  excursion²) about the operating point, the tracked coordinate's stretched over the references
  the study commands; and each limit on a difference of states (a deflection) as two rows.
- U: the actuator limit.
- W, the one-step error the tube holds: the parametric error of every corner of the Monte Carlo's
  box against the known linearization over X × U (`mpc.tube.disturbance_set`, each corner's drift
  from the operating point included), the case's input disturbance B·[−d, d], and a box of 1e-6
  in each state (so that 0 is inside W).
- Z = F(α, s) as a zonotope (`mpc.tube.TubeOptions(zonotope=True)`): RPI by construction, its
  support values in closed form, no LP per row; `record_error` is off, as each membership test
  would be an LP per step.

What the row guarantees: the `mpc.tube_mpc` guarantee for the linear model with w ∈ W, which here
means the models of the box's corners and their hull, the text's input disturbance, and states and
inputs in X × U; that is every scenario's parameter error and disturbance, as far as the linear
models go. Not covered: the linearization's remainder on the nonlinear plant (the larger the
reference moves the state from the operating point, the larger), parameters whose linear models
leave the corners' hull, the measurement noise scenario, and the offset a constant disturbance
leaves (no integral action). The table judges the true plant.

A tube that cannot be built is still a row. When W is larger than the constraints can hold, or the
tracking terminal set is empty, the construction's refusal (which names the constraint and the
margin it lacks) is what the row says: `Refused` stands in for the controller and raises it
(`ConstructionRefused`) at the first sample of every scenario, so each of its rows fails with that
message and nothing is simulated. There is no fallback to a smaller W.
"""

from __future__ import annotations

import dataclasses

import numpy as np

import models
from models.state_limits import StateLimit
from models.uncertainty import corner_params
from mpc import MPCSettings, ScenarioTreeMPC, SoftSpec, scenario_tree_mpc
from mpc.sets import Polytope, Zonotope
from mpc.tube import TubeOptions, ancillary_feedback, build_tube, disturbance_set, vertex_models
from mpc.tube_mpc import TubeMPC

from .case import KNOWN_ERROR, CaseStudy
from .provider_calls import NotProvided

#: The relative half-width of the text's box of parameters.
BOX = KNOWN_ERROR
#: The tree's label in the tables.
LABEL = "scenario-tree NMPC"
#: The tube's label in the tables.
TUBE_LABEL = "tube MPC"
#: The box added to W in every state (its units), so that the origin is in W's interior.
INTERIOR = 1e-6


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
    known = case.known_plant() if known is None else known
    controller: ScenarioTreeMPC = scenario_tree_mpc(
        known, case.mpc, branches(models.get(case.plant), box_of(case)), tracked=case.tracked, name=LABEL
    )
    return {LABEL: controller}


# ---------------------------------------------------------------------------- the tube's row
class ConstructionRefused(ValueError):
    """A robust controller whose construction was refused, raised where its row would run."""


@dataclasses.dataclass(frozen=True)
class Refused:
    """The stand-in of a controller whose construction was refused: a `models.Controller` that raises
    `ConstructionRefused` with `reason` at its first sample, so that each of its rows fails saying why
    (the status keeps the message's first 200 characters; `remark` carries all of it).

    Attributes
    ----------
    name : the row's label;  reason : the construction's refusal, naming the constraint and its margin
    sample_period : s;  measures, n_reference : as the refused controller's
    """

    name: str
    reason: str
    sample_period: float
    measures: str = "state"
    n_reference: int = 1

    @property
    def remark(self) -> str:
        """What every row of it says first (the runner's ``controller.remark``): the whole refusal."""
        return f"refused at construction: {self.reason}"

    def refusal(self) -> ConstructionRefused:
        """The error its rows fail with."""
        return ConstructionRefused(self.reason)

    def initial_state(self, y0, r0=None):
        """Raises `ConstructionRefused`: there is no controller to start."""
        raise self.refusal()

    def step(self, xc, y, r=None):
        """Raises `ConstructionRefused`: there is no controller to step."""
        raise self.refusal()

    def step_info(self) -> dict:
        """No step was taken: an empty record."""
        return {}


def box_of(case: CaseStudy) -> float:
    """The relative half-width of the case's Monte Carlo box (its "mc" scenario's), `BOX` without one."""
    return max((s.rel for s in case.scenarios if s.monte_carlo), default=BOX)


def region(case: CaseStudy, plant: models.Plant, known: models.Plant) -> tuple[np.ndarray, np.ndarray, list]:
    """The tube's state box in absolute coordinates (see the module docstring): lower, upper (nx,) and
    each side's source, "limit <name>", "excursion" or "references and excursion"."""
    xe, _ = known.equilibrium()
    excursion = 1 / np.sqrt(np.asarray(case.mpc.state_weight, dtype=float))
    lower, upper = xe - excursion, xe + excursion
    source = ["excursion"] * plant.nx
    tracked = plant.state_names.index(case.tracked)
    levels = [0.0] + [level for s in case.scenarios for level in s.levels]
    value = plant.equilibrium()[0][tracked]  # the study commands about the true plant's equilibrium
    lower[tracked] = value + min(levels) * case.step - excursion[tracked]
    upper[tracked] = value + max(levels) * case.step + excursion[tracked]
    source[tracked] = "references and excursion"
    rel = box_of(case)
    for limit in case.state_limits:
        if limit.relative_to is not None:
            continue
        j = plant.state_names.index(limit.state)
        top = limit.upper
        if limit.upper_parameter is not None:
            uncertain = limit.upper_parameter in plant.uncertain_params
            top = plant.params[limit.upper_parameter] * (1 - rel if uncertain else 1.0)
        lower[j], upper[j] = limit.lower, top
        source[j] = f"limit {limit.name}"
    return lower, upper, source


def tube_constraints(case: CaseStudy, plant: models.Plant, known: models.Plant) -> tuple[Polytope, list]:
    """X in deviations from the known operating point: `region`'s box, then two rows per limit on a
    difference of states; and the rows' names ("theta upper (excursion)"), which say where a row's
    bound comes from and, for a difference, its unit-length scaling (a refusal gives bounds as X has them)."""
    xe, _ = known.equilibrium()
    lower, upper, source = region(case, plant, known)
    n = plant.nx
    rows, bounds = [np.eye(n), -np.eye(n)], [upper - xe, xe - lower]
    names = [f"{s} upper ({w})" for s, w in zip(plant.state_names, source)]
    names += [f"{s} lower ({w})" for s, w in zip(plant.state_names, source)]
    for limit in case.state_limits:
        if limit.relative_to is None:
            continue
        row = np.zeros(n)
        row[plant.state_names.index(limit.state)] = 1.0
        row[plant.state_names.index(limit.relative_to)] = -1.0
        rows += [row[None, :], -row[None, :]]
        bounds += [[limit.upper - row @ xe], [row @ xe - limit.lower]]
        unit = f"limit, as ({limit.state} - {limit.relative_to})/√2"  # X's rows are unit length
        names += [f"{limit.name} upper ({unit})", f"{limit.name} lower ({unit})"]
    return Polytope(np.vstack(rows), np.concatenate(bounds)), names


def tube_design(case: CaseStudy, known: models.Plant) -> tuple:
    """(model, TubeSets) of the case's tube row (see the module docstring); ValueError when refused."""
    plant, settings = models.get(case.plant), case.mpc
    xe, ue = known.equilibrium()
    model = known.linearize(xe, ue).discretize(settings.sample_period)
    A, B = model.A, model.B
    X, names = tube_constraints(case, plant, known)
    limit = known.input_limit
    u_lower, u_upper = -limit - ue, limit - ue
    corners, offsets = vertex_models(plant, corner_params(plant, box_of(case)), xe, ue, settings.sample_period)
    lower, upper, _ = region(case, plant, known)
    W = disturbance_set(
        A,
        B,
        input_bound=case.input_disturbance,
        vertex_models=corners,
        offsets=offsets,
        state_lower=lower - xe,
        state_upper=upper - xe,
        input_lower=u_lower,
        input_upper=u_upper,
    ).plus(Zonotope.box(-INTERIOR * np.ones(plant.nx), INTERIOR * np.ones(plant.nx)))
    K = ancillary_feedback(A, B, np.diag(settings.state_weight), settings.input_weight)
    sets = build_tube(
        A, B, W, X, u_lower, u_upper, feedback=K, state_constraint_names=names, options=TubeOptions(zonotope=True)
    )
    return model, sets


def tube(case: CaseStudy, known: models.Plant | None = None) -> dict:
    """The case's "tube MPC" (see the module docstring), designed from `known` (default the case's known
    model); a `Refused` stand-in saying why when its construction is refused."""
    if case.mpc is None:
        raise NotProvided(f"the {case.plant} case has no MPC settings for a tube MPC")
    known = case.known_plant() if known is None else known
    settings = case.mpc
    try:
        model, sets = tube_design(case, known)
        tracked = np.zeros((known.nu, known.nx))
        tracked[0, known.state_names.index(case.tracked)] = 1.0
        controller = TubeMPC(
            model,
            sets,
            horizon=settings.horizon,
            state_weight=np.diag(settings.state_weight),
            input_weight=settings.input_weight,
            tracked_rows=tracked,
            record_error=False,
            name=TUBE_LABEL,
        )
    except ValueError as error:
        return {TUBE_LABEL: Refused(TUBE_LABEL, str(error), settings.sample_period)}
    return {TUBE_LABEL: controller}
