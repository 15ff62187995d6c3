"""The robust rows of a study: the scenario tree's branches and settings; the tube's region, constraints and
W from the case's record, its row where it builds (the UUV) keeping every constraint on its own linear
model under W's corners over the study's series of steps, and its refusal as a row that says why."""

import dataclasses
import re

import numpy as np
import pytest

import models
import studies
from models.state_limits import StateLimit
from mpc import ScenarioTreeMPC
from mpc.sets import Zonotope
from mpc.tube_mpc import TubeMPC
from studies import providers, robust_rows
from studies.cases import pendulum
from studies.provider_calls import find


def test_branches_are_the_two_opposite_corners_of_the_box():
    plant = models.get("pendulum")
    low, high = robust_rows.branches(plant)
    for i, name in enumerate(plant.params):
        factor = (0.95, 1.05) if name in plant.uncertain_params else (1.0, 1.0)
        assert low[i] == pytest.approx(plant.params[name] * factor[0], rel=1e-15)
        assert high[i] == pytest.approx(plant.params[name] * factor[1], rel=1e-15)


def test_state_limits_become_soft_bounds_unless_already_bound_within_them():
    settings = studies.get("pendulum").mpc
    limited = robust_rows.with_limits(settings, pendulum.STATE_LIMITS)
    assert limited.soft[: len(settings.soft)] == settings.soft
    (travel,) = limited.soft[len(settings.soft) :]
    (limit,) = pendulum.STATE_LIMITS
    assert travel.combination == {"z": 1.0} and (travel.lower, travel.upper) == (limit.lower, limit.upper)
    deflection = StateLimit("gap", "z", -1.0, 1.0, source="test", relative_to="theta", upper_parameter="ell")
    (gap,) = robust_rows.with_limits(settings, [deflection]).soft[len(settings.soft) :]
    known = models.get("pendulum").with_params(ell=0.7)
    assert gap.combination == {"z": 1.0, "theta": -1.0} and gap.bounds(known) == (-1.0, 0.7)
    wider = StateLimit("swing", "theta", -0.3, 0.3, source="test")  # the case already holds |theta| <= 0.2
    assert robust_rows.with_limits(settings, [wider]).soft == settings.soft
    with pytest.raises(TypeError, match="StateLimit"):
        robust_rows.with_limits(settings, [("z", -1, 1)])


def test_the_robust_rows_are_providers_the_command_line_finds():
    assert find("studies.robust_rows:scenario_tree") is robust_rows.scenario_tree
    assert find("studies.robust_rows:tube") is robust_rows.tube


@pytest.mark.slow  # builds (and compiles) the pendulum's tree: about 20 s
def test_the_scenario_tree_row_is_built_on_the_case_settings():
    case = studies.get("pendulum")
    known = case.known_plant()
    (controller,) = robust_rows.scenario_tree(case, known).values()
    assert isinstance(controller, ScenarioTreeMPC) and controller.name == robust_rows.LABEL
    np.testing.assert_array_equal(controller.branch_params, robust_rows.branches(models.get("pendulum")))
    assert controller.horizon == case.mpc.horizon and controller.robust_horizon == 1
    no_mpc = dataclasses.replace(case, mpc=None)
    with pytest.raises(providers.NotProvided, match="no MPC settings"):
        robust_rows.scenario_tree(no_mpc, known)


def test_both_rows_are_among_the_cases_own_providers():
    assert robust_rows.scenario_tree in providers.STANDARD and robust_rows.tube in providers.STANDARD
    no_mpc = dataclasses.replace(studies.get("arm"), mpc=None)
    for provider in (robust_rows.scenario_tree, robust_rows.tube):
        with pytest.raises(providers.NotProvided, match="no MPC settings"):
            provider(no_mpc)


def test_the_tube_region_is_the_limits_the_excursions_and_the_references():
    """Pendulum: the cart travel from its limit (±2.5 m, wider than the ±2 m references), θ and the rates
    from the MPC's Bryson weights (1/√Q); ball on beam: 0 <= z <= ℓ at the box's shortest beam."""
    case, plant = studies.get("pendulum"), models.get("pendulum")
    lower, upper, source = robust_rows.region(case, plant, case.known_plant())
    excursion = 1 / np.sqrt(case.mpc.state_weight)
    np.testing.assert_allclose(upper, [2.5, *excursion[1:]], rtol=1e-15)
    np.testing.assert_allclose(lower, -upper, rtol=1e-15)
    assert source == ["limit cart travel", "excursion", "excursion", "excursion"]
    ballbeam = studies.get("ballbeam")
    lower, upper, _ = robust_rows.region(ballbeam, models.get("ballbeam"), ballbeam.known_plant())
    assert (lower[0], upper[0]) == (0.0, pytest.approx(0.5 * 0.95, rel=1e-15))
    uuv = studies.get("uuv")  # the roll's references span ±30°, widened by its excursion 0.1 rad
    lower, upper, _ = robust_rows.region(uuv, models.get("uuv"), uuv.known_plant())
    assert (lower[0], upper[0]) == (pytest.approx(-np.deg2rad(30) - 0.1), pytest.approx(np.deg2rad(30) + 0.1))


def test_a_deflection_limit_is_two_rows_of_the_tube_constraints():
    case, plant = studies.get("satellite"), models.get("satellite")
    X, names = robust_rows.tube_constraints(case, plant, case.known_plant())
    theta, phi = plant.state_names.index("theta"), plant.state_names.index("phi")
    row = names.index("panel deflection upper (limit, as (phi - theta)/√2)")
    expected = np.zeros(plant.nx)
    expected[[phi, theta]] = [1.0, -1.0]
    np.testing.assert_allclose(X.H[row] * np.sqrt(2), expected, atol=1e-15)  # Polytope rows are unit length
    assert X.h[row] * np.sqrt(2) == pytest.approx(0.2, rel=1e-12)  # about the operating point, φ = θ


@pytest.fixture(scope="module")
def uuv_tube():
    case = studies.get("uuv")
    (controller,) = robust_rows.tube(case, case.known_plant()).values()
    return case, controller


def test_the_uuv_tube_row_tracks_the_roll_with_the_case_settings(uuv_tube):
    case, controller = uuv_tube
    assert isinstance(controller, TubeMPC) and controller.tracking and controller.name == robust_rows.TUBE_LABEL
    assert controller.horizon == case.mpc.horizon and controller.sample_period == case.mpc.sample_period
    assert controller.tube.error_set_exact and isinstance(controller.tube.error_set, Zonotope)


def test_the_uuv_tube_row_keeps_its_constraints_on_its_linear_model_under_w(uuv_tube):
    """Where the row's guarantee is exact: the known linear model with w at W's corners (the parametric
    error's box, the disturbance and the interior box), over the study's series of steps."""
    case, controller = uuv_tube
    model, tube = controller.model, controller.tube
    W = tube.disturbance
    signs = np.sign(np.random.default_rng(0).normal(size=(W.generators.shape[1], 4000)))
    corners = W.center[:, None] + W.generators @ signs  # extreme points of W
    X = robust_rows.tube_constraints(case, models.get("uuv"), case.known_plant())[0]
    limit = case.known_plant().input_limit
    steps = dict((s.name, s) for s in case.scenarios)["steps"]
    count = round(steps.duration(case) / controller.sample_period)
    reference = steps.reference(case, 0.0)
    for seed in range(10):
        rng = np.random.default_rng(seed)
        x = model.xe.copy()
        z = controller.initial_state(x, [reference(0.0)])
        for k in range(count):
            z, u = controller.step(z, x, [reference(k * controller.sample_period)])
            assert abs(u[0]) <= limit[0] + 1e-9
            x = model.xe + model.A @ (x - model.xe) + model.B @ (u - model.ue) + corners[:, rng.integers(4000)]
            assert X.contains((x - model.xe)[None, :], tolerance=1e-9)[0]


def test_a_refused_tube_is_a_row_that_says_why():
    """The pendulum's W (its ±5 % box over the tube's region and 0.5 N) is more than its 5 N can hold: the
    row stands, and each scenario fails with the refusal naming the input bound and the margin it lacks."""
    case = studies.get("pendulum")
    (refused,) = robust_rows.tube(case, case.known_plant()).values()
    assert isinstance(refused, robust_rows.Refused)
    with pytest.raises(robust_rows.ConstructionRefused, match=r"^the error set is larger.*'input 0 upper' lacks"):
        refused.initial_state(np.zeros(4), [0.0])
    assert refused.remark == f"refused at construction: {refused.reason}" and "lacks at least" in refused.reason
    result = studies.run_study(case, scenarios=("step", "mc"), mc=2, providers=[robust_rows.tube])
    rows = result.table[result.table.controller == robust_rows.TUBE_LABEL]
    assert list(rows.scenario) == ["step", "mc"]
    assert not any("tube MPC" in note for note in result.notes)  # the remark explains the failures
    for status in rows.status:
        assert status.startswith("failed: ConstructionRefused: the error set is larger")
        assert re.search(r"'input 0 upper' lacks at least [\d.]+ \(bound 5,", status), status
