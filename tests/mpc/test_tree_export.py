"""The scenario-tree NMPC is not exported to C (mpc.export_nmpc): the refusal names the tree, its
branches and robust horizon, and what the C would have to do differently; the nominal NMPC beside it
still exports (tests/mpc/test_export_nmpc.py runs its C against Python)."""

import pytest

import models
import studies
from models.export import UnsupportedExport
from models.uncertainty import corner_params
from mpc.export_nmpc import export_nonlinear_mpc
from mpc.scenario_tree import scenario_tree_mpc


def test_a_scenario_tree_is_refused_by_the_nonlinear_export_naming_it():
    case, plant = studies.get("pendulum"), models.get("pendulum")
    known = case.known_plant(plant)
    branches = corner_params(plant, rel=0.05, names=["m2"])
    tree = scenario_tree_mpc(known, case.mpc, branches, tracked="z", compiled=False, horizon=5, robust_horizon=2)
    with pytest.raises(
        UnsupportedExport,
        match=r"scenario-tree NMPC: a scenario tree \(2 branches, robust horizon 2\) is not exported: "
        r".*ScenarioTreeProblem",
    ):
        export_nonlinear_mpc(tree, "tree", [0.0])
