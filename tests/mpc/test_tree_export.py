"""The scenario-tree NMPC exported as C (mpc.export_nmpc on a ScenarioTreeMPC): the C closed loop on the
true pendulum gives the Python tree's commands to 1e-9 over a short run, with the tree's stacked
problem (two corners of the ±5 % box in the pendulum's mass and length, robust horizon 2) solved by
the real-time iteration in C, its shared moves as equality rows of DAQP (horizon 6 over 0.5 s in the
default suite; horizon 20 over 2 s is slow: about 10 s, mostly the compilation)."""

from __future__ import annotations

import numpy as np
import pytest

import models
import studies
from models import compile as mc
from models.uncertainty import corner_params
from mpc.export_nmpc import export_nonlinear_mpc
from mpc.export_nmpc_replay import replay
from mpc.scenario_tree import scenario_tree_mpc

DURATION = 2.0
REFERENCE = 0.2


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


def _tree(horizon: int):
    case, plant = studies.get("pendulum"), models.get("pendulum")
    known = case.known_plant(plant)
    branches = corner_params(plant, rel=0.05, names=["m2", "ell"])[[0, -1]]  # the two opposite corners
    return case, plant, scenario_tree_mpc(known, case.mpc, branches, tracked="z", horizon=horizon, robust_horizon=2)


@pytest.mark.parametrize(
    "horizon, duration", [(6, 0.5), pytest.param(20, DURATION, marks=pytest.mark.slow)], ids=["short", "long"]
)
def test_exported_scenario_tree_gives_the_python_commands_in_closed_loop(horizon, duration):
    case, plant, tree = _tree(horizon)
    compiled = export_nonlinear_mpc(tree, "tree", [REFERENCE]).load()
    runs = [
        models.simulate_closed_loop(
            plant, c, REFERENCE, duration, input_disturbance=case.input_disturbance, noise_std=1e-4, seed=3
        )
        for c in (tree, compiled)
    ]
    assert runs[0].diverged_at is None
    assert runs[1].u.shape == runs[0].u.shape == (round(duration / tree.sample_period), plant.nu)
    assert all(s["success"] for s in runs[0].status) and all(s["success"] for s in runs[1].status)
    np.testing.assert_allclose(runs[1].u, runs[0].u, atol=1e-9, rtol=0)
    assert np.ptp(runs[0].u) > 0.1 * plant.input_limit[0]  # the run moves


@pytest.mark.slow  # about 25 s here: two C builds of the replay program
def test_the_branchwise_transformation_gives_daqps_own(tmp_path):
    """The exported QP's transformation (R, R⁻¹ and M = A R⁻¹ branch by branch, `ldp`) against DAQP's own
    update_ldp on the whole matrices (the same C built with -DDAQP_DENSE_LDP): the tree's H has one
    component per branch, the terms left out are exact zeros, so every command is the same double."""
    case, plant, tree = _tree(12)
    exported = export_nonlinear_mpc(tree, "tree_ldp", [REFERENCE])
    run = models.simulate_closed_loop(
        plant, exported.load(), REFERENCE, 1.0, input_disturbance=case.input_disturbance, noise_std=1e-4, seed=3
    )
    replays = [
        replay(exported, run.measured, run.r[:-1], tmp_path / name, flags=[*mc.FLAGS, *extra])
        for name, extra in (("branchwise", []), ("dense", ["-DDAQP_DENSE_LDP"]))
    ]
    assert all(np.all(r.codes == 0) for r in replays)
    np.testing.assert_array_equal(replays[0].commands, replays[1].commands)
    np.testing.assert_allclose(replays[0].commands, run.u, atol=1e-9, rtol=0)
    assert np.ptp(run.u) > 0.1 * plant.input_limit[0]
