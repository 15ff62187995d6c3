"""The robust rows of a study: the scenario tree's branches and settings, the tube's note."""

import dataclasses

import numpy as np
import pytest

import models
import studies
from models.state_limits import StateLimit
from mpc import ScenarioTreeMPC
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


def test_the_tube_row_is_absent_with_the_reason():
    with pytest.raises(providers.NotProvided, match="takes no reference"):
        robust_rows.tube(studies.get("pendulum"))
